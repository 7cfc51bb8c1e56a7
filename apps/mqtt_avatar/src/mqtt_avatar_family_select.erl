%% @doc Internal. The `select' family (HA `select', zigbee2mqtt's settable
%% `enum' exposes): `Select<Name>' with request parameter `Option', one of
%% the options; the stream `SENSOR/<Name>' and `Read<Name>'.
%% docs/mqtt.md section 2.4.
-module(mqtt_avatar_family_select).
-behaviour(mqtt_avatar_family).

-export([from_ha/2, from_z2m/2, generate/2, abbreviations/0]).

-spec abbreviations() -> [{binary(), binary()}].
abbreviations() -> [{<<"ops">>, <<"options">>}].

-spec from_ha(map(), mqtt_avatar_discovery:entity()) ->
          {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
from_ha(C, Base) ->
    mqtt_avatar_ha:require(command_topic, Base, fun() ->
        case mqtt_avatar_ha:strings(<<"options">>, C) of
            [_ | _] = Options ->
                mqtt_avatar_ha:with_command_template(C, Base#{options => Options,
                                                              field => undefined});
            _ -> {error, <<"a select needs options">>}
        end
    end).

%% @doc A settable zigbee2mqtt `enum' expose.
-spec from_z2m(map(), mqtt_avatar_z2m:ctx()) -> [mqtt_avatar_discovery:entity()].
from_z2m(#{<<"property">> := P} = X, Ctx) ->
    Options = case maps:get(<<"values">>, X, []) of
                  L when is_list(L) -> [V || V <- [mqtt_avatar_z2m:text(V0) || V0 <- L], is_binary(V)];
                  _ -> []
              end,
    E = mqtt_avatar_z2m:entity(select, P, Ctx),
    [E#{name := mqtt_avatar_z2m:text(maps:get(<<"label">>, X, maps:get(<<"name">>, X, P))),
        value := {json, [P]}, options => Options, field => P}].

-spec generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) -> mqtt_avatar_part:part().
generate(#{options := Options} = E, Ctx) ->
    mqtt_avatar_part:valued(E, <<"Select">>, <<"Option">>, [], mqtt_avatar_part:one_of(Options),
                            <<"Select">>, Ctx).

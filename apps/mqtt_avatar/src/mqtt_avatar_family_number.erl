%% @doc Internal. The `number' family (HA `number', zigbee2mqtt's settable
%% `numeric' exposes): `Set<Name>' with request parameter `Value' checked
%% against min..max, capabilities Min, Max, Step, Unit; the stream
%% `SENSOR/<Name>' and `Read<Name>'. docs/mqtt.md section 2.4.
-module(mqtt_avatar_family_number).
-behaviour(mqtt_avatar_family).

-export([from_ha/2, from_z2m/2, generate/2, abbreviations/0]).

-spec abbreviations() -> [{binary(), binary()}].
abbreviations() -> [].

-spec from_ha(map(), mqtt_avatar_discovery:entity()) ->
          {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
from_ha(C, Base) ->
    mqtt_avatar_ha:require(command_topic, Base, fun() ->
        mqtt_avatar_ha:with_command_template(
          C, Base#{min => mqtt_avatar_ha:number(<<"min">>, C, <<"1">>),
                   max => mqtt_avatar_ha:number(<<"max">>, C, <<"100">>),
                   step => mqtt_avatar_ha:number(<<"step">>, C, <<"1">>),
                   field => undefined})
    end).

%% @doc A settable zigbee2mqtt `numeric' expose.
-spec from_z2m(map(), mqtt_avatar_z2m:ctx()) -> [mqtt_avatar_discovery:entity()].
from_z2m(#{<<"property">> := P} = X, Ctx) ->
    Num = fun(K, D) -> case maps:get(K, X, undefined) of
                           N when is_number(N) -> evatar_json:to_text(N);
                           _ -> D
                       end
          end,
    E = mqtt_avatar_z2m:entity(number, P, Ctx),
    [E#{name := mqtt_avatar_z2m:text(maps:get(<<"label">>, X, maps:get(<<"name">>, X, P))),
        value := {json, [P]}, unit := mqtt_avatar_z2m:text(maps:get(<<"unit">>, X, undefined)),
        min => Num(<<"value_min">>, undefined), max => Num(<<"value_max">>, undefined),
        step => Num(<<"value_step">>, undefined), field => P}].

-spec generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) -> mqtt_avatar_part:part().
generate(#{min := Min, max := Max, step := Step} = E, Ctx) ->
    Caps = [{N, V} || {N, V} <- [{<<"Min">>, Min}, {<<"Max">>, Max}, {<<"Step">>, Step},
                                 {<<"Unit">>, maps:get(unit, E)},
                                 {<<"DeviceClass">>, maps:get(device_class, E)}], is_binary(V)],
    Check = case is_binary(Min) andalso is_binary(Max) of
                true -> mqtt_avatar_part:range(Min, Max);
                false -> <<>>
            end,
    mqtt_avatar_part:valued(E, <<"Set">>, <<"Value">>, Caps, Check, <<"Number">>, Ctx).

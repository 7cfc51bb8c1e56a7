%% @doc Internal. The `siren' family (HA `siren'): one service that turns
%% the siren on with a tone (`Sound'), and `Volume'/`Duration' when the
%% siren supports them, as JSON. docs/mqtt.md section 2.
-module(mqtt_avatar_family_siren).
-behaviour(mqtt_avatar_family).

-export([from_ha/2, generate/2, abbreviations/0]).

-spec from_ha(map(), mqtt_avatar_discovery:entity()) ->
          {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
from_ha(C, Base) ->
    mqtt_avatar_ha:require(command_topic, Base, fun() ->
        {ok, maps:merge(Base#{volume => mqtt_avatar_ha:bool(<<"support_volume_set">>, C, false),
                              duration => mqtt_avatar_ha:bool(<<"support_duration">>, C, false)},
                        mqtt_avatar_ha:on_off(C))}
    end).

-spec generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) -> mqtt_avatar_part:part().
generate(E, Ctx) ->
    Type = mqtt_avatar_part:camel(mqtt_avatar_part:first_name([maps:get(name, E), <<"PlaySound">>])),
    Args = [<<"Sound=tone">>]
        ++ [<<"Volume=volume_level">> || maps:get(volume, E)]
        ++ [<<"Duration=duration">> || maps:get(duration, E)],
    Capabilities = [{<<"Sound">>, <<"yes">>}]
        ++ [{<<"Volume">>, <<"yes">>} || maps:get(volume, E)]
        ++ [{<<"Duration">>, <<"yes">>} || maps:get(duration, E)],
    Command = iolist_to_binary(mqtt_avatar_json:encode(#{<<"state">> => maps:get(on, E)})),
    Params = Capabilities ++ maps:get(room, Ctx)
        ++ [{<<"MqttCommandTopic">>, maps:get(command_topic, E)},
            {<<"MqttCommand">>, <<"json:", Command/binary>>},
            {<<"MqttCommandArgs">>, iolist_to_binary(lists:join(" ", Args))}]
        ++ mqtt_avatar_part:echo_params(E, <<"any">>),
    mqtt_avatar_part:actuator([mqtt_avatar_part:entry(<<"ACTUATOR">>, Type, Params)], Ctx).

-spec abbreviations() -> [{binary(), binary()}].
abbreviations() -> [].

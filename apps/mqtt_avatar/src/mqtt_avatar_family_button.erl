%% @doc Internal. The `button' family (HA `button'): one service named
%% after the button that publishes `payload_press'. docs/mqtt.md section 2.
-module(mqtt_avatar_family_button).
-behaviour(mqtt_avatar_family).

-export([from_ha/2, generate/2, abbreviations/0]).

-spec from_ha(map(), mqtt_avatar_discovery:entity()) ->
          {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
from_ha(C, Base) ->
    mqtt_avatar_ha:require(command_topic, Base, fun() ->
        {ok, Base#{press => mqtt_avatar_ha:str(<<"payload_press">>, C, <<"PRESS">>)}}
    end).

-spec generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) -> mqtt_avatar_part:part().
generate(E, Ctx) ->
    Type = mqtt_avatar_part:camel(mqtt_avatar_part:first_name([maps:get(name, E), <<"Press">>])),
    Params = maps:get(room, Ctx)
        ++ [{<<"MqttCommandTopic">>, maps:get(command_topic, E)},
            {<<"MqttCommand">>, <<"raw:", (maps:get(press, E))/binary>>},
            {<<"MqttExpect">>, <<"none">>}],
    mqtt_avatar_part:actuator([mqtt_avatar_part:entry(<<"ACTUATOR">>, Type, Params)], Ctx).

-spec abbreviations() -> [{binary(), binary()}].
abbreviations() -> [].

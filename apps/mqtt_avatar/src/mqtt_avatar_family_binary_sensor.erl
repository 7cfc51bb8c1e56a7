%% @doc Internal. The `binary_sensor' family (HA `binary_sensor',
%% zigbee2mqtt's `binary' exposes): Events when the state changes
%% (MotionDetected for motion, occupancy and presence), and a read service.
%% docs/mqtt.md section 2.
-module(mqtt_avatar_family_binary_sensor).
-behaviour(mqtt_avatar_family).

-export([from_ha/2, generate/2]).

-spec from_ha(map(), mqtt_avatar_discovery:entity()) ->
          {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
from_ha(C, Base) ->
    mqtt_avatar_ha:require(state_topic, Base, fun() ->
        {ok, maps:merge(Base, mqtt_avatar_ha:on_off(C))}
    end).

-spec generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) -> mqtt_avatar_part:part().
generate(E, #{room := Room}) ->
    {Param, Stream, Read} =
        case lists:member(maps:get(device_class, E), [<<"motion">>, <<"occupancy">>, <<"presence">>,
                                                       <<"moving">>]) of
            true -> {<<"Motion">>, <<"MotionDetected">>, <<"ReadMotion">>};
            false ->
                P = mqtt_avatar_part:camel(mqtt_avatar_part:first_name(
                                             [maps:get(name, E), maps:get(device_class, E),
                                              <<"State">>])),
                {P, <<P/binary, "Changed">>, <<"Read", P/binary>>}
        end,
    Map = mqtt_avatar_part:on_off_map(E, <<"yes">>, <<"no">>),
    mqtt_avatar_part:stream(E, Room, Param, Stream, Read, event, Map).

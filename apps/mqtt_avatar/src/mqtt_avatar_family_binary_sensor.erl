%% @doc Internal. The `binary_sensor' family (HA `binary_sensor',
%% zigbee2mqtt's `binary' exposes): Events when the state changes
%% (MotionDetected for motion, occupancy and presence; else named after
%% the sensor and after its device class), and a read service.
%% docs/mqtt.md section 2.
-module(mqtt_avatar_family_binary_sensor).
-behaviour(mqtt_avatar_family).

-export([from_ha/2, generate/2, abbreviations/0]).

-spec from_ha(map(), mqtt_avatar_discovery:entity()) ->
          {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
from_ha(C, Base) ->
    mqtt_avatar_ha:require(state_topic, Base, fun() ->
        {ok, maps:merge(Base, mqtt_avatar_ha:on_off(C))}
    end).

-spec generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) -> mqtt_avatar_part:part().
generate(E, #{room := Room}) ->
    Map = mqtt_avatar_part:on_off_map(E, <<"yes">>, <<"no">>),
    Parts = case lists:member(maps:get(device_class, E), [<<"motion">>, <<"occupancy">>,
                                                          <<"presence">>, <<"moving">>]) of
                true ->
                    [mqtt_avatar_part:stream(E, Room, <<"Motion">>, <<"MotionDetected">>,
                                             <<"ReadMotion">>, event, Map)];
                false ->
                    %% Named after what the user called it and after what it is.
                    {Name, Class} = mqtt_avatar_part:named(E, <<"State">>),
                    [mqtt_avatar_part:stream(E, Room, P, <<P/binary, "Changed">>, <<"Read", P/binary>>,
                                             event, Map)
                     || P <- [Name | [Class || Class =/= undefined]]]
            end,
    mqtt_avatar_part:with_info(mqtt_avatar_part:merge(Parts),
                               [{<<"DeviceClass">>, maps:get(device_class, E)}]).

-spec abbreviations() -> [{binary(), binary()}].
abbreviations() -> [].

%% @doc Internal. The `sensor' family (HA `sensor', zigbee2mqtt's
%% `numeric', `enum' and `text' exposes): SensorData readings and a read
%% service, named after the sensor and after its device class, with its
%% unit, device class and state class. docs/mqtt.md section 2.
-module(mqtt_avatar_family_sensor).
-behaviour(mqtt_avatar_family).

-export([from_ha/2, generate/2, abbreviations/0]).

-spec from_ha(map(), mqtt_avatar_discovery:entity()) ->
          {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
from_ha(_C, Base) ->
    mqtt_avatar_ha:require(state_topic, Base, fun() -> {ok, Base} end).

-spec generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) -> mqtt_avatar_part:part().
generate(E, #{room := Room}) ->
    %% Named after what the user called it and after what it is, so a VA
    %% asking for a Temperature in the kitchen binds whatever its name.
    {Name, Class} = mqtt_avatar_part:named(E, <<"Value">>),
    Parts = [mqtt_avatar_part:stream(E, Room, P, P, <<"Read", P/binary>>, sensor_data, [])
             || P <- [Name | [Class || Class =/= undefined]]],
    mqtt_avatar_part:with_info(mqtt_avatar_part:merge(Parts),
                               [{<<"Unit">>, maps:get(unit, E)},
                                {<<"DeviceClass">>, maps:get(device_class, E)},
                                {<<"StateClass">>, maps:get(state_class, E, undefined)}]).

-spec abbreviations() -> [{binary(), binary()}].
abbreviations() -> [].

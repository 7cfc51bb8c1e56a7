%% @doc Internal. The `sensor' family (HA `sensor', zigbee2mqtt's
%% `numeric', `enum' and `text' exposes): SensorData readings and a read
%% service, named after the sensor. docs/mqtt.md section 2.
-module(mqtt_avatar_family_sensor).
-behaviour(mqtt_avatar_family).

-export([from_ha/2, generate/2]).

-spec from_ha(map(), mqtt_avatar_discovery:entity()) ->
          {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
from_ha(_C, Base) ->
    mqtt_avatar_ha:require(state_topic, Base, fun() -> {ok, Base} end).

-spec generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) -> mqtt_avatar_part:part().
generate(E, #{room := Room}) ->
    P = mqtt_avatar_part:camel(mqtt_avatar_part:first_name(
                                 [maps:get(name, E), maps:get(device_class, E), <<"Value">>])),
    mqtt_avatar_part:stream(E, Room, P, P, <<"Read", P/binary>>, sensor_data, []).

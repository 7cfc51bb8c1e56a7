%% @doc Internal. The `event' family (HA `event', zigbee2mqtt's `action'
%% enum): an Event stream whose `Event' parameter is the event type, with
%% the event's other fields. docs/mqtt.md section 2.
-module(mqtt_avatar_family_event).
-behaviour(mqtt_avatar_family).

-export([from_ha/2, generate/2, abbreviations/0]).

-spec from_ha(map(), mqtt_avatar_discovery:entity()) ->
          {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
from_ha(_C, Base) ->
    mqtt_avatar_ha:require(state_topic, Base, fun() -> {ok, Base#{attributes := true}} end).

-spec generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) -> mqtt_avatar_part:part().
generate(E, #{room := Room}) ->
    P = mqtt_avatar_part:camel(mqtt_avatar_part:first_name([maps:get(name, E), <<"Event">>])),
    Value = case maps:get(value, E) of
                raw -> {json, [<<"event_type">>]};
                V -> V
            end,
    mqtt_avatar_part:stream(E#{value := Value, attributes := true}, Room, <<"Event">>, P,
                            <<"Read", P/binary>>, event, [], P).

-spec abbreviations() -> [{binary(), binary()}].
abbreviations() -> [].

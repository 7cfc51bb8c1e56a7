%% @doc Internal. The `sensor' family (HA `sensor', zigbee2mqtt's
%% `numeric', `enum' and `text' exposes): SensorData readings and a read
%% service, named after the sensor and after its device class, with its
%% unit, device class and state class. docs/mqtt.md section 2.
-module(mqtt_avatar_family_sensor).
-behaviour(mqtt_avatar_family).

-export([from_ha/2, generate/2, abbreviations/0]).

-spec from_ha(map(), mqtt_avatar_discovery:entity()) ->
          {ok, mqtt_avatar_discovery:entity()} | {error, binary()}.
from_ha(C, Base) ->
    mqtt_avatar_ha:require(state_topic, Base, fun() ->
        {ok, Base#{numeric => numeric(Base, mqtt_avatar_ha:str(<<"suggested_display_precision">>, C))}}
    end).

%% Home Assistant expects numbers of a sensor with a device class (but
%% date, enum and timestamp, the classes it knows to be text), a unit, a
%% state class or a display precision, and refuses any other state of it:
%% so does the Avatar (MqttNumeric, docs/mqtt.md section 3.3).
numeric(E, Precision) ->
    Class = maps:get(device_class, E, undefined),
    case lists:member(Class, [<<"date">>, <<"enum">>, <<"timestamp">>]) of
        true -> false;
        false -> lists:any(fun(V) -> V =/= undefined end,
                           [Class, maps:get(unit, E, undefined), maps:get(state_class, E, undefined),
                            Precision])
    end.

-spec generate(mqtt_avatar_discovery:entity(), mqtt_avatar_part:ctx()) -> mqtt_avatar_part:part().
generate(E, #{room := Room}) ->
    %% Named after what the user called it and after what it is, so a VA
    %% asking for a Temperature in the kitchen binds whatever its name.
    {Name, Class} = mqtt_avatar_part:named(E, <<"Value">>),
    Numeric = maps:get(numeric, E, false),
    Parts = [numeric(mqtt_avatar_part:stream(E, Room, P, P, <<"Read", P/binary>>, sensor_data, []),
                     P, Numeric)
             || P <- [Name | [Class || Class =/= undefined]]],
    mqtt_avatar_part:with_info(mqtt_avatar_part:merge(Parts),
                               [{<<"Unit">>, maps:get(unit, E)},
                                {<<"DeviceClass">>, maps:get(device_class, E)},
                                {<<"StateClass">>, maps:get(state_class, E, undefined)}]).

numeric(Part, _Param, false) ->
    Part;
numeric(#{consumes := Consumes} = Part, Param, true) ->
    Part#{consumes := [C#{parameters := Ps ++ [{<<"MqttNumeric">>, Param}]}
                       || #{parameters := Ps} = C <- Consumes]}.

-spec abbreviations() -> [{binary(), binary()}].
abbreviations() -> [].

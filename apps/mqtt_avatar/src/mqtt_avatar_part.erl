%% @doc Internal. The building blocks a device family (mqtt_avatar_family_*)
%% writes its BIL with: entries, on/off actuators, streams with their read
%% service, and the reserved `Mqtt*' parameters (docs/mqtt.md section 3)
%% that tie them to topics. Pure.
-module(mqtt_avatar_part).

-export([entry/3, on_off/6, actuator/2, actuator/3, stream/7, stream/8, command/4,
         echo_params/2, value_params/3, match/2, on_off_map/3, source/1, join_path/1,
         json_at/2, first_name/1, camel/1, extra/1, named/2]).

-export_type([part/0, ctx/0]).

%% What one entity contributes to its device's component: Services,
%% Consumes entries, the parameters its sensors add to the device's
%% combined read service, and the Device of the component's ACTION
%% FEEDBACK entry (`none': the entity needs none).
-type part() :: #{services := [bil:entry()],
                  consumes := [bil:entry()],
                  sensor := [binary()],
                  feedback := none | binary()}.
%% `room': the `Room' parameter of every entry (or none); `device': the
%% device the entity belongs to.
-type ctx() :: #{room := [bil:parameter()], device := mqtt_avatar_discovery:device()}.

%% @doc One BIL entry.
-spec entry(binary(), binary(), [bil:parameter()]) -> bil:entry().
entry(Category, Type, Params) ->
    #{category => Category, type => Type, parameters => Params}.

%% @doc An on/off actuator (lights, switches, fans, humidifiers): two
%% services whose commands are `on'/`off' (raw, or JSON at the value's path
%% when `json_command'), confirmed by `state_on'/`state_off' on the state
%% topic, whose value becomes the feedback parameter `StateParam' on/off.
-spec on_off(mqtt_avatar_discovery:entity(), ctx(), {binary(), binary()}, [bil:parameter()],
             binary(), binary()) -> part().
on_off(E, Ctx, {OnType, OffType}, Capabilities, StateParam, Device) ->
    #{on := On, off := Off, state_on := SOn, state_off := SOff, value := Value} = E,
    Room = maps:get(room, Ctx),
    Command = fun(Payload) ->
                      case {maps:get(json_command, E), Value} of
                          {true, {json, [_ | _] = Path}} ->
                              <<"json:", (json_at(Path, Payload))/binary>>;
                          {true, _} ->
                              <<"json:", (json_at([<<"state">>], Payload))/binary>>;
                          {false, _} ->
                              <<"raw:", Payload/binary>>
                      end
              end,
    Entry = fun(Type, Payload, Expected) ->
                    entry(<<"ACTUATOR">>, Type,
                          Capabilities ++ Room
                          ++ [{<<"MqttCommandTopic">>, maps:get(command_topic, E)},
                              {<<"MqttCommand">>, Command(Payload)}]
                          ++ echo_params(E, match(Value, Expected))
                          ++ value_params(E, StateParam, on_off_map(E, <<"on">>, <<"off">>)))
            end,
    actuator([Entry(OnType, On, SOn), Entry(OffType, Off, SOff)], Ctx, Device).

%% @doc A command service: `Payload' (`raw:...' or `json:...') published on
%% `Topic', request parameters `Args' (MqttCommandArgs) put into it, and the
%% rest of `Params' (capabilities, Mqtt* echo parameters) as given.
-spec command(binary(), binary(), binary(), [bil:parameter()]) -> bil:entry().
command(Type, Topic, Payload, Params) ->
    {Mqtt, Plain} = lists:partition(fun({N, _}) -> mqtt_avatar_spec:is_reserved(N) end, Params),
    entry(<<"ACTUATOR">>, Type, Plain ++ [{<<"MqttCommandTopic">>, Topic},
                                          {<<"MqttCommand">>, Payload} | Mqtt]).

%% What confirms a command: a state topic and the value expected on it.
-spec echo_params(map(), binary()) -> [bil:parameter()].
echo_params(#{state_topic := undefined}, _Expect) ->
    [{<<"MqttExpect">>, <<"none">>}];
echo_params(#{state_topic := T} = E, Expect) ->
    [{<<"MqttStateTopic">>, T}, {<<"MqttExpect">>, Expect}]
        ++ [{<<"MqttAttributes">>, <<"all">>} || maps:get(attributes, E, false)].

%% @doc The feedback parameter `Param' read from the echo, translated by
%% `Map' (MqttMap text).
-spec value_params(map(), binary(), binary()) -> [bil:parameter()].
value_params(#{state_topic := undefined}, _Param, _Map) ->
    [];
value_params(#{value := V}, Param, Map) ->
    [{<<"MqttValue">>, <<Param/binary, "=", (source(V))/binary>>}]
        ++ [{<<"MqttMap">>, Map} || Map =/= <<>>].

%% @doc An MqttExpect text: the payload (or its field) equal to `Expected'.
-spec match(mqtt_avatar_spec:source(), binary()) -> binary().
match(raw, Expected) -> <<"raw:", Expected/binary>>;
match({json, Path}, Expected) -> <<"json:", (join_path(Path))/binary, "=", Expected/binary>>.

%% @doc An MqttMap translating the entity's `state_on'/`state_off' to
%% `ToOn'/`ToOff' (`<<>>' when nothing needs translating or cannot be).
-spec on_off_map(map(), binary(), binary()) -> binary().
on_off_map(#{state_on := On, state_off := Off}, ToOn, ToOff) ->
    case lists:all(fun plain_token/1, [On, Off]) andalso
        {bool_key(On), bool_key(Off)} =/= {ToOn, ToOff} of
        true -> <<(bool_key(On))/binary, "=", ToOn/binary, " ", (bool_key(Off))/binary, "=",
                  ToOff/binary>>;
        false -> <<>>
    end.

%% JSON booleans arrive as yes/no (docs/mqtt.md), so map those.
bool_key(<<"true">>) -> <<"yes">>;
bool_key(<<"false">>) -> <<"no">>;
bool_key(V) -> V.

plain_token(<<>>) -> false;
plain_token(V) -> binary:match(V, [<<" ">>, <<"=">>, <<"\t">>, <<"\n">>]) =:= nomatch.

%% @doc A stream (Consumes `SENSOR/Stream' fed by the entity's state topic,
%% its value as parameter `Param') and its read service `SENSOR/Read'.
-spec stream(map(), [bil:parameter()], binary(), binary(), binary(), sensor_data | event,
             binary() | [term()]) -> part().
stream(E, Room, Param, Stream, Read, Context, Map) ->
    stream(E, Room, Param, Stream, Read, Context, Map, Param).

-spec stream(map(), [bil:parameter()], binary(), binary(), binary(), sensor_data | event,
             binary() | [term()], binary()) -> part().
stream(E, Room, Param, Stream, Read, Context, Map, SensorParam) ->
    Consumes = entry(<<"SENSOR">>, Stream,
                     Room ++ [{<<"MqttStateTopic">>, maps:get(state_topic, E)},
                              {<<"MqttValue">>, <<Param/binary, "=", (source(maps:get(value, E)))/binary>>}]
                     ++ [{<<"MqttMap">>, Map} || is_binary(Map), Map =/= <<>>]
                     ++ [{<<"MqttContext">>, <<"Event">>} || Context =:= event]
                     ++ [{<<"MqttAttributes">>, <<"all">>} || maps:get(attributes, E, false)]
                     ++ [{<<"MqttOnChange">>, <<"yes">>} || maps:get(on_change, E, false)]),
    Service = entry(<<"SENSOR">>, Read, [{SensorParam, <<"yes">>}] ++ Room),
    #{services => [Service], consumes => [Consumes], sensor => [SensorParam], feedback => none}.

%% @doc A part of actuator services; the device's model (else name) is the
%% Device of its ACTION FEEDBACK entry.
-spec actuator([bil:entry()], ctx()) -> part().
actuator(Services, Ctx) ->
    #{device := D} = Ctx,
    Device = camel(first_name([maps:get(model, D), maps:get(name, D), <<"Device">>])),
    actuator(Services, Ctx, Device).

-spec actuator([bil:entry()], ctx(), binary()) -> part().
actuator(Services, _Ctx, Device) ->
    #{services => Services, consumes => [], sensor => [], feedback => Device}.

%% @doc The `MqttExtra' parameter: `Name=Value' pairs every signal of the
%% entry carries, which binding never sees (values with spaces are left
%% out: they cannot be written there).
-spec extra([{binary(), binary() | undefined}]) -> [bil:parameter()].
extra(Pairs) ->
    case [[N, "=", V] || {N, V} <- Pairs, is_binary(V), plain_token(V)] of
        [] -> [];
        Tokens -> [{<<"MqttExtra">>, iolist_to_binary(lists:join(" ", Tokens))}]
    end.

%% @doc `{Camel, CamelClass}': what the user called the entity, and what it
%% is (its device class), both in CamelCase; the second is `undefined'
%% when it has no device class or it is the same name.
-spec named(map(), binary()) -> {binary(), binary() | undefined}.
named(E, Default) ->
    Class = case maps:get(device_class, E, undefined) of
                undefined -> undefined;
                C -> camel(C)
            end,
    Name = camel(first_name([maps:get(name, E, undefined), maps:get(device_class, E, undefined),
                             Default])),
    case Class of
        Name -> {Name, undefined};
        <<>> -> {Name, undefined};
        _ -> {Name, Class}
    end.

%% ---------------------------------------------------------------------------
%% Names and sources
%% ---------------------------------------------------------------------------

%% @doc A payload source as MqttValue writes it.
-spec source(mqtt_avatar_spec:source()) -> binary().
source(raw) -> <<"raw">>;
source({json, Path}) -> <<"json:", (join_path(Path))/binary>>.

-spec join_path([binary()]) -> binary().
join_path(Path) -> iolist_to_binary(lists:join(<<".">>, Path)).

%% @doc `Value' at `Path' of a JSON object, as JSON text.
-spec json_at([binary()], mqtt_avatar_json:json()) -> binary().
json_at(Path, Value) ->
    Json = lists:foldr(fun(K, Inner) -> #{K => Inner} end, Value, Path),
    iolist_to_binary(mqtt_avatar_json:encode(Json)).

%% @doc The first candidate that gives a name.
-spec first_name([binary() | undefined]) -> binary().
first_name(Candidates) ->
    case [C || C <- Candidates, is_binary(C), camel(C) =/= <<>>] of
        [C | _] -> C;
        [] -> <<"Device">>
    end.

-spec camel(binary()) -> binary().
camel(Name) -> mqtt_avatar_logic:camel(Name).

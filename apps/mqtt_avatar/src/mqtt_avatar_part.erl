%% @doc Internal. The building blocks a device family (mqtt_avatar_family_*)
%% writes its BIL with: entries, on/off actuators, streams with their read
%% service, and the reserved `Mqtt*' parameters (docs/mqtt.md section 3)
%% that tie them to topics. Pure.
-module(mqtt_avatar_part).

-export([entry/3, on_off/6, actuator/2, actuator/3, stream/7, stream/8, command/4,
         echo_params/2, value_params/3, match/2, on_off_map/3, source/1, join_path/1,
         json_at/2, first_name/1, camel/1, extra/1, named/2,
         fixed/6, setter/7, watch/5, family/5, map_text/1, range/2, echo_of/2, settings/3,
         one_of/1, valued/7, with_info/2, merge/1, value/2, payload_service/5]).

-export_type([part/0, ctx/0, control/0, state/0]).

%% Where a value is set: a command topic, and the JSON field the value
%% goes in (`undefined': the payload is the value itself).
%% `scale': MqttScale text (`Lo..Hi'): the device's range of a value the
%% VA sets and reads as a percentage.
-type control() :: #{topic := binary(), field := binary() | undefined, template => binary(),
                     scale => binary()}.
%% Where a value is read: a state topic and the payload source.
-type state() :: #{topic := binary(), source := mqtt_avatar_spec:source(), scale => binary()}.
%% A value the VA sets (`control') and reads (`state'), as parameter
%% `param', with service `service' and MqttArgCheck text `check'.
-type setting() :: #{param := binary(), service := binary(), check := binary(),
                     control => control(), state => state(), map => binary()}.
-export_type([setting/0]).
-type echo() :: {binary(), state(), binary()} | {binary(), state(), binary(), binary() | any}
              | undefined.

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
    value(Param, V) ++ [{<<"MqttMap">>, Map} || Map =/= <<>>].

%% @doc An MqttExpect text: the payload (or its field) equal to `Expected'.
-spec match(mqtt_avatar_spec:source(), binary()) -> binary().
match(raw, Expected) -> <<"raw:", Expected/binary>>;
%% What the state template renders (MqttValueTemplate), so a lock is not
%% done at `unlocking' because its state has a template.
match({template, _}, Expected) -> <<"template:", Expected/binary>>;
match({json, Path}, Expected) -> <<"json:", (join_path(Path))/binary, "=", Expected/binary>>.

%% @doc An MqttMap translating the entity's `state_on'/`state_off' to
%% `ToOn'/`ToOff' as HA does (`<<>>' when nothing needs translating or
%% cannot be). A device writing `true'/`false' is mapped both as it wrote
%% them (a raw payload) and as yes/no (a JSON boolean arrives so).
-spec on_off_map(map(), binary(), binary()) -> binary().
on_off_map(#{state_on := On, state_off := Off}, ToOn, ToOff) ->
    case lists:all(fun plain_token/1, [On, Off]) of
        true ->
            Pairs = [{F, T} || {From, T} <- [{On, ToOn}, {Off, ToOff}],
                               F <- lists:usort([From, bool_key(From)]), F =/= T],
            iolist_to_binary(lists:join(" ", [[F, "=", T] || {F, T} <- Pairs]));
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
                     Room ++ [{<<"MqttStateTopic">>, maps:get(state_topic, E)}]
                     ++ value(Param, maps:get(value, E))
                     ++ [{<<"MqttMap">>, Map} || is_binary(Map), Map =/= <<>>]
                     ++ [{<<"MqttContext">>, <<"Event">>} || Context =:= event]
                     ++ [{<<"MqttAttributes">>, <<"all">>} || maps:get(attributes, E, false)]
                     ++ [{<<"MqttOnChange">>, <<"yes">>} || maps:get(on_change, E, false)]),
    Service = entry(<<"SENSOR">>, Read, [{SensorParam, <<"yes">>}] ++ Room),
    #{services => [Service], consumes => [Consumes], sensor => [SensorParam], feedback => none}.

%% @doc One service named after the entity (else `Default') whose request
%% parameter `Arg' is the whole payload published on the command topic
%% (notify, text): done when the broker has it (`none'), or at the next
%% message of the state topic (`any').
-spec payload_service(mqtt_avatar_discovery:entity(), ctx(), binary(), binary(), none | any) ->
          part().
payload_service(E, Ctx, Default, Arg, Echo) ->
    Type = camel(first_name([maps:get(name, E), Default])),
    Confirm = case Echo of
                  none -> [{<<"MqttExpect">>, <<"none">>}];
                  any -> echo_params(E, <<"any">>)
              end,
    Params = [{Arg, <<"yes">>}] ++ maps:get(room, Ctx)
        ++ [{<<"MqttCommandTopic">>, maps:get(command_topic, E)},
            {<<"MqttCommand">>, <<"raw:">>}, {<<"MqttCommandArgs">>, Arg}] ++ Confirm,
    actuator([entry(<<"ACTUATOR">>, Type, Params)], Ctx).

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

%% @doc `Info' (`[{Name, Value | undefined}]': Unit, DeviceClass...) on
%% the part's services, and as MqttExtra on its streams, so every reading
%% carries it without constraining binding.
-spec with_info(part(), [{binary(), binary() | undefined}]) -> part().
with_info(#{services := Services, consumes := Consumes} = Part, Info) ->
    Known = [{N, V} || {N, V} <- Info, is_binary(V)],
    Extra = extra(Known),
    Add = fun(#{parameters := Ps} = E, More) -> E#{parameters := Ps ++ More} end,
    Part#{services := [Add(S, Known) || S <- Services],
          consumes := [Add(C, Extra) || C <- Consumes]}.

%% @doc Several parts of one entity as one.
-spec merge([part()]) -> part().
merge([First | _] = Parts) ->
    #{services => lists:append([S || #{services := S} <- Parts]),
      consumes => lists:append([C || #{consumes := C} <- Parts]),
      sensor => lists:append([S || #{sensor := S} <- Parts]),
      feedback => maps:get(feedback, First)}.

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
%% Controls and states (the families of docs/mqtt.md section 2.4)
%% ---------------------------------------------------------------------------

%% @doc A service that publishes a fixed `Payload' on `Control' (the
%% payload itself, or `{"field": Payload}'), confirmed by the next message
%% of `Echo' (`{Param, State, Map}'), or the first whose value is
%% `Expected' (`{Param, State, Map, Expected}'), or the broker's PUBACK
%% (`undefined'); the value becomes feedback parameter `Param'.
-spec fixed(binary(), [bil:parameter()], control(), binary(), echo(), ctx()) -> bil:entry().
fixed(Type, Caps, #{topic := Topic, field := Field} = Control, Payload, Echo, #{room := Room}) ->
    Command = case Field of
                  undefined -> <<"raw:", Payload/binary>>;
                  _ -> <<"json:", (json_at([Field], Payload))/binary>>
              end,
    command(Type, Topic, Command, Caps ++ Room ++ echo(Echo) ++ command_template(Control)).

%% HA's command template of the control: what is published is the template
%% rendered with the value (docs/mqtt.md section 3.2).
command_template(#{template := T}) -> [{<<"MqttCommandTemplate">>, T}];
command_template(_) -> [].

%% @doc A service that sets request parameter `Arg' (checked by `Check',
%% MqttArgCheck text without the name: `0..100', `a|b', or `<<>>' for
%% present) on `Control', confirmed as `fixed/6' confirms.
-spec setter(binary(), binary(), [bil:parameter()], control(), binary(), echo(), ctx()) ->
          bil:entry().
setter(Type, Arg, Caps, #{topic := Topic, field := Field} = Control, Check, Echo, #{room := Room}) ->
    {Command, Args} = case Field of
                          undefined -> {<<"raw:">>, Arg};
                          _ -> {<<"json:{}">>, <<Arg/binary, "=", Field/binary>>}
                      end,
    CheckText = case Check of
                    <<>> -> Arg;
                    _ -> <<Arg/binary, "=", Check/binary>>
                end,
    command(Type, Topic, Command, [{Arg, <<"yes">>}] ++ Caps ++ Room
                                  ++ [{<<"MqttCommandArgs">>, Args},
                                      {<<"MqttArgCheck">>, CheckText}]
                                  ++ echo(Echo) ++ command_template(Control)
                                  ++ scale(Arg, Control)).

%% MqttScale of `Param' when the control or state has a device range.
scale(Param, #{scale := Range}) -> [{<<"MqttScale">>, <<Param/binary, "=", Range/binary>>}];
scale(_Param, _) -> [].

echo(undefined) ->
    [{<<"MqttExpect">>, <<"none">>}];
echo({Param, State, Map}) ->
    echo({Param, State, Map, any});
echo({Param, #{topic := T, source := Source}, Map, Expected}) ->
    Expect = case Expected of
                 any -> <<"any">>;
                 _ -> match(Source, Expected)
             end,
    [{<<"MqttStateTopic">>, T}, {<<"MqttExpect">>, Expect}] ++ value(Param, Source)
        ++ [{<<"MqttMap">>, Map} || Map =/= <<>>].

%% @doc A stream `SENSOR/Type' of the value of `State' as parameter
%% `Param', translated by `Map', sent only when it changed if `OnChange'.
-spec watch(binary(), binary(), state(), binary(), #{on_change => boolean(),
                                                   context => sensor_data | event,
                                                   room := [bil:parameter()],
                                                   extra => [bil:parameter()]}) -> bil:entry().
watch(Type, Param, #{topic := T, source := Source} = State, Map, Opts) ->
    entry(<<"SENSOR">>, Type,
          maps:get(room, Opts)
          ++ [{<<"MqttStateTopic">>, T}]
          ++ value(Param, Source)
          ++ [{<<"MqttMap">>, Map} || Map =/= <<>>]
          ++ [{<<"MqttContext">>, <<"Event">>} || maps:get(context, Opts, sensor_data) =:= event]
          ++ [{<<"MqttOnChange">>, <<"yes">>} || maps:get(on_change, Opts, false)]
          ++ scale(Param, State)
          ++ maps:get(extra, Opts, [])).

%% @doc A family's part: its services, a stream per state it reads
%% (`[{Param, State, Map}]', named `<Family><Param>', sent on change
%% when several share a topic), a read service
%% `Read<Family>' naming them, and ACTION FEEDBACK Device `<Family>'.
-spec family(binary(), [bil:entry()], [{binary(), state(), binary()}],
             mqtt_avatar_discovery:entity(), ctx()) -> part().
family(Family, Services, States, E, #{room := Room}) ->
    %% Streams that share a topic (one JSON state) send only changes, or
    %% every message would send all of them.
    Topics = [T || {_, #{topic := T}, _} <- States],
    Shared = fun(T) -> length([x || X <- Topics, X =:= T]) > 1 end,
    Streams = [watch(<<Family/binary, Param/binary>>, Param, State, Map,
                     #{room => Room, on_change => maps:get(on_change, E, false) orelse Shared(T)})
               || {Param, #{topic := T} = State, Map} <- States],
    Read = [entry(<<"SENSOR">>, <<"Read", Family/binary>>,
                  [{Param, <<"yes">>} || {Param, _, _} <- States] ++ Room) || States =/= []],
    #{services => Services ++ Read, consumes => Streams,
      sensor => [], feedback => case Services of
                                    [] -> none;
                                    _ -> Family
                                end}.

%% @doc The services (`Set...') and the states read of a family's settings.
-spec settings([setting()], [bil:parameter()], ctx()) ->
          {[bil:entry()], [{binary(), state(), binary()}]}.
settings(Settings, Caps, Ctx) ->
    Reads = [{P, S, maps:get(map, X, <<>>)} || #{param := P, state := S} = X <- Settings],
    Services = [setter(Type, P, Caps, Control, Check, echo_of(P, Reads), Ctx)
                || #{param := P, service := Type, control := Control, check := Check} <- Settings],
    {Services, Reads}.

%% @doc One value the VA sets and reads, named after the entity (numbers,
%% selects): `<Verb><Name>' with request parameter `Arg', the stream
%% `SENSOR/<Name>' and `Read<Name>', both with parameter `Arg'.
-spec valued(mqtt_avatar_discovery:entity(), binary(), binary(), [bil:parameter()], binary(),
             binary(), ctx()) -> part().
valued(E, Verb, Arg, Caps, Check, Device, #{room := Room} = Ctx) ->
    Name = camel(first_name([maps:get(name, E), maps:get(device_class, E), Device])),
    Control = maps:merge(#{topic => maps:get(command_topic, E), field => maps:get(field, E, undefined)},
                         maps:with([template], E)),
    State = case maps:get(state_topic, E) of
                undefined -> [];
                T -> [{Arg, #{topic => T, source => maps:get(value, E)}, <<>>}]
            end,
    Set = setter(<<Verb/binary, Name/binary>>, Arg, Caps, Control, Check, echo_of(Arg, State), Ctx),
    Opts = #{room => Room, on_change => maps:get(on_change, E, false)},
    Streams = [watch(Name, P, S, M, Opts) || {P, S, M} <- State],
    Read = [entry(<<"SENSOR">>, <<"Read", Name/binary>>, [{Arg, <<"yes">>}] ++ Room) || State =/= []],
    #{services => [Set | Read], consumes => Streams, sensor => [], feedback => Device}.

%% @doc An MqttArgCheck list `a|b|c' of the values, each percent-encoded
%% where MqttArgCheck could not hold it as written (a space, `|', `%' or a
%% control character: `Spotify%20Connect'), so every option is checked
%% (`<<>>', no check but presence, only for no values or an empty one).
-spec one_of([binary()] | undefined) -> binary().
one_of(undefined) -> <<>>;
one_of(Values) ->
    case lists:all(fun(V) -> V =/= <<>> end, Values) of
        true when Values =/= [] -> iolist_to_binary(lists:join("|", [escape(V) || V <- Values]));
        _ -> <<>>
    end.

escape(V) ->
    << <<(escape_byte(B))/binary>> || <<B>> <= V >>.

escape_byte(B) when B =< 32; B =:= $|; B =:= $%; B =:= 127 ->
    list_to_binary(io_lib:format("%~2.16.0B", [B]));
escape_byte(B) ->
    <<B>>.

%% @doc An MqttArgCheck range `Lo..Hi' from two JSON numbers in either
%% order (a cover whose open position is below its closed one).
-spec range(binary(), binary()) -> binary().
range(A, B) ->
    {ok, X} = evatar_json:decode(A),
    {ok, Y} = evatar_json:decode(B),
    case X =< Y of
        true -> <<A/binary, "..", B/binary>>;
        false -> <<B/binary, "..", A/binary>>
    end.

%% @doc The state read as `Param' among a family's states, `undefined'
%% when it reads none: what confirms a command that changes it.
-spec echo_of(binary(), [{binary(), state(), binary()}]) -> {binary(), state(), binary()} | undefined.
echo_of(Param, States) ->
    case lists:keyfind(Param, 1, States) of
        false -> undefined;
        S -> S
    end.

%% @doc An MqttMap text from `[{DevicePayload, BilValue}]': the pairs that
%% differ and can be written (no spaces or `='): MqttMap compares without
%% case but passes an unmapped value on as the device wrote it.
-spec map_text([{binary() | undefined, binary()}]) -> binary().
map_text(Pairs) ->
    iolist_to_binary(lists:join(" ", [[From, "=", To] || {From, To} <- Pairs, is_binary(From),
                                                         plain_token(From), From =/= To])).


%% ---------------------------------------------------------------------------
%% Names and sources
%% ---------------------------------------------------------------------------

%% @doc The MqttValue of parameter `Param' read from `Source', and the
%% MqttValueTemplate when a template reads it.
-spec value(binary(), mqtt_avatar_spec:source()) -> [bil:parameter()].
value(Param, Source) ->
    [{<<"MqttValue">>, <<Param/binary, "=", (source(Source))/binary>>}]
        ++ [{<<"MqttValueTemplate">>, T} || {template, T} <- [Source]].

%% @doc A payload source as MqttValue writes it.
-spec source(mqtt_avatar_spec:source()) -> binary().
source(raw) -> <<"raw">>;
source({template, _}) -> <<"template">>;
source({json, Path}) -> <<"json:", (join_path(Path))/binary>>.

-spec join_path([binary()]) -> binary().
join_path(Path) -> iolist_to_binary(lists:join(<<".">>, Path)).

%% @doc `Value' at `Path' of a JSON object, as JSON text.
-spec json_at([binary()], evatar_json:json()) -> binary().
json_at(Path, Value) ->
    Json = lists:foldr(fun(K, Inner) -> #{K => Inner} end, Value, Path),
    evatar_json:encode(Json).

%% @doc The first candidate that gives a name.
-spec first_name([binary() | undefined]) -> binary().
first_name(Candidates) ->
    case [C || C <- Candidates, is_binary(C), camel(C) =/= <<>>] of
        [C | _] -> C;
        [] -> <<"Device">>
    end.

-spec camel(binary()) -> binary().
camel(Name) -> mqtt_avatar_logic:camel(Name).

%% @doc Internal. The MQTT Avatar's decisions, as a pure state machine:
%% `handle(Event, NowMs, State) -> {State1, Effects}'. MQTT messages become
%% BIL sensor data, events and feedback; BIL requests become publishes. The
%% process (mqtt_avatar_fsm) executes the effects; this module holds no pid,
%% socket or timer.
%%
%% Events: `{mqtt, #{topic, payload, retain}}', `{signal, bil:signal()}',
%% `{binding, Report}', `{puback, Key}', `{publish_failed, Key, Reason}',
%% `{echo_timeout, Key}', `{mqtt_status, up | down}'.
%% Effects: `{send, PartialSignal}', `{publish, Topic, Payload, Key}',
%% `{start_timer, Key, Ms}', `{cancel_timer, Key}', `{problem, Report}'.
-module(mqtt_avatar_logic).

-export([new/3, new/4, set_spec/2, handle/3, extract/2, extract/3, camel/1, last_values/1,
         availability/1, pending_count/1, partners/1, is_number_text/1]).

-export_type([state/0, event/0, effect/0]).

-type key() :: {binary(), binary()}.
-type event() :: {mqtt, #{topic := binary(), payload := binary(), retain := boolean()}}
               | {signal, bil:signal()}
               | {binding, #{bound := [bil:binding()], _ => _}}
               | {puback, key()}
               | {publish_failed, key(), term()}
               | {echo_timeout, key()}
               | {mqtt_status, up | down}.
-type effect() :: {send, agent_bridge_client:partial_signal()}
                | {publish, binary(), iodata(), key() | undefined}
                | {start_timer, key(), non_neg_integer()}
                | {cancel_timer, key()}
                | {problem, map()}.
-opaque state() :: #{entity := binary(),
                     echo_timeout := non_neg_integer(),
                     ts_field := binary() | undefined,
                     comps := #{binary() => mqtt_avatar_spec:component()},
                     routes := #{binary() => [route()]},
                     bound := [bil:binding()],
                     mqtt := up | down,
                     last := #{{binary(), pos_integer()} => [bil:parameter()]},
                     avail := #{binary() => {online | offline, integer()}},
                     lights := #{{binary(), binary()} => mqtt_avatar_light:state()},
                     avail_entries := #{binary() => #{pos_integer() => online | offline}},
                     states := #{{binary(), binary()} => [bil:parameter()]},
                     quiet := #{{atom(), binary(), binary()} => {integer(), non_neg_integer()}},
                     pending := #{key() => pending()}}.
-type route() :: {stream, binary(), pos_integer()} | {avail, binary(), pos_integer()}
               | {state, binary()} | {light, binary(), mqtt_avatar_light:light()}.
-type pending() :: #{component := binary(),
                     requester := binary(),
                     service := mqtt_avatar_spec:service(),
                     awaiting := boolean(),
                     %% a light command: what it waits for, the topics heard since
                     wait => mqtt_avatar_light:wait(),
                     heard => [binary()]}.

%% Longest payload turned into one parameter value: keeps signals far
%% below BIL's 64 KiB limit.
-define(MAX_VALUE, 4096).

%% A topic's unreadable payloads (bad_payload, bad_availability) are
%% reported at most once in this many ms; the next report says how many
%% were left out meanwhile (docs/mqtt.md section 6).
-define(PROBLEM_INTERVAL, 60000).
-define(RATE_LIMITED, [bad_payload, bad_availability]).

%% ---------------------------------------------------------------------------
%% API
%% ---------------------------------------------------------------------------

%% @doc A state for entity `Entity' with spec `Spec'; `EchoTimeout' ms is how
%% long a command waits for its state echo before it is forgotten (EVATAR's
%% own feedback timeout answers the VA).
-spec new(binary(), mqtt_avatar_spec:spec(), non_neg_integer()) -> state().
new(Entity, Spec, EchoTimeout) ->
    new(Entity, Spec, EchoTimeout, #{}).

%% @doc As `new/3'; `timestamp_field' names a top-level JSON field holding
%% the time of a reading (ms since 1970), which then becomes the signal's
%% Timestamp instead of the time of sending.
-spec new(binary(), mqtt_avatar_spec:spec(), non_neg_integer(),
          #{timestamp_field => binary()}) -> state().
new(Entity, Spec, EchoTimeout, Opts) ->
    set_spec(Spec, #{entity => Entity, echo_timeout => EchoTimeout,
                     ts_field => maps:get(timestamp_field, Opts, undefined),
                     comps => #{}, routes => #{},
                     bound => [], mqtt => down, last => #{}, avail => #{}, lights => #{},
                     avail_entries => #{}, states => #{}, quiet => #{}, pending => #{}}).

%% @doc Replaces the spec (after a new discovery); keeps what is known about
%% the components that remain.
-spec set_spec(mqtt_avatar_spec:spec(), state()) -> state().
set_spec(#{components := Comps}, S) ->
    Index = maps:from_list([{Id, C} || #{id := Id} = C <- Comps]),
    %% Built reversed (one topic, a bridge's state, may route to every
    %% component), then put in component order.
    Routes = maps:map(fun(_, Rs) -> lists:reverse(Rs) end,
                      lists:foldl(fun add_routes/2, #{}, Comps)),
    KeepLast = fun({Id, N}, _) ->
                       case maps:find(Id, Index) of
                           {ok, #{streams := Streams}} -> N =< length(Streams);
                           error -> false
                       end
               end,
    KeepAvail = fun(Id, _) -> maps:is_key(Id, Index) end,
    Old = maps:get(comps, S, #{}),
    %% What each availability entry said is kept while the entries stay.
    SameEntries = fun(Id, _) ->
                          case {maps:find(Id, Old), maps:find(Id, Index)} of
                              {{ok, #{availability := A}}, {ok, #{availability := A}}} -> true;
                              _ -> false
                          end
                  end,
    KeepState = fun({Id, Topic}, _) -> lists:member({state, Id}, maps:get(Topic, Routes, [])) end,
    KeepQuiet = fun({_, Topic, _}, _) -> maps:is_key(Topic, Routes) end,
    KeepLight = fun({Id, _}, _) -> maps:is_key(Id, Index) end,
    S#{comps := Index, routes := Routes,
       lights := maps:filter(KeepLight, maps:get(lights, S)),
       last := maps:filter(KeepLast, maps:get(last, S)),
       avail := maps:filter(KeepAvail, maps:get(avail, S)),
       avail_entries := maps:filter(SameEntries, maps:get(avail_entries, S)),
       states := maps:filter(KeepState, maps:get(states, S)),
       quiet := maps:filter(KeepQuiet, maps:get(quiet, S))}.

%% @doc Last values of every stream: `#{ComponentID => [Param]}'.
-spec last_values(state()) -> #{binary() => [bil:parameter()]}.
last_values(#{last := Last}) ->
    maps:fold(fun({Id, _}, Ps, Acc) -> Acc#{Id => dedupe(maps:get(Id, Acc, []) ++ Ps)} end,
              #{}, Last).

%% @doc What is known of each component's availability.
-spec availability(state()) -> #{binary() => online | offline}.
availability(#{avail := A}) ->
    maps:map(fun(_, {State, _}) -> State end, A).

%% @doc Commands waiting for their state echo.
-spec pending_count(state()) -> non_neg_integer().
pending_count(#{pending := P}) -> map_size(P).

%% @doc Applies one event.
-spec handle(event(), integer(), state()) -> {state(), [effect()]}.
handle({mqtt_status, Status}, _Now, S) ->
    {S#{mqtt := Status}, []};
handle({binding, #{bound := Bound}}, Now, S) ->
    S1 = S#{bound := Bound},
    %% New partners learn the current state: the last reading of each
    %% stream (often a retained message that came before the binding), and
    %% the devices that are away.
    Readings = [{send, #{context => Ctx, sender => Id, receiver => R,
                         body => #{category => Cat, type => Type, parameters => Params}}}
                || {{Id, N}, Params} <- lists:sort(maps:to_list(maps:get(last, S1))),
                   #{category := Cat, type := Type, context := Ctx} <- [stream(Id, N, S1)],
                   R <- stream_receivers(Id, Cat, Type, S1)
                        -- stream_receivers(Id, Cat, Type, S)],
    Away = lists:append([availability_events(Id, offline, undefined, Now, S1)
                         || {Id, {offline, _}} <- lists:sort(maps:to_list(maps:get(avail, S1)))]),
    {S1, Readings ++ Away};
handle({mqtt, #{topic := Topic} = Msg}, Now, #{routes := Routes} = S) ->
    {S1, E1, Answered} = echo(Msg, S),
    {S2, E2} = lists:foldl(fun(Route, {SAcc, EAcc}) ->
                                   {SAcc1, E} = route(Route, Msg#{answered => Answered}, Now, SAcc),
                                   {SAcc1, EAcc ++ E}
                           end, {S1, E1}, maps:get(Topic, Routes, [])),
    limit_problems(E2, Now, S2);
handle({signal, #{context := Ctx} = Signal}, Now, S)
  when Ctx =:= request; Ctx =:= request_no_feedback ->
    request(Signal, Now, S);
handle({signal, #{context := error, body := #{type := Code, parameters := Ps}} = Signal}, _Now, S) ->
    {S, [{problem, #{what => evatar_error, code => Code,
                     message => with_advice(proplists:get_value(<<"Message">>, Ps, <<>>)),
                     signal => maps:get(in_reply_to, Signal)}}]};
handle({signal, #{context := Ctx, sender := From}}, _Now, S) ->
    {S, [{problem, #{what => unexpected_signal, context => Ctx, sender => From,
                     message => <<"an MQTT Avatar only answers requests">>}}]};
handle({puback, Key}, _Now, #{pending := P} = S) ->
    case maps:find(Key, P) of
        {ok, #{service := #{expect := none}} = Pending} ->
            {S#{pending := maps:remove(Key, P)},
             [{cancel_timer, Key} | answer_done(Key, Pending, light_params(Pending, S), S)]};
        _ ->
            {S, []}
    end;
handle({publish_failed, Key, Reason}, _Now, #{pending := P} = S) ->
    case maps:take(Key, P) of
        {Pending, P1} ->
            Msg = iolist_to_binary(io_lib:format("the broker did not take the command: ~0p",
                                                 [Reason])),
            {S#{pending := P1}, [{cancel_timer, Key} | answer_error(Key, Pending, <<"PublishFailed">>, Msg)]};
        error ->
            {S, []}
    end;
handle({echo_timeout, Key}, _Now, #{pending := P} = S) ->
    case maps:take(Key, P) of
        {#{component := C, service := #{type := T}}, P1} ->
            {S#{pending := P1},
             [{problem, #{what => no_state_echo, component => C, service => T,
                          request => element(2, Key),
                          message => <<"the device did not echo its state in time; EVATAR's "
                                       "feedback timeout answers the VA">>}}]};
        error ->
            {S, []}
    end.

%% ---------------------------------------------------------------------------
%% Incoming MQTT messages
%% ---------------------------------------------------------------------------

add_routes(#{id := Id, streams := Streams, services := Services, availability := Avail},
           Routes) ->
    {R0, _} = lists:foldl(fun(#{topic := T}, {Acc, N}) ->
                                  {append(T, {stream, Id, N}, Acc), N + 1}
                          end, {Routes, 1}, Streams),
    %% A light's TurnLightOn and TurnLightOff share its config: one route.
    Lights = lists:usort([L || #{light := L} <- Services]),
    R1 = lists:foldl(fun(L, Acc) ->
                             lists:foldl(fun(T, A) -> append(T, {light, Id, L}, A) end, Acc,
                                         mqtt_avatar_light:state_topics(L))
                     end, R0, Lights),
    %% An actuator's state topics: every message there is its state, asked
    %% for or not.
    R2 = lists:foldl(fun(T, Acc) -> append(T, {state, Id}, Acc) end, R1,
                     lists:usort([T || #{kind := command, state_topic := T} <- Services,
                                       T =/= undefined])),
    case Avail of
        #{entries := Entries} ->
            {R3, _} = lists:foldl(fun(#{topic := T}, {Acc, N}) ->
                                          {append(T, {avail, Id, N}, Acc), N + 1}
                                  end, {R2, 1}, Entries),
            R3;
        undefined -> R2
    end.

append(K, V, M) -> M#{K => [V | maps:get(K, M, [])]}.

stream(Id, N, #{comps := Comps}) ->
    lists:nth(N, maps:get(streams, maps:get(Id, Comps))).

route({stream, Id, N}, #{payload := Payload, retain := Retain, topic := Topic}, _Now, S) ->
    #{last := Last} = S,
    Stream = stream(Id, N, S),
    #{mapping := Mapping, static := Static, context := Ctx, category := Cat, type := Type,
      on_change := OnChange} = Stream,
    case numbers(read_values(Mapping, Payload, exclude(S)), maps:get(numeric, Stream, []), Static) of
        {ok, []} ->
            {S, []};
        {ok, Values} ->
            Params = dedupe(Values ++ Static),
            Stamp = timestamp(Payload, S),
            Previous = maps:get({Id, N}, Last, undefined),
            S1 = S#{last := Last#{{Id, N} => Params}},
            case (Retain orelse OnChange) andalso Previous =:= Params of
                true ->
                    %% A retained state already passed on (after a reconnect),
                    %% or an unchanged reading of an on-change stream.
                    {S1, []};
                false ->
                    Body = #{category => Cat, type => Type, parameters => Params},
                    {S1, [{send, Stamp#{context => Ctx, sender => Id, receiver => R, body => Body}}
                          || R <- stream_receivers(Id, Cat, Type, S)]}
            end;
        {error, Why} ->
            {S, [bad_payload(Id, Topic, Payload, Why)]}
    end;
route({light, Id, L}, #{payload := Payload, topic := Topic} = Msg, _Now, #{lights := Lights} = S) ->
    Key = {Id, mqtt_avatar_light:command_topic(L)},
    Old = maps:get(Key, Lights, #{}),
    case mqtt_avatar_light:read(L, Topic, Payload, Old) of
        {ok, New} ->
            {S1, E} = light_echo(Key, Topic, Payload, S#{lights := Lights#{Key => New}}),
            Answered = [R || {send, #{context := C, receiver := R}} <- E,
                             C =:= feedback orelse C =:= progress],
            {S1, E ++ light_changed(Id, Old, New, Msg#{answered => Answered
                                                      ++ maps:get(answered, Msg, [])}, S1)};
        {error, Message} ->
            {S, [{problem, #{what => bad_payload, component => Id, topic => Topic,
                             message => Message}}]}
    end;
route({avail, Id, N}, #{payload := Payload, topic := Topic}, Now, S) ->
    #{comps := Comps, avail_entries := Entries} = S,
    #{availability := #{mode := Mode, entries := Es}} = maps:get(Id, Comps),
    #{value := Source, online := On, offline := Off} = lists:nth(N, Es),
    Text = case {text(Payload), Source} of
               {error, _} -> {error, <<"the payload is not UTF-8 text">>};
               {{ok, Plain}, raw} -> {ok, Plain};
               {{ok, _}, {template, Tpl}} ->
                   %% Home Assistant's availability_template (checked by the spec).
                   {ok, Parsed} = mqtt_avatar_template:parse(Tpl),
                   mqtt_avatar_template:render(Parsed, mqtt_avatar_template:payload_vars(Payload));
               {{ok, Legacy}, {json, Path}} ->
                   %% zigbee2mqtt wrote plain online/offline before it wrote JSON.
                   case json_text(Payload, Path) of
                       {ok, _} = Ok -> Ok;
                       {error, _} = E -> case lists:member(string:trim(Legacy), [On, Off]) of
                                             true -> {ok, Legacy};
                                             false -> E
                                         end
                   end
           end,
    New = case Text of
              {ok, T} ->
                  X = string:casefold(string:trim(T)),
                  case {X =:= string:casefold(On), X =:= string:casefold(Off)} of
                      {true, _} -> online;
                      {_, true} -> offline;
                      _ -> {error, <<"got ", (quoted(T))/binary, ", neither the available (",
                                     (quoted(On))/binary, ") nor the not-available (",
                                     (quoted(Off))/binary, ") payload">>}
                  end;
              {error, M} -> {error, M}
          end,
    case New of
        {error, M1} ->
            {S, [{problem, #{what => bad_availability, component => Id, topic => Topic,
                             message => M1}}]};
        _ ->
            Known = (maps:get(Id, Entries, #{}))#{N => New},
            available(Id, combine(Mode, New, Known), Now, S#{avail_entries := Entries#{Id => Known}})
    end;
route({state, Id}, Msg, _Now, S) ->
    actuator_state(Id, Msg, S).

%% Home Assistant's availability_mode over the entries heard from so far
%% (an entry never heard from does not count).
combine(latest, New, _Known) -> New;
combine(all, _New, Known) ->
    case lists:member(offline, maps:values(Known)) of
        true -> offline;
        false -> online
    end;
combine(any, _New, Known) ->
    case lists:member(online, maps:values(Known)) of
        true -> online;
        false -> offline
    end.

%% The device's availability is now State: its partners learn a change.
available(Id, State, Now, #{avail := Av} = S) ->
    case {State, maps:get(Id, Av, undefined)} of
        {State, {State, _}} ->
            {S, []};
        {online, undefined} ->
            {S#{avail := Av#{Id => {online, Now}}}, []};
        {State, Old} ->
            Since = case Old of
                        {offline, T0} -> T0;
                        _ -> undefined
                    end,
            {S#{avail := Av#{Id => {State, Now}}}, availability_events(Id, State, Since, Now, S)}
    end.

%% A message on an actuator's state topic: its state, whoever changed it.
%% A changed state is an Event StateChanged to the component's partners,
%% but for the requesters whose request this message answered (they get
%% its Feedback or Progress). The first state known, retained, is no
%% change.
actuator_state(Id, #{topic := Topic, payload := Payload, retain := Retain} = Msg, S) ->
    #{comps := Comps, states := States} = S,
    #{services := All} = maps:get(Id, Comps),
    Services = [Sv || #{kind := command, state_topic := T} = Sv <- All, T =:= Topic],
    Mappings = lists:usort([M || #{mapping := #{values := Vs, attributes := A} = M} <- Services,
                                 Vs =/= [] orelse A]),
    Results = [read_values(M, Payload, exclude(S)) || M <- Mappings],
    case {readable(Payload, needs(Services)), [E || {error, E} <- Results]} of
        {{error, Why}, _} ->
            {S, [bad_payload(Id, Topic, Payload, Why)]};
        {ok, [Why | _]} ->
            {S, [bad_payload(Id, Topic, Payload, Why)]};
        {ok, []} ->
            Values = dedupe(lists:append([V || {ok, V} <- Results])),
            Names = [N || #{values := Vs} <- Mappings, {N, _} <- Vs],
            case [P || {N, _} = P <- Values, lists:member(N, Names)] of
                [] ->
                    {S, []};
                Key ->
                    Previous = maps:get({Id, Topic}, States, undefined),
                    S1 = S#{states := States#{{Id, Topic} => Key}},
                    case Previous of
                        Key ->
                            {S1, []};
                        undefined when Retain ->
                            {S1, []};
                        _ ->
                            [#{static := Static} | _] = Services,
                            {S1, state_changed(Id, Values, Static, maps:get(answered, Msg, []),
                                               Msg, S)}
                    end
            end
    end.

%% A light's state (mqtt_avatar_light) changed, as for any actuator.
light_changed(Id, Old, New, #{retain := Retain} = Msg, S) ->
    {Before, After} = {mqtt_avatar_light:params(Old), mqtt_avatar_light:params(New)},
    if
        After =:= Before; After =:= [] -> [];
        Before =:= [], Retain -> [];
        true -> state_changed(Id, After, [], maps:get(answered, Msg, []), Msg, S)
    end.

state_changed(Id, Values, Static, Answered, #{payload := Payload}, #{comps := Comps} = S) ->
    #{room := Room} = maps:get(Id, Comps),
    Params = dedupe([{<<"Component">>, Id}] ++ Values ++ Static
                    ++ [{<<"Room">>, Room} || Room =/= undefined]),
    Body = #{category => <<"EVENT">>, type => <<"StateChanged">>, parameters => Params},
    Stamp = timestamp(Payload, S),
    [{send, Stamp#{context => event, sender => Id, receiver => R, body => Body}}
     || R <- partners(Id, S) -- Answered].

%% What reading a state topic's payload takes: JSON, text, or nothing.
needs(Services) ->
    Matches = [M || #{expect := E, progress := P} <- Services, M <- [E, P]],
    Sources = [Src || #{mapping := #{values := Vs}} <- Services, {_, Src} <- Vs],
    %% (a template reads the payload as text, and as JSON when it is JSON)
    Json = lists:any(fun({json, _, _}) -> true; (_) -> false end, Matches)
        orelse lists:any(fun({json, _}) -> true; (_) -> false end, Sources)
        orelse lists:any(fun(#{mapping := #{attributes := A}}) -> A end, Services),
    Text = Sources =/= [] orelse lists:any(fun({raw, _}) -> true; (_) -> false end, Matches),
    if Json -> json; Text -> text; true -> none end.

readable(_Payload, none) ->
    ok;
readable(Payload, Needs) ->
    case {text(Payload), Needs} of
        {error, _} -> {error, <<"the payload is not UTF-8 text">>};
        {{ok, _}, text} -> ok;
        {{ok, _}, json} ->
            case evatar_json:decode(Payload) of
                {ok, _} -> ok;
                {error, R} -> {error, not_json(R, <<"the state's MqttExpect or MqttValue json:">>)}
            end
    end.

%% A bad_payload problem. A payload that is not JSON or a value that is not
%% a number is limited per topic, whatever the payload (a device sending
%% varying garbage costs one report a minute); any other per message.
bad_payload(Id, Topic, Payload, Why) ->
    {Limit, Message} = why(Why, Topic, Payload),
    Problem = #{what => bad_payload, component => Id, topic => Topic, message => Message},
    {problem, case Limit of
                  undefined -> Problem;
                  _ -> Problem#{limit => Limit}
              end}.

%% What a reason of read_values/3 or numbers/3 says, and its limit key.
why({not_json, {too_large, _} = R, _Reader}, _Topic, _Payload) ->
    {undefined, evatar_json:format_error(R)};
why({not_json, R, Reader}, Topic, Payload) ->
    {not_json, iolist_to_binary(
                 ["the payload", on_topic(Topic), " is not JSON (", quoted(start(Payload)), "; ",
                  evatar_json:format_error(R), "), but ", Reader, " reads it as JSON"])};
why({not_number, Value, Info}, Topic, _Payload) ->
    {not_number, iolist_to_binary(
                   ["the value ", quoted(Value), on_topic(Topic), " is not a number, and this "
                    "sensor's readings must be numbers (", Info, ", as in Home Assistant): "
                    "not sent (docs/mqtt.md section 3.3, MqttNumeric)"])};
why(Message, _Topic, _Payload) when is_binary(Message) ->
    {undefined, Message}.

on_topic(undefined) -> "";
on_topic(Topic) -> [" on ", Topic].

%% A payload's text (its UTF-8 start, for quoting).
start(Payload) ->
    case text(Payload) of
        {ok, T} -> T;
        error -> <<"(not UTF-8)">>
    end.

%% A JSON decoding error `R' of a payload that `Reader' reads as JSON.
not_json(R, Reader) ->
    {not_json, R, Reader}.

%% HA refuses a state that is not a number from a sensor it expects numbers
%% of (MqttNumeric names those values): nothing is sent, and the problem
%% says why. An empty value, or HA's `None', is no reading at all.
numbers({ok, Values}, [_ | _] = Numeric, Static) ->
    Checked = [{N, V} || {N, V} <- Values, lists:member(N, Numeric)],
    case [V || {_, V} <- Checked, not is_number_text(V), not no_reading(V)] of
        [] ->
            case [x || {_, V} <- Checked, no_reading(V)] of
                [] -> {ok, Values};
                _ -> {ok, []}
            end;
        [Bad | _] ->
            Info = [[N, " ", V] || {K, N} <- [{<<"DeviceClass">>, "device class"},
                                              {<<"Unit">>, "unit"},
                                              {<<"StateClass">>, "state class"}],
                                   {Key, V} <- Static, Key =:= K],
            {error, {not_number, Bad, case Info of
                                          [] -> <<"MqttNumeric">>;
                                          _ -> lists:join(", ", Info)
                                      end}}
    end;
numbers(Result, _Numeric, _Static) ->
    Result.

no_reading(V) ->
    lists:member(string:trim(V), [<<>>, <<"None">>]).

%% A number as Home Assistant reads one from a numeric sensor's state: a
%% decimal number, signed or not, with a fraction and an exponent or not
%% (`21.5', `-3', `.5', `1e3'), spaces around it allowed; not `nan' or
%% `inf'.
-spec is_number_text(binary()) -> boolean().
is_number_text(V) ->
    re:run(string:trim(V), <<"^[+-]?([0-9]+\\.?[0-9]*|\\.[0-9]+)([eE][+-]?[0-9]+)?$">>,
           [{capture, none}]) =:= match.

%% A broken device can send a bad payload many times a second: the same
%% problem (kind, topic, message) once per PROBLEM_INTERVAL, and once per
%% MQTT message even when several entries read the topic.
limit_problems(Effects, Now, S) ->
    {Out, _, Quiet} =
        lists:foldl(
          fun({problem, #{what := W, topic := T} = P} = E, {Acc, Seen, Q}) ->
                  case lists:member(W, ?RATE_LIMITED) of
                      false ->
                          {[E | Acc], Seen, Q};
                      true ->
                          K = {W, T, maps:get(limit, P, maps:get(message, P, <<>>))},
                          case {lists:member(K, Seen), maps:get(K, Q, undefined)} of
                              {true, _} ->
                                  {Acc, Seen, Q};
                              {false, {Last, Left}} when Now - Last < ?PROBLEM_INTERVAL ->
                                  {Acc, [K | Seen], Q#{K := {Last, Left + 1}}};
                              {false, Before} ->
                                  Left = case Before of
                                             {_, L} -> L;
                                             undefined -> 0
                                         end,
                                  P1 = case Left of
                                           0 -> maps:remove(limit, P);
                                           _ -> (maps:remove(limit, P))#{suppressed => Left}
                                       end,
                                  {[{problem, P1} | Acc], [K | Seen], Q#{K => {Now, 0}}}
                          end
                  end;
             (E, {Acc, Seen, Q}) ->
                  {[E | Acc], Seen, Q}
          end, {[], [], maps:get(quiet, S)}, Effects),
    {S#{quiet := Quiet}, lists:reverse(Out)}.

availability_events(Id, State, OfflineSince, Now, #{comps := Comps} = S) ->
    #{room := Room} = maps:get(Id, Comps),
    {Type, Extra} = case State of
                        offline ->
                            {<<"DeviceDisconnected">>, [{<<"Availability">>, <<"offline">>}]};
                        online when is_integer(OfflineSince) ->
                            {<<"DeviceReconnected">>,
                             [{<<"Availability">>, <<"online">>},
                              {<<"OfflineSeconds">>,
                               integer_to_binary(max(0, Now - OfflineSince) div 1000)}]};
                        online ->
                            {<<"DeviceReconnected">>, [{<<"Availability">>, <<"online">>}]}
                    end,
    Params = [{<<"Component">>, Id}] ++ [{<<"Room">>, Room} || Room =/= undefined] ++ Extra,
    Body = #{category => <<"EVENT">>, type => Type, parameters => Params},
    [{send, #{context => event, sender => Id, receiver => P, body => Body}}
     || P <- partners(Id, S)].

%% A state message may answer commands waiting for their echo.
echo(#{topic := Topic, payload := Payload}, #{pending := P} = S) ->
    Waiting = [{K, V} || {K, #{service := #{state_topic := T}} = V} <- maps:to_list(P),
                         T =:= Topic],
    Answered = [R || {_, #{requester := R, service := #{expect := E, progress := Pr} = Sv}} <- Waiting,
                     matches(E, Payload, maps:get(mapping, Sv, #{}))
                         orelse matches(Pr, Payload, maps:get(mapping, Sv, #{}))],
    {S1, Effects} = echo(Waiting, Payload, S),
    {S1, Effects, lists:usort(Answered)}.

echo(Waiting, Payload, S) ->
    lists:foldl(fun({Key, #{service := Service} = Pending}, {SAcc, EAcc}) ->
                        #{expect := Expect, progress := Progress, mapping := Mapping} = Service,
                        case {matches(Expect, Payload, Mapping), matches(Progress, Payload, Mapping)} of
                            {true, _} ->
                                Values = values_or_empty(Mapping, Payload, SAcc),
                                #{pending := PAcc} = SAcc,
                                {SAcc#{pending := maps:remove(Key, PAcc)},
                                 EAcc ++ [{cancel_timer, Key}
                                          | stamp(answer_done(Key, Pending, Values, SAcc),
                                                  timestamp(Payload, SAcc))]};
                            {false, true} ->
                                Values = values_or_empty(Mapping, Payload, SAcc),
                                {SAcc, EAcc ++ [{start_timer, Key, maps:get(echo_timeout, SAcc)}
                                                | stamp(answer_progress(Key, Pending, Values, SAcc),
                                                        timestamp(Payload, SAcc))]};
                            {false, false} ->
                                {SAcc, EAcc}
                        end
                end, {S, []}, lists:sort(Waiting)).

%% A light's state message may complete the commands waiting for it.
light_echo({Id, CT} = LKey, Topic, Payload, #{lights := Lights} = S) ->
    State = maps:get(LKey, Lights),
    Waiting = lists:sort([{K, V} || {K, #{component := C, wait := _,
                                          service := #{command_topic := T}} = V}
                                        <- maps:to_list(maps:get(pending, S)),
                                    C =:= Id, T =:= CT]),
    lists:foldl(fun({Key, #{wait := Wait, service := #{mapping := Mapping}} = Pending}, {SAcc, EAcc}) ->
                        Heard = [Topic | maps:get(heard, Pending, [])],
                        #{pending := PAcc} = SAcc,
                        case mqtt_avatar_light:satisfied(Wait, State, Heard) of
                            true ->
                                Values = mqtt_avatar_light:params(State)
                                    ++ values_or_empty(Mapping, Payload, SAcc),
                                {SAcc#{pending := maps:remove(Key, PAcc)},
                                 EAcc ++ [{cancel_timer, Key}
                                          | stamp(answer_done(Key, Pending, Values, SAcc),
                                                  timestamp(Payload, SAcc))]};
                            false ->
                                {SAcc#{pending := PAcc#{Key := Pending#{heard => Heard}}}, EAcc}
                        end
                end, {S, []}, Waiting).

%% The state of the light a command was for (after an optimistic one, as asked).
light_params(#{component := C, service := #{light := L}}, #{lights := Lights}) ->
    mqtt_avatar_light:params(maps:get({C, mqtt_avatar_light:command_topic(L)}, Lights, #{}));
light_params(_Pending, _S) ->
    [].

values_or_empty(Mapping, Payload, S) ->
    case extract(Mapping, Payload, exclude(S)) of
        {ok, Vs} -> Vs;
        {error, _} -> []
    end.

exclude(#{ts_field := undefined}) -> #{};
exclude(#{ts_field := F}) -> #{exclude => [F]}.

%% The reading's own time, when the payload carries it.
timestamp(_Payload, #{ts_field := undefined}) ->
    #{};
timestamp(Payload, #{ts_field := Field}) ->
    case evatar_json:decode(Payload) of
        {ok, #{Field := T}} when is_integer(T), T >= 0, T < 1 bsl 62 -> #{timestamp => T};
        _ -> #{}
    end.

%% Answers are only signals.
stamp(Sends, Stamp) ->
    [{send, maps:merge(Signal, Stamp)} || {send, Signal} <- Sends].

%% A state template's value (MqttExpect template:TEXT): what the template
%% renders of the payload, compared as raw: is.
matches({template, Text}, Payload, #{template := T}) ->
    case mqtt_avatar_template:value(T, mqtt_avatar_template:payload_vars(Payload)) of
        {ok, V} when is_binary(V); is_number(V); is_boolean(V) ->
            same(string:trim(scalar(V)), Text) orelse same(evatar_json:to_text(V), Text);
        _ -> false
    end;
matches({template, _}, _Payload, _Mapping) ->
    false;
matches(Match, Payload, _Mapping) ->
    matches(Match, Payload).

matches(none, _) -> false;
matches(undefined, _) -> false;
matches(any, _) -> true;
matches({raw, Text}, Payload) ->
    case text(Payload) of
        {ok, T} -> same(string:trim(T), Text);
        error -> false
    end;
matches({json, Path, Text}, Payload) ->
    case evatar_json:decode(Payload) of
        {ok, J} ->
            case evatar_json:get_path(Path, J) of
                {ok, V} -> same(evatar_json:to_text(V), Text) orelse same(yes_no(V), Text);
                error -> false
            end;
        {error, _} -> false
    end.

same(A, B) ->
    string:casefold(A) =:= string:casefold(B).

%% ---------------------------------------------------------------------------
%% Requests from the VA
%% ---------------------------------------------------------------------------

request(#{id := Id, sender := From, receiver := To, context := Ctx,
          body := #{category := Cat, type := Type, parameters := Args}}, _Now, S) ->
    #{comps := Comps, pending := P, mqtt := Mqtt, avail := Av, echo_timeout := Timeout} = S,
    Key = {From, Id},
    Awaiting = Ctx =:= request,
    Base = #{component => To, requester => From, awaiting => Awaiting},
    case maps:find(To, Comps) of
        error ->
            {S, answer_error(Key, Base, <<"UnknownComponent">>,
                             <<"no such component in this MQTT Avatar">>)};
        {ok, Comp} ->
            case find_service(Cat, Type, Comp) of
                none ->
                    {S, answer_error(Key, Base, <<"UnknownService">>,
                                     iolist_to_binary(["component ", To, " has no service ",
                                                       Cat, "/", Type]))};
                #{kind := unsupported, type := T} ->
                    {S, answer_error(Key, Base, <<"NotSupported">>,
                                     iolist_to_binary(["service ", T, " of ", To, " has no MQTT "
                                                       "mapping (no MqttCommand, no stream to read)"]))};
                #{kind := read} = Service ->
                    {S, answer_read(Key, Base#{service => Service}, Comp, S)};
                #{kind := command} = Service ->
                    Pending = Base#{service => Service},
                    case {Mqtt, maps:get(To, Av, undefined)} of
                        {down, _} ->
                            {S, answer_error(Key, Pending, <<"BrokerUnavailable">>,
                                             <<"the MQTT broker is not reachable at the moment">>)};
                        {up, {offline, _}} ->
                            {S, answer_error(Key, Pending, <<"DeviceUnavailable">>,
                                             iolist_to_binary(["device ", To, " is offline (its "
                                                               "availability topic says so)"]))};
                        {up, _} when is_map_key(light, Service) ->
                            light_command(Key, Pending, Args, Timeout, P, S);
                        {up, _} ->
                            case checked_payload(Service, Args) of
                                {ok, Payload} ->
                                    publish(Key, Pending, Payload, Timeout, P, S);
                                {error, Code, Message} ->
                                    {S, answer_error(Key, Pending, Code, Message)}
                            end
                    end
            end
    end.

publish(Key, #{service := #{command_topic := Topic, expect := Expect}} = Pending, Payload,
        Timeout, P, S) ->
    case {maps:get(awaiting, Pending), Expect} of
        {false, _} ->
            {S, [{publish, Topic, Payload, undefined}]};
        {true, _} when is_map_key(Key, P) ->
            {S, answer_error(Key, Pending, <<"DuplicateRequest">>,
                             <<"a request with this SignalID is still waiting for its echo">>)};
        {true, _} ->
            {S#{pending := P#{Key => Pending}},
             [{publish, Topic, Payload, Key}, {start_timer, Key, Timeout}]}
    end.

%% TurnLightOn/TurnLightOff: mqtt_avatar_light checks the parameters and
%% makes the publishes; the light's state messages confirm (light_echo/4),
%% or the PUBACK for a light without a state topic.
light_command(Key, #{component := C, service := #{light := L, command := {light, OnOff}}} = Pending,
              Args, Timeout, P, S) ->
    case mqtt_avatar_light:command(L, OnOff, Args) of
        {error, Message} ->
            {S, answer_error(Key, Pending, <<"BadParameter">>, Message)};
        {ok, Publishes, Wait} ->
            S1 = case mqtt_avatar_light:optimistic(L) of
                     true ->
                         #{lights := Lights} = S,
                         LKey = {C, mqtt_avatar_light:command_topic(L)},
                         S#{lights := Lights#{LKey => maps:merge(maps:get(LKey, Lights, #{}),
                                                                 maps:get(assumed, Wait))}};
                     false ->
                         S
                 end,
            case maps:get(awaiting, Pending) of
                false ->
                    {S1, [{publish, T, Payload, undefined} || {T, Payload} <- Publishes]};
                true when is_map_key(Key, P) ->
                    {S, answer_error(Key, Pending, <<"DuplicateRequest">>,
                                     <<"a request with this SignalID is still waiting for its echo">>)};
                true ->
                    {S1#{pending := P#{Key => Pending#{wait => Wait, heard => []}}},
                     [{publish, T, Payload, Key} || {T, Payload} <- Publishes]
                     ++ [{start_timer, Key, Timeout}]}
            end
    end.

find_service(Cat, Type, #{services := Services}) ->
    K = {mqtt_avatar_spec:keyword(Cat), mqtt_avatar_spec:keyword(Type)},
    case [Sv || #{category := C, type := T} = Sv <- Services,
                {mqtt_avatar_spec:keyword(C), mqtt_avatar_spec:keyword(T)} =:= K] of
        [Service | _] -> Service;
        [] -> none
    end.

%% The request's parameters checked (MqttArgCheck, MqttCode), then the
%% payload. A code is compared, never logged nor echoed.
checked_payload(Service, Params) ->
    case check_args(maps:get(checks, Service, []), Params) of
        ok ->
            case check_code(maps:get(code, Service, undefined), Params) of
                ok ->
                    Local = maps:get(code, Service, undefined) =/= undefined,
                    Scale = maps:get(scale, maps:get(mapping, Service, #{}), []),
                    Args = [to_device(P, Scale) || {N, _} = P <- Params,
                                                   N =/= <<"Code">> orelse not Local],
                    case command_payload(Service, Args) of
                        {ok, Payload} ->
                            render_command(maps:get(command_template, Service, undefined),
                                           iolist_to_binary(Payload), Args);
                        {error, M} ->
                            {error, <<"BadParameter">>, M}
                    end;
                {error, M} ->
                    {error, <<"WrongCode">>, M}
            end;
        {error, M} ->
            {error, <<"BadParameter">>, M}
    end.

%% HA's command template: `value' (and `action', as alarm panels call it)
%% is what would be published without it, `code' a remote code.
render_command(undefined, Payload, _Args) ->
    {ok, Payload};
render_command(Template, Payload, Args) ->
    Value = case evatar_json:decode(Payload) of
                {ok, N} when is_number(N) -> N;
                _ -> Payload
            end,
    Vars = #{<<"value">> => Value, <<"action">> => Payload,
             <<"code">> => proplists:get_value(<<"Code">>, Args, undefined)},
    case mqtt_avatar_template:render(Template, Vars) of
        {ok, Text} -> {ok, Text};
        {error, M} -> {error, <<"BadParameter">>, <<"the command template: ", M/binary>>}
    end.

check_args([], _Params) ->
    ok;
check_args([{Name, Check} | Rest], Params) ->
    case {lists:keyfind(Name, 1, Params), Check} of
        {false, _} ->
            {error, <<"the request needs parameter ", Name/binary>>};
        {{_, _}, present} ->
            check_args(Rest, Params);
        {{_, V}, {range, Lo, Hi}} ->
            case evatar_json:decode(V) of
                {ok, N} when is_number(N), N >= Lo, N =< Hi -> check_args(Rest, Params);
                _ -> {error, iolist_to_binary([Name, " must be a number from ",
                                               evatar_json:to_text(Lo), " to ",
                                               evatar_json:to_text(Hi)])}
            end;
        {{_, V}, {one_of, Values}} ->
            case [X || X <- Values, same(X, V)] of
                [_ | _] -> check_args(Rest, Params);
                [] -> {error, iolist_to_binary([Name, " must be one of: ",
                                                lists:join(", ", Values)])}
            end
    end.

check_code(undefined, _Params) ->
    ok;
check_code({pbkdf2_sha256, Iterations, Salt, Hash}, Params) ->
    case lists:keyfind(<<"Code">>, 1, Params) of
        {_, Code} ->
            Derived = crypto:pbkdf2_hmac(sha256, Code, Salt, Iterations, byte_size(Hash)),
            case crypto:hash_equals(Derived, Hash) of
                true -> ok;
                false -> {error, <<"the code is wrong">>}
            end;
        false ->
            {error, <<"this service needs parameter Code">>}
    end.

command_payload(#{command := {raw, Text}, args := Args}, Params) ->
    case [V || {Name, _} <- Args, {N, V} <- Params, N =:= Name] of
        [V | _] -> {ok, V};
        [] -> {ok, Text}
    end;
command_payload(#{command := {json, Base}, args := []}, _Params) ->
    {ok, evatar_json:encode(Base)};
command_payload(#{command := {json, Base}, args := Args}, Params) when is_map(Base) ->
    Json = lists:foldl(fun({Name, Path}, Acc) ->
                               case lists:keyfind(Name, 1, Params) of
                                   {_, V} -> put_path(Path, json_value(V), Acc);
                                   false -> Acc
                               end
                       end, Base, Args),
    {ok, evatar_json:encode(Json)};
command_payload(#{command := {json, _}}, _Params) ->
    {error, <<"MqttCommandArgs needs MqttCommand to be a JSON object">>}.

put_path([K], V, M) -> M#{K => V};
put_path([K | Rest], V, M) ->
    Inner = case maps:get(K, M, #{}) of
                I when is_map(I) -> I;
                _ -> #{}
            end,
    M#{K => put_path(Rest, V, Inner)}.

%% Request parameters are text; numbers go out as JSON numbers, and
%% `true' and `false' as JSON booleans (a siren's Strobe: zigbee2mqtt
%% reads the text "false" as true).
json_value(V) ->
    case evatar_json:decode(V) of
        {ok, N} when is_number(N); is_boolean(N) -> N;
        _ -> V
    end.

%% ---------------------------------------------------------------------------
%% Answers
%% ---------------------------------------------------------------------------

answer_read({_, Id}, #{service := #{type := T, static := Static}} = Pending, Comp, S) ->
    #{id := CompId, read_body := {Cat, Type}} = Comp,
    Values = maps:get(CompId, last_values(S), []),
    Result = case Values of
                 [] -> <<"unknown">>;
                 _ -> <<"done">>
             end,
    case maps:get(awaiting, Pending) of
        true ->
            Params = dedupe([{<<"Service">>, T}, {<<"Result">>, Result}] ++ Values ++ Static),
            [{send, #{context => feedback, sender => CompId, receiver => maps:get(requester, Pending),
                      in_reply_to => Id,
                      body => #{category => Cat, type => Type, parameters => Params}}}];
        false ->
            []
    end.

answer_done({_, Id}, #{awaiting := true} = Pending, Values, #{comps := Comps}) ->
    #{component := C, requester := R, service := #{type := T, static := Static}} = Pending,
    {Cat, Type} = maps:get(feedback, maps:get(C, Comps)),
    Params = dedupe([{<<"Service">>, T}, {<<"Result">>, <<"done">>}] ++ Values ++ Static),
    [{send, #{context => feedback, sender => C, receiver => R, in_reply_to => Id,
              body => #{category => Cat, type => Type, parameters => Params}}}];
answer_done(_, _, _, _) ->
    [].

answer_progress({_, Id}, #{awaiting := true} = Pending, Values, #{comps := Comps}) ->
    #{component := C, requester := R, service := #{type := T}} = Pending,
    {Cat, Type} = maps:get(feedback, maps:get(C, Comps)),
    Params = dedupe([{<<"Service">>, T}] ++ Values),
    [{send, #{context => progress, sender => C, receiver => R, in_reply_to => Id,
              body => #{category => Cat, type => Type, parameters => Params}}}];
answer_progress(_, _, _, _) ->
    [].

answer_error({_, Id}, #{awaiting := true, component := C, requester := R}, Code, Message) ->
    [{send, #{context => error, sender => C, receiver => R, in_reply_to => Id,
              body => #{category => <<"ERROR">>, type => Code,
                        parameters => [{<<"Message">>, Message}]}}}];
answer_error({_, Id}, #{component := C}, Code, Message) ->
    [{problem, #{what => request_failed, component => C, code => Code, request => Id,
                 message => Message}}].

%% ---------------------------------------------------------------------------
%% Payload mapping
%% ---------------------------------------------------------------------------

%% @doc Applies a mapping to a payload: the BIL parameters it gives (none
%% when no mapped field is present), or `{error, Message}' for a payload
%% that cannot be read (not UTF-8, not JSON where JSON is expected).
-spec extract(#{values := list(), attributes := boolean(), map := list()}, binary()) ->
          {ok, [bil:parameter()]} | {error, binary()}.
extract(Mapping, Payload) ->
    extract(Mapping, Payload, #{}).

%% @doc As `extract/2'; top-level fields named in `exclude' never become
%% attributes.
-spec extract(#{values := list(), attributes := boolean(), map := list()}, binary(),
              #{exclude => [binary()]}) ->
          {ok, [bil:parameter()]} | {error, binary()}.
extract(Mapping, Payload, Opts) ->
    case read_values(Mapping, Payload, Opts) of
        {ok, _} = Ok -> Ok;
        {error, Why} -> {error, element(2, why(Why, undefined, Payload))}
    end.

%% As extract/3, with the reason of an error still a term: a payload that
%% is not JSON where JSON is read is `{not_json, Reason, Reader}'.
read_values(#{values := Values, attributes := Attributes, map := Map} = Mapping, Payload, Opts) ->
    Exclude = maps:get(exclude, Opts, []),
    NeedsJson = Attributes orelse lists:any(fun({_, S}) -> S =/= raw andalso S =/= template end,
                                            Values),
    Decoded = case NeedsJson of
                  true -> evatar_json:decode(Payload);
                  false -> {ok, undefined}
              end,
    case {text(Payload), Decoded} of
        {error, _} ->
            {error, <<"the payload is not UTF-8 text">>};
        {_, {error, Reason}} ->
            Reader = case [[N, "=json:", mqtt_avatar_part:join_path(P)]
                           || {N, {json, P}} <- Values] of
                         [R | _] -> ["MqttValue ", R];
                         [] -> "MqttAttributes all"
                     end,
            {error, not_json(Reason, Reader)};
        {{ok, Text}, {ok, Json}} ->
            Mapped0 = [one_value(Name, Source, Text, Json, Payload, Mapping) || {Name, Source} <- Values],
            Mapped = lists:append([V || V <- Mapped0, is_list(V)]),
            Attrs = case {Attributes, Json} of
                        {true, J} when is_map(J) ->
                            [{camel(K), scalar(V)} || {K, V} <- lists:sort(maps:to_list(J)),
                                                      is_scalar(V), camel(K) =/= <<>>,
                                                      not lists:member(K, Exclude)];
                        _ -> []
                    end,
            Scale = maps:get(scale, Mapping, []),
            Params = [{N, translate(V, Map)} || {N, V} <- [from_device(P, Scale) || P <- Mapped]
                                                           ++ Attrs],
            case {[M || {error, M} <- Mapped0], [N || {N, V} <- Params, byte_size(V) > ?MAX_VALUE]} of
                {[M | _], _} -> {error, M};
                {[], []} -> {ok, dedupe(Params)};
                {[], [N | _]} -> {error, <<"value of ", N/binary, " longer than 4096 bytes">>}
            end
    end.

one_value(Name, raw, Text, _Json, _Payload, _Mapping) ->
    [{Name, Text}];
one_value(Name, template, _Text, _Json, Payload, #{template := T} = Mapping) ->
    %% HA's state template: `value' and `value_json' of the payload.
    Vars = mqtt_avatar_template:payload_vars(Payload),
    NotJson = maps:get(<<"value_json">>, Vars) =:= undefined
        andalso mqtt_avatar_template:reads(T, <<"value_json">>),
    case {mqtt_avatar_template:value(T, Vars), NotJson} of
        {Failed, true} when Failed =:= {ok, undefined}; element(1, Failed) =:= error ->
            %% The template reads JSON and the payload is not: say that,
            %% not what it led to (an undefined value given to `| float').
            {error, R} = evatar_json:decode(Payload),
            {error, not_json(R, ["the value template ",
                                 quoted(maps:get(template_text, Mapping, <<"of ", Name/binary>>))])};
        {{ok, undefined}, false} ->
            %% HA's own examples write `{{ value.x }}', which reads nothing
            %% of a text payload: say so rather than send no state.
            {error, <<"the value template of ", Name/binary, " gave nothing for this payload "
                      "(it reads a field the payload does not have; `value' is the payload's "
                      "text, write value_json.x for a field of a JSON payload)">>};
        {{ok, null}, _} -> [];
        {{ok, V}, _} when is_binary(V); is_number(V); is_boolean(V) -> [{Name, scalar(V)}];
        {{ok, V}, _} -> [{Name, clean(mqtt_avatar_template:to_text(V))}];
        {{error, M}, false} -> {error, <<"the value template of ", Name/binary, ": ", M/binary>>}
    end;
one_value(Name, {json, Path}, _Text, Json, _Payload, _Mapping) ->
    case evatar_json:get_path(Path, Json) of
        {ok, null} -> [];
        {ok, V} -> [{Name, scalar(V)}];
        error -> []
    end.

json_text(Payload, Path) ->
    case evatar_json:decode(Payload) of
        {ok, J} ->
            case evatar_json:get_path(Path, J) of
                {ok, V} -> {ok, evatar_json:to_text(V)};
                error -> {error, <<"the availability field is missing">>}
            end;
        {error, R} ->
            {error, evatar_json:format_error(R)}
    end.

%% A description refused for one of the pairing's limits: which option
%% raises it, and how (docs/mqtt.md section 6, "Limits").
with_advice(Message) ->
    case [O || O <- [<<"max_consumes">>, <<"max_binding_report">>, <<"max_id_length">>,
                     <<"max_description_size">>],
               binary:match(Message, <<"(", O/binary>>) =/= nomatch] of
        [<<"max_description_size">> | _] ->
            <<Message/binary, ": the new description was not taken; raise the bil application's "
              "max_description_size (a release: EVATAR_MAX_DESCRIPTION_SIZE) and the listener's "
              "max_frame (conn => #{max_frame => Bytes} in the node configuration file's "
              "listeners entry) above the description's size, or leave entities out with "
              "overrides (skip); docs/mqtt.md section 6, Limits">>;
        [Option | _] ->
            <<Message/binary, ": the new description was not taken (the Avatar runs on its last "
              "accepted one); raise the pairing option ", Option/binary, " (PUT /api/pairings/ID "
              "recreates the pairing with it; the node configuration file's pairings entry counts "
              "only when the pairing is created), or leave entities out with overrides (skip); "
              "docs/mqtt.md section 6, Limits">>;
        [] ->
            Message
    end.

%% MqttScale, as HA scales a fan's percentage to its speed_range Lo..Hi:
%% the device gets ceil(Lo - 1 + Pct * (Hi - Lo + 1) / 100), and its value
%% V reads as (V - Lo + 1) * 100 div (Hi - Lo + 1) per cent. A value that
%% is not a number is left as it is (MqttArgCheck refuses it in a request).
to_device({N, V} = P, Scale) ->
    case {lists:keyfind(N, 1, Scale), evatar_json:decode(V)} of
        {{_, Lo, Hi}, {ok, Pct}} when is_number(Pct) ->
            {N, integer_to_binary(ceiling(Lo - 1 + Pct * (Hi - Lo + 1) / 100))};
        _ -> P
    end.

from_device({N, V} = P, Scale) ->
    case {lists:keyfind(N, 1, Scale), evatar_json:decode(V)} of
        {{_, Lo, Hi}, {ok, X}} when is_number(X) ->
            {N, integer_to_binary(floor((X - Lo + 1) * 100 / (Hi - Lo + 1)))};
        _ -> P
    end.

%% ceil/1 without float noise: 60 * 10 / 100 is 6.000000000000001.
ceiling(X) -> ceil(round(X * 1000000) / 1000000).

%% BIL's yes/no for JSON booleans; the text of everything else.
scalar(V) -> yes_no(V).

yes_no(true) -> <<"yes">>;
yes_no(false) -> <<"no">>;
yes_no(V) -> clean(evatar_json:to_text(V)).

is_scalar(V) -> not is_map(V) andalso not is_list(V) andalso V =/= null.

translate(V, Map) ->
    case lists:keyfind(string:casefold(V), 1, Map) of
        {_, To} -> To;
        false -> V
    end.

%% Valid UTF-8, with the control characters XML cannot carry replaced.
text(Payload) ->
    case unicode:characters_to_binary(Payload) of
        Payload -> {ok, clean(Payload)};
        _ -> error
    end.

clean(Bin) ->
    << <<(case C of
              _ when C =:= $\t; C =:= $\n; C =:= $\r -> C;
              _ when C < 16#20; C =:= 16#FFFE; C =:= 16#FFFF -> $\s;
              _ -> C
          end)/utf8>> || <<C/utf8>> <= Bin >>.

%% @doc A JSON key as a BIL parameter name: `last_motion' gives
%% `LastMotion'. Only ASCII letters and digits are kept; a leading digit
%% gets a `P' in front; `<<>>' when nothing is left.
-spec camel(binary()) -> binary().
camel(Key) ->
    Parts = [P || P <- re:split(Key, <<"[^A-Za-z0-9]+">>, [{return, binary}]), P =/= <<>>],
    Name = << <<(upper_first(P))/binary>> || P <- Parts >>,
    case Name of
        <<C, _/binary>> when C >= $0, C =< $9 -> <<"P", Name/binary>>;
        _ -> Name
    end.

upper_first(<<C, Rest/binary>>) when C >= $a, C =< $z -> <<(C - 32), Rest/binary>>;
upper_first(B) -> B.

dedupe(Params) ->
    {Out, _} = lists:foldl(fun({N, _} = P, {Acc, Seen}) ->
                                   case maps:is_key(N, Seen) of
                                       true -> {Acc, Seen};
                                       false -> {[P | Acc], Seen#{N => true}}
                                   end
                           end, {[], #{}}, Params),
    lists:reverse(Out).

%% ---------------------------------------------------------------------------
%% Binding
%% ---------------------------------------------------------------------------

stream_receivers(Id, Cat, Type, #{entity := E, bound := Bound}) ->
    [C || #{consumer := #{entity := CE, component := CC}, provider := #{component := C},
            category := BC, type := BT} <- Bound,
          CE =:= E, CC =:= Id, BC =:= Cat, BT =:= Type].

%% @doc Each component's partners as the Avatar's last Binding report
%% says (the components bound to it, either way): who its events go to.
-spec partners(state()) -> #{binary() => [binary()]}.
partners(#{comps := Comps} = S) ->
    maps:from_list([{Id, partners(Id, S)} || Id <- maps:keys(Comps)]).

partners(Id, #{entity := E, bound := Bound}) ->
    lists:usort([P || #{consumer := #{entity := CE, component := CC},
                        provider := #{component := P}} <- Bound, CE =:= E, CC =:= Id]
                ++ [C || #{provider := #{entity := PE, component := PC},
                           consumer := #{component := C}} <- Bound, PE =:= E, PC =:= Id]).

%% A payload (UTF-8 text) quoted in a problem: at most 64 characters of it.
quoted(Text) ->
    case string:length(Text) > 64 of
        true -> <<"'", (unicode:characters_to_binary(string:slice(Text, 0, 64)))/binary, "...'">>;
        false -> <<"'", (unicode:characters_to_binary(Text))/binary, "'">>
    end.

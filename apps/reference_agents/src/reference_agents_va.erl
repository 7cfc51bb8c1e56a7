%% @doc Internal. One reference Virtual Agent: joins an EVATAR pairing as
%% role `agent' through `agent_bridge_client' (the client an external MAS
%% uses), describes its virtual body (its sensor and actuator emulators),
%% and runs the Observe-Choose-Act cycle of the paper's Fig. 8: it observes
%% EVATAR for a binding, then tests the binding (the embodiment test), and
%% once embodied passes every observation to its mind
%% (`reference_agents_mind') and carries out the acts the mind chooses. A
%% VA without a body (the coordinator) skips EVATAR and only thinks and
%% talks.
%%
%% ```
%%                 connect failed / connection lost (retry after a pause)
%%               +------------------------------------------------+
%%               v                                                |
%%  init --> connecting --Welcome, body sent--> observing --Binding with links--> testing
%%   |                                           ^    ^                           |   |
%%   | no body                                   |    +--- nothing works ---------+   |
%%   v                                           |                                    |
%%  unembodied (mind only)                       +--- binding lost ---- embodied <----+
%%                                                   (new binding: testing again)  some work
%% '''
-module(reference_agents_va).
-behaviour(gen_statem).

-export([start_link/1, stop/1, inspect/1, traffic/1, tell/3, introduce/2]).
-export([init/1, callback_mode/0, handle_event/4, terminate/3]).

-export_type([opts/0, traffic/0]).

-type traffic() :: #{state := atom(), entity := binary() | undefined,
                     in := non_neg_integer(), out := non_neg_integer(),
                     told := non_neg_integer(), heard := non_neg_integer()}.

%% `body' is the VA's BIL description, or `none' for a VA without an
%% Avatar. `peers' maps the names of other VAs to their pids (MAS
%% communication). `clock' gives the time in ms (the simulation's). `seen'
%% is an atomics array (`atomics:new(1, [{signed, true}])') whose first
%% element the VA keeps at the latest simulated time its Avatars' signals
%% carried (0 until the first), so a simulation clock can follow it
%% (avatar_sim:follow/3). What it has handled and sent on its connection
%% (traffic/1) lets a simulation clock run in lockstep with it.
-type opts() :: #{name := binary(),
                  mind := module(),
                  mind_args => term(),
                  body := bil:description() | none,
                  endpoints => [agent_bridge_client:endpoint()],
                  pairing => binary(),
                  credential => binary(),
                  peers => #{binary() => pid()},
                  owner => pid(),
                  narrator => pid() | undefined,
                  clock => fun(() -> integer()),
                  seen => atomics:atomics_ref(),
                  test_timeout => pos_integer(),
                  retry => pos_integer()}.

%% The states of the machine (the diagram above).
-type state() :: connecting | unembodied | testing | embodied | observing.

-record(d, {opts :: opts(),
            name :: binary(),
            mind :: module(),
            mind_state :: term(),
            client :: pid() | undefined,
            table :: reference_agents_emulator:table() | undefined,
            test :: reference_agents_embodiment:test() | undefined,
            test_gen = 0 :: non_neg_integer(),
            report :: reference_agents_embodiment:report() | undefined,
            %% Open requests: SignalID -> {mind, Tag} | {check, Gen, CheckId}.
            pending = #{} :: #{binary() => {mind, term()} | {check, non_neg_integer(), pos_integer()}},
            counter = 0 :: non_neg_integer(),
            peers = #{} :: #{binary() => pid()},
            %% The Timestamp of the last signal from the Avatar: the VA's idea
            %% of physical time (simulated time with avatar_sim).
            last_time :: integer() | undefined,
            %% On this connection: the Sequence of the last signal handled,
            %% signals sent; MAS messages told and heard since the start.
            in = 0 :: non_neg_integer(),
            out = 0 :: non_neg_integer(),
            told = 0 :: non_neg_integer(),
            heard = 0 :: non_neg_integer(),
            history = [] :: [{state(), integer()}]}).

%% ---------------------------------------------------------------------------
%% API
%% ---------------------------------------------------------------------------

-spec start_link(opts()) -> {ok, pid()}.
start_link(#{name := Name} = Opts) when is_binary(Name) ->
    gen_statem:start_link(?MODULE, Opts#{owner => maps:get(owner, Opts, self())}, []).

%% @doc Says Bye to EVATAR and stops.
-spec stop(pid()) -> ok.
stop(Va) -> gen_statem:stop(Va).

%% @doc The VA's state, its embodiment report, what its mind shows and
%% how many of its requests await their answer.
-spec inspect(pid()) -> #{name := binary(), state := state(),
                          embodiment := reference_agents_embodiment:report() | undefined,
                          mind := map(), states := [{state(), integer()}],
                          pending := non_neg_integer()}.
inspect(Va) -> gen_statem:call(Va, inspect).

%% @doc A cheap read of the VA's traffic: its state, the entity it joined
%% as, the Sequence of the last signal from EVATAR it has handled and how
%% many signals it has sent on its current connection (`in', `out': what
%% evatar:traffic/1 counts on the pairing's side), and the MAS messages it
%% has told other VAs and heard from them.
-spec traffic(pid()) -> traffic().
traffic(Va) -> gen_statem:call(Va, traffic).

%% @doc Delivers a MAS message from `From' (a VA name) to the VA.
-spec tell(pid(), binary(), term()) -> ok.
tell(Va, From, Message) ->
    Va ! {reference_agents, message, From, Message},
    ok.

%% @doc Tells the VA the names and pids of the other VAs.
-spec introduce(pid(), #{binary() => pid()}) -> ok.
introduce(Va, Peers) -> gen_statem:cast(Va, {peers, Peers}).

%% ---------------------------------------------------------------------------
%% gen_statem
%% ---------------------------------------------------------------------------

-spec callback_mode() -> gen_statem:callback_mode_result().
callback_mode() -> [handle_event_function, state_enter].

-spec init(opts()) -> gen_statem:init_result(state()).
init(#{name := Name, mind := Mind} = Opts) ->
    logger:update_process_metadata(#{va => Name}),
    {ok, MindState} = Mind:init(maps:get(mind_args, Opts, [])),
    D = #d{opts = Opts, name = Name, mind = Mind, mind_state = MindState,
           peers = maps:get(peers, Opts, #{})},
    case maps:get(body, Opts) of
        none -> {ok, unembodied, D};
        _Body -> {ok, connecting, D}
    end.

-spec handle_event(gen_statem:event_type(), term(), state(), #d{}) ->
          gen_statem:event_handler_result(state()).
%% Entering a state: remember it (tests read the history) and start work.
handle_event(enter, _Old, State, D) ->
    D1 = D#d{history = [{State, now(D)} | D#d.history]},
    case State of
        connecting -> {keep_state, D1, [{state_timeout, 0, connect}]};
        _ -> {keep_state, D1}
    end;

handle_event(state_timeout, connect, connecting, #d{opts = Opts} = D) ->
    #{body := Body, endpoints := Endpoints, pairing := Pairing,
      credential := Credential} = Opts,
    ClientOpts = #{pairing => Pairing, role => agent, entity_id => maps:get(entity_id, Body),
                   credential => Credential, owner => self()},
    case agent_bridge_client:connect(Endpoints, ClientOpts) of
        {ok, Client} ->
            ok = agent_bridge_client:describe(Client, Body),
            D1 = narrate(D, info, ["joined pairing ", Pairing, " over TCP and described its body (",
                                   integer_to_binary(length(maps:get(components, Body))),
                                   " emulators); observing EVATAR for a binding"]),
            {next_state, observing, D1#d{client = Client, in = 0, out = 0,
                                         table = reference_agents_emulator:new(Body)}};
        {error, Why} ->
            D1 = narrate(D, info, io_lib:format("cannot join ~s: ~0p; trying again", [Pairing, Why])),
            {keep_state, D1, [{state_timeout, maps:get(retry, Opts, 500), connect}]}
    end;

%% Observe EVATAR for a binding.
handle_event(info, {agent_bridge, C, {binding, Report}}, State, #d{client = C} = D)
  when State =:= observing; State =:= testing; State =:= embodied ->
    Table = reference_agents_emulator:bind(reference_agents_emulator:new(body(D)), Report),
    Changed = reference_agents_emulator:signature(Table)
        =/= reference_agents_emulator:signature(D#d.table),
    Links = reference_agents_emulator:bound(Table),
    if
        not Changed, State =/= observing ->
            {keep_state, D#d{table = Table}};
        Links =:= [] ->
            D1 = narrate(D#d{table = Table}, perceive,
                         "EVATAR reports no binding for this body (its Avatar is not there)"),
            D2 = case State of
                     embodied -> observe({disembodied, <<"the Avatar is gone">>}, D1);
                     _ -> D1
                 end,
            {next_state, observing, D2#d{test = undefined}};
        true ->
            D1 = narrate(D#d{table = Table}, perceive,
                         io_lib:format("EVATAR bound ~b of its consumer entries (~b unbound): "
                                       "testing the binding",
                                       [length(Links),
                                        length(reference_agents_emulator:unbound(Table))])),
            start_test(D1)
    end;

%% The embodiment test.
handle_event(info, {agent_bridge, C, {signal, S}}, testing, #d{client = C} = D0) ->
    D = seen(S, D0),
    case test_signal(S, D) of
        {handled, D1} -> maybe_tested(handled(S, D1));
        not_test -> {keep_state_and_data, [postpone]}
    end;
handle_event({timeout, test}, Gen, testing, #d{test_gen = Gen} = D) ->
    finish_test(D);
handle_event({timeout, test}, _OldGen, _State, _D) ->
    keep_state_and_data;

%% Embodied (or observing, or without a body): observe, choose, act.
handle_event(info, {agent_bridge, C, {signal, S}}, _State, #d{client = C} = D) ->
    {keep_state, signal(S, seen(S, handled(S, D)))};
handle_event(info, {reference_agents, message, From, _Message}, testing, _D)
  when is_binary(From) ->
    {keep_state_and_data, [postpone]};
handle_event(info, {reference_agents, message, From, Message}, _State, D) when is_binary(From) ->
    {keep_state, observe({message, From, Message}, D#d{heard = D#d.heard + 1})};
handle_event(cast, {peers, Peers}, _State, D) ->
    {keep_state, D#d{peers = maps:merge(D#d.peers, Peers)}};

handle_event(info, {agent_bridge, C, {closed, Why}}, _State, #d{client = C} = D) ->
    D1 = narrate(D, info, io_lib:format("connection to EVATAR closed (~0p); joining again", [Why])),
    D2 = fail_pending(<<"the connection to EVATAR was lost">>, D1#d{client = undefined}),
    D3 = observe({disembodied, <<"the connection to EVATAR was lost">>}, D2),
    {next_state, connecting, D3#d{test = undefined}};
handle_event(info, {agent_bridge, _OldClient, _}, _State, _D) ->
    keep_state_and_data;

handle_event({call, From}, inspect, State, #d{mind = Mind} = D) ->
    {keep_state_and_data,
     [{reply, From, #{name => D#d.name, state => State, embodiment => D#d.report,
                      mind => Mind:inspect(D#d.mind_state),
                      states => lists:reverse(D#d.history),
                      pending => map_size(D#d.pending)}}]};
handle_event({call, From}, traffic, State, D) ->
    {keep_state_and_data,
     [{reply, From, #{state => State, entity => entity_id(D), in => D#d.in, out => D#d.out,
                      told => D#d.told, heard => D#d.heard}}]};
handle_event(info, _Other, _State, _D) ->
    keep_state_and_data.

-spec terminate(term(), state(), #d{}) -> ok.
terminate(_Why, _State, #d{client = undefined}) -> ok;
terminate(_Why, _State, #d{client = C}) -> agent_bridge_client:close(C).

%% ---------------------------------------------------------------------------
%% The embodiment test
%% ---------------------------------------------------------------------------

start_test(#d{table = Table, mind = Mind, test_gen = Gen0} = D) ->
    Gen = Gen0 + 1,
    MindState = D#d.mind_state,
    {Test, Steps} = reference_agents_embodiment:start(
                      Table, fun(Link) -> Mind:probe(Link, MindState) end),
    %% Requests of an earlier test are forgotten: their answers are late.
    Pending = maps:filter(fun(_, {check, _, _}) -> false; (_, _) -> true end, D#d.pending),
    D1 = lists:foldl(fun(Step, Acc) -> test_step(Step, Gen, Acc) end,
                     D#d{test = Test, test_gen = Gen, pending = Pending}, Steps),
    Timeout = maps:get(test_timeout, D#d.opts, 5000),
    case reference_agents_embodiment:done(D1#d.test) of
        true -> finish_test(D1);
        false -> {next_state, testing, D1, [{{timeout, test}, Timeout, Gen}]}
    end.

test_step({request, Id, Emulator, Service, Params}, Gen, D) ->
    case reference_agents_emulator:request(Emulator, Service, Params, D#d.table) of
        {ok, Signal} ->
            {SigId, D1} = send_signal(Signal#{context => request}, D),
            D1#d{pending = (D1#d.pending)#{SigId => {check, Gen, Id}}};
        {error, Why} ->
            D#d{test = reference_agents_embodiment:result(Id, {failed, why(Why)}, D#d.test)}
    end;
test_step({await_reading, _Id, _Emulator}, _Gen, D) ->
    D.

test_signal(#{context := Ctx, in_reply_to := Ref} = S, #d{pending = P, test_gen = Gen} = D)
  when is_map_key(Ref, P), (Ctx =:= feedback orelse Ctx =:= error) ->
    case maps:get(Ref, P) of
        {check, Gen, Id} ->
            Outcome = case outcome(S) of
                          {ok, _} -> ok;
                          {failed, _} = F -> F
                      end,
            {handled, D#d{pending = maps:remove(Ref, P),
                          test = reference_agents_embodiment:result(Id, Outcome, D#d.test)}};
        {check, _OldGen, _} ->
            {handled, D#d{pending = maps:remove(Ref, P)}};
        {mind, _} ->
            not_test
    end;
test_signal(#{context := Ctx, receiver := Emulator} = S, D)
  when Ctx =:= sensor_data; Ctx =:= event ->
    case reference_agents_emulator:percept(S, D#d.table) of
        {ok, _} ->
            %% The reading passes the sensor's check, and the mind sees it
            %% too once the test is over.
            Test = reference_agents_embodiment:reading(Emulator, D#d.test),
            case Test =:= D#d.test of
                true -> not_test;
                false -> {handled, D#d{test = Test}}
            end;
        error -> not_test
    end;
test_signal(_S, _D) ->
    not_test.

maybe_tested(D) ->
    case reference_agents_embodiment:done(D#d.test) of
        true -> finish_test(D);
        false -> {keep_state, D}
    end.

finish_test(#d{test = Test} = D) ->
    Report = reference_agents_embodiment:report(Test),
    [First | Details] = reference_agents_embodiment:format(Report),
    D1 = lists:foldl(fun(Line, Acc) -> narrate(Acc, info, Line) end,
                     narrate(D, decide, First), Details),
    D2 = D1#d{report = Report, test = undefined},
    case maps:get(verdict, Report) of
        none ->
            D3 = narrate(D2, decide, "not embodied: observing EVATAR for a new binding"),
            {next_state, observing, observe({disembodied, <<"the embodiment test failed">>}, D3)};
        Verdict ->
            D3 = narrate(D2, decide,
                         case Verdict of
                             embodied -> "state: embodied in its Avatar";
                             partial -> "state: embodied, without the relationships that failed"
                         end),
            {next_state, embodied, observe({embodied, Report}, D3)}
    end.

%% ---------------------------------------------------------------------------
%% Observe, choose, act
%% ---------------------------------------------------------------------------

signal(#{context := Ctx, in_reply_to := Ref} = S, #d{pending = P} = D)
  when is_map_key(Ref, P), (Ctx =:= feedback orelse Ctx =:= error) ->
    case maps:get(Ref, P) of
        {mind, Tag} -> observe({result, Tag, outcome(S)}, D#d{pending = maps:remove(Ref, P)});
        {check, _, _} -> D#d{pending = maps:remove(Ref, P)}
    end;
signal(#{context := progress, in_reply_to := Ref, body := #{parameters := Ps}},
       #d{pending = P} = D) when is_map_key(Ref, P) ->
    case maps:get(Ref, P) of
        {mind, Tag} -> observe({progress, Tag, Ps}, D);
        _ -> D
    end;
signal(#{context := Ctx} = S, D) when Ctx =:= sensor_data; Ctx =:= event ->
    case D#d.table =/= undefined andalso reference_agents_emulator:percept(S, D#d.table) of
        {ok, Percept} -> observe({percept, Percept}, D);
        _ -> observe({signal, S}, D)
    end;
signal(S, D) ->
    observe({signal, S}, D).

observe(Observation, #d{mind = Mind, mind_state = MS} = D) ->
    {MS1, Acts} = Mind:choose(Observation, now(D), MS),
    lists:foldl(fun act/2, D#d{mind_state = MS1}, Acts).

act({request, Tag, Emulator, Service, Params}, D) ->
    case request_signal(Emulator, Service, Params, D) of
        {ok, Signal} ->
            {SigId, D1} = send_signal(Signal#{context => request}, D),
            D1#d{pending = (D1#d.pending)#{SigId => {mind, Tag}}};
        {error, Why} ->
            observe({result, Tag, {failed, Why}}, D)
    end;
act({send, Emulator, Service, Params}, D) ->
    case request_signal(Emulator, Service, Params, D) of
        {ok, Signal} ->
            {_, D1} = send_signal(Signal#{context => request_no_feedback}, D),
            D1;
        {error, Why} ->
            narrate(D, info, ["cannot send ", Service, ": ", Why])
    end;
act({tell, To, Message}, #d{peers = Peers, name = Me} = D) ->
    case Peers of
        #{To := Pid} -> ok = tell(Pid, Me, Message), D#d{told = D#d.told + 1};
        _ -> narrate(D, info, ["no VA called ", To, " to tell"])
    end;
act({narrate, Kind, Text}, D) ->
    narrate(D, Kind, Text);
act({notify, Term}, #d{opts = #{owner := Owner}, name = Me} = D) ->
    Owner ! {reference_agents, Me, Term},
    D.

request_signal(_Emulator, _Service, _Params, #d{client = undefined}) ->
    {error, <<"not connected to EVATAR">>};
request_signal(Emulator, Service, Params, #d{table = Table}) ->
    case reference_agents_emulator:request(Emulator, Service, Params, Table) of
        {ok, _} = Ok -> Ok;
        {error, Why} -> {error, why(Why)}
    end.

send_signal(Signal, #d{client = C, counter = N, name = Name} = D) ->
    Id = <<Name/binary, "-", (integer_to_binary(N + 1))/binary>>,
    %% A closed connection shows up as a {closed, _} message just after.
    Out = case agent_bridge_client:send(C, Signal#{id => Id, timestamp => now(D)}) of
              ok -> D#d.out + 1;
              {error, _} -> D#d.out
          end,
    {Id, D#d{counter = N + 1, out = Out}}.

%% Feedback from EVATAR itself (Timeout, ProviderGone) and error signals
%% are failures; a device's feedback saying Done=no or Status=failed too.
outcome(#{context := error, body := #{type := Code, parameters := Ps}}) ->
    {failed, iolist_to_binary([Code, ": ", param(<<"Message">>, Ps, <<>>)])};
outcome(#{sender := <<"EVATAR">>, body := #{type := Type, parameters := Ps}}) ->
    {failed, iolist_to_binary(["EVATAR ", Type, ": ", param(<<"Message">>, Ps, <<>>)])};
outcome(#{body := #{parameters := Ps}}) ->
    Failed = [V || {N, V} <- Ps, lists:member(key(N), [<<"done">>, <<"status">>]),
                   lists:member(key(V), [<<"no">>, <<"failed">>, <<"error">>])],
    case Failed of
        [] -> {ok, Ps};
        _ -> {failed, iolist_to_binary(["the device answered ",
                                        lists:join(" ", [[N, "=", V] || {N, V} <- Ps])])}
    end.

fail_pending(Why, #d{pending = P} = D) ->
    maps:fold(fun(_, {mind, Tag}, Acc) -> observe({result, Tag, {failed, Why}}, Acc);
                 (_, _, Acc) -> Acc
              end, D#d{pending = #{}}, P).

why({not_bound, Service, Reason}) ->
    iolist_to_binary([Service, " is not bound (", io_lib:format("~p", [Reason]), ")"]).

param(Name, Ps, Default) ->
    case [V || {N, V} <- Ps, key(N) =:= key(Name)] of
        [V | _] -> V;
        [] -> Default
    end.

key(B) -> reference_agents_activity:keyword(B).

body(#d{opts = #{body := Body}}) -> Body.

entity_id(#d{opts = #{body := #{entity_id := Id}}}) -> Id;
entity_id(#d{}) -> undefined.

%% The Sequence EVATAR stamped on the last signal handled (signals come in
%% order on a connection).
handled(#{seq := Seq}, D) when is_integer(Seq) -> D#d{in = Seq};
handled(_S, D) -> D.

%% Every signal from the Avatar tells the time; EVATAR's own carry real time.
seen(#{sender := From, timestamp := T}, #d{last_time = Last} = D)
  when From =/= <<"EVATAR">>, is_integer(T), (Last =:= undefined orelse T > Last) ->
    case D#d.opts of
        #{seen := Cell} -> atomics:put(Cell, 1, T);
        #{} -> ok
    end,
    D#d{last_time = T};
seen(_S, D) ->
    D.

narrate(#d{opts = Opts, name = Name} = D, Kind, Text) ->
    ok = reference_agents_narrator:event(maps:get(narrator, Opts, undefined), Name, Kind, Text),
    D.

now(#d{opts = #{clock := Clock}}) -> Clock();
now(#d{last_time = T}) when is_integer(T) -> T;
now(#d{}) -> erlang:system_time(millisecond).

%% @doc Internal to the broker comparison (broker_bench): the load
%% generator, the same design for the three systems. N pairs of (agent,
%% device), each end one Erlang process in the generator's VM:
%%
%% - through EVATAR, a pairing per pair: the VA and the Avatar each connect
%%   with agent_bridge_client (which encodes what it sends and parses what
%%   it receives), the VA sends a RequestAwaitingFeedback, EVATAR routes it
%%   to the Avatar, whose Feedback comes back the same way;
%% - through an MQTT broker, with mqtt_client (MQTT 3.1.1, QoS 1 both
%%   ways): the agent publishes the same BIL request signal, encoded with
%%   bil:encode_signal/1, on `bench/I/req'; the device, subscribed to it,
%%   parses it with bil:parse_signal/1 and publishes the encoded Feedback
%%   on `bench/I/resp', to which the agent is subscribed; the agent parses
%%   it to match the request. Each end thus encodes and parses what the
%%   client library would through EVATAR.
%%
%% The agent counts a round trip when the answer to its request arrives.
%% Closed loop: one request in flight per agent, the next sent on each
%% answer. Open loop: requests due on a fixed schedule, latency measured
%% from the scheduled send time (no coordinated omission).
-module(broker_bench_gen).

-export([setup/2, teardown/1]).
-export([agent_init/3, device_init/3]).

-export_type([pair/0]).

-type pair() :: #{index := pos_integer(), agent := pid(), device := pid(),
                  pairing => binary()}.
-type target() :: broker_bench_sut:sut().

-define(VA_COMPONENT, <<"LightEmulator01">>).
-define(AV_COMPONENT, <<"HomeLightActuator01">>).
-define(SETUP_TIMEOUT, 120000).
-define(DRAIN_TIMEOUT, 15000).
-define(BATCH, 32).

%% ---------------------------------------------------------------------------
%% Setup and teardown
%% ---------------------------------------------------------------------------

%% @doc Sets up N pairs against the system, ?BATCH at a time; returns once
%% every agent can send (bound through EVATAR, subscribed on a broker).
-spec setup(pos_integer(), target()) -> [pair()].
setup(N, Sut) ->
    setup_batches(lists:seq(1, N), Sut, []).

setup_batches([], _Sut, Acc) ->
    lists:reverse(Acc);
setup_batches(Is, Sut, Acc) ->
    {Batch, Rest} = lists:split(min(?BATCH, length(Is)), Is),
    Pairs = [start_pair(I, Sut) || I <- Batch],
    _ = [await(P, ready) || #{agent := P} <- Pairs],
    setup_batches(Rest, Sut, lists:reverse(Pairs, Acc)).

start_pair(I, #{system := evatar, node := Node} = Sut) ->
    Id = <<"bench-", (integer_to_binary(I))/binary>>,
    Creds = evatar_bench_gen:credentials(),
    {ok, _} = erpc:call(Node, evatar, create_pairing,
                        [Id, Creds#{join_timeout => ?SETUP_TIMEOUT, feedback_timeout => 10000}]),
    Device = proc_lib:spawn(?MODULE, device_init, [self(), Sut, I]),
    await(Device, ready),
    Agent = proc_lib:spawn(?MODULE, agent_init, [self(), Sut, I]),
    #{index => I, agent => Agent, device => Device, pairing => Id};
start_pair(I, Sut) ->
    Device = proc_lib:spawn(?MODULE, device_init, [self(), Sut, I]),
    await(Device, ready),
    Agent = proc_lib:spawn(?MODULE, agent_init, [self(), Sut, I]),
    #{index => I, agent => Agent, device => Device}.

await(Pid, Tag) ->
    receive
        {Pid, Tag} -> ok;
        {Pid, failed, Why} -> error({setup_failed, Why})
    after ?SETUP_TIMEOUT -> error({setup_timeout, Tag})
    end.

%% @doc Stops every agent and device (their client processes follow them)
%% and waits until they are gone.
-spec teardown([pair()]) -> ok.
teardown(Pairs) ->
    Procs = [{P, monitor(process, P)} || #{agent := A, device := D} <- Pairs, P <- [A, D]],
    _ = [exit(P, shutdown) || {P, _} <- Procs],
    _ = [receive {'DOWN', Ref, process, P, _} -> ok after 10000 -> error({not_stopped, P}) end
         || {P, Ref} <- Procs],
    ok.

%% ---------------------------------------------------------------------------
%% Connections
%% ---------------------------------------------------------------------------

%% A connected end: the client process, and for MQTT the topic it sends on.
-type conn() :: {evatar, pid()} | {mqtt, pid(), binary()}.

connect(#{system := evatar, host := Ip, port := Port}, I, Role) ->
    {VaDesc, AvDesc} = evatar_bench_gen:descriptions(I, <<"bench">>),
    Desc = case Role of agent -> VaDesc; avatar -> AvDesc end,
    #{entity_id := Entity} = Desc,
    #{agent_credential := AgCred, avatar_credential := AvCred} = evatar_bench_gen:credentials(),
    Cred = case Role of agent -> AgCred; avatar -> AvCred end,
    {ok, C} = agent_bridge_client:connect(
                [{Ip, Port}], #{pairing => <<"bench-", (integer_to_binary(I))/binary>>,
                                role => Role, entity_id => Entity, credential => Cred}),
    ok = agent_bridge_client:describe(C, Desc),
    {evatar, C};
connect(#{host := Ip, port := Port}, I, Role) ->
    Prefix = <<"bench/", (integer_to_binary(I))/binary, "/">>,
    {Name, Sub, Pub} = case Role of
                           agent -> {<<"agent-">>, <<"resp">>, <<"req">>};
                           avatar -> {<<"device-">>, <<"req">>, <<"resp">>}
                       end,
    {ok, C} = mqtt_client:start_link(#{host => Ip, port => Port, protocol => v311,
                                       client_id => <<Name/binary, (integer_to_binary(I))/binary>>,
                                       clean_start => true, keepalive => 300,
                                       reconnect => false}),
    ok = mqtt_client:await_connected(C, ?SETUP_TIMEOUT),
    {ok, [1]} = mqtt_client:subscribe(C, [{<<Prefix/binary, Sub/binary>>, 1}], ?SETUP_TIMEOUT),
    {mqtt, C, <<Prefix/binary, Pub/binary>>}.

%% Through EVATAR, waits for the Binding report that binds the VA's
%% emulator to the actuator (the Avatar may see an earlier one).
await_bound({evatar, C} = Conn) ->
    receive
        {agent_bridge, C, {binding, #{bound := Bound}}} ->
            case [x || #{consumer := #{component := ?VA_COMPONENT}} <- Bound] of
                [] -> await_bound(Conn);
                _ -> ok
            end;
        {agent_bridge, C, {closed, Why}} ->
            error({closed_while_binding, Why})
    after ?SETUP_TIMEOUT -> error(binding_timeout)
    end;
await_bound({mqtt, _, _}) ->
    ok.

%% ---------------------------------------------------------------------------
%% The device: answers every request with a feedback
%% ---------------------------------------------------------------------------

%% @private
-spec device_init(pid(), target(), pos_integer()) -> no_return().
device_init(Parent, Sut, I) ->
    monitor(process, Parent),
    Conn = try connect(Sut, I, avatar)
           catch C:R -> Parent ! {self(), failed, {device, I, C, R}}, exit(normal)
           end,
    Parent ! {self(), ready},
    device_loop(Conn).

device_loop({evatar, C} = Conn) ->
    receive
        {agent_bridge, C, {signal, #{context := request} = Req}} ->
            ok = agent_bridge_client:send(C, feedback(Req)),
            device_loop(Conn);
        {agent_bridge, C, {closed, _}} ->
            exit(normal);
        {'DOWN', _, process, _, _} ->
            exit(normal);
        _Other ->
            device_loop(Conn)
    end;
device_loop({mqtt, C, Topic} = Conn) ->
    receive
        {mqtt_client, C, {publish, #{payload := Payload}}} ->
            case bil:parse_signal(Payload) of
                {ok, #{context := request} = Req} ->
                    Fb = (feedback(Req))#{timestamp => os:system_time(millisecond),
                                          seq => undefined, epoch => undefined},
                    ok = mqtt_client:publish_async(C, Topic, bil:encode_signal(Fb), #{qos => 1});
                _ ->
                    ok
            end,
            device_loop(Conn);
        {'DOWN', _, process, _, _} ->
            exit(normal);
        _Other ->
            device_loop(Conn)
    end.

feedback(#{id := Id, sender := S, receiver := R}) ->
    #{context => feedback, id => <<"fb-", Id/binary>>, in_reply_to => Id,
      sender => R, receiver => S, body => evatar_bench_gen:feedback_body()}.

%% ---------------------------------------------------------------------------
%% The agent: closed-loop and open-loop request senders
%% ---------------------------------------------------------------------------

-record(a, {conn :: conn(),
            parent :: pid(),
            index :: pos_integer(),
            counters :: counters:counters_ref() | undefined,
            next = 1 :: pos_integer(),
            %% request number => scheduled (open loop) or send time, in µs
            inflight = #{} :: #{pos_integer() => integer()},
            errors = 0 :: non_neg_integer()}).

%% @private
-spec agent_init(pid(), target(), pos_integer()) -> no_return().
agent_init(Parent, Sut, I) ->
    monitor(process, Parent),
    Conn = try
               C = connect(Sut, I, agent),
               ok = await_bound(C),
               C
           catch Class:R -> Parent ! {self(), failed, {agent, I, Class, R}}, exit(normal)
           end,
    Parent ! {self(), ready},
    idle(#a{conn = Conn, parent = Parent, index = I}).

%% Between phases: waits for the controller's next command.
idle(A) ->
    receive
        {closed, Counters} ->
            closed(send_request(now_us(), A#a{counters = Counters}));
        {open, Plan} ->
            open(Plan, A);
        {'DOWN', _, process, _, _} ->
            exit(normal);
        Other ->
            case answer(Other, A) of
                {_, _, A1} -> idle(A1);
                ignore -> idle(A)
            end
    end.

%% Closed loop: every answer sends the next request at once.
closed(#a{counters = Counters, index = I} = A) ->
    receive
        stop_loop ->
            drain(A, now_us() + ?DRAIN_TIMEOUT * 1000);
        {'DOWN', _, process, _, _} ->
            exit(normal);
        Msg ->
            case answer(Msg, A) of
                {ok, _, A1} ->
                    ok = counters:add(Counters, I, 1),
                    closed(send_request(now_us(), A1));
                {error, _, A1} ->
                    closed(send_request(now_us(), A1));
                ignore ->
                    closed(A)
            end
    end.

drain(#a{inflight = F, parent = Parent} = A, Deadline)
  when map_size(F) =:= 0; Deadline =:= expired ->
    Parent ! {self(), drained, #{errors => A#a.errors, unanswered => map_size(F)}},
    idle(A#a{inflight = #{}, errors = 0});
drain(A, Deadline) ->
    receive
        Msg ->
            case answer(Msg, A) of
                {_, _, A1} -> drain(A1, Deadline);
                ignore -> drain(A, Deadline)
            end
    after max(0, (Deadline - now_us()) div 1000) ->
            drain(A, expired)
    end.

%% Open loop: request k is due at start + phase + k * interval whatever
%% happened to the earlier ones; due times fall on whole milliseconds (the
%% resolution of Erlang timers) and latency counts from the due time.
%% Plan: #{start := Ms, interval := Us, phase := Us, until := Ms,
%%         window := {FromUs, ToUs}}.
open(#{start := StartMs, phase := Phase} = Plan, A) ->
    open(Plan, StartMs * 1000 + Phase, A, [], []).

open(#{until := Until} = Plan, DueUs, A, Lat, Lag) ->
    case DueUs div 1000 >= Until of
        true ->
            open_drain(Plan, A, Lat, Lag, now_us() + ?DRAIN_TIMEOUT * 1000);
        false ->
            TRef = erlang:start_timer(DueUs div 1000, self(), due, [{abs, true}]),
            open_wait(Plan, DueUs, TRef, A, Lat, Lag)
    end.

open_wait(#{window := {From, To}} = Plan, DueUs, TRef, A, Lat, Lag) ->
    receive
        {timeout, TRef, due} ->
            {Due1, A1, Lag1} = send_due(Plan, DueUs, A, Lag),
            open(Plan, Due1, A1, Lat, Lag1);
        {'DOWN', _, process, _, _} ->
            exit(normal);
        Msg ->
            case answer(Msg, A) of
                {_, S, A1} when S >= From, S < To ->
                    open_wait(Plan, DueUs, TRef, A1, [now_us() - S | Lat], Lag);
                {_, _, A1} ->
                    open_wait(Plan, DueUs, TRef, A1, Lat, Lag);
                ignore ->
                    open_wait(Plan, DueUs, TRef, A, Lat, Lag)
            end
    end.

%% Every request whose due millisecond has come goes now.
send_due(#{interval := Interval, window := {From, To}} = Plan, DueUs, A, Lag) ->
    Now = now_us(),
    Sched = DueUs div 1000 * 1000,
    case Sched =< Now of
        true ->
            Lag1 = case Sched >= From andalso Sched < To of
                       true -> [Now - Sched | Lag];
                       false -> Lag
                   end,
            send_due(Plan, DueUs + Interval, send_request(Sched, A), Lag1);
        false ->
            {DueUs, A, Lag}
    end.

open_drain(#{window := {From, To}}, #a{inflight = F, parent = Parent} = A, Lat, Lag, Deadline)
  when map_size(F) =:= 0; Deadline =:= expired ->
    Lost = length([S || S <- maps:values(F), S >= From, S < To]),
    Parent ! {self(), samples, #{latencies => Lat, send_lags => Lag, errors => A#a.errors,
                                 unanswered => Lost}},
    idle(A#a{inflight = #{}, errors = 0});
open_drain(#{window := {From, To}} = Plan, A, Lat, Lag, Deadline) ->
    receive
        Msg ->
            case answer(Msg, A) of
                {_, S, A1} when S >= From, S < To ->
                    open_drain(Plan, A1, [now_us() - S | Lat], Lag, Deadline);
                {_, _, A1} ->
                    open_drain(Plan, A1, Lat, Lag, Deadline);
                ignore ->
                    open_drain(Plan, A, Lat, Lag, Deadline)
            end
    after max(0, (Deadline - now_us()) div 1000) ->
            open_drain(Plan, A, Lat, Lag, expired)
    end.

now_us() -> erlang:monotonic_time(microsecond).

%% Sends request number `next', remembering Sched (its due or send time).
send_request(Sched, #a{conn = Conn, next = K, inflight = F} = A) ->
    Req = #{context => request, id => <<"q", (integer_to_binary(K))/binary>>,
            sender => ?VA_COMPONENT, receiver => ?AV_COMPONENT,
            body => evatar_bench_gen:request_body()},
    ok = send(Conn, Req),
    A#a{next = K + 1, inflight = F#{K => Sched}}.

send({evatar, C}, Req) ->
    agent_bridge_client:send(C, Req);
send({mqtt, C, Topic}, Req) ->
    Signal = Req#{in_reply_to => undefined, timestamp => os:system_time(millisecond),
                  seq => undefined, epoch => undefined},
    mqtt_client:publish_async(C, Topic, bil:encode_signal(Signal), #{qos => 1}).

%% Matches a message with the open request it answers: `{ok | error,
%% Sched, A}' (error for an error signal or EVATAR's Timeout feedback), or
%% `ignore'.
answer({agent_bridge, C, {signal, Signal}}, #a{conn = {evatar, C}} = A) ->
    settle(Signal, A);
answer({agent_bridge, C, {closed, Why}}, #a{conn = {evatar, C}}) ->
    exit({agent_closed, Why});
answer({mqtt_client, C, {publish, #{payload := Payload}}}, #a{conn = {mqtt, C, _}} = A) ->
    case bil:parse_signal(Payload) of
        {ok, Signal} -> settle(Signal, A);
        {error, _} -> ignore
    end;
answer({mqtt_client, C, {disconnected, Why}}, #a{conn = {mqtt, C, _}}) ->
    exit({agent_disconnected, Why});
answer(_, _A) ->
    ignore.

settle(#{in_reply_to := <<"q", N/binary>>, context := Ctx, body := #{category := Cat}},
       #a{inflight = F} = A) ->
    case maps:take(binary_to_integer(N), F) of
        {Sched, F1} ->
            case {Ctx, Cat} of
                {feedback, <<"EVATAR">>} -> {error, Sched, A#a{inflight = F1, errors = A#a.errors + 1}};
                {feedback, _} -> {ok, Sched, A#a{inflight = F1}};
                _ -> {error, Sched, A#a{inflight = F1, errors = A#a.errors + 1}}
            end;
        error ->
            ignore
    end;
settle(_, _A) ->
    ignore.

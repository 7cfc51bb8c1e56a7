%% @doc Internal to the broker comparison (broker_bench): the load
%% generator, the same design for every system. N pairs of (agent,
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
%%   client library would through EVATAR;
%% - through nats-server, with NATS request-reply (broker_bench_nats): the
%%   device subscribes to `bench.I.req'; the agent subscribes to its inbox
%%   `_INBOX.bench.I' and publishes the same encoded request on
%%   `bench.I.req' with the inbox as reply subject; the device publishes
%%   the encoded Feedback to the reply subject. Core NATS acknowledges
%%   nothing (at most once), where MQTT QoS 1 acknowledges every publish
%%   and EVATAR's bridge protocol acknowledges every signal.
%%
%% Over TLS (the sut's `tls' is not false) both clients check the server's
%% certificate against the sut's CA, with TLS 1.3 or 1.2.
%%
%% The agent counts a round trip when the answer to its request arrives;
%% its closed and open loops are bench_requester's, as in evatar_bench_gen.
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
-type conn() :: {evatar, pid()} | {mqtt, pid(), binary()}
              | {nats, broker_bench_nats:conn(), binary(), binary()}.

connect(#{system := evatar, host := Ip, port := Port, tls := Tls}, I, Role) ->
    {VaDesc, AvDesc} = evatar_bench_gen:descriptions(I, <<"bench">>),
    Desc = case Role of agent -> VaDesc; avatar -> AvDesc end,
    #{entity_id := Entity} = Desc,
    #{agent_credential := AgCred, avatar_credential := AvCred} = evatar_bench_gen:credentials(),
    Cred = case Role of agent -> AgCred; avatar -> AvCred end,
    {ok, C} = agent_bridge_client:connect(
                [{Ip, Port}], #{pairing => <<"bench-", (integer_to_binary(I))/binary>>,
                                role => Role, entity_id => Entity, credential => Cred,
                                tls => Tls}),
    ok = agent_bridge_client:describe(C, Desc),
    {evatar, C};
connect(#{system := nats, host := Ip, port := Port}, I, Role) ->
    Req = <<"bench.", (integer_to_binary(I))/binary, ".req">>,
    Inbox = <<"_INBOX.bench.", (integer_to_binary(I))/binary>>,
    {ok, C} = broker_bench_nats:connect(Ip, Port, ?SETUP_TIMEOUT),
    ok = broker_bench_nats:subscribe(C, case Role of agent -> Inbox; avatar -> Req end, 1),
    {nats, C, Req, Inbox};
connect(#{host := Ip, port := Port, tls := Tls}, I, Role) ->
    Prefix = <<"bench/", (integer_to_binary(I))/binary, "/">>,
    {Name, Sub, Pub} = case Role of
                           agent -> {<<"agent-">>, <<"resp">>, <<"req">>};
                           avatar -> {<<"device-">>, <<"req">>, <<"resp">>}
                       end,
    {ok, C} = mqtt_client:start_link(#{host => Ip, port => Port, protocol => v311,
                                       client_id => <<Name/binary, (integer_to_binary(I))/binary>>,
                                       clean_start => true, keepalive => 300,
                                       reconnect => false, tls => mqtt_tls(Tls)}),
    ok = mqtt_client:await_connected(C, ?SETUP_TIMEOUT),
    {ok, [1]} = mqtt_client:subscribe(C, [{<<Prefix/binary, Sub/binary>>, 1}], ?SETUP_TIMEOUT),
    {mqtt, C, <<Prefix/binary, Pub/binary>>}.

%% The same checks as agent_bridge_client's over TLS.
mqtt_tls(false) ->
    false;
mqtt_tls(#{cacertfile := Ca}) ->
    [{verify, verify_peer}, {cacertfile, Ca}, {versions, ['tlsv1.3', 'tlsv1.2']}].

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
await_bound(_) ->
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
            ok = answer_encoded(Payload, fun(Fb) ->
                                                 mqtt_client:publish_async(C, Topic, Fb, #{qos => 1})
                                         end),
            device_loop(Conn);
        {'DOWN', _, process, _, _} ->
            exit(normal);
        _Other ->
            device_loop(Conn)
    end;
device_loop({nats, C, _, _} = Conn) ->
    receive
        {nats, C, {msg, _, Reply, Payload}} when is_binary(Reply) ->
            ok = answer_encoded(Payload, fun(Fb) ->
                                                 broker_bench_nats:publish(C, Reply, undefined, Fb)
                                         end),
            device_loop(Conn);
        {nats, C, {closed, _}} ->
            exit(normal);
        {'DOWN', _, process, _, _} ->
            exit(normal);
        _Other ->
            device_loop(Conn)
    end.

%% A broker's device: parses the request and publishes the encoded Feedback.
answer_encoded(Payload, Publish) ->
    case bil:parse_signal(Payload) of
        {ok, #{context := request} = Req} ->
            Fb = (feedback(Req))#{timestamp => os:system_time(millisecond),
                                  seq => undefined, epoch => undefined},
            ok = Publish(bil:encode_signal(Fb));
        _ ->
            ok
    end.

feedback(#{id := Id, sender := S, receiver := R}) ->
    #{context => feedback, id => <<"fb-", Id/binary>>, in_reply_to => Id,
      sender => R, receiver => S, body => evatar_bench_gen:feedback_body()}.

%% ---------------------------------------------------------------------------
%% The agent: bench_requester over this connection
%% ---------------------------------------------------------------------------

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
    bench_requester:run(#{parent => Parent, index => I,
                          send => fun(K) -> send(Conn, K) end,
                          answer => fun(Msg) -> answer(Msg, Conn) end}).

-spec send(conn(), pos_integer()) -> ok.
send(Conn, K) ->
    Req = #{context => request, id => <<"q", (integer_to_binary(K))/binary>>,
            sender => ?VA_COMPONENT, receiver => ?AV_COMPONENT,
            body => evatar_bench_gen:request_body()},
    Signal = fun() -> Req#{in_reply_to => undefined, timestamp => os:system_time(millisecond),
                           seq => undefined, epoch => undefined}
             end,
    case Conn of
        {evatar, C} ->
            agent_bridge_client:send(C, Req);
        {mqtt, C, Topic} ->
            mqtt_client:publish_async(C, Topic, bil:encode_signal(Signal()), #{qos => 1});
        {nats, C, Subject, Inbox} ->
            broker_bench_nats:publish(C, Subject, Inbox, bil:encode_signal(Signal()))
    end.

%% Which request a message answers, and how (see bench_requester).
-spec answer(term(), conn()) -> {pos_integer(), ok | error | timeout} | ignore.
answer({agent_bridge, C, {signal, Signal}}, {evatar, C}) ->
    evatar_bench_gen:answer_kind(Signal);
answer({agent_bridge, C, {closed, Why}}, {evatar, C}) ->
    exit({agent_closed, Why});
answer({mqtt_client, C, {publish, #{payload := Payload}}}, {mqtt, C, _}) ->
    case bil:parse_signal(Payload) of
        {ok, Signal} -> evatar_bench_gen:answer_kind(Signal);
        {error, _} -> ignore
    end;
answer({mqtt_client, C, {disconnected, Why}}, {mqtt, C, _}) ->
    exit({agent_disconnected, Why});
answer({nats, C, {msg, _, _, Payload}}, {nats, C, _, _}) ->
    case bil:parse_signal(Payload) of
        {ok, Signal} -> evatar_bench_gen:answer_kind(Signal);
        {error, _} -> ignore
    end;
answer({nats, C, {closed, Why}}, {nats, C, _, _}) ->
    exit({agent_closed, Why});
answer(_, _Conn) ->
    ignore.

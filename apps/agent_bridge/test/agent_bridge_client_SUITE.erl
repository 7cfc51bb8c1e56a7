%% Common Test suite of the Erlang client's lifecycle (agent_bridge_client)
%% against a real node over real TCP: close twice, close during the TCP
%% connect and during the handshake (a listener that never answers, one that
%% answers late), refused connects in a loop that leave no process or port
%% behind (counted in a node of their own), reconnecting with the same
%% EntityID right after close, connect on a connected client, and the
%% accepted-signal notices of notify_acks.
-module(agent_bridge_client_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").
-import(evatar_test_wait, [until/1]).

-compile([export_all, nowarn_export_all]).

-define(VA_CRED, evatar_test_fixtures:va_credential()).
-define(AV_CRED, evatar_test_fixtures:avatar_credential()).

suite() -> [{timetrap, {seconds, 120}}].

all() ->
    [close_twice, close_before_connect, close_during_tcp_connect,
     close_during_silent_handshake, close_during_late_welcome, close_during_reconnect,
     connect_connected_client,
     refused_loop_leaves_nothing, reconnect_same_id_after_close,
     reconnect_same_id_after_close_ha, accepted_signals_notified, bad_signal_keeps_session,
     bad_signal_keeps_session_ha].

%% ---------------------------------------------------------------------------
%% Setup
%% ---------------------------------------------------------------------------

init_per_suite(Config) ->
    ok = evatar_test_node:start([]),
    %% Refusals without delay or lockout, and no handshake rate: the loops
    %% below make hundreds of handshakes from 127.0.0.1 in seconds.
    Addr = evatar_test_node:listen(client_lifecycle,
                                         #{handshake => #{rate => infinity, failure_delay => 0,
                                                          max_failures => 1000000}}),
    [{addr, Addr} | Config].

end_per_suite(_Config) ->
    evatar_test_node:stop([client_lifecycle], [agent_bridge]).

init_per_testcase(Case, Config) ->
    Pairing = atom_to_binary(Case),
    {ok, _} = evatar_test_fixtures:create_pairing(Pairing, #{}),
    [{pairing, Pairing} | Config].

end_per_testcase(_Case, Config) ->
    _ = evatar:delete_pairing(?config(pairing, Config)),
    ok.

%% ---------------------------------------------------------------------------
%% Cases
%% ---------------------------------------------------------------------------

%% close/1 twice returns ok both times; the owner hears {closed, normal} once
%% and the process is gone after the first.
close_twice(Config) ->
    {ok, C} = client(Config, <<"va">>),
    ok = agent_bridge_client:close(C),
    false = is_process_alive(C),
    ok = agent_bridge_client:close(C),
    receive {agent_bridge, C, {closed, normal}} -> ok after evatar_test_time:guard() -> ct:fail(no_closed) end,
    %% C is gone: whatever it sent is here already.
    ok = evatar_test_wait:gone(C),
    [] = evatar_test_wait:mailbox(fun(M) -> is_tuple(M) andalso tuple_size(M) =:= 3
                                             andalso element(1, M) =:= agent_bridge
                                             andalso element(2, M) =:= C end),
    {error, closed} = agent_bridge_client:send(C, light_request()).

%% A client made by start/2 and closed before connecting stops; connect/1
%% then fails with closed.
close_before_connect(Config) ->
    {ok, C} = agent_bridge_client:start([?config(addr, Config)], opts(Config, <<"va">>)),
    ok = agent_bridge_client:close(C),
    false = is_process_alive(C),
    {error, closed} = agent_bridge_client:connect(C).

%% close/1 while the TCP connect waits (a listener whose accept queue is
%% full drops the SYN): the connect/1 caller gets {error, closed}, the
%% helper process and its socket are gone.
close_during_tcp_connect(_Config) ->
    {ok, L} = gen_tcp:listen(0, [{ip, {127, 0, 0, 1}}, {backlog, 1}, {active, false}]),
    {ok, Port} = inet:port(L),
    Fillers = fill_backlog(Port, []),
    Opts = (opts([{pairing, <<"p">>}], <<"va">>))#{connect_timeout => infinity},
    {ok, C} = agent_bridge_client:start([{{127, 0, 0, 1}, Port}], Opts),
    Caller = connect_async(C),
    ok = until(fun() -> connectors() =/= [] end),
    [Helper] = connectors(),
    connecting = state(C),
    ok = agent_bridge_client:close(C),
    {error, closed} = connect_result(Caller),
    false = is_process_alive(C),
    false = is_process_alive(Helper),
    [gen_tcp:close(S) || S <- Fillers],
    ok = gen_tcp:close(L).

%% close/1 while the server accepted and never answers the Hello: the
%% connect/1 caller gets {error, closed} and the server sees the socket
%% closed.
close_during_silent_handshake(_Config) ->
    {Port, Server} = fake_server(silent),
    Opts = (opts([{pairing, <<"p">>}], <<"va">>))#{handshake_timeout => infinity},
    {ok, C} = agent_bridge_client:start([{{127, 0, 0, 1}, Port}], Opts),
    Caller = connect_async(C),
    receive {Server, hello} -> ok after evatar_test_time:guard() -> ct:fail(no_hello) end,
    handshaking = state(C),
    ok = agent_bridge_client:close(C),
    {error, closed} = connect_result(Caller),
    receive {Server, peer_closed} -> ok after evatar_test_time:guard() -> ct:fail(socket_left_open) end.

%% close/1 while the Welcome is on its way (the server sends it after the
%% client was told to close): the client stays closed and the late Welcome
%% is dropped with the socket.
close_during_late_welcome(Config) ->
    {Port, Server} = fake_server({late_welcome, ?config(pairing, Config)}),
    {ok, C} = agent_bridge_client:start([{{127, 0, 0, 1}, Port}], opts(Config, <<"va">>)),
    Caller = connect_async(C),
    receive {Server, hello} -> ok after evatar_test_time:guard() -> ct:fail(no_hello) end,
    ok = agent_bridge_client:close(C),
    Server ! welcome,
    {error, closed} = connect_result(Caller),
    receive {Server, peer_closed} -> ok after evatar_test_time:guard() -> ct:fail(socket_left_open) end,
    false = is_process_alive(C),
    ok = evatar_test_wait:gone(C),
    [] = evatar_test_wait:mailbox(fun(M) -> is_tuple(M) andalso tuple_size(M) =:= 3
                                             andalso element(1, M) =:= agent_bridge
                                             andalso element(2, M) =:= C end).

%% With ha, close/1 while the client reconnects on its own and waits in a
%% handshake that never ends (its pairing went, and the next endpoint
%% accepts and stays silent): the client stops, the owner hears {closed,
%% normal} and the silent server sees the socket closed.
close_during_reconnect(Config) ->
    {Port, Server} = fake_server(silent),
    {ok, C} = agent_bridge_client:connect([?config(addr, Config), {{127, 0, 0, 1}, Port}],
                                          (opts(Config, <<"va">>))#{ha => true,
                                                                    handshake_timeout => infinity}),
    exit(evatar_registry:whereis_name(?config(pairing, Config)), kill),
    receive {Server, hello} -> ok after evatar_test_time:guard() -> ct:fail(no_reconnect) end,
    handshaking = state(C),
    ok = agent_bridge_client:close(C),
    false = is_process_alive(C),
    receive {agent_bridge, C, {closed, normal}} -> ok after evatar_test_time:guard() -> ct:fail(no_closed) end,
    receive {Server, peer_closed} -> ok after evatar_test_time:guard() -> ct:fail(socket_left_open) end.

%% connect/1 on a connected client fails locally with already_connected, and
%% while another process connects it with connecting; the session is not
%% disturbed.
connect_connected_client(Config) ->
    {ok, C} = client(Config, <<"va">>),
    {ok, #{session_id := Sid}} = agent_bridge_client:session(C),
    {error, already_connected} = agent_bridge_client:connect(C),
    {ok, #{session_id := Sid}} = agent_bridge_client:session(C),
    ok = agent_bridge_client:close(C),
    {Port, Server} = fake_server(silent),
    {ok, C2} = agent_bridge_client:start([{{127, 0, 0, 1}, Port}],
                                         (opts(Config, <<"va">>))#{handshake_timeout => infinity}),
    Caller = connect_async(C2),
    receive {Server, hello} -> ok after evatar_test_time:guard() -> ct:fail(no_hello) end,
    {error, connecting} = agent_bridge_client:connect(C2),
    ok = agent_bridge_client:close(C2),
    {error, closed} = connect_result(Caller).

%% 100 connects with a wrong credential, in a node of their own: each is
%% refused BadCredential, and the node's processes and ports come back to
%% what they were (no client, helper or socket left behind).
refused_loop_leaves_nothing(Config) ->
    Paths = lists:append([["-pa", P] || P <- code:get_path(),
                                        not lists:prefix(code:lib_dir(), P)]),
    {ok, Peer, _} = peer:start(#{connection => standard_io, args => Paths}),
    try
        {Before, After, Codes} = peer:call(Peer, ?MODULE, refused_loop,
                                           [?config(addr, Config), ?config(pairing, Config), 100],
                                           60000),
        [<<"BadCredential">>] = lists:usort(Codes),
        100 = length(Codes),
        ?assertEqual(Before, After)
    after
        peer:stop(Peer)
    end.

%% @private Runs in the peer: {Counts before, counts after, refusal codes}.
refused_loop(Addr, Pairing, N) ->
    {ok, _} = application:ensure_all_started(ssl),
    Opts = #{pairing => Pairing, role => agent, entity_id => <<"va">>, credential => <<"wrong">>},
    %% One round first, so the code and the tables it loads are counted.
    {error, {refused, _, _}} = agent_bridge_client:connect([Addr], Opts),
    Before = counts(),
    Codes = [begin
                 {error, {refused, Code, _}} = agent_bridge_client:connect([Addr], Opts),
                 Code
             end || _ <- lists:seq(1, N)],
    %% connect/2 returns once the client is gone; wait anyway, in case.
    ok = until(fun() ->
                                        case counts() of
                                            Before -> true;
                                            Now -> {false, #{before => Before, now => Now}}
                                        end
                                end),
    {Before, counts(), Codes}.

counts() ->
    {erlang:system_info(process_count), length(erlang:ports())}.

%% 50 close/connect cycles with the same EntityID in a tight loop: none is
%% refused EntityExists, because close/1 waits for EVATAR's Bye.
reconnect_same_id_after_close(Config) ->
    cycles(Config, #{}, 50).

%% The same with protocol version 2.
reconnect_same_id_after_close_ha(Config) ->
    cycles(Config, #{ha => true}, 50).

%% With notify_acks, the owner learns which signals EVATAR accepted, by
%% SignalID, each once.
accepted_signals_notified(Config) ->
    {ok, Av} = agent_bridge_client:connect([?config(addr, Config)],
                                           (opts(Config, avatar, <<"av">>))#{ha => true,
                                                                             notify_acks => true}),
    ok = agent_bridge_client:describe(Av, avatar_description(<<"av">>)),
    {ok, Va} = client(Config, <<"va">>),
    ok = agent_bridge_client:describe(Va, va_description(<<"va">>)),
    _ = evatar_test_fixtures:wait_binding(Va, fun(#{bound := B}) -> B =/= [] end, evatar_test_time:guard()),
    Ids = [begin
               Id = <<"reading-", (integer_to_binary(I))/binary>>,
               ok = agent_bridge_client:send(Av, (sensor(I))#{id => Id}),
               Id
           end || I <- lists:seq(1, 20)],
    ok = agent_bridge_client:await_acks(Av, evatar_test_time:guard()),
    Ids = accepted(Av, length(Ids), []),
    ok = agent_bridge_client:close(Va),
    ok = agent_bridge_client:close(Av).

%% A signal that cannot be encoded (no body, a receiver that is not a
%% binary, a parameter name that is not an XML name, not a map) is the
%% caller's {error, {bad_signal, _}}; the client and its session go on.
bad_signal_keeps_session(Config) ->
    bad_signals(Config, #{}).

%% The same with protocol version 2 (the signal would be kept for resending).
bad_signal_keeps_session_ha(Config) ->
    bad_signals(Config, #{ha => true}).

bad_signals(Config, Extra) ->
    {ok, C} = agent_bridge_client:connect([?config(addr, Config)],
                                          maps:merge(opts(Config, <<"va">>), Extra)),
    {ok, #{session_id := Sid}} = agent_bridge_client:session(C),
    Good = light_request(),
    Bad = [maps:remove(body, Good), Good#{receiver => 42},
           Good#{body => (maps:get(body, Good))#{parameters => [{<<"bad name">>, <<"v">>}]}}],
    [{error, {bad_signal, _}} = agent_bridge_client:send(C, B) || B <- Bad],
    {error, {bad_signal, _}} = agent_bridge_client:send(C, not_a_map),
    {error, {bad_signal, _}} = agent_bridge_client:request(C, hd(Bad), evatar_test_time:guard()),
    {ok, #{session_id := Sid}} = agent_bridge_client:session(C),
    ok = agent_bridge_client:send(C, Good),
    ok = agent_bridge_client:close(C).

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

opts(Config, Entity) -> opts(Config, agent, Entity).

opts(Config, Role, Entity) ->
    #{pairing => ?config(pairing, Config), role => Role, entity_id => Entity,
      credential => case Role of agent -> ?VA_CRED; avatar -> ?AV_CRED end}.

client(Config, Entity) ->
    agent_bridge_client:connect([?config(addr, Config)], opts(Config, Entity)).

cycles(Config, Extra, N) ->
    Results = [begin
                   R = agent_bridge_client:connect([?config(addr, Config)],
                                                   maps:merge(opts(Config, <<"va">>), Extra)),
                   case R of
                       {ok, C} -> ok = agent_bridge_client:close(C), ok;
                       {error, _} = Error -> Error
                   end
               end || _ <- lists:seq(1, N)],
    ?assertEqual([], [R || R <- Results, R =/= ok]).

accepted(_C, 0, Acc) ->
    lists:reverse(Acc);
accepted(C, N, Acc) ->
    receive
        {agent_bridge, C, {accepted, Ids}} ->
            accepted(C, N - length(Ids), lists:reverse(Ids, Acc))
    after evatar_test_time:guard() -> ct:fail({accepted_missing, N, lists:reverse(Acc)})
    end.

connect_async(C) ->
    Self = self(),
    spawn_link(fun() -> Self ! {connect_result, self(), agent_bridge_client:connect(C)} end).

connect_result(Caller) ->
    receive {connect_result, Caller, R} -> R after evatar_test_time:guard() -> ct:fail(connect_did_not_return) end.

state(C) ->
    {State, _} = sys:get_state(C),
    State.

%% The clients' helper processes that are making a TCP connection.
connectors() ->
    [P || P <- processes(),
          case process_info(P, current_stacktrace) of
              {current_stacktrace, Stack} ->
                  lists:keymember(connector, 2, [{M, F} || {M, F, _, _} <- Stack,
                                                           M =:= agent_bridge_client]);
              undefined ->
                  false
          end].

%% Connects to Port until the listener's accept queue is full (as the
%% kernel counts it), so that the next SYN is dropped. (Stopping at the
%% first connect that took over 300 ms stopped early when a loaded machine
%% was that slow with a queue not full: the client then connected at once.)
fill_backlog(Port, Acc) when length(Acc) < 64 ->
    case accept_queue_full(Port) of
        true ->
            Acc;
        false ->
            case gen_tcp:connect({127, 0, 0, 1}, Port, [{active, false}], 1000) of
                {ok, S} -> fill_backlog(Port, [S | Acc]);
                {error, timeout} -> fill_backlog(Port, Acc)
            end
    end.

%% Whether the accept queue of the listener on 127.0.0.1:Port is full: for
%% a listening socket /proc/net/tcp shows the queue's length as rx_queue,
%% and Linux drops SYNs once it exceeds the backlog (1 here).
accept_queue_full(Port) ->
    {ok, Table} = file:read_file("/proc/net/tcp"),
    Local = iolist_to_binary(io_lib:format("0100007F:~4.16.0B", [Port])),
    [Queue] = [binary_to_integer(Rx, 16)
               || Row <- binary:split(Table, <<"\n">>, [global, trim_all]),
                  [_, L, _, <<"0A">>, TxRx | _] <- [binary:split(Row, <<" ">>, [global, trim_all])],
                  L =:= Local, [_, Rx] <- [binary:split(TxRx, <<":">>)]],
    Queue > 1.

%% A listener of one connection: it reads the Hello and tells the test
%% process, then stays silent, or sends a Welcome when told to; either way
%% it tells when the client closed the socket.
fake_server(Mode) ->
    Self = self(),
    Pid = spawn_link(fun() ->
                             {ok, L} = gen_tcp:listen(0, [binary, {packet, 4}, {active, false},
                                                          {ip, {127, 0, 0, 1}}]),
                             {ok, Port} = inet:port(L),
                             Self ! {self(), port, Port},
                             {ok, S} = gen_tcp:accept(L),
                             {ok, _Hello} = gen_tcp:recv(S, 0),
                             Self ! {self(), hello},
                             case Mode of
                                 silent -> ok;
                                 {late_welcome, Pairing} ->
                                     receive welcome -> ok end,
                                     _ = gen_tcp:send(S, welcome(Pairing))
                             end,
                             {error, closed} = gen_tcp:recv(S, 0),
                             Self ! {self(), peer_closed}
                     end),
    receive {Pid, port, Port} -> {Port, Pid} after evatar_test_time:guard() -> ct:fail(no_fake_server) end.

welcome(Pairing) ->
    bil_control:encode({welcome, #{pairing => Pairing, entity_id => <<"va">>,
                                   session_id => binary:copy(<<"a">>, 32),
                                   max_frame => 1048576, join_timeout => 2000}}).


light_request() ->
    #{sender => <<"LightEmulator01">>, receiver => <<"Light01">>,
      body => #{category => <<"ACTUATOR">>, type => <<"TurnLightOn">>, parameters => []}}.

sensor(I) ->
    #{context => sensor_data, sender => <<"Thermo01">>, receiver => <<"ThermoEmulator01">>,
      body => #{category => <<"SENSOR">>, type => <<"Temperature">>,
                parameters => [{<<"N">>, integer_to_binary(I)}]}}.

entry(Cat, Type) -> #{category => Cat, type => Type, parameters => []}.

va_description(Id) ->
    #{entity_id => Id, api_name => <<"TEST VA">>, entity_type => agent,
      context => <<"EmulatorDescription">>,
      components => [#{id => <<"ThermoEmulator01">>,
                       services => [entry(<<"SENSOR">>, <<"Temperature">>)],
                       consumes => []}]}.

avatar_description(Id) ->
    #{entity_id => Id, api_name => <<"TEST AVATAR">>, entity_type => avatar,
      context => <<"ActuatorDescription">>,
      components => [#{id => <<"Thermo01">>, services => [entry(<<"SENSOR">>, <<"Reading">>)],
                       consumes => [entry(<<"SENSOR">>, <<"Temperature">>)]}]}.

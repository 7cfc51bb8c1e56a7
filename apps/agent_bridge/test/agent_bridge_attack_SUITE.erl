%% Common Test suite of attacks on a real EVATAR node over real sockets
%% (issue 15, section 4; docs/protocol.md section 7): the node is an OS
%% process of its own (OTP `peer', controlled over its standard I/O) whose
%% file descriptor limit is 256 (`ulimit -n'), with a bystander pairing
%% whose VA and Avatar keep doing round trips through every attack. Each
%% case asserts what the node answers the attacker, counted on the
%% attacker's sockets, and that the node and the bystander survive.
-module(agent_bridge_attack_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").
-import(evatar_test_wait, [until/1]).

-compile([export_all, nowarn_export_all]).

-define(FD_LIMIT, 256).
-define(BAD, <<"guess">>).

suite() -> [{timetrap, {seconds, 120}}].

all() ->
    [connection_flood, handshake_rate, wrong_credential_flood, slow_consumer_closed,
     idle_v1_session, idle_v1_keepalive, long_id_hello].

%% ---------------------------------------------------------------------------
%% Setup: one node, one listener per attack (each with the limit it shows)
%% ---------------------------------------------------------------------------

init_per_suite(Config) ->
    Paths = lists:append([["-pa", P] || P <- code:get_path(),
                                        not lists:prefix(code:lib_dir(), P)]),
    Erl = os:find_executable("erl"),
    %% The node's own descriptor limit, low enough that a flood would
    %% exhaust it if a listener had no connection limit.
    Sh = "ulimit -n " ++ integer_to_list(?FD_LIMIT) ++ " && exec \"$0\" \"$@\"",
    {ok, Peer, _} = peer:start(#{connection => standard_io,
                                 exec => {"/bin/sh", ["-c", Sh, Erl]},
                                 args => ["-kernel", "logger_level", "info" | Paths]}),
    Log = filename:join(?config(priv_dir, Config), "node.log"),
    ok = call(Peer, ?MODULE, node_setup, [Log]),
    OsPid = call(Peer, os, getpid, []),
    Listeners =
        #{flood => #{max_connections => 50, handshake => #{rate => infinity},
                     %% idle sockets hold their slots for the whole case
                     conn => #{handshake_timeout => 60000}},
          rate => #{handshake => #{rate => 1, burst => 10}, conn => #{handshake_timeout => 60000}},
          creds => #{handshake => #{rate => infinity, failure_delay => 20,
                                    max_failure_delay => 200, max_failures => 10,
                                    lockout => 600000}},
          slow => #{conn => #{max_out_frames => 50, max_out_bytes => 65536}},
          idle => #{conn => #{idle_timeout => evatar_test_time:ms(300)}},
          idle_slow => #{conn => #{idle_timeout => evatar_test_time:ms(2000)}},
          main => #{}},
    Addrs = maps:map(fun(Name, Opts) -> call(Peer, ?MODULE, listen, [Name, Opts]) end, Listeners),
    Bystander = start_bystander(Peer, maps:get(main, Addrs)),
    [{peer, Peer}, {os_pid, OsPid}, {log, Log}, {addrs, Addrs}, {bystander, Bystander}
     | Config].

end_per_suite(Config) ->
    {_, _, Holder} = ?config(bystander, Config),
    exit(Holder, kill),
    peer:stop(?config(peer, Config)).

init_per_testcase(Case, Config) ->
    Pairing = atom_to_binary(Case),
    {ok, _} = call(?config(peer, Config), evatar_test_fixtures, create_pairing, [Pairing, #{}]),
    [{pairing, Pairing} | Config].

end_per_testcase(_Case, Config) ->
    _ = call(?config(peer, Config), evatar, delete_pairing, [?config(pairing, Config)]),
    %% Every attack leaves the node serving the bystander's session.
    ok = bystander_round_trip(Config).

%% @private Runs on the node: logs at info to File, starts the bridge.
node_setup(File) ->
    ok = logger:set_primary_config(level, info),
    ok = logger:remove_handler(default),
    ok = logger:add_handler(file, logger_std_h,
                            #{config => #{file => File},
                              filters => [{progress, {fun logger_filters:progress/2, stop}}],
                              formatter => {logger_formatter,
                                            #{single_line => true,
                                              template => [time, " ", level, " ", pid, " ",
                                                           msg, "\n"]}}}),
    evatar_test_node:start([]).

%% @private Runs on the node: a listener on 127.0.0.1 at a free port.
listen(Name, Opts) ->
    evatar_test_node:listen(Name, Opts#{ip => {127, 0, 0, 1}}).

%% ---------------------------------------------------------------------------
%% Attacks
%% ---------------------------------------------------------------------------

%% 600 idle sockets on a listener with max_connections 50, from a node
%% allowed 256 descriptors: 50 are held, every other one gets Refused
%% TooManyConnections and is closed; the node's descriptors stay well
%% under its limit, an existing session works throughout, and once the
%% flood goes a new client joins.
connection_flood(Config) ->
    Addr = addr(flood, Config),
    {ok, Va} = agent_bridge_client:connect([Addr], client_opts(Config, agent, <<"va">>)),
    ok = agent_bridge_client:describe(Va, agent_bridge_SUITE:va_description(<<"va">>)),
    FdsBefore = fds(Config),
    Socks = [raw_connect(Addr, []) || _ <- lists:seq(1, 600)],
    Answers = answers(Socks),
    Refused = length([A || A <- Answers, A =:= <<"TooManyConnections">>]),
    Open = length([A || A <- Answers, A =:= open]),
    FdsDuring = fds(Config),
    ct:log("flood of 600: ~b held open, ~b refused TooManyConnections; node fds ~b before, "
           "~b during (limit ~b)", [Open, Refused, FdsBefore, FdsDuring, ?FD_LIMIT]),
    %% The VA holds one of the 50 slots.
    ?assertEqual(49, Open),
    ?assertEqual(600 - 49, Refused),
    ?assert(FdsDuring < ?FD_LIMIT - 64),
    #{connections := 50} = guard_info(flood, Config),
    ok = bystander_round_trip(Config),
    {ok, _} = agent_bridge_client:session(Va),
    [ok = gen_tcp:close(S) || S <- Socks],
    ok = until(fun() -> maps:get(connections, guard_info(flood, Config)) =:= 1 end),
    {ok, Av} = agent_bridge_client:connect([Addr], client_opts(Config, avatar, <<"av">>)),
    ok = agent_bridge_client:close(Av),
    ok = agent_bridge_client:close(Va),
    %% The node never ran out of descriptors.
    ?assertEqual(nomatch, binary:match(read_log(Config), <<"accept_failed">>)).

%% 40 connections at once from one address to a listener allowing 10 at
%% once and 1 per second after: the first 10 are served, and later ones
%% get Refused RateLimited at once; another address is not affected.
handshake_rate(Config) ->
    Addr = addr(rate, Config),
    Socks = [raw_connect(Addr, []) || _ <- lists:seq(1, 40)],
    %% After the flood; its answer is read with theirs (an open socket is
    %% one that gets nothing for 10 s: one wait for all).
    S2 = raw_connect(Addr, [{ip, {127, 0, 0, 2}}]),
    [Other | Answers] = answers([S2 | Socks]),
    Open = length([A || A <- Answers, A =:= open]),
    Limited = length([A || A <- Answers, A =:= <<"RateLimited">>]),
    ct:log("40 connections from one address: ~b served, ~b RateLimited", [Open, Limited]),
    ?assert(Open >= 10),
    ?assert(Limited >= 1),
    ?assertEqual(40, Open + Limited),
    ?assertEqual(open, Other),
    [gen_tcp:close(S) || S <- [S2 | Socks]],
    ok.

%% 200 wrong credentials at once from one address: 9 are answered
%% BadCredential, the 10th locks the address out (max_failures), and every
%% other one, under way or later, is answered LockedOut (later ones before
%% any Hello, even with the right credential); another address still joins.
wrong_credential_flood(Config) ->
    Addr = addr(creds, Config),
    Self = self(),
    Pids = [spawn_link(fun() -> Self ! {answer, self(), wrong_hello(Addr, Config)} end)
            || _ <- lists:seq(1, 200)],
    Answers = [receive {answer, P, A} -> A after evatar_test_time:guard() -> ct:fail(no_answer) end || P <- Pids],
    Bad = length([A || A <- Answers, A =:= <<"BadCredential">>]),
    Locked = length([A || A <- Answers, A =:= <<"LockedOut">>]),
    ct:log("200 wrong credentials at once: ~b BadCredential, ~b LockedOut, others ~p",
           [Bad, Locked, [A || A <- Answers, A =/= <<"BadCredential">>, A =/= <<"LockedOut">>]]),
    ?assertEqual(200, Bad + Locked),
    %% The 10th failure starts the lockout; from then on every handshake
    %% under way is answered LockedOut, so only 9 verdicts get out.
    ?assertEqual(9, Bad),
    %% Sequential attempts now: every one refused at once, none checked.
    Later = [wrong_hello(Addr, Config) || _ <- lists:seq(1, 50)],
    ?assertEqual([<<"LockedOut">>], lists:usort(Later)),
    {error, {refused, <<"LockedOut">>, _}} =
        agent_bridge_client:connect([Addr], client_opts(Config, agent, <<"va">>)),
    %% Another address is not locked out.
    S = raw_connect(Addr, [{ip, {127, 0, 0, 3}}]),
    ok = gen_tcp:send(S, hello(Config, agent, <<"va">>, evatar_test_fixtures:va_credential())),
    {control, {welcome, _}} = recv_doc(S),
    ok = gen_tcp:close(S),
    %% The lockout was logged once, the refusals in summaries.
    Log = read_log(Config),
    ?assertEqual(1, length(binary:matches(Log, <<"address_locked_out">>))),
    Lines = length(binary:matches(Log, <<"handshake_refused">>)),
    ct:log("log lines handshake_refused so far: ~b", [Lines]),
    ?assert(Lines < 50).

%% A VA that never reads while signals pile up for it: the node drops it
%% as a slow consumer and resets its socket at once, so the client's
%% connection is closed without the client reading anything.
slow_consumer_closed(Config) ->
    Addr = addr(slow, Config),
    S = raw_connect(Addr, [{recbuf, 4096}]),
    ok = gen_tcp:send(S, hello(Config, agent, <<"va">>, evatar_test_fixtures:va_credential())),
    {control, {welcome, _}} = recv_doc(S),
    ok = gen_tcp:send(S, bil:encode_description(agent_bridge_SUITE:va_description(<<"va">>))),
    %% The Avatar comes through a listener with the default queue bounds:
    %% it reads, and must not be dropped itself.
    {ok, Av} = agent_bridge_client:connect([addr(main, Config)],
                                           client_opts(Config, avatar, <<"av">>)),
    ok = agent_bridge_client:describe(Av, agent_bridge_SUITE:avatar_description(<<"av">>, false)),
    Payload = binary:copy(<<"x">>, 2000),
    Held = maps:get(connections, guard_info(slow, Config)),
    [ok = agent_bridge_client:send(Av, agent_bridge_SUITE:sensor(I, Payload))
     || I <- lists:seq(1, 3000)],
    %% The server let go of the socket: the connection count fell by one
    %% while the VA still has not read a byte.
    ok = until(fun() -> maps:get(connections, guard_info(slow, Config)) =:= Held - 1 end),
    %% ... and reset it: the client's kernel has closed the connection
    %% although the client neither read nor wrote. (A plain close would
    %% leave it established until the client read every queued byte, the
    %% server's end waiting in FIN_WAIT1 behind them.)
    {ok, {_, Port}} = inet:sockname(S),
    ok = until(fun() -> tcp_state(Port) =/= established end),
    ?assertMatch({ok, _}, agent_bridge_client:session(Av)),
    ok = agent_bridge_client:close(Av),
    gen_tcp:close(S).

%% A version 1 session with no frame either way for idle_timeout (300 ms
%% here, on evatar_test_time's scale) is closed with Refused IdleTimeout.
idle_v1_session(Config) ->
    S = joined_v1(addr(idle, Config), Config),
    ?assertMatch({control, {refused, #{code := <<"IdleTimeout">>}}}, until_not_binding(S)),
    {error, closed} = gen_tcp:recv(S, 0, evatar_test_time:guard()).

%% A version 1 client that sends an empty Ack more often than the idle
%% timeout (2 s here, on evatar_test_time's scale) keeps its session:
%% after 20 keepalives over twice the timeout its Bye is answered with a
%% Bye. The pause between keepalives is the case's subject (a tenth of the
%% timeout), not a wait for an event.
idle_v1_keepalive(Config) ->
    S = joined_v1(addr(idle_slow, Config), Config),
    Ack = bil_control:encode({ack, #{}}),
    [begin ok = gen_tcp:send(S, Ack), timer:sleep(evatar_test_time:ms(200)) end
     || _ <- lists:seq(1, 20)],
    ok = gen_tcp:send(S, bil_control:encode({bye, <<>>})),
    %% A Binding may come first (the description was accepted).
    ?assertEqual(bye, until_bye(S)).

%% A Hello with a 60,000-byte EntityID and a wrong credential: refused, and
%% the node's log grows by far less than the id (ids are cut to 64 bytes).
long_id_hello(Config) ->
    Before = byte_size(read_log(Config)),
    Id = binary:copy(<<"x">>, 60000),
    S = raw_connect(addr(main, Config), []),
    ok = gen_tcp:send(S, hello(Config, agent, Id, ?BAD)),
    {control, {refused, #{code := Code}}} = recv_doc(S),
    ct:log("refused ~s", [Code]),
    {error, closed} = gen_tcp:recv(S, 0, evatar_test_time:guard()),
    ok = until(fun() -> byte_size(read_log(Config)) > Before end),
    Log = read_log(Config),
    Grown = byte_size(Log) - Before,
    ct:log("log grew by ~b bytes:~n~s", [Grown, binary:part(Log, Before, Grown)]),
    ?assert(Grown < 2048),
    ?assertEqual(nomatch, binary:match(Log, binary:copy(<<"x">>, 100))).

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

call(Peer, M, F, A) -> peer:call(Peer, M, F, A, 30000).

addr(Name, Config) -> maps:get(Name, ?config(addrs, Config)).

guard_info(Name, Config) ->
    Peer = ?config(peer, Config),
    call(Peer, ?MODULE, node_guard_info, [Name]).

%% @private Runs on the node.
node_guard_info(Name) ->
    [LSup] = [agent_bridge_listener_keeper:listener_sup(P)
              || {{agent_bridge_listener, N}, P, _, _}
                     <- supervisor:which_children(agent_bridge_sup), N =:= Name],
    agent_bridge_guard:info(agent_bridge_listener_sup:guard(LSup)).

%% Open descriptors of the node's OS process.
fds(Config) ->
    {ok, Fds} = file:list_dir("/proc/" ++ ?config(os_pid, Config) ++ "/fd"),
    length(Fds).

%% The state of this host's TCP connection from local port Port
%% (/proc/net/tcp): established, other, or none (closed and gone).
tcp_state(Port) ->
    {ok, Table} = file:read_file("/proc/net/tcp"),
    Local = iolist_to_binary(io_lib:format(":~4.16.0B ", [Port])),
    Rows = [binary:split(Row, <<" ">>, [global, trim_all])
            || Row <- binary:split(Table, <<"\n">>, [global, trim_all])],
    case [St || [_, L, _, St | _] <- Rows, binary:match(<<L/binary, " ">>, Local) =/= nomatch] of
        [] -> none;
        [<<"01">> | _] -> established;
        [_ | _] -> other
    end.

read_log(Config) ->
    ok = call(?config(peer, Config), logger_std_h, filesync, [file]),
    {ok, Log} = file:read_file(?config(log, Config)),
    Log.

client_opts(Config, Role, Entity) ->
    agent_bridge_SUITE:client_opts(Config, Role, Entity).

hello(Config, Role, Entity, Cred) ->
    agent_bridge_SUITE:hello(Config, Role, Entity, Cred).

raw_connect({Ip, Port}, Extra) ->
    {ok, S} = gen_tcp:connect(Ip, Port, [binary, {packet, 4}, {active, false} | Extra], 10000),
    S.

recv_doc(S) -> recv_doc(S, evatar_test_time:guard()).

recv_doc(S, Timeout) ->
    {ok, Frame} = gen_tcp:recv(S, 0, Timeout),
    {ok, Doc} = bil_control:parse_frame(Frame, #{}),
    Doc.

%% refused_or_open/1 of every socket, read all at once.
answers(Socks) ->
    Self = self(),
    Pids = [spawn_link(fun() ->
                               Self ! {answer, self(), refused_or_open(S)}
                       end) || S <- Socks],
    [receive {answer, P, A} -> A after evatar_test_time:guard() -> ct:fail(no_answer) end || P <- Pids].

%% The Refused code a fresh socket got without sending anything, or `open'
%% when the server kept it (waiting for the Hello: the listeners of these
%% cases wait 60 s, so nothing comes within the 10 s of this read).
refused_or_open(S) ->
    case gen_tcp:recv(S, 0, 10000) of
        {ok, Frame} ->
            {ok, {control, {refused, #{code := Code}}}} = bil_control:parse_frame(Frame, #{}),
            Code;
        {error, timeout} ->
            open
    end.

%% One connection with a wrong credential: the Refused code it got.
wrong_hello(Addr, Config) ->
    S = raw_connect(Addr, []),
    %% Sent at once: a socket refused at accept may have its Refused
    %% already waiting, which the reply read below returns.
    _ = gen_tcp:send(S, hello(Config, agent, <<"va">>, ?BAD)),
    Code = case gen_tcp:recv(S, 0, 30000) of
               {ok, Frame} ->
                   {ok, {control, {refused, #{code := C}}}} = bil_control:parse_frame(Frame, #{}),
                   C;
               {error, Why} ->
                   Why
           end,
    ok = gen_tcp:close(S),
    Code.

joined_v1(Addr, Config) ->
    S = raw_connect(Addr, []),
    ok = gen_tcp:send(S, hello(Config, agent, <<"va">>, evatar_test_fixtures:va_credential())),
    {control, {welcome, _}} = recv_doc(S),
    ok = gen_tcp:send(S, bil:encode_description(agent_bridge_SUITE:va_description(<<"va">>))),
    S.

until_bye(S) ->
    case until_not_binding(S) of
        {control, {bye, _}} -> bye;
        Other -> Other
    end.

%% The next document that is not a Binding report.
until_not_binding(S) ->
    case recv_doc(S, 10000) of
        {control, {binding, _}} -> until_not_binding(S);
        Other -> Other
    end.


start_bystander(Peer, Addr) ->
    Pairing = <<"bystander">>,
    {ok, _} = call(Peer, evatar_test_fixtures, create_pairing, [Pairing, #{}]),
    Parent = self(),
    Holder = spawn(fun() ->
                           {Va, Av} = agent_bridge_SUITE:bound_pair([{addr, Addr},
                                                                     {pairing, Pairing}]),
                           Parent ! {bystander, Va, Av},
                           receive stop -> ok end
                   end),
    receive {bystander, Va, Av} -> {Va, Av, Holder} after evatar_test_time:guard() -> ct:fail(no_bystander) end.

bystander_round_trip(Config) ->
    agent_bridge_SUITE:bystander_round_trip(Config).

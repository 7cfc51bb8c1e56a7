%% @doc Failover benchmark of EVATAR's high availability (issue 5), on a
%% cluster of real OS-process nodes on this machine (test/evatar_test_cluster.erl).
%%
%% a. Failover time: from the fault to the first signal delivered through
%%    the new active. A pairing is active on one node with its standby on
%%    the next; its Avatar streams sensor data every 5 ms to its VA, both
%%    HA clients of the bridge knowing every node. The fault is kill -9 of
%%    the active's node, or a silent stall (SIGSTOP: its sockets stay open);
%%    the clock starts just before the signal is sent (by a shell already
%%    running, so no fork is counted) and stops when the VA's client hands
%%    over the first signal stamped with a higher epoch. p50 and p99 over
%%    `trials' trials each (nearest rank: with 50 trials p99 is the
%%    slowest but none), printed next to the targets and to the reference
%%    figures of other failure detectors.
%% b. The cost of TLS distribution: the same measurements over inet_tcp and
%%    inet_tls (certificates by scripts/gen-dist-certs.sh) between two
%%    nodes: message round trips and bulk throughput of distribution
%%    itself, then request/feedback round trips and a sensor stream through
%%    a pairing whose every accepted signal is replicated to the standby on
%%    the other node before the Ack.
%%
%% c. Pauses (`pauses', not in the default run): the active's node is
%%    stopped with SIGSTOP for 100 ms to 5 s and woken with SIGCONT, on a
%%    lone node and in a three-node cluster, and the table says for each
%%    length whether the pairing failed over, whether anything was fenced
%%    (a client told `Fenced', or a new epoch on the same node), how many
%%    times the clients reconnected, and how long after SIGCONT traffic
%%    flowed again.
%%
%% Every section runs the release's defaults: evatar's timings
%% (heartbeat_ms, suspect_ms, lease_ms) and the bridge's heartbeat, as
%% config/sys.config.src ships them.
%%
%% Run it with scripts/bench-failover.sh (`make bench-failover').
-module(failover_bench).

-export([main/0, main/1]).
-export([dist_ping_pong/2, dist_bulk/3, sink/0]).

-define(SENSOR_MS, 5).

%% @doc Every section with the default options.
-spec main() -> ok.
main() -> main([]).

%% @doc Options: `{trials, N}' (default 50), `kill' or `stall' or `tls' or
%% `pauses' (only those sections; default the first three), `quick' (5
%% trials, short TLS runs: a smoke run whose figures are not meant to be
%% read), `{pauses, [Ms]}' (that section, with those pause lengths),
%% `{dir, Dir}' (node logs; default a fresh directory under /tmp).
-spec main([term()]) -> ok.
main(Opts) ->
    _ = evatar_test_cluster:ensure_distributed(),
    Quick = lists:member(quick, Opts),
    Trials = proplists:get_value(trials, Opts, case Quick of true -> 5; false -> 50 end),
    Dir = proplists:get_value(dir, Opts, temp_dir()),
    Sections = case [S || S <- [kill, stall, tls, pauses],
                          lists:member(S, Opts) orelse lists:keymember(S, 1, Opts)] of
                   [] -> [kill, stall, tls];
                   Some -> Some
               end,
    io:format("EVATAR failover benchmark: ~s, ~b schedulers, node logs in ~s~n",
              [lists:join(", ", [case S of
                                     tls -> "TLS cost";
                                     _ -> io_lib:format("~s (~b trials)", [S, Trials])
                                 end || S <- Sections]),
               erlang:system_info(schedulers_online), Dir]),
    Failover = [{Fault, failover(Fault, Trials, Dir)}
                || Fault <- [kill, stall], lists:member(Fault, Sections)],
    _ = Failover =/= [] andalso print_failover(Failover, Trials),
    _ = lists:member(tls, Sections) andalso tls_cost(Dir, Quick),
    _ = lists:member(pauses, Sections)
        andalso pauses(case lists:keyfind(pauses, 1, Opts) of
                           {pauses, Lengths} when is_list(Lengths) -> Lengths;
                           false -> [100, 250, 400, 1000, 2000, 5000]
                       end, Dir),
    ok.

temp_dir() ->
    Dir = filename:join("/tmp", "evatar-failover-bench-" ++ os:getpid()),
    ok = filelib:ensure_path(Dir),
    Dir.

%% ---------------------------------------------------------------------------
%% a. Failover time
%% ---------------------------------------------------------------------------

failover(Fault, Trials, Dir0) ->
    Dir = filename:join(Dir0, atom_to_list(Fault)),
    ok = filelib:ensure_path(Dir),
    %% No proxies: node-to-node links are direct, as in a deployment.
    {ok, C} = evatar_test_cluster:start(#{dir => Dir, prefix => "fo" ++ atom_to_list(Fault),
                                          net => none, conn => #{}}),
    Shell = open_port({spawn, "/bin/sh"}, [binary, stderr_to_stdout]),
    try
        io:format("~s: ", [name(Fault)]),
        Times = [trial(C, Shell, Fault, K) || K <- lists:seq(1, Trials)],
        io:format("~n"),
        Times
    after
        port_close(Shell),
        evatar_test_cluster:stop(C)
    end.

trial(C, Shell, Fault, K) ->
    N = length(evatar_test_cluster:nodes(C)),
    A = 1 + (K - 1) rem N,
    Id = iolist_to_binary(io_lib:format("fo-~s-~b", [Fault, K])),
    ok = evatar_test_pairing:create(C, A, Id),
    {ok, A, #{epoch := E0}} = evatar_test_pairing:active(C, Id),
    {ok, Pair} = evatar_test_traffic:start_pair(evatar_test_cluster:endpoints(C), Id,
                                                #{sensor_interval => ?SENSOR_MS, notify => self()}),
    VaName = entity(Pair),
    ok = await_signals(VaName, E0, 20, 30000),
    flush(VaName),
    OsPid = evatar_test_cluster:os_pid(C, A),
    Sig = case Fault of kill -> "KILL"; stall -> "STOP" end,
    Wall = calendar:system_time_to_rfc3339(erlang:system_time(millisecond),
                                           [{unit, millisecond}]),
    T0 = erlang:monotonic_time(microsecond),
    true = port_command(Shell, ["kill -", Sig, " ", OsPid, "\n"]),
    Result = first_after(VaName, E0, 60000),
    #{va := #{reconnects := VaRe}, av := #{reconnects := AvRe}} = evatar_test_traffic:history(Pair),
    evatar_test_traffic:close(Pair),
    %% Repair, and leave one healthy pairing less behind.
    case Fault of
        kill ->
            %% The cluster notices the exit of the OS process by itself.
            ok = evatar_test_cluster:await(fun() -> node_down(C, A) end, 10000, {down, A}),
            ok = evatar_test_cluster:restart(C, A);
        stall ->
            ok = evatar_test_cluster:stall(C, A),
            ok = evatar_test_cluster:resume(C, A)
    end,
    ok = evatar_test_cluster:await_formed(C, 60000),
    _ = evatar_test_pairing:await_healthy(C, Id, 60000),
    case evatar_test_pairing:active(C, Id) of
        {ok, I, _} -> _ = evatar_test_pairing:delete(C, I, Id);
        _ -> ok
    end,
    Ms = case Result of
             {ok, T1} -> (T1 - T0) / 1000;
             timeout -> timeout
         end,
    io:format("~s ", [case Ms of timeout -> "timeout"; _ -> integer_to_list(round(Ms)) end]),
    %% What a slow trial looked like, for the note printed after the table.
    Detail = #{trial => K, node => A, at => Wall,
               va => [reconnect(R, T0) || R <- VaRe], av => [reconnect(R, T0) || R <- AvRe]},
    {Ms, Detail}.

%% A client's reconnection: when (ms after the fault), where, why it had
%% lost the previous connection.
reconnect(#{at := At, endpoint := {_, Port}} = R, T0) ->
    {At - T0 div 1000, Port, maps:get(reason, R, undefined)}.

entity(#{pairing := Id}) -> <<Id/binary, "-va">>.

node_down(C, I) ->
    [S] = [S || #{i := J, status := S} <- evatar_test_cluster:info(C), J =:= I],
    S =:= down.

await_signals(Va, Epoch, N, Timeout) ->
    Deadline = erlang:monotonic_time(millisecond) + Timeout,
    await_signals_loop(Va, Epoch, N, Deadline).

await_signals_loop(_Va, _Epoch, 0, _Deadline) ->
    ok;
await_signals_loop(Va, Epoch, N, Deadline) ->
    Left = max(0, Deadline - erlang:monotonic_time(millisecond)),
    receive
        {evatar_test_traffic, Va, {received, _, Epoch, _}} -> await_signals_loop(Va, Epoch, N - 1, Deadline)
    after Left ->
            {error, no_traffic}
    end.

flush(Va) ->
    receive {evatar_test_traffic, Va, _} -> flush(Va)
    after 0 -> ok
    end.

first_after(Va, E0, Timeout) ->
    receive
        {evatar_test_traffic, Va, {received, _, Epoch, T}} when is_integer(Epoch), Epoch > E0 -> {ok, T};
        {evatar_test_traffic, Va, _} -> first_after(Va, E0, Timeout)
    after Timeout ->
            timeout
    end.

name(kill) -> "kill -9 of the active's node";
name(stall) -> "silent stall (SIGSTOP) of the active's node".

print_failover(Results, Trials) ->
    io:format("~na. Failover time, from the fault to the first signal delivered through the new "
              "active (ms), ~b trials each~n~n", [Trials]),
    io:format("  ~-44s ~8s ~8s ~8s ~8s  ~s~n", ["fault", "p50", "p99", "max", "failed", "target"]),
    _ = [begin
             Ok = lists:sort([T || {T, _} <- Times, is_number(T)]),
             Failed = length(Times) - length(Ok),
             {Target, Limit} = target(Fault),
             P99 = percentile(Ok, 99),
             Verdict = case Failed =:= 0 andalso is_number(P99) andalso P99 =< Limit of
                           true -> "met";
                           false -> "MISSED"
                       end,
             io:format("  ~-44s ~8s ~8s ~8s ~8b  ~s: ~s~n",
                       [name(Fault), fmt(percentile(Ok, 50)), fmt(P99), fmt(last(Ok)), Failed,
                        Target, Verdict])
         end || {Fault, Times} <- Results],
    io:format("~n  for scale, the time other systems take to notice a failure and act:~n"),
    _ = [io:format("  ~-58s ~s~n", [What, Figure]) || {What, Figure} <- references()],
    %% The three slowest trials of each fault, and any over its target.
    Slow = lists:append(
             [[{Fault, T, D} || {T, D} <- Times, not is_number(T)]
              ++ [{Fault, T, D} || {T, D} <- lists:sublist(lists:reverse(lists:keysort(1,
                                                  [X || {T, _} = X <- Times, is_number(T)])),
                                                           3)]
              ++ [{Fault, T, D} || {T, D} <- lists:sublist(lists:reverse(lists:keysort(1,
                                                  [X || {T, _} = X <- Times, is_number(T)])),
                                                           4, length(Times)),
                                   T > element(2, target(Fault))]
              || {Fault, Times} <- Results]),
    io:format("~n  the slowest trials (clients' reconnections: ms after the fault, bridge port, "
              "why the previous connection ended):~n"),
    _ = [io:format("  ~s trial ~b (active on node ~b, fault at ~s): ~s ms~n"
                   "      VA ~p~n      Avatar ~p~n",
                   [Fault, K, A, At, fmt(T), Va, Av])
         || {Fault, T, #{trial := K, node := A, at := At, va := Va, av := Av}} <- Slow],
    ok.

target(kill) -> {"p99 <= 200 ms", 200};
target(stall) -> {"p99 <= 1000 ms", 1000}.

references() ->
    [{"Erlang distribution, silent node (net_ticktime 60 s)", "45,000-75,000 ms"},
     {"keepalived (VRRP, 1 s adverts, 3 missed)", "about 3,000 ms"},
     {"etcd leader election (1 s election timeout)", "about 1,000 ms"}].

%% Nearest rank.
percentile([], _P) -> undefined;
percentile(Sorted, P) ->
    Rank = max(1, ceil(P / 100 * length(Sorted))),
    lists:nth(Rank, Sorted).

last([]) -> undefined;
last(L) -> lists:last(L).

fmt(undefined) -> "-";
fmt(timeout) -> "timeout";
fmt(X) -> io_lib:format("~.1f", [X]).

%% ---------------------------------------------------------------------------
%% c. Pauses of the active's node
%% ---------------------------------------------------------------------------

pauses(Lengths, Dir0) ->
    io:format("~nc. Pauses of the active's node (SIGSTOP, SIGCONT after the pause), "
              "the release's defaults~n~n"),
    io:format("  ~-8s ~-9s ~8s ~8s ~8s ~10s  ~s~n",
              ["nodes", "pause ms", "failover", "fenced", "reconn.", "flows ms", "clients' reasons"]),
    _ = [pauses(N, Lengths, Dir0) || N <- [1, 3]],
    io:format("~n  failover: the pairing is active on another node; fenced: a client was told "
              "Fenced, or the pairing~n  has a new epoch on the same node; flows: from SIGCONT "
              "to the next signal the VA receives.~n"),
    ok.

pauses(N, Lengths, Dir0) ->
    Dir = filename:join(Dir0, "pauses" ++ integer_to_list(N)),
    ok = filelib:ensure_path(Dir),
    {ok, C} = evatar_test_cluster:start(#{dir => Dir, n => N, prefix => "fp" ++ integer_to_list(N),
                                          net => none, conn => #{}}),
    Shell = open_port({spawn, "/bin/sh"}, [binary, stderr_to_stdout]),
    try
        [pause_trial(C, Shell, N, Ms) || Ms <- Lengths]
    after
        port_close(Shell),
        evatar_test_cluster:stop(C)
    end.

pause_trial(C, Shell, N, Ms) ->
    Id = iolist_to_binary(io_lib:format("fp-~b-~b", [N, Ms])),
    ok = evatar_test_pairing:create(C, 1, Id),
    {ok, 1, #{epoch := E0}} = evatar_test_pairing:active(C, Id),
    {ok, Pair} = evatar_test_traffic:start_pair(evatar_test_cluster:endpoints(C), Id,
                                                #{sensor_interval => ?SENSOR_MS, notify => self()}),
    VaName = entity(Pair),
    ok = await_signals(VaName, E0, 20, 30000),
    OsPid = evatar_test_cluster:os_pid(C, 1),
    true = port_command(Shell, ["kill -STOP ", OsPid, "\n"]),
    timer:sleep(Ms),
    flush(VaName),
    T0 = erlang:monotonic_time(microsecond),
    true = port_command(Shell, ["kill -CONT ", OsPid, "\n"]),
    Flows = receive {evatar_test_traffic, VaName, {received, _, _, T}} -> (T - T0) / 1000
            after 60000 -> timeout
            end,
    {ok, _} = evatar_test_traffic:round_trip(Pair, 60000),
    {ok, I, #{epoch := E1}} = evatar_test_pairing:await_active(C, Id, fun(_, _) -> true end, 60000),
    #{va := #{reconnects := VaRe}, av := #{reconnects := AvRe}} = evatar_test_traffic:history(Pair),
    Reasons = [maps:get(reason, R, undefined) || R <- VaRe ++ AvRe],
    Fenced = [R || {refused, <<"Fenced">>, _} = R <- Reasons] =/= []
        orelse (I =:= 1 andalso E1 =/= E0),
    evatar_test_traffic:close(Pair),
    io:format("  ~-8b ~-9b ~8s ~8s ~8b ~10s  ~s~n",
              [N, Ms, yes_no(I =/= 1), yes_no(Fenced), length(Reasons), fmt(Flows),
               reasons(Reasons)]),
    ok = evatar_test_cluster:await_formed(C, 60000),
    _ = N > 1 andalso evatar_test_pairing:await_healthy(C, Id, 60000),
    _ = evatar_test_pairing:delete(C, I, Id),
    ok.

yes_no(true) -> "yes";
yes_no(false) -> "no".

reasons(Reasons) ->
    Names = [case R of
                 {refused, Code, _} -> binary_to_list(Code);
                 Atom when is_atom(Atom) -> atom_to_list(Atom);
                 _ -> "other"
             end || R <- Reasons],
    lists:join(" ", [io_lib:format("~s x~b", [Name, length([X || X <- Names, X =:= Name])])
                     || Name <- lists:usort(Names)]).

%% ---------------------------------------------------------------------------
%% b. TLS distribution
%% ---------------------------------------------------------------------------

tls_cost(Dir0, Quick) ->
    Dir = filename:join(Dir0, "tls"),
    Certs = filename:join(Dir, "certs"),
    ok = filelib:ensure_path(Dir),
    Script = filename:join([evatar_test_cluster:repo_root(), "scripts", "gen-dist-certs.sh"]),
    Out = os:cmd("bash " ++ Script ++ " " ++ Certs ++ " 127.0.0.1 localhost >/dev/null 2>&1; echo $?"),
    "0\n" = Out,
    Scale = case Quick of true -> 10; false -> 1 end,
    Tcp = dist_figures(#{dir => filename:join(Dir, "tcp"), prefix => "fbtcp"}, Scale),
    Tls = dist_figures(#{dir => filename:join(Dir, "tls"), prefix => "fbtls",
                         launcher => peer, control => stdio, dist => inet_tls,
                         ssl_optfile => filename:join(Certs, "ssl_dist.conf")}, Scale),
    io:format("~nb. Distribution over TCP (inet_tcp_dist) and over TLS (inet_tls_dist), "
              "between two nodes~n~n"),
    io:format("  ~-56s ~12s ~12s ~8s~n", ["", "inet_tcp", "inet_tls", "tls/tcp"]),
    _ = [io:format("  ~-56s ~12s ~12s ~8s~n",
                   [Label, fmt(maps:get(K, Tcp)), fmt(maps:get(K, Tls)),
                    fmt_ratio(maps:get(K, Tls), maps:get(K, Tcp))])
         || {K, Label} <- [{rtt_us, "message round trip, mean (us)"},
                           {bulk_mbs, "bulk, 64 KiB messages (MB/s)"},
                           {req_ms, "request/feedback through a pairing, median (ms)"},
                           {stream_per_s, "sensor stream through a pairing (signals/s)"}]],
    io:format("~n  the pairing figures include the bridge, XML and the replication to the "
              "standby before each Ack;~n  the first two are distribution alone.~n"),
    ok.

fmt_ratio(A, B) when is_number(A), is_number(B), B > 0 -> io_lib:format("~.2f", [A / B]);
fmt_ratio(_, _) -> "-".

dist_figures(Opts, Scale) ->
    ok = filelib:ensure_path(maps:get(dir, Opts)),
    %% The nodes run this module's dist_ping_pong/2 and dist_bulk/3.
    {ok, C} = evatar_test_cluster:start(Opts#{n => 2, net => none, modules => [?MODULE]}),
    try
        N2 = evatar_test_cluster:node(C, 2),
        Rounds = 20000 div Scale,
        {ok, RttUs} = evatar_test_cluster:call(C, 1, ?MODULE, dist_ping_pong, [N2, Rounds], 120000),
        {ok, MBs} = evatar_test_cluster:call(C, 1, ?MODULE, dist_bulk, [N2, 65536, 2000 div Scale],
                                             120000),
        Id = <<"fb-tls-cost">>,
        ok = evatar_test_pairing:create(C, 1, Id),
        {ok, Pair} = evatar_test_traffic:start_pair(evatar_test_cluster:endpoints(C), Id, #{notify => self()}),
        ReqMs = request_latency(Pair, 1000 div Scale),
        PerS = stream(Pair, 5000 div Scale),
        evatar_test_traffic:close(Pair),
        #{rtt_us => RttUs, bulk_mbs => MBs, req_ms => ReqMs, stream_per_s => PerS}
    after
        evatar_test_cluster:stop(C)
    end.

%% The median of N sequential round trips, in ms (a median: one slow round
%% trip on a shared machine says little about the link).
request_latency(Pair, N) ->
    Times = [begin
                 T0 = erlang:monotonic_time(microsecond),
                 {ok, _} = evatar_test_traffic:round_trip(Pair, 30000),
                 (erlang:monotonic_time(microsecond) - T0) / 1000
             end || _ <- lists:seq(1, N)],
    percentile(lists:sort(Times), 50).

%% The Avatar sends N sensor signals as fast as its client takes them; the
%% rate is from the first send to the last arrival at the VA.
stream(#{av := Av, pairing := Id} = _Pair, N) ->
    Va = <<Id/binary, "-va">>,
    flush(Va),
    T0 = erlang:monotonic_time(microsecond),
    ok = evatar_test_traffic:burst(Av, N),
    case count_arrivals(Va, N, 120000) of
        {ok, T1} -> N / ((T1 - T0) / 1000000);
        timeout -> undefined
    end.

count_arrivals(_Va, 0, _Timeout) ->
    {ok, erlang:monotonic_time(microsecond)};
count_arrivals(Va, N, Timeout) ->
    receive {evatar_test_traffic, Va, {received, _, _, _}} -> count_arrivals(Va, N - 1, Timeout)
    after Timeout -> timeout
    end.

%% @private Run on a node: the mean round trip (us) of a small message to a
%% process on Node and back.
-spec dist_ping_pong(node(), pos_integer()) -> {ok, float()}.
dist_ping_pong(Node, Rounds) ->
    Echo = spawn(Node, fun() -> echo() end),
    _ = [begin Echo ! {self(), ping}, receive pong -> ok end end || _ <- lists:seq(1, 100)],
    T0 = erlang:monotonic_time(microsecond),
    _ = [begin Echo ! {self(), ping}, receive pong -> ok end end || _ <- lists:seq(1, Rounds)],
    T1 = erlang:monotonic_time(microsecond),
    exit(Echo, kill),
    {ok, (T1 - T0) / Rounds}.

echo() ->
    receive {From, ping} -> From ! pong, echo() end.

%% @private Run on a node: MB/s of Count messages of Size bytes to a process
%% on Node, until it has them all.
-spec dist_bulk(node(), pos_integer(), pos_integer()) -> {ok, float()}.
dist_bulk(Node, Size, Count) ->
    Sink = spawn(Node, ?MODULE, sink, []),
    Bin = crypto:strong_rand_bytes(Size),
    T0 = erlang:monotonic_time(microsecond),
    _ = [Sink ! {data, Bin} || _ <- lists:seq(1, Count)],
    Sink ! {done, self(), Count},
    receive {sink, Count} -> ok end,
    T1 = erlang:monotonic_time(microsecond),
    {ok, Size * Count / ((T1 - T0) / 1000000) / 1000000}.

%% @private
-spec sink() -> ok.
sink() -> sink(0).

sink(N) ->
    receive
        {data, _} -> sink(N + 1);
        {done, From, _} -> From ! {sink, N}, ok
    end.

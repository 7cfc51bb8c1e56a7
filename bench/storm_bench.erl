%% @doc Failover storm benchmark: kill -9 of a node that holds the actives
%% of N pairings, on a three-node cluster of real OS-process nodes on this
%% machine (evatar_test_cluster, the release's HA timings), every pairing
%% with traffic (its Avatar sends a sensor reading every `sensor_ms').
%%
%% The N pairings are created with their actives on node 1 (the rebalancer
%% off, so they stay there); each gets a VA and an Avatar, HA clients of the
%% bridge knowing every node, and does one round trip. Then node 1 is
%% killed. At the kill every pair starts a round trip (the VA's request,
%% the Avatar's feedback): the clients reconnect to the new active and the
%% request, resent by the VA's client, is answered there. Figures:
%%
%% - served: per pairing, from the kill until its round trip is answered
%%   at an epoch above the one it had on node 1; p50, p99, max, and how
%%   many of the N within 1 s and 3 s (the goals: 1,000 within 1 s, 5,000
%%   within 3 s);
%% - synced: from the kill until every pairing has an active and a synced
%%   standby again (on nodes 2 and 3); after 600 s, how many have not;
%% - lost / duplicated: evatar_test_checker over every pair's history
%%   (sensor readings and requests, both directions) once traffic has
%%   stopped and settled: both must be 0.
%%
%% Options: `{pairings, [N]}' (default [1000]), `{sensor_ms, Ms}' (default
%% 1000), `quick' (pairings [50]: a smoke run), `{dir, Dir}' (node logs).
%% Run it with scripts/bench-storm.sh (`make bench-storm').
-module(storm_bench).

-export([main/0, main/1]).

%% @doc The default run.
-spec main() -> ok.
main() -> main([]).

-spec main([term()]) -> ok.
main(Opts) ->
    _ = evatar_test_cluster:ensure_distributed(),
    Quick = lists:member(quick, Opts),
    Sizes = proplists:get_value(pairings, Opts, case Quick of true -> [50]; false -> [1000] end),
    SensorMs = proplists:get_value(sensor_ms, Opts, 1000),
    Dir = proplists:get_value(dir, Opts, temp_dir()),
    io:format("EVATAR failover storm: kill -9 of the node holding N actives, 3 nodes, "
              "~b schedulers here, a sensor reading every ~b ms per pairing, node logs in ~s~n",
              [erlang:system_info(schedulers_online), SensorMs, Dir]),
    Rows = [storm(N, SensorMs, filename:join(Dir, integer_to_list(N))) || N <- Sizes],
    print(Rows).

temp_dir() ->
    Dir = filename:join("/tmp", "evatar-storm-bench-" ++ os:getpid()),
    ok = filelib:ensure_path(Dir),
    Dir.

storm(N, SensorMs, Dir) ->
    ok = filelib:ensure_path(Dir),
    %% N pairings are 2N clients from one address: above the listener's
    %% default connection and handshake limits (docs/ha.md says how to
    %% raise them, as here).
    {ok, C} = evatar_test_cluster:start(#{dir => Dir, prefix => "st", net => none,
                                          conn => #{},
                                          listener => #{max_connections => infinity,
                                                        handshake => #{rate => infinity}},
                                          evatar => [{rebalance, false}]}),
    Shell = open_port({spawn, "/bin/sh"}, [binary, stderr_to_stdout]),
    try
        run(C, Shell, N, SensorMs)
    after
        port_close(Shell),
        evatar_test_cluster:stop(C)
    end.

run(C, Shell, N, SensorMs) ->
    Ids = [iolist_to_binary(io_lib:format("storm-~5..0b", [K])) || K <- lists:seq(1, N)],
    Me = self(),
    {CreateUs, {Pairs, Before}} =
        timer:tc(fun() ->
                         evatar_test_pairing:start_many(C, Ids, #{sensor_interval => SensorMs})
                 end),
    OnNode1 = [Id || {Id, {1, _}} <- maps:to_list(Before)],
    io:format("  ~b pairings created and serving in ~b ms (~b a second); ~b of them active on node 1~n",
              [N, CreateUs div 1000, round(N / max(1, CreateUs) * 1.0e6), length(OnNode1)]),
    %% Every pair waits at the start line; the kill releases them.
    Go = make_ref(),
    Runners = [spawn_link(fun() ->
                                  receive {Go, T0} -> ok end,
                                  Me ! {served, P, served(P, T0, maps:get(Id, Before))}
                          end) || #{pairing := Id} = P <- Pairs],
    %% What the storm costs: CPU of each OS process (the two nodes left and
    %% this one, which holds the 2N clients) and reductions by kind of
    %% process, from the kill until every pair was served.
    Survivors = [{K, evatar_test_cluster:node(C, K), evatar_test_cluster:os_pid(C, K)} || K <- [2, 3]],
    Procs = [{"node " ++ integer_to_list(K), Pid} || {K, _, Pid} <- Survivors]
        ++ [{"clients", os:getpid()}],
    Cpu0 = [{Name, cpu_ms(Pid)} || {Name, Pid} <- Procs],
    Reds0 = [{K, reductions(Node)} || {K, Node, _} <- Survivors],
    Samplers = [{K, sampler(Node)} || {K, Node, _} <- Survivors],
    T0 = erlang:monotonic_time(microsecond),
    true = port_command(Shell, ["kill -KILL ", evatar_test_cluster:os_pid(C, 1), "\n"]),
    _ = [R ! {Go, T0} || R <- Runners],
    Served = [receive {served, P, S} -> S end || P <- Pairs],
    ServedMs = (erlang:monotonic_time(microsecond) - T0) / 1000,
    Queues = [{K, stop_sampler(Sampler)} || {K, Sampler} <- Samplers],
    Cpu = [{Name, cpu_ms(Pid) - proplists:get_value(Name, Cpu0)} || {Name, Pid} <- Procs],
    Reds = [{K, diff(reductions(Node), proplists:get_value(K, Reds0))} || {K, Node, _} <- Survivors],
    %% Printed now: a storm that does not settle still leaves its figures.
    io:format("  N = ~b: every pair served within ~.1f ms of the kill; waiting for every "
              "pairing's synced standby (at most 600 s)~n", [N, ServedMs]),
    Healthy = fun() -> [Id || Id <- Ids, evatar_test_pairing:healthy(C, Id)] end,
    SyncedMs = case evatar_test_cluster:await(fun() -> length(Healthy()) =:= N end,
                                              600000, all_synced) of
                   ok -> (erlang:monotonic_time(microsecond) - T0) / 1000;
                   {error, _} -> {not_synced, N - length(Healthy())}
               end,
    Settled = evatar_test_pairing:pmap(fun(P) -> ok = evatar_test_traffic:stop_traffic(P),
                                                 evatar_test_traffic:settle(P, 60000)
                                       end, Pairs, 32),
    Check = evatar_test_checker:check_pairs([evatar_test_traffic:history(P) || P <- Pairs]),
    _ = [evatar_test_traffic:close(P) || P <- Pairs],
    #{n => N, on_node1 => length(OnNode1), served => Served, synced_ms => SyncedMs,
      unsettled => length([R || R <- Settled, R =/= ok]),
      check => Check, cost => {ServedMs, Cpu, Reds, Queues}}.

%% On Node, every 10 ms until stopped: the longest message queue of its
%% evatar_cluster process (heartbeats, votes and standby starts share it)
%% and the longest run queue of its schedulers.
sampler(Node) ->
    {Mod, Bin, File} = code:get_object_code(?MODULE),
    {module, Mod} = erpc:call(Node, code, load_binary, [Mod, File, Bin]),
    Me = self(),
    spawn(Node, fun() -> sample(Me, whereis(evatar_cluster), 0, 0) end).

sample(To, Cluster, MaxQ, MaxRun) ->
    receive
        stop -> To ! {self(), MaxQ, MaxRun}
    after 10 ->
            {message_queue_len, Q} = erlang:process_info(Cluster, message_queue_len),
            Run = lists:max(erlang:statistics(run_queue_lengths)),
            sample(To, Cluster, max(MaxQ, Q), max(MaxRun, Run))
    end.

stop_sampler(Pid) ->
    Pid ! stop,
    receive {Pid, MaxQ, MaxRun} -> {MaxQ, MaxRun} after 30000 -> {timeout, timeout} end.


%% CPU time (user + system, ms) an OS process has used, from /proc.
cpu_ms(OsPid) ->
    {ok, Stat} = file:read_file(["/proc/", OsPid, "/stat"]),
    %% The command name (field 2) may hold spaces; the fields after it do not.
    [_, After] = binary:split(Stat, <<") ">>),
    Fields = binary:split(After, <<" ">>, [global]),
    Ticks = binary_to_integer(lists:nth(12, Fields)) + binary_to_integer(lists:nth(13, Fields)),
    Ticks * 1000 div clock_ticks().

clock_ticks() ->
    list_to_integer(string:trim(os:cmd("getconf CLK_TCK"))).

%% A node's reductions by kind of process: the module of its proc_lib
%% initial call (or of its plain initial call), summed.
reductions(Node) ->
    %% The fun below is this module's: the node must have its code.
    {Mod, Bin, File} = code:get_object_code(?MODULE),
    {module, Mod} = erpc:call(Node, code, load_binary, [Mod, File, Bin]),
    erpc:call(Node, fun() ->
                            lists:foldl(fun(P, Acc) ->
                                                case kind_reds(P) of
                                                    {K, R} -> maps:update_with(K, fun(X) -> X + R end, R, Acc);
                                                    none -> Acc
                                                end
                                        end, #{}, erlang:processes())
                    end, 30000).

kind_reds(P) ->
    case erlang:process_info(P, [dictionary, initial_call, reductions]) of
        [{dictionary, D}, {initial_call, {M0, _, _}}, {reductions, R}] ->
            case proplists:get_value('$initial_call', D) of
                {M, _, _} -> {M, R};
                undefined -> {M0, R}
            end;
        undefined ->
            none
    end.

%% Reductions of each kind since Before (processes born since count whole;
%% processes gone since are not counted).
diff(After, Before) ->
    maps:map(fun(K, R) -> R - maps:get(K, Before, 0) end, After).

%% Ms from the kill until P's round trip is answered above the epoch it
%% had on node 1 (one more try when the first was answered by node 1
%% before it died, or below that epoch); `failed' after 60 s.
served(P, T0, {_, E0}) ->
    case evatar_test_traffic:round_trip(P, 60000) of
        {ok, E} when is_integer(E), E > E0 ->
            (erlang:monotonic_time(microsecond) - T0) / 1000;
        {ok, _} ->
            case (erlang:monotonic_time(microsecond) - T0) < 60000000 of
                true -> served(P, T0, {x, E0});
                false -> failed
            end;
        {error, _} ->
            failed
    end.

print(Rows) ->
    io:format("~n  ~8s ~8s ~9s ~9s ~9s ~9s ~9s ~10s ~6s ~6s~n",
              ["N", "on kill", "p50 ms", "p99 ms", "max ms", "<= 1 s", "<= 3 s", "synced ms",
               "lost", "dup"]),
    _ = [begin
             Ok = lists:sort([T || T <- S, is_number(T)]),
             Failed = length(S) - length(Ok),
             Within = fun(L) -> length([T || T <- Ok, T =< L]) end,
             io:format("  ~8b ~8b ~9s ~9s ~9s ~9b ~9b ~10s ~6b ~6b~s~s~n",
                       [N, On, fmt(pct(Ok, 50)), fmt(pct(Ok, 99)), fmt(last(Ok)),
                        Within(1000), Within(3000), fmt(Synced), lost(Check), dup(Check),
                        case Failed of 0 -> ""; _ -> io_lib:format("  (~b not served in 60 s)", [Failed]) end,
                        case Unsettled of
                            0 -> "";
                            _ -> io_lib:format("  (~b pairs' signals not settled 60 s after "
                                               "their traffic stopped: counted lost)", [Unsettled])
                        end])
         end || #{n := N, on_node1 := On, served := S, synced_ms := Synced, check := Check,
                  unsettled := Unsettled} <- Rows],
    _ = [io:format("~n  checker, N = ~b:~n~s~n", [N, evatar_test_checker:format(Check)])
         || #{n := N, check := Check} <- Rows],
    _ = [print_cost(N, Cost) || #{n := N, cost := Cost} <- Rows],
    io:format("~n  goals: all 1,000 served within 1 s, all 5,000 within 3 s; lost and dup 0~n"),
    ok.

lost(#{lost := L}) -> length(L).
dup(#{duplicated := D, unexpected := U}) -> length(D) + length(U).

pct([], _) -> undefined;
pct(Sorted, P) -> lists:nth(max(1, ceil(P / 100 * length(Sorted))), Sorted).

last([]) -> undefined;
last(L) -> lists:last(L).

fmt(undefined) -> "-";
fmt({not_synced, K}) -> io_lib:format("~b unsynced", [K]);
fmt(X) -> io_lib:format("~.1f", [X]).

%% CPU from the kill until every pair was served, per process and per
%% pairing, and where the survivors' reductions went (the top kinds).
print_cost(N, {ServedMs, Cpu, Reds, Queues}) ->
    io:format("~n  cost, N = ~b, the ~.1f ms from the kill until every pair was served "
              "(~b schedulers here):~n", [N, ServedMs, erlang:system_info(schedulers_online)]),
    _ = [io:format("    ~-8s CPU ~7b ms  (~.2f ms a pairing, ~b % of one core)~n",
                   [Name, Ms, Ms / N, round(100 * Ms / max(1.0, ServedMs))]) || {Name, Ms} <- Cpu],
    Total = lists:sum([Ms || {_, Ms} <- Cpu]),
    io:format("    all      CPU ~7b ms  (~.2f ms a pairing)~n", [Total, Total / N]),
    _ = [begin
             Sum = lists:sum(maps:values(R)),
             Top = lists:sublist(lists:reverse(lists:keysort(2, maps:to_list(R))), 8),
             io:format("    node ~b reductions ~b (~b a pairing): ~s~n",
                       [K, Sum, Sum div N,
                        lists:join(", ", [io_lib:format("~s ~.1f %", [M, 100 * V / max(1, Sum)])
                                          || {M, V} <- Top])])
         end || {K, R} <- Reds],
    _ = [io:format("    node ~b at most ~p messages waiting for evatar_cluster, ~p processes "
                   "in a scheduler's run queue~n", [K, Q, Run]) || {K, {Q, Run}} <- Queues],
    ok.

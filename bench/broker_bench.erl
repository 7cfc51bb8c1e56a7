%% @doc EVATAR against the brokers users would pick instead, side by side
%% in one run: EVATAR, mosquitto, RabbitMQ's MQTT plugin and nats-server
%% (request-reply), each its own OS process on loopback, driven by the same
%% load generator (broker_bench_gen) in this VM. `{transport, tls}' runs
%% EVATAR's TLS listener against mosquitto's, with the same certificate. For each N (pairs of agent and device): the closed-loop maximum
%% round trips/s; p50, p99, p99.9 latency in an open loop at 25 %, 50 % and
%% 75 % of each system's own maximum; the system's CPU seconds per 100,000
%% round trips and its peak resident memory. Writes a markdown table and a
%% JSON file under bench/results/ with the machine, the versions and the
%% ratios EVATAR/mosquitto, EVATAR/RabbitMQ and EVATAR/NATS. How to run and read it:
%% bench/README.md, section d. Not part of the product.
-module(broker_bench).

-export([main/0, main/1]).

-export_type([option/0]).

-import(evatar_bench_report, [fmt/2, int/1, ms/1]).

-type option() :: quick | profile | no_profile
                | {systems, [broker_bench_sut:system()]}
                | {transport, tcp | tls}        % tls: EVATAR and mosquitto only
                | {sizes, [pos_integer()]}
                | {loads, [float()]}            % open-loop rates, shares of the maximum
                | {seconds, number()}           % each measuring window
                | {rounds, pos_integer()}       % closed-loop turns per system
                | {warmup, number()}            % before each window
                | {profile_n, pos_integer()}
                | {profile_seconds, number()}
                | {out, file:filename()}
                | {run_dir, file:filename()}.

-define(SYSTEMS, [evatar, mosquitto, rabbitmq, nats]).
%% The systems with a TLS listener in this benchmark.
-define(TLS_SYSTEMS, [evatar, mosquitto]).
%% The systems EVATAR's figures are divided by, with their ratio's key.
-define(PEERS, [{mosquitto, evatar_over_mosquitto}, {rabbitmq, evatar_over_rabbitmq},
                {nats, evatar_over_nats}]).

%% ---------------------------------------------------------------------------
%% Entry points
%% ---------------------------------------------------------------------------

%% @equiv main([])
-spec main() -> ok.
main() -> main([]).

%% @doc Runs the comparison, prints the tables and writes the results.
-spec main([option()]) -> ok.
main(Options) ->
    ok = io:setopts([{encoding, unicode}]),
    ok = logger:set_primary_config(level, warning),
    Cfg = config(Options),
    ok = filelib:ensure_dir(filename:join(maps:get(run_dir, Cfg), "x")),
    ok = ensure_distribution(Cfg),
    %% The clients' TLS (agent_bridge_client expects ssl to be running).
    {ok, _} = application:ensure_all_started(ssl),
    Machine0 = machine(),
    Versions = broker_bench_sut:versions(),
    io:format("Broker comparison (~s): systems ~w, N ~w, ~p s windows (closed loop in ~b rounds) "
              "after ~p s warm-up, open loop at ~w of each maximum~s~nload average at start: ~w~n",
              [maps:get(transport, Cfg), maps:get(systems, Cfg), maps:get(sizes, Cfg),
               maps:get(seconds, Cfg),
               maps:get(rounds, Cfg), maps:get(warmup, Cfg), maps:get(loads, Cfg),
               case maps:get(quick, Cfg) of
                   true -> " (QUICK: a smoke run, figures not meant to be read)";
                   false -> ""
               end, maps:get(load_average, Machine0)]),
    Runs = lists:append([run_size(N, Cfg) || N <- maps:get(sizes, Cfg)]),
    Profile = case maps:get(profile, Cfg) andalso lists:member(evatar, maps:get(systems, Cfg)) of
                  true -> profile(Cfg);
                  false -> undefined
              end,
    LoadEnd = loadavg(),
    Machine = Machine0#{load_average_start => maps:get(load_average, Machine0),
                        load_average_end => LoadEnd},
    Ratios = ratios(Runs, Cfg),
    Goals = goals(Runs, Cfg),
    Date = list_to_binary(calendar:system_time_to_rfc3339(os:system_time(second))),
    Md = markdown(Date, Machine, Versions, Cfg, Runs, Ratios, Goals, Profile),
    io:put_chars(["\n", Md]),
    Results = #{date => Date, machine => Machine, versions => Versions,
                config => maps:remove(tls_dir, Cfg#{out := unicode:characters_to_binary(maps:get(out, Cfg)),
                               run_dir := unicode:characters_to_binary(maps:get(run_dir, Cfg))}),
                runs => Runs, ratios => Ratios, goals => Goals, profile => Profile},
    Prefix = case maps:get(transport, Cfg) of tcp -> "brokers"; tls -> "brokers-tls" end,
    {Json, MdFile} = evatar_bench_report:write(maps:get(out, Cfg), Prefix, Results, Md),
    io:format("~nResults written to ~s and ~s~n", [Json, MdFile]),
    ok.

config(Options) ->
    Quick = lists:member(quick, Options),
    Default = case Quick of
                  true -> #{sizes => [1, 100], seconds => 2, warmup => 0.5, rounds => 2,
                            profile_seconds => 2};
                  false -> #{sizes => [1, 100, 1000], seconds => 6, warmup => 2, rounds => 3,
                             profile_seconds => 5}
              end,
    Transport = proplists:get_value(transport, Options, tcp),
    lists:member(Transport, [tcp, tls]) orelse error({unknown_transport, Transport}),
    Known = case Transport of tcp -> ?SYSTEMS; tls -> ?TLS_SYSTEMS end,
    Cfg = lists:foldl(fun({K, V}, Acc) -> Acc#{K => V};
                         (_, Acc) -> Acc
                      end,
                      Default#{systems => Known, loads => [0.25, 0.5, 0.75],
                               profile_n => 100, out => "bench/results",
                               run_dir => default_run_dir()},
                      Options),
    Bad = [S || S <- maps:get(systems, Cfg), not lists:member(S, Known)],
    Bad =:= [] orelse error({unknown_systems, Bad, {known, Transport, Known}}),
    Tls = case Transport of
              tcp -> #{};
              tls -> #{tls_dir => certs(maps:get(run_dir, Cfg))}
          end,
    (maps:merge(Cfg, Tls))#{quick => Quick, transport => Transport,
         profile => lists:member(profile, Options)
             orelse not (Quick orelse lists:member(no_profile, Options))}.

%% The CA, server certificate and key of both TLS listeners, made by
%% scripts/gen-bridge-certs.sh (found from the source of the evatar app,
%% apps/evatar/src/evatar.erl, as tls_bench does).
certs(RunDir) ->
    Dir = filename:join(RunDir, "certs"),
    Src = proplists:get_value(source, evatar:module_info(compile)),
    Root = filename:dirname(filename:dirname(filename:dirname(filename:dirname(Src)))),
    Script = filename:join([Root, "scripts", "gen-bridge-certs.sh"]),
    Out = os:cmd("EVATAR_SERVER_HOSTS='localhost 127.0.0.1' bash " ++ Script ++ " " ++ Dir
                 ++ " bench 2>&1; echo rc=$?"),
    case string:find(Out, "rc=0\n") of
        nomatch -> error({gen_bridge_certs, Out});
        _ -> Dir
    end.

default_run_dir() ->
    case os:getenv("BROKER_BENCH_RUN_DIR") of
        false -> filename:join("/tmp", "broker_bench_" ++ os:getpid());
        D -> D
    end.

%% The EVATAR node is a peer started over distribution.
ensure_distribution(#{systems := Systems}) ->
    case lists:member(evatar, Systems) andalso node() =:= nonode@nohost of
        false ->
            ok;
        true ->
            _ = os:cmd("epmd -daemon"),
            Name = list_to_atom("broker_bench_" ++ os:getpid()),
            case net_kernel:start([Name, shortnames]) of
                {ok, _} -> ok;
                {error, {already_started, _}} -> ok
            end
    end.

%% ---------------------------------------------------------------------------
%% The machine
%% ---------------------------------------------------------------------------

machine() ->
    {ok, CpuInfo} = file:read_file("/proc/cpuinfo"),
    Model = case re:run(CpuInfo, "^model name\\s*:\\s*(.*)$", [multiline, {capture, all_but_first, binary}]) of
                {match, [M]} -> M;
                nomatch -> <<"unknown">>
            end,
    {ok, MemInfo} = file:read_file("/proc/meminfo"),
    {match, [MemKb]} = re:run(MemInfo, "^MemTotal:\\s*([0-9]+)", [multiline, {capture, all_but_first, binary}]),
    #{cpu_model => Model, cores => cpu_count(),
      memory_mib => binary_to_integer(MemKb) div 1024,
      kernel => list_to_binary(string:trim(os:cmd("uname -r"))),
      load_average => loadavg()}.

cpu_count() ->
    case erlang:system_info(logical_processors_available) of
        N when is_integer(N) -> N;
        _ -> erlang:system_info(logical_processors)
    end.

loadavg() ->
    {ok, B} = file:read_file("/proc/loadavg"),
    [binary_to_float(X) || X <- lists:sublist(binary:split(B, <<" ">>, [global]), 3)].

%% ---------------------------------------------------------------------------
%% One size: the three systems side by side
%% ---------------------------------------------------------------------------

%% Every system is started (fresh for this N) and gets its N pairs; then
%% their closed loops take turns, `rounds' windows each, and their open
%% loops take turns rate by rate, so that a burst of other load on a shared
%% machine falls on all of them alike rather than on whichever ran then.
run_size(N, #{systems := Systems, loads := Loads} = Cfg) ->
    io:format("~n-- N = ~b: starting ~w...~n", [N, Systems]),
    run_size(N, Systems, Cfg, Loads, []).

run_size(N, [Sys | Rest], Cfg, Loads, Started) ->
    Sut = broker_bench_sut:start(Sys, maps:get(run_dir, Cfg), Cfg),
    try
        run_size(N, Rest, Cfg, Loads, [Sut | Started])
    after
        broker_bench_sut:stop(Sut)
    end;
run_size(N, [], Cfg, Loads, Started) ->
    Suts = lists:reverse(Started),
    Ready = [begin
                 OsPid = maps:get(os_pid, Sut),
                 #{rss := Rss0} = broker_bench_sut:memory_kib(OsPid),
                 T0 = erlang:monotonic_time(millisecond),
                 Pairs = broker_bench_gen:setup(N, Sut),
                 SetupMs = erlang:monotonic_time(millisecond) - T0,
                 io:format("   ~s: ~b pairs (~b connections) ready in ~b ms~n",
                           [Sys, N, 2 * N, SetupMs]),
                 #{system => Sys, os_pid => OsPid, pairs => Pairs, setup_ms => SetupMs,
                   rss0 => Rss0}
             end || #{system := Sys} = Sut <- Suts],
    Rounds = maps:get(rounds, Cfg),
    RoundCfg = Cfg#{seconds := maps:get(seconds, Cfg) / Rounds,
                    warmup := maps:get(warmup, Cfg) / 2},
    Windows = [[{Sys, closed_loop(Pairs, RoundCfg, OsPid)}
                || #{system := Sys, pairs := Pairs, os_pid := OsPid} <- Ready]
               || _ <- lists:seq(1, Rounds)],
    Closed = maps:from_list(
               [{Sys, combine([W || Round <- Windows, {S, W} <- Round, S =:= Sys])}
                || #{system := Sys} <- Ready]),
    _ = [io:format("   ~s closed loop: ~s round trips/s (rounds ~s), ~s CPU s per 100k~n",
                   [Sys, int(maps:get(rate, C)), rates(C), f2(maps:get(cpu_s_per_100k, C))])
         || #{system := Sys} <- Ready, C <- [maps:get(Sys, Closed)]],
    HwmClosed = maps:from_list([{Sys, maps:get(hwm, broker_bench_sut:memory_kib(OsPid))}
                                || #{system := Sys, os_pid := OsPid} <- Ready]),
    Open = [{Sys, L, open_at(Sys, Pairs, maps:get(rate, maps:get(Sys, Closed)), L, Cfg, OsPid)}
            || L <- Loads, #{system := Sys, pairs := Pairs, os_pid := OsPid} <- Ready],
    Runs = [begin
                #{rss := Rss1, hwm := Hwm} = broker_bench_sut:memory_kib(OsPid),
                #{system => Sys, n => N, setup_ms => SetupMs, closed => maps:get(Sys, Closed),
                  open => [O || {S, _, O} <- Open, S =:= Sys],
                  memory_kib => #{rss_after_start => Rss0, rss_at_end => Rss1,
                                  peak_rss_closed => maps:get(Sys, HwmClosed),
                                  peak_rss => Hwm}}
            end || #{system := Sys, os_pid := OsPid, setup_ms := SetupMs, rss0 := Rss0} <- Ready],
    _ = [ok = broker_bench_gen:teardown(Pairs) || #{pairs := Pairs} <- Ready],
    Runs.

open_at(Sys, Pairs, Max, L, Cfg, OsPid) ->
    O = open_loop(Pairs, max(1.0, Max * L), Cfg, OsPid),
    io:format("   ~s open ~b%: ~s/s offered, p50 ~s ms, p99 ~s ms, p99.9 ~s ms "
              "(slowest 0.1 % due within ~s ms; generator's send lag max ~s ms)~n",
              [Sys, round(L * 100), int(maps:get(offered, O)), ms(maps:get(p50, O)),
               ms(maps:get(p99, O)), ms(maps:get(p999, O)), f1(maps:get(slow_span_ms, O)),
               ms(maps:get(send_lag_max, O))]),
    O#{load => L}.

rates(#{round_rates := Rs}) -> string:join([int(R) || R <- Rs], " / ").

%% Closed loop: every agent keeps one request in flight; the rate is
%% counted over the window after the warm-up.
closed_loop(Pairs, #{warmup := Warm, seconds := Secs}, OsPid) ->
    N = length(Pairs),
    C = counters:new(N, [write_concurrency]),
    Count = fun() -> lists:sum([counters:get(C, I) || I <- lists:seq(1, N)]) end,
    _ = [A ! {closed, C, 1} || #{agent := A} <- Pairs],
    timer:sleep(round(Warm * 1000)),
    S1 = snapshot(Count(), OsPid),
    timer:sleep(round(Secs * 1000)),
    S2 = snapshot(Count(), OsPid),
    _ = [A ! stop_loop || #{agent := A} <- Pairs],
    Drained = collect(Pairs, drained),
    Done = maps:get(count, S2) - maps:get(count, S1),
    (usage(S1, S2, Done))#{rate => Done / seconds(S1, S2), round_trips => Done,
                           errors => sum(errors, Drained) + sum(timeouts, Drained),
                           unanswered => sum(unanswered, Drained)}.

%% The closed-loop windows of one system as one: totals over all of them,
%% and each window's rate.
combine(Ws) ->
    Total = fun(K) -> lists:sum([maps:get(K, W) || W <- Ws]) end,
    Done = Total(round_trips),
    Secs = Total(seconds),
    (derive(Secs, Total(sut_s), Total(gen_s), Total(machine_s), Done))#{
      rate => Done / Secs, round_trips => Done, rounds => length(Ws),
      round_rates => [maps:get(rate, W) || W <- Ws],
      errors => Total(errors), unanswered => Total(unanswered)}.

%% Open loop at Rate round trips/s over all pairs: each agent on its own
%% fixed schedule, phases spread at random, latency from the scheduled time.
open_loop(Pairs, Rate, #{warmup := Warm, seconds := Secs}, OsPid) ->
    N = length(Pairs),
    Interval = max(1, round(N * 1.0e6 / Rate)),
    Start = erlang:monotonic_time(millisecond) + 200,
    From = Start + round(Warm * 1000),
    To = From + round(Secs * 1000),
    Plan = #{start => Start, interval => Interval, until => To,
             window => {From * 1000, To * 1000}},
    _ = [A ! {open, Plan#{phase => rand:uniform(Interval) - 1}} || #{agent := A} <- Pairs],
    sleep_until(From),
    S1 = snapshot(0, OsPid),
    sleep_until(To),
    S2 = snapshot(0, OsPid),
    Samples = collect(Pairs, samples),
    #{samples := Count} = Figures = evatar_bench_report:latency_figures(Samples, Secs),
    maps:merge(usage(S1, S2, Count),
               Figures#{offered => Rate, interval_us => Interval,
                        errors => sum(errors, Samples) + sum(timeouts, Samples),
                        unanswered => sum(unanswered, Samples)}).

sleep_until(Ms) ->
    timer:sleep(max(0, Ms - erlang:monotonic_time(millisecond))).

collect(Pairs, Tag) ->
    [receive {A, Tag, R} -> R
     after 60000 -> error({no_answer_from_agent, Tag})
     end || #{agent := A} <- Pairs].

sum(Key, Maps) -> lists:sum([maps:get(Key, M) || M <- Maps]).

%% CPU of the system under test, of this VM (the generator) and of the
%% whole machine, from /proc.
snapshot(Count, OsPid) ->
    {ok, Stat} = file:read_file("/proc/stat"),
    [CpuLine | _] = binary:split(Stat, <<"\n">>),
    [<<"cpu">> | Fields] = binary:split(CpuLine, <<" ">>, [global, trim_all]),
    Ticks = [binary_to_integer(X) || X <- Fields],
    Idle = lists:nth(4, Ticks) + lists:nth(5, Ticks),
    #{count => Count, t => erlang:monotonic_time(microsecond),
      sut => broker_bench_sut:cpu_ticks(OsPid),
      gen => broker_bench_sut:cpu_ticks(os:getpid()),
      busy => lists:sum(Ticks) - Idle, total => lists:sum(Ticks)}.

seconds(S1, S2) -> (maps:get(t, S2) - maps:get(t, S1)) / 1.0e6.

%% Cores used over the window, and the system's CPU seconds per 100,000
%% round trips (clock ticks are 1/100 s).
usage(S1, S2, RoundTrips) ->
    Secs = seconds(S1, S2),
    D = fun(K) -> maps:get(K, S2) - maps:get(K, S1) end,
    Machine = D(busy) / max(1, D(total)) * cpu_count() * Secs,
    derive(Secs, D(sut) / 100, D(gen) / 100, Machine, RoundTrips).

%% From CPU seconds over a window: cores used, and CPU seconds per 100,000
%% round trips.
derive(Secs, Sut, Gen, Machine, RoundTrips) ->
    Per100k = fun(_, 0) -> undefined;
                 (Cpu, K) -> Cpu / K * 100000
              end,
    #{seconds => Secs, sut_s => Sut, gen_s => Gen, machine_s => Machine,
      sut_cores => Sut / Secs, gen_cores => Gen / Secs,
      other_cores => max(0.0, (Machine - Sut - Gen) / Secs),
      cpu_s_per_100k => Per100k(Sut, RoundTrips),
      gen_cpu_s_per_100k => Per100k(Gen, RoundTrips)}.

%% ---------------------------------------------------------------------------
%% Profile of the EVATAR node under the closed loop
%% ---------------------------------------------------------------------------

profile(#{profile_n := N, profile_seconds := Secs, out := Out} = Cfg) ->
    io:format("~n-- profile: eprof on every process of the EVATAR node, closed loop, N = ~b, ~p s~n",
              [N, Secs]),
    Sut = broker_bench_sut:start(evatar, maps:get(run_dir, Cfg), Cfg),
    try
        Pairs = broker_bench_gen:setup(N, Sut),
        C = counters:new(N, [write_concurrency]),
        Count = fun() -> lists:sum([counters:get(C, I) || I <- lists:seq(1, N)]) end,
        _ = [A ! {closed, C, 1} || #{agent := A} <- Pairs],
        timer:sleep(1000),
        File = filename:absname(filename:join(Out, "eprof-brokers.txt")),
        ok = filelib:ensure_dir(File),
        C0 = Count(),
        T0 = erlang:monotonic_time(microsecond),
        ok = erpc:call(maps:get(node, Sut), broker_bench_sut, profile_node, [Secs, File, []],
                       round(Secs * 1000) + 600000),
        Rate = (Count() - C0) / ((erlang:monotonic_time(microsecond) - T0) / 1.0e6),
        _ = [A ! stop_loop || #{agent := A} <- Pairs],
        _ = collect(Pairs, drained),
        ok = broker_bench_gen:teardown(Pairs),
        #{file => list_to_binary(File), n => N, seconds => Secs,
          rate_while_profiling => Rate, top => top_functions(File, 15)}
    after
        broker_bench_sut:stop(Sut)
    end.

%% The largest rows of eprof's total analysis (sorted by time, ascending).
top_functions(File, K) ->
    {ok, Bin} = file:read_file(File),
    Rows = [L || L <- binary:split(Bin, <<"\n">>, [global]),
                 re:run(L, <<"^[a-z'][^ ]*:[^ ]+/[0-9]+ ">>) =/= nomatch],
    lists:sublist(lists:reverse(Rows), K).

%% ---------------------------------------------------------------------------
%% Ratios and goals
%% ---------------------------------------------------------------------------

%% Every figure of the table, by name, for one run.
figures(#{closed := C, open := Open, memory_kib := M}) ->
    maps:from_list(
      [{max_rate, maps:get(rate, C)},
       {cpu_s_per_100k, maps:get(cpu_s_per_100k, C)},
       {gen_cpu_s_per_100k, maps:get(gen_cpu_s_per_100k, C)},
       {peak_rss_closed_mib, maps:get(peak_rss_closed, M) / 1024},
       {peak_rss_mib, maps:get(peak_rss, M) / 1024},
       {rss_after_start_mib, maps:get(rss_after_start, M) / 1024}]
      ++ lists:append([[{open_key(L, offered), maps:get(offered, O)},
                        {open_key(L, p50_ms), ms_or_undef(maps:get(p50, O))},
                        {open_key(L, p99_ms), ms_or_undef(maps:get(p99, O))},
                        {open_key(L, p999_ms), ms_or_undef(maps:get(p999, O))},
                        {open_key(L, cpu_s_per_100k), maps:get(cpu_s_per_100k, O)},
                        {open_key(L, other_cores), maps:get(other_cores, O)},
                        {open_key(L, slow_span_ms), maps:get(slow_span_ms, O)},
                        {open_key(L, send_lag_max_ms), ms_or_undef(maps:get(send_lag_max, O))}]
                       || #{load := L} = O <- Open])).

open_key(L, What) ->
    list_to_atom(fmt("open~b_~s", [round(L * 100), What])).

ms_or_undef(undefined) -> undefined;
ms_or_undef(Us) -> Us / 1000.

find(Runs, Sys, N) ->
    case [R || #{system := S, n := M} = R <- Runs, S =:= Sys, M =:= N] of
        [R] -> R;
        [] -> undefined
    end.

ratio(A, B) when is_number(A), is_number(B), B > 0 -> A / B;
ratio(_, _) -> undefined.

%% For each N and each figure: EVATAR's divided by each peer's.
ratios(Runs, #{sizes := Sizes}) ->
    [maps:from_list([{n, N} | [{Key, ratio_map(find(Runs, evatar, N), find(Runs, Peer, N))}
                               || {Peer, Key} <- ?PEERS]])
     || N <- Sizes].

ratio_map(undefined, _) -> undefined;
ratio_map(_, undefined) -> undefined;
ratio_map(E, B) ->
    FE = figures(E),
    FB = figures(B),
    maps:map(fun(K, V) -> ratio(V, maps:get(K, FB, undefined)) end, FE).

%% The goals at every N: EVATAR at least 1.0x mosquitto's maximum, at most
%% its p99 at 50 % load and its CPU per round trip; at least 2x RabbitMQ's
%% maximum; CPU per round trip at most 1.0x NATS's at the smallest N and
%% within 1.3x of it at the larger ones.
goals(Runs, #{sizes := Sizes}) ->
    Smallest = lists:min(Sizes),
    Cpu = fun(FE, FB) -> ratio(maps:get(cpu_s_per_100k, FE), maps:get(cpu_s_per_100k, FB)) end,
    %% A goal against a system this run did not measure is left out.
    [G || G <- goals(Runs, Sizes, Smallest, Cpu), G =/= not_measured].

goals(Runs, Sizes, Smallest, Cpu) ->
    lists:append(
      [[goal(N, <<"max rt/s >= 1.0x mosquitto">>, E, M,
             fun(FE, FM) -> ratio(maps:get(max_rate, FE), maps:get(max_rate, FM)) end,
             fun(R) -> R >= 1.0 end),
        goal(N, <<"CPU per rt <= 1.0x mosquitto">>, E, M, Cpu, fun(R) -> R =< 1.0 end),
        goal(N, <<"p99 at 50% load <= mosquitto's">>, E, M,
             fun(FE, FM) -> ratio(maps:get(open50_p99_ms, FE, undefined),
                                  maps:get(open50_p99_ms, FM, undefined)) end,
             fun(R) -> R =< 1.0 end),
        goal(N, <<"max rt/s >= 2x RabbitMQ">>, E, Rb,
             fun(FE, FR) -> ratio(maps:get(max_rate, FE), maps:get(max_rate, FR)) end,
             fun(X) -> X >= 2.0 end),
        case N of
            Smallest -> goal(N, <<"CPU per rt <= 1.0x NATS">>, E, Na, Cpu, fun(R) -> R =< 1.0 end);
            _ -> goal(N, <<"CPU per rt <= 1.3x NATS">>, E, Na, Cpu, fun(R) -> R =< 1.3 end)
        end]
       || N <- Sizes,
          E <- [find(Runs, evatar, N)], M <- [find(Runs, mosquitto, N)],
          Rb <- [find(Runs, rabbitmq, N)], Na <- [find(Runs, nats, N)]]).

goal(N, What, E, B, Ratio, Ok) when E =/= undefined, B =/= undefined ->
    case Ratio(figures(E), figures(B)) of
        undefined -> #{n => N, goal => What, ratio => undefined, met => undefined};
        X -> #{n => N, goal => What, ratio => X, met => Ok(X)}
    end;
goal(_N, _What, _, _, _, _) ->
    not_measured.

%% ---------------------------------------------------------------------------
%% Markdown
%% ---------------------------------------------------------------------------

markdown(Date, Machine, Versions, Cfg, Runs, Ratios, Goals, Profile) ->
    Systems = maps:get(systems, Cfg),
    [io_lib:format("# EVATAR against brokers~s, ~s~n~n",
                   [case maps:get(transport, Cfg) of tcp -> ""; tls -> " over TLS" end, Date]),
     "Produced by `make bench-brokers` (scripts/bench-brokers.sh, bench/broker_bench.erl); how to\n"
     "read it: bench/README.md, section d.",
     case maps:get(quick, Cfg) of
         true -> " **QUICK smoke run: the figures are not meant to be read.**";
         false -> ""
     end, "\n\n",
     io_lib:format("- machine: ~s, ~b logical CPUs, ~b MiB, Linux ~s~n",
                   [maps:get(cpu_model, Machine), maps:get(cores, Machine),
                    maps:get(memory_mib, Machine), maps:get(kernel, Machine)]),
     io_lib:format("- load average (1, 5, 15 min) at start ~s, at end ~s~n",
                   [loads(maps:get(load_average_start, Machine)),
                    loads(maps:get(load_average_end, Machine))]),
     io_lib:format("- versions: OTP ~s (erts ~s), mosquitto ~s, RabbitMQ ~s, nats-server ~s, "
                   "EVATAR ~s~n",
                   [maps:get(otp, Versions), maps:get(erts, Versions),
                    maps:get(mosquitto, Versions), maps:get(rabbitmq, Versions),
                    maps:get(nats, Versions), maps:get(evatar, Versions)]),
     io_lib:format("- closed loop: ~p s per system in ~b rounds, the systems taking turns, each "
                   "round after ~p s warm-up; open loop: ~p s windows after ~p s warm-up, at ~s "
                   "of each system's own maximum, the systems taking turns; systems ~w; N ~w~n",
                   [maps:get(seconds, Cfg), maps:get(rounds, Cfg), maps:get(warmup, Cfg) / 2,
                    maps:get(seconds, Cfg), maps:get(warmup, Cfg),
                    string:join([fmt("~b%", [round(L * 100)]) || L <- maps:get(loads, Cfg)], ", "),
                    Systems, maps:get(sizes, Cfg)]),
     "- a round trip: the agent sends a BIL RequestAwaitingFeedback signal (~530 bytes) to its\n"
     "  device and counts the round trip when the device's Feedback (~500 bytes) comes back;\n"
     "  EVATAR through the bridge protocol (agent_bridge_client, a pairing per pair), the MQTT\n"
     "  brokers with MQTT 3.1.1 QoS 1 on a request topic and a response topic (mqtt_client),\n"
     "  nats-server with core NATS request-reply (a reply inbox, no acknowledgements;\n"
     "  broker_bench_nats)\n",
     case maps:get(transport, Cfg) of
         tcp -> "";
         tls -> "- transport: TLS (1.3 or 1.2, the clients check the server certificate against the\n"
                "  CA) to EVATAR's TLS bridge listener and mosquitto's TLS listener, both with the\n"
                "  same ECDSA P-256 certificate from scripts/gen-bridge-certs.sh\n"
     end,
     "- ratios are EVATAR's figure divided by the broker's: above 1 is better for EVATAR for\n"
     "  round trips/s, below 1 is better for latency, CPU and memory\n",
     [size_table(N, Systems, Runs, Ratios) || N <- maps:get(sizes, Cfg)],
     goals_table(Goals),
     profile_text(Profile)].

loads(L) -> string:join([fmt("~.2f", [X]) || X <- L], ", ").

size_table(N, Systems, Runs, Ratios) ->
    Rs = [find(Runs, S, N) || S <- Systems],
    RatioMap = hd([R || #{n := M} = R <- Ratios, M =:= N]),
    Peers = [{Peer, maps:get(Key, RatioMap)} || {Peer, Key} <- ?PEERS, has_both(Systems, Peer)],
    Header = ["figure (N = " ++ int(N) ++ ")" | [name(S) || S <- Systems]]
        ++ ["EVATAR/" ++ name(Peer) || {Peer, _} <- Peers],
    Keys = [{max_rate, "max round trips/s (closed loop)", fun evatar_bench_report:int/1},
            {cpu_s_per_100k, "CPU s per 100k round trips (closed loop)", fun f2/1},
            {gen_cpu_s_per_100k, "generator VM's CPU s per 100k round trips (closed loop)",
             fun f2/1},
            {peak_rss_closed_mib, "peak RSS, MiB (VmHWM: start, setup, closed loop)", fun f1/1},
            {peak_rss_mib, "peak RSS, MiB (VmHWM: the whole run at this N)", fun f1/1},
            {rss_after_start_mib, "RSS after start, before any client, MiB", fun f1/1}]
        ++ lists:append(
             [[{open_key(L, offered), fmt("open ~b%: offered round trips/s", [P]), fun evatar_bench_report:int/1},
               {open_key(L, p50_ms), fmt("open ~b%: p50 ms", [P]), fun f3/1},
               {open_key(L, p99_ms), fmt("open ~b%: p99 ms", [P]), fun f3/1},
               {open_key(L, p999_ms), fmt("open ~b%: p99.9 ms", [P]), fun f3/1},
               {open_key(L, cpu_s_per_100k), fmt("open ~b%: CPU s per 100k round trips", [P]),
                fun f2/1},
               %% Other processes' load and where the slowest requests
               %% fell are context, not figures of the system: no ratio.
               {open_key(L, other_cores), fmt("open ~b%: cores used by other processes", [P]),
                fun f2/1, no_ratio},
               {open_key(L, slow_span_ms),
                fmt("open ~b%: slowest 0.1 %, span of their due times, ms", [P]), fun f1/1,
                no_ratio},
               {open_key(L, send_lag_max_ms),
                fmt("open ~b%: generator's send lag, max ms", [P]), fun f3/1, no_ratio}]
              || #{open := Open} <- [hd([R || R <- Rs, R =/= undefined])],
                 #{load := L} <- Open, P <- [round(L * 100)]]),
    Fig = [case R of undefined -> #{}; _ -> figures(R) end || R <- Rs],
    Rows = [[Label | [Fmt(maps:get(K, F, undefined)) || F <- Fig]]
            ++ [ratio(Kind, PM, K) || {_, PM} <- Peers]
            || Key <- Keys, {K, Label, Fmt, Kind} <- [with_ratio(Key)]],
    Blank = blank(Systems),
    Context = [[["closed loop: round trips/s in each round" | [case R of
                                                                   undefined -> "-";
                                                                   #{closed := C} -> rates(C)
                                                               end || R <- Rs]] ++ Blank],
               context_row("closed loop: cores used by the system", Rs, sut_cores, Systems),
               context_row("closed loop: cores used by the generator VM", Rs, gen_cores, Systems),
               context_row("closed loop: cores used by other processes", Rs, other_cores, Systems),
               [["setup of N pairs, ms" | [case R of undefined -> "-";
                                               _ -> int(maps:get(setup_ms, R)) end || R <- Rs]]
                ++ Blank],
               [["errors + unanswered (all loops)" | [errors(R) || R <- Rs]] ++ Blank]],
    ["\n", evatar_bench_report:md_table(Header, Rows ++ lists:append(Context))].

%% A row of the size table is a figure with ratios unless marked no_ratio.
with_ratio({K, Label, Fmt}) -> {K, Label, Fmt, ratio};
with_ratio({_, _, _, no_ratio} = Row) -> Row.

ratio(ratio, M, K) -> f2(rget(M, K));
ratio(no_ratio, _M, _K) -> "".

%% The empty ratio cells of a context row.
blank(Systems) ->
    ["" || {Peer, _} <- ?PEERS, has_both(Systems, Peer)].

context_row(Label, Rs, Key, Systems) ->
    [[Label | [case R of
                   undefined -> "-";
                   #{closed := C} -> f2(maps:get(Key, C))
               end || R <- Rs]]
     ++ blank(Systems)].

errors(undefined) -> "-";
errors(#{closed := C, open := Open}) ->
    int(lists:sum([maps:get(errors, X) + maps:get(unanswered, X) || X <- [C | Open]])).

has_both(Systems, Broker) ->
    lists:member(evatar, Systems) andalso lists:member(Broker, Systems).

rget(undefined, _) -> undefined;
rget(M, K) -> maps:get(K, M, undefined).

name(evatar) -> "EVATAR";
name(mosquitto) -> "mosquitto";
name(rabbitmq) -> "RabbitMQ";
name(nats) -> "NATS".

goals_table([]) -> [];
goals_table(Goals) ->
    ["\n## Goals\n\n",
     evatar_bench_report:md_table(
       ["N", "goal", "EVATAR/broker", "result"],
       [[int(N), binary_to_list(G), f2(R),
         case Met of true -> "MET"; false -> "NOT MET"; undefined -> "-" end]
        || #{n := N, goal := G, ratio := R, met := Met} <- Goals])].

profile_text(undefined) -> [];
profile_text(#{file := File, n := N, seconds := Secs, rate_while_profiling := Rate, top := Top}) ->
    [io_lib:format("~n## Profile of the EVATAR node~n~neprof over every process of the EVATAR node "
                   "for ~p s of closed loop at N = ~b (~s round trips/s while traced: eprof "
                   "slows what it traces, read the shares); full listing in ~s. Top ~b "
                   "functions by time:~n~n",
                   [Secs, N, int(Rate), filename:basename(File), length(Top)]),
     "```\nFUNCTION                                       CALLS        %     TIME  [uS / CALLS]\n",
     [[L, "\n"] || L <- Top], "```\n"].

f1(undefined) -> "-";
f1(X) -> fmt("~.1f", [float(X)]).

f2(undefined) -> "-";
f2(X) -> fmt("~.2f", [float(X)]).

f3(undefined) -> "-";
f3(X) -> fmt("~.3f", [float(X)]).

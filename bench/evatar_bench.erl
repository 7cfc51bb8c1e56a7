%% @doc The mediator benchmark (issue 3, section 7): on one node, N pairings
%% (1, 100, 1000), each a VA and an Avatar over loopback TCP through
%% agent_bridge, doing request-feedback round trips: the closed-loop
%% maximum, latency percentiles in an open loop at half of it, memory per
%% pairing; then the memory of idle bound pairings with 10,000 pairings
%% live. Prints tables with the targets side by side and writes JSON and
%% markdown under bench/results/. Not part of the product; see
%% bench/EVATAR_BENCH.md for how to run it and how to read it.
-module(evatar_bench).

-export([main/0, main/1]).
%% For flood_bench, which measures on the same system under test.
-export([start/1, environment/1, closed_loop/3, open_loop/4, teardown/2, gc_all/0]).

-export_type([option/0]).

-import(evatar_bench_report, [fmt/2, int/1, kib/1, ms/1]).

%% `quick': a smoke run (N in 1 and 100, short windows, 500 idle
%% pairings); the figures are not meant to be read.
-type option() :: quick | no_idle | no_load | profile
                | {sizes, [pos_integer()]}
                | {modes, [evatar_bench_gen:mode() | split]}
                | {seconds, number()}          % closed and open measuring windows
                | {warmup, number()}           % before each window
                | {inflight, pos_integer()}    % W, requests in flight per VA (closed loop)
                | {idle, non_neg_integer()}    % idle pairings live
                | {rounds, pos_integer()}      % runs of the target rows (raw, client at N = 1,000)
                | {out, file:filename()}       % results directory
                %% Each size and mode again with W live-tail watchers per
                %% pairing (evatar_tap), alternated, `rounds' times: the
                %% dashboard's cost on routing (docs/dashboard.md).
                | {watch, [non_neg_integer()]}.

-define(TARGET_RATE, 20000).
-define(TARGET_N, 1000).
-define(TARGET_P99_US, 2000).
-define(JOIN_WORKERS, 32).

%% ---------------------------------------------------------------------------
%% Entry points
%% ---------------------------------------------------------------------------

%% @equiv main([])
-spec main() -> ok.
main() -> main([]).

%% @doc Runs the benchmark in this node and prints its tables.
-spec main([option()]) -> ok.
main(Options) ->
    ok = io:setopts([{encoding, unicode}]),
    Cfg = config(Options),
    %% The second node also holds the idle clients' sockets: with both ends
    %% in one OS process, its file-descriptor limit halves what fits.
    %% Distribution starts before EVATAR does: the pairings' catalogue is an
    %% mnesia table of this node's name, which a later net_kernel:start/1
    %% would change.
    WantGen = lists:member(split, maps:get(modes, Cfg)) orelse maps:get(idle, Cfg) > 0,
    Dist = case WantGen of
               true -> start_distribution();
               false -> off
           end,
    Ctx0 = start(Cfg),
    {Ctx, Cfg1} = case Dist of
                      off -> {Ctx0, Cfg};
                      _ -> gen_node(Ctx0, Cfg, Dist)
                  end,
    Env = environment(Ctx),
    print_header(Cfg1, Env),
    Costs = costs(),
    Loaded = case maps:get(load, Cfg1) of
                 true -> [run_size(N, Mode, Cfg1, Ctx) || Mode <- maps:get(modes, Cfg1),
                                                         N <- maps:get(sizes, Cfg1)];
                 false -> []
             end,
    %% One run says little about the targets: the same code gives rates
    %% 30 % apart from one run to the next on this two-core machine
    %% (EVATAR_BENCH.md, "Run-to-run spread"). The target rows are run
    %% `rounds' times; the targets are judged on the medians.
    Rounds = Loaded ++
        [(run_size(?TARGET_N, Mode, Cfg1, Ctx))#{round => K}
         || maps:get(load, Cfg1), lists:member(?TARGET_N, maps:get(sizes, Cfg1)),
            K <- lists:seq(2, maps:get(rounds, Cfg1)),
            Mode <- maps:get(modes, Cfg1), Mode =:= raw orelse Mode =:= client],
    Profile = case maps:get(profile, Cfg1) of
                  true -> profile(Cfg1, Ctx);
                  false -> undefined
              end,
    Idle = case maps:get(idle, Cfg1) of
               0 -> undefined;
               IdleN -> idle(IdleN, Ctx)
           end,
    Targets = targets(Rounds),
    Watched = watched(Cfg1, Ctx),
    Text = [summary(Cfg1, Env, Costs, Loaded, Idle, Targets, Profile), watch_table(Watched)],
    io:put_chars(["\n", Text]),
    Results = #{environment => Env,
                config => Cfg1#{out := unicode:characters_to_binary(maps:get(out, Cfg1))},
                costs => Costs,
                loaded => Loaded, idle => Idle, targets => Targets, watched => Watched,
                profile => Profile},
    {Json, Md} = evatar_bench_report:write(maps:get(out, Cfg1), Results,
                                            markdown(Env, Text)),
    io:format("~nResults written to ~s and ~s~n", [Json, Md]),
    _ = [peer:stop(Peer) || #{gen := #{peer := Peer}} <- [Ctx]],
    ok.

config(Options) ->
    Quick = lists:member(quick, Options),
    Default = case Quick of
                  true -> #{sizes => [1, 100], seconds => 2, warmup => 0.5, idle => 500,
                            rounds => 1};
                  false -> #{sizes => [1, 100, 1000], seconds => 8, warmup => 2, idle => 10000,
                             rounds => 3}
              end,
    Cfg = lists:foldl(fun({K, V}, Acc) -> Acc#{K => V};
                         (_, Acc) -> Acc
                      end, Default#{modes => [direct, floor, codec, raw, split, client],
                                    inflight => 1,
                                    out => "bench/results"}, Options),
    Cfg#{quick => Quick,
         idle => case lists:member(no_idle, Options) of
                     true -> 0;
                     false -> maps:get(idle, Cfg)
                 end,
         load => not lists:member(no_load, Options),
         profile => lists:member(profile, Options)}.

%% ---------------------------------------------------------------------------
%% The system under test
%% ---------------------------------------------------------------------------

%% @doc Starts EVATAR in this node with the benchmark's listener (no
%% connection limits, no read rate; `conn' of Cfg: its connection options); returns its
%% address and connection supervisor.
-spec start(map()) -> #{addr := {inet:ip_address(), inet:port_number()}, conn_sup := pid(),
                        floor := term()}.
start(Cfg) ->
    %% Logging at info for 10,000 joins would measure the logger.
    ok = logger:set_primary_config(level, warning),
    ok = application:set_env(agent_bridge, listeners, []),
    {ok, _} = application:ensure_all_started(agent_bridge),
    {ok, _} = application:ensure_all_started(runtime_tools),
    {ok, Keeper} = agent_bridge:start_listener(evatar_bench,
                                             #{ip => {127, 0, 0, 1}, port => 0,
                                               acceptors => 8, backlog => 4096,
                                               %% thousands of clients from one
                                               %% address: no guard limits
                                               max_connections => infinity,
                                               handshake => #{rate => infinity},
                                               %% one client per pairing end, as fast
                                               %% as it goes: no read rate (docs/
                                               %% protocol.md section 8)
                                               conn => maps:merge(#{max_read_rate => infinity},
                                                                  maps:get(conn, Cfg, #{}))}),
    {ok, Addr} = agent_bridge:address(evatar_bench),
    _ = erlang:system_flag(scheduler_wall_time, true),
    LSup = agent_bridge_listener_keeper:listener_sup(Keeper),
    #{addr => Addr, conn_sup => agent_bridge_listener_sup:conn_sup(LSup),
      floor => evatar_bench_floor:listen()}.

%% @doc The machine, the VM and the listener, for the results.
-spec environment(#{addr := {inet:ip_address(), inet:port_number()}, _ => _}) -> map().
environment(#{addr := {Ip, Port}}) ->
    #{otp => list_to_binary(erlang:system_info(otp_release)),
      erts => list_to_binary(erlang:system_info(version)),
      schedulers => erlang:system_info(schedulers_online),
      cpus => erlang:system_info(logical_processors_available),
      arch => list_to_binary(erlang:system_info(system_architecture)),
      max_fds => max_fds(),
      port_limit => erlang:system_info(port_limit),
      process_limit => erlang:system_info(process_limit),
      load_average => loadavg(),
      listener => list_to_binary(fmt("~s:~b", [inet:ntoa(Ip), Port])),
      date => list_to_binary(calendar:system_time_to_rfc3339(os:system_time(second)))}.

max_fds() ->
    case erlang:system_info(check_io) of
        [First | _] when is_list(First) -> proplists:get_value(max_fds, First, undefined);
        Info when is_list(Info) -> proplists:get_value(max_fds, Info, undefined)
    end.

used_fds() ->
    case file:list_dir("/proc/self/fd") of
        {ok, Fds} -> length(Fds);
        {error, _} -> 100
    end.

loadavg() ->
    case file:read_file("/proc/loadavg") of
        {ok, B} -> [binary_to_float(X) || X <- lists:sublist(binary:split(B, <<" ">>, [global]), 3)];
        {error, _} -> undefined
    end.

%% The `split' generator runs in a second node, a peer OS process on the
%% same machine, so that this node's CPU is EVATAR's alone. Distribution
%% is started for it; without epmd the mode is dropped with a note.
start_distribution() ->
    _ = os:cmd("epmd -daemon"),
    Name = list_to_atom("evatar_bench_" ++ os:getpid()),
    case net_kernel:start([Name, shortnames]) of
        {ok, _} -> ok;
        {error, {already_started, _}} -> ok;
        {error, Why} -> {error, Why}
    end.

gen_node(Ctx, Cfg, Started) ->
    case Started of
        ok ->
            OtpLib = code:lib_dir(),
            Paths = [P || P <- code:get_path(), not lists:prefix(OtpLib, P)],
            {ok, Peer, Node} = peer:start_link(#{name => peer:random_name(evatar_bench_gen),
                                                 args => ["+P", "2000000"]
                                                     ++ lists:append([["-pa", P] || P <- Paths]),
                                                 wait_boot => 30000}),
            OsPid = erpc:call(Node, os, getpid, []),
            {Ctx#{gen => #{node => Node, os_pid => OsPid, peer => Peer}}, Cfg};
        {error, Reason} ->
            io:format("NOTE: cannot start distribution (~p): the split generator is skipped~n",
                      [Reason]),
            {Ctx, Cfg#{modes => maps:get(modes, Cfg) -- [split]}}
    end.

%% ---------------------------------------------------------------------------
%% The work EVATAR does per round trip, one function at a time
%% ---------------------------------------------------------------------------

%% Microseconds per call of each step of EVATAR's hot path, in this
%% process: the fastest of 5 batches, since other load only adds time.
costs() ->
    {VaDesc, AvDesc} = evatar_bench_gen:descriptions(1, <<"cost">>),
    #{entity_id := VaId} = VaDesc,
    #{entity_id := AvId} = AvDesc,
    #{agent_credential := AgCred, avatar_credential := AvCred} = evatar_bench_gen:credentials(),
    {ok, Config} = evatar_pairing_logic:config(evatar_bench_gen:credentials()),
    Now = erlang:system_time(millisecond),
    Bound = lists:foldl(fun(E, St) -> element(1, evatar_pairing_logic:handle(E, Now, St)) end,
                        evatar_pairing_logic:new(<<"cost">>, Config),
                        [{join, avatar, AvId, AvCred}, {describe, AvId, AvDesc},
                         {join, agent, VaId, AgCred}, {describe, VaId, VaDesc}]),
    Request = #{id => <<"q123456">>, context => request, sender => <<"LightEmulator01">>,
                receiver => <<"HomeLightActuator01">>, in_reply_to => undefined,
                timestamp => os:system_time(millisecond), seq => undefined, epoch => undefined,
                body => evatar_bench_gen:request_body()},
    Feedback = Request#{id => <<"fb-q123456">>, context => feedback,
                        sender => <<"HomeLightActuator01">>, receiver => <<"LightEmulator01">>,
                        in_reply_to => <<"q123456">>, body => evatar_bench_gen:feedback_body()},
    ReqFrame = iolist_to_binary(bil:encode_signal(Request)),
    FbFrame = iolist_to_binary(bil:encode_signal(Feedback)),
    Delivered = Request#{seq => 12345, epoch => 1},
    %% One request and its feedback through the pure logic, back to the
    %% same state, so the loop can repeat it.
    Logic = fun() ->
                    {St1, _} = evatar_pairing_logic:handle({signal, VaId, Request}, Now, Bound),
                    evatar_pairing_logic:handle({signal, AvId, Feedback}, Now, St1)
            end,
    {_, [{deliver, AvId, _} | _]} = evatar_pairing_logic:handle({signal, VaId, Request}, Now,
                                                                 Bound),
    Rows = [{parse_request, fun() -> bil_control:parse_frame(ReqFrame, #{}) end},
            {parse_feedback, fun() -> bil_control:parse_frame(FbFrame, #{}) end},
            {encode_signal, fun() -> iolist_size(bil:encode_signal(Delivered)) end},
            {logic_request_and_feedback, Logic}],
    Us = maps:from_list([{Name, best_us(F)} || {Name, F} <- Rows]),
    Us#{request_bytes => byte_size(ReqFrame), feedback_bytes => byte_size(FbFrame),
        work_per_round_trip => maps:get(parse_request, Us) + maps:get(parse_feedback, Us)
            + 2 * maps:get(encode_signal, Us) + maps:get(logic_request_and_feedback, Us)}.

best_us(F) ->
    Batch = 2000,
    lists:min([begin
                   {T, ok} = timer:tc(fun() -> repeat(F, Batch) end),
                   T / Batch
               end || _ <- lists:seq(1, 5)]).

repeat(_F, 0) -> ok;
repeat(F, K) -> _ = F(), repeat(F, K - 1).

%% ---------------------------------------------------------------------------
%% One size: N loaded pairings
%% ---------------------------------------------------------------------------

run_size(N, Mode, Cfg, #{addr := Addr, conn_sup := ConnSup, floor := Floor} = Ctx) ->
    Gen = case Mode of
              split -> maps:get(gen, Ctx);
              _ -> local
          end,
    io:format("~n-- ~s generator, N = ~b: setting up ~b pairings (~b TCP connections)...~n",
              [Mode, N, N, 2 * N]),
    gc_all(),
    M0 = erlang:memory(total),
    T0 = erlang:monotonic_time(millisecond),
    IsFloor = lists:member(Mode, evatar_bench_floor:kinds()),
    Pairs = if
                Mode =:= split -> evatar_bench_gen:setup(N, raw, Addr, maps:get(node, Gen));
                IsFloor -> evatar_bench_gen:setup(N, Mode, Floor);
                true -> evatar_bench_gen:setup(N, Mode, Addr)
            end,
    SetupMs = erlang:monotonic_time(millisecond) - T0,
    gc_all(),
    M1 = erlang:memory(total),
    Groups1 = groups(classify()),
    Ctx1 = Ctx#{watch_pids => [watcher(Id) || #{id := Id} <- Pairs,
                                              _ <- lists:seq(1, maps:get(watch, Cfg, 0))]},
    io:format("   bound in ~b ms (~b tail watchers); closed loop...~n",
              [SetupMs, length(maps:get(watch_pids, Ctx1))]),
    Closed = closed_loop(Pairs, Cfg, Gen),
    M2 = erlang:memory(total),
    Groups2 = groups(classify()),
    Rate = maps:get(rate, Closed),
    io:format("   ~s round trips/s; open loop at ~s/s...~n", [int(Rate), int(Rate / 2)]),
    Open = open_loop(Pairs, max(1.0, Rate / 2), Cfg, Gen),
    Stats = case IsFloor of
                true -> #{};
                false -> pairing_stats(Pairs)
            end,
    Watchers = maps:get(watch_pids, Ctx1),
    Tailed = lists:sum([tailed(W) || W <- Watchers]),
    ok = teardown(Pairs, ConnSup),
    io:format("   p50 ~s ms, p99 ~s ms, p99.9 ~s ms~n",
              [ms(maps:get(p50, Open)), ms(maps:get(p99, Open)), ms(maps:get(p999, Open))]),
    #{mode => Mode, n => N, setup_ms => SetupMs, watch => maps:get(watch, Cfg, 0),
      tailed => Tailed,
      closed => Closed, open => Open, pairing_stats => Stats,
      memory => #{after_setup => per_pairing(M1 - M0, Groups1, N),
                  after_load => per_pairing(M2 - M0, Groups2, N)}}.

%% A live-tail watcher of one pairing, as an event stream of the dashboard
%% is: it takes every item (acknowledging as evatar_tap:handle/2 does) and
%% counts them.
watcher(PairingId) ->
    Parent = self(),
    Pid = spawn(fun() ->
                        {ok, Sub} = evatar_tap:watch(PairingId, #{}),
                        Parent ! {watching, self()},
                        watch_loop(Sub, 0)
                end),
    receive {watching, Pid} -> Pid after 10000 -> error({no_watcher, PairingId}) end.

watch_loop(Sub, N) ->
    receive
        {count, From} ->
            From ! {tailed, self(), N};
        Msg ->
            case evatar_tap:handle(Msg, Sub) of
                {items, Items, Sub1} -> watch_loop(Sub1, N + length(Items));
                ignore -> watch_loop(Sub, N)
            end
    end.

%% The items a watcher took; it ends.
tailed(Pid) ->
    Pid ! {count, self()},
    receive {tailed, Pid, N} -> N after 10000 -> 0 end.

%% The sizes and modes again with and without watchers, alternated.
watched(#{watch := Ws} = Cfg, Ctx) ->
    [(run_size(N, Mode, Cfg#{watch => W}, Ctx))#{round => K}
     || K <- lists:seq(1, maps:get(rounds, Cfg)), N <- maps:get(sizes, Cfg),
        Mode <- maps:get(modes, Cfg), Mode =/= split,
        not lists:member(Mode, evatar_bench_floor:kinds()), W <- Ws];
watched(_Cfg, _Ctx) ->
    [].

watch_table([]) ->
    [];
watch_table(Runs) ->
    ["\n## The live tail's cost (watchers per pairing, alternated)\n\n",
     "| mode | N | round | watchers | items tailed | round trips/s | 1/rate µs | "
     "open loop p50 ms | p99 ms |\n|---|---|---|---|---|---|---|---|---|\n",
     [fmt("| ~s | ~b | ~b | ~b | ~s | ~s | ~.1f | ~s | ~s |~n",
          [Mode, N, K, W, int(T), int(maps:get(rate, C)), 1.0e6 / max(1.0, maps:get(rate, C)),
           ms(maps:get(p50, O)), ms(maps:get(p99, O))])
      || #{mode := Mode, n := N, round := K, watch := W, tailed := T, closed := C, open := O}
             <- Runs]].

%% Memory per pairing from a node delta and the process groups.
per_pairing(Delta, Groups, N) ->
    G = fun(Class, Key) -> maps:get(Key, maps:get(Class, Groups, #{}), 0) / N end,
    #{node_total => Delta / N,
      pairing_procs => G(pairing, memory),
      conn_procs => G(connection, memory),
      server_sockets => G(connection, port_memory),
      client_procs => G(client, memory) + G(generator, memory),
      client_sockets => G(client, port_memory) + G(generator, port_memory)}.

%% @doc Closed loop: every VA keeps W requests in flight; throughput is
%% counted over the window after the warm-up. Gen: `local', or the
%% generator's node.
-spec closed_loop([evatar_bench_gen:pair()], #{inflight := pos_integer(), warmup := number(),
                                               seconds := number(), _ => _},
                  local | map()) -> map().
closed_loop(Pairs, #{inflight := W, warmup := Warm, seconds := Secs}, Gen) ->
    N = length(Pairs),
    %% A counters reference works only on the node that made it.
    {Counters, Count} =
        case Gen of
            local ->
                C = counters:new(N, [write_concurrency]),
                {C, fun() -> lists:sum([counters:get(C, I) || I <- lists:seq(1, N)]) end};
            #{node := Node} ->
                Key = {evatar_bench_counters, erlang:unique_integer([positive])},
                ok = erpc:call(Node, evatar_bench_gen, new_counters, [Key, N]),
                {{persistent, Key}, fun() -> erpc:call(Node, evatar_bench_gen, count, [Key]) end}
        end,
    Classes = classify(),
    _ = [Va ! {closed, Counters, W} || #{va := Va} <- Pairs],
    timer:sleep(round(Warm * 1000)),
    S1 = snapshot(Count, Classes, Gen),
    timer:sleep(round(Secs * 1000)),
    S2 = snapshot(Count, Classes, Gen),
    _ = [Va ! stop_loop || #{va := Va} <- Pairs],
    Drained = collect(Pairs, drained),
    Done = maps:get(count, S2) - maps:get(count, S1),
    Seconds = (maps:get(t, S2) - maps:get(t, S1)) / 1.0e6,
    (usage(S1, S2))#{rate => Done / Seconds, round_trips => Done, seconds => Seconds,
                     inflight => W,
                     errors => sum(errors, Drained), timeouts => sum(timeouts, Drained),
                     unanswered => sum(unanswered, Drained)}.

%% @doc Open loop at Rate round trips/s over all pairings: each VA sends on
%% its own fixed schedule, latency counted from the scheduled time.
-spec open_loop([evatar_bench_gen:pair()], number(),
                #{warmup := number(), seconds := number(), _ => _}, local | map()) -> map().
open_loop(Pairs, Rate, #{warmup := Warm, seconds := Secs}, Gen) ->
    N = length(Pairs),
    Interval = max(1, round(N * 1.0e6 / Rate)),
    Start = erlang:monotonic_time(millisecond) + 200,
    From = Start + round(Warm * 1000),
    To = From + round(Secs * 1000),
    Plan = #{start => Start, interval => Interval, until => To, window => {From * 1000, To * 1000}},
    _ = [Va ! {open, Plan#{phase => rand:uniform(Interval) - 1}} || #{va := Va} <- Pairs],
    Classes = classify(),
    sleep_until(From),
    S1 = snapshot(fun() -> 0 end, Classes, Gen),
    sleep_until(To),
    S2 = snapshot(fun() -> 0 end, Classes, Gen),
    Samples = collect(Pairs, samples),
    Figures = evatar_bench_report:latency_figures(Samples, Secs),
    maps:merge(usage(S1, S2),
               Figures#{offered => Rate, interval_us => Interval, seconds => Secs,
                        errors => sum(errors, Samples), timeouts => sum(timeouts, Samples),
                        unanswered => sum(unanswered, Samples)}).

sleep_until(Ms) ->
    timer:sleep(max(0, Ms - erlang:monotonic_time(millisecond))).

collect(Pairs, Tag) ->
    [receive {Va, Tag, R} -> R
     after 60000 -> error({no_answer_from_va, Tag})
     end || #{va := Va} <- Pairs].

sum(Key, Maps) -> lists:sum([maps:get(Key, M) || M <- Maps]).

%% Everything the pairings counted: the routing is checked, not assumed.
pairing_stats(Pairs) ->
    lists:foldl(
      fun(#{id := Id}, Acc) ->
              {ok, S} = evatar:stats(Id),
              #{routed := Routed, errors := Errors} = S,
              Acc1 = maps:fold(fun(Ctx, V, A) -> add({routed, Ctx}, V, A) end, Acc, Routed),
              Acc2 = maps:fold(fun(C, V, A) -> add({error, C}, V, A) end, Acc1, Errors),
              lists:foldl(fun(K, A) -> add(K, maps:get(K, S), A) end, Acc2,
                          [timeouts, late_feedback, provider_gone, dropped])
      end, #{}, Pairs).

add({Kind, Sub}, V, Acc) ->
    Key = iolist_to_binary([atom_to_binary(Kind), "_", to_bin(Sub)]),
    maps:update_with(Key, fun(X) -> X + V end, V, Acc);
add(K, V, Acc) ->
    maps:update_with(atom_to_binary(K), fun(X) -> X + V end, V, Acc).

to_bin(A) when is_atom(A) -> atom_to_binary(A);
to_bin(B) when is_binary(B) -> B.

%% @doc Stops the generator's processes of Pairs, deletes the pairings,
%% and waits until no connection or pairing is left.
-spec teardown([evatar_bench_gen:pair()], pid()) -> ok.
teardown(Pairs, ConnSup) ->
    %% The generator goes first, and is waited for (it may be on another
    %% node), so no client sees its pairing deleted under it.
    Gen = [{P, monitor(process, P)} || #{va := Va, avatar := Av} <- Pairs, P <- [Va, Av]],
    _ = [exit(P, shutdown) || {P, _} <- Gen],
    _ = [receive {'DOWN', Ref, process, P, _} -> ok after 10000 -> error({not_stopped, P}) end
         || {P, Ref} <- Gen],
    _ = [exit(P, kill) || #{relays := Relays} <- Pairs, P <- Relays],
    _ = [evatar:delete_pairing(Id) || #{id := Id} = P <- Pairs, not is_map_key(relays, P)],
    wait_empty(ConnSup, 3000).

wait_empty(_ConnSup, 0) ->
    error(connections_left_over);
wait_empty(ConnSup, Tries) ->
    Conns = proplists:get_value(active, supervisor:count_children(ConnSup)),
    Pairings = proplists:get_value(active, supervisor:count_children(evatar_pairings_sup)),
    case Conns + Pairings of
        0 -> ok;
        _ -> timer:sleep(10), wait_empty(ConnSup, Tries - 1)
    end.

%% ---------------------------------------------------------------------------
%% Where the CPU goes during a window
%% ---------------------------------------------------------------------------

snapshot(Count, Classes, Gen) ->
    Msacc = case erlang:statistics(microstate_accounting) of
                undefined -> undefined;
                M -> M
            end,
    S = #{count => Count(), t => erlang:monotonic_time(microsecond),
          swt => erlang:statistics(scheduler_wall_time),
          reductions => reductions(Classes), msacc => Msacc,
          proc => proc_cpu(case Gen of
                               local -> undefined;
                               #{os_pid := P} -> P
                           end)},
    %% Micro-state accounting runs only inside windows.
    _ = erlang:system_flag(microstate_accounting, true),
    _ = erlang:system_flag(microstate_accounting, reset),
    S.

usage(S1, S2) ->
    Secs = (maps:get(t, S2) - maps:get(t, S1)) / 1.0e6,
    Scheds = erlang:system_info(schedulers),
    Util = case {maps:get(swt, S1), maps:get(swt, S2)} of
               {W1, W2} when is_list(W1), is_list(W2) ->
                   Pairs = [{A2 - A1, T2 - T1}
                            || {I, A1, T1} <- W1, I =< Scheds,
                               {J, A2, T2} <- W2, J =:= I],
                   lists:sum([A || {A, _} <- Pairs]) / max(1, lists:sum([T || {_, T} <- Pairs]));
               _ ->
                   undefined
           end,
    R1 = maps:get(reductions, S1),
    R2 = maps:get(reductions, S2),
    Red = maps:map(fun(Class, V2) -> V2 - maps:get(Class, R1, 0) end, R2),
    TotalRed = max(1, lists:sum(maps:values(Red))),
    _ = erlang:system_flag(microstate_accounting, false),
    #{scheduler_utilisation => Util,
      reductions_share => maps:map(fun(_, V) -> V / TotalRed end, Red),
      msacc => msacc(maps:get(msacc, S2)),
      cpu => cpu(maps:get(proc, S1), maps:get(proc, S2), Secs)}.

%% Sums of the reductions of each class of process: a measure of the
%% Erlang work each does (not of time spent in system calls).
reductions(Classes) ->
    maps:fold(fun(Pid, Class, Acc) ->
                      case erlang:process_info(Pid, reductions) of
                          {reductions, R} -> maps:update_with(Class, fun(X) -> X + R end, R, Acc);
                          undefined -> Acc
                      end
              end, #{}, Classes).

%% Share of the normal schedulers' time in each micro-state.
msacc(undefined) -> undefined;
msacc(Threads) ->
    Sums = lists:foldl(fun(#{type := scheduler, counters := C}, Acc) ->
                               maps:fold(fun(K, V, A) -> maps:update_with(K, fun(X) -> X + V end,
                                                                          V, A) end, Acc, C);
                          (_, Acc) -> Acc
                       end, #{}, Threads),
    Total = max(1, lists:sum(maps:values(Sums))),
    maps:map(fun(_, V) -> V / Total end, Sums).

%% CPU time of this OS process, of the generator's node when it has its
%% own (`split'), and of the whole machine, from /proc (Linux), so a busy
%% machine shows in the figures.
proc_cpu(GenOsPid) ->
    try
        {Utime, Stime} = os_cpu("self"),
        GenTime = case GenOsPid of
                      undefined -> 0;
                      _ -> {GU, GS} = os_cpu(GenOsPid), GU + GS
                  end,
        {ok, Stat} = file:read_file("/proc/stat"),
        [CpuLine | _] = binary:split(Stat, <<"\n">>),
        [<<"cpu">> | Fields1] = binary:split(CpuLine, <<" ">>, [global, trim_all]),
        Ticks = [binary_to_integer(X) || X <- Fields1],
        Idle = lists:nth(4, Ticks) + lists:nth(5, Ticks),
        #{self => Utime + Stime, sys => Stime, gen => GenTime, busy => lists:sum(Ticks) - Idle,
          total => lists:sum(Ticks), waits => sched_waits()}
    catch
        _:_ -> undefined
    end.

%% How often this node's normal scheduler threads blocked in the kernel
%% (voluntary context switches, summed): a scheduler with no work sleeps,
%% and one that meets a contended lock waits. Few in a saturated closed
%% loop; many in the slow runs (EVATAR_BENCH.md, "Run-to-run spread").
sched_waits() ->
    {ok, Tasks} = file:list_dir("/proc/self/task"),
    lists:sum([voluntary_switches(T) || T <- Tasks, is_scheduler_thread(T)]).

is_scheduler_thread(Tid) ->
    case file:read_file("/proc/self/task/" ++ Tid ++ "/comm") of
        {ok, Comm} -> string:find(Comm, "_scheduler") =/= nomatch;
        {error, _} -> false
    end.

voluntary_switches(Tid) ->
    case file:read_file("/proc/self/task/" ++ Tid ++ "/status") of
        {ok, Status} ->
            case re:run(Status, "\\nvoluntary_ctxt_switches:\\s*(\\d+)",
                        [{capture, all_but_first, binary}]) of
                {match, [N]} -> binary_to_integer(N);
                nomatch -> 0
            end;
        {error, _} -> 0
    end.

%% User and system clock ticks of an OS process.
os_cpu(Pid) ->
    {ok, Stat} = file:read_file("/proc/" ++ Pid ++ "/stat"),
    [_, AfterComm] = binary:split(Stat, <<") ">>),
    Fields = binary:split(AfterComm, <<" ">>, [global]),
    %% utime and stime are fields 14 and 15; 12 and 13 after the comm.
    {binary_to_integer(lists:nth(12, Fields)), binary_to_integer(lists:nth(13, Fields))}.

%% In cores: this node's CPU use, every other process's, and the machine's.
cpu(#{self := S1, sys := Y1, gen := G1, busy := B1, total := T1, waits := W1},
    #{self := S2, sys := Y2, gen := G2, busy := B2, total := T2, waits := W2}, Secs) ->
    Cpus = erlang:system_info(logical_processors_available),
    Ncpu = case is_integer(Cpus) of true -> Cpus; false -> 2 end,
    Self = (S2 - S1) / 100 / Secs,
    Machine = (B2 - B1) / max(1, T2 - T1) * Ncpu,
    Gen = (G2 - G1) / 100 / Secs,
    #{node_cores => Self, gen_cores => Gen, other_cores => max(0.0, Machine - Self - Gen),
      machine_cores => Machine,
      node_sys_share => (Y2 - Y1) / max(1, S2 - S1), cores => Ncpu,
      %% Per scheduler thread and second.
      sched_waits => (W2 - W1) / Secs / erlang:system_info(schedulers)};
cpu(_, _, _) ->
    undefined.

%% ---------------------------------------------------------------------------
%% Processes and memory by role
%% ---------------------------------------------------------------------------

%% Every process of the node by role: pairing trees, bridge connections,
%% agent_bridge_client processes, the benchmark's own load generator.
classify() ->
    maps:from_list([{P, C} || P <- processes(), C <- [class(P)], C =/= other]).

class(P) ->
    case proc_lib:translate_initial_call(P) of
        {evatar_pairing, init, 1} -> pairing;
        {supervisor, evatar_pairing_sup, 1} -> pairing;
        {agent_bridge_conn, init, 1} -> connection;
        {agent_bridge_client, init, 1} -> client;
        {evatar_bench_gen, _, _} -> generator;
        {evatar_bench_floor, relay, _} -> connection;
        {evatar_bench_floor, middle, _} -> pairing;
        _ -> other
    end.

%% Memory, process count, socket count and socket memory per role; sockets
%% belong to the role of the process that owns them.
groups(Classes) ->
    Procs = maps:fold(
              fun(Pid, Class, Acc) ->
                      case erlang:process_info(Pid, memory) of
                          {memory, M} -> bump(Class, [{memory, M}, {procs, 1}], Acc);
                          undefined -> Acc
                      end
              end, #{}, Classes),
    lists:foldl(
      fun(Port, Acc) ->
              case {erlang:port_info(Port, connected), erlang:port_info(Port, memory)} of
                  {{connected, Owner}, {memory, M}} when is_map_key(Owner, Classes) ->
                      bump(maps:get(Owner, Classes), [{port_memory, M}, {ports, 1}], Acc);
                  _ ->
                      Acc
              end
      end, Procs, erlang:ports()).

bump(Class, KVs, Acc) ->
    G = maps:get(Class, Acc, #{memory => 0, procs => 0, port_memory => 0, ports => 0}),
    Acc#{Class => lists:foldl(fun({K, V}, M) -> M#{K := maps:get(K, M) + V} end, G, KVs)}.

%% @doc Garbage-collects every process of the node.
-spec gc_all() -> ok.
gc_all() ->
    _ = [erlang:garbage_collect(P) || P <- processes()],
    ok.

%% ---------------------------------------------------------------------------
%% Idle pairings
%% ---------------------------------------------------------------------------

%% Target pairings live; as many of them as the node's limits allow (all,
%% normally) get a VA and an Avatar joined through agent_bridge_client and
%% bound, then nothing is sent. Both ends run in this node; each role's
%% share is the sum of its processes' memory and its sockets' memory.
idle(Target, #{addr := Addr, conn_sup := ConnSup} = Ctx) ->
    %% Clients run in the generator's node when there is one: this node then
    %% holds two sockets per pairing instead of four.
    {ClientNode, Where} = case Ctx of
                              #{gen := #{node := GenNode}} -> {GenNode, "the generator's node"};
                              _ -> {node(), "this node"}
                          end,
    {Fit, Limits} = idle_fit(case ClientNode =:= node() of true -> 4; false -> 2 end),
    K = min(Target, Fit),
    Note = case K < Target of
               true ->
                   fmt("only ~b of the ~b pairings can be bound with both ends connected (clients"
                       " in ~s): ~s. All ~b pairings are live; ~b are bound with a VA and an "
                       "Avatar connected. Raise the limit (e.g. `ulimit -n 100000` as a user "
                       "allowed to raise the hard limit) for the full figure.",
                       [K, Target, Where, Limits, Target, K]);
               false ->
                   ""
           end,
    io:format("~n-- idle: ~b pairings live, ~b bound with both ends connected~n", [Target, K]),
    _ = [io:format("   NOTE: ~s~n", [Note]) || Note =/= ""],
    Sink = erpc:call(ClientNode, proc_lib, spawn, [evatar_bench_gen, sink, []]),
    %% Let what the loaded runs left behind (closing sockets, exiting
    %% processes) go before the baseline.
    timer:sleep(1000),
    gc_all(),
    M0 = erlang:memory(total),
    Ids = [<<"idle-", (integer_to_binary(I))/binary>> || I <- lists:seq(1, Target)],
    Opts = (evatar_bench_gen:credentials())#{join_timeout => 60000},
    C0 = erlang:monotonic_time(microsecond),
    _ = [{ok, _} = evatar:create_pairing(Id, Opts) || Id <- Ids],
    CreateUs = erlang:monotonic_time(microsecond) - C0,
    io:format("   ~b pairings created in ~b ms (~s a second)~n",
              [Target, CreateUs div 1000, int(per_second(Target, CreateUs))]),
    gc_all(),
    M1 = erlang:memory(total),
    G1 = groups(classify()),
    T0 = erlang:monotonic_time(microsecond),
    ok = join_idle(K, Sink, Addr, ClientNode),
    JoinUs = erlang:monotonic_time(microsecond) - T0,
    JoinMs = JoinUs div 1000,
    io:format("   ~b pairings bound in ~b ms (~s a second)~n",
              [K, JoinMs, int(per_second(K, JoinUs))]),
    %% Idle means idle: past the connections' and pairings' hibernate_after
    %% (5 s), as a quiet home is most of the time.
    timer:sleep(6000),
    M2 = erlang:memory(total),
    G2 = groups(classify()),
    gc_all(),
    M3 = erlang:memory(total),
    G3 = groups(classify()),
    Fs = erlang:memory(),
    Result = #{live => Target, bound => K, join_ms => JoinMs, note => list_to_binary(Note),
               create_ms => CreateUs div 1000,
               created_per_s => per_second(Target, CreateUs),
               bound_per_s => per_second(K, JoinUs),
               clients_in => list_to_binary(Where),
               fd_limit => max_fds(),
               as_is => idle_figures(M2 - M1, G2, G1, K, Target, (M1 - M0) / Target),
               after_gc => idle_figures(M3 - M1, G3, G1, K, Target, (M1 - M0) / Target),
               node_memory => maps:from_list(Fs),
               processes => maps:map(fun(_, G) -> maps:get(procs, G) end, G2),
               sockets => maps:map(fun(_, G) -> maps:get(ports, G) end, G2)},
    Sink ! stop,
    _ = [evatar:delete_pairing(Id) || Id <- Ids],
    ok = wait_empty(ConnSup, 6000),
    Result.

%% Events a second over a span of microseconds.
per_second(_N, 0) -> undefined;
per_second(N, Us) -> N * 1.0e6 / Us.

mem(Groups, Class, Key) -> maps:get(Key, maps:get(Class, Groups, #{}), 0).

%% Per bound pairing: what joining both ends added, by role; and the total
%% per pairing including the empty pairing's share.
idle_figures(JoinDelta, G, GEmpty, K, Target, EmptyNode) ->
    EmptyProcs = mem(GEmpty, pairing, memory) / Target,
    Growth = (mem(G, pairing, memory) - mem(GEmpty, pairing, memory)) / K,
    Conn = mem(G, connection, memory) / K,
    ServerSock = mem(G, connection, port_memory) / K,
    Client = (mem(G, client, memory) + mem(G, generator, memory)) / K,
    ClientSock = mem(G, client, port_memory) / K,
    %% Node memory the joins added outside any process or socket: ETS,
    %% off-heap binaries, ...
    Rest = JoinDelta / K - Conn - ServerSock - Client - ClientSock - Growth,
    Evatar = EmptyNode + Growth + Conn + ServerSock + Rest,
    #{empty_pairing_node => EmptyNode, empty_pairing_procs => EmptyProcs,
      pairing_procs_bound => EmptyProcs + Growth, pairing_procs_growth => Growth,
      conn_procs => Conn, server_sockets => ServerSock,
      client_procs => Client, client_sockets => ClientSock,
      rest => Rest,
      evatar_side_per_bound => Evatar,
      node_total_per_bound => EmptyNode + JoinDelta / K}.

%% How many pairings can be bound: `Sockets' sockets in this node each
%% (4 with the clients here, 2 with them in the generator's node, which has
%% the same limits and fewer sockets), six processes and two ephemeral ports.
idle_fit(Sockets) ->
    Fds = case max_fds() of
              undefined -> 1 bsl 30;
              Max -> (Max - used_fds() - 64) div Sockets
          end,
    Ports = (erlang:system_info(port_limit) - erlang:system_info(port_count) - 64) div Sockets,
    Procs = (erlang:system_info(process_limit) - erlang:system_info(process_count) - 1000) div 6,
    Ephemeral = case file:read_file("/proc/sys/net/ipv4/ip_local_port_range") of
                    {ok, B} ->
                        [Lo, Hi] = [binary_to_integer(X)
                                    || X <- binary:split(B, [<<"\t">>, <<" ">>, <<"\n">>],
                                                         [global, trim_all])],
                        (Hi - Lo + 1 - 1000) div 2;
                    {error, _} -> 1 bsl 30
                end,
    Fit = lists:min([Fds, Ports, Procs, Ephemeral]),
    Why = [fmt("the file-descriptor limit (ulimit -n) is ~b and ~b sockets per pairing are "
               "needed in this node", [max_fds(), Sockets]) || Fit =:= Fds]
        ++ [fmt("the port limit (+Q) is ~b", [erlang:system_info(port_limit)]) || Fit =:= Ports]
        ++ [fmt("the process limit (+P) is ~b", [erlang:system_info(process_limit)])
            || Fit =:= Procs]
        ++ ["the ephemeral port range (/proc/sys/net/ipv4/ip_local_port_range) is too small"
            || Fit =:= Ephemeral],
    {max(0, Fit), lists:flatten(lists:join("; ", Why))}.

join_idle(K, Sink, Addr, ClientNode) ->
    Self = self(),
    Evatar = node(),
    Workers = [proc_lib:spawn_link(
                 ClientNode,
                 fun() ->
                         _ = [evatar_bench_gen:idle_join(I, Sink, Addr, Evatar)
                              || I <- lists:seq(W, K, ?JOIN_WORKERS)],
                         Self ! {self(), joined}
                 end) || W <- lists:seq(1, min(K, ?JOIN_WORKERS))],
    _ = [receive {W, joined} -> ok after 600000 -> error(idle_join_timeout) end
         || W <- Workers],
    ok.

%% ---------------------------------------------------------------------------
%% Profile: where the time goes at the largest size
%% ---------------------------------------------------------------------------

%% eprof over the bridge connections and the pairings during a short closed
%% loop with the raw generator at the largest size. eprof slows what it
%% traces, so only the shares are meaningful, and they are not timed with
%% the other figures.
profile(#{sizes := Sizes} = Cfg, #{addr := Addr, conn_sup := ConnSup}) ->
    N = lists:max(Sizes),
    io:format("~n-- profile: eprof on the connection and pairing processes, N = ~b, raw generator~n",
              [N]),
    Pairs = evatar_bench_gen:setup(N, raw, Addr),
    Counters = counters:new(N, [write_concurrency]),
    _ = [Va ! {closed, Counters, maps:get(inflight, Cfg)} || #{va := Va} <- Pairs],
    timer:sleep(1000),
    Server = [P || {P, C} <- maps:to_list(classify()), C =:= connection orelse C =:= pairing],
    File = filename:join(maps:get(out, Cfg), "eprof.txt"),
    ok = filelib:ensure_dir(File),
    %% eprof prints its analysis to its server's group leader: a file here.
    {ok, Dev} = file:open(File, [write]),
    Leader = group_leader(),
    true = group_leader(Dev, self()),
    {ok, _} = eprof:start(),
    true = group_leader(Leader, self()),
    profiling = eprof:start_profiling(Server),
    timer:sleep(3000),
    profiling_stopped = eprof:stop_profiling(),
    _ = [Va ! stop_loop || #{va := Va} <- Pairs],
    _ = collect(Pairs, drained),
    ok = eprof:analyze(total, [{sort, time}]),
    stopped = eprof:stop(),
    ok = file:close(Dev),
    ok = teardown(Pairs, ConnSup),
    top_functions(File, 30).

%% The first lines of eprof's total analysis, for the summary.
top_functions(File, Lines) ->
    {ok, Bin} = file:read_file(File),
    All = binary:split(Bin, <<"\n">>, [global]),
    Rows = [L || L <- All, re:run(L, <<"^[a-z_]+:[^ ]+/[0-9]+ ">>) =/= nomatch],
    Sorted = lists:sublist(lists:reverse(Rows), Lines),
    #{file => list_to_binary(File), top => Sorted}.

%% ---------------------------------------------------------------------------
%% Targets and summary
%% ---------------------------------------------------------------------------

%% The raw and client rows at N = 1,000 against the targets, each judged
%% on the median over its rounds (every round is listed too).
targets(Loaded) ->
    [estimate(R) || #{n := ?TARGET_N, mode := split} = R <- Loaded] ++
    [begin
         Runs = [round_figures(R) || #{n := ?TARGET_N, mode := M} = R <- Loaded, M =:= Mode],
         Rate = median([maps:get(rate, X) || X <- Runs]),
         P99s = [P || #{p99_us := P} <- Runs, is_number(P)],
         P99 = case P99s of
                   [] -> undefined;
                   _ -> median(P99s)
               end,
         #{mode => Mode, n => ?TARGET_N, rounds => Runs,
           others_closed => lists:max([O || #{others_closed := O} <- Runs]),
           others_open => lists:max([O || #{others_open := O} <- Runs]),
           rate => Rate, rate_target => ?TARGET_RATE, rate_met => Rate >= ?TARGET_RATE,
           rate_met_rounds => length([x || #{rate := R} <- Runs, R >= ?TARGET_RATE]),
           p99_us => P99, p99_target_us => ?TARGET_P99_US,
           p99_at_rate => median([maps:get(p99_at_rate, X) || X <- Runs]),
           p99_met => is_number(P99) andalso P99 =< ?TARGET_P99_US,
           p99_met_rounds => length([x || P <- P99s, P =< ?TARGET_P99_US])}
     end || Mode <- [raw, client], lists:any(fun(#{n := N, mode := M}) ->
                                                     N =:= ?TARGET_N andalso M =:= Mode
                                             end, Loaded)].

round_figures(#{closed := #{rate := Rate} = C, open := #{p99 := P99, offered := Offered} = O} = R) ->
    #{round => maps:get(round, R, 1), rate => Rate, p99_us => P99, p99_at_rate => Offered,
      us_per_rt => us_per_rt(C),
      sched_waits => case C of
                         #{cpu := #{sched_waits := W}} -> W;
                         _ -> undefined
                     end,
      others_closed => others(C), others_open => others(O)}.

median(Xs) ->
    Sorted = lists:sort(Xs),
    N = length(Sorted),
    case N rem 2 of
        1 -> lists:nth((N + 1) div 2, Sorted);
        0 -> (lists:nth(N div 2, Sorted) + lists:nth(N div 2 + 1, Sorted)) / 2
    end.

%% EVATAR's node alone, its clients in another OS process: the CPU one
%% round trip costs it, and the rate two cores would give at that cost.
estimate(#{closed := #{rate := Rate, cpu := #{node_cores := Cores, cores := Ncpu}} = C}) ->
    UsPerRt = Cores * 1.0e6 / Rate,
    Capacity = Ncpu * 1.0e6 / UsPerRt,
    #{mode => split, n => ?TARGET_N, rate => Rate, us_per_rt => UsPerRt,
      capacity_estimate => Capacity, rate_target => ?TARGET_RATE,
      estimate_met => Capacity >= ?TARGET_RATE, others_closed => others(C)};
estimate(#{closed := C}) ->
    #{mode => split, n => ?TARGET_N, others_closed => others(C)}.

others(#{cpu := #{other_cores := X}}) -> X;
others(_) -> undefined.

met(true) -> "MET";
met(false) -> "NOT MET".

print_header(Cfg, Env) ->
    io:format("EVATAR mediator benchmark: OTP ~s (erts ~s), ~b schedulers, ~p logical CPUs, ~s~n"
              "fd limit ~p, port limit ~b, process limit ~b, load average at start ~s~n"
              "sizes ~w, generators ~w, W = ~b in flight per VA, windows ~p s after ~p s warm-up"
              "~s~n",
              [maps:get(otp, Env), maps:get(erts, Env), maps:get(schedulers, Env),
               maps:get(cpus, Env), maps:get(arch, Env), maps:get(max_fds, Env),
               maps:get(port_limit, Env), maps:get(process_limit, Env),
               fmt("~w", [maps:get(load_average, Env)]),
               maps:get(sizes, Cfg), maps:get(modes, Cfg), maps:get(inflight, Cfg),
               maps:get(seconds, Cfg), maps:get(warmup, Cfg),
               case maps:get(quick, Cfg) of
                   true -> " (QUICK: a smoke run, figures not meant to be read)";
                   false -> ""
               end]).

summary(Cfg, Env, Costs, Loaded, Idle, Targets, Profile) ->
    [io_lib:format("== EVATAR mediator benchmark (~s, OTP ~s, ~b schedulers) ==~n",
                   [maps:get(date, Env), maps:get(otp, Env), maps:get(schedulers, Env)]),
     io_lib:format("A round trip: the VA sends a RequestAwaitingFeedback (~b bytes) to its Avatar through~n"
                   "EVATAR over loopback TCP; the Avatar answers with a Feedback (~b bytes) back to the VA.~n",
                   [maps:get(request_bytes, Costs), maps:get(feedback_bytes, Costs)]),
     "Generators: raw = minimal socket clients (pre-encoded frames, ids found by binary match),\n"
     "so nearly all the CPU goes to EVATAR; client = agent_bridge_client on both ends (it parses\n"
     "and encodes every document), in the same node, sharing the same cores; floor = the raw\n"
     "generator against relays that forward frames untouched through the same sockets and\n"
     "process hops (conn -> pairing -> conn) with no parse, routing or encode: the transport's\n"
     "own cost on this machine; direct = plain Erlang processes joined through the evatar API\n"
     "(no TCP, no XML, no bridge): the pairing's own cost; split = the raw generator in a second\n"
     "Erlang node (a peer OS process on this machine), so this node's CPU is EVATAR's alone.\n",
     costs_table(Costs),
     [loaded_tables(Cfg, Loaded) || Loaded =/= []],
     [idle_table(Idle) || Idle =/= undefined],
     [targets_table(Targets) || Targets =/= []],
     [profile_text(Profile) || Profile =/= undefined]].

costs_table(C) ->
    Row = fun(Label, Key) -> [Label, fmt("~.2f", [maps:get(Key, C)])] end,
    ["\n-- EVATAR's work per round trip, one step at a time (this process, fastest of 5 batches)\n\n",
     evatar_bench_report:table(
       ["step", "us/call"],
       [Row(fmt("parse the VA's request frame (~b bytes)", [maps:get(request_bytes, C)]),
            parse_request),
        Row(fmt("parse the Avatar's feedback frame (~b bytes)", [maps:get(feedback_bytes, C)]),
            parse_feedback),
        Row("encode a delivered signal (x2 per round trip)", encode_signal),
        Row("pairing logic: route request + feedback", logic_request_and_feedback),
        Row("= sum per round trip", work_per_round_trip)])].

loaded_tables(Cfg, Loaded) ->
    Floor = maps:from_list([{N, maps:get(rate, C)} || #{mode := floor, n := N, closed := C} <- Loaded]),
    Closed = [[atom_to_list(Mode), int(N), int(maps:get(rate, C)),
               case Floor of
                   #{N := F} when Mode =:= raw; Mode =:= client -> pct(maps:get(rate, C) / F);
                   _ -> "-"
               end,
               pct(maps:get(scheduler_utilisation, C)),
               cores(C, node_cores), gen_cores(C), cpu_per_rt(C), sys_share(C), cores(C, other_cores),
               work(C),
               int(maps:get(errors, C) + maps:get(timeouts, C) + maps:get(unanswered, C))]
              || #{mode := Mode, n := N, closed := C} <- Loaded],
    Open = [[atom_to_list(Mode), int(N), int(maps:get(offered, O)), int(maps:get(achieved, O)),
             ms(maps:get(p50, O)), ms(maps:get(p99, O)), ms(maps:get(p999, O)), ms(maps:get(max, O)),
             ms(maps:get(send_lag_p99, O)), ms(maps:get(send_lag_max, O)),
             span(maps:get(slow_span_ms, O)), pct(maps:get(scheduler_utilisation, O)),
             cores(O, other_cores),
             int(maps:get(errors, O) + maps:get(timeouts, O) + maps:get(unanswered, O))]
            || #{mode := Mode, n := N, open := O} <- Loaded],
    %% Below 100 pairings the node delta is within the node's own noise.
    Node = fun(M, N) when N >= 100 -> kib(maps:get(node_total, M));
              (_, _) -> "-"
           end,
    Mem = [[atom_to_list(Mode), int(N), Node(S, N), Node(L, N),
            kib(maps:get(pairing_procs, L)), kib(maps:get(conn_procs, L)),
            kib(maps:get(server_sockets, L)), kib(maps:get(client_procs, L)),
            kib(maps:get(client_sockets, L))]
           || #{mode := Mode, n := N, memory := #{after_setup := S, after_load := L}} <- Loaded,
              Mode =:= raw orelse Mode =:= client orelse Mode =:= split],
    Msacc = [[atom_to_list(Mode), int(N) | msacc_cells(maps:get(msacc, C))]
             || #{mode := Mode, n := N, closed := C} <- Loaded],
    [io_lib:format("~n-- Closed loop: maximum round trips/s (each VA keeps ~b request(s) in flight; "
                   "~p s window after ~p s warm-up)~n",
                   [maps:get(inflight, Cfg), maps:get(seconds, Cfg), maps:get(warmup, Cfg)]),
     "   of floor = rt/s against the floor's at the same N; sched = normal schedulers' busy share;\n"
     "   node = CPU cores used by this OS process (from /proc), us/rt = node CPU per round trip,\n"
     "   both ends included (split: EVATAR's alone), sys = its kernel share; gen node = cores of\n"
     "   the split generator's node; others = cores used by every other process of the machine\n"
     "   (a busy machine shows here); work = share of reductions by role, in this node: gen\n"
     "   (benchmark generator) / cli (agent_bridge_client) / conn (bridge) / pair (pairing)\n\n",
     evatar_bench_report:table(["gen", "N", "rt/s", "of floor", "sched", "node", "gen node",
                                "us/rt", "sys", "others", "work gen/cli/conn/pair %", "errors"],
                               Closed),
     "\n   Scheduler time by micro-state (msacc), same window:\n\n",
     evatar_bench_report:table(["gen", "N", "emulator", "port", "check_io", "gc", "other",
                                "aux", "sleep"], Msacc),
     io_lib:format("~n-- Open loop at half the maximum: latency percentiles (~p s window after ~p s"
                   " warm-up)~n", [maps:get(seconds, Cfg), maps:get(warmup, Cfg)]),
     "   Each VA sends on a fixed schedule (whole milliseconds, spread over the pairings) and\n"
     "   latency is measured from the SCHEDULED send time, not the actual one, so a slow answer\n"
     "   cannot hide the requests it delayed (no coordinated omission). lag p99 = the\n"
     "   generator's own delay between scheduled and actual send, included in the latency,\n"
     "   lag max its largest; slow span = how many ms apart the slowest 0.1 % of requests were\n"
     "   due (a few tens of ms: one stall; most of the window: a spread tail).\n"
     "   When other processes take CPU (others), the rate measured as the maximum may no longer\n"
     "   be sustainable and queues, hence latencies, grow: such rows say little about EVATAR.\n\n",
     evatar_bench_report:table(["gen", "N", "offered/s", "done/s", "p50 ms", "p99 ms",
                                "p99.9 ms", "max ms", "lag p99", "lag max", "slow span",
                                "sched", "others", "errors"],
                               Open),
     "\n-- Memory per pairing, KiB: node = erlang:memory(total) delta / N after setup (every process\n"
     "   garbage-collected) and after the load (as is; '-' below N = 100, where it is noise);\n"
     "   the other columns sum process_info(memory) and the sockets' port_info(memory) by role\n"
     "   after the load; client = both ends' generator and client processes, in this node\n\n",
     evatar_bench_report:table(["gen", "N", "node setup", "node loaded", "pairing procs",
                                "conn procs", "server sockets", "client procs",
                                "client sockets"], Mem)].

idle_table(#{live := Live, bound := K} = Idle) ->
    #{as_is := A, after_gc := G} = Idle,
    Row = fun(Label, Key) -> [Label, kib(maps:get(Key, A)), kib(maps:get(Key, G))] end,
    [io_lib:format("~n-- Idle: ~s pairings live, ~s bound with a VA and an Avatar connected (both"
                   " through agent_bridge_client, in ~s), nothing sent~n",
                   [int(Live), int(K), maps:get(clients_in, Idle, <<"this node">>)]),
     [io_lib:format("   NOTE: ~s~n", [maps:get(note, Idle)]) || maps:get(note, Idle) =/= <<>>],
     io_lib:format("   Created: ~s pairings in ~s ms, ~s a second (evatar:create_pairing/2, one after"
                   " the other);~n"
                   "   bound: ~s in ~s ms, ~s a second (~b workers joining a VA and an Avatar each,"
                   " until bound)~n",
                   [int(Live), int(maps:get(create_ms, Idle)), int(maps:get(created_per_s, Idle)),
                    int(K), int(maps:get(join_ms, Idle)), int(maps:get(bound_per_s, Idle)),
                    ?JOIN_WORKERS]),
     "   Per bound pairing, KiB. Roles are separated by summing process_info(memory) of each\n"
     "   role's processes and port_info(memory) of the sockets they own; rest = node delta not\n"
     "   in any process or socket (ETS, binaries). 'after GC' = after garbage-collecting every\n"
     "   process, i.e. live data only.\n\n",
     evatar_bench_report:table(
       ["", "as is", "after GC"],
       [Row("empty pairing: node delta / pairings live", empty_pairing_node),
        Row("  of which its two processes (sup + statem)", empty_pairing_procs),
        Row("pairing processes' growth once bound", pairing_procs_growth),
        Row("bridge connection processes (2)", conn_procs),
        Row("server sockets (2, port_info memory)", server_sockets),
        Row("rest of the node (ETS, off-heap binaries)", rest),
        Row("= EVATAR side per idle bound pairing", evatar_side_per_bound),
        Row("client processes (2, agent_bridge_client; 0 when in the generator's node)",
            client_procs),
        Row("client sockets (2, port_info memory)", client_sockets),
        Row("= node total per idle bound pairing", node_total_per_bound)])].

targets_table(Targets) ->
    Of = fun(K, Runs) -> fmt(" (~b of ~b rounds)", [K, length(Runs)]) end,
    Rows = lists:append(
             [[[fmt("~s round trips/s with ~s pairings", [int(?TARGET_RATE), int(?TARGET_N)]),
                atom_to_list(Mode), int(Rate) ++ " rt/s", met(RateMet) ++ Of(RateK, Runs)],
               [fmt("p99 at most ~b ms at half that rate", [?TARGET_P99_US div 1000]),
                atom_to_list(Mode), ms(P99) ++ " ms at " ++ int(At) ++ " rt/s",
                met(P99Met) ++ Of(P99K, Runs)]]
              || #{mode := Mode, rate := Rate, rate_met := RateMet, p99_us := P99,
                   p99_at_rate := At, p99_met := P99Met, rounds := Runs,
                   rate_met_rounds := RateK, p99_met_rounds := P99K} <- Targets])
        ++ [[fmt("EVATAR alone: ~s rt/s on ~b cores at its CPU cost", [int(?TARGET_RATE), Ncpu]),
             "split", fmt("~b us/rt -> ~s rt/s", [round(Us), int(Cap)]),
             "estimate: " ++ met(Met)]
            || #{us_per_rt := Us, capacity_estimate := Cap, estimate_met := Met} <- Targets,
               Ncpu <- [cpu_count()]],
    Busy = [fmt("~s: other processes used ~s cores (closed loop) and ~s (open loop)",
                [M, fmt_cores(A), fmt_cores(B)])
            || #{mode := M, others_closed := A, others_open := B} <- Targets],
    Estimate = [["   The split estimate divides the cores by EVATAR's own CPU per round trip, its\n"
                 "   clients running elsewhere; it is not a measured rate.\n"]
                || #{us_per_rt := _} <- Targets],
    RoundRows = [[atom_to_list(Mode), fmt("~b", [K]), int(Rate), int(Us), int(W),
                  ms(P99) ++ " at " ++ int(At), fmt_cores(Oc), fmt_cores(Oo)]
                 || #{mode := Mode, rounds := Runs} <- Targets,
                    #{round := K, rate := Rate, us_per_rt := Us, sched_waits := W, p99_us := P99,
                      p99_at_rate := At, others_closed := Oc, others_open := Oo} <- Runs],
    ["\n-- Targets (issue 3), judged on the median over the rounds: each round sets up the\n"
     "   N = 1,000 pairings again and runs the closed loop, then the open loop at half the\n"
     "   maximum it measured; 'measured' is the median of the rounds' figures\n\n",
     evatar_bench_report:table(["gen", "round", "rt/s", "us/rt", "sched waits/s",
                                "p99 ms at rt/s", "others closed", "others open"], RoundRows),
     "   sched waits/s = voluntary context switches per scheduler thread and second in the\n"
     "   closed loop (sleeping or waiting for a lock): high in the slow rounds (EVATAR_BENCH.md)\n\n",
     evatar_bench_report:table(["target", "gen", "measured", "result"], Rows),
     Estimate,
     "\n   Machine load during the N = 1,000 measurements (of ",
     fmt("~p", [erlang:system_info(logical_processors_available)]), " cores):\n",
     [["   ", B, "\n"] || B <- Busy]].

cpu_count() ->
    case erlang:system_info(logical_processors_available) of
        N when is_integer(N) -> N;
        _ -> erlang:system_info(schedulers_online)
    end.

fmt_cores(undefined) -> "?";
fmt_cores(X) -> fmt("~.2f", [X]).

profile_text(#{file := File, top := Top}) ->
    [io_lib:format("~n-- eprof, connection and pairing processes (full listing: ~s)~n~n", [File]),
     [[L, "\n"] || L <- Top]].

work(#{reductions_share := S}) ->
    string:join([fmt("~b", [round(100 * maps:get(K, S, 0))])
                 || K <- [generator, client, connection, pairing]], "/").

msacc_cells(undefined) -> ["-" || _ <- lists:seq(1, 7)];
msacc_cells(M) -> [pct(maps:get(K, M, 0)) || K <- [emulator, port, check_io, gc, other, aux, sleep]].

pct(undefined) -> "-";
pct(F) -> fmt("~b%", [round(100 * F)]).

cpu_per_rt(Closed) -> int(us_per_rt(Closed)).

%% The node's CPU per round trip of a closed loop, in µs.
us_per_rt(#{cpu := #{node_cores := C}, rate := R}) when R > 0 -> C * 1.0e6 / R;
us_per_rt(_) -> undefined.

sys_share(#{cpu := #{node_sys_share := S}}) -> pct(S);
sys_share(_) -> "-".

gen_cores(#{cpu := #{gen_cores := G}}) when G > 0 -> fmt("~.2f", [G]);
gen_cores(_) -> "-".

cores(#{cpu := undefined}, _) -> "-";
cores(#{cpu := C}, K) -> fmt("~.2f", [maps:get(K, C)]).

markdown(Env, Text) ->
    ["# EVATAR mediator benchmark, ", maps:get(date, Env), "\n\n",
     "Produced by `make bench-evatar` (scripts/bench-evatar.sh). Plain-text tables as printed.\n\n",
     "```\n", Text, "```\n"].

span(undefined) -> "-";
span(Ms) -> evatar_bench_report:fmt("~b ms", [round(Ms)]).

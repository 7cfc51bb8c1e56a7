%% @doc Where the server CPU of one round trip goes: the broker comparison's
%% systems (broker_bench_sut, broker_bench_gen) under their closed loop,
%% measured over a fixed number of round trips per window, each figure
%% divided by the round trips of its window. For every system: user and
%% kernel CPU from /proc, then `perf stat' on the server's OS process
%% (context switches and system calls by name, from the kernel's syscall
%% tracepoints, which cost little). For EVATAR also, each in a window of
%% its own because each slows the node differently: the node's
%% statistics (reductions, process switches, bytes through its ports) and
%% micro-state accounting of its threads (emulator, gc, port, check_io,
%% other, sleep); every message each kind of process receives (trace
%% `receive': the process hops); the events its state machines handle
%% (call_count of their handle_event/4); eprof over every process, its calls and
%% time per round trip (timers, sends, codec). How to read it:
%% bench/README.md, "Where a round trip's CPU goes".
%%
%%   scripts/bench-brokers.sh profile-rt '[{sizes, [1, 16, 256]}]'
%%
%% Options: `{systems, [evatar, mosquitto, nats]}' (default), `{sizes,
%% [1, 16, 256]}', `{round_trips, 10000}' per plain window (perf and
%% statistics), `{traced_round_trips, 2000}' per traced window (receive
%% trace, eprof), `{out, "bench/results"}'. Not part of the product.
-module(broker_bench_profile).

-export([main/1]).
-export([count_receives/1, receive_counts/1]).

-define(TIMEOUT_MS, 600000).
-define(EVENT_HANDLERS, [{agent_bridge_conn, handle_event, 4}, {evatar_pairing, handle_event, 4}]).
-define(SYSCALLS, [read, readv, recvfrom, recvmsg, write, writev, sendto, sendmsg,
                   epoll_wait, epoll_pwait, epoll_ctl, futex, nanosleep, sched_yield,
                   poll, ppoll, pselect6, getrusage, clock_nanosleep, timerfd_settime]).

%% @doc Profiles each system at each size, prints the figures and writes
%% them under `out' as `rt-profile-<date>.{json,md}'.
-spec main([{atom(), term()}]) -> ok.
main(Options) ->
    ok = logger:set_primary_config(level, warning),
    %% The controller counts round trips around each snapshot: behind the
    %% generator's 2 N busy processes its counts would come late.
    _ = process_flag(priority, high),
    Systems = proplists:get_value(systems, Options, [evatar, mosquitto, nats]),
    Sizes = proplists:get_value(sizes, Options, [1, 16, 256]),
    Cfg = #{round_trips => proplists:get_value(round_trips, Options, 10000),
            traced => proplists:get_value(traced_round_trips, Options, 2000),
            run_dir => case os:getenv("BROKER_BENCH_RUN_DIR") of
                           false -> "/tmp/broker_bench_profile_" ++ os:getpid();
                           D -> D
                       end},
    ok = filelib:ensure_dir(filename:join(maps:get(run_dir, Cfg), "x")),
    _ = os:cmd("epmd -daemon"),
    {ok, _} = net_kernel:start([list_to_atom("broker_bench_profile_" ++ os:getpid()), shortnames]),
    Load0 = loadavg(),
    io:format("Round-trip profile: systems ~w, N ~w, ~b round trips per window "
              "(~b traced); load average ~w~n",
              [Systems, Sizes, maps:get(round_trips, Cfg), maps:get(traced, Cfg), Load0]),
    Rows = [profile(Sys, N, Cfg) || N <- Sizes, Sys <- Systems],
    Load1 = loadavg(),
    Md = markdown(Rows, Cfg, Load0, Load1),
    io:put_chars(["\n", Md]),
    Date = list_to_binary(calendar:system_time_to_rfc3339(os:system_time(second))),
    {Json, File} = evatar_bench_report:write(proplists:get_value(out, Options, "bench/results"),
                                            "rt-profile",
                                            #{date => Date, load_average_start => Load0,
                                              load_average_end => Load1,
                                              versions => broker_bench_sut:versions(),
                                              rows => Rows}, Md),
    io:format("~nResults written to ~s and ~s~n", [Json, File]),
    ok.

%% ---------------------------------------------------------------------------
%% One system at one N
%% ---------------------------------------------------------------------------

profile(Sys, N, #{round_trips := K, traced := KT, run_dir := RunDir}) ->
    io:format("~n-- ~s, N = ~b~n", [Sys, N]),
    Sut = broker_bench_sut:start(Sys, RunDir, #{}),
    try
        Pairs = broker_bench_gen:setup(N, Sut),
        C = counters:new(N, [write_concurrency]),
        Count = fun() -> lists:sum([counters:get(C, I) || I <- lists:seq(1, N)]) end,
        _ = [A ! {closed, C, 1} || #{agent := A} <- Pairs],
        OsPid = maps:get(os_pid, Sut),
        %% Warm-up: connections, caches and schedulers settle.
        ok = await_count(Count, Count() + max(500, K div 10)),
        Cpu = window(Count, K, fun() -> cpu(OsPid) end, fun cpu_delta/2),
        io:format("   CPU: ~.1f us per round trip (~.1f user, ~.1f kernel), ~b rt/s~n",
                  [maps:get(us_per_rt, Cpu), maps:get(user_us_per_rt, Cpu),
                   maps:get(sys_us_per_rt, Cpu), round(maps:get(rate, Cpu))]),
        Perf = perf(OsPid, Count, K),
        io:format("   perf: ~.2f context switches, ~.2f syscalls per round trip~n",
                  [maps:get(context_switches, Perf), maps:get(syscalls, Perf)]),
        Node = case Sut of
                   #{system := evatar, node := Nd} -> node_figures(Nd, Count, K, KT);
                   _ -> #{}
               end,
        _ = [A ! stop_loop || #{agent := A} <- Pairs],
        _ = [receive {A, drained, _} -> ok after 60000 -> error(not_drained) end
             || #{agent := A} <- Pairs],
        ok = broker_bench_gen:teardown(Pairs),
        #{system => Sys, n => N, cpu => Cpu, perf => Perf, node => Node}
    after
        broker_bench_sut:stop(Sut)
    end.

await_count(Count, Target) ->
    Deadline = erlang:monotonic_time(millisecond) + ?TIMEOUT_MS,
    await_count(Count, Target, Deadline).

await_count(Count, Target, Deadline) ->
    case Count() >= Target of
        true -> ok;
        false ->
            erlang:monotonic_time(millisecond) < Deadline orelse error(round_trips_stalled),
            timer:sleep(2),
            await_count(Count, Target, Deadline)
    end.

%% Before, K round trips, After: Delta(Before, After) with the round trips
%% and seconds of the window. A snapshot of the node takes a while when
%% the generator's VM is busy (N = 256): the round trips are counted
%% before and after each snapshot and the middles taken.
window(Count, K, Snap, Delta) ->
    {C0, T0, S0} = snap(Count, Snap),
    ok = await_count(Count, round(C0) + K),
    {C1, T1, S1} = snap(Count, Snap),
    (Delta(S0, S1))(C1 - C0, (T1 - T0) / 1.0e6).

snap(Count, Snap) ->
    Ca = Count(),
    Ta = erlang:monotonic_time(microsecond),
    S = Snap(),
    Tb = erlang:monotonic_time(microsecond),
    Cb = Count(),
    {(Ca + Cb) / 2, (Ta + Tb) / 2, S}.

%% ---------------------------------------------------------------------------
%% From outside: /proc and perf
%% ---------------------------------------------------------------------------

cpu(OsPid) ->
    {ok, Stat} = file:read_file("/proc/" ++ OsPid ++ "/stat"),
    [_, AfterComm] = binary:split(Stat, <<") ">>),
    Fields = binary:split(AfterComm, <<" ">>, [global]),
    {binary_to_integer(lists:nth(12, Fields)), binary_to_integer(lists:nth(13, Fields))}.

%% Clock ticks are 1/100 s: 10,000 us each.
cpu_delta({U0, S0}, {U1, S1}) ->
    fun(Done, Secs) ->
            Per = fun(Ticks) -> Ticks * 10000 / max(1, Done) end,
            #{round_trips => Done, seconds => Secs, rate => Done / Secs,
              us_per_rt => Per(U1 - U0 + S1 - S0), user_us_per_rt => Per(U1 - U0),
              sys_us_per_rt => Per(S1 - S0)}
    end.

%% perf stat attached to every thread of the process over K round trips,
%% stopped with SIGINT; context switches and system calls per round trip.
perf(OsPid, Count, K) ->
    File = filename:join("/tmp", "rt_profile_perf_" ++ OsPid ++ ".csv"),
    Events = ["task-clock", "context-switches", "cpu-migrations", "page-faults",
              "raw_syscalls:sys_enter"
              | ["syscalls:sys_enter_" ++ atom_to_list(S) || S <- ?SYSCALLS]],
    Port = open_port({spawn_executable, os:find_executable("perf")},
                     [{args, ["stat", "-x", ",", "-o", File, "-p", OsPid,
                              "-e", string:join(Events, ",")]},
                      exit_status, stderr_to_stdout, binary]),
    %% perf counts from when it has attached, a few ms after this.
    C0 = Count(),
    {os_pid, PerfPid} = erlang:port_info(Port, os_pid),
    ok = await_count(Count, C0 + K),
    _ = os:cmd("kill -INT " ++ integer_to_list(PerfPid)),
    Done = Count() - C0,
    receive {Port, {exit_status, _}} -> ok after 30000 -> error(perf_did_not_stop) end,
    {ok, Csv} = file:read_file(File),
    ok = file:delete(File),
    Counts = maps:from_list(
               [{Event, binary_to_integer(hd(binary:split(V, <<".">>)))}
                || Line <- binary:split(Csv, <<"\n">>, [global]),
                   [V, _Unit, Event | _] <- [binary:split(Line, <<",">>, [global])],
                   V =/= <<>>, is_digit(V)]),
    Per = fun(Event) -> maps:get(list_to_binary(Event), Counts, 0) / max(1, Done) end,
    Calls = maps:from_list([{S, Per("syscalls:sys_enter_" ++ atom_to_list(S))} || S <- ?SYSCALLS]),
    Named = lists:sum(maps:values(Calls)),
    All = Per("raw_syscalls:sys_enter"),
    #{round_trips => Done, context_switches => Per("context-switches"),
      cpu_migrations => Per("cpu-migrations"), task_clock_ms_per_rt => Per("task-clock"),
      syscalls => All, by_syscall => maps:filter(fun(_, V) -> V >= 0.005 end, Calls),
      other_syscalls => max(0.0, All - Named)}.

is_digit(<<D, _/binary>>) -> D >= $0 andalso D =< $9;
is_digit(_) -> false.

%% ---------------------------------------------------------------------------
%% From inside the EVATAR node
%% ---------------------------------------------------------------------------

node_figures(Node, Count, K, KT) ->
    Stats = window(Count, K, fun() -> erpc:call(Node, fun node_stats/0) end,
                   fun stats_delta/2),
    io:format("   node: ~b reductions, ~.1f process switches, ~b bytes in, ~b out "
              "per round trip~n",
              [round(maps:get(reductions, Stats)), maps:get(process_switches, Stats),
               round(maps:get(bytes_in, Stats)), round(maps:get(bytes_out, Stats))]),
    _ = erpc:call(Node, erlang, system_flag, [microstate_accounting, reset]),
    _ = erpc:call(Node, erlang, system_flag, [microstate_accounting, true]),
    Msacc = window(Count, K, fun() -> erpc:call(Node, erlang, statistics,
                                                [microstate_accounting]) end,
                   fun msacc_delta/2),
    _ = erpc:call(Node, erlang, system_flag, [microstate_accounting, false]),
    io:format("   msacc, busy threads' time: ~s~n",
              [string:join([io_lib:format("~s ~b%", [S, round(V * 100)])
                            || {S, V} <- lists:reverse(lists:keysort(2, maps:to_list(
                                                                           maps:get(busy_shares, Msacc)))),
                               V >= 0.005], ", ")]),
    Tracer = erpc:call(Node, erlang, spawn, [?MODULE, count_receives, [self()]]),
    Hops = window(Count, KT,
                  fun() -> erpc:call(Node, ?MODULE, receive_counts, [Tracer]) end,
                  fun hops_delta/2),
    Tracer ! stop,
    io:format("   messages received per round trip: ~s~n",
              [string:join([io_lib:format("~s ~.2f", [Kind, V])
                            || #{kind := Kind, per_rt := V} <- maps:get(top, Hops)], ", ")]),
    Events = events_window(Node, Count, KT),
    io:format("   events handled per round trip: ~s~n", [events_text(Events)]),
    Eprof = eprof_window(Node, Count, KT),
    #{stats => Stats, msacc => Msacc, hops => Hops, events => Events, eprof => Eprof}.

%% The events the state machines handle (calls of their handle_event/4,
%% counted by call_count): a message taken from a mailbox elsewhere, as
%% the connection takes the inet driver's write reply, is no event.
events_window(Node, Count, KT) ->
    _ = [erpc:call(Node, erlang, trace_pattern, [MFA, true, [call_count]]) || MFA <- ?EVENT_HANDLERS],
    Snap = fun() -> [{M, call_count(Node, MFA)} || {M, _, _} = MFA <- ?EVENT_HANDLERS] end,
    Events = window(Count, KT, Snap,
                    fun(C0, C1) ->
                            fun(Done, _Secs) ->
                                    maps:from_list([{M, (N1 - proplists:get_value(M, C0)) / max(1, Done)}
                                                    || {M, N1} <- C1])
                            end
                    end),
    _ = [erpc:call(Node, erlang, trace_pattern, [MFA, false, [call_count]]) || MFA <- ?EVENT_HANDLERS],
    Events.

call_count(Node, MFA) ->
    case erpc:call(Node, erlang, trace_info, [MFA, call_count]) of
        {call_count, N} when is_integer(N) -> N;
        _ -> 0
    end.

events_text(Events) ->
    string:join([io_lib:format("~s ~.2f", [M, V]) || {M, V} <- lists:sort(maps:to_list(Events))],
                ", ").

%% Runs in the EVATAR node.
node_stats() ->
    {{input, In}, {output, Out}} = erlang:statistics(io),
    {Switches, _} = erlang:statistics(context_switches),
    {Red, _} = erlang:statistics(reductions),
    #{in => In, out => Out, switches => Switches, reductions => Red,
      ports => length(erlang:ports()), processes => erlang:system_info(process_count)}.

stats_delta(S0, S1) ->
    fun(Done, Secs) ->
            D = fun(Key) -> (maps:get(Key, S1) - maps:get(Key, S0)) / max(1, Done) end,
            #{round_trips => Done, seconds => Secs, reductions => D(reductions),
              process_switches => D(switches), bytes_in => D(in), bytes_out => D(out),
              processes => maps:get(processes, S1), ports => maps:get(ports, S1)}
    end.

%% Micro-state accounting: time of every thread of the node, by state, in
%% us per round trip (the states include sleep, which is no CPU), and the
%% busy states' shares. These are wall-clock times: on a loaded machine a
%% thread the kernel has put aside still counts in its state, so read the
%% shares and take the CPU from /proc.
msacc_delta(_Before, Threads) ->
    fun(Done, Secs) ->
            Sums = lists:foldl(
                     fun(#{counters := Cs}, Acc) ->
                             maps:fold(fun(St, V, A) -> maps:update_with(St, fun(X) -> X + V end,
                                                                         V, A) end, Acc, Cs)
                     end, #{}, Threads),
            %% perf_counter units per second.
            Unit = erlang:convert_time_unit(1, second, perf_counter),
            ByState = maps:map(fun(_, V) -> V / Unit * 1.0e6 / max(1, Done) end, Sums),
            Busy = lists:sum([V || {St, V} <- maps:to_list(ByState), St =/= sleep]),
            #{round_trips => Done, seconds => Secs, by_state => ByState, busy_us_per_rt => Busy,
              busy_shares => maps:map(fun(_, V) -> V / max(1.0e-9, Busy) end,
                                      maps:remove(sleep, ByState))}
    end.

%% @private The tracer that counts the messages each kind of process
%% receives; runs in the EVATAR node.
-spec count_receives(pid()) -> ok.
count_receives(Controller) ->
    monitor(process, Controller),
    _ = erlang:trace(processes, true, ['receive']),
    Me = self(),
    _ = erlang:trace(Me, false, ['receive']),
    count_loop(#{}, #{}).

count_loop(Kinds, Counts) ->
    receive
        {trace, Pid, 'receive', _} ->
            {Kind, Kinds1} = kind(Pid, Kinds),
            count_loop(Kinds1, maps:update_with(Kind, fun(X) -> X + 1 end, 1, Counts));
        {counts, From, Ref} ->
            From ! {Ref, Counts},
            count_loop(Kinds, Counts);
        _Stop ->
            _ = erlang:trace(processes, false, ['receive']),
            ok
    end.

kind(Pid, Kinds) ->
    case Kinds of
        #{Pid := K} -> {K, Kinds};
        _ ->
            K = case process_info(Pid, [registered_name, initial_call, dictionary]) of
                    undefined -> <<"(gone)">>;
                    [{registered_name, Name}, _, _] when is_atom(Name) -> atom_to_binary(Name);
                    [_, {initial_call, Init}, {dictionary, Dict}] ->
                        {M, F, A} = case proplists:get_value('$initial_call', Dict) of
                                        undefined -> Init;
                                        MFA -> MFA
                                    end,
                        iolist_to_binary(io_lib:format("~s:~s/~b", [M, F, A]))
                end,
            {K, Kinds#{Pid => K}}
    end.

%% @private Asks the tracer for its counts; runs in the EVATAR node.
-spec receive_counts(pid()) -> #{binary() => non_neg_integer()}.
receive_counts(Tracer) ->
    Ref = make_ref(),
    Tracer ! {counts, self(), Ref},
    receive {Ref, Counts} -> Counts after 60000 -> error(tracer_silent) end.

hops_delta(C0, C1) ->
    fun(Done, Secs) ->
            Per = maps:map(fun(K, V) -> (V - maps:get(K, C0, 0)) / max(1, Done) end, C1),
            Top = lists:sublist(lists:reverse(lists:keysort(2, [{K, V} || {K, V} <- maps:to_list(Per),
                                                                         V >= 0.01])), 8),
            #{round_trips => Done, seconds => Secs, total => lists:sum(maps:values(Per)),
              by_kind => Per, top => [#{kind => K, per_rt => V} || {K, V} <- Top]}
    end.

%% eprof over every process of the node for KT round trips: calls and
%% time per round trip of the largest functions, and time by module group.
eprof_window(Node, Count, KT) ->
    File = filename:absname(filename:join("/tmp", "rt_profile_eprof_" ++ os:getpid() ++ ".txt")),
    Parent = self(),
    Runner = spawn_link(fun() ->
                                Parent ! {self(), erpc:call(Node, broker_bench_sut, profile_node,
                                                            [{until, Parent}, File, []],
                                                            ?TIMEOUT_MS)}
                        end),
    Profiler = receive {ready, P} -> P after 60000 -> error(eprof_not_started) end,
    C0 = Count(),
    ok = await_count(Count, C0 + KT),
    Profiler ! {stop, self()},
    receive {stopped, Profiler} -> ok after 60000 -> error(eprof_not_stopped) end,
    Done = Count() - C0,
    receive {Runner, ok} -> ok after ?TIMEOUT_MS -> error(eprof_timeout) end,
    {ok, Bin} = file:read_file(File),
    ok = file:delete(File),
    Rows = [{iolist_to_binary([M, ":", F, "/", A]), M, binary_to_integer(Calls),
             binary_to_integer(Us)}
            || Line <- binary:split(Bin, <<"\n">>, [global]),
               {match, [M, F, A, Calls, Us]} <-
                   [re:run(Line, <<"^([a-z'][^: ]*):(\\S+)/([0-9]+)\\s+([0-9]+)\\s+[0-9.]+\\s+([0-9]+)">>,
                           [{capture, all_but_first, binary}])]],
    TotalUs = lists:sum([Us || {_, _, _, Us} <- Rows]),
    Groups = lists:foldl(fun({_, M, _, Us}, Acc) ->
                                 maps:update_with(group(M), fun(X) -> X + Us end, Us, Acc)
                         end, #{}, Rows),
    Top = lists:sublist(lists:reverse(lists:keysort(4, Rows)), 20),
    Watched = [R || {Name, _, _, _} = R <- Rows, watched(Name)],
    Per = fun(X) -> X / max(1, Done) end,
    io:format("   eprof: ~.1f us of Erlang code per round trip while traced~n", [Per(TotalUs)]),
    #{round_trips => Done, us_per_rt_traced => Per(TotalUs),
      groups => maps:map(fun(_, Us) -> Us / max(1, TotalUs) end, Groups),
      top => [#{function => Name, calls_per_rt => Per(Calls), us_per_rt => Per(Us)}
              || {Name, _, Calls, Us} <- Top],
      watched => [#{function => Name, calls_per_rt => Per(Calls), us_per_rt => Per(Us)}
                  || {Name, _, Calls, Us} <- Watched]}.

%% Functions whose calls per round trip tell the scheme: frames sent,
%% socket reads re-armed, timers started and cancelled, messages sent.
watched(Name) ->
    lists:member(Name, [<<"erlang:port_command/3">>, <<"erlang:port_command/2">>,
                        <<"prim_inet:send/3">>, <<"gen_tcp:send/2">>, <<"ssl:send/2">>,
                        <<"inet:setopts/2">>, <<"prim_inet:setopts/2">>,
                        <<"erlang:start_timer/4">>, <<"erlang:start_timer/3">>,
                        <<"erlang:send_after/3">>, <<"erlang:send_after/4">>,
                        <<"erlang:cancel_timer/2">>, <<"erlang:cancel_timer/1">>,
                        <<"erlang:send/2">>, <<"erlang:send/3">>, <<"gen:do_call/4">>,
                        <<"erlang:monotonic_time/1">>, <<"erlang:monotonic_time/0">>,
                        <<"ets:lookup/2">>, <<"ets:insert/2">>, <<"erlang:garbage_collect/0">>]).

group(<<"bil", _/binary>>) -> <<"bil (codec, binding)">>;
group(<<"evatar_protocol", _/binary>>) -> <<"evatar_protocol (frames)">>;
group(<<"agent_bridge", _/binary>>) -> <<"agent_bridge (connections)">>;
group(<<"evatar", _/binary>>) -> <<"evatar (pairings)">>;
group(<<"sock_flow", _/binary>>) -> <<"sock_flow">>;
group(M) when M =:= <<"gen">>; M =:= <<"gen_statem">>; M =:= <<"gen_server">>;
              M =:= <<"proc_lib">> -> <<"gen_statem, gen_server, proc_lib">>;
group(M) when M =:= <<"gen_tcp">>; M =:= <<"inet">>; M =:= <<"prim_inet">>;
              M =:= <<"erts_internal">>; M =:= <<"ssl">>; M =:= <<"tls_sender">>;
              M =:= <<"tls_gen_connection">>; M =:= <<"tls_record">>;
              M =:= <<"ssl_gen_statem">> ->
    %% erts_internal:port_command/3 is the write to the socket.
    <<"socket I/O (port_command, gen_tcp, inet, ssl)">>;
group(<<"erlang">>) -> <<"erlang BIFs">>;
group(M) when M =:= <<"maps">>; M =:= <<"lists">>; M =:= <<"binary">>; M =:= <<"unicode">>;
              M =:= <<"ets">>; M =:= <<"queue">> -> <<"stdlib (maps, lists, binary, ets)">>;
group(_) -> <<"other">>.

%% ---------------------------------------------------------------------------
%% Report
%% ---------------------------------------------------------------------------

loadavg() ->
    {ok, B} = file:read_file("/proc/loadavg"),
    [binary_to_float(X) || X <- lists:sublist(binary:split(B, <<" ">>, [global]), 3)].

markdown(Rows, Cfg, Load0, Load1) ->
    F1 = fun(X) -> io_lib:format("~.1f", [float(X)]) end,
    F2 = fun(X) -> io_lib:format("~.2f", [float(X)]) end,
    Sys = [begin
               #{cpu := C, perf := P} = R,
               [atom_to_list(S), integer_to_list(N), integer_to_list(round(maps:get(rate, C))),
                F1(maps:get(us_per_rt, C)), F1(maps:get(user_us_per_rt, C)),
                F1(maps:get(sys_us_per_rt, C)), F2(maps:get(context_switches, P)),
                F2(maps:get(syscalls, P)),
                string:join([io_lib:format("~s ~.2f", [K, V])
                             || {K, V} <- lists:reverse(lists:keysort(2, maps:to_list(
                                                                        maps:get(by_syscall, P)))),
                                V >= 0.05], ", ")]
           end || #{system := S, n := N} = R <- Rows],
    Ev = [R || #{system := evatar} = R <- Rows],
    [io_lib:format("# Where a round trip's CPU goes~n~n~b round trips per window (~b traced), "
                   "load average ~w at start, ~w at end~n~n",
                   [maps:get(round_trips, Cfg), maps:get(traced, Cfg), Load0, Load1]),
     evatar_bench_report:md_table(
       ["system", "N", "rt/s", "CPU us/rt", "user", "kernel", "ctx switches/rt",
        "syscalls/rt", "syscalls by name per rt"], Sys),
     [["\n## EVATAR, N = ", integer_to_list(N), "\n\n",
       io_lib:format("- node: ~b reductions, ~.1f process switches, ~b bytes in and ~b out "
                     "per round trip (~b processes, ~b ports)~n",
                     [round(maps:get(reductions, St)), maps:get(process_switches, St),
                      round(maps:get(bytes_in, St)), round(maps:get(bytes_out, St)),
                      maps:get(processes, St), maps:get(ports, St)]),
       io_lib:format("- the node's busy threads' time by micro-state (wall clock, shares): ~s~n",
                     [string:join([io_lib:format("~s ~b%", [K, round(V * 100)])
                                   || {K, V} <- lists:reverse(lists:keysort(2, maps:to_list(
                                                                               maps:get(busy_shares, Ms)))),
                                      V >= 0.005], ", ")]),
       io_lib:format("- messages received per round trip: ~.2f; ~s~n",
                     [maps:get(total, H),
                      string:join([io_lib:format("~s ~.2f", [K, V])
                                   || #{kind := K, per_rt := V} <- maps:get(top, H)],
                                  ", ")]),
       io_lib:format("- events handled per round trip (handle_event/4 calls): ~s~n",
                     [events_text(maps:get(events, Nd, #{}))]),
       io_lib:format("- eprof: ~.1f us of Erlang code per round trip while traced; by group: ~s~n",
                     [maps:get(us_per_rt_traced, E),
                      string:join([io_lib:format("~s ~b%", [G, round(S * 100)])
                                   || {G, S} <- lists:reverse(lists:keysort(2, maps:to_list(
                                                                               maps:get(groups, E)))),
                                      S >= 0.005], ", ")]),
       "- calls per round trip: ",
       string:join([io_lib:format("~s ~.2f", [Fn, Cl])
                    || #{function := Fn, calls_per_rt := Cl} <- maps:get(watched, E), Cl >= 0.01],
                   ", "), "\n\n",
       evatar_bench_report:md_table(["function", "calls/rt", "us/rt (traced)"],
                                    [[binary_to_list(Fn), F2(Cl), F2(U)]
                                     || #{function := Fn, calls_per_rt := Cl, us_per_rt := U}
                                            <- maps:get(top, E)])]
      || #{n := N, node := #{stats := St, msacc := Ms, hops := H, eprof := E} = Nd} <- Ev]].

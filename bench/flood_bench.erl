%% @doc Isolation on one node: N pairings (1,000) of the raw generator
%% (evatar_bench_gen) in an open loop at a fixed offered rate, measured in
%% alternating rounds without and with flooders, each flooder in a pairing
%% of its own: a VA that sends requests as fast as its socket takes them
%% and never reads (its Avatar answers), and a VA that sends as fast as its
%% socket takes them to an Avatar that never answers. Prints the other
%% pairings' latency percentiles side by side, their ratio with/without,
%% and what the flooded pairings cost the node (memory, queues, work).
%% Each round with the flood runs twice: `paced', the flooders on the
%% benchmark's listener, whose connections read at most `max_read_rate'
%% frames a second (the default), and `unpaced', on a second listener with
%% `max_read_rate => infinity', as the bridge was before that bound.
%% Not part of the product; bench/README.md, "Isolation", has figures.
-module(flood_bench).

-export([main/0, main/1]).

-export_type([option/0]).

-import(evatar_bench_report, [fmt/2, int/1, kib/1, ms/1]).

-type option() :: quick
                | {pairings, pos_integer()}        % N, the others (1,000)
                | {rounds, pos_integer()}          % rounds of each kind, interleaved (3)
                | {seconds, number()}              % each measuring window (8)
                | {warmup, number()}               % before each window (2)
                | {load, float()}                  % offered rate: this share of the closed loop's maximum (0.5)
                | {rate, pos_integer()}            % or a fixed offered rate, round trips/s
                | {flooders, [evatar_bench_gen:flood_kind()]}   % (both)
                | {out, file:filename()}.

-define(GOAL_RATIO, 1.2).
-define(SAMPLE_MS, 250).

%% @equiv main([])
-spec main() -> ok.
main() -> main([]).

%% @doc Runs the benchmark in this node and prints its tables; writes
%% them as JSON and markdown (`flood-<date>-<time>') under `out'.
-spec main([option()]) -> ok.
main(Options) ->
    ok = io:setopts([{encoding, unicode}]),
    Cfg = config(Options),
    #{addr := Addr, conn_sup := ConnSup} = Ctx = evatar_bench:start(
                                                  #{conn => maps:with([max_read_rate],
                                                                      agent_bridge_conn:default_opts())}),
    Env = evatar_bench:environment(Ctx),
    N = maps:get(pairings, Cfg),
    io:format("Flood benchmark: OTP ~s, ~b schedulers, load average ~w; ~b pairings, ~b rounds"
              " of each kind, ~p s windows after ~p s warm-up~s~n",
              [maps:get(otp, Env), maps:get(schedulers, Env), maps:get(load_average, Env), N,
               maps:get(rounds, Cfg), maps:get(seconds, Cfg), maps:get(warmup, Cfg),
               case maps:get(quick, Cfg) of
                   true -> " (QUICK: a smoke run, figures not meant to be read)";
                   false -> ""
               end]),
    {ok, _} = agent_bridge:start_listener(flood_bench_unpaced,
                                          #{ip => {127, 0, 0, 1}, port => 0,
                                            max_connections => infinity,
                                            handshake => #{rate => infinity},
                                            conn => #{max_read_rate => infinity}}),
    {ok, Unpaced} = agent_bridge:address(flood_bench_unpaced),
    T0 = erlang:monotonic_time(millisecond),
    Pairs = evatar_bench_gen:setup(N, raw, Addr),
    io:format("-- ~b pairings bound in ~b ms; closed loop...~n",
              [N, erlang:monotonic_time(millisecond) - T0]),
    Closed = evatar_bench:closed_loop(Pairs, Cfg#{inflight => 1}, local),
    Max = maps:get(rate, Closed),
    Rate = case Cfg of
               #{rate := R} -> R;
               #{load := L} -> max(1.0, L * Max)
           end,
    io:format("   maximum ~s round trips/s; open loop at ~s/s~n", [int(Max), int(Rate)]),
    Base = node_memory(),
    Rounds = lists:append([[measure(K, off, Pairs, Rate, Cfg, Addr),
                            measure(K, paced, Pairs, Rate, Cfg, Addr),
                            measure(K, unpaced, Pairs, Rate, Cfg, Unpaced)]
                           || K <- lists:seq(1, maps:get(rounds, Cfg))]),
    ok = evatar_bench:teardown(Pairs, ConnSup),
    Summary = summary(Rounds),
    Text = report(Cfg, Env, Max, Rate, Base, Rounds, Summary),
    io:put_chars(["\n", Text]),
    Results = #{environment => Env,
                config => Cfg#{out := unicode:characters_to_binary(maps:get(out, Cfg))},
                closed => Closed, offered => Rate, node_memory_before => Base,
                rounds => Rounds, summary => Summary},
    {Json, Md} = evatar_bench_report:write(
                   maps:get(out, Cfg), "flood", Results,
                   ["# EVATAR flood benchmark, ", maps:get(date, Env), "\n\n",
                    "Produced by `make bench-flood` (scripts/bench-flood.sh). Plain-text tables "
                    "as printed.\n\n```\n", Text, "```\n"]),
    io:format("~nResults written to ~s and ~s~n", [Json, Md]),
    ok.

config(Options) ->
    Quick = lists:member(quick, Options),
    Default = case Quick of
                  true -> #{pairings => 100, rounds => 1, seconds => 2, warmup => 0.5};
                  false -> #{pairings => 1000, rounds => 3, seconds => 8, warmup => 2}
              end,
    Cfg = lists:foldl(fun({K, V}, Acc) -> Acc#{K => V};
                         (_, Acc) -> Acc
                      end, Default#{load => 0.5, flooders => [no_read, silent],
                                    out => "bench/results"}, Options),
    Cfg#{quick => Quick}.

%% ---------------------------------------------------------------------------
%% One round
%% ---------------------------------------------------------------------------

%% The open loop over the others, with the flood `on' or `off'. With it,
%% the flooders join first (each tells when it floods), a sampler follows
%% their processes through the window, and everything of the flood is
%% gone before the next round.
measure(K, off, Pairs, Rate, Cfg, _Addr) ->
    io:format("-- round ~b without the flood...~n", [K]),
    Open = evatar_bench:open_loop(Pairs, Rate, Cfg, local),
    print_open(Open),
    #{round => K, flood => off, open => Open, node_memory_after => node_memory()};
measure(K, Mode, Pairs, Rate, Cfg, Addr) ->
    io:format("-- round ~b with the flood (~w, ~s)...~n", [K, maps:get(flooders, Cfg), Mode]),
    Tab = ets:new(flood_sockets, [public, set]),
    true = ets:insert(Tab, {listener, Addr}),
    Floods = [start_flooder(Kind, K, Addr, Tab) || Kind <- maps:get(flooders, Cfg)],
    Red0 = flood_reductions(Floods, Tab),
    Total0 = element(1, erlang:statistics(reductions)),
    Sampler = start_sampler(Floods, Tab),
    Open = evatar_bench:open_loop(Pairs, Rate, Cfg, local),
    Peaks = stop_sampler(Sampler),
    Red1 = flood_reductions(Floods, Tab),
    Total1 = element(1, erlang:statistics(reductions)),
    End = [flood_end(F, Tab) || F <- Floods],
    ok = stop_flooders(Floods, Tab),
    ets:delete(Tab),
    print_open(Open),
    Shares = reduction_shares(Red0, Red1, max(1, Total1 - Total0)),
    #{round => K, flood => Mode, open => Open, node_memory_after => node_memory(),
      flooders => [F#{peaks => maps:get(Kind, Peaks, #{})}
                   || #{kind := Kind} = F <- End],
      flood_reduction_share => lists:sum(maps:values(Shares)),
      flood_reduction_shares => Shares}.

print_open(O) ->
    io:format("   p50 ~s ms, p99 ~s ms, p99.9 ~s ms, done ~s/s, sched ~s~n",
              [ms(maps:get(p50, O)), ms(maps:get(p99, O)), ms(maps:get(p999, O)),
               int(maps:get(achieved, O)), pct(maps:get(scheduler_utilisation, O))]).

%% A flooded pairing of its own: the pairing, its Avatar (answering for
%% `no_read', silent for `silent'), then the flooding VA.
start_flooder(Kind, K, Addr, Tab) ->
    Id = iolist_to_binary(["flood-", atom_to_binary(Kind), "-", integer_to_binary(K)]),
    {ok, Pairing} = evatar:create_pairing(Id, evatar_bench_gen:credentials()),
    {VaDesc, AvDesc} = evatar_bench_gen:descriptions(K, Id),
    Self = self(),
    Av = case Kind of
             no_read -> proc_lib:spawn(evatar_bench_gen, avatar_init,
                                       [Self, raw, Addr, Id, AvDesc]);
             silent -> proc_lib:spawn(evatar_bench_gen, silent_avatar_init,
                                      [Self, Addr, Id, AvDesc])
         end,
    receive {Av, described} -> ok after 60000 -> error({flood_avatar_not_described, Id}) end,
    C = counters:new(5, [write_concurrency]),
    Va = proc_lib:spawn(evatar_bench_gen, flood_va_init,
                        [Self, Kind, Addr, Id, VaDesc, #{counters => C, table => Tab}]),
    receive {Va, flooding} -> ok after 60000 -> error({flooder_not_bound, Id}) end,
    {ok, AvName} = avatar_sockname(Av),
    true = ets:insert(Tab, {Av, AvName}),
    #{kind => Kind, id => Id, pairing => Pairing, va => Va, avatar => Av, counters => C,
      va_mon => monitor(process, Va), started => erlang:monotonic_time(millisecond)}.

%% The Avatar's socket, from its process's links (a raw Avatar owns one).
avatar_sockname(Av) ->
    {links, Links} = erlang:process_info(Av, links),
    [Port] = [P || P <- Links, is_port(P)],
    inet:sockname(Port).

%% The bridge connection serving a client socket, found by its peer
%% address among the connection processes' sockets; `undefined' between a
%% reset and the rejoin. Only sockets of the round's listener count: a
%% connection of the round before may still be reading what its flooder
%% sent, from a client port the system has given out again.
server_side(Name, Tab) ->
    [{listener, {_, LPort}}] = ets:lookup(Tab, listener),
    Found = [{Port, Owner} || Port <- erlang:ports(),
                              erlang:port_info(Port, name) =:= {name, "tcp_inet"},
                              inet:peername(Port) =:= {ok, Name},
                              {ok, {_, Local}} <- [inet:sockname(Port)], Local =:= LPort,
                              {connected, Owner} <- [erlang:port_info(Port, connected)]],
    case Found of
        [{Port, Conn}] -> {Port, Conn};
        [] -> undefined
    end.

%% The processes of a flood: its clients, its pairing (statem and
%% supervisor) and the bridge connections serving its two clients.
flood_pids(#{va := Va, avatar := Av, pairing := P}, Tab) ->
    Sup = [S || S <- [sup_of(P)], is_pid(S)],
    Conns = [C || Client <- [Va, Av], [{_, Name}] <- [ets:lookup(Tab, Client)],
                  {_, C} <- [server_side(Name, Tab)]],
    [Va, Av, P | Sup] ++ Conns.

sup_of(P) ->
    case erlang:process_info(P, dictionary) of
        {dictionary, D} ->
            case proplists:get_value('$ancestors', D) of
                [Sup | _] when is_pid(Sup) -> Sup;
                _ -> undefined
            end;
        undefined -> undefined
    end.

%% Each process of the floods with its role (clients: the flooders' own
%% VA and Avatar processes, which a real flooder would run elsewhere) and
%% its reductions so far.
flood_reductions(Floods, Tab) ->
    maps:from_list([{P, {role(P, F), R}}
                    || F <- Floods, P <- flood_pids(F, Tab),
                       {reductions, R} <- [erlang:process_info(P, reductions)]]).

role(P, #{va := Va, avatar := Av}) when P =:= Va; P =:= Av -> clients;
role(P, #{pairing := Pairing}) when P =:= Pairing -> pairing;
role(P, _) ->
    case proc_lib:translate_initial_call(P) of
        {agent_bridge_conn, init, 1} -> connections;
        _ -> pairing
    end.

%% The floods' share of the node's reductions between two readings, by
%% role; a process gone by the second reading (a connection reset) is not
%% counted.
reduction_shares(Red0, Red1, Total) ->
    lists:foldl(fun({P, {Role, R}}, Acc) ->
                        R0 = case Red0 of
                                 #{P := {_, X}} -> X;
                                 _ -> 0
                             end,
                        maps:update_with(Role, fun(V) -> V + (R - R0) / Total end,
                                         (R - R0) / Total, Acc)
                end, #{clients => 0.0, connections => 0.0, pairing => 0.0},
                maps:to_list(Red1)).

%% ---------------------------------------------------------------------------
%% Following the flood's processes
%% ---------------------------------------------------------------------------

%% Every ?SAMPLE_MS (the sampling period; nothing waits on it) the
%% largest figures so far of each flood: its pairing's and its VA's
%% connection's memory and queue, their off-heap binaries, the VA's
%% server socket's output queue. The connection is looked up again only
%% when the flooder joined anew.
start_sampler(Floods, Tab) ->
    Self = self(),
    spawn_link(fun() -> sample_loop(Self, Floods, Tab, #{}, #{}) end).

stop_sampler(Pid) ->
    Pid ! {stop, self()},
    receive {peaks, Pid, Peaks} -> Peaks after 30000 -> error(sampler_stuck) end.

sample_loop(Parent, Floods, Tab, Conns, Peaks) ->
    {Conns1, Peaks1} =
        lists:foldl(fun(#{kind := Kind, va := Va, pairing := P}, {CAcc, PAcc}) ->
                            {Side, CAcc1} = va_conn(Va, Tab, CAcc),
                            Now = flood_now(P, Side),
                            Old = maps:get(Kind, PAcc, #{}),
                            Max = fun(_, A, B) -> maps:merge_with(fun(_, X, Y) -> max(X, Y) end,
                                                                  A, B)
                                  end,
                            {CAcc1, PAcc#{Kind => maps:merge_with(Max, Old, Now)}}
                    end, {Conns, Peaks}, Floods),
    receive
        {stop, Parent} -> Parent ! {peaks, self(), Peaks1}
    after ?SAMPLE_MS ->
            sample_loop(Parent, Floods, Tab, Conns1, Peaks1)
    end.

va_conn(Va, Tab, Cache) ->
    case ets:lookup(Tab, Va) of
        [{_, Name}] ->
            case Cache of
                #{Va := {Name, Side}} when Side =/= undefined -> {Side, Cache};
                _ -> Side = server_side(Name, Tab), {Side, Cache#{Va => {Name, Side}}}
            end;
        [] ->
            {undefined, Cache}
    end.

%% The flood's figures now, in bytes and messages.
flood_now(Pairing, Side) ->
    P = proc(Pairing),
    {C, Sock} = case Side of
                    {Port, Conn} -> {proc(Conn), port(Port)};
                    undefined -> {#{}, #{}}
                end,
    #{pairing => P, va_conn => C, va_socket => Sock}.

proc(Pid) ->
    case erlang:process_info(Pid, [memory, message_queue_len, binary]) of
        [{memory, M}, {message_queue_len, Q}, {binary, Bins}] ->
            #{memory => M, queue => Q, binaries => lists:sum([S || {_, S, _} <- Bins])};
        undefined ->
            #{}
    end.

port(Port) ->
    case {erlang:port_info(Port, memory), erlang:port_info(Port, queue_size)} of
        {{memory, M}, {queue_size, Q}} -> #{memory => M, queue_bytes => Q};
        _ -> #{}
    end.

%% ---------------------------------------------------------------------------
%% The end of a flood
%% ---------------------------------------------------------------------------

flood_end(#{kind := Kind, id := Id, pairing := P, va := Va, avatar := Av, counters := C,
            started := T0}, Tab) ->
    Secs = (erlang:monotonic_time(millisecond) - T0) / 1000,
    Side = case ets:lookup(Tab, Va) of
               [{_, Name}] -> server_side(Name, Tab);
               [] -> undefined
           end,
    AvSide = case ets:lookup(Tab, Av) of
                 [{_, AvName}] -> server_side(AvName, Tab);
                 [] -> undefined
             end,
    Stats = case evatar:stats(Id) of
                {ok, S} -> maps:with([routed, timeouts, errors, pending, dropped], S);
                {error, Why} -> #{unavailable => Why}
            end,
    Alive = is_process_alive(Va),
    Sent = counters:get(C, 1),
    #{kind => Kind, id => Id, seconds => Secs, flooder_alive => Alive,
      sent => Sent, sent_per_s => Sent / max(0.001, Secs),
      rejoins => counters:get(C, 2), timeouts_read => counters:get(C, 3),
      errors_read => counters:get(C, 4), frames_read => counters:get(C, 5),
      pairing_end => proc(P),
      pairing_sup_end => case sup_of(P) of undefined -> #{}; Sup -> proc(Sup) end,
      va_conn_end => case Side of {_, Conn} -> proc(Conn); undefined -> #{} end,
      va_socket_end => case Side of {Port, _} -> port(Port); undefined -> #{} end,
      avatar_conn_end => case AvSide of {_, AvConn} -> proc(AvConn); undefined -> #{} end,
      pairing_stats => Stats}.

%% Stops the flood's clients, deletes its pairings, and waits until every
%% process of it is gone.
stop_flooders(Floods, Tab) ->
    Pids = lists:append([flood_pids(F, Tab) || F <- Floods]),
    Mons = [{P, monitor(process, P)} || P <- Pids],
    _ = [exit(P, kill) || #{va := Va, avatar := Av} <- Floods, P <- [Va, Av]],
    _ = [evatar:delete_pairing(Id) || #{id := Id} <- Floods],
    _ = [receive {'DOWN', Ref, process, P, _} -> ok
         after 30000 -> error({flood_process_left, P})
         end || {P, Ref} <- Mons],
    _ = [receive {'DOWN', Ref, process, _, _} -> ok after 0 -> ok end
         || #{va_mon := Ref} <- Floods],
    ok.

node_memory() ->
    evatar_bench:gc_all(),
    erlang:memory(total).

%% ---------------------------------------------------------------------------
%% Figures
%% ---------------------------------------------------------------------------

summary(Rounds) ->
    Med = fun(Flood, Key) ->
                  median([maps:get(Key, O) || #{flood := F, open := O} <- Rounds, F =:= Flood,
                                              is_number(maps:get(Key, O))])
          end,
    Modes = [paced, unpaced],
    Figures = maps:from_list([{{F, K}, Med(F, K)} || F <- [off | Modes], K <- [p50, p99, p999]]),
    Of = fun(F) -> maps:from_list([{K, maps:get({F, K}, Figures)} || K <- [p50, p99, p999]]) end,
    Ratios = fun(M) -> maps:from_list([{K, ratio(maps:get({M, K}, Figures),
                                                 maps:get({off, K}, Figures))}
                                       || K <- [p50, p99, p999]])
             end,
    PerRound = fun(M) -> [ratio(maps:get(p99, On), maps:get(p99, Off))
                          || #{round := K, flood := off, open := Off} <- Rounds,
                             #{round := K2, flood := F, open := On} <- Rounds, K =:= K2, F =:= M]
               end,
    RoundRatio = fun(M) -> median([X || X <- PerRound(M), is_number(X)]) end,
    Busy = lists:max([0.0 | [X || #{open := #{cpu := #{other_cores := X}}} <- Rounds]]),
    Saturated = lists:max([0.0 | [U || #{flood := off, open := #{scheduler_utilisation := U}}
                                           <- Rounds, is_number(U)]]),
    Paced = RoundRatio(paced),
    #{others_max => Busy, baseline_sched_max => Saturated,
      without => Of(off), paced => Of(paced), unpaced => Of(unpaced),
      ratio => maps:from_list([{M, Ratios(M)} || M <- Modes]),
      p99_ratio_per_round => maps:from_list([{M, PerRound(M)} || M <- Modes]),
      p99_ratio_median_of_rounds => maps:from_list([{M, RoundRatio(M)} || M <- Modes]),
      goal_ratio => ?GOAL_RATIO,
      %% Judged on the rounds' own ratios, paced (the product's default):
      %% each pairs a window with the flood with the window before it,
      %% under the same noise.
      goal_met => is_number(Paced) andalso Paced =< ?GOAL_RATIO}.

ratio(A, B) when is_number(A), is_number(B), B > 0 -> A / B;
ratio(_, _) -> undefined.

median([]) -> undefined;
median(Xs) ->
    S = lists:sort(Xs),
    N = length(S),
    case N rem 2 of
        1 -> lists:nth((N + 1) div 2, S);
        0 -> (lists:nth(N div 2, S) + lists:nth(N div 2 + 1, S)) / 2
    end.

report(Cfg, Env, Max, Rate, Base, Rounds, Summary) ->
    N = maps:get(pairings, Cfg),
    RoundRows = [[fmt("~b", [K]), atom_to_list(F), int(maps:get(offered, O)),
                  int(maps:get(achieved, O)), ms(maps:get(p50, O)), ms(maps:get(p99, O)),
                  ms(maps:get(p999, O)), ms(maps:get(max, O)), ms(maps:get(send_lag_p99, O)),
                  pct(maps:get(scheduler_utilisation, O)), cores(O),
                  case R of
                      #{flood_reduction_shares := #{clients := Cl, connections := Co,
                                                    pairing := Pa}} ->
                          fmt("~b/~b/~b", [round(100 * Cl), round(100 * Co), round(100 * Pa)]);
                      _ -> "-"
                  end,
                  int(maps:get(errors, O) + maps:get(timeouts, O) + maps:get(unanswered, O)),
                  kib(maps:get(node_memory_after, R))]
                 || #{round := K, flood := F, open := O} = R <- Rounds],
    #{without := W, paced := Pa, unpaced := Un, ratio := #{paced := RPa, unpaced := RUn}} = Summary,
    Side = [[atom_to_list(K), ms(maps:get(K, W)), ms(maps:get(K, Pa)), ms(maps:get(K, Un)),
             ratio_cell(maps:get(K, RPa)), ratio_cell(maps:get(K, RUn))]
            || K <- [p50, p99, p999]],
    #{p99_ratio_per_round := PerRound, p99_ratio_median_of_rounds := RoundMedian} = Summary,
    FloodRows = lists:append(
                  [[flood_row(K, Fl) || Fl <- Fls]
                   || #{round := K0, flood := M, flooders := Fls} <- Rounds,
                      K <- [fmt("~b ~s", [K0, M])]]),
    PeakRows = lists:append(
                 [[peak_row(K, Fl) || Fl <- Fls]
                  || #{round := K0, flood := M, flooders := Fls} <- Rounds,
                     K <- [fmt("~b ~s", [K0, M])]]),
    [io_lib:format("== EVATAR flood benchmark (~s, OTP ~s, ~b schedulers) ==~n",
                   [maps:get(date, Env), maps:get(otp, Env), maps:get(schedulers, Env)]),
     io_lib:format("~b pairings of the raw generator (evatar_bench_gen), the others; closed-loop"
                   " maximum ~s round trips/s,~n"
                   "open loop at ~s/s (~s) in every round, ~p s windows after ~p s warm-up;"
                   " rounds without and with~n"
                   "the flood interleaved. Flooders, each in its own pairing: ~s.~n",
                   [N, int(Max), int(Rate),
                    case Cfg of
                        #{rate := _} -> "fixed";
                        #{load := L} -> fmt("~b % of the maximum", [round(100 * L)])
                    end,
                    maps:get(seconds, Cfg), maps:get(warmup, Cfg),
                    string:join([describe(K) || K <- maps:get(flooders, Cfg)], "; ")]),
     "\n-- The others' latency per round (from the scheduled send time; lag p99 = the\n"
     "   generator's own delay; sched = normal schedulers' busy share; others = cores used\n"
     "   by other OS processes; flood work % = the floods' share of the node's reductions in\n"
     "   the round, at least (connections reset meanwhile are not counted): their clients\n"
     "   (in this node, as the others' generator) / bridge connections / pairings;\n"
     "   node after = erlang:memory(total) after the round, the flood gone, every process\n"
     "   garbage-collected; before the first round: " ++ kib(Base) ++ " KiB)\n\n",
     evatar_bench_report:table(["round", "flood", "offered/s", "done/s", "p50 ms", "p99 ms",
                                "p99.9 ms", "max ms", "lag p99", "sched", "others",
                                "flood work cli/conn/pair %", "errors", "node after KiB"], RoundRows),
     "\n-- Side by side: medians over the rounds, and with/without\n\n",
     evatar_bench_report:table(["", "without ms", "paced ms", "unpaced ms", "paced/without",
                                "unpaced/without"], Side),
     [io_lib:format("~n   p99 ~s/without per round (against the window without in the same round):"
                    " ~s; median ~s",
                    [M, string:join([ratio_cell(X) || X <- maps:get(M, PerRound)], ", "),
                     ratio_cell(maps:get(M, RoundMedian))])
      || M <- [paced, unpaced]],
     io_lib:format("~n   Goal: the others' p99 within ~.1fx of the same run without the flood, paced"
                   " (the default),~n   on the median of the rounds' ratios: ~s~n",
                   [?GOAL_RATIO, case maps:get(goal_met, Summary) of
                                     true -> "MET";
                                     false -> "NOT MET"
                                 end]),
     [io_lib:format("   NOTE: other OS processes used up to ~.2f cores, and the schedulers were up"
                    " to ~b % busy~n"
                    "   in the rounds without the flood: this node had what CPU the machine left"
                    " it, the absolute~n"
                    "   figures are noise and the ratio only indicative (over 90 %: the offered"
                    " rate was not~n"
                    "   sustainable even without the flood; offer less, {load, 0.25} or"
                    " {rate, R}).~n",
                    [maps:get(others_max, Summary),
                     round(100 * maps:get(baseline_sched_max, Summary))])
      || maps:get(others_max, Summary) > 0.5 orelse maps:get(baseline_sched_max, Summary) > 0.9],
     "\n-- What each flood did and holds at the end of its round (KiB; mbox = message\n"
     "   queue; bins = off-heap binaries the process refers to; sock q = bytes queued in\n"
     "   the VA's server socket port; rejoins = connections reset and joined again;\n"
     "   read = frames the flooder read back: timeouts, TooManyRequests errors)\n\n",
     evatar_bench_report:table(["round", "flooder", "sent/s", "rejoins", "read",
                                "timeouts", "errors", "pairing KiB", "mbox", "va conn KiB",
                                "mbox", "bins KiB", "sock q KiB", "av conn KiB", "pending"],
                               FloodRows),
     io_lib:format("~n-- The largest figures seen during the round (sampled every ~b ms)~n~n",
                   [?SAMPLE_MS]),
     evatar_bench_report:table(["round", "flooder", "pairing KiB", "mbox", "bins KiB",
                                "va conn KiB", "mbox", "bins KiB", "sock q KiB"], PeakRows)].

describe(no_read) -> "no_read = a VA sending as fast as its socket takes it, never reading (its"
                         " Avatar answers)";
describe(silent) -> "silent = a VA sending as fast as its socket takes it, reading, to an Avatar"
                        " that never answers".

flood_row(K, #{kind := Kind} = F) ->
    P = maps:get(pairing_end, F),
    C = maps:get(va_conn_end, F),
    S = maps:get(va_socket_end, F),
    A = maps:get(avatar_conn_end, F),
    [K, atom_to_list(Kind), int(maps:get(sent_per_s, F)), int(maps:get(rejoins, F)),
     int(maps:get(frames_read, F)), int(maps:get(timeouts_read, F)), int(maps:get(errors_read, F)),
     kib(maps:get(memory, P, undefined)), int(maps:get(queue, P, undefined)),
     kib(maps:get(memory, C, undefined)), int(maps:get(queue, C, undefined)),
     kib(maps:get(binaries, C, undefined)), kib(maps:get(queue_bytes, S, undefined)),
     kib(maps:get(memory, A, undefined)),
     int(maps:get(pending, maps:get(pairing_stats, F), undefined))].

peak_row(K, #{kind := Kind, peaks := P}) ->
    G = fun({Who, Key}) -> maps:get(Key, maps:get(Who, P, #{}), undefined) end,
    [K, atom_to_list(Kind), kib(G({pairing, memory})), int(G({pairing, queue})),
     kib(G({pairing, binaries})), kib(G({va_conn, memory})), int(G({va_conn, queue})),
     kib(G({va_conn, binaries})), kib(G({va_socket, queue_bytes}))].

ratio_cell(undefined) -> "-";
ratio_cell(X) -> fmt("~.2fx", [X]).

pct(undefined) -> "-";
pct(F) -> fmt("~b%", [round(100 * F)]).

cores(#{cpu := #{other_cores := X}}) -> fmt("~.2f", [X]);
cores(_) -> "-".

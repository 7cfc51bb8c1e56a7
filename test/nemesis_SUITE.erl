%% Common Test suite in the manner of Jepsen: a nemesis injects randomized
%% faults into a three-node EVATAR cluster of real OS processes (kill -9,
%% SIGSTOP then SIGCONT, a silent partition isolating one node or cutting
%% one link, healed by flushing or resetting the cut connections, restart
%% of a killed node) while several pairings carry traffic: every VA sends
%% requests and receives their feedback, every Avatar answers them and
%% streams sensor data, all through HA clients of the bridge that know
%% every node; and power cuts (kill -9 of every node at once, then all
%% started again). Afterwards every signal is classified as Jepsen's RabbitMQ
%% checker does (evatar_test_checker): ok, lost, duplicated, unexpected (and
%% recovered, unconfirmed). The run passes with zero lost, zero duplicated
%% and zero unexpected, every pairing back to one active and one synced
%% standby, and no client given up. Signals in flight at a power cut may
%% be lost or duplicated (docs/ha.md section 6): the checker counts them
%% apart.
%%
%% The nemesis keeps a majority of nodes working most of the time (one
%% fault at a time, each repaired before the next), so the cluster makes
%% progress; unavailability while a fault lasts is allowed, loss is not.
%% Partitions go through evatar_test_proxy, as in ha_SUITE. The nodes run
%% with the release's rebalancing: a node that returns gets its share of
%% actives and standbys back by planned handovers while the faults go on,
%% and those moves must lose and duplicate nothing too.
%%
%% A fault lasts until its effect is seen, never for a time: while a
%% majority of the nodes works, until every pairing has carried a random
%% number of signals each way (1 to 6) since the fault began, through
%% whichever instance serves it then (a takeover, a fencing, a client
%% moving on); with no majority (two nodes down, a power cut), until both
%% clients of every pairing hold a signal no node acknowledged. After the
%% repair, the cluster is left to become healthy again, then to carry 0
%% to 3 more signals each way, before the next fault. So the faults fall
%% at moments as varied as the seed makes them, and a run does the same
%% on an idle and on a busy machine.
%%
%% The normal run (`make test') injects EVATAR_NEMESIS_COUNT=16 faults;
%% `make soak' sets EVATAR_SOAK_SECONDS instead, and faults go on for that
%% long. EVATAR_NEMESIS_SEED replays a run (the seed is printed);
%% EVATAR_NEMESIS_FAULTS chooses the kinds of faults (fault_kinds/0).
-module(nemesis_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").

-compile([export_all, nowarn_export_all]).

-define(PAIRINGS, 4).
-define(TRAFFIC, #{request_interval => 40, sensor_interval => 40}).
-define(DEFAULT_COUNT, 16).

%% A fault and its repair take a few seconds; the timetrap is a hang guard.
suite() -> [{timetrap, evatar_test_time:ms(300000) + case budget() of
                                                        {seconds, S} -> 1000 * S;
                                                        {faults, N} -> 20000 * N
                                                    end}].

all() -> [{group, checker}, {group, nemesis}].

groups() ->
    [{checker, [parallel], [checker_classifies, checker_power_cut]},
     {nemesis, [], [random_faults]}].

%% How many faults, or for how long (a soak).
budget() ->
    case {os:getenv("EVATAR_SOAK_SECONDS"), os:getenv("EVATAR_NEMESIS_COUNT")} of
        {false, false} -> {faults, ?DEFAULT_COUNT};
        {false, N} -> {faults, list_to_integer(N)};
        {S, _} -> {seconds, list_to_integer(S)}
    end.

init_per_group(nemesis, Config) ->
    init_nemesis(Config);
init_per_group(_, Config) ->
    Config.

init_nemesis(Config) ->
    Dist = evatar_test_cluster:ensure_distributed(),
    Dir = filename:join(?config(priv_dir, Config), "nemesis"),
    ok = filelib:ensure_path(Dir),
    %% Detection as in ha_SUITE (see there); the nemesis is the faults.
    {ok, C} = evatar_test_cluster:start(#{dir => Dir, prefix => "nem",
                                          evatar => evatar_test_time:ha_timing()}),
    [{cluster, C}, {dist, Dist} | Config].

end_per_group(nemesis, Config) ->
    ok = evatar_test_cluster:stop(?config(cluster, Config)),
    evatar_test_cluster:release_distribution(?config(dist, Config));
end_per_group(_, _Config) ->
    ok.

%% ---------------------------------------------------------------------------
%% Cases
%% ---------------------------------------------------------------------------

%% The checker sorts a made-up history into the right categories, so a run
%% with a lost, duplicated or unexpected signal cannot pass.
checker_classifies(_Config) ->
    Sent = [<<"a">>, <<"b">>, <<"c">>, <<"d">>, <<"e">>, <<"f">>],
    Accepted = [<<"a">>, <<"b">>, <<"c">>, <<"d">>],
    Delivered = [<<"a">>, <<"b">>, <<"b">>, <<"e">>, <<"zz">>],
    R = evatar_test_checker:classify(Sent, Accepted, Delivered),
    ?assertMatch(#{ok := 1, lost := [<<"c">>, <<"d">>], duplicated := [<<"b">>],
                   unexpected := [<<"zz">>], recovered := 1, unconfirmed := 1}, R),
    ?assertNot(evatar_test_checker:passed(R)),
    Clean = evatar_test_checker:classify(Sent, Accepted, [<<"a">>, <<"b">>, <<"c">>, <<"d">>]),
    ?assert(evatar_test_checker:passed(Clean)),
    ?assertMatch(#{ok := 4, unconfirmed := 2}, Clean),
    ?assertNot(evatar_test_checker:passed(evatar_test_checker:classify([<<"x">>], [<<"x">>], []))),
    ok.

%% Across a power cut at 100: a signal acknowledged before it and never
%% delivered was in flight (allowed), one acknowledged after it is lost,
%% and so is the feedback to a request asked after it (the feedback to one
%% asked before it is allowed: that request was forgotten);
%% one delivered before and again after it is allowed, one delivered twice
%% after it is a duplicate.
checker_power_cut(_Config) ->
    Va = #{sent => [<<"a">>, <<"b">>, <<"c">>, <<"d">>, <<"q">>, <<"r">>],
           accepted => [<<"a">>, <<"b">>, <<"c">>, <<"d">>, <<"q">>, <<"r">>],
           accepted_at => #{<<"a">> => 50, <<"b">> => 150, <<"c">> => 60, <<"d">> => 160,
                            <<"q">> => 90, <<"r">> => 130},
           received => [], received_at => #{}},
    %% The Avatar got request q before the cut and r after it; neither
    %% feedback arrived.
    Av = #{sent => [<<"fb-q">>, <<"fb-r">>], accepted => [<<"fb-q">>, <<"fb-r">>],
           accepted_at => #{<<"fb-q">> => 140, <<"fb-r">> => 145},
           received => [{<<"c">>, 1}, {<<"c">>, 1}, {<<"d">>, 1}, {<<"d">>, 1},
                        {<<"q">>, 1}, {<<"r">>, 1}],
           received_at => #{<<"c">> => [120, 70], <<"d">> => [180, 170], <<"q">> => [95],
                            <<"r">> => [135]}},
    R = evatar_test_checker:check_pairs([#{va => Va, av => Av}], [100]),
    ?assertMatch(#{lost := [<<"b">>, <<"fb-r">>], duplicated := [<<"d">>], lost_at_cut := 2,
                   duplicated_at_cut := 1}, R),
    ?assertNot(evatar_test_checker:passed(R)),
    ok.

%% Randomized faults (EVATAR_NEMESIS_COUNT of them, or for
%% EVATAR_SOAK_SECONDS) while traffic flows; then zero
%% lost, zero duplicated, zero unexpected, every pairing healthy.
random_faults(Config) ->
    C = ?config(cluster, Config),
    Seed = seed(),
    ct:pal("nemesis seed ~p (EVATAR_NEMESIS_SEED=~s to replay), ~p, faults among ~p",
           [Seed, seed_string(Seed), budget(), fault_kinds()]),
    _ = rand:seed(exsss, Seed),
    N = length(evatar_test_cluster:nodes(C)),
    Ids = [iolist_to_binary(io_lib:format("nem-~b", [K])) || K <- lists:seq(1, ?PAIRINGS)],
    _ = [ok = evatar_test_pairing:create(C, 1 + (K - 1) rem N, Id)
         || {K, Id} <- lists:enumerate(Ids)],
    Pairs = [begin {ok, P} = evatar_test_traffic:start_pair(evatar_test_cluster:endpoints(C), Id, ?TRAFFIC), P end
             || Id <- Ids],
    Start = erlang:monotonic_time(millisecond),
    Until = case budget() of
                {seconds, S} -> {deadline, Start + S * 1000};
                {faults, F} -> {faults, F}
            end,
    Log = nemesis(C, Ids, Pairs, Until, []),
    ct:pal("faults (~b), at ms from the start:~n~s",
           [length(Log), [io_lib:format("  ~6b ~p~n", [T - Start, F]) || {T, F} <- Log]]),
    %% Repair what may still be broken, then let every pairing recover.
    ok = evatar_test_cluster:heal(C, flush),
    _ = [ok = evatar_test_cluster:resume(C, I) || #{i := I, status := stalled} <- evatar_test_cluster:info(C)],
    _ = [ok = evatar_test_cluster:restart(C, I) || #{i := I, status := down} <- evatar_test_cluster:info(C)],
    ok = evatar_test_cluster:await_formed(C, 120000),
    %% One deadline for all pairings: they recover (and settle) together.
    %% Rebalancing is on (the release's default), so a node's return may
    %% still move pairings by planned handovers: every pairing must be seen
    %% healthy at one moment, not each of them again a second later.
    Healthy = evatar_test_cluster:await(
                fun() -> lists:all(fun(Id) -> evatar_test_pairing:healthy(C, Id) end, Ids) end,
                60000, all_healthy),
    Roles = [{Id, evatar_test_pairing:roles(C, Id)} || Id <- Ids],
    _ = [ok = evatar_test_traffic:stop_traffic(P) || P <- Pairs],
    Cuts = [At || {_, {power_cut, At}} <- Log],
    %% Signals in flight at a power cut never arrive: wait for all others.
    Settled = evatar_test_pairing:pmap(
                fun(P) -> {maps:get(pairing, P), evatar_test_traffic:settle(P, Cuts, 45000)} end,
                Pairs, max(1, length(Pairs))),
    Histories = [evatar_test_traffic:history(P) || P <- Pairs],
    Result = evatar_test_checker:check_pairs(Histories, Cuts),
    _ = [ct:pal("~s: ~s; history in ~s", [maps:get(pairing, P), evatar_test_checker:format(R),
                                         evatar_test_traffic:dump(P, H)])
         || {P, H} <- lists:zip(Pairs, Histories),
            R <- [evatar_test_checker:check_pairs([H])], not evatar_test_checker:passed(R)],
    Sent = lists:sum([length(maps:get(sent, H)) || #{va := Va, av := Av} <- Histories,
                                                   H <- [Va, Av]]),
    Reconnects = lists:sum([length(maps:get(reconnects, H)) || #{va := Va, av := Av} <- Histories,
                                                             H <- [Va, Av]]),
    %% Signals from EVATAR itself (errors, timeouts), by type: reported.
    Mediator = lists:foldl(fun(#{body := #{type := T}}, M) ->
                                   maps:update_with(T, fun(X) -> X + 1 end, 1, M);
                              (_, M) ->
                                   M
                           end, #{}, [Sig || #{va := Va, av := Av} <- Histories, H <- [Va, Av],
                                             Sig <- maps:get(mediator, H)]),
    Summary = io_lib:format("~b faults, ~b signals sent, ~b reconnections; ~s; from EVATAR: ~s",
                            [length(Log), Sent, Reconnects, evatar_test_checker:format(Result),
                             [io_lib:format("~s ~b ", [T, X]) || {T, X} <- maps:to_list(Mediator)]]),
    ct:pal("~s", [Summary]),
    ct:comment("~s", [hd(string:split(lists:flatten(Summary), "\n"))]),
    ?assertEqual(ok, Healthy, Roles),
    ?assertEqual([], [X || {_, R} = X <- Settled, R =/= ok]),
    ?assert(evatar_test_checker:passed(Result)),
    ?assertEqual([], [{E, R} || #{va := Va, av := Av} <- Histories, H <- [Va, Av],
                                #{entity := E, closed := R} <- [H], R =/= undefined]),
    ?assert(Sent > 0),
    ok.

%% ---------------------------------------------------------------------------
%% The nemesis
%% ---------------------------------------------------------------------------

%% One fault at a time: choose, apply, hold it until its effect is seen
%% (held/3), repair, let the cluster become healthy again (at most 20 s:
%% a fault may also hit it before it is) and carry 0-3 more signals each
%% way.
nemesis(C, Ids, Pairs, Until, Log) ->
    Done = case Until of
               {deadline, D} -> erlang:monotonic_time(millisecond) >= D;
               {faults, F} -> length(Log) >= F
           end,
    case Done of
        true ->
            lists:reverse(Log);
        false ->
            Fault0 = choose(C, Ids),
            T = erlang:monotonic_time(millisecond),
            ok = apply_fault(C, Fault0),
            %% When every node is dead: the checker's reference for it.
            Fault = case Fault0 of
                        power_cut -> {power_cut, erlang:monotonic_time(millisecond)};
                        _ -> Fault0
                    end,
            ok = held(C, Fault, Pairs, T),
            ok = repair(C, Fault),
            _ = evatar_test_cluster:await_formed(C, 20000),
            _ = evatar_test_cluster:await(fun() -> lists:all(fun(Id) -> evatar_test_pairing:healthy(C, Id) end,
                                                             Ids) end, 20000, healthy),
            ok = carried(Pairs, erlang:monotonic_time(millisecond), rand:uniform(4) - 1, settled),
            nemesis(C, Ids, Pairs, Until, [{T, Fault} | Log])
    end.

%% A fault that leaves a majority working lasts until the nodes that see
%% it suspect what it hit, then until every pairing has carried 1-6
%% signals each way since (the HA serves through a single fault:
%% docs/ha.md section 6); one that leaves none working (two nodes down, a
%% power cut), until every client holds a signal no node acknowledged,
%% sent since it began.
held(_C, {power_cut, _}, Pairs, Since) ->
    queued(Pairs, Since);
held(_C, {kill_and_stall_other, _, _}, Pairs, Since) ->
    queued(Pairs, Since);
held(C, Fault, Pairs, _Since) ->
    ok = evatar_test_wait:until(fun() -> suspected(C, Fault) end, #{what => {suspected, Fault}}),
    carried(Pairs, erlang:monotonic_time(millisecond), rand:uniform(6), {held, Fault}).

%% Whether the nodes that see a fault no longer count what it hit alive.
suspected(C, {cut_link, I, J, _}) ->
    not_alive(C, I, J) andalso not_alive(C, J, I);
suspected(C, Fault) ->
    I = element(2, Fault),
    lists:all(fun(J) -> not_alive(C, J, I) end,
              lists:seq(1, length(evatar_test_cluster:nodes(C))) -- [I]).

not_alive(C, Observer, I) ->
    case evatar_test_cluster:call(C, Observer, evatar_cluster, alive_nodes, []) of
        Alive when is_list(Alive) -> not lists:member(evatar_test_cluster:node(C, I), Alive);
        _ -> false
    end.

carried(_Pairs, _Since, 0, _What) ->
    ok;
carried(Pairs, Since, N, What) ->
    evatar_test_wait:until(fun() -> evatar_test_traffic:carried(Pairs, Since, N) end,
                           #{what => {carried, N, What}}).

queued(Pairs, Since) ->
    evatar_test_wait:until(fun() -> evatar_test_traffic:queued(Pairs, Since) end,
                           #{what => queued_while_no_majority}).

%% Half of the faults hit the node holding an active instance.
choose(C, Ids) ->
    N = length(evatar_test_cluster:nodes(C)),
    Target = case rand:uniform(2) of
                 1 ->
                     Id = lists:nth(rand:uniform(length(Ids)), Ids),
                     case evatar_test_pairing:active(C, Id) of
                         {ok, I, _} -> I;
                         {error, _} -> rand:uniform(N)
                     end;
                 2 ->
                     rand:uniform(N)
             end,
    Kinds = fault_kinds(),
    case lists:nth(rand:uniform(length(Kinds)), Kinds) of
        kill -> {kill, Target};
        stall -> {stall, Target};
        isolate -> {isolate, Target, heal_mode()};
        cut_link -> {cut_link, Target, other(Target, N), heal_mode()};
        double -> {kill_and_stall_other, Target, other(Target, N)};
        power_cut -> power_cut
    end.

%% EVATAR_NEMESIS_FAULTS, comma-separated, chooses among the kinds (all by
%% default): kill, stall, isolate (one node cut off from the others),
%% cut_link (a partial partition: one link cut, the third node sees both),
%% double (one node killed and another stalled at once), power_cut (every
%% node killed at once, then all started again).
fault_kinds() ->
    All = [kill, stall, isolate, cut_link, double, power_cut],
    case os:getenv("EVATAR_NEMESIS_FAULTS") of
        false -> All;
        S -> [K || K <- All, lists:member(atom_to_list(K), string:lexemes(S, ", "))]
    end.

heal_mode() ->
    case rand:uniform(2) of
        1 -> flush;
        2 -> reset
    end.

other(I, N) ->
    Others = lists:seq(1, N) -- [I],
    lists:nth(rand:uniform(length(Others)), Others).

apply_fault(C, {kill, I}) -> evatar_test_cluster:kill(C, I);
apply_fault(C, {stall, I}) -> evatar_test_cluster:stall(C, I);
apply_fault(C, {isolate, I, _}) -> evatar_test_cluster:isolate(C, I);
apply_fault(C, {cut_link, I, J, _}) ->
    %% A partial partition: I and J lose each other, the third node still
    %% sees both.
    evatar_test_cluster:cut(C, [{I, J}]);
apply_fault(C, power_cut) -> evatar_test_cluster:power_cut(C);
apply_fault(C, {kill_and_stall_other, I, J}) ->
    %% Two nodes down at once for a moment: no majority, no progress, and
    %% still nothing may be lost.
    ok = evatar_test_cluster:kill(C, I),
    evatar_test_cluster:stall(C, J).

repair(C, {kill, I}) -> evatar_test_cluster:restart(C, I);
repair(C, {stall, I}) -> evatar_test_cluster:resume(C, I);
repair(C, {isolate, _, Mode}) -> evatar_test_cluster:heal(C, Mode);
repair(C, {cut_link, _, _, Mode}) -> evatar_test_cluster:heal(C, Mode);
repair(C, {power_cut, _}) -> evatar_test_cluster:restart_all(C);
repair(C, {kill_and_stall_other, I, J}) ->
    ok = evatar_test_cluster:resume(C, J),
    evatar_test_cluster:restart(C, I).

seed() ->
    case os:getenv("EVATAR_NEMESIS_SEED") of
        false ->
            {erlang:unique_integer([positive]), erlang:system_time(microsecond) rem 1000000007,
             rand:uniform(1000000)};
        S ->
            {ok, Tokens, _} = erl_scan:string(S ++ "."),
            {ok, Term} = erl_parse:parse_term(Tokens),
            Term
    end.

seed_string(Seed) ->
    lists:flatten(io_lib:format("'~w'", [Seed])).

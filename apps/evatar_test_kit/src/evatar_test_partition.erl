%% @doc Test support. The partition scenario of issue 18, run on an evatar_test_cluster
%% cluster with evatar_test_traffic pairs, and what it measures: for each pairing,
%% the longest time its VA went without a round trip across a partition.
%% Used by test/netns_SUITE.erl (which asserts) and
%% bench/partition_bench.erl (which prints).
%%
%% The scenario leaves a stale promise behind, then cuts the active of the
%% pairing that holds it from its current standby:
%% <ol>
%% <li>pairing P is active on node A with its standby on S; S is cut from
%% the other nodes: P's standby runs an election alone and S promises it
%% the next epoch; A has the cluster accept a configuration without S and
%% places a new standby on the third node T;</li>
%% <li>the network heals (the promise on S stays), every pairing is
%% healthy again;</li>
%% <li>the measured partition, of one `kind': `nodes' (T cut from the
%% other nodes, its clients still reach it), `all' (T cut from
%% everything), `link' (only the link between A and T cut). A must have
%% a configuration without T accepted; S refuses it for its promise, T is
%% silent.</li>
%% </ol>
%%
%% The rebalancing scenario (rebalance/3): a node is cut from the other
%% nodes until every pairing has failed over away from it; rebalancing is
%% switched on and the node returns; the rebalancer moves actives and
%% standbys to it by planned handovers and standby moves until every node
%% holds its share. What it measures: for each pairing, the longest time
%% its VA went without a round trip from the return on. A test fires the
%% rebalancer's rounds itself (`fire'), each once the moves of the one
%% before are carried out; the benchmark leaves them to their timers.
-module(evatar_test_partition).

-export([run/4, rebalance/3, baseline/2, counts/2, placement/2, unserved/2, await_healthy/3]).

-export_type([kind/0, result/0, rebalance_result/0]).

-type kind() :: nodes | all | link.
%% unserved: per pairing, its longest time without a round trip from its
%% last one before the cut to the end of the run (unserved/2), `never' if
%% none came after the cut; served_during_cut: the pairings with a round
%% trip in the second half of the partition; stale_promise: {P's epoch,
%% the epoch S had promised P} when the measured partition began.
-type result() :: #{kind := kind(), unserved := [{binary(), non_neg_integer() | never}],
                    max := non_neg_integer() | never, served_during_cut := [binary()],
                    pairing := binary(), active := pos_integer(), standby := pos_integer(),
                    promised := pos_integer(), stale_promise := {non_neg_integer(), non_neg_integer()},
                    cut_ms := non_neg_integer()}.

%% unserved: per pairing, its longest time without a round trip from its
%% last one before the node returned to the end of the run; spread_ms:
%% from the return until every node held its share; counts_before,
%% counts_after: {actives, standbys} per node index when the node returned
%% and at the end.
-type counts() :: #{pos_integer() => {non_neg_integer(), non_neg_integer()}}.
-type rebalance_result() :: #{unserved := [{binary(), non_neg_integer() | never}],
                              max := non_neg_integer() | never,
                              spread_ms := non_neg_integer(),
                              counts_before := counts(), counts_after := counts()}.

%% @doc Runs the scenario on `Net' with the pairs already carrying traffic
%% (the first pair's pairing is P). Opts: first_ms (the first partition,
%% default 2000), cut_ms (the measured one, default 4000), timeout (for
%% every wait, default 60000).
-spec run(evatar_test_cluster:cluster(), [evatar_test_traffic:pair()], kind(), map()) ->
          {ok, result()} | {error, term()}.
run(Net, [#{pairing := P} | _] = Pairs, Kind, Opts) ->
    First = maps:get(first_ms, Opts, 2000),
    CutMs = maps:get(cut_ms, Opts, 4000),
    Timeout = maps:get(timeout, Opts, 60000),
    Ids = [Id || #{pairing := Id} <- Pairs],
    ok = await_healthy(Net, Ids, Timeout),
    {A, S} = placement(Net, P),
    ok = evatar_test_cluster:isolate(Net, S),
    timer:sleep(First),
    ok = evatar_test_cluster:heal(Net),
    ok = await_healthy(Net, Ids, Timeout),
    %% Every pair served again before the measured cut.
    _ = [{ok, _} = evatar_test_traffic:round_trip(Pair, Timeout) || Pair <- Pairs],
    case placement(Net, P) of
        {A, T} when T =/= S ->
            Stale = promise(Net, S, P),
            CutAt = erlang:monotonic_time(millisecond),
            ok = case Kind of
                     nodes -> evatar_test_cluster:isolate(Net, T);
                     all -> evatar_test_cluster:cut_off(Net, T);
                     link -> evatar_test_cluster:cut(Net, [{A, T}])
                 end,
            timer:sleep(CutMs),
            HealAt = erlang:monotonic_time(millisecond),
            ok = evatar_test_cluster:heal(Net),
            ok = await_healthy(Net, Ids, Timeout),
            _ = [{ok, _} = evatar_test_traffic:round_trip(Pair, Timeout) || Pair <- Pairs],
            Histories = [{Id, maps:get(va, evatar_test_traffic:history(Pair))}
                         || #{pairing := Id} = Pair <- Pairs],
            Gaps = [{Id, unserved(H, CutAt)} || {Id, H} <- Histories],
            Half = CutAt + (HealAt - CutAt) div 2,
            {ok, #{kind => Kind, unserved => Gaps,
                   max => lists:max([G || {_, G} <- Gaps]),
                   served_during_cut => [Id || {Id, H} <- Histories,
                                               [At || At <- completions(H), At >= Half,
                                                     At =< HealAt] =/= []],
                   pairing => P, active => A, standby => T, promised => S,
                   stale_promise => Stale, cut_ms => HealAt - CutAt}};
        Other ->
            {error, {placement_changed, P, {A, S}, Other}}
    end.

%% @doc Runs the rebalancing scenario on `Net' (rebalancing off until
%% then) with the pairs already carrying traffic. Opts: node (the node that
%% leaves and returns, default the last), env (the evatar environment set
%% on every node before it returns, default `[{rebalance, true}]': the
%% release's delay and batch), timeout (for every wait, default 60000),
%% fire (default false: the rebalancer's rounds run on their timers; true:
%% the delay and the time between rounds are set beyond any wait, and
%% every round is fired, evatar:run_now(rebalancer), once every pairing is
%% healthy and the moves of the round before are carried out, until a
%% round plans none).
-spec rebalance(evatar_test_cluster:cluster(), [evatar_test_traffic:pair()], map()) ->
          {ok, rebalance_result()} | {error, term()}.
rebalance(Net, Pairs, Opts) ->
    N = length(evatar_test_cluster:nodes(Net)),
    Back = maps:get(node, Opts, N),
    Timeout = maps:get(timeout, Opts, 60000),
    Ids = [Id || #{pairing := Id} <- Pairs],
    ok = await_healthy(Net, Ids, Timeout),
    ok = evatar_test_cluster:isolate(Net, Back),
    Away = fun() ->
                   lists:all(fun(Id) ->
                                     R = evatar_test_pairing:roles(Net, Id),
                                     [I || {active, _, I} <- R, I =/= Back] =/= []
                                         andalso [I || {standby, _, I} <- R, I =/= Back] =/= []
                             end, Ids)
           end,
    ok = evatar_test_cluster:await(Away, Timeout, {failed_over_from, Back}),
    Before = counts(Net, Ids),
    Fire = maps:get(fire, Opts, false),
    Never = evatar_test_time:guard(),
    ok = evatar_test_cluster:set_env(Net, evatar,
                                     maps:get(env, Opts, [{rebalance, true}])
                                     ++ [{K, Never} || Fire,
                                                       K <- [rebalance_delay_ms, rebalance_round_ms]]),
    BackAt = erlang:monotonic_time(millisecond),
    ok = evatar_test_cluster:heal(Net),
    %% Every node's share: as many actives, and as many standbys, as any
    %% other node, give or take one.
    Low = length(Ids) div N,
    High = Low + min(1, length(Ids) rem N),
    %% The counts reported are those of the read that ended the wait: a
    %% later read may catch a move the rebalancer planned before that
    %% read (on a placement that left out a pairing still moving) and
    %% count its pairing nowhere while it moves.
    Self = self(),
    Ref = make_ref(),
    Even = fun() ->
                   await_healthy(Net, Ids, 1000) =:= ok andalso
                       begin
                           Counts = counts(Net, Ids),
                           lists:all(fun({A, S}) -> A >= Low andalso A =< High
                                                        andalso S >= Low andalso S =< High
                                     end, maps:values(Counts))
                               andalso (Self ! {Ref, Counts}) =/= x
                       end
           end,
    Spread = case Fire of
                 true -> fire_rounds(Net, Ids, Even, Timeout, 0);
                 false -> evatar_test_cluster:await(Even, Timeout, spread_evenly)
             end,
    case Spread of
        ok ->
            After = receive {Ref, Counts} -> Counts end,
            SpreadAt = erlang:monotonic_time(millisecond),
            _ = [{ok, _} = evatar_test_traffic:round_trip(Pair, Timeout) || Pair <- Pairs],
            Gaps = [{Id, unserved(maps:get(va, evatar_test_traffic:history(Pair)), BackAt)}
                    || #{pairing := Id} = Pair <- Pairs],
            {ok, #{unserved => Gaps, max => lists:max([G || {_, G} <- Gaps]),
                   spread_ms => SpreadAt - BackAt, counts_before => Before,
                   counts_after => After}};
        {error, _} = Error ->
            {error, {Error, Before, counts(Net, Ids)}}
    end.

%% Rounds fired one after the other: each once every pairing is healthy
%% (the moves of the round before carried out, the returned node's
%% instances settled), until a round plans nothing; the placement must
%% then be even. A round that plans nothing while it is not (a pairing
%% left out of the gathered placement) is fired again once all are
%% healthy, up to the plan's bound of three moves a pairing.
fire_rounds(Net, Ids, Even, Timeout, Round) ->
    ok = evatar_test_cluster:await_formed(Net, Timeout),
    ok = await_healthy(Net, Ids, Timeout),
    Before = maps:from_list([{Id, placement(Net, Id)} || Id <- Ids]),
    case lists:append([Moves || {_, {ok, Moves}} <- evatar_test_cluster:run_now(Net, rebalancer)]) of
        [] ->
            case Even() of
                true -> ok;
                false when Round =< 3 * length(Ids) -> fire_rounds(Net, Ids, Even, Timeout, Round + 1);
                false -> {error, {not_spread, Round, counts(Net, Ids)}}
            end;
        Moves ->
            Expected = [{Id, moved(Net, Move, maps:get(Id, Before))} || Move <- Moves,
                                                                       Id <- [element(2, Move)]],
            Done = fun() ->
                           lists:all(fun({Id, Where}) ->
                                             evatar_test_pairing:healthy(Net, Id)
                                                 andalso current_placement(Net, Id) =:= Where
                                     end, Expected)
                   end,
            case evatar_test_cluster:await(Done, Timeout, {moves_carried_out, Round, Moves}) of
                ok -> fire_rounds(Net, Ids, Even, Timeout, Round + 1);
                {error, _} = Error -> Error
            end
    end.

%% Where a move leaves its pairing: {ActiveIndex, StandbyIndex}.
moved(_Net, {handover, _Id}, {A, S}) -> {S, A};
moved(Net, {standby, _Id, Node}, {A, _S}) -> {A, evatar_test_cluster:index(Net, Node)}.

%% @doc {actives, standbys} of the pairings Ids per node index.
-spec counts(evatar_test_cluster:cluster(), [binary()]) -> counts().
counts(Net, Ids) ->
    Roles = lists:append([evatar_test_pairing:roles(Net, Id) || Id <- Ids]),
    maps:from_list([{I, {length([x || {active, _, J} <- Roles, J =:= I]),
                         length([x || {standby, _, J} <- Roles, J =:= I])}}
                    || I <- lists:seq(1, length(evatar_test_cluster:nodes(Net)))]).

%% @doc The nodes of pairing Id's active and standby: {ActiveIndex,
%% StandbyIndex}.
-spec placement(evatar_test_cluster:cluster(), binary()) -> {pos_integer(), pos_integer()}.
placement(Net, Id) ->
    {_, _} = current_placement(Net, Id).

%% The placement now, or `moving' while a handover or a standby move is
%% under way (two actives or two standbys listed for a moment, or none).
current_placement(Net, Id) ->
    Roles = evatar_test_pairing:roles(Net, Id),
    case {[I || {active, _, I} <- Roles], [I || {standby, _, I} <- Roles]} of
        {[A], [S]} -> {A, S};
        _ -> moving
    end.

%% {Epoch of P, the epoch node S promised P}: the votes evatar_cluster
%% keeps (its table is readable by any process of its node).
promise(Net, S, P) ->
    {ok, _, #{epoch := E}} = evatar_test_pairing:active(Net, P),
    Promised = case evatar_test_cluster:call(Net, S, ets, lookup, [evatar_ha_votes, P]) of
                   [{P, #{promised := Pr}}] -> Pr;
                   _ -> 0
               end,
    {E, Promised}.

%% @doc From a VA's history: the longest time without a round trip that
%% began at or after its last round trip before `CutAt' (the partition) and
%% ended after `CutAt', up to its last round trip (the end of the run):
%% the gaps between consecutive completed round trips (a feedback's first
%% arrival). The first requests after a cut may still be served by an
%% active on the minority side, until it fences: counting from the first
%% round trip after the cut would hide the failover that follows.
%% `never' when no round trip completed after the cut.
-spec unserved(evatar_test_traffic:history(), integer()) -> non_neg_integer() | never.
unserved(History, CutAt) ->
    Times = lists:sort(completions(History)),
    case {[T || T <- Times, T =< CutAt], [T || T <- Times, T > CutAt]} of
        {[_ | _] = Before, [_ | _] = After} ->
            Span = [lists:last(Before) | After],
            lists:max([B - A || {A, B} <- lists:zip(lists:droplast(Span), tl(Span))]);
        _ ->
            never
    end.

%% @doc What the figures compare with: the longest time any of the pairs'
%% VAs went without a round trip over the next `Ms' ms, with no fault (the
%% load of the machine alone), counted from the start of the window to its
%% end. Sleeps `Ms'.
-spec baseline([evatar_test_traffic:pair()], pos_integer()) -> non_neg_integer().
baseline(Pairs, Ms) ->
    From = erlang:monotonic_time(millisecond),
    timer:sleep(Ms),
    To = erlang:monotonic_time(millisecond),
    lists:max([begin
                   Times = lists:sort([T || T <- completions(maps:get(va, evatar_test_traffic:history(P))),
                                            T >= From, T =< To]),
                   Span = [From | Times] ++ [To],
                   lists:max([B - A || {A, B} <- lists:zip(lists:droplast(Span), tl(Span))])
               end || P <- Pairs]).

%% When the round trips of a VA's history completed (monotonic ms): the
%% first arrival of each feedback (its requests are `fb-' ++ their id).
completions(#{received_at := ReceivedAt}) ->
    [lists:min(Ts) || {<<"fb-", _/binary>>, Ts} <- maps:to_list(ReceivedAt)].

%% @doc Waits until every pairing has one active and one synced standby.
-spec await_healthy(evatar_test_cluster:cluster(), [binary()], pos_integer()) -> ok | {error, term()}.
await_healthy(Net, Ids, Timeout) ->
    case evatar_test_cluster:await(fun() -> lists:all(fun(Id) -> evatar_test_pairing:healthy(Net, Id) end, Ids) end,
                                   Timeout, all_healthy) of
        ok -> ok;
        {error, _} = Error -> {error, {Error, [{Id, evatar_test_pairing:roles(Net, Id)} || Id <- Ids]}}
    end.

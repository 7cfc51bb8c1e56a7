%% @doc Test support. The partition scenario of issue 18, run on an ha_netns
%% cluster with ha_traffic pairs, and what it measures: for each pairing,
%% the longest time its VA went without a round trip across a partition.
%% Used by test/netns_SUITE.erl (which asserts) and
%% bench/partition_bench.erl (which prints). Internal to test/.
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
-module(ha_partition).

-export([run/4, placement/2, unserved/2, await_healthy/3]).

-export_type([kind/0, result/0]).

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

%% @doc Runs the scenario on `Net' with the pairs already carrying traffic
%% (the first pair's pairing is P). Opts: first_ms (the first partition,
%% default 2000), cut_ms (the measured one, default 4000), timeout (for
%% every wait, default 60000).
-spec run(ha_netns:net(), [ha_traffic:pair()], kind(), map()) ->
          {ok, result()} | {error, term()}.
run(Net, [#{pairing := P} | _] = Pairs, Kind, Opts) ->
    First = maps:get(first_ms, Opts, 2000),
    CutMs = maps:get(cut_ms, Opts, 4000),
    Timeout = maps:get(timeout, Opts, 60000),
    Ids = [Id || #{pairing := Id} <- Pairs],
    ok = await_healthy(Net, Ids, Timeout),
    {A, S} = placement(Net, P),
    ok = ha_netns:cut_nodes(Net, S),
    timer:sleep(First),
    ok = ha_netns:heal(Net),
    ok = await_healthy(Net, Ids, Timeout),
    %% Every pair served again before the measured cut.
    _ = [{ok, _} = ha_traffic:round_trip(Pair, Timeout) || Pair <- Pairs],
    case placement(Net, P) of
        {A, T} when T =/= S ->
            Stale = promise(Net, S, P),
            CutAt = erlang:monotonic_time(millisecond),
            ok = case Kind of
                     nodes -> ha_netns:cut_nodes(Net, T);
                     all -> ha_netns:isolate(Net, T);
                     link -> ha_netns:cut_link(Net, A, T)
                 end,
            timer:sleep(CutMs),
            HealAt = erlang:monotonic_time(millisecond),
            ok = ha_netns:heal(Net),
            ok = await_healthy(Net, Ids, Timeout),
            _ = [{ok, _} = ha_traffic:round_trip(Pair, Timeout) || Pair <- Pairs],
            Histories = [{Id, maps:get(va, ha_traffic:history(Pair))}
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

%% @doc The nodes of pairing Id's active and standby: {ActiveIndex,
%% StandbyIndex}.
-spec placement(ha_netns:net(), binary()) -> {pos_integer(), pos_integer()}.
placement(Net, Id) ->
    Roles = ha_pairing:roles(Net, Id),
    [A] = [I || {active, _, I} <- Roles],
    [S] = [I || {standby, _, I} <- Roles],
    {A, S}.

%% {Epoch of P, the epoch node S promised P}: the votes evatar_cluster
%% keeps (its table is readable by any process of its node).
promise(Net, S, P) ->
    {ok, _, #{epoch := E}} = ha_pairing:active(Net, P),
    Promised = case ha_cluster:call(Net, S, ets, lookup, [evatar_cluster_votes, P]) of
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
-spec unserved(ha_traffic:history(), integer()) -> non_neg_integer() | never.
unserved(History, CutAt) ->
    Times = lists:sort(completions(History)),
    case {[T || T <- Times, T =< CutAt], [T || T <- Times, T > CutAt]} of
        {[_ | _] = Before, [_ | _] = After} ->
            Span = [lists:last(Before) | After],
            lists:max([B - A || {A, B} <- lists:zip(lists:droplast(Span), tl(Span))]);
        _ ->
            never
    end.

%% When the round trips of a VA's history completed (monotonic ms): the
%% first arrival of each feedback (its requests are `fb-' ++ their id).
completions(#{received_at := ReceivedAt}) ->
    [lists:min(Ts) || {<<"fb-", _/binary>>, Ts} <- maps:to_list(ReceivedAt)].

%% @doc Waits until every pairing has one active and one synced standby.
-spec await_healthy(ha_netns:net(), [binary()], pos_integer()) -> ok | {error, term()}.
await_healthy(Net, Ids, Timeout) ->
    case ha_cluster:await(fun() -> lists:all(fun(Id) -> ha_pairing:healthy(Net, Id) end, Ids) end,
                          Timeout, all_healthy) of
        ok -> ok;
        {error, _} = Error -> {error, {Error, [{Id, ha_pairing:roles(Net, Id)} || Id <- Ids]}}
    end.

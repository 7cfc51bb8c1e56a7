%% @doc Partitions of a real network: three EVATAR nodes, each an OS process
%% in a network namespace of its own (evatar_test_cluster with `net =>
%% netns': evatar_test_net_netns), linked by links of their own, with VA and Avatar clients reaching them over TCP; a
%% partition takes links down. Each case first leaves a stale promise
%% behind (a standby cut off with its node, which promised it the next
%% epoch), then cuts the active of that pairing from its current standby
%% (evatar_test_partition): the side with a majority must keep serving every
%% pairing through the partition, with nothing lost or duplicated
%% (docs/ha.md section 6, docs/ha-design.md section 5). A last case cuts
%% a node off until its pairings failed over and checks that the
%% rebalancer gives it its share back when it returns (section 8.2).
%% Skipped, saying why, when not run as root or without `ip'.
-module(netns_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").

-export([suite/0, all/0, init_per_suite/1, end_per_suite/1,
         init_per_testcase/2, end_per_testcase/2]).
-export([node_cut_from_nodes/1, node_cut_from_everything/1, one_link_cut/1,
         rebalance_after_return/1]).

%% The suites' detection timings (evatar_test_time:ha_timing/0): on a loaded machine the
%% release's 50/250/150 suspect live nodes, and a needless takeover would
%% move the pairings the scenario places. So would the rebalancer after
%% each heal: it is on only for the case about it.
-define(EVATAR, evatar_test_time:ha_timing() ++ [{rebalance, false}]).
-define(TIMEOUT, evatar_test_time:guard()).
%% The first partition outlasts suspect_ms and an election; the measured
%% one leaves a failover (suspect_ms, clients' 3 bridge heartbeats) well
%% inside its first half.
-define(SCENARIO, #{first_ms => evatar_test_time:cluster_ms(2500),
                    cut_ms => evatar_test_time:cluster_ms(5000),
                    timeout => ?TIMEOUT}).

suite() ->
    [{timetrap, evatar_test_time:ms(300000)}].

all() ->
    [node_cut_from_nodes, node_cut_from_everything, one_link_cut, rebalance_after_return].

init_per_suite(Config) ->
    case evatar_test_net_netns:available() of
        ok ->
            Dist = evatar_test_cluster:ensure_distributed(),
            Dir = filename:join(?config(priv_dir, Config), "netns"),
            ok = filelib:ensure_path(Dir),
            case evatar_test_cluster:start(#{dir => Dir, net => netns, prefix => "evns", evatar => ?EVATAR,
                                  conn => #{heartbeat => 100}}) of
                {ok, Net} ->
                    [{net, Net}, {dist, Dist} | Config];
                {error, Why} ->
                    evatar_test_cluster:release_distribution(Dist),
                    ct:fail({netns_cluster, Why})
            end;
        {skip, Why} ->
            {skip, Why}
    end.

end_per_suite(Config) ->
    ok = evatar_test_cluster:stop(?config(net, Config)),
    evatar_test_cluster:release_distribution(?config(dist, Config)).

init_per_testcase(Case, Config) ->
    Net = ?config(net, Config),
    N = case Case of
            rebalance_after_return -> 6;
            _ -> 3
        end,
    Ids = [iolist_to_binary([atom_to_list(Case), "-", integer_to_list(K)]) || K <- lists:seq(1, N)],
    %% The case begins on a formed cluster that holds none of an earlier
    %% case's pairings: the rebalancer places every pairing of the cluster,
    %% so a leftover one would change the share each node must hold.
    ok = evatar_test_cluster:await_formed(Net, ?TIMEOUT),
    [] = catalogued(Net),
    try
        %% As many pairings active on each node, each with its standby on
        %% the next node.
        _ = [ok = evatar_test_pairing:create(Net, (K - 1) rem 3 + 1, Id) || {K, Id} <- lists:enumerate(Ids)],
        Pairs = [begin
                     {ok, P} = evatar_test_traffic:start_pair(evatar_test_cluster:endpoints(Net), Id,
                                                              #{request_interval => 20,
                                                                sensor_interval => 100}),
                     P
                 end || Id <- Ids],
        [{ids, Ids}, {pairs, Pairs} | Config]
    catch
        Class:Why:Stack ->
            %% end_per_testcase does not run after a failed init: leave
            %% nothing behind for the next case.
            ok = remove(Net, Ids),
            erlang:raise(Class, Why, Stack)
    end.

end_per_testcase(_Case, Config) ->
    Net = ?config(net, Config),
    ok = evatar_test_cluster:heal(Net),
    ok = evatar_test_cluster:set_env(Net, evatar, [{rebalance, false}]),
    _ = [evatar_test_traffic:close(P) || P <- ?config(pairs, Config)],
    ok = remove(Net, ?config(ids, Config)).

%% Deletes pairings Ids once the healed cluster has formed again (a node
%% that was cut off may not know its peers yet), through whichever node
%% holds an instance, and waits until no node has an instance of them or
%% a catalogue entry for them.
remove(Net, Ids) ->
    ok = evatar_test_cluster:await_formed(Net, ?TIMEOUT),
    Gone = fun() ->
                   Left = [Id || Id <- Ids, evatar_test_pairing:roles(Net, Id) =/= []]
                       ++ [Id || Id <- catalogued(Net), lists:member(Id, Ids)],
                   _ = [evatar_test_pairing:delete(Net, holder(Net, Id), Id) || Id <- lists:usort(Left)],
                   Left =:= []
           end,
    evatar_test_cluster:await(Gone, ?TIMEOUT, {pairings_left, Ids}).

%% A node to delete Id through: its active's, else one with an instance
%% (a standby's node deletes at the active), else the first node (the
%% deletion is recorded in the catalogue).
holder(Net, Id) ->
    case [{R =/= active, I} || {R, _, I} <- evatar_test_pairing:roles(Net, Id)] of
        [] -> 1;
        Held -> element(2, lists:min(Held))
    end.

%% The pairings in any node's catalogue.
catalogued(Net) ->
    lists:usort(lists:append([L || I <- lists:seq(1, length(evatar_test_cluster:nodes(Net))),
                                   L <- [evatar_test_cluster:call(Net, I, evatar, catalogued, [])],
                                   is_list(L)])).

%% ---------------------------------------------------------------------------
%% Cases
%% ---------------------------------------------------------------------------

%% A node cut from the other nodes, its clients still reaching it.
node_cut_from_nodes(Config) ->
    partition(nodes, Config).

%% A node cut from everything: the other nodes and the clients.
node_cut_from_everything(Config) ->
    partition(all, Config).

%% Only the link between the active and its standby's node cut: the
%% third node hears both.
one_link_cut(Config) ->
    partition(link, Config).

partition(Kind, Config) ->
    Net = ?config(net, Config),
    Pairs = ?config(pairs, Config),
    Ids = ?config(ids, Config),
    {ok, #{stale_promise := {Epoch, Promised}} = R} =
        evatar_test_partition:run(Net, Pairs, Kind, ?SCENARIO),
    ct:pal("~p: ~p", [Kind, R]),
    ct:comment("longest unserved ~p ms", [maps:get(max, R)]),
    %% The scenario did leave the stale promise it is about.
    ?assert(Promised > Epoch),
    %% Every pairing was served in the second half of the partition.
    ?assertEqual(lists:sort(Ids), lists:sort(maps:get(served_during_cut, R))),
    check(Kind, Pairs).

%% After faults, a returning node gets its share again: node 3 is cut off
%% until its pairings failed over (every active and standby then on nodes
%% 1 and 2), and when it is back the rebalancer moves actives and standbys
%% to it by planned handovers and standby moves while traffic flows, until
%% every node holds two of each, with nothing lost or duplicated. The case
%% fires the rebalancer's rounds (evatar:run_now(rebalancer)), each once
%% the moves of the round before are carried out: what each round decides
%% is checked, not raced by the next; when a round comes is the
%% benchmark's business (make bench-partition).
rebalance_after_return(Config) ->
    Net = ?config(net, Config),
    Pairs = ?config(pairs, Config),
    {ok, R} = evatar_test_partition:rebalance(
                Net, Pairs, #{node => 3, timeout => ?TIMEOUT, fire => true,
                              env => [{rebalance, true}]}),
    ct:pal("rebalance: ~p", [R]),
    ?assertEqual(#{1 => {2, 2}, 2 => {2, 2}, 3 => {2, 2}}, maps:get(counts_after, R)),
    check(rebalance, Pairs).

%% Every signal a sender was told was accepted arrived once, and no
%% request was answered by EVATAR's Timeout feedback.
check(Kind, Pairs) ->
    _ = [ok = evatar_test_traffic:stop_traffic(P) || P <- Pairs],
    Settled = [evatar_test_traffic:settle(P, ?TIMEOUT) || P <- Pairs],
    Histories = [evatar_test_traffic:history(P) || P <- Pairs],
    Result = evatar_test_checker:check_pairs(Histories),
    ct:pal("~p: ~s; histories in ~s",
           [Kind, evatar_test_checker:format(Result),
            [[evatar_test_traffic:dump(P, H), " "] || {P, H} <- lists:zip(Pairs, Histories)]]),
    ?assert(evatar_test_checker:passed(Result)),
    ?assertEqual([ok || _ <- Pairs], Settled),
    ?assertEqual([], [S || #{va := Va} <- Histories, S <- maps:get(mediator, Va)]).

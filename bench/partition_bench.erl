%% @doc Partition benchmark: the longest time a pairing of the majority side
%% goes without a round trip, for three kinds of partition of a real network
%% (each node an OS process in a network namespace of its own:
%% evatar_test_cluster's netns backend, evatar_test_net_netns), after a first partition left a stale promise behind
%% (evatar_test_partition, docs/ha-design.md section 5). It runs the
%% same scenario on this build and, when given one, on an earlier build
%% (`{before, Dir}': a source tree compiled with `rebar3 compile'), and
%% prints both side by side. Needs root and `ip'. Run through
%% scripts/bench-partition.sh (`make bench-partition').
%%
%% A last row measures a rebalancing (evatar_test_partition:rebalance/3,
%% this build only): six pairings, two active on each node; node 3 is cut
%% from the others until every pairing failed over away from it, then it
%% returns with rebalancing on (the release's rebalance_delay_ms 5000 and
%% rebalance_batch 2) and the rebalancer moves actives and standbys back to
%% it by planned handovers: the longest time a pairing's VA went without a
%% round trip from the return until every node holds two actives and two
%% standbys, and what was lost or duplicated (both must be 0). Every row
%% also gives the same pairings' longest gap over 3 s before any fault:
%% what the machine's load alone costs.
%%
%% Options: `{before, Dir}'; `{trials, N}' (default 1: each trial runs the
%% scenario once per kind on a fresh cluster); `{cut_ms, Ms}' (default
%% 8000); `{kinds, [nodes | all | link | rebalance]}'; `quick' (cut 3000
%% ms, kinds nodes and rebalance only).
-module(partition_bench).

-export([main/1]).

%% The release's defaults (config/sys.config.src): node timings 50/250/150
%% ms, the bridge's heartbeat 150 ms. No rebalancing: its planned handovers
%% after the first heal would be measured with the partition.
-define(EVATAR, [{heartbeat_ms, 50}, {suspect_ms, 250}, {lease_ms, 150}, {rebalance, false}]).
-define(CONN, #{heartbeat => 150}).

-spec main([term()]) -> ok.
main(Opts) ->
    case evatar_test_net_netns:available() of
        ok -> run(Opts);
        {skip, Why} -> io:format("partition_bench: not run: ~s~n", [Why])
    end.

run(Opts) ->
    Quick = lists:member(quick, Opts),
    Trials = proplists:get_value(trials, Opts, 1),
    CutMs = proplists:get_value(cut_ms, Opts, case Quick of true -> 3000; false -> 8000 end),
    Kinds = proplists:get_value(kinds, Opts, case Quick of true -> [nodes, rebalance];
                                                         false -> [nodes, all, link, rebalance]
                                             end),
    Builds = [{"after (this build)", #{}}]
        ++ case proplists:get_value(before, Opts) of
               undefined -> [];
               Dir -> [{"before (" ++ Dir ++ ")",
                        #{code_path => filelib:wildcard(
                                         filename:join([Dir, "_build", "default", "lib", "*",
                                                        "ebin"]))}}]
           end,
    _ = evatar_test_cluster:ensure_distributed(),
    io:format("partition_bench: 3 nodes in network namespaces, 3 pairings (one active on "
              "each node; six, two on each, for the rebalancing), a request every 20 ms per "
              "pairing; release timings 50/250/150 ms, bridge heartbeat 150 ms; first "
              "partition 2000 ms, measured partition ~b ms; "
              "~b trial(s); load average before: ~s~n",
              [CutMs, Trials, loadavg()]),
    %% The build before the stale-promise fix had no rebalancer.
    Results = [{Kind, Name, [trial(Kind, Build, CutMs, T) || T <- lists:seq(1, Trials)]}
               || Kind <- Kinds, {Name, Build} <- Builds,
                  Kind =/= rebalance orelse Build =:= #{}],
    io:format("~nlongest unserved time of a majority-side pairing (ms; per pairing in "
              "brackets; the pairing that held the stale promise first):~n~n"),
    io:format("| partition | build | longest | per trial [per pairing] | no fault, 3 s before "
              "| lost | duplicated |~n"
              "|---|---|---|---|---|---|---|~n"),
    _ = [io:format("| ~s | ~s | ~s | ~s | ~s | ~b | ~b |~n",
                   [kind_name(Kind), Name, fmt(lists:max([M || #{max := M} <- Rs])),
                    lists:join("; ", [[fmt(M), " ", gaps(G)] || #{max := M, gaps := G} <- Rs]),
                    lists:join("; ", [integer_to_list(B) || #{baseline := B} <- Rs]),
                    lists:sum([L || #{lost := L} <- Rs]),
                    lists:sum([D || #{duplicated := D} <- Rs])])
         || {Kind, Name, Rs} <- Results],
    _ = [io:format("~nrebalancing: every node held two actives and two standbys ~s ms after "
                   "node 3 returned (rebalance_delay_ms 5000 included); {actives, standbys} per "
                   "node before: ~s~n", [lists:join(", ", [integer_to_list(S) || #{spread_ms := S} <- Rs]),
                                          lists:join("; ", [io_lib:format("~w", [B])
                                                            || #{counts_before := B} <- Rs])])
         || {rebalance, _, Rs} <- Results],
    io:format("~nload average after: ~s~n", [loadavg()]),
    ok.

trial(Kind, Build, CutMs, T) ->
    Dir = filename:join(["/tmp", "partition_bench-" ++ os:getpid(),
                         atom_to_list(Kind) ++ "-" ++ integer_to_list(T) ++ "-"
                         ++ integer_to_list(erlang:unique_integer([positive]))]),
    ok = filelib:ensure_path(Dir),
    {ok, Net} = evatar_test_cluster:start(Build#{dir => Dir, net => netns, prefix => "evns",
                                                 evatar => ?EVATAR, conn => ?CONN}),
    try
        %% One pairing active on each node; two for the rebalancing.
        Ids = [<<"bench-", (integer_to_binary(K))/binary>>
                   || K <- lists:seq(1, case Kind of rebalance -> 6; _ -> 3 end)],
        _ = [ok = evatar_test_pairing:create(Net, (K - 1) rem 3 + 1, Id)
             || {K, Id} <- lists:enumerate(Ids)],
        Pairs = [begin
                     {ok, P} = evatar_test_traffic:start_pair(evatar_test_cluster:endpoints(Net), Id,
                                                              #{request_interval => 20}),
                     P
                 end || Id <- Ids],
        %% The same pairs' longest gap over 3 s with no fault: the load's share.
        Baseline = evatar_test_partition:baseline(Pairs, 3000),
        {ok, R} = case Kind of
                      rebalance -> evatar_test_partition:rebalance(Net, Pairs, #{node => 3});
                      _ -> evatar_test_partition:run(Net, Pairs, Kind, #{first_ms => 2000,
                                                                          cut_ms => CutMs})
                  end,
        _ = [ok = evatar_test_traffic:stop_traffic(P) || P <- Pairs],
        _ = [evatar_test_traffic:settle(P, 30000) || P <- Pairs],
        Check = evatar_test_checker:check_pairs([evatar_test_traffic:history(P) || P <- Pairs]),
        _ = [evatar_test_traffic:close(P) || P <- Pairs],
        (maps:with([spread_ms, counts_before], R))#{
          max => maps:get(max, R), gaps => [G || {_, G} <- maps:get(unserved, R)],
          baseline => Baseline,
          lost => length(maps:get(lost, Check)),
          duplicated => length(maps:get(duplicated, Check))}
    after
        evatar_test_cluster:stop(Net)
    end.

kind_name(nodes) -> "(a) node cut from the other nodes";
kind_name(all) -> "(b) node cut from everything";
kind_name(link) -> "(c) one link between two nodes cut";
kind_name(rebalance) -> "(d) a node returns: rebalancing by planned handover (6 pairings)".

fmt(never) -> "never served again";
fmt(Ms) -> integer_to_list(Ms).

gaps(Gs) -> ["[", lists:join(", ", [fmt(G) || G <- Gs]), "]"].

loadavg() ->
    case file:read_file("/proc/loadavg") of
        {ok, B} -> lists:join(" ", lists:sublist(string:lexemes(binary_to_list(B), " "), 3));
        _ -> "?"
    end.

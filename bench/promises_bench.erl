%% @doc What keeping a voter's promises on disc costs (evatar_ha_promises,
%% written and fdatasync'ed before a grant is sent): the time of one write
%% of one record (a vote in a quiet cluster), and of one write of a batch
%% of records (a takeover storm: evatar_cluster answers the requests that
%% wait in its mailbox with one write), p50 and p99 over the rounds, in
%% microseconds, on the disc of `{dir, Dir}' (default a fresh directory
%% under /tmp). Run: `make bench-promises' or
%% `scripts/bench-promises.sh '[{storm, 300}, {rounds, 2000}]''.
-module(promises_bench).

-export([main/1]).

-spec main([{dir, file:filename()} | {rounds, pos_integer()} | {storm, pos_integer()}]) -> ok.
main(Opts) ->
    Dir = proplists:get_value(dir, Opts, filename:join("/tmp", "promises_bench-" ++ os:getpid())),
    Rounds = proplists:get_value(rounds, Opts, 1000),
    Storm = proplists:get_value(storm, Opts, 300),
    {ok, L0, _} = evatar_ha_promises:open(filename:join(Dir, "data")),
    Rec = fun(K) -> #{promised => K, holder => self(), conf => {K, 1}, registered => true} end,
    Id = fun(K) -> <<"pairing-", (integer_to_binary(K))/binary>> end,
    {Single, L1} = rounds(Rounds, L0, fun(K) -> [{Id(K rem Storm), Rec(K)}] end),
    {Batch, _} = rounds(max(1, Rounds div 10), L1,
                        fun(K) -> [{Id(P), Rec(K)} || P <- lists:seq(1, Storm)] end),
    io:format("promises on disc in ~s (~s)~n", [Dir, os:cmd("df -h --output=source,fstype " ++ Dir
                                                       ++ " | tail -1 | tr -s ' '") -- "\n"]),
    io:format("one vote, one write + fdatasync: p50 ~b us, p99 ~b us (~b rounds)~n",
              [pct(Single, 50), pct(Single, 99), length(Single)]),
    io:format("a storm of ~b votes, one write + fdatasync: p50 ~b us, p99 ~b us "
              "(~b us per vote at p50; ~b rounds)~n",
              [Storm, pct(Batch, 50), pct(Batch, 99), pct(Batch, 50) div Storm, length(Batch)]),
    ok = file:del_dir_r(Dir).

rounds(N, L, Entries) ->
    lists:foldl(fun(K, {Acc, L1}) ->
                        E = Entries(K),
                        T0 = erlang:monotonic_time(microsecond),
                        {ok, L2} = evatar_ha_promises:write(L1, E),
                        T = erlang:monotonic_time(microsecond) - T0,
                        L3 = case evatar_ha_promises:needs_compaction(L2, length(E)) of
                                 true -> element(2, evatar_ha_promises:compact(L2, E));
                                 false -> L2
                             end,
                        {[T | Acc], L3}
                end, {[], L}, lists:seq(1, N)).

pct(Samples, P) ->
    Sorted = lists:sort(Samples),
    lists:nth(max(1, (length(Sorted) * P + 99) div 100), Sorted).

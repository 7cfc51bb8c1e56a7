%% EUnit and PropEr tests of the catalogue's pure rules: merging two
%% nodes' catalogues, the winner of two writes, who restores a pairing.
-module(evatar_catalogue_rules_tests).

%% Both headers define LET: PropEr's is not used here.
-include_lib("proper/include/proper.hrl").
-undef(LET).
-include_lib("eunit/include/eunit.hrl").

-define(R, evatar_catalogue_rules).

cfg() -> #{agent_credential => <<"a">>, avatar_credential => <<"b">>}.

live(Id, V) -> {Id, V, {live, cfg(), a@h}}.

%% A write made after seeing another (a higher counter) wins, whatever the
%% clocks say; two writes made apart at one counter: a tombstone over a
%% live entry, then the greater node name; never the wall clock.
versions_test() ->
    V1 = ?R:next_version(none, 1000, a@h),
    ?assertEqual({1, 1000, a@h}, V1),
    V2 = ?R:next_version(V1, 5, b@h),
    ?assert(?R:wins(live(<<"p">>, V2), live(<<"p">>, V1))),
    ?assert(?R:wins({<<"p">>, V2, deleted}, live(<<"p">>, V1))),
    %% Same counter: the node name, not the later clock.
    ?assert(?R:wins(live(<<"p">>, {3, 9, b@h}), live(<<"p">>, {3, 10, a@h}))),
    %% Same counter: a tombstone, whatever the node names and clocks.
    ?assert(?R:wins({<<"p">>, {3, 1, a@h}, deleted}, live(<<"p">>, {3, 10, b@h}))),
    ?assertNot(?R:wins(live(<<"p">>, {3, 10, b@h}), {<<"p">>, {3, 1, a@h}, deleted})),
    %% A tombstone of an older counter loses to a write made after it.
    ?assert(?R:wins(live(<<"p">>, {4, 0, a@h}), {<<"p">>, {3, 99, b@h}, deleted})).

%% A node changes the catalogue only while it hears a majority; a cluster
%% of one always does, and in a cluster of two either node goes on alone.
may_change_test() ->
    ?assert(?R:may_change(3, true)),
    ?assertNot(?R:may_change(3, false)),
    ?assertNot(?R:may_change(5, false)),
    ?assert(?R:may_change(2, false)),
    ?assert(?R:may_change(1, true)).

%% A deletion made during a partition wins over the older live entry on
%% the other side; an entry only one side has is kept.
merge_partition_test() ->
    Ours = [live(<<"p">>, {1, 10, a@h}), live(<<"only-ours">>, {1, 11, a@h})],
    Theirs = [{<<"p">>, {2, 20, c@h}, deleted}, live(<<"only-theirs">>, {1, 12, c@h})],
    Merged = ?R:merge(Ours, Theirs),
    ?assertEqual([<<"only-ours">>, <<"only-theirs">>, <<"p">>], [Id || {Id, _, _} <- Merged]),
    ?assertMatch({_, _, deleted}, lists:keyfind(<<"p">>, 1, Merged)),
    ?assertEqual([{<<"p">>, {2, 20, c@h}, deleted}, live(<<"only-theirs">>, {1, 12, c@h})],
                 ?R:changed(Ours, Theirs)),
    ?assertEqual([], ?R:changed(Merged, Ours)).

%% A node that runs an instance of a pairing whose creation has not
%% reached its catalogue yet (it took over from the home node that created
%% it and died) deletes it with the first version it can write. That
%% tombstone, written after the creation, wins over the live entry when it
%% arrives later, in either order, and on the node that comes back with the
%% live entry on disc (ha_SUITE restart_with_changed_catalogue); also when
%% the deleting node's clock is far behind the creating node's.
blind_deletion_test() ->
    blind_deletion(1000, 1100),
    blind_deletion(1000, -86400000).

blind_deletion(CreatedAt, DeletedAt) ->
    Created = live(<<"p">>, ?R:next_version(none, CreatedAt, c@h)),
    Deleted = {<<"p">>, ?R:next_version(none, DeletedAt, a@h), deleted},
    ?assertEqual([Deleted], ?R:merge([Created], [Deleted])),
    ?assertEqual([Deleted], ?R:merge([Deleted], [Created])),
    ?assertEqual([Deleted], ?R:changed([Created], [Deleted])),
    ?assertEqual([], ?R:changed([Deleted], [Created])),
    ?assertEqual([<<"p">>], ?R:to_stop(?R:merge([Created], [Deleted]), [<<"p">>])).

%% The home node restores its pairing; without it, the next alive node of
%% the ring after the home does; nobody when nobody is alive.
owner_test() ->
    Nodes = [a@h, b@h, c@h],
    ?assertEqual(b@h, ?R:owner(b@h, Nodes, Nodes)),
    ?assertEqual(c@h, ?R:owner(b@h, Nodes, [a@h, c@h])),
    ?assertEqual(a@h, ?R:owner(c@h, Nodes, [a@h, b@h])),
    ?assertEqual(none, ?R:owner(c@h, Nodes, [])),
    %% A home that is no longer configured (a renamed node).
    ?assertEqual(a@h, ?R:owner(old@h, Nodes, [a@h])).

%% Only what this node owns and nobody runs is started; only deleted
%% pairings that run here are stopped.
start_stop_test() ->
    E = [{<<"mine">>, {1, 1, a@h}, {live, cfg(), a@h}},
         {<<"running">>, {1, 1, a@h}, {live, cfg(), a@h}},
         {<<"theirs">>, {1, 1, b@h}, {live, cfg(), b@h}},
         {<<"dead">>, {2, 1, a@h}, deleted}],
    View = {[a@h, b@h], [a@h, b@h]},
    ?assertEqual([{<<"mine">>, cfg()}], ?R:to_start(E, a@h, View, [<<"running">>])),
    ?assertEqual([<<"dead">>], ?R:to_stop(E, [<<"dead">>, <<"running">>])).

%% An instance that stepped down (a newer instance, a stale claim) did not
%% give up: its pairing, left without instances, is restored; one that
%% crashed did (its restart limit decides).
gave_up_test() ->
    ?assertNot(?R:gave_up({shutdown, {newer_instance, 'n2@h', 3}})),
    ?assertNot(?R:gave_up({shutdown, stale_claim})),
    ?assertNot(?R:gave_up(normal)),
    ?assertNot(?R:gave_up(shutdown)),
    ?assert(?R:gave_up({badarg, []})),
    ?assert(?R:gave_up(killed)).

%% Merging is commutative, associative and idempotent: catalogues
%% exchanged in any order end equal.
merge_converges_test() ->
    ok = evatar_test_proper:check(prop_merge(), 300).

%% Whatever the nodes' clocks say, the same writes exchanged the same way
%% end with the same winner: a history of creates and deletes on three
%% nodes (each written as evatar_catalogue does, from what that node holds),
%% with catalogues sent between them, replayed with the clocks of the
%% writes changed, picks the same write for every id.
clocks_decide_nothing_test() ->
    ok = evatar_test_proper:check(prop_clocks_decide_nothing(), 300).

prop_clocks_decide_nothing() ->
    ?FORALL({Steps, Skew}, {list(step()), list(integer())},
            begin
                Clocks = fun(I) -> lists:nth(1 + I rem max(1, length(Skew)), [0 | Skew]) end,
                strip(replay(Steps, fun(_I) -> 0 end)) =:= strip(replay(Steps, Clocks))
            end).

step() ->
    oneof([{write, oneof([a@h, b@h, c@h]), oneof([<<"p1">>, <<"p2">>]),
            oneof([create, delete, blind_delete])},
           {send, oneof([a@h, b@h, c@h]), oneof([a@h, b@h, c@h])}]).

%% Each write's clock is Clock(its index): the same writes, other clocks.
replay(Steps, Clock) ->
    Nodes = #{a@h => [], b@h => [], c@h => []},
    {Final, _} = lists:foldl(fun(Step, {Cats, I}) -> {step(Step, Clock(I), Cats), I + 1} end,
                             {Nodes, 0}, Steps),
    lists:foldl(fun(Cat, Acc) -> ?R:merge(Acc, Cat) end, [], maps:values(Final)).

step({send, From, To}, _Wall, Cats) ->
    Cats#{To := ?R:merge(maps:get(To, Cats), maps:get(From, Cats))};
step({write, Node, Id, Kind}, Wall, Cats) ->
    Cat = maps:get(Node, Cats),
    Current = lists:keyfind(Id, 1, Cat),
    Value = case {Kind, Current} of
                {create, false} -> {live, cfg(), Node};
                {create, {_, _, deleted}} -> {live, cfg(), Node};
                {delete, {_, _, {live, _, _}}} -> deleted;
                %% A node running an instance it has no entry of.
                {blind_delete, false} -> deleted;
                _ -> none
            end,
    case Value of
        none ->
            Cats;
        _ ->
            V = ?R:next_version(case Current of false -> none; {_, V0, _} -> V0 end, Wall, Node),
            Cats#{Node := ?R:merge(Cat, [{Id, V, Value}])}
    end.

strip(Entries) ->
    [{Id, C, N, Value} || {Id, {C, _Wall, N}, Value} <- Entries].

prop_merge() ->
    ?FORALL({A, B, C}, {catalogue(), catalogue(), catalogue()},
            begin
                AB = ?R:merge(A, B),
                AB =:= ?R:merge(B, A)
                    andalso ?R:merge(AB, C) =:= ?R:merge(A, ?R:merge(B, C))
                    andalso ?R:merge(AB, AB) =:= AB
                    andalso ?R:merge(AB, ?R:changed(A, B)) =:= AB
            end).

catalogue() ->
    proper_types:bind(list(entry()),
                      fun(Entries) ->
                              maps:values(maps:from_list([{Id, E} || {Id, _, _} = E <- Entries]))
                      end, false).

entry() ->
    proper_types:bind(
      {oneof([<<"p1">>, <<"p2">>, <<"p3">>]), range(1, 4), range(1, 3), oneof([a@h, b@h])},
      %% One value per version, as a real write makes.
      fun({Id, C, T, N}) ->
              {Id, {C, T, N}, case erlang:phash2({Id, C, T, N}, 2) of
                                  0 -> deleted;
                                  1 -> {live, cfg(), N}
                              end}
      end, false).

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
%% clocks say; two writes made apart are ordered by wall clock, then node.
versions_test() ->
    V1 = ?R:next_version(none, 1000, a@h),
    ?assertEqual({1, 1000, a@h}, V1),
    V2 = ?R:next_version(V1, 5, b@h),
    ?assert(?R:newer(V2, V1)),
    ?assert(?R:newer({3, 10, a@h}, {3, 9, b@h})),
    ?assert(?R:newer({3, 10, b@h}, {3, 10, a@h})).

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
%% live entry on disc (ha_SUITE restart_with_changed_catalogue).
blind_deletion_test() ->
    Created = live(<<"p">>, ?R:next_version(none, 1000, c@h)),
    Deleted = {<<"p">>, ?R:next_version(none, 1100, a@h), deleted},
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

%% Merging is commutative, associative and idempotent: catalogues
%% exchanged in any order end equal.
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

merge_converges_test() ->
    ok = evatar_test_proper:check(prop_merge(), 300).

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
              {Id, {C, T, N}, case (C + T) rem 2 of
                                  0 -> deleted;
                                  1 -> {live, cfg(), N}
                              end}
      end, false).

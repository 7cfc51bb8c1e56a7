%% Tests of evatar_placement: the rebalancing plan, case by case and by
%% PropEr over random placements.
-module(evatar_placement_tests).

%% Both headers define LET: PropEr's is the one used here.
-include_lib("eunit/include/eunit.hrl").
-undef(LET).
-include_lib("proper/include/proper.hrl").

-define(NODES, [a, b, c]).

%% After faults: every active on a, every standby on b, c idle.
skewed(N) ->
    maps:from_list([{id(K), {a, b}} || K <- lists:seq(1, N)]).

id(K) -> <<"p", (integer_to_binary(K))/binary>>.

run(Nodes, Placement) ->
    lists:foldl(fun evatar_placement:apply_move/2, Placement,
                evatar_placement:plan(Nodes, Placement)).

spread(Nodes, Placement, Pos) ->
    Counts = [element(Pos, C) || C <- maps:values(evatar_placement:counts(Nodes, Placement))],
    lists:max(Counts) - lists:min(Counts).

balanced_plans_nothing_test() ->
    P = #{<<"x">> => {a, b}, <<"y">> => {b, c}, <<"z">> => {c, a}},
    ?assertEqual([], evatar_placement:plan(?NODES, P)).

%% The returning node c gets its share of actives and standbys.
node_returns_test() ->
    P = skewed(6),
    Moves = evatar_placement:plan(?NODES, P),
    After = run(?NODES, P),
    ?assertEqual(#{a => {2, 2}, b => {2, 2}, c => {2, 2}}, evatar_placement:counts(?NODES, After)),
    ?assert(length(Moves) =< 3 * 6),
    ?assertEqual([], evatar_placement:plan(?NODES, After)).

%% Handovers alone move actives whose standby is where they should go;
%% then one standby moves off the node left with two.
handover_when_standby_there_test() ->
    P = #{<<"x">> => {a, b}, <<"y">> => {a, b}, <<"z">> => {a, c}},
    ?assertEqual([{handover, <<"x">>}, {handover, <<"z">>}, {standby, <<"x">>, c}],
                 evatar_placement:plan(?NODES, P)).

%% One live node, or pairings on a node that is not live: nothing moves
%% them.
not_live_test() ->
    ?assertEqual([], evatar_placement:plan([a], skewed(3))),
    P = #{<<"x">> => {a, d}, <<"y">> => {a, d}, <<"z">> => {a, d}},
    ?assertEqual([], evatar_placement:plan(?NODES, P)).

prop_test() ->
    ok = evatar_test_proper:check(prop_plan(), 500).

%% Every plan's moves are valid in order (a handover of a pairing with a
%% standby; a standby moved to another live node than both of its
%% instances), leave actives spread within one and, with three nodes or
%% more, standbys too; pairings on dead nodes stay; a second plan is empty;
%% at most three moves per pairing.
prop_plan() ->
    ?FORALL({Nodes, Dead, Placement}, placement(),
            begin
                Moves = evatar_placement:plan(Nodes, Placement),
                Final = lists:foldl(fun(M, P) -> valid(M, P, Nodes) end, Placement, Moves),
                Live = maps:filter(fun(_, {A, S}) -> not lists:member(A, Dead)
                                                         andalso not lists:member(S, Dead)
                                   end, Final),
                ?WHENFAIL(io:format("nodes ~p dead ~p~nplacement ~p~nmoves ~p~nfinal ~p~n",
                                    [Nodes, Dead, Placement, Moves, Final]),
                          spread(Nodes, Live, 1) =< 1
                          andalso (length(Nodes) < 3 orelse spread(Nodes, Live, 2) =< 1)
                          andalso maps:with(maps:keys(Placement) -- maps:keys(Live), Final)
                                  =:= maps:without(maps:keys(Live), Placement)
                          andalso evatar_placement:plan(Nodes, Final) =:= []
                          andalso length(Moves) =< 3 * map_size(Live))
            end).

valid({handover, Id}, P, _Nodes) ->
    #{Id := {A, S}} = P,
    true = A =/= S,
    evatar_placement:apply_move({handover, Id}, P);
valid({standby, Id, Node} = M, P, Nodes) ->
    #{Id := {A, S}} = P,
    true = lists:member(Node, Nodes) andalso Node =/= A andalso Node =/= S,
    evatar_placement:apply_move(M, P).

placement() ->
    ?LET({N, D}, {range(2, 5), range(0, 1)},
         begin
             Nodes = lists:sublist([a, b, c, d, e], N),
             Dead = lists:sublist([x], D),
             All = Nodes ++ Dead,
             ?LET(Pairs, list({elements(All), elements(All)}),
                  {Nodes, Dead,
                   maps:from_list([{id(K), {A, S}}
                                   || {K, {A, S}} <- lists:enumerate(Pairs), A =/= S])})
         end).

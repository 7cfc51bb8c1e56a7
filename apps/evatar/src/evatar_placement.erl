%% @doc Internal. Where pairings' instances should be: a pure plan of moves
%% that spreads actives, then standbys, evenly over the live nodes
%% (docs/ha-design.md section 2, "Rebalancing"). No processes, no
%% clock: `evatar_rebalancer' gathers the placement and executes the moves.
%%
%% Two moves exist, both paths the pairing already has: `{handover, Id}' (a
%% planned handover: the active and its synced standby swap nodes, nothing
%% is lost or delivered twice) and `{standby, Id, Node}' (the active
%% dismisses its standby and places a new one on `Node').
%% Actives first: while two nodes' active counts differ by more than one,
%% an active moves from the fullest to the emptiest node, by a handover
%% when its standby is there already, else by a standby move there and a
%% handover. Then standbys, by standby moves, while two nodes' counts
%% differ by more than one and a standby can go from the fuller to the
%% emptier node without meeting its own active there. Every move narrows
%% a gap, so a plan has at most about as many moves as pairings (three per
%% pairing at most); it costs O(M * N^3 * log P) for M moves, N nodes and
%% P pairings, N being a home's handful of machines.
-module(evatar_placement).

-export([plan/2, apply_move/2, counts/2]).

-export_type([placement/0, move/0]).

%% Per pairing: the node of its active and of its standby.
-type placement() :: #{evatar:pairing_id() => {Active :: node(), Standby :: node()}}.
-type move() :: {handover, evatar:pairing_id()}
              | {standby, evatar:pairing_id(), node()}.

%% Index: {ActiveNode, StandbyNode} => ordered set of ids.
-type index() :: #{{node(), node()} => gb_sets:set(evatar:pairing_id())}.

%% @doc The moves, in order, that spread the pairings of `Placement' over
%% `Nodes' (the live nodes). Pairings with an instance on a node not in
%% `Nodes' are left where they are and not counted. [] when the actives'
%% and the standbys' counts per node each differ by at most one.
-spec plan([node()], placement()) -> [move()].
plan(Nodes0, Placement) ->
    Nodes = lists:usort(Nodes0),
    Live = maps:filter(fun(_, {A, S}) -> A =/= S andalso lists:member(A, Nodes)
                                             andalso lists:member(S, Nodes)
                       end, Placement),
    case length(Nodes) < 2 of
        true ->
            [];
        false ->
            Index = index(Live),
            {Index1, Actives} = actives(Nodes, Index, []),
            {_, Standbys} = standbys(Nodes, Index1, []),
            lists:reverse(Actives) ++ lists:reverse(Standbys)
    end.

%% @doc A move's effect on a placement (what the plan assumes it does).
-spec apply_move(move(), placement()) -> placement().
apply_move({handover, Id}, Placement) ->
    #{Id := {A, S}} = Placement,
    Placement#{Id := {S, A}};
apply_move({standby, Id, Node}, Placement) ->
    #{Id := {A, _}} = Placement,
    Placement#{Id := {A, Node}}.

%% @doc How many actives and how many standbys each of `Nodes' holds.
-spec counts([node()], placement()) -> #{node() => {non_neg_integer(), non_neg_integer()}}.
counts(Nodes, Placement) ->
    Zero = maps:from_list([{N, {0, 0}} || N <- Nodes]),
    maps:fold(fun(_, {A, S}, Acc) ->
                      Acc1 = bump(A, 1, Acc),
                      bump(S, 2, Acc1)
              end, Zero, Placement).

bump(Node, Pos, Acc) ->
    case Acc of
        #{Node := T} -> Acc#{Node := setelement(Pos, T, element(Pos, T) + 1)};
        #{} -> Acc
    end.

%% ---------------------------------------------------------------------------
%% Actives
%% ---------------------------------------------------------------------------

actives(Nodes, Index, Moves) ->
    Count = fun(N) -> lists:sum([size_of(N, X, Index) || X <- Nodes, X =/= N]) end,
    {Full, Empty} = extremes(Nodes, Count),
    case Count(Full) - Count(Empty) > 1 of
        false ->
            {Index, Moves};
        true ->
            case pick(Full, Empty, Index) of
                {ok, Id} ->
                    %% Its standby is on the emptiest node already: swap.
                    actives(Nodes, move(Id, {Full, Empty}, {Empty, Full}, Index),
                            [{handover, Id} | Moves]);
                none ->
                    %% Any of its actives: the standby goes to the emptiest
                    %% node first, then they swap.
                    {S, Id} = first([{size_of(Full, X, Index) > 0, X} || X <- Nodes,
                                                                         X =/= Full],
                                    Full, Index),
                    actives(Nodes, move(Id, {Full, S}, {Empty, Full}, Index),
                            [{handover, Id}, {standby, Id, Empty} | Moves])
            end
    end.

%% ---------------------------------------------------------------------------
%% Standbys
%% ---------------------------------------------------------------------------

standbys(Nodes, Index, Moves) ->
    Count = maps:from_list([{N, lists:sum([size_of(X, N, Index) || X <- Nodes, X =/= N])}
                            || N <- Nodes]),
    %% Pairs of nodes whose counts differ by more than one, the widest
    %% first; the first that has a standby on the fuller node whose active
    %% is on neither (a pairing's two instances stay apart) moves it.
    Pairs = lists:sort([{maps:get(E, Count) - maps:get(F, Count), F, E}
                        || F <- Nodes, E <- Nodes, maps:get(F, Count) - maps:get(E, Count) > 1]),
    Movable = [{F, E, A, Id} || {_, F, E} <- Pairs, A <- Nodes, A =/= F, A =/= E,
                                {ok, Id} <- [pick(A, F, Index)]],
    case Movable of
        [{F, E, A, Id} | _] ->
            standbys(Nodes, move(Id, {A, F}, {A, E}, Index), [{standby, Id, E} | Moves]);
        [] ->
            {Index, Moves}
    end.

%% ---------------------------------------------------------------------------
%% The index
%% ---------------------------------------------------------------------------

-spec index(placement()) -> index().
index(Placement) ->
    maps:fold(fun(Id, Key, Acc) ->
                      maps:update_with(Key, fun(Set) -> gb_sets:add(Id, Set) end,
                                       gb_sets:singleton(Id), Acc)
              end, #{}, Placement).

size_of(A, S, Index) ->
    case Index of
        #{{A, S} := Set} -> gb_sets:size(Set);
        #{} -> 0
    end.

%% The smallest id active on A with its standby on S.
pick(A, S, Index) ->
    case Index of
        #{{A, S} := Set} ->
            case gb_sets:is_empty(Set) of
                true -> none;
                false -> {ok, gb_sets:smallest(Set)}
            end;
        #{} ->
            none
    end.

%% The first node X (with a pairing active on A and standby on X) and the
%% smallest such id.
first([{true, X} | _], A, Index) ->
    {ok, Id} = pick(A, X, Index),
    {X, Id};
first([{false, _} | Rest], A, Index) ->
    first(Rest, A, Index).

move(Id, From, To, Index) ->
    Left = gb_sets:delete(Id, maps:get(From, Index)),
    Index#{From := Left,
           To => gb_sets:add(Id, maps:get(To, Index, gb_sets:empty()))}.

%% The node with the most and the node with the fewest, by `Count'; ties
%% to the smallest node name, so the plan is the same on every node.
extremes(Nodes, Count) ->
    Counted = [{Count(N), N} || N <- Nodes],
    {_, Full} = lists:foldl(fun({C, N}, {BC, _}) when C > BC -> {C, N};
                               (_, Best) -> Best
                            end, hd(Counted), tl(Counted)),
    {_, Empty} = lists:foldl(fun({C, N}, {BC, _}) when C < BC -> {C, N};
                                (_, Best) -> Best
                             end, hd(Counted), tl(Counted)),
    {Full, Empty}.

%% @doc Internal. The pure decisions of the pairings' catalogue
%% (`evatar_catalogue'): which of two versions of an entry wins when two
%% nodes' catalogues meet, which entries a node must start or stop, and
%% which node holds a pairing's active after a restart. No processes, no
%% clock, no storage (docs/ha-design.md, section 11).
%%
%% An entry is a register per pairing id: a live entry (the pairing's
%% configuration and its home node) or a tombstone (it was deleted), with
%% a version `{Counter, WallMs, Node}'. A node writes at one more than the
%% highest counter it holds for that id, so a write made after seeing
%% another always wins over it. Two writes made apart (neither saw the
%% other) are ordered without any clock ({@link wins/2}): the higher
%% counter, then a tombstone over a live entry, then the node name. So a
%% deletion is never undone by a write it did not see at its counter, and
%% every node picks the same winner whatever its clock says. `WallMs'
%% only tells people when a write was made.
%%
%% Which writes may be made at all is decided by {@link may_change/2}: a
%% node changes the catalogue only while it hears a majority of the
%% configured nodes (a cluster of two, which has no majority once split,
%% also alone), so a change made on a minority side of a partition cannot
%% beat one made on the majority side: it is refused.
-module(evatar_catalogue_rules).

-export([next_version/3, wins/2, merge/2, changed/2, may_change/2, owner/3, to_start/4,
         to_stop/2, gave_up/1]).

-export_type([entry/0, version/0, value/0]).

-type version() :: {Counter :: non_neg_integer(), WallMs :: integer(), node()}.
-type value() :: {live, evatar_pairing_logic:config(), Home :: node()} | deleted.
-type entry() :: {evatar:pairing_id(), version(), value()}.

%% @doc The version of a new write of an id whose current entry (if any)
%% has version `Current', made on `Node' at wall-clock time `WallMs' (kept
%% for people reading the catalogue; it orders nothing).
-spec next_version(version() | none, integer(), node()) -> version().
next_version(none, WallMs, Node) -> {1, WallMs, Node};
next_version({C, _, _}, WallMs, Node) -> {C + 1, WallMs, Node}.

%% @doc Whether entry `A' wins over entry `B' of the same id: the higher
%% counter; at the same counter (two writes made apart) a tombstone over a
%% live entry, then the greater node name; then, only for two writes of
%% one node at one counter (a node that lost its catalogue in memory and
%% wrote again), the greater value, then the later `WallMs' (the values
%% are then equal: no decision rests on a clock).
-spec wins(entry(), entry()) -> boolean().
wins({_, VA, A}, {_, VB, B}) ->
    rank(VA, A) > rank(VB, B).

rank({Counter, WallMs, Node}, Value) ->
    {Counter, Value =:= deleted, Node, Value, WallMs}.

%% @doc Whether a node may create or delete a pairing now: while it hears
%% a majority of the configured nodes (a lone node always does); in a
%% cluster of two also without (neither side of a split has a majority:
%% each goes on, and their concurrent writes are ordered by {@link wins/2}).
-spec may_change(ClusterSize :: pos_integer(), HearsMajority :: boolean()) -> boolean().
may_change(_Size, true) -> true;
may_change(Size, false) -> Size =< 2.

%% @doc Merges a peer's entries into ours (both lists sorted or not, one
%% entry per id): per id, the entry that wins. Commutative,
%% associative and idempotent, so catalogues exchanged in any order, any
%% number of times, end equal.
-spec merge([entry()], [entry()]) -> [entry()].
merge(Ours, Theirs) ->
    Merged = lists:foldl(fun({Id, _, _} = E, Acc) ->
                                 case Acc of
                                     #{Id := E0} ->
                                         case wins(E, E0) of
                                             true -> Acc#{Id := E};
                                             false -> Acc
                                         end;
                                     #{} ->
                                         Acc#{Id => E}
                                 end
                         end, maps:from_list([{Id, E} || {Id, _, _} = E <- Ours]), Theirs),
    lists:sort(maps:values(Merged)).

%% @doc The entries of `Theirs' that win over (or are missing from)
%% `Ours': what a node must write when it receives a peer's catalogue.
-spec changed([entry()], [entry()]) -> [entry()].
changed(Ours, Theirs) ->
    Known = maps:from_list([{Id, E} || {Id, _, _} = E <- Ours]),
    [E || {Id, _, _} = E <- Theirs,
          case Known of
              #{Id := E0} -> wins(E, E0);
              #{} -> true
          end].

%% @doc The node that starts a pairing none of whose instances runs: its
%% home node when that is alive, else the first alive node after the home
%% in the sorted ring of configured nodes (the same ring as standby
%% placement). `none' when no configured node is alive.
-spec owner(Home :: node(), Configured :: [node()], Alive :: [node()]) -> node() | none.
owner(Home, Configured, Alive) ->
    case lists:member(Home, Alive) of
        true -> Home;
        false -> evatar_ha_membership:standby_node(lists:usort([Home | Configured]), Home, Alive,
                                              undefined)
    end.

%% @doc The live entries this node (`Self') must start: those it owns and
%% of which no instance runs anywhere (`Running': the ids with an instance
%% on this node or on an alive peer).
-spec to_start([entry()], node(), {[node()], [node()]}, [evatar:pairing_id()]) ->
          [{evatar:pairing_id(), evatar_pairing_logic:config()}].
to_start(Entries, Self, {Configured, Alive}, Running) ->
    Up = maps:from_list([{Id, true} || Id <- Running]),
    [{Id, Config} || {Id, _, {live, Config, Home}} <- Entries, not is_map_key(Id, Up),
                     owner(Home, Configured, Alive) =:= Self].

%% @doc The ids with a tombstone among those running on this node: their
%% instances stop.
-spec to_stop([entry()], [evatar:pairing_id()]) -> [evatar:pairing_id()].
to_stop(Entries, Local) ->
    Deleted = maps:from_list([{Id, true} || {Id, _, deleted} <- Entries]),
    [Id || Id <- Local, is_map_key(Id, Deleted)].

%% @doc Whether a pairing's active (or fenced) instance that stopped with
%% `Reason' may have given up: it crashed, and its supervisor restarts it
%% or, past its restart limit, removes it; then this node does not start
%% it again itself. An instance that stopped on purpose (`normal',
%% `shutdown', `{shutdown, Why}': it stepped down for a newer instance, or
%% its claim was found stale, or it was deleted) did not: a pairing left
%% without any instance after that is restored as any other.
-spec gave_up(term()) -> boolean().
gave_up(normal) -> false;
gave_up(shutdown) -> false;
gave_up({shutdown, _}) -> false;
gave_up(_Crash) -> true.

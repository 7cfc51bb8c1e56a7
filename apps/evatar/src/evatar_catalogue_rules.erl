%% @doc Internal. The pure decisions of the pairings' catalogue
%% (`evatar_catalogue'): which of two versions of an entry wins when two
%% nodes' catalogues meet, which entries a node must start or stop, and
%% which node holds a pairing's active after a restart. No processes, no
%% clock, no storage (docs/ha-design.md, section 11).
%%
%% An entry is a last-writer-wins register per pairing id: a live entry
%% (the pairing's configuration and its home node) or a tombstone (it was
%% deleted). Its version `{Counter, WallMs, Node}' orders every write: a
%% node writes at one more than the highest counter it holds for that id,
%% so a write made after seeing another always wins over it; two writes
%% made apart (a partition) are ordered by their wall clocks, then by node
%% name, so every node picks the same winner with no operator action.
-module(evatar_catalogue_rules).

-export([next_version/3, merge/2, newer/2, changed/2, owner/3, to_start/4, to_stop/2,
         gave_up/1]).

-export_type([entry/0, version/0, value/0]).

-type version() :: {Counter :: non_neg_integer(), WallMs :: integer(), node()}.
-type value() :: {live, evatar_pairing_logic:config(), Home :: node()} | deleted.
-type entry() :: {evatar:pairing_id(), version(), value()}.

%% @doc The version of a new write of an id whose current entry (if any)
%% has version `Current', made on `Node' at wall-clock time `WallMs'.
-spec next_version(version() | none, integer(), node()) -> version().
next_version(none, WallMs, Node) -> {1, WallMs, Node};
next_version({C, _, _}, WallMs, Node) -> {C + 1, WallMs, Node}.

%% @doc Whether version `A' wins over `B'.
-spec newer(version(), version()) -> boolean().
newer(A, B) -> A > B.

%% @doc Merges a peer's entries into ours (both lists sorted or not, one
%% entry per id): per id, the entry of the newer version. Commutative,
%% associative and idempotent, so catalogues exchanged in any order, any
%% number of times, end equal.
-spec merge([entry()], [entry()]) -> [entry()].
merge(Ours, Theirs) ->
    Merged = lists:foldl(fun({Id, V, _} = E, Acc) ->
                                 case Acc of
                                     #{Id := {_, V0, _}} ->
                                         case newer(V, V0) of
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
    Known = maps:from_list([{Id, V} || {Id, V, _} <- Ours]),
    [E || {Id, V, _} = E <- Theirs,
          case Known of
              #{Id := V0} -> newer(V, V0);
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
        false -> evatar_ha_rules:standby_node(lists:usort([Home | Configured]), Home, Alive,
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

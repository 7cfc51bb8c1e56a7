%% @doc Internal. The pure decisions of the pairings' catalogue
%% (`evatar_catalogue', which reads, writes and sends, and decides
%% nothing): which of two versions of an entry wins when two nodes'
%% catalogues meet, who may change the catalogue, which peer gets the
%% whole catalogue when ({@link exchange/3}, {@link received/3}), and the
%% reconcile loop: which local instances stop, which are watched, when
%% the node is ready, which waiting ensures are written, which pairings it
%% restores and when (the back-off). No processes, no clock, no storage
%% (docs/ha-design.md, section 11).
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
%%
%% A look (the reconcile loop: every 500 ms and after every change) is one
%% to three steps, each `{Effects, Next, Memory}' from the {@link facts()}
%% the process read (the clocks among them) and the {@link memory()} the
%% rules keep between looks:
%% ```
%% look(Facts, M) -------> stops, watches; not ready: done
%%   | pending ensures: room --> room_checked(ok | full, Entries, Facts, M)
%%   v                              | writes of the absent ones
%% owned, run nowhere here? <-------+
%%   | none: done; no connected peer: answered([], ..) at once
%%   v
%% {ask, Nodes, Cont} --> answered(Their roles, Cont, Facts, M) --> restores
%% '''
%% The process carries out each step's effects in order ({@link
%% effect()}: real I/O only) before it takes the next step; a restore that
%% started a process comes back through {@link started/3}, a watched
%% instance that stopped through {@link down/3}.
-module(evatar_catalogue_rules).

-export([next_version/3, wins/2, merge/2, changed/2, may_change/2, owner/3, to_start/4,
         to_stop/2, gave_up/1]).
-export([new/1, look/2, room_checked/4, answered/4, started/3, down/3, pend/3, retry/2,
         ready/2, restore_delay/2]).
-export([exchange/3, received/3, sync_now/1, recipients/2]).

-export_type([entry/0, version/0, value/0, facts/0, effect/0, next/0, memory/0, cont/0,
              answer/0, round/0]).

-type version() :: {Counter :: non_neg_integer(), WallMs :: integer(), node()}.
-type value() :: {live, evatar_pairing_logic:config(), Home :: node()} | deleted.
-type entry() :: {evatar:pairing_id(), version(), value()}.

%% What the process reads before a look: its catalogue, its instances
%% (evatar_registry:roles/0), the cluster as evatar_cluster sees it (alive
%% includes this node; connected: the configured peers connected now), the
%% setting `catalogue_alone_ms', and the monotonic and wall clocks.
-type facts() :: #{self := node(),
                   entries := [entry()],
                   roles := [{evatar:pairing_id(), pid(), atom(), non_neg_integer()}],
                   configured := [node()],
                   alive := [node()],
                   connected := [node()],
                   majority := boolean(),
                   size := pos_integer(),
                   alone_ms := non_neg_integer(),
                   now_ms := integer(),
                   wall_ms := integer()}.
%% What the process reads before an exchange round: the alive nodes (this
%% one included), the monotonic clock and the setting `catalogue_sync_ms'.
-type round() :: #{self := node(), alive := [node()], now_ms := integer(),
                   sync_ms := pos_integer()}.
%% What the process does: send its whole catalogue to a peer, ask a local
%% instance of a deleted pairing to delete itself (from another process:
%% it may take a while), monitor an instance, write an entry and send it
%% to the peers, start a pairing from the catalogue (and log
%% `pairing_restored' with the outcome), log.
-type effect() :: {push, node()}
                | {delete, pid()}
                | {monitor, pid()}
                | {write, entry()}
                | {restore, evatar:pairing_id(), evatar_pairing_logic:config(),
                   RetryAfterMs :: pos_integer()}
                | {log, logger:level(), logger:report()}.
%% What the next step needs: nothing, whether the data directory has room
%% (evatar_data_dir) and the entries after that check, or which pairings
%% these peers run (their evatar_registry:roles/0, as erpc:multicall/5
%% answers).
-type next() :: done | room | {ask, [node()], cont()}.
-type answer() :: {ok, [{evatar:pairing_id(), pid(), atom(), non_neg_integer()}]}
                | {error | exit | throw, term()}.
-opaque cont() :: {[entry()], [{evatar:pairing_id(), evatar_pairing_logic:config()}]}.

-record(mem, {started :: integer(),
              %% The exchange: the peers alive at the last round, those
              %% whose whole catalogue this node received since, and when
              %% every alive peer was last sent the whole catalogue.
              alive = [] :: [node()],
              synced = #{} :: #{node() => true},
              last_sync :: integer(),
              %% Per pairing: when this node last restored it, and how
              %% long the next restore waits.
              backoff = #{} :: #{evatar:pairing_id() => {integer(), pos_integer()}},
              %% Local instances asked to delete themselves.
              stopping = #{} :: #{pid() => true},
              %% Pairings that were active here: one that stopped here
              %% without being deleted gave up (its restart limit), and is
              %% not restored on this node until it restarts; unless it
              %% stopped on purpose (down/3), or runs elsewhere.
              ran = #{} :: #{evatar:pairing_id() => true},
              %% The monitored instances.
              watched = #{} :: #{pid() => evatar:pairing_id()},
              %% Ensures asked while this node did not hear a majority:
              %% written at the first look that is ready, when absent.
              pending = #{} :: #{evatar:pairing_id() => evatar_pairing_logic:config()}}).
-opaque memory() :: #mem{}.

-define(RESTORE_BACKOFF_MIN, 1000).
-define(RESTORE_BACKOFF_MAX, 300000).

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

%% ---------------------------------------------------------------------------
%% The reconcile loop
%% ---------------------------------------------------------------------------

%% @doc The memory of a catalogue started at monotonic time `NowMs'.
-spec new(NowMs :: integer()) -> memory().
new(NowMs) ->
    #mem{started = NowMs, last_sync = NowMs}.

%% @doc The first step of a look: each local instance of a deleted pairing
%% is asked once to delete itself, the local actives (and fenced) are
%% watched and count as run here; then, once {@link ready/2}, the pending
%% ensures (after a check of the room: `room') or what this node owns.
-spec look(facts(), memory()) -> {[effect()], next(), memory()}.
look(#{entries := Entries, roles := Roles} = F, #mem{stopping = Stopping0} = M0) ->
    Pids = maps:from_list([{Id, Pid} || {Id, Pid, _, _} <- Roles]),
    {Stops, Stopping} = lists:foldl(fun(Id, Acc) -> stop(Id, maps:get(Id, Pids), Acc) end,
                                    {[], maps:with(maps:values(Pids), Stopping0)},
                                    to_stop(Entries, maps:keys(Pids))),
    Actives = [{Id, Pid} || {Id, Pid, R, _} <- Roles, R =:= active orelse R =:= fenced],
    {Watches, Watched} = lists:foldl(fun({Id, Pid}, {Es, W}) ->
                                             {Es1, W1} = watch(Id, Pid, W),
                                             {Es ++ Es1, W1}
                                     end, {[], M0#mem.watched}, Actives),
    M = M0#mem{stopping = Stopping, watched = Watched,
               ran = maps:merge(M0#mem.ran, maps:from_list([{Id, true} || {Id, _} <- Actives]))},
    Effects = lists:reverse(Stops) ++ Watches,
    case ready(F, M) of
        false -> {Effects, done, M};
        true when M#mem.pending =:= #{} -> owned(Effects, Entries, F, M);
        true -> {Effects, room, M}
    end.

stop(_Id, Pid, {Es, Stopping}) when is_map_key(Pid, Stopping) ->
    {Es, Stopping};
stop(Id, Pid, {Es, Stopping}) ->
    {[{delete, Pid}, {log, notice, #{what => pairing_deleted_elsewhere, pairing => Id}} | Es],
     Stopping#{Pid => true}}.

watch(Id, Pid, Watched) when is_map_key(Pid, Watched) -> {[], Watched#{Pid := Id}};
watch(Id, Pid, Watched) -> {[{monitor, Pid}], Watched#{Pid => Id}}.

%% @doc Whether this node may start what it owns: it has the catalogue of
%% every peer alive or connected, and either hears a majority or, in a
%% cluster of two, has been alone for `alone_ms' since its start.
-spec ready(facts(), memory()) -> boolean().
ready(#{majority := Majority, size := Size, alone_ms := AloneMs, now_ms := Now} = F,
      #mem{started = Started, synced = Synced}) ->
    lists:all(fun(N) -> is_map_key(N, Synced) end, peers(F))
        andalso (Majority orelse (Size =< 2 andalso Now - Started >= AloneMs)).

peers(#{self := Self, alive := Alive, connected := Connected}) ->
    lists:usort([N || N <- Alive, N =/= Self] ++ Connected).

%% @doc After `room': with room (`ok'), each pending ensure of which
%% `Entries' (the catalogue read after the check) has no live entry is
%% written, this node its home, and none counts as given up here any
%% more; without (`full') they wait for a later look. Then what this node
%% owns, from the entries with those writes.
-spec room_checked(ok | full, [entry()], facts(), memory()) -> {[effect()], next(), memory()}.
room_checked(full, Entries, F, M) ->
    owned([], Entries, F, M);
room_checked(ok, Entries, #{self := Self, wall_ms := Wall} = F,
             #mem{pending = Pending, ran = Ran} = M) ->
    Known = maps:from_list([{Id, E} || {Id, _, _} = E <- Entries]),
    Written = [{Id, next_version(version(maps:get(Id, Known, none)), Wall, Self),
                {live, Config, Self}}
               || {Id, Config} <- lists:sort(maps:to_list(Pending)),
                  not live(maps:get(Id, Known, none))],
    Effects = lists:append([[{write, E}, {log, notice, #{what => pairing_ensured, pairing => Id}}]
                            || {Id, _, _} = E <- Written]),
    owned(Effects, merge(Entries, Written), F,
          M#mem{pending = #{}, ran = maps:without(maps:keys(Pending), Ran)}).

version({_, V, _}) -> V;
version(none) -> none.

live({_, _, {live, _, _}}) -> true;
live(_) -> false.

%% What this node owns of which no instance runs here: none, done; else
%% the connected peers are asked what they run. A connected peer whose
%% catalogue this node has (ready/2) counts as alive for ownership even
%% before its heartbeats are heard: after a power cut a home node not yet
%% heard but restoring its pairings would otherwise meet a second
%% instance at the same epoch started by the next node.
owned(Effects, Entries, #{self := Self, configured := Configured, roles := Roles,
                          connected := Connected} = F, M) ->
    Local = [Id || {Id, _, _, _} <- Roles],
    case to_start(Entries, Self, {Configured, [Self | peers(F)]}, Local) of
        [] ->
            {Effects, done, M};
        Candidates when Connected =:= [] ->
            {Restores, done, M1} = answered([], {Entries, Candidates}, F, M),
            {Effects ++ Restores, done, M1};
        Candidates ->
            {Effects, {ask, Connected, {Entries, Candidates}}, M}
    end.

%% @doc The last step: from the peers' answers (their local instances),
%% the candidates that run nowhere and did not give up here are restored,
%% each unless its back-off ({@link restore_delay/2}) says wait. A pairing
%% that runs elsewhere did not give up here. A peer that did not answer
%% may run anything: nothing starts, and every id counts as running
%% elsewhere.
-spec answered([answer()], cont(), facts(), memory()) -> {[effect()], done, memory()}.
answered(Answers, {_Entries, Candidates}, #{now_ms := Now}, #mem{ran = Ran0} = M0) ->
    %% Seen running on a peer: it did not give up here. A peer that did not
    %% answer may run anything: nothing is restored this look, and what
    %% this node remembers of the pairings that gave up here is kept.
    Remote = maps:from_list([{Id, true} || {ok, Roles} <- Answers, {Id, _, _, _} <- Roles]),
    Ran = maps:without(maps:keys(Remote), Ran0),
    Missing = case lists:all(fun({ok, _}) -> true; (_) -> false end, Answers) of
                  true -> [C || {Id, _} = C <- Candidates, not is_map_key(Id, Remote),
                                not is_map_key(Id, Ran)];
                  false -> []
              end,
    {Effects, M} = lists:foldl(fun(C, {Es, Mi}) -> restore(C, Now, Es, Mi) end,
                               {[], M0#mem{ran = Ran}}, Missing),
    {lists:reverse(Effects), done, M}.

restore({Id, Config}, Now, Es, #mem{backoff = Backoff} = M) ->
    case restore_delay(maps:get(Id, Backoff, none), Now) of
        wait -> {Es, M};
        Next -> {[{restore, Id, Config, Next} | Es], M#mem{backoff = Backoff#{Id => {Now, Next}}}}
    end.

%% @doc Whether a pairing last restored at `Last' with a wait of `Delay'
%% may be restored at `Now', and how long the restore after that waits: a
%% pairing restored again soon after its last restore (it keeps dying
%% with both its instances) waits twice as long each time, up to 5 min;
%% one that lasted ten times its wait, or never restored, 1 s.
-spec restore_delay(none | {Last :: integer(), Delay :: pos_integer()}, Now :: integer()) ->
          wait | pos_integer().
restore_delay({Last, Delay}, Now) when Now - Last < Delay -> wait;
restore_delay({Last, Delay}, Now) when Now - Last < 10 * Delay ->
    min(?RESTORE_BACKOFF_MAX, 2 * Delay);
restore_delay(_, _Now) -> ?RESTORE_BACKOFF_MIN.

%% @doc This node started pairing `Id' itself (created or restored here)
%% and its process is `Pid' (`undefined': gone already). It ran here from
%% its first instant: one that crashes past its restart limit before the
%% next look saw it active gave up all the same, and is not restored
%% (evatar_pairing_SUITE crash_loop_at_creation_gives_up). It is watched
%% like an active, so that stepping down still leaves it to be restored;
%% one gone already is left to the next look.
-spec started(evatar:pairing_id(), pid() | undefined, memory()) -> {[effect()], memory()}.
started(_Id, undefined, M) ->
    {[], M};
started(Id, Pid, #mem{ran = Ran, watched = Watched} = M) ->
    {Effects, Watched1} = watch(Id, Pid, Watched),
    {Effects, M#mem{ran = Ran#{Id => true}, watched = Watched1}}.

%% @doc A monitored process stopped with `Reason': `true' when its
%% pairing stepped down ({@link gave_up/1} says no), so that a look now
%% restores it if no instance is left anywhere (else it would stay down
%% for good); `false' when it gave up, or was not watched.
-spec down(pid(), term(), memory()) -> {Look :: boolean(), memory()}.
down(Pid, Reason, #mem{watched = Watched, ran = Ran} = M) ->
    case maps:take(Pid, Watched) of
        error ->
            {false, M};
        {Id, Watched1} ->
            case gave_up(Reason) of
                true -> {false, M#mem{watched = Watched1}};
                false -> {true, M#mem{watched = Watched1, ran = maps:remove(Id, Ran)}}
            end
    end.

%% @doc An ensure asked while this node may not change the catalogue: it
%% waits in memory until a look is ready, then is written if still absent.
-spec pend(evatar:pairing_id(), evatar_pairing_logic:config(), memory()) -> memory().
pend(Id, Config, #mem{pending = Pending} = M) ->
    M#mem{pending = Pending#{Id => Config}}.

%% @doc An ensure of `Id' found it in the catalogue or wrote it: a pairing
%% that gave up here may start again.
-spec retry(evatar:pairing_id(), memory()) -> memory().
retry(Id, #mem{ran = Ran} = M) ->
    M#mem{ran = maps:remove(Id, Ran)}.

%% ---------------------------------------------------------------------------
%% The exchange
%% ---------------------------------------------------------------------------

%% @doc An exchange round (every look; `Forced': as if its timer were due):
%% a peer that became alive gets the whole catalogue, and so does every
%% alive peer every `sync_ms' (what a silent partition held back). A peer
%% no longer alive must send its catalogue again before this node is
%% {@link ready/2}.
-spec exchange(round(), Forced :: boolean(), memory()) -> {[effect()], memory()}.
exchange(#{self := Self, alive := Alive0, now_ms := Now, sync_ms := SyncMs}, Forced,
         #mem{alive = Old, synced = Synced, last_sync = Last} = M) ->
    Alive = [N || N <- Alive0, N =/= Self],
    Periodic = Forced orelse Now - Last >= SyncMs,
    Due = case Periodic of
              true -> Alive;
              false -> Alive -- Old
          end,
    {[{push, N} || N <- Due],
     M#mem{alive = Alive, synced = maps:with(Alive, Synced),
           last_sync = case Periodic of
                           true -> Now;
                           false -> Last
                       end}}.

%% @doc A peer's entries arrived, its whole catalogue (`Full') or one
%% write: after a whole one this node is in sync with `From', and a peer
%% it was not in sync with gets its own back, so both sides are, whoever
%% noticed the other first.
-spec received(node(), Full :: boolean(), memory()) -> {[effect()], memory()}.
received(_From, false, M) ->
    {[], M};
received(From, true, #mem{synced = Synced} = M) ->
    {[{push, From} || not is_map_key(From, Synced)], M#mem{synced = Synced#{From => true}}}.

%% @doc The whole catalogue now to every peer alive at the last round.
-spec sync_now(memory()) -> [effect()].
sync_now(#mem{alive = Alive}) ->
    [{push, N} || N <- Alive].

%% @doc Who learns a write at once: the peers alive at the last round and
%% the `Connected' ones (one just started, not yet heard, would otherwise
%% learn it only at the next whole exchange).
-spec recipients(Connected :: [node()], memory()) -> [node()].
recipients(Connected, #mem{alive = Alive}) ->
    lists:usort(Alive ++ Connected).

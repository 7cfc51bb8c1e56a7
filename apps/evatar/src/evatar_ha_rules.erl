%% @doc Internal. The pure decisions of high availability: where a standby
%% goes, whether a set of heard nodes is a majority, whether a standby may
%% take over, and which of two instances of one pairing gives way after a
%% partition heals. No processes, no clock: `evatar_cluster' and
%% `evatar_pairing' call these with what they observed (docs/architecture.md,
%% section 8).
-module(evatar_ha_rules).

-export([standby_node/4, majority/2, must_fence/3, reconcile/2,
         stalled/3, own_pause/3, discount/3, after_pause/2, check_timings/1,
         quorum_size/1, new_record/0, vote/5, register/4]).

-export_type([instance/0, verdict/0, claim/0, record/0, refusal/0, pause_action/0]).

%% A claim: the configuration {Epoch, Seq} an instance holds. The active
%% makes a new one (Seq + 1) each time its standby changes and gives it to
%% the new standby with the snapshot; a takeover at epoch E starts at {E, 1}.
%% Whoever holds the highest claim holds everything any instance released.
-type claim() :: {non_neg_integer(), non_neg_integer()}.
%% What one node (a voter) remembers of one pairing: the highest epoch it
%% promised (voted for, or saw registered), the instance it promised it to
%% (the holder), and the highest claim it saw.
-type record() :: #{promised := non_neg_integer(), holder := pid() | undefined,
                    conf := claim()}.
-type refusal() :: stale_claim | {promised, non_neg_integer()} | holder_live.

-type instance() :: #{role := active | standby | fenced | starting,
                      epoch := non_neg_integer(),
                      node := node(),
                      pid := pid(),
                      peer => pid() | undefined}.
-type verdict() :: keep | step_down | stop.
-type pause_action() :: keep | reconfirm | await.

%% @doc The node for a standby of a pairing active on `Self': `Preferred'
%% when it is alive, else the first alive node after `Self' in the sorted
%% ring of `Configured'. `none' when no other node is alive.
-spec standby_node([node()], node(), [node()], node() | undefined) -> node() | none.
standby_node(Configured, Self, Alive, Preferred) ->
    Candidates = [N || N <- Alive, N =/= Self, lists:member(N, Configured)],
    case lists:member(Preferred, Candidates) of
        true ->
            Preferred;
        false ->
            Ring = lists:usort(Configured),
            {Before, After} = lists:splitwith(fun(N) -> N =< Self end, Ring),
            case [N || N <- After ++ Before, lists:member(N, Candidates)] of
                [N | _] -> N;
                [] -> none
            end
    end.

%% @doc Whether `Heard' (nodes heard recently, this one included) is a
%% strict majority of the `Configured' nodes.
-spec majority([node()], [node()]) -> boolean().
majority(Configured, Heard) ->
    Votes = length([N || N <- lists:usort(Heard), lists:member(N, Configured)]),
    Votes * 2 > length(lists:usort(Configured)).

%% @doc Whether an active must fence itself: in a cluster of 3 or more, when
%% it hears neither its standby's node nor a majority within the lease.
-spec must_fence(ClusterSize :: pos_integer(), Majority :: boolean(),
                 StandbyHeard :: boolean()) -> boolean().
must_fence(Size, _Majority, _StandbyHeard) when Size =< 2 -> false;
must_fence(_Size, Majority, StandbyHeard) -> not (Majority orelse StandbyHeard).

%% @doc What instance `Me' does on learning of `Other', another instance of
%% the same pairing on another node. Two actives (fenced counts as active):
%% the lower epoch steps down; on equal epochs the one on the greater node
%% name does. A standby stops when an active with a higher epoch that is not
%% its own active exists. Anything else keeps going.
-spec reconcile(instance(), instance()) -> verdict().
reconcile(#{role := MyRole, epoch := E1, node := N1},
          #{role := OtherRole, epoch := E2, node := N2})
  when (MyRole =:= active orelse MyRole =:= fenced),
       (OtherRole =:= active orelse OtherRole =:= fenced) ->
    case E2 > E1 orelse (E2 =:= E1 andalso N2 < N1) of
        true -> step_down;
        false -> keep
    end;
reconcile(#{role := standby, epoch := E1} = Me,
          #{role := OtherRole, epoch := E2, pid := Pid})
  when OtherRole =:= active; OtherRole =:= fenced ->
    case E2 > E1 andalso maps:get(peer, Me, undefined) =/= Pid of
        true -> stop;
        false -> keep
    end;
reconcile(_Me, _Other) ->
    keep.

%% @doc Whether this node itself was stopped or starved: the last tick came
%% much later than planned. Then silence from the others is not their fault,
%% and they are given a fresh start instead of being suspected.
-spec stalled(LastTickMs :: integer(), NowMs :: integer(), SuspectMs :: pos_integer()) ->
          boolean().
stalled(LastTick, Now, SuspectMs) ->
    Now - LastTick > SuspectMs.

%% @doc How long this node was itself paused before a tick: how much later
%% than planned (`HeartbeatMs' after the last one) the tick came. The
%% peers' silence during that time says nothing about them ({@link
%% discount/3}).
-spec own_pause(LastTickMs :: integer(), NowMs :: integer(), HeartbeatMs :: pos_integer()) ->
          non_neg_integer().
own_pause(LastTick, Now, HeartbeatMs) ->
    max(0, Now - LastTick - HeartbeatMs).

%% @doc When a peer counts as last heard once this node's own pause is
%% taken out: a peer silent for 40 ms before a pause of 300 ms is silent
%% for 40 ms after it, not 340 ms, so neither its suspicion nor this
%% node's lease counts time in which this node could not hear anything.
%% A peer silent before the pause stays as silent. Never later than `Now'.
-spec discount(HeardAtMs :: integer(), PausedMs :: non_neg_integer(), NowMs :: integer()) ->
          integer().
discount(HeardAt, PausedMs, Now) ->
    min(Now, HeardAt + PausedMs).

%% @doc What an active does when its node finds it was paused itself
%% ({@link stalled/3}: SIGSTOP, a laptop lid, a long GC or a load spike),
%% rather than that its peers went silent. It never fences for the pause
%% alone (docs/ha.md section 6):
%% <ul>
%% <li>`keep' on a lone node: no other node holds the pairing's state, so
%% nobody can have taken it over.</li>
%% <li>`reconfirm' in a cluster: keep every client, hold what is not yet
%% seen outside, and ask every node to record this active's configuration
%% again. A majority that accepts it has promised the pairing to nobody
%% else (and now refuses a standby's election while it hears this node);
%% a refusal means a standby won meanwhile, and the active fences.</li>
%% <li>`await' in a cluster while a registration of this active's
%% configuration is already under way (`Registering'): its answer settles
%% the same question.</li>
%% </ul>
-spec after_pause(ClusterSize :: pos_integer(), Registering :: boolean()) -> pause_action().
after_pause(Size, _Registering) when Size =< 1 -> keep;
after_pause(_Size, true) -> await;
after_pause(_Size, false) -> reconfirm.

%% @doc Whether the high-availability timings hang together: positive
%% integers with `lease_ms + heartbeat_ms =< suspect_ms', so an active cut
%% off from the majority has fenced before any node stops hearing it for
%% `suspect_ms' and votes it away (docs/architecture.md section 8). The
%% error names the setting and says what is wrong.
-spec check_timings(#{heartbeat_ms := term(), suspect_ms := term(), lease_ms := term()}) ->
          ok | {error, {bad_ha_timing, atom(), term(), string()}}.
check_timings(#{heartbeat_ms := Hb, suspect_ms := Suspect, lease_ms := Lease} = T) ->
    case [K || K <- [heartbeat_ms, suspect_ms, lease_ms],
               not (is_integer(maps:get(K, T)) andalso maps:get(K, T) > 0)] of
        [K | _] ->
            {error, {bad_ha_timing, K, maps:get(K, T), "must be a positive integer (ms)"}};
        [] when Lease + Hb > Suspect ->
            {error, {bad_ha_timing, suspect_ms, Suspect,
                     lists:flatten(io_lib:format("must be at least lease_ms + heartbeat_ms "
                                                 "(~b + ~b)", [Lease, Hb]))}};
        [] ->
            ok
    end.

%% ---------------------------------------------------------------------------
%% Votes: one promise per pairing and epoch on every node
%% ---------------------------------------------------------------------------

%% @doc How many nodes must grant a vote or accept a registration: a strict
%% majority of the configured nodes; 1 in a cluster of 2 or 1, where the
%% availability rule holds (a node decides alone, docs/architecture.md).
-spec quorum_size(pos_integer()) -> pos_integer().
quorum_size(Size) when Size =< 2 -> 1;
quorum_size(Size) -> Size div 2 + 1.

%% @doc A voter's record of a pairing it has heard nothing about.
-spec new_record() -> record().
new_record() -> #{promised => 0, holder => undefined, conf => {0, 0}}.

%% @doc Whether a voter grants candidate `Cand' the pairing at epoch `Ec',
%% the candidate holding claim `Claim'. `Blocked' is whether another
%% instance this voter knows as serving (its holder, or the active the
%% candidate followed, unless the candidate saw that process die) is still
%% heard: while it is, nobody else gets the pairing (the lease). A claim
%% older than the highest this voter saw is stale for good: a newer
%% configuration has released what that candidate lacks. One promise per
%% epoch: an epoch at or below the promised one goes only to the instance
%% it was promised to.
-spec vote(record(), pos_integer(), pid(), claim(), Blocked :: boolean()) ->
          {granted, record()} | {refused, refusal()}.
vote(#{conf := Conf}, _Ec, _Cand, Claim, _Blocked) when Claim < Conf ->
    {refused, stale_claim};
vote(#{promised := P, holder := H}, Ec, Cand, _Claim, _Blocked)
  when Ec < P; Ec =:= P, H =/= Cand ->
    {refused, {promised, P}};
vote(_Record, _Ec, _Cand, _Claim, true) ->
    {refused, holder_live};
vote(#{conf := Conf} = R, Ec, Cand, Claim, false) ->
    {granted, R#{promised := Ec, holder := Cand, conf := max(Conf, Claim)}}.

%% @doc Whether a voter accepts the active `From''s new configuration
%% `{E, Seq}' (the standby dropped, or a takeover confirmed): not when it
%% promised a later epoch to someone else, nor when it saw a newer claim.
-spec register(record(), pos_integer(), non_neg_integer(), pid()) ->
          {ok, record()} | {refused, refusal()}.
register(#{promised := P}, E, _Seq, _From) when E < P ->
    {refused, {promised, P}};
register(#{conf := Conf}, E, Seq, _From) when {E, Seq} < Conf ->
    {refused, stale_claim};
register(R, E, Seq, From) ->
    {ok, R#{promised := E, holder := From, conf := {E, Seq}}}.

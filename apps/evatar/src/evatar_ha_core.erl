%% @doc Internal. The quorum side of high availability, pure: an
%% instance's configuration (its claim), its elections and registrations,
%% and the leaf decisions every node takes about them (a vote, a
%% registration), about fencing, pauses and two instances that meet.
%% {@link handle/3} maps an event and a snapshot of what the instance is and
%% sees ({@link ctx()}) to the new state and a list of effects, in the
%% manner of `evatar_pairing_logic'. `evatar_ha_instance' calls it and
%% turns its decisions (won, lost, registered, fence) into the instance's
%% effects, which `evatar_pairing' executes (sends the votes, arms
%% the timers, takes over, fences); `evatar_cluster' answers votes and
%% registrations with {@link vote/5} and {@link register/4}.
%%
%% ```
%%          elect                      won (a majority granted)
%%  idle ---------> electing ------------------------------------> registering
%%   ^   <---------    |  ^ refused {promised, P}: again above P      |    |
%%   |  heard active   |  +-------------------                        |    |
%%   |                 | refused stale_claim: lost                    |    |
%%   |                                                                |    |
%%   +------------- registered (a majority accepted) <----------------+    |
%%                  refused by too many: the active fences  <--------------+
%%                  refused {promised, P} (an active, not after a pause):
%%                    it stands for election itself above P (reelect)
%%                  neither, in 2 x suspect_ms: the active fences
%% '''
%% A claim `{Epoch, Seq}' names a configuration: the active makes a new one
%% each time its standby changes and gives it to the new standby with the
%% snapshot; a takeover at epoch E starts at `{E, 1}'. While a registration
%% runs (after a takeover, after the standby's node was lost, after a pause)
%% the instance holds every effect seen outside (`holding/1',
%% `evatar_ha_commit'). Nothing here holds a process, a timer or a clock:
%% instances are any term (pids in the node, names in the model).
-module(evatar_ha_core).

-export([new/0, handle/3, claim/1, holding/1, electing/1, registering/1, restoring/1]).
-export([next_claim/1, quorum_size/1, new_record/0, answer/2, vote/5, register/4, blockers/4,
         restore_vote/4, restore_blockers/5,
         must_fence/3, reconcile/2, after_pause/2]).

-export_type([state/0, ctx/0, event/0, effect/0, claim/0, record/0, refusal/0,
              instance/0, verdict/0, pause_action/0, role/0, voter_request/0, voter_effect/0]).

-type claim() :: {non_neg_integer(), non_neg_integer()}.
%% What one node (a voter) remembers of one pairing: the highest epoch it
%% promised (voted for, or saw registered), the instance it promised it to
%% (the holder), and the highest claim it saw.
%% `registered' says whether the holder recorded a configuration (it is an
%% active that may serve) or was only promised an epoch (a candidate).
-type record() :: #{promised := non_neg_integer(), holder := term(), conf := claim(),
                    registered => boolean()}.
%% What a voter is asked (`Blocked': whether an instance that holds the
%% pairing's lease is still heard, {@link blockers/4}), and what it does:
%% `{persist, Record}', write the new record where a crash of the node
%% does not erase it, then `{reply, Answer}'.
-type voter_request() :: {vote, Ec :: pos_integer(), Cand :: term(), claim(), Blocked :: boolean()}
                       | {restore_vote, Ec :: pos_integer(), Cand :: term(), Blocked :: boolean()}
                       | {register, E :: pos_integer(), Seq :: non_neg_integer(), From :: term()}.
-type voter_effect() :: {persist, record()} | {reply, granted | ok | {refused, refusal()}}.
-type refusal() :: stale_claim | {promised, non_neg_integer()} | holder_live.
-type role() :: starting | active | standby | fenced | handing_over.

%% What the instance is and sees when an event comes: the configured
%% nodes (a snapshot of evatar_cluster's view), the heartbeat, the epoch of
%% its pairing state, and its role; `suspect_ms' (default 5 heartbeats, the
%% release's ratio) bounds a registration; `self', the instance's own node,
%% decides a registration in a cluster of two.
-type ctx() :: #{nodes := [node()], heartbeat_ms := pos_integer(),
                 epoch := non_neg_integer(), role := role(), suspect_ms => pos_integer(),
                 self => node(), keep_standby => boolean()}.

%% `{elect, {restore, NoneOn}, _}': a pairing restored afresh (no
%% instance was found; `NoneOn' are the nodes that said they run none)
%% stands for election before it serves, as a takeover does.
-type event() :: {elect, Why :: term(), ActiveDead :: boolean()}
               | {handover_asked}
               | {timeout, election | register | deadline}
               | {vote_reply, Ec :: pos_integer(), node(), granted | {refused, refusal()}}
               | {register_reply, claim(), node(), ok | {refused, refusal()}}
               | standby_node_lost
               | standby_claimed
               | paused
               | active_heard
               | {runs_none, node()}
               | {claim, claim()}.

%% `{vote, Node, Ec, Claim, ActiveDead}': ask Node for the pairing at Ec;
%% `{register, Node, Claim}': ask Node to record this active's
%% configuration; `{timer, Key, Ms}': (re)arm the one timer of that key,
%% which comes back as `{timeout, Key}'. The last three end an election or
%% a registration and come last in a list.
-type effect() :: {vote, node(), pos_integer(), claim(), boolean()}
                | {restore_vote, node(), pos_integer(), [node()]}
                | {register, node(), claim()}
                | {timer, election | register | deadline, non_neg_integer()}
                | {pause, pause_action()}
                | {won, Why :: term(), Epoch :: pos_integer()}
                | {lost, refusal()}
                | registered
                | {fence, refusal() | registration_timeout}.

-type election() :: #{epoch := non_neg_integer(), granted := [node()], replied := [node()],
                      dead := boolean(), why := term(), attempt := non_neg_integer(),
                      none_on => [node()]}.
%% pause: a reconfirmation after a pause of this node, where a refusal for
%% a promise means a standby may have won (the active fences).
-type registration() :: #{claim := claim(), ok := [node()], no := [node()],
                          pause => boolean()}.

-record(core, {conf = {1, 0} :: claim(),
               %% The highest promise seen in refusals.
               promised = 0 :: non_neg_integer(),
               election :: undefined | election(),
               reg :: undefined | registration(),
               hold = false :: boolean()}).
-opaque state() :: #core{}.

-type instance() :: #{role := active | standby | fenced | starting,
                      epoch := non_neg_integer(),
                      node := node(),
                      pid := term(),
                      peer => term()}.
-type verdict() :: keep | step_down | stop.
-type pause_action() :: keep | reconfirm | await.

%% @doc An instance with the first configuration of a new pairing.
-spec new() -> state().
new() -> #core{}.

%% @doc The configuration this instance holds.
-spec claim(state()) -> claim().
claim(#core{conf = C}) -> C.

%% @doc Whether effects seen outside wait for a registration.
-spec holding(state()) -> boolean().
holding(#core{hold = H}) -> H.

%% @doc Whether an election runs.
-spec electing(state()) -> boolean().
electing(#core{election = E}) -> E =/= undefined.

%% @doc Whether a restore's election runs.
-spec restoring(state()) -> boolean().
restoring(#core{election = E}) -> is_map(E) andalso is_map_key(none_on, E).

%% @doc Whether a registration runs.
-spec registering(state()) -> boolean().
registering(#core{reg = R}) -> R =/= undefined.

%% @doc The active takes a new standby: the configuration with it, which
%% goes to the standby with its snapshot.
-spec next_claim(state()) -> {claim(), state()}.
next_claim(#core{conf = {E, Seq}} = C) ->
    Claim = {E, Seq + 1},
    {Claim, C#core{conf = Claim}}.

%% @doc One event. See {@link event()} and {@link effect()}.
-spec handle(event(), ctx(), state()) -> {state(), [effect()]}.
handle({elect, Why, true}, Ctx, #core{election = #{dead := false} = El} = C) ->
    %% Running since the active went silent, and now it is known dead (its
    %% node came back without it): its lease no longer counts on any node,
    %% so ask again at once. Else a node heard again would keep refusing
    %% `holder_live' for a process that no longer exists.
    elect(Ctx, C#core{election = El#{dead := true, why := Why}});
handle({elect, _Why, _Dead}, _Ctx, #core{election = #{}} = C) ->
    {C, []};
handle({elect, {restore, NoneOn}, _Dead}, Ctx, C) ->
    elect(Ctx, C#core{election = (fresh(restore, true))#{none_on => NoneOn}});
handle({elect, Why, Dead}, Ctx, C) ->
    elect(Ctx, C#core{election = fresh(Why, Dead)});
handle({handover_asked}, Ctx, C) ->
    %% The active gives the pairing up: an election in which its lease
    %% does not count.
    elect(Ctx, C#core{election = fresh(handover, true)});
handle({timeout, election}, #{role := R} = Ctx, #core{election = #{}} = C)
  when R =:= standby; R =:= fenced; R =:= active ->
    elect(Ctx, C);
handle({timeout, register}, #{role := R} = Ctx,
       #core{reg = #{claim := Claim}, election = undefined} = C)
  when R =/= fenced ->
    send_register(Claim, Ctx, C);
handle({timeout, deadline}, #{role := active}, #core{hold = true} = C) ->
    %% Neither accepted nor refused by a majority, nor settled by its own
    %% election, while this node hears a majority (else the lease fenced
    %% it first): the pairing says so and fences; its election goes on.
    {C#core{reg = undefined}, [{fence, registration_timeout}]};
handle({timeout, _}, _Ctx, C) ->
    {C, []};
handle({vote_reply, Ec, Node, Result}, #{role := R} = Ctx,
       #core{election = #{epoch := Ec, granted := G, replied := Rep} = El} = C)
  when R =:= standby; R =:= fenced; R =:= active ->
    El1 = El#{replied := lists:usort([Node | Rep])},
    case Result of
        granted ->
            G1 = lists:usort([Node | G]),
            case length(G1) >= quorum(Ctx) of
                true -> won(El1, Ctx, C);
                false -> {C#core{election = El1#{granted := G1}}, []}
            end;
        {refused, stale_claim} ->
            %% A newer configuration released what this instance lacks.
            {C#core{election = undefined}, [{lost, stale_claim}]};
        {refused, {promised, P}} ->
            %% Promised to another candidate: ask again above it, soon.
            {C#core{election = El1, promised = max(P, C#core.promised)},
             [{timer, election, 5}]};
        {refused, holder_live} ->
            {C#core{election = El1}, []}
    end;
handle({vote_reply, _, _, _}, _Ctx, C) ->
    {C, []};
handle({register_reply, {E, _} = Claim, Node, ok}, Ctx,
       #core{reg = #{claim := Claim, ok := Ok} = Reg, promised = P} = C) ->
    Ok1 = lists:usort([Node | Ok]),
    case accepted(Ok1, Ctx) of
        true when P > E, map_get(role, Ctx) =:= active ->
            %% Accepted at epoch E (the claim's: the epoch this
            %% configuration is registered at), but a node refused it for
            %% a promise of a later epoch P. Majorities share a node, so
            %% nobody released anything at P, unless that node was
            %% restarted since and forgot (votes live in memory): an
            %% instance that won P may have served clients and crashed,
            %% and clients that saw P refuse a lower epoch. Stand for an
            %% epoch above P first, holding what is held; the registration
            %% stays, so no standby is taken meanwhile (a stale promise
            %% costs one more round).
            handle({elect, reelect, false}, Ctx, C#core{reg = Reg#{ok := Ok1}});
        true ->
            %% Accepted: a re-election begun because one node refused it
            %% (a stale promise) is moot. Left running, it could be won
            %% after a standby was placed with this claim, and move the
            %% configuration above the claim that standby holds: its
            %% election would be refused stale_claim for good, and what it
            %% confirmed lost.
            {C#core{reg = undefined, hold = false, election = end_reelect(C#core.election)},
             [registered]};
        false -> {C#core{reg = Reg#{ok := Ok1}}, []}
    end;
handle({register_reply, Claim, Node, {refused, {promised, P}}}, #{role := active} = Ctx,
       #core{reg = #{claim := Claim}} = C)
  when is_map_key(self, Ctx), map_get(self, Ctx) =:= Node, length(map_get(nodes, Ctx)) =< 2 ->
    %% A cluster of two decides alone (availability), by this
    %% node's own voter: it promised a later epoch P to the other
    %% node's instance, which took the pairing over and served
    %% clients at P while this one was paused (or cut off). If that
    %% instance is gone again (and its node, restarted, accepts
    %% anything), clients that saw P would refuse this lower epoch:
    %% stand for one above P, holding what is held. A voter still
    %% hearing that instance refuses (holder_live), and the two
    %% instances reconcile (the lower epoch steps down).
    handle({elect, reelect, false}, Ctx, C#core{promised = max(P, C#core.promised)});
handle({register_reply, Claim, _Node, {refused, {promised, P}}}, #{role := active} = Ctx,
       #core{reg = #{claim := Claim} = Reg} = C) when not is_map_key(pause, Reg) ->
    %% A node promised a later epoch to another instance: a standby cut off
    %% with it in an earlier partition, whose promise outlived the heal, or
    %% one that won since. Raft's answer, without dropping the clients:
    %% this active, which holds the newest claim, stands for an epoch above
    %% that promise under the rules of every election (docs/ha-design.md
    %% section 5): a winner still heard, or its newer claim, makes the
    %% voters refuse it; else it wins and the stale promise is gone. The
    %% registration stays (effects held, no standby taken) until then.
    handle({elect, reelect, false}, Ctx, C#core{promised = max(P, C#core.promised)});
handle({register_reply, Claim, Node, {refused, Why}}, Ctx, #core{reg = #{claim := Claim}} = C) ->
    refused(Node, Why, Ctx, C);
handle({register_reply, _, _, _}, _Ctx, C) ->
    {C, []};
handle(standby_node_lost, #{heartbeat_ms := Hb} = Ctx, #core{conf = {E, Seq}} = C) ->
    %% The standby may be taking over (a partition looks the same): the
    %% cluster must accept a configuration without it first, a heartbeat
    %% later (by then a partition that cuts this node off entirely has
    %% fenced it, and it registers nothing).
    Claim = {E, Seq + 1},
    {C#core{conf = Claim, hold = true, reg = #{claim => Claim, ok => [], no => []}},
     [{timer, register, Hb}, deadline(Ctx)]};
handle(paused, #{nodes := Nodes} = Ctx, #core{conf = Claim, reg = Reg, hold = Hold} = C) ->
    %% Held with no registration sent: a fenced active that won again waits
    %% for its standby to hold the claim; registering it now could leave
    %% that standby stale. Its registration settles it (await).
    case after_pause(length(Nodes), Reg =/= undefined orelse Hold) of
        reconfirm ->
            {#core{reg = R1} = C1, Effects} = send_register(Claim, Ctx, C),
            {C1#core{reg = R1#{pause => true}}, [{pause, reconfirm} | Effects]};
        Action ->
            {C, [{pause, Action}]}
    end;
handle({runs_none, Node}, Ctx, #core{election = #{none_on := NoneOn} = El} = C) ->
    %% A restore's election: a node heard again runs no instance either, so
    %% a holder recorded there (an earlier incarnation's) no longer counts.
    case lists:member(Node, NoneOn) of
        true -> {C, []};
        false -> elect(Ctx, C#core{election = El#{none_on := lists:usort([Node | NoneOn])}})
    end;
handle({runs_none, _}, _Ctx, C) ->
    {C, []};
handle(active_heard, _Ctx, C) ->
    {C#core{election = undefined}, []};
handle(standby_claimed, #{role := active} = Ctx,
       #core{hold = true, reg = undefined, election = undefined, conf = Claim} = C) ->
    %% A fenced active that won again kept its standby: that one confirmed
    %% the snapshot with the new claim, so the cluster may record it now.
    send_register(Claim, Ctx, C);
handle(standby_claimed, _Ctx, C) ->
    {C, []};
handle({claim, Claim}, _Ctx, C) ->
    %% A standby's claim from its snapshot, or the old active's after a
    %% handover: no election, no registration of its own.
    {C#core{conf = Claim, election = undefined, reg = undefined, hold = false}, []}.

%% ---------------------------------------------------------------------------

%% Whether the nodes that accepted a registration are enough: a strict
%% majority; in a cluster of two (quorum 1), this node's own voter when the
%% context names this node (`self'), which always answers and remembers
%% what the other node was promised.
accepted(Ok, #{self := Self} = Ctx) ->
    case quorum(Ctx) of
        1 -> lists:member(Self, Ok);
        Q -> length(Ok) >= Q
    end;
accepted(Ok, Ctx) ->
    length(Ok) >= quorum(Ctx).

refused(Node, Why, #{nodes := Nodes} = Ctx, #core{reg = #{no := No} = Reg} = C0) ->
    C = case Why of
            {promised, P} -> C0#core{promised = max(P, C0#core.promised)};
            _ -> C0
        end,
    No1 = lists:usort([Node | No]),
    Decisive = case Ctx of
                   #{self := Node} -> quorum(Ctx) =:= 1;
                   #{} -> false
               end,
    case Decisive orelse length(Nodes) - length(No1) < quorum(Ctx) of
        true ->
            %% Too many nodes promised the pairing to another instance, or
            %% saw a newer configuration: this one cannot go on serving.
            {C#core{reg = undefined}, [{fence, Why}]};
        false ->
            {C#core{reg = Reg#{no := No1}}, []}
    end.

end_reelect(#{why := reelect}) -> undefined;
end_reelect(El) -> El.

fresh(Why, Dead) ->
    #{epoch => 0, granted => [], replied => [], dead => Dead, why => Why, attempt => 0}.

%% (Re)sends the vote requests at an epoch above any promise seen: the same
%% epoch again (a node grants its promise to the same candidate twice),
%% unless a refusal showed a higher promise. Quick retries at first (a node
%% may not have seen a killed node's connection close yet), then once per
%% heartbeat.
elect(#{nodes := Nodes, heartbeat_ms := Hb, epoch := Epoch},
      #core{election = #{dead := Dead, attempt := N} = El, conf = Claim} = C) ->
    Ec = max(maps:get(epoch, El), max(Epoch, C#core.promised) + 1),
    Votes = case El of
                #{none_on := NoneOn} -> [{restore_vote, Node, Ec, NoneOn} || Node <- Nodes];
                #{} -> [{vote, Node, Ec, Claim, Dead} || Node <- Nodes]
            end,
    {C#core{election = El#{epoch := Ec, granted := [], replied := [], attempt := N + 1}},
     Votes ++ [{timer, election, min(Hb, 10 bsl min(N, 6))}]}.

%% Won: the configuration {Ec, 1}, which no other instance's claim can
%% reach. After a handover the old active becomes the standby at once;
%% otherwise everything is held until a majority recorded it.
won(#{epoch := Ec, why := handover}, #{nodes := Nodes}, C) ->
    %% Recorded on every node, but the old active, in sync, is the standby
    %% at once: nothing waits for the answers (the process gives this
    %% instance its claim once the takeover is applied, which ends the hold).
    {C#core{election = undefined, conf = {Ec, 1}, reg = undefined, hold = true},
     [{register, N, {Ec, 1}} || N <- Nodes] ++ [{won, handover, Ec}]};
won(#{epoch := Ec, why := reelect}, #{role := active, keep_standby := true} = Ctx, C) ->
    %% Re-elected with a standby: as after a fence, the standby gets the
    %% claim {Ec, 1} first and the registration waits for it.
    {C#core{election = undefined, conf = {Ec, 1}, reg = undefined, hold = true},
     [deadline(Ctx), {won, reelect, Ec}]};
won(#{epoch := Ec, why := reelect}, #{role := active} = Ctx, C) ->
    %% Still serving: the clients stay; the new epoch is registered like a
    %% takeover's, and effects are released once a majority accepted it.
    {C1, Effects} = send_register({Ec, 1}, Ctx, C#core{election = undefined, conf = {Ec, 1},
                                                       reg = undefined}),
    {C1, Effects ++ [{won, reelect, Ec}]};
won(#{epoch := Ec, why := fenced}, #{keep_standby := true} = Ctx, C) ->
    %% A fenced active wins again with its standby in sync (it holds what
    %% was released): it keeps that standby, which gets the claim {Ec, 1}
    %% with a snapshot first; the registration waits for its confirmation
    %% (`standby_claimed'), so no majority records a configuration the
    %% standby lacks (docs/ha-design.md section 5). Held until registered, or
    %% fenced at the deadline.
    {C#core{election = undefined, conf = {Ec, 1}, reg = undefined, hold = true},
     [deadline(Ctx), {won, keep_standby, Ec}]};
won(#{epoch := Ec, why := Why}, Ctx, C) ->
    {C1, Effects} = send_register({Ec, 1}, Ctx, C#core{election = undefined, conf = {Ec, 1},
                                                       reg = undefined}),
    {C1, Effects ++ [{won, Why, Ec}]}.

%% Asks every node that has not accepted it yet to record `Claim'; a new
%% claim's registration gets its deadline.
send_register({E, Seq} = Claim, #{nodes := Nodes, heartbeat_ms := Hb} = Ctx, C) ->
    {Done, Deadline, Kept} = case C#core.reg of
                                 #{claim := Claim, ok := Ok} = R -> {Ok, [], maps:with([pause], R)};
                                 _ -> {[], [deadline(Ctx)], #{}}
                             end,
    {C#core{hold = true, reg = Kept#{claim => {E, Seq}, ok => Done, no => []}},
     [{register, N, Claim} || N <- Nodes, not lists:member(N, Done)]
     ++ Deadline ++ [{timer, register, 2 * Hb + 50}]}.

%% A registration settles within 2 x suspect_ms, or the active fences.
deadline(#{heartbeat_ms := Hb} = Ctx) ->
    {timer, deadline, 2 * maps:get(suspect_ms, Ctx, 5 * Hb)}.

quorum(#{nodes := Nodes}) -> quorum_size(length(Nodes)).

%% ---------------------------------------------------------------------------
%% Leaf decisions
%% ---------------------------------------------------------------------------

%% @doc How many nodes must grant a vote or accept a registration: a strict
%% majority of the configured nodes; 1 in a cluster of 2 or 1, where the
%% availability rule holds (a node decides alone, docs/ha-design.md
%% section 8).
-spec quorum_size(pos_integer()) -> pos_integer().
quorum_size(Size) when Size =< 2 -> 1;
quorum_size(Size) -> Size div 2 + 1.

%% @doc A voter's record of a pairing it has heard nothing about.
-spec new_record() -> record().
new_record() -> #{promised => 0, holder => undefined, conf => {0, 0}, registered => false}.

%% @doc A voter's answer to a vote or a registration, as effects in
%% order. A promise outlives a crash of its node (docs/ha.md section 6):
%% the `persist' of a changed record comes before the reply, which goes out
%% only once the record is durable; a voter that cannot write it sends
%% nothing, so it grants nothing. A grant that changes nothing (a
%% candidate's retry) writes nothing.
-spec answer(voter_request(), record()) -> [voter_effect()].
answer({vote, Ec, Cand, Claim, Blocked}, Record) ->
    case vote(Record, Ec, Cand, Claim, Blocked) of
        {granted, R1} -> [{persist, R1} || R1 =/= Record] ++ [{reply, granted}];
        Refused -> [{reply, Refused}]
    end;
answer({restore_vote, Ec, Cand, Blocked}, Record) ->
    case restore_vote(Record, Ec, Cand, Blocked) of
        {granted, R1} -> [{persist, R1} || R1 =/= Record] ++ [{reply, granted}];
        Refused -> [{reply, Refused}]
    end;
answer({register, E, Seq, From}, Record) ->
    case register(Record, E, Seq, From) of
        {ok, R1} -> [{persist, R1} || R1 =/= Record] ++ [{reply, ok}];
        Refused -> [{reply, Refused}]
    end.

%% @doc Whether a voter grants candidate `Cand' the pairing at epoch `Ec',
%% the candidate holding claim `Claim'. `Blocked' is whether another
%% instance this voter knows as serving (its holder, or the active the
%% candidate followed, unless the candidate saw that process die) is still
%% heard: while it is, nobody else gets the pairing (the lease). A claim
%% older than the highest this voter saw is stale for good: a newer
%% configuration has released what that candidate lacks. One promise per
%% epoch: an epoch at or below the promised one goes only to the instance
%% it was promised to.
-spec vote(record(), pos_integer(), term(), claim(), Blocked :: boolean()) ->
          {granted, record()} | {refused, refusal()}.
vote(#{conf := Conf}, _Ec, _Cand, Claim, _Blocked) when Claim < Conf ->
    {refused, stale_claim};
vote(#{promised := P, holder := H}, Ec, Cand, _Claim, _Blocked)
  when Ec < P; Ec =:= P, H =/= Cand ->
    {refused, {promised, P}};
vote(_Record, _Ec, _Cand, _Claim, true) ->
    {refused, holder_live};
vote(#{conf := Conf} = R, Ec, Cand, Claim, false) ->
    {granted, R#{promised := Ec, holder := Cand, conf := max(Conf, Claim), registered => false}}.

%% @doc Whether a voter grants a restored instance `Cand' the pairing at
%% `Ec': a pairing that no node was found to run, started afresh by the
%% catalogue. Its state is new, so a newer configuration this voter saw
%% (one whose instances are all gone) does not make it stale; one promise
%% per epoch, and the lease (`Blocked', {@link restore_blockers/5}), hold
%% as for any candidate. Its configuration is recorded when it registers.
-spec restore_vote(record(), pos_integer(), term(), Blocked :: boolean()) ->
          {granted, record()} | {refused, refusal()}.
restore_vote(#{promised := P, holder := H}, Ec, Cand, _Blocked)
  when Ec < P; Ec =:= P, H =/= Cand ->
    {refused, {promised, P}};
restore_vote(_Record, _Ec, _Cand, true) ->
    {refused, holder_live};
restore_vote(R, Ec, Cand, false) ->
    {granted, R#{promised := Ec, holder := Cand, registered => false}}.

%% @doc The instances that block a restore vote for `Cand' while the voter
%% sees them serve: an instance of the pairing on the voter's own node
%% (`Local', with its role: an active or a standby, whether or not it ever
%% registered, since a new pairing's never did, or one starting, which may
%% be about to become a standby; not a fenced one, such as another
%% restorer: two restorers would otherwise refuse each other for ever),
%% and the holder, if
%% it recorded a configuration and its node (`NodeOf') is not one the
%% restorer heard say it runs no instance of the pairing (`NoneOn': a
%% holder there is dead, e.g. one of a node's earlier incarnation, read
%% back from disc).
-spec restore_blockers(record(), term(), [node()], fun((term()) -> node() | undefined),
                       Local :: {term(), atom()} | undefined) -> [term()].
restore_blockers(Record, Cand, NoneOn, NodeOf, Local) ->
    [P || {P, Role} <- [Local], P =/= Cand,
          lists:member(Role, [starting, active, handing_over, standby])]
    ++ [H || H <- blockers(Record, Cand, undefined, false), not lists:member(NodeOf(H), NoneOn)].

%% @doc Whether a voter accepts the active `From''s new configuration
%% `{E, Seq}' (the standby dropped, or a takeover confirmed): not when it
%% promised a later epoch to someone else, nor when it saw a newer claim.
-spec register(record(), pos_integer(), non_neg_integer(), term()) ->
          {ok, record()} | {refused, refusal()}.
register(#{promised := P}, E, _Seq, _From) when E < P ->
    {refused, {promised, P}};
register(#{conf := Conf}, E, Seq, _From) when {E, Seq} < Conf ->
    {refused, stale_claim};
register(R, E, Seq, From) ->
    {ok, R#{promised := E, holder := From, conf := {E, Seq}, registered => true}}.

%% @doc The instances whose lease blocks a vote for `Cand' while the voter
%% hears them (the caller decides who it hears): the holder if it recorded
%% a configuration (an active; a candidate that was only promised an epoch
%% serves nothing, and a promise to a standby that gave its election up
%% must not block the pairing for ever), and the active the candidate
%% followed, unless it saw that process die.
-spec blockers(record(), term(), term(), ActiveDead :: boolean()) -> [term()].
blockers(Record, Cand, Active, Dead) ->
    Holder = [maps:get(holder, Record) || maps:get(registered, Record, true)],
    [P || P <- lists:usort(Holder ++ [Active]), P =/= undefined, P =/= Cand,
          not (Dead andalso P =:= Active)].

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

%% @doc What an active does when its node finds it was paused itself
%% (SIGSTOP, a laptop lid, a long GC or a load spike), rather than that its
%% peers went silent. It never fences for the pause alone (docs/ha.md
%% section 6):
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

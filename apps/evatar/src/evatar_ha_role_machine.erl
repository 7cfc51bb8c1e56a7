%% @doc Internal. The role machine's decisions that need no quorum, pure:
%% how an instance starts (active at once, the standby of the active it
%% was given, or ask the peers first and choose from their answers), what
%% it does about another instance of its pairing ({@link meet/2}), how a
%% standby applies the active's events, and when a resume held by a
%% standby is answered NotActive. Like `evatar_ha_core' it holds no
%% process, timer or clock. `evatar_ha_instance' calls start/4, starting/3
%% and meet/2 and turns their results into its effects, and applies a
%% standby's events with apply_events/4; `evatar_pairing' calls held_due/3
%% (docs/ha-design.md, sections 7 and 12).
%%
%% ```
%%  start/4 --> become_active                   a new pairing
%%          --> {offer, Active}                 (then a snapshot, or stop)
%%          --> {ask, Peers} + {timer, asked}   a restore or a restart: every
%%                 |                            answer, or the timer, decides
%%                 |                            (starting/3):
%%                 +--> an active or fenced one found: {offer, Active}
%%                 +--> only standbys (taking over), or a peer silent:
%%                 |    {timer, retry_ask}, ask the alive peers again
%%                 +--> nobody: {restore, NoneOn}, an election before serving
%% '''
-module(evatar_ha_role_machine).

-export([start/4, starting/3]).
-export([apply_events/4]).
-export([held_due/3, held_poll_ms/1]).
-export([meet/2, runs_none/1]).

-export_type([starting/0, start_event/0, start_effect/0, held/1, held_ctx/0, meeting/0]).

%% The peers asked and their answers so far.
-opaque starting() :: #{asks := non_neg_integer(),
                        answers := [{node(), evatar_ha_proto_v1:instance_info()}]}.
-type start_event() :: {instance, node(), evatar_ha_proto_v1:instance_info()}
                     | {timeout, asked}
                     | {timeout, retry_ask, Peers :: [node()]}.
%% `{ask, Peers}': ask each peer what it runs of the pairing (answers come
%% as `{instance, ..}'); `{timer, Key, Ms}': (re)arm that timer, which
%% comes back as `{timeout, Key}'; `{offer, Active}': offer to be the
%% standby of `Active'; `become_active': start as the pairing's active.
%% `{restore, NoneOn}': start afresh, but serve only once elected (the
%% nodes in `NoneOn' said they run no instance of the pairing).
-type start_effect() :: become_active
                      | {restore, [node()]}
                      | {offer, pid()}
                      | {ask, [node()]}
                      | {timer, asked | retry_ask, non_neg_integer()}
                      | {log, notice, map()}.

%% What an instance does about another instance of its pairing: nothing,
%% tell the other it is stale (this active's epoch is higher), step down
%% (close its clients and go) or stop.
-type meeting() :: keep | tell_stale | step_down | stop.

%% A resume held by a standby: who asked, what, and since when
%% (monotonic milliseconds).
-type held(From) :: {From, term(), integer()}.
%% `electing': an election runs (or the active was lost); `heard_after':
%% whether the active's node was heard after a time (false without one).
-type held_ctx() :: #{suspect_ms := pos_integer(), heartbeat_ms := pos_integer(),
                      electing := boolean(), heard_after := fun((integer()) -> boolean())}.

%% ---------------------------------------------------------------------------
%% Starting
%% ---------------------------------------------------------------------------

%% @doc How an instance starts: its mode (`restore': the catalogue found
%% no instance of the pairing), what the registry remembers of an earlier
%% instance on this node (`none' for a new pairing) and the alive peers. A
%% new pairing is active at once; a restore, or a restart, asks the peers
%% first, and one that finds nobody (or has nobody to ask) stands for
%% election before it serves: two nodes whose views differ may both
%% restore a pairing, and one epoch is granted to one of them only.
-spec start(create | restore | {standby_for, pid()}, Previous :: term(), [node()],
            SuspectMs :: pos_integer()) -> {starting(), [start_effect()]}.
start(create, none, _Peers, _SuspectMs) ->
    {new_starting(), [become_active]};
start({standby_for, Active}, none, _Peers, _SuspectMs) ->
    {new_starting(), [{offer, Active}]};
start(_Mode, _Previous, [], _SuspectMs) ->
    {new_starting(), [{restore, []}]};
start(_Mode, Previous, Peers, SuspectMs) ->
    {S, Effects} = ask(Peers, SuspectMs, new_starting()),
    {S, [{log, notice, #{what => pairing_restarted, previous => Previous}}
         || Previous =/= none] ++ Effects}.

%% @doc An answer of a peer, or a timer. A restarted instance: an active
%% (or fenced one) elsewhere takes it as its standby; a standby elsewhere
%% is about to take over (ask again); nobody: start afresh.
-spec starting(start_event(), SuspectMs :: pos_integer(), starting()) ->
          {starting(), [start_effect()]}.
starting({instance, Node, Info}, SuspectMs, #{asks := N, answers := Answers} = S) ->
    S1 = S#{answers := [{Node, Info} | Answers]},
    case length(Answers) + 1 >= N of
        true -> decide(SuspectMs, S1);
        false -> {S1, []}
    end;
starting({timeout, asked}, SuspectMs, S) ->
    decide(SuspectMs, S);
starting({timeout, retry_ask, Peers}, SuspectMs, S) ->
    ask(Peers, SuspectMs, S).

new_starting() -> #{asks => 0, answers => []}.

%% @doc Whether a node's answer says it runs no instance of the pairing,
%% or one still starting (which holds no state): a holder recorded there
%% is dead.
-spec runs_none(evatar_ha_proto_v1:instance_info()) -> boolean().
runs_none(none) -> true;
runs_none(#{role := starting}) -> true;
runs_none(_Info) -> false.

ask(Peers, SuspectMs, S) ->
    {S#{asks := length(Peers), answers := []},
     [{ask, Peers}, {timer, asked, 2 * SuspectMs}]}.

decide(SuspectMs, #{asks := Asks, answers := Answers} = S) ->
    Infos = [I || {_, I} <- Answers, is_map(I)],
    case [I || #{role := R} = I <- Infos, R =:= active orelse R =:= fenced] of
        [#{pid := Active} | _] ->
            {S, [{offer, Active}]};
        [] ->
            %% A peer that has not answered may run anything (as for the
            %% catalogue): ask again, as while a standby takes over.
            Waiting = [I || #{role := standby} = I <- Infos] =/= [] orelse length(Answers) < Asks,
            case Waiting of
                true when Asks > 0 -> {S#{answers := []}, [{timer, retry_ask, SuspectMs}]};
                _ -> {S, [{restore, lists:usort([N || {N, Info} <- Answers, runs_none(Info)])}]}
            end
    end.

%% ---------------------------------------------------------------------------
%% Two instances meet
%% ---------------------------------------------------------------------------

%% @doc What this instance does about another instance of its pairing it
%% heard of ({@link evatar_ha_core:reconcile/2}); an active that keeps
%% tells a lower-epoch active or fenced one at once that it is stale.
-spec meet(evatar_ha_core:instance(), evatar_ha_core:instance()) -> meeting().
meet(#{role := MyRole, epoch := MyE} = Me, #{role := Role, epoch := E} = Other) ->
    case evatar_ha_core:reconcile(Me, Other) of
        keep when MyRole =:= active, Role =/= standby, MyE > E -> tell_stale;
        Verdict -> Verdict
    end.

%% ---------------------------------------------------------------------------
%% The standby applies the active's events
%% ---------------------------------------------------------------------------

%% @doc Applies a batch of the active's events `{Version, NowMs, Event}'
%% in order with `Apply' (the pairing's rules: deterministic, so the
%% standby's state follows the active's). An event already applied (a
%% batch sent again) is skipped; a gap stops the batch: `{resync, Mine}'
%% asks the active for a snapshot above this version. Else `{confirm, V}':
%% everything up to V is applied here.
-spec apply_events([{pos_integer(), integer(), Event}], fun((Event, integer(), L) -> L), L,
                   evatar_ha_commit:state()) ->
          {L, evatar_ha_commit:state(), {confirm | resync, non_neg_integer()}}.
apply_events([{V, Now, Event} | Rest], Apply, Logic, C) ->
    Mine = evatar_ha_commit:version(C),
    if
        V =:= Mine + 1 -> apply_events(Rest, Apply, Apply(Event, Now, Logic),
                                       evatar_ha_commit:applied(V, C));
        V =< Mine -> apply_events(Rest, Apply, Logic, C);
        true -> {Logic, C, {resync, Mine}}
    end;
apply_events([], _Apply, Logic, C) ->
    {Logic, C, {confirm, evatar_ha_commit:version(C)}}.

%% ---------------------------------------------------------------------------
%% Resumes held by a standby
%% ---------------------------------------------------------------------------

%% @doc Splits the held resumes into those answered NotActive now and
%% those kept: one goes once the active was heard after it came (the active
%% is alive: the client had another reason to leave it) unless an election
%% runs, or after suspect_ms + 2 heartbeats (at most 800 ms) without a
%% decision.
-spec held_due([held(F)], NowMs :: integer(), held_ctx()) -> {Go :: [held(F)], Keep :: [held(F)]}.
held_due(Held, Now, #{suspect_ms := Suspect, heartbeat_ms := Hb, electing := Electing,
                      heard_after := HeardAfter}) ->
    Max = min(800, Suspect + 2 * Hb),
    lists:partition(fun({_, _, Since}) ->
                            Now - Since > Max orelse (not Electing andalso HeardAfter(Since))
                    end, Held).

%% @doc How often held resumes are looked at: every half heartbeat.
-spec held_poll_ms(HeartbeatMs :: pos_integer()) -> pos_integer().
held_poll_ms(Hb) -> max(5, Hb div 2).

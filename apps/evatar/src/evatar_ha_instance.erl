%% @doc Internal. One instance of a pairing, pure: its role, the
%% pairing's rules (`evatar_pairing_logic') and the output commit
%% (`evatar_ha_commit') in one state. {@link handle/3} maps an event of
%% another instance, of the cluster, of the peer's monitor or of a timer,
%% with a snapshot of the cluster ({@link view()}), to the new state and
%% effects that are all I/O (send, monitor, timer, tell a client, log,
%% the registry), in the manner of rabbitmq/ra's `ra_server'; the client
%% traffic of an active comes through {@link rules/3}, {@link reply/3},
%% {@link report_binding/3} and {@link flush_maybe/2}. `evatar_pairing'
%% executes the effects on pids, monitors and timers, the model
%% (`evatar_ha_sim') on its simulated nodes: both run this code, rules
%% included. An instance (`me', `active', `standby') is any term: a pid in
%% the node, `{Node, Ref}' in the model; a client's connection
%% (`conns') too.
%%
%% Inside, the role machine decides first ({@link decide/3}): starting
%% (with `evatar_ha_role_machine'), the messages between instances, the
%% cluster's events and the timers, then what each outcome of
%% `evatar_ha_core' (elections, registrations) means and what only a
%% serving active does (placement, fencing, silent links, handover, the
%% rebalancer's moves); its decisions that mean "run the
%% rules or the commit" (`{logic, ..}', `{release, V}', `{flush, Mode}',
%% `{snapshot, To, Claim}', ...) are carried out here, in order, and only
%% their I/O leaves (docs/ha-design.md, section 12).
%%
%% ```
%%  starting --start/4, answers--> active | (offer) --snapshot--> standby
%%  active  --silent link, rebalancer--> handing_over --handover_done--> standby
%%          <--------------- aborted (timer) ------------
%%  active, handing_over --fence (no majority, refused)--> fenced --won again--> active
%%  standby --won (election, handover)--> active
%%  any     --lost, dismissed, newer instance met--> stop
%% '''
-module(evatar_ha_instance).

-export([new/3, handle/3, rules/3, reply/3, report_binding/3, flush_maybe/2, flush/1]).
-export([decide/3]).
-export([role/1, active/1, standby/1, core/1, mode/1, electing/1, reconfirming/1,
         logic/1, epoch/1, version/1, synced/1, silent_poll_ms/1, node_of/1]).

-export_type([state/0, role/0, view/0, ctx/0, event/0, effect/0, decision/0, peer_msg/0, node_msg/0,
              timer_key/0]).

-type role() :: starting | active | handing_over | standby | fenced.
-type peer() :: term().

%% What the caller sees when an event comes: the cluster (configured
%% nodes, alive nodes, whether it hears a majority and which nodes it heard
%% within the lease), the options, the time for the rules (`now', system
%% milliseconds), the clients' connections (`conns', entity id to
%% connection: held effects are bound to them) and how many messages wait
%% (`queue_len', 0 if absent: batches go out when none waits).
%% Confirmations and event batches need only the options, the time and
%% the connections. {@link handle/3} adds the state's epoch, version,
%% highest version confirmed by the standby and whether that one is synced
%% (what {@link decide/3} reads).
-type view() :: #{nodes := [node()], heartbeat_ms := pos_integer(),
                  suspect_ms := pos_integer(), now := integer(), conns := conns(),
                  queue_len => non_neg_integer(),
                  epoch => non_neg_integer(),
                  version => non_neg_integer(), confirmed => non_neg_integer(),
                  synced => boolean(),
                  alive => [node()], majority => boolean(), heard => [node()],
                  standby_opt => boolean(), client_ack_timeout => pos_integer(),
                  handover_on_silent_link => boolean(), self => node()}.
-type conns() :: #{binary() => term()}.
%% What a client's event needs: the time and the connections.
-type ctx() :: #{now := integer(), conns := conns(), _ => _}.
%% The role machine's timers are `{ha, Key}'; the rules' are their own keys.
-type timer_key() :: {ha, atom()} | evatar_pairing_logic:timer_key().

-type event() :: {start, evatar_pairing:mode(), Previous :: term()}
               | {instance, node(), evatar_ha_proto_v1:instance_info()}
               | {msg, tuple()}
               | {cluster, term()}
               | {down, active | standby, Why :: term()}
               | {timeout, timer_key()}
               | paused.

%% A message to another instance (evatar_ha_proto_v1 in the node).
-type peer_msg() :: {offer, non_neg_integer()} | dismiss | {resync, non_neg_integer()}
                  | {confirm, non_neg_integer()} | {stale, non_neg_integer()}
                  | {handover, non_neg_integer()}
                  | {handover_done, pos_integer(), evatar_ha_core:claim()}
                  | {events, [evatar_ha_commit:repl_event()]}
                  | {snapshot, non_neg_integer(), evatar_pairing_logic:state(),
                     evatar_ha_core:claim()}.

%% What the executor does, in order: all I/O, by what it reaches.
%% `{send, Peer, Msg}': the pairing's other instance;
%% `{to_node, Node, Msg}': a node's cluster service (its voter, its
%% standby starter, the instances it runs), for this instance;
%% `{monitor, active | standby, Peer | none}': watch that instance (none:
%% stop watching); `{to_client, Who, Msg}': a client's connection, Who
%% being an entity id (its current connection) or `{conn, Conn}' (the one
%% it had when the effect was made, one of `conns'); `{drop, Who, Code,
%% Reason}': close an entity's connection and forget it (`all': every
%% connection; the entities stay, for a resume elsewhere); timers;
%% `{reply_to, ..}'; `flush_later': call {@link flush/1} once the messages
%% waiting are handled; `{stepped, ..}': the rules ran an event (metrics
%% and the live tail watch it); `cancel_rule_timers': every timer but the
%% `{ha, _}' ones; and the process's own (shell_io()).
-type effect() :: {send, peer(), peer_msg()}
                | {to_node, node(), node_msg()}
                | {monitor, active | standby, peer() | none}
                | {timer, timer_key(), non_neg_integer()}
                | {ensure_timer, timer_key(), non_neg_integer()}
                | {cancel_timer, timer_key()} | cancel_rule_timers
                | {to_client, binary() | {conn, term()}, term()}
                | {drop, binary() | all, atom(), binary()}
                | {reply_to, term(), term()}
                | flush_later
                | {stepped, evatar_pairing_logic:event(), [evatar_pairing_logic:effect()],
                   integer()}
                | shell_io().

%% What a node's cluster service is asked for this instance
%% (evatar_ha_proto_v1 in the node): what it runs of the pairing, a
%% standby, a vote (at an election, or at a restore), to record a claim.
-type node_msg() :: ask | {start_standby, evatar_pairing_logic:config()}
                  | {vote, pos_integer(), evatar_ha_core:claim(), peer(), boolean()}
                  | {restore_vote, pos_integer(), [node()]}
                  | {register, evatar_ha_core:claim()}.

%% What the role machine decides ({@link decide/3}): I/O, and what to do
%% with the rules and the commit, which {@link handle/3} does.
-type decision() :: peer_io()
                  | {timer, atom(), non_neg_integer()} | {ensure_timer, atom(), non_neg_integer()}
                  | {cancel_timer, atom()}
                  | new_logic | {install, non_neg_integer(), term()} | {apply, [term()]}
                  | {logic, term(), evatar_ha_commit:mode()}
                  | arm_logic_timers | cancel_logic_timers
                  | {release, non_neg_integer()} | release_all | {flush, evatar_ha_commit:mode()}
                  | {flush_maybe, evatar_ha_commit:mode()}
                  | unsync | {synced_at, non_neg_integer()} | reset_commit
                  | {snapshot, peer(), evatar_ha_core:claim()}
                  | {drop, binary(), silent_link, binary()}
                  | {disconnect_all, atom(), binary()}
                  | shell_io().

%% The other instance, the cluster's nodes and the monitors.
-type peer_io() :: {send, peer(), peer_msg()}
                 | {ask, [node()]}
                 | {start_standby, node()}
                 | {vote, node(), pos_integer(), evatar_ha_core:claim(), peer(), boolean()}
                 | {restore_vote, node(), pos_integer(), [node()]}
                 | {register, node(), evatar_ha_core:claim()}
                 | {monitor, active | standby, peer()} | {demonitor, active | standby}.
%% The clients, the registry, the held calls, logs and metrics, the process.
-type shell_io() :: serving | pause_seen | publish | reconfirmed | reply_held | serve_held
                  | {metric, atom()} | {metric, atom(), term()} | {log, logger:level(), map()}
                  | postpone | {stop, term()}.

-define(PLACE_RETRY_MS, 1000).

%% The state: the role, the pairing's rules and the output commit.
-record(inst, {id :: term(),
               me :: term(),
               config :: evatar_pairing_logic:config(),
               logic :: evatar_pairing_logic:state() | undefined,
               commit = evatar_ha_commit:new(0) :: evatar_ha_commit:state(),
               role = starting :: starting | active | handing_over | standby | fenced,
               %% Standby and starting: its active; active: its standby.
               active :: term(),
               standby :: term(),
               watching = false :: boolean(),   % the active is monitored
               active_lost = false :: boolean(),
               placing = false :: boolean(),
               standby_node :: node() | undefined,
               core = evatar_ha_core:new() :: evatar_ha_core:state(),
               start :: evatar_ha_role_machine:starting() | undefined,
               reconfirming = false :: boolean(),
               %% Won again after a fence, keeping the standby: it has not
               %% yet confirmed the snapshot with the new claim.
               claiming = false :: boolean()}).

-type effects() :: [decision()].

-opaque state() :: #inst{}.

%% @doc A starting instance `Me' of pairing `Id' with the rules'
%% configuration `Config' (its `standby_node', if any, is where it prefers
%% to place its standby).
-spec new(term(), peer(), evatar_pairing_logic:config()) -> state().
new(Id, Me, Config) ->
    #inst{id = Id, me = Me, config = Config,
          standby_node = maps:get(standby_node, Config, undefined)}.

-spec role(state()) -> role().
role(#inst{role = R}) -> R.
-spec active(state()) -> peer() | undefined.
active(#inst{active = A}) -> A.
-spec standby(state()) -> peer() | undefined.
standby(#inst{standby = S}) -> S.
-spec core(state()) -> evatar_ha_core:state().
core(#inst{core = C}) -> C.
%% @doc Whether an election runs, or the standby lost its active.
-spec electing(state()) -> boolean().
electing(#inst{core = C, active_lost = L}) -> L orelse evatar_ha_core:electing(C).
%% @doc Whether inspections wait for a reconfirmation after a pause.
-spec reconfirming(state()) -> boolean().
reconfirming(#inst{reconfirming = R}) -> R.

%% @doc The rules' state (undefined while starting).
-spec logic(state()) -> evatar_pairing_logic:state() | undefined.
logic(#inst{logic = L}) -> L.
%% @doc The pairing's epoch (0 while starting).
-spec epoch(state()) -> non_neg_integer().
epoch(#inst{logic = undefined}) -> 0;
epoch(#inst{logic = L}) -> evatar_pairing_logic:epoch(L).
%% @doc The version of the last event applied.
-spec version(state()) -> non_neg_integer().
version(#inst{commit = C}) -> evatar_ha_commit:version(C).
%% @doc Whether the standby confirmed anything since its snapshot.
-spec synced(state()) -> boolean().
synced(#inst{commit = C}) -> evatar_ha_commit:synced(C).

%% ---------------------------------------------------------------------------
%% Events: the role machine decides, the rules and the commit run here
%% ---------------------------------------------------------------------------

%% @doc One event; see {@link event()} and {@link effect()}. A rules'
%% timer runs the rules on an active, waits while fenced or handing over
%% (`postpone'), and is dropped otherwise.
-spec handle(event(), view(), state()) -> {state(), [effect()]}.
handle(Event, View, S) ->
    V = full_view(View, S),
    case Event of
        {timeout, {ha, silent}} when S#inst.role =:= active ->
            Unacked = evatar_pairing_logic:unacked_since(S#inst.logic),
            carry_out(decide({silent, Unacked, now(V)}, V, S), V);
        {timeout, {ha, Key}} ->
            carry_out(decide({timeout, Key}, V, S), V);
        {timeout, Key} ->
            rule_timeout(Key, V, S);
        _ ->
            carry_out(decide(Event, V, S), V)
    end.

full_view(View, #inst{commit = C} = S) ->
    View#{epoch => epoch(S), version => evatar_ha_commit:version(C),
          confirmed => evatar_ha_commit:confirmed(C), synced => evatar_ha_commit:synced(C)}.

rule_timeout(Key, V, #inst{role = active} = S) ->
    {_Reply, S1, Out} = step({timeout, Key}, mode(S), V, S),
    {S2, Flush} = flush_maybe(queue_len(V), S1),
    {S2, Out ++ Flush};
rule_timeout(_Key, _V, #inst{role = Role} = S) when Role =:= fenced; Role =:= handing_over ->
    {S, [postpone]};
rule_timeout(_Key, _V, S) ->
    {S, []}.

%% @doc An event of an active's client (a join, a signal, an Ack, a
%% leave, a detach): the rules' reply (`ok' for events without one) and
%% what goes out now, or waits for the standby or the cluster.
-spec rules(evatar_pairing_logic:event(), ctx(), state()) -> {term(), state(), [effect()]}.
rules(Event, Ctx, S) ->
    step(Event, mode(S), Ctx, S).

%% @doc A call's reply: now without a standby, else after what is held.
-spec reply(term(), term(), state()) -> {state(), [effect()]}.
reply(From, Reply, #inst{commit = C} = S) ->
    commit(evatar_ha_commit:reply(From, Reply, mode(S), C), S).

%% @doc A GetBinding (docs/protocol.md section 2): the current report, to
%% that entity only, behind what is held. It changes no state, so it is not
%% shipped to the standby.
-spec report_binding(binary(), conns(), state()) -> {state(), [effect()]}.
report_binding(EntityId, Conns, #inst{logic = L, commit = C} = S) ->
    {_, Effects} = evatar_pairing_logic:handle({report_binding, EntityId}, 0, L),
    Sends = [{send, Conn, {bound, R}} || {report, E, R} <- Effects, {ok, Conn} <- [maps:find(E, Conns)]],
    commit(evatar_ha_commit:report(Sends, mode(S), C), S).

%% @doc The batch goes out if no message waits (`QueueLen' 0) or enough
%% events were applied; else `flush_later'.
-spec flush_maybe(non_neg_integer(), state()) -> {state(), [effect()]}.
flush_maybe(QueueLen, #inst{commit = C} = S) ->
    commit(evatar_ha_commit:flush_maybe(QueueLen, mode(S), C), S).

%% @doc The batch goes out: the events to the standby, or the Acks.
-spec flush(state()) -> {state(), [effect()]}.
flush(#inst{commit = C} = S) ->
    commit(evatar_ha_commit:flush(mode(S), C), S).

%% The role machine's decisions, in order: those about the rules and the
%% commit are carried out here, the rest is I/O already.
carry_out({S, Decisions}, V) ->
    carry_out(Decisions, V, S, []).

carry_out([D | Rest], V, S, Acc) ->
    {S1, Out} = carry_out1(D, V, S),
    carry_out(Rest, V, S1, lists:reverse(Out, Acc));
carry_out([], _V, S, Acc) ->
    {S, lists:reverse(Acc)}.

carry_out1(new_logic, _V, #inst{id = Id, config = Config} = S) ->
    {S#inst{logic = evatar_pairing_logic:new(Id, Config)}, []};
carry_out1({install, Version, Logic}, _V, #inst{commit = C} = S) ->
    {S#inst{logic = Logic, commit = evatar_ha_commit:applied(Version, C)}, []};
carry_out1({apply, Events}, _V, S) ->
    apply_events(Events, S);
carry_out1({logic, Event, Mode}, V, S) ->
    {_Reply, S1, Out} = step(Event, Mode, V, S),
    {S1, Out};
carry_out1(arm_logic_timers, V, #inst{logic = L} = S) ->
    %% A takeover: the rules' deadlines, from the state, on this node's timers.
    {S, [cancel_rule_timers | [{timer, K, Ms} || {K, Ms} <- evatar_pairing_logic:timers(L, now(V))]]};
carry_out1(cancel_logic_timers, _V, S) ->
    {S, [cancel_rule_timers]};
carry_out1({release, Version}, _V, #inst{commit = C} = S) ->
    commit(evatar_ha_commit:confirm(Version, C), S);
carry_out1(release_all, _V, #inst{commit = C} = S) ->
    commit(evatar_ha_commit:release_all(C), S);
carry_out1({flush, Mode}, _V, #inst{commit = C} = S) ->
    commit(evatar_ha_commit:flush(Mode, C), S);
carry_out1({flush_maybe, Mode}, V, #inst{commit = C} = S) ->
    commit(evatar_ha_commit:flush_maybe(queue_len(V), Mode, C), S);
carry_out1(unsync, _V, #inst{commit = C} = S) ->
    {S#inst{commit = evatar_ha_commit:unsync(C)}, []};
carry_out1({synced_at, Version}, _V, #inst{commit = C} = S) ->
    {S#inst{commit = evatar_ha_commit:synced_at(Version, C)}, []};
carry_out1(reset_commit, _V, #inst{commit = C} = S) ->
    {S#inst{commit = evatar_ha_commit:reset(C)}, []};
carry_out1({snapshot, To, Claim}, _V, #inst{logic = L, commit = C} = S) ->
    {S#inst{commit = evatar_ha_commit:shipped(C)},
     [{send, To, {snapshot, evatar_ha_commit:version(C), L, Claim}}]};
carry_out1({drop, EntityId, _Code, _Reason} = Drop, V, S) ->
    %% A silent link: its connection goes, and the entity is detached (kept
    %% for a resume), held effects bound to the connections left.
    Ctx = V#{conns := maps:remove(EntityId, conns(V))},
    {_Reply, S1, Out} = step({detach, EntityId}, mode(S), Ctx, S),
    {S1, [Drop | Out]};
carry_out1({timer, Key, Ms}, _V, S) ->
    {S, [{timer, {ha, Key}, Ms}]};
carry_out1({ensure_timer, Key, Ms}, _V, S) ->
    {S, [{ensure_timer, {ha, Key}, Ms}]};
carry_out1({cancel_timer, Key}, _V, S) ->
    {S, [{cancel_timer, {ha, Key}}]};
carry_out1({disconnect_all, Code, Reason}, _V, S) ->
    {S, [{drop, all, Code, Reason}]};
carry_out1({ask, Nodes}, _V, S) ->
    {S, [{to_node, N, ask} || N <- Nodes]};
carry_out1({start_standby, Node}, _V, #inst{config = Config, standby_node = Preferred} = S) ->
    %% The standby starts with the pairing's configuration and where its
    %% standbys go now (a rebalance may have moved it).
    Start = case Preferred of
                undefined -> Config;
                _ -> Config#{standby_node => Preferred}
            end,
    {S, [{to_node, Node, {start_standby, Start}}]};
carry_out1({vote, Node, Ec, Claim, Active, Dead}, _V, S) ->
    {S, [{to_node, Node, {vote, Ec, Claim, Active, Dead}}]};
carry_out1({restore_vote, Node, Ec, NoneOn}, _V, S) ->
    {S, [{to_node, Node, {restore_vote, Ec, NoneOn}}]};
carry_out1({register, Node, Claim}, _V, S) ->
    {S, [{to_node, Node, {register, Claim}}]};
carry_out1({demonitor, Which}, _V, S) ->
    {S, [{monitor, Which, none}]};
carry_out1(Effect, _V, S) ->
    {S, [Effect]}.

%% One event through the rules; the commit says what of their effects goes
%% out now and what waits.
step(Event, Mode, Ctx, #inst{logic = L, commit = C} = S) ->
    Now = now(Ctx),
    {L1, Effects} = evatar_pairing_logic:handle(Event, Now, L),
    {Reply, Out, C1} = evatar_ha_commit:step(Event, Now, Effects, conns(Ctx), Mode, C),
    S1 = S#inst{logic = L1, commit = C1},
    {Reply, S1, [{stepped, Event, Effects, Now} | io(Out, S1)]}.

commit({Out, C}, S) ->
    S1 = S#inst{commit = C},
    {S1, io(Out, S1)}.

%% The commit's effects, as I/O.
io(Out, S) ->
    [E || Effect <- Out, E <- io1(Effect, S)].

io1({deliver, EntityId, Signal}, _S) -> [{to_client, EntityId, {signal, Signal}}];
io1({report, EntityId, Report}, _S) -> [{to_client, EntityId, {bound, Report}}];
io1({send, Conn, Msg}, _S) -> [{to_client, {conn, Conn}, Msg}];
io1({acks, Acks}, _S) -> [{to_client, E, {ack, Sid}} || {E, Sid} <- maps:to_list(Acks)];
io1({start_timer, Key, Ms}, _S) -> [{timer, Key, Ms}];
io1({ship, Events}, #inst{standby = Sb}) -> [{send, Sb, {events, Events}} || Sb =/= undefined];
io1(Effect, _S) -> [Effect].   % drop, cancel_timer, log, reply_to, flush_later

%% The standby applies the active's batch with the rules
%% (evatar_ha_role_machine), and confirms it or asks again.
apply_events(Events, #inst{logic = L0, commit = C0, active = A} = S) ->
    Apply = fun(Event, Now, L) -> element(1, evatar_pairing_logic:handle(Event, Now, L)) end,
    {L, C, Answer} = evatar_ha_role_machine:apply_events(Events, Apply, L0, C0),
    S1 = S#inst{logic = L, commit = C},
    Publish = [publish || evatar_pairing_logic:epoch(L) =/= evatar_pairing_logic:epoch(L0)],
    {S1, [{send, A, Answer} | Publish]}.

now(#{now := Now}) -> Now.
conns(#{conns := Conns}) -> Conns.
queue_len(V) -> maps:get(queue_len, V, 0).

%% @doc The role machine alone: the decisions for one event, given the
%% whole view (with the state's epoch, version, confirmed and synced).
%% Tests use it; {@link handle/3} carries them out.
-spec decide(event() | {silent, [{binary(), integer()}], integer()}, view(), state()) ->
          {state(), [decision()]}.
decide(Event, View, #inst{role = starting} = S) ->
    starting(Event, View, S);
decide({instance, Node, Info}, View, #inst{role = fenced} = S) ->
    %% A restorer asked a node heard again (an instance there is met
    %% through the inventories).
    case evatar_ha_role_machine:runs_none(Info) of
        true -> core({runs_none, Node}, View, S);
        false -> {S, []}
    end;
decide({msg, Msg}, View, S) ->
    msg(Msg, View, S);
decide({cluster, Event}, View, S) ->
    cluster(Event, View, S);
decide({down, standby, Why}, View, S) ->
    standby_down(Why, View, S);
decide({down, active, Why}, View, #inst{role = standby} = S) ->
    active_down(Why, View, S#inst{watching = false});
decide({down, active, _Why}, _View, S) ->
    {S#inst{watching = false}, []};
decide({timeout, Key}, View, S) ->
    timeout(Key, View, S);
decide({silent, Unacked, Now}, View, #inst{role = active} = S) ->
    silent(Unacked, Now, View, S);
decide(paused, View, #inst{role = active} = S) ->
    paused(View, S);
decide(_Event, _View, S) ->
    {S, []}.

%% ---------------------------------------------------------------------------
%% Starting: ask the peers, or offer to be the standby of the active found
%% ---------------------------------------------------------------------------

starting({start, Mode, Previous}, V, S) ->
    started(evatar_ha_role_machine:start(Mode, Previous, peers(V, S), suspect(V)), V, S);
starting({instance, Node, Info}, V, #inst{start = St} = S) ->
    started(evatar_ha_role_machine:starting({instance, Node, Info}, suspect(V), St), V, S);
starting({timeout, asked}, V, #inst{start = St} = S) ->
    started(evatar_ha_role_machine:starting({timeout, asked}, suspect(V), St), V, S);
starting({timeout, retry_ask}, V, #inst{start = St} = S) ->
    started(evatar_ha_role_machine:starting({timeout, retry_ask, peers(V, S)}, suspect(V), St), V, S);
starting({timeout, offered}, _V, S) ->
    stop(no_snapshot, S, []);
starting({timeout, _}, _V, S) ->
    {S, []};
starting({msg, {snapshot, A, _E, Version, State, Claim}}, V, #inst{active = A} = S) ->
    become_standby(Version, State, Claim, V, S);
starting({msg, {dismiss, A}}, _V, #inst{active = A} = S) ->
    stop(dismissed, S, []);
starting({down, active, _}, _V, S) ->
    stop(active_gone, S, []);
starting(_Event, _V, S) ->
    {S, [postpone]}.

started({St, Effects}, V, S) ->
    start_effects(Effects, V, S#inst{start = St}, []).

start_effects([{offer, Active} | _], V, S, Acc) ->
    {S#inst{active = Active, watching = true},
     lists:reverse(Acc, [{monitor, active, Active}, {send, Active, {offer, v(version, V)}},
                         {timer, offered, 5 * suspect(V) + 2000}])};
start_effects([become_active | _], #{nodes := Nodes} = V, #inst{core = Core} = S, Acc) ->
    %% A new pairing: every node records its first configuration (nothing
    %% waits for the answers), so that a voter that hears this active
    %% refuses a restore of the pairing by a node that does not.
    S1 = S#inst{role = active},
    {S2, Place} = place_soon(V, S1),
    Announce = [{register, N, evatar_ha_core:claim(Core)} || N <- Nodes],
    {S2, lists:reverse(Acc, [new_logic, {log, info, #{what => pairing_started}}, serving
                             | left_starting([publish | Announce ++ Place])])};
start_effects([{restore, _} | Rest], #{nodes := [_]} = V, S, Acc) ->
    %% A lone node: nobody else can hold the pairing.
    start_effects([become_active | Rest], V, S, Acc);
start_effects([{restore, NoneOn} | _], V, #inst{me = Me} = S, Acc) ->
    %% Nobody runs the pairing, as far as this node found: a new state, but
    %% fenced (no client is taken, nothing goes out) until it wins an
    %% election, which makes it active at a new epoch as a takeover does.
    Nodes = lists:usort([node_of(Me) | NoneOn]),
    {S1, Elect} = core({elect, {restore, Nodes}, true}, V, S#inst{role = fenced}),
    {S1, lists:reverse(Acc, [new_logic, {log, notice, #{what => pairing_restoring,
                                                        runs_none => Nodes}}
                             | left_starting([publish | Elect])])};
start_effects([E | Rest], V, S, Acc) ->
    start_effects(Rest, V, S, [E | Acc]);   % ask, timer, log: as they are
start_effects([], _V, S, Acc) ->
    {S, lists:reverse(Acc)}.

left_starting(Effects) ->
    [{cancel_timer, K} || K <- [asked, retry_ask, offered]] ++ Effects.

become_standby(Version, State, Claim, V, #inst{active = A, core = Core} = S) ->
    {Core1, []} = evatar_ha_core:handle({claim, Claim}, core_ctx(standby, V), Core),
    {S#inst{role = standby, core = Core1, active_lost = false},
     [{install, Version, State}, {send, A, {confirm, Version}},
      {log, info, #{what => standby_synced, active => node_of(A), version => Version}}
      | left_starting([publish])]}.

%% ---------------------------------------------------------------------------
%% Messages between instances (evatar_ha_proto_v1)
%% ---------------------------------------------------------------------------

%% Active: a new instance offers to be the standby; it gets a snapshot
%% unless a registration runs.
msg({offer, Sb, _}, _V, #inst{role = active, standby = undefined, core = Core} = S) ->
    case evatar_ha_core:registering(Core) of
        false ->
            S1 = S#inst{standby = Sb, placing = false},
            {S2, Snap} = snapshot_to(S1),
            {S2, [{monitor, standby, Sb}, unsync, Snap, publish]};
        true ->
            {S, [{send, Sb, dismiss}]}
    end;
msg({offer, Sb, _}, _V, #inst{standby = Sb} = S) ->
    snapshot(S);
msg({offer, Other, _}, _V, S) ->
    {S, [{send, Other, dismiss}]};
msg({resync, Sb, _}, _V, #inst{standby = Sb} = S) ->
    snapshot(S);
msg({resync, Other, _}, _V, S) ->
    {S, [{send, Other, dismiss}]};
msg({confirm, Sb, E, Version}, V, #inst{standby = Sb, role = active, claiming = true} = S) ->
    %% Won again after a fence: a confirmation at the new epoch comes after
    %% the snapshot with the new claim (older ones carry the old epoch), so
    %% the cluster may record that claim now.
    case E =:= v(epoch, V) of
        true ->
            {S1, Effects} = core(standby_claimed, V, S#inst{claiming = false}),
            {S1, [{release, Version} | Effects]};
        false ->
            {S, [{release, Version}]}
    end;
msg({confirm, Sb, _E, Version}, V, #inst{standby = Sb, role = Role} = S) ->
    case Role of
        handing_over ->
            {S1, Effects} = send_handover(V#{confirmed := max(Version, v(confirmed, V))}, S),
            {S1, [{release, Version} | Effects]};
        _ ->
            {S, [{release, Version}]}
    end;
msg({confirm, _, _, _}, _V, S) ->
    {S, []};
msg({rebalance, Move}, V, #inst{role = active, standby = Sb, core = Core} = S)
  when Sb =/= undefined ->
    %% Only with a synced standby and no registration or election under
    %% way; else the rebalancer's next round plans again.
    case v(synced, V) andalso not evatar_ha_core:holding(Core)
        andalso not evatar_ha_core:electing(Core) of
        true -> rebalance(Move, V, S);
        false -> {S, []}
    end;

%% Standby: the state, then the events in order. Word from the active ends
%% any election this standby had started.
msg({snapshot, A, _E, Version, State, Claim}, V, #inst{role = standby, active = A} = S) ->
    %% Never back to an older state than the one confirmed (a snapshot
    %% delivered twice would undo what the active released since).
    case Version < v(version, V) of
        true -> {S, []};
        false -> become_standby(Version, State, Claim, V, S)
    end;
msg({events, A, _E, Events}, V, #inst{role = standby, active = A, core = Core} = S) ->
    {Core1, []} = evatar_ha_core:handle(active_heard, core_ctx(standby, V), Core),
    {S1, Watch} = watch_active(S#inst{active_lost = false, core = Core1}),
    {S1, Watch ++ [{apply, Events}]};
msg({events, From, E, _}, V, S) ->
    other_instance(From, active, E, V, S);
msg({dismiss, A}, _V, #inst{role = standby, active = A} = S) ->
    stop(dismissed, S, []);
msg({handover, A, E, Version}, V, #inst{role = standby, active = A} = S) ->
    case {v(epoch, V), v(version, V)} of
        {E, Version} -> core({handover_asked}, V, S#inst{active_lost = true});
        _ -> {S, []}
    end;
msg({handover_done, New, _E, Claim}, V,
    #inst{role = handing_over, standby = New, core = Core} = S) ->
    {Core1, []} = evatar_ha_core:handle({claim, Claim}, core_ctx(standby, V), Core),
    Moved = <<"the pairing moved to ", (atom_to_binary(node_of(New)))/binary>>,
    {S#inst{role = standby, active = New, watching = true, standby = undefined, core = Core1,
            reconfirming = false},
     [{log, warning, #{what => handed_over, to => node_of(New)}},
      {disconnect_all, not_active, Moved}, {demonitor, standby}, {monitor, active, New},
      {cancel_timer, handover}, cancel_logic_timers, reset_commit, publish, reconfirmed]};
msg({stale, From, E}, V, S) ->
    other_instance(From, active, E, V, S);
msg({peer_instance, Pid, Role, E}, V, S) when is_atom(Role), is_integer(E) ->
    other_instance(Pid, Role, E, V, S);
msg({vote_reply, _Id, Ec, Node, Result}, V, S) ->
    core({vote_reply, Ec, Node, Result}, V, S);
msg({register_reply, _Id, Claim, Node, Result}, V, S) ->
    core({register_reply, Claim, Node, Result}, V, S);
msg(_Msg, _V, S) ->
    {S, []}.

%% A new standby gets the whole state and a new claim: the configuration
%% with it as the standby.
snapshot(S) ->
    {S1, Snap} = snapshot_to(S),
    {S1, [Snap]}.

snapshot_to(#inst{standby = Sb, core = Core, claiming = true} = S) ->
    %% The claim not registered yet goes again: the registration waits for
    %% the standby to hold it.
    {S, {snapshot, Sb, evatar_ha_core:claim(Core)}};
snapshot_to(#inst{standby = Sb, core = Core} = S) ->
    {Claim, Core1} = evatar_ha_core:next_claim(Core),
    {S#inst{core = Core1}, {snapshot, Sb, Claim}}.

%% What this instance does about another instance of its pairing
%% (evatar_ha_role_machine:meet/2).
other_instance(Me, _Role, _E, _V, #inst{me = Me} = S) ->
    {S, []};
other_instance(Pid, Role, E, V, #inst{role = R, me = Me} = S) ->
    {MyRole, Peer} = case R of
                         standby -> {standby, S#inst.active};
                         fenced -> {fenced, S#inst.standby};
                         _ -> {active, S#inst.standby}
                     end,
    Mine = #{role => MyRole, epoch => v(epoch, V), node => node_of(Me), pid => Me, peer => Peer},
    Other = #{role => Role, epoch => E, node => node_of(Pid), pid => Pid},
    Why = {newer_instance, node_of(Pid), E},
    case evatar_ha_role_machine:meet(Mine, Other) of
        step_down -> step_down(Why, S, [{send, P, dismiss} || P <- [S#inst.standby],
                                                              P =/= undefined, P =/= Pid]);
        stop -> stop(Why, S, []);
        tell_stale -> {S, [{send, Pid, {stale, v(epoch, V)}}]};
        keep -> {S, []}
    end.

%% ---------------------------------------------------------------------------
%% Failure detection (evatar_cluster's events) and the peer's DOWN
%% ---------------------------------------------------------------------------

cluster({node_alive, _}, V, #inst{role = active} = S) ->
    place(V, S);
cluster({Lost, Node}, V, #inst{role = R, standby = Sb} = S)
  when (Lost =:= node_suspected orelse Lost =:= node_down), R =/= standby, Sb =/= undefined ->
    case node_of(Sb) of
        Node -> standby_down(noconnection, V, S);
        _ -> {S, []}
    end;
cluster({Lost, Node}, V, #inst{role = standby, active = A} = S)
  when Lost =:= node_suspected; Lost =:= node_down ->
    case node_of(A) of
        Node -> core({elect, active_silent, false}, V, S#inst{active_lost = true});
        _ -> {S, []}
    end;
cluster({node_alive, Node}, V, #inst{role = standby, active = A, active_lost = true} = S) ->
    case node_of(A) of
        Node ->
            %% The active's node is back: pick up the replication again (an
            %% election under way goes on: the nodes decide).
            {S1, Watch} = watch_active(S),
            {S1, [{send, A, {resync, v(version, V)}} | Watch]};
        _ ->
            {S, []}
    end;
cluster({quorum, true}, V, #inst{role = standby, active_lost = true} = S) ->
    core({elect, active_silent, false}, V, S);
cluster({quorum, false}, V, #inst{role = Role} = S) when Role =:= active; Role =:= handing_over ->
    %% Handing over is still serving until the standby takes the pairing:
    %% it fences as an active does.
    maybe_fence(V, S);
cluster(stalled, V, #inst{role = active} = S) ->
    %% This node was stopped for longer than suspect_ms: the pairing may
    %% have another active by now, or (far more often) not.
    paused(V, S);
cluster({quorum, true}, V, #inst{role = fenced} = S) ->
    core({elect, fenced, false}, V, S);
cluster({node_alive, Node}, V, #inst{role = fenced, core = Core} = S) ->
    case evatar_ha_core:restoring(Core) of
        true -> {S, [{ask, [Node]}]};
        false -> core({elect, fenced, false}, V, S)
    end;
cluster(_Event, _V, S) ->
    {S, []}.

%% The standby's process died (its node is up): it cannot take over, so go
%% on without it at once. Its node is lost or silent: it may be taking over
%% (a partition looks the same), so first the cluster must accept a
%% configuration without it (evatar_ha_core); everything stays held until then.
standby_down(Why, V, #inst{standby = Sb, claiming = Claiming} = S) ->
    Log = {log, warning, #{what => standby_lost, standby => node_of(Sb), reason => Why}},
    {S1, Forget} = forget_standby(S),
    case Why of
        noconnection ->
            {S2, Effects} = core(standby_node_lost, V, S1),
            {S2, [Log | Forget] ++ Effects ++ [publish]};
        _ when Claiming ->
            %% Won again after a fence and the kept standby died before it
            %% held the new claim: the claim is registered without it.
            {S2, Effects} = core(standby_claimed, V, S1),
            {S2, [Log | Forget] ++ Effects ++ [publish]};
        _ ->
            {S2, Place} = place(V, S1),
            {S2, [Log | Forget] ++ [release_all, publish | Place]}
    end.

active_down(noconnection, V, S) ->
    core({elect, active_silent, false}, V, S#inst{active_lost = true});
active_down(Why, V, S) ->
    %% The process died and its node is up: its lease counts no more.
    core({elect, {active_died, Why}, true}, V, S#inst{active_lost = true}).

watch_active(#inst{watching = false, active = A} = S) when A =/= undefined ->
    {S#inst{watching = true}, [{monitor, active, A}]};
watch_active(S) ->
    {S, []}.

%% ---------------------------------------------------------------------------
%% Timers
%% ---------------------------------------------------------------------------

timeout(K, V, S) when K =:= election; K =:= register; K =:= deadline ->
    core({timeout, K}, V, S);
timeout(place, V, S) ->
    place(V, S#inst{placing = false});
timeout(handover, V, #inst{role = handing_over} = S) ->
    %% No handover_done: serve again, unless the cluster may have moved on
    %% meanwhile (no majority, the standby's node unheard): then fence, as
    %% an active would have when the majority went.
    {S1, Fence} = maybe_fence(V, S#inst{role = active}),
    {S1, [{log, warning, #{what => handover_aborted}} | Fence]};
timeout(_Key, _V, S) ->
    {S, []}.

%% ---------------------------------------------------------------------------
%% Elections and registrations: evatar_ha_core decides, this says what
%% each outcome means for the instance
%% ---------------------------------------------------------------------------

%% An event of `evatar_ha_core', and what its outcome means here.
-spec core(evatar_ha_core:event(), view(), #inst{}) -> {#inst{}, effects()}.
core(Event, V, #inst{role = Role, core = Core} = S) ->
    Ctx = (core_ctx(Role, V))#{keep_standby => keeps_standby(V, S)},
    {Core1, Effects} = evatar_ha_core:handle(Event, Ctx, Core),
    core_effects(Effects, V, S#inst{core = Core1}, []).

%% What `evatar_ha_core' needs to know of the instance and the view.
-spec core_ctx(evatar_ha_core:role(), view()) -> evatar_ha_core:ctx().
core_ctx(Role, #{nodes := Nodes, heartbeat_ms := Hb, suspect_ms := Suspect} = V) ->
    Ctx = #{nodes => Nodes, heartbeat_ms => Hb, suspect_ms => Suspect, epoch => v(epoch, V),
            role => Role},
    maps:merge(Ctx, maps:with([self], V)).

core_effects([{vote, Node, Ec, Claim, Dead} | Rest], V, S, Acc) ->
    Active = case S of
                 #inst{role = standby, active = A} -> A;
                 #inst{me = Me} -> Me
             end,
    core_effects(Rest, V, S, [{vote, Node, Ec, Claim, Active, Dead} | Acc]);
core_effects([{restore_vote, _, _, _} = E | Rest], V, S, Acc) ->
    core_effects(Rest, V, S, [E | Acc]);
core_effects([{Kind, _, _} = E | Rest], V, S, Acc) when Kind =:= register; Kind =:= timer ->
    core_effects(Rest, V, S, [E | Acc]);
core_effects([{pause, keep} | Rest], V, S, Acc) ->
    core_effects(Rest, V, S, Acc);
core_effects([{pause, await} | Rest], V, S, Acc) ->
    core_effects(Rest, V, S#inst{reconfirming = true}, Acc);
core_effects([{pause, reconfirm} | Rest], V, #inst{core = Core} = S, Acc) ->
    Log = {log, notice, #{what => reconfirming_after_pause, claim => evatar_ha_core:claim(Core)}},
    core_effects(Rest, V, S#inst{reconfirming = true}, [Log | Acc]);
core_effects([Decision], V, S, Acc) ->
    {S1, Effects} = decided(Decision, V, S),
    {S1, lists:reverse(Acc, Effects)};
core_effects([], _V, S, Acc) ->
    {S, lists:reverse(Acc)}.

decided({won, handover, Ec}, V, #inst{role = standby, active = Old} = S) ->
    %% The old active becomes this one's standby, already in sync, with
    %% the claim {Ec, 1}.
    {S1, Effects} = take_over(handover, Ec, V, S),
    {Core, []} = evatar_ha_core:handle({claim, {Ec, 1}}, core_ctx(active, V), S1#inst.core),
    S2 = S1#inst{standby = Old, placing = false, core = Core},
    {S2, Effects ++ [{monitor, standby, Old}, {send, Old, {handover_done, Ec, {Ec, 1}}},
                     {synced_at, v(version, V)}, {flush, mode(S2)}, publish]};
decided({won, reelect, Ec}, V, #inst{role = active, standby = Sb, core = Core} = S)
  when Sb =/= undefined ->
    %% Re-elected with a standby (after a pause): it gets the claim {Ec, 1}
    %% in a snapshot after the new epoch, and the registration waits for its
    %% confirmation at Ec, as after a fence (a majority that recorded {Ec, 1}
    %% first would leave it stale, and what it confirmed lost).
    case keeps_standby(V, S) of
        true ->
            {S#inst{claiming = true},
             [{log, warning, #{what => reelected, epoch => Ec}},
              {logic, {reelected, Ec}, mode(S)}, {snapshot, Sb, evatar_ha_core:claim(Core)},
              publish]};
        false ->
            {S, [{log, warning, #{what => reelected, epoch => Ec}},
                 {logic, {reelected, Ec}, mode(S)}, publish]}
    end;
decided({won, reelect, Ec}, _V, #inst{role = active} = S) ->
    %% Re-elected above a stale promise while serving: the clients stay,
    %% only the epoch moves; effects wait for the registration of {Ec, 1}.
    {S, [{log, warning, #{what => reelected, epoch => Ec}}, {logic, {reelected, Ec}, mode(S)},
         publish]};
decided({won, keep_standby, Ec}, V, #inst{standby = Sb, core = Core} = S) ->
    %% A fenced active won again and keeps its standby, in sync: what was
    %% released is there. The standby gets the new claim {Ec, 1} with a
    %% snapshot taken after the takeover (so its confirmation carries Ec);
    %% that confirmation lets the registration go (evatar_ha_core), and the
    %% standby's confirmations release what goes out meanwhile.
    S1 = S#inst{role = active, active = undefined, watching = false, active_lost = false,
                claiming = true},
    {S1, [{log, warning, #{what => takeover, epoch => Ec, reason => fenced, version => v(version, V),
                           standby => node_of(Sb)}},
          {metric, evatar_takeovers_total, fenced}, serving, arm_logic_timers,
          {logic, {takeover, Ec}, mode(S1)}, {snapshot, Sb, evatar_ha_core:claim(Core)},
          {ensure_timer, silent, silent_poll_ms(maps:get(client_ack_timeout, V))}, publish,
          serve_held]};
decided({won, Why, Ec}, V, S) ->
    take_over(Why, Ec, V, S);
decided({lost, Why}, _V, #inst{role = standby} = S) ->
    stop(Why, S, [reply_held]);
decided({lost, Why}, _V, S) ->
    step_down(Why, S, []);
decided(registered, _V, #inst{standby = Sb} = S) when Sb =/= undefined ->
    %% A reconfirmation after a pause: the standby's confirmations still
    %% decide what goes out.
    {S#inst{reconfirming = false}, [reconfirmed]};
decided(registered, V, S) ->
    {S1, Place} = place(V, S#inst{reconfirming = false}),
    {S2, Soon} = place_soon(V, S1),
    {S2, [reconfirmed, release_all | Place ++ Soon]};
decided({fence, Why}, V, #inst{role = Role, core = Core} = S) ->
    Log = case Why of
              registration_timeout ->
                  {log, warning, #{what => registration_timeout,
                                   claim => evatar_ha_core:claim(Core)}};
              _ ->
                  {log, warning, #{what => registration_refused, reason => Why}}
          end,
    {S1, Effects} = case Role of
                        active -> fence_now(V, S);
                        _ -> {S, []}
                    end,
    {S1, [Log | Effects]}.

%% An instance that won the election at `Ec' takes over: a standby (fully
%% applied up to its version) or a fenced active asking again. It holds
%% every effect until the cluster accepted its new configuration; resumes
%% held while it was a standby are served now.
take_over(Why, Ec, V, #inst{standby = Sb} = S) ->
    S1 = S#inst{role = active, active = undefined, watching = false, active_lost = false,
                standby = undefined},
    Reason = case Why of
                 {R, _} -> R;
                 R -> R
             end,
    {S1, [{demonitor, active}, {demonitor, standby}] ++ [{send, Sb, dismiss} || Sb =/= undefined]
     ++ [{log, warning, #{what => takeover, epoch => Ec, reason => Why, version => v(version, V)}},
         {metric, evatar_takeovers_total, Reason}, serving, unsync, arm_logic_timers,
         {logic, {takeover, Ec}, mode(S1)},
         {ensure_timer, silent, silent_poll_ms(maps:get(client_ack_timeout, V))}, publish,
         serve_held]}.

%% A newer active exists: close the clients (they resume there) and go.
-spec step_down(term(), #inst{}, effects()) -> {#inst{}, effects()}.
step_down(Why, S, Pre) ->
    {S, Pre ++ [{log, warning, #{what => stepping_down, reason => Why}},
                {metric, evatar_step_downs_total},
                {disconnect_all, stale_epoch, <<"a newer instance of this pairing is active">>},
                {stop, Why}]}.

%% The instance stops (after the effects `Pre').
-spec stop(term(), #inst{}, effects()) -> {#inst{}, effects()}.
stop(Why, S, Pre) ->
    {S, Pre ++ [{log, info, #{what => instance_stopped, reason => Why}}, {stop, Why}]}.

%% Lets the standby go: dismissed, unmonitored, the commit unsynced.
-spec forget_standby(#inst{}) -> {#inst{}, effects()}.
forget_standby(#inst{standby = Sb} = S) ->
    {S#inst{standby = undefined, claiming = false},
     [{demonitor, standby}] ++ [{send, Sb, dismiss} || Sb =/= undefined] ++ [unsync]}.

%% ---------------------------------------------------------------------------
%% Fencing and pauses
%% ---------------------------------------------------------------------------

%% In a cluster of 3 or more: no majority and no word from the standby's
%% node within the lease.
-spec maybe_fence(view(), #inst{}) -> {#inst{}, effects()}.
maybe_fence(#{nodes := Nodes, majority := Majority, heard := Heard} = V, #inst{standby = Sb} = S) ->
    StandbyHeard = Sb =/= undefined andalso lists:member(node_of(Sb), Heard),
    case evatar_ha_core:must_fence(length(Nodes), Majority, StandbyHeard) of
        true -> fence_now(V, S);
        false -> {S, []}
    end.

%% Stops serving: every client is closed with Fenced (they go to their
%% other endpoints), nothing goes out; with a majority heard it asks for
%% the pairing again at once (an election in which its standby may win).
fence_now(#{majority := Majority} = V, S) ->
    S1 = S#inst{role = fenced, claiming = false},
    {S2, Elect} = case Majority of
                      true -> core({elect, fenced, false}, V, S1);
                      false -> {S1, []}
                  end,
    {S2#inst{reconfirming = false},
     [{log, warning, #{what => fenced}}, {metric, evatar_fenced_total},
      {disconnect_all, fenced, <<"this node lost the majority of the cluster">>}
      | Elect] ++ [publish, reconfirmed]}.

%% This node was paused itself while this instance was active (SIGSTOP, a
%% laptop lid, a long GC): decided by evatar_ha_core:after_pause/2. Nothing
%% is fenced for the pause alone.
-spec paused(view(), #inst{}) -> {#inst{}, effects()}.
paused(V, S) ->
    {S1, Effects} = core(paused, V, S),
    {S1, [pause_seen | Effects]}.

%% ---------------------------------------------------------------------------
%% The standby: placed by the active on the next alive node
%% ---------------------------------------------------------------------------

%% A fenced active that wins again keeps its standby when that one is in
%% sync and its node alive (else it takes over alone, as a standby does).
keeps_standby(V, #inst{role = Role, standby = Sb})
  when Sb =/= undefined, Role =:= fenced orelse Role =:= active ->
    v(synced, V) andalso lists:member(node_of(Sb), maps:get(alive, V, []));
keeps_standby(_V, _S) ->
    false.

wants_standby(#{nodes := Nodes, standby_opt := Opt},
              #inst{role = active, standby = undefined, placing = false}) ->
    Opt andalso length(Nodes) > 1;
wants_standby(_V, _S) ->
    false.

%% A standby placed at once, if one is wanted.
-spec place_soon(view(), #inst{}) -> {#inst{}, effects()}.
place_soon(V, S) ->
    case wants_standby(V, S) of
        true -> {S, [{timer, place, 0}]};
        false -> {S, []}
    end.

%% Asks the next alive node to start a standby; tried again later when
%% nothing came of it.
-spec place(view(), #inst{}) -> {#inst{}, effects()}.
place(V, #inst{me = Me, standby_node = Preferred} = S) ->
    case wants_standby(V, S) of
        true ->
            #{nodes := Nodes, alive := Alive} = V,
            case evatar_ha_membership:standby_node(Nodes, node_of(Me), Alive, Preferred) of
                none -> {S, []};
                Node -> {S#inst{placing = true}, [{start_standby, Node},
                                                  {timer, place, ?PLACE_RETRY_MS}]}
            end;
        false ->
            {S, []}
    end.

%% ---------------------------------------------------------------------------
%% Silent client links, and the planned handover they start
%% ---------------------------------------------------------------------------

%% `Unacked': each entity's oldest unacknowledged delivery (system ms).
%% Deliveries still held for a registration were never sent: their
%% receivers are not silent.
-spec silent([{binary(), integer()}], integer(), view(), #inst{}) -> {#inst{}, effects()}.
silent(Unacked, Now, #{client_ack_timeout := Timeout} = V, #inst{core = Core, standby = Sb} = S) ->
    Silent = [E || not evatar_ha_core:holding(Core), {E, T} <- Unacked, Now - T > Timeout],
    Drops = lists:append(
              [[{log, warning, #{what => silent_link, entity => E}},
                {metric, evatar_entities_dropped_total, silent_link},
                {drop, E, silent_link, <<"delivered signals were not acknowledged in time">>}]
               || E <- Silent]),
    Arm = {ensure_timer, silent, silent_poll_ms(Timeout)},
    case Silent =/= [] andalso maps:get(handover_on_silent_link, V) =:= true
        andalso Sb =/= undefined andalso v(synced, V) of
        true ->
            {S1, Effects} = hand_over(V, S),
            {S1, Drops ++ [Arm | Effects]};
        false ->
            {S, Drops ++ [Arm, {flush_maybe, mode(S)}]}
    end.

%% A planned handover to the synced standby (a silent link, or the
%% rebalancer): it goes once the standby has confirmed everything.
hand_over(V, S) ->
    S1 = S#inst{role = handing_over},
    {S2, Send} = send_handover(V, S1),
    {S2, [{timer, handover, 4 * suspect(V)}, {flush, mode(S1)} | Send]}.

%% The handover goes to the standby once it confirmed every version;
%% until then what is queued is shipped.
-spec send_handover(view(), #inst{}) -> {#inst{}, effects()}.
send_handover(V, #inst{standby = Sb} = S) when Sb =/= undefined ->
    case v(confirmed, V) =:= v(version, V) of
        true -> {S, [{send, Sb, {handover, v(version, V)}}]};
        false -> {S, [{flush, mode(S)}]}
    end;
send_handover(_V, S) ->
    {S, [{flush, mode(S)}]}.

%% A move of the rebalancer (evatar_placement): a planned handover, or the
%% standby moved to another node: dismissed, a configuration without it
%% registered as when its node is lost (effects held until a majority
%% accepted it), then a new standby placed there from a snapshot.
-spec rebalance(evatar_placement:move(), view(), #inst{}) -> {#inst{}, effects()}.
rebalance({handover, Id}, V, #inst{id = Id, standby = Sb} = S) ->
    {S1, Effects} = hand_over(V, S),
    {S1, [{log, notice, #{what => rebalance_handover, to => node_of(Sb)}} | Effects]};
rebalance({standby, Id, Node}, V, #inst{id = Id, standby = Sb, me = Me} = S) ->
    case Node =/= node_of(Me) andalso Node =/= node_of(Sb) of
        true ->
            {S1, Forget} = forget_standby(S#inst{standby_node = Node}),
            {S2, Effects} = core(standby_node_lost, V, S1),
            {S2, [{log, notice, #{what => rebalance_standby, from => node_of(Sb), to => Node}}
                  | Forget] ++ Effects ++ [publish]};
        false ->
            {S, []}
    end;
rebalance(_Move, _V, S) ->
    {S, []}.

%% ---------------------------------------------------------------------------

%% ---------------------------------------------------------------------------

peers(#{alive := Alive}, #inst{me = Me}) ->
    [N || N <- Alive, N =/= node_of(Me)].

suspect(#{suspect_ms := Ms}) -> Ms.
%% What the view says of the state (handle/3 put it there).
v(Key, V) -> maps:get(Key, V).

%% @doc How the output commit runs now: `replicated' with a standby,
%% `held' while a registration holds effects, else `direct'.
-spec mode(state()) -> evatar_ha_commit:mode().
mode(#inst{standby = undefined, core = Core}) ->
    case evatar_ha_core:holding(Core) of
        true -> held;
        false -> direct
    end;
mode(#inst{}) -> replicated.

%% @doc How often silent client links are looked for.
-spec silent_poll_ms(pos_integer()) -> pos_integer().
silent_poll_ms(Timeout) -> max(50, Timeout div 2).

%% @doc The node of an instance: a pid's, or the model's `{Node, Ref}'.
-spec node_of(peer()) -> node() | undefined.
node_of(Pid) when is_pid(Pid) -> node(Pid);
node_of({Node, _}) when is_atom(Node) -> Node;
node_of(_) -> undefined.

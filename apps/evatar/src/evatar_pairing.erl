%% @doc Internal. The process of one instance of a pairing: a shell around
%% one pure state, `evatar_ha_instance''s, which holds the instance's role
%% (with `evatar_ha_core' and `evatar_ha_role_machine'), the pairing's rules (`evatar_pairing_logic')
%% and the output commit (`evatar_ha_commit': which effects go out now and
%% which wait for the standby or the cluster), and returns only I/O;
%% docs/ha-design.md, section 12. Start reading at handle_event/4 here,
%% then `evatar_ha_instance:handle/3' and effect/2 here, which carries
%% out each effect and decides nothing. This process owns what cannot be
%% replicated: the pids of the entities' processes and of the other
%% instance, their monitors, one map of timers keyed by what they are for
%% (a logic timer key, or `{ha, Key}'), the calls and the client hot path.
%% An instance is the `active' one or the `standby' of an active on
%% another node.
%%
%% ```
%%                 start_link
%%                     |
%%                     v
%%              +----------+  create: active at once; restore, restart after a crash,
%%              | starting |  or asked to be a standby: ask the peers, offer
%%              +----------+  ourselves to the active found
%%               |        |
%%   none found  |        | snapshot received
%%               v        v
%%  +-----------------+  takeover: election won (active dead or  +---------+
%%  | active          | <---- silent), or handover ------------- | standby |
%%  | waiting | bound |                                          |         |
%%  |                 | -- handing_over (silent link, rebalancer)->|         |
%%  +-----------------+                                          +---------+
%%     |    ^     | lower epoch met, stale,                  dismissed, stale
%%     |    |     | or delete                                claim, or an active
%%     |    |     +--------------> (stop) <----------------- of higher epoch
%%     |    | election won again (a new epoch)
%%     v    |
%%  +---------+  no majority and no word from the standby's node
%%  | fenced  |  within the lease, or the cluster refused its configuration
%%  +---------+  (after a pause of this node, a standby won meanwhile):
%%               clients closed with Fenced, nothing externalised, logic
%%               timers postponed. A pause alone fences nothing.
%% '''
%% The state name is the role of `evatar_ha_instance' (`starting',
%% `handing_over', `standby', `fenced'), except that an active's is the
%% logic's {@link evatar_pairing_logic:phase/1} (`waiting' or `bound');
%% `handing_over', drawn above as an arrow, is a state of its own: an active
%% waiting for its standby to take over (back to active if it does not). Client events and calls are postponed while `starting' and
%% `handing_over'. Acks are batched until the mailbox is empty.
-module(evatar_pairing).
-behaviour(gen_statem).

%% A pairing idle this long compacts its heap: a home's pairing is quiet
%% most of the time.
-define(HIBERNATE_AFTER, 5000).

-include_lib("kernel/include/logger.hrl").

-export([start_link/2, start_link/3]).
-export([init/1, callback_mode/0, handle_event/4, terminate/3]).

-export_type([mode/0]).

-type mode() :: create | restore | {standby_for, pid()}.
-type state() :: starting | evatar_pairing_logic:phase() | standby | fenced | handing_over.

%% The process's state: the pure instance, and what cannot be replicated.
-record(data, {id :: evatar:pairing_id(),
               config :: evatar_pairing_logic:config(),
               mode :: evatar_pairing:mode(),
               %% The role, the rules and the output commit: pure.
               inst :: evatar_ha_instance:state(),
               pids = #{} :: #{binary() => {pid(), reference()}},
               refs = #{} :: #{reference() => binary()},
               timers = #{} :: #{evatar_pairing_logic:timer_key() | {ha, atom()} => reference()},
               %% The monitors of the other instance.
               mons = #{} :: #{active | standby => reference()},
               %% The stall generation this active began serving at; after a
               %% pause, inspections wait for the reconfirmation.
               gen = 0 :: non_neg_integer(),
               inspects = [] :: [{gen_statem:from(), atom()}],
               %% Standby: resumes held until it takes over or hears its active.
               held = [] :: [evatar_ha_role_machine:held(gen_statem:from())],
               %% The live tail's watchers (evatar_tap): [] costs nothing.
               watchers = [] :: [evatar_tap:watcher()],
               %% This pairing's own counters once active here (evatar_metrics).
               metrics = undefined :: evatar_metrics:pairing_ref()}).
-type data() :: #data{}.

%% @doc Starts a new pairing (the active), registered as
%% `{via, evatar_registry, PairingId}'.
-spec start_link(evatar:pairing_id(), evatar_pairing_logic:config()) ->
          {ok, pid()} | {error, term()}.
start_link(PairingId, Config) ->
    start_link(PairingId, Config, create).

%% @doc Starts an instance: `create' (a new pairing, active), `restore' (a
%% pairing no node runs: fenced until it wins an election) or
%% `{standby_for, Active}'.
-spec start_link(evatar:pairing_id(), evatar_pairing_logic:config(), mode()) ->
          {ok, pid()} | {error, term()}.
start_link(PairingId, Config, Mode) ->
    gen_statem:start_link({via, evatar_registry, PairingId}, ?MODULE,
                          {PairingId, Config, Mode}, [{hibernate_after, ?HIBERNATE_AFTER}]).

%% @private
-spec callback_mode() -> gen_statem:callback_mode_result().
callback_mode() -> handle_event_function.

%% @private
-spec init({evatar:pairing_id(), evatar_pairing_logic:config(), mode()}) ->
          gen_statem:init_result(state()).
init({PairingId, Config, Mode}) ->
    logger:set_process_metadata(#{pairing => PairingId, domain => [evatar, pairing]}),
    Inst = evatar_ha_instance:new(PairingId, self(), Config),
    {ok, starting, #data{id = PairingId, config = Config, mode = Mode, inst = Inst},
     [{next_event, internal, load}]}.

%% @private
%% Events are sorted by kind first, then by state, in functions of their
%% own: no clause relies on coming after another of a different state.
-spec handle_event(gen_statem:event_type(), term(), state(), data()) ->
          gen_statem:event_handler_result(state()).
handle_event(info, {timeout, TRef, Key}, State, #data{timers = Timers} = Data) ->
    case Timers of
        #{Key := TRef} -> timeout(Key, State, Data);
        #{} -> keep_state_and_data  % cancelled or replaced meanwhile
    end;
handle_event(internal, load, starting, #data{id = Id, mode = Mode} = Data) ->
    ha({start, Mode, evatar_registry:previous(Id)}, Data);
handle_event(info, {evatar_ha, 1, {instance, Id, Node, Info}}, _State, #data{id = Id} = Data) ->
    ha({instance, Node, Info}, Data);
handle_event(info, {evatar_ha, 1, Body}, _State, Data) ->
    ha({msg, Body}, Data);
handle_event(info, {evatar_cluster, Event}, _State, Data) ->
    ha({cluster, Event}, Data);
handle_event(info, {'DOWN', Ref, process, _, Why}, State, Data) ->
    down(Ref, Why, State, Data);
handle_event({call, From}, {inspect, ha}, starting, Data) ->
    {keep_state_and_data, [{reply, From, ha_status(Data)}]};
handle_event(_Type, _Event, starting, _Data) ->
    {keep_state_and_data, [postpone]};
handle_event(info, evatar_flush, _State, Data) ->
    {keep_state, flush(Data)};
handle_event(info, {evatar_tap_ack, Ref, N}, _State, #data{watchers = Watchers} = Data)
  when is_integer(N), N >= 0 ->
    {keep_state, Data#data{watchers = evatar_tap:acked(Ref, N, Watchers)}};
handle_event(info, {evatar_tap_unwatch, Ref}, _State, #data{watchers = Watchers} = Data) ->
    _ = erlang:demonitor(Ref, [flush]),
    {keep_state, Data#data{watchers = evatar_tap:down(Ref, Watchers)}};
handle_event(info, {evatar_tap_down, Ref, process, _, _}, _State,
             #data{watchers = Watchers} = Data) ->
    {keep_state, Data#data{watchers = evatar_tap:down(Ref, Watchers)}};
handle_event({call, From}, Request, State, Data) ->
    call(Request, From, State, Data);
handle_event(cast, Request, State, Data) when State =:= waiting; State =:= bound ->
    active_cast(Request, Data);
handle_event(cast, _Request, handing_over, _Data) ->
    {keep_state_and_data, [postpone]};
handle_event(cast, _Request, _StandbyOrFenced, _Data) ->
    %% Not accepted, so never acknowledged: the client sends it again to
    %% the active.
    keep_state_and_data;
handle_event(Type, Event, _State, #data{id = Id}) ->
    ?LOG_NOTICE(#{what => unexpected_event, pairing => Id, type => Type, event => Event}),
    keep_state_and_data.

%% ---------------------------------------------------------------------------
%% Timers: one map, keyed by what each is for
%% ---------------------------------------------------------------------------

timeout({ha, held}, standby, #data{timers = Timers} = Data) ->
    {keep_state, check_held(Data#data{timers = maps:remove({ha, held}, Timers)})};
timeout({ha, _} = Key, _State, #data{timers = Timers} = Data) ->
    ha({timeout, Key}, Data#data{timers = maps:remove(Key, Timers)});
timeout(Key, State, #data{timers = Timers} = Data) when State =:= waiting; State =:= bound ->
    ha({timeout, Key}, Data#data{timers = maps:remove(Key, Timers)});
timeout(_Key, State, _Data) when State =:= fenced; State =:= handing_over ->
    %% Runs if this instance serves again (a handover aborted): the timer
    %% stays in the map, so that its message is still taken then.
    {keep_state_and_data, [postpone]};
timeout(_Key, _State, _Data) ->
    keep_state_and_data.

%% ---------------------------------------------------------------------------
%% Calls
%% ---------------------------------------------------------------------------

call({inspect, What}, From, State, Data0) ->
    %% An active whose node was paused since it began serving asks the
    %% cluster whether it is still the active and says nothing until it
    %% knows: never `active' beside a standby that took over meanwhile.
    Data = unpause(State, Data0),
    case evatar_ha_instance:reconfirming(Data#data.inst) of
        true ->
            {keep_state, Data#data{inspects = [{From, What} | Data#data.inspects]}};
        false ->
            {keep_state, Data, [{reply, From, inspect(What, State, Data)}]}
    end;
call({auth, Role, EntityId}, From, _State, #data{config = Config}) ->
    %% What a join must present, so that the joining process checks its
    %% credential itself (evatar:join/4): an id the pairing refuses anyway
    %% costs no hash.
    Reply = case evatar_auth:check_id(EntityId, maps:get(max_id_length, Config)) of
                ok -> {ok, evatar_auth:requirement(Role, EntityId, Config)};
                {error, _} = Error -> Error
            end,
    {keep_state_and_data, [{reply, From, Reply}]};
call({expire_timer, Key}, From, _State, #data{timers = Timers}) ->
    %% evatar:expire_timer/2 (tests): the expiry goes through the mailbox
    %% like the real one, and the real one, cancelled, is ignored if it
    %% was already on its way (its key no longer maps to this reference).
    case Timers of
        #{Key := TRef} ->
            _ = erlang:cancel_timer(TRef, [{async, true}, {info, false}]),
            self() ! {timeout, TRef, Key},
            {keep_state_and_data, [{reply, From, ok}]};
        #{} ->
            {keep_state_and_data, [{reply, From, {error, no_timer}}]}
    end;
call(_Request, _From, handing_over, _Data) ->
    {keep_state_and_data, [postpone]};
call(delete, From, _State, #data{id = Id, inst = Inst}) ->
    ?LOG_INFO(#{what => pairing_deleted, pairing => Id}),
    _ = [evatar_ha_proto_v1:dismiss(S, self()) || S <- [evatar_ha_instance:standby(Inst)],
                                                  is_pid(S)],
    {stop_and_reply, normal, [{reply, From, ok}]};
call({tap_watch, Pid, Filter}, From, State, #data{id = Id} = Data)
  when is_pid(Pid), is_map(Filter), (State =:= waiting orelse State =:= bound) ->
    case evatar_tap:add(Pid, Filter, Data#data.watchers, Id) of
        {ok, Ref, Watchers} ->
            {keep_state, Data#data{watchers = Watchers}, [{reply, From, {ok, Ref}}]};
        {error, _} = Error ->
            {keep_state_and_data, [{reply, From, Error}]}
    end;
call({tap_watch, _, _}, From, standby, #data{inst = Inst}) ->
    {keep_state_and_data, [{reply, From, {redirect, evatar_ha_instance:active(Inst)}}]};
call({tap_watch, _, _}, From, fenced, _Data) ->
    {keep_state_and_data, [{reply, From, {error, busy}}]};
call({resume, _, _, _, _, _} = Request, From, standby, Data) ->
    %% A client that lost the active comes here: answer once this instance
    %% either took over (it serves the resume then) or heard its active
    %% after the request came (NotActive), instead of sending the client
    %% through its endpoints and back-off while a takeover is under way.
    Held = [{From, Request, erlang:monotonic_time(millisecond)} | Data#data.held],
    {keep_state, arm_held(Data#data{held = Held})};
call({leave, _}, From, State, _Data) when State =:= standby; State =:= fenced ->
    {keep_state_and_data, [{reply, From, ok}]};
call(_Request, From, standby, #data{inst = Inst}) ->
    Active = evatar_ha_instance:active(Inst),
    {keep_state_and_data, [{reply, From, {error, {not_active, node_of(Active)}}}]};
call(_Request, From, fenced, _Data) ->
    {keep_state_and_data, [{reply, From, {error, fenced}}]};
call(Request, From, _Active, Data) ->
    active_call(Request, From, Data).

%% @private
%% Only an orderly stop runs this (the process does not trap exits): tell
%% every entity's process, so it can close its connection with a reason.
-spec terminate(term(), state(), data()) -> ok.
terminate(normal, _State, #data{id = Id, pids = Pids}) ->
    _ = [Pid ! {evatar, Id, {dropped, pairing_deleted, <<"the pairing was deleted">>}}
         || {Pid, _} <- maps:values(Pids)],
    evatar_registry:delete_role(Id, self());
terminate({shutdown, _}, _State, #data{id = Id}) ->
    evatar_registry:delete_role(Id, self());
terminate(_Reason, _State, _Data) ->
    ok.

%% ---------------------------------------------------------------------------
%% Active: the client traffic
%% ---------------------------------------------------------------------------

%% The hot path: no reply, no timer for anything but requests.
active_cast({signal, EntityId, Signal}, Data) ->
    {keep_state, flush_maybe(run({signal, EntityId, Signal}, Data))};
active_cast({client_ack, EntityId, Seq}, Data) when is_integer(Seq) ->
    {keep_state, flush_maybe(run({client_ack, EntityId, Seq}, Data))};
active_cast({report_binding, EntityId}, Data) when is_binary(EntityId) ->
    {keep_state, report_binding(EntityId, Data)};
active_cast({leave, EntityId}, Data) when is_binary(EntityId) ->
    %% evatar:leave_async/1: a closing connection that needs no answer.
    {ok, Data1} = rules({leave, EntityId, left}, Data),
    next(flush_maybe(forget(EntityId, Data1)), []);
active_cast(Request, #data{id = Id}) ->
    ?LOG_NOTICE(#{what => unexpected_event, pairing => Id, type => cast, event => Request}),
    keep_state_and_data.

active_call({join, Role, EntityId, Credential, Pid}, From, Data) ->
    join({join, Role, EntityId, Credential}, EntityId, Pid, From, Data);
active_call({join, Role, EntityId, Credential, Pid, #{session := S}}, From, Data)
  when is_binary(S) ->
    join({join, Role, EntityId, Credential, S}, EntityId, Pid, From, Data);
active_call({resume, Role, EntityId, Credential, Pid,
             #{session := S, received := R, epoch := E}}, From, Data)
  when is_binary(S), is_integer(R), R >= 0, is_integer(E), E >= 0 ->
    join({resume, Role, EntityId, Credential, S, R, E}, EntityId, Pid, From, Data);
active_call({describe, EntityId, Description}, From, Data) ->
    {Reply, Data1} = rules({describe, EntityId, Description}, Data),
    next(flush_maybe(reply(From, Reply, Data1)), []);
active_call({leave, EntityId}, From, Data) ->
    {ok, Data1} = rules({leave, EntityId, left}, Data),
    next(flush_maybe(reply(From, ok, forget(EntityId, Data1))), []);
active_call(Request, _From, #data{id = Id}) ->
    ?LOG_NOTICE(#{what => unexpected_event, pairing => Id, type => call, event => Request}),
    keep_state_and_data.

%% The other instance's process, or an entity's.
down(Ref, Why, State, #data{mons = Mons, refs = Refs} = Data) ->
    case Mons of
        #{standby := Ref} -> ha({down, standby, Why}, Data#data{mons = maps:remove(standby, Mons)});
        #{active := Ref} -> ha({down, active, Why}, Data#data{mons = maps:remove(active, Mons)});
        #{} when State =:= starting; State =:= handing_over -> {keep_state_and_data, [postpone]};
        #{} ->
            case Refs of
                #{Ref := EntityId} ->
                    {_, Data1} = rules({detach, EntityId}, forget(EntityId, Data)),
                    next(flush_maybe(Data1), []);
                #{} ->
                    keep_state_and_data
            end
    end.

%% The connection is registered before the event runs: a resume delivers
%% again at once what the entity has not acknowledged. A refusal puts back
%% whatever was registered before.
join(Event, EntityId, Pid, From, #data{pids = Pids0} = Data0) ->
    Data = unpause(waiting, Data0),
    Old = maps:get(EntityId, Pids0, undefined),
    Ref = erlang:monitor(process, Pid),
    Data1 = Data#data{pids = Pids0#{EntityId => {Pid, Ref}},
                      refs = (Data#data.refs)#{Ref => EntityId}},
    case rules(Event, Data1) of
        {Ok, Data2} when Ok =:= ok; element(1, Ok) =:= ok ->
            ok = evatar_metrics:pairing_inc(Data2#data.metrics, evatar_pairing_joins_total, none),
            joined(Event, Pid, From, Old, Ok, Data2);
        {Error, Data2} ->
            ok = evatar_metrics:pairing_inc(Data2#data.metrics,
                                            evatar_pairing_join_refusals_total, none),
            true = erlang:demonitor(Ref, [flush]),
            Pids2 = case Old of
                        undefined -> maps:remove(EntityId, Data2#data.pids);
                        _ -> (Data2#data.pids)#{EntityId => Old}
                    end,
            Data3 = Data2#data{pids = Pids2, refs = maps:remove(Ref, Data2#data.refs)},
            next(flush_maybe(reply(From, Error, Data3)), [])
    end.

joined(Event, Pid, From, Old, Ok, #data{config = Config} = Data1) ->
    Data2 = case Old of
                {OldPid, OldRef} ->
                    _ = [OldPid ! {evatar, Data1#data.id,
                                   {dropped, session_resumed,
                                    <<"the session was resumed on another connection">>}}
                         || OldPid =/= Pid],
                    true = erlang:demonitor(OldRef, [flush]),
                    Data1#data{refs = maps:remove(OldRef, Data1#data.refs)};
                undefined ->
                    Data1
            end,
    {Resumed, Last} = case Ok of
                          {ok, R, L} -> {R, L};
                          ok -> {false, <<>>}
                      end,
    Info = #{join_timeout => maps:get(join_timeout, Config),
             epoch => epoch(Data2),
             resumed => Resumed, last_accepted => Last,
             dedup_window => maps:get(dedup_window, Config)},
    Data3 = case Event of
                {join, _, _, _} -> Data2;
                _ -> arm_silent(Data2)
            end,
    next(flush_maybe(reply(From, {ok, Info}, Data3)), []).

%% ---------------------------------------------------------------------------
%% The instance's role: evatar_ha_instance decides, this executes
%% ---------------------------------------------------------------------------

ha(Event, #data{inst = Inst} = Data) ->
    {Inst1, Effects} = evatar_ha_instance:handle(Event, view(Event, Data), Inst),
    effects(Effects, Data#data{inst = Inst1}, []).

%% A snapshot of what the instance needs to know of the cluster, the time
%% and the clients' connections. The replication's messages and the rules'
%% timers need only the options.
view(Event, #data{pids = Pids}) ->
    Nodes = evatar_cluster:configured(),
    Base = #{nodes => Nodes, heartbeat_ms => opt(heartbeat_ms), suspect_ms => opt(suspect_ms),
             self => node(), now => erlang:system_time(millisecond), conns => Pids},
    case Event of
        {msg, {Replication, _, _, _}} when Replication =:= confirm; Replication =:= events ->
            Base;
        {timeout, Key} when element(1, Key) =/= ha ->
            {message_queue_len, N} = erlang:process_info(self(), message_queue_len),
            Base#{queue_len => N};
        _ ->
            Lease = opt(lease_ms),
            {message_queue_len, Waiting} = erlang:process_info(self(), message_queue_len),
            Base#{queue_len => Waiting, alive => evatar_cluster:alive_nodes(),
                  majority => evatar_cluster:majority_now(),
                  heard => [N || N <- Nodes, evatar_cluster:heard_within(N, Lease)],
                  standby_opt => opt(standby) =:= true,
                  client_ack_timeout => opt(client_ack_timeout),
                  handover_on_silent_link => opt(handover_on_silent_link) =:= true}
    end.

%% ---------------------------------------------------------------------------
%% Pauses, held resumes, silent links
%% ---------------------------------------------------------------------------

%% This node was paused itself while this instance was active (SIGSTOP, a
%% laptop lid, a long GC): evatar_ha_instance asks the cluster again
%% (evatar_ha_core:after_pause/2). Nothing is fenced for the pause alone.
unpause(State, #data{gen = Gen} = Data) when State =:= waiting; State =:= bound ->
    case evatar_cluster:unstalled(Gen) of
        true ->
            Data;
        false ->
            {next_state, _, Data1, []} = ha(paused, Data),
            Data1
    end;
unpause(_State, Data) ->
    Data.

arm_held(#data{timers = #{{ha, held} := _}} = Data) ->
    Data;
arm_held(Data) ->
    timer({ha, held}, evatar_ha_role_machine:held_poll_ms(opt(heartbeat_ms)), Data).

%% evatar_ha_role_machine:held_due/3 says which held resumes are answered NotActive.
check_held(#data{held = Held, inst = Inst} = Data) ->
    Active = evatar_ha_instance:active(Inst),
    Ctx = #{suspect_ms => opt(suspect_ms), heartbeat_ms => opt(heartbeat_ms),
            electing => evatar_ha_instance:electing(Inst),
            heard_after => fun(Since) -> is_pid(Active) andalso
                                             evatar_cluster:heard_after(node(Active), Since)
                           end},
    {Go, Keep} = evatar_ha_role_machine:held_due(Held, erlang:monotonic_time(millisecond), Ctx),
    Data1 = reply_held(Data#data{held = Go}),
    case Keep of
        [] -> Data1#data{held = []};
        _ -> arm_held(Data1#data{held = Keep})
    end.

arm_silent(Data) ->
    effect({ensure_timer, {ha, silent},
            evatar_ha_instance:silent_poll_ms(opt(client_ack_timeout))},
           Data).

%% ---------------------------------------------------------------------------

opt(Key) -> evatar_cluster:opt(Key).

node_of(Pid) -> evatar_ha_instance:node_of(Pid).

%% ---------------------------------------------------------------------------
%% Executing the pure instance's effects: all I/O, nothing decided here
%% ---------------------------------------------------------------------------

%% What an inspection of the pairing shows.
-spec inspect(atom(), state(), data()) -> term().
inspect(ha, _State, Data) ->
    ha_status(Data);
inspect(What, State, #data{inst = Inst} = Data) ->
    Logic = evatar_ha_instance:logic(Inst),
    case What of
        summary -> (evatar_pairing_logic:summary(Logic))#{pid => self(), role => role(Data),
                                                           state => phase(State, Logic)};
        bindings -> evatar_pairing_logic:bindings(Logic);
        registry -> evatar_pairing_logic:registration_list(Logic);
        stats -> evatar_pairing_logic:stats(Logic);
        traffic -> evatar_pairing_logic:traffic(Logic);
        watchers -> length(Data#data.watchers);
        state -> Logic;
        %% One read of both: a state compared with another instance's
        %% only at the same version (tests).
        versioned_state -> {evatar_ha_instance:version(Inst), Logic}
    end.

%% (Re)arms the timer of `Key'.
-spec timer(term(), non_neg_integer(), data()) -> data().
timer(Key, Ms, #data{timers = Timers} = Data) ->
    ok = cancel(maps:get(Key, Timers, undefined)),
    Data#data{timers = Timers#{Key => erlang:start_timer(Ms, self(), Key)}}.

untimer(Key, #data{timers = Timers} = Data) ->
    ok = cancel(maps:get(Key, Timers, undefined)),
    Data#data{timers = maps:remove(Key, Timers)}.

cancel(undefined) -> ok;
cancel(TRef) -> erlang:cancel_timer(TRef, [{async, true}, {info, false}]).

%% The rules' timers only (every key but `{ha, _}').
cancel_rule_timers(#data{timers = Timers} = Data) ->
    {Ha, Rules} = maps:fold(fun({ha, _} = K, T, {H, L}) -> {H#{K => T}, L};
                               (_K, T, {H, L}) -> {H, [T | L]}
                            end, {#{}, []}, Timers),
    _ = [cancel(T) || T <- Rules],
    Data#data{timers = Ha}.

%% ---------------------------------------------------------------------------
%% The client traffic of an active, through the pure instance
%% ---------------------------------------------------------------------------

%% The state after an event: the instance's role (an active's is its
%% phase), with the actions to take.
-spec next(data(), [gen_statem:action()]) -> gen_statem:event_handler_result(state()).
next(#data{inst = Inst} = Data, Actions) ->
    case evatar_ha_instance:role(Inst) of
        active -> {next_state, evatar_pairing_logic:phase(evatar_ha_instance:logic(Inst)), Data,
                   Actions};
        Role -> {next_state, Role, Data, Actions}
    end.

-spec phase(state(), evatar_pairing_logic:state()) -> state().
phase(State, Logic) when State =:= waiting; State =:= bound ->
    evatar_pairing_logic:phase(Logic);
phase(State, _Logic) ->
    State.

-spec run(evatar_pairing_logic:event(), data()) -> data().
run(Event, Data) ->
    {_Reply, Data1} = rules(Event, Data),
    Data1.

%% One event of a client through the rules; returns their reply.
-spec rules(evatar_pairing_logic:event(), data()) -> {term(), data()}.
rules(Event, #data{inst = Inst, pids = Pids} = Data) ->
    Ctx = #{now => erlang:system_time(millisecond), conns => Pids},
    {Reply, Inst1, Effects} = evatar_ha_instance:rules(Event, Ctx, Inst),
    {Reply, execute(Effects, Data#data{inst = Inst1})}.

%% A GetBinding: the current report, to that entity only.
-spec report_binding(binary(), data()) -> data().
report_binding(EntityId, #data{inst = Inst, pids = Pids} = Data) ->
    pure(evatar_ha_instance:report_binding(EntityId, Pids, Inst), Data).

%% A call's reply, held like any other effect.
-spec reply(gen_statem:from(), term(), data()) -> data().
reply(From, Reply, #data{inst = Inst} = Data) ->
    pure(evatar_ha_instance:reply(From, Reply, Inst), Data).

-spec flush_maybe(data()) -> data().
flush_maybe(#data{inst = Inst} = Data) ->
    {message_queue_len, N} = erlang:process_info(self(), message_queue_len),
    pure(evatar_ha_instance:flush_maybe(N, Inst), Data).

-spec flush(data()) -> data().
flush(#data{inst = Inst} = Data) ->
    pure(evatar_ha_instance:flush(Inst), Data).

pure({Inst, Effects}, Data) ->
    execute(Effects, Data#data{inst = Inst}).

execute(Effects, Data) ->
    lists:foldl(fun effect/2, Data, Effects).

%% Ids in a report come from clients: cut to 64 bytes (evatar_log).
log(Level, Report, #data{id = Id}) ->
    ?LOG(Level, evatar_log:report(Report#{pairing => Id})).

tell(EntityId, Message, #data{id = Id, pids = Pids}) ->
    case Pids of
        #{EntityId := {Pid, _}} ->
            Pid ! {evatar, Id, Message},
            ok;
        #{} ->
            ok
    end.

-spec forget(binary(), data()) -> data().
forget(EntityId, #data{pids = Pids, refs = Refs} = Data) ->
    case Pids of
        #{EntityId := {_Pid, Ref}} ->
            true = erlang:demonitor(Ref, [flush]),
            Data#data{pids = maps:remove(EntityId, Pids), refs = maps:remove(Ref, Refs)};
        #{} ->
            Data
    end.

%% ---------------------------------------------------------------------------
%% The effects: all I/O
%% ---------------------------------------------------------------------------

%% Carries out the instance's effects, in order.
-spec effects([evatar_ha_instance:effect()], data(), [gen_statem:action()]) ->
          gen_statem:event_handler_result(state()).
effects([{stop, Why}], Data, _Actions) ->
    {stop, {shutdown, Why}, Data};
effects([postpone | Rest], Data, Actions) ->
    effects(Rest, Data, [postpone | Actions]);
effects([serve_held | Rest], #data{held = Held} = Data, Actions) ->
    Calls = [{next_event, {call, From}, Request} || {From, Request, _} <- lists:reverse(Held)],
    effects(Rest, Data#data{held = []}, lists:reverse(Calls, Actions));
effects([Effect | Rest], Data, Actions) ->
    effects(Rest, effect(Effect, Data), Actions);
effects([], Data, Actions) ->
    next(Data, lists:reverse(Actions)).

-spec effect(evatar_ha_instance:effect(), data()) -> data().
effect({send, To, Msg}, Data) ->
    ok = send(To, Msg, Data),
    Data;
effect({to_client, {conn, {Pid, _Ref}}, Msg}, #data{id = Id} = Data) ->
    Pid ! {evatar, Id, Msg},
    Data;
effect({to_client, EntityId, Msg}, Data) ->
    ok = tell(EntityId, Msg, Data),
    Data;
effect({drop, all, Code, Reason}, #data{id = Id, pids = Pids} = Data) ->
    %% The entities stay in the state, for a resume elsewhere.
    _ = [Pid ! {evatar, Id, {dropped, Code, Reason}} || {Pid, _} <- maps:values(Pids)],
    _ = [erlang:demonitor(Ref, [flush]) || {_, Ref} <- maps:values(Pids)],
    Data#data{pids = #{}, refs = #{}};
effect({drop, EntityId, Code, Reason}, Data) ->
    ok = tell(EntityId, {dropped, Code, Reason}, Data),
    forget(EntityId, Data);
effect({reply_to, From, R}, Data) ->
    gen_statem:reply(From, R),
    Data;
effect(flush_later, Data) ->
    self() ! evatar_flush,
    Data;
effect({stepped, Event, Effects, Now}, #data{id = Id} = Data) ->
    ok = evatar_metrics:pairing_step(Data#data.metrics, Event, Effects),
    case Data#data.watchers of
        [] -> Data;
        W -> Data#data{watchers = evatar_tap:emit(Id, Event, Effects, Now, W)}
    end;
effect({to_node, Node, Msg}, Data) ->
    ok = to_node(Node, Msg, Data),
    Data;
effect({monitor, Which, Pid}, #data{mons = Mons} = Data) ->
    _ = [erlang:demonitor(M, [flush]) || M <- [maps:get(Which, Mons, undefined)], is_reference(M)],
    case Pid of
        none -> Data#data{mons = maps:remove(Which, Mons)};
        _ -> Data#data{mons = Mons#{Which => erlang:monitor(process, Pid)}}
    end;
effect({timer, Key, Ms}, Data) ->
    timer(Key, Ms, Data);
effect({ensure_timer, Key, Ms}, #data{timers = Timers} = Data) ->
    case Timers of
        #{Key := _} -> Data;
        #{} -> timer(Key, Ms, Data)
    end;
effect({cancel_timer, Key}, Data) ->
    untimer(Key, Data);
effect(cancel_rule_timers, Data) ->
    cancel_rule_timers(Data);
effect(serving, #data{id = Id} = Data) ->
    Data#data{gen = evatar_cluster:stall_gen(), metrics = evatar_metrics:pairing(Id)};
effect(pause_seen, Data) ->
    Data#data{gen = evatar_cluster:stall_gen()};
effect(publish, Data) ->
    publish(Data);
effect(reconfirmed, #data{inspects = Waiting} = Data) ->
    %% The inspections that waited for the reconfirmation, in order.
    {next_state, State, _, _} = next(Data, []),
    _ = [gen_statem:reply(From, inspect(What, State, Data))
         || {From, What} <- lists:reverse(Waiting)],
    Data#data{inspects = []};
effect(reply_held, Data) ->
    reply_held(Data);
effect({metric, Name}, Data) ->
    ok = evatar_metrics:inc(Name),
    Data;
effect({metric, Name, Label}, Data) ->
    ok = evatar_metrics:inc(Name, Label),
    Data;
effect({log, Level, Report}, Data) ->
    ok = log(Level, Report, Data),
    Data.

%% The requests to a node's cluster service (evatar_ha_proto_v1).
to_node(Node, ask, #data{id = Id}) ->
    evatar_ha_proto_v1:ask(Node, Id, self());
to_node(Node, {start_standby, Config}, #data{id = Id} = Data) ->
    evatar_ha_proto_v1:start_standby(Node, Id, Config, self(), epoch(Data));
to_node(Node, {vote, Ec, Claim, Active, Dead}, #data{id = Id}) ->
    evatar_ha_proto_v1:vote(Node, Id, Ec, self(), Claim, Active, Dead);
to_node(Node, {restore_vote, Ec, NoneOn}, #data{id = Id}) ->
    evatar_ha_proto_v1:restore_vote(Node, Id, Ec, self(), NoneOn);
to_node(Node, {register, {E, Seq}}, #data{id = Id}) ->
    evatar_ha_proto_v1:register(Node, Id, E, Seq, self()).

%% The messages to the other instance (evatar_ha_proto_v1).
send(To, {offer, Version}, _Data) -> evatar_ha_proto_v1:offer(To, self(), Version);
send(To, dismiss, _Data) -> evatar_ha_proto_v1:dismiss(To, self());
send(To, {resync, Version}, _Data) -> evatar_ha_proto_v1:resync(To, self(), Version);
send(To, {confirm, Version}, Data) -> evatar_ha_proto_v1:confirm(To, epoch(Data), Version);
send(To, {stale, Epoch}, _Data) -> evatar_ha_proto_v1:stale(To, self(), Epoch);
send(To, {handover, Version}, Data) -> evatar_ha_proto_v1:handover(To, epoch(Data), Version);
send(To, {handover_done, Ec, Claim}, _Data) ->
    evatar_ha_proto_v1:handover_done(To, self(), Ec, Claim);
send(To, {events, Events}, Data) -> evatar_ha_proto_v1:events(To, epoch(Data), Events);
send(To, {snapshot, Version, Logic, Claim}, Data) ->
    evatar_ha_proto_v1:snapshot(To, epoch(Data), Version, Logic, Claim).

publish(#data{id = Id, inst = Inst} = Data) ->
    Role = role(Data),
    Peer = case Role of
               standby -> evatar_ha_instance:active(Inst);
               _ -> evatar_ha_instance:standby(Inst)
           end,
    ok = evatar_registry:set_role(Id, self(), Role, epoch(Data), Peer),
    case Data of
        #data{watchers = []} -> Data;
        _ when Role =:= active -> Data;
        #data{watchers = Watchers} -> Data#data{watchers = evatar_tap:moved(Id, Role, Watchers)}
    end.

%% The role as the registry and inspections show it: a handover under way
%% is still the active.
-spec role(data()) -> atom().
role(#data{inst = Inst}) ->
    case evatar_ha_instance:role(Inst) of
        handing_over -> active;
        Role -> Role
    end.

%% The resumes a standby held are answered NotActive.
-spec reply_held(data()) -> data().
reply_held(#data{held = Held, inst = Inst} = Data) ->
    Node = node_of(evatar_ha_instance:active(Inst)),
    _ = [gen_statem:reply(From, {error, {not_active, Node}}) || {From, _, _} <- Held],
    Data#data{held = []}.

%% `evatar:ha_status/1''s answer.
-spec ha_status(data()) -> map().
ha_status(#data{inst = Inst} = Data) ->
    Role = role(Data),
    {Active, Standby} = case Role of
                            standby -> {evatar_ha_instance:active(Inst), undefined};
                            starting -> {evatar_ha_instance:active(Inst), undefined};
                            _ -> {self(), evatar_ha_instance:standby(Inst)}
                        end,
    #{role => Role, epoch => epoch(Data), node => node(), active => Active, standby => Standby,
      standby_node => node_of(Standby),
      synced => case Role of
                    standby -> true;
                    _ -> evatar_ha_instance:synced(Inst)
                end,
      version => evatar_ha_instance:version(Inst)}.

%% The pairing's epoch (0 while starting).
-spec epoch(data()) -> non_neg_integer().
epoch(#data{inst = Inst}) -> evatar_ha_instance:epoch(Inst).

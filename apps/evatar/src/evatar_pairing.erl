%% @doc Internal. The process of one instance of a pairing: a shell that
%% runs three pure modules and executes their effects. `evatar_pairing_logic'
%% decides the pairing's rules, `evatar_ha_commit' which effects go out
%% now and which wait for the standby or the cluster, `evatar_ha_core' the
%% configuration, elections and registrations (docs/architecture.md,
%% sections 5 and 8). This process owns what cannot be replicated: the pids
%% of the entities' processes and of the other instance, their monitors,
%% and one map of timers keyed by what they are for (a logic timer key, or
%% `{ha, Key}'). An instance is the `active' one or the `standby' of an
%% active on another node.
%%
%% ```
%%                 start_link
%%                     |
%%                     v
%%              +----------+  create: active at once; restart after a crash,
%%              | starting |  or asked to be a standby: ask the peers, offer
%%              +----------+  ourselves to the active found
%%               |        |
%%   none found  |        | snapshot received
%%               v        v
%%  +-----------------+  takeover: election won (active dead or  +---------+
%%  | active          | <---- silent), or handover ------------- | standby |
%%  | waiting | bound |                                          |         |
%%  |                 | ---- handover (silent client link) ----> |         |
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
%% The active's state name is the logic's {@link evatar_pairing_logic:phase/1}
%% (`waiting' or `bound'); `handing_over' is the short planned-handover
%% step. Acks are batched until the mailbox is empty.
-module(evatar_pairing).
-behaviour(gen_statem).

%% A pairing idle this long compacts its heap: a home's pairing is quiet
%% most of the time.
-define(HIBERNATE_AFTER, 5000).
-define(PLACE_RETRY_MS, 1000).

-include_lib("kernel/include/logger.hrl").

-export([start_link/2, start_link/3]).
-export([init/1, callback_mode/0, handle_event/4, terminate/3]).

-export_type([mode/0]).

-type mode() :: create | {standby_for, pid()}.
-type role() :: starting | active | standby | fenced.
-type state() :: starting | evatar_pairing_logic:phase() | standby | fenced | handing_over.
%% The timers of this process, all in one map: the logic's, and the
%% shell's own (`{ha, Key}').
-type timer_key() :: evatar_pairing_logic:timer_key()
                   | {ha, election | register | start | handover | place | held | silent}.

-record(data, {id :: evatar:pairing_id(),
               config :: evatar_pairing_logic:config(),
               mode :: mode(),
               role = starting :: role(),
               logic :: evatar_pairing_logic:state() | undefined,
               commit = evatar_ha_commit:new(0) :: evatar_ha_commit:state(),
               core = evatar_ha_core:new() :: evatar_ha_core:state(),
               pids = #{} :: #{binary() => {pid(), reference()}},
               refs = #{} :: #{reference() => binary()},
               timers = #{} :: #{timer_key() => reference()},
               %% Active: its standby; standby (and starting): its active.
               standby :: pid() | undefined,
               standby_mon :: reference() | undefined,
               placing = false :: boolean(),
               active :: pid() | undefined,
               active_mon :: reference() | undefined,
               active_lost = false :: boolean(),
               %% The stall generation this active began serving at; after a
               %% pause, inspections wait for the reconfirmation.
               gen = 0 :: non_neg_integer(),
               reconfirming = false :: boolean(),
               inspects = [] :: [{gen_statem:from(), atom()}],
               %% Standby: resumes held until it takes over or hears its active.
               held = [] :: [{gen_statem:from(), term(), integer()}],
               %% Starting: the peers asked and their answers.
               start :: evatar_ha_roles:starting() | undefined,
               %% The live tail's watchers (evatar_tap): [] costs nothing.
               watchers = [] :: [evatar_tap:watcher()],
               %% This pairing's own counters once active here (evatar_metrics).
               metrics = undefined :: evatar_metrics:pairing_ref()}).

%% @doc Starts a new pairing (the active), registered as
%% `{via, evatar_registry, PairingId}'.
-spec start_link(evatar:pairing_id(), evatar_pairing_logic:config()) ->
          {ok, pid()} | {error, term()}.
start_link(PairingId, Config) ->
    start_link(PairingId, Config, create).

%% @doc Starts an instance: `create' (a new pairing, active) or
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
    {ok, starting, #data{id = PairingId, config = Config, mode = Mode},
     [{next_event, internal, load}]}.

%% @private
%% Events are sorted by kind first, then by state, in functions of their
%% own: no clause relies on coming after another of a different state.
-spec handle_event(gen_statem:event_type(), term(), state(), #data{}) ->
          gen_statem:event_handler_result(state()).
handle_event(info, {timeout, TRef, Key}, State, #data{timers = Timers} = Data) ->
    case Timers of
        #{Key := TRef} -> timeout(Key, State, Data);
        #{} -> keep_state_and_data  % cancelled or replaced meanwhile
    end;
handle_event(Type, Event, starting, Data) ->
    starting(Type, Event, Data);
handle_event(info, {evatar_ha, 1, Body}, State, Data) ->
    ha(Body, State, Data);
handle_event(info, {evatar_cluster, Event}, State, Data) ->
    cluster_event(Event, State, Data);
handle_event(info, {'DOWN', Ref, process, _, Why}, State, Data) ->
    down(Ref, Why, State, Data);
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
handle_event(internal, handover, handing_over, Data) ->
    {keep_state, send_handover(Data)};
handle_event(_Type, _Event, handing_over, _Data) ->
    {keep_state_and_data, [postpone]};
handle_event(cast, _Request, _StandbyOrFenced, _Data) ->
    %% Not accepted, so never acknowledged: the client sends it again to
    %% the active.
    keep_state_and_data;
handle_event(Type, Event, _State, #data{id = Id}) ->
    ?LOG_NOTICE(#{what => unexpected_event, pairing => Id, type => Type, event => Event}),
    keep_state_and_data.

%% ---------------------------------------------------------------------------
%% Starting: ask the peers, or offer to be the standby of the active found
%% ---------------------------------------------------------------------------

starting(internal, load, #data{id = Id, mode = Mode} = Data) ->
    start(evatar_ha_roles:start(Mode, evatar_registry:previous(Id), peers(), suspect_ms()), Data);
starting(info, {evatar_ha, 1, {instance, Id, Node, Info}}, #data{id = Id} = Data) ->
    start_event({instance, Node, Info}, Data);
starting(info, {evatar_ha, 1, {snapshot, Active, _Epoch, Version, State, Claim}},
         #data{active = Active} = Data) ->
    become_standby(Version, State, Claim, Data);
starting(info, {evatar_ha, 1, {dismiss, Active}}, #data{active = Active} = Data) ->
    stop_instance(dismissed, Data);
starting(info, {'DOWN', Ref, process, _, _}, #data{active_mon = Ref} = Data) ->
    stop_instance(active_gone, Data);
starting({call, From}, {inspect, ha}, Data) ->
    {keep_state_and_data, [{reply, From, ha_status(Data)}]};
starting(_Type, _Event, _Data) ->
    {keep_state_and_data, [postpone]}.

%% evatar_ha_roles decides how this instance starts; this executes it.
start_event(Event, #data{start = S} = Data) ->
    start(evatar_ha_roles:starting(Event, suspect_ms(), S), Data).

start({S, Effects}, Data) ->
    start_effects(Effects, Data#data{start = S}).

start_effects([{log, Level, Report} | Rest], #data{id = Id} = Data) ->
    ?LOG(Level, Report#{pairing => Id}),
    start_effects(Rest, Data);
start_effects([{ask, Peers} | Rest], #data{id = Id} = Data) ->
    _ = [evatar_ha_proto_v1:ask(N, Id, self()) || N <- Peers],
    start_effects(Rest, Data);
start_effects([{timer, Key, Ms} | Rest], Data) ->
    start_effects(Rest, timer({ha, Key}, Ms, Data));
start_effects([{offer, Active}], #data{commit = C} = Data) ->
    Mon = erlang:monitor(process, Active),
    ok = evatar_ha_proto_v1:offer(Active, self(), evatar_ha_commit:version(C)),
    {keep_state, timer({ha, offered}, 5 * suspect_ms() + 2000,
                       Data#data{active = Active, active_mon = Mon})};
start_effects([become_active], Data) ->
    become_active(Data);
start_effects([], Data) ->
    {keep_state, Data}.

%% ---------------------------------------------------------------------------
%% Timers: one map, keyed by what each is for
%% ---------------------------------------------------------------------------

timeout({ha, Key}, State, #data{timers = Timers} = Data) ->
    ha_timeout(Key, State, Data#data{timers = maps:remove({ha, Key}, Timers)});
timeout(Key, State, #data{timers = Timers} = Data) when State =:= waiting; State =:= bound ->
    Data1 = run({timeout, Key}, Data#data{timers = maps:remove(Key, Timers)}),
    next(flush_maybe(Data1), []);
timeout(_Key, State, _Data) when State =:= fenced; State =:= handing_over ->
    %% Runs if this instance serves again (a handover aborted).
    {keep_state_and_data, [postpone]};
timeout(_Key, _State, _Data) ->
    keep_state_and_data.

ha_timeout(asked, starting, Data) -> start_event({timeout, asked}, Data);
ha_timeout(retry_ask, starting, Data) -> start_event({timeout, retry_ask, peers()}, Data);
ha_timeout(offered, starting, Data) -> stop_instance(no_snapshot, Data);
ha_timeout(election, State, Data) -> core({timeout, election}, State, Data);
ha_timeout(register, State, Data) -> core({timeout, register}, State, Data);
ha_timeout(place, State, Data) -> {keep_state, place(State, Data#data{placing = false})};
ha_timeout(held, standby, Data) -> {keep_state, check_held(Data)};
ha_timeout(silent, State, Data) when State =:= waiting; State =:= bound -> silent_check(Data);
ha_timeout(handover, handing_over, #data{id = Id} = Data) ->
    ?LOG_WARNING(#{what => handover_aborted, pairing => Id}),
    next(Data, []);
ha_timeout(_Key, _State, Data) ->
    {keep_state, Data}.

%% (Re)arms the timer of `Key'.
timer(Key, Ms, #data{timers = Timers} = Data) ->
    ok = cancel(maps:get(Key, Timers, undefined)),
    Data#data{timers = Timers#{Key => erlang:start_timer(Ms, self(), Key)}}.

untimer(Key, #data{timers = Timers} = Data) ->
    ok = cancel(maps:get(Key, Timers, undefined)),
    Data#data{timers = maps:remove(Key, Timers)}.

cancel(undefined) -> ok;
cancel(TRef) -> erlang:cancel_timer(TRef, [{async, true}, {info, false}]).

%% The logic's timers only: re-armed from its state on a takeover, dropped
%% on a handover.
cancel_logic_timers(#data{timers = Timers} = Data) ->
    {Ha, Logic} = maps:fold(fun({ha, _} = K, T, {H, L}) -> {H#{K => T}, L};
                               (_K, T, {H, L}) -> {H, [T | L]}
                            end, {#{}, []}, Timers),
    _ = [cancel(T) || T <- Logic],
    Data#data{timers = Ha}.

arm_logic_timers(#data{logic = Logic} = Data) ->
    Now = erlang:system_time(millisecond),
    lists:foldl(fun({Key, Ms}, D) -> timer(Key, Ms, D) end, cancel_logic_timers(Data),
                evatar_pairing_logic:timers(Logic, Now)).

%% ---------------------------------------------------------------------------
%% Calls
%% ---------------------------------------------------------------------------

call({inspect, What}, From, State, Data0) ->
    %% An active whose node was paused since it began serving asks the
    %% cluster whether it is still the active and says nothing until it
    %% knows: never `active' beside a standby that took over meanwhile.
    Data = case stalled_active(State, Data0) of
               true -> paused(Data0);
               false -> Data0
           end,
    case Data of
        #data{reconfirming = true, inspects = Waiting} ->
            {keep_state, Data#data{inspects = [{From, What} | Waiting]}};
        #data{} ->
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
call(_Request, _From, handing_over, _Data) ->
    {keep_state_and_data, [postpone]};
call(delete, From, _State, #data{id = Id, standby = Standby}) ->
    ?LOG_INFO(#{what => pairing_deleted, pairing => Id}),
    _ = [evatar_ha_proto_v1:dismiss(Standby, self()) || is_pid(Standby)],
    {stop_and_reply, normal, [{reply, From, ok}]};
call({tap_watch, Pid, Filter}, From, State, #data{id = Id} = Data)
  when is_pid(Pid), is_map(Filter), (State =:= waiting orelse State =:= bound) ->
    case evatar_tap:add(Pid, Filter, Data#data.watchers, Id) of
        {ok, Ref, Watchers} ->
            {keep_state, Data#data{watchers = Watchers}, [{reply, From, {ok, Ref}}]};
        {error, _} = Error ->
            {keep_state_and_data, [{reply, From, Error}]}
    end;
call({tap_watch, _, _}, From, standby, #data{active = Active}) ->
    {keep_state_and_data, [{reply, From, {redirect, Active}}]};
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
call(_Request, From, standby, #data{active = Active}) ->
    {keep_state_and_data, [{reply, From, {error, {not_active, node_of(Active)}}}]};
call(_Request, From, fenced, _Data) ->
    {keep_state_and_data, [{reply, From, {error, fenced}}]};
call(Request, From, _Active, Data) ->
    active_call(Request, From, Data).

inspect(ha, _State, Data) ->
    ha_status(Data);
inspect(What, State, #data{logic = Logic, commit = C} = Data) ->
    case What of
        summary -> (evatar_pairing_logic:summary(Logic))#{pid => self(),
                                                           role => Data#data.role,
                                                           state => phase(State, Logic)};
        bindings -> evatar_pairing_logic:bindings(Logic);
        registry -> evatar_pairing_logic:registration_list(Logic);
        stats -> evatar_pairing_logic:stats(Logic);
        watchers -> length(Data#data.watchers);
        state -> Logic;
        %% One read of both: a state compared with another instance's
        %% only at the same version (tests).
        versioned_state -> {evatar_ha_commit:version(C), Logic}
    end.

%% The reconfirmation after a pause is over (accepted, or fenced): the
%% inspections that waited for it are answered, in order.
reconfirmed(State, #data{inspects = Waiting} = Data) ->
    Data1 = Data#data{reconfirming = false, inspects = []},
    _ = [gen_statem:reply(From, inspect(What, State, Data1))
         || {From, What} <- lists:reverse(Waiting)],
    Data1.

%% @private
%% Only an orderly stop runs this (the process does not trap exits): tell
%% every entity's process, so it can close its connection with a reason.
-spec terminate(term(), state(), #data{}) -> ok.
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
    {ok, Data1} = step({leave, EntityId, left}, Data),
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
    {Reply, Data1} = step({describe, EntityId, Description}, Data),
    next(flush_maybe(reply(From, Reply, Data1)), []);
active_call({leave, EntityId}, From, Data) ->
    {ok, Data1} = step({leave, EntityId, left}, Data),
    next(flush_maybe(reply(From, ok, forget(EntityId, Data1))), []);
active_call(Request, _From, #data{id = Id}) ->
    ?LOG_NOTICE(#{what => unexpected_event, pairing => Id, type => call, event => Request}),
    keep_state_and_data.

%% The other instance's process, or an entity's.
down(Ref, Why, State, #data{standby_mon = Ref} = Data) ->
    standby_down(Why, State, Data);
down(Ref, Why, standby, #data{active_mon = Ref} = Data) ->
    active_down(Why, Data#data{active_mon = undefined});
down(Ref, _Why, _State, #data{active_mon = Ref} = Data) ->
    {keep_state, Data#data{active_mon = undefined}};
down(_Ref, _Why, handing_over, _Data) ->
    {keep_state_and_data, [postpone]};
down(Ref, _Why, _State, #data{refs = Refs} = Data) ->
    case Refs of
        #{Ref := EntityId} ->
            {_, Data1} = step({detach, EntityId}, forget(EntityId, Data)),
            next(flush_maybe(Data1), []);
        #{} ->
            keep_state_and_data
    end.

%% The connection is registered before the event runs: a resume delivers
%% again at once what the entity has not acknowledged. A refusal puts back
%% whatever was registered before.
join(Event, EntityId, Pid, From, #data{pids = Pids0, refs = Refs} = Data0) ->
    Data = case stalled_active(waiting, Data0) of
               true -> paused(Data0);
               false -> Data0
           end,
    Old = maps:get(EntityId, Pids0, undefined),
    Ref = erlang:monitor(process, Pid),
    Data1 = Data#data{pids = Pids0#{EntityId => {Pid, Ref}}, refs = Refs#{Ref => EntityId}},
    case step(Event, Data1) of
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
             epoch => evatar_pairing_logic:epoch(Data2#data.logic),
             resumed => Resumed, last_accepted => Last,
             dedup_window => maps:get(dedup_window, Config)},
    Data3 = case Event of
                {join, _, _, _} -> Data2;
                _ -> arm_silent(Data2)
            end,
    next(flush_maybe(reply(From, {ok, Info}, Data3)), []).

%% ---------------------------------------------------------------------------
%% Running the logic, and the output commit
%% ---------------------------------------------------------------------------

next(#data{role = active, logic = Logic} = Data, Actions) ->
    {next_state, evatar_pairing_logic:phase(Logic), Data, Actions};
next(#data{role = Role} = Data, Actions) ->
    {next_state, Role, Data, Actions}.

phase(State, Logic) when State =:= waiting; State =:= bound ->
    evatar_pairing_logic:phase(Logic);
phase(State, _Logic) ->
    State.

run(Event, Data) ->
    {_Reply, Data1} = step(Event, Data),
    Data1.

%% Applies one event to the logic; evatar_ha_commit says what of its
%% effects goes out now. Returns the logic's reply (`ok' for events that
%% have none).
step(Event, #data{logic = Logic, commit = C, pids = Pids} = Data) ->
    Now = erlang:system_time(millisecond),
    {Logic1, Effects} = evatar_pairing_logic:handle(Event, Now, Logic),
    ok = evatar_metrics:pairing_step(Data#data.metrics, Event, Effects),
    Watchers = case Data#data.watchers of
                   [] -> [];
                   W -> evatar_tap:emit(Data#data.id, Event, Effects, Now, W)
               end,
    Conns = maps:map(fun(_, {Pid, _}) -> Pid end, Pids),
    {Reply, Out, C1} = evatar_ha_commit:step(Event, Now, Effects, Conns, mode(Data), C),
    {Reply, execute(Out, Data#data{logic = Logic1, commit = C1, watchers = Watchers})}.

mode(#data{standby = undefined, core = Core}) ->
    case evatar_ha_core:holding(Core) of
        true -> held;
        false -> direct
    end;
mode(#data{}) ->
    replicated.

%% A GetBinding (docs/protocol.md section 2): the current report, to that
%% entity only. It changes no state, so it is not shipped to the standby.
report_binding(EntityId, #data{logic = Logic, pids = Pids, commit = C} = Data) ->
    {_, Effects} = evatar_pairing_logic:handle({report_binding, EntityId}, 0, Logic),
    Sends = [{send, Pid, {bound, R}} || {report, E, R} <- Effects,
                                        {Pid, _} <- [maps:get(E, Pids, {undefined, x})],
                                        is_pid(Pid)],
    {Out, C1} = evatar_ha_commit:report(Sends, mode(Data), C),
    execute(Out, Data#data{commit = C1}).

%% A call's reply, held like any other effect.
reply(From, Reply, #data{commit = C} = Data) ->
    {Out, C1} = evatar_ha_commit:reply(From, Reply, mode(Data), C),
    execute(Out, Data#data{commit = C1}).

flush_maybe(#data{commit = C} = Data) ->
    {message_queue_len, N} = erlang:process_info(self(), message_queue_len),
    {Out, C1} = evatar_ha_commit:flush_maybe(N, mode(Data), C),
    execute(Out, Data#data{commit = C1}).

flush(#data{commit = C} = Data) ->
    {Out, C1} = evatar_ha_commit:flush(mode(Data), C),
    execute(Out, Data#data{commit = C1}).

%% The standby confirmed `V': what was held for it goes out.
release(V, #data{commit = C} = Data) ->
    {Out, C1} = evatar_ha_commit:confirm(V, C),
    execute(Out, Data#data{commit = C1}).

%% No standby any more, or the cluster accepted this active's
%% configuration: everything held goes out now.
release_all(#data{commit = C} = Data) ->
    {Out, C1} = evatar_ha_commit:release_all(C),
    execute(Out, Data#data{commit = C1}).

execute([{deliver, EntityId, Signal} | Rest], Data) ->
    ok = tell(EntityId, {signal, Signal}, Data),
    execute(Rest, Data);
execute([{report, EntityId, Report} | Rest], Data) ->
    ok = tell(EntityId, {bound, Report}, Data),
    execute(Rest, Data);
execute([{drop, EntityId, Code, Reason} | Rest], Data) ->
    ok = tell(EntityId, {dropped, Code, Reason}, Data),
    execute(Rest, forget(EntityId, Data));
execute([{send, Pid, Msg} | Rest], #data{id = Id} = Data) ->
    Pid ! {evatar, Id, Msg},
    execute(Rest, Data);
execute([{reply_to, From, R} | Rest], Data) ->
    gen_statem:reply(From, R),
    execute(Rest, Data);
execute([{acks, Acks} | Rest], #data{id = Id, pids = Pids} = Data) ->
    maps:foreach(fun(EntityId, SignalId) ->
                         case Pids of
                             #{EntityId := {Pid, _}} -> Pid ! {evatar, Id, {ack, SignalId}};
                             #{} -> ok
                         end
                 end, Acks),
    execute(Rest, Data);
execute([{ship, Events} | Rest], #data{standby = Standby, logic = Logic} = Data) ->
    ok = evatar_ha_proto_v1:events(Standby, evatar_pairing_logic:epoch(Logic), Events),
    execute(Rest, Data);
execute([flush_later | Rest], Data) ->
    self() ! evatar_flush,
    execute(Rest, Data);
execute([{start_timer, Key, Ms} | Rest], Data) ->
    execute(Rest, timer(Key, Ms, Data));
execute([{cancel_timer, Key} | Rest], Data) ->
    execute(Rest, untimer(Key, Data));
execute([{log, Level, Report} | Rest], #data{id = Id} = Data) ->
    %% Ids in a report come from clients: cut to 64 bytes (evatar_log).
    ?LOG(Level, evatar_log:report(Report#{pairing => Id})),
    execute(Rest, Data);
execute([], Data) ->
    Data.

tell(EntityId, Message, #data{id = Id, pids = Pids}) ->
    case Pids of
        #{EntityId := {Pid, _}} ->
            Pid ! {evatar, Id, Message},
            ok;
        #{} ->
            ok
    end.

forget(EntityId, #data{pids = Pids, refs = Refs} = Data) ->
    case Pids of
        #{EntityId := {_Pid, Ref}} ->
            true = erlang:demonitor(Ref, [flush]),
            Data#data{pids = maps:remove(EntityId, Pids), refs = maps:remove(Ref, Refs)};
        #{} ->
            Data
    end.

%% Tells every connected entity's process to close with `Code' (the entity
%% stays in the state, for a resume elsewhere) and forgets them all.
disconnect_all(Code, Reason, #data{id = Id, pids = Pids} = Data) ->
    _ = [Pid ! {evatar, Id, {dropped, Code, Reason}} || {Pid, _} <- maps:values(Pids)],
    _ = [erlang:demonitor(Ref, [flush]) || {_, Ref} <- maps:values(Pids)],
    Data#data{pids = #{}, refs = #{}}.

%% ---------------------------------------------------------------------------
%% Roles
%% ---------------------------------------------------------------------------

become_active(#data{id = Id, config = Config} = Data) ->
    Logic = evatar_pairing_logic:new(Id, Config),
    ?LOG_INFO(#{what => pairing_started, pairing => Id}),
    Data1 = publish(left_starting(Data#data{logic = Logic, role = active,
                                            gen = evatar_cluster:stall_gen(),
                                            metrics = evatar_metrics:pairing(Id)})),
    {next_state, evatar_pairing_logic:phase(Logic), place_soon(Data1)}.

become_standby(Version, State, Claim, #data{id = Id, active = Active, commit = C} = Data) ->
    ok = evatar_ha_proto_v1:confirm(Active, evatar_pairing_logic:epoch(State), Version),
    ?LOG_INFO(#{what => standby_synced, pairing => Id, active => node_of(Active),
                version => Version}),
    {Core, []} = evatar_ha_core:handle({claim, Claim}, ctx(standby, Data), Data#data.core),
    Data1 = publish(left_starting(Data#data{logic = State, role = standby, core = Core,
                                            commit = evatar_ha_commit:applied(Version, C),
                                            active_lost = false})),
    {next_state, standby, Data1}.

left_starting(Data) ->
    lists:foldl(fun untimer/2, Data, [{ha, asked}, {ha, retry_ask}, {ha, offered}]).

%% An instance that won the election at `Epoch' takes over: a standby
%% (fully applied up to its version) or a fenced active asking again. It
%% holds every effect until the cluster accepted its new configuration
%% (evatar_ha_core); then it releases them and places a standby. Resumes
%% held while it was a standby are served now.
take_over(Why, Epoch, #data{id = Id, active_mon = Mon, standby_mon = SMon, commit = C} = Data) ->
    _ = [erlang:demonitor(M, [flush]) || M <- [Mon, SMon], is_reference(M)],
    _ = [evatar_ha_proto_v1:dismiss(P, self()) || P <- [Data#data.standby], is_pid(P)],
    ?LOG_WARNING(#{what => takeover, pairing => Id, epoch => Epoch, reason => Why,
                   version => evatar_ha_commit:version(C)}),
    ok = evatar_metrics:inc(evatar_takeovers_total, takeover_reason(Why)),
    Data1 = Data#data{role = active, metrics = evatar_metrics:pairing(Id), active = undefined,
                      active_mon = undefined, active_lost = false, standby = undefined,
                      standby_mon = undefined, commit = evatar_ha_commit:unsync(C),
                      gen = evatar_cluster:stall_gen(), held = []},
    {_, Data2} = step({takeover, Epoch}, arm_logic_timers(Data1)),
    next(arm_silent(publish(Data2)),
         [{next_event, {call, From}, Request} || {From, Request, _} <- lists:reverse(Data#data.held)]).

takeover_reason({Why, _}) -> Why;
takeover_reason(Why) -> Why.

publish(#data{id = Id, role = Role, logic = Logic} = Data) ->
    Peer = case Role of
               standby -> Data#data.active;
               _ -> Data#data.standby
           end,
    ok = evatar_registry:set_role(Id, self(), Role, epoch(Logic), Peer),
    case Data of
        #data{watchers = []} -> Data;
        #data{role = active} -> Data;
        #data{watchers = Watchers} -> Data#data{watchers = evatar_tap:moved(Id, Role, Watchers)}
    end.

stop_instance(Why, #data{id = Id} = Data) ->
    ?LOG_INFO(#{what => instance_stopped, pairing => Id, reason => Why}),
    {stop, {shutdown, Why}, Data}.

%% A newer active exists: close the clients (they resume there) and go.
step_down(Why, #data{id = Id} = Data) ->
    ?LOG_WARNING(#{what => stepping_down, pairing => Id, reason => Why}),
    ok = evatar_metrics:inc(evatar_step_downs_total),
    Data1 = disconnect_all(stale_epoch, <<"a newer instance of this pairing is active">>, Data),
    {stop, {shutdown, Why}, Data1}.

%% ---------------------------------------------------------------------------
%% The standby: placed by the active on the next alive node
%% ---------------------------------------------------------------------------

wants_standby(#data{role = active, standby = undefined, placing = false}) ->
    evatar_cluster:opt(standby) =:= true andalso evatar_cluster:size() > 1;
wants_standby(_) ->
    false.

place_soon(Data) ->
    case wants_standby(Data) of
        true -> timer({ha, place}, 0, Data);
        false -> Data
    end.

%% Asks the next alive node to start a standby; tried again later when
%% nothing came of it.
place(State, #data{id = Id, config = Config, logic = Logic} = Data)
  when State =:= waiting; State =:= bound ->
    case wants_standby(Data) of
        true ->
            case evatar_cluster:place_standby(maps:get(standby_node, Config, undefined)) of
                none ->
                    Data;
                Node ->
                    ok = evatar_ha_proto_v1:start_standby(Node, Id, Config, self(),
                                                          evatar_pairing_logic:epoch(Logic)),
                    timer({ha, place}, ?PLACE_RETRY_MS, Data#data{placing = true})
            end;
        false ->
            Data
    end;
place(_State, Data) ->
    Data.

%% A new standby gets the whole state and a new claim: the configuration
%% with it as the standby. The snapshot holds every event queued so far.
snapshot_to(#data{standby = Standby, logic = Logic, commit = C, core = Core} = Data) ->
    {Claim, Core1} = evatar_ha_core:next_claim(Core),
    ok = evatar_ha_proto_v1:snapshot(Standby, evatar_pairing_logic:epoch(Logic),
                                     evatar_ha_commit:version(C), Logic, Claim),
    Data#data{commit = evatar_ha_commit:shipped(C), core = Core1}.

%% The standby's process died (its node is up): it cannot take over, so go
%% on without it at once. Its node is lost or silent: it may be taking over
%% (a partition looks the same), so first the cluster must accept a
%% configuration without it (evatar_ha_core); everything stays held until then.
standby_down(Why, State, #data{id = Id, standby = Standby} = Data) ->
    ?LOG_WARNING(#{what => standby_lost, pairing => Id, standby => node_of(Standby),
                   reason => Why}),
    case Why of
        noconnection ->
            {keep_state, Data1} = core(standby_node_lost, State, forget_standby(Data)),
            {keep_state, publish(Data1)};
        _ ->
            {keep_state, place(State, publish(release_all(forget_standby(Data))))}
    end.

forget_standby(#data{standby = Standby, standby_mon = Mon, commit = C} = Data) ->
    _ = [erlang:demonitor(Mon, [flush]) || is_reference(Mon)],
    _ = [evatar_ha_proto_v1:dismiss(Standby, self()) || is_pid(Standby)],
    Data#data{standby = undefined, standby_mon = undefined, commit = evatar_ha_commit:unsync(C)}.

active_down(noconnection, Data) ->
    core({elect, active_silent, false}, standby, Data#data{active_lost = true});
active_down(Why, Data) ->
    %% The process died and its node is up: its lease counts no more.
    core({elect, {active_died, Why}, true}, standby, Data#data{active_lost = true}).

remonitor_active(#data{active = Active, active_mon = undefined} = Data) when is_pid(Active) ->
    Data#data{active_mon = erlang:monitor(process, Active)};
remonitor_active(Data) ->
    Data.

%% ---------------------------------------------------------------------------
%% Messages between instances (evatar_ha_proto_v1)
%% ---------------------------------------------------------------------------

%% Active: a new instance offers to be the standby.
ha({offer, Standby, _V}, State, #data{standby = undefined, core = Core} = Data)
  when State =:= waiting; State =:= bound ->
    case evatar_ha_core:registering(Core) of
        false ->
            Mon = erlang:monitor(process, Standby),
            Data1 = Data#data{standby = Standby, standby_mon = Mon, placing = false,
                              commit = evatar_ha_commit:unsync(Data#data.commit)},
            {keep_state, publish(snapshot_to(Data1))};
        true ->
            ok = evatar_ha_proto_v1:dismiss(Standby, self()),
            keep_state_and_data
    end;
ha({offer, Standby, _V}, _State, #data{standby = Standby} = Data) ->
    {keep_state, snapshot_to(Data)};
%% The rebalancer's moves: made only by an active with a synced standby and
%% no registration or election under way; else the next round plans again.
ha({rebalance, Move}, State, #data{standby = Standby, core = Core, commit = C} = Data)
  when is_pid(Standby), (State =:= waiting orelse State =:= bound) ->
    case evatar_ha_commit:synced(C) andalso not evatar_ha_core:holding(Core)
        andalso not evatar_ha_core:electing(Core) of
        true -> rebalance(Move, State, Data);
        false -> keep_state_and_data
    end;
ha({rebalance, _Move}, _State, _Data) ->
    keep_state_and_data;
ha({offer, Standby, _V}, _State, _Data) ->
    ok = evatar_ha_proto_v1:dismiss(Standby, self()),
    keep_state_and_data;
ha({resync, Standby, _V}, _State, #data{standby = Standby} = Data) ->
    {keep_state, snapshot_to(Data)};
ha({resync, Other, _V}, _State, _Data) ->
    ok = evatar_ha_proto_v1:dismiss(Other, self()),
    keep_state_and_data;
ha({confirm, Standby, _E, V}, State, #data{standby = Standby} = Data) ->
    Data1 = release(V, Data),
    case State of
        handing_over -> {keep_state, send_handover(Data1)};
        _ -> {keep_state, Data1}
    end;
ha({confirm, _Other, _E, _V}, _State, _Data) ->
    keep_state_and_data;

%% Standby: the state, then the events in order. Word from the active ends
%% any election this standby had started.
ha({snapshot, Active, _Epoch, Version, State, Claim}, standby, #data{active = Active} = Data) ->
    %% Never back to an older state than the one confirmed (a snapshot
    %% delivered twice would undo what the active released since).
    case Version < evatar_ha_commit:version(Data#data.commit) of
        true -> keep_state_and_data;
        false -> become_standby(Version, State, Claim, Data)
    end;
ha({events, Active, _Epoch, Events}, standby, #data{active = Active, logic = Logic} = Data) ->
    {Core, []} = evatar_ha_core:handle(active_heard, ctx(standby, Data), Data#data.core),
    Data1 = apply_events(Events, remonitor_active(Data#data{active_lost = false, core = Core})),
    case epoch(Data1#data.logic) =:= epoch(Logic) of
        true -> {keep_state, Data1};
        false -> {keep_state, publish(Data1)}
    end;
ha({events, From, Epoch, _Events}, State, Data) ->
    other_instance(From, active, Epoch, State, Data);
ha({dismiss, Active}, standby, #data{active = Active} = Data) ->
    stop_instance(dismissed, Data);
ha({dismiss, _}, _State, _Data) ->
    keep_state_and_data;
ha({handover, Active, Epoch, Version}, standby, #data{active = Active, logic = Logic} = Data) ->
    case {epoch(Logic), evatar_ha_commit:version(Data#data.commit)} of
        {Epoch, Version} ->
            core({handover_asked}, standby, Data#data{active_lost = true});
        _ ->
            keep_state_and_data
    end;
ha({handover, _Active, _Epoch, _Version}, _State, _Data) ->
    keep_state_and_data;
ha({handover_done, New, _Epoch, Claim}, handing_over, #data{standby = New, id = Id} = Data) ->
    ?LOG_WARNING(#{what => handed_over, pairing => Id, to => node_of(New)}),
    Data1 = disconnect_all(not_active, <<"the pairing moved to ", (node_name(New))/binary>>,
                           Data),
    _ = erlang:demonitor(Data1#data.standby_mon, [flush]),
    Mon = erlang:monitor(process, New),
    {Core, []} = evatar_ha_core:handle({claim, Claim}, ctx(standby, Data), Data#data.core),
    Data2 = cancel_logic_timers(untimer({ha, handover}, Data1)),
    Data3 = Data2#data{role = standby, active = New, active_mon = Mon, standby = undefined,
                       standby_mon = undefined, core = Core,
                       commit = evatar_ha_commit:reset(Data2#data.commit)},
    {next_state, standby, reconfirmed(standby, publish(Data3))};
ha({stale, From, Epoch}, State, Data) ->
    other_instance(From, active, Epoch, State, Data);
ha({peer_instance, Pid, Role, Epoch}, State, Data) when is_pid(Pid), is_atom(Role),
                                                       is_integer(Epoch) ->
    other_instance(Pid, Role, Epoch, State, Data);

%% Elections and registrations: the answers of every node.
ha({vote_reply, _Id, Ec, Node, Result}, State, Data) ->
    core({vote_reply, Ec, Node, Result}, State, Data);
ha({register_reply, _Id, Claim, Node, Result}, State, Data) ->
    core({register_reply, Claim, Node, Result}, State, Data);
ha(_Body, _State, _Data) ->
    keep_state_and_data.

%% evatar_ha_roles applies the batch; this confirms it, or asks again.
apply_events(Events, #data{active = Active, logic = Logic0, commit = C0} = Data) ->
    Apply = fun(Event, Now, L) -> element(1, evatar_pairing_logic:handle(Event, Now, L)) end,
    {Logic, C, Answer} = evatar_ha_roles:apply_events(Events, Apply, Logic0, C0),
    ok = case Answer of
             {confirm, V} -> evatar_ha_proto_v1:confirm(Active, evatar_pairing_logic:epoch(Logic), V);
             {resync, Mine} -> evatar_ha_proto_v1:resync(Active, self(), Mine)
         end,
    Data#data{logic = Logic, commit = C}.

%% What this instance does about another instance of its pairing
%% (evatar_ha_core:reconcile/2).
other_instance(Pid, _Role, _Epoch, _State, _Data) when Pid =:= self() ->
    keep_state_and_data;
other_instance(Pid, Role, Epoch, State, #data{logic = Logic} = Data) ->
    MyRole = case State of
                 S when S =:= waiting; S =:= bound; S =:= handing_over -> active;
                 S -> S
             end,
    MyEpoch = epoch(Logic),
    Peer = case MyRole of
               standby -> Data#data.active;
               _ -> Data#data.standby
           end,
    Me = #{role => MyRole, epoch => MyEpoch, node => node(), pid => self(), peer => Peer},
    Other = #{role => Role, epoch => Epoch, node => node(Pid), pid => Pid},
    case evatar_ha_roles:meet(Me, Other) of
        step_down ->
            _ = [evatar_ha_proto_v1:dismiss(P, self()) || P <- [Data#data.standby],
                                                          is_pid(P), P =/= Pid],
            step_down({newer_instance, node(Pid), Epoch}, Data);
        stop ->
            stop_instance({newer_instance, node(Pid), Epoch}, Data);
        tell_stale ->
            ok = evatar_ha_proto_v1:stale(Pid, self(), MyEpoch),
            keep_state_and_data;
        keep ->
            keep_state_and_data
    end.

%% ---------------------------------------------------------------------------
%% Failure detection (evatar_cluster's events)
%% ---------------------------------------------------------------------------

cluster_event({node_alive, _Node}, State, Data) when State =:= waiting; State =:= bound ->
    {keep_state, place(State, Data)};
cluster_event({Lost, Node}, State, #data{standby = Standby} = Data)
  when (Lost =:= node_suspected orelse Lost =:= node_down), is_pid(Standby),
       node(Standby) =:= Node, State =/= standby ->
    standby_down(noconnection, State, Data);
cluster_event({Lost, Node}, standby, #data{active = Active} = Data)
  when (Lost =:= node_suspected orelse Lost =:= node_down), is_pid(Active),
       node(Active) =:= Node ->
    core({elect, active_silent, false}, standby, Data#data{active_lost = true});
cluster_event({node_alive, Node}, standby, #data{active = Active, active_lost = true} = Data)
  when is_pid(Active), node(Active) =:= Node ->
    %% The active's node is back: pick up the replication again (an
    %% election under way goes on: the nodes decide).
    ok = evatar_ha_proto_v1:resync(Active, self(), evatar_ha_commit:version(Data#data.commit)),
    {keep_state, remonitor_active(Data)};
cluster_event({quorum, true}, standby, #data{active_lost = true} = Data) ->
    core({elect, active_silent, false}, standby, Data);
cluster_event({quorum, false}, State, Data) when State =:= waiting; State =:= bound ->
    maybe_fence(Data);
cluster_event(stalled, State, Data) when State =:= waiting; State =:= bound ->
    %% This node was stopped for longer than suspect_ms: the pairing may
    %% have another active by now, or (far more often) not.
    {keep_state, paused(Data)};
cluster_event({quorum, true}, fenced, Data) ->
    core({elect, fenced, false}, fenced, Data);
cluster_event({node_alive, _}, fenced, Data) ->
    core({elect, fenced, false}, fenced, Data);
cluster_event(_Event, _State, _Data) ->
    keep_state_and_data.

%% ---------------------------------------------------------------------------
%% Elections and registrations: evatar_ha_core decides, this executes
%% ---------------------------------------------------------------------------

ctx(Role, _Data) ->
    #{nodes => evatar_cluster:configured(), heartbeat_ms => evatar_cluster:opt(heartbeat_ms),
      suspect_ms => evatar_cluster:opt(suspect_ms), epoch => 0, role => Role}.

core(Event, State, #data{logic = Logic, core = Core} = Data) ->
    Role = case State of
               S when S =:= waiting; S =:= bound -> active;
               S -> S
           end,
    {Core1, Effects} = evatar_ha_core:handle(Event, (ctx(Role, Data))#{epoch := epoch(Logic)},
                                             Core),
    core_effects(Effects, State, Data#data{core = Core1}).

core_effects([{vote, Node, Ec, Claim, Dead} | Rest], State, #data{id = Id} = Data) ->
    Active = case Data#data.role of
                 standby -> Data#data.active;
                 _ -> self()
             end,
    ok = evatar_ha_proto_v1:vote(Node, Id, Ec, self(), Claim, Active, Dead),
    core_effects(Rest, State, Data);
core_effects([{register, Node, {E, Seq}} | Rest], State, #data{id = Id} = Data) ->
    ok = evatar_ha_proto_v1:register(Node, Id, E, Seq, self()),
    core_effects(Rest, State, Data);
core_effects([{timer, Key, Ms} | Rest], State, Data) ->
    core_effects(Rest, State, timer({ha, Key}, Ms, Data));
core_effects([{pause, keep} | Rest], State, Data) ->
    core_effects(Rest, State, Data);
core_effects([{pause, await} | Rest], State, Data) ->
    core_effects(Rest, State, Data#data{reconfirming = true});
core_effects([{pause, reconfirm} | Rest], State, #data{id = Id, core = Core} = Data) ->
    ?LOG_NOTICE(#{what => reconfirming_after_pause, pairing => Id,
                  claim => evatar_ha_core:claim(Core)}),
    core_effects(Rest, State, Data#data{reconfirming = true});
core_effects([{won, handover, Ec}], standby, #data{active = Old, commit = C} = Data) ->
    %% The old active becomes this one's standby, already in sync, with
    %% the claim {Ec, 1}.
    {next_state, S, D, A} = take_over(handover, Ec, Data),
    Mon = erlang:monitor(process, Old),
    ok = evatar_ha_proto_v1:handover_done(Old, self(), Ec, {Ec, 1}),
    {Core, []} = evatar_ha_core:handle({claim, {Ec, 1}}, ctx(active, D), D#data.core),
    D1 = D#data{standby = Old, standby_mon = Mon, placing = false, core = Core,
                commit = evatar_ha_commit:synced_at(evatar_ha_commit:version(C), D#data.commit)},
    {next_state, S, publish(flush(D1)), A};
core_effects([{won, reelect, Ec}], State, #data{id = Id} = Data)
  when State =:= waiting; State =:= bound ->
    %% Re-elected above a stale promise while serving: the clients stay,
    %% only the epoch moves; effects wait for the registration of {Ec, 1}.
    ?LOG_WARNING(#{what => reelected, pairing => Id, epoch => Ec}),
    {_, Data1} = step({reelected, Ec}, Data),
    {keep_state, publish(Data1)};
core_effects([{won, Why, Ec}], _State, Data) ->
    take_over(Why, Ec, Data);
core_effects([{lost, Why}], standby, Data) ->
    stop_instance(Why, reply_held(Data));
core_effects([{lost, Why}], _State, Data) ->
    step_down(Why, Data);
core_effects([registered], State, #data{standby = Standby} = Data) when is_pid(Standby) ->
    %% A reconfirmation after a pause: the standby's confirmations still
    %% decide what goes out.
    {keep_state, reconfirmed(State, Data)};
core_effects([registered], State, Data) ->
    Data1 = release_all(reconfirmed(State, Data)),
    {keep_state, place_soon(place(State, Data1))};
core_effects([{fence, Why}], State, #data{id = Id} = Data) ->
    _ = case Why of
            registration_timeout ->
                ?LOG_WARNING(#{what => registration_timeout, pairing => Id,
                               claim => evatar_ha_core:claim(Data#data.core)});
            _ ->
                ?LOG_WARNING(#{what => registration_refused, pairing => Id, reason => Why})
        end,
    case State of
        S when S =:= waiting; S =:= bound -> fence_now(Data);
        _ -> {keep_state, Data}
    end;
core_effects([], _State, Data) ->
    {keep_state, Data}.

%% ---------------------------------------------------------------------------
%% Fencing and pauses
%% ---------------------------------------------------------------------------

maybe_fence(#data{standby = Standby} = Data) ->
    StandbyHeard = is_pid(Standby) andalso
        evatar_cluster:heard_within(node(Standby), evatar_cluster:opt(lease_ms)),
    case evatar_ha_core:must_fence(evatar_cluster:size(), evatar_cluster:majority_now(),
                                   StandbyHeard) of
        true -> fence_now(Data);
        false -> keep_state_and_data
    end.

%% Stops serving: every client is closed with Fenced (they go to their
%% other endpoints), nothing goes out; with a majority heard it asks for
%% the pairing again at once (an election in which its standby may win).
fence_now(#data{id = Id} = Data) ->
    ?LOG_WARNING(#{what => fenced, pairing => Id}),
    ok = evatar_metrics:inc(evatar_fenced_total),
    Data1 = disconnect_all(fenced, <<"this node lost the majority of the cluster">>,
                           Data#data{role = fenced}),
    {keep_state, Data2} = case evatar_cluster:majority_now() of
                              true -> core({elect, fenced, false}, fenced, Data1);
                              false -> {keep_state, Data1}
                          end,
    {next_state, fenced, reconfirmed(fenced, publish(Data2))}.

stalled_active(State, #data{gen = Gen}) when State =:= waiting; State =:= bound ->
    not evatar_cluster:unstalled(Gen);
stalled_active(_State, _Data) ->
    false.

%% This node was paused itself while this instance was active (SIGSTOP, a
%% laptop lid, a long GC): told apart from a loss of the peers by
%% evatar_cluster, decided by evatar_ha_core:after_pause/2. Nothing is
%% fenced for the pause alone.
paused(Data) ->
    {keep_state, Data1} = core(paused, waiting, Data#data{gen = evatar_cluster:stall_gen()}),
    Data1.

%% ---------------------------------------------------------------------------
%% Resumes held by a standby
%% ---------------------------------------------------------------------------

arm_held(#data{timers = #{{ha, held} := _}} = Data) ->
    Data;
arm_held(Data) ->
    timer({ha, held}, evatar_ha_roles:held_poll_ms(evatar_cluster:opt(heartbeat_ms)), Data).

%% evatar_ha_roles:held_due/3 says which held resumes are answered NotActive.
check_held(#data{held = Held, active = Active, core = Core} = Data) ->
    Ctx = #{suspect_ms => suspect_ms(), heartbeat_ms => evatar_cluster:opt(heartbeat_ms),
            electing => evatar_ha_core:electing(Core) orelse Data#data.active_lost,
            heard_after => fun(Since) -> is_pid(Active) andalso
                                             evatar_cluster:heard_after(node(Active), Since)
                           end},
    {Go, Keep} = evatar_ha_roles:held_due(Held, erlang:monotonic_time(millisecond), Ctx),
    Data1 = reply_held(Data#data{held = Go}),
    case Keep of
        [] -> Data1#data{held = []};
        _ -> arm_held(Data1#data{held = Keep})
    end.

reply_held(#data{held = Held, active = Active} = Data) ->
    _ = [gen_statem:reply(From, {error, {not_active, node_of(Active)}}) || {From, _, _} <- Held],
    Data#data{held = []}.

%% ---------------------------------------------------------------------------
%% Silent client links, and the planned handover they start
%% ---------------------------------------------------------------------------

arm_silent(#data{timers = #{{ha, silent} := _}} = Data) ->
    Data;
arm_silent(Data) ->
    timer({ha, silent}, max(50, evatar_cluster:opt(client_ack_timeout) div 2), Data).

silent_check(#data{logic = Logic, id = Id} = Data) ->
    Timeout = evatar_cluster:opt(client_ack_timeout),
    Now = erlang:system_time(millisecond),
    %% Deliveries still held for a registration were never sent: their
    %% receivers are not silent.
    Silent = [E || not evatar_ha_core:holding(Data#data.core),
                   {E, T} <- evatar_pairing_logic:unacked_since(Logic), Now - T > Timeout],
    Data1 = lists:foldl(
              fun(E, D) ->
                      ?LOG_WARNING(#{what => silent_link, pairing => Id, entity => E}),
                      ok = evatar_metrics:inc(evatar_entities_dropped_total, silent_link),
                      ok = tell(E, {dropped, silent_link,
                                    <<"delivered signals were not acknowledged in time">>}, D),
                      run({detach, E}, forget(E, D))
              end, Data, Silent),
    Handover = Silent =/= [] andalso evatar_cluster:opt(handover_on_silent_link) =:= true
        andalso is_pid(Data1#data.standby) andalso evatar_ha_commit:synced(Data1#data.commit),
    Data2 = arm_silent(Data1),
    case Handover of
        true -> hand_over(Data2);
        false -> next(flush_maybe(Data2), [])
    end.

%% A planned handover to the synced standby (a silent link, or the
%% rebalancer): it goes once the standby has confirmed everything.
hand_over(Data) ->
    {next_state, handing_over,
     flush(timer({ha, handover}, 4 * evatar_cluster:opt(suspect_ms), Data)),
     [{next_event, internal, handover}]}.

%% A move of the rebalancer (evatar_placement): a planned handover, or the
%% standby moved to another node: dismissed, a configuration without it
%% registered as when its node is lost (effects held until a majority
%% accepted it), then a new standby placed there from a snapshot.
rebalance({handover, Id}, _State, #data{id = Id, standby = Standby} = Data) ->
    ?LOG_NOTICE(#{what => rebalance_handover, pairing => Id, to => node(Standby)}),
    hand_over(Data);
rebalance({standby, Id, Node}, State, #data{id = Id, standby = Standby, config = Config} = Data)
  when Node =/= node(), Node =/= node(Standby) ->
    ?LOG_NOTICE(#{what => rebalance_standby, pairing => Id, from => node(Standby), to => Node}),
    {keep_state, Data1} = core(standby_node_lost, State,
                               forget_standby(Data#data{config = Config#{standby_node => Node}})),
    {keep_state, publish(Data1)};
rebalance(_Move, _State, _Data) ->
    keep_state_and_data.

%% The planned handover goes once the standby has confirmed everything.
send_handover(#data{standby = Standby, commit = C, logic = Logic} = Data) when is_pid(Standby) ->
    V = evatar_ha_commit:version(C),
    case evatar_ha_commit:confirmed(C) of
        V ->
            ok = evatar_ha_proto_v1:handover(Standby, evatar_pairing_logic:epoch(Logic), V),
            Data;
        _ ->
            flush(Data)
    end;
send_handover(Data) ->
    flush(Data).

%% ---------------------------------------------------------------------------

peers() ->
    [N || N <- evatar_cluster:alive_nodes(), N =/= node()].

suspect_ms() -> evatar_cluster:opt(suspect_ms).

epoch(undefined) -> 0;
epoch(Logic) -> evatar_pairing_logic:epoch(Logic).

node_of(Pid) when is_pid(Pid) -> node(Pid);
node_of(_) -> undefined.

node_name(Pid) -> atom_to_binary(node(Pid)).

ha_status(#data{role = Role, logic = Logic, commit = C} = Data) ->
    {Active, Standby} = case Role of
                            standby -> {Data#data.active, undefined};
                            starting -> {Data#data.active, undefined};
                            _ -> {self(), Data#data.standby}
                        end,
    #{role => Role, epoch => epoch(Logic), node => node(), active => Active, standby => Standby,
      standby_node => node_of(Standby),
      synced => case Role of
                    standby -> true;
                    _ -> evatar_ha_commit:synced(C)
                end,
      version => evatar_ha_commit:version(C)}.

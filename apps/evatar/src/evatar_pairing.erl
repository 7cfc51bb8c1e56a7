%% @doc Internal. The process of one instance of a pairing: runs
%% `evatar_pairing_logic' and executes its effects (messages to entity
%% processes, timers, logs). It owns what cannot be replicated: the pids of
%% the entities' processes, their monitors and the timer references. With a
%% cluster (docs/architecture.md, section 8) an instance is the `active' one
%% or the `standby' of an active on another node.
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
%%               clients closed with Fenced, nothing externalised, timers
%%               postponed. A pause alone fences nothing (paused/1).
%% '''
%% The active's name is the logic's {@link evatar_pairing_logic:phase/1}
%% (`waiting' or `bound'); `handing_over' is the short planned-handover
%% step. While there is a standby, every event is shipped to it with its
%% time and version, and every effect seen outside (a delivery, a report, a
%% reply, an Ack) is held until the standby confirms that version: what a
%% client sees is always in the standby's history. Without one (degraded)
%% effects go out at once, except after a takeover or the loss of the
%% standby's node: then they are held until a majority of nodes accepted the
%% new configuration (elections and registrations: docs/architecture.md
%% section 8.4). Acks are batched until the mailbox is empty.
-module(evatar_pairing).
-behaviour(gen_statem).

%% A pairing idle this long compacts its heap: a home's pairing is quiet
%% most of the time.
-define(HIBERNATE_AFTER, 5000).

-include_lib("kernel/include/logger.hrl").

-export([start_link/2, start_link/3]).
-export([init/1, callback_mode/0, handle_event/4, terminate/3]).

-export_type([mode/0]).

-type mode() :: create | {standby_for, pid()}.
-type role() :: starting | active | standby | fenced.

-define(FLUSH_EVERY, 64).
-define(PLACE_RETRY_MS, 1000).

-record(data, {id :: evatar:pairing_id(),
               config :: evatar_pairing_logic:config(),
               logic :: evatar_pairing_logic:state() | undefined,
               pids = #{} :: #{binary() => {pid(), reference()}},
               refs = #{} :: #{reference() => binary()},
               timers = #{} :: #{evatar_pairing_logic:timer_key() => reference()},
               mode :: mode(),
               role = starting :: role(),
               version = 0 :: non_neg_integer(),
               %% Active: the standby and what it has not confirmed yet.
               standby :: pid() | undefined,
               standby_mon :: reference() | undefined,
               synced = false :: boolean(),
               confirmed = 0 :: non_neg_integer(),
               repl = [] :: [{pos_integer(), integer(), evatar_pairing_logic:event()}],
               outbox = queue:new() :: queue:queue({non_neg_integer(), [term()]}),
               acks = #{} :: #{binary() => binary()},
               unflushed = 0 :: non_neg_integer(),
               placing = false :: boolean(),
               silent_armed = false :: boolean(),
               %% Standby (and starting): the active.
               active :: pid() | undefined,
               active_mon :: reference() | undefined,
               active_lost = false :: boolean(),
               %% Every role: the configuration this instance holds (the
               %% active's current one, a standby's claim), the highest
               %% promise seen in refusals, a running election, a running
               %% registration, and whether effects are held without a
               %% standby until that registration is accepted.
               conf = {1, 0} :: evatar_ha_rules:claim(),
               promised = 0 :: non_neg_integer(),
               election :: undefined | #{epoch := non_neg_integer(), granted := [node()],
                                         replied := [node()], dead := boolean(),
                                         why := term(), attempt := non_neg_integer()},
               reg :: undefined | #{claim := evatar_ha_rules:claim(), ok := [node()],
                                    no := [node()]},
               hold = false :: boolean(),
               gen = 0 :: non_neg_integer(),
               %% Active after a pause of its node: asking the cluster
               %% whether it is still the active; inspections wait for it.
               reconfirming = false :: boolean(),
               inspects = [] :: [{gen_statem:from(), atom()}],
               %% Standby: resumes held until it takes over or hears its active.
               held = [] :: [{gen_statem:from(), term(), integer()}],
               held_armed = false :: boolean(),
               asks = 0 :: non_neg_integer(),
               answers = [] :: [{node(), evatar_ha_proto_v1:instance_info()}],
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
          gen_statem:init_result(starting).
init({PairingId, Config, Mode}) ->
    logger:set_process_metadata(#{pairing => PairingId, domain => [evatar, pairing]}),
    {ok, starting, #data{id = PairingId, config = Config, mode = Mode},
     [{next_event, internal, load}]}.

%% ---------------------------------------------------------------------------
%% Starting
%% ---------------------------------------------------------------------------

%% @private
-spec handle_event(gen_statem:event_type(), term(), atom(), #data{}) ->
          gen_statem:event_handler_result(atom()).
handle_event(internal, load, starting, #data{id = Id, mode = Mode} = Data) ->
    case {Mode, evatar_registry:previous(Id), peers()} of
        {create, none, _} ->
            become_active(new, Data);
        {{standby_for, Active}, none, _} ->
            offer_to(Active, Data);
        {_, _Previous, []} ->
            %% A restart with nobody to ask: start afresh, as a lone node does.
            become_active(new, Data);
        {_, Previous, Peers} ->
            ?LOG_NOTICE(#{what => pairing_restarted, pairing => Id, previous => Previous}),
            ask_peers(Peers, Data)
    end;
handle_event(info, {evatar_ha, 1, {instance, Id, Node, Info}}, starting,
             #data{id = Id, answers = Answers, asks = N} = Data) ->
    Data1 = Data#data{answers = [{Node, Info} | Answers]},
    case length(Data1#data.answers) >= N of
        true -> decide_start(Data1);
        false -> {keep_state, Data1}
    end;
handle_event(state_timeout, asked, starting, Data) ->
    decide_start(Data);
handle_event(internal, retry_ask, starting, Data) ->
    ask_peers(peers(), Data);
handle_event(state_timeout, retry_ask, starting, Data) ->
    ask_peers(peers(), Data);
handle_event(info, {evatar_ha, 1, {snapshot, Active, Epoch, Version, State, Claim}}, starting,
             #data{active = Active} = Data) ->
    become_standby(Epoch, Version, State, Claim, Data);
handle_event(info, {evatar_ha, 1, {dismiss, Active}}, starting, #data{active = Active} = Data) ->
    stop_instance(dismissed, Data);
handle_event(state_timeout, offered, starting, Data) ->
    stop_instance(no_snapshot, Data);
handle_event(info, {'DOWN', Ref, process, _, _}, starting, #data{active_mon = Ref} = Data) ->
    stop_instance(active_gone, Data);
handle_event({call, From}, {inspect, ha}, starting, Data) ->
    {keep_state_and_data, [{reply, From, ha_status(Data)}]};
handle_event(_Type, _Event, starting, _Data) ->
    {keep_state_and_data, [postpone]};

%% ---------------------------------------------------------------------------
%% Messages between instances and from evatar_cluster (every role)
%% ---------------------------------------------------------------------------

handle_event(info, {evatar_ha, 1, Body}, State, Data) ->
    ha(Body, State, Data);
handle_event(info, {evatar_cluster, Event}, State, Data) ->
    cluster_event(Event, State, Data);
handle_event(info, {'DOWN', Ref, process, _, Why}, State, #data{standby_mon = Ref} = Data) ->
    standby_down(Why, State, Data);
handle_event(info, {'DOWN', Ref, process, _, Why}, State, #data{active_mon = Ref} = Data) ->
    active_down(Why, State, Data#data{active_mon = undefined});
handle_event({call, From}, {inspect, What}, State, Data) ->
    %% An active whose node was paused since it began serving asks the
    %% cluster whether it is still the active (evatar_ha_rules:after_pause/2)
    %% and says nothing until it knows: never `active' beside a standby
    %% that took over meanwhile.
    Data1 = case stalled_active(State, Data) of
                true -> paused(Data);
                false -> Data
            end,
    case Data1 of
        #data{reconfirming = true, inspects = Waiting} ->
            {keep_state, Data1#data{inspects = [{From, What} | Waiting]}};
        #data{} ->
            {keep_state, Data1, [{reply, From, inspect(What, State, Data1)}]}
    end;
handle_event({call, From}, {auth, Role, EntityId}, _State, #data{config = Config}) ->
    %% What a join must present, so that the joining process checks its
    %% credential itself (evatar:join/4): an id the pairing refuses anyway
    %% costs no hash.
    Reply = case evatar_auth:check_id(EntityId, maps:get(max_id_length, Config)) of
                ok -> {ok, evatar_auth:requirement(Role, EntityId, Config)};
                {error, _} = Error -> Error
            end,
    {keep_state_and_data, [{reply, From, Reply}]};
handle_event({timeout, place}, place, State, Data) ->
    {keep_state, place(State, Data#data{placing = false})};
handle_event(info, {evatar_election_retry, Ec}, State, #data{election = #{epoch := Ec}} = Data)
  when State =:= standby; State =:= fenced ->
    {keep_state, elect(Data)};
handle_event(info, {evatar_election_retry, _}, _State, _Data) ->
    keep_state_and_data;
handle_event(info, {evatar_register_retry, Claim}, State, #data{reg = #{claim := Claim}} = Data)
  when State =/= fenced ->
    {keep_state, send_register(Data)};
handle_event(info, {evatar_register_retry, _}, _State, _Data) ->
    keep_state_and_data;
handle_event({call, From}, {tap_watch, Pid, Filter}, State, #data{id = Id} = Data)
  when is_pid(Pid), is_map(Filter), (State =:= waiting orelse State =:= bound) ->
    case evatar_tap:add(Pid, Filter, Data#data.watchers, Id) of
        {ok, Ref, Watchers} ->
            {keep_state, Data#data{watchers = Watchers}, [{reply, From, {ok, Ref}}]};
        {error, _} = Error ->
            {keep_state_and_data, [{reply, From, Error}]}
    end;
handle_event({call, From}, {tap_watch, _, _}, standby, #data{active = Active}) ->
    {keep_state_and_data, [{reply, From, {redirect, Active}}]};
handle_event({call, From}, {tap_watch, _, _}, fenced, _Data) ->
    {keep_state_and_data, [{reply, From, {error, busy}}]};
handle_event(info, {evatar_tap_ack, Ref, N}, _State, #data{watchers = Watchers} = Data)
  when is_integer(N), N >= 0 ->
    {keep_state, Data#data{watchers = evatar_tap:acked(Ref, N, Watchers)}};
handle_event(info, {evatar_tap_unwatch, Ref}, _State, #data{watchers = Watchers} = Data) ->
    _ = erlang:demonitor(Ref, [flush]),
    {keep_state, Data#data{watchers = evatar_tap:down(Ref, Watchers)}};
handle_event(info, {evatar_tap_down, Ref, process, _, _}, _State,
             #data{watchers = Watchers} = Data) ->
    {keep_state, Data#data{watchers = evatar_tap:down(Ref, Watchers)}};
handle_event(info, evatar_flush, _State, Data) ->
    {keep_state, flush(Data)};
handle_event(info, evatar_held_check, standby, Data) ->
    {keep_state, check_held(Data#data{held_armed = false})};
handle_event(info, evatar_held_check, _State, Data) ->
    {keep_state, Data#data{held_armed = false}};

%% ---------------------------------------------------------------------------
%% Standby, fenced, handing over: no client traffic
%% ---------------------------------------------------------------------------

handle_event({call, From}, delete, State, #data{id = Id} = Data)
  when State =:= standby; State =:= fenced ->
    ?LOG_INFO(#{what => pairing_deleted, pairing => Id}),
    _ = [evatar_ha_proto_v1:dismiss(P, self()) || P <- [Data#data.standby], is_pid(P)],
    {stop_and_reply, normal, [{reply, From, ok}]};
handle_event({call, From}, {resume, _, _, _, _, _} = Request, standby, Data) ->
    %% A client that lost the active comes here: answer once this instance
    %% either took over (it serves the resume then) or heard its active
    %% after the request came (NotActive), instead of sending the client
    %% through its endpoints and back-off while a takeover is under way.
    Held = [{From, Request, erlang:monotonic_time(millisecond)} | Data#data.held],
    {keep_state, arm_held(Data#data{held = Held})};
handle_event({call, From}, Request, standby, #data{active = Active}) ->
    Reply = case Request of
                {leave, _} -> ok;
                _ -> {error, {not_active, node_of(Active)}}
            end,
    {keep_state_and_data, [{reply, From, Reply}]};
handle_event({call, From}, Request, fenced, _Data) ->
    Reply = case Request of
                {leave, _} -> ok;
                _ -> {error, fenced}
            end,
    {keep_state_and_data, [{reply, From, Reply}]};
handle_event(cast, _Client, State, _Data) when State =:= standby; State =:= fenced ->
    %% Not accepted, so never acknowledged: the client sends it again to
    %% the active.
    keep_state_and_data;
handle_event(info, {timeout, _TRef, _Key}, fenced, _Data) ->
    {keep_state_and_data, [postpone]};
handle_event(info, {timeout, _TRef, _Key}, standby, _Data) ->
    keep_state_and_data;
handle_event(internal, handover, handing_over, Data) ->
    {keep_state, send_handover(Data)};
handle_event(state_timeout, handover, handing_over, Data) ->
    ?LOG_WARNING(#{what => handover_aborted, pairing => Data#data.id}),
    next(Data#data{role = active}, []);
handle_event(info, evatar_silent_check, State, Data) when State =/= waiting, State =/= bound ->
    {keep_state, Data#data{silent_armed = false}};
handle_event(_Type, _Event, handing_over, _Data) ->
    {keep_state_and_data, [postpone]};

%% ---------------------------------------------------------------------------
%% Active: the client traffic
%% ---------------------------------------------------------------------------

%% The hot path: no reply, no timer for anything but requests.
handle_event(cast, {signal, EntityId, Signal}, _State, Data) ->
    {keep_state, flush_maybe(run({signal, EntityId, Signal}, Data))};
handle_event(cast, {client_ack, EntityId, Seq}, _State, Data) when is_integer(Seq) ->
    {keep_state, flush_maybe(run({client_ack, EntityId, Seq}, Data))};
handle_event(cast, {report_binding, EntityId}, _State, Data) when is_binary(EntityId) ->
    {keep_state, report_binding(EntityId, Data)};
handle_event({call, From}, {join, Role, EntityId, Credential, Pid}, _State, Data) ->
    join({join, Role, EntityId, Credential}, EntityId, Pid, From, Data);
handle_event({call, From}, {join, Role, EntityId, Credential, Pid, #{session := S}}, _State,
             Data) when is_binary(S) ->
    join({join, Role, EntityId, Credential, S}, EntityId, Pid, From, Data);
handle_event({call, From}, {resume, Role, EntityId, Credential, Pid,
                            #{session := S, received := R, epoch := E}}, _State, Data)
  when is_binary(S), is_integer(R), R >= 0, is_integer(E), E >= 0 ->
    join({resume, Role, EntityId, Credential, S, R, E}, EntityId, Pid, From, Data);
handle_event({call, From}, {describe, EntityId, Description}, _State, Data) ->
    {Reply, Data1} = step({describe, EntityId, Description}, Data),
    next(flush_maybe(reply(From, Reply, Data1)), []);
handle_event({call, From}, {leave, EntityId}, _State, Data) ->
    {ok, Data1} = step({leave, EntityId, left}, Data),
    next(flush_maybe(reply(From, ok, forget(EntityId, Data1))), []);
handle_event(cast, {leave, EntityId}, _State, Data) when is_binary(EntityId) ->
    %% evatar:leave_async/1: a closing connection that needs no answer.
    {ok, Data1} = step({leave, EntityId, left}, Data),
    next(flush_maybe(forget(EntityId, Data1)), []);
handle_event(info, {'DOWN', Ref, process, _Pid, _Reason}, _State, #data{refs = Refs} = Data) ->
    case Refs of
        #{Ref := EntityId} ->
            Data1 = forget(EntityId, Data),
            {_, Data2} = step({detach, EntityId}, Data1),
            next(flush_maybe(Data2), []);
        #{} ->
            keep_state_and_data
    end;
handle_event(info, {timeout, TRef, Key}, _State, #data{timers = Timers} = Data) ->
    case Timers of
        #{Key := TRef} ->
            Data1 = run({timeout, Key}, Data#data{timers = maps:remove(Key, Timers)}),
            next(flush_maybe(Data1), []);
        #{} ->
            %% Cancelled or replaced while the message was on its way.
            keep_state_and_data
    end;
handle_event(info, evatar_silent_check, _State, Data) ->
    silent_check(Data#data{silent_armed = false});
handle_event({call, From}, delete, _State, #data{id = Id} = Data) ->
    ?LOG_INFO(#{what => pairing_deleted, pairing => Id}),
    _ = [evatar_ha_proto_v1:dismiss(P, self()) || P <- [Data#data.standby], is_pid(P)],
    {stop_and_reply, normal, [{reply, From, ok}]};
handle_event(EventType, Event, _State, #data{id = Id}) ->
    ?LOG_NOTICE(#{what => unexpected_event, pairing => Id, type => EventType,
                  event => Event}),
    keep_state_and_data.

inspect(ha, _State, Data) ->
    ha_status(Data);
inspect(What, State, #data{logic = Logic} = Data) ->
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
        versioned_state -> {Data#data.version, Logic}
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
-spec terminate(term(), atom(), #data{}) -> ok.
terminate(normal, _State, #data{id = Id, pids = Pids}) ->
    _ = [Pid ! {evatar, Id, {dropped, pairing_deleted, <<"the pairing was deleted">>}}
         || {Pid, _} <- maps:values(Pids)],
    evatar_registry:delete_role(Id, self());
terminate({shutdown, _}, _State, #data{id = Id}) ->
    evatar_registry:delete_role(Id, self());
terminate(_Reason, _State, _Data) ->
    ok.

%% ---------------------------------------------------------------------------
%% Joining and resuming
%% ---------------------------------------------------------------------------

%% The connection is registered before the event runs: a resume delivers
%% again at once what the entity has not acknowledged. A refusal puts back
%% whatever was registered before.
join(Event, EntityId, Pid, From, Data) ->
    case stalled_active(waiting, Data) of
        true -> join1(Event, EntityId, Pid, From, paused(Data));
        false -> join1(Event, EntityId, Pid, From, Data)
    end.

join1(Event, EntityId, Pid, From, #data{pids = Pids, refs = Refs} = Data) ->
    Old = maps:get(EntityId, Pids, undefined),
    Ref = erlang:monitor(process, Pid),
    Data1 = Data#data{pids = Pids#{EntityId => {Pid, Ref}}, refs = Refs#{Ref => EntityId}},
    case step(Event, Data1) of
        {ok, Data2} ->
            ok = evatar_metrics:pairing_inc(Data2#data.metrics, evatar_pairing_joins_total, none),
            joined(Event, Pid, From, Old, ok, Data2);
        {{ok, _, _} = Ok, Data2} ->
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
%% Running the logic
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

%% Applies one event to the logic and executes its effects in order;
%% returns the logic's reply (`ok' for events that have none). With a
%% standby the event is queued for shipping and the effects seen outside
%% wait in the outbox for its confirmation.
step(Event, #data{logic = Logic, version = V} = Data) ->
    Now = erlang:system_time(millisecond),
    {Logic1, Effects} = evatar_pairing_logic:handle(Event, Now, Logic),
    ok = evatar_metrics:pairing_step(Data#data.metrics, Event, Effects),
    Data1 = case Data#data.watchers of
                [] ->
                    Data#data{logic = Logic1, version = V + 1};
                Watchers ->
                    Data#data{logic = Logic1, version = V + 1,
                              watchers = evatar_tap:emit(Data#data.id, Event, Effects, Now,
                                                         Watchers)}
            end,
    case Data1#data.standby of
        undefined when not Data1#data.hold ->
            execute(Effects, ok, Data1);
        undefined ->
            %% No standby, and a registration under way: held until the
            %% cluster has accepted it (then released at once).
            {Reply, Held, Data2} = internal(Effects, ok, [], Data1),
            {Reply, hold(V + 1, Held, Data2)};
        _ ->
            {Reply, Held, Data2} = internal(Effects, ok, [], Data1),
            Data3 = Data2#data{repl = [{V + 1, Now, Event} | Data2#data.repl]},
            {Reply, hold(V + 1, Held, Data3)}
    end.

%% With a standby: timers and logs now, the rest held.
internal([{start_timer, _, _} = E | Rest], Reply, Held, Data) ->
    {_, Data1} = execute([E], ok, Data),
    internal(Rest, Reply, Held, Data1);
internal([{cancel_timer, _} = E | Rest], Reply, Held, Data) ->
    {_, Data1} = execute([E], ok, Data),
    internal(Rest, Reply, Held, Data1);
internal([{log, _, _} = E | Rest], Reply, Held, Data) ->
    {_, Data1} = execute([E], ok, Data),
    internal(Rest, Reply, Held, Data1);
internal([{reply, Reply} | Rest], _Reply, Held, Data) ->
    internal(Rest, Reply, Held, Data);
internal([{Kind, EntityId, What} | Rest], Reply, Held, #data{pids = Pids} = Data)
  when Kind =:= deliver; Kind =:= report ->
    %% Bound now to the connection it was meant for: released later, it
    %% must not reach a connection that attached since (that one gets the
    %% resume's redelivery, in Sequence order).
    Msg = case Kind of
              deliver -> {signal, What};
              report -> {bound, What}
          end,
    case Pids of
        #{EntityId := {Pid, _}} -> internal(Rest, Reply, [{send, Pid, Msg} | Held], Data);
        #{} -> internal(Rest, Reply, Held, Data)
    end;
internal([E | Rest], Reply, Held, Data) ->
    internal(Rest, Reply, [E | Held], Data);
internal([], Reply, Held, Data) ->
    {Reply, lists:reverse(Held), Data}.

hold(_V, [], Data) -> Data;
hold(V, Effects, #data{outbox = Q} = Data) -> Data#data{outbox = queue:in({V, Effects}, Q)}.

%% A GetBinding (docs/protocol.md section 2): the current report, to that
%% entity only. It changes no state, so it is not shipped to the standby;
%% it waits behind the effects still held for the standby, so that it never
%% overtakes an older report.
report_binding(EntityId, #data{logic = Logic, pids = Pids, outbox = Q} = Data) ->
    {_, Effects} = evatar_pairing_logic:handle({report_binding, EntityId}, 0, Logic),
    Sends = [{send, Pid, {bound, R}} || {report, E, R} <- Effects,
                                        {Pid, _} <- [maps:get(E, Pids, {undefined, x})],
                                        is_pid(Pid)],
    case queue:is_empty(Q) of
        true ->
            {ok, Data1} = execute(Sends, ok, Data),
            Data1;
        false ->
            hold(Data#data.version, Sends, Data)
    end.

%% A call's reply, held like any other effect while there is a standby.
reply(From, Reply, #data{standby = undefined, hold = false} = Data) ->
    gen_statem:reply(From, Reply),
    Data;
reply(From, Reply, #data{version = V} = Data) ->
    hold(V, [{reply_to, From, Reply}], Data).

execute([{deliver, EntityId, Signal} | Rest], Reply, Data) ->
    ok = tell(EntityId, {signal, Signal}, Data),
    execute(Rest, Reply, Data);
execute([{send, Pid, Msg} | Rest], Reply, #data{id = Id} = Data) ->
    Pid ! {evatar, Id, Msg},
    execute(Rest, Reply, Data);
execute([{report, EntityId, Report} | Rest], Reply, Data) ->
    ok = tell(EntityId, {bound, Report}, Data),
    execute(Rest, Reply, Data);
execute([{drop, EntityId, Code, Reason} | Rest], Reply, Data) ->
    ok = tell(EntityId, {dropped, Code, Reason}, Data),
    execute(Rest, Reply, forget(EntityId, Data));
execute([{accepted, EntityId, SignalId} | Rest], Reply, #data{acks = Acks} = Data) ->
    execute(Rest, Reply, Data#data{acks = Acks#{EntityId => SignalId}});
execute([{reply_to, From, R} | Rest], Reply, Data) ->
    gen_statem:reply(From, R),
    execute(Rest, Reply, Data);
execute([{start_timer, Key, Ms} | Rest], Reply, #data{timers = Timers} = Data) ->
    ok = cancel(maps:get(Key, Timers, undefined)),
    TRef = erlang:start_timer(Ms, self(), Key),
    execute(Rest, Reply, Data#data{timers = Timers#{Key => TRef}});
execute([{cancel_timer, Key} | Rest], Reply, #data{timers = Timers} = Data) ->
    ok = cancel(maps:get(Key, Timers, undefined)),
    execute(Rest, Reply, Data#data{timers = maps:remove(Key, Timers)});
execute([{log, Level, Report} | Rest], Reply, #data{id = Id} = Data) ->
    %% Ids in a report come from clients: cut to 64 bytes (evatar_log).
    ?LOG(Level, evatar_log:report(Report#{pairing => Id})),
    execute(Rest, Reply, Data);
execute([{reply, Reply} | Rest], _Reply, Data) ->
    execute(Rest, Reply, Data);
execute([], Reply, Data) ->
    {Reply, Data}.

%% Ships the queued events to the standby, or sends the batched Acks when
%% there is none, once the mailbox is empty or every FLUSH_EVERY events:
%% one message per batch instead of one per signal.
flush_maybe(#data{repl = [], acks = Acks} = Data) when map_size(Acks) =:= 0 ->
    Data;
flush_maybe(#data{unflushed = N} = Data) ->
    case erlang:process_info(self(), message_queue_len) of
        {message_queue_len, 0} -> flush(Data);
        _ when N >= ?FLUSH_EVERY -> flush(Data);
        _ when N =:= 0 ->
            %% Deferred: whatever the waiting messages are (not all of them
            %% flush), this one flushes once they are handled.
            self() ! evatar_flush,
            Data#data{unflushed = 1};
        _ -> Data#data{unflushed = N + 1}
    end.

flush(#data{standby = undefined, hold = true} = Data) ->
    Data#data{unflushed = 0};
flush(#data{standby = undefined} = Data) ->
    send_acks(Data#data{unflushed = 0});
flush(#data{repl = []} = Data) ->
    Data#data{unflushed = 0};
flush(#data{standby = Standby, repl = Repl, logic = Logic} = Data) ->
    ok = evatar_ha_proto_v1:events(Standby, evatar_pairing_logic:epoch(Logic),
                                   lists:reverse(Repl)),
    Data#data{repl = [], unflushed = 0}.

send_acks(#data{acks = Acks, id = Id, pids = Pids} = Data) ->
    maps:foreach(fun(EntityId, SignalId) ->
                         case Pids of
                             #{EntityId := {Pid, _}} -> Pid ! {evatar, Id, {ack, SignalId}};
                             #{} -> ok
                         end
                 end, Acks),
    Data#data{acks = #{}}.

%% The standby confirmed `Version': what was held for it goes out.
release(Version, #data{outbox = Q} = Data) ->
    case queue:peek(Q) of
        {value, {V, Effects}} when V =< Version ->
            {_, Data1} = execute(Effects, ok, Data#data{outbox = queue:drop(Q)}),
            release(Version, Data1);
        _ ->
            send_acks(Data)
    end.

%% No standby any more (it died, or this node may go on alone): everything
%% held goes out now (degraded).
release_all(#data{version = V} = Data) ->
    Data1 = release(V, Data),
    Data1#data{repl = [], unflushed = 0}.

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

cancel(undefined) ->
    ok;
cancel(TRef) ->
    ok = erlang:cancel_timer(TRef, [{async, true}, {info, false}]).

cancel_all(#data{timers = Timers} = Data) ->
    _ = [cancel(T) || T <- maps:values(Timers)],
    Data#data{timers = #{}}.

arm_timers(#data{logic = Logic} = Data) ->
    Now = erlang:system_time(millisecond),
    lists:foldl(fun({Key, Ms}, D) ->
                        {_, D1} = execute([{start_timer, Key, Ms}], ok, D),
                        D1
                end, cancel_all(Data), evatar_pairing_logic:timers(Logic, Now)).

%% ---------------------------------------------------------------------------
%% Roles
%% ---------------------------------------------------------------------------

become_active(new, #data{id = Id, config = Config} = Data) ->
    Logic = evatar_pairing_logic:new(Id, Config),
    ?LOG_INFO(#{what => pairing_started, pairing => Id}),
    Data1 = publish(Data#data{logic = Logic, role = active, gen = evatar_cluster:stall_gen(),
                              metrics = evatar_metrics:pairing(Id)}),
    {next_state, evatar_pairing_logic:phase(Logic), Data1,
     [{{timeout, place}, 0, place} || wants_standby(Data1)]}.

%% An instance that won the election at `Epoch' takes over: a standby
%% (fully applied up to its version) or a fenced active asking again. It
%% holds every effect until the cluster accepted its new configuration
%% `{Epoch, 1}' (send_register/1), which no other instance's claim can
%% reach; then it releases them and places a standby. Resumes held while it
%% was a standby are served now.
take_over(Why, Epoch, #data{id = Id, active_mon = Mon, standby_mon = SMon} = Data) ->
    _ = [erlang:demonitor(M, [flush]) || M <- [Mon, SMon], is_reference(M)],
    _ = [evatar_ha_proto_v1:dismiss(P, self()) || P <- [Data#data.standby], is_pid(P)],
    ?LOG_WARNING(#{what => takeover, pairing => Id, epoch => Epoch, reason => Why,
                   version => Data#data.version}),
    ok = evatar_metrics:inc(evatar_takeovers_total, takeover_reason(Why)),
    Data1 = Data#data{role = active, metrics = evatar_metrics:pairing(Id), active = undefined, active_mon = undefined,
                      active_lost = false, standby = undefined, standby_mon = undefined,
                      synced = false, repl = [], election = undefined, hold = true,
                      conf = {Epoch, 1}, gen = evatar_cluster:stall_gen(), held = []},
    Data2 = arm_timers(Data1),
    {_, Data3} = step({takeover, Epoch}, Data2),
    Data4 = arm_silent(publish(send_register(Data3))),
    next(Data4, [{next_event, {call, From}, Request} || {From, Request, _} <- lists:reverse(Data#data.held)]).

takeover_reason({Why, _}) -> Why;
takeover_reason(Why) -> Why.

become_standby(_Epoch, Version, State, Claim, #data{id = Id, active = Active} = Data) ->
    ok = evatar_ha_proto_v1:confirm(Active, evatar_pairing_logic:epoch(State), Version),
    ?LOG_INFO(#{what => standby_synced, pairing => Id, active => node_of(Active),
                version => Version}),
    Data1 = publish(Data#data{logic = State, version = Version, role = standby,
                              active_lost = false, conf = Claim, election = undefined}),
    {next_state, standby, Data1}.

offer_to(Active, #data{version = V} = Data) ->
    Mon = erlang:monitor(process, Active),
    ok = evatar_ha_proto_v1:offer(Active, self(), V),
    {keep_state, Data#data{active = Active, active_mon = Mon},
     [{state_timeout, 5 * evatar_cluster:opt(suspect_ms) + 2000, offered}]}.

ask_peers(Peers, #data{id = Id, asks = _} = Data) ->
    _ = [evatar_ha_proto_v1:ask(N, Id, self()) || N <- Peers],
    {keep_state, Data#data{asks = length(Peers), answers = []},
     [{state_timeout, 2 * evatar_cluster:opt(suspect_ms), asked}]}.

%% A restarted instance: an active elsewhere takes it as its standby; a
%% standby elsewhere is about to take over (ask again); nobody: start afresh.
decide_start(#data{answers = Answers} = Data) ->
    Infos = [I || {_, I} <- Answers, is_map(I)],
    case [I || #{role := R} = I <- Infos, R =:= active orelse R =:= fenced] of
        [#{pid := Active} | _] ->
            offer_to(Active, Data);
        [] ->
            case [I || #{role := standby} = I <- Infos] of
                [_ | _] when Data#data.asks > 0 ->
                    {keep_state, Data#data{answers = []},
                     [{state_timeout, evatar_cluster:opt(suspect_ms), retry_ask}]};
                _ ->
                    become_active(new, Data)
            end
    end.

publish(#data{id = Id, role = Role, logic = Logic} = Data) ->
    Epoch = case Logic of
                undefined -> 0;
                _ -> evatar_pairing_logic:epoch(Logic)
            end,
    Peer = case Role of
               standby -> Data#data.active;
               _ -> Data#data.standby
           end,
    ok = evatar_registry:set_role(Id, self(), Role, Epoch, Peer),
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

wants_standby(#data{role = active, standby = undefined, placing = false}) ->
    evatar_cluster:opt(standby) =:= true andalso evatar_cluster:size() > 1;
wants_standby(_) ->
    false.

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
                    erlang:send_after(?PLACE_RETRY_MS, self(), {evatar_cluster, place_retry}),
                    Data#data{placing = true}
            end;
        false ->
            Data
    end;
place(_State, Data) ->
    Data.

%% ---------------------------------------------------------------------------
%% Replication and role messages
%% ---------------------------------------------------------------------------

%% Active: a new instance offers to be the standby.
ha({offer, Standby, _V}, State, #data{standby = undefined, reg = undefined} = Data)
  when State =:= waiting; State =:= bound ->
    Mon = erlang:monitor(process, Standby),
    Data1 = Data#data{standby = Standby, standby_mon = Mon, synced = false, placing = false},
    {keep_state, publish(snapshot_to(Data1))};
ha({offer, Standby, _V}, _State, #data{standby = Standby} = Data) ->
    {keep_state, snapshot_to(Data)};
ha({offer, Standby, _V}, _State, _Data) ->
    ok = evatar_ha_proto_v1:dismiss(Standby, self()),
    keep_state_and_data;
ha({resync, Standby, _V}, _State, #data{standby = Standby} = Data) ->
    {keep_state, snapshot_to(Data)};
ha({resync, Other, _V}, _State, _Data) ->
    ok = evatar_ha_proto_v1:dismiss(Other, self()),
    keep_state_and_data;
ha({confirm, Standby, _E, V}, State, #data{standby = Standby, confirmed = C} = Data) ->
    Data1 = release(V, Data#data{confirmed = max(C, V), synced = true}),
    case State of
        handing_over -> {keep_state, send_handover(Data1)};
        _ -> {keep_state, Data1}
    end;
ha({confirm, _Other, _E, _V}, _State, _Data) ->
    keep_state_and_data;

%% Standby: the state, then the events in order. Word from the active ends
%% any election this standby had started.
ha({snapshot, Active, Epoch, Version, State, Claim}, standby, #data{active = Active} = Data) ->
    become_standby(Epoch, Version, State, Claim, Data);
ha({events, Active, _Epoch, Events}, standby, #data{active = Active, logic = Logic} = Data) ->
    Before = evatar_pairing_logic:epoch(Logic),
    {keep_state, Data1} = apply_events(Events, remonitor_active(Data#data{active_lost = false,
                                                                          election = undefined})),
    case evatar_pairing_logic:epoch(Data1#data.logic) of
        Before -> {keep_state, Data1};
        _ -> {keep_state, publish(Data1)}
    end;
ha({events, From, Epoch, _Events}, State, Data) ->
    other_instance(From, active, Epoch, State, Data);
ha({dismiss, Active}, standby, #data{active = Active} = Data) ->
    stop_instance(dismissed, Data);
ha({dismiss, _}, _State, _Data) ->
    keep_state_and_data;
ha({handover, Active, Epoch, Version}, standby,
   #data{active = Active, version = Version, logic = Logic} = Data) ->
    case evatar_pairing_logic:epoch(Logic) =:= Epoch of
        true ->
            %% The active gives the pairing up: an election in which its
            %% lease does not count.
            {keep_state, elect(Data#data{active_lost = true,
                                         election = #{epoch => 0, granted => [], replied => [],
                                                      dead => true, why => handover,
                                                      attempt => 0}})};
        false ->
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
    Data2 = cancel_all(Data1#data{role = standby, active = New, active_mon = Mon,
                                  standby = undefined, standby_mon = undefined,
                                  outbox = queue:new(), repl = [], acks = #{}, conf = Claim,
                                  hold = false, reg = undefined}),
    {next_state, standby, reconfirmed(standby, publish(Data2))};
ha({stale, From, Epoch}, State, Data) ->
    other_instance(From, active, Epoch, State, Data);
ha({peer_instance, Pid, Role, Epoch}, State, Data) when is_pid(Pid), is_atom(Role),
                                                       is_integer(Epoch) ->
    other_instance(Pid, Role, Epoch, State, Data);

%% Elections and registrations: the answers of every node.
ha({vote_reply, _Id, Ec, Node, Result}, State,
   #data{election = #{epoch := Ec, granted := G, replied := R} = El} = Data)
  when State =:= standby; State =:= fenced ->
    El1 = El#{replied := lists:usort([Node | R])},
    case Result of
        granted ->
            G1 = lists:usort([Node | G]),
            case length(G1) >= evatar_cluster:quorum_size() of
                true -> won(El1, State, Data);
                false -> {keep_state, Data#data{election = El1#{granted := G1}}}
            end;
        {refused, stale_claim} ->
            %% A newer configuration released what this instance lacks.
            lost(stale_claim, State, Data);
        {refused, {promised, P}} ->
            {keep_state, retry_soon(Data#data{election = El1, promised = max(P, Data#data.promised)})};
        {refused, holder_live} ->
            {keep_state, Data#data{election = El1}}
    end;
ha({vote_reply, _, _, _, _}, _State, _Data) ->
    keep_state_and_data;
ha({register_reply, _Id, Claim, Node, ok}, State,
   #data{reg = #{claim := Claim, ok := Ok} = Reg} = Data) ->
    Ok1 = lists:usort([Node | Ok]),
    case length(Ok1) >= evatar_cluster:quorum_size() of
        true -> registered(State, Data#data{reg = undefined});
        false -> {keep_state, Data#data{reg = Reg#{ok := Ok1}}}
    end;
ha({register_reply, _Id, Claim, Node, {refused, Why}}, State,
   #data{reg = #{claim := Claim, no := No} = Reg} = Data) ->
    No1 = lists:usort([Node | No]),
    Size = evatar_cluster:size(),
    case Size - length(No1) < evatar_cluster:quorum_size() of
        true ->
            %% Too many nodes promised the pairing to another instance, or saw
            %% a newer configuration: this one cannot go on serving.
            ?LOG_WARNING(#{what => registration_refused, pairing => Data#data.id,
                           reason => Why}),
            D1 = Data#data{reg = undefined},
            case State of
                S when S =:= waiting; S =:= bound -> fence_now(D1, []);
                _ -> {keep_state, D1}
            end;
        false ->
            {keep_state, Data#data{reg = Reg#{no := No1}}}
    end;
ha({register_reply, _, _, _, _}, _State, _Data) ->
    keep_state_and_data;
ha(_Body, _State, _Data) ->
    keep_state_and_data.

%% A new standby gets the whole state and a new claim: the configuration
%% with it as the standby.
snapshot_to(#data{standby = Standby, logic = Logic, version = V, conf = {E, Seq}} = Data) ->
    Claim = {E, Seq + 1},
    ok = evatar_ha_proto_v1:snapshot(Standby, evatar_pairing_logic:epoch(Logic), V, Logic, Claim),
    %% The snapshot holds every event queued so far.
    Data#data{repl = [], unflushed = 0, conf = Claim}.

apply_events([{V, Now, Event} | Rest], #data{version = Mine} = Data) when V =:= Mine + 1 ->
    {Logic1, _Effects} = evatar_pairing_logic:handle(Event, Now, Data#data.logic),
    apply_events(Rest, Data#data{logic = Logic1, version = V});
apply_events([{V, _, _} | Rest], #data{version = Mine} = Data) when V =< Mine ->
    apply_events(Rest, Data);
apply_events([_Gap | _], #data{active = Active, version = Mine} = Data) ->
    ok = evatar_ha_proto_v1:resync(Active, self(), Mine),
    {keep_state, Data};
apply_events([], #data{active = Active, logic = Logic, version = V} = Data) ->
    ok = evatar_ha_proto_v1:confirm(Active, evatar_pairing_logic:epoch(Logic), V),
    {keep_state, Data}.

%% What this instance does about another instance of its pairing.
other_instance(Pid, Role, Epoch, State, #data{logic = Logic} = Data) ->
    MyRole = case State of
                 S when S =:= waiting; S =:= bound; S =:= handing_over -> active;
                 S -> S
             end,
    MyEpoch = case Logic of
                  undefined -> 0;
                  _ -> evatar_pairing_logic:epoch(Logic)
              end,
    Peer = case MyRole of
               standby -> Data#data.active;
               _ -> Data#data.standby
           end,
    Me = #{role => MyRole, epoch => MyEpoch, node => node(), pid => self(), peer => Peer},
    Other = #{role => Role, epoch => Epoch, node => node(Pid), pid => Pid},
    case MyRole =:= starting orelse Pid =:= self() of
        true ->
            keep_state_and_data;
        false ->
            case evatar_ha_rules:reconcile(Me, Other) of
                step_down ->
                    _ = [evatar_ha_proto_v1:dismiss(P, self()) || P <- [Data#data.standby],
                                                                  is_pid(P), P =/= Pid],
                    step_down({newer_instance, node(Pid), Epoch}, Data);
                stop ->
                    stop_instance({newer_instance, node(Pid), Epoch}, Data);
                keep when MyRole =:= active, Role =/= standby, MyEpoch > Epoch ->
                    %% Let the stale one know at once.
                    ok = evatar_ha_proto_v1:stale(Pid, self(), MyEpoch),
                    keep_state_and_data;
                keep ->
                    keep_state_and_data
            end
    end.

remonitor_active(#data{active = Active, active_mon = undefined} = Data) when is_pid(Active) ->
    Data#data{active_mon = erlang:monitor(process, Active)};
remonitor_active(Data) ->
    Data.

%% ---------------------------------------------------------------------------
%% Failure detection
%% ---------------------------------------------------------------------------

cluster_event(place_retry, State, Data) ->
    {keep_state, place(State, Data#data{placing = false})};
cluster_event({node_alive, _Node}, State, Data) when State =:= waiting; State =:= bound ->
    {keep_state, place(State, Data)};
cluster_event({Lost, Node}, State, #data{standby = Standby} = Data)
  when (Lost =:= node_suspected orelse Lost =:= node_down), is_pid(Standby),
       node(Standby) =:= Node, State =/= standby ->
    standby_down(noconnection, State, Data);
cluster_event({Lost, Node}, standby, #data{active = Active} = Data)
  when (Lost =:= node_suspected orelse Lost =:= node_down), is_pid(Active),
       node(Active) =:= Node ->
    {keep_state, start_election(active_silent, false, Data#data{active_lost = true})};
cluster_event({node_alive, Node}, standby, #data{active = Active, active_lost = true} = Data)
  when is_pid(Active), node(Active) =:= Node ->
    %% The active's node is back: pick up the replication again (an
    %% election under way goes on: the nodes decide).
    ok = evatar_ha_proto_v1:resync(Active, self(), Data#data.version),
    {keep_state, remonitor_active(Data)};
cluster_event({quorum, true}, standby, #data{active_lost = true} = Data) ->
    {keep_state, start_election(active_silent, false, Data)};
cluster_event({quorum, false}, State, Data) when State =:= waiting; State =:= bound ->
    maybe_fence(Data);
cluster_event(stalled, State, Data) when State =:= waiting; State =:= bound ->
    %% This node was stopped for longer than suspect_ms: the pairing may
    %% have another active by now, or (far more often) not.
    {keep_state, paused(Data)};
cluster_event({quorum, true}, fenced, Data) ->
    {keep_state, start_election(fenced, false, Data)};
cluster_event({node_alive, _}, fenced, Data) ->
    {keep_state, start_election(fenced, false, Data)};
cluster_event(_Event, _State, _Data) ->
    keep_state_and_data.

%% The standby's process died (its node is up): it cannot take over, so go
%% on without it at once. Its node is lost or silent: it may be taking over
%% (a partition looks the same), so first the cluster must accept a
%% configuration without it; everything stays held until then.
standby_down(Why, State, #data{id = Id, standby = Standby} = Data) ->
    ?LOG_WARNING(#{what => standby_lost, pairing => Id, standby => node_of(Standby),
                   reason => Why}),
    case Why of
        noconnection ->
            #data{standby_mon = Mon, conf = {E, Seq}} = Data,
            _ = [erlang:demonitor(Mon, [flush]) || is_reference(Mon)],
            _ = [evatar_ha_proto_v1:dismiss(Standby, self()) || is_pid(Standby)],
            Claim = {E, Seq + 1},
            Data1 = Data#data{standby = undefined, standby_mon = undefined, synced = false,
                              repl = [], unflushed = 0, conf = Claim, hold = true,
                              reg = #{claim => Claim, ok => [], no => []}},
            %% A heartbeat later: by then a partition that cuts this node
            %% off entirely has fenced it, and it registers nothing.
            _ = erlang:send_after(evatar_cluster:opt(heartbeat_ms), self(),
                                  {evatar_register_retry, Claim}),
            {keep_state, publish(Data1)};
        _ ->
            {keep_state, place(State, drop_standby(Data))}
    end.

drop_standby(#data{standby = Standby, standby_mon = Mon} = Data) ->
    _ = [erlang:demonitor(Mon, [flush]) || is_reference(Mon)],
    _ = [evatar_ha_proto_v1:dismiss(Standby, self()) || is_pid(Standby)],
    Data1 = release_all(Data#data{standby = undefined, standby_mon = undefined,
                                  synced = false}),
    publish(Data1).

active_down(noconnection, standby, Data) ->
    {keep_state, start_election(active_silent, false, Data#data{active_lost = true})};
active_down(Why, standby, Data) ->
    %% The process died and its node is up: its lease counts no more.
    {keep_state, start_election({active_died, Why}, true, Data#data{active_lost = true})};
active_down(_Why, _State, _Data) ->
    keep_state_and_data.

%% ---------------------------------------------------------------------------
%% Elections: a standby whose active is gone, or a fenced active, asks every
%% node for the pairing at a new epoch (evatar_ha_rules:vote/5 decides on
%% each node); a majority of grants (1 of 2 in a two-node cluster) wins.
%% ---------------------------------------------------------------------------

start_election(_Why, _Dead, #data{election = #{}} = Data) ->
    Data;
start_election(Why, Dead, Data) ->
    elect(Data#data{election = #{epoch => 0, granted => [], replied => [], dead => Dead,
                                 why => Why, attempt => 0}}).

%% (Re)sends the vote requests at an epoch above any promise seen.
elect(#data{election = #{dead := Dead, attempt := N} = El, id = Id, logic = Logic,
            conf = Claim} = Data) ->
    %% The same epoch again (a node grants its promise to the same
    %% candidate twice), unless a refusal showed a higher promise.
    Ec = max(maps:get(epoch, El),
             max(evatar_pairing_logic:epoch(Logic), Data#data.promised) + 1),
    Active = case Data#data.role of
                 standby -> Data#data.active;
                 _ -> self()
             end,
    _ = [evatar_ha_proto_v1:vote(N1, Id, Ec, self(), Claim, Active, Dead)
         || N1 <- evatar_cluster:configured()],
    %% Quick retries at first (a node may not have seen a killed node's
    %% connection close yet), then once per heartbeat.
    Hb = evatar_cluster:opt(heartbeat_ms),
    _ = erlang:send_after(min(Hb, 10 bsl min(N, 6)), self(), {evatar_election_retry, Ec}),
    Data#data{election = El#{epoch := Ec, granted := [], replied := [], attempt := N + 1}}.

%% Refused for a promise to another candidate: ask again above it.
retry_soon(#data{election = #{epoch := Ec}} = Data) ->
    _ = erlang:send_after(5, self(), {evatar_election_retry, Ec}),
    Data.

won(#{epoch := Ec, why := handover}, standby, #data{active = Old, version = V} = Data) ->
    %% The old active becomes this one's standby, already in sync, with
    %% the claim {Ec, 1}.
    {next_state, S, D, A} = take_over(handover, Ec, Data),
    Mon = erlang:monitor(process, Old),
    D1 = D#data{standby = Old, standby_mon = Mon, synced = true, confirmed = V,
                placing = false, reg = undefined, hold = false},
    ok = evatar_ha_proto_v1:handover_done(Old, self(), Ec, {Ec, 1}),
    {next_state, S, publish(flush(D1)), A};
won(#{epoch := Ec, why := Why}, _State, Data) ->
    take_over(Why, Ec, Data).

lost(Why, standby, Data) ->
    stop_instance(Why, reply_held(Data));
lost(Why, _State, Data) ->
    step_down(Why, Data).

%% Asks every node to record this active's configuration; effects stay held
%% until a majority did (registered/2).
send_register(#data{id = Id, conf = {E, Seq}} = Data) ->
    Done = case Data#data.reg of
               #{claim := {E, Seq}, ok := Ok} -> Ok;
               _ -> []
           end,
    _ = [evatar_ha_proto_v1:register(N, Id, E, Seq, self())
         || N <- evatar_cluster:configured(), not lists:member(N, Done)],
    _ = erlang:send_after(2 * evatar_cluster:opt(heartbeat_ms) + 50, self(),
                          {evatar_register_retry, {E, Seq}}),
    Data#data{hold = true, reg = #{claim => {E, Seq}, ok => Done, no => []}}.

registered(State, #data{standby = Standby} = Data) when is_pid(Standby) ->
    %% A reconfirmation after a pause: the standby's confirmations still
    %% decide what goes out.
    {keep_state, reconfirmed(State, Data#data{hold = false})};
registered(State, Data0) ->
    Data = reconfirmed(State, Data0),
    Data1 = release_all(Data#data{hold = false}),
    {keep_state, place(State, Data1), [{{timeout, place}, 0, place} || wants_standby(Data1)]}.

%% ---------------------------------------------------------------------------
%% Fencing
%% ---------------------------------------------------------------------------

maybe_fence(#data{standby = Standby} = Data) ->
    StandbyHeard = is_pid(Standby) andalso
        evatar_cluster:heard_within(node(Standby), evatar_cluster:opt(lease_ms)),
    case evatar_ha_rules:must_fence(evatar_cluster:size(), evatar_cluster:majority_now(),
                                    StandbyHeard) of
        true -> fence_now(Data, []);
        false -> keep_state_and_data
    end.

%% Stops serving: every client is closed with Fenced (they go to their
%% other endpoints), nothing goes out; with a majority heard it asks for
%% the pairing again at once (an election in which its standby may win).
fence_now(#data{id = Id} = Data, Actions) ->
    ?LOG_WARNING(#{what => fenced, pairing => Id}),
    ok = evatar_metrics:inc(evatar_fenced_total),
    Data1 = disconnect_all(fenced, <<"this node lost the majority of the cluster">>,
                           Data#data{role = fenced}),
    Data2 = case evatar_cluster:majority_now() of
                true -> start_election(fenced, false, Data1);
                false -> Data1
            end,
    {next_state, fenced, reconfirmed(fenced, publish(Data2)), Actions}.

stalled_active(State, #data{gen = Gen}) when State =:= waiting; State =:= bound ->
    not evatar_cluster:unstalled(Gen);
stalled_active(_State, _Data) ->
    false.

%% This node was paused itself while this instance was active (SIGSTOP, a
%% laptop lid, a long GC): told apart from a loss of the peers by
%% evatar_cluster, decided by evatar_ha_rules:after_pause/2. Nothing is
%% fenced for the pause alone: with a standby, only what it confirmed goes
%% out, and a standby that took over meanwhile confirms nothing more; a
%% reconfirmation holds the rest until a majority recorded this active's
%% configuration again (or refused it, and the active fences).
paused(#data{id = Id, reg = Reg} = Data) ->
    Data1 = Data#data{gen = evatar_cluster:stall_gen()},
    case evatar_ha_rules:after_pause(evatar_cluster:size(), Reg =/= undefined) of
        keep ->
            Data1;
        await ->
            Data1#data{reconfirming = true};
        reconfirm ->
            ?LOG_NOTICE(#{what => reconfirming_after_pause, pairing => Id,
                          claim => Data1#data.conf}),
            send_register(Data1#data{reconfirming = true})
    end.

%% ---------------------------------------------------------------------------
%% Resumes held by a standby
%% ---------------------------------------------------------------------------

arm_held(#data{held_armed = true} = Data) ->
    Data;
arm_held(Data) ->
    _ = erlang:send_after(max(5, evatar_cluster:opt(heartbeat_ms) div 2), self(),
                          evatar_held_check),
    Data#data{held_armed = true}.

%% A held resume is answered NotActive once the active was heard after it
%% came (the active is alive: the client had another reason to leave it),
%% or after suspect_ms + 2 heartbeats (at most 800 ms) without a decision.
check_held(#data{held = Held, active = Active} = Data) ->
    Now = erlang:monotonic_time(millisecond),
    Max = min(800, evatar_cluster:opt(suspect_ms) + 2 * evatar_cluster:opt(heartbeat_ms)),
    Electing = Data#data.election =/= undefined orelse Data#data.active_lost,
    {Go, Keep} = lists:partition(
                   fun({_, _, Since}) ->
                           Now - Since > Max orelse
                               (not Electing andalso is_pid(Active)
                                andalso evatar_cluster:heard_after(node(Active), Since))
                   end, Held),
    _ = [gen_statem:reply(From, {error, {not_active, node_of(Active)}}) || {From, _, _} <- Go],
    Data1 = Data#data{held = Keep},
    case Keep of
        [] -> Data1;
        _ -> arm_held(Data1)
    end.

reply_held(#data{held = Held, active = Active} = Data) ->
    _ = [gen_statem:reply(From, {error, {not_active, node_of(Active)}}) || {From, _, _} <- Held],
    Data#data{held = []}.

%% ---------------------------------------------------------------------------
%% Silent client links
%% ---------------------------------------------------------------------------

arm_silent(#data{silent_armed = true} = Data) ->
    Data;
arm_silent(Data) ->
    Interval = max(50, evatar_cluster:opt(client_ack_timeout) div 2),
    _ = erlang:send_after(Interval, self(), evatar_silent_check),
    Data#data{silent_armed = true}.

silent_check(#data{logic = Logic, id = Id} = Data) ->
    Timeout = evatar_cluster:opt(client_ack_timeout),
    Now = erlang:system_time(millisecond),
    Silent = [E || {E, T} <- evatar_pairing_logic:unacked_since(Logic), Now - T > Timeout],
    Data1 = lists:foldl(
              fun(E, D) ->
                      ?LOG_WARNING(#{what => silent_link, pairing => Id, entity => E}),
                      ok = evatar_metrics:inc(evatar_entities_dropped_total, silent_link),
                      ok = tell(E, {dropped, silent_link,
                                    <<"delivered signals were not acknowledged in time">>}, D),
                      run({detach, E}, forget(E, D))
              end, Data, Silent),
    Handover = Silent =/= [] andalso evatar_cluster:opt(handover_on_silent_link) =:= true
        andalso is_pid(Data1#data.standby) andalso Data1#data.synced,
    Data2 = arm_silent(Data1),
    case Handover of
        true ->
            {next_state, handing_over, flush(Data2),
             [{state_timeout, 4 * evatar_cluster:opt(suspect_ms), handover},
              {next_event, internal, handover}]};
        false ->
            next(flush_maybe(Data2), [])
    end.

%% The planned handover goes once the standby has confirmed everything.
send_handover(#data{standby = Standby, confirmed = V, version = V, logic = Logic} = Data)
  when is_pid(Standby) ->
    ok = evatar_ha_proto_v1:handover(Standby, evatar_pairing_logic:epoch(Logic), V),
    Data;
send_handover(Data) ->
    flush(Data).

peers() ->
    [N || N <- evatar_cluster:alive_nodes(), N =/= node()].

node_of(Pid) when is_pid(Pid) -> node(Pid);
node_of(_) -> undefined.

node_name(Pid) -> atom_to_binary(node(Pid)).

ha_status(#data{role = Role, logic = Logic, version = V} = Data) ->
    Epoch = case Logic of
                undefined -> 0;
                _ -> evatar_pairing_logic:epoch(Logic)
            end,
    {Active, Standby} = case Role of
                            standby -> {Data#data.active, undefined};
                            starting -> {Data#data.active, undefined};
                            _ -> {self(), Data#data.standby}
                        end,
    #{role => Role, epoch => Epoch, node => node(), active => Active, standby => Standby,
      standby_node => node_of(Standby),
      synced => case Role of
                    standby -> true;
                    _ -> Data#data.synced
                end,
      version => V}.

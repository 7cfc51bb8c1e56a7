%% @doc Internal. The effect executor of `evatar_pairing''s process: carries
%% out the I/O that the pure instance (`evatar_ha_instance': the role, the
%% pairing's rules and the output commit in one state) returns, on the
%% entities' processes, the other instance, the monitors and the one map
%% of timers held in the process's state (docs/ha-design.md, section 12).
%% It decides nothing.
-module(evatar_pairing_effects).

-export([rules/2, run/2, effect/2, inspect/3, next/2, phase/2, report_binding/2, reply/3,
         flush_maybe/1, flush/1, forget/2, timer/3, effects/3, reply_held/1, role/1,
         ha_status/1, epoch/1]).

-include_lib("kernel/include/logger.hrl").
-include("evatar_pairing.hrl").

-type data() :: #data{}.
-type state() :: starting | evatar_pairing_logic:phase() | standby | fenced | handing_over.

%% @doc What an inspection of the pairing shows.
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

%% @doc The state after an event: the instance's role (an active's is its
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

%% @doc One event of a client through the rules; returns their reply.
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

%% @doc Carries out the instance's effects, in order.
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
effect({tell, EntityId, Msg}, Data) ->
    ok = tell(EntityId, Msg, Data),
    Data;
effect({to_conn, {Pid, _Ref}, Msg}, #data{id = Id} = Data) ->
    Pid ! {evatar, Id, Msg},
    Data;
effect({drop, EntityId, Code, Reason}, Data) ->
    ok = tell(EntityId, {dropped, Code, Reason}, Data),
    forget(EntityId, Data);
effect({reply_to, From, R}, Data) ->
    gen_statem:reply(From, R),
    Data;
effect({acks, Acks}, #data{id = Id, pids = Pids} = Data) ->
    maps:foreach(fun(EntityId, SignalId) ->
                         case Pids of
                             #{EntityId := {Pid, _}} -> Pid ! {evatar, Id, {ack, SignalId}};
                             #{} -> ok
                         end
                 end, Acks),
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
effect({ask, Peers}, #data{id = Id} = Data) ->
    _ = [evatar_ha_proto_v1:ask(N, Id, self()) || N <- Peers],
    Data;
effect({start_standby, Node}, #data{id = Id, config = Config} = Data) ->
    ok = evatar_ha_proto_v1:start_standby(Node, Id, Config, self(), epoch(Data)),
    Data;
effect({vote, Node, Ec, Claim, Active, Dead}, #data{id = Id} = Data) ->
    ok = evatar_ha_proto_v1:vote(Node, Id, Ec, self(), Claim, Active, Dead),
    Data;
effect({restore_vote, Node, Ec, NoneOn}, #data{id = Id} = Data) ->
    ok = evatar_ha_proto_v1:restore_vote(Node, Id, Ec, self(), NoneOn),
    Data;
effect({register, Node, {E, Seq}}, #data{id = Id} = Data) ->
    ok = evatar_ha_proto_v1:register(Node, Id, E, Seq, self()),
    Data;
effect({monitor, Which, Pid}, #data{mons = Mons} = Data) ->
    _ = [erlang:demonitor(M, [flush]) || M <- [maps:get(Which, Mons, undefined)], is_reference(M)],
    Data#data{mons = Mons#{Which => erlang:monitor(process, Pid)}};
effect({demonitor, Which}, #data{mons = Mons} = Data) ->
    _ = [erlang:demonitor(M, [flush]) || M <- [maps:get(Which, Mons, undefined)], is_reference(M)],
    Data#data{mons = maps:remove(Which, Mons)};
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
effect({disconnect_all, Code, Reason}, #data{id = Id, pids = Pids} = Data) ->
    %% The entities stay in the state, for a resume elsewhere.
    _ = [Pid ! {evatar, Id, {dropped, Code, Reason}} || {Pid, _} <- maps:values(Pids)],
    _ = [erlang:demonitor(Ref, [flush]) || {_, Ref} <- maps:values(Pids)],
    Data#data{pids = #{}, refs = #{}};
effect({standby_node, Node}, #data{config = Config} = Data) ->
    Data#data{config = Config#{standby_node => Node}};
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

%% @doc The resumes a standby held are answered NotActive.
-spec reply_held(data()) -> data().
reply_held(#data{held = Held, inst = Inst} = Data) ->
    Node = node_of(evatar_ha_instance:active(Inst)),
    _ = [gen_statem:reply(From, {error, {not_active, Node}}) || {From, _, _} <- Held],
    Data#data{held = []}.

%% @doc `evatar:ha_status/1''s answer.
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

%% @doc The pairing's epoch (0 while starting).
-spec epoch(data()) -> non_neg_integer().
epoch(#data{inst = Inst}) -> evatar_ha_instance:epoch(Inst).

node_of(Pid) -> evatar_ha_instance:node_of(Pid).

%% @doc Internal. The effect executor of `evatar_pairing''s process: runs
%% an event through the pairing's rules (`evatar_pairing_logic') and the
%% output commit (`evatar_ha_commit'), and carries out what they and the
%% role machine (`evatar_ha_instance') decided, on the entities' processes,
%% the other instance, the monitors and the one map of timers held in the
%% process's state (docs/ha-design.md, section 12). It decides nothing.
-module(evatar_pairing_effects).

-export([step/2, run/2, effect/2, inspect/3, next/2, phase/2, mode/1, report_binding/2, reply/3,
         flush_maybe/1,
         flush/2, forget/2, timer/3, arm_logic_timers/1, effects/3, reply_held/1, role/1,
         ha_status/1]).

-include_lib("kernel/include/logger.hrl").
-include("evatar_pairing.hrl").

-type data() :: #data{}.
-type state() :: starting | evatar_pairing_logic:phase() | standby | fenced | handing_over.

%% @doc What an inspection of the pairing shows.
-spec inspect(atom(), state(), data()) -> term().
inspect(ha, _State, Data) ->
    ha_status(Data);
inspect(What, State, #data{logic = Logic, commit = C} = Data) ->
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
        versioned_state -> {evatar_ha_commit:version(C), Logic}
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

%% The logic's timers only: re-armed from its state on a takeover, dropped
%% on a handover.
cancel_logic_timers(#data{timers = Timers} = Data) ->
    {Ha, Logic} = maps:fold(fun({ha, _} = K, T, {H, L}) -> {H#{K => T}, L};
                               (_K, T, {H, L}) -> {H, [T | L]}
                            end, {#{}, []}, Timers),
    _ = [cancel(T) || T <- Logic],
    Data#data{timers = Ha}.

-spec arm_logic_timers(data()) -> data().
arm_logic_timers(#data{logic = Logic} = Data) ->
    Now = erlang:system_time(millisecond),
    lists:foldl(fun({Key, Ms}, D) -> timer(Key, Ms, D) end, cancel_logic_timers(Data),
                evatar_pairing_logic:timers(Logic, Now)).

%% ---------------------------------------------------------------------------
%% Running the logic, and the output commit
%% ---------------------------------------------------------------------------

%% @doc The state after an event: the instance's role (an active's is its
%% phase), with the actions to take.
-spec next(data(), [gen_statem:action()]) -> gen_statem:event_handler_result(state()).
next(#data{inst = Inst, logic = Logic} = Data, Actions) ->
    case evatar_ha_instance:role(Inst) of
        active -> {next_state, evatar_pairing_logic:phase(Logic), Data, Actions};
        Role -> {next_state, Role, Data, Actions}
    end.

-spec phase(state(), evatar_pairing_logic:state()) -> state().
phase(State, Logic) when State =:= waiting; State =:= bound ->
    evatar_pairing_logic:phase(Logic);
phase(State, _Logic) ->
    State.

-spec run(evatar_pairing_logic:event(), data()) -> data().
run(Event, Data) ->
    {_Reply, Data1} = step(Event, Data),
    Data1.

%% @doc Applies one event to the logic; returns its reply.
-spec step(evatar_pairing_logic:event(), data()) -> {term(), data()}.
step(Event, Data) ->
    step(Event, mode(Data), Data).

%% Applies one event to the logic; evatar_ha_commit says what of its
%% effects goes out now. Returns the logic's reply (`ok' for events that
%% have none).
step(Event, Mode, #data{logic = Logic, commit = C, pids = Pids} = Data) ->
    Now = erlang:system_time(millisecond),
    {Logic1, Effects} = evatar_pairing_logic:handle(Event, Now, Logic),
    ok = evatar_metrics:pairing_step(Data#data.metrics, Event, Effects),
    Watchers = case Data#data.watchers of
                   [] -> [];
                   W -> evatar_tap:emit(Data#data.id, Event, Effects, Now, W)
               end,
    %% Only held effects are bound to a connection (evatar_ha_commit:step/6):
    %% a pairing without a standby does not rebuild the map for each signal.
    Conns = case Mode of
                direct -> #{};
                _ -> maps:map(fun(_, {Pid, _}) -> Pid end, Pids)
            end,
    {Reply, Out, C1} = evatar_ha_commit:step(Event, Now, Effects, Conns, Mode, C),
    {Reply, execute(Out, Data#data{logic = Logic1, commit = C1, watchers = Watchers})}.

-spec mode(data()) -> evatar_ha_commit:mode().
mode(#data{inst = Inst}) -> evatar_ha_instance:mode(Inst).

%% A GetBinding (docs/protocol.md section 2): the current report, to that
%% entity only. It changes no state, so it is not shipped to the standby.
-spec report_binding(binary(), data()) -> data().
report_binding(EntityId, #data{logic = Logic, pids = Pids, commit = C} = Data) ->
    {_, Effects} = evatar_pairing_logic:handle({report_binding, EntityId}, 0, Logic),
    Sends = [{send, Pid, {bound, R}} || {report, E, R} <- Effects,
                                        {Pid, _} <- [maps:get(E, Pids, {undefined, x})],
                                        is_pid(Pid)],
    {Out, C1} = evatar_ha_commit:report(Sends, mode(Data), C),
    execute(Out, Data#data{commit = C1}).

%% A call's reply, held like any other effect.
-spec reply(gen_statem:from(), term(), data()) -> data().
reply(From, Reply, #data{commit = C} = Data) ->
    {Out, C1} = evatar_ha_commit:reply(From, Reply, mode(Data), C),
    execute(Out, Data#data{commit = C1}).

-spec flush_maybe(data()) -> data().
flush_maybe(Data) ->
    flush_maybe(mode(Data), Data).

flush_maybe(Mode, #data{commit = C} = Data) ->
    {message_queue_len, N} = erlang:process_info(self(), message_queue_len),
    commit(evatar_ha_commit:flush_maybe(N, Mode, C), Data).

-spec flush(evatar_ha_commit:mode(), data()) -> data().
flush(Mode, #data{commit = C} = Data) ->
    commit(evatar_ha_commit:flush(Mode, C), Data).

commit({Out, C}, Data) ->
    execute(Out, Data#data{commit = C}).

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
execute([{ship, Events} | Rest], #data{inst = Inst, logic = Logic} = Data) ->
    ok = evatar_ha_proto_v1:events(evatar_ha_instance:standby(Inst),
                                   evatar_pairing_logic:epoch(Logic), Events),
    execute(Rest, Data);
execute([flush_later | Rest], Data) ->
    self() ! evatar_flush,
    execute(Rest, Data);
execute([{start_timer, Key, Ms} | Rest], Data) ->
    execute(Rest, timer(Key, Ms, Data));
execute([{cancel_timer, Key} | Rest], Data) ->
    execute(Rest, untimer(Key, Data));
execute([{log, Level, Report} | Rest], Data) ->
    ok = log(Level, Report, Data),
    execute(Rest, Data);
execute([], Data) ->
    Data.

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

%% @doc Carries out the role machine's effects, in order.
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
effect({ask, Peers}, #data{id = Id} = Data) ->
    _ = [evatar_ha_proto_v1:ask(N, Id, self()) || N <- Peers],
    Data;
effect({start_standby, Node}, #data{id = Id, config = Config, logic = Logic} = Data) ->
    ok = evatar_ha_proto_v1:start_standby(Node, Id, Config, self(), epoch(Logic)),
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
    timer({ha, Key}, Ms, Data);
effect({ensure_timer, Key, Ms}, #data{timers = Timers} = Data) ->
    case Timers of
        #{{ha, Key} := _} -> Data;
        #{} -> timer({ha, Key}, Ms, Data)
    end;
effect({cancel_timer, Key}, Data) ->
    untimer({ha, Key}, Data);
effect(new_logic, #data{id = Id, config = Config} = Data) ->
    Data#data{logic = evatar_pairing_logic:new(Id, Config)};
effect({install, Version, Logic}, #data{commit = C} = Data) ->
    Data#data{logic = Logic, commit = evatar_ha_commit:applied(Version, C)};
effect({apply, Events}, Data) ->
    apply_events(Events, Data);
effect({logic, Event, Mode}, Data) ->
    element(2, step(Event, Mode, Data));
effect(arm_logic_timers, Data) ->
    arm_logic_timers(Data);
effect(cancel_logic_timers, Data) ->
    cancel_logic_timers(Data);
effect({release, Version}, #data{commit = C} = Data) ->
    commit(evatar_ha_commit:confirm(Version, C), Data);
effect(release_all, #data{commit = C} = Data) ->
    commit(evatar_ha_commit:release_all(C), Data);
effect({flush, Mode}, Data) ->
    flush(Mode, Data);
effect({flush_maybe, Mode}, Data) ->
    flush_maybe(Mode, Data);
effect(unsync, #data{commit = C} = Data) ->
    Data#data{commit = evatar_ha_commit:unsync(C)};
effect({synced_at, Version}, #data{commit = C} = Data) ->
    Data#data{commit = evatar_ha_commit:synced_at(Version, C)};
effect(reset_commit, #data{commit = C} = Data) ->
    Data#data{commit = evatar_ha_commit:reset(C)};
effect({snapshot, To, Claim}, #data{logic = Logic, commit = C} = Data) ->
    ok = evatar_ha_proto_v1:snapshot(To, epoch(Logic), evatar_ha_commit:version(C), Logic, Claim),
    Data#data{commit = evatar_ha_commit:shipped(C)};
effect({drop, EntityId, Code, Reason}, Data) ->
    ok = tell(EntityId, {dropped, Code, Reason}, Data),
    run({detach, EntityId}, forget(EntityId, Data));
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
send(To, {confirm, Version}, #data{logic = L}) -> evatar_ha_proto_v1:confirm(To, epoch(L), Version);
send(To, {stale, Epoch}, _Data) -> evatar_ha_proto_v1:stale(To, self(), Epoch);
send(To, {handover, Version}, #data{logic = L}) ->
    evatar_ha_proto_v1:handover(To, epoch(L), Version);
send(To, {handover_done, Ec, Claim}, _Data) ->
    evatar_ha_proto_v1:handover_done(To, self(), Ec, Claim).

%% evatar_ha_role_machine applies the batch; this confirms it, or asks again.
apply_events(Events, #data{inst = Inst, logic = Logic0, commit = C0} = Data) ->
    Apply = fun(Event, Now, L) -> element(1, evatar_pairing_logic:handle(Event, Now, L)) end,
    {Logic, C, Answer} = evatar_ha_role_machine:apply_events(Events, Apply, Logic0, C0),
    Active = evatar_ha_instance:active(Inst),
    ok = case Answer of
             {confirm, V} -> evatar_ha_proto_v1:confirm(Active, epoch(Logic), V);
             {resync, Mine} -> evatar_ha_proto_v1:resync(Active, self(), Mine)
         end,
    Data1 = Data#data{logic = Logic, commit = C},
    case epoch(Logic) =:= epoch(Logic0) of
        true -> Data1;
        false -> publish(Data1)
    end.

publish(#data{id = Id, inst = Inst, logic = Logic} = Data) ->
    Role = role(Data),
    Peer = case Role of
               standby -> evatar_ha_instance:active(Inst);
               _ -> evatar_ha_instance:standby(Inst)
           end,
    ok = evatar_registry:set_role(Id, self(), Role, epoch(Logic), Peer),
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
ha_status(#data{inst = Inst, commit = C, logic = Logic} = Data) ->
    Role = role(Data),
    {Active, Standby} = case Role of
                            standby -> {evatar_ha_instance:active(Inst), undefined};
                            starting -> {evatar_ha_instance:active(Inst), undefined};
                            _ -> {self(), evatar_ha_instance:standby(Inst)}
                        end,
    #{role => Role, epoch => epoch(Logic), node => node(), active => Active, standby => Standby,
      standby_node => node_of(Standby),
      synced => case Role of
                    standby -> true;
                    _ -> evatar_ha_commit:synced(C)
                end,
      version => evatar_ha_commit:version(C)}.


epoch(undefined) -> 0;
epoch(Logic) -> evatar_pairing_logic:epoch(Logic).

node_of(Pid) -> evatar_ha_instance:node_of(Pid).

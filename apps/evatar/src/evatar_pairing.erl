%% @doc Internal. The process of one pairing: runs `evatar_pairing_logic'
%% and executes its effects (messages to entity processes, timers, logs). It
%% owns what cannot be replicated: the pids of the entities' processes, their
%% monitors and the timer references.
%%
%% ```
%%            start_link
%%                |
%%                v
%%           +----------+  internal `load' (now: build the empty state;
%%           | starting |  issue 5: fetch the replicated state)
%%           +----------+
%%                |
%%                v
%%           +---------+  an agent and an avatar registered   +-------+
%%           | waiting | -----------------------------------> | bound |
%%           |         | <----------------------------------- |       |
%%           +---------+  one side left, crashed or dropped   +-------+
%%                |                                               |
%%                +------ delete (stop normal, tree shuts down) --+
%% '''
%% The state name is the logic's {@link evatar_pairing_logic:phase/1}; every
%% event is handled the same way in both, the name is for inspection. Events
%% arriving while `starting' are postponed.
-module(evatar_pairing).
-behaviour(gen_statem).

-include_lib("kernel/include/logger.hrl").

-export([start_link/2]).
-export([init/1, callback_mode/0, handle_event/4, terminate/3]).

-record(data, {id :: evatar:pairing_id(),
               config :: evatar_pairing_logic:config(),
               logic :: evatar_pairing_logic:state() | undefined,
               pids = #{} :: #{binary() => {pid(), reference()}},
               refs = #{} :: #{reference() => binary()},
               timers = #{} :: #{evatar_pairing_logic:timer_key() => reference()}}).

%% @doc Starts the pairing, registered as `{via, evatar_registry, PairingId}'.
-spec start_link(evatar:pairing_id(), evatar_pairing_logic:config()) ->
          {ok, pid()} | {error, term()}.
start_link(PairingId, Config) ->
    gen_statem:start_link({via, evatar_registry, PairingId}, ?MODULE,
                          {PairingId, Config}, []).

%% @private
-spec callback_mode() -> gen_statem:callback_mode_result().
callback_mode() -> handle_event_function.

%% @private
-spec init({evatar:pairing_id(), evatar_pairing_logic:config()}) ->
          gen_statem:init_result(starting).
init({PairingId, Config}) ->
    logger:set_process_metadata(#{pairing => PairingId, domain => [evatar, pairing]}),
    {ok, starting, #data{id = PairingId, config = Config},
     [{next_event, internal, load}]}.

%% @private
-spec handle_event(gen_statem:event_type(), term(), atom(), #data{}) ->
          gen_statem:event_handler_result(atom()).
handle_event(internal, load, starting, #data{id = Id, config = Config} = Data) ->
    Logic = evatar_pairing_logic:new(Id, Config),
    ?LOG_INFO(#{what => pairing_started, pairing => Id}),
    {next_state, evatar_pairing_logic:phase(Logic), Data#data{logic = Logic}};
handle_event(_Type, _Event, starting, _Data) ->
    {keep_state_and_data, [postpone]};

%% The hot path: no reply, no timer for anything but requests.
handle_event(cast, {signal, EntityId, Signal}, _State, Data) ->
    run({signal, EntityId, Signal}, Data, []);
handle_event({call, From}, {join, Role, EntityId, Credential, Pid}, _State,
             #data{config = Config} = Data) ->
    case step({join, Role, EntityId, Credential}, Data) of
        {ok, Data1} ->
            Ref = erlang:monitor(process, Pid),
            Data2 = Data1#data{pids = (Data1#data.pids)#{EntityId => {Pid, Ref}},
                               refs = (Data1#data.refs)#{Ref => EntityId}},
            next(Data2, [{reply, From, {ok, maps:get(join_timeout, Config)}}]);
        {Error, Data1} ->
            next(Data1, [{reply, From, Error}])
    end;
handle_event({call, From}, {describe, EntityId, Description}, _State, Data) ->
    {Reply, Data1} = step({describe, EntityId, Description}, Data),
    next(Data1, [{reply, From, Reply}]);
handle_event({call, From}, {leave, EntityId}, _State, Data) ->
    {ok, Data1} = step({leave, EntityId, left}, Data),
    next(forget(EntityId, Data1), [{reply, From, ok}]);
handle_event(info, {'DOWN', Ref, process, _Pid, _Reason}, _State, #data{refs = Refs} = Data) ->
    case Refs of
        #{Ref := EntityId} ->
            Data1 = forget(EntityId, Data),
            {ok, Data2} = step({leave, EntityId, down}, Data1),
            next(Data2, []);
        #{} ->
            keep_state_and_data
    end;
handle_event(info, {timeout, TRef, Key}, _State, #data{timers = Timers} = Data) ->
    case Timers of
        #{Key := TRef} ->
            run({timeout, Key}, Data#data{timers = maps:remove(Key, Timers)}, []);
        #{} ->
            %% Cancelled or replaced while the message was on its way.
            keep_state_and_data
    end;
handle_event({call, From}, {inspect, What}, _State, #data{logic = Logic} = Data) ->
    Reply = case What of
                summary -> (evatar_pairing_logic:summary(Logic))#{pid => self()};
                bindings -> evatar_pairing_logic:bindings(Logic);
                registry -> evatar_pairing_logic:registration_list(Logic);
                stats -> evatar_pairing_logic:stats(Logic);
                state -> Logic
            end,
    {keep_state, Data, [{reply, From, Reply}]};
handle_event({call, From}, delete, _State, #data{id = Id}) ->
    ?LOG_INFO(#{what => pairing_deleted, pairing => Id}),
    {stop_and_reply, normal, [{reply, From, ok}]};
handle_event(EventType, Event, _State, #data{id = Id}) ->
    ?LOG_NOTICE(#{what => unexpected_event, pairing => Id, type => EventType,
                  event => Event}),
    keep_state_and_data.

%% @private
%% Only an orderly stop runs this (the process does not trap exits): tell
%% every entity's process, so it can close its connection with a reason.
-spec terminate(term(), atom(), #data{}) -> ok.
terminate(normal, _State, #data{id = Id, pids = Pids}) ->
    _ = [Pid ! {evatar, Id, {dropped, pairing_deleted, <<"the pairing was deleted">>}}
         || {Pid, _} <- maps:values(Pids)],
    ok;
terminate(_Reason, _State, _Data) ->
    ok.

%% ---------------------------------------------------------------------------
%% Running the logic
%% ---------------------------------------------------------------------------

%% Signals and timeouts never change who is registered, so the state name
%% stays: the hot path skips recomputing the phase.
run(Event, Data, Actions) ->
    {_Reply, Data1} = step(Event, Data),
    {keep_state, Data1, Actions}.

next(#data{logic = Logic} = Data, Actions) ->
    {next_state, evatar_pairing_logic:phase(Logic), Data, Actions}.

%% Applies one event to the logic and executes the effects in order; returns
%% the logic's reply (`ok' for events that have none).
step(Event, #data{logic = Logic} = Data) ->
    Now = erlang:system_time(millisecond),
    {Logic1, Effects} = evatar_pairing_logic:handle(Event, Now, Logic),
    execute(Effects, ok, Data#data{logic = Logic1}).

execute([{deliver, EntityId, Signal} | Rest], Reply, Data) ->
    ok = tell(EntityId, {signal, Signal}, Data),
    execute(Rest, Reply, Data);
execute([{report, EntityId, Report} | Rest], Reply, Data) ->
    ok = tell(EntityId, {bound, Report}, Data),
    execute(Rest, Reply, Data);
execute([{drop, EntityId, Code, Reason} | Rest], Reply, Data) ->
    ok = tell(EntityId, {dropped, Code, Reason}, Data),
    execute(Rest, Reply, forget(EntityId, Data));
execute([{start_timer, Key, Ms} | Rest], Reply, #data{timers = Timers} = Data) ->
    ok = cancel(maps:get(Key, Timers, undefined)),
    TRef = erlang:start_timer(Ms, self(), Key),
    execute(Rest, Reply, Data#data{timers = Timers#{Key => TRef}});
execute([{cancel_timer, Key} | Rest], Reply, #data{timers = Timers} = Data) ->
    ok = cancel(maps:get(Key, Timers, undefined)),
    execute(Rest, Reply, Data#data{timers = maps:remove(Key, Timers)});
execute([{log, Level, Report} | Rest], Reply, #data{id = Id} = Data) ->
    ?LOG(Level, Report#{pairing => Id}),
    execute(Rest, Reply, Data);
execute([{reply, Reply} | Rest], _Reply, Data) ->
    execute(Rest, Reply, Data);
execute([], Reply, Data) ->
    {Reply, Data}.

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

cancel(undefined) ->
    ok;
cancel(TRef) ->
    ok = erlang:cancel_timer(TRef, [{async, true}, {info, false}]).

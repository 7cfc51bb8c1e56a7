%% Test helper: a real MQTT device on a real broker, as small as a Tasmota
%% or zigbee2mqtt device looks from the network: a will message on its
%% availability topic, retained discovery configs and `online', and an
%% answer (state echo) to each command. Its session can be cut abruptly
%% (the broker then publishes the will) and opened again.
-module(mqtt_avatar_test_device).

-export([start/2, publish/4, mute/2, crash/1, revive/1, stop/1, commands/1, births/1]).

%% Spec: `availability' (topic or undefined), `discovery' ([{Topic, Json}]),
%% `commands' (topic filters), `reply' (fun(Topic, Payload) -> [{Topic,
%% Payload, Retain}]), `announce_on' (a birth topic: the discovery configs
%% are then published, not retained, only when `online' arrives there, as
%% devices that wait for Home Assistant's birth message do)
start(Port, Spec) ->
    Parent = self(),
    Pid = spawn(fun() -> init(Parent, Port, Spec) end),
    receive {Pid, ready} -> {ok, Pid}
    after evatar_test_time:guard() -> {error, device_not_ready}
    end.

publish(Dev, Topic, Payload, Retain) -> call(Dev, {publish, Topic, Payload, Retain}).
mute(Dev, Bool) -> call(Dev, {mute, Bool}).
%% Kills the MQTT connection without DISCONNECT: the broker sends the will.
crash(Dev) -> call(Dev, crash).
revive(Dev) -> call(Dev, revive).
stop(Dev) -> call(Dev, stop).
%% Every command received, oldest first.
commands(Dev) -> call(Dev, commands).
%% How many birth messages (`online' on `announce_on') it answered.
births(Dev) -> call(Dev, births).

%% A device that is gone answers at once: `stop' of a stopped device is
%% `ok' (a case's clean-up may stop it again), anything else fails.
call(Dev, Req) ->
    Ref = erlang:monitor(process, Dev),
    Dev ! {call, self(), Ref, Req},
    receive
        {Ref, Reply} ->
            erlang:demonitor(Ref, [flush]),
            Reply;
        {'DOWN', Ref, process, _, _} when Req =:= stop -> ok;
        {'DOWN', Ref, process, _, Reason} -> error({device_down, Req, Reason})
    after evatar_test_time:guard() -> error({device_timeout, Req})
    end.

init(Parent, Port, Spec) ->
    State = #{port => Port, spec => Spec, muted => false, commands => [], parent => Parent,
              births => 0},
    Client = connect(State),
    Parent ! {self(), ready},
    loop(State#{client => Client}).

connect(#{port := Port, spec := Spec}) ->
    Will = case maps:get(availability, Spec, undefined) of
               undefined -> #{};
               A -> #{will => #{topic => A, payload => <<"offline">>, qos => 1, retain => true}}
           end,
    {ok, C} = mqtt_client:start(Will#{host => {127, 0, 0, 1}, port => Port, owner => self(),
                                      reconnect => #{min_ms => 100, max_ms => 500}}),
    ok = mqtt_client:await_connected(C, 5000),
    Birth = maps:get(announce_on, Spec, undefined),
    [ok = mqtt_client:publish(C, T, J, #{qos => 1, retain => true})
     || Birth =:= undefined, {T, J} <- maps:get(discovery, Spec, [])],
    case maps:get(commands, Spec, []) ++ [Birth || Birth =/= undefined] of
        [] -> ok;
        Filters -> {ok, _} = mqtt_client:subscribe(C, [{F, 1} || F <- Filters])
    end,
    case maps:get(availability, Spec, undefined) of
        undefined -> ok;
        Av -> ok = mqtt_client:publish(C, Av, <<"online">>, #{qos => 1, retain => true})
    end,
    C.

loop(#{client := C, spec := Spec} = S) ->
    Birth = maps:get(announce_on, Spec, undefined),
    receive
        {mqtt_client, C, {publish, #{topic := Birth, payload := <<"online">>}}} ->
            [ok = mqtt_client:publish(C, T, J, #{qos => 1, retain => false})
             || {T, J} <- maps:get(discovery, Spec, [])],
            loop(S#{births := maps:get(births, S) + 1});
        {mqtt_client, C, {publish, #{topic := Birth}}} ->
            loop(S);
        {mqtt_client, C, {publish, #{topic := T, payload := P}}} ->
            S1 = S#{commands := maps:get(commands, S) ++ [{T, P}]},
            case maps:get(muted, S) of
                true -> ok;
                false ->
                    Reply = maps:get(reply, Spec, fun(_, _) -> [] end),
                    [ok = mqtt_client:publish(C, RT, RP, #{qos => 1, retain => R})
                     || {RT, RP, R} <- Reply(T, P)]
            end,
            loop(S1);
        {mqtt_client, C, {connected, _}} ->
            %% As real devices do after every reconnect: the broker may
            %% have published the will meanwhile.
            case maps:get(availability, Spec, undefined) of
                undefined -> ok;
                Av -> ok = mqtt_client:publish_async(C, Av, <<"online">>, #{qos => 1, retain => true})
            end,
            loop(S);
        {mqtt_client, _, _} ->
            loop(S);
        {call, From, Ref, {publish, T, P, R}} ->
            From ! {Ref, mqtt_client:publish(C, T, P, #{qos => 1, retain => R})},
            loop(S);
        {call, From, Ref, {mute, B}} ->
            From ! {Ref, ok},
            loop(S#{muted := B});
        {call, From, Ref, crash} ->
            Mon = monitor(process, C),
            exit(C, kill),
            receive {'DOWN', Mon, _, _, _} -> ok end,
            From ! {Ref, ok},
            loop(S#{client := undefined});
        {call, From, Ref, revive} ->
            C1 = connect(S),
            From ! {Ref, ok},
            loop(S#{client := C1});
        {call, From, Ref, commands} ->
            From ! {Ref, maps:get(commands, S)},
            loop(S);
        {call, From, Ref, births} ->
            From ! {Ref, maps:get(births, S)},
            loop(S);
        {call, From, Ref, stop} ->
            case C of
                undefined -> ok;
                _ -> mqtt_client:stop(C)
            end,
            From ! {Ref, ok}
    end.

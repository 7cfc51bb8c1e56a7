%% @doc Internal. The smart-home light control scenario (paper, section
%% 3.2): one VA per room, each embodied in that room's devices, which the
%% simulated house brings in as one gateway Avatar per room, each in its own
%% pairing. The resident walks from room to room after dusk and talks to
%% the living room's microphone; the room VAs switch the lights and hand
%% the user over to each other.
-module(evatar_demo_rooms).

-export([start/1, run_until/2, outcome/1, stop/1, default_script/0, rooms/0]).

-export_type([opts/0]).

%% `until' is for evatar_demo:rooms/1 (start/1 ignores it).
-type opts() :: #{speed => number(), tick => pos_integer(), seed => integer(),
                  start => calendar:datetime(), script => list(), until => string(),
                  spool => file:filename(), feedback_timeout => pos_integer(),
                  print => boolean(), io => pid() | atom()}.

%% @doc Each room: its devices and the emulators of its VA. The house has
%% one time sensor; it comes with the living room, whose VA shares the time
%% with the others.
-spec rooms() -> [{binary(), [binary()], [binary()]}].
rooms() ->
    [{<<"living">>,
      [<<"LivingLightSwitch01">>, <<"LivingMotionSensor01">>, <<"LivingMicrophone01">>,
       <<"TimeSensor01">>],
      [<<"LivingLightEmulator01">>, <<"LivingMotionEmulator01">>, <<"MicrophoneEmulator01">>,
       <<"TimeEmulator01">>]},
     {<<"kitchen">>,
      [<<"KitchenLightSwitch01">>, <<"KitchenMotionSensor01">>],
      [<<"KitchenLightEmulator01">>, <<"KitchenMotionEmulator01">>]},
     {<<"bedroom">>,
      [<<"BedroomSocketSwitch01">>, <<"BedroomMotionSensor01">>],
      [<<"LampEmulator01">>, <<"BedroomMotionEmulator01">>]}].

%% @doc Late afternoon, 15 November (sunset in London about 16:10): the
%% resident comes home in daylight, then moves about after dusk, tells the
%% living room to keep its light off, then back to automatic, then to keep
%% it on, and goes to bed.
-spec default_script() -> list().
default_script() ->
    [{{at, "15:55"}, <<"resident">>, {go, <<"hall">>}},
     {{delay, 60000}, <<"resident">>, {go, <<"living">>}},
     {{at, "16:30"}, <<"resident">>, {go, <<"kitchen">>}},
     {{delay, 180000}, <<"resident">>, {go, <<"living">>}},
     {{delay, 60000}, <<"resident">>, {say, <<"keep the light off">>}},
     {{delay, 60000}, <<"resident">>, {go, <<"kitchen">>}},
     {{delay, 60000}, <<"resident">>, {go, <<"living">>}},
     {{delay, 60000}, <<"resident">>, {say, <<"lights automatic">>}},
     {{delay, 60000}, <<"resident">>, {say, <<"keep the light on">>}},
     {{delay, 10000}, <<"resident">>, still},
     {{delay, 60000}, <<"resident">>, {go, <<"kitchen">>}},
     {{delay, 120000}, <<"resident">>, {go, <<"bedroom">>}}].

%% @doc Sets everything up; returns once every room VA is embodied, with
%% the simulated clock paused.
-spec start(opts()) -> {ok, evatar_demo_scenario:scenario()} | {error, term()}.
start(Opts) ->
    {ok, S0} = evatar_demo_scenario:start(
                 (maps:with([print, io], Opts))#{name => rooms,
                                                 clock => #{speed => 2, tick => maps:get(tick, Opts, 500),
                                                            start => maps:get(start, Opts,
                                                                              {{2024, 11, 15}, {15, 50, 0}})}}),
    Clock = evatar_demo_scenario:get(clock, S0),
    {ok, Rules} = reference_agents:parse_rules(
                    filename:join(evatar_demo_scenario:priv_dir(), "home.rules")),
    Rooms = rooms(),
    Timeout = maps:get(feedback_timeout, Opts, 5000),
    S1 = lists:foldl(fun({Room, _, _}, Acc) ->
                             evatar_demo_scenario:pairing(
                               pairing(Room), #{agent_credential => <<"va-", Room/binary>>,
                                                avatar_credential => <<"gw-", Room/binary>>,
                                                feedback_timeout => Timeout}, Acc)
                     end, S0, Rooms),
    {ok, Home} = avatar_sim:start_home(
                   #{clock => Clock, seed => maps:get(seed, Opts, 1),
                     endpoints => [evatar_demo_scenario:endpoint(S1)],
                     gateways => [#{pairing => pairing(Room), credential => <<"gw-", Room/binary>>,
                                    entity_id => <<"gateway-", Room/binary>>,
                                    components => Devices} || {Room, Devices, _} <- Rooms],
                     spool => maps:get(spool, Opts, "spool"),
                     script => maps:get(script, Opts, default_script())}),
    S2 = evatar_demo_scenario:add(home, Home,
                                  evatar_demo_scenario:add(avatars, [Home], S1)),
    %% Each room's VA starts once its gateway has described the room's
    %% devices to EVATAR, so its first embodiment test is of the whole room.
    Described = [evatar_demo_scenario:await_described(pairing(Room), Devices, 30000)
                 || {Room, Devices, _} <- Rooms],
    case [E || {error, _} = E <- Described] of
        [] ->
            start_vas(Opts, Rules, Rooms, Clock, S2);
        [E | _] ->
            ok = stop(S2),
            E
    end.

start_vas(Opts, Rules, Rooms, Clock, S2) ->
    Full = evatar_demo_scenario:body("smart_home_va.xml"),
    Names = [va(Room) || {Room, _, _} <- Rooms],
    %% The clock runs in lockstep with every room VA; settle/1 waits for the
    %% one with the time sensor, the living room's, to have read the last
    %% time.
    Seen = atomics:new(1, [{signed, true}]),
    {Vas, S3} = lists:foldl(
                  fun({Room, _, Emulators}, {Acc, SAcc}) ->
                          Name = va(Room),
                          Body = evatar_demo_scenario:body_subset(Full, Name, Emulators),
                          Follow = maps:from_list([{seen, Seen} || lists:member(<<"TimeEmulator01">>,
                                                                                 Emulators)]),
                          {Va, SAcc1} = evatar_demo_scenario:start_va(
                                          Follow#{name => Name, mind => reference_agents_room,
                                                  mind_args => #{room => Room, body => Body, rules => Rules,
                                                                 peers => Names -- [Name]},
                                                  body => Body, pairing => pairing(Room),
                                                  credential => <<"va-", Room/binary>>}, SAcc),
                          {Acc#{Name => Va}, SAcc1}
                  end, {#{}, S2}, Rooms),
    _ = [reference_agents:introduce(Va, maps:remove(Name, Vas)) || {Name, Va} <- maps:to_list(Vas)],
    S4 = evatar_demo_scenario:add(room_vas, Vas, S3),
    Embodied = [evatar_demo_scenario:await_va_state(Va, [embodied], 20000, {embodied, Name})
                || {Name, Va} <- maps:to_list(Vas)],
    case [E || {error, _} = E <- Embodied] of
        [] ->
            ok = avatar_sim:pause(Clock),
            ok = avatar_sim:set_speed(Clock, maps:get(speed, Opts, 1000)),
            {ok, evatar_demo_scenario:lockstep(S4, Seen)};
        [E | _] ->
            ok = stop(S4),
            E
    end.

pairing(Room) -> <<"home-", Room/binary>>.
va(Room) -> <<Room/binary, "-va">>.

-spec run_until(evatar_demo_scenario:scenario(), string()) -> ok | {error, term()}.
run_until(S, HHMM) -> evatar_demo_holiday:run_until(S, HHMM).

-spec outcome(evatar_demo_scenario:scenario()) -> map().
outcome(S) ->
    Vas = evatar_demo_scenario:get(room_vas, S),
    #{vas => maps:map(fun(_, Va) -> reference_agents:inspect(Va) end, Vas),
      home => avatar_sim:state(evatar_demo_scenario:get(home, S)),
      story => reference_agents_narrator:events(evatar_demo_scenario:narrator(S))}.

-spec stop(evatar_demo_scenario:scenario()) -> ok.
stop(S) -> evatar_demo_scenario:stop(S).

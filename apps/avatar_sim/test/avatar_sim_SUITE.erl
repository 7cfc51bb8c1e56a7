%% Common Test suite of the simulated Avatars joining a real EVATAR over real
%% TCP, each driven by a tiny test VA (agent_bridge_client, role agent) with
%% the example VA descriptions: request-feedback round trips for both
%% Avatars, progress, sensor signals, the keypad's wrong password, the
%% intrusion e-mail landing in a spool, determinism, and the failure hooks.
-module(avatar_sim_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").
-import(evatar_test_wait, [until/1]).

-compile([export_all, nowarn_export_all]).

-define(VA_CRED, evatar_test_fixtures:va_credential()).
-define(AV_CRED, evatar_test_fixtures:avatar_credential()).
-define(WAIT, evatar_test_time:guard()).

suite() -> [{timetrap, {seconds, 60}}].

all() ->
    [{group, robots}, {group, home}, {group, determinism}, {group, failures}].

groups() ->
    [{robots, [], [robot_motor_round_trip, robot_forward_progress, robot_sensor_signals,
                   robot_bad_parameter, second_robot_own_pairing]},
     {home, [], [home_light_round_trip, home_request_without_feedback, home_keypad_wrong_password, home_script_motion_and_voice,
                 home_intrusion_email, home_gateway_per_room, home_bad_script_file]},
     {determinism, [], [same_seed_same_signals]},
     {failures, [], [muted_device_times_out, device_leaves_and_comes_back,
                      device_detached_and_attached]}].

%% ---------------------------------------------------------------------------
%% Setup
%% ---------------------------------------------------------------------------

init_per_suite(Config) ->
    ok = evatar_test_node:start([avatar_sim]),
    [{addr, evatar_test_node:listen(avatar_sim_test)} | Config].

end_per_suite(_Config) ->
    evatar_test_node:stop([avatar_sim_test], [avatar_sim, agent_bridge]).

init_per_testcase(Case, Config) ->
    Timeout = case Case of muted_device_times_out -> 2000; _ -> 5000 end,
    Pairings = [<<(atom_to_binary(Case))/binary, "-", (integer_to_binary(N))/binary>>
                || N <- [1, 2]],
    [{ok, _} = evatar_test_fixtures:create_pairing(P, #{feedback_timeout => Timeout})
     || P <- Pairings],
    Spool = filename:join(?config(priv_dir, Config), atom_to_list(Case) ++ "-spool"),
    [{pairings, Pairings}, {spool, Spool} | Config].

end_per_testcase(_Case, Config) ->
    [catch avatar_sim:stop(A) || {_, A, _} <- started()],
    erase(started),
    [_ = evatar:delete_pairing(P) || P <- ?config(pairings, Config)],
    ok.

pairing(N, Config) -> lists:nth(N, ?config(pairings, Config)).

started() -> case get(started) of undefined -> []; L -> L end.

remember(Kind, Avatar, Clock) -> put(started, [{Kind, Avatar, Clock} | started()]).

%% ---------------------------------------------------------------------------
%% Robots
%% ---------------------------------------------------------------------------

%% A fine-grain motor request gets its feedback.
robot_motor_round_trip(Config) ->
    {_Arena, Va} = robot_and_va(Config, #{}),
    {ok, Fb} = request(Va, <<"MotorAEmulator">>, <<"MotorA">>, <<"ACTUATOR">>, <<"Rotate">>,
                       [{<<"Angle">>, <<"180">>}, {<<"Speed">>, <<"360">>}]),
    #{context := feedback, sender := <<"MotorA">>,
      body := #{category := <<"ACTUATOR">>, type := <<"ACTION FEEDBACK">>}} = Fb,
    [<<"done">>, <<"A">>, <<"180">>] = params(Fb, [<<"Result">>, <<"Port">>, <<"Angle">>]).

%% A coarse-grain behaviour sends progress, then its feedback.
robot_forward_progress(Config) ->
    {Arena, Va} = robot_and_va(Config, #{}),
    {ok, Fb} = request(Va, <<"ForwardBehaviourEmulator">>, <<"ForwardBehaviour">>,
                       <<"BEHAVIOUR">>, <<"Forward">>, [{<<"Distance">>, <<"0.45">>}]),
    #{in_reply_to := ReqId} = Fb,
    [<<"done">>, <<"750">>] = params(Fb, [<<"Result">>, <<"X">>]),
    Progress = [S || S = #{context := progress, in_reply_to := R} <- signals(Va), R =:= ReqId],
    ?assert(length(Progress) >= 2),
    [<<"Forward">>, _] = params(hd(Progress), [<<"Service">>, <<"Percent">>]),
    #{robots := [#{x := X} | _]} = avatar_sim:state(Arena),
    ?assert(abs(X - 750) < 1).

%% Driving to a ball streams its colour and presses the bumper.
robot_sensor_signals(Config) ->
    {_Arena, Va} = robot_and_va(Config, #{}),
    {ok, Fb} = request(Va, <<"GoToBehaviourEmulator">>, <<"GoToBehaviour">>, <<"BEHAVIOUR">>,
                       <<"GoTo">>, [{<<"X">>, <<"1000">>}, {<<"Y">>, <<"450">>}]),
    [<<"contact">>] = params(Fb, [<<"Result">>]),
    Signals = signals(Va),
    Colours = [C || #{context := sensor_data, sender := <<"LightSensor">>,
                      receiver := <<"LightSensorEmulator">>,
                      body := #{type := <<"ColourApproximation">>}} = S <- Signals,
                    [C] <- [params(S, [<<"Colour">>])]],
    ?assertEqual(<<"red">>, lists:last(Colours)),
    [_ | _] = [S || #{context := event, sender := <<"TouchSensor">>,
                      receiver := <<"TouchSensorEmulator">>} = S <- Signals,
                    params(S, [<<"Pressed">>]) =:= [<<"yes">>]],
    {ok, Grab} = request(Va, <<"GrabBehaviourEmulator">>, <<"GrabBehaviour">>, <<"BEHAVIOUR">>,
                         <<"Grab">>, []),
    [<<"yes">>, <<"red">>] = params(Grab, [<<"Holding">>, <<"Colour">>]).

%% A request with a bad parameter is answered by an error signal.
robot_bad_parameter(Config) ->
    {_Arena, Va} = robot_and_va(Config, #{}),
    {error, #{context := error, body := #{category := <<"ERROR">>, type := <<"BadParameter">>}}} =
        request(Va, <<"GoToBehaviourEmulator">>, <<"GoToBehaviour">>, <<"BEHAVIOUR">>,
                <<"GoTo">>, [{<<"Y">>, <<"10">>}]).

%% Robot 2 joins its own pairing with its own ids; both robots share the arena.
second_robot_own_pairing(Config) ->
    {ok, Clock} = avatar_sim:start_clock(#{speed => 50}),
    {ok, Arena} = avatar_sim:start_arena(#{clock => Clock, endpoints => [?config(addr, Config)],
                                           robots => [#{pairing => pairing(1, Config), credential => ?AV_CRED},
                                                      #{pairing => pairing(2, Config), credential => ?AV_CRED}]}),
    remember(arena, Arena, Clock),
    Desc = avatar_sim_desc:example("lego_va.xml"),
    Va1 = va(Config, pairing(1, Config), Desc),
    Va2 = va(Config, pairing(2, Config), Desc#{entity_id := <<"golem-lego-va-02">>}),
    {ok, B2} = evatar:bindings(pairing(2, Config)),
    #{entities := Entities2} = B2,
    ?assert(lists:member(<<"lego-nxt-02">>, Entities2)),
    {ok, Fb} = request(Va2, <<"ForwardBehaviourEmulator">>, <<"ForwardBehaviour-2">>,
                       <<"BEHAVIOUR">>, <<"Forward">>, [{<<"Distance">>, <<"0.2">>}]),
    #{sender := <<"ForwardBehaviour-2">>} = Fb,
    [<<"done">>, <<"1500">>] = params(Fb, [<<"Result">>, <<"X">>]),
    {ok, _} = request(Va1, <<"RotateBehaviourEmulator">>, <<"RotateBehaviour">>, <<"BEHAVIOUR">>,
                      <<"Rotate">>, [{<<"Angle">>, <<"90">>}]),
    #{robots := [#{entity := <<"lego-nxt-01">>, heading := H1},
                 #{entity := <<"lego-nxt-02">>, x := X2}]} = avatar_sim:state(Arena),
    ?assert(abs(H1 - 90) < 1),
    ?assert(abs(X2 - 1500) < 1).

%% ---------------------------------------------------------------------------
%% Home
%% ---------------------------------------------------------------------------

%% A light switch request gets its feedback and switches the light.
home_light_round_trip(Config) ->
    {Home, Va} = home_and_va(Config, #{}),
    {ok, Fb} = request(Va, <<"LivingLightEmulator01">>, <<"LivingLightSwitch01">>, <<"ACTUATOR">>,
                       <<"TurnLightOn">>, []),
    [<<"on">>, <<"living">>, <<"yes">>] = params(Fb, [<<"Light">>, <<"Room">>, <<"Changed">>]),
    #{lights := #{<<"living">> := on}} = avatar_sim:state(Home).

%% A Request awaiting no feedback is carried out and never answered, even when the action ends later.
home_request_without_feedback(Config) ->
    {Home, Va} = home_and_va(Config, #{}),
    ok = agent_bridge_client:send(Va, #{context => request_no_feedback,
                                        sender => <<"SpeakerEmulator01">>, receiver => <<"HallSpeaker01">>,
                                        body => #{category => <<"ACTUATOR">>, type => <<"PlaySound">>,
                                                  parameters => [{<<"Duration">>, <<"100">>}]}}),
    ok = agent_bridge_client:send(Va, #{context => request_no_feedback,
                                        sender => <<"KitchenLightEmulator01">>,
                                        receiver => <<"KitchenLightSwitch01">>,
                                        body => #{category => <<"ACTUATOR">>, type => <<"TurnLightOn">>,
                                                  parameters => []}}),
    until(fun() -> maps:get(<<"kitchen">>, maps:get(lights, avatar_sim:state(Home))) =:= on end),
    %% The sound ends on the clock (a task); once no task is left it has
    %% ended, and the answer it would have given is behind us.
    until(fun() ->
                  #{played := Played, tasks_left := Left} = avatar_sim:state(Home),
                  Played =/= [] andalso Left =:= 0
          end),
    [#{kind := sound}] = maps:get(played, avatar_sim:state(Home)),
    %% A round trip through the same house after that: a feedback sent
    %% for either request would have reached the VA before this answer.
    {ok, _} = request(Va, <<"KeypadEmulator01">>, <<"DoorKeypad01">>, <<"SENSOR">>, <<"ReadKeypad">>, []),
    [] = [S || #{context := C} = S <- signals(Va), C =:= feedback orelse C =:= progress].

%% A wrong code at the keypad reaches the VA as the "wrong password input" event.
home_keypad_wrong_password(Config) ->
    {Home, Va} = home_and_va(Config, #{}),
    ok = avatar_sim:act(Home, <<"intruder">>, {keypad, <<"0000">>}),
    #{context := event, receiver := <<"KeypadEmulator01">>, body := #{type := <<"PasswordInput">>}} = S =
        wait_signal(Va, fun(#{sender := Sd}) -> Sd =:= <<"DoorKeypad01">> end),
    [<<"yes">>, <<"1">>] = params(S, [<<"WrongPassword">>, <<"Attempts">>]).

%% Scripted people make motion and say things the VA perceives.
home_script_motion_and_voice(Config) ->
    Script = [{{offset, 1000}, <<"resident">>, {go, <<"living">>}},
              {{delay, 1000}, <<"resident">>, {say, <<"keep the light on">>}}],
    {_Home, Va} = home_and_va(Config, #{script => Script}),
    M = wait_signal(Va, fun(#{sender := Sd}) -> Sd =:= <<"LivingMotionSensor01">> end),
    #{context := event, receiver := <<"LivingMotionEmulator01">>} = M,
    [<<"yes">>, <<"living">>] = params(M, [<<"Motion">>, <<"Room">>]),
    V = wait_signal(Va, fun(#{sender := Sd}) -> Sd =:= <<"LivingMicrophone01">> end),
    #{receiver := <<"MicrophoneEmulator01">>} = V,
    [<<"keep the light on">>] = params(V, [<<"Text">>]).

%% Photos of the intruder are attached to an INTRUSION e-mail written to the spool.
home_intrusion_email(Config) ->
    {_Home, Va} = home_and_va(Config, #{people => #{<<"intruder">> => <<"hall">>}}),
    {ok, Photos} = request(Va, <<"CameraEmulator01">>, <<"HallCamera01">>, <<"ACTUATOR">>,
                           <<"TakePhoto">>, [{<<"Count">>, <<"2">>}, {<<"Interval">>, <<"500">>}]),
    [Ids] = params(Photos, [<<"Photos">>]),
    {ok, Sent} = request(Va, <<"NotifierEmulator01">>, <<"Notifier01">>, <<"ACTUATOR">>,
                         <<"SendEmail">>, [{<<"Subject">>, <<"INTRUSION">>},
                                           {<<"Body">>, <<"Someone is in the hall.">>},
                                           {<<"Attachment">>, Ids}]),
    [File, <<"2">>] = params(Sent, [<<"File">>, <<"Attachments">>]),
    Spool = ?config(spool, Config),
    ?assertEqual(filename:absname(Spool), filename:dirname(binary_to_list(File))),
    {ok, Eml} = file:read_file(File),
    {match, _} = re:run(Eml, <<"^Subject: INTRUSION\r$">>, [multiline]),
    Attached = attachments(Eml),
    Expected = [begin
                    {ok, Png} = file:read_file(filename:join([Spool, "photos", Id])),
                    {Id, Png}
                end || Id <- binary:split(Ids, <<",">>, [global])],
    ?assertEqual(Expected, Attached),
    [<<137, $P, $N, $G, _/binary>> = Png || {_, Png} <- Attached].

%% One gateway per room: each room's pairing binds only that room's devices.
home_gateway_per_room(Config) ->
    {ok, Clock} = avatar_sim:start_clock(#{speed => 50}),
    {ok, Home} = avatar_sim:start_home(
                   #{clock => Clock, endpoints => [?config(addr, Config)], spool => ?config(spool, Config),
                     gateways => [#{pairing => pairing(1, Config), credential => ?AV_CRED,
                                    entity_id => <<"home-living">>,
                                    components => [<<"LivingLightSwitch01">>, <<"LivingMotionSensor01">>]},
                                  #{pairing => pairing(2, Config), credential => ?AV_CRED,
                                    entity_id => <<"home-kitchen">>,
                                    components => [<<"KitchenLightSwitch01">>, <<"KitchenMotionSensor01">>]}]}),
    remember(home, Home, Clock),
    Va = va(Config, pairing(1, Config), avatar_sim_desc:example("smart_home_va.xml")),
    {ok, #{bound := Bound}} = evatar:bindings(pairing(1, Config)),
    Providers = lists:usort([P || #{provider := #{component := P}} <- Bound]),
    ?assert(lists:member(<<"LivingLightSwitch01">>, Providers)),
    ?assertNot(lists:member(<<"KitchenLightSwitch01">>, Providers)),
    {ok, _} = request(Va, <<"LivingLightEmulator01">>, <<"LivingLightSwitch01">>, <<"ACTUATOR">>,
                      <<"TurnLightOn">>, []),
    [#{entity := <<"home-kitchen">>, state := connected}, #{entity := <<"home-living">>}] =
        avatar_sim:links(Home).

%% A malformed script file is refused with the number of the bad line.
home_bad_script_file(Config) ->
    File = filename:join(?config(priv_dir, Config), "bad.script"),
    ok = file:write_file(File, <<"# people\n17:30 resident go hall\n+2x resident go living\n">>),
    {error, {script, 3, Why}} = avatar_sim:start_home(#{script_file => File,
                                                        spool => ?config(spool, Config)}),
    ct:log("~s", [Why]).

%% ---------------------------------------------------------------------------
%% Determinism
%% ---------------------------------------------------------------------------

%% The same seed gives the same signals, times included; another seed another run.
same_seed_same_signals(Config) ->
    Run = fun(Seed, Pairing) ->
                  {ok, Clock} = avatar_sim:start_clock(#{speed => manual}),
                  Script = [{{offset, 2000}, <<"intruder">>, {go, <<"hall">>}},
                            {{delay, 3000}, <<"intruder">>, {keypad, <<"0000">>}},
                            {{delay, 4000}, <<"intruder">>, {go, <<"living">>}}],
                  {ok, Arena} = avatar_sim:start_arena(
                                  #{clock => Clock, seed => Seed, endpoints => [?config(addr, Config)],
                                    robots => [#{pairing => Pairing, credential => ?AV_CRED}]}),
                  {ok, Home} = avatar_sim:start_home(
                                 #{clock => Clock, seed => Seed, endpoints => [?config(addr, Config)],
                                   script => Script, spool => ?config(spool, Config),
                                   gateways => [#{pairing => Pairing, credential => ?AV_CRED}]}),
                  remember(arena, Arena, Clock),
                  remember(home, Home, Clock),
                  Va = va_desc(Config, Pairing,
                               merge([avatar_sim_desc:example("lego_va.xml"),
                                      avatar_sim_desc:example("smart_home_va.xml")]), 3),
                  settle(Arena), settle(Home),
                  ok = agent_bridge_client:send(Va, #{context => request,
                                                      sender => <<"ExploreBehaviourEmulator">>,
                                                      receiver => <<"ExploreBehaviour">>,
                                                      body => #{category => <<"BEHAVIOUR">>,
                                                                type => <<"Explore">>,
                                                                parameters => [{<<"Duration">>, <<"30">>},
                                                                               {<<"UntilObject">>, <<"no">>}]}}),
                  _ = avatar_sim:state(Arena),
                  until(fun() -> maps:get(behaviour, hd(maps:get(robots, avatar_sim:state(Arena))))
                                     =:= explore end),
                  [ok = avatar_sim:advance(Clock, 1000) || _ <- lists:seq(1, 15)],
                  %% A request answered after everything the Avatars sent so far.
                  {ok, _} = request(Va, <<"TouchSensorEmulator">>, <<"TouchSensor">>, <<"SENSOR">>,
                                    <<"ReadTouch">>, []),
                  {ok, _} = request(Va, <<"KeypadEmulator01">>, <<"DoorKeypad01">>, <<"SENSOR">>,
                                    <<"ReadKeypad">>, []),
                  %% Each Avatar's signals in their order; how the two interleave is up to TCP.
                  Robot = avatar_sim_desc:component_ids(avatar_sim_desc:example("lego_robot.xml")),
                  Got = lists:partition(
                          fun({_, Sd, _, _, _}) -> lists:member(Sd, Robot) end,
                          [{C, Sd, T, P, Ts} || #{context := C, sender := Sd, timestamp := Ts,
                                                  body := #{type := T, parameters := P}} <- signals(Va),
                                                C =/= feedback]),
                  Log = avatar_sim:log(Arena) ++ avatar_sim:log(Home),
                  ok = agent_bridge_client:close(Va),
                  [avatar_sim:stop(A) || A <- [Arena, Home]],
                  avatar_sim:stop_clock(Clock),
                  {Got, [maps:remove(entity, E) || E <- Log]}
          end,
    {Got1, Log1} = Run(7, pairing(1, Config)),
    {Got2, Log2} = Run(7, pairing(2, Config)),
    {FromRobot, FromHome} = Got1,
    ct:log("~p + ~p signals, ~p log entries", [length(FromRobot), length(FromHome), length(Log1)]),
    ?assert(length(FromRobot) > 10),
    [_ | _] = [x || {event, <<"DoorKeypad01">>, _, _, _} <- FromHome],
    [_ | _] = [x || {progress, <<"ExploreBehaviour">>, _, _, _} <- FromRobot],
    ?assertEqual(Got1, Got2),
    ?assertEqual(Log1, Log2),
    ok = evatar:delete_pairing(pairing(1, Config)),
    {ok, _} = evatar_test_fixtures:create_pairing(pairing(1, Config), #{}),
    {_, Log3} = Run(8, pairing(1, Config)),
    ?assertNotEqual(Log1, Log3).

%% ---------------------------------------------------------------------------
%% Failure hooks
%% ---------------------------------------------------------------------------

%% A muted device never answers: EVATAR's timeout tells the VA, while the
%% rest of the house still answers; unmuted, it answers again.
muted_device_times_out(Config) ->
    {Home, Va} = home_and_va(Config, #{}),
    ok = avatar_sim:mute(Home, <<"KitchenLightSwitch01">>),
    Self = self(),
    %% The muted request waits out the pairing's feedback timeout (2 s)
    %% while the living room's request is answered: a healthy round trip
    %% no longer races a 300 ms timeout on a loaded, cover-compiled node.
    _ = spawn_link(fun() ->
                           Self ! {muted, request(Va, <<"KitchenLightEmulator01">>,
                                                  <<"KitchenLightSwitch01">>, <<"ACTUATOR">>,
                                                  <<"TurnLightOn">>, [])}
                   end),
    {ok, #{sender := <<"LivingLightSwitch01">>}} =
        request(Va, <<"LivingLightEmulator01">>, <<"LivingLightSwitch01">>, <<"ACTUATOR">>,
                <<"TurnLightOn">>, []),
    receive
        {muted, Muted} ->
            {ok, #{sender := <<"EVATAR">>, body := #{category := <<"EVATAR">>, type := <<"Timeout">>}}} =
                Muted
    after ?WAIT -> ct:fail(no_timeout_feedback)
    end,
    #{lights := #{<<"kitchen">> := off}} = avatar_sim:state(Home),
    ok = avatar_sim:unmute(Home, <<"KitchenLightSwitch01">>),
    {ok, #{sender := <<"KitchenLightSwitch01">>}} =
        request(Va, <<"KitchenLightEmulator01">>, <<"KitchenLightSwitch01">>, <<"ACTUATOR">>,
                <<"TurnLightOn">>, []).

%% The home leaves (no Bye) and comes back: EVATAR unbinds it, then binds it again.
device_leaves_and_comes_back(Config) ->
    {Home, Va} = home_and_va(Config, #{}),
    ok = avatar_sim:disconnect(Home, <<"easy-home-01">>),
    #{entities := [_]} = wait_binding(Va, fun(#{entities := Es}) -> length(Es) =:= 1 end),
    [#{state := away}] = avatar_sim:links(Home),
    ok = avatar_sim:reconnect(Home, <<"easy-home-01">>),
    #{unbound := []} = wait_binding(Va, fun(#{entities := Es}) -> length(Es) =:= 2 end),
    {ok, #{sender := <<"KitchenLightSwitch01">>}} =
        request(Va, <<"KitchenLightEmulator01">>, <<"KitchenLightSwitch01">>, <<"ACTUATOR">>,
                <<"TurnLightOn">>, []),
    %% Away for a while, back by itself.
    ok = avatar_sim:disconnect(Home, <<"easy-home-01">>, 200),
    _ = wait_binding(Va, fun(#{entities := Es}) -> length(Es) =:= 1 end),
    _ = wait_binding(Va, fun(#{entities := Es}) -> length(Es) =:= 2 end).

%% One device leaves the description and comes back: a rebinding each time.
device_detached_and_attached(Config) ->
    {Home, Va} = home_and_va(Config, #{}),
    ok = avatar_sim:detach_device(Home, <<"KitchenLightSwitch01">>),
    #{unbound := Unbound} = wait_binding(Va, fun(#{unbound := U}) -> U =/= [] end),
    [_ | _] = [U || #{consumer := #{component := <<"KitchenLightEmulator01">>}} = U <- Unbound],
    {error, #{body := #{type := <<"UnknownReceiver">>}}} =
        request(Va, <<"KitchenLightEmulator01">>, <<"KitchenLightSwitch01">>, <<"ACTUATOR">>,
                <<"TurnLightOn">>, []),
    ok = avatar_sim:attach_device(Home, <<"KitchenLightSwitch01">>),
    #{unbound := []} = wait_binding(Va, fun(#{unbound := U}) -> U =:= [] end),
    {ok, _} = request(Va, <<"KitchenLightEmulator01">>, <<"KitchenLightSwitch01">>, <<"ACTUATOR">>,
                      <<"TurnLightOn">>, []).

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

robot_and_va(Config, Opts) ->
    {ok, Clock} = avatar_sim:start_clock(#{speed => 50}),
    {ok, Arena} = avatar_sim:start_arena(
                    maps:merge(#{clock => Clock, endpoints => [?config(addr, Config)],
                                 robots => [#{pairing => pairing(1, Config), credential => ?AV_CRED}]},
                               Opts)),
    remember(arena, Arena, Clock),
    {Arena, va(Config, pairing(1, Config), avatar_sim_desc:example("lego_va.xml"))}.

home_and_va(Config, Opts) ->
    {ok, Clock} = avatar_sim:start_clock(#{speed => 50, paused => true}),
    {ok, Home} = avatar_sim:start_home(
                   maps:merge(#{clock => Clock, endpoints => [?config(addr, Config)],
                                spool => ?config(spool, Config),
                                gateways => [#{pairing => pairing(1, Config), credential => ?AV_CRED}]},
                              Opts)),
    remember(home, Home, Clock),
    Va = va(Config, pairing(1, Config), avatar_sim_desc:example("smart_home_va.xml")),
    settle(Home),
    ok = avatar_sim:resume(Clock),
    {Home, Va}.

va(Config, Pairing, Desc) -> va_desc(Config, Pairing, Desc, 2).

%% Joins as the VA and waits until the pairing has `N' entities bound.
va_desc(Config, Pairing, Desc, N) ->
    {ok, C} = agent_bridge_client:connect([?config(addr, Config)],
                                          #{pairing => Pairing, role => agent,
                                            entity_id => maps:get(entity_id, Desc),
                                            credential => ?VA_CRED}),
    ok = agent_bridge_client:describe(C, Desc),
    _ = wait_binding(C, fun(#{entities := Es}) -> length(Es) =:= N end),
    C.

%% Every link of the Avatar has its bindings, and the world has heard of them.
settle(Avatar) ->
    until(fun() -> lists:all(fun(#{routes := R}) -> R > 0 end, avatar_sim:links(Avatar)) end),
    _ = avatar_sim:state(Avatar),
    ok.

merge([First | _] = Descs) ->
    First#{components := lists:append([Cs || #{components := Cs} <- Descs])}.

request(Va, Sender, Receiver, Category, Type, Params) ->
    agent_bridge_client:request(Va, #{sender => Sender, receiver => Receiver,
                                      body => #{category => Category, type => Type,
                                                parameters => Params}}, ?WAIT).

params(#{body := #{parameters := P}}, Keys) ->
    [proplists:get_value(K, P) || K <- Keys].

%% Signals received so far, in order.
signals(Va) ->
    receive {agent_bridge, Va, {signal, S}} -> [S | signals(Va)]
    after 0 -> []
    end.

wait_signal(Va, Pred) ->
    evatar_test_fixtures:wait_signal(Va, Pred, ?WAIT).

wait_binding(Va, Pred) ->
    evatar_test_fixtures:wait_binding(Va, Pred, ?WAIT).


%% The attachments of an .eml file: {Filename, DecodedBytes}.
attachments(Eml) ->
    [_, Rest] = binary:split(Eml, <<"boundary=\"">>),
    [Boundary, _] = binary:split(Rest, <<"\"">>),
    Parts = binary:split(Eml, <<"--", Boundary/binary>>, [global]),
    [{Name, base64:decode(binary:replace(Body, <<"\r\n">>, <<>>, [global]))}
     || Part <- Parts,
        {match, [Name]} <- [re:run(Part, <<"filename=\"([^\"]+)\"">>, [{capture, all_but_first, binary}])],
        [_, Body] <- [binary:split(Part, <<"\r\n\r\n">>)]].

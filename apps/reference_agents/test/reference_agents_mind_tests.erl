%% @doc EUnit tests of the VA's pure parts: the emulator table built from a
%% BIL body and a real binding (bil:bind/1 over the example bodies), the
%% embodiment test's plan and verdict, and the decisions of the house,
%% room and coordinator minds.
-module(reference_agents_mind_tests).

-include_lib("eunit/include/eunit.hrl").

body(File) ->
    {ok, Xml} = file:read_file(filename:join([code:priv_dir(bil), "examples", File])),
    {ok, D} = bil:parse_description(Xml),
    D.

report(Va, Avatar) ->
    (bil:bind([Va, Avatar]))#{entities => [maps:get(entity_id, Va), maps:get(entity_id, Avatar)]}.

lego_table() ->
    Va = body("lego_va.xml"),
    reference_agents_emulator:bind(reference_agents_emulator:new(Va), report(Va, body("lego_robot.xml"))).

%% Emulators.

emulators_follow_the_binding_test() ->
    T = lego_table(),
    ?assertEqual(actuator, reference_agents_emulator:kind(<<"MotorAEmulator">>, T)),
    ?assertEqual(behaviour, reference_agents_emulator:kind(<<"GoToBehaviourEmulator">>, T)),
    ?assertEqual(sensor, reference_agents_emulator:kind(<<"LightSensorEmulator">>, T)),
    {ok, #{sender := <<"MotorAEmulator">>, receiver := <<"MotorA">>,
           body := #{category := <<"ACTUATOR">>, type := <<"Rotate">>,
                     parameters := [{<<"Angle">>, <<"90">>}]}}} =
        reference_agents_emulator:request(<<"MotorAEmulator">>, <<"rotate">>,
                                          [{<<"Angle">>, <<"90">>}], T),
    ?assertEqual([<<"LightSensor">>], reference_agents_emulator:sources(<<"LightSensorEmulator">>, T)),
    ?assertEqual([], reference_agents_emulator:unbound(T)).

an_unbound_emulator_says_why_test() ->
    Va = body("lego_va.xml"),
    #{components := Cs} = Robot = body("lego_robot.xml"),
    NoGrab = Robot#{components := [C || #{id := Id} = C <- Cs, Id =/= <<"GrabBehaviour">>]},
    T = reference_agents_emulator:bind(reference_agents_emulator:new(Va), report(Va, NoGrab)),
    ?assertEqual({error, {not_bound, <<"Grab">>, no_provider}},
                 reference_agents_emulator:request(<<"GrabBehaviourEmulator">>, <<"Grab">>, [], T)),
    ?assertNotEqual(reference_agents_emulator:signature(lego_table()),
                    reference_agents_emulator:signature(T)).

find_by_service_and_room_test() ->
    T = reference_agents_emulator:new(body("smart_home_va.xml")),
    ?assertEqual([<<"KitchenLightEmulator01">>],
                 reference_agents_emulator:find(<<"ACTUATOR">>, <<"TurnLightOn">>,
                                                [{<<"Room">>, <<"kitchen">>}], T)),
    ?assertEqual([<<"LampEmulator01">>],
                 reference_agents_emulator:find(<<"actuator">>, <<"switch socket on">>, [], T)).

percept_from_sensor_data_test() ->
    T = lego_table(),
    S = #{context => sensor_data, sender => <<"LightSensor">>, receiver => <<"LightSensorEmulator">>,
          timestamp => 42, id => <<"x">>, in_reply_to => undefined, seq => 1, epoch => 1,
          body => #{category => <<"SENSOR">>, type => <<"ColourApproximation">>,
                    parameters => [{<<"Colour">>, <<"red">>}]}},
    ?assertEqual({ok, #{emulator => <<"LightSensorEmulator">>, source => <<"LightSensor">>,
                        service => <<"ColourApproximation">>, time => 42,
                        params => [{<<"Colour">>, <<"red">>}]}},
                 reference_agents_emulator:percept(S, T)),
    ?assertEqual(error, reference_agents_emulator:percept(S#{context := feedback}, T)).

%% The embodiment test.

embodiment_plan_and_verdicts_test() ->
    T = lego_table(),
    {ok, Mind} = reference_agents_robot_mind:init(#{name => <<"va-1">>, body => body("lego_va.xml"),
                                               coordinator => <<"c">>}),
    {Test, Steps} = reference_agents_embodiment:start(
                      T, fun(L) -> reference_agents_robot_mind:probe(L, Mind) end),
    Requests = [Id || {request, Id, _, _, _} <- Steps],
    %% 12 bound consumers of the VA; GoTo is not tested by a request.
    ?assertEqual(11, length(Requests)),
    ?assertNot(reference_agents_embodiment:done(Test)),
    All = lists:foldl(fun(Id, Acc) -> reference_agents_embodiment:result(Id, ok, Acc) end,
                      Test, Requests),
    ?assert(reference_agents_embodiment:done(All)),
    #{verdict := embodied, untested := [#{service := <<"GoTo">>}]} =
        reference_agents_embodiment:report(All),
    [First | Rest] = Requests,
    Partial = lists:foldl(fun(Id, Acc) -> reference_agents_embodiment:result(Id, ok, Acc) end,
                          reference_agents_embodiment:result(
                            First, {failed, <<"EVATAR Timeout: no answer">>}, Test), Rest),
    #{verdict := partial, failed := [{#{emulator := E}, <<"EVATAR Timeout: no answer">>}]} =
        Report = reference_agents_embodiment:report(Partial),
    ?assert(is_binary(E)),
    Lines = iolist_to_binary(lists:join("\n", reference_agents_embodiment:format(Report))),
    ?assertNotEqual(nomatch, binary:match(Lines, <<"FAILED">>)),
    #{verdict := none} = reference_agents_embodiment:report(Test).

a_sensor_without_read_request_is_tested_by_a_reading_test() ->
    T = lego_table(),
    {Test, Steps} = reference_agents_embodiment:start(T, fun(_) -> skip end),
    ?assertEqual([<<"LightSensorEmulator">>, <<"TouchSensorEmulator">>],
                 lists:sort([E || {await_reading, _, E} <- Steps])),
    Test1 = reference_agents_embodiment:reading(<<"LightSensorEmulator">>, Test),
    ?assertEqual([<<"TouchSensorEmulator">>],
                 [E || #{emulator := E} <- reference_agents_embodiment:pending(Test1)]).

%% The house mind.

home() ->
    Body = body("smart_home_va.xml"),
    {ok, Rules} = reference_agents_rules:parse_file(
                    filename:join(code:priv_dir(reference_agents), "home.rules")),
    {ok, H} = reference_agents_home:init(#{body => Body, rules => Rules, policy => <<"holiday">>}),
    H.

requests(Acts) -> [{Tag, E, S} || {request, Tag, E, S, _} <- Acts].

time_percept(HHMM) ->
    {percept, #{emulator => <<"TimeEmulator01">>, source => <<"TimeSensor01">>,
                service => <<"TimeOfDay">>, time => 0,
                params => [{<<"TimeOfDay">>, HHMM}, {<<"Dark">>, <<"yes">>}]}}.

house_schedule_switches_the_living_light_at_six_test() ->
    {H1, _} = reference_agents_home:choose(time_percept(<<"17:59">>), 0, home()),
    {_, Acts} = reference_agents_home:choose(time_percept(<<"18:00">>), 0, H1),
    ?assertEqual([{{light, <<"living">>, on, 1}, <<"LivingLightEmulator01">>, <<"TurnLightOn">>}],
                 requests(Acts)).

house_intruder_photos_before_email_test() ->
    P = fun(Svc, Ps) -> {percept, #{emulator => <<"E">>, source => <<"S">>, service => Svc,
                                    params => Ps, time => 1000}} end,
    {H1, _} = reference_agents_home:choose(
                P(<<"PasswordInput">>, [{<<"WrongPassword">>, <<"yes">>}]), 0, home()),
    {H2, Acts} = reference_agents_home:choose(
                   P(<<"MotionDetected">>, [{<<"Motion">>, <<"yes">>}, {<<"Room">>, <<"hall">>}]), 0, H1),
    ?assertEqual([<<"TakePhoto">>, <<"PlaySound">>, <<"PlayVoiceMessage">>],
                 [S || {_, _, S} <- requests(Acts)]),
    [PhotoTag] = [T || {T, _, <<"TakePhoto">>} <- requests(Acts)],
    {_, Mail} = reference_agents_home:choose(
                  {result, PhotoTag, {ok, [{<<"Photos">>, <<"p1.png,p2.png">>}]}}, 0, H2),
    [{request, _, <<"NotifierEmulator01">>, <<"SendEmail">>, Params}] =
        [A || {request, _, _, _, _} = A <- Mail],
    ?assertEqual(<<"INTRUSION">>, proplists:get_value(<<"Subject">>, Params)),
    ?assertEqual(<<"p1.png,p2.png">>, proplists:get_value(<<"Attachment">>, Params)).

house_sends_the_email_even_when_the_camera_fails_test() ->
    P = fun(Svc, Ps) -> {percept, #{emulator => <<"E">>, source => <<"S">>, service => Svc,
                                    params => Ps, time => 1000}} end,
    {H1, _} = reference_agents_home:choose(
                P(<<"PasswordInput">>, [{<<"WrongPassword">>, <<"yes">>}]), 0, home()),
    {H2, Acts} = reference_agents_home:choose(P(<<"MotionDetected">>, [{<<"Motion">>, <<"yes">>}]), 0, H1),
    [PhotoTag] = [T || {T, _, <<"TakePhoto">>} <- requests(Acts)],
    {_, Mail} = reference_agents_home:choose({result, PhotoTag, {failed, <<"EVATAR Timeout">>}}, 0, H2),
    [{request, _, _, <<"SendEmail">>, Params}] = [A || {request, _, _, _, _} = A <- Mail],
    ?assertEqual(undefined, proplists:get_value(<<"Attachment">>, Params)).

house_restores_wanted_lights_after_rebinding_test() ->
    {H1, _} = reference_agents_home:choose(time_percept(<<"17:59">>), 0, home()),
    {H2, Acts} = reference_agents_home:choose(time_percept(<<"18:00">>), 0, H1),
    [Tag] = [T || {T, _, _} <- requests(Acts)],
    {H3, _} = reference_agents_home:choose({result, Tag, {failed, <<"not bound">>}}, 0, H2),
    {_, Back} = reference_agents_home:choose({embodied, #{}}, 0, H3),
    ?assert(lists:member(<<"TurnLightOn">>, [S || {_, _, S} <- requests(Back)])).

%% The room mind: hand-off and voice override.

room(Room, Emulators) ->
    Full = body("smart_home_va.xml"),
    Body = Full#{components := [C || #{id := Id} = C <- maps:get(components, Full),
                                     lists:member(Id, Emulators)]},
    {ok, Rules} = reference_agents_rules:parse_file(
                    filename:join(code:priv_dir(reference_agents), "home.rules")),
    {ok, R} = reference_agents_room:init(#{room => Room, body => Body, rules => Rules,
                                           peers => [<<"other-va">>]}),
    {R1, _} = reference_agents_room:choose({message, <<"other-va">>,
                                            {time, [{<<"TimeOfDay">>, <<"20:00">>},
                                                    {<<"Dark">>, <<"yes">>}]}}, 0, R),
    R1.

living() ->
    room(<<"living">>, [<<"LivingLightEmulator01">>, <<"LivingMotionEmulator01">>,
                        <<"MicrophoneEmulator01">>]).

motion() ->
    {percept, #{emulator => <<"LivingMotionEmulator01">>, source => <<"s">>,
                service => <<"MotionDetected">>, time => 0,
                params => [{<<"Motion">>, <<"yes">>}, {<<"Room">>, <<"living">>}]}}.

voice(Text) ->
    {percept, #{emulator => <<"MicrophoneEmulator01">>, source => <<"m">>,
                service => <<"VoiceCommand">>, time => 0, params => [{<<"Text">>, Text}]}}.

room_motion_in_the_dark_switches_on_and_tells_the_others_test() ->
    {_, Acts} = reference_agents_room:choose(motion(), 0, living()),
    ?assertMatch([{_, <<"LivingLightEmulator01">>, <<"TurnLightOn">>}], requests(Acts)),
    ?assert(lists:member({tell, <<"other-va">>, {entered, <<"living">>}}, Acts)).

room_checks_for_motion_before_switching_off_test() ->
    {R1, _} = reference_agents_room:choose(motion(), 0, living()),
    {R2, Acts} = reference_agents_room:choose({message, <<"other-va">>, {entered, <<"kitchen">>}}, 0, R1),
    [{{check, <<"other-va">>} = Tag, <<"LivingMotionEmulator01">>, <<"ReadMotion">>}] = requests(Acts),
    {_, Still} = reference_agents_room:choose({result, Tag, {ok, [{<<"Motion">>, <<"yes">>}]}}, 0, R2),
    ?assertEqual([], requests(Still)),
    {_, Off} = reference_agents_room:choose({result, Tag, {ok, [{<<"Motion">>, <<"no">>}]}}, 0, R2),
    ?assertMatch([{_, _, <<"TurnLightOff">>}], requests(Off)).

room_voice_keeps_the_light_on_test() ->
    {R1, On} = reference_agents_room:choose(voice(<<"Keep the light on!">>), 0, living()),
    ?assertMatch([{_, _, <<"TurnLightOn">>}], requests(On)),
    {_, Acts} = reference_agents_room:choose({message, <<"other-va">>, {entered, <<"kitchen">>}}, 0, R1),
    ?assertEqual([], requests(Acts)).

room_voice_keeps_the_light_off_test() ->
    {R1, _} = reference_agents_room:choose(voice(<<"keep the light off">>), 0, living()),
    {R2, Acts} = reference_agents_room:choose(motion(), 0, R1),
    ?assertEqual([], requests(Acts)),
    {R3, _} = reference_agents_room:choose(voice(<<"lights automatic">>), 0, R2),
    {_, Again} = reference_agents_room:choose(motion(), 0, R3),
    ?assertMatch([{_, _, <<"TurnLightOn">>}], requests(Again)).

room_no_light_in_daylight_test() ->
    {R1, _} = reference_agents_room:choose({message, <<"other-va">>,
                                            {time, [{<<"TimeOfDay">>, <<"12:00">>},
                                                    {<<"Sunset">>, <<"16:10">>},
                                                    {<<"Sunrise">>, <<"07:20">>}]}}, 0, living()),
    {_, Acts} = reference_agents_room:choose(motion(), 0, R1),
    ?assertEqual([], requests(Acts)).

%% The coordinator.

coordinator_explores_agrees_then_commands_test() ->
    Robots = [<<"va1">>, <<"va2">>],
    {ok, C0} = reference_agents_coordinator:init(
                 #{robots => Robots, targets => #{<<"red">> => <<"se">>},
                   zones => #{<<"se">> => {1750, 250}}}),
    M = fun(From, Msg, C) -> reference_agents_coordinator:choose({message, From, Msg}, 0, C) end,
    {C1, []} = strip(M(<<"va1">>, {ready, <<"va1">>, {300, 300, 0}}, C0)),
    {C2, Explore} = strip(M(<<"va2">>, {ready, <<"va2">>, {1700, 1200, 180}}, C1)),
    [{tell, <<"va1">>, {explore, _, #{lanes := [150, 350, 550, 750]}}},
     {tell, <<"va2">>, {explore, _, #{lanes := [950, 1150, 1350]}}}] = Explore,
    Red = fun(S) -> [#{symbol => S, colour => <<"red">>, position => {1000, 450}}] end,
    {C3, []} = strip(M(<<"va1">>, {anchors, <<"va1">>, Red(<<"a">>), undefined}, C2)),
    {C4, Lex} = strip(M(<<"va2">>, {anchors, <<"va2">>, Red(<<"b">>), undefined}, C3)),
    [{tell, _, {lexicon, L}}, {tell, _, {lexicon, L}}] = Lex,
    {C5, []} = strip(M(<<"va1">>, {lexicon_ack, <<"va1">>, erlang:phash2(L)}, C4)),
    {C6, [{tell, <<"va1">>, {pick_place, <<"red-ball">>, <<"se">>, {1750, 250}}}]} =
        strip(M(<<"va2">>, {lexicon_ack, <<"va2">>, erlang:phash2(L)}, C5)),
    {_, Done} = reference_agents_coordinator:choose(
                  {message, <<"va1">>, {placed, <<"va1">>, <<"red-ball">>, <<"se">>, {1750, 250}}}, 0, C6),
    [{notify, {done, #{given_up := []}}}] = [A || {notify, _} = A <- Done].

strip({C, Acts}) -> {C, [A || A <- Acts, element(1, A) =/= narrate]}.

waypoints_serpentine_test() ->
    ?assertEqual([{150, 150}, {1850, 150}, {1850, 350}, {150, 350}],
                 reference_agents_robot_mind:waypoints({300, 100, 0}, [150, 350], {150, 1850})),
    ?assertEqual([{1850, 350}, {150, 350}, {150, 150}, {1850, 150}],
                 reference_agents_robot_mind:waypoints({1700, 1200, 0}, [150, 350], {150, 1850})).

placement_test() ->
    {X, Y} = reference_agents_robot_mind:placement({0, 0, 0}, {1000, 0}, 110),
    ?assertEqual({890.0, 0.0}, {X, Y}),
    ?assertEqual({10, 10}, reference_agents_robot_mind:placement({0, 0, 0}, {10, 10}, 110)).

%% A pick whose look finds no ball at the anchored point (the bumper met
%% something else, or the sighting was off) is not repeated from the same
%% place: the VA backs off and goes round, then approaches from another
%% stand-off point.
pick_retry_goes_round_test() ->
    {ok, R0} = reference_agents_robot_mind:init(#{name => <<"va-1">>, body => body("lego_va.xml"),
                                             coordinator => <<"c">>}),
    Pose = fun(X, Y, H) -> [{<<"X">>, integer_to_binary(X)}, {<<"Y">>, integer_to_binary(Y)},
                            {<<"Heading">>, integer_to_binary(H)}] end,
    {R1, _} = reference_agents_robot_mind:choose({result, locate, {ok, Pose(1000, 500, 0)}}, 0, R0),
    Lexicon = [#{word => <<"blue-ball">>, colour => <<"blue">>, position => {1440, 773},
                 names => #{}}],
    {R2, _} = reference_agents_robot_mind:choose({message, <<"c">>, {lexicon, Lexicon}}, 0, R1),
    {R3, Acts3} = reference_agents_robot_mind:choose(
                    {message, <<"c">>, {pick_place, <<"blue-ball">>, <<"n">>, {1000, 1300}}}, 0, R2),
    [{request, approach, _, <<"GoTo">>, First}] = robot_requests(Acts3),
    %% The bumper touches something at the stand-off point; no ball is seen
    %% however the claw turns.
    {R4, Acts4} = reference_agents_robot_mind:choose(
                    {result, approach, {ok, [{<<"Result">>, <<"contact">>} | Pose(1280, 670, 33)]}},
                    1, R3),
    {R5, Next} = scan_nothing(robot_requests(Acts4), R4),
    [{request, {avoid, back, pick}, _, <<"Forward">>, [{<<"Distance">>, Back}]}] = Next,
    ?assert(binary_to_float(Back) < 0),
    {R6, [{request, {avoid, left, pick}, _, <<"Rotate">>, _}]} =
        reqs(reference_agents_robot_mind:choose({result, {avoid, back, pick}, {ok, Pose(1300, 580, 303)}},
                                           3, R5)),
    {R7, [{request, {avoid, ahead, pick}, _, <<"Forward">>, _}]} =
        reqs(reference_agents_robot_mind:choose({result, {avoid, left, pick}, {ok, Pose(1300, 580, 33)}},
                                           4, R6)),
    {_, [{request, approach, _, <<"GoTo">>, Second}]} =
        reqs(reference_agents_robot_mind:choose({result, {avoid, ahead, pick},
                                            {ok, [{<<"Result">>, <<"done">>} | Pose(1510, 716, 33)]}},
                                           5, R7)),
    XY = fun(Ps) -> [V || {K, V} <- Ps, K =:= <<"X">> orelse K =:= <<"Y">>] end,
    ?assertNotEqual(XY(First), XY(Second)).

robot_requests(Acts) -> [A || {request, _, _, _, _} = A <- Acts].

reqs({R, Acts}) -> {R, robot_requests(Acts)}.

%% Answers every look with the grey floor and every turn with done, until
%% the VA asks for something else.
scan_nothing([{request, {look, _, _} = Tag, _, <<"ReadLight">>, []}], R) ->
    {R1, A} = reference_agents_robot_mind:choose({result, Tag, {ok, [{<<"Colour">>, <<"grey">>}]}}, 2, R),
    scan_nothing(robot_requests(A), R1);
scan_nothing([{request, {turn, _, _} = Tag, _, <<"Rotate">>, _}], R) ->
    {R1, A} = reference_agents_robot_mind:choose({result, Tag, {ok, []}}, 2, R),
    scan_nothing(robot_requests(A), R1);
scan_nothing(Other, R) ->
    {R, Other}.

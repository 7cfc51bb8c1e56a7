%% The robots' LeJOS-like API as a pure model: requests, ticks, answers and sensor signals.
-module(avatar_sim_robots_tests).
-include_lib("eunit/include/eunit.hrl").

-define(T0, 1731690000000).

model(Robots, Opts) ->
    Base = avatar_sim_desc:example("lego_robot.xml"),
    Rs = [#{index => I, entity => avatar_sim_desc:robot_entity(I),
            description => avatar_sim_desc:robot(I, Base), x => X, y => Y, heading => H}
          || {I, X, Y, H} <- Robots],
    avatar_sim_robots:init(maps:merge(#{robots => Rs, seed => 1}, Opts), ?T0).

req(Id, Receiver, Type, Params) ->
    #{id => Id, context => request, sender => <<Receiver/binary, "Emulator">>,
      receiver => Receiver, in_reply_to => undefined, timestamp => 0, seq => undefined,
      epoch => undefined,
      body => #{category => <<"BEHAVIOUR">>, type => Type, parameters => Params}}.

%% Runs ticks until `Until' ms after T0, collecting effects with their time.
run(M, From, Until) ->
    lists:foldl(fun(T, {Acc, Es}) ->
                        {Acc1, Es1} = avatar_sim_robots:tick(T, Acc),
                        {Acc1, Es ++ [{T, E} || E <- Es1]}
                end, {M, []}, lists:seq(?T0 + From + 100, ?T0 + Until, 100)).

answers(Id, Context, Es) ->
    [P || {_, {answer, #{id := I}, C, #{parameters := P}}} <- Es, I =:= Id, C =:= Context].

pushes(Type, Es) ->
    [{T, C, P} || {T, {push, C, _, #{type := Ty, parameters := P}}} <- Es, Ty =:= Type].

val(K, P) -> proplists:get_value(K, P).

%% Forward drives the distance, sends progress each second, then its feedback.
forward_test() ->
    M0 = model([{1, 300, 300, 0}], #{}),
    {M1, []} = avatar_sim_robots:request(req(<<"f">>, <<"ForwardBehaviour">>, <<"Forward">>,
                                              [{<<"Distance">>, <<"0.3">>}]), ?T0, M0),
    {M2, Es} = run(M1, 0, 3000),
    [Fb] = answers(<<"f">>, feedback, Es),
    ?assertEqual(<<"done">>, val(<<"Result">>, Fb)),
    ?assertEqual(<<"Forward">>, val(<<"Service">>, Fb)),
    ?assertEqual(<<"600">>, val(<<"X">>, Fb)),
    ?assertEqual(<<"300">>, val(<<"Travelled">>, Fb)),
    ?assert(length(answers(<<"f">>, progress, Es)) >= 1),
    #{robots := [#{x := X, tacho := #{a := A, c := C}}]} = avatar_sim_robots:state(0, M2),
    ?assert(abs(X - 600) < 1.0e-6),
    ?assertEqual(A, C),
    ?assert(A > 600).

%% Driving into the wall ends with contact and presses, then releases, the touch sensor.
wall_contact_test() ->
    M0 = model([{1, 300, 300, 180}], #{}),
    {M1, []} = avatar_sim_robots:request(req(<<"f">>, <<"ForwardBehaviour">>, <<"Forward">>,
                                              [{<<"Distance">>, <<"1">>}]), ?T0, M0),
    {M2, Es} = run(M1, 0, 3000),
    [Fb] = answers(<<"f">>, feedback, Es),
    ?assertEqual(<<"contact">>, val(<<"Result">>, Fb)),
    ?assertEqual(<<"80">>, val(<<"X">>, Fb)),
    [{_, <<"TouchSensor">>, Pressed}] = pushes(<<"Touch">>, Es),
    ?assertEqual(<<"yes">>, val(<<"Pressed">>, Pressed)),
    {M3, []} = avatar_sim_robots:request(req(<<"b">>, <<"ForwardBehaviour">>, <<"Forward">>,
                                              [{<<"Distance">>, <<"-0.1">>}]), ?T0 + 3000, M2),
    {_, Es2} = run(M3, 3000, 5000),
    [{_, _, Released}] = pushes(<<"Touch">>, Es2),
    ?assertEqual(<<"no">>, val(<<"Pressed">>, Released)).

%% Go to a ball (contact), grab it, carry it to a zone and release it there.
pick_and_place_test() ->
    M0 = model([{1, 300, 300, 0}], #{balls => [#{colour => <<"red">>, x => 700, y => 500}]}),
    {M1, []} = avatar_sim_robots:request(req(<<"g">>, <<"GoToBehaviour">>, <<"GoTo">>,
                                              [{<<"X">>, <<"700">>}, {<<"Y">>, <<"500">>}]), ?T0, M0),
    {M2, Es} = run(M1, 0, 10000),
    [Fb] = answers(<<"g">>, feedback, Es),
    ?assertEqual(<<"contact">>, val(<<"Result">>, Fb)),
    ?assert(lists:any(fun({_, _, P}) -> val(<<"Colour">>, P) =:= <<"red">> end,
                      pushes(<<"ColourApproximation">>, Es))),
    {M3, []} = avatar_sim_robots:request(req(<<"c">>, <<"GrabBehaviour">>, <<"Grab">>, []),
                                         ?T0 + 10000, M2),
    {M4, Es2} = run(M3, 10000, 11000),
    [Grab] = answers(<<"c">>, feedback, Es2),
    ?assertEqual([<<"yes">>, <<"red">>], [val(<<"Holding">>, Grab), val(<<"Colour">>, Grab)]),
    {M5, []} = avatar_sim_robots:request(req(<<"z">>, <<"GoToBehaviour">>, <<"GoTo">>,
                                              [{<<"X">>, <<"1000">>}, {<<"Y">>, <<"1300">>},
                                               {<<"Heading">>, <<"90">>}]), ?T0 + 11000, M4),
    {M6, Es3} = run(M5, 11000, 25000),
    [Arrived] = answers(<<"z">>, feedback, Es3),
    ?assertEqual([<<"done">>, <<"1000">>, <<"1300">>, <<"90">>],
                 [val(K, Arrived) || K <- [<<"Result">>, <<"X">>, <<"Y">>, <<"Heading">>]]),
    {M7, []} = avatar_sim_robots:request(req(<<"r">>, <<"ReleaseBehaviour">>, <<"Release">>, []),
                                         ?T0 + 25000, M6),
    {M8, Es4} = run(M7, 25000, 26000),
    [Rel] = answers(<<"r">>, feedback, Es4),
    ?assertEqual(<<"red">>, val(<<"Released">>, Rel)),
    #{balls := [#{zone := Zone, held_by := none}], robots := [#{holding := none}]} =
        avatar_sim_robots:state(0, M8),
    ?assertEqual(<<"n">>, Zone).

%% Explore wanders until the light sensor sees a ball, deterministically for a seed.
explore_test() ->
    Go = fun(Seed) ->
                 M0 = model([{1, 300, 300, 45}], #{seed => Seed}),
                 {M1, []} = avatar_sim_robots:request(
                              req(<<"e">>, <<"ExploreBehaviour">>, <<"Explore">>,
                                  [{<<"Duration">>, <<"300">>}]), ?T0, M0),
                 {_, Es} = run(M1, 0, 300000),
                 Es
         end,
    Es = Go(3),
    [Fb] = answers(<<"e">>, feedback, Es),
    ?assertEqual(<<"found">>, val(<<"Result">>, Fb)),
    ?assert(lists:member(val(<<"Colour">>, Fb), [<<"red">>, <<"green">>, <<"blue">>])),
    ?assert(length(answers(<<"e">>, progress, Es)) >= 1),
    ?assertEqual(Es, Go(3)),
    ?assertNotEqual(Es, Go(4)).

%% Explore ignores the colours it is told to.
explore_ignore_test() ->
    M0 = model([{1, 700, 450, 0}], #{balls => [#{colour => <<"red">>, x => 1000, y => 450}]}),
    {M1, []} = avatar_sim_robots:request(req(<<"e">>, <<"ExploreBehaviour">>, <<"Explore">>,
                                              [{<<"Duration">>, <<"5">>}, {<<"Ignore">>, <<"red">>}]),
                                         ?T0, M0),
    {_, Es} = run(M1, 0, 6000),
    [Fb] = answers(<<"e">>, feedback, Es),
    ?assertEqual(<<"timeout">>, val(<<"Result">>, Fb)).

%% A new wheel behaviour preempts the running one; Stop stops everything.
preempt_and_stop_test() ->
    M0 = model([{1, 300, 750, 0}], #{}),
    {M1, []} = avatar_sim_robots:request(req(<<"a">>, <<"ForwardBehaviour">>, <<"Forward">>, []), ?T0, M0),
    {M2, Es} = avatar_sim_robots:request(req(<<"b">>, <<"RotateBehaviour">>, <<"Rotate">>, []), ?T0, M1),
    [{answer, #{id := <<"a">>}, feedback, #{parameters := P}}] = Es,
    ?assertEqual(<<"preempted">>, val(<<"Result">>, P)),
    {M3, Es2} = avatar_sim_robots:request(req(<<"s">>, <<"StopBehaviour">>, <<"Stop">>, []), ?T0, M2),
    [<<"stopped">>, <<"done">>] = [val(<<"Result">>, Ps) || {answer, _, feedback, #{parameters := Ps}} <- Es2],
    #{robots := [#{behaviour := none}]} = avatar_sim_robots:state(0, M3).

%% Fine grain: motor A alone makes the robot curve; motor B closes the claw.
motors_test() ->
    M0 = model([{1, 300, 750, 0}], #{}),
    Motor = fun(Id, Port, Params) ->
                    (req(Id, <<"Motor", Port>>, <<"Rotate">>, Params))#{
                      body := #{category => <<"ACTUATOR">>, type => <<"Rotate">>, parameters => Params}}
            end,
    {M1, []} = avatar_sim_robots:request(Motor(<<"a">>, $A, [{<<"Angle">>, <<"360">>}]), ?T0, M0),
    {M2, []} = avatar_sim_robots:request(Motor(<<"b">>, $B, [{<<"Angle">>, <<"45">>}]), ?T0, M1),
    {M3, Es} = run(M2, 0, 2000),
    [A] = answers(<<"a">>, feedback, Es),
    [B] = answers(<<"b">>, feedback, Es),
    ?assertEqual([<<"done">>, <<"A">>, <<"360">>], [val(K, A) || K <- [<<"Result">>, <<"Port">>, <<"Angle">>]]),
    ?assertEqual([<<"done">>, <<"B">>, <<"45">>], [val(K, B) || K <- [<<"Result">>, <<"Port">>, <<"Angle">>]]),
    #{robots := [#{heading := H, claw := 45}]} = avatar_sim_robots:state(0, M3),
    ?assert(H > 180).

%% Bad parameters and unknown services are answered with error signals.
errors_test() ->
    M0 = model([{1, 300, 750, 0}], #{}),
    {_, [{answer, _, error, #{type := <<"BadParameter">>}}]} =
        avatar_sim_robots:request(req(<<"x">>, <<"GoToBehaviour">>, <<"GoTo">>, [{<<"Y">>, <<"1">>}]), ?T0, M0),
    {_, [{answer, _, error, #{type := <<"BadParameter">>}}]} =
        avatar_sim_robots:request(req(<<"x">>, <<"ForwardBehaviour">>, <<"Forward">>,
                                      [{<<"Distance">>, <<"far">>}]), ?T0, M0),
    {_, [{answer, _, error, #{type := <<"UnknownService">>}}]} =
        avatar_sim_robots:request(req(<<"x">>, <<"ForwardBehaviour">>, <<"Fly">>, []), ?T0, M0).

%% Robot 2's components carry its suffix; sensor reads answer with the sensor's body.
robot_two_and_sensors_test() ->
    M0 = model([{1, 300, 300, 0}, {2, 890, 450, 0}], #{}),
    {_, [{answer, _, feedback, #{category := <<"SENSOR">>, type := <<"ColourApproximation">>,
                                 parameters := P}}]} =
        avatar_sim_robots:request(req(<<"l">>, <<"LightSensor-2">>, <<"ReadLight">>, []), ?T0, M0),
    ?assertEqual(<<"red">>, val(<<"Colour">>, P)),
    {_, Es} = run(M0, 0, 1000),
    ?assert(lists:member(<<"LightSensor-2">>, [C || {_, C, _} <- pushes(<<"Luminosity">>, Es)])).

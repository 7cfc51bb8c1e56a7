%% Arena geometry and the light sensor's colour approximation.
-module(avatar_sim_arena_tests).
-include_lib("eunit/include/eunit.hrl").

arena(Poses) ->
    A = avatar_sim_arena:new(#{balls => [#{colour => <<"red">>, x => 1000, y => 450}]}),
    A#{poses := Poses}.

pose(X, Y, H) -> #{x => float(X), y => float(Y), h => float(H)}.

%% Both wheels turned by the same angle drive straight ahead.
straight_drive_test() ->
    A = arena(#{1 => pose(300, 300, 0)}),
    Deg = 100 / avatar_sim_arena:wheel_mm_per_deg(),
    {F, #{poses := #{1 := #{x := X, y := Y, h := H}}}} = avatar_sim_arena:drive(A, 1, Deg, Deg),
    ?assertEqual(1.0, F),
    ?assert(abs(X - 400) < 1.0e-6),
    ?assert(abs(Y - 300) < 1.0e-6),
    ?assert(abs(H) < 1.0e-6).

%% Opposite wheel angles turn on the spot, anticlockwise when the right one goes forward.
turn_on_the_spot_test() ->
    A = arena(#{1 => pose(300, 300, 0)}),
    Half = avatar_sim_arena:track() / 2,
    Deg = (math:pi() / 2) * Half / avatar_sim_arena:wheel_mm_per_deg(),
    {1.0, #{poses := #{1 := #{x := X, h := H}}}} = avatar_sim_arena:drive(A, 1, -Deg, Deg),
    ?assert(abs(H - 90) < 1.0e-6),
    ?assert(abs(X - 300) < 1.0e-6).

%% Driving into a wall stops the robot where its bumper touches it.
wall_contact_test() ->
    A = arena(#{1 => pose(300, 300, 180)}),
    Deg = 500 / avatar_sim_arena:wheel_mm_per_deg(),
    {F, A1 = #{poses := #{1 := #{x := X} = P}}} = avatar_sim_arena:drive(A, 1, Deg, Deg),
    ?assert(F < 1.0),
    ?assert(abs(X - avatar_sim_arena:robot_radius()) < 0.5),
    ?assert(avatar_sim_arena:clearance(A1, 1, P) < 1.0).

%% A robot stops when it touches the other robot.
robot_contact_test() ->
    A = arena(#{1 => pose(300, 750, 0), 2 => pose(700, 750, 180)}),
    Deg = 1000 / avatar_sim_arena:wheel_mm_per_deg(),
    {_, #{poses := #{1 := #{x := X}}}} = avatar_sim_arena:drive(A, 1, Deg, Deg),
    ?assert(abs(X - (700 - 2 * avatar_sim_arena:robot_radius())) < 0.5).

%% Driving head-on into a ball stops with the ball at the claw point, ready to grab.
ball_contact_puts_ball_at_claw_test() ->
    A = arena(#{1 => pose(600, 450, 0)}),
    Deg = 1000 / avatar_sim_arena:wheel_mm_per_deg(),
    {F, A1} = avatar_sim_arena:drive(A, 1, Deg, Deg),
    ?assert(F < 1.0),
    {ok, #{colour := <<"red">>}} = avatar_sim_arena:ball_at_claw(A1, 1),
    ?assertEqual(none, avatar_sim_arena:ball_at_claw(A, 1)).

%% A robot already touching something may still move away from it.
moving_away_from_contact_test() ->
    A = arena(#{1 => pose(80, 300, 180)}),
    Deg = 100 / avatar_sim_arena:wheel_mm_per_deg(),
    {1.0, #{poses := #{1 := #{x := X}}}} = avatar_sim_arena:drive(A, 1, -Deg, -Deg),
    ?assert(abs(X - 180) < 1.0e-6).

%% Every palette colour is approximated as itself.
classify_palette_test() ->
    [?assertEqual(Name, avatar_sim_arena:classify(RGB)) || {Name, RGB} <- avatar_sim_arena:palette()].

%% The sensor over a ball, the floor, a zone and beyond a wall reads the right colour despite noise.
light_surfaces_test() ->
    A = (arena(#{1 => pose(890, 450, 0), 2 => pose(500, 900, 0), 3 => pose(140, 1250, 0),
                 4 => pose(1900, 750, 0)}))#{},
    Read = fun(I, Seed) ->
                   {#{colour := C}, _} = avatar_sim_arena:light(A, I, {none, rand:seed_s(exsss, Seed)}),
                   C
           end,
    [begin
         ?assertEqual(<<"red">>, Read(1, S)),
         ?assertEqual(<<"grey">>, Read(2, S)),
         ?assertEqual(<<"white">>, Read(3, S)),
         ?assertEqual(<<"black">>, Read(4, S))
     end || S <- lists:seq(1, 100)].

%% The same random state gives the same reading; another one gives other noise.
light_is_seeded_test() ->
    A = arena(#{1 => pose(890, 450, 0)}),
    {R1, _} = avatar_sim_arena:light(A, 1, {none, rand:seed_s(exsss, 5)}),
    {R2, _} = avatar_sim_arena:light(A, 1, {none, rand:seed_s(exsss, 5)}),
    ?assertEqual(R1, R2),
    Others = [element(1, avatar_sim_arena:light(A, 1, {none, rand:seed_s(exsss, S)}))
              || S <- lists:seq(6, 20)],
    ?assert(lists:any(fun(#{rgb := RGB}) -> RGB =/= maps:get(rgb, R1) end, Others)).

%% Zones are found by position.
zone_of_test() ->
    A = avatar_sim_arena:new(#{}),
    ?assertEqual(<<"nw">>, avatar_sim_arena:zone_of(A, 260.0, 1240.0)),
    ?assertEqual(none, avatar_sim_arena:zone_of(A, 1000.0, 750.0)).

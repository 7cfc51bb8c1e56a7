%% @doc EUnit tests of activity recognition, action policies and the time
%% of day: simple activities from readings, complex ones within their
%% window (Fig. 10), the vetoes, the schedule crossing midnight, darkness.
-module(reference_agents_activity_tests).

-include_lib("eunit/include/eunit.hrl").

-define(MIN, 60000).

rules() ->
    {ok, R} = reference_agents_rules:parse(
                <<"simple motion when MotionDetected Motion=yes\n"
                  "simple failed when PasswordInput WrongPassword=yes\n"
                  "simple right when PasswordInput WrongPassword=no\n"
                  "complex intruder when motion and failed within 2 min unless right\n"
                  "simple alarm_heard when Sound\n"
                  "complex confirmed when intruder and alarm_heard within 1 min\n"
                  "policy holiday on intruder do alarm\n"
                  "policy holiday on motion in hall if dark do photos 1\n"
                  "policy holiday at 18:00 if dark do light living on\n"
                  "policy holiday at 23:30 do light all off\n"
                  "policy holiday at 00:10 if between 00:00 and 01:00 do light living off\n">>),
    R.

percept(Service, Params, T) ->
    #{service => Service, params => Params, time => T}.

motion(T) -> percept(<<"MotionDetected">>, [{<<"Motion">>, <<"yes">>}, {<<"Room">>, <<"hall">>}], T).
wrong(T) -> percept(<<"PasswordInput">>, [{<<"WrongPassword">>, <<"yes">>}], T).
right(T) -> percept(<<"PasswordInput">>, [{<<"WrongPassword">>, <<"no">>}], T).

feed(Percepts) ->
    lists:foldl(fun(P, {S, Acc}) ->
                        {S1, Found} = reference_agents_activity:perceive(P, S),
                        {S1, Acc ++ [A || #{activity := A} <- Found]}
                end, {reference_agents_activity:new(rules()), []}, Percepts).

simple_activity_matches_service_and_parameters_test() ->
    {_, Found} = feed([motion(0), percept(<<"motion detected">>, [{<<"motion">>, <<"YES">>}], 1),
                       percept(<<"MotionDetected">>, [{<<"Motion">>, <<"no">>}], 2)]),
    ?assertEqual([<<"motion">>, <<"motion">>], Found).

fig10_motion_then_wrong_password_is_an_intruder_test() ->
    {_, Found} = feed([motion(0), wrong(90000)]),
    ?assertEqual([<<"motion">>, <<"failed">>, <<"intruder">>], Found).

fig10_in_either_order_test() ->
    {_, Found} = feed([wrong(0), motion(60000)]),
    ?assertEqual([<<"failed">>, <<"motion">>, <<"intruder">>], Found).

outside_the_window_is_no_intruder_test() ->
    {_, Found} = feed([motion(0), wrong(2 * ?MIN + 1)]),
    ?assertNot(lists:member(<<"intruder">>, Found)).

the_right_code_vetoes_the_intruder_test() ->
    {_, Found} = feed([wrong(0), right(10000), motion(20000)]),
    ?assertNot(lists:member(<<"intruder">>, Found)).

an_intruder_is_reported_once_per_window_test() ->
    {_, Found} = feed([motion(0), wrong(1000), motion(30000), wrong(40000),
                       motion(3 * ?MIN + 2000), wrong(3 * ?MIN + 3000)]),
    ?assertEqual(2, length([A || A <- Found, A =:= <<"intruder">>])).

complex_of_complex_test() ->
    {_, Found} = feed([motion(0), wrong(1000), percept(<<"Sound">>, [], 5000)]),
    ?assertEqual([<<"motion">>, <<"failed">>, <<"intruder">>, <<"alarm_heard">>, <<"confirmed">>],
                 Found).

complex_instance_carries_its_parts_and_room_test() ->
    S0 = reference_agents_activity:new(rules()),
    {S1, _} = reference_agents_activity:perceive(motion(0), S0),
    {_, [_, #{activity := <<"intruder">>, room := <<"hall">>, kind := complex,
              parts := [#{activity := <<"motion">>, time := 0},
                        #{activity := <<"failed">>, time := 5}]}]} =
        reference_agents_activity:perceive(wrong(5), S1).

history_forgets_old_activities_test() ->
    {S, _} = feed([motion(0), motion(10 * ?MIN)]),
    ?assertEqual(1, length(reference_agents_activity:history(S))).

%% Policies.

on_activity_respects_room_and_conditions_test() ->
    R = rules(),
    Hall = #{activity => <<"motion">>, room => <<"hall">>},
    Kitchen = #{activity => <<"motion">>, room => <<"kitchen">>},
    Dark = #{minute => 1200, dark => true},
    Light = #{minute => 900, dark => false},
    ?assertMatch([#{actions := [{photos, 1}]}],
                 reference_agents_policy:on_activity(<<"holiday">>, Hall, Dark, R)),
    ?assertEqual([], reference_agents_policy:on_activity(<<"holiday">>, Hall, Light, R)),
    ?assertEqual([], reference_agents_policy:on_activity(<<"holiday">>, Kitchen, Dark, R)),
    ?assertEqual([], reference_agents_policy:on_activity(<<"away">>, Hall, Dark, R)).

on_time_fires_when_the_clock_passes_test() ->
    R = rules(),
    Dark = fun(M) -> #{minute => M, dark => true} end,
    ?assertMatch([#{trigger := {at, 1080}}],
                 reference_agents_policy:on_time(<<"holiday">>, 1079, 1080, Dark(1080), R)),
    ?assertMatch([#{trigger := {at, 1080}}],
                 reference_agents_policy:on_time(<<"holiday">>, 1070, 1095, Dark(1095), R)),
    ?assertEqual([], reference_agents_policy:on_time(<<"holiday">>, 1080, 1081, Dark(1081), R)),
    ?assertEqual([], reference_agents_policy:on_time(<<"holiday">>, 1079, 1080,
                                                     #{minute => 1080, dark => false}, R)).

on_time_across_midnight_test() ->
    R = rules(),
    Fired = reference_agents_policy:on_time(<<"holiday">>, 1400, 15, #{minute => 15, dark => true}, R),
    ?assertEqual([1410, 10], [M || #{trigger := {at, M}} <- Fired]).

dark_test_() ->
    [?_assert(reference_agents_policy:dark(1000, 980, 430)),
     ?_assert(reference_agents_policy:dark(100, 980, 430)),
     ?_assertNot(reference_agents_policy:dark(600, 980, 430)),
     %% Sunrise after sunset on the clock: polar-style inputs still work.
     ?_assert(reference_agents_policy:dark(100, 60, 200)),
     ?_assertNot(reference_agents_policy:dark(300, 60, 200))].

minute_test_() ->
    [?_assertEqual(1085, reference_agents_policy:minute(<<"18:05">>)),
     ?_assertEqual(65, reference_agents_policy:minute(<<"1:05:59">>)),
     ?_assertEqual(undefined, reference_agents_policy:minute(<<"24:00">>)),
     ?_assertEqual(undefined, reference_agents_policy:minute(<<"noon">>)),
     ?_assertEqual("07:09", lists:flatten(reference_agents_policy:format_minute(429)))].

%% What the VA knows of the time of day.

daytime_from_sensor_readings_test() ->
    D0 = reference_agents_daytime:new(),
    ?assertNot(reference_agents_daytime:known(D0)),
    {D1, {1079, 1080}} = reference_agents_daytime:update(
                           [{<<"TimeOfDay">>, <<"18:00">>}, {<<"Dark">>, <<"yes">>}], D0),
    ?assert(reference_agents_daytime:dark(D1)),
    {D2, none} = reference_agents_daytime:update([{<<"Sunset">>, <<"18:30">>},
                                                  {<<"Sunrise">>, <<"07:00">>}], D1),
    %% Once sunset and sunrise are known, the VA computes darkness itself.
    ?assertNot(reference_agents_daytime:dark(D2)),
    {D3, {1080, 1115}} = reference_agents_daytime:update([{<<"TimeOfDay">>, <<"18:35">>}], D2),
    ?assert(reference_agents_daytime:dark(D3)),
    ?assertEqual(#{minute => 1115, dark => true}, reference_agents_daytime:context(D3)).

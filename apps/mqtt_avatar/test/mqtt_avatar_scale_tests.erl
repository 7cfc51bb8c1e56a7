%% @doc EUnit tests of how the description's generation grows with the
%% home: the work per device (reductions of the whole node, the batches'
%% processes included) for ten times more devices stays within 1.5 times
%% the work per device of the smaller home, so the generation is not
%% quadratic (docs/mqtt.md section 6, "Large homes"). Work, not time: the
%% figures in time are bench/mqtt_gen_bench's.
-module(mqtt_avatar_scale_tests).

-include_lib("eunit/include/eunit.hrl").

-define(N, 200).

%% A building of motion sensors all named the same (Home Assistant names a
%% device by its model): each needs a ComponentID of its own.
same_name_sensors_grow_linearly_test_() ->
    {timeout, 120,
     fun() ->
             Small = per_device(?N),
             Large = per_device(10 * ?N),
             ?assert(Large =< 1.5 * Small, {per_device_reductions, ?N, Small, 10 * ?N, Large})
     end}.

%% The names are unique and every device keeps its own override key.
same_name_sensors_get_distinct_ids_test() ->
    Devices = devices(50),
    Overrides = #{<<"ha:sensor-7">> => #{room => <<"hall">>},
                  <<"nothing-matches">> => #{room => <<"attic">>}},
    {#{components := Cs}, Problems} =
        mqtt_avatar_generate:description(#{entity_id => <<"scale">>, overrides => Overrides},
                                         Devices, []),
    Ids = [Id || #{id := Id} <- Cs],
    ?assertEqual(50, length(lists:usort(Ids))),
    ?assertEqual([<<"MotionSensor">>, <<"MotionSensor2">>, <<"MotionSensor3">>],
                 lists:sublist(Ids, 3)),
    ?assertMatch([#{what := unused_override, key := <<"nothing-matches">>}], Problems).

%% Reductions of the node per device generated, from a fresh process (so
%% no earlier garbage is collected on its account).
per_device(N) ->
    Devices = devices(N),
    {Before, _} = erlang:statistics(exact_reductions),
    {Pid, Ref} = spawn_monitor(
                   fun() ->
                           {D, Spec, []} = mqtt_avatar_generate:build(#{entity_id => <<"scale">>},
                                                                      Devices, []),
                           N = length(maps:get(components, D)),
                           N = length(maps:get(components, Spec))
                   end),
    receive
        {'DOWN', Ref, process, Pid, normal} ->
            {After, _} = erlang:statistics(exact_reductions),
            (After - Before) / N;
        {'DOWN', Ref, process, Pid, Reason} ->
            error({generation_failed, Reason})
    end.

devices(N) ->
    [#{key => <<"ha:sensor-", (integer_to_binary(I))/binary>>,
       name => <<"Motion sensor">>, room => <<"Hall">>, model => <<"SNZB-03">>,
       availability => undefined,
       entities => [#{uid => <<"sensor-", (integer_to_binary(I))/binary, "-motion">>,
                      kind => binary_sensor, name => <<"Motion">>, device_class => <<"motion">>,
                      state_topic => <<"home/sensor-", (integer_to_binary(I))/binary>>,
                      command_topic => undefined, value => {json, [<<"occupancy">>]},
                      attributes => false, on_change => true, unit => undefined,
                      on => <<"ON">>, off => <<"OFF">>, state_on => <<"ON">>,
                      state_off => <<"OFF">>}]}
     || I <- lists:seq(1, N)].

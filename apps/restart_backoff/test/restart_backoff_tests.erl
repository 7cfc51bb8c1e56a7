%% EUnit: the pure restart policy of kept processes (MQTT Avatars, listeners).
-module(restart_backoff_tests).

-include_lib("eunit/include/eunit.hrl").

delays(Runs, B0) ->
    {Out, _} = lists:mapfoldl(fun(Ran, B) ->
                                      {D, E, B1} = restart_backoff:exited(Ran, B),
                                      {{D, E}, B1}
                              end, B0, Runs),
    Out.

doubles_from_one_second_to_a_minute_test() ->
    B = restart_backoff:new(#{}),
    Ds = [D || {D, _} <- delays(lists:duplicate(9, 10), B)],
    ?assertEqual([1000, 2000, 4000, 8000, 16000, 32000, 60000, 60000, 60000], Ds).

crash_loop_is_reported_from_the_third_short_run_test() ->
    B = restart_backoff:new(#{}),
    [{_, none}, {_, none}, {4000, {crash_loop, #{crashes := 3, delay_ms := 4000}}},
     {8000, {crash_loop, #{crashes := 4}}}] = delays([5, 5, 5, 5], B).

a_stable_run_starts_over_test() ->
    B = restart_backoff:new(#{min_ms => 100, max_ms => 1000, stable_after_ms => 500,
                                  loop_after => 2}),
    [{100, none}, {200, {crash_loop, _}}, {400, {crash_loop, #{crashes := 3}}}, {100, none},
     {200, {crash_loop, #{crashes := 2}}}] = delays([1, 1, 1, 500, 1], B).

max_below_min_is_min_test() ->
    B = restart_backoff:new(#{min_ms => 100, max_ms => 10}),
    [{100, none}, {100, none}] = delays([1, 1], B),
    0 = restart_backoff:crashes(B),
    100 = restart_backoff:next_delay(B).

%% Options are checked key by key, with a message naming the wrong one.
check_test() ->
    ok = restart_backoff:check(#{}),
    ok = restart_backoff:check(#{min_ms => 10, loop_after => 2}),
    {error, <<"unknown restart option min (", _/binary>>} = restart_backoff:check(#{min => 1}),
    {error, <<"restart option max_ms must be a positive integer">>} =
        restart_backoff:check(#{max_ms => 0}),
    {error, <<"restart must be a map", _/binary>>} = restart_backoff:check([]).

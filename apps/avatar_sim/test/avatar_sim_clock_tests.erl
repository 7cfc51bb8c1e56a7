%% The simulation clock: ticks in lockstep with acknowledgements, by hand or paced.
-module(avatar_sim_clock_tests).
-include_lib("eunit/include/eunit.hrl").

%% A subscriber that records tick times and acks them.
recorder(Clock, Parent) ->
    spawn_link(fun() ->
                       ok = avatar_sim_clock:subscribe(Clock, self()),
                       Parent ! {subscribed, self()},
                       loop(Clock, [])
               end).

loop(Clock, Seen) ->
    receive
        {avatar_sim_clock, Ref, Now} ->
            avatar_sim_clock:ack(Clock, Ref),
            loop(Clock, [Now | Seen]);
        {seen, From} ->
            From ! {seen, lists:reverse(Seen)},
            loop(Clock, Seen)
    end.

seen(Pid) ->
    Pid ! {seen, self()},
    receive {seen, S} -> S end.

%% In manual mode time moves only by advance/2, tick by tick, and every subscriber sees every tick.
manual_test() ->
    {ok, Pid, Clock} = avatar_sim_clock:start_link(#{speed => manual, tick => 100, start_ms => 1000}),
    A = recorder(Clock, self()),
    B = recorder(Clock, self()),
    [receive {subscribed, P} -> ok end || P <- [A, B]],
    ?assertEqual(1000, avatar_sim_clock:now(Clock)),
    ok = avatar_sim_clock:advance(Clock, 250),
    ?assertEqual(1300, avatar_sim_clock:now(Clock)),
    ?assertEqual([1100, 1200, 1300], seen(A)),
    ?assertEqual(seen(A), seen(B)),
    %% No tick is due: the machine is stopped, the one state without a
    %% tick timer, so real time cannot move the clock.
    ?assertMatch({stopped, _}, sys:get_state(Pid)),
    ?assertEqual(1300, avatar_sim_clock:now(Clock)),
    unlink(A), unlink(B), exit(A, kill), exit(B, kill),
    ok = avatar_sim_clock:advance(Clock, 100),
    ?assertEqual(1400, avatar_sim_clock:now(Clock)),
    unlink(Pid),
    ok = avatar_sim_clock:stop(Clock).

%% Paced mode runs faster than real time, and pause/resume stop and restart it.
paced_test() ->
    {ok, Pid, Clock} = avatar_sim_clock:start_link(#{speed => 50, tick => 100, start_ms => 0, paused => true}),
    A = recorder(Clock, self()),
    receive {subscribed, A} -> ok end,
    %% Paused: stopped, no tick timer.
    ?assertMatch({stopped, _}, sys:get_state(Pid)),
    ?assertEqual(0, avatar_sim_clock:now(Clock)),
    ok = avatar_sim_clock:resume(Clock),
    %% Until it has run ten ticks, however loaded the machine (a fixed
    %% sleep made this depend on the scheduler).
    ok = evatar_test_wait:until(fun() -> avatar_sim_clock:now(Clock) >= 1000 end),
    ok = avatar_sim_clock:pause(Clock),
    Now = avatar_sim_clock:now(Clock),
    ?assert(Now >= 1000),
    ?assertMatch({stopped, _}, sys:get_state(Pid)),
    ?assertEqual(Now, avatar_sim_clock:now(Clock)),
    Seen = seen(A),
    ?assertEqual(lists:seq(100, Now, 100), Seen),
    #{paused := true, speed := 50} = avatar_sim_clock:info(Clock),
    unlink(A), exit(A, kill), unlink(Pid),
    ok = avatar_sim_clock:stop(Clock).

%% The default start is 2024-11-15 17:00 UTC.
default_start_test() ->
    {ok, Pid, Clock} = avatar_sim_clock:start_link(#{speed => manual}),
    ?assertEqual(1731690000000, avatar_sim_clock:now(Clock)),
    unlink(Pid),
    ok = avatar_sim_clock:stop(Clock).

%% A clock that follows an observer waits for it: at any speed it stops at
%% the tick that would take it past the observer's time plus the lead, and
%% goes on once the observer has perceived more; not following, it runs on.
follow_test() ->
    {ok, Pid, Clock} = avatar_sim_clock:start_link(#{speed => 1000000, tick => 100, start_ms => 0,
                                                     paused => true}),
    A = recorder(Clock, self()),
    receive {subscribed, A} -> ok end,
    Cell = atomics:new(1, [{signed, true}]),
    ok = avatar_sim_clock:follow(Clock, fun() -> atomics:get(Cell, 1) end, 500),
    ok = atomics:put(Cell, 1, 1000),
    ok = avatar_sim_clock:resume(Clock),
    %% It gets to 1500 (1000 + the lead) and is then held there: the wait
    %% for it to reach 1500 ends, and later reads are still 1500.
    ok = evatar_test_wait:until(fun() -> avatar_sim_clock:now(Clock) >= 1500 end),
    ?assertEqual(1500, avatar_sim_clock:now(Clock)),
    ?assertMatch(#{now := 1500}, avatar_sim_clock:info(Clock)),
    ok = atomics:put(Cell, 1, 4000),
    ok = evatar_test_wait:until(fun() -> avatar_sim_clock:now(Clock) >= 4500 end),
    ?assertEqual(4500, avatar_sim_clock:now(Clock)),
    %% advance/2 is not held; `none' stops following.
    ok = avatar_sim_clock:advance(Clock, 1000),
    ?assertEqual(5500, avatar_sim_clock:now(Clock)),
    ok = avatar_sim_clock:follow(Clock, none, 0),
    ok = evatar_test_wait:until(fun() -> avatar_sim_clock:now(Clock) >= 10000 end),
    ok = avatar_sim_clock:pause(Clock),
    ?assertEqual(lists:seq(100, avatar_sim_clock:now(Clock), 100), seen(A)),
    unlink(A), exit(A, kill), unlink(Pid),
    ok = avatar_sim_clock:stop(Clock).

%% In lockstep a paced tick starts only when the quiet predicate says so,
%% asked at tick boundaries once every world has acked: with the predicate
%% saying yes three times, the clock runs exactly three ticks at any speed
%% and is then held, asking again; advance/2 is not held; `none' runs on.
lockstep_test() ->
    {ok, Pid, Clock} = avatar_sim_clock:start_link(#{speed => 1000000, tick => 100, start_ms => 0,
                                                     paused => true}),
    A = recorder(Clock, self()),
    receive {subscribed, A} -> ok end,
    Parent = self(),
    Budget = atomics:new(1, [{signed, true}]),
    Quiet = fun() ->
                    %% Asked only between ticks: the world has acked the last one.
                    Now = avatar_sim_clock:now(Clock),
                    true = lists:last([0 | seen(A)]) =:= Now,
                    Yes = atomics:sub_get(Budget, 1, 1) >= 0,
                    Parent ! {asked, Now, Yes},
                    Yes
            end,
    ok = avatar_sim_clock:lockstep(Clock, Quiet),
    ok = avatar_sim_clock:resume(Clock),
    %% Not quiet: asked, no tick.
    {0, false} = asked(),
    ok = atomics:put(Budget, 1, 3),
    %% Three yes (asked at 0, 100, 200), then held at 300.
    ok = asked_until(300, false),
    ?assertEqual(300, avatar_sim_clock:now(Clock)),
    ?assertEqual([100, 200, 300], seen(A)),
    %% Held, it asks again, and time stays.
    {300, false} = asked(),
    ok = avatar_sim_clock:advance(Clock, 200),
    ?assertEqual(500, avatar_sim_clock:now(Clock)),
    ok = avatar_sim_clock:lockstep(Clock, none),
    ok = evatar_test_wait:until(fun() -> avatar_sim_clock:now(Clock) >= 2000 end),
    ok = avatar_sim_clock:pause(Clock),
    ?assertEqual(lists:seq(100, avatar_sim_clock:now(Clock), 100), seen(A)),
    unlink(A), exit(A, kill), unlink(Pid),
    ok = avatar_sim_clock:stop(Clock).

%% The next answer of the quiet predicate, and the time it was asked at.
asked() ->
    receive {asked, Now, Yes} -> {Now, Yes} end.

%% Reads answers until the predicate said Yes at time Now.
asked_until(Now, Yes) ->
    case asked() of
        {Now, Yes} -> ok;
        _ -> asked_until(Now, Yes)
    end.

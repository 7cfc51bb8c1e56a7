%% @doc The smart-home scenarios end to end, on the simulated clock: the
%% simulated house joins EVATAR over TCP, the reference VAs join as agents
%% through agent_bridge_client. Holiday: the evening light schedule (only
%% when dark), the intrusion reported by an e-mail with photos in the spool.
%% Light control with one VA per room: the hand-off and the voice override.
%% Failure cases: a device that never answers, a device that leaves and
%% comes back, the whole gateway going away and back, a malformed rules
%% file.
-module(evatar_demo_home_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").

-export([all/0, groups/0, suite/0, init_per_suite/1, end_per_suite/1,
         init_per_group/2, end_per_group/2, init_per_testcase/2, end_per_testcase/2]).
-export([intrusion_email_with_photos/1, intrusion_narrated/1, evening_light_schedule/1,
         no_lights_in_daylight/1, device_never_answers/1, device_leaves_and_comes_back/1,
         gateway_leaves_and_comes_back/1, malformed_rules_file/1,
         room_hand_off/1, voice_override/1, no_room_light_before_dusk/1,
         sleep_policy/1, away_policy/1, same_evening_under_load/1]).

-define(SPEED, 2000).
-define(MIN, 60000).

suite() -> [{timetrap, {seconds, 120}}].

all() ->
    [{group, holiday}, {group, rooms}, no_lights_in_daylight, sleep_policy, away_policy,
     same_evening_under_load,
     device_never_answers,
     device_leaves_and_comes_back, gateway_leaves_and_comes_back, malformed_rules_file].

groups() ->
    [{holiday, [], [intrusion_email_with_photos, intrusion_narrated, evening_light_schedule]},
     {rooms, [], [room_hand_off, voice_override, no_room_light_before_dusk]}].

init_per_suite(Config) ->
    %% The applications the scenarios start (agent_bridge without its
    %% default listener, as config/test.config says) are stopped by them.
    Config.

end_per_suite(_Config) ->
    ok.

%% One evening, shared by the cases of the group.
init_per_group(holiday, Config) ->
    Spool = filename:join(?config(priv_dir, Config), "holiday-spool"),
    {ok, Outcome} = evatar_demo_holiday:run(#{speed => ?SPEED, spool => Spool}),
    [{outcome, Outcome}, {spool, Spool} | Config];
init_per_group(rooms, Config) ->
    Spool = filename:join(?config(priv_dir, Config), "rooms-spool"),
    %% Slower than the house alone: the hand-off is three VAs talking.
    {ok, S} = evatar_demo_rooms:start(#{speed => 1000, spool => Spool}),
    try
        ok = evatar_demo_rooms:run_until(S, "16:45"),
        [{outcome, evatar_demo_rooms:outcome(S)} | Config]
    after
        evatar_demo_rooms:stop(S)
    end.

end_per_group(_Group, _Config) ->
    ok.

init_per_testcase(_Case, Config) ->
    Config.

end_per_testcase(_Case, _Config) ->
    %% Nothing of a scenario may be left behind.
    ?assertEqual([], [Id || #{id := Id} <- pairings()]),
    ok.

pairings() ->
    case lists:keymember(evatar, 1, application:which_applications()) of
        true -> evatar:pairings();
        false -> []
    end.

%% ---------------------------------------------------------------------------
%% Holiday
%% ---------------------------------------------------------------------------

%% @doc The intruder's wrong code and motion in the hall make the house VA
%% take photos and write an e-mail "INTRUSION" with them attached: a real
%% MIME message in the spool, its PNG photos next to it.
intrusion_email_with_photos(Config) ->
    evatar_demo_holiday_checks:intrusion_email_with_photos(?config(outcome, Config),
                                                           ?config(spool, Config)).

%% @doc The story tells, in order, the perceived activities, the complex
%% activity, the decision of the policy and the actuations with their
%% outcomes (the alarm sounded, the message played).
intrusion_narrated(Config) ->
    _ = evatar_demo_holiday_checks:intrusion_narrated(?config(outcome, Config)),
    ok.

%% @doc The holiday policy switches the lights as scheduled in the rules
%% file, once each, and only those: each change at or after its time and
%% before the next scheduled time (the VA hears the time once a simulated
%% minute).
evening_light_schedule(Config) ->
    evatar_demo_holiday_checks:evening_light_schedule(?config(outcome, Config)).

%% @doc In June the sun sets after 21:00 in London: the 18:00 rule, which
%% asks for darkness, does nothing.
no_lights_in_daylight(Config) ->
    Spool = filename:join(?config(priv_dir, Config), "june"),
    {ok, #{home := #{light_log := Log}, va := #{mind := #{decisions := Decisions}}}} =
        evatar_demo_holiday:run(#{speed => ?SPEED, spool => Spool,
                                  start => {{2024, 6, 15}, {17, 55, 0}}, until => "18:10"}),
    ?assertEqual([], Log),
    ?assertEqual([], Decisions).

%% @doc The sleep policy at night: an intruder wakes the house (alarm,
%% every light on, a spoken warning, a text message), and motion in the hall
%% in the small hours is photographed.
sleep_policy(Config) ->
    Spool = filename:join(?config(priv_dir, Config), "sleep"),
    %% The intruder stays in the hall eight simulated minutes, at a quarter
    %% of the other cases' speed (about one real second); in lockstep each
    %% photo is taken at the tick the VA heard the motion that asked for it
    %% (before, a loaded machine took every photo of a one-minute stay at
    %% full speed after the intruder had gone).
    Script = [{{at, "02:00"}, <<"intruder">>, {go, <<"hall">>}},
              {{delay, 20000}, <<"intruder">>, {keypad, <<"1111">>}},
              {{at, "02:08"}, <<"intruder">>, {go, <<"outside">>}}],
    {ok, #{home := Home, va := #{mind := #{decisions := Decisions}}}} =
        evatar_demo_holiday:run(#{speed => ?SPEED div 4, spool => Spool, policy => <<"sleep">>,
                                  start => {{2024, 11, 16}, {1, 55, 0}}, until => "02:10",
                                  script => Script}),
    #{lights := Lights, sms := [#{text := <<"Intruder at home">>, file := SmsFile}],
      played := Played, photos := Photos, emails := []} = Home,
    ?assertEqual(#{<<"living">> => on, <<"kitchen">> => on, <<"bedroom">> => on}, Lights),
    ?assert(filelib:is_regular(SmsFile)),
    ?assertMatch([#{what := <<"alarm">>}, #{kind := voice}], [P || #{volume := V} = P <- Played, V > 0]),
    %% A photo for each report of motion in the hall (the first photo was
    %% the embodiment test's, of the empty hall).
    [#{people := []} | ByRule] = Photos,
    ?assertMatch([_ | _], ByRule),
    %% (The last may come just after the intruder left.)
    ?assertEqual([<<"hall">>], lists:usort([R || #{room := R} <- ByRule])),
    ?assertMatch([_ | _], [P || #{people := [<<"intruder">>]} = P <- ByRule]),
    Acted = [A || #{activity := A} <- Decisions],
    ?assertEqual(length(ByRule), length([A || A <- Acted, A =:= <<"motion">>])),
    ?assertEqual(1, length([A || A <- Acted, A =:= <<"intruder">>])).

%% @doc The away policy: the light for the return home at 17:45 when dark,
%% and on an intruder the photos, the e-mail with them and a text message.
away_policy(Config) ->
    Spool = filename:join(?config(priv_dir, Config), "away"),
    Script = [{{at, "17:50"}, <<"intruder">>, {keypad, <<"0000">>}},
              {{delay, 10000}, <<"intruder">>, {go, <<"hall">>}},
              {{delay, 60000}, <<"intruder">>, {go, <<"outside">>}}],
    {ok, #{home := Home}} =
        evatar_demo_holiday:run(#{speed => ?SPEED, spool => Spool, policy => <<"away">>,
                                  start => {{2024, 11, 15}, {17, 40, 0}}, until => "17:55",
                                  script => Script}),
    #{light_log := [#{room := <<"living">>, state := on}],
      emails := [#{subject := <<"INTRUSION">>, attachments := [_, _, _]}],
      sms := [#{text := <<"Intrusion at home: see your e-mail">>}]} = Home,
    ok.

%% @doc In lockstep an evening's outcome does not depend on the machine's
%% load: the intrusion and the 22:00 rule run twice, the second time with
%% every scheduler kept busy by spinning processes, and the story told
%% from 21:38 (what the VA perceived, decided and did, each stamped with
%% simulated time), the house's light changes, photos and sounds are the same.
same_evening_under_load(Config) ->
    Spool = filename:join(?config(priv_dir, Config), "load"),
    Idle = lockstep_evening(Spool),
    Spinners = [spawn(fun spin/0) || _ <- lists:seq(1, 2 * erlang:system_info(schedulers_online))],
    Busy = try lockstep_evening(Spool)
           after [exit(P, kill) || P <- Spinners]
           end,
    ct:log("~p", [Idle]),
    ?assertMatch(#{story := [_ | _], photos := [_ | _], played := [_ | _]}, Idle),
    ?assertEqual(Idle, Busy).

%% 21:35 to 22:05 in lockstep; what is compared from 21:38 on (the VA's
%% embodiment test, before, runs on real time).
lockstep_evening(Spool) ->
    _ = file:del_dir_r(Spool),
    {ok, O} = evatar_demo_holiday:run(#{speed => ?SPEED, spool => Spool,
                                        start => {{2024, 11, 15}, {21, 35, 0}}, until => "22:05"}),
    #{story := Story, home := #{light_log := Lights, photos := Photos, played := Played}} = O,
    From = fun(T) -> minute(T) >= "21:38" end,
    #{story => [{minute_second(T), Who, Kind, Text}
                || #{time := T, who := Who, kind := Kind, text := Text} <- Story, From(T)],
      lights => [{T, R, St} || #{time := T, room := R, state := St} <- Lights, From(T)],
      photos => [maps:without([file], P) || #{time := T} = P <- Photos, From(T)],
      played => [P || #{time := T} = P <- Played, From(T)]}.

spin() -> spin().

%% ---------------------------------------------------------------------------
%% Failures
%% ---------------------------------------------------------------------------

%% @doc The speaker swallows every request: the VA learns it from EVATAR's
%% Timeout feedback, says so, and the rest of the policy goes on (photos,
%% e-mail).
device_never_answers(Config) ->
    Spool = filename:join(?config(priv_dir, Config), "mute"),
    {ok, S} = evatar_demo_holiday:start(#{speed => ?SPEED, spool => Spool,
                                          start => {{2024, 11, 15}, {21, 35, 0}},
                                          feedback_timeout =>
                                              evatar_test_time:ms(500)}),
    try
        Home = evatar_demo_scenario:get(home, S),
        ok = avatar_sim:mute(Home, <<"HallSpeaker01">>),
        ok = evatar_demo_holiday:run_until(S, "21:45"),
        Va = evatar_demo_scenario:get(va, S),
        {ok, _} = evatar_demo_scenario:await(
                    fun() ->
                            #{mind := #{outcomes := Os}} = reference_agents:inspect(Va),
                            Failed = [W || #{what := W, result := {failed, _}} <- Os],
                            case lists:sort(Failed) =:= [alarm, say] of
                                true -> {true, Os};
                                false -> false
                            end
                    end, 10000, speaker_timeouts),
        #{mind := #{outcomes := Outcomes}} = reference_agents:inspect(Va),
        [<<"EVATAR Timeout", _/binary>>] =
            lists:usort([binary:part(W, 0, 14) || #{result := {failed, W}} <- Outcomes]),
        ?assertMatch([ok], [R || #{what := email, result := R} <- Outcomes]),
        #{emails := [#{attachments := [_, _, _]}], played := Played} = avatar_sim:state(Home),
        ?assertEqual([], [P || #{volume := V} = P <- Played, V > 0]),
        Story = reference_agents_narrator:events(evatar_demo_scenario:narrator(S)),
        ?assertMatch([_ | _], [T || #{text := T} <- Story,
                                    binary:match(T, <<"alarm FAILED: EVATAR Timeout">>) =/= nomatch])
    after
        evatar_demo_holiday:stop(S)
    end.

%% @doc The living room's light switch leaves the gateway: EVATAR rebinds,
%% the VA tests its body again and carries on without it (partial); the
%% 18:00 rule fails for that light only. When the switch comes back the VA
%% is embodied again and switches the light to what the policy wants.
device_leaves_and_comes_back(Config) ->
    live_evening(Config, "detach", fun detach_living_switch/4).

detach_living_switch(S, Home, Va, Clock) ->
    ok = avatar_sim:detach_device(Home, <<"LivingLightSwitch01">>),
    {ok, #{embodiment := #{failed := Failed}}} =
        await_verdict(Va, partial),
    ?assertMatch([_ | _], [E || {#{emulator := <<"LivingLightEmulator01">> = E}, _} <- Failed]),
    ok = avatar_sim:pause(Clock),
    ok = avatar_sim:set_speed(Clock, ?SPEED),
    ok = evatar_demo_holiday:run_until(S, "18:05"),
    #{mind := #{outcomes := Outcomes}} = reference_agents:inspect(Va),
    ?assertMatch([{failed, <<"TurnLightOn is not bound", _/binary>>}],
                 [R || #{tag := {light, <<"living">>, on, _}, result := R} <- Outcomes]),
    #{lights := #{<<"living">> := off}} = avatar_sim:state(Home),
    ok = avatar_sim:set_speed(Clock, 2),
    ok = avatar_sim:resume(Clock),
    ok = avatar_sim:attach_device(Home, <<"LivingLightSwitch01">>),
    {ok, _} = await_verdict(Va, embodied),
    {ok, _} = evatar_demo_scenario:await(
                fun() ->
                        case avatar_sim:state(Home) of
                            #{lights := #{<<"living">> := on}} -> {true, on};
                            _ -> false
                        end
                end, 10000, living_light_restored),
    #{states := States} = reference_agents:inspect(Va),
    ?assert(lists:suffix([testing, embodied, testing, embodied, testing, embodied],
                         dedupe([St || {St, _} <- States]))).

%% @doc The whole gateway loses its connection: the VA sees its body go
%% (observing) and, when the gateway is back, tests it and is embodied
%% again.
gateway_leaves_and_comes_back(Config) ->
    live_evening(Config, "gateway", fun disconnect_gateway/4).

disconnect_gateway(_S, Home, Va, _Clock) ->
    ok = avatar_sim:disconnect(Home, <<"easy-home-01">>),
    {ok, _} = evatar_demo_scenario:await_va_state(Va, [observing], 10000, observing),
    ok = avatar_sim:reconnect(Home, <<"easy-home-01">>),
    {ok, _} = await_verdict(Va, embodied),
    #{states := States} = reference_agents:inspect(Va),
    ?assert(lists:suffix([testing, embodied, observing, testing, embodied],
                         dedupe([St || {St, _} <- States]))).

%% @doc A rules file with a mistake is refused before anything runs, with
%% a message naming the file and the line.
malformed_rules_file(Config) ->
    File = filename:join(?config(priv_dir, Config), "bad.rules"),
    ok = file:write_file(File, <<"# a house\n"
                                 "simple motion when MotionDetected Motion=yes\n"
                                 "simple failed when PasswordInput WrongPassword=yes\n"
                                 "\n"
                                 "complex intruder when motion and failed within 2 min\n"
                                 "policy holiday on intruder do alarm\n"
                                 "policy holiday on intruder do explode\n">>),
    {error, {rules, Message}} = evatar_demo_holiday:start(
                                  #{rules => File, spool => ?config(priv_dir, Config)}),
    ct:log("~s", [Message]),
    Prefix = iolist_to_binary([File, ":7: unknown action explode"]),
    ?assertMatch(<<Prefix:(byte_size(Prefix))/binary, _/binary>>, Message),
    ?assertEqual([], pairings()).

%% ---------------------------------------------------------------------------
%% One VA per room
%% ---------------------------------------------------------------------------

%% @doc When the resident goes from one room to another after dusk, the new
%% room's VA switches its light on and tells the others; the old room's VA
%% checks for motion and switches its light off. The case checks what
%% caused what (each VA's log is in the order it decided and heard the
%% house's answers), which holds with the clock in lockstep or not, rather
%% than the house's timestamps of two VAs' switches.
room_hand_off(Config) ->
    #{home := #{light_log := Log}, vas := Vas} = ?config(outcome, Config),
    Changes = [{minute(T), R, S} || #{time := T, room := R, state := S} <- Log],
    ct:log("~p", [Changes]),
    %% 16:30 to the kitchen: its light goes on, and the living room's VA,
    %% told so, finds nobody there and switches its light off, which the
    %% house confirms; 16:33 back to the living room: the other way round.
    #{mind := #{log := LivingLog}} = maps:get(<<"living-va">>, Vas),
    #{mind := #{log := KitchenLog}} = maps:get(<<"kitchen-va">>, Vas),
    ct:log("~p~n~p", [LivingLog, KitchenLog]),
    ?assert(in_order([{handoff, <<"kitchen-va">>}, {light, off, {handoff, <<"kitchen-va">>}}],
                     [W || #{what := W} <- LivingLog])),
    ?assert(in_order([{handoff, <<"living-va">>}, {light, off, {handoff, <<"living-va">>}}],
                     [W || #{what := W} <- KitchenLog])),
    %% The house saw it: both switches happened after the move that caused them.
    ?assertMatch([_ | _], [C || {M, <<"kitchen">>, on} = C <- Changes, M >= "16:30"]),
    ?assertMatch([_ | _], [C || {M, <<"living">>, off} = C <- Changes, M >= "16:30"]),
    ?assertMatch([_ | _], [C || {M, <<"kitchen">>, off} = C <- Changes, M >= "16:33"]).

%% @doc "Keep the light off" keeps the living room dark when the resident
%% comes back; "lights automatic" gives the room back to the policy; "keep
%% the light on" keeps it on after the resident has left.
voice_override(Config) ->
    #{home := #{light_log := Log}, vas := Vas} = ?config(outcome, Config),
    Living = [{T, S} || #{time := T, room := <<"living">>, state := S} <- Log],
    #{mind := #{override := keep_on, light := on, log := VaLog}} = maps:get(<<"living-va">>, Vas),
    ct:log("~p~n~p", [Living, VaLog]),
    [KeepOff] = [T || #{what := {voice, keep_off}, time := T} <- VaLog],
    [Auto] = [T || #{what := {voice, none}, time := T} <- VaLog],
    [KeepOn] = [T || #{what := {voice, keep_on}, time := T} <- VaLog],
    ?assert(KeepOff < Auto andalso Auto < KeepOn),
    %% The house's changes from "keep the light off" on, in the order the
    %% house made them. A switch the VA decided before the command (motion
    %% just before) may land after the command's time when the clock is not
    %% in lockstep (the VAs react in real time); it lands before the
    %% command's own switch, which the VA sent after it. Then: switched off
    %% by the command, and not on again until "automatic", although the
    %% resident came back into the room meanwhile (the next "on" was decided
    %% after "automatic", so it lands after it); kept on after "keep the light
    %% on", never off, although the resident left for the kitchen and the
    %% bedroom.
    %% (The house logs changes only, so they alternate.)
    Since = [C || {T, _} = C <- Living, T >= KeepOff],
    ?assertMatch([{_, off}, {_, on}], without_late_on(Since)),
    [{_, off}, {OnAgain, on}] = without_late_on(Since),
    ?assert(OnAgain >= Auto),
    ?assert(lists:member({handoff_ignored, <<"kitchen-va">>}, [W || #{what := W} <- VaLog])).

%% @doc Before dusk (the resident comes home at 15:56) no room VA switches
%% a light on.
no_room_light_before_dusk(Config) ->
    #{home := #{light_log := Log}} = ?config(outcome, Config),
    ?assertEqual([], [L || #{time := T} = L <- Log, minute(T) < "16:05"]).

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

%% Runs Case(S, Home, Va, Clock) on a holiday evening whose clock runs at
%% twice real time, so that the VA sees each change to the house as it
%% happens; the scenario is stopped whatever the outcome.
live_evening(Config, Name, Case) ->
    Spool = filename:join(?config(priv_dir, Config), Name),
    {ok, S} = evatar_demo_holiday:start(#{speed => ?SPEED, spool => Spool}),
    try
        Home = evatar_demo_scenario:get(home, S),
        Va = evatar_demo_scenario:get(va, S),
        Clock = evatar_demo_scenario:get(clock, S),
        ok = avatar_sim:set_speed(Clock, 2),
        ok = avatar_sim:resume(Clock),
        Case(S, Home, Va, Clock)
    after
        evatar_demo_holiday:stop(S)
    end.

await_verdict(Va, Verdict) ->
    evatar_demo_scenario:await(
      fun() ->
              case reference_agents:inspect(Va) of
                  #{state := embodied, embodiment := #{verdict := Verdict}} = I -> {true, I};
                  _ -> false
              end
      end, 15000, {verdict, Verdict}).

minute(Ms) ->
    evatar_demo_holiday_checks:minute(Ms).

minute_second(Ms) -> lists:flatten(reference_agents_narrator:format_time(Ms)).

%% Whether Wanted appear in Whats in this order (others may come between).
in_order([], _Whats) -> true;
in_order([W | Wanted], [W | Whats]) -> in_order(Wanted, Whats);
in_order(Wanted, [_ | Whats]) -> in_order(Wanted, Whats);
in_order([_ | _], []) -> false.

%% The living room's changes since a voice command, without a first "on"
%% (decided before the command, landed after it).
without_late_on([{_, on} | Rest]) -> Rest;
without_late_on(Changes) -> Changes.

dedupe([A, A | Rest]) -> dedupe([A | Rest]);
dedupe([A | Rest]) -> [A | dedupe(Rest)];
dedupe([]) -> [].

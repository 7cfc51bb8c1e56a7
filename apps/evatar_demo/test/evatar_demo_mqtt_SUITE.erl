%% @doc The holiday scenario with the house's devices on MQTT: a real
%% mosquitto (started by the scenario, evatar_demo_broker), the
%% simulated devices found through Home Assistant discovery by the MQTT
%% Avatar, and the house VA unchanged. It must come to the same outcomes as
%% over TCP (evatar_demo_home_SUITE): the intrusion e-mail with its
%% photos in the spool, the evening light schedule, the alarm and the voice
%% message. Also `make demo DEMO_ARGS=mqtt' and the broker's own errors.
%% Skipped when mosquitto is not installed.
-module(evatar_demo_mqtt_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").

-export([all/0, groups/0, suite/0, init_per_suite/1, end_per_suite/1,
         init_per_group/2, end_per_group/2, init_per_testcase/2, end_per_testcase/2]).
-export([intrusion_email_with_photos/1, intrusion_narrated/1, evening_light_schedule/1,
         devices_discovered_on_mosquitto/1, broker_stopped_with_the_scenario/1,
         mqtt_demo/1, broker_not_installed/1, broker_that_cannot_run/1]).

-define(SPEED, 2000).
-define(APPS, [agent_bridge, evatar, avatar_sim, mqtt_avatar, mqtt_client]).
%% Every device of smart_home.xml but the notifier, which is a PC on TCP.
-define(MQTT_DEVICES, [<<"BedroomMotionSensor01">>, <<"BedroomSocketSwitch01">>,
                       <<"DoorKeypad01">>, <<"HallCamera01">>, <<"HallMotionSensor01">>,
                       <<"HallSpeaker01">>, <<"KitchenLightSwitch01">>,
                       <<"KitchenMotionSensor01">>, <<"LivingLightSwitch01">>,
                       <<"LivingMicrophone01">>, <<"LivingMotionSensor01">>,
                       <<"TimeSensor01">>]).

suite() -> [{timetrap, {seconds, 90}}].

all() ->
    [{group, holiday}, mqtt_demo, broker_not_installed, broker_that_cannot_run].

groups() ->
    [{holiday, [], [intrusion_email_with_photos, intrusion_narrated, evening_light_schedule,
                    devices_discovered_on_mosquitto, broker_stopped_with_the_scenario]}].

init_per_suite(Config) ->
    case evatar_demo_broker:executable() of
        false ->
            {skip, "mosquitto is not installed (Debian package mosquitto): "
                   "the MQTT scenario needs a real broker"};
        _ ->
            Loaded = [App || {App, _, _} <- application:loaded_applications()],
            [{loaded_before, [App || App <- ?APPS, lists:member(App, Loaded)]},
             {running_before, running()} | Config]
    end.

%% The suites that run after this one load the applications themselves.
end_per_suite(Config) ->
    _ = [application:unload(App) || App <- ?APPS,
                                    not lists:member(App, ?config(loaded_before, Config))],
    ok.

%% One evening over MQTT, shared by the cases of the group.
init_per_group(holiday, Config) ->
    Spool = filename:join(?config(priv_dir, Config), "mqtt-spool"),
    {ok, Outcome} = evatar_demo_holiday:run(#{speed => ?SPEED, spool => Spool, mqtt => true}),
    [{outcome, Outcome}, {spool, Spool} | Config].

end_per_group(_Group, _Config) ->
    ok.

init_per_testcase(_Case, Config) ->
    #{level := Level} = logger:get_primary_config(),
    [{logger_level, Level} | Config].

end_per_testcase(_Case, Config) ->
    %% Nothing of a scenario may be left behind: no application it started,
    %% no pairing (the VA's nor the MQTT home's private one).
    ?assertEqual([], running() -- ?config(running_before, Config)),
    ?assertEqual([], [Id || #{id := Id} <- pairings(),
                            Id =:= <<"home">> orelse binary:match(Id, <<"mqtt-hardware">>) =/= nomatch]),
    ok.

running() ->
    [A || {A, _, _} <- application:which_applications(), lists:member(A, ?APPS)].

pairings() ->
    case lists:keymember(evatar, 1, application:which_applications()) of
        true -> evatar:pairings();
        false -> []
    end.

%% ---------------------------------------------------------------------------
%% Holiday over MQTT
%% ---------------------------------------------------------------------------

%% @doc The intruder's wrong code at the MQTT keypad and motion at the MQTT
%% motion sensor make the house VA have the MQTT camera take 3 photos and
%% the notifier write the e-mail "INTRUSION" with them attached: a MIME
%% message in the spool, its PNG photos of the hall next to it.
intrusion_email_with_photos(Config) ->
    evatar_demo_holiday_checks:intrusion_email_with_photos(?config(outcome, Config),
                                                           ?config(spool, Config)).

%% @doc The story tells, in order, the activities perceived from MQTT
%% readings, the intruder, the policy's decision and the actuations with
%% their outcomes; the MQTT speaker sounded the alarm, then played the
%% message.
intrusion_narrated(Config) ->
    Texts = evatar_demo_holiday_checks:intrusion_narrated(?config(outcome, Config)),
    %% Nothing the VA asked of its MQTT body went unanswered.
    ?assertEqual([], [T || T <- Texts, binary:match(T, <<"FAILED">>) =/= nomatch]).

%% @doc The MQTT lights follow the holiday schedule of the rules file, once
%% each and only those, each change at or after its time and before the
%% next scheduled time, as over TCP.
evening_light_schedule(Config) ->
    evatar_demo_holiday_checks:evening_light_schedule(?config(outcome, Config)).

%% @doc The devices were MQTT devices: the MQTT Avatar discovered every
%% device of smart_home.xml but the notifier, without problems, and the
%% story says where the broker was and how many were discovered; the house
%% VA was fully embodied through them.
devices_discovered_on_mosquitto(Config) ->
    #{mqtt := #{host := "127.0.0.1", port := Port},
      mqtt_avatar := #{status := #{components := Components}, problems := Problems},
      story := Story, va := #{embodiment := #{verdict := Verdict}}} = ?config(outcome, Config),
    ?assertEqual(?MQTT_DEVICES, lists:sort(Components)),
    ?assertEqual([], [P || #{what := W} = P <- Problems, W =/= unused_override]),
    ?assertEqual(embodied, Verdict),
    Said = iolist_to_binary([T || #{who := <<"scenario">>, text := T} <- Story]),
    Where = iolist_to_binary(io_lib:format("devices are on mosquitto at 127.0.0.1:~b", [Port])),
    ?assertNotEqual(nomatch, binary:match(Said, Where)),
    ?assertNotEqual(nomatch, binary:match(Said, <<"discovered 12 of them through Home Assistant">>)).

%% @doc The scenario's mosquitto is gone once the scenario is over: its
%% port refuses connections.
broker_stopped_with_the_scenario(Config) ->
    #{mqtt := #{port := Port}} = ?config(outcome, Config),
    ?assertMatch({error, econnrefused}, gen_tcp:connect({127, 0, 0, 1}, Port, [], 2000)).

%% ---------------------------------------------------------------------------
%% The demo and the broker
%% ---------------------------------------------------------------------------

%% @doc `make demo DEMO_ARGS=mqtt' returns ok, narrates where the devices
%% are and how many were discovered, then the holiday evening, and ends
%% with where the e-mail and its photos landed.
mqtt_demo(Config) ->
    {ok, Output} = evatar_demo_capture:run(["mqtt"]),
    ct:log("~ts", [Output]),
    Patterns = ["scenario +the easy smart home's 12 devices are on mosquitto at 127\\.0\\.0\\.1:[0-9]+; "
                "the MQTT Avatar easy-home-mqtt discovered 12 of them through Home Assistant discovery",
                "house-va +PERCEIVE +EVATAR bound 18 of its consumer entries \\(0 unbound\\)",
                "DECIDE +embodiment test: embodied",
                "\\[18:0[0-9]:[0-9]{2}\\] house-va +DECIDE +policy holiday at 18:00 if dark do light living on",
                "\\[21:4[0-9]:[0-9]{2}\\] house-va +PERCEIVE +activity failed_authorisation in hall",
                "PERCEIVE +complex activity intruder in hall",
                "ACT +take 3 photos \\(TakePhoto via CameraEmulator01\\)",
                "ACT +sound the alarm",
                "PERCEIVE +e-mail written to .*/spool/[0-9]{8}-[0-9]{6}-[0-9]+\\.eml \\(3 attachment",
                "broker: mosquitto at 127\\.0\\.0\\.1:[0-9]+, started for the demo and stopped with it",
                "MQTT Avatar: 12 components discovered",
                "e-mail \"INTRUSION\": /.*\\.eml\n    attached photo-[0-9]{4}\\.png: /.*/spool/photos/photo-[0-9]{4}\\.png"],
    ?assertEqual([], [P || P <- Patterns, re:run(Output, P) =:= nomatch]),
    %% It ends with where everything landed.
    {Mqtt, _} = binary:match(Output, <<"The MQTT side">>),
    {Landed, _} = binary:match(Output, <<"Where it all landed">>),
    ?assert(Mqtt < Landed),
    ?assertEqual(?config(logger_level, Config), maps:get(level, logger:get_primary_config())).

%% @doc Without mosquitto the broker says so, with the package to install.
broker_not_installed(_Config) ->
    {error, Message} = evatar_demo_broker:start_link(#{executable => false}),
    ?assertNotEqual(nomatch, binary:match(Message, <<"mosquitto is not installed">>)),
    ?assertNotEqual(nomatch, binary:match(Message, <<"apt-get install mosquitto">>)).

%% @doc A mosquitto that cannot run gives an error quoting what went wrong
%% and leaves no process and no directory behind.
broker_that_cannot_run(Config) ->
    Before = filelib:wildcard(filename:join(tmp(), "evatar-mosquitto-*")),
    Bogus = filename:join(?config(priv_dir, Config), "no-such-mosquitto"),
    {error, Message} = evatar_demo_broker:start_link(#{executable => Bogus}),
    ct:log("~ts", [Message]),
    ?assertNotEqual(nomatch, binary:match(Message, <<"mosquitto exited at once">>)),
    ?assertNotEqual(nomatch, binary:match(Message, list_to_binary(Bogus))),
    ?assertEqual(Before, filelib:wildcard(filename:join(tmp(), "evatar-mosquitto-*"))),
    ?assertEqual([], [P || P <- processes(),
                           {initial_call, {evatar_demo_broker, init, 1}}
                               =:= erlang:process_info(P, initial_call)]).

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

tmp() ->
    case os:getenv("TMPDIR") of
        false -> "/tmp";
        "" -> "/tmp";
        T -> T
    end.

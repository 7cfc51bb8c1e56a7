%% Common Test suite of avatar_sim_mqtt_kind, without a broker: the MQTT
%% face of each simulated device, and the translations between its
%% messages and BIL requests, answers and readings.
-module(avatar_sim_mqtt_kind_SUITE).

-include_lib("stdlib/include/assert.hrl").

-compile([export_all, nowarn_export_all]).

suite() -> [{timetrap, {minutes, 1}}].

all() -> [every_device_has_a_face, names, commands, push].

ctx() -> #{prefix => <<"sim">>, discovery_prefix => <<"ha">>}.

components() ->
    {ok, Xml} = file:read_file(filename:join([code:priv_dir(bil), "examples", "smart_home.xml"])),
    {ok, #{components := C}} = bil:parse_description(Xml),
    C.

%% Every device of smart_home.xml but the notifier has a kind, and the
%% discovery it publishes generates a component with the same ComponentID.
every_device_has_a_face(_Config) ->
    Kinds = [{Id, avatar_sim_mqtt_kind:kind(C)} || #{id := Id} = C <- components()],
    ?assertEqual([<<"Notifier01">>], [Id || {Id, none} <- Kinds]),
    Devices = [avatar_sim_mqtt_kind:device(C, K, ctx())
               || C <- components(), K <- [avatar_sim_mqtt_kind:kind(C)], K =/= none],
    Messages = [{T, evatar_json:encode(J)}
                || #{discovery := Ds} <- Devices, {T, J} <- Ds],
    {D, Problems} = mqtt_avatar:generate(Messages,
                                         #{discovery => #{homeassistant => <<"ha">>},
                                           overrides => avatar_sim_mqtt_kind:overrides(Devices, ctx())}),
    ?assertEqual([], Problems),
    ?assertEqual(lists:sort([Id || {Id, K} <- Kinds, K =/= none]),
                 lists:sort([Id || #{id := Id} <- maps:get(components, D)])),
    ?assertEqual(ok, mqtt_avatar:check(D)).

%% Device names are the ComponentIDs in words; nodes in snake case.
names(_Config) ->
    ?assertEqual(<<"Hall Motion Sensor 01">>, avatar_sim_mqtt_kind:device_name(<<"HallMotionSensor01">>)),
    ?assertEqual(<<"hall_motion_sensor_01">>, avatar_sim_mqtt_kind:node_name(<<"HallMotionSensor01">>)),
    ?assertEqual(<<"Time Sensor 01">>, avatar_sim_mqtt_kind:device_name(<<"TimeSensor01">>)).

%% Commands as Home Assistant, zigbee2mqtt and Tasmota send them.
commands(_Config) ->
    C = ctx(),
    ?assertEqual({request, <<"TurnLightOn">>, []},
                 avatar_sim_mqtt_kind:command(light, <<"sim/x/set">>, <<"{\"state\":\"ON\"}">>, C)),
    ?assertMatch({error, _}, avatar_sim_mqtt_kind:command(light, <<"sim/x/set">>, <<"ON">>, C)),
    ?assertEqual({request, <<"SwitchSocketOff">>, []},
                 avatar_sim_mqtt_kind:command(socket, <<"cmnd/x/POWER">>, <<"off">>, C)),
    ?assertEqual({request, <<"TakePhoto">>, [{<<"Count">>, <<"3">>}]},
                 avatar_sim_mqtt_kind:command(camera, <<"t">>, <<"{\"count\":3}">>, C)),
    ?assertEqual({request, <<"PlaySound">>, [{<<"Sound">>, <<"chime">>}, {<<"Volume">>, <<"0">>}]},
                 avatar_sim_mqtt_kind:command(speaker, <<"sim/s/sound/set">>,
                                              <<"{\"state\":\"ON\",\"tone\":\"chime\",\"volume_level\":0}">>, C)),
    ?assertEqual({request, <<"PlayVoiceMessage">>, [{<<"Message">>, <<"hello">>}]},
                 avatar_sim_mqtt_kind:command(speaker, <<"sim/s/voice/set">>, <<"hello">>, C)),
    ?assertEqual({request, <<"ListenForCommands">>, [{<<"Listen">>, <<"no">>}]},
                 avatar_sim_mqtt_kind:command(microphone, <<"sim/m/listen/set">>, <<"no">>, C)),
    ?assertMatch({error, _}, avatar_sim_mqtt_kind:command(keypad, <<"t">>, <<"x">>, C)).

%% Readings become JSON states: yes/no as booleans, numbers as numbers,
%% names in snake case, with the simulated time.
push(_Config) ->
    Ctx = (avatar_sim_mqtt_kind:topics(<<"HallMotionSensor01">>, ctx()))#{ts => 42},
    [{<<"sim/hall_motion_sensor_01/state">>, Json, true}] =
        avatar_sim_mqtt_kind:push(motion, <<"MotionDetected">>,
                                  [{<<"Motion">>, <<"yes">>}, {<<"Room">>, <<"hall">>},
                                   {<<"People">>, <<"2">>}], Ctx),
    ?assertEqual({ok, #{<<"motion">> => true, <<"people">> => 2, <<"ts">> => 42}},
                 evatar_json:decode(Json)),
    TCtx = (avatar_sim_mqtt_kind:topics(<<"TimeSensor01">>, ctx()))#{ts => 1},
    [{_, TJson, true}] = avatar_sim_mqtt_kind:push(time, <<"TimeOfDay">>,
                                                   [{<<"TimeOfDay">>, <<"21:00">>},
                                                    {<<"Dark">>, <<"yes">>}], TCtx),
    ?assertEqual({ok, #{<<"time_of_day">> => <<"21:00">>, <<"dark">> => true, <<"ts">> => 1}},
                 evatar_json:decode(TJson)).

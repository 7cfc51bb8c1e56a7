%% Common Test suite of the MQTT Avatar against a real mosquitto (started
%% by evatar_test_mosquitto on a free loopback port), a real EVATAR pairing behind a
%% real agent_bridge listener (port 0), test devices that are real MQTT
%% clients, and a test VA joined with agent_bridge_client.
-module(mqtt_avatar_SUITE).

-include_lib("stdlib/include/assert.hrl").

-import(mqtt_avatar_test_setup, [light_device/1, test_va/1, mqtt/1, request/4, provider_of/3,
                                 consumer_of/3, entry/3]).
-import(evatar_test_wait, [until/1]).

-define(LIVE_LISTENER, mqtt_avatar_suite).
-define(LIVE_CASE_PREFIX, "").
-define(LIVE_FEEDBACK_MS, 1500).
-import(mqtt_avatar_test_setup, [param/2]).
-include("mqtt_avatar_live_suite.hrl").

all() ->
    [{group, round_trip}, {group, streams}, {group, failures}].

groups() ->
    [{round_trip, [], [discovery_to_feedback, hand_written_description, zigbee2mqtt_device]},
     {streams, [], [sensor_stream, retained_state_on_join]},
     {failures, [], [no_echo_times_out, device_offline_and_back, malformed_inputs,
                     broker_restart]}].

%% ---------------------------------------------------------------------------
%% Round trips
%% ---------------------------------------------------------------------------

%% An HA-discovered light joins, binds to the VA's light emulator, and a
%% TurnLightOn request becomes a publish on .../set whose state echo is
%% the VA's feedback; EVATAR never sees the Mqtt* parameters.
discovery_to_feedback(Config) ->
    Dev = light_device(Config),
    A = avatar(Config, #{}),
    Va = test_va(Config),
    Comp = provider_of(Va, <<"LightEmulator01">>, <<"TurnLightOn">>),
    <<"KitchenLight01">> = Comp,
    {ok, F} = agent_bridge_client:request(Va, request(<<"LightEmulator01">>, Comp,
                                                      <<"TurnLightOn">>, []), 5000),
    #{context := feedback, sender := Comp,
      body := #{category := <<"ACTUATOR">>, type := <<"ACTION FEEDBACK">>, parameters := Ps}} = F,
    <<"TurnLightOn">> = param(<<"Service">>, Ps),
    <<"done">> = param(<<"Result">>, Ps),
    <<"on">> = param(<<"Light">>, Ps),
    <<"kitchen">> = param(<<"Room">>, Ps),
    <<"yes">> = param(<<"Changed">>, Ps),
    [{_, Cmd}] = mqtt_avatar_test_device:commands(Dev),
    {ok, #{<<"state">> := <<"ON">>}} = evatar_json:decode(Cmd),
    {ok, Registry} = evatar:registry(?config(pairing, Config)),
    [#{description := Public}] = [E || #{role := avatar} = E <- Registry],
    [] = [N || #{services := S, consumes := C} <- maps:get(components, Public),
               #{parameters := P} <- S ++ C, {<<"Mqtt", _/binary>> = N, _} <- P],
    %% The generated description is valid and passes the checks.
    ok = mqtt_avatar:check(mqtt_avatar:description(A)).

%% A hand-written BIL description with Mqtt* parameters (no discovery):
%% a raw ON/OFF device in the Tasmota style (cmnd/.../POWER, stat/.../POWER).
hand_written_description(Config) ->
    P = ?config(prefix, Config),
    Reply = fun(_T, Payload) -> [{<<"stat/", P/binary, "/POWER">>, Payload, false}] end,
    {ok, Dev} = mqtt_avatar_test_device:start(port(Config),
                                              #{commands => [<<"cmnd/", P/binary, "/POWER">>],
                                                reply => Reply}),
    remember(devices, Dev),
    Xml = iolist_to_binary(
            ["<bil:description xmlns:bil=\"urn:evatar:bil:1\"><bil:context>"
             "<EntityID>tasmota-home</EntityID><APIName>MQTT</APIName><EntityType>Avatar</EntityType>"
             "<Context>x</Context></bil:context><bil:types><bil:Component>"
             "<ComponentID>Plug01</ComponentID>"
             "<Service><ServiceCategory>ACTUATOR</ServiceCategory><ServiceType>TurnLightOn</ServiceType>"
             "<ServiceParameters><Light>yes</Light><Room>kitchen</Room>"
             "<MqttCommandTopic>cmnd/", P, "/POWER</MqttCommandTopic>"
             "<MqttStateTopic>stat/", P, "/POWER</MqttStateTopic>"
             "<MqttCommand>raw:ON</MqttCommand><MqttExpect>raw:ON</MqttExpect>"
             "<MqttValue>Light=raw</MqttValue><MqttMap>ON=on OFF=off</MqttMap>"
             "</ServiceParameters></Service>"
             "<Consumes><ServiceCategory>ACTUATOR</ServiceCategory><ServiceType>ACTION FEEDBACK</ServiceType>"
             "<ServiceParameters><Feedback>yes</Feedback><Room>kitchen</Room></ServiceParameters></Consumes>"
             "</bil:Component></bil:types></bil:description>"]),
    _A = avatar(Config, #{entity_id => <<"tasmota-home">>, description => Xml, discovery => false}),
    Va = test_va(Config),
    <<"Plug01">> = provider_of(Va, <<"LightEmulator01">>, <<"TurnLightOn">>),
    {ok, #{context := feedback, body := #{parameters := Ps}}} =
        agent_bridge_client:request(Va, request(<<"LightEmulator01">>, <<"Plug01">>,
                                                <<"TurnLightOn">>, []), 5000),
    <<"on">> = param(<<"Light">>, Ps),
    [{_, <<"ON">>}] = mqtt_avatar_test_device:commands(Dev),
    %% A description with a broken Mqtt* parameter is refused at start,
    %% with the component, entry and parameter named.
    Bad = binary:replace(Xml, <<"<MqttExpect>raw:ON</MqttExpect>">>,
                         <<"<MqttExpect>sometimes</MqttExpect><MqttStatTopic>x</MqttStatTopic>">>),
    {error, Problems} = mqtt_avatar:start(#{entity_id => <<"tasmota-home">>, description => Bad,
                                            mqtt => mqtt(Config)}),
    [<<"MqttExpect">>, <<"MqttStatTopic">>] = lists:sort([maps:get(parameter, X) || X <- Problems]).

%% zigbee2mqtt's retained bridge/devices list is enough for a motion
%% sensor to join and push its occupancy as MotionDetected events.
zigbee2mqtt_device(Config) ->
    P = ?config(prefix, Config),
    Base = <<"z2m_", P/binary>>,
    Devices = evatar_json:encode(
                [#{<<"type">> => <<"Coordinator">>, <<"friendly_name">> => <<"Coordinator">>},
                 #{<<"type">> => <<"EndDevice">>, <<"friendly_name">> => <<"hall_pir">>,
                   <<"ieee_address">> => <<"0x00158d0001a2b3c4">>,
                   <<"definition">> =>
                       #{<<"model">> => <<"RTCGQ11LM">>, <<"vendor">> => <<"Aqara">>,
                         <<"description">> => <<"Motion sensor">>,
                         <<"exposes">> =>
                             [#{<<"type">> => <<"binary">>, <<"name">> => <<"occupancy">>,
                                <<"property">> => <<"occupancy">>, <<"access">> => 1,
                                <<"value_on">> => true, <<"value_off">> => false},
                              #{<<"type">> => <<"numeric">>, <<"name">> => <<"battery">>,
                                <<"property">> => <<"battery">>, <<"access">> => 1,
                                <<"unit">> => <<"%">>}]}}]),
    {ok, Dev} = mqtt_avatar_test_device:start(port(Config), #{}),
    remember(devices, Dev),
    ok = mqtt_avatar_test_device:publish(Dev, <<Base/binary, "/bridge/devices">>, Devices, true),
    _A = avatar(Config, #{discovery => #{homeassistant => false, zigbee2mqtt => Base},
                          overrides => #{<<"0x00158d0001a2b3c4">> => #{room => <<"hall">>}}}),
    %% (an override names a device by its IEEE address, `z2m:' prefix optional)
    Va = test_va(Config),
    Comp = consumer_of(Va, <<"MotionEmulator01">>, <<"MotionDetected">>),
    <<"HallPir">> = Comp,
    ok = mqtt_avatar_test_device:publish(Dev, <<Base/binary, "/hall_pir">>,
                                         <<"{\"occupancy\":true,\"battery\":91}">>, false),
    #{context := event, sender := Comp, body := #{type := <<"MotionDetected">>, parameters := Ps}} =
        wait_signal(Va, fun(#{body := #{type := T}}) -> T =:= <<"MotionDetected">> end),
    <<"yes">> = param(<<"Motion">>, Ps),
    <<"hall">> = param(<<"Room">>, Ps).

%% ---------------------------------------------------------------------------
%% Streams
%% ---------------------------------------------------------------------------

%% Readings published by a sensor reach the VA's emulator as SensorData,
%% every one, in order; motion arrives as an Event.
sensor_stream(Config) ->
    Dev = hall_device(Config),
    A = avatar(Config, #{}),
    Va = test_va(Config),
    Comp = consumer_of(Va, <<"TempEmulator01">>, <<"Temperature">>),
    %% Readings before the Avatar has its own Binding report would reach the
    %% VA as the last one only (a new partner learns the current reading).
    ok = ?SETUP:wait_partner(A, Comp, <<"TempEmulator01">>),
    P = ?config(prefix, Config),
    N = 25,
    [ok = mqtt_avatar_test_device:publish(Dev, <<P/binary, "/hall/temperature">>,
                                          iolist_to_binary(["{\"temperature\": ", integer_to_list(I),
                                                            ".5}"]), false)
     || I <- lists:seq(1, N)],
    Readings = [begin
                    #{context := sensor_data, sender := Comp,
                      body := #{type := <<"Temperature">>, parameters := Ps}} =
                        wait_signal(Va, fun(#{body := #{type := T}}) -> T =:= <<"Temperature">> end),
                    param(<<"Temperature">>, Ps)
                end || _ <- lists:seq(1, N)],
    Expected = [iolist_to_binary([integer_to_list(I), ".5"]) || I <- lists:seq(1, N)],
    Expected = Readings,
    ok = mqtt_avatar_test_device:publish(Dev, <<P/binary, "/hall/motion">>,
                                         <<"{\"occupancy\":true,\"people\":2}">>, false),
    #{context := event, body := #{parameters := MPs}} =
        wait_signal(Va, fun(#{body := #{type := T}}) -> T =:= <<"MotionDetected">> end),
    <<"yes">> = param(<<"Motion">>, MPs),
    <<"2">> = param(<<"People">>, MPs),
    <<"hall">> = param(<<"Room">>, MPs).

%% A retained state published before the Avatar existed reaches the VA
%% once it is bound, and answers the sensor's read service.
retained_state_on_join(Config) ->
    Dev = hall_device(Config),
    P = ?config(prefix, Config),
    ok = mqtt_avatar_test_device:publish(Dev, <<P/binary, "/hall/motion">>,
                                         <<"{\"occupancy\":true,\"people\":1}">>, true),
    _A = avatar(Config, #{}),
    Va = test_va(Config),
    #{context := event, sender := Comp, body := #{parameters := Ps}} =
        wait_signal(Va, fun(#{body := #{type := T}}) -> T =:= <<"MotionDetected">> end),
    <<"yes">> = param(<<"Motion">>, Ps),
    Comp = provider_of(Va, <<"MotionEmulator01">>, <<"ReadMotion">>),
    {ok, #{context := feedback, body := #{type := <<"MotionDetected">>, parameters := RPs}}} =
        agent_bridge_client:request(Va, #{sender => <<"MotionEmulator01">>, receiver => Comp,
                                          body => entry(<<"SENSOR">>, <<"ReadMotion">>, [])}, 5000),
    <<"yes">> = param(<<"Motion">>, RPs),
    <<"done">> = param(<<"Result">>, RPs).

%% ---------------------------------------------------------------------------
%% Failures
%% ---------------------------------------------------------------------------

%% A device that does not echo: EVATAR's Timeout feedback reaches the VA,
%% and the Avatar reports the missing echo.
no_echo_times_out(Config) ->
    Dev = light_device(Config),
    A = avatar(Config, #{echo_timeout => 1000}),
    Va = test_va(Config),
    Comp = provider_of(Va, <<"LightEmulator01">>, <<"TurnLightOn">>),
    ok = mqtt_avatar_test_device:mute(Dev, true),
    {ok, #{sender := <<"EVATAR">>, body := #{category := <<"EVATAR">>, type := <<"Timeout">>}}} =
        agent_bridge_client:request(Va, request(<<"LightEmulator01">>, Comp,
                                                <<"TurnLightOn">>, []), 5000),
    [_] = mqtt_avatar_test_device:commands(Dev),
    ok = until(fun() ->
                       lists:any(fun(#{what := W}) -> W =:= no_state_echo end,
                                 mqtt_avatar:problems(A))
               end).

%% A device whose connection dies: the broker's last will says offline,
%% the VA gets DeviceDisconnected, requests fail at once with
%% DeviceUnavailable; back online, DeviceReconnected, and requests work.
device_offline_and_back(Config) ->
    Dev = light_device(Config),
    _A = avatar(Config, #{}),
    Va = test_va(Config),
    Comp = provider_of(Va, <<"LightEmulator01">>, <<"TurnLightOn">>),
    ok = mqtt_avatar_test_device:crash(Dev),
    #{context := event, sender := Comp, receiver := <<"LightEmulator01">>,
      body := #{category := <<"EVENT">>, type := <<"DeviceDisconnected">>, parameters := Ps}} =
        wait_signal(Va, fun(#{context := C}) -> C =:= event end),
    <<"offline">> = param(<<"Availability">>, Ps),
    <<"kitchen">> = param(<<"Room">>, Ps),
    {error, #{body := #{category := <<"ERROR">>, type := <<"DeviceUnavailable">>}}} =
        agent_bridge_client:request(Va, request(<<"LightEmulator01">>, Comp,
                                                <<"TurnLightOn">>, []), 5000),
    ok = mqtt_avatar_test_device:revive(Dev),
    #{body := #{type := <<"DeviceReconnected">>, parameters := RPs}} =
        wait_signal(Va, fun(#{context := C}) -> C =:= event end),
    <<"online">> = param(<<"Availability">>, RPs),
    _ = binary_to_integer(param(<<"OfflineSeconds">>, RPs)),
    {ok, #{context := feedback, sender := Comp, body := #{parameters := Ps2}}} =
        agent_bridge_client:request(Va, request(<<"LightEmulator01">>, Comp,
                                                <<"TurnLightOff">>, []), 5000),
    <<"off">> = param(<<"Light">>, Ps2).

%% Malformed payloads and discovery messages are reported (through the
%% API and the log) with their topic and a reason; nothing reaches the VA
%% for them and the Avatar keeps working.
malformed_inputs(Config) ->
    P = ?config(prefix, Config),
    Dev = hall_device(Config),
    Light = light_device(Config),
    A = avatar(Config, #{}),
    Va = test_va(Config),
    Comp = provider_of(Va, <<"LightEmulator01">>, <<"TurnLightOn">>),
    Ha = <<"ha_", P/binary>>,
    Bad = [{<<P/binary, "/hall/temperature">>, <<"{\"temperature\": ">>},
           {<<P/binary, "/hall/temperature">>, <<"{\"temperature\": \"", 255, "\"}">>},
           {<<P/binary, "/hall/temperature">>, <<255, 254>>},
           {<<P/binary, "/light/availability">>, <<"maybe">>},
           {<<Ha/binary, "/sensor/x/broken/config">>, <<"{\"name\": ">>},
           {<<Ha/binary, "/sensor/x/nostate/config">>, <<"{\"name\": \"No state\"}">>},
           {<<Ha/binary, "/light/x/wild/config">>,
            <<"{\"name\": \"Wild\", \"command_topic\": \"a/#\"}">>},
           {<<Ha/binary, "/sensor/x/tpl/config">>,
            <<"{\"name\": \"Tpl\", \"state_topic\": \"t\", \"value_template\": "
              "\"{% for x in value %}1{% endfor %}\"}">>},
           {<<Ha/binary, "/sensor/x/array/config">>, <<"[1, 2]">>},
           {<<Ha/binary, "/vacuum/x/robot/config">>, <<"{}">>}],
    [ok = mqtt_avatar_test_device:publish(Dev, T, Pl, false) || {T, Pl} <- Bad],
    %% (Three bad payloads on one topic in a row are one problem: a broken
    %% device cannot flood the log.)
    BadTopics = lists:usort([T || {T, _} <- Bad]),
    ok = until(fun() ->
                       [] =:= BadTopics -- [maps:get(topic, X) || X <- mqtt_avatar:problems(A),
                                                                  is_map_key(topic, X)]
               end),
    Problems = mqtt_avatar:problems(A),
    ct:pal("~p", [Problems]),
    Topics = lists:usort([maps:get(topic, X) || X <- Problems, is_map_key(topic, X)]),
    [] = lists:usort([T || {T, _} <- Bad]) -- Topics,
    true = lists:all(fun(#{message := M}) -> is_binary(M) andalso M =/= <<>> end, Problems),
    Whats = lists:usort([W || #{what := W} <- Problems]),
    [bad_availability, bad_discovery, bad_payload] = Whats -- [unused_override],
    %% Still working, and the VA saw none of it: the Avatar had handled the
    %% bad payloads (their problems are listed) before it answered, and what
    %% it sent before the feedback reached the VA before it.
    {ok, #{context := feedback, sender := Comp}} =
        agent_bridge_client:request(Va, request(<<"LightEmulator01">>, Comp,
                                                <<"TurnLightOn">>, []), 5000),
    [] = evatar_test_wait:mailbox(
           fun({agent_bridge, V, {signal, #{body := #{type := <<"Temperature">>}}}}) -> V =:= Va;
              (_) -> false
           end),
    _ = Light,
    true = is_process_alive(A).

%% The broker restarts: while it is away requests fail with
%% BrokerUnavailable; then the Avatar reconnects, resubscribes, picks up a
%% retained state and round trips work again. (The light is switched off
%% cleanly for the restart, so the broker has no will of its to publish
%% and the light's availability stays as it was.)
broker_restart(Config) ->
    {ok, Broker} = evatar_test_mosquitto:start(#{persistence => true}),
    Config1 = [{broker, Broker} | Config],
    P = ?config(prefix, Config),
    Light = light_device(Config1),
    Hall = hall_device(Config1),
    A = avatar(Config1, #{}),
    Va = test_va(Config1),
    Comp = provider_of(Va, <<"LightEmulator01">>, <<"TurnLightOn">>),
    {ok, _} = agent_bridge_client:request(Va, request(<<"LightEmulator01">>, Comp,
                                                      <<"TurnLightOn">>, []), 5000),
    Subscriptions = maps:get(subscriptions, mqtt_avatar:status(A)),
    ok = mqtt_avatar_test_device:stop(Light),
    ok = evatar_test_mosquitto:kill(Broker, term),
    ok = until(fun() -> maps:get(mqtt, mqtt_avatar:status(A)) =:= down end),
    {error, #{body := #{type := <<"BrokerUnavailable">>}}} =
        agent_bridge_client:request(Va, request(<<"LightEmulator01">>, Comp,
                                                <<"TurnLightOff">>, []), 5000),
    {ok, Broker2} = evatar_test_mosquitto:start(maps:get(opts, Broker)),
    try
        ok = until(fun() -> maps:get(mqtt, mqtt_avatar:status(A)) =:= up end),
        Subscriptions = maps:get(subscriptions, mqtt_avatar:status(A)),
        %% A state made retained now is delivered live or on resubscription.
        ok = mqtt_avatar_test_device:publish(Hall, <<P/binary, "/hall/motion">>,
                                             <<"{\"occupancy\":true,\"people\":3}">>, true),
        #{body := #{parameters := Ps}} =
            wait_signal(Va, fun(#{body := #{type := T}}) -> T =:= <<"MotionDetected">> end),
        <<"3">> = param(<<"People">>, Ps),
        _Light2 = light_device(Config1),
        {ok, #{context := feedback, body := #{parameters := FPs}}} =
            agent_bridge_client:request(Va, request(<<"LightEmulator01">>, Comp,
                                                    <<"TurnLightOff">>, []), 5000),
        <<"off">> = param(<<"Light">>, FPs),
        true = is_process_alive(A)
    after
        ok = evatar_test_mosquitto:stop(Broker2)
    end.

%% ---------------------------------------------------------------------------
%% Devices
%% ---------------------------------------------------------------------------

%% A camera with motion detection and a thermometer in the hall.
hall_device(Config) ->
    P = ?config(prefix, Config),
    Dev = #{<<"identifiers">> => <<P/binary, "-hall">>, <<"name">> => <<"Hall Sensor 01">>,
            <<"suggested_area">> => <<"Hall">>, <<"model">> => <<"Multisensor">>},
    Motion = #{<<"name">> => <<"Motion">>, <<"unique_id">> => <<P/binary, "-motion">>,
               <<"device_class">> => <<"motion">>, <<"state_topic">> => <<P/binary, "/hall/motion">>,
               <<"json_attributes_topic">> => <<P/binary, "/hall/motion">>,
               <<"value_template">> => <<"{{ value_json.occupancy }}">>,
               <<"payload_on">> => true, <<"payload_off">> => false, <<"device">> => Dev},
    Temp = #{<<"name">> => <<"Temperature">>, <<"unique_id">> => <<P/binary, "-temp">>,
             <<"device_class">> => <<"temperature">>, <<"unit_of_measurement">> => <<"°C"/utf8>>,
             <<"state_topic">> => <<P/binary, "/hall/temperature">>,
             <<"value_template">> => <<"{{ value_json.temperature | float }}">>, <<"device">> => Dev},
    Ha = <<"ha_", P/binary>>,
    {ok, D} = mqtt_avatar_test_device:start(
                port(Config),
                #{discovery => [{<<Ha/binary, "/binary_sensor/", P/binary, "/motion/config">>,
                                 evatar_json:encode(Motion)},
                                {<<Ha/binary, "/sensor/", P/binary, "/temp/config">>,
                                 evatar_json:encode(Temp)}]}),
    remember(devices, D),
    D.

%% ---------------------------------------------------------------------------
%% Avatar and VA
%% ---------------------------------------------------------------------------

avatar(Config, Extra) ->
    ?SETUP:avatar(Config, <<"mqtt-home">>, Extra).

port(Config) ->
    ?SETUP:broker_port(Config).

wait_signal(Va, Pred) ->
    %% Generous: the machine running the tests may be busy (25 readings).
    evatar_test_fixtures:wait_signal(Va, Pred, evatar_test_time:guard()).


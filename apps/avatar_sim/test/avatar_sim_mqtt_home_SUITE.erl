%% Common Test suite of the smart home over MQTT: a real mosquitto, the
%% simulated devices publishing Home Assistant discovery, the MQTT Avatar
%% discovering them and joining EVATAR through a real bridge listener, and
%% a VA whose body is smart_home_va.xml, unchanged, joined over TCP. The
%% home starts through its scenario set-up (evatar_demo_mqtt_home),
%% which owns the private hardware pairing.
-module(avatar_sim_mqtt_home_SUITE).

-include_lib("common_test/include/ct.hrl").

-compile([export_all, nowarn_export_all]).

-define(VA_CRED, evatar_test_fixtures:va_credential()).
-define(AV_CRED, evatar_test_fixtures:avatar_credential()).

suite() -> [{timetrap, {seconds, 90}}].

all() ->
    [binds_like_the_tcp_home, request_feedback_round_trip, people_drive_the_sensors,
     photos_with_progress, device_power_cut, notifier_over_tcp, stray_hardware_pairing_replaced].

init_per_suite(Config) ->
    evatar_test_node:start_with_broker([avatar_sim], mqtt_home_suite, Config).

end_per_suite(Config) ->
    ok = evatar_test_node:stop_broker(?config(broker, Config)),
    evatar_test_node:stop([mqtt_home_suite], [avatar_sim]).

init_per_testcase(Case, Config) ->
    Pairing = atom_to_binary(Case),
    {ok, _} = evatar_test_fixtures:create_pairing(Pairing, #{feedback_timeout => evatar_test_time:ms(5000)}),
    Home = start_home(Config, Case, Pairing),
    {ok, Va} = agent_bridge_client:connect([?config(addr, Config)],
                                           #{pairing => Pairing, role => agent,
                                             entity_id => <<"golem-home-va-01">>,
                                             credential => ?VA_CRED}),
    ok = agent_bridge_client:describe(Va, va_body()),
    [{pairing, Pairing}, {home, Home}, {va, Va} | Config].

start_home(Config, Case, Pairing) ->
    Spool = filename:join(?config(priv_dir, Config), Case),
    {ok, Home} = evatar_demo_mqtt_home:start(
                   #{mqtt => #{host => {127, 0, 0, 1}, port => maps:get(port, ?config(broker, Config))},
                     endpoints => [?config(addr, Config)],
                     pairing => Pairing, credential => ?AV_CRED,
                     prefix => <<"sim-", Pairing/binary>>,
                     discovery_prefix => <<"ha-", Pairing/binary>>,
                     clock => #{speed => 20, start => {{2024, 11, 15}, {21, 0, 0}}},
                     spool => Spool}),
    Home.

end_per_testcase(_Case, Config) ->
    _ = agent_bridge_client:close(?config(va, Config)),
    %% A case may have stopped it (and stopped the home it started).
    _ = [ok = evatar_demo_mqtt_home:stop(H) || H <- [?config(home, Config)], is_process_alive(H)],
    _ = evatar:delete_pairing(?config(pairing, Config)),
    ok.

%% ---------------------------------------------------------------------------
%% Cases
%% ---------------------------------------------------------------------------

%% A home killed with its node (kill -9: no terminate) leaves its private
%% hardware pairing in the durable catalogue, restored at every restart.
%% The next start of the home deletes it and makes its own: one pairing of
%% that id, with this start's credentials, and the home works.
stray_hardware_pairing_replaced(Config) ->
    Id = <<"mqtt-hardware-easy-home-mqtt">>,
    ok = evatar_demo_mqtt_home:stop(?config(home, Config)),
    [] = [I || I <- evatar:catalogued(), I =:= Id],
    %% What the killed start left: its pairing, with its credentials.
    {ok, _} = evatar:create_pairing(Id, #{agent_credential => <<"stale-agent">>,
                                          avatar_credential => <<"stale-avatar">>}),
    Home = start_home(Config, stray, ?config(pairing, Config)),
    try
        %% The house joined the new pairing with this start's credential.
        ok = evatar_test_wait:until(
               fun() ->
                       {ok, Registry} = evatar:registry(Id),
                       lists:member(<<"easy-home-mqtt-hardware">>,
                                    [E || #{entity := E} <- Registry])
               end, #{timeout => 30000}),
        [Id] = [I || I <- evatar:catalogued(), I =:= Id],
        {error, _} = evatar:join(Id, agent, <<"intruder">>, <<"stale-agent">>)
    after
        ok = evatar_demo_mqtt_home:stop(Home)
    end,
    [] = [I || I <- evatar:catalogued(), I =:= Id].

%% Every consumer of smart_home_va.xml binds, as with the TCP home: the MQTT
%% devices through their discovered BIL (with the home's overrides), the
%% notifier over TCP; the discovered ComponentIDs are smart_home.xml's.
binds_like_the_tcp_home(Config) ->
    Report = wait_binding(?config(va, Config), fun(#{unbound := U, bound := B}) ->
                                                       U =:= [] andalso length(B) > 20
                                               end),
    #{bound := Bound} = Report,
    {ok, Xml} = file:read_file(filename:join([code:priv_dir(bil), "examples", "smart_home.xml"])),
    {ok, #{components := Tcp}} = bil:parse_description(Xml),
    Providers = lists:usort([P || #{consumer := #{entity := <<"golem-home-va-01">>},
                                    provider := #{component := P}} <- Bound]),
    Providers = lists:usort([Id || #{id := Id} <- Tcp]),
    A = avatar_sim_mqtt_home:avatar(?config(home, Config)),
    [] = [P || P <- mqtt_avatar:problems(A), maps:get(what, P) =/= unused_override],
    ok = mqtt_avatar:check(mqtt_avatar:description(A)).

%% TurnLightOn travels VA -> EVATAR -> MQTT Avatar -> mosquitto -> the
%% light (zigbee2mqtt JSON) -> the simulated house, and the state echo comes
%% back as the feedback the TCP home gives (Light, Room, Changed).
request_feedback_round_trip(Config) ->
    Va = ?config(va, Config),
    Light = provider(Va, <<"KitchenLightEmulator01">>, <<"TurnLightOn">>),
    <<"KitchenLightSwitch01">> = Light,
    {ok, #{context := feedback, sender := Light,
           body := #{type := <<"ACTION FEEDBACK">>, parameters := Ps}}} =
        agent_bridge_client:request(Va, req(<<"KitchenLightEmulator01">>, Light, <<"ACTUATOR">>,
                                            <<"TurnLightOn">>, []), 10000),
    <<"TurnLightOn">> = p(<<"Service">>, Ps),
    <<"done">> = p(<<"Result">>, Ps),
    <<"on">> = p(<<"Light">>, Ps),
    <<"kitchen">> = p(<<"Room">>, Ps),
    <<"yes">> = p(<<"Changed">>, Ps),
    #{lights := #{<<"kitchen">> := on}} = avatar_sim:state(house(Config)),
    %% The socket speaks Tasmota's raw ON/OFF.
    Socket = provider(Va, <<"LampEmulator01">>, <<"SwitchSocketOn">>),
    {ok, #{body := #{parameters := SPs}}} =
        agent_bridge_client:request(Va, req(<<"LampEmulator01">>, Socket, <<"ACTUATOR">>,
                                            <<"SwitchSocketOn">>, []), 10000),
    <<"on">> = p(<<"Socket">>, SPs),
    #{lights := #{<<"bedroom">> := on}} = avatar_sim:state(house(Config)),
    %% The time sensor answers ReadTime from the readings it published.
    Time = provider(Va, <<"TimeEmulator01">>, <<"ReadTime">>),
    {ok, #{body := #{parameters := TPs}}} =
        agent_bridge_client:request(Va, req(<<"TimeEmulator01">>, Time, <<"SENSOR">>,
                                            <<"ReadTime">>, []), 10000),
    <<"yes">> = p(<<"Dark">>, TPs),
    _ = p(<<"Sunset">>, TPs).

%% People in the house are seen by the MQTT devices: motion, keypad input
%% and speech reach the VA's emulators as the TCP home sends them, with the
%% simulated time as Timestamp; the time sensor reports when bound.
people_drive_the_sensors(Config) ->
    Va = ?config(va, Config),
    House = house(Config),
    #{context := sensor_data, sender := <<"TimeSensor01">>, timestamp := T0,
      body := #{parameters := TPs}} =
        wait_signal(Va, fun(#{body := #{type := T}}) -> T =:= <<"TimeOfDay">> end),
    <<"yes">> = p(<<"Dark">>, TPs),
    true = T0 >= calendar:datetime_to_gregorian_seconds({{2024, 11, 15}, {21, 0, 0}}) * 1000
        - 62167219200000,
    ok = avatar_sim:act(House, <<"intruder">>, {go, <<"hall">>}),
    #{context := event, sender := <<"HallMotionSensor01">>, receiver := <<"MotionEmulator01">>,
      body := #{parameters := MPs}} =
        wait_signal(Va, fun(#{body := #{type := T}, sender := S}) ->
                                T =:= <<"MotionDetected">> andalso S =:= <<"HallMotionSensor01">>
                        end),
    <<"yes">> = p(<<"Motion">>, MPs),
    <<"hall">> = p(<<"Room">>, MPs),
    <<"1">> = p(<<"People">>, MPs),
    ok = avatar_sim:act(House, <<"intruder">>, {keypad, <<"0000">>}),
    #{context := event, receiver := <<"KeypadEmulator01">>, body := #{parameters := KPs}} =
        wait_signal(Va, fun(#{body := #{type := T}}) -> T =:= <<"PasswordInput">> end),
    <<"yes">> = p(<<"WrongPassword">>, KPs),
    <<"1">> = p(<<"Attempts">>, KPs),
    ok = avatar_sim:act(House, <<"resident">>, {go, <<"living">>}),
    ok = avatar_sim:act(House, <<"resident">>, {say, <<"keep the light on">>}),
    #{context := event, body := #{parameters := VPs}} =
        wait_signal(Va, fun(#{body := #{type := T}}) -> T =:= <<"VoiceCommand">> end),
    <<"keep the light on">> = p(<<"Text">>, VPs),
    <<"living">> = p(<<"Room">>, VPs).

%% A camera request with Count 2: progress for the first photo, feedback
%% with both photo ids, as the TCP home answers.
photos_with_progress(Config) ->
    Va = ?config(va, Config),
    Camera = provider(Va, <<"CameraEmulator01">>, <<"TakePhoto">>),
    {ok, #{context := feedback, body := #{parameters := Ps}}} =
        agent_bridge_client:request(Va, req(<<"CameraEmulator01">>, Camera, <<"ACTUATOR">>,
                                            <<"TakePhoto">>, [{<<"Count">>, <<"2">>},
                                                              {<<"Interval">>, <<"500">>}]), 10000),
    [_, _] = binary:split(p(<<"Photos">>, Ps), <<",">>, [global]),
    <<"2">> = p(<<"Count">>, Ps),
    #{context := progress, body := #{parameters := PPs}} =
        wait_signal(Va, fun(#{context := C}) -> C =:= progress end),
    _ = p(<<"Photo">>, PPs).

%% A device whose power is cut: the broker's last will reaches the VA as
%% DeviceDisconnected; powered on, DeviceReconnected, and it works again.
device_power_cut(Config) ->
    Va = ?config(va, Config),
    Home = ?config(home, Config),
    Light = provider(Va, <<"LivingLightEmulator01">>, <<"TurnLightOn">>),
    ok = avatar_sim_mqtt_home:power_off(Home, Light),
    #{context := event, sender := Light, receiver := <<"LivingLightEmulator01">>,
      body := #{type := <<"DeviceDisconnected">>}} =
        wait_signal(Va, fun(#{context := C, sender := S}) -> C =:= event andalso S =:= Light end),
    {error, #{body := #{type := <<"DeviceUnavailable">>}}} =
        agent_bridge_client:request(Va, req(<<"LivingLightEmulator01">>, Light, <<"ACTUATOR">>,
                                            <<"TurnLightOn">>, []), 10000),
    ok = avatar_sim_mqtt_home:power_on(Home, Light),
    #{body := #{type := <<"DeviceReconnected">>}} =
        wait_signal(Va, fun(#{context := C, sender := S}) -> C =:= event andalso S =:= Light end),
    %% Powered on again, it takes commands again (not EVATAR's Timeout).
    {ok, #{context := feedback, sender := Light, body := #{parameters := Ps}}} =
        agent_bridge_client:request(Va, req(<<"LivingLightEmulator01">>, Light, <<"ACTUATOR">>,
                                            <<"TurnLightOn">>, []), 10000),
    <<"on">> = p(<<"Light">>, Ps).

%% The notifier (a PC, not an MQTT device) joins the VA's pairing over TCP
%% next to the MQTT Avatar.
notifier_over_tcp(Config) ->
    Va = ?config(va, Config),
    Notifier = provider(Va, <<"NotifierEmulator01">>, <<"SendSMS">>),
    <<"Notifier01">> = Notifier,
    {ok, #{context := feedback, body := #{parameters := Ps}}} =
        agent_bridge_client:request(Va, req(<<"NotifierEmulator01">>, Notifier, <<"ACTUATOR">>,
                                            <<"SendSMS">>, [{<<"TextMsg">>, <<"hello">>}]), 10000),
    true = filelib:is_regular(p(<<"File">>, Ps)).

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

va_body() ->
    {ok, Xml} = file:read_file(filename:join([code:priv_dir(bil), "examples", "smart_home_va.xml"])),
    {ok, D} = bil:parse_description(Xml),
    D.

house(Config) ->
    avatar_sim_mqtt_home:house(?config(home, Config)).

req(From, To, Cat, Type, Params) ->
    #{sender => From, receiver => To, body => #{category => Cat, type => Type, parameters => Params}}.

provider(Va, Consumer, Type) ->
    Match = fun(B) -> [P || #{consumer := #{component := C}, type := T, provider := #{component := P}}
                                <- B, C =:= Consumer, T =:= Type] end,
    #{bound := Bound} = wait_binding(Va, fun(#{bound := B}) -> Match(B) =/= [] end),
    [P] = Match(Bound),
    P.

%% Bindings arrive as the description grows; remember the last one.
wait_binding(Va, Pred) ->
    case get({binding, Va}) of
        #{} = R0 ->
            case Pred(R0) of
                true -> R0;
                false -> wait_binding_msg(Va, Pred)
            end;
        undefined ->
            wait_binding_msg(Va, Pred)
    end.

wait_binding_msg(Va, Pred) ->
    receive
        {agent_bridge, Va, {binding, Report}} ->
            put({binding, Va}, Report),
            case Pred(Report) of
                true -> Report;
                false -> wait_binding_msg(Va, Pred)
            end
    after evatar_test_time:guard() -> ct:fail({no_binding, get({binding, Va})})
    end.

wait_signal(Va, Pred) ->
    receive
        {agent_bridge, Va, {signal, S}} ->
            case Pred(S) of
                true -> S;
                false -> wait_signal(Va, Pred)
            end;
        {agent_bridge, Va, {binding, Report}} ->
            put({binding, Va}, Report),
            wait_signal(Va, Pred)
    after evatar_test_time:guard() -> ct:fail(no_signal)
    end.

p(Name, Params) ->
    case lists:keyfind(Name, 1, Params) of
        {_, V} -> V;
        false -> ct:fail({missing_parameter, Name, Params})
    end.

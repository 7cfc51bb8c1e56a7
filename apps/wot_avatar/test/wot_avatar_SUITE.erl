%% Common Test suite of the WoT Avatar against a real peer: a node-wot
%% 0.9.2 servient (HTTP binding; things.js in the data dir, packages from
%% evatar_test_npm) exposing a lamp, a thermostat and a motion sensor, one
%% WoT Avatar per Thing joined through a real agent_bridge listener to a
%% real pairing, and a test VA (agent_bridge_client) that embodies them;
%% and a node-wot 0.8.16 servient (MQTT binding; node-wot-mqtt/ in the
%% data dir, its own npm project) exposing a lamp on a real mosquitto.
%% Every wait is for an event: a signal, a Binding report, a line the
%% servient prints; never for a time.
-module(wot_avatar_SUITE).

-include_lib("common_test/include/ct.hrl").

-compile([export_all, nowarn_export_all]).

-define(PAIRING, <<"wot-home">>).
-define(LISTENER, wot_avatar_suite).
-define(WAIT, evatar_test_time:guard()).

suite() -> [{timetrap, {seconds, 120}}].

all() ->
    [lamp_action_and_brightness, thermostat_range_and_polling, motion_event, thing_away_and_back,
     killed_avatar_restarts_with_backoff, node_config_embodies_a_thing, mqtt_forms_through_mosquitto,
     node_wot_mqtt_lamp, bad_options].

init_per_suite(Config) ->
    Npm = evatar_test_npm:install(),
    NpmMqtt = evatar_test_npm:install_mqtt(),
    ok = evatar_test_node:start([wot_avatar]),
    Addr = evatar_test_node:listen(?LISTENER),
    [{npm, Npm}, {npm_mqtt, NpmMqtt}, {addr, Addr} | Config].

end_per_suite(_Config) ->
    evatar_test_node:stop([?LISTENER], [wot_avatar]).

init_per_testcase(node_wot_mqtt_lamp, Config) ->
    %% its servient needs the case's broker: started by the case
    {ok, _} = evatar_test_fixtures:create_pairing(?PAIRING, #{feedback_timeout => evatar_test_time:ms(10000)}),
    Config;
init_per_testcase(_Case, Config) ->
    {ok, _} = evatar_test_fixtures:create_pairing(?PAIRING, #{feedback_timeout => evatar_test_time:ms(10000)}),
    Port = hd(evatar_test_cluster:free_ports(1)),
    Servient = servient(Config, Port),
    [{port, Port}, {servient, Servient} | Config].

end_per_testcase(_Case, Config) ->
    [catch wot_avatar:stop(A) || A <- forget(avatars)],
    [catch agent_bridge_client:close(V) || V <- forget(vas)],
    [catch wot_avatar:unkeep(E) || E <- forget(kept)],
    [catch peer:stop(P) || P <- forget(peers)],
    stop_servient(?config(servient, Config)),
    stop_servient(erase(servient2)),
    _ = evatar:delete_pairing(?PAIRING),
    ok.

%% ---------------------------------------------------------------------------
%% Cases
%% ---------------------------------------------------------------------------

%% The lamp's toggle action answers with the Thing's output; its brightness
%% is written (the Thing sees the write), read back, and its observation
%% (long-poll) pushes the new value as SensorData.
lamp_action_and_brightness(Config) ->
    A = avatar(Config, <<"lamp">>, #{}),
    #{components := [#{id := <<"Lamp">>}]} = wot_avatar:description(A),
    Va = va(Config),
    <<"Lamp">> = provider_of(Va, <<"LampVa">>, <<"Toggle">>),
    <<"Lamp">> = consumer_of(Va, <<"LampVa">>, <<"Brightness">>),
    {ok, F1} = request(Va, <<"LampVa">>, <<"Lamp">>, <<"Toggle">>, []),
    #{context := feedback, sender := <<"Lamp">>,
      body := #{type := <<"ACTION FEEDBACK">>, parameters := P1}} = F1,
    <<"true">> = param(<<"On">>, P1),
    <<"done">> = param(<<"Result">>, P1),
    {ok, #{context := feedback, body := #{parameters := P2}}} =
        request(Va, <<"LampVa">>, <<"Lamp">>, <<"Toggle">>, []),
    <<"false">> = param(<<"On">>, P2),
    %% The observation is registered before the write: its push is certain.
    ok = servient_line(Config, <<"OBSERVED lamp brightness">>),
    {ok, #{context := feedback, body := #{parameters := P3}}} =
        request(Va, <<"LampVa">>, <<"Lamp">>, <<"SetBrightness">>, [{<<"Value">>, <<"80">>}]),
    <<"80">> = param(<<"Value">>, P3),
    ok = servient_line(Config, <<"WRITE lamp brightness 80">>),
    {ok, #{context := feedback, body := #{type := <<"ReadBrightness">>, parameters := P4}}} =
        request(Va, <<"LampVa">>, <<"Lamp">>, <<"ReadBrightness">>, []),
    <<"80">> = param(<<"Value">>, P4),
    #{context := sensor_data, body := #{parameters := P5}} =
        evatar_test_fixtures:wait_signal(Va, fun(#{body := #{type := T, parameters := Ps}}) ->
                                                     T =:= <<"Brightness">> andalso
                                                         lists:member({<<"Value">>, <<"80">>}, Ps)
                                             end, ?WAIT),
    <<"80">> = param(<<"Value">>, P5),
    %% Out of range: refused before the Thing.
    {error, #{context := error, body := #{type := <<"BadParameter">>}}} =
        request(Va, <<"LampVa">>, <<"Lamp">>, <<"SetBrightness">>, [{<<"Value">>, <<"101">>}]),
    [] = wot_avatar:problems(A).

%% The thermostat's setpoint range (10..30) is checked by EVATAR's side: a
%% value out of it is refused and never reaches the Thing; one inside is
%% written. Its temperature, not observable, is polled and reaches the VA.
thermostat_range_and_polling(Config) ->
    _A = avatar(Config, <<"thermostat">>, #{poll_ms => 200}),
    Va = va(Config),
    <<"Thermostat">> = provider_of(Va, <<"ThermoVa">>, <<"SetSetpoint">>),
    {error, #{context := error, body := #{type := <<"BadParameter">>, parameters := E1}}} =
        request(Va, <<"ThermoVa">>, <<"Thermostat">>, <<"SetSetpoint">>, [{<<"Value">>, <<"45">>}]),
    <<"parameter Value is above its maximum 30">> = param(<<"Message">>, E1),
    {error, #{context := error, body := #{type := <<"BadParameter">>}}} =
        request(Va, <<"ThermoVa">>, <<"Thermostat">>, <<"SetSetpoint">>, [{<<"Value">>, <<"warm">>}]),
    {ok, #{body := #{parameters := R1}}} =
        request(Va, <<"ThermoVa">>, <<"Thermostat">>, <<"ReadSetpoint">>, []),
    <<"21">> = param(<<"Value">>, R1),
    {ok, #{context := feedback}} =
        request(Va, <<"ThermoVa">>, <<"Thermostat">>, <<"SetSetpoint">>, [{<<"Value">>, <<"22.5">>}]),
    %% The first write the Thing sees is the one in range.
    ok = servient_line(Config, <<"WRITE thermostat setpoint 22.5">>, fun(<<"WRITE", _/binary>>) -> true;
                                                                        (_) -> false
                                                                     end),
    {ok, #{body := #{parameters := R2}}} =
        request(Va, <<"ThermoVa">>, <<"Thermostat">>, <<"ReadSetpoint">>, []),
    <<"22.5">> = param(<<"Value">>, R2),
    #{context := sensor_data, body := #{parameters := T}} =
        evatar_test_fixtures:wait_signal(Va, fun(#{body := #{type := Ty}}) -> Ty =:= <<"Temperature">> end,
                                         ?WAIT),
    <<"19.5">> = param(<<"Value">>, T).

%% The motion sensor's event (a long-poll subscription) reaches the VA as
%% an Event signal with the event's data.
motion_event(Config) ->
    A = avatar(Config, <<"motion-sensor">>, #{room => <<"hall">>}),
    Va = va(Config),
    <<"MotionSensor">> = consumer_of(Va, <<"MotionVa">>, <<"Motion">>),
    wait_partner(A),
    ok = servient_line(Config, <<"SUBSCRIBED motion-sensor motion">>),
    ok = servient_input(Config, <<"motion\n">>),
    #{context := event, sender := <<"MotionSensor">>, body := #{parameters := Ps}} =
        evatar_test_fixtures:wait_signal(Va, fun(#{body := #{type := T}}) -> T =:= <<"Motion">> end, ?WAIT),
    <<"true">> = param(<<"Detected">>, Ps),
    <<"hall">> = param(<<"Zone">>, Ps),
    <<"hall">> = param(<<"Room">>, Ps).

%% The servient killed (kill -9): the lamp's Avatar leaves the pairing, its
%% problem says why; the servient back on the same port: it joins again
%% and the action works again. Kept (wot_avatar:keep/1), as the node
%% configuration file keeps them.
thing_away_and_back(Config) ->
    Opts = opts(Config, <<"lamp">>, #{}),
    {ok, _Keeper} = wot_avatar:keep(Opts),
    {ok, A} = evatar_test_wait:value(kept, fun() -> wot_avatar:find(<<"wot-lamp">>) end,
                                     fun({ok, _}) -> true; (_) -> false end),
    ok = wot_avatar:await_ready(A, ?WAIT),
    Va = va(Config),
    <<"Lamp">> = provider_of(Va, <<"LampVa">>, <<"Toggle">>),
    {ok, #{context := feedback}} = request(Va, <<"LampVa">>, <<"Lamp">>, <<"Toggle">>, []),
    ok = servient_line(Config, <<"OBSERVED lamp brightness">>),
    kill_servient(?config(servient, Config)),
    %% Gone: the VA's registry loses the lamp.
    _ = evatar_test_fixtures:wait_binding(Va, fun(#{bound := B}) -> not lists:any(fun is_lamp/1, B) end,
                                          ?WAIT),
    #{state := away, thing := down} = wot_avatar:status(A),
    true = lists:any(fun(#{what := W}) -> W =:= thing_gone end, wot_avatar:problems(A)),
    {error, #{context := error}} = request(Va, <<"LampVa">>, <<"Lamp">>, <<"Toggle">>, []),
    %% Back.
    Servient2 = servient(Config, ?config(port, Config)),
    put(servient2, Servient2),
    _ = evatar_test_fixtures:wait_binding(Va, fun(#{bound := B}) -> lists:any(fun is_lamp/1, B) end, ?WAIT),
    {ok, A} = wot_avatar:find(<<"wot-lamp">>),
    {ok, #{context := feedback, body := #{parameters := P}}} =
        request(Va, <<"LampVa">>, <<"Lamp">>, <<"Toggle">>, []),
    %% a new servient: the lamp starts off again
    <<"true">> = param(<<"On">>, P),
    ok = wot_avatar:unkeep(<<"wot-lamp">>),
    stop_servient(Servient2).

%% A kept Avatar killed (exit(Pid, kill): a crash, no Bye) is started
%% again by its keeper after min_ms, then after twice that (the runs are
%% short), and each new process joins and is bound again: the VA's request
%% reaches the Thing through it.
killed_avatar_restarts_with_backoff(Config) ->
    Opts = opts(Config, <<"lamp">>, #{restart => #{min_ms => 100, max_ms => 1000,
                                                   stable_after_ms => 600000}}),
    {ok, _Keeper} = wot_avatar:keep(Opts),
    remember(kept, <<"wot-lamp">>),
    A1 = await_kept_start(1),
    Va = va(Config),
    <<"Lamp">> = provider_of(Va, <<"LampVa">>, <<"Toggle">>),
    Delays = [kill_and_rebind(Va, N) || N <- [2, 3]],
    %% The delay each restart waited: the next delay read before the kill.
    [100, 200] = Delays,
    [#{crashes := 2, next_delay_ms := 400, state := running, avatar := A3}] = wot_avatar:kept(),
    true = A3 =/= A1,
    {ok, #{context := feedback, sender := <<"Lamp">>}} =
        request(Va, <<"LampVa">>, <<"Lamp">>, <<"Toggle">>, []).

%% A node started from a configuration file whose wot_avatars section names
%% the lamp's TD (a peer node, its applications started in the release's
%% order, node_config first): its keeper runs the WoT Avatar, which joins
%% the file's pairing on the file's listener; a VA there invokes the lamp.
node_config_embodies_a_thing(Config) ->
    Listener = hd(evatar_test_cluster:free_ports(1)),
    Td = ["http://127.0.0.1:", integer_to_list(?config(port, Config)), "/lamp"],
    Text = io_lib:format(
             "%% written by wot_avatar_SUITE\n"
             "{listeners, [#{name => \"main\", ip => \"127.0.0.1\", port => ~b}]}.\n"
             "{pairings, [#{id => \"~ts\", agent_credential => \"~ts\",\n"
             "              avatar_credential => \"~ts\", feedback_timeout => 10000}]}.\n"
             "{wot_avatars, [#{entity_id => \"wot-lamp\", pairing => \"~ts\",\n"
             "                 td => \"~ts\", poll_ms => 0, retry_max_ms => 1000}]}.\n",
             [Listener, ?PAIRING, evatar_test_fixtures:va_credential(),
              evatar_test_fixtures:avatar_credential(), ?PAIRING, Td]),
    File = filename:join(?config(priv_dir, Config), "wot_avatars.config"),
    ok = file:write_file(File, Text),
    {ok, Peer, _} = peer:start_link(#{name => peer:random_name(?MODULE), host => "127.0.0.1",
                                      longnames => true, connection => standard_io,
                                      args => code_path(), env => [{"EVATAR_CONFIG", File}]}),
    remember(peers, Peer),
    [{ok, _} = peer:call(Peer, application, ensure_all_started, [App], 30000)
     || App <- [node_config, evatar, agent_bridge, wot_avatar]],
    [#{entity_id := <<"wot-lamp">>}] = peer:call(Peer, wot_avatar, kept, []),
    Va = va([{addr, {{127, 0, 0, 1}, Listener}} | Config]),
    <<"Lamp">> = provider_of(Va, <<"LampVa">>, <<"Toggle">>),
    {ok, #{context := feedback, body := #{parameters := P}}} =
        request(Va, <<"LampVa">>, <<"Lamp">>, <<"Toggle">>, []),
    <<"true">> = param(<<"On">>, P),
    {ok, A} = peer:call(Peer, wot_avatar, find, [<<"wot-lamp">>]),
    [] = peer:call(Peer, wot_avatar, problems, [A]).

%% A TD whose forms are MQTT (node-wot's MQTT broker server's topics:
%% THING/actions/A, THING/properties/P and .../writeproperty), read from a
%% file, on a real mosquitto: the VA's toggle and brightness write are
%% publishes the device (this case's MQTT client) receives, answered once
%% the broker acknowledges them; a value the device publishes on the
%% property's topic reaches the VA as SensorData; a value out of range is
%% refused before anything is published.
mqtt_forms_through_mosquitto(Config) ->
    {ok, Broker} = evatar_test_mosquitto:start(),
    try
        Port = integer_to_binary(maps:get(port, Broker)),
        Url = fun(Topic) -> <<"mqtt://127.0.0.1:", Port/binary, "/mqtt-lamp/", Topic/binary>> end,
        Td = #{<<"@context">> => <<"https://www.w3.org/2022/wot/td/v1.1">>, <<"title">> => <<"mqtt-lamp">>,
               <<"securityDefinitions">> => #{<<"nosec_sc">> => #{<<"scheme">> => <<"nosec">>}},
               <<"security">> => <<"nosec_sc">>,
               <<"properties">> =>
                   #{<<"brightness">> =>
                         #{<<"type">> => <<"integer">>, <<"minimum">> => 0, <<"maximum">> => 100,
                           <<"observable">> => true,
                           <<"forms">> => [#{<<"href">> => Url(<<"properties/brightness">>),
                                             <<"op">> => [<<"observeproperty">>],
                                             <<"mqv:controlPacket">> => <<"subscribe">>},
                                           #{<<"href">> => Url(<<"properties/brightness/writeproperty">>),
                                             <<"op">> => [<<"writeproperty">>],
                                             <<"mqv:controlPacket">> => <<"publish">>}]}},
               <<"actions">> => #{<<"toggle">> => #{<<"forms">> => [#{<<"href">> => Url(<<"actions/toggle">>)}]}}},
        File = filename:join(?config(priv_dir, Config), "mqtt-lamp.td.json"),
        ok = file:write_file(File, evatar_json:encode(Td)),
        {ok, Device} = mqtt_client:start_link(#{host => "127.0.0.1", port => maps:get(port, Broker),
                                                client_id => <<"wot-suite-device">>}),
        ok = mqtt_client:await_connected(Device, ?WAIT),
        {ok, _} = mqtt_client:subscribe(Device, [{<<"mqtt-lamp/#">>, 1}]),
        {A, Va} = mqtt_lamp(Config, File),
        {ok, #{context := feedback, body := #{type := <<"ACTION FEEDBACK">>, parameters := P1}}} =
            request(Va, <<"LampVa">>, <<"Lamp">>, <<"Toggle">>, []),
        <<"done">> = param(<<"Result">>, P1),
        #{payload := _} = device_message(Device, <<"mqtt-lamp/actions/toggle">>),
        {ok, #{context := feedback, body := #{parameters := P2}}} =
            request(Va, <<"LampVa">>, <<"Lamp">>, <<"SetBrightness">>, [{<<"Value">>, <<"80">>}]),
        <<"80">> = param(<<"Value">>, P2),
        #{payload := <<"80">>} = device_message(Device, <<"mqtt-lamp/properties/brightness/writeproperty">>),
        {error, #{context := error, body := #{type := <<"BadParameter">>}}} =
            request(Va, <<"LampVa">>, <<"Lamp">>, <<"SetBrightness">>, [{<<"Value">>, <<"101">>}]),
        wait_partner(A),
        ok = mqtt_client:publish(Device, <<"mqtt-lamp/properties/brightness">>, <<"42">>, #{qos => 1}),
        #{context := sensor_data, sender := <<"Lamp">>, body := #{parameters := P3}} =
            evatar_test_fixtures:wait_signal(Va, fun(#{body := #{type := T}}) -> T =:= <<"Brightness">> end,
                                             ?WAIT),
        <<"42">> = param(<<"Value">>, P3),
        ok = mqtt_client:stop(Device)
    after
        ok = evatar_test_mosquitto:stop(Broker)
    end.

%% node-wot's own MQTT servient (0.8.16, the newest @node-wot/binding-mqtt)
%% on a real mosquitto: its TD, as node-wot publishes it (retained, on the
%% Thing's title; forms with no mqv:controlPacket, readproperty on the
%% observe topic), read from a file. The VA's toggles and brightness write
%% change the servient's state (it prints each change); its publishes of
%% the brightness, after the write and after a change on the device's
%% side, reach the VA as SensorData.
node_wot_mqtt_lamp(Config) ->
    {ok, Broker} = evatar_test_mosquitto:start(),
    try
        BrokerPort = maps:get(port, Broker),
        Servient = servient(Config, "node-wot-mqtt/lamp_mqtt.js",
                            ["mqtt://127.0.0.1:" ++ integer_to_list(BrokerPort)], ?config(npm_mqtt, Config)),
        put(servient2, Servient),
        {ok, C} = mqtt_client:start_link(#{host => "127.0.0.1", port => BrokerPort,
                                           client_id => <<"wot-suite-td-reader">>}),
        ok = mqtt_client:await_connected(C, ?WAIT),
        {ok, _} = mqtt_client:subscribe(C, [{<<"mqtt-lamp">>, 1}]),
        #{payload := TdText} = device_message(C, <<"mqtt-lamp">>),
        ok = mqtt_client:stop(C),
        File = filename:join(?config(priv_dir, Config), "node-wot-mqtt-lamp.td.json"),
        ok = file:write_file(File, TdText),
        {A, Va} = mqtt_lamp(Config, File),
        wait_partner(A),
        {ok, #{context := feedback, body := #{type := <<"ACTION FEEDBACK">>}}} =
            request(Va, <<"LampVa">>, <<"Lamp">>, <<"Toggle">>, []),
        ok = servient_line(Config, <<"TOGGLE mqtt-lamp on true">>),
        {ok, #{context := feedback}} = request(Va, <<"LampVa">>, <<"Lamp">>, <<"Toggle">>, []),
        ok = servient_line(Config, <<"TOGGLE mqtt-lamp on false">>),
        {ok, #{context := feedback, body := #{parameters := P1}}} =
            request(Va, <<"LampVa">>, <<"Lamp">>, <<"SetBrightness">>, [{<<"Value">>, <<"80">>}]),
        <<"80">> = param(<<"Value">>, P1),
        ok = servient_line(Config, <<"WRITE mqtt-lamp brightness 80">>),
        _ = brightness(Va, <<"80">>),
        ok = servient_input(Config, <<"brightness 30\n">>),
        _ = brightness(Va, <<"30">>),
        {error, #{context := error, body := #{type := <<"BadParameter">>}}} =
            request(Va, <<"LampVa">>, <<"Lamp">>, <<"SetBrightness">>, [{<<"Value">>, <<"101">>}]),
        [<<"WRITE mqtt-lamp brightness 80">>] = [L || <<"WRITE", _/binary>> = L <- servient_lines(Servient)]
    after
        stop_servient(erase(servient2)),
        ok = evatar_test_mosquitto:stop(Broker)
    end.

%% Options with mistakes: every one named, nothing started.
bad_options(_Config) ->
    {error, Ps} = wot_avatar:start(#{entity_id => <<>>, td => <<"ftp://x">>, poll_ms => -1,
                                     colour => blue}),
    [colour, entity_id, evatar, poll_ms, td] =
        lists:sort([maps:get(key, P, colour) || P <- Ps]).

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

is_lamp(#{provider := #{entity := E}}) -> E =:= <<"wot-lamp">>;
is_lamp(_) -> false.

opts(Config, Thing, Extra) ->
    Td = case Extra of
             #{td := T} -> T;
             _ -> <<"http://127.0.0.1:", (integer_to_binary(?config(port, Config)))/binary, "/", Thing/binary>>
         end,
    maps:merge(#{entity_id => <<"wot-", Thing/binary>>, td => Td,
                 evatar => #{endpoints => [?config(addr, Config)], pairing => ?PAIRING,
                             credential => evatar_test_fixtures:avatar_credential()},
                 retry_max_ms => 1000, restart => #{min_ms => 100, max_ms => 1000}},
               Extra).

avatar(Config, Thing, Extra) ->
    {ok, A} = wot_avatar:start(opts(Config, Thing, Extra)),
    remember(avatars, A),
    ok = wot_avatar:await_ready(A, ?WAIT),
    A.

va(Config) ->
    {ok, Va} = agent_bridge_client:connect([?config(addr, Config)],
                                           #{pairing => ?PAIRING, role => agent, entity_id => <<"wot-va">>,
                                             credential => evatar_test_fixtures:va_credential()}),
    remember(vas, Va),
    ok = agent_bridge_client:describe(Va, va_description()),
    Va.

va_description() ->
    Fb = fun(Device) -> entry(<<"ACTUATOR">>, <<"ACTION FEEDBACK">>,
                              [{<<"Feedback">>, <<"yes">>}, {<<"Device">>, Device}]) end,
    #{entity_id => <<"wot-va">>, api_name => <<"TEST VA">>, entity_type => agent,
      context => <<"WotTestVa">>,
      components =>
          [#{id => <<"LampVa">>,
             services => [Fb(<<"Lamp">>), entry(<<"SENSOR">>, <<"Brightness">>, [])],
             consumes => [entry(<<"ACTUATOR">>, <<"Toggle">>, []),
                          entry(<<"ACTUATOR">>, <<"SetBrightness">>, []),
                          entry(<<"SENSOR">>, <<"ReadBrightness">>, [])]},
           #{id => <<"ThermoVa">>,
             services => [Fb(<<"Thermostat">>), entry(<<"SENSOR">>, <<"Temperature">>, [])],
             consumes => [entry(<<"ACTUATOR">>, <<"SetSetpoint">>, []),
                          entry(<<"SENSOR">>, <<"ReadSetpoint">>, [])]},
           #{id => <<"MotionVa">>,
             services => [entry(<<"SENSOR">>, <<"Motion">>, [{<<"Room">>, <<"hall">>}])],
             consumes => []}]}.

entry(Cat, Type, Params) -> #{category => Cat, type => Type, parameters => Params}.

request(Va, From, To, Type, Params) ->
    Cat = case Type of
              <<"Read", _/binary>> -> <<"SENSOR">>;
              _ -> <<"ACTUATOR">>
          end,
    agent_bridge_client:request(Va, #{sender => From, receiver => To, body => entry(Cat, Type, Params)},
                                ?WAIT).

provider_of(Va, Consumer, Type) -> bound(Va, consumer, Consumer, Type, provider).

consumer_of(Va, Provider, Type) -> bound(Va, provider, Provider, Type, consumer).

bound(Va, Side, Id, Type, Other) ->
    %% a report of now: the one that answered an earlier call was consumed
    ok = agent_bridge_client:get_binding(Va),
    Match = fun(#{type := T} = Row) -> T =:= Type andalso maps:get(component, maps:get(Side, Row)) =:= Id end,
    Report = evatar_test_fixtures:wait_binding(Va, fun(#{bound := B}) -> lists:any(Match, B) end, ?WAIT),
    [C] = [maps:get(component, maps:get(Other, R)) || R <- maps:get(bound, Report), Match(R)],
    C.

%% The WoT Avatar of the MQTT lamp whose TD is File, with no problem, and
%% a VA bound to it.
mqtt_lamp(Config, File) ->
    A = avatar(Config, <<"mqtt-lamp">>, #{td => {file, File}, allowed_hosts => [<<"127.0.0.1">>],
                                         component => <<"Lamp">>}),
    [] = wot_avatar:problems(A),
    Va = va(Config),
    <<"Lamp">> = provider_of(Va, <<"LampVa">>, <<"Toggle">>),
    <<"Lamp">> = consumer_of(Va, <<"LampVa">>, <<"Brightness">>),
    {A, Va}.

%% The Brightness SensorData with Value V, waited for.
brightness(Va, V) ->
    evatar_test_fixtures:wait_signal(Va, fun(#{context := sensor_data, body := #{type := T, parameters := Ps}}) ->
                                                 T =:= <<"Brightness">> andalso lists:member({<<"Value">>, V}, Ps);
                                            (_) -> false
                                         end, ?WAIT).

%% The next message the device gets on Topic (the avatar's own are the
%% only ones published there).
device_message(Device, Topic) ->
    receive
        {mqtt_client, Device, {publish, #{topic := Topic} = M}} -> M
    after ?WAIT -> ct:fail({no_message_on, Topic})
    end.

%% The kept lamp's Nth start, running and joined; its pid.
await_kept_start(N) ->
    {ok, [#{avatar := A}]} =
        evatar_test_wait:value({kept_start, N}, fun() -> {ok, wot_avatar:kept()} end,
                               fun({ok, [#{state := running, starts := S}]}) -> S =:= N;
                                  (_) -> false
                               end),
    ok = wot_avatar:await_ready(A, ?WAIT),
    A.

%% Kills the kept lamp's Avatar and waits for start N to join and be bound
%% to the VA again, and the VA's request to go through it; returns the
%% delay the keeper waited (its next delay before the kill).
kill_and_rebind(Va, N) ->
    [#{avatar := Old, next_delay_ms := Delay}] = wot_avatar:kept(),
    ok = flush_bindings(Va),
    true = exit(Old, kill),
    %% The old entity leaves (replaced by the new join, once its
    %% connection is seen gone): the VA's registry loses the lamp, then
    %% gets the new process's.
    _ = evatar_test_fixtures:wait_binding(Va, fun(#{bound := B}) -> not lists:any(fun is_lamp/1, B) end,
                                          ?WAIT),
    _ = evatar_test_fixtures:wait_binding(Va, fun(#{bound := B}) -> lists:any(fun is_lamp/1, B) end, ?WAIT),
    New = await_kept_start(N),
    true = New =/= Old,
    {ok, #{context := feedback}} = request(Va, <<"LampVa">>, <<"Lamp">>, <<"Toggle">>, []),
    Delay.

%% The Binding reports the VA has received so far (a report waited for
%% must come after this).
flush_bindings(Va) ->
    receive {agent_bridge, Va, {binding, _}} -> flush_bindings(Va)
    after 0 -> ok
    end.

code_path() ->
    lists:append([["-pa", D] || D <- code:get_path(), string:find(D, "_build") =/= nomatch]).

%% The Avatar's own Binding report may come after the VA's: wait until it
%% knows its partner, so that the event goes to it.
wait_partner(A) ->
    ok = evatar_test_wait:until(fun() -> maps:get(partners, wot_avatar:status(A)) =/= [] end).

param(Name, Ps) ->
    case lists:keyfind(Name, 1, Ps) of
        {_, V} -> V;
        false -> ct:fail({missing_parameter, Name, Ps})
    end.

remember(Kind, Pid) ->
    _ = put(Kind, [Pid | case get(Kind) of undefined -> []; L -> L end]),
    ok.

forget(Kind) ->
    case erase(Kind) of
        undefined -> [];
        L -> L
    end.

%% ---------------------------------------------------------------------------
%% The servient: an OS process, its output lines kept by a reader process
%% so that a case can wait for any line printed since it started.
%% ---------------------------------------------------------------------------

servient(Config, Port) ->
    servient(Config, "things.js", [integer_to_list(Port)], ?config(npm, Config)).

%% A node script of the data dir run with the packages installed in Npm;
%% its stderr goes to a log file in priv_dir named after it.
servient(Config, Name, Args, Npm) ->
    Script = filename:join(?config(data_dir, Config), Name),
    Log = filename:join(?config(priv_dir, Config), filename:basename(Name, ".js") ++ ".log"),
    Node = os:find_executable("node"),
    Node =/= false orelse ct:fail("node is not installed (Debian: nodejs, npm)"),
    Self = self(),
    Reader = spawn(fun() ->
                           P = open_port({spawn_executable, "/bin/sh"},
                                         [{args, ["-c", "exec \"$0\" \"$1\" \"$2\" 2>>\"$3\"",
                                                  Node, Script | Args] ++ [Log]},
                                          {env, evatar_test_npm:node_env(Npm)},
                                          {line, 4096}, binary, exit_status]),
                           reader(P, Self, [])
                   end),
    receive
        {servient_ready, Reader, OsPid} -> #{reader => Reader, os_pid => OsPid};
        {servient_exit, Reader, Status, Lines} -> ct:fail({servient_failed, Status, Lines})
    after evatar_test_time:guard() -> ct:fail(servient_not_ready)
    end.

reader(P, Owner, Lines) ->
    receive
        {P, {data, {eol, <<"READY ", Pid/binary>> = L}}} ->
            Owner ! {servient_ready, self(), binary_to_list(Pid)},
            reader(P, Owner, Lines ++ [L]);
        {P, {data, {eol, L}}} ->
            reader(P, Owner, Lines ++ [L]);
        {P, {data, {noeol, _}}} ->
            reader(P, Owner, Lines);
        {P, {exit_status, S}} ->
            Owner ! {servient_exit, self(), S, Lines},
            reader_dead(Lines);
        {lines, From} ->
            From ! {lines, self(), Lines},
            reader(P, Owner, Lines);
        {input, From, Data} ->
            true = port_command(P, Data),
            From ! {input_sent, self()},
            reader(P, Owner, Lines);
        stop ->
            catch port_close(P)
    end.

reader_dead(Lines) ->
    receive
        {lines, From} -> From ! {lines, self(), Lines}, reader_dead(Lines);
        stop -> ok
    end.

current_servient(Config) ->
    case get(servient2) of
        undefined -> ?config(servient, Config);
        S -> S
    end.

%% Waits until the servient has printed Line (or, with Pred, until the
%% first line satisfying Pred, which must be Line).
servient_line(Config, Line) ->
    servient_line(Config, Line, fun(L) -> L =:= Line end).

servient_line(Config, Line, Pred) ->
    #{reader := R} = current_servient(Config),
    {ok, Lines} = evatar_test_wait:value(
                    {servient_line, Line},
                    fun() -> R ! {lines, self()},
                             receive {lines, R, Ls} -> {ok, Ls} after evatar_test_time:guard() -> {ok, []} end
                    end,
                    fun({ok, Ls}) -> lists:any(Pred, Ls) end),
    [Line | _] = lists:filter(Pred, Lines),
    ok.

%% The lines the servient has printed so far.
servient_lines(#{reader := R}) ->
    R ! {lines, self()},
    receive {lines, R, Ls} -> Ls after evatar_test_time:guard() -> ct:fail(servient_lines) end.

servient_input(Config, Data) ->
    #{reader := R} = current_servient(Config),
    R ! {input, self(), Data},
    receive {input_sent, R} -> ok after evatar_test_time:guard() -> ct:fail(servient_input) end.

kill_servient(#{os_pid := OsPid, reader := R}) ->
    [] = os:cmd("kill -9 " ++ OsPid),
    receive {servient_exit, R, _, _} -> ok after evatar_test_time:guard() -> ct:fail(servient_not_killed) end.

stop_servient(#{os_pid := OsPid, reader := R}) ->
    _ = os:cmd("kill -9 " ++ OsPid ++ " 2>/dev/null"),
    R ! stop,
    ok;
stop_servient(_) ->
    ok.

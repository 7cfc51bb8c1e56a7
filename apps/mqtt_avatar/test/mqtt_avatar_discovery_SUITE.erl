%% Common Test suite of discovery and generation, without a broker: Home
%% Assistant discovery configs (full and abbreviated keys, the `~' base
%% topic) and zigbee2mqtt's device list become BIL descriptions that are
%% valid against bil.xsd; malformed messages give problems, not crashes;
%% hand-written Mqtt* parameters are checked; overrides adapt the result.
-module(mqtt_avatar_discovery_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("proper/include/proper.hrl").
-include_lib("xmerl/include/xmerl.hrl").

-compile([export_all, nowarn_export_all]).

suite() -> [{timetrap, {seconds, 120}}].

all() ->
    [ha_json_light, tasmota_outlet, sensors_and_events, siren_notify_button, zigbee2mqtt_devices,
     malformed_discovery, config_removed, overrides, generated_bil_validates,
     printed_bil_reads_back, families_validate, hand_written_checks, public_description_binds,
     empty_topic_with_base, z2m_null_on_off, ha_device_discovery, prop_discovery_never_crashes,
     prop_payload_mapping_never_crashes].

%% ---------------------------------------------------------------------------
%% Home Assistant
%% ---------------------------------------------------------------------------

%% @doc An abbreviated JSON-schema light with a base topic becomes
%% TurnLightOn/TurnLightOff with JSON commands, state echoes and the
%% device's availability.
ha_json_light(_Config) ->
    {D, []} = mqtt_avatar:generate([light()], #{}),
    [#{id := <<"KitchenLight01">>, services := [On, Off], consumes := [Fb]}] = components(D),
    #{type := <<"TurnLightOn">>, parameters := OnPs} = On,
    <<"yes">> = p(<<"Light">>, OnPs),
    <<"kitchen">> = p(<<"Room">>, OnPs),
    %% The light's HA config rides in MqttLight (docs/mqtt.md 2.4).
    <<"light:on">> = p(<<"MqttCommand">>, OnPs),
    {ok, #{<<"schema">> := <<"json">>, <<"command_topic">> := <<"home/kitchen/set">>,
           <<"state_topic">> := <<"home/kitchen/state">>}} = evatar_json:decode(p(<<"MqttLight">>, OnPs)),
    <<"home/kitchen/availability">> = p(<<"MqttAvailabilityTopic">>, OnPs),
    #{type := <<"TurnLightOff">>, parameters := OffPs} = Off,
    <<"light:off">> = p(<<"MqttCommand">>, OffPs),
    #{type := <<"ACTION FEEDBACK">>, parameters := FbPs} = Fb,
    <<"LightSwitch">> = p(<<"Device">>, FbPs),
    ok = mqtt_avatar:check(D).

%% @doc HA's device-based discovery (`homeassistant/device/<id>/config',
%% HA's own example): each `cmps' entry is a component of its platform
%% `p', taking the shared keys (`dev', `stat_t', `avty_t'...) unless it
%% sets them; a bad entry is a problem and the others stay; an entry with
%% only `p' is left out; the empty config removes them all.
ha_device_discovery(_Config) ->
    Topic = <<"homeassistant/device/0AFFD2/config">>,
    Cfg = #{<<"dev">> => #{<<"ids">> => <<"0AFFD2">>, <<"name">> => <<"Hall Multisensor">>,
                           <<"mf">> => <<"Bla electronics">>, <<"sa">> => <<"Hall">>},
            <<"o">> => #{<<"name">> => <<"bla2mqtt">>, <<"sw">> => <<"2.1">>},
            <<"cmps">> =>
                #{<<"some_unique_component_id1">> =>
                      #{<<"p">> => <<"sensor">>, <<"device_class">> => <<"temperature">>,
                        <<"unit_of_measurement">> => <<"°C"/utf8>>,
                        <<"value_template">> => <<"{{ value_json.temperature }}">>,
                        <<"unique_id">> => <<"temp01ae_t">>},
                  <<"some_unique_id2">> =>
                      #{<<"p">> => <<"sensor">>, <<"device_class">> => <<"humidity">>,
                        <<"unit_of_measurement">> => <<"%">>,
                        <<"value_template">> => <<"{{ value_json.humidity }}">>,
                        <<"unique_id">> => <<"temp01ae_h">>},
                  <<"relay">> =>
                      #{<<"platform">> => <<"switch">>, <<"cmd_t">> => <<"hall/relay/set">>,
                        <<"stat_t">> => <<"hall/relay">>, <<"unique_id">> => <<"relay01">>},
                  <<"gone">> => #{<<"p">> => <<"sensor">>},
                  <<"bad">> => #{<<"p">> => <<"teleporter">>, <<"unique_id">> => <<"x">>}},
            <<"state_topic">> => <<"sensorBedroom/state">>,
            <<"avty_t">> => <<"hall/status">>, <<"qos">> => 2},
    {D, Problems} = mqtt_avatar:generate([{Topic, enc(Cfg)}], #{}),
    [#{topic := Topic, message := M}] = Problems,
    {match, _} = re:run(M, <<"component bad: platform teleporter is not supported">>),
    [#{id := <<"HallMultisensor">>, services := Services, consumes := Consumes}] = components(D),
    Streams = [C || #{category := <<"SENSOR">>} = C <- Consumes],
    Types = [T || #{type := T} <- Streams],
    true = lists:member(<<"Temperature">>, Types) andalso lists:member(<<"Humidity">>, Types),
    %% The shared state topic, the component's own template, the device's
    %% room and availability.
    [<<"sensorBedroom/state">>] = lists:usort([p(<<"MqttStateTopic">>, Ps) || #{parameters := Ps} <- Streams]),
    true = lists:member(<<"Temperature=json:temperature">>,
                        [p(<<"MqttValue">>, Ps) || #{parameters := Ps} <- Streams]),
    [<<"hall">>] = lists:usort([p(<<"Room">>, Ps) || #{parameters := Ps} <- Streams]),
    %% The switch keeps its own state topic.
    [SwPs] = [Ps || #{type := <<"TurnSwitchOn">>, parameters := Ps} <- Services]
        ++ [Ps || #{type := <<"SwitchOn">>, parameters := Ps} <- Services],
    <<"hall/relay">> = p(<<"MqttStateTopic">>, SwPs),
    <<"hall/status">> = p(<<"MqttAvailabilityTopic">>, SwPs),
    ok = mqtt_avatar:check(D),
    %% The empty config removes every component of the device.
    {D2, _} = mqtt_avatar:generate([{Topic, enc(Cfg)}, {Topic, <<>>}], #{}),
    [] = components(D2),
    %% A device config without cmps is named as such.
    {_, [#{message := M3}]} = mqtt_avatar:generate([{Topic, enc(maps:remove(<<"cmps">>, Cfg))}], #{}),
    {match, _} = re:run(M3, <<"needs cmps">>).

%% @doc A Tasmota-style plug (raw ON/OFF on cmnd/ and stat/ topics, LWT
%% with Online/Offline) becomes a socket switch whose Appliance is `any'.
tasmota_outlet(_Config) ->
    Config = #{<<"name">> => <<"Bedroom lamp">>, <<"uniq_id">> => <<"A4CF12_RL_1">>,
               <<"~">> => <<"tasmota_A4CF12">>, <<"stat_t">> => <<"stat/~/POWER">>,
               <<"cmd_t">> => <<"cmnd/~/POWER">>, <<"pl_on">> => <<"ON">>, <<"pl_off">> => <<"OFF">>,
               <<"avty_t">> => <<"tele/~/LWT">>, <<"pl_avail">> => <<"Online">>,
               <<"pl_not_avail">> => <<"Offline">>, <<"dev_cla">> => <<"outlet">>,
               <<"dev">> => #{<<"ids">> => [<<"A4CF12">>], <<"name">> => <<"Bedroom Socket Switch 01">>,
                              <<"sa">> => <<"Bedroom">>}},
    %% `~' only expands at the start or the end of a topic, as in HA.
    {D, []} = mqtt_avatar:generate([{<<"homeassistant/switch/A4CF12/RL_1/config">>, enc(Config)}], #{}),
    [#{id := <<"BedroomSocketSwitch01">>, services := [On, _Off], consumes := [Fb]}] = components(D),
    #{type := <<"SwitchSocketOn">>, parameters := Ps} = On,
    <<"any">> = p(<<"Appliance">>, Ps),
    <<"raw:ON">> = p(<<"MqttCommand">>, Ps),
    <<"raw:ON">> = p(<<"MqttExpect">>, Ps),
    <<"stat/~/POWER">> = p(<<"MqttStateTopic">>, Ps),
    <<"Online">> = p(<<"MqttPayloadAvailable">>, Ps),
    <<"Offline">> = p(<<"MqttPayloadNotAvailable">>, Ps),
    <<"SocketSwitch">> = p(<<"Device">>, maps:get(parameters, Fb)),
    %% With the base at the start, it expands.
    Config2 = Config#{<<"stat_t">> => <<"~/stat/POWER">>},
    {D2, []} = mqtt_avatar:generate([{<<"homeassistant/switch/A4CF12/RL_1/config">>, enc(Config2)}], #{}),
    [#{services := [#{parameters := Ps2} | _]}] = components(D2),
    <<"tasmota_A4CF12/stat/POWER">> = p(<<"MqttStateTopic">>, Ps2).

%% @doc Binary sensors, sensors and events of one device become one
%% component: a stream (Consumes) and a read service per entity, plus one
%% read service for the whole device.
sensors_and_events(_Config) ->
    {D, []} = mqtt_avatar:generate(time_and_keypad(), #{}),
    [Keypad, Time] = components(D),
    #{id := <<"DoorKeypad01">>, services := KS, consumes := [KC]} = Keypad,
    [<<"ReadPasswordInput">>, <<"ReadKeypad">>] = [T || #{type := T} <- KS],
    #{type := <<"PasswordInput">>, parameters := KPs} = KC,
    <<"Event">> = p(<<"MqttContext">>, KPs),
    <<"all">> = p(<<"MqttAttributes">>, KPs),
    <<"Event=json:event_type">> = p(<<"MqttValue">>, KPs),
    <<"hall">> = p(<<"Room">>, KPs),
    #{id := <<"TimeSensor01">>, services := TS, consumes := TC} = Time,
    [<<"ReadSunset">>, <<"ReadTimeOfDay">>, <<"ReadTime">>] = [T || #{type := T} <- TS],
    #{parameters := ReadTime} = lists:last(TS),
    <<"yes">> = p(<<"TimeOfDay">>, ReadTime),
    <<"yes">> = p(<<"Sunset">>, ReadTime),
    [<<"Sunset">>, <<"TimeOfDay">>] = [T || #{type := T} <- TC],
    [undefined, undefined] = [proplists:get_value(<<"MqttContext">>, Ps) || #{parameters := Ps} <- TC],
    ok = mqtt_avatar:check(D).

%% @doc Sirens, notify and buttons: request parameters become command
%% arguments, and buttons do not wait for an echo.
siren_notify_button(_Config) ->
    {D, []} = mqtt_avatar:generate(speaker_and_camera(), #{}),
    [Camera, Speaker] = components(D),
    #{services := [#{type := <<"TakePhoto">>, parameters := BPs}]} = Camera,
    <<"raw:PRESS">> = p(<<"MqttCommand">>, BPs),
    <<"none">> = p(<<"MqttExpect">>, BPs),
    #{services := [Voice, Sound], consumes := [#{parameters := Fb}]} = Speaker,
    #{type := <<"PlayVoiceMessage">>, parameters := VPs} = Voice,
    <<"Message">> = p(<<"MqttCommandArgs">>, VPs),
    #{type := <<"PlaySound">>, parameters := SPs} = Sound,
    <<"Sound=tone Volume=volume_level Duration=duration">> = p(<<"MqttCommandArgs">>, SPs),
    <<"yes">> = p(<<"Volume">>, SPs),
    <<"Speaker">> = p(<<"Device">>, Fb),
    ok = mqtt_avatar:check(D).

%% ---------------------------------------------------------------------------
%% zigbee2mqtt
%% ---------------------------------------------------------------------------

%% @doc zigbee2mqtt's bridge/devices: a light, a plug, a motion sensor with
%% a battery, a remote's action; the coordinator and a device without a
%% definition are left out (the latter with a problem).
zigbee2mqtt_devices(_Config) ->
    {D, Problems} = mqtt_avatar:generate([{<<"zigbee2mqtt/bridge/devices">>, z2m_devices()}], #{}),
    [#{message := <<"device half_joined has no definition", _/binary>>}] = Problems,
    [Bulb, Plug, Pir, Remote] = components(D),
    #{id := <<"LivingBulb">>, services := [#{parameters := LPs} | _]} = Bulb,
    <<"light:on">> = p(<<"MqttCommand">>, LPs),
    {ok, #{<<"schema">> := <<"json">>, <<"command_topic">> := <<"zigbee2mqtt/living_bulb/set">>}} =
        evatar_json:decode(p(<<"MqttLight">>, LPs)),
    <<"zigbee2mqtt/living_bulb/availability">> = p(<<"MqttAvailabilityTopic">>, LPs),
    <<"json:state">> = p(<<"MqttAvailabilityValue">>, LPs),
    #{services := [#{type := <<"SwitchSocketOn">>} | _]} = Plug,
    #{services := PirServices, consumes := PirStreams} = Pir,
    [<<"MotionDetected">>, <<"Battery">>] = [T || #{type := T} <- PirStreams],
    true = lists:member(<<"ReadMotion">>, [T || #{type := T} <- PirServices]),
    [#{parameters := MPs} | _] = PirStreams,
    <<"yes">> = p(<<"MqttOnChange">>, MPs),
    #{consumes := [#{type := <<"Action">>, parameters := RPs}]} = Remote,
    <<"Event=json:action">> = p(<<"MqttValue">>, RPs),
    ok = mqtt_avatar:check(D).

%% ---------------------------------------------------------------------------
%% Problems
%% ---------------------------------------------------------------------------

%% @doc Each malformed discovery message gives a problem naming its topic
%% and what is wrong; the good ones in the same batch still join.
malformed_discovery(_Config) ->
    Bad = [{<<"homeassistant/sensor/x/json/config">>, <<"{\"name\": ">>, <<"invalid JSON">>},
           {<<"homeassistant/sensor/x/array/config">>, <<"[1]">>, <<"not a JSON object">>},
           {<<"homeassistant/sensor/x/nostate/config">>, <<"{\"name\":\"n\"}">>, <<"needs state_topic">>},
           {<<"homeassistant/light/x/nocmd/config">>, <<"{\"name\":\"n\",\"state_topic\":\"s\"}">>,
            <<"needs command_topic">>},
           {<<"homeassistant/light/x/wild/config">>, <<"{\"command_topic\":\"a/+/b\"}">>, <<"wildcard">>},
           {<<"homeassistant/sensor/x/tpl/config">>,
            <<"{\"state_topic\":\"s\",\"value_template\":\"{{ states('sensor.x') }}\"}">>,
            <<"not supported">>},
           {<<"homeassistant/sensor/x/topic/config">>, <<"{\"state_topic\": 42}">>, <<"not a string">>},
           {<<"homeassistant/water_heater/x/boiler/config">>, <<"{}">>, <<"is not supported">>},
           {<<"homeassistant/vacuum/x/robot/config">>, <<"{}">>, <<"needs command_topic">>},
           {<<"homeassistant/select/x/noopts/config">>, <<"{\"cmd_t\":\"c\"}">>, <<"needs options">>},
           {<<"homeassistant/climate/x/tpl/config">>,
            <<"{\"mode_stat_t\":\"s\",\"mode_stat_tpl\":\"{% for x in y %}1{% endfor %}\"}">>,
            <<"not supported">>},
           {<<"homeassistant/sensor/x/utf/config">>, <<"{\"name\":\"", 255, "\"}">>, <<"invalid JSON">>},
           {<<"zigbee2mqtt/bridge/devices">>, <<"{\"not\":\"a list\"}">>, <<"not a JSON array">>}],
    {D, Problems} = mqtt_avatar:generate([light() | [{T, P} || {T, P, _} <- Bad]], #{}),
    [#{id := <<"KitchenLight01">>}] = components(D),
    Expected = lists:sort([{T, W} || {T, _, W} <- Bad]),
    Got = lists:sort([{T, M} || #{what := bad_discovery, topic := T, message := M} <- Problems]),
    N = length(Expected),
    N = length(Got),
    [] = [{T, M, W} || {{T, W}, {T, M}} <- lists:zip(Expected, Got), binary:match(M, W) =:= nomatch],
    %% Messages on other topics are not discovery.
    {_, [#{what := not_discovery}]} = mqtt_avatar:generate([{<<"home/kitchen/state">>, <<"ON">>}], #{}).

%% @doc An empty retained config removes the entity, as in HA.
config_removed(_Config) ->
    {T, _} = light(),
    {D, []} = mqtt_avatar:generate([light(), {T, <<>>}], #{}),
    [] = components(D).

%% @doc Overrides: a device gets another ComponentID and room, an entity's
%% services get parameters (here what the VA's camera emulator needs), an
%% entity is skipped, and an override that matches nothing is reported.
overrides(_Config) ->
    Overrides = #{<<"ha:hall-camera">> => #{component => <<"HallCamera01">>, room => <<"hallway">>},
                  <<"hall-camera-photo">> =>
                      #{parameters => [{<<"Count">>, <<"yes">>},
                                       {<<"MqttCommand">>, <<"json:{\"photo\":true}">>},
                                       {<<"MqttCommandArgs">>, <<"Count=count">>}]},
                  <<"hall-speaker-voice">> => #{skip => true},
                  <<"nobody">> => #{room => <<"attic">>}},
    {D, [#{what := unused_override, key := <<"nobody">>}]} =
        mqtt_avatar:generate(speaker_and_camera(), #{overrides => Overrides}),
    [Camera, Speaker] = components(D),
    #{id := <<"HallCamera01">>, services := [#{parameters := Ps}]} = Camera,
    <<"hallway">> = p(<<"Room">>, Ps),
    <<"yes">> = p(<<"Count">>, Ps),
    <<"json:{\"photo\":true}">> = p(<<"MqttCommand">>, Ps),
    #{services := [#{type := <<"PlaySound">>}]} = Speaker,
    ok = mqtt_avatar:check(D),
    %% Hand-written components win over discovered ones with the same id.
    Static = #{entity_id => <<"x">>, api_name => <<>>, entity_type => avatar, context => <<>>,
               components => [#{id => <<"KitchenLight01">>,
                                services => [#{category => <<"SENSOR">>, type => <<"Mine">>,
                                               parameters => []}],
                                consumes => []}]},
    {D2, [#{what := component_clash}]} = mqtt_avatar:generate([light()], #{description => Static}),
    [#{services := [#{type := <<"Mine">>}]}] = components(D2).

%% ---------------------------------------------------------------------------
%% Validity
%% ---------------------------------------------------------------------------

%% @doc Every generated description is valid against apps/bil/priv/bil.xsd
%% (xmerl_xsd), parses with EVATAR's parser, and so does its public form.
generated_bil_validates(Config) ->
    Messages = [light() | time_and_keypad() ++ speaker_and_camera()]
        ++ [{<<"zigbee2mqtt/bridge/devices">>, z2m_devices()}],
    {D, _} = mqtt_avatar:generate(Messages, #{entity_id => <<"mqtt-home-01">>}),
    9 = length(components(D)),
    validate(Config, [{"generated.xml", D}, {"public.xml", mqtt_avatar:public_description(D)}]).

%% @doc Every family of docs/mqtt.md section 2.3, announced in HA's format
%% (abbreviated keys) and as zigbee2mqtt exposes, gives a description
%% without problems that passes the checks and bil.xsd; the new reserved
%% parameters are checked in hand-written BIL too.
families_validate(Config) ->
    Enc = fun(M) -> evatar_json:encode(M) end,
    Dev = fun(N) -> #{<<"ids">> => [N], <<"name">> => N, <<"sa">> => <<"Living">>} end,
    Ha = [{<<"cover">>, #{<<"cmd_t">> => <<"b/set">>, <<"stat_t">> => <<"b/state">>,
                          <<"pos_t">> => <<"b/pos">>, <<"set_pos_t">> => <<"b/pos/set">>,
                          <<"tilt_cmd_t">> => <<"b/tilt/set">>, <<"tilt_status_t">> => <<"b/tilt">>,
                          <<"dev_cla">> => <<"blind">>, <<"dev">> => Dev(<<"Blind">>)}},
          {<<"valve">>, #{<<"cmd_t">> => <<"v/set">>, <<"stat_t">> => <<"v/state">>, <<"pos">> => true,
                          <<"dev">> => Dev(<<"Valve">>)}},
          {<<"climate">>, #{<<"mode_cmd_t">> => <<"ac/mode/set">>, <<"mode_stat_t">> => <<"ac/state">>,
                            <<"mode_stat_tpl">> => <<"{{ value_json.mode }}">>,
                            <<"temp_cmd_t">> => <<"ac/temp/set">>, <<"curr_temp_t">> => <<"ac/state">>,
                            <<"curr_temp_tpl">> => <<"{{ value_json.current }}">>,
                            <<"pr_mode_cmd_t">> => <<"ac/preset/set">>, <<"pr_modes">> => [<<"eco">>],
                            <<"pow_cmd_t">> => <<"ac/power">>, <<"dev">> => Dev(<<"AC">>)}},
          {<<"fan">>, #{<<"cmd_t">> => <<"f/set">>, <<"stat_t">> => <<"f/state">>,
                        <<"pct_cmd_t">> => <<"f/pct/set">>, <<"osc_cmd_t">> => <<"f/osc/set">>,
                        <<"dir_cmd_t">> => <<"f/dir/set">>, <<"dev">> => Dev(<<"Fan">>)}},
          {<<"humidifier">>, #{<<"cmd_t">> => <<"h/set">>, <<"hum_cmd_t">> => <<"h/hum/set">>,
                               <<"modes">> => [<<"eco">>], <<"mode_cmd_t">> => <<"h/mode/set">>,
                               <<"dev">> => Dev(<<"Dryer">>)}},
          {<<"lock">>, #{<<"cmd_t">> => <<"l/set">>, <<"stat_t">> => <<"l/state">>,
                         <<"dev">> => Dev(<<"Door">>)}},
          {<<"number">>, #{<<"name">> => <<"Volume">>, <<"cmd_t">> => <<"n/set">>, <<"stat_t">> => <<"n">>,
                           <<"min">> => 0, <<"max">> => 10, <<"dev">> => Dev(<<"Speaker">>)}},
          {<<"select">>, #{<<"name">> => <<"Source">>, <<"cmd_t">> => <<"s/set">>,
                           <<"ops">> => [<<"TV">>, <<"Line in">>], <<"dev">> => Dev(<<"Speaker">>)}},
          {<<"alarm_control_panel">>, #{<<"cmd_t">> => <<"a/set">>, <<"stat_t">> => <<"a/state">>,
                                        <<"code">> => <<"1234">>, <<"dev">> => Dev(<<"Alarm">>)}},
          {<<"scene">>, #{<<"name">> => <<"Movie night">>, <<"cmd_t">> => <<"sc/set">>}},
          {<<"vacuum">>, #{<<"cmd_t">> => <<"vac/cmd">>, <<"stat_t">> => <<"vac/state">>,
                           <<"set_fan_spd_t">> => <<"vac/fan">>, <<"fanspd_lst">> => [<<"min">>],
                           <<"dev">> => Dev(<<"Robot">>)}}],
    Exposes = [#{<<"type">> => <<"cover">>,
                 <<"features">> => [#{<<"name">> => <<"state">>, <<"property">> => <<"state">>,
                                      <<"access">> => 3},
                                    #{<<"name">> => <<"position">>, <<"property">> => <<"position">>,
                                      <<"access">> => 7}]},
               #{<<"type">> => <<"lock">>,
                 <<"features">> => [#{<<"name">> => <<"state">>, <<"property">> => <<"state">>,
                                      <<"access">> => 7, <<"value_on">> => <<"LOCK">>}]},
               #{<<"type">> => <<"climate">>,
                 <<"features">> => [#{<<"name">> => <<"system_mode">>, <<"property">> => <<"system_mode">>,
                                      <<"access">> => 7, <<"values">> => [<<"off">>, <<"heat">>]},
                                    #{<<"name">> => <<"local_temperature">>,
                                      <<"property">> => <<"local_temperature">>, <<"access">> => 1}]},
               #{<<"type">> => <<"numeric">>, <<"name">> => <<"countdown">>, <<"property">> => <<"countdown">>,
                 <<"access">> => 7, <<"value_min">> => 0, <<"value_max">> => 100}],
    Z2m = Enc([#{<<"friendly_name">> => <<"multi">>, <<"ieee_address">> => <<"0x1">>,
                 <<"definition">> => #{<<"model">> => <<"M">>, <<"exposes">> => Exposes}}]),
    Messages = [{<<"homeassistant/", C/binary, "/x/", C/binary, "/config">>, Enc(Cfg)} || {C, Cfg} <- Ha]
        ++ [{<<"zigbee2mqtt/bridge/devices">>, Z2m}],
    {D, []} = mqtt_avatar:generate(Messages, #{entity_id => <<"families">>}),
    ok = mqtt_avatar:check(D),
    Types = [T || #{services := S} <- components(D), #{type := T} <- S],
    [] = [<<"OpenCover">>, <<"SetValvePosition">>, <<"SetHvacMode">>, <<"TurnClimateOn">>,
          <<"SetFanPercentage">>, <<"StartFanOscillation">>, <<"SetHumidifierMode">>, <<"Lock">>,
          <<"SetVolume">>, <<"SelectSource">>, <<"ArmAway">>, <<"ActivateMovieNight">>,
          <<"SetVacuumFanSpeed">>, <<"SetCountdown">>] -- Types,
    %% An option with a space is listed percent-encoded, so still checked.
    [Select] = [E || #{services := S} <- components(D), #{type := <<"SelectSource">>} = E <- S],
    <<"Option=TV|Line%20in">> = p(<<"MqttArgCheck">>, maps:get(parameters, Select)),
    validate(Config, [{"families.xml", D}, {"families-public.xml", mqtt_avatar:public_description(D)}]),
    %% The new reserved parameters, written wrong by hand.
    Entry = fun(Ps) -> #{category => <<"ACTUATOR">>, type => <<"Set">>,
                         parameters => [{<<"MqttCommandTopic">>, <<"c">>}, {<<"MqttCommand">>, <<"raw:">>}
                                        | Ps]} end,
    Bad = #{entity_id => <<"x">>, api_name => <<>>, entity_type => avatar, context => <<>>,
            components => [#{id => <<"C">>, consumes => [],
                             services => [Entry([{<<"MqttArgCheck">>, <<"Value=10..1">>}]),
                                          Entry([{<<"MqttCode">>, <<"1234">>}]),
                                          Entry([{<<"MqttExtra">>, <<"Unit">>}])]}]},
    {error, Problems} = mqtt_avatar:check(Bad),
    [<<"MqttArgCheck">>, <<"MqttCode">>, <<"MqttExtra">>] = lists:sort([N || #{parameter := N} <- Problems]).

validate(Config, Descriptions) ->
    {ok, Schema} = xmerl_xsd:process_schema(filename:join(code:priv_dir(bil), "bil.xsd")),
    Dir = ?config(priv_dir, Config),
    lists:foreach(
      fun({Name, Desc}) ->
              File = filename:join(Dir, Name),
              ok = file:write_file(File, bil:encode_description(Desc)),
              %% Our own output only: xmerl_scan makes atoms of element names.
              {Element, _} = xmerl_scan:file(File),
              case xmerl_xsd:validate(Element, Schema) of
                  {#xmlElement{}, _} -> ok;
                  {error, Errors} -> ct:fail({invalid, Name, Errors})
              end,
              {ok, Desc} = bil:parse_description(iolist_to_binary(bil:encode_description(Desc)))
      end, Descriptions).

%% @doc The printed (indented) BIL reads back to the same description, so
%% a person can save, edit and load it.
printed_bil_reads_back(Config) ->
    {D, _} = mqtt_avatar:generate([light() | time_and_keypad()], #{}),
    Xml = mqtt_avatar:description_xml(D),
    true = length(binary:split(Xml, <<"\n">>, [global])) > 50,
    File = filename:join(?config(priv_dir, Config), "edited.xml"),
    ok = file:write_file(File, Xml),
    {ok, D} = mqtt_avatar:read_description(File),
    {error, <<_/binary>>} = mqtt_avatar:read_description(filename:join(?config(priv_dir, Config), "none.xml")).

%% @doc Mistakes in hand-written Mqtt* parameters are found, each with its
%% component, entry and parameter.
hand_written_checks(_Config) ->
    Entry = fun(Type, Ps) -> #{category => <<"ACTUATOR">>, type => Type, parameters => Ps} end,
    D = #{entity_id => <<"x">>, api_name => <<>>, entity_type => avatar, context => <<>>,
          components =>
              [#{id => <<"C1">>,
                 services => [Entry(<<"A">>, [{<<"MqttCommand">>, <<"raw:ON">>}]),
                              Entry(<<"B">>, [{<<"MqttCommandTopic">>, <<"x/#">>},
                                              {<<"MqttCommand">>, <<"json:{bad">>}]),
                              Entry(<<"C">>, [{<<"MqttCommandTopic">>, <<"x">>},
                                              {<<"MqttCommand">>, <<"ON">>},
                                              {<<"MqttExpect">>, <<"raw:ON">>}])],
                 consumes => [Entry(<<"D">>, [{<<"MqttValue">>, <<"Temp=xml:a">>},
                                              {<<"MqttStateTopic">>, <<"s">>},
                                              {<<"MqttContext">>, <<"Sometimes">>},
                                              {<<"MqttColour">>, <<"red">>}])]}]},
    {error, Problems} = mqtt_avatar:check(D),
    Found = lists:sort([{E, P} || #{entry := E, parameter := P} <- Problems]),
    Expected = lists:sort([{<<"Service ACTUATOR/A">>, <<"MqttCommandTopic">>},
                           {<<"Service ACTUATOR/B">>, <<"MqttCommandTopic">>},
                           {<<"Service ACTUATOR/B">>, <<"MqttCommand">>},
                           {<<"Service ACTUATOR/C">>, <<"MqttCommand">>},
                           {<<"Consumes ACTUATOR/D">>, <<"MqttValue">>},
                           {<<"Consumes ACTUATOR/D">>, <<"MqttContext">>},
                           {<<"Consumes ACTUATOR/D">>, <<"MqttColour">>}]),
    %% A inherits B's wildcard command topic; C inherits D's state topic,
    %% so only C's command is wrong.
    Expected = Found,
    true = lists:all(fun(#{message := M}) -> byte_size(M) > 10 end, Problems).

%% @doc The public description (no Mqtt* parameters) binds with a VA as a
%% hand-written one would: the sensors' Consumes entries carry no MQTT
%% constraint.
public_description_binds(_Config) ->
    {D, _} = mqtt_avatar:generate([light() | time_and_keypad()], #{}),
    Public = mqtt_avatar:public_description(D),
    [] = [N || #{services := S, consumes := C} <- components(Public), #{parameters := Ps} <- S ++ C,
               {<<"Mqtt", _/binary>> = N, _} <- Ps],
    {ok, Va} = bil:parse_description(read_example("smart_home_va.xml")),
    #{bound := Bound} = bil:bind([Va, Public]),
    Pairs = lists:sort([{C, P} || #{consumer := #{component := C}, provider := #{component := P}}
                                      <- Bound]),
    true = lists:member({<<"KitchenLightEmulator01">>, <<"KitchenLight01">>}, Pairs),
    true = lists:member({<<"KitchenLight01">>, <<"KitchenLightEmulator01">>}, Pairs),
    true = lists:member({<<"TimeEmulator01">>, <<"TimeSensor01">>}, Pairs),
    true = lists:member({<<"TimeSensor01">>, <<"TimeEmulator01">>}, Pairs),
    true = lists:member({<<"DoorKeypad01">>, <<"KeypadEmulator01">>}, Pairs),
    true = lists:member({<<"KeypadEmulator01">>, <<"DoorKeypad01">>}, Pairs).

%% ---------------------------------------------------------------------------
%% Properties
%% ---------------------------------------------------------------------------

%% @doc An empty topic next to a `~' base topic is a problem, not a crash
%% (found by prop_discovery_never_crashes).
empty_topic_with_base(_Config) ->
    Payload = evatar_json:encode(
                                 #{<<"stat_t">> => <<>>, <<"~">> => <<"a/b">>,
                                   <<"availability_topic">> => <<"a/b">>}),
    {_Desc, Problems} = mqtt_avatar:generate([{<<"homeassistant/light/o/config">>, Payload}], #{}),
    true = is_list(Problems).

%% @doc A zigbee2mqtt on/off feature whose value_on and value_off are null
%% (a fan's state, a switch's) is commanded with the usual ON and OFF, and
%% read as a sensor when exposed alone; the generation crashed with badarg
%% (found by prop_discovery_never_crashes, 1 run in about 6,000).
z2m_null_on_off(_Config) ->
    State = #{<<"access">> => 7, <<"name">> => <<"state">>, <<"property">> => <<"state">>,
              <<"type">> => <<"binary">>, <<"value_on">> => null, <<"value_off">> => null},
    OnOff = [<<"json:{\"state\":\"OFF\"}">>, <<"json:{\"state\":\"ON\"}">>],
    %% (exposed alone, the feature is read, not commanded)
    Exposes = [{[#{<<"type">> => <<"fan">>, <<"features">> => [State]}], OnOff},
               {[#{<<"type">> => <<"switch">>, <<"features">> => [State]}], OnOff},
               {[State], []}],
    [begin
         Devices = evatar_json:encode(
                                      [#{<<"friendly_name">> => <<"kitchen_thing">>,
                                         <<"definition">> => #{<<"exposes">> => Es}}]),
         {D, []} = mqtt_avatar:generate([{<<"zigbee2mqtt/bridge/devices">>, Devices}], #{}),
         [#{services := Services}] = components(D),
         Commands = [C || #{parameters := Ps} <- Services, {<<"MqttCommand">>, C} <- Ps],
         Want = lists:usort(Commands),
         ok = mqtt_avatar:check(D)
     end || {Es, Want} <- Exposes],
    ok.

%% @doc Discovery configs built from HA's keys with random values (and
%% random topics) give an entity, a problem or `ignore', never an exception;
%% so do random zigbee2mqtt device lists.
prop_discovery_never_crashes(_Config) ->
    Keys = [<<"name">>, <<"unique_id">>, <<"state_topic">>, <<"command_topic">>, <<"stat_t">>,
            <<"cmd_t">>, <<"~">>, <<"availability_topic">>, <<"availability">>, <<"value_template">>,
            <<"payload_on">>, <<"device_class">>, <<"device">>, <<"dev">>, <<"schema">>,
            <<"json_attributes_topic">>, <<"payload_press">>, <<"support_volume_set">>,
            %% the other families' keys
            <<"position_topic">>, <<"set_pos_t">>, <<"tilt_cmd_t">>, <<"position_open">>,
            <<"mode_cmd_t">>, <<"mode_stat_t">>, <<"modes">>, <<"temp_cmd_t">>, <<"min_temp">>,
            <<"max_temp">>, <<"pct_cmd_t">>, <<"osc_cmd_t">>, <<"pr_modes">>, <<"options">>,
            <<"min">>, <<"max">>, <<"code">>, <<"supported_features">>, <<"reports_position">>,
            <<"fan_speed_list">>, <<"set_fan_speed_topic">>, <<"payload_lock">>, <<"state_locked">>],
    Value = oneof([binary(), <<"~/x">>, <<"{{ value_json.a }}">>, <<"a/+/b">>, int(), real(), bool(),
                   null, exactly([]), exactly([#{<<"topic">> => <<"t">>}]),
                   exactly([<<"a">>, <<"b c">>, 1]), list(binary()),
                   exactly(#{<<"ids">> => [<<"i">>], <<"name">> => <<"n">>})]),
    Topic = ?LET({C, Rest}, {oneof([elements(mqtt_avatar_ha:components()), binary()]),
                             oneof([[<<"o">>, <<"config">>], [<<"n">>, <<"o">>, <<"config">>],
                                    list(binary())])},
                 iolist_to_binary(lists:join(<<"/">>, [<<"homeassistant">>, C | Rest]))),
    P = ?FORALL({T, Pairs}, {Topic, list({elements(Keys), Value})},
                begin
                    Payload = evatar_json:encode(maps:from_list(Pairs)),
                    {Desc, Problems} = mqtt_avatar:generate([{T, Payload}], #{}),
                    is_list(Problems) andalso
                        (components(Desc) =:= [] orelse mqtt_avatar:check(Desc) =:= ok)
                end),
    ok = evatar_test_proper:check(P, 500),
    Feature = ?LET({N, A, Extra}, {oneof([<<"state">>, <<"position">>, <<"system_mode">>,
                                          <<"local_temperature">>, <<"mode">>, binary()]),
                                   oneof([1, 3, 5, 7, binary()]),
                                   oneof([#{}, #{<<"value_min">> => 30, <<"value_max">> => 5},
                                          #{<<"values">> => [<<"a">>, 1, null]},
                                          #{<<"value_on">> => null}])},
                   maps:merge(#{<<"name">> => N, <<"property">> => N, <<"access">> => A}, Extra)),
    Expose = ?LET({T, Prop, A, Fs}, {oneof([<<"binary">>, <<"numeric">>, <<"light">>, <<"enum">>,
                                            <<"cover">>, <<"climate">>, <<"lock">>, <<"fan">>,
                                            binary()]),
                                     oneof([<<"occupancy">>, <<"state">>, binary()]),
                                     oneof([1, 7]), list(Feature)},
                  #{<<"type">> => T, <<"property">> => Prop, <<"access">> => A,
                    <<"features">> => Fs}),
    Device = ?LET({Name, Exposes}, {oneof([<<"pir">>, binary()]), list(Expose)},
                  #{<<"friendly_name">> => Name, <<"definition">> => #{<<"exposes">> => Exposes}}),
    Z = ?FORALL(B, oneof([binary(), ?LET(L, list(Device), evatar_json:encode(L))]),
                begin
                    {Desc, _} = mqtt_avatar:generate([{<<"zigbee2mqtt/bridge/devices">>, B}], #{}),
                    components(Desc) =:= [] orelse mqtt_avatar:check(Desc) =:= ok
                end),
    ok = evatar_test_proper:check(Z, 300).

%% @doc Any payload on a state topic gives parameters BIL can carry, or a
%% readable error; never an exception.
prop_payload_mapping_never_crashes(_Config) ->
    Mapping = #{values => [{<<"A">>, raw}, {<<"B">>, {json, [<<"b">>]}}],
                attributes => true, map => [{<<"on">>, <<"yes">>}]},
    Json = ?LET(Pairs, list({oneof([binary(), <<"b">>, <<"on_off">>, <<"9lives">>]),
                             oneof([binary(), int(), real(), bool(), null, list(int()),
                                    ?LET(I, int(), #{<<"x">> => I})])}),
                evatar_json:encode(maps:from_list(Pairs))),
    P = ?FORALL(Payload, oneof([binary(), Json]),
                case mqtt_avatar_logic:extract(Mapping, Payload) of
                    {ok, Params} ->
                        Names = [N || {N, _} <- Params],
                        Signal = #{id => <<"s1">>, context => sensor_data, sender => <<"a">>,
                                   receiver => <<"b">>, in_reply_to => undefined, timestamp => 1,
                                   seq => undefined, epoch => undefined,
                                   body => #{category => <<"SENSOR">>, type => <<"T">>,
                                             parameters => Params}},
                        length(Names) =:= length(lists:usort(Names))
                            andalso lists:all(fun mqtt_avatar_spec:is_name/1, Names)
                            andalso element(1, bil:parse_signal(
                                                 iolist_to_binary(bil:encode_signal(Signal)))) =:= ok;
                    {error, M} ->
                        is_binary(M)
                end),
    ok = evatar_test_proper:check(P, 500).

%% ---------------------------------------------------------------------------
%% Fixtures: what devices publish
%% ---------------------------------------------------------------------------

light() ->
    {<<"homeassistant/light/kitchen/light/config">>,
     enc(#{<<"name">> => null, <<"uniq_id">> => <<"kitchen-light">>, <<"~">> => <<"home/kitchen">>,
           <<"stat_t">> => <<"~/state">>, <<"cmd_t">> => <<"~/set">>, <<"schema">> => <<"json">>,
           <<"avty_t">> => <<"~/availability">>,
           <<"dev">> => #{<<"ids">> => [<<"kitchen-light-dev">>], <<"name">> => <<"Kitchen Light 01">>,
                          <<"sa">> => <<"Kitchen">>, <<"mdl">> => <<"LightSwitch">>}})}.

time_and_keypad() ->
    TimeDev = #{<<"identifiers">> => [<<"time">>], <<"name">> => <<"Time Sensor 01">>,
                <<"model">> => <<"Time">>},
    KeypadDev = #{<<"identifiers">> => [<<"keypad">>], <<"name">> => <<"Door Keypad 01">>,
                  <<"model">> => <<"Keypad">>, <<"suggested_area">> => <<"Hall">>},
    [{<<"homeassistant/sensor/time/time_of_day/config">>,
      enc(#{<<"name">> => <<"Time of day">>, <<"unique_id">> => <<"time-tod">>,
            <<"state_topic">> => <<"home/time/time_of_day">>,
            <<"value_template">> => <<"{{ value_json.time_of_day }}">>,
            <<"json_attributes_topic">> => <<"home/time/time_of_day">>, <<"device">> => TimeDev})},
     {<<"homeassistant/sensor/time/sunset/config">>,
      enc(#{<<"name">> => <<"Sunset">>, <<"unique_id">> => <<"time-sunset">>,
            <<"state_topic">> => <<"home/time/sunset">>,
            <<"value_template">> => <<"{{ value_json.sunset }}">>, <<"device">> => TimeDev})},
     {<<"homeassistant/event/keypad/password/config">>,
      enc(#{<<"name">> => <<"Password input">>, <<"unique_id">> => <<"keypad-password">>,
            <<"state_topic">> => <<"home/keypad/event">>,
            <<"event_types">> => [<<"password_right">>, <<"password_wrong">>],
            <<"device">> => KeypadDev})}].

speaker_and_camera() ->
    Speaker = #{<<"ids">> => <<"hall-speaker">>, <<"name">> => <<"Hall Speaker 01">>,
                <<"mdl">> => <<"Speaker">>, <<"sa">> => <<"Hall">>},
    Camera = #{<<"ids">> => <<"hall-camera">>, <<"name">> => <<"Hall Camera 01">>,
               <<"mdl">> => <<"Camera">>, <<"sa">> => <<"Hall">>},
    [{<<"homeassistant/siren/speaker/sound/config">>,
      enc(#{<<"name">> => <<"Play sound">>, <<"uniq_id">> => <<"hall-speaker-sound">>,
            <<"cmd_t">> => <<"home/speaker/siren/set">>, <<"stat_t">> => <<"home/speaker/siren">>,
            <<"av_tones">> => [<<"alarm">>, <<"chime">>], <<"sup_vol">> => true,
            <<"sup_dur">> => true, <<"dev">> => Speaker})},
     {<<"homeassistant/notify/speaker/voice/config">>,
      enc(#{<<"name">> => <<"Play voice message">>, <<"uniq_id">> => <<"hall-speaker-voice">>,
            <<"cmd_t">> => <<"home/speaker/say">>, <<"dev">> => Speaker})},
     {<<"homeassistant/button/camera/photo/config">>,
      enc(#{<<"name">> => <<"Take photo">>, <<"uniq_id">> => <<"hall-camera-photo">>,
            <<"cmd_t">> => <<"home/camera/photo">>, <<"dev">> => Camera})}].

z2m_devices() ->
    Light = #{<<"type">> => <<"light">>,
              <<"features">> => [#{<<"type">> => <<"binary">>, <<"name">> => <<"state">>,
                                   <<"property">> => <<"state">>, <<"access">> => 7,
                                   <<"value_on">> => <<"ON">>, <<"value_off">> => <<"OFF">>},
                                 #{<<"type">> => <<"numeric">>, <<"name">> => <<"brightness">>,
                                   <<"property">> => <<"brightness">>, <<"access">> => 7}]},
    Switch = Light#{<<"type">> => <<"switch">>},
    enc([#{<<"type">> => <<"Coordinator">>, <<"friendly_name">> => <<"Coordinator">>,
           <<"ieee_address">> => <<"0x00">>, <<"definition">> => null},
         #{<<"friendly_name">> => <<"living_bulb">>, <<"ieee_address">> => <<"0x01">>,
           <<"definition">> => #{<<"model">> => <<"LED1545G12">>, <<"description">> => <<"bulb">>,
                                 <<"exposes">> => [Light, #{<<"type">> => <<"numeric">>,
                                                            <<"name">> => <<"linkquality">>,
                                                            <<"property">> => <<"linkquality">>,
                                                            <<"access">> => 0}]}},
         #{<<"friendly_name">> => <<"bedroom_plug">>, <<"ieee_address">> => <<"0x02">>,
           <<"definition">> => #{<<"model">> => <<"ZNCZ02LM">>,
                                 <<"description">> => <<"Mi power plug ZigBee">>,
                                 <<"exposes">> => [Switch]}},
         #{<<"friendly_name">> => <<"hall_pir">>, <<"ieee_address">> => <<"0x03">>,
           <<"definition">> => #{<<"model">> => <<"RTCGQ11LM">>,
                                 <<"exposes">> => [#{<<"type">> => <<"binary">>, <<"name">> => <<"occupancy">>,
                                                     <<"property">> => <<"occupancy">>, <<"access">> => 1,
                                                     <<"value_on">> => true, <<"value_off">> => false},
                                                   #{<<"type">> => <<"numeric">>, <<"name">> => <<"battery">>,
                                                     <<"property">> => <<"battery">>, <<"access">> => 1}]}},
         #{<<"friendly_name">> => <<"remote">>, <<"ieee_address">> => <<"0x04">>,
           <<"definition">> => #{<<"model">> => <<"E1524">>,
                                 <<"exposes">> => [#{<<"type">> => <<"enum">>, <<"name">> => <<"action">>,
                                                     <<"property">> => <<"action">>, <<"access">> => 1,
                                                     <<"values">> => [<<"toggle">>]}]}},
         #{<<"friendly_name">> => <<"half_joined">>, <<"ieee_address">> => <<"0x05">>,
           <<"definition">> => null}]).

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

enc(Term) -> evatar_json:encode(Term).

components(#{components := C}) -> C.

p(Name, Params) ->
    case lists:keyfind(Name, 1, Params) of
        {_, V} -> V;
        false -> ct:fail({missing_parameter, Name, Params})
    end.

read_example(Name) ->
    {ok, B} = file:read_file(filename:join([code:priv_dir(bil), "examples", Name])),
    B.

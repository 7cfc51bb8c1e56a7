%% Common Test suite of the device families beyond lights and switches
%% (docs/mqtt.md section 2.4) against a real mosquitto, a real EVATAR node
%% with its bridge listener, and a VA joined over TCP with
%% agent_bridge_client. Each family is announced as Home Assistant
%% announces it (and as zigbee2mqtt does, where it has the expose), played
%% by test devices that behave like the real thing: they apply commands
%% and publish their new state, as a cover that goes opening then open, a
%% lock that goes locking then locked, an alarm that goes arming then armed.
-module(mqtt_avatar_families_SUITE).

-import(mqtt_avatar_test_setup, [entry/3]).
-import(evatar_test_wait, [until/1]).

-define(LIVE_LISTENER, mqtt_families_suite).
-define(LIVE_CASE_PREFIX, "").
-define(LIVE_FEEDBACK_MS, 3000).
-import(mqtt_avatar_test_setup, [param/2]).
-include("mqtt_avatar_live_suite.hrl").

all() ->
    [covers_and_valves, climate_and_humidifier, fan, lock_and_alarm, alarm_with_remote_code,
     number_select_scene, vacuum, sensors_named_by_what_they_are, zigbee2mqtt_families].

%% ---------------------------------------------------------------------------
%% Cases
%% ---------------------------------------------------------------------------

%% A blind (state, position and tilt topics) and a water valve: open,
%% stop, position and tilt requests reach the device, which moves and
%% says so; feedback and streams carry its state; out-of-range positions
%% are refused before anything is published.
covers_and_valves(Config) ->
    P = ?config(prefix, Config),
    T = fun(S) -> <<P/binary, "/blind/", S/binary>> end,
    Blind = device(Config, [{<<"cover">>, <<"blind">>,
                             #{<<"name">> => null, <<"dev_cla">> => <<"blind">>,
                               <<"cmd_t">> => T(<<"set">>), <<"stat_t">> => T(<<"state">>),
                               <<"pos_t">> => T(<<"position">>), <<"set_pos_t">> => T(<<"position/set">>),
                               <<"tilt_cmd_t">> => T(<<"tilt/set">>), <<"tilt_status_t">> => T(<<"tilt">>),
                               <<"dev">> => dev(P, <<"Living Blind">>, <<"Living">>)}}],
                   [T(<<"set">>), T(<<"position/set">>), T(<<"tilt/set">>)],
                   fun(Topic, Cmd) -> blind(T, Topic, Cmd) end),
    V = fun(S) -> <<P/binary, "/valve/", S/binary>> end,
    _Valve = device(Config, [{<<"valve">>, <<"valve">>,
                              #{<<"name">> => null, <<"cmd_t">> => V(<<"set">>),
                                <<"stat_t">> => V(<<"state">>),
                                <<"dev">> => dev(P, <<"Garden Valve">>, <<"Garden">>)}}],
                    [V(<<"set">>)],
                    fun(_, <<"OPEN">>) -> [{V(<<"state">>), <<"opening">>}, {V(<<"state">>), <<"open">>}];
                       (_, <<"CLOSE">>) -> [{V(<<"state">>), <<"closed">>}]
                    end),
    _A = avatar(Config),
    Va = va(Config, [<<"OpenCover">>, <<"StopCover">>, <<"SetCoverPosition">>, <<"SetCoverTilt">>,
                     <<"ReadCover">>, <<"OpenValve">>, <<"CloseValve">>],
            [<<"CoverState">>, <<"CoverPosition">>, <<"CoverTilt">>, <<"ValveState">>]),
    Cover = provider(Va, <<"OpenCover">>),
    <<"LivingBlind">> = Cover,
    %% Open: done at the first state the cover publishes (it starts moving).
    Fb = ok(request(Va, Cover, <<"OpenCover">>, [])),
    <<"OpenCover">> = param(<<"Service">>, Fb),
    <<"opening">> = param(<<"State">>, Fb),
    <<"living">> = param(<<"Room">>, Fb),
    %% (in the order the cover published them)
    <<"100">> = param(<<"Position">>, stream(Va, <<"CoverPosition">>, <<"Position">>, <<"100">>)),
    <<"open">> = param(<<"State">>, stream(Va, <<"CoverState">>, <<"State">>, <<"open">>)),
    <<"stopped">> = param(<<"State">>, ok(request(Va, Cover, <<"StopCover">>, []))),
    <<"40">> = param(<<"Position">>, ok(request(Va, Cover, <<"SetCoverPosition">>,
                                                [{<<"Position">>, <<"40">>}]))),
    <<"30">> = param(<<"Tilt">>, ok(request(Va, Cover, <<"SetCoverTilt">>, [{<<"Tilt">>, <<"30">>}]))),
    Before = mqtt_avatar_test_device:commands(Blind),
    <<"BadParameter">> = error_code(request(Va, Cover, <<"SetCoverPosition">>,
                                            [{<<"Position">>, <<"140">>}])),
    <<"BadParameter">> = error_code(request(Va, Cover, <<"SetCoverPosition">>, [])),
    Before = mqtt_avatar_test_device:commands(Blind),
    [{_, <<"OPEN">>}, {_, <<"STOP">>}, {_, <<"40">>}, {_, <<"30">>}] = Before,
    Read = ok(request(Va, Cover, <<"ReadCover">>, [], <<"SENSOR">>)),
    <<"30">> = param(<<"Tilt">>, Read),
    <<"40">> = param(<<"Position">>, Read),
    %% The valve.
    Valve = provider(Va, <<"OpenValve">>),
    <<"GardenValve">> = Valve,
    <<"opening">> = param(<<"State">>, ok(request(Va, Valve, <<"OpenValve">>, []))),
    <<"open">> = param(<<"State">>, stream(Va, <<"ValveState">>, <<"State">>, <<"open">>)),
    <<"closed">> = param(<<"State">>, ok(request(Va, Valve, <<"CloseValve">>, []))).

blind(T, Topic, Cmd) ->
    Set = T(<<"set">>), PosSet = T(<<"position/set">>), TiltSet = T(<<"tilt/set">>),
    case {Topic, Cmd} of
        {Set, <<"OPEN">>} -> [{T(<<"state">>), <<"opening">>}, {T(<<"position">>), <<"100">>},
                              {T(<<"state">>), <<"open">>}];
        {Set, <<"CLOSE">>} -> [{T(<<"state">>), <<"closing">>}, {T(<<"position">>), <<"0">>},
                               {T(<<"state">>), <<"closed">>}];
        {Set, <<"STOP">>} -> [{T(<<"state">>), <<"stopped">>}];
        {PosSet, N} -> [{T(<<"position">>), N}];
        {TiltSet, N} -> [{T(<<"tilt">>), N}]
    end.

%% A heat pump (mode, target temperature with low/high, fan, swing and
%% preset topics, the current temperature in a JSON reading) and a
%% dehumidifier: every setting is applied by the device and confirmed by
%% its state; values outside the device's modes or range are refused.
climate_and_humidifier(Config) ->
    P = ?config(prefix, Config),
    T = fun(S) -> <<P/binary, "/hp/", S/binary>> end,
    Settings = [<<"mode">>, <<"temp">>, <<"temp_lo">>, <<"temp_hi">>, <<"fan">>, <<"swing">>,
                <<"preset">>],
    _Hp = device(Config, [{<<"climate">>, <<"hp">>,
                           #{<<"name">> => null,
                             <<"mode_cmd_t">> => T(<<"mode/set">>), <<"mode_stat_t">> => T(<<"mode">>),
                             <<"modes">> => [<<"off">>, <<"heat">>, <<"cool">>],
                             <<"temp_cmd_t">> => T(<<"temp/set">>), <<"temp_stat_t">> => T(<<"temp">>),
                             <<"temp_lo_cmd_t">> => T(<<"temp_lo/set">>),
                             <<"temp_lo_stat_t">> => T(<<"temp_lo">>),
                             <<"temp_hi_cmd_t">> => T(<<"temp_hi/set">>),
                             <<"temp_hi_stat_t">> => T(<<"temp_hi">>),
                             <<"min_temp">> => 16, <<"max_temp">> => 30,
                             <<"curr_temp_t">> => T(<<"sensor">>),
                             %% (a template only the evaluator reads: tenths of a degree)
                             <<"curr_temp_tpl">> => <<"{{ value_json.tenths / 10 }}">>,
                             <<"fan_mode_cmd_t">> => T(<<"fan/set">>), <<"fan_mode_stat_t">> => T(<<"fan">>),
                             <<"swing_mode_cmd_t">> => T(<<"swing/set">>),
                             <<"swing_mode_stat_t">> => T(<<"swing">>),
                             <<"pr_mode_cmd_t">> => T(<<"preset/set">>), <<"pr_mode_stat_t">> => T(<<"preset">>),
                             <<"pr_modes">> => [<<"eco">>, <<"boost">>],
                             <<"dev">> => dev(P, <<"Living Heat Pump">>, <<"Living">>)}}],
                  [T(<<S/binary, "/set">>) || S <- Settings],
                  fun(Topic, Cmd) -> [{binary:part(Topic, 0, byte_size(Topic) - 4), Cmd}] end),
    H = fun(S) -> <<P/binary, "/dry/", S/binary>> end,
    _Dry = device(Config, [{<<"humidifier">>, <<"dry">>,
                            #{<<"name">> => null, <<"dev_cla">> => <<"dehumidifier">>,
                              <<"cmd_t">> => H(<<"set">>), <<"stat_t">> => H(<<"state">>),
                              <<"hum_cmd_t">> => H(<<"hum/set">>), <<"hum_stat_t">> => H(<<"hum">>),
                              <<"min_hum">> => 30, <<"max_hum">> => 80,
                              <<"mode_cmd_t">> => H(<<"mode/set">>), <<"mode_stat_t">> => H(<<"mode">>),
                              <<"modes">> => [<<"normal">>, <<"laundry">>],
                              <<"dev">> => dev(P, <<"Cellar Dryer">>, <<"Cellar">>)}}],
                   [H(<<"set">>), H(<<"hum/set">>), H(<<"mode/set">>)],
                   fun(Topic, Cmd) ->
                           case binary:split(Topic, <<"/set">>) of
                               [Base, <<>>] when Base =:= <<P/binary, "/dry">> -> [{H(<<"state">>), Cmd}];
                               [Base, <<>>] -> [{Base, Cmd}]
                           end
                   end),
    Dev = device(Config, [], [], undefined),
    _A = avatar(Config),
    Va = va(Config, [<<"SetHvacMode">>, <<"SetTargetTemperature">>, <<"SetTargetTemperatureLow">>,
                     <<"SetTargetTemperatureHigh">>, <<"SetFanMode">>, <<"SetSwingMode">>,
                     <<"SetClimatePresetMode">>, <<"TurnHumidifierOn">>, <<"SetTargetHumidity">>,
                     <<"SetHumidifierMode">>],
            [<<"ClimateCurrentTemperature">>, <<"ClimateHvacMode">>, <<"HumidifierState">>]),
    Hp = provider(Va, <<"SetHvacMode">>),
    <<"LivingHeatPump">> = Hp,
    <<"heat">> = param(<<"HvacMode">>, ok(request(Va, Hp, <<"SetHvacMode">>,
                                                  [{<<"HvacMode">>, <<"heat">>}]))),
    <<"heat">> = param(<<"HvacMode">>, stream(Va, <<"ClimateHvacMode">>, <<"HvacMode">>, <<"heat">>)),
    <<"BadParameter">> = error_code(request(Va, Hp, <<"SetHvacMode">>, [{<<"HvacMode">>, <<"sauna">>}])),
    <<"21.5">> = param(<<"TargetTemperature">>,
                       ok(request(Va, Hp, <<"SetTargetTemperature">>,
                                  [{<<"TargetTemperature">>, <<"21.5">>}]))),
    <<"BadParameter">> = error_code(request(Va, Hp, <<"SetTargetTemperature">>,
                                            [{<<"TargetTemperature">>, <<"45">>}])),
    <<"18">> = param(<<"TargetTemperatureLow">>,
                     ok(request(Va, Hp, <<"SetTargetTemperatureLow">>,
                                [{<<"TargetTemperatureLow">>, <<"18">>}]))),
    <<"26">> = param(<<"TargetTemperatureHigh">>,
                     ok(request(Va, Hp, <<"SetTargetTemperatureHigh">>,
                                [{<<"TargetTemperatureHigh">>, <<"26">>}]))),
    <<"high">> = param(<<"FanMode">>, ok(request(Va, Hp, <<"SetFanMode">>,
                                                 [{<<"FanMode">>, <<"high">>}]))),
    <<"on">> = param(<<"SwingMode">>, ok(request(Va, Hp, <<"SetSwingMode">>,
                                                 [{<<"SwingMode">>, <<"on">>}]))),
    <<"eco">> = param(<<"PresetMode">>, ok(request(Va, Hp, <<"SetClimatePresetMode">>,
                                                   [{<<"PresetMode">>, <<"eco">>}]))),
    ok = mqtt_avatar_test_device:publish(Dev, T(<<"sensor">>), <<"{\"tenths\": 195}">>, false),
    <<"19.5">> = param(<<"CurrentTemperature">>, stream(Va, <<"ClimateCurrentTemperature">>,
                                                        <<"CurrentTemperature">>, <<"19.5">>)),
    %% The dehumidifier.
    Dry = provider(Va, <<"TurnHumidifierOn">>),
    <<"CellarDryer">> = Dry,
    <<"on">> = param(<<"State">>, ok(request(Va, Dry, <<"TurnHumidifierOn">>, []))),
    <<"45">> = param(<<"TargetHumidity">>, ok(request(Va, Dry, <<"SetTargetHumidity">>,
                                                      [{<<"TargetHumidity">>, <<"45">>}]))),
    <<"BadParameter">> = error_code(request(Va, Dry, <<"SetTargetHumidity">>,
                                            [{<<"TargetHumidity">>, <<"95">>}])),
    <<"laundry">> = param(<<"Mode">>, ok(request(Va, Dry, <<"SetHumidifierMode">>,
                                                 [{<<"Mode">>, <<"laundry">>}]))).

%% A ceiling fan: on/off, speed percentage, preset, oscillation (its own
%% payloads, read back as yes/no) and direction.
fan(Config) ->
    P = ?config(prefix, Config),
    T = fun(S) -> <<P/binary, "/fan/", S/binary>> end,
    Fan = device(Config, [{<<"fan">>, <<"fan">>,
                           #{<<"name">> => <<"Ceiling fan">>,
                             <<"cmd_t">> => T(<<"on/set">>), <<"stat_t">> => T(<<"on">>),
                             %% HA's own fan example: true/false, speeds 1..10.
                             <<"pl_on">> => <<"true">>, <<"pl_off">> => <<"false">>,
                             <<"spd_rng_min">> => 1, <<"spd_rng_max">> => 10,
                             <<"pct_cmd_t">> => T(<<"pct/set">>), <<"pct_stat_t">> => T(<<"pct">>),
                             <<"pr_mode_cmd_t">> => T(<<"preset/set">>), <<"pr_mode_stat_t">> => T(<<"preset">>),
                             <<"pr_modes">> => [<<"breeze">>, <<"sleep">>],
                             <<"osc_cmd_t">> => T(<<"osc/set">>), <<"osc_stat_t">> => T(<<"osc">>),
                             <<"pl_osc_on">> => <<"swing">>, <<"pl_osc_off">> => <<"still">>,
                             <<"dir_cmd_t">> => T(<<"dir/set">>),
                             <<"dev">> => dev(P, <<"Bedroom Fan">>, <<"Bedroom">>)}}],
                 [T(<<"+/set">>)],
                 fun(Topic, Cmd) ->
                         case binary:split(Topic, <<"/set">>) of
                             [Base, <<>>] when Base =/= <<P/binary, "/fan/dir">> -> [{Base, Cmd}];
                             _ -> []
                         end
                 end),
    _A = avatar(Config),
    Va = va(Config, [<<"TurnFanOn">>, <<"TurnFanOff">>, <<"SetFanPercentage">>, <<"SetFanPresetMode">>,
                     <<"StartFanOscillation">>, <<"StopFanOscillation">>, <<"SetFanDirection">>],
            [<<"FanState">>, <<"FanPercentage">>]),
    F = provider(Va, <<"TurnFanOn">>),
    <<"BedroomFan">> = F,
    <<"on">> = param(<<"State">>, ok(request(Va, F, <<"TurnFanOn">>, []))),
    <<"60">> = param(<<"Percentage">>, ok(request(Va, F, <<"SetFanPercentage">>,
                                                  [{<<"Percentage">>, <<"60">>}]))),
    <<"60">> = param(<<"Percentage">>, stream(Va, <<"FanPercentage">>, <<"Percentage">>, <<"60">>)),
    <<"BadParameter">> = error_code(request(Va, F, <<"SetFanPercentage">>,
                                            [{<<"Percentage">>, <<"101">>}])),
    <<"sleep">> = param(<<"PresetMode">>, ok(request(Va, F, <<"SetFanPresetMode">>,
                                                     [{<<"PresetMode">>, <<"sleep">>}]))),
    <<"BadParameter">> = error_code(request(Va, F, <<"SetFanPresetMode">>,
                                            [{<<"PresetMode">>, <<"turbo">>}])),
    <<"yes">> = param(<<"Oscillation">>, ok(request(Va, F, <<"StartFanOscillation">>, []))),
    <<"no">> = param(<<"Oscillation">>, ok(request(Va, F, <<"StopFanOscillation">>, []))),
    %% No direction state topic: done when the broker has the command.
    <<"done">> = param(<<"Result">>, ok(request(Va, F, <<"SetFanDirection">>,
                                                [{<<"Direction">>, <<"reverse">>}]))),
    <<"off">> = param(<<"State">>, ok(request(Va, F, <<"TurnFanOff">>, []))),
    Cmds = [C || {_, C} <- mqtt_avatar_test_device:commands(Fan)],
    %% The percentage went out in the device's range (60 % of 1..10 is 6).
    [<<"true">>, <<"6">>, <<"sleep">>, <<"swing">>, <<"still">>, <<"reverse">>, <<"false">>] = Cmds.

%% A door lock that takes time (locking, then locked: the request is done
%% at locked) and an alarm panel with a local code: a wrong or missing
%% code is refused by the Avatar and nothing is published; the right one
%% arms it (Progress at arming, Feedback at armed_away), and the code is
%% neither published nor in the description.
lock_and_alarm(Config) ->
    P = ?config(prefix, Config),
    L = fun(S) -> <<P/binary, "/lock/", S/binary>> end,
    _Lock = device(Config, [{<<"lock">>, <<"lock">>,
                             #{<<"name">> => null, <<"cmd_t">> => L(<<"set">>),
                               <<"stat_t">> => L(<<"state">>), <<"pl_open">> => <<"OPEN">>,
                               <<"dev">> => dev(P, <<"Front Door">>, <<"Hall">>)}}],
                   [L(<<"set">>)],
                   fun(_, <<"LOCK">>) -> [{L(<<"state">>), <<"LOCKING">>}, {L(<<"state">>), <<"LOCKED">>}];
                      (_, <<"UNLOCK">>) -> [{L(<<"state">>), <<"UNLOCKING">>},
                                            {L(<<"state">>), <<"UNLOCKED">>}];
                      (_, <<"OPEN">>) -> [{L(<<"state">>), <<"OPEN">>}]
                   end),
    Al = fun(S) -> <<P/binary, "/alarm/", S/binary>> end,
    Alarm = device(Config, [{<<"alarm_control_panel">>, <<"alarm">>,
                             #{<<"name">> => null, <<"cmd_t">> => Al(<<"set">>),
                               <<"stat_t">> => Al(<<"state">>), <<"code">> => <<"4711">>,
                               <<"sup_feat">> => [<<"arm_home">>, <<"arm_away">>],
                               <<"dev">> => dev(P, <<"House Alarm">>, <<"Hall">>)}}],
                   [Al(<<"set">>)],
                   fun(_, <<"ARM_AWAY">>) -> [{Al(<<"state">>), <<"arming">>},
                                              {Al(<<"state">>), <<"armed_away">>}];
                      (_, <<"DISARM">>) -> [{Al(<<"state">>), <<"disarmed">>}]
                   end),
    A = avatar(Config),
    Va = va(Config, [<<"Lock">>, <<"Unlock">>, <<"OpenLock">>, <<"ArmAway">>, <<"Disarm">>],
            [<<"LockState">>, <<"AlarmState">>]),
    Lk = provider(Va, <<"Lock">>),
    <<"FrontDoor">> = Lk,
    <<"locked">> = param(<<"State">>, ok(request(Va, Lk, <<"Lock">>, []))),
    <<"unlocked">> = param(<<"State">>, ok(request(Va, Lk, <<"Unlock">>, []))),
    <<"open">> = param(<<"State">>, ok(request(Va, Lk, <<"OpenLock">>, []))),
    Panel = provider(Va, <<"ArmAway">>),
    <<"WrongCode">> = error_code(request(Va, Panel, <<"ArmAway">>, [{<<"Code">>, <<"1234">>}])),
    <<"WrongCode">> = error_code(request(Va, Panel, <<"ArmAway">>, [])),
    [] = mqtt_avatar_test_device:commands(Alarm),
    Id = <<"arm-1">>,
    ok = agent_bridge_client:send(Va, #{id => Id, context => request, sender => <<"Va01">>,
                                        receiver => Panel,
                                        body => entry(<<"ACTUATOR">>, <<"ArmAway">>,
                                                      [{<<"Code">>, <<"4711">>}])}),
    #{context := progress, body := #{parameters := Pr}} =
        wait_signal(Va, fun(#{in_reply_to := R}) -> R =:= Id; (_) -> false end),
    <<"arming">> = param(<<"State">>, Pr),
    #{context := feedback, body := #{parameters := Done}} =
        wait_signal(Va, fun(#{in_reply_to := R, context := C}) -> R =:= Id andalso C =:= feedback;
                           (_) -> false end),
    <<"armed_away">> = param(<<"State">>, Done),
    false = lists:keymember(<<"Code">>, 1, Done),
    <<"disarmed">> = param(<<"State">>, ok(request(Va, Panel, <<"Disarm">>,
                                                  [{<<"Code">>, <<"4711">>}]))),
    [<<"ARM_AWAY">>, <<"DISARM">>] = [C || {_, C} <- mqtt_avatar_test_device:commands(Alarm)],
    Xml = iolist_to_binary(mqtt_avatar:description_xml(mqtt_avatar:description(A))),
    nomatch = binary:match(Xml, <<"4711">>),
    [] = [X || X <- mqtt_avatar:problems(A), binary:match(term_to_binary(X), <<"4711">>) =/= nomatch].

%% An alarm panel whose code the device checks (`REMOTE_CODE'): the code
%% is required, and goes to the device through the panel's command
%% template, as in HA.
alarm_with_remote_code(Config) ->
    P = ?config(prefix, Config),
    Al = fun(S) -> <<P/binary, "/garage/", S/binary>> end,
    Alarm = device(Config, [{<<"alarm_control_panel">>, <<"alarm">>,
                             #{<<"name">> => null, <<"cmd_t">> => Al(<<"set">>),
                               <<"stat_t">> => Al(<<"state">>), <<"code">> => <<"REMOTE_CODE">>,
                               <<"cmd_tpl">> => <<"{\"action\": \"{{ action }}\", \"code\": \"{{ code }}\"}">>,
                               <<"sup_feat">> => [<<"arm_home">>],
                               <<"dev">> => dev(P, <<"Garage Alarm">>, <<"Garage">>)}}],
                   [Al(<<"set">>)],
                   fun(_, Cmd) ->
                           {ok, #{<<"action">> := Action, <<"code">> := Code}} = evatar_json:decode(Cmd),
                           case {Action, Code} of
                               {<<"ARM_HOME">>, <<"2468">>} -> [{Al(<<"state">>), <<"armed_home">>}];
                               _ -> [{Al(<<"state">>), <<"disarmed">>}]
                           end
                   end),
    _A = avatar(Config),
    Va = va(Config, [<<"ArmHome">>], [<<"AlarmState">>]),
    Panel = provider(Va, <<"ArmHome">>),
    <<"BadParameter">> = error_code(request(Va, Panel, <<"ArmHome">>, [])),
    [] = mqtt_avatar_test_device:commands(Alarm),
    <<"armed_home">> = param(<<"State">>, ok(request(Va, Panel, <<"ArmHome">>,
                                                    [{<<"Code">>, <<"2468">>}]))),
    [{_, Cmd}] = mqtt_avatar_test_device:commands(Alarm),
    {ok, #{<<"action">> := <<"ARM_HOME">>, <<"code">> := <<"2468">>}} = evatar_json:decode(Cmd).

%% A speaker's volume (number: min/max/step, a command template and a
%% value template), its source (select) and a scene: values within the
%% device's range and options are applied and read back, others refused;
%% the scene is activated.
number_select_scene(Config) ->
    P = ?config(prefix, Config),
    S = fun(X) -> <<P/binary, "/speaker/", X/binary>> end,
    Dev = dev(P, <<"Kitchen Speaker">>, <<"Kitchen">>),
    Speaker = device(Config, [{<<"number">>, <<"volume">>,
                                #{<<"name">> => <<"Volume">>, <<"cmd_t">> => S(<<"volume/set">>),
                                  <<"cmd_tpl">> => <<"{\"volume\": {{ value }}}">>,
                                  <<"val_tpl">> => <<"{{ value_json.volume }}">>,
                                  <<"stat_t">> => S(<<"volume">>), <<"min">> => 0, <<"max">> => 10,
                                  <<"step">> => 0.5, <<"unit_of_meas">> => <<"dB">>, <<"dev">> => Dev}},
                               {<<"select">>, <<"source">>,
                                #{<<"name">> => <<"Source">>, <<"cmd_t">> => S(<<"source/set">>),
                                  <<"stat_t">> => S(<<"source">>),
                                  <<"ops">> => [<<"radio">>, <<"tv">>, <<"Spotify Connect">>],
                                  <<"dev">> => Dev}}],
                      [S(<<"+/set">>)],
                      fun(Topic, Cmd) -> [{binary:part(Topic, 0, byte_size(Topic) - 4), Cmd}] end),
    Scene = device(Config, [{<<"scene">>, <<"movie">>,
                             #{<<"name">> => <<"Movie night">>, <<"cmd_t">> => <<P/binary, "/scene/movie">>,
                               <<"pl_on">> => <<"go">>}}],
                   [<<P/binary, "/scene/movie">>], undefined),
    _A = avatar(Config),
    Va = va(Config, [<<"SetVolume">>, <<"SelectSource">>, <<"ReadVolume">>, <<"ActivateMovieNight">>],
            [<<"Volume">>]),
    Sp = provider(Va, <<"SetVolume">>),
    <<"KitchenSpeaker">> = Sp,
    Fb = ok(request(Va, Sp, <<"SetVolume">>, [{<<"Value">>, <<"7.5">>}])),
    <<"7.5">> = param(<<"Value">>, Fb),
    <<"dB">> = param(<<"Unit">>, Fb),
    <<"7.5">> = param(<<"Value">>, stream(Va, <<"Volume">>, <<"Value">>, <<"7.5">>)),
    <<"BadParameter">> = error_code(request(Va, Sp, <<"SetVolume">>, [{<<"Value">>, <<"11">>}])),
    <<"BadParameter">> = error_code(request(Va, Sp, <<"SetVolume">>, [{<<"Value">>, <<"loud">>}])),
    <<"tv">> = param(<<"Option">>, ok(request(Va, Sp, <<"SelectSource">>, [{<<"Option">>, <<"tv">>}]))),
    <<"BadParameter">> = error_code(request(Va, Sp, <<"SelectSource">>, [{<<"Option">>, <<"vinyl">>}])),
    %% An option with a space is allowed, and still checked.
    <<"Spotify Connect">> = param(<<"Option">>, ok(request(Va, Sp, <<"SelectSource">>,
                                                           [{<<"Option">>, <<"Spotify Connect">>}]))),
    <<"BadParameter">> = error_code(request(Va, Sp, <<"SelectSource">>, [{<<"Option">>, <<"Spotify">>}])),
    <<"7.5">> = param(<<"Value">>, ok(request(Va, Sp, <<"ReadVolume">>, [], <<"SENSOR">>))),
    %% The volume went out through its command template.
    [{_, <<"{\"volume\": 7.5}">>} | _] = mqtt_avatar_test_device:commands(Speaker),
    Sc = provider(Va, <<"ActivateMovieNight">>),
    <<"done">> = param(<<"Result">>, ok(request(Va, Sc, <<"ActivateMovieNight">>, []))),
    [{_, <<"go">>}] = mqtt_avatar_test_device:commands(Scene).

%% A robot vacuum with HA's JSON state: start, fan speed and return to
%% base are applied and confirmed by its state; its battery is streamed.
vacuum(Config) ->
    P = ?config(prefix, Config),
    T = fun(S) -> <<P/binary, "/robot/", S/binary>> end,
    State = fun(St, Fan) -> evatar_json:encode(
                                                #{<<"state">> => St, <<"battery_level">> => 81,
                                                  <<"fan_speed">> => Fan}) end,
    Robot = device(Config, [{<<"vacuum">>, <<"robot">>,
                             #{<<"name">> => null, <<"cmd_t">> => T(<<"command">>),
                               <<"stat_t">> => T(<<"state">>), <<"set_fan_spd_t">> => T(<<"fan">>),
                               <<"fanspd_lst">> => [<<"quiet">>, <<"max">>],
                               <<"sup_feat">> => [<<"start">>, <<"pause">>, <<"stop">>,
                                                  <<"return_home">>, <<"status">>, <<"battery">>,
                                                  <<"fan_speed">>, <<"locate">>],
                               <<"dev">> => dev(P, <<"Robot">>, <<"Living">>)}}],
                   [T(<<"command">>), T(<<"fan">>)],
                   fun(Topic, Cmd) ->
                           case {Topic =:= T(<<"fan">>), Cmd} of
                               {true, Fan} -> [{T(<<"state">>), State(<<"cleaning">>, Fan)}];
                               {false, <<"start">>} -> [{T(<<"state">>), State(<<"cleaning">>, <<"quiet">>)}];
                               {false, <<"return_to_base">>} ->
                                   [{T(<<"state">>), State(<<"returning">>, <<"quiet">>)}];
                               {false, _} -> [{T(<<"state">>), State(<<"idle">>, <<"quiet">>)}]
                           end
                   end),
    _A = avatar(Config),
    Va = va(Config, [<<"StartVacuum">>, <<"SetVacuumFanSpeed">>, <<"ReturnVacuumToBase">>,
                     <<"LocateVacuum">>],
            [<<"VacuumBattery">>, <<"VacuumState">>]),
    R = provider(Va, <<"StartVacuum">>),
    <<"cleaning">> = param(<<"State">>, ok(request(Va, R, <<"StartVacuum">>, []))),
    <<"81">> = param(<<"Battery">>, stream(Va, <<"VacuumBattery">>, <<"Battery">>, <<"81">>)),
    <<"max">> = param(<<"FanSpeed">>, ok(request(Va, R, <<"SetVacuumFanSpeed">>,
                                                 [{<<"FanSpeed">>, <<"max">>}]))),
    <<"BadParameter">> = error_code(request(Va, R, <<"SetVacuumFanSpeed">>,
                                            [{<<"FanSpeed">>, <<"turbo">>}])),
    <<"returning">> = param(<<"State">>, ok(request(Va, R, <<"ReturnVacuumToBase">>, []))),
    [<<"start">>, <<"max">>, <<"return_to_base">>] =
        [C || {_, C} <- mqtt_avatar_test_device:commands(Robot)].

%% "A temperature sensor in the kitchen": a VA that asks for just that
%% binds to a sensor the user named "Kitchen thermometer", because the
%% sensor's services are also named after its device class; its readings
%% carry the unit, device class and state class. A door contact named
%% "Back door" binds a VA asking for DoorChanged the same way. A numeric
%% sensor (humidity, %) publishing `abc' sends the VA nothing, as Home
%% Assistant refuses it, and the Avatar lists the problem; a payload that
%% is not JSON, read by a value_json template, is listed as such.
sensors_named_by_what_they_are(Config) ->
    P = ?config(prefix, Config),
    Dev = dev(P, <<"Kitchen Multisensor">>, <<"Kitchen">>),
    Sensor = device(Config, [{<<"sensor">>, <<"thermo">>,
                              #{<<"name">> => <<"Kitchen thermometer">>,
                                <<"dev_cla">> => <<"temperature">>, <<"stat_cla">> => <<"measurement">>,
                                <<"unit_of_meas">> => <<"°C"/utf8>>,
                                <<"stat_t">> => <<P/binary, "/kitchen/sensor">>,
                                %% (evaluated: not a plain path)
                                <<"val_tpl">> => <<"{{ (value_json.t | float) | round(1) }}">>,
                                <<"dev">> => Dev}},
                             {<<"binary_sensor">>, <<"door">>,
                              #{<<"name">> => <<"Back door">>, <<"dev_cla">> => <<"door">>,
                                <<"stat_t">> => <<P/binary, "/kitchen/door">>, <<"dev">> => Dev}},
                             {<<"sensor">>, <<"humidity">>,
                              #{<<"name">> => <<"Humidity">>, <<"dev_cla">> => <<"humidity">>,
                                <<"unit_of_meas">> => <<"%">>,
                                <<"stat_t">> => <<P/binary, "/kitchen/humidity">>, <<"dev">> => Dev}}],
                    [], undefined),
    A = avatar(Config),
    Va = ?SETUP:connect_va(Config, <<"kitchen-va">>),
    Kitchen = [{<<"Room">>, <<"kitchen">>}],
    ok = agent_bridge_client:describe(
           Va, #{entity_id => <<"kitchen-va">>, api_name => <<"KITCHEN VA">>, entity_type => agent,
                 context => <<"Kitchen">>,
                 components =>
                     [#{id => <<"KitchenWatch">>,
                        services => [entry(<<"SENSOR">>, <<"Temperature">>, Kitchen),
                                     entry(<<"SENSOR">>, <<"DoorChanged">>, Kitchen),
                                     entry(<<"SENSOR">>, <<"Humidity">>, Kitchen)],
                        consumes => [entry(<<"SENSOR">>, <<"ReadTemperature">>,
                                           [{<<"Temperature">>, <<"yes">>}, {<<"Unit">>, <<"°C"/utf8>>}
                                            | Kitchen])]}]}),
    Comp = evatar_test_fixtures:wait_binding(
             Va, fun(#{bound := B}) ->
                         lists:sort([T || #{type := T} <- B]) =:=
                             [<<"DoorChanged">>, <<"Humidity">>, <<"ReadTemperature">>,
                              <<"Temperature">>]
                 end, 10000),
    [<<"KitchenMultisensor">>] = lists:usort([maps:get(component, maps:get(provider, B))
                                              || #{type := <<"ReadTemperature">>} = B
                                                     <- maps:get(bound, Comp)]),
    ok = mqtt_avatar_test_device:publish(Sensor, <<P/binary, "/kitchen/sensor">>, <<"{\"t\": 21.44}">>, false),
    #{context := sensor_data, body := #{parameters := Ps}} =
        wait_signal(Va, fun(#{body := #{type := T}}) -> T =:= <<"Temperature">> end),
    <<"21.4">> = param(<<"Temperature">>, Ps),
    <<"°C"/utf8>> = param(<<"Unit">>, Ps),
    <<"temperature">> = param(<<"DeviceClass">>, Ps),
    <<"measurement">> = param(<<"StateClass">>, Ps),
    <<"kitchen">> = param(<<"Room">>, Ps),
    {ok, #{body := #{parameters := Read}}} =
        agent_bridge_client:request(Va, #{sender => <<"KitchenWatch">>, receiver => <<"KitchenMultisensor">>,
                                          body => entry(<<"SENSOR">>, <<"ReadTemperature">>, [])}, 5000),
    <<"21.4">> = param(<<"Temperature">>, Read),
    ok = mqtt_avatar_test_device:publish(Sensor, <<P/binary, "/kitchen/door">>, <<"ON">>, false),
    #{context := event, body := #{parameters := Ds}} =
        wait_signal(Va, fun(#{body := #{type := T}}) -> T =:= <<"DoorChanged">> end),
    <<"yes">> = param(<<"Door">>, Ds),
    %% Not a number from a numeric sensor: nothing reaches the VA (the
    %% next Humidity it gets is the 55 published after), one problem.
    Humidity = <<P/binary, "/kitchen/humidity">>,
    ok = mqtt_avatar_test_device:publish(Sensor, Humidity, <<"abc">>, false),
    ok = until(fun() -> problems_with(A, Humidity, <<"'abc'">>) =/= [] end),
    [#{what := bad_payload, message := NotNumber}] = problems_with(A, Humidity, <<"'abc'">>),
    {match, _} = re:run(NotNumber, "is not a number.*device class humidity, unit %"),
    ok = mqtt_avatar_test_device:publish(Sensor, Humidity, <<"55">>, false),
    #{body := #{parameters := Hs}} =
        wait_signal(Va, fun(#{body := #{type := T}}) -> T =:= <<"Humidity">> end),
    <<"55">> = param(<<"Humidity">>, Hs),
    %% Not JSON, read by a value_json template: said as such.
    Thermo = <<P/binary, "/kitchen/sensor">>,
    ok = mqtt_avatar_test_device:publish(Sensor, Thermo, <<"not json">>, false),
    ok = until(fun() -> problems_with(A, Thermo, <<"is not JSON">>) =/= [] end),
    [#{message := NotJson}] = problems_with(A, Thermo, <<"is not JSON">>),
    {match, _} = re:run(NotJson, "'not json'.*the value template '\\{\\{ \\(value_json.t"),
    %% Each once, though the thermometer's two streams read the topic.
    2 = length([x || #{what := bad_payload} <- mqtt_avatar:problems(A)]).

%% The Avatar's problems on Topic whose message has Text.
problems_with(A, Topic, Text) ->
    [X || #{topic := T, message := M} = X <- mqtt_avatar:problems(A), T =:= Topic,
          binary:match(M, Text) =/= nomatch].

%% zigbee2mqtt's exposes of a cover, a thermostat (TRV), a lock, a fan and
%% a plug's settable numeric and enum: one simulated zigbee2mqtt applies
%% each JSON command to the device's state and publishes the whole state,
%% as zigbee2mqtt does.
zigbee2mqtt_families(Config) ->
    P = ?config(prefix, Config),
    Base = <<"z2m_", P/binary>>,
    Feature = fun(Type, Name, Access, Extra) ->
                      maps:merge(#{<<"type">> => Type, <<"name">> => Name, <<"property">> => Name,
                                   <<"access">> => Access}, Extra)
              end,
    Device = fun(Name, Exposes) ->
                     #{<<"type">> => <<"EndDevice">>, <<"friendly_name">> => Name,
                       <<"ieee_address">> => <<"0x", Name/binary>>,
                       <<"definition">> => #{<<"model">> => Name, <<"description">> => Name,
                                             <<"exposes">> => Exposes}}
             end,
    Devices = [Device(<<"living_blind">>,
                      [#{<<"type">> => <<"cover">>,
                         <<"features">> => [Feature(<<"enum">>, <<"state">>, 3,
                                                    #{<<"values">> => [<<"OPEN">>, <<"CLOSE">>, <<"STOP">>]}),
                                            Feature(<<"numeric">>, <<"position">>, 7,
                                                    #{<<"value_min">> => 0, <<"value_max">> => 100})]}]),
               Device(<<"hall_trv">>,
                      [#{<<"type">> => <<"climate">>,
                         <<"features">> => [Feature(<<"numeric">>, <<"occupied_heating_setpoint">>, 7,
                                                    #{<<"value_min">> => 5, <<"value_max">> => 30}),
                                            Feature(<<"numeric">>, <<"local_temperature">>, 5, #{}),
                                            Feature(<<"enum">>, <<"system_mode">>, 7,
                                                    #{<<"values">> => [<<"off">>, <<"heat">>, <<"auto">>]}),
                                            Feature(<<"enum">>, <<"running_state">>, 5,
                                                    #{<<"values">> => [<<"idle">>, <<"heat">>]})]}]),
               Device(<<"front_lock">>,
                      [#{<<"type">> => <<"lock">>,
                         <<"features">> => [Feature(<<"binary">>, <<"state">>, 7,
                                                    #{<<"value_on">> => <<"LOCK">>,
                                                      <<"value_off">> => <<"UNLOCK">>})]}]),
               Device(<<"ceiling_fan">>,
                      [#{<<"type">> => <<"fan">>,
                         <<"features">> => [(Feature(<<"binary">>, <<"state">>, 7,
                                                     #{<<"value_on">> => <<"ON">>,
                                                       <<"value_off">> => <<"OFF">>}))
                                            #{<<"property">> => <<"fan_state">>},
                                            (Feature(<<"enum">>, <<"mode">>, 7,
                                                     #{<<"values">> => [<<"low">>, <<"high">>]}))
                                            #{<<"property">> => <<"fan_mode">>}]}]),
               Device(<<"desk_plug">>,
                      [Feature(<<"numeric">>, <<"countdown">>, 7,
                               #{<<"value_min">> => 0, <<"value_max">> => 43200, <<"unit">> => <<"s">>}),
                       Feature(<<"enum">>, <<"power_on_behavior">>, 7,
                               #{<<"values">> => [<<"off">>, <<"on">>, <<"previous">>]})])],
    Initial = #{<<"living_blind">> => #{<<"state">> => <<"CLOSE">>, <<"position">> => 0},
                <<"hall_trv">> => #{<<"occupied_heating_setpoint">> => 17, <<"local_temperature">> => 19.5,
                                    <<"system_mode">> => <<"off">>, <<"running_state">> => <<"idle">>},
                <<"front_lock">> => #{<<"state">> => <<"UNLOCK">>},
                <<"ceiling_fan">> => #{<<"fan_state">> => <<"OFF">>, <<"fan_mode">> => <<"low">>},
                <<"desk_plug">> => #{<<"countdown">> => 0, <<"power_on_behavior">> => <<"off">>}},
    Z2m = device(Config, [], [<<Base/binary, "/+/set">>],
                 fun(Topic, Cmd) -> z2m(Base, Initial, Topic, Cmd) end),
    ok = mqtt_avatar_test_device:publish(Z2m, <<Base/binary, "/bridge/devices">>,
                                         evatar_json:encode(Devices), true),
    [ok = mqtt_avatar_test_device:publish(Z2m, <<Base/binary, "/", N/binary>>,
                                          evatar_json:encode(S), true)
     || {N, S} <- maps:to_list(Initial)],
    _A = avatar(Config, #{discovery => #{homeassistant => false, zigbee2mqtt => Base}}),
    Va = va(Config, [<<"OpenCover">>, <<"SetCoverPosition">>, <<"SetHvacMode">>,
                     <<"SetTargetTemperature">>, <<"Lock">>, <<"TurnFanOn">>, <<"SetFanPresetMode">>,
                     <<"SetCountdown">>, <<"SelectPowerOnBehavior">>],
            [<<"ClimateCurrentTemperature">>]),
    Blind = provider(Va, <<"OpenCover">>),
    <<"LivingBlind">> = Blind,
    <<"open">> = param(<<"State">>, ok(request(Va, Blind, <<"OpenCover">>, []))),
    <<"30">> = param(<<"Position">>, ok(request(Va, Blind, <<"SetCoverPosition">>,
                                                [{<<"Position">>, <<"30">>}]))),
    Trv = provider(Va, <<"SetHvacMode">>),
    <<"19.5">> = param(<<"CurrentTemperature">>, stream(Va, <<"ClimateCurrentTemperature">>,
                                                        <<"CurrentTemperature">>, <<"19.5">>)),
    <<"heat">> = param(<<"HvacMode">>, ok(request(Va, Trv, <<"SetHvacMode">>,
                                                  [{<<"HvacMode">>, <<"heat">>}]))),
    <<"21">> = param(<<"TargetTemperature">>, ok(request(Va, Trv, <<"SetTargetTemperature">>,
                                                         [{<<"TargetTemperature">>, <<"21">>}]))),
    <<"BadParameter">> = error_code(request(Va, Trv, <<"SetTargetTemperature">>,
                                            [{<<"TargetTemperature">>, <<"35">>}])),
    Lock = provider(Va, <<"Lock">>),
    <<"locked">> = param(<<"State">>, ok(request(Va, Lock, <<"Lock">>, []))),
    Fan = provider(Va, <<"TurnFanOn">>),
    <<"on">> = param(<<"State">>, ok(request(Va, Fan, <<"TurnFanOn">>, []))),
    <<"high">> = param(<<"PresetMode">>, ok(request(Va, Fan, <<"SetFanPresetMode">>,
                                                    [{<<"PresetMode">>, <<"high">>}]))),
    Plug = provider(Va, <<"SetCountdown">>),
    <<"DeskPlug">> = Plug,
    <<"60">> = param(<<"Value">>, ok(request(Va, Plug, <<"SetCountdown">>, [{<<"Value">>, <<"60">>}]))),
    <<"previous">> = param(<<"Option">>, ok(request(Va, Plug, <<"SelectPowerOnBehavior">>,
                                                    [{<<"Option">>, <<"previous">>}]))),
    Cmds = [begin {ok, J} = evatar_json:decode(C), J end
            || {_, C} <- mqtt_avatar_test_device:commands(Z2m)],
    [#{<<"state">> := <<"OPEN">>}, #{<<"position">> := 30}, #{<<"system_mode">> := <<"heat">>},
     #{<<"occupied_heating_setpoint">> := 21}, #{<<"state">> := <<"LOCK">>},
     #{<<"fan_state">> := <<"ON">>}, #{<<"fan_mode">> := <<"high">>}, #{<<"countdown">> := 60},
     #{<<"power_on_behavior">> := <<"previous">>}] = Cmds.

%% zigbee2mqtt: the device's state with the command applied, published
%% whole. (Runs in the test device's process: its state is kept there.)
z2m(Base, Initial, Topic, Cmd) ->
    Prefix = <<Base/binary, "/">>,
    <<Prefix:(byte_size(Prefix))/binary, Rest/binary>> = Topic,
    Name = binary:part(Rest, 0, byte_size(Rest) - 4),
    State0 = case get({z2m, Name}) of
                 undefined -> maps:get(Name, Initial);
                 S -> S
             end,
    {ok, Change} = evatar_json:decode(Cmd),
    Moved = case Change of
                #{<<"state">> := <<"OPEN">>} when Name =:= <<"living_blind">> -> #{<<"position">> => 100};
                _ -> #{}
            end,
    State = maps:merge(maps:merge(State0, Change), Moved),
    put({z2m, Name}, State),
    [{<<Base/binary, "/", Name/binary>>, evatar_json:encode(State)}].

%% ---------------------------------------------------------------------------
%% Devices, Avatar, VA
%% ---------------------------------------------------------------------------

dev(P, Name, Area) ->
    #{<<"ids">> => [<<P/binary, "-", Name/binary>>], <<"name">> => Name, <<"sa">> => Area}.

%% A test device announcing `Configs' ([{Component, Object, Config}]) in
%% HA's format, taking commands on `Commands' and answering each with the
%% state messages of `Reply(Topic, Payload)' ([{Topic, Payload}]).
device(Config, Configs, Commands, Reply) ->
    P = ?config(prefix, Config),
    Discovery = [{<<"ha_", P/binary, "/", C/binary, "/", P/binary, "/", O/binary, "/config">>,
                  evatar_json:encode(Cfg#{<<"uniq_id">> => <<P/binary, "-", O/binary>>})}
                 || {C, O, Cfg} <- Configs],
    Spec = #{discovery => Discovery, commands => Commands},
    Spec1 = case Reply of
                undefined -> Spec;
                _ -> Spec#{reply => fun(T, Pl) -> [{RT, RP, false} || {RT, RP} <- Reply(T, Pl)] end}
            end,
    {ok, D} = mqtt_avatar_test_device:start(?SETUP:broker_port(Config), Spec1),
    remember(devices, D),
    D.

avatar(Config) ->
    avatar(Config, #{}).

avatar(Config, Extra) ->
    ?SETUP:avatar(Config, <<"families">>, Extra).

%% A VA with one component, Va01, that requests `Requests' (services of
%% any Avatar component) and receives the streams `Streams' and every
%% feedback.
va(Config, Requests, Streams) ->
    Va = ?SETUP:connect_va(Config, <<"test-va">>),
    Any = [{<<"Room">>, <<"any">>}],
    ok = agent_bridge_client:describe(
           Va, #{entity_id => <<"test-va">>, api_name => <<"TEST VA">>, entity_type => agent,
                 context => <<"Families">>,
                 components =>
                     [#{id => <<"Va01">>,
                        services => [entry(<<"ACTUATOR">>, <<"ACTION FEEDBACK">>,
                                           [{<<"Feedback">>, <<"yes">>}, {<<"Device">>, <<"any">>} | Any])]
                                    ++ [entry(<<"SENSOR">>, S, Any) || S <- Streams],
                        consumes => [entry(category(R), R, []) || R <- Requests]}]}),
    put(requests, Requests),
    _ = evatar_test_fixtures:wait_binding(
          Va, fun(#{bound := B}) ->
                      Bound = [T || #{consumer := #{entity := <<"test-va">>}, type := T} <- B],
                      lists:all(fun(R) -> lists:member(R, Bound) end, Requests)
              end, 10000),
    Va.

category(<<"Read", _/binary>>) -> <<"SENSOR">>;
category(_) -> <<"ACTUATOR">>.

%% The Avatar component bound to the VA's request of type `Type'.
provider(Va, Type) ->
    ok = agent_bridge_client:get_binding(Va),
    #{bound := B} = evatar_test_fixtures:wait_binding(Va, fun(_) -> true end, evatar_test_time:guard()),
    [C] = [C || #{consumer := #{entity := <<"test-va">>}, type := T, provider := #{component := C}} <- B,
                T =:= Type],
    C.

request(Va, To, Type, Params) ->
    request(Va, To, Type, Params, category(Type)).

request(Va, To, Type, Params, Category) ->
    agent_bridge_client:request(Va, #{sender => <<"Va01">>, receiver => To,
                                      body => entry(Category, Type, Params)}, 10000).

ok({ok, #{context := feedback, body := #{parameters := Ps}}}) -> Ps;
ok(Other) -> ct:fail({no_feedback, Other}).

error_code({error, #{context := error, body := #{type := Code}}}) -> Code;
error_code(Other) -> ct:fail({no_error, Other}).

%% The first signal of stream `Type' whose `Param' is `Value'.
stream(Va, Type, Param, Value) ->
    #{body := #{parameters := Ps}} =
        wait_signal(Va, fun(#{body := #{type := T, parameters := Ps}}) ->
                                T =:= Type andalso lists:member({Param, Value}, Ps)
                        end),
    Ps.

wait_signal(Va, Pred) ->
    evatar_test_fixtures:wait_signal(Va, Pred, evatar_test_time:guard()).


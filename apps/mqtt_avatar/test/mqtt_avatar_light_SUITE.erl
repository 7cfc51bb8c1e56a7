%% Common Test suite of lights through the MQTT Avatar, against a real
%% mosquitto (evatar_test_mosquitto, free loopback port) and a real EVATAR pairing
%% behind a real agent_bridge listener: bulbs announced in Home
%% Assistant's three light schemas and by zigbee2mqtt
%% (mqtt_avatar_test_bulb, real MQTT clients that apply commands and
%% publish their state), and a VA joined with agent_bridge_client that sets
%% brightness, colour, colour temperature, effect and transition and reads
%% them back in its feedback. docs/mqtt.md section 2.7.
-module(mqtt_avatar_light_SUITE).

-import(mqtt_avatar_test_setup, [entry/3]).
-import(evatar_test_wait, [until/1]).

-define(LIVE_LISTENER, mqtt_avatar_light_suite).
-define(LIVE_CASE_PREFIX, "l_").
-define(LIVE_FEEDBACK_MS, 3000).
-import(mqtt_avatar_test_setup, [param/2]).
-include("mqtt_avatar_live_suite.hrl").

all() ->
    [{group, schemas}, {group, failures}].

groups() ->
    [{schemas, [], [json_schema, default_schema, template_schema, zigbee2mqtt_light]},
     {failures, [], [bad_values_and_payloads]}].

%% ---------------------------------------------------------------------------
%% Cases
%% ---------------------------------------------------------------------------

%% HA's JSON schema: brightness, RGB colour and transition in one command;
%% then colour temperature (in kelvin) and an effect; then off. Each
%% feedback carries what the bulb reports.
json_schema(Config) ->
    Dev = bulb(Config, json),
    _A = avatar(Config, #{}),
    Va = va(Config),
    C = provider_of(Va, <<"KitchenLight">>),
    Ps = on(Va, <<"KitchenLight">>, C, [{<<"Brightness">>, <<"50">>}, {<<"ColorRGB">>, <<"255,0,0">>},
                                         {<<"Transition">>, <<"2">>}]),
    <<"on">> = param(<<"Light">>, Ps),
    <<"50">> = param(<<"Brightness">>, Ps),
    <<"255,0,0">> = param(<<"ColorRGB">>, Ps),
    <<"0.0,100.0">> = param(<<"ColorHS">>, Ps),
    <<"kitchen">> = param(<<"Room">>, Ps),
    {_, Cmd} = lists:last(mqtt_avatar_test_device:commands(Dev)),
    {ok, #{<<"state">> := <<"ON">>, <<"brightness">> := 128, <<"transition">> := 2,
           <<"color">> := #{<<"r">> := 255, <<"g">> := 0, <<"b">> := 0}}} = evatar_json:decode(Cmd),
    Ps2 = on(Va, <<"KitchenLight">>, C, [{<<"ColorTempKelvin">>, <<"2500">>}, {<<"Effect">>, <<"rainbow">>}]),
    <<"400">> = param(<<"ColorTemp">>, Ps2),
    <<"2500">> = param(<<"ColorTempKelvin">>, Ps2),
    <<"rainbow">> = param(<<"Effect">>, Ps2),
    <<"50">> = param(<<"Brightness">>, Ps2),
    {_, Cmd2} = lists:last(mqtt_avatar_test_device:commands(Dev)),
    {ok, #{<<"color_temp">> := 400, <<"effect">> := <<"rainbow">>}} = evatar_json:decode(Cmd2),
    Ps3 = off(Va, <<"KitchenLight">>, C, [{<<"Transition">>, <<"0.5">>}]),
    <<"off">> = param(<<"Light">>, Ps3),
    {_, Cmd3} = lists:last(mqtt_avatar_test_device:commands(Dev)),
    {ok, #{<<"state">> := <<"OFF">>, <<"transition">> := 0.5}} = evatar_json:decode(Cmd3).

%% HA's default schema, as a Tasmota bulb announces it: one topic per
%% feature, every answer on one RESULT topic read through templates;
%% brightness scaled to 0..100, an effect command template.
default_schema(Config) ->
    P = ?config(prefix, Config),
    Dev = bulb(Config, default),
    _A = avatar(Config, #{}),
    Va = va(Config),
    C = provider_of(Va, <<"HallLight">>),
    Ps = on(Va, <<"HallLight">>, C, [{<<"Brightness">>, <<"30">>}, {<<"ColorRGB">>, <<"#00FF00">>}]),
    <<"on">> = param(<<"Light">>, Ps),
    <<"30">> = param(<<"Brightness">>, Ps),
    <<"0,255,0">> = param(<<"ColorRGB">>, Ps),
    %% Features first, then POWER (on_command_type last), as HA does.
    [{<<"cmnd/", P:(byte_size(P))/binary, "/Dimmer">>, <<"30">>},
     {_, <<"0,255,0">>}, {_, <<"ON">>}] = mqtt_avatar_test_device:commands(Dev),
    Ps2 = on(Va, <<"HallLight">>, C, [{<<"ColorTempKelvin">>, <<"4000">>}, {<<"Effect">>, <<"cycle">>}]),
    <<"250">> = param(<<"ColorTemp">>, Ps2),
    <<"4000">> = param(<<"ColorTempKelvin">>, Ps2),
    <<"cycle">> = param(<<"Effect">>, Ps2),
    [{_, <<"250">>}, {_, <<"CYCLE">>}, {_, <<"ON">>}] = lists:nthtail(3, mqtt_avatar_test_device:commands(Dev)),
    %% The default schema has no transition: said, not ignored.
    {error, #{body := #{type := <<"BadParameter">>, parameters := EPs}}} =
        request(Va, <<"HallLight">>, C, <<"TurnLightOff">>, [{<<"Transition">>, <<"2">>}]),
    <<"Transition: this light's schema (default) has no transition">> = param(<<"Message">>, EPs),
    <<"off">> = param(<<"Light">>, off(Va, <<"HallLight">>, C, [])).

%% HA's template schema: the command is rendered by command_on_template
%% ({% if %} blocks, arithmetic, filters) and the state read by
%% state_template, brightness_template, red/green/blue_template...
template_schema(Config) ->
    Dev = bulb(Config, template),
    _A = avatar(Config, #{}),
    Va = va(Config),
    C = provider_of(Va, <<"BedroomLight">>),
    Ps = on(Va, <<"BedroomLight">>, C, [{<<"Brightness">>, <<"20">>}, {<<"ColorHS">>, <<"240,100">>},
                                         {<<"Effect">>, <<"candle">>}, {<<"Transition">>, <<"1.5">>}]),
    <<"on">> = param(<<"Light">>, Ps),
    <<"20">> = param(<<"Brightness">>, Ps),
    <<"0,0,255">> = param(<<"ColorRGB">>, Ps),
    <<"candle">> = param(<<"Effect">>, Ps),
    [{_, Cmd}] = mqtt_avatar_test_device:commands(Dev),
    {ok, #{<<"turn">> := <<"on">>, <<"brightness">> := 51, <<"rgb">> := [0, 0, 255],
           <<"fx">> := <<"candle">>, <<"transition">> := 1500} = J} = evatar_json:decode(Cmd),
    false = maps:is_key(<<"ct">>, J),
    Ps2 = on(Va, <<"BedroomLight">>, C, [{<<"ColorTemp">>, <<"370">>}]),
    <<"370">> = param(<<"ColorTemp">>, Ps2),
    <<"off">> = param(<<"Light">>, off(Va, <<"BedroomLight">>, C, [])),
    {_, <<"{\"turn\":\"off\"}">>} = lists:last(mqtt_avatar_test_device:commands(Dev)).

%% A zigbee2mqtt bulb from bridge/devices (light expose with brightness
%% 0..254, color_temp, color_xy, color_hs; an effect enum): colour as xy
%% goes out as xy, brightness on z2m's scale.
zigbee2mqtt_light(Config) ->
    Dev = bulb(Config, z2m),
    P = ?config(prefix, Config),
    _A = avatar(Config, #{discovery => #{homeassistant => false, zigbee2mqtt => <<"z2m_", P/binary>>},
                          overrides => #{<<"garage_bulb">> => #{room => <<"garage">>}}}),
    Va = va(Config),
    C = provider_of(Va, <<"GarageLight">>),
    <<"GarageBulb">> = C,
    Ps = on(Va, <<"GarageLight">>, C, [{<<"Brightness">>, <<"100">>}, {<<"ColorXY">>, <<"0.701,0.299">>},
                                        {<<"Effect">>, <<"breathe">>}]),
    <<"on">> = param(<<"Light">>, Ps),
    <<"100">> = param(<<"Brightness">>, Ps),
    <<"0.701,0.299">> = param(<<"ColorXY">>, Ps),
    <<"breathe">> = param(<<"Effect">>, Ps),
    {_, Cmd} = lists:last(mqtt_avatar_test_device:commands(Dev)),
    {ok, #{<<"state">> := <<"ON">>, <<"brightness">> := 254, <<"effect">> := <<"breathe">>,
           <<"color">> := #{<<"x">> := 0.701, <<"y">> := 0.299}}} = evatar_json:decode(Cmd),
    Ps2 = on(Va, <<"GarageLight">>, C, [{<<"ColorHS">>, <<"120,50">>}]),
    <<"120.0,50.0">> = param(<<"ColorHS">>, Ps2),
    {_, Cmd2} = lists:last(mqtt_avatar_test_device:commands(Dev)),
    {ok, #{<<"color">> := #{<<"h">> := 120.0, <<"s">> := 50.0}}} = evatar_json:decode(Cmd2).

%% Bad values get BadParameter errors naming the parameter and the range;
%% an unreadable light state, a template that fails on a state and a light
%% config with an unsupported template are reported as problems; nothing
%% crashes and the light still works.
bad_values_and_payloads(Config) ->
    P = ?config(prefix, Config),
    _Dev = bulb(Config, json),
    A = avatar(Config, #{}),
    Va = va(Config),
    C = provider_of(Va, <<"KitchenLight">>),
    Bad = [{[{<<"Brightness">>, <<"150">>}], <<"Brightness must be a number from 0 to 100, got 150">>},
           {[{<<"Brightness">>, <<"dim">>}], <<"Brightness must be a number from 0 to 100, got dim">>},
           {[{<<"ColorRGB">>, <<"255,0">>}], <<"ColorRGB must be r,g,b (0..255 each) or #RRGGBB, got 255,0">>},
           {[{<<"ColorTemp">>, <<"100">>}], <<"ColorTemp must be a number from 153 to 500, got 100">>},
           {[{<<"Effect">>, <<"disco">>}], <<"Effect disco is not one of this light's effects: rainbow, blink">>},
           {[{<<"ColorRGB">>, <<"1,2,3">>}, {<<"ColorTemp">>, <<"300">>}],
            <<"give one of ColorRGB, ColorHS, ColorXY, ColorTemp, ColorTempKelvin, not ColorRGB and ColorTemp">>},
           {[{<<"Transition">>, <<"-1">>}], <<"Transition must be a number from 0 to 3600, got -1">>}],
    [begin
         {error, #{body := #{type := <<"BadParameter">>, parameters := EPs}}} =
             request(Va, <<"KitchenLight">>, C, <<"TurnLightOn">>, Params),
         Message = param(<<"Message">>, EPs)
     end || {Params, Message} <- Bad],
    {ok, Probe} = mqtt_avatar_test_device:start(port(Config), #{}),
    remember(devices, Probe),
    Ha = <<"ha_", P/binary>>,
    ok = mqtt_avatar_test_device:publish(Probe, <<P/binary, "/bulb/state">>, <<"{\"state\": ">>, false),
    ok = mqtt_avatar_test_device:publish(Probe, <<P/binary, "/bulb/state">>, <<"{\"state\":\"MAYBE\"}">>, false),
    {ok, Shelly} = evatar_json:decode(element(2, hd(element(1, mqtt_avatar_test_bulb:discovery(
                                                                      template, P, #{}))))),
    BadTemplate = Shelly#{<<"uniq_id">> => <<P/binary, "-for">>,
                          <<"stat_tpl">> => <<"{% for x in value_json %}{{ x }}{% endfor %}">>},
    ok = mqtt_avatar_test_device:publish(Probe, <<Ha/binary, "/light/x/for/config">>,
                                         evatar_json:encode(BadTemplate), false),
    ok = until(fun() ->
                       Ms = [{W, M} || #{what := W, message := M} <- mqtt_avatar:problems(A)],
                       lists:any(fun({W, M}) -> W =:= bad_discovery andalso
                                                    binary:match(M, <<"unsupported construct '{% for %}'">>) =/= nomatch
                                 end, Ms)
                           andalso lists:member({bad_payload, <<"state MAYBE is neither ON nor OFF">>}, Ms)
                           andalso lists:keymember(bad_payload, 1, Ms)
                           andalso length([x || {bad_payload, _} <- Ms]) >= 2
               end),
    <<"on">> = param(<<"Light">>, on(Va, <<"KitchenLight">>, C, [{<<"Brightness">>, <<"10">>}])),
    true = is_process_alive(A).

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

bulb(Config, Schema) ->
    Dev = mqtt_avatar_test_bulb:start(port(Config), Schema, ?config(prefix, Config)),
    remember(devices, Dev),
    Dev.

on(Va, From, To, Params) -> feedback(Va, From, To, <<"TurnLightOn">>, Params).
off(Va, From, To, Params) -> feedback(Va, From, To, <<"TurnLightOff">>, Params).

feedback(Va, From, To, Type, Params) ->
    {ok, #{context := feedback, sender := To, body := #{parameters := Ps}}} =
        request(Va, From, To, Type, Params),
    <<"done">> = param(<<"Result">>, Ps),
    Ps.

request(Va, From, To, Type, Params) ->
    agent_bridge_client:request(Va, #{sender => From, receiver => To,
                                      body => entry(<<"ACTUATOR">>, Type, Params)}, 10000).

avatar(Config, Extra) ->
    ?SETUP:avatar(Config, <<"lights">>, Extra).

port(Config) -> ?SETUP:broker_port(Config).

%% A VA with one light emulator per room, each wanting a dimmable light.
va(Config) ->
    Va = ?SETUP:connect_va(Config, <<"light-va">>),
    Lights = [{<<"KitchenLight">>, <<"kitchen">>}, {<<"HallLight">>, <<"hall">>},
              {<<"BedroomLight">>, <<"bedroom">>}, {<<"GarageLight">>, <<"garage">>}],
    ok = agent_bridge_client:describe(
           Va, #{entity_id => <<"light-va">>, api_name => <<"LIGHT VA">>, entity_type => agent,
                 context => <<"EmulatorDescription">>,
                 components =>
                     [#{id => Id,
                        services => [entry(<<"ACTUATOR">>, <<"ACTION FEEDBACK">>,
                                           [{<<"Feedback">>, <<"yes">>}, {<<"Room">>, Room}])],
                        consumes => [entry(<<"ACTUATOR">>, <<"TurnLightOn">>,
                                           [{<<"Light">>, <<"yes">>}, {<<"Brightness">>, <<"yes">>},
                                            {<<"Room">>, Room}]),
                                     entry(<<"ACTUATOR">>, <<"TurnLightOff">>,
                                           [{<<"Light">>, <<"yes">>}, {<<"Room">>, Room}])]}
                      || {Id, Room} <- Lights]}),
    Va.

provider_of(Va, Consumer) ->
    Report = evatar_test_fixtures:wait_binding(
               Va, fun(#{bound := B}) ->
                           [x || #{consumer := #{component := C}, type := <<"TurnLightOn">>} <- B,
                                 C =:= Consumer] =/= []
                   end, 10000),
    [P] = [P || #{consumer := #{component := C}, type := <<"TurnLightOn">>,
                  provider := #{component := P}} <- maps:get(bound, Report), C =:= Consumer],
    P.


%% EUnit tests of the pure discovery parts of issue 20: availability lists
%% (Home Assistant's and zigbee2mqtt's) down to the generated Mqtt*
%% parameters and the runtime spec, and discovery problems reported once.
-module(mqtt_avatar_discovery_tests).

-include_lib("eunit/include/eunit.hrl").

enc(Term) -> evatar_json:encode(Term).

%% One discovery message through a fresh state: the device and problems.
one(Topic, Config) ->
    {changed, S, []} = mqtt_avatar_discovery:handle(Topic, enc(Config), mqtt_avatar_discovery:new(#{})),
    mqtt_avatar_discovery:devices(S).

spec_of(Devices) ->
    {D, []} = mqtt_avatar_generate:description(#{entity_id => <<"e">>}, Devices, []),
    {ok, #{components := [C]}} = mqtt_avatar_spec:from_description(D),
    {D, C}.

params(#{components := [#{services := [#{parameters := Ps} | _]}]}) -> Ps.

%% zigbee2mqtt's own HA discovery: the bridge's state and the device's
%% availability, both JSON, mode all; abbreviations and `~' understood.
ha_availability_list_test() ->
    Config = #{<<"name">> => <<"Lamp">>, <<"uniq_id">> => <<"lamp-1">>,
               <<"~">> => <<"zigbee2mqtt/lamp">>,
               <<"cmd_t">> => <<"~/set">>, <<"stat_t">> => <<"~">>, <<"schema">> => <<"json">>,
               <<"avty">> => [#{<<"t">> => <<"zigbee2mqtt/bridge/state">>,
                                <<"val_tpl">> => <<"{{ value_json.state }}">>},
                              #{<<"topic">> => <<"~/availability">>,
                                <<"value_template">> => <<"{{ value_json.state }}">>,
                                <<"pl_avail">> => <<"up">>, <<"pl_not_avail">> => <<"down">>}],
               <<"avty_mode">> => <<"all">>,
               <<"dev">> => #{<<"ids">> => [<<"0x01">>], <<"name">> => <<"Lamp">>}},
    [#{availability := Avail}] = Devices = one(<<"homeassistant/light/0x01/light/config">>, Config),
    ?assertEqual(#{mode => all,
                   entries => [#{topic => <<"zigbee2mqtt/bridge/state">>, online => <<"online">>,
                                 offline => <<"offline">>, value => {json, [<<"state">>]}},
                               #{topic => <<"zigbee2mqtt/lamp/availability">>, online => <<"up">>,
                                 offline => <<"down">>, value => {json, [<<"state">>]}}]},
                 Avail),
    {D, #{availability := SpecAvail}} = spec_of(Devices),
    ?assertEqual(Avail, SpecAvail),
    Ps = params(D),
    ?assertEqual(<<"zigbee2mqtt/lamp/availability">>, proplists:get_value(<<"MqttAvailabilityTopic2">>, Ps)),
    ?assertEqual(<<"up">>, proplists:get_value(<<"MqttPayloadAvailable2">>, Ps)),
    ?assertEqual(<<"all">>, proplists:get_value(<<"MqttAvailabilityMode">>, Ps)).

%% The single-topic form keeps its top-level payloads and template; the
%% default mode (latest) is not written.
ha_single_topic_test() ->
    Config = #{<<"name">> => <<"Plug">>, <<"cmd_t">> => <<"cmnd/plug/POWER">>,
               <<"avty_t">> => <<"tele/plug/LWT">>, <<"pl_avail">> => <<"Online">>,
               <<"pl_not_avail">> => <<"Offline">>},
    [#{availability := Avail}] = Devices = one(<<"homeassistant/switch/plug/config">>, Config),
    ?assertEqual(#{mode => latest, entries => [#{topic => <<"tele/plug/LWT">>, online => <<"Online">>,
                                                 offline => <<"Offline">>, value => raw}]}, Avail),
    {D, _} = spec_of(Devices),
    ?assertEqual(undefined, proplists:get_value(<<"MqttAvailabilityMode">>, params(D))).

%% Mistakes in the availability list are the entity's problem, named.
ha_availability_mistakes_test() ->
    Base = #{<<"name">> => <<"Plug">>, <<"cmd_t">> => <<"p/set">>},
    Problem = fun(Extra) ->
                      S0 = mqtt_avatar_discovery:new(#{}),
                      {unchanged, _, [#{what := bad_discovery, message := M}]} =
                          mqtt_avatar_discovery:handle(<<"homeassistant/switch/p/config">>,
                                                       enc(maps:merge(Base, Extra)), S0),
                      M
              end,
    ?assertMatch({match, _}, re:run(Problem(#{<<"avty_mode">> => <<"most">>,
                                                             <<"avty_t">> => <<"p/av">>}), <<"availability_mode">>)),
    ?assertMatch({match, _}, re:run(Problem(#{<<"avty">> => [#{<<"t">> => <<"a/#">>}]}), <<"wildcard">>)),
    ?assertMatch({match, _}, re:run(Problem(#{<<"avty">> => [#{<<"pl_avail">> => <<"x">>}]}),
                                    <<"without topic">>)),
    Nine = [#{<<"t">> => <<"a", (integer_to_binary(I))/binary>>} || I <- lists:seq(1, 9)],
    ?assertMatch({match, _}, re:run(Problem(#{<<"avty">> => Nine}), <<"more than 8">>)).

%% zigbee2mqtt's device list: the device's own availability and the
%% bridge's state, mode all.
z2m_availability_test() ->
    List = [#{<<"friendly_name">> => <<"bulb">>, <<"ieee_address">> => <<"0x02">>,
              <<"definition">> => #{<<"model">> => <<"B1">>, <<"exposes">> => []}}],
    S0 = mqtt_avatar_discovery:new(#{zigbee2mqtt => <<"z2m">>}),
    {changed, S1, []} = mqtt_avatar_discovery:handle(<<"z2m/bridge/devices">>, enc(List), S0),
    [#{availability := #{mode := all, entries := Entries}}] = mqtt_avatar_discovery:devices(S1),
    ?assertEqual([<<"z2m/bulb/availability">>, <<"z2m/bridge/state">>],
                 [T || #{topic := T} <- Entries]).

%% A config over max_config_size is a problem when it arrives, and not
%% again while the same config keeps coming; a good config clears it.
too_large_config_test() ->
    Topic = <<"homeassistant/sensor/big/config">>,
    Big = enc(#{<<"name">> => binary:copy(<<"x">>, 300), <<"stat_t">> => <<"s">>}),
    S0 = mqtt_avatar_discovery:new(#{max_config_size => 200}),
    {unchanged, S1, [#{what := bad_discovery, topic := Topic, message := M}]} =
        mqtt_avatar_discovery:handle(Topic, Big, S0),
    ?assertMatch({match, _}, re:run(M, <<"over max_config_size \\(200 bytes\\)">>)),
    {unchanged, S2, []} = mqtt_avatar_discovery:handle(Topic, Big, S1),
    ?assert(mqtt_avatar_discovery:is_empty(S2)),
    Small = enc(#{<<"name">> => <<"T">>, <<"stat_t">> => <<"s">>}),
    {changed, S3, []} = mqtt_avatar_discovery:handle(Topic, Small, S2),
    {unchanged, _, [#{what := bad_discovery}]} = mqtt_avatar_discovery:handle(Topic, Big, S3),
    %% Not a discovery topic: not read, whatever its size.
    ignore = mqtt_avatar_discovery:handle(<<"elsewhere/x">>, Big, S0),
    %% The default limit is 64 KiB.
    Default = mqtt_avatar_discovery:new(#{}),
    {unchanged, _, [#{message := M64}]} =
        mqtt_avatar_discovery:handle(Topic, binary:copy(<<" ">>, 65537), Default),
    ?assertMatch({match, _}, re:run(M64, <<"65536 bytes">>)).

%% A device re-announcing a broken config (as at every birth message) is
%% reported once.
repeated_bad_config_test() ->
    Topic = <<"homeassistant/sensor/x/config">>,
    S0 = mqtt_avatar_discovery:new(#{}),
    {unchanged, S1, [_]} = mqtt_avatar_discovery:handle(Topic, <<"{\"name\": ">>, S0),
    {unchanged, S2, []} = mqtt_avatar_discovery:handle(Topic, <<"{\"name\": ">>, S1),
    %% A different mistake on the same topic is news.
    {unchanged, _, [_]} = mqtt_avatar_discovery:handle(Topic, <<"[]">>, S2).

%% An availability_template that is more than a path is rendered at each
%% message (mqtt_avatar_template) and compared with the payloads; one the
%% evaluator cannot read is the entity's problem.
availability_template_test() ->
    Tpl = <<"{{ 'online' if value_json.rssi > -90 else 'offline' }}">>,
    Config = #{<<"name">> => <<"Plug">>, <<"cmd_t">> => <<"p/set">>, <<"avty_t">> => <<"p/status">>,
               <<"avty_tpl">> => Tpl},
    [#{availability := #{entries := [#{value := {template, Tpl}}]}}] = Devices =
        one(<<"homeassistant/switch/p/config">>, Config),
    {D, _} = spec_of(Devices),
    ?assertEqual(<<"template:", Tpl/binary>>, proplists:get_value(<<"MqttAvailabilityValue">>, params(D))),
    {ok, Spec} = mqtt_avatar_spec:from_description(D),
    S0 = mqtt_avatar_logic:new(<<"e">>, Spec, 1000),
    Avail = fun(Payload, S) ->
                    {S1, _} = mqtt_avatar_logic:handle(
                                {mqtt, #{topic => <<"p/status">>, payload => Payload, retain => false}},
                                0, S),
                    {maps:values(mqtt_avatar_logic:availability(S1)), S1}
            end,
    {[online], S1} = Avail(<<"{\"rssi\": -60}">>, S0),
    {[offline], S2} = Avail(<<"{\"rssi\": -95}">>, S1),
    %% A payload the template cannot read is bad_availability.
    {_, [{problem, #{what := bad_availability}}]} =
        mqtt_avatar_logic:handle({mqtt, #{topic => <<"p/status">>, payload => <<"{\"rssi\": \"x\"}">>,
                                          retain => false}}, 0, S2),
    S00 = mqtt_avatar_discovery:new(#{}),
    {unchanged, _, [#{message := M}]} =
        mqtt_avatar_discovery:handle(<<"homeassistant/switch/q/config">>,
                                     enc(Config#{<<"avty_tpl">> => <<"{% for x in value_json %}{{ x }}{% endfor %}">>}), S00),
    ?assertMatch({match, _}, re:run(M, <<"value template \\{% for">>)).

%% ---------------------------------------------------------------------------
%% zigbee2mqtt's device list size (max_device_list_size, docs/mqtt.md 6)
%% ---------------------------------------------------------------------------

%% A zigbee2mqtt bridge/devices list of N copies of a sensor, padded with a
%% long description, as real lists are.
devices(N) ->
    Dev = fun(I) ->
                  #{<<"friendly_name">> => iolist_to_binary(["sensor_", integer_to_list(I)]),
                    <<"ieee_address">> => iolist_to_binary(["0x", integer_to_list(I)]),
                    <<"type">> => <<"EndDevice">>,
                    <<"definition">> =>
                        #{<<"model">> => <<"WSDCGQ11LM">>,
                          <<"description">> => binary:copy(<<"Aqara temperature sensor ">>, 200),
                          <<"exposes">> => [#{<<"type">> => <<"numeric">>, <<"name">> => <<"temperature">>,
                                              <<"property">> => <<"temperature">>, <<"access">> => 1,
                                              <<"unit">> => <<"°C"/utf8>>}]}}
          end,
    enc([Dev(I) || I <- lists:seq(1, N)]).

%% Over 1 MiB (the JSON decoder's default, the limit before), under the
%% 4 MiB default of max_device_list_size: read whole.
large_device_list_is_read_by_default_test() ->
    Payload = devices(300),
    ?assert(byte_size(Payload) > 1048576),
    ?assert(byte_size(Payload) < 4194304),
    {changed, S, []} = mqtt_avatar_discovery:handle(<<"zigbee2mqtt/bridge/devices">>, Payload,
                                                    mqtt_avatar_discovery:new(#{})),
    ?assertEqual(300, length(mqtt_avatar_discovery:devices(S))).

%% Over max_device_list_size: one problem that gives the size, the limit
%% and the option, and the state is kept; raised, the same list is read.
over_max_device_list_size_is_named_test() ->
    Payload = devices(20),
    S0 = mqtt_avatar_discovery:new(#{max_device_list_size => 1000}),
    {unchanged, _, [#{what := bad_discovery, message := M}]} =
        mqtt_avatar_discovery:handle(<<"zigbee2mqtt/bridge/devices">>, Payload, S0),
    Expected = iolist_to_binary(["the device list is ", integer_to_list(byte_size(Payload)),
                                 " bytes, over max_device_list_size (1000 bytes)"]),
    ?assertMatch({0, _}, binary:match(M, Expected)),
    ?assert(mqtt_avatar_discovery:is_empty(S0)),
    {changed, _, []} = mqtt_avatar_discovery:handle(<<"zigbee2mqtt/bridge/devices">>, Payload,
                                                    mqtt_avatar_discovery:new(
                                                      #{max_device_list_size => 1048576})).

%% The JSON decoder's own limit is not reported as a syntax error at byte 0.
too_large_json_is_not_a_syntax_error_test() ->
    {error, R} = evatar_json:decode(<<"[1]">>, #{max_size => 2}),
    M = evatar_json:format_error(R),
    ?assertEqual(nomatch, binary:match(M, <<"at byte">>)),
    ?assertNotEqual(nomatch, binary:match(M, <<"size limit">>)).

%% A value template with a filter the evaluator does not have (`format',
%% docs/mqtt.md 2.3) is refused with a message naming it, not read as a
%% plain path; filters that do not change a value read as text still give
%% a path, and the others the evaluator has are evaluated.
value_template_filters_test() ->
    Sensor = fun(Tpl) ->
                     #{<<"name">> => <<"Temperature">>, <<"uniq_id">> => <<"t-1">>,
                       <<"stat_t">> => <<"kitchen/t">>, <<"val_tpl">> => Tpl,
                       <<"dev">> => #{<<"ids">> => [<<"th-1">>], <<"name">> => <<"Thermo">>}}
             end,
    Topic = <<"homeassistant/sensor/th-1/t/config">>,
    {D, Problems} = mqtt_avatar:generate([{Topic, enc(Sensor(<<"{{ value_json.t | format('%.1f') }}">>))}],
                                         #{}),
    ?assertEqual([], maps:get(components, D)),
    [#{what := bad_discovery, message := M}] = Problems,
    ?assertMatch({match, _}, re:run(M, <<"unsupported filter 'format' at offset \\d+">>)),
    Value = fun(Tpl) ->
                    {#{components := [#{consumes := Cs}]}, []} =
                        mqtt_avatar:generate([{Topic, enc(Sensor(Tpl))}], #{}),
                    lists:usort([V || #{parameters := Ps} <- Cs, {<<"MqttValue">>, V} <- Ps])
            end,
    ?assertEqual([<<"Temperature=json:t">>], Value(<<"{{ value_json.t | float | round(1) }}">>)),
    ?assertEqual([<<"Temperature=template">>], Value(<<"{{ value_json.t | multiply(10) }}">>)).

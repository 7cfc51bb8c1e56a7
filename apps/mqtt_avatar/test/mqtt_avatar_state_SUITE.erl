%% Common Test suite of issue 20's state and availability, against a real
%% mosquitto, a real EVATAR pairing behind a real listener and a VA joined
%% with agent_bridge_client over TCP: actuator state changed outside the
%% VA, availability lists (Home Assistant's and zigbee2mqtt's), the birth
%% message, and problems reported once. Setup and helpers are
%% mqtt_avatar_test_setup's.
-module(mqtt_avatar_state_SUITE).

-import(mqtt_avatar_test_setup, [light_device/1, test_va/1, mqtt/1, request/4, provider_of/3]).
-import(evatar_test_wait, [until/1]).

-define(LIVE_LISTENER, mqtt_avatar_state_suite).
-define(LIVE_CASE_PREFIX, "").
-define(LIVE_FEEDBACK_MS, 1500).
-import(mqtt_avatar_test_setup, [param/2]).
-include("mqtt_avatar_live_suite.hrl").

all() ->
    [switched_at_the_wall, z2m_device_availability, ha_availability_list, birth_message,
     problems_once].

%% ---------------------------------------------------------------------------
%% Cases
%% ---------------------------------------------------------------------------

%% A light switched at the wall (its state published by itself) reaches the
%% VA as StateChanged; the VA's own request gets its Feedback and no Event;
%% an unreadable state with no request waiting is bad_payload, once.
switched_at_the_wall(Config) ->
    P = ?config(prefix, Config),
    Dev = light_device(Config),
    A = avatar(Config, #{}),
    Va = test_va(Config),
    Comp = provider_of(Va, <<"LightEmulator01">>, <<"TurnLightOn">>),
    %% The VA's Binding report may come before the Avatar's: a state changed
    %% before the Avatar knows its partners is told to nobody.
    ok = ?SETUP:wait_partner(A, Comp, <<"LightEmulator01">>),
    State = <<P/binary, "/light/state">>,
    ok = mqtt_avatar_test_device:publish(Dev, State, <<"{\"state\":\"ON\"}">>, true),
    #{sender := Comp, receiver := <<"LightEmulator01">>,
      body := #{category := <<"EVENT">>, parameters := Ps}} = state_changed(Va),
    <<"on">> = param(<<"Light">>, Ps),
    <<"kitchen">> = param(<<"Room">>, Ps),
    Comp = param(<<"Component">>, Ps),
    {ok, #{context := feedback, body := #{parameters := FPs}}} =
        agent_bridge_client:request(Va, request(<<"LightEmulator01">>, Comp,
                                                   <<"TurnLightOff">>, []), 5000),
    <<"off">> = param(<<"Light">>, FPs),
    %% Unreadable states, no request waiting: one problem for the three.
    [ok = mqtt_avatar_test_device:publish(Dev, State, Bad, false)
     || Bad <- [<<"{\"state\":">>, <<"{\"state\":">>, <<"{\"state\":">>]],
    %% The next StateChanged is the wall's ON, not an Event for the VA's
    %% own OFF (signals to the VA keep their order).
    ok = mqtt_avatar_test_device:publish(Dev, State, <<"{\"state\":\"ON\",\"changed\":true}">>, true),
    #{body := #{parameters := Ps2}} = state_changed(Va),
    <<"on">> = param(<<"Light">>, Ps2),
    [#{component := Comp, message := _}] =
        [X || #{what := bad_payload, topic := T} = X <- mqtt_avatar:problems(A), T =:= State].

%% A zigbee2mqtt device (its bridge/devices list): the device going offline
%% while the bridge is up is seen, and so is the bridge going down while
%% the device says online; both JSON and plain payloads. A state changed
%% outside the VA is StateChanged as for Home Assistant's devices.
z2m_device_availability(Config) ->
    P = ?config(prefix, Config),
    Base = <<"z2m_", P/binary>>,
    Devices = evatar_json:encode(
                [#{<<"friendly_name">> => <<"kitchen_bulb">>, <<"ieee_address">> => <<"0x0a">>,
                   <<"definition">> =>
                       #{<<"model">> => <<"LED1545G12">>, <<"description">> => <<"bulb">>,
                         <<"exposes">> =>
                             [#{<<"type">> => <<"light">>,
                                <<"features">> => [#{<<"name">> => <<"state">>,
                                                     <<"property">> => <<"state">>,
                                                     <<"access">> => 7, <<"value_on">> => <<"ON">>,
                                                     <<"value_off">> => <<"OFF">>}]}]}}]),
    Topic = <<Base/binary, "/kitchen_bulb">>,
    Reply = fun(_T, Cmd) ->
                    {ok, #{<<"state">> := St}} = evatar_json:decode(Cmd),
                    [{Topic, evatar_json:encode(#{<<"state">> => St,
                                                                        <<"linkquality">> => 90}),
                      true}]
            end,
    {ok, Dev} = mqtt_avatar_test_device:start(?SETUP:broker_port(Config), #{commands => [<<Topic/binary, "/set">>],
                                                                 reply => Reply}),
    remember(devices, Dev),
    Pub = fun(T, Pl) -> ok = mqtt_avatar_test_device:publish(Dev, T, Pl, true) end,
    Pub(<<Base/binary, "/bridge/devices">>, Devices),
    Pub(<<Base/binary, "/bridge/state">>, <<"{\"state\":\"online\"}">>),
    Pub(<<Topic/binary, "/availability">>, <<"{\"state\":\"online\"}">>),
    _A = avatar(Config, #{discovery => #{homeassistant => false, zigbee2mqtt => Base},
                             overrides => #{<<"kitchen_bulb">> => #{room => <<"kitchen">>}}}),
    Va = test_va(Config),
    Comp = provider_of(Va, <<"LightEmulator01">>, <<"TurnLightOn">>),
    <<"KitchenBulb">> = Comp,
    %% The bulb alone drops off the mesh.
    Pub(<<Topic/binary, "/availability">>, <<"{\"state\":\"offline\"}">>),
    #{body := #{parameters := OffPs}} = availability(Va, <<"DeviceDisconnected">>),
    <<"kitchen">> = param(<<"Room">>, OffPs),
    {error, #{body := #{type := <<"DeviceUnavailable">>}}} =
        agent_bridge_client:request(Va, request(<<"LightEmulator01">>, Comp, <<"TurnLightOn">>, []),
                                    5000),
    Pub(<<Topic/binary, "/availability">>, <<"online">>),
    _ = availability(Va, <<"DeviceReconnected">>),
    %% The bridge stops (its last will, plain text in older versions).
    Pub(<<Base/binary, "/bridge/state">>, <<"offline">>),
    _ = availability(Va, <<"DeviceDisconnected">>),
    Pub(<<Base/binary, "/bridge/state">>, <<"{\"state\":\"online\"}">>),
    _ = availability(Va, <<"DeviceReconnected">>),
    {ok, #{context := feedback}} =
        agent_bridge_client:request(Va, request(<<"LightEmulator01">>, Comp, <<"TurnLightOn">>, []),
                                    5000),
    %% Switched off from zigbee2mqtt's frontend.
    Pub(Topic, <<"{\"state\":\"OFF\",\"linkquality\":87}">>),
    #{body := #{parameters := SPs}} = state_changed(Va),
    <<"off">> = param(<<"Light">>, SPs).

%% Home Assistant's availability list with availability_mode any: one
%% topic going offline leaves the device available; all of them, not.
ha_availability_list(Config) ->
    P = ?config(prefix, Config),
    Base = <<P/binary, "/light">>,
    Disc = #{<<"name">> => null, <<"uniq_id">> => <<P/binary, "-light">>, <<"~">> => Base,
             <<"stat_t">> => <<"~/state">>, <<"cmd_t">> => <<"~/set">>, <<"schema">> => <<"json">>,
             <<"avty">> => [#{<<"t">> => <<"~/wifi">>},
                            #{<<"t">> => <<"~/zigbee">>, <<"pl_avail">> => <<"1">>,
                              <<"pl_not_avail">> => <<"0">>}],
             <<"avty_mode">> => <<"any">>,
             <<"dev">> => #{<<"ids">> => [<<P/binary, "-dev">>], <<"name">> => <<"Kitchen Light 01">>,
                            <<"sa">> => <<"Kitchen">>}},
    {ok, Dev} = mqtt_avatar_test_device:start(
                  ?SETUP:broker_port(Config),
                  #{discovery => [{<<"ha_", P/binary, "/light/", P/binary, "/config">>,
                                   evatar_json:encode(Disc)}]}),
    remember(devices, Dev),
    Pub = fun(T, Pl) -> ok = mqtt_avatar_test_device:publish(Dev, <<Base/binary, T/binary>>, Pl, true) end,
    Pub(<<"/wifi">>, <<"online">>),
    Pub(<<"/zigbee">>, <<"1">>),
    A = avatar(Config, #{}),
    Va = test_va(Config),
    Comp = provider_of(Va, <<"LightEmulator01">>, <<"TurnLightOn">>),
    Pub(<<"/wifi">>, <<"offline">>),
    Pub(<<"/zigbee">>, <<"0">>),
    %% Only the second one makes it unavailable.
    _ = availability(Va, <<"DeviceDisconnected">>),
    #{Comp := offline} = maps:get(availability, mqtt_avatar:status(A)),
    Pub(<<"/zigbee">>, <<"1">>),
    _ = availability(Va, <<"DeviceReconnected">>).

%% A device that announces itself only when Home Assistant comes online
%% (its configs not retained) is discovered through the Avatar's birth
%% message, and announces itself again when the Avatar's MQTT session
%% comes back (a birth at every connection).
birth_message(Config) ->
    P = ?config(prefix, Config),
    Birth = <<"ha_", P/binary, "/status">>,
    Disc = #{<<"name">> => <<"Lamp">>, <<"uniq_id">> => <<P/binary, "-lamp">>,
             <<"cmd_t">> => <<P/binary, "/lamp/set">>,
             <<"dev">> => #{<<"ids">> => [<<P/binary, "-lamp">>], <<"name">> => <<"Lamp 01">>}},
    {ok, Dev} = mqtt_avatar_test_device:start(
                  ?SETUP:broker_port(Config),
                  #{announce_on => Birth,
                    discovery => [{<<"ha_", P/binary, "/light/", P/binary, "/config">>,
                                   evatar_json:encode(Disc)}]}),
    remember(devices, Dev),
    ClientId = <<"evatar-birth-", P/binary>>,
    A = avatar(Config, #{birth => #{topic => Birth}, evatar => false,
                            mqtt => (mqtt(Config))#{client_id => ClientId}}),
    ok = until(fun() -> lists:member(<<"Lamp01">>, maps:get(components, mqtt_avatar:status(A))) end),
    1 = mqtt_avatar_test_device:births(Dev),
    %% Another client with the Avatar's client id takes its session over:
    %% the Avatar connects again and is born again.
    {ok, Thief} = mqtt_client:start(#{host => {127, 0, 0, 1}, port => ?SETUP:broker_port(Config),
                                      client_id => ClientId, reconnect => false}),
    ok = until(fun() -> mqtt_avatar_test_device:births(Dev) >= 2 end),
    _ = mqtt_client:stop(Thief),
    %% Without a birth message, such a device stays unknown.
    {ok, Quiet} = mqtt_avatar:start(#{entity_id => <<"quiet-", P/binary>>, mqtt => mqtt(Config),
                                      discovery => #{homeassistant => <<"ha_", P/binary>>,
                                                     zigbee2mqtt => false},
                                      birth => false, settle => 200, discovery_wait => 500}),
    remember(avatars, Quiet),
    ok = mqtt_avatar:await_ready(Quiet, evatar_test_time:guard()),
    [] = maps:get(components, mqtt_avatar:status(Quiet)).

%% A discovery config over max_config_size is a problem as it arrives (no
%% other change needed), and not again when re-sent or at later changes;
%% nor is a generated problem (an override matching nothing) repeated at
%% every new device.
problems_once(Config) ->
    P = ?config(prefix, Config),
    Ha = <<"ha_", P/binary>>,
    A = avatar(Config, #{evatar => false, discovery => #{homeassistant => Ha, zigbee2mqtt => false,
                                                          max_config_size => 1024},
                            overrides => #{<<"nobody">> => #{room => <<"attic">>}}}),
    {ok, Dev} = mqtt_avatar_test_device:start(?SETUP:broker_port(Config), #{}),
    remember(devices, Dev),
    Big = evatar_json:encode(#{<<"name">> => binary:copy(<<"x">>, 2000), <<"stat_t">> => <<"s">>}),
    BigTopic = <<Ha/binary, "/sensor/big/config">>,
    ok = mqtt_avatar_test_device:publish(Dev, BigTopic, Big, true),
    Count = fun(Pred) -> length([X || X <- mqtt_avatar:problems(A), Pred(X)]) end,
    IsBig = fun(#{what := W} = X) -> W =:= bad_discovery andalso maps:get(topic, X, none) =:= BigTopic end,
    IsUnused = fun(#{what := W}) -> W =:= unused_override end,
    ok = until(fun() -> Count(IsBig) =:= 1 end),
    %% Re-sent, then unrelated devices come (each a new description).
    ok = mqtt_avatar_test_device:publish(Dev, BigTopic, Big, true),
    Sensor = fun(N) ->
                     {<<Ha/binary, "/sensor/s", N/binary, "/config">>,
                      evatar_json:encode(#{<<"name">> => <<"S", N/binary>>,
                                                <<"stat_t">> => <<P/binary, "/s", N/binary>>})}
             end,
    [begin
         {T, C} = Sensor(N),
         ok = mqtt_avatar_test_device:publish(Dev, T, C, true),
         ok = until(fun() -> lists:member(<<"S", N/binary>>,
                                             maps:get(components, mqtt_avatar:status(A))) end)
     end || N <- [<<"1">>, <<"2">>]],
    1 = Count(IsBig),
    1 = Count(IsUnused).

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

state_changed(Va) ->
    event(Va, <<"StateChanged">>).

availability(Va, Type) ->
    event(Va, Type).

%% The VA's next Event of type Type.
event(Va, Type) ->
    evatar_test_fixtures:wait_signal(Va, fun(#{context := C, body := #{type := T}}) ->
                                                 C =:= event andalso T =:= Type
                                         end, 10000).

avatar(Config, Extra) ->
    ?SETUP:avatar(Config, <<"mqtt-home">>, Extra).


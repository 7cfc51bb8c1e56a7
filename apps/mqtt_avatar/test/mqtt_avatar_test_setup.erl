%% @doc Test support, not a suite: the setup the live suites of
%% mqtt_avatar share (mqtt_avatar_SUITE, _families_, _light_ and
%% _state_SUITE; their Common Test callbacks are mqtt_avatar_live_suite.hrl),
%% and the kitchen light and test VA two of them drive. One EVATAR node with a
%% bridge listener and a real mosquitto (evatar_test_node), a pairing per
%% case, and the case's Avatars, test devices and VAs, remembered as they
%% start and stopped when the case ends. Only mqtt_avatar's suites use it,
%% so it lives in this app's test directory (the rule of
%% apps/evatar_test_kit/README.md).
-module(mqtt_avatar_test_setup).

-export([init_per_suite/2, end_per_suite/2, init_per_testcase/3, end_per_testcase/1,
         remember/2, avatar/3, connect_va/2, broker_port/1, mqtt/1, entry/3, param/2,
         light_device/1, test_va/1, request/4, provider_of/3, consumer_of/3, wait_binding/2,
         wait_partner/3]).

-type config() :: [{atom(), term()}].

%% @doc A node with mqtt_avatar, a bridge listener `Listener' and a
%% mosquitto: Config with `addr' and `broker', or the suite's skip.
-spec init_per_suite(atom(), config()) -> config() | {skip, string()}.
init_per_suite(Listener, Config) ->
    evatar_test_node:start_with_broker([mqtt_avatar], Listener, Config).

%% @doc Stops what init_per_suite/2 started.
-spec end_per_suite(atom(), config()) -> ok.
end_per_suite(Listener, Config) ->
    ok = evatar_test_node:stop_broker(proplists:get_value(broker, Config)),
    evatar_test_node:stop([Listener], [mqtt_avatar]).

%% @doc The case's pairing `Name' (also the prefix of its topics and ids),
%% with feedback_timeout `FeedbackMs'.
-spec init_per_testcase(binary(), pos_integer(), config()) -> config().
init_per_testcase(Name, FeedbackMs, Config) ->
    {ok, _} = evatar_test_fixtures:create_pairing(Name, #{feedback_timeout => FeedbackMs}),
    [{pairing, Name}, {prefix, Name} | Config].

%% @doc Stops the case's Avatars, devices and VAs, and deletes its pairing.
-spec end_per_testcase(config()) -> ok.
end_per_testcase(Config) ->
    [catch mqtt_avatar:stop(A) || A <- forget(avatars)],
    [catch mqtt_avatar_test_device:stop(D) || D <- forget(devices)],
    [catch agent_bridge_client:close(V) || V <- forget(vas)],
    _ = evatar:delete_pairing(proplists:get_value(pairing, Config)),
    ok.

%% @doc Remembers a process of kind `avatars', `devices' or `vas' (a
%% bulb is a device) for end_per_testcase/1 to stop.
-spec remember(avatars | devices | vas, pid()) -> ok.
remember(Kind, Pid) ->
    _ = put(Kind, [Pid | case get(Kind) of undefined -> []; L -> L end]),
    ok.

forget(Kind) ->
    case erase(Kind) of
        undefined -> [];
        L -> L
    end.

%% @doc An MQTT Avatar `<<EntityPrefix, "-", Prefix>>' on the suite's
%% mosquitto and listener, joined to the case's pairing, reading Home
%% Assistant discovery under `ha_<Prefix>'; `Extra' overrides options.
%% Remembered, and ready when returned.
-spec avatar(config(), binary(), map()) -> pid().
avatar(Config, EntityPrefix, Extra) ->
    P = proplists:get_value(prefix, Config),
    Opts = maps:merge(#{entity_id => <<EntityPrefix/binary, "-", P/binary>>,
                        mqtt => #{host => {127, 0, 0, 1}, port => broker_port(Config)},
                        evatar => #{endpoints => [proplists:get_value(addr, Config)],
                                    pairing => proplists:get_value(pairing, Config),
                                    credential => evatar_test_fixtures:avatar_credential()},
                        discovery => #{homeassistant => <<"ha_", P/binary>>, zigbee2mqtt => false},
                        settle => 200},
                      Extra),
    {ok, A} = mqtt_avatar:start(Opts),
    ok = remember(avatars, A),
    ok = mqtt_avatar:await_ready(A, 10000),
    A.

%% @doc A VA `EntityId' joined to the case's pairing (not yet described);
%% remembered.
-spec connect_va(config(), binary()) -> pid().
connect_va(Config, EntityId) ->
    {ok, Va} = agent_bridge_client:connect([proplists:get_value(addr, Config)],
                                           #{pairing => proplists:get_value(pairing, Config),
                                             role => agent, entity_id => EntityId,
                                             credential => evatar_test_fixtures:va_credential()}),
    ok = remember(vas, Va),
    Va.

%% @doc The port of the suite's mosquitto.
-spec broker_port(config()) -> inet:port_number().
broker_port(Config) ->
    maps:get(port, proplists:get_value(broker, Config)).

%% @doc The suite's mosquitto as mqtt_client options.
-spec mqtt(config()) -> map().
mqtt(Config) ->
    #{host => {127, 0, 0, 1}, port => broker_port(Config)}.

%% @doc An HA JSON-schema light (zigbee2mqtt style) in the kitchen, whose
%% discovery config is under `ha_<Prefix>': a test device that applies
%% its commands and publishes its state; remembered.
-spec light_device(config()) -> pid().
light_device(Config) ->
    P = proplists:get_value(prefix, Config),
    Base = <<P/binary, "/light">>,
    Disc = #{<<"name">> => null, <<"uniq_id">> => <<P/binary, "-light">>, <<"~">> => Base,
             <<"stat_t">> => <<"~/state">>, <<"cmd_t">> => <<"~/set">>, <<"schema">> => <<"json">>,
             <<"avty_t">> => <<"~/availability">>, <<"json_attr_t">> => <<"~/state">>,
             <<"dev">> => #{<<"ids">> => [<<P/binary, "-light-dev">>], <<"name">> => <<"Kitchen Light 01">>,
                            <<"sa">> => <<"Kitchen">>, <<"mdl">> => <<"LightSwitch">>}},
    Reply = fun(_T, Cmd) ->
                    {ok, #{<<"state">> := S}} = evatar_json:decode(Cmd),
                    [{<<Base/binary, "/state">>,
                      evatar_json:encode(#{<<"state">> => S,
                                                                 <<"changed">> => true}), true}]
            end,
    {ok, Dev} = mqtt_avatar_test_device:start(
                  broker_port(Config),
                  #{availability => <<Base/binary, "/availability">>,
                    discovery => [{<<"ha_", P/binary, "/light/", P/binary, "/light/config">>,
                                   evatar_json:encode(Disc)}],
                    commands => [<<Base/binary, "/set">>], reply => Reply}),
    ok = remember(devices, Dev),
    Dev.

%% @doc The VA `test-va', described: a light emulator in the kitchen, a
%% motion and a temperature emulator in the hall; remembered.
-spec test_va(config()) -> pid().
test_va(Config) ->
    Va = connect_va(Config, <<"test-va">>),
    ok = agent_bridge_client:describe(Va, va_description()),
    Va.

va_description() ->
    #{entity_id => <<"test-va">>, api_name => <<"TEST VA">>, entity_type => agent,
      context => <<"EmulatorDescription">>,
      components =>
          [#{id => <<"LightEmulator01">>,
             services => [entry(<<"ACTUATOR">>, <<"ACTION FEEDBACK">>,
                                [{<<"Feedback">>, <<"yes">>}, {<<"Device">>, <<"LightSwitch">>},
                                 {<<"Room">>, <<"kitchen">>}])],
             consumes => [entry(<<"ACTUATOR">>, <<"TurnLightOn">>,
                                [{<<"Light">>, <<"yes">>}, {<<"Room">>, <<"kitchen">>}]),
                          entry(<<"ACTUATOR">>, <<"TurnLightOff">>,
                                [{<<"Light">>, <<"yes">>}, {<<"Room">>, <<"kitchen">>}])]},
           #{id => <<"MotionEmulator01">>,
             services => [entry(<<"SENSOR">>, <<"MotionDetected">>, [{<<"Room">>, <<"hall">>}])],
             consumes => [entry(<<"SENSOR">>, <<"ReadMotion">>, [{<<"Motion">>, <<"yes">>}])]},
           #{id => <<"TempEmulator01">>,
             services => [entry(<<"SENSOR">>, <<"Temperature">>, [{<<"Room">>, <<"hall">>}])],
             consumes => []}]}.

%% @doc An ACTUATOR request signal.
-spec request(binary(), binary(), binary(), [{binary(), binary()}]) -> map().
request(From, To, Type, Params) ->
    #{sender => From, receiver => To, body => entry(<<"ACTUATOR">>, Type, Params)}.

%% @doc The provider bound to the VA component `Consumer''s Consumes entry
%% `Type', once bound.
-spec provider_of(pid(), binary(), binary()) -> binary().
provider_of(Va, Consumer, Type) ->
    bound(Va, consumer, Consumer, Type, provider).

%% @doc The Avatar component whose Consumes entry `Type' is bound to the VA
%% component `Provider''s service, once bound.
-spec consumer_of(pid(), binary(), binary()) -> binary().
consumer_of(Va, Provider, Type) ->
    bound(Va, provider, Provider, Type, consumer).

%% The `Other' side of the one row of type Type whose `Side' is Id.
bound(Va, Side, Id, Type, Other) ->
    Match = fun(#{type := T} = Row) -> T =:= Type andalso maps:get(component, maps:get(Side, Row)) =:= Id end,
    Report = wait_binding(Va, fun(#{bound := B}) -> lists:any(Match, B) end),
    [C] = [maps:get(component, maps:get(Other, R)) || R <- maps:get(bound, Report), Match(R)],
    C.

%% @doc Waits until the Avatar `A' itself knows that its component `Comp'
%% is bound with `Partner' (its own Binding report, which may reach it after
%% the VA's): only then does an event of `Comp' go to `Partner'.
-spec wait_partner(pid(), binary(), binary()) -> ok.
wait_partner(A, Comp, Partner) ->
    ok = evatar_test_wait:until(
           fun() ->
                   lists:member(Partner, maps:get(Comp, maps:get(partners, mqtt_avatar:status(A)), []))
           end).

%% @doc The VA's first Binding report that satisfies `Pred' (10 s at most).
-spec wait_binding(pid(), fun((map()) -> boolean())) -> map().
wait_binding(Va, Pred) ->
    evatar_test_fixtures:wait_binding(Va, Pred, 10000).

%% @doc A service or Consumes entry.
-spec entry(binary(), binary(), [{binary(), binary()}]) -> map().
entry(Cat, Type, Params) ->
    #{category => Cat, type => Type, parameters => Params}.

%% @doc A parameter's value; fails the case when it is missing.
-spec param(binary(), [{binary(), term()}]) -> term().
param(Name, Params) ->
    case lists:keyfind(Name, 1, Params) of
        {_, V} -> V;
        false -> ct:fail({missing_parameter, Name, Params})
    end.

%% @doc Test support, not a suite: the EVATAR node that the Common Test
%% suites of several apps (agent_bridge, avatar_sim, evatar_demo,
%% evatar_web, mqtt_avatar, wot_avatar) set up alike. Starts evatar, then
%% agent_bridge (in that order: see start/1), opens bridge listeners on
%% 127.0.0.1 at a port the system picks, and runs a real mosquitto
%% (evatar_test_mosquitto). The suites' credentials, pairings and other
%% fixtures are in evatar_test_fixtures.
-module(evatar_test_node).

-export([start/1, start_with_broker/3, stop/2, listen/1, listen/2, stop_broker/1]).

%% @doc Starts evatar, agent_bridge (without a default listener) and Apps.
-spec start([atom()]) -> ok.
start(Apps) ->
    ok = application:set_env(agent_bridge, listeners, [], [{persistent, true}]),
    %% Started explicitly: an earlier suite may have stopped evatar while
    %% leaving agent_bridge running, which ensure_all_started would not notice.
    {ok, _} = application:ensure_all_started(evatar),
    {ok, _} = application:ensure_all_started(agent_bridge),
    lists:foreach(fun(App) -> {ok, _} = application:ensure_all_started(App) end, Apps).

%% @doc For a suite of an MQTT side: start/1, a listener Name and a
%% mosquitto on free loopback ports; Config with their `addr' and `broker',
%% or the suite's skip when mosquitto is not installed.
-spec start_with_broker([atom()], atom(), list()) -> list() | {skip, string()}.
start_with_broker(Apps, Name, Config) ->
    case start_broker() of
        {ok, Broker} ->
            ok = start(Apps),
            [{addr, listen(Name)}, {broker, Broker} | Config];
        {skip, _} = Skip ->
            Skip
    end.

%% @doc Stops the listeners, then the applications, in the order given.
-spec stop([atom()], [atom()]) -> ok.
stop(Listeners, Apps) ->
    [ok = agent_bridge:stop_listener(L) || L <- Listeners],
    [ok = application:stop(App) || App <- Apps],
    ok.

%% @doc A listener on 127.0.0.1 at a free port; its address.
-spec listen(atom()) -> {inet:ip_address(), inet:port_number()}.
listen(Name) ->
    listen(Name, #{}).

%% @doc The same with listener options (conn, ...); the port is always 0.
-spec listen(atom(), map()) -> {inet:ip_address(), inet:port_number()}.
listen(Name, Opts) ->
    {ok, _} = agent_bridge:start_listener(Name, Opts#{port => 0}),
    {ok, Addr} = agent_bridge:address(Name),
    Addr.

start_broker() ->
    case evatar_test_mosquitto:available() of
        false -> {skip, "mosquitto is not installed (Debian package mosquitto)"};
        true -> {ok, _} = evatar_test_mosquitto:start(#{})
    end.

%% @doc Stops the broker of start_with_broker/3.
-spec stop_broker(evatar_test_mosquitto:broker()) -> ok.
stop_broker(Broker) ->
    ok = evatar_test_mosquitto:stop(Broker).

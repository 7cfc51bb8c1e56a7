%% @doc Test support, not a suite: the EVATAR node that the Common Test
%% suites of several apps set up alike. Starts evatar, then agent_bridge
%% (in that order: see start/1), opens bridge listeners on 127.0.0.1 at a
%% port the system picks, creates pairings with the suites' credentials,
%% runs the real mosquitto of mqtt_broker, and waits for a client's reports.
-module(agent_bridge_test_node).

-export([start/1, start_with_broker/3, stop/2, listen/1, listen/2, va_credential/0,
         avatar_credential/0, create_pairing/2, stop_broker/1, wait_binding/3, wait_signal/3,
         wait_until/2, bridge_certs/2]).

%% @doc Starts evatar, agent_bridge (without a default listener) and Apps.
-spec start([atom()]) -> ok.
start(Apps) ->
    ok = application:set_env(agent_bridge, listeners, [], [{persistent, true}]),
    %% Started explicitly: an earlier suite may have stopped evatar while
    %% leaving agent_bridge running, which ensure_all_started would not notice.
    {ok, _} = application:ensure_all_started(evatar),
    {ok, _} = application:ensure_all_started(agent_bridge),
    [{ok, _} = application:ensure_all_started(App) || App <- Apps],
    ok.

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

%% @doc Runs scripts/gen-bridge-certs.sh: a CA, a server certificate for
%% localhost and 127.0.0.1, and a client certificate per name in Dir.
-spec bridge_certs(file:filename(), [string()]) -> file:filename().
bridge_certs(Dir, Clients) ->
    Src = proplists:get_value(source, evatar:module_info(compile)),
    Root = filename:dirname(filename:dirname(filename:dirname(filename:dirname(Src)))),
    Script = filename:join([Root, "scripts", "gen-bridge-certs.sh"]),
    Out = os:cmd(lists:join(" ", ["EVATAR_SERVER_HOSTS='localhost 127.0.0.1'", "bash", Script, Dir
                                  | Clients]) ++ " 2>&1; echo rc=$?"),
    case string:find(Out, "rc=0\n") of
        nomatch -> ct:fail({gen_bridge_certs, Out});
        _ -> Dir
    end.

%% @doc The credential of the VAs of the suites' pairings.
-spec va_credential() -> binary().
va_credential() -> <<"va-secret">>.

%% @doc The credential of the Avatars of the suites' pairings.
-spec avatar_credential() -> binary().
avatar_credential() -> <<"avatar-secret">>.

%% @doc A pairing with the suites' credentials and the options Opts.
-spec create_pairing(binary(), map()) -> {ok, pid()}.
create_pairing(Id, Opts) ->
    {ok, _} = evatar:create_pairing(Id, Opts#{agent_credential => va_credential(),
                                              avatar_credential => avatar_credential()}).

start_broker() ->
    case mqtt_broker:available() of
        false -> {skip, "mosquitto is not installed (Debian package mosquitto)"};
        true -> {ok, _} = mqtt_broker:start(#{})
    end.

%% @doc Stops the broker of start_with_broker/3.
-spec stop_broker(mqtt_broker:broker()) -> ok.
stop_broker(Broker) ->
    ok = mqtt_broker:stop(Broker).

%% @doc The first Binding report to client C that satisfies Pred, within
%% Timeout ms of each report; the case fails without one.
-spec wait_binding(pid(), fun((map()) -> boolean()), timeout()) -> map().
wait_binding(C, Pred, Timeout) ->
    wait_report(C, binding, Pred, Timeout, no_binding).

%% @doc The first signal to client C that satisfies Pred, within Timeout ms
%% of each signal; the case fails without one.
-spec wait_signal(pid(), fun((map()) -> boolean()), timeout()) -> map().
wait_signal(C, Pred, Timeout) ->
    wait_report(C, signal, Pred, Timeout, no_signal).

%% @doc ok once Fun() is true, asked every 20 ms at most Tries times.
-spec wait_until(fun(() -> boolean()), non_neg_integer()) -> ok | {error, timeout}.
wait_until(_Fun, 0) -> {error, timeout};
wait_until(Fun, Tries) ->
    case Fun() of
        true -> ok;
        false -> timer:sleep(20), wait_until(Fun, Tries - 1)
    end.

wait_report(C, Kind, Pred, Timeout, Failure) ->
    receive
        {agent_bridge, C, {Kind, Report}} ->
            case Pred(Report) of
                true -> Report;
                false -> wait_report(C, Kind, Pred, Timeout, Failure)
            end
    after Timeout -> ct:fail(Failure)
    end.

%% @doc The Web of Things export (docs/wot.md): the simulated smart home
%% (avatar_sim) joins a pairing over TCP, the node's WoT consumer joins it as
%% the agent (http option `things'), and its TDs are checked with the Thing
%% Description Playground (TD 1.1 JSON Schema and assertion checks, npm
%% @thing-description-playground/core) and driven by a real node-wot
%% consumer (npm @node-wot/core, @node-wot/binding-http), pinned in this
%% suite's data dir and installed into _build/wot-npm (again when the lock
%% file changes; evatar_test_npm); and the MQTT Avatar's MQTT forms driven
%% by node-wot 0.8.16's MQTT binding (evatar_test_npm:install_mqtt/0).
-module(evatar_web_wot_SUITE).

-include_lib("common_test/include/ct.hrl").
-import(evatar_test_wait, [until/1]).

-export([all/0, suite/0, init_per_suite/1, end_per_suite/1]).
-export([tds_pass_schema_and_assertions/1, consumer_is_bound_like_a_va/1,
         node_wot_switches_the_lamp/1, feedback_timeout_is_504/1, actions_need_the_token/1,
         a_va_cannot_join_beside_it/1, bad_things_option_is_named/1,
         node_wot_reads_the_time/1, a_joined_va_keeps_it_out/1, node_wot_mqtt_drives_the_devices/1]).

-define(T, evatar_web_test).
-define(TOKEN, "wot-operator-token-0123456789abcdef").
-define(HOME, <<"wot-home">>).
-define(VA_CRED, <<"wot-va-secret">>).
-define(AV_CRED, <<"wot-av-secret">>).
-define(LAMP, "BedroomSocketSwitch01").
-define(MQTT, <<"wot-mqtt">>).
-define(MQTT_AV, <<"wot-mqtt-home">>).
-define(BUSY, <<"wot-busy">>).

suite() -> [{timetrap, {minutes, 6}}].

all() -> [bad_things_option_is_named, tds_pass_schema_and_assertions, consumer_is_bound_like_a_va,
          actions_need_the_token, node_wot_switches_the_lamp, node_wot_reads_the_time, a_va_cannot_join_beside_it,
          feedback_timeout_is_504, a_joined_va_keeps_it_out,
          %% last: it publishes a retained reading, and node_wot_reads_the_time wants none
          node_wot_mqtt_drives_the_devices].

init_per_suite(Config) ->
    Npm = evatar_test_npm:install(),
    NpmMqtt = evatar_test_npm:install_mqtt(),
    ok = application:set_env(agent_bridge, listeners, [], [{persistent, true}]),
    {ok, _} = application:ensure_all_started(evatar),
    {ok, _} = application:ensure_all_started(agent_bridge),
    {ok, _} = application:ensure_all_started(avatar_sim),
    {ok, _} = agent_bridge:start_listener(wot, #{port => 0}),
    {ok, Addr} = agent_bridge:address(wot),
    _ = evatar:delete_pairing(?HOME),
    {ok, _} = evatar:create_pairing(?HOME, #{agent_credential => ?VA_CRED,
                                             avatar_credential => ?AV_CRED,
                                             feedback_timeout => evatar_test_time:ms(2000)}),
    _ = evatar:delete_pairing(?MQTT),
    _ = evatar:delete_pairing(?BUSY),
    %% ?BUSY: a VA (this suite's process) holds the agent slot before the
    %% consumer starts; an Avatar with bil's light_actuator.xml is described.
    {ok, _} = evatar:create_pairing(?BUSY, #{agent_credential => ?VA_CRED,
                                             avatar_credential => ?AV_CRED, join_timeout => 600000}),
    Va = hold(agent, <<"busy-va">>, smart_home_va_stub()),
    Lamp = hold(avatar, <<"7008">>, example("light_actuator.xml")),
    {ok, _} = evatar:create_pairing(?MQTT, #{agent_credential => ?VA_CRED,
                                             avatar_credential => ?AV_CRED}),
    ?T:start(#{operator_token_hash => evatar:hash_credential(list_to_binary(?TOKEN)),
               things => [#{pairing => ?HOME, credential => ?VA_CRED, entity_id => <<"wot">>},
                          #{pairing => ?MQTT, credential => ?VA_CRED},
                          #{pairing => ?BUSY, credential => ?VA_CRED}]}),
    {ok, Home} = avatar_sim:start_home(#{endpoints => [Addr], spool => ?config(priv_dir, Config),
                                         gateways => [#{pairing => ?HOME, credential => ?AV_CRED}]}),
    %% The MQTT Avatar: devices announced by Home Assistant discovery on a
    %% real mosquitto, discovered by mqtt_avatar, joined to ?MQTT.
    {ok, _} = application:ensure_all_started(mqtt_avatar),
    {ok, Broker} = evatar_test_mosquitto:start(),
    Mqtt = #{host => "127.0.0.1", port => maps:get(port, Broker)},
    ok = announce(Mqtt),
    {ok, _} = mqtt_avatar:keep(#{entity_id => ?MQTT_AV, mqtt => Mqtt, discovery => #{},
                                 evatar => #{endpoints => [Addr], pairing => ?MQTT,
                                             credential => ?AV_CRED}}),
    until(fun() -> home_bound() end),
    until(fun() -> length(things()) =:= 3 end),
    [{npm, Npm}, {npm_mqtt, NpmMqtt}, {home, Home}, {broker, Broker}, {busy_va, Va}, {busy_lamp, Lamp} | Config].

end_per_suite(Config) ->
    ok = avatar_sim:stop(?config(home, Config)),
    _ = mqtt_avatar:unkeep(?MQTT_AV),
    ok = evatar_test_mosquitto:stop(?config(broker, Config)),
    _ = evatar:delete_pairing(?HOME),
    _ = evatar:delete_pairing(?MQTT),
    [P ! stop || P <- [?config(busy_va, Config), ?config(busy_lamp, Config)]],
    _ = evatar:delete_pairing(?BUSY),
    ok = agent_bridge:stop_listener(wot),
    ?T:stop(),
    %% evatar_web_test's defaults have no `things': later suites must not
    %% start this suite's consumers.
    application:unset_env(evatar_web, things).

%% ---------------------------------------------------------------------------
%% Cases
%% ---------------------------------------------------------------------------

%% A wrong `things' option stops the start naming the key.
bad_things_option_is_named(_Config) ->
    {error, {things, _}} = evatar_web:check_opts(#{things => [#{pairing => <<"p">>}]}),
    {error, {things, _}} = evatar_web:check_opts(#{things => [#{pairing => <<"p">>, credential => <<"c">>},
                                                              #{pairing => <<"p">>, credential => <<"d">>}]}),
    {error, {things, _}} = evatar_web:check_opts(#{things => [#{pairing => <<"p">>, credential => <<"c">>,
                                                                 room => 1}]}),
    ok = evatar_web:check_opts(#{things => [#{pairing => "p", credential => "secret", entity_id => "wot"}]}).

%% Every TD the node exports (the simulated home's and the MQTT Avatar's,
%% one of them alone, /.well-known/wot)
%% passes the TD 1.1 JSON Schema and the playground's assertions; each
%% actuator service is an action with its input and output, each sensor
%% stream a property, and the security is the bearer token.
tds_pass_schema_and_assertions(Config) ->
    {200, Hdrs, Body} = ?T:raw(get, "/api/things", [], none),
    "application/json" = proplists:get_value("content-type", Hdrs),
    {ok, TDs} = evatar_json:decode(list_to_binary(Body)),
    [TD] = [X || #{<<"title">> := <<"easy-home-01">>} = X <- TDs],
    [#{<<"actions">> := MqttActions, <<"properties">> := MqttProps}] =
        [X || #{<<"title">> := ?MQTT_AV} = X <- TDs],
    true = maps:size(MqttActions) >= 2 andalso maps:size(MqttProps) >= 2,
    %% The MQTT Avatar's devices carry their own MQTT binding forms beside
    %% the HTTP ones: a publish to the plug's command topic, a subscribe
    %% to the temperature's state topic (on the suite's broker). (The
    %% light's commands come from its HA config, MqttLight: no form.)
    Port = integer_to_list(maps:get(port, ?config(broker, Config))),
    MqttForms = fun(Affs) -> [F || #{<<"forms">> := Fs} <- maps:values(Affs), F <- Fs,
                                   binary:match(maps:get(<<"href">>, F), <<"mqtt://">>) =/= nomatch] end,
    [_, _] = PlugForms = [F || #{<<"href">> := H} = F <- MqttForms(MqttActions),
                               H =:= list_to_binary("mqtt://127.0.0.1:" ++ Port ++ "/home/hall_plug/set")],
    ok = lists:foreach(fun(#{<<"op">> := [<<"invokeaction">>], <<"mqv:controlPacket">> := <<"publish">>,
                             <<"bil:mqttCommand">> := _}) -> ok
                       end, PlugForms),
    [_ | _] = [F || #{<<"href">> := H, <<"mqv:controlPacket">> := <<"subscribe">>,
                      <<"op">> := [<<"observeproperty">>]} = F <- MqttForms(MqttProps),
                    H =:= list_to_binary("mqtt://127.0.0.1:" ++ Port ++ "/home/hall_temperature")],
    [] = [P || #{<<"forms">> := [_, _ | _], <<"observable">> := false} = P <- maps:values(MqttProps)],
    #{<<"@context">> := [<<"https://www.w3.org/2019/wot/td/v1">>, <<"https://www.w3.org/2022/wot/td/v1.1">>, _],
      <<"id">> := Id, <<"security">> := [<<"bearer_sc">>],
      <<"securityDefinitions">> := #{<<"bearer_sc">> := #{<<"scheme">> := <<"bearer">>}},
      <<"actions">> := #{<<?LAMP, ".SwitchSocketOn">> := #{<<"input">> := In, <<"output">> := Out,
                                                             <<"forms">> := [Form]}},
      <<"properties">> := #{<<"TimeSensor01.TimeOfDay">> := #{<<"readOnly">> := true}}} = TD,
    {match, _} = re:run(Id, "^urn:evatar:thing:.+:wot-home:easy-home-01$"),
    #{<<"properties">> := #{<<"Appliance">> := _, <<"Room">> := _}} = In,
    #{<<"properties">> := #{<<"Feedback">> := _, <<"Device">> := _}} = Out,
    #{<<"additionalResponses">> := [#{<<"success">> := false, <<"schema">> := <<"error">>}]} = Form,
    {200, TdHdrs, One} = ?T:raw(get, "/api/things/wot-home/easy-home-01", [], none),
    "application/td+json" = proplists:get_value("content-type", TdHdrs),
    {200, _, Node} = ?T:raw(get, "/.well-known/wot", [], none),
    Files = [write(Config, "list.json", Body), write(Config, "one.json", One),
             write(Config, "node.json", Node)],
    {0, Report} = node(Config, "validate.js", Files),
    ct:pal("~ts", [Report]),
    {match, _} = re:run(Report, "checked 5 TDs, 0 failed"),
    %% The checker can fail: a TD without its security is refused.
    Broken = write(Config, "broken.json", evatar_json:encode(maps:remove(<<"security">>, TD))),
    {1, Refused} = node(Config, "validate.js", [Broken]),
    {match, _} = re:run(Refused, "checked 1 TDs, 1 failed").

%% The WoT consumer is an agent of the pairing: it is in the Body Mapping
%% Registry, bound to the home's components like any VA.
consumer_is_bound_like_a_va(_Config) ->
    {200, #{<<"agents">> := [#{<<"entity">> := <<"wot">>}], <<"bound">> := Bound}} =
        ?T:get("/api/pairings/wot-home/bindings"),
    [_] = [B || #{<<"consumer">> := #{<<"entity">> := <<"wot">>, <<"component">> := <<"wot.", ?LAMP>>},
                  <<"provider">> := #{<<"component">> := <<?LAMP>>},
                  <<"type">> := <<"SwitchSocketOn">>} = B <- Bound],
    %% The dashboard's graph shows it on the agents' side.
    {200, Graph} = ?T:get("/api/pairings/wot-home/graph"),
    {match, _} = re:run(evatar_json:encode(Graph), "\"wot\\.BedroomSocketSwitch01\"").

%% Invoking an action is a change: without the operator token, 401.
actions_need_the_token(_Config) ->
    {401, #{<<"error">> := <<"unauthorized">>}} =
        ?T:request(post, action_path("SwitchSocketOn"), [], "{}"),
    {401, #{<<"error">> := <<"bad_token">>}} =
        ?T:request(post, action_path("SwitchSocketOn"), [{"authorization", "Bearer wrong-token"}], "{}").

%% A node-wot consumer fetches the lamp's TD and invokes SwitchSocketOn
%% through it: the request goes through the pairing to the simulated
%% socket, whose feedback is the action's output; the house's socket is on.
node_wot_switches_the_lamp(Config) ->
    Url = ?T:url("/api/things/wot-home/easy-home-01"),
    {0, Out} = node(Config, "consume.js", [Url, ?TOKEN, "invoke", ?LAMP ".SwitchSocketOn", "{}"]),
    ct:pal("~ts", [Out]),
    {match, [Json]} = re:run(Out, "^OUTPUT (.*)$", [multiline, {capture, all_but_first, binary}]),
    {ok, #{<<"Socket">> := <<"on">>, <<"Room">> := <<"bedroom">>}} = evatar_json:decode(Json),
    {0, Off} = node(Config, "consume.js", [Url, ?TOKEN, "invoke", ?LAMP ".SwitchSocketOff", "{}"]),
    {match, _} = re:run(Off, "OUTPUT .*\"Socket\":\"off\"").

%% The time sensor pushes TimeOfDay readings once bound: node-wot reads
%% the property, the reading's parameters.
node_wot_reads_the_time(Config) ->
    Path = "/api/things/wot-home/easy-home-01/properties/TimeSensor01/TimeOfDay",
    until(fun() -> element(1, ?T:get(Path)) =:= 200 end),
    {200, #{<<"TimeOfDay">> := _}} = ?T:get(Path),
    Url = ?T:url("/api/things/wot-home/easy-home-01"),
    {0, Out} = node(Config, "consume.js", [Url, ?TOKEN, "read", "TimeSensor01.TimeOfDay"]),
    ct:pal("~ts", [Out]),
    {match, _} = re:run(Out, "OUTPUT .*\"TimeOfDay\":\"[0-9][0-9]:[0-9][0-9]\""),
    {200, #{<<"TimeSensor01.TimeOfDay">> := #{<<"TimeOfDay">> := _}}} =
        ?T:get("/api/things/wot-home/easy-home-01/properties"),
    %% A stream that never pushed (nothing publishes the MQTT devices'
    %% states): 503 no_reading, the error the TD declares.
    [#{<<"properties">> := MqttProps}] = [X || #{<<"title">> := ?MQTT_AV} = X <- things()],
    [#{<<"forms">> := [#{<<"href">> := Href} | _]} | _] = maps:values(MqttProps),
    {503, #{<<"error">> := <<"no_reading">>}} = ?T:get("/" ++ binary_to_list(Href)).

%% node-wot 0.8.16 with only its MQTT binding consumes the MQTT Avatar's
%% TD: it observes the temperature through its MQTT form (a reading the
%% device published, retained, on its state topic) and invokes a plug
%% action through its: the device's command topic gets the payload the
%% form's bil:mqttCommand names, published by node-wot, not by EVATAR.
node_wot_mqtt_drives_the_devices(Config) ->
    [Td] = [X || #{<<"title">> := ?MQTT_AV} = X <- things()],
    Port = integer_to_binary(maps:get(port, ?config(broker, Config))),
    Broker = <<"mqtt://127.0.0.1:", Port/binary, "/">>,
    Mqtt = fun(Kind) -> [{Name, F} || {Name, #{<<"forms">> := Fs}} <- maps:to_list(maps:get(Kind, Td)),
                                      #{<<"href">> := <<B:(byte_size(Broker))/binary, _/binary>>} = F <- Fs,
                                      B =:= Broker] end,
    [{Action, Payload} | _] =
        [{A, P} || {A, #{<<"href">> := H, <<"bil:mqttCommand">> := <<"raw:", P/binary>>}} <- Mqtt(<<"actions">>),
                   H =:= <<Broker/binary, "home/hall_plug/set">>],
    %% (the sensor's component has two streams on its state topic)
    [Property | _] = lists:sort([P || {P, #{<<"href">> := H}} <- Mqtt(<<"properties">>),
                                      H =:= <<Broker/binary, "home/hall_temperature">>]),
    File = write(Config, "mqtt-avatar.td.json", evatar_json:encode(Td)),
    {ok, C} = mqtt_client:start_link(#{host => "127.0.0.1", port => maps:get(port, ?config(broker, Config)),
                                       client_id => <<"wot-suite-devices">>}),
    ok = mqtt_client:await_connected(C, evatar_test_time:guard()),
    {ok, _} = mqtt_client:subscribe(C, [{<<"home/hall_plug/set">>, 1}]),
    ok = mqtt_client:publish(C, <<"home/hall_temperature">>, <<"21.5">>, #{qos => 1, retain => true}),
    {0, Out} = node(Config, "consume_mqtt.js", [File, Action, Property], ?config(npm_mqtt, Config)),
    ct:pal("~ts", [Out]),
    {match, _} = re:run(Out, ["OBSERVED \\Q", Property, "\\E 21.5\n"]),
    {match, _} = re:run(Out, ["INVOKED \\Q", Action, "\\E "]),
    receive
        {mqtt_client, C, {publish, #{topic := <<"home/hall_plug/set">>, payload := Got}}} -> Payload = Got
    after evatar_test_time:guard() -> ct:fail(no_command_published)
    end,
    ok = mqtt_client:publish(C, <<"home/hall_temperature">>, <<>>, #{qos => 1, retain => true}),
    ok = mqtt_client:stop(C).

%% A pairing holds one agent: while the WoT consumer is joined, a VA is
%% refused `occupied' (docs/wot.md, limits).
a_va_cannot_join_beside_it(_Config) ->
    {error, occupied} = evatar:join(?HOME, agent, <<"another-va">>, ?VA_CRED).

%% A muted lamp does not answer: after the pairing's feedback timeout the
%% action answers 504 feedback_timeout, the error its TD declares.
feedback_timeout_is_504(Config) ->
    ok = avatar_sim:mute(?config(home, Config), <<?LAMP>>),
    try
        {504, #{<<"error">> := <<"feedback_timeout">>}} =
            ?T:request(post, action_path("SwitchSocketOn"), auth(), "{}")
    after
        avatar_sim:unmute(?config(home, Config), <<?LAMP>>)
    end,
    {200, #{<<"Socket">> := <<"on">>}} = ?T:request(post, action_path("SwitchSocketOn"), auth(), "{}").

%% A pairing holds one agent (docs/wot.md, limits): while a VA holds it the
%% consumer lists the Avatar's TD but its actions answer 503 not_joined,
%% naming the taken slot; once the VA leaves, the consumer joins.
a_joined_va_keeps_it_out(Config) ->
    Path = "/api/things/wot-busy/7008/actions/HomeLightActuator01/TurnLightOn",
    {503, #{<<"error">> := <<"not_joined">>, <<"message">> := M}} = ?T:request(post, Path, auth(), "{}"),
    {match, _} = re:run(M, "agent slot is taken"),
    ?config(busy_va, Config) ! stop,
    until(fun() ->
                  case ?T:get("/api/pairings/wot-busy/bindings") of
                      {200, #{<<"agents">> := [#{<<"entity">> := <<"wot">>}]}} -> true;
                      _ -> false
                  end
          end).

%% ---------------------------------------------------------------------------

%% A process joined to ?BUSY as Role, described, until told to stop.
hold(Role, Entity, Description) ->
    Parent = self(),
    Cred = case Role of agent -> ?VA_CRED; avatar -> ?AV_CRED end,
    Pid = spawn(fun() ->
                        {ok, S} = evatar:join(?BUSY, Role, Entity, Cred),
                        ok = evatar:describe(S, Description#{entity_id := Entity}),
                        Parent ! {held, self()},
                        receive stop -> evatar:leave(S) end
                end),
    receive {held, Pid} -> Pid after evatar_test_time:guard() -> ct:fail({cannot_join, Entity}) end.

example(File) ->
    {ok, Xml} = file:read_file(filename:join([code:priv_dir(bil), "examples", File])),
    {ok, D} = bil:parse_description(Xml),
    D.

smart_home_va_stub() -> example("light_va.xml").

auth() -> [{"authorization", "Bearer " ?TOKEN}].

things() ->
    {200, _, Body} = ?T:raw(get, "/api/things", [], none),
    {ok, TDs} = evatar_json:decode(list_to_binary(Body)),
    TDs.

%% Retained Home Assistant discovery configs of a light, a switch, a
%% temperature sensor and a motion sensor (docs/mqtt.md section 2.1).
announce(Mqtt) ->
    {ok, C} = mqtt_client:start(Mqtt#{client_id => <<"wot-suite-announcer">>}),
    ok = mqtt_client:await_connected(C, evatar_test_time:guard()),
    Dev = fun(Id) -> #{<<"ids">> => [Id], <<"name">> => Id} end,
    Configs = [{<<"light/kitchen_light">>,
                #{<<"name">> => <<"Kitchen light">>, <<"uniq_id">> => <<"kitchen_light">>,
                  <<"cmd_t">> => <<"home/kitchen_light/set">>, <<"stat_t">> => <<"home/kitchen_light/state">>,
                  <<"dev">> => Dev(<<"kitchen_light">>)}},
               {<<"switch/hall_plug">>,
                #{<<"name">> => <<"Hall plug">>, <<"uniq_id">> => <<"hall_plug">>,
                  <<"cmd_t">> => <<"home/hall_plug/set">>, <<"stat_t">> => <<"home/hall_plug/state">>,
                  <<"dev">> => Dev(<<"hall_plug">>)}},
               {<<"sensor/hall_temperature">>,
                #{<<"name">> => <<"Hall temperature">>, <<"uniq_id">> => <<"hall_temperature">>,
                  <<"stat_t">> => <<"home/hall_temperature">>, <<"dev_cla">> => <<"temperature">>,
                  <<"unit_of_meas">> => <<"C">>, <<"dev">> => Dev(<<"hall_temperature">>)}},
               {<<"binary_sensor/hall_motion">>,
                #{<<"name">> => <<"Hall motion">>, <<"uniq_id">> => <<"hall_motion">>,
                  <<"stat_t">> => <<"home/hall_motion">>, <<"dev_cla">> => <<"motion">>,
                  <<"dev">> => Dev(<<"hall_motion">>)}}],
    [ok = mqtt_client:publish(C, <<"homeassistant/", T/binary, "/config">>, evatar_json:encode(J),
                              #{qos => 1, retain => true}) || {T, J} <- Configs],
    mqtt_client:stop(C).

action_path(Service) -> "/api/things/wot-home/easy-home-01/actions/" ?LAMP "/" ++ Service.

home_bound() ->
    case ?T:get("/api/pairings/wot-home/bindings") of
        {200, #{<<"bound">> := Bound, <<"agents">> := [_]}} ->
            lists:any(fun(#{<<"provider">> := #{<<"component">> := C}}) -> C =:= <<?LAMP>> end, Bound);
        _ ->
            false
    end.

write(Config, Name, Data) ->
    F = filename:join(?config(priv_dir, Config), Name),
    ok = file:write_file(F, Data),
    F.

%% Runs a script of the data dir with the installed node_modules (Npm:
%% those of another npm project).
node(Config, Script, Args) ->
    node(Config, Script, Args, ?config(npm, Config)).

node(Config, Script, Args, Npm) ->
    Node = os:find_executable("node"),
    Node =/= false orelse ct:fail("node is not installed (Debian: nodejs, npm)"),
    evatar_test_npm:run(Node, [filename:join(?config(data_dir, Config), Script) | Args],
                        evatar_test_npm:node_env(Npm)).


%% @doc Contract test of the HTTP API: schemathesis (PyPI, pinned in this
%% suite's data dir) fuzzes the live server with requests made from
%% priv/openapi.json and checks every answer against it: no 5xx, no status,
%% content type, header or body outside the document. The node has the
%% operator token, a pairing bound to the simulated smart home (avatar_sim)
%% and a VA, a pairing with identities, one for the fuzzer to change and
%% delete, a kept MQTT Avatar, a kept WoT Avatar (its TD a file) and a WoT
%% consumer exporting the home as a Thing, so that routes with ids answer
%% real data.
%% docs/api.md section 6 says how to run it alone.
-module(evatar_web_contract_SUITE).

-include_lib("common_test/include/ct.hrl").
-import(evatar_test_wait, [until/1]).

-export([all/0, suite/0, init_per_suite/1, end_per_suite/1]).
-export([create_input_is_options_and_id/1, fuzz_the_live_server/1, a_wrong_document_fails/1]).

-define(T, evatar_web_test).
-define(TOKEN, "contract-operator-token-0123456789abcdef").
-define(HOME, <<"contract-home">>).
-define(IDS, <<"contract-ids">>).
-define(SCRATCH, <<"contract-scratch">>).
-define(MQTT_PAIRING, <<"contract-mqtt">>).
-define(MQTT_AV, <<"contract-plug">>).
-define(WOT_PAIRING, <<"contract-wot">>).
-define(WOT_AV, <<"contract-lamp">>).
%% The pairing the node's WoT consumer exports (docs/wot.md), and the
%% home's entity in it.
-define(THINGS, <<"contract-things">>).
-define(THING, <<"contract-thing">>).
-define(VA_CRED, <<"contract-va-secret">>).
-define(AV_CRED, <<"contract-av-secret">>).
%% A failure found by the fuzzer reproduces with this seed (docs/api.md).
-define(SEED, "20261202").

suite() -> [{timetrap, {minutes, 8}}].

all() -> [create_input_is_options_and_id, a_wrong_document_fails, fuzz_the_live_server].

init_per_suite(Config) ->
    Python = venv(),
    ok = application:set_env(agent_bridge, listeners, [], [{persistent, true}]),
    {ok, _} = application:ensure_all_started(evatar),
    {ok, _} = application:ensure_all_started(agent_bridge),
    {ok, _} = application:ensure_all_started(mqtt_avatar),
    {ok, _} = application:ensure_all_started(wot_avatar),
    {ok, _} = application:ensure_all_started(avatar_sim),
    {ok, _} = agent_bridge:start_listener(contract, #{port => 0}),
    {ok, Addr} = agent_bridge:address(contract),
    [_ = evatar:delete_pairing(P) || P <- pairings()],
    Creds = #{agent_credential => ?VA_CRED, avatar_credential => ?AV_CRED},
    {ok, _} = evatar:create_pairing(?HOME, Creds#{join_timeout => 600000}),
    {ok, _} = evatar:create_pairing(?THINGS, Creds#{join_timeout => 600000}),
    ?T:start(#{operator_token_hash => evatar:hash_credential(list_to_binary(?TOKEN)),
               things => [#{pairing => ?THINGS, credential => ?VA_CRED}]}),
    {ok, _} = evatar:create_pairing(?SCRATCH, Creds),
    {ok, _} = evatar:create_pairing(?IDS, #{agent_credential => ?VA_CRED,
                                           identities => [#{entity => <<"cam">>, role => avatar,
                                                            credential => ?AV_CRED}]}),
    %% The simulated smart home joins ?HOME as its Avatar, and a VA with
    %% its counterpart description (bil's smart_home_va.xml) as the agent.
    {ok, Home} = avatar_sim:start_home(#{endpoints => [Addr], spool => ?config(priv_dir, Config),
                                         gateways => [#{pairing => ?HOME, credential => ?AV_CRED},
                                                      #{pairing => ?THINGS, credential => ?AV_CRED,
                                                        entity_id => ?THING}]}),
    Va = start_va(Addr),
    %% A kept MQTT Avatar on a real mosquitto, joined to its own pairing.
    {ok, Broker} = evatar_test_mosquitto:start(),
    {ok, _} = evatar:create_pairing(?MQTT_PAIRING, Creds),
    {ok, _} = mqtt_avatar:keep(#{entity_id => ?MQTT_AV,
                                 mqtt => #{host => "127.0.0.1", port => maps:get(port, Broker)},
                                 evatar => #{endpoints => [Addr], pairing => ?MQTT_PAIRING,
                                             credential => ?AV_CRED},
                                 description => mqtt_xml(), discovery => false}),
    until(fun() ->
                  case ?T:get("/api/pairings/" ++ binary_to_list(?HOME) ++ "/bindings") of
                      {200, #{<<"bound">> := [_ | _], <<"avatars">> := [_ | _]}} -> true;
                      _ -> false
                  end
          end),
    %% A kept WoT Avatar, its TD a file (its action's host answers nothing;
    %% a CoAP action is left out, one problem).
    {ok, _} = evatar:create_pairing(?WOT_PAIRING, Creds),
    Td = filename:join(?config(priv_dir, Config), "contract-lamp.td.json"),
    ok = file:write_file(Td, evatar_test_fixtures:wot_lamp_td(<<"contract-lamp">>)),
    {ok, _} = wot_avatar:keep(#{entity_id => ?WOT_AV, td => {file, Td}, allowed_hosts => [<<"127.0.0.1">>],
                                evatar => #{endpoints => [Addr], pairing => ?WOT_PAIRING,
                                            credential => ?AV_CRED}}),
    until(fun() -> element(1, ?T:get("/api/mqtt_avatars/" ++ binary_to_list(?MQTT_AV))) =:= 200 end),
    until(fun() ->
                  element(1, ?T:get("/api/wot_avatars/" ++ binary_to_list(?WOT_AV) ++ "/problems")) =:= 200
          end),
    Thing = "/api/things/" ++ binary_to_list(?THINGS) ++ "/" ++ binary_to_list(?THING),
    until(fun() -> element(1, ?T:raw(get, Thing, [], none)) =:= 200 end),
    %% The clock's reading comes once the consumer is bound to it, after
    %% the TD is listed (later on a loaded machine): until it is there, its
    %% property answers 503 no_reading, and the fuzzer would see no 2xx.
    until(fun() ->
                  element(1, ?T:raw(get, Thing ++ "/properties/TimeSensor01/TimeOfDay", [], none))
                      =:= 200
          end),
    [{python, Python}, {home, Home}, {va, Va}, {broker, Broker} | Config].

end_per_suite(Config) ->
    ?config(va, Config) ! stop,
    ok = avatar_sim:stop(?config(home, Config)),
    _ = mqtt_avatar:unkeep(?MQTT_AV),
    _ = wot_avatar:unkeep(?WOT_AV),
    ok = evatar_test_mosquitto:stop(?config(broker, Config)),
    [_ = evatar:delete_pairing(P) || P <- pairings()],
    %% What the fuzzer created.
    [_ = evatar:delete_pairing(Id) || #{id := Id} <- evatar:pairings()],
    ok = agent_bridge:stop_listener(contract),
    ?T:stop(),
    %% evatar_web_test's defaults have no `things': later suites must not
    %% start this suite's consumer.
    application:unset_env(evatar_web, things).

pairings() -> [?HOME, ?IDS, ?SCRATCH, ?MQTT_PAIRING, ?THINGS, ?WOT_PAIRING].

%% ---------------------------------------------------------------------------
%% Cases
%% ---------------------------------------------------------------------------

%% POST's body is PUT's options and `id' (OpenAPI 3.0 cannot extend an
%% object that forbids other properties, so the document repeats them):
%% the two lists stay the same.
create_input_is_options_and_id(_Config) ->
    {ok, #{<<"components">> := #{<<"schemas">> := Schemas}}} =
        evatar_json:decode(element(2, file:read_file(spec()))),
    #{<<"CreateInput">> := #{<<"properties">> := Create, <<"additionalProperties">> := false},
      <<"OptionsInput">> := #{<<"properties">> := Options, <<"additionalProperties">> := false}} = Schemas,
    Options = maps:remove(<<"id">>, Create),
    #{<<"id">> := #{<<"maxLength">> := 128}} = Create.

%% The checker can fail: a copy of the document that leaves out the 404
%% of GET /api/pairings/{id} makes schemathesis report the server's 404.
a_wrong_document_fails(Config) ->
    {ok, Spec} = evatar_json:decode(element(2, file:read_file(spec()))),
    #{<<"paths">> := #{<<"/api/pairings/{id}">> := #{<<"get">> := #{<<"responses">> := R} = Get} = P}
          = Paths} = Spec,
    Wrong = Spec#{<<"paths">> := Paths#{<<"/api/pairings/{id}">> :=
                                            P#{<<"get">> := Get#{<<"responses">> := maps:remove(<<"404">>, R)}}}},
    File = filename:join(?config(priv_dir, Config), "wrong-openapi.json"),
    ok = file:write_file(File, evatar_json:encode(Wrong)),
    {Status, Out} = schemathesis(Config, File, ["--include-name", "GET /api/pairings/{id}",
                                                "-n", "5", "--phases", "coverage,fuzzing"]),
    ct:pal("~ts", [Out]),
    true = Status =/= 0,
    {match, _} = re:run(Out, "Undocumented status code", [unicode]),
    {match, _} = re:run(Out, "\\[404\\] Not Found", [unicode]).

%% Every operation of the document, fuzzed with a fixed seed: no failure,
%% and every operation answered a 2xx at least once (so was checked on
%% real data, not only on 404s and 400s).
fuzz_the_live_server(Config) ->
    T0 = erlang:monotonic_time(millisecond),
    {Status, Out} = schemathesis(Config, spec(), []),
    ct:pal("schemathesis took ~b s~n~ts", [(erlang:monotonic_time(millisecond) - T0) div 1000, Out]),
    Script = filename:join(?config(data_dir, Config), "statuses.py"),
    {0, Statuses} = run(?config(python, Config), [Script, ndjson(Config)], []),
    ct:pal("~ts", [Statuses]),
    case Status of
        0 -> ok;
        _ -> ct:fail({schemathesis_found_failures, Status, "see the report above"})
    end,
    case re:run(Statuses, "operations without a 2xx: none", [unicode]) of
        {match, _} -> ok;
        nomatch -> ct:fail({operations_without_real_data, "see the table above"})
    end.

ndjson(Config) -> filename:join(?config(priv_dir, Config), "schemathesis.ndjson").

%% ---------------------------------------------------------------------------
%% Schemathesis
%% ---------------------------------------------------------------------------

spec() -> filename:join(code:priv_dir(evatar_web), "openapi.json").

%% Runs `schemathesis run' on `Spec' against the live server, with the
%% checks the contract is made of and the configuration of config/1.
schemathesis(Config, Spec, Extra) ->
    Toml = filename:join(?config(priv_dir, Config), "schemathesis.toml"),
    ok = file:write_file(Toml, config()),
    Exe = filename:join(filename:dirname(?config(python, Config)), "schemathesis"),
    Checks = "not_a_server_error,status_code_conformance,content_type_conformance,"
             "response_schema_conformance,response_headers_conformance,positive_data_acceptance,negative_data_rejection",
    Args = ["--config-file", Toml, "--no-color", "run", Spec,
            "--url", string:trim(?T:url(""), trailing, "/"),
            "--checks", Checks, "--seed", ?SEED, "--workers", "1",
            "--report", "junit,ndjson", "--report-dir", ?config(priv_dir, Config),
            "--report-ndjson-path", ndjson(Config)] ++ Extra,
    ct:pal("~ts ~ts", [Exe, lists:join(" ", Args)]),
    run(Exe, Args, [{"EVATAR_TOKEN", ?TOKEN}, {"HOME", ?config(priv_dir, Config)},
                    {"COLUMNS", "200"}]).

%% The token for every request (the document's `bearer' scheme); a bounded
%% number of examples per operation; ids of real pairings and of the MQTT
%% Avatar for half the requests of the routes with ids (the other half are
%% the fuzzer's own); event streams read up to their first event. Values a
%% schema cannot state come from the node: a standby_node is a node of the
%% cluster, an MQTT Avatar's xml is a BIL description. The methods sent to
%% see a 405 leave out TRACE (cowboy refuses it itself, 501, before it reads
%% the path) and OPTIONS (204 with Allow on every path of the document; the
%% document lists no OPTIONS operations) (docs/api.md section 6).
config() ->
    Ids = fun(L) -> lists:join(", ", [["\"", X, "\""] || X <- L]) end,
    ["max-stream-events = 1\n",
     "request-timeout = 20\n",
     "continue-on-failure = true\n",
     "[generation]\nmax-examples = 20\ndatabase = \"none\"\n",
     "[phases.coverage]\nunexpected-methods = [\"GET\", \"PUT\", \"POST\", \"DELETE\","
     " \"PATCH\"]\n",
     "[phases.stateful]\nmax-steps = 10\n",
     "[auth.openapi.bearer]\nbearer = \"${EVATAR_TOKEN}\"\n",
     "[dictionaries.reads]\nvalues = [", Ids([?HOME, ?IDS, ?MQTT_PAIRING]), "]\n",
     "[dictionaries.changes]\nvalues = [", Ids([?SCRATCH]), "]\n",
     "[dictionaries.avatars]\nvalues = [", Ids([?MQTT_AV]), "]\n",
     "[dictionaries.wot_avatars]\nvalues = [", Ids([?WOT_AV]), "]\n",
     "[dictionaries.events]\nvalues = [", Ids([?HOME]), "]\n",
     "[dictionaries.nodes]\nvalues = [", Ids([atom_to_binary(node())]), "]\n",
     "[dictionaries.xml]\nvalues = ['", mqtt_xml(), "']\n",
     "[dictionaries.things]\nvalues = [", Ids([?THINGS]), "]\n",
     "[dictionaries.thing]\nvalues = [", Ids([?THING]), "]\n",
     "[dictionaries.component]\nvalues = [\"BedroomSocketSwitch01\"]\n",
     "[dictionaries.service]\nvalues = [\"SwitchSocketOn\"]\n",
     %% One criterion per entry (several are or'ed); the first entry that
     %% matches an operation is the one that applies.
     "[[operations]]\ninclude-name-regex = \"^GET /api/pairings/\"\n",
     "parameters = { \"path.id\" = { dictionary = \"reads\", probability = 0.5 } }\n",
     "[[operations]]\ninclude-name-regex = \"^(PUT|POST|DELETE) /api/pairings\"\n",
     "parameters = { \"path.id\" = { dictionary = \"changes\", probability = 0.3 },"
     " \"body.standby_node\" = { dictionary = \"nodes\", probability = 1.0 } }\n",
     "[[operations]]\ninclude-name-regex = \"^GET /api/mqtt_avatars/\"\n",
     "parameters = { \"path.id\" = { dictionary = \"avatars\", probability = 0.5 } }\n",
     "[[operations]]\ninclude-name-regex = \"^GET /api/wot_avatars/\"\n",
     "parameters = { \"path.id\" = { dictionary = \"wot_avatars\", probability = 0.5 } }\n",
     "[[operations]]\ninclude-name-regex = \"^PUT /api/mqtt_avatars/\"\n",
     "parameters = { \"path.id\" = { dictionary = \"avatars\", probability = 0.5 },"
     " \"body.xml\" = { dictionary = \"xml\", probability = 1.0 } }\n",
     "[dictionaries.sensor]\nvalues = [\"TimeSensor01\"]\n",
     "[dictionaries.reading]\nvalues = [\"TimeOfDay\"]\n",
     %% A property with a reading: the home's clock sends one at its start.
     "[[operations]]\ninclude-name-regex = \"^GET /api/things/.*/properties/\"\n",
     "parameters = { \"path.pairing\" = { dictionary = \"things\", probability = 0.7 },"
     " \"path.entity\" = { dictionary = \"thing\", probability = 0.7 },"
     " \"path.component\" = { dictionary = \"sensor\", probability = 0.7 },"
     " \"path.service\" = { dictionary = \"reading\", probability = 0.7 } }\n",
     "[[operations]]\ninclude-name-regex = \"^(GET|POST) /api/things/\"\n",
     "parameters = { \"path.pairing\" = { dictionary = \"things\", probability = 0.7 },"
     " \"path.entity\" = { dictionary = \"thing\", probability = 0.7 },"
     " \"path.component\" = { dictionary = \"component\", probability = 0.7 },"
     " \"path.service\" = { dictionary = \"service\", probability = 0.7 } }\n",
     "[[operations]]\ninclude-name = \"GET /api/events\"\n",
     "parameters = { \"query.pairing\" = { dictionary = \"events\", probability = 0.5 } }\n"].

%% A venv under _build (EVATAR_CONTRACT_VENV to choose another) with the
%% pinned requirements of the data dir; made again when they change.
venv() ->
    Python3 = os:find_executable("python3"),
    Python3 =/= false orelse ct:fail("python3 is not installed (Debian: python3, python3-venv)"),
    Src = proplists:get_value(source, evatar_web:module_info(compile)),
    Root = filename:dirname(filename:dirname(filename:dirname(filename:dirname(Src)))),
    Venv = case os:getenv("EVATAR_CONTRACT_VENV") of
               V when is_list(V), V =/= "" -> V;
               _ -> filename:join([Root, "_build", "contract-venv"])
           end,
    Req = filename:join([Root, "apps", "evatar_web", "test", "evatar_web_contract_SUITE_data",
                         "requirements.txt"]),
    {ok, Pins} = file:read_file(Req),
    Marker = filename:join(Venv, "requirements.installed"),
    Python = filename:join([Venv, "bin", "python"]),
    case file:read_file(Marker) of
        {ok, Pins} ->
            ok;
        _ ->
            {0, _} = run(Python3, ["-m", "venv", "--clear", Venv], []),
            case run(Python, ["-m", "pip", "install", "--quiet", "--disable-pip-version-check",
                              "-r", Req], []) of
                {0, _} -> ok;
                {S, Out} -> ct:fail({cannot_install_schemathesis, S, Out})
            end,
            ok = file:write_file(Marker, Pins)
    end,
    Python.

run(Exe, Args, Env) ->
    Port = open_port({spawn_executable, Exe}, [{args, Args}, {env, Env}, exit_status, binary,
                                               stderr_to_stdout]),
    collect(Port, []).

collect(Port, Acc) ->
    receive
        {Port, {data, D}} -> collect(Port, [Acc, D]);
        {Port, {exit_status, S}} -> {S, unicode:characters_to_list(iolist_to_binary(Acc))}
    after evatar_test_time:ms(420000) -> ct:fail({no_exit, iolist_to_binary(Acc)})
    end.

%% ---------------------------------------------------------------------------
%% The fixture's clients
%% ---------------------------------------------------------------------------

%% The VA: a process of its own (init_per_suite's ends), holding the
%% connection until told to stop.
start_va(Addr) ->
    Parent = self(),
    {ok, Xml} = file:read_file(filename:join([code:priv_dir(bil), "examples", "smart_home_va.xml"])),
    {ok, Description} = bil:parse_description(Xml),
    Pid = spawn(fun() ->
                        {ok, C} = agent_bridge_client:connect(
                                    [Addr], #{pairing => ?HOME, role => agent,
                                              entity_id => maps:get(entity_id, Description),
                                              credential => ?VA_CRED}),
                        ok = agent_bridge_client:describe(C, Description),
                        Parent ! {va_up, self()},
                        receive stop -> agent_bridge_client:close(C) end
                end),
    receive {va_up, Pid} -> Pid after evatar_test_time:guard() -> ct:fail(va_did_not_join) end.

mqtt_xml() ->
    iolist_to_binary(
      ["<bil:description xmlns:bil=\"urn:evatar:bil:1\"><bil:context>"
       "<EntityID>", ?MQTT_AV, "</EntityID><APIName>MQTT</APIName><EntityType>Avatar</EntityType>"
       "<Context>x</Context></bil:context><bil:types><bil:Component>"
       "<ComponentID>Plug01</ComponentID>"
       "<Service><ServiceCategory>ACTUATOR</ServiceCategory><ServiceType>TurnLightOn</ServiceType>"
       "<ServiceParameters><Light>yes</Light><Room>kitchen</Room>"
       "<MqttCommandTopic>cmnd/plug/POWER</MqttCommandTopic>"
       "<MqttStateTopic>stat/plug/POWER</MqttStateTopic>"
       "<MqttCommand>raw:ON</MqttCommand><MqttExpect>raw:ON</MqttExpect>"
       "<MqttValue>Light=raw</MqttValue><MqttMap>ON=on OFF=off</MqttMap>"
       "</ServiceParameters></Service></bil:Component></bil:types></bil:description>"]).


%% Common Test: a node brought up by its configuration file alone, with
%% EVATAR_CONFIG naming a file in the case's directory. Group from_file:
%% each node is a real OS process (OTP peer, controlled over its standard
%% I/O) whose applications start in the release's order (node_config,
%% evatar, agent_bridge, mqtt_avatar). Group release: the release itself
%% (rebar3 release, then bin/evatar daemon, eval, stop, foreground). The
%% MQTT Avatars talk to a real mosquitto (evatar_test_mosquitto); VAs join over TCP.
-module(node_config_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").

-export([all/0, suite/0, groups/0, init_per_suite/1, end_per_suite/1,
         init_per_testcase/2, end_per_testcase/2]).
-export([starts_everything_from_the_file/1, killed_avatar_restarts_with_backoff/1,
         node_restart_brings_everything_back/1, malformed_files_stop_the_start/1,
         identities_from_the_file/1,
         bad_broker_is_a_reported_crash_loop/1, init_per_group/2, end_per_group/2,
         release_daemon_runs_the_file/1, release_refuses_a_bad_file/1,
         release_refuses_another_nodes_data_dir/1, release_refuses_token_hash_and_file/1]).
%% Run on the peer nodes.
-export([collect/0, log/2, events/0]).

-define(VA_CRED, <<"va-secret-for-config">>).
-define(AV_CRED, <<"av-secret-for-config">>).
-define(COLLECTOR, node_config_suite_log).

suite() -> [{timetrap, {minutes, 3}}].

all() ->
    [{group, from_file}, malformed_files_stop_the_start, {group, release}].

groups() ->
    [{from_file, [], [starts_everything_from_the_file, killed_avatar_restarts_with_backoff,
                      node_restart_brings_everything_back, bad_broker_is_a_reported_crash_loop,
                      identities_from_the_file]},
     %% The release as shipped (rebar3 release, bin/evatar): its boot order
     %% and its applications, driven only through bin/evatar.
     {release, [], [release_daemon_runs_the_file, release_refuses_a_bad_file,
                    release_refuses_another_nodes_data_dir, release_refuses_token_hash_and_file]}].

init_per_group(release, Config) ->
    Rel = evatar_test_release:dir(),
    %% The nodes' HOME holds their cookie, as an installed node's does
    %% (docs/ha.md section 1); their epmd is the group's own.
    Home = filename:join(?config(priv_dir, Config), "home"),
    Cookie = filename:join(Home, ".erlang.cookie"),
    ok = filelib:ensure_dir(Cookie),
    ok = file:write_file(Cookie, binary:encode_hex(crypto:strong_rand_bytes(24))),
    ok = file:change_mode(Cookie, 8#400),
    [{rel, Rel}, {home, Home},
     {epmd_port, integer_to_list(free_port())} | Config];
init_per_group(_, Config) ->
    Config.

end_per_group(release, Config) ->
    _ = os:cmd("ERL_EPMD_PORT=" ++ ?config(epmd_port, Config) ++ " epmd -kill"),
    ok;
end_per_group(_, _Config) ->
    ok.

init_per_suite(Config) ->
    {ok, Broker} = evatar_test_mosquitto:start(),
    [{broker, Broker} | Config].

end_per_suite(Config) ->
    ok = evatar_test_mosquitto:stop(?config(broker, Config)).

init_per_testcase(Case, Config) ->
    [{prefix, atom_to_list(Case)} | Config].

end_per_testcase(_Case, _Config) ->
    [catch peer:stop(P) || P <- cleanup()],
    ok.

%% ---------------------------------------------------------------------------
%% Cases
%% ---------------------------------------------------------------------------

%% The file's listener listens, its pairing exists and a VA joins it with
%% the file's credential over TCP, and its MQTT Avatar is connected to the
%% broker, has discovered a device under the file's prefix (with the
%% file's override applied) and has joined the pairing.
starts_everything_from_the_file(Config) ->
    ok = publish_light(Config),
    {Peer, Port} = boot(Config, home_file(Config, #{})),
    {ok, {{127, 0, 0, 1}, Port}} = peer:call(Peer, agent_bridge, address, [<<"main">>]),
    [#{id := <<"home">>}] = peer:call(Peer, evatar, pairings, []),
    Avatar = await_running(Peer, 1),
    ok = evatar_test_cluster:await(fun() -> up =:= maps:get(mqtt, peer:call(Peer, mqtt_avatar, status, [Avatar]))
                                   end, 60000, mqtt_up),
    {ok, Va} = agent_bridge_client:connect([{{127, 0, 0, 1}, Port}],
                                           #{pairing => <<"home">>, role => agent,
                                             entity_id => <<"test-va">>, credential => ?VA_CRED}),
    ok = agent_bridge_client:close(Va),
    #{description := D} = await_avatar_joined(Peer),
    [Light] = [C || #{id := <<"KitchenLight01">>} = C <- maps:get(components, D)],
    ?assert(lists:member({<<"Room">>, <<"hall">>},
                         lists:append([Ps || #{parameters := Ps} <- maps:get(services, Light)])),
            Light).

%% A pairing whose file lists a VA's own identity, its credential kept
%% hashed (bin/evatar hash_credential's form): that VA joins over TCP with
%% its secret; another EntityID with the same secret, or with the role
%% credential the file also gives, is refused BadCredential (unlisted ids
%% are refused by default), and so is the listed VA with a wrong secret.
identities_from_the_file(Config) ->
    Port = free_port(),
    Own = <<"kitchen-va-own-secret">>,
    Text = ["{listeners, [#{name => \"main\", ip => \"127.0.0.1\", port => ", integer_to_list(Port),
            "}]}.\n{pairings, [#{id => \"home\", agent_credential => \"", ?VA_CRED, "\",\n"
            "              identities => [#{entity => \"kitchen-va\", role => agent,\n"
            "                               credential => ", node_config:hashed_credential(Own), "}]}]}.\n"],
    File = filename:join(?config(priv_dir, Config), "identities.config"),
    ok = file:write_file(File, Text),
    {Peer, Port} = boot(Config, {File, Port}),
    [#{id := <<"home">>}] = peer:call(Peer, evatar, pairings, []),
    Join = fun(Entity, Credential) ->
                   agent_bridge_client:connect([{{127, 0, 0, 1}, Port}],
                                               #{pairing => <<"home">>, role => agent,
                                                 entity_id => Entity, credential => Credential})
           end,
    {error, {refused, <<"BadCredential">>, _}} = Join(<<"other-va">>, Own),
    {error, {refused, <<"BadCredential">>, _}} = Join(<<"other-va">>, ?VA_CRED),
    {error, {refused, <<"BadCredential">>, _}} = Join(<<"kitchen-va">>, ?VA_CRED),
    {ok, Va} = Join(<<"kitchen-va">>, Own),
    ok = agent_bridge_client:close(Va).

%% exit(Avatar, kill): the Avatar is started again after 1 s, then 2 s,
%% then 4 s (the delay doubles while runs stay short), joins again each
%% time, and the third short run in a row is logged as a crash loop.
killed_avatar_restarts_with_backoff(Config) ->
    {Peer, _} = boot(Config, home_file(Config, #{})),
    A1 = await_running(Peer, 1),
    _ = await_avatar_joined(Peer),
    Delays = [kill_and_await_restart(Peer, N) || N <- [2, 3, 4]],
    %% The delay each restart waited: what the next-delay was before it.
    [1000, 2000, 4000] = Delays,
    #{crashes := 3, next_delay_ms := 8000} = kept(Peer),
    A4 = await_running(Peer, 4),
    ?assertNotEqual(A1, A4),
    _ = await_avatar_joined(Peer),
    [#{crashes := 3, entity := <<"house">>}] =
        [R || #{what := crash_loop} = R <- logged(Peer)].

%% Stopping the node and starting it again from the same file brings the
%% listener, the pairing and the kept Avatar back, with nobody at a shell.
node_restart_brings_everything_back(Config) ->
    File = home_file(Config, #{}),
    {Peer1, Port} = boot(Config, File),
    _ = await_running(Peer1, 1),
    ok = peer:stop(Peer1),
    {Peer2, Port} = boot(Config, File),
    {ok, {_, Port}} = peer:call(Peer2, agent_bridge, address, [<<"main">>]),
    [#{id := <<"home">>}] = peer:call(Peer2, evatar, pairings, []),
    _ = await_running(Peer2, 1),
    _ = await_avatar_joined(Peer2).

%% A broker that refuses the Avatar (a wrong password: mosquitto with a
%% password file) makes it stop at every start: the keeper keeps trying
%% with a growing delay and reports the crash loop; the node and its
%% pairing stay up.
bad_broker_is_a_reported_crash_loop(Config) ->
    {ok, Broker} = evatar_test_mosquitto:start(#{users => [{"home", "right"}]}),
    try
        File = home_file(Config, #{broker_port => maps:get(port, Broker),
                                   mqtt_extra => ", username => \"home\", password => \"wrong\"",
                                   restart => "#{min_ms => 100, max_ms => 400}"}),
        {Peer, _} = boot(Config, File),
        ok = evatar_test_cluster:await(fun() -> [] =/= [R || #{what := crash_loop} = R <- logged(Peer)] end,
                                       60000, crash_loop),
        [#{crashes := N} | _] = [R || #{what := crash_loop} = R <- logged(Peer)],
        ?assert(N >= 3),
        ok = evatar_test_cluster:await(fun() -> maps:get(next_delay_ms, kept(Peer)) =:= 400 end, 60000,
                                       delay_at_max),
        [#{id := <<"home">>}] = peer:call(Peer, evatar, pairings, [])
    after
        ok = evatar_test_mosquitto:stop(Broker)
    end.

%% Files with mistakes stop the start: node_config refuses, with the file,
%% the line, the entry and the mistake, and nothing else starts (no
%% listener, no pairing).
malformed_files_stop_the_start(Config) ->
    Cases =
        [{"{pairings, [#{id => \"home\", agent_credential => \"a\"}]}.\n",
          "line 1: pairings entry 1 (home): avatar_credential required"},
         {"{listeners, [#{port => 7400, acceptors => 0}]}.\n",
          "line 1: listeners entry 1: acceptors must be a positive integer"},
         {"{pairings, [#{id => \"home\", agent_credential => \"a\", avatar_credential => \"b\"}]}.\n"
          "{mqtt_avatars, [#{entity_id => \"house\", pairing => \"flat\",\n"
          "                  mqtt => #{host => \"localhost\", port => 1883}}]}.\n",
          "line 2: mqtt_avatars entry 1 (house): pairing \"flat\" is not declared"},
         {"{pairings, [#{id => \"a\", agent_credential => \"a\", avatar_credential => \"b\"},\n"
          "            #{id => \"a\", agent_credential => \"c\", avatar_credential => \"d\"}]}.\n",
          "pairings: id \"a\" appears more than once"},
         {"{pairings, [#{id => \"a\", zz_unknown_key_of_node_config_suite => 1}]}.\n",
          "line 1: unknown word zz_unknown_key_of_node_config_suite"},
         {"{pairings, [#{id => \"a\"}]\n", "line 1: the file ends inside the entry that starts at line 1"},
         {"{pairings, [#{id => \"a\",, port => 1}]}.\n", "line 1: syntax error before"}],
    Dir = ?config(priv_dir, Config),
    {ok, Peer, _} = peer:start_link(#{name => peer:random_name(?MODULE), host => "127.0.0.1",
                                      longnames => true, connection => standard_io,
                                      args => code_path()}),
    remember(Peer),
    lists:foreach(
      fun({N, {Text, Expected}}) ->
              File = filename:join(Dir, "bad" ++ integer_to_list(N) ++ ".config"),
              ok = file:write_file(File, Text),
              true = peer:call(Peer, os, putenv, ["EVATAR_CONFIG", File]),
              {error, {node_config, {{bad_config, File, Problems} = Reason, _}}} = start_apps(Peer),
              Message = binary_to_list(peer:call(Peer, node_config, format_error, [Reason])),
              ?assert(lists:any(fun(P) -> string:find(P, Expected) =/= nomatch end, Problems),
                      {Expected, Problems}),
              ?assertEqual(File ++ ": ", lists:sublist(Message, length(File) + 2)),
              [] = [A || {A, _, _} <- peer:call(Peer, application, which_applications, []),
                         lists:member(A, [node_config, evatar, agent_bridge, mqtt_avatar])]
      end, lists:zip(lists:seq(1, length(Cases)), Cases)),
    %% The misspelt key did not become an atom on the node.
    {'EXIT', _} = (catch peer:call(Peer, erlang, list_to_existing_atom,
                                   ["zz_unknown_key_of_node_config_suite"])),
    ok.

%% `bin/evatar daemon' with the file: the listener, the pairing and the
%% MQTT Avatar come up; the Avatar killed is started again; after
%% `bin/evatar stop' and `daemon' again everything is back.
release_daemon_runs_the_file(Config) ->
    {File, Port} = home_file(Config, #{}),
    Env = release_env(Config, File),
    try
        Ok = File ++ ": ok (1 listener(s), 1 pairing(s), 1 MQTT Avatar(s))",
        Ok = string:trim(evatar_cmd(Config, Env, "check_config")),
        Ok = string:trim(evatar_cmd(Config, Env, "daemon")),
        ok = await_eval(Config, Env, "joined", "house_joined()"),
        {ok, Va} = agent_bridge_client:connect([{{127, 0, 0, 1}, Port}],
                                               #{pairing => <<"home">>, role => agent,
                                                 entity_id => <<"release-va">>, credential => ?VA_CRED}),
        ok = agent_bridge_client:close(Va),
        "ok" = eval(Config, Env, "begin [#{avatar := P}] = mqtt_avatar:kept(), true = exit(P, kill), ok end"),
        ok = await_eval(Config, Env, "2", "begin [#{starts := N, state := running}] = mqtt_avatar:kept(), N end"),
        ok = await_eval(Config, Env, "joined", "house_joined()"),
        _ = evatar_cmd(Config, Env, "stop"),
        Ok = string:trim(evatar_cmd(Config, Env, "daemon")),
        ok = await_eval(Config, Env, "joined", "house_joined()")
    after
        _ = evatar_cmd(Config, Env, "stop")
    end.

%% `bin/evatar foreground' with a file with mistakes: the node does not
%% start, and its output names the file, the line, the entry and every
%% mistake of each entry, one line each (an Avatar's unknown key and its
%% port in quotes in one run: MQTT_REVIEW D9; a pairing's unknown word and
%% its bad values; the http section's four mistakes).
release_refuses_a_bad_file(Config) ->
    File = filename:join(?config(priv_dir, Config), "release_bad.config"),
    ok = file:write_file(File, "{pairings, [#{id => \"home\", agent_credential => \"a\",\n"
                               "              avatar_credential => \"b\", join_timeout => -5,\n"
                               "              zz_colour_of_node_config_suite => blue, "
                               "max_avatars => \"many\"}]}.\n"
                               "{mqtt_avatars, [#{entity_id => \"house\", pairing => \"home\", "
                               "discover => #{},\n"
                               "                  mqtt => #{host => \"localhost\", port => \"1883\"}}]}.\n"
                               "{http, #{colour => \"red\", ip => \"no-address\", port => 70000, "
                               "max_clients => 0}}.\n"),
    Env = release_env(Config, File),
    %% An unknown word does not stop the reading of its entry, and the
    %% http section's four mistakes are all named.
    Expected = [File ++ ": line 1: pairings entry 1 (home): join_timeout -5 is not accepted",
                File ++ ": line 1: pairings entry 1 (home): max_avatars \"many\" is not accepted",
                File ++ ": line 3: unknown word zz_colour_of_node_config_suite",
                File ++ ": line 4: mqtt_avatars entry 1 (house): unknown key discover (known: ",
                File ++ ": line 4: mqtt_avatars entry 1 (house): mqtt: port must be an integer of "
                        "at least 1",
                File ++ ": line 6: http: unknown key colour",
                File ++ ": line 6: http: ip \"no-address\" is not an IP address",
                File ++ ": line 6: http: port: ",
                File ++ ": line 6: http: max_clients: "],
    %% daemon (its pre-start hook), check_config and foreground (the boot
    %% itself) all refuse, with the message on the terminal.
    lists:foreach(fun(Command) ->
                          Out = evatar_cmd(Config, Env, Command ++ "; echo \"exit status $?\""),
                          [?assertNotEqual(nomatch, string:find(Out, E), {Command, Out})
                           || E <- Expected],
                          ?assertNotEqual(nomatch, string:find(Out, "EVATAR will not start"), Out),
                          ?assertEqual(nomatch, string:find(Out, "exit status 0"), {Command, Out})
                  end, ["daemon", "check_config", "foreground"]),
    %% The daemon did not start.
    ?assertNotEqual(nomatch, string:find(evatar_cmd(Config, Env, "ping"), "not running")).

%% An http section with both an operator_token_hash and a token_file (the
%% HTTP API refuses both at its start): check_config names it, daemon does
%% not start, and foreground says why and exits with status 1, without
%% "Kernel pid terminated" or an erl_crash.dump.
release_refuses_token_hash_and_file(Config) ->
    Dir = filename:join(?config(priv_dir, Config), "token_both"),
    ok = filelib:ensure_path(Dir),
    Token = filename:join(Dir, "token"),
    ok = file:write_file(Token, "a-long-operator-token\n"),
    File = filename:join(Dir, "evatar.config"),
    ok = file:write_file(File, ["{http, #{port => 0, token_file => \"", Token, "\",\n"
                                "         operator_token_hash => ",
                                node_config:hashed_credential(<<"another-token">>), "}}.\n"]),
    Env = release_env(Config, File),
    Dump = filename:join(?config(rel, Config), "erl_crash.dump"),
    _ = file:delete(Dump),
    Expected = File ++ ": line 1: http: operator_token_hash and token_file: give one, not both",
    lists:foreach(fun(Command) ->
                          Out = evatar_cmd(Config, Env, Command ++ "; echo \"exit status $?\""),
                          ct:log("~s:~n~s", [Command, Out]),
                          ?assertNotEqual(nomatch, string:find(Out, Expected), {Command, Out}),
                          ?assertNotEqual(nomatch, string:find(Out, "exit status 1"), {Command, Out}),
                          ?assertEqual(nomatch, string:find(Out, "Kernel pid terminated"),
                                       {Command, Out}),
                          ?assertEqual(nomatch, string:find(Out, "crash dump"), {Command, Out})
                  end, ["check_config", "daemon", "foreground"]),
    ?assertEqual(false, filelib:is_regular(Dump)),
    ?assertNotEqual(nomatch, string:find(evatar_cmd(Config, Env, "ping"), "not running")),
    %% The boot itself, without the start script's check: the release's
    %% boot file run as bin/evatar runs it (its root, OTP's erlexec), in
    %% Dir (where a crash dump would land).
    Rel = ?config(rel, Config),
    Boot = filename:join([Rel, "releases", "0.1.0", "start"]),
    Bin = filename:join([code:root_dir(), "erts-" ++ erlang:system_info(version), "bin"]),
    Out = os:cmd(lists:flatten(
                   ["cd '", Dir, "' && EVATAR_CONFIG='", File, "' ROOTDIR='", Rel, "' BINDIR='",
                    Bin, "' EMU=beam PROGNAME=erl timeout 120 '", Bin, "/erlexec' -noinput "
                    "-mode embedded -boot '", Boot, "' -boot_var SYSTEM_LIB_DIR '",
                    code:lib_dir(), "' 2>&1; echo \"exit status $?\""])),
    ct:log("boot:~n~s", [Out]),
    ?assertNotEqual(nomatch, string:find(Out, Expected), Out),
    ?assertNotEqual(nomatch, string:find(Out, "exit status 1"), Out),
    ?assertEqual(nomatch, string:find(Out, "Kernel pid terminated"), Out),
    ?assertEqual(false, filelib:is_regular(filename:join(Dir, "erl_crash.dump"))).

%% A data directory (EVATAR_DATA_DIR) made by one node name, given to a
%% node of another name: that node does not start, and its console log
%% names the directory and the node it belongs to. The first node, started
%% again on it, runs.
release_refuses_another_nodes_data_dir(Config) ->
    {File, _Port} = home_file(Config, #{}),
    First = release_env(Config, File),
    Data = env("EVATAR_DATA_DIR", First),
    Other = release_env(Config, File, Data),
    try
        _ = evatar_cmd(Config, First, "daemon"),
        ok = await_eval(Config, First, "joined", "house_joined()"),
        _ = evatar_cmd(Config, First, "stop"),
        ok = await_not_running(Config, First),
        _ = evatar_cmd(Config, Other, "daemon"),
        ok = await_not_running(Config, Other),
        Log = console_log(Other),
        ?assertNotEqual(nomatch, string:find(Log, "data_dir_of_another_node"), Log),
        ?assertNotEqual(nomatch, string:find(Log, Data), Log),
        ?assertNotEqual(nomatch, string:find(Log, env("EVATAR_NODE", First)), Log),
        _ = evatar_cmd(Config, First, "daemon"),
        ok = await_eval(Config, First, "joined", "house_joined()")
    after
        _ = evatar_cmd(Config, First, "stop"),
        _ = evatar_cmd(Config, Other, "stop")
    end.

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

%% One node of the release: its own name, data directory (the catalogue's
%% mnesia directory belongs to one node name, docs/ha.md section 1) and
%% console log directory, so no case, and no other suite that starts the
%% release, leaves it a directory of another node.
release_env(Config, File) ->
    release_env(Config, File, none).

release_env(Config, File, Data0) ->
    Name = "nc" ++ integer_to_list(erlang:unique_integer([positive])) ++ "_" ++ os:getpid(),
    Dir = filename:join(?config(priv_dir, Config), Name),
    Data = case Data0 of
               none -> filename:join(Dir, "data");
               _ -> Data0
           end,
    Dist = integer_to_list(free_port()),
    [{"EVATAR_CONFIG", File}, {"EVATAR_NODE", Name ++ "@127.0.0.1"},
     {"HOME", ?config(home, Config)}, {"ERL_EPMD_PORT", ?config(epmd_port, Config)},
     {"EVATAR_DATA_DIR", Data}, {"RUNNER_LOG_DIR", filename:join(Dir, "log")},
     {"EVATAR_DIST_PORT_MIN", Dist}, {"EVATAR_DIST_PORT_MAX", Dist},
     %% The HTTP API on a free port (suites run side by side).
     {"EVATAR_HTTP_PORT", "0"}].

env(Name, Env) ->
    {Name, Value} = lists:keyfind(Name, 1, Env),
    Value.

await_not_running(Config, Env) ->
    evatar_test_cluster:await(fun() -> string:find(evatar_cmd(Config, Env, "ping"), "not running") =/= nomatch
                              end, 90000, not_running).

%% The node's console log (run_erl's erlang.log.N files), read anew.
console_log(Env) ->
    Files = filelib:wildcard(filename:join(env("RUNNER_LOG_DIR", Env), "erlang.log.*")),
    lists:append([binary_to_list(B) || F <- lists:sort(Files), {ok, B} <- [file:read_file(F)]]).

evatar_cmd(Config, Env, Args) ->
    Exports = [[K, "='", V, "' "] || {K, V} <- Env],
    os:cmd(lists:flatten(["cd '", ?config(rel, Config), "' && env ", Exports,
                          "timeout 120 bin/evatar ", Args, " 2>&1"])).

%% Evaluates an expression on the release's node; `house_joined()' stands
%% for "the Avatar house is registered in the pairing home".
eval(Config, Env, Expr0) ->
    Joined = "case evatar:registry(<<\"home\">>) of {ok, Es} -> case [x || #{entity := <<\"house\">>, "
             "registered := true} <- Es] of [_] -> joined; _ -> no end; _ -> no end",
    Expr = string:replace(Expr0, "house_joined()", Joined, all),
    string:trim(evatar_cmd(Config, Env, ["eval '", Expr, ".'"])).

%% On a timeout, the node's console log says why (e.g. it did not start).
await_eval(Config, Env, Expected, Expr) ->
    case evatar_test_cluster:await(fun() -> eval(Config, Env, Expr) =:= Expected end, 90000, {eval, Expr}) of
        ok -> ok;
        {error, _} = Error ->
            ct:log("~s console log:~n~s", [env("EVATAR_NODE", Env), console_log(Env)]),
            Error
    end.

%% A file with a listener on a free port, the pairing "home" and the MQTT
%% Avatar "house" on the suite's broker, discovering under the case's prefix.
home_file(Config, Opts) ->
    Port = maps:get(listener_port, Opts, free_port()),
    Broker = maps:get(broker_port, Opts, maps:get(port, ?config(broker, Config))),
    Prefix = "ha_" ++ ?config(prefix, Config),
    Text = io_lib:format(
             "%% written by node_config_SUITE\n"
             "{listeners, [#{name => \"main\", ip => \"127.0.0.1\", port => ~b}]}.\n"
             "{pairings, [#{id => \"home\", agent_credential => \"~s\",\n"
             "              avatar_credential => \"~s\"}]}.\n"
             "{mqtt_avatars,\n"
             " [#{entity_id => \"house\", pairing => \"home\",\n"
             "    mqtt => #{host => \"127.0.0.1\", port => ~b~s},\n"
             "    discovery => #{homeassistant => \"~s\", zigbee2mqtt => false},\n"
             "    overrides => #{\"Kitchen Light 01\" => #{room => \"hall\"}},\n"
             "    settle => 200~s}]}.\n",
             [Port, ?VA_CRED, ?AV_CRED, Broker, maps:get(mqtt_extra, Opts, ""), Prefix,
              case maps:get(restart, Opts, undefined) of
                  undefined -> "";
                  R -> ",\n    restart => " ++ R
              end]),
    File = filename:join(?config(priv_dir, Config), ?config(prefix, Config) ++ ".config"),
    ok = file:write_file(File, Text),
    {File, Port}.

%% Starts a node from the file, as the release does, with a log collector.
boot(_Config, {File, Port}) ->
    {ok, Peer, _} = peer:start_link(#{name => peer:random_name(?MODULE), host => "127.0.0.1",
                                      longnames => true, connection => standard_io,
                                      args => code_path(), env => [{"EVATAR_CONFIG", File}]}),
    remember(Peer),
    ok = peer:call(Peer, ?MODULE, collect, []),
    ok = peer:call(Peer, logger, add_handler, [node_config_suite, ?MODULE, #{level => notice}]),
    ok = start_apps(Peer),
    {Peer, Port}.

%% The release's order: node_config fills the others' environment first.
start_apps(Peer) ->
    lists:foldl(fun(App, ok) ->
                        case peer:call(Peer, application, ensure_all_started, [App], 30000) of
                            {ok, _} -> ok;
                            {error, _} = Error -> Error
                        end;
                   (_, Error) -> Error
                end, ok, [node_config, evatar, agent_bridge, mqtt_avatar]).

code_path() ->
    lists:append([["-pa", D] || D <- code:get_path(), string:find(D, "_build") =/= nomatch]).

kept(Peer) ->
    [Status] = peer:call(Peer, mqtt_avatar, kept, []),
    Status.

%% Waits for the kept Avatar's Nth start, running; returns its pid.
await_running(Peer, Starts) ->
    ok = evatar_test_cluster:await(fun() ->
                                  case kept(Peer) of
                                      #{state := running, starts := Starts} -> true;
                                      _ -> false
                                  end
                          end, 60000, {avatar_running, Starts}),
    #{avatar := Pid} = kept(Peer),
    Pid.

%% Kills the running Avatar; returns the delay its keeper waits before
%% start number N, read while it waits.
kill_and_await_restart(Peer, N) ->
    #{avatar := Pid, state := running} = kept(Peer),
    Expected = maps:get(next_delay_ms, kept(Peer)),
    true = peer:call(Peer, erlang, exit, [Pid, kill]),
    _ = await_running(Peer, N),
    Expected.

await_avatar_joined(Peer) ->
    Find = fun() ->
                   case peer:call(Peer, evatar, registry, [<<"home">>]) of
                       {ok, Entities} -> [E || #{role := avatar, entity := <<"house">>,
                                                 registered := true} = E <- Entities];
                       _ -> []
                   end
           end,
    ok = evatar_test_cluster:await(fun() -> Find() =/= [] end, 60000, avatar_joined),
    [E] = Find(),
    E.

%% A retained Home Assistant discovery config for one light, under the
%% case's prefix.
publish_light(Config) ->
    P = list_to_binary(?config(prefix, Config)),
    Disc = #{<<"name">> => null, <<"uniq_id">> => <<P/binary, "-light">>,
             <<"~">> => <<P/binary, "/light">>, <<"stat_t">> => <<"~/state">>,
             <<"cmd_t">> => <<"~/set">>, <<"schema">> => <<"json">>,
             <<"dev">> => #{<<"ids">> => [<<P/binary, "-dev">>], <<"name">> => <<"Kitchen Light 01">>,
                            <<"mdl">> => <<"LightSwitch">>}},
    {ok, C} = mqtt_client:start_link(#{host => {127, 0, 0, 1},
                                       port => maps:get(port, ?config(broker, Config)),
                                       client_id => <<"node-config-suite">>}),
    ok = mqtt_client:await_connected(C, evatar_test_time:guard()),
    ok = mqtt_client:publish(C, <<"ha_", P/binary, "/light/", P/binary, "/config">>,
                             evatar_json:encode(Disc), #{qos => 1, retain => true}),
    mqtt_client:stop(C).

free_port() ->
    {ok, S} = gen_tcp:listen(0, [{ip, {127, 0, 0, 1}}]),
    {ok, Port} = inet:port(S),
    ok = gen_tcp:close(S),
    Port.

remember(Peer) ->
    put(peers, [Peer | get_peers()]).

cleanup() ->
    Peers = get_peers(),
    put(peers, []),
    Peers.

get_peers() ->
    case get(peers) of
        undefined -> [];
        Ps -> Ps
    end.

%% ---------------------------------------------------------------------------
%% On the peer: a logger handler keeping the report maps
%% ---------------------------------------------------------------------------

collect() ->
    Pid = spawn(fun() -> collector([]) end),
    true = register(?COLLECTOR, Pid),
    ok.

collector(Events) ->
    receive
        {event, E} -> collector([E | Events]);
        {get, From} -> From ! {events, lists:reverse(Events)}, collector(Events)
    end.

log(#{msg := {report, Report}}, _Config) when is_map(Report) ->
    ?COLLECTOR ! {event, Report},
    ok;
log(_Event, _Config) ->
    ok.

events() ->
    ?COLLECTOR ! {get, self()},
    receive {events, Es} -> Es after evatar_test_time:guard() -> error(no_collector) end.

logged(Peer) ->
    peer:call(Peer, ?MODULE, events, []).

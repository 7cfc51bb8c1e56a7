%% Common Test suite of the release's operator commands (README.md,
%% "Operator commands"): a node of the release of evatar_test_release:dir/0
%% (EVATAR_REL, or `rebar3 release'), started with bin/evatar daemon with
%% its own HOME, data directory and free ports, and driven only with
%% bin/evatar cluster, pairings, pairing, create, bindings, rotate, delete,
%% mqtt_problems and wot_problems, in text and with --json; real clients
%% join it over TCP with the credentials the commands generated. The
%% cookie is never on a command line: every program the commands start is
%% traced (strace -f, execve), and the trace of relx's own `rpc' shows that
%% the check sees a leak.
-module(release_commands_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").

-compile([export_all, nowarn_export_all]).

-import(rel_node, [node_env/3, env/2, home/1, node_name/1, start_node/2,
                   stop_node/2, rel/3, run/4, quote/1]).

suite() -> [{timetrap, {minutes, 5}}].

all() ->
    [cluster_text_and_json, cookie_not_on_command_lines, usage_and_unreachable,
     commands_on_a_running_node, refusals_exit_1, http_api_of_the_release,
     commands_leave_no_atoms].

init_per_suite(Config) ->
    ct:timetrap({minutes, 10}),
    [{rel, evatar_test_release:dir()} | Config].

end_per_suite(_Config) ->
    ok.

%% One node per case, started with bin/evatar daemon.
init_per_testcase(Case, Config) ->
    Config1 = rel_node:init_case(Case, Config),
    Env = node_env(Config1, "ops", []),
    ok = start_node(Config1, Env),
    [{env, Env} | Config1].

end_per_testcase(_Case, Config) ->
    rel_node:end_case(Config).

%% ---------------------------------------------------------------------------
%% Cases
%% ---------------------------------------------------------------------------

%% cluster: the node and its quorum, as text and as JSON.
cluster_text_and_json(Config) ->
    Node = node_name(env(Config)),
    {0, Text} = evatar(Config, ["cluster"]),
    ct:pal("cluster:~n~ts", [Text]),
    ?assertMatch({match, _}, re:run(Text, "node: " ++ Node), Text),
    ?assertMatch({match, _}, re:run(Text, "quorum: yes"), Text),
    #{<<"node">> := NodeBin, <<"quorum">> := true} = json(evatar(Config, ["cluster", "--json"])),
    ?assertEqual(list_to_binary(Node), NodeBin).

%% The release carries the HTTP server's libraries and its node serves the
%% API: a read, OPTIONS with Allow, and a JSON 405 with Allow.
http_api_of_the_release(Config) ->
    Rel = ?config(rel, Config),
    [[_] = filelib:wildcard(filename:join([Rel, "lib", App ++ "-*"])) || App <- ["cowboy", "ranch", "cowlib"]],
    Log = rel_node:console_log(env(Config)),
    ok = evatar_test_wait:until(
           fun() -> re:run(Log(), "listening on http://127.0.0.1:[0-9]+/") =/= nomatch end,
           #{interval => 200}),
    {match, [Port]} = re:run(Log(), "listening on http://127.0.0.1:([0-9]+)/", [{capture, all_but_first, list}]),
    Url = "http://127.0.0.1:" ++ Port ++ "/api/cluster",
    {ok, _} = application:ensure_all_started(inets),
    {ok, {{_, 200, _}, Headers, Body}} = httpc:request(get, {Url, []}, [], []),
    "application/json" = proplists:get_value("content-type", Headers),
    {ok, #{<<"quorum">> := true}} = evatar_json:decode(list_to_binary(Body)),
    {ok, {{_, 204, _}, Options, ""}} = httpc:request(options, {Url, []}, [], []),
    "GET, HEAD, OPTIONS" = proplists:get_value("allow", Options),
    {ok, {{_, 405, _}, NotAllowed, Json}} = httpc:request(delete, {Url, []}, [], []),
    "GET, HEAD, OPTIONS" = proplists:get_value("allow", NotAllowed),
    {ok, #{<<"error">> := <<"method_not_allowed">>}} = evatar_json:decode(list_to_binary(Json)).

%% Bad usage exits 2 with the usage, before reaching any node, and a secret
%% given as an argument is refused; a node that does not run: exit 3.
usage_and_unreachable(Config) ->
    {2, Usage} = evatar(Config, ["pairing"]),
    ?assertMatch({match, _}, re:run(Usage, "Usage: bin/evatar"), Usage),
    {2, _} = evatar(Config, ["pairings", "unexpected"]),
    {2, _} = evatar(Config, ["create", "x", "--agent-credential-file", "/no/such/file"]),
    {2, _} = evatar(Config, ["rotate", "x", "agent", "plain-secret-argument"]),
    ok = stop_node(env(Config), Config),
    {3, Down} = evatar(Config, ["cluster"]),
    ?assertMatch({match, _}, re:run(Down, "cannot reach"), Down).

%% create generates credentials (printed once) with which a VA and an
%% Avatar join over TCP; pairings, pairing and cluster show the pairing;
%% bindings shows what is bound to what and the unbound entry with its
%% reason; rotate gives a new agent credential (the old one is refused, the
%% new one joins); delete removes the pairing.
commands_on_a_running_node(Config) ->
    with_facade([{create, 2}, {pairings, 0}, {pairing, 1}, {bindings, 1}, {rotate, 2},
                 {delete, 1}, {problems, 1}, {mqtt_avatars, 0}, {wot_problems, 1}, {wot_avatars, 0}],
                fun() -> commands(Config) end).

commands(Config) ->
    %% create, text: the secrets are shown once, with a warning.
    {0, Text} = evatar(Config, ["create", "shown"]),
    ?assertMatch({match, _}, re:run(Text, "New credentials \\(shown once"), Text),
    ?assertMatch({match, _}, re:run(Text, "agent_credential: \\S{20,}"), Text),
    %% create, JSON: the same, readable by a script.
    #{<<"generated_credentials">> := #{<<"agent_credential">> := VaCred,
                                        <<"avatar_credential">> := AvCred}} =
        json(evatar(Config, ["create", "home", "--json", "join_timeout=60000"])),
    %% Clients join with them over TCP.
    Va = join(Config, <<"home">>, agent, <<"va">>, VaCred),
    Av = join(Config, <<"home">>, avatar, <<"av">>, AvCred),
    ok = send(Av, {description, avatar_description(<<"av">>)}),
    ok = send(Va, {description, va_description(<<"va">>)}),
    _ = recv_until(Va, fun({control, {binding, #{bound := [_ | _]}}}) -> true;
                          (_) -> false
                       end),
    %% pairings and pairing.
    {0, Pairings} = evatar(Config, ["pairings"]),
    ?assertMatch({match, _}, re:run(Pairings, "home"), Pairings),
    ?assertMatch({match, _}, re:run(Pairings, "shown"), Pairings),
    PairingsJson = json(evatar(Config, ["pairings", "--json"])),
    ?assert(lists:member(<<"home">>, ids(PairingsJson)), PairingsJson),
    {0, One} = evatar(Config, ["pairing", "home"]),
    ?assertMatch({match, _}, re:run(One, "va"), One),
    #{} = json(evatar(Config, ["pairing", "home", "--json"])),
    %% cluster.
    {0, Cluster} = evatar(Config, ["cluster"]),
    ?assertMatch({match, _}, re:run(Cluster, node_name(env(Config))), Cluster),
    #{} = json(evatar(Config, ["cluster", "--json"])),
    %% bindings: the light is bound, the door is not (no provider).
    {0, Bindings} = evatar(Config, ["bindings", "home"]),
    ct:pal("bindings:~n~ts", [Bindings]),
    ?assertMatch({match, _},
                 re:run(Bindings, "va/LightEmulator01\\s+->\\s+ACTUATOR/TurnLightOn\\s+->\\s+"
                                  "av/Light01"), Bindings),
    ?assertMatch({match, _}, re:run(Bindings, "va/DoorEmulator01\\s+ACTUATOR/OpenDoor\\s+\\S+"),
                 Bindings),
    #{<<"bound">> := [_], <<"unbound">> := [_]} = json(evatar(Config, ["bindings", "home",
                                                                       "--json"])),
    %% rotate: a new agent credential; the old one is refused, the new joins.
    ok = close(Va),
    #{<<"generated_credential">> := NewVa} =
        json(evatar(Config, ["rotate", "home", "agent", "--json"])),
    ?assertNotEqual(VaCred, NewVa),
    <<"BadCredential">> = refused(Config, <<"home">>, agent, <<"va">>, VaCred),
    Va2 = join(Config, <<"home">>, agent, <<"va">>, NewVa),
    ok = close(Va2),
    %% A credential from a file, not from the command line.
    File = filename:join(?config(dir, Config), "secret"),
    ok = file:write_file(File, <<"from-a-file-0123456789\n">>),
    {0, Rotated} = evatar(Config, ["rotate", "home", "agent", "--credential-file", File]),
    nomatch = re:run(Rotated, "from-a-file"),
    ok = close(join(Config, <<"home">>, agent, <<"va">>, <<"from-a-file-0123456789">>)),
    %% mqtt_problems and wot_problems: none on this node.
    {0, _} = evatar(Config, ["mqtt_problems"]),
    {0, NoWots} = evatar(Config, ["wot_problems"]),
    ?assertMatch({match, _}, re:run(NoWots, "^No WoT Avatars on this node\\.$", [multiline]), NoWots),
    [] = json(evatar(Config, ["wot_problems", "--json"])),
    {1, NoWot} = evatar(Config, ["wot_problems", "wot-lamp"]),
    ?assertMatch({match, _}, re:run(NoWot, "refused: not_found \\(entity_id\\): no WoT Avatar wot-lamp"),
                 NoWot),
    %% delete.
    ok = close(Av),
    {0, _} = evatar(Config, ["delete", "home"]),
    ?assertNot(lists:member(<<"home">>, ids(json(evatar(Config, ["pairings", "--json"]))))).

%% No program a command starts has the cookie on its command line (strace
%% of every execve), and the command did reach the node; the same trace of
%% relx's own `rpc' finds the cookie, so the check can see a leak.
cookie_not_on_command_lines(Config) ->
    {ok, Cookie} = file:read_file(filename:join(home(env(Config)), ".erlang.cookie")),
    Trace = fun(Args) ->
                    File = filename:join(?config(dir, Config),
                                         "strace-" ++ integer_to_list(erlang:unique_integer(
                                                                         [positive]))),
                    Bin = filename:join([?config(rel, Config), "bin", "evatar"]),
                    {Rc, Out} = run(Config, env(Config), "/usr/bin/strace",
                                    ["-f", "-qq", "-e", "trace=execve", "-s", "65536",
                                     "-o", File, Bin | Args]),
                    {ok, Execs} = file:read_file(File),
                    {Rc, Out, Execs}
            end,
    {0, _, Execs} = Trace(["cluster"]),
    ?assertEqual(nomatch, binary:match(Execs, [Cookie, <<"\"-setcookie\"">>])),
    %% A create: whatever the node answers, neither the cookie nor the
    %% credentials generated for it were on a command line.
    {_, Out, CreateExecs} = Trace(["create", "traced", "--json"]),
    ct:pal("create: ~ts", [Out]),
    ?assertEqual(nomatch, binary:match(CreateExecs, [Cookie, <<"\"-setcookie\"">>])),
    Secrets = case re:run(Out, "\"([0-9a-f]{48})\"",
                          [global, {capture, all_but_first, binary}]) of
                  {match, Ms} -> [S || [S] <- Ms];
                  nomatch -> []
              end,
    _ = [?assertEqual(nomatch, binary:match(CreateExecs, S)) || S <- Secrets],
    {0, _, RpcExecs} = Trace(["rpc", "erlang", "node"]),
    ?assertNotEqual(nomatch, binary:match(RpcExecs, Cookie)).

%% A refusal of the node exits 1 with its code and message (as JSON with
%% --json).
refusals_exit_1(Config) ->
    with_facade([{pairing, 1}, {delete, 1}], fun() -> refusals(Config) end).

refusals(Config) ->
    {1, NotFound} = evatar(Config, ["pairing", "no-such-pairing"]),
    ?assertMatch({match, _}, re:run(NotFound, "refused: "), NotFound),
    #{<<"error">> := _, <<"message">> := _} =
        json1(evatar(Config, ["pairing", "no-such-pairing", "--json"])),
    {1, _} = evatar(Config, ["delete", "no-such-pairing"]).

%% 1,000 commands, from four shells at once, leave at most a few atoms in
%% the node: every node name a node sees stays an atom, and the helper
%% node of each command used to take a new one (relx's nodetool and our
%% operator commands: +1 or +2 per command, a health check every 10 s
%% fills the atom table in months). Each shell runs 250: 4 `cluster', 2
%% `ping' and 2 `eval' with USE_NODETOOL=1 (TLS distribution's path),
%% and 242 `ping', `rpc' and `eval' through erl_call. The helpers of
%% `cluster' and nodetool now take one of the fixed evatar_ctl1..4@HOST,
%% erl_call's a dynamic name, which the node gives again to the next one
%% once the first is gone. Every command must succeed: four at once used
%% to fail now and then on the vm.args another one was writing.
commands_leave_no_atoms(Config0) ->
    Config = [{rel, release_with_erts(Config0)} | Config0],
    Atoms = fun() ->
                    {0, Out} = evatar(Config, ["eval", "erlang:system_info(atom_count)."]),
                    list_to_integer(string:trim(Out))
            end,
    Before = Atoms(),
    Bin = filename:join([?config(rel, Config), "bin", "evatar"]),
    Shell = filename:join(?config(dir, Config), "commands.sh"),
    ok = file:write_file(Shell, commands_script(Bin)),
    Env = env(Config),
    Port = open_port({spawn_executable, "/bin/sh"},
                     [{args, [Shell, "4"]}, {env, Env}, exit_status, stderr_to_stdout, binary]),
    {Status, Out} = collect(Port, []),
    ct:pal("commands: exit ~p~n~ts", [Status, Out]),
    After = Atoms(),
    ct:pal("atom_count: ~p before, ~p after 1000 commands (+~p)", [Before, After, After - Before]),
    ct:comment("1000 commands: atom_count +~p", [After - Before]),
    ?assertEqual(0, Status, Out),
    ?assertMatch({match, _}, re:run(Out, "^ran 1000 commands, 0 failed", [multiline]), Out),
    %% Four shells: the four evatar_ctl names, and as many dynamic names as
    %% erl_call helpers were connected at once (four, and a few more when
    %% one connected before the node had seen the last one go).
    ?assert(After - Before =< 12, {atoms, Before, After}).

%% Four shells, each running its 250 commands one after another; prints
%% how many ran and how many failed.
commands_script(Bin) ->
    ["#!/bin/sh\n"
     "B=", quote(Bin), "\n"
     "shell() {\n"
     "  f=0\n"
     "  for i in 1 2; do\n"
     "    \"$B\" cluster >/dev/null 2>&1 || f=$((f+1))\n"
     "    USE_NODETOOL=1 \"$B\" ping >/dev/null 2>&1 || f=$((f+1))\n"
     "    USE_NODETOOL=1 \"$B\" eval 'ok.' >/dev/null 2>&1 || f=$((f+1))\n"
     "    \"$B\" cluster >/dev/null 2>&1 || f=$((f+1))\n"
     "  done\n"
     "  for i in $(seq 1 80); do\n"
     "    \"$B\" ping >/dev/null 2>&1 || f=$((f+1))\n"
     "    \"$B\" rpc erlang node >/dev/null 2>&1 || f=$((f+1))\n"
     "    \"$B\" eval 'ok.' >/dev/null 2>&1 || f=$((f+1))\n"
     "  done\n"
     "  \"$B\" ping >/dev/null 2>&1 || f=$((f+1))\n"
     "  \"$B\" ping >/dev/null 2>&1 || f=$((f+1))\n"
     "  echo $f > \"$1\"\n"
     "}\n"
     "dir=$(mktemp -d)\n"
     "for s in $(seq 1 \"$1\"); do shell \"$dir/$s\" & done\n"
     "wait\n"
     "failed=$(cat \"$dir\"/* | awk '{n += $1} END {print n}')\n"
     "rm -rf \"$dir\"\n"
     "echo \"ran $(($1 * 250)) commands, $failed failed\"\n"].

collect(Port, Acc) ->
    receive
        {Port, {data, D}} -> collect(Port, [D | Acc]);
        {Port, {exit_status, S}} -> {S, binary_to_list(iolist_to_binary(lists:reverse(Acc)))}
    after evatar_test_time:ms(600000) ->
            ct:fail({commands_hang, lists:reverse(Acc)})
    end.

%% The release as the tarball of `make tar' lays it out, with the ERTS it
%% runs on inside: a copy of bin/ beside links to the rest and to this
%% machine's ERTS. Without one, bin/evatar starts an `erl' for every command
%% to find the ERTS (half a second each here).
release_with_erts(Config) ->
    Rel = ?config(rel, Config),
    View = filename:join(?config(dir, Config), "rel"),
    ok = filelib:ensure_path(View),
    {0, _} = run(Config, [], "/bin/cp", ["-a", filename:join(Rel, "bin"), View]),
    Erts = "erts-" ++ erlang:system_info(version),
    _ = [ok = file:make_symlink(filename:join(Rel, F), filename:join(View, F))
         || F <- filelib:wildcard("*", Rel), F =/= "bin", F =/= Erts],
    Own = filename:join(Rel, Erts),
    ok = file:make_symlink(case filelib:is_dir(Own) of
                               true -> Own;
                               false -> filename:join(code:root_dir(), Erts)
                           end, filename:join(View, Erts)),
    View.

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

env(Config) -> ?config(env, Config).

%% The commands call evatar_ops (web-api's facade, landing in pieces): a
%% case whose functions are not there yet is skipped, saying which.
with_facade(Functions, Case) ->
    {module, evatar_ops} = code:ensure_loaded(evatar_ops),
    case [FA || {F, A} = FA <- Functions, not erlang:function_exported(evatar_ops, F, A)] of
        [] -> Case();
        Missing -> {skip, lists:flatten(io_lib:format("evatar_ops lacks ~p", [Missing]))}
    end.

evatar(Config, Args) ->
    rel(Config, env(Config), Args).

%% The JSON a command printed on success.
json({0, Out}) ->
    {ok, Term} = evatar_json:decode(list_to_binary(Out)),
    Term;
json({Rc, Out}) ->
    ct:fail({command_failed, Rc, Out}).

%% The JSON of a refusal (exit 1).
json1({1, Out}) ->
    {ok, Term} = evatar_json:decode(list_to_binary(Out)),
    Term.

ids(Pairings) when is_list(Pairings) ->
    [Id || #{<<"id">> := Id} <- Pairings];
ids(#{<<"pairings">> := Pairings}) ->
    ids(Pairings).

bridge(Config) ->
    {{127, 0, 0, 1}, list_to_integer(env("EVATAR_PORT", env(Config)))}.

connect_hello(Config, Pairing, Role, Entity, Cred) ->
    {Ip, Port} = bridge(Config),
    {ok, S} = gen_tcp:connect(Ip, Port, [binary, {packet, 4}, {active, false}], 10000),
    ok = gen_tcp:send(S, evatar_test_fixtures:hello(Pairing, Role, Entity, Cred, 1)),
    {S, recv(S)}.

join(Config, Pairing, Role, Entity, Cred) ->
    {S, {control, {welcome, _}}} = connect_hello(Config, Pairing, Role, Entity, Cred),
    S.

refused(Config, Pairing, Role, Entity, Cred) ->
    {S, {control, {refused, #{code := Code}}}} = connect_hello(Config, Pairing, Role, Entity,
                                                               Cred),
    ok = gen_tcp:close(S),
    Code.

send(S, {description, D}) ->
    gen_tcp:send(S, bil:encode_description(D)).

close(S) ->
    gen_tcp:close(S).

recv(S) -> evatar_test_fixtures:recv_doc(S, evatar_test_time:guard()).

recv_until(S, Pred) -> evatar_test_fixtures:recv_until(S, Pred, evatar_test_time:guard()).

va_description(Id) ->
    C = fun evatar_test_fixtures:component/3,
    evatar_test_fixtures:description(
      Id, agent, <<"TEST VA">>, <<"EmulatorDescription">>,
      [C(<<"LightEmulator01">>, [{<<"BEHAVIOUR">>, <<"Light">>}], [{<<"ACTUATOR">>, <<"TurnLightOn">>}]),
       C(<<"DoorEmulator01">>, [{<<"BEHAVIOUR">>, <<"Door">>}], [{<<"ACTUATOR">>, <<"OpenDoor">>}])]).

avatar_description(Id) ->
    evatar_test_fixtures:description(
      Id, avatar, <<"TEST AVATAR">>, <<"ActuatorDescription">>,
      [evatar_test_fixtures:component(<<"Light01">>, [{<<"ACTUATOR">>, <<"TurnLightOn">>}], [])]).

%% @doc Test support, not a suite: release nodes for the suites that drive
%% the release as an operator does (dist_SUITE, release_commands_SUITE). The
%% release of evatar_test_release:dir/0 (EVATAR_REL, or built once for the
%% run); each node with a HOME of its own (so a cookie of its own), its own
%% data directory, free ports and the case's epmd; `bin/evatar' run with its output in a file.
%% The suites' Config holds `rel', `dir' (the case's directory),
%% `epmd_port' and `nodes' (an ETS bag of the nodes started, for the end of
%% the case).
-module(rel_node).

-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").

-export([init_case/2, end_case/1]).
-export([clean_env/0, node_env/3, node_env/4, env/2, home/1, node_name/1,
         start_node/2, stop_node/2, kill_by_name/1, rel/3, run/4, quote/1, console_log/1]).

-define(WAIT, evatar_test_time:guard()).

%% @doc A case's directory, epmd port and table of nodes, in Config.
-spec init_case(atom(), list()) -> list().
init_case(Case, Config) ->
    Dir = filename:join(?config(priv_dir, Config), atom_to_list(Case)),
    ok = filelib:ensure_path(Dir),
    [EpmdPort] = evatar_test_cluster:free_ports(1),
    [{dir, Dir}, {epmd_port, EpmdPort}, {nodes, ets:new(nodes, [public, bag])} | Config].

%% @doc Stops what the case started: its nodes (by pid if stop does not
%% work), then its epmd.
-spec end_case(list()) -> ok.
end_case(Config) ->
    Nodes = ets:tab2list(?config(nodes, Config)),
    _ = [stop_node(Env, Config) || {node, Env} <- Nodes],
    _ = os:cmd("ERL_EPMD_PORT=" ++ integer_to_list(?config(epmd_port, Config))
               ++ " epmd -kill"),
    ok.

%% Variables a caller's environment might hold that would change what is
%% tested; unset for every command.
clean_env() ->
    [{V, false} || V <- ["EVATAR_COOKIE", "ERL_FLAGS", "ERL_AFLAGS", "ERL_ZFLAGS",
                         "ERL_EPMD_ADDRESS", "RELX_COOKIE", "EVATAR_DIST", "EVATAR_DIST_IP",
                         "EVATAR_PEERS", "USE_NODETOOL", "EVATAR_NODE", "EVATAR_PORT",
                         "EVATAR_IP", "EVATAR_HTTP", "EVATAR_HTTP_IP", "EVATAR_HTTP_TOKEN_FILE"]].

node_env(Config, Name, Extra) ->
    node_env(Config, Name, Extra, "127.0.0.1").

%% The environment of one node: its own HOME (so its own cookie), output
%% directory, name, ports and the case's epmd.
node_env(Config, Name, Extra, Host) ->
    Dir = filename:join(?config(dir, Config), Name),
    Home = filename:join(Dir, "home"),
    ok = filelib:ensure_path(Home),
    [Bridge, Dist] = evatar_test_cluster:free_ports(2),
    Base = [{"HOME", Home},
            {"RELX_OUT_FILE_PATH", Dir},
            {"RUNNER_LOG_DIR", filename:join(Dir, "log")},
            %% Its own catalogue: a data directory belongs to one node name.
            {"EVATAR_DATA_DIR", filename:join(Dir, "data")},
            {"EVATAR_NODE", "ds" ++ Name ++ os:getpid() ++ "@" ++ Host},
            {"EVATAR_PORT", integer_to_list(Bridge)},
            %% The HTTP API on a port of its own (suites run side by side).
            {"EVATAR_HTTP_PORT", "0"},
            {"EVATAR_DIST_PORT_MIN", integer_to_list(Dist)},
            {"EVATAR_DIST_PORT_MAX", integer_to_list(Dist)},
            {"ERL_EPMD_PORT", integer_to_list(?config(epmd_port, Config))}],
    lists:ukeymerge(1, lists:ukeysort(1, Extra),
                    lists:ukeysort(1, Base ++ [V || {K, _} = V <- clean_env(),
                                                    not lists:keymember(K, 1, Base)])).

env(Name, Env) ->
    {Name, Value} = lists:keyfind(Name, 1, Env),
    Value.

home(Env) -> env("HOME", Env).

node_name(Env) -> env("EVATAR_NODE", Env).

%% bin/evatar daemon, remembered for end_per_testcase. daemon returns once
%% the node answers a ping, before its applications have started: wait
%% until evatar runs, so that a node that dies while it boots (as every
%% node but the first did on the release's shared data directory) fails
%% here, not as an attacker refused by a node that is not there or a
%% remote_console that finds no node.
start_node(Config, Env) ->
    true = ets:insert(?config(nodes, Config), {node, Env}),
    case rel(Config, Env, ["daemon"]) of
        {0, _} ->
            Running = "lists:keymember(evatar, 1, application:which_applications()).",
            case evatar_test_cluster:await(fun() ->
                                          case rel(Config, Env, ["eval", Running]) of
                                              {0, Out} -> string:trim(Out) =:= "true";
                                              _ -> false
                                          end
                                  end, ?WAIT, {evatar_running, node_name(Env)}) of
                ok ->
                    ok;
                {error, _} = Error ->
                    ct:log("~s console log:~n~s", [node_name(Env), (console_log(Env))()]),
                    Error
            end;
        {Rc, Out} ->
            {error, {daemon, Rc, Out}}
    end.

stop_node(Env, Config) ->
    case rel(Config, Env, ["stop"]) of
        {0, _} -> ok;
        _ -> kill_by_name(node_name(Env))
    end.

%% kill -9 of the OS process whose command line names the node (a node
%% that bin/evatar cannot reach, when a case fails).
kill_by_name(Node) ->
    Arg = <<0, (list_to_binary(Node))/binary, 0>>,
    _ = [os:cmd("kill -9 " ++ Pid)
         || Pid <- filelib:wildcard("[0-9]*", "/proc"),
            {ok, Cmd} <- [file:read_file("/proc/" ++ Pid ++ "/cmdline")],
            binary:match(Cmd, <<0, "-name", Arg/binary>>) =/= nomatch],
    ok.

%% Runs bin/evatar with Args in Env: {ExitStatus, Output}.
rel(Config, Env, Args) ->
    run(Config, Env, filename:join([?config(rel, Config), "bin", "evatar"]), Args).

%% Runs a program with its output in a file (a daemon's children keep no
%% pipe of ours open) and its input from /dev/null.
run(Config, Env, Prog, Args) ->
    Out = filename:join(?config(dir, Config),
                        "cmd-" ++ integer_to_list(erlang:unique_integer([positive])) ++ ".out"),
    Cmd = "exec " ++ lists:join(" ", [quote(A) || A <- [Prog | Args]])
        ++ " > " ++ quote(Out) ++ " 2>&1 < /dev/null",
    Port = open_port({spawn_executable, "/bin/sh"},
                     [{args, ["-c", lists:flatten(Cmd)]}, {env, Env}, exit_status]),
    receive
        {Port, {exit_status, Status}} ->
            {ok, Bin} = file:read_file(Out),
            {Status, binary_to_list(Bin)}
    after ?WAIT ->
            ct:fail({no_exit, Prog, Args})
    end.

quote(S) ->
    "'" ++ lists:flatten(string:replace(S, "'", "'\\''", all)) ++ "'".

%% The node's console log (run_erl's, in RUNNER_LOG_DIR), read anew.
console_log(Env) ->
    File = filename:join(env("RUNNER_LOG_DIR", Env), "erlang.log.1"),
    fun() ->
            case file:read_file(File) of
                {ok, Bin} -> Bin;
                {error, enoent} -> <<>>
            end
    end.


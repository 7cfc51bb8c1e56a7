%% @doc Test support: the npm packages of the Web of Things suites
%% (node-wot 0.9.2 and the Thing Description Playground), pinned in
%% apps/evatar_web/test/evatar_web_wot_SUITE_data/package-lock.json and
%% installed once with `npm ci' into _build/wot-npm (EVATAR_WOT_NPM to
%% choose another directory), again when the lock file changes; and node
%% scripts run with them. evatar_web_wot_SUITE and wot_avatar_SUITE share it.
%% install/1 does the same for another npm project of a suite's data dir,
%% in a directory of its own: two versions of node-wot cannot share one
%% node_modules. install_mqtt/0 installs node-wot 0.8.16 with its MQTT
%% binding (no 0.9 release of it), pinned in
%% apps/wot_avatar/test/wot_avatar_SUITE_data/node-wot-mqtt, whose scripts
%% wot_avatar_SUITE and evatar_web_wot_SUITE run.
-module(evatar_test_npm).

-export([install/0, install/1, install_mqtt/0, node_env/1, run/3]).

%% `npm ci' into $1 of the project in $2 with npm $3, under flock(1) of
%% $1/.install.lock, unless the lock file there says it is done.
-define(INSTALL, "set -e; exec 9>\"$1/.install.lock\"; flock 9; "
                 "if cmp -s \"$2/package-lock.json\" \"$1/lock.installed\"; then exit 0; fi; "
                 "cp \"$2/package.json\" \"$2/package-lock.json\" \"$1/\"; "
                 "\"$3\" ci --no-audit --no-fund --prefix \"$1\"; "
                 "cp \"$2/package-lock.json\" \"$1/lock.installed\"").

%% @doc Installs the packages if the lock file changed since; their
%% directory. Raises when npm is missing or fails.
-spec install() -> file:filename().
install() ->
    Root = root(),
    Dir = case os:getenv("EVATAR_WOT_NPM") of
              V when is_list(V), V =/= "" -> V;
              _ -> filename:join([Root, "_build", "wot-npm"])
          end,
    install(filename:join([Root, "apps", "evatar_web", "test", "evatar_web_wot_SUITE_data"]), Dir).

%% @doc Installs the npm project (package.json and package-lock.json) of
%% directory Data into _build/wot-npm-NAME, NAME Data's last component
%% (EVATAR_WOT_NPM-NAME when that is set), if its lock file changed since;
%% that directory.
-spec install(file:filename()) -> file:filename().
install(Data) ->
    Name = filename:basename(Data),
    Dir = case os:getenv("EVATAR_WOT_NPM") of
              V when is_list(V), V =/= "" -> V ++ "-" ++ Name;
              _ -> filename:join([root(), "_build", "wot-npm-" ++ Name])
          end,
    install(Data, Dir).

%% @doc install/1 of the node-wot 0.8.16 MQTT project; its directory.
-spec install_mqtt() -> file:filename().
install_mqtt() ->
    install(filename:join([root(), "apps", "wot_avatar", "test", "wot_avatar_SUITE_data", "node-wot-mqtt"])).

root() ->
    Src = proplists:get_value(source, ?MODULE:module_info(compile)),
    filename:dirname(filename:dirname(filename:dirname(filename:dirname(Src)))).

install(Data, Dir) ->
    Npm = os:find_executable("npm"),
    Npm =/= false orelse error({npm_not_installed, "Debian: npm"}),
    {ok, Lock} = file:read_file(filename:join(Data, "package-lock.json")),
    case file:read_file(filename:join(Dir, "lock.installed")) of
        {ok, Lock} ->
            ok;
        _ ->
            ok = filelib:ensure_dir(filename:join(Dir, "x")),
            %% Two suites running at once (make check's two halves) may both
            %% find the packages missing: under the directory's lock the
            %% second finds them installed, instead of emptying
            %% node_modules under the first one's scripts.
            case run("/bin/sh", ["-c", ?INSTALL, "sh", Dir, Data, Npm], []) of
                {0, _} -> ok;
                {S, Out} -> error({cannot_install_npm_packages, S, Out})
            end
    end,
    Dir.

%% @doc The environment a node script needs to find the installed packages.
-spec node_env(file:filename()) -> [{string(), string()}].
node_env(Dir) ->
    [{"NODE_PATH", filename:join(Dir, "node_modules")}].

%% @doc Runs a program to its end: exit status and output (stderr too).
-spec run(file:filename(), [string()], [{string(), string()}]) -> {non_neg_integer(), string()}.
run(Exe, Args, Env) ->
    Port = open_port({spawn_executable, Exe}, [{args, Args}, {env, Env}, exit_status, binary,
                                               stderr_to_stdout]),
    collect(Port, []).

collect(Port, Acc) ->
    receive
        {Port, {data, D}} -> collect(Port, [Acc, D]);
        {Port, {exit_status, S}} -> {S, unicode:characters_to_list(iolist_to_binary(Acc))}
    after 300000 -> error({no_exit, iolist_to_binary(Acc)})
    end.

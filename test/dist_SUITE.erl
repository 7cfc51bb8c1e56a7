%% Common Test suite of Erlang distribution's safety in the release (issue
%% 15, section 1), tried as an attacker would: the release of
%% evatar_test_release:dir/0 (EVATAR_REL, or `rebar3 release') is started
%% with bin/evatar as README.md says, each node with a HOME of its own, and attacked over real sockets.
%%
%% - cookie: no node starts with a known cookie. The first start makes a
%%   random one in $HOME/.erlang.cookie, mode 0400, kept across restarts
%%   and never on the node's command line; a node with another cookie
%%   (the old default, a guess) cannot connect, one with the file's can;
%%   the start script refuses -setcookie, EVATAR_COOKIE, the old default in
%%   the file, and a file others can read. bin/evatar's own commands (ping,
%%   rpc, eval, pid, remote_console, stop) keep working.
%% - interfaces: distribution and epmd listen on loopback by default and
%%   on the address EVATAR_DIST_IP names otherwise, never on another
%%   address of the machine (127.0.0.2, also an address of lo, stands for
%%   the home network's); an epmd started earlier on every interface is
%%   reported.
%% - cluster: scripts/cluster.sh runs nodes that share one generated cookie.
%%
%% Every case has an epmd of its own (ERL_EPMD_PORT), started by bin/evatar
%% and killed at the end, so the machine's epmd is neither used nor changed.
-module(dist_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").
-include_lib("kernel/include/file.hrl").

-compile([export_all, nowarn_export_all]).

-import(rel_node, [clean_env/0, node_env/3, node_env/4, env/2, home/1, node_name/1,
                   start_node/2, stop_node/2, rel/3, run/4, console_log/1]).

-define(WAIT, evatar_test_time:guard()).

suite() -> [{timetrap, {minutes, 5}}].

all() ->
    [{group, cookie}, {group, interfaces}, {group, cluster}].

groups() ->
    [{cookie, [], [first_start_makes_a_cookie, release_commands, wrong_cookie_cannot_connect,
                   refuses_known_or_visible_cookies]},
     {interfaces, [], [loopback_by_default, named_interface, name_off_the_interface_refused,
                       wide_epmd_reported]},
     {cluster, [], [cluster_sh_shares_one_cookie]}].

%% ---------------------------------------------------------------------------
%% Setup
%% ---------------------------------------------------------------------------

init_per_suite(Config) ->
    ct:timetrap({minutes, 10}),
    [{rel, evatar_test_release:dir()} | Config].

end_per_suite(_Config) ->
    ok.

init_per_testcase(Case, Config) ->
    rel_node:init_case(Case, Config).

end_per_testcase(_Case, Config) ->
    rel_node:end_case(Config).

%% ---------------------------------------------------------------------------
%% Cookie
%% ---------------------------------------------------------------------------

%% The first start makes a random cookie in $HOME/.erlang.cookie, mode
%% 0400, which the node uses and which is not on its command line; a
%% restart keeps it.
first_start_makes_a_cookie(Config) ->
    Env = node_env(Config, "first", []),
    Home = home(Env),
    CookieFile = filename:join(Home, ".erlang.cookie"),
    false = filelib:is_file(CookieFile),
    {Rc0, Out0} = rel(Config, Env, ["ping"]),
    ?assertNotEqual(0, Rc0, Out0),
    ok = start_node(Config, Env),
    {ok, #file_info{mode = Mode, type = regular}} = file:read_file_info(CookieFile),
    ?assertEqual(8#400, Mode band 8#777),
    {ok, Cookie} = file:read_file(CookieFile),
    ?assertMatch({match, _}, re:run(Cookie, "^[0-9a-f]{48}$")),
    ?assertNotEqual(<<"evatar_dev_cookie">>, Cookie),
    {0, NodeCookie} = rel(Config, Env, ["eval", "erlang:get_cookie()."]),
    ?assertEqual(lists:flatten(io_lib:format("~p", [binary_to_atom(Cookie)])),
                 string:trim(NodeCookie)),
    %% Not on the node's command line, where every local user can read it.
    {0, Pid} = rel(Config, Env, ["pid"]),
    {ok, CmdLine} = file:read_file("/proc/" ++ string:trim(Pid) ++ "/cmdline"),
    nomatch = binary:match(CmdLine, [Cookie, <<"-setcookie">>]),
    ok = stop_node(Env, Config),
    ok = start_node(Config, Env),
    ?assertEqual({ok, Cookie}, file:read_file(CookieFile)),
    {0, NodeCookie} = rel(Config, Env, ["eval", "erlang:get_cookie()."]).

%% bin/evatar's commands find the node with the generated cookie: ping,
%% rpc, eval, pid, remote_console (in a pseudo-terminal) and stop.
release_commands(Config) ->
    Env = node_env(Config, "commands", []),
    Node = node_name(Env),
    ok = start_node(Config, Env),
    {0, "pong" ++ _} = rel(Config, Env, ["ping"]),
    {0, Rpc} = rel(Config, Env, ["rpc", "erlang", "node"]),
    ?assertEqual("'" ++ Node ++ "'", string:trim(Rpc)),
    {0, Eval} = rel(Config, Env, ["eval", "lists:sum([1, 2, 3])."]),
    ?assertEqual("6", string:trim(Eval)),
    ok = remote_console(Config, Env, Node),
    {0, _} = rel(Config, Env, ["stop"]),
    {Rc, Out} = rel(Config, Env, ["ping"]),
    ?assertNotEqual(0, Rc, Out).

%% Nodes with another cookie (the old default, a guess) cannot connect to
%% the node, and it logs each attempt; a node with the cookie of the file
%% can, and can run code there (what the cookie protects).
wrong_cookie_cannot_connect(Config) ->
    Env = node_env(Config, "target", []),
    Node = list_to_atom(node_name(Env)),
    ok = start_node(Config, Env),
    {ok, Cookie} = file:read_file(filename:join(home(Env), ".erlang.cookie")),
    Guess = lists:flatten([io_lib:format("~2.16.0b", [B]) || <<B>> <= crypto:strong_rand_bytes(24)]),
    [[pang] = attack(Config, C, [{net_adm, ping, [Node]}])
     || C <- ["evatar_dev_cookie", Guess, "nocookie"]],
    Log = console_log(Env),
    ok = evatar_test_cluster:await(fun() -> count(Log(), "Connection attempt from node") >= 3 end,
                                   ?WAIT, rejections_logged),
    ?assertMatch({match, _}, re:run(Log(), "rejected", [])),
    [pong, Node] = attack(Config, binary_to_list(Cookie),
                          [{net_adm, ping, [Node]}, {erpc, call, [Node, erlang, node, []]}]).

%% The start script refuses a cookie on the command line (-setcookie in
%% ERL_FLAGS), the former EVATAR_COOKIE, a cookie file holding the old
%% default, and a cookie file others can read; no node is left running.
refuses_known_or_visible_cookies(Config) ->
    Flags = node_env(Config, "flags", [{"ERL_FLAGS", "-setcookie evatar_dev_cookie"}]),
    refused(Config, Flags, "ERL_FLAGS"),
    Var = node_env(Config, "var", [{"EVATAR_COOKIE", "evatar_dev_cookie"}]),
    refused(Config, Var, "EVATAR_COOKIE is no longer read"),
    Known = node_env(Config, "known", []),
    ok = write_cookie(home(Known), "evatar_dev_cookie", 8#400),
    refused(Config, Known, "evatar_dev_cookie, the default of earlier versions"),
    Open = node_env(Config, "open", []),
    ok = write_cookie(home(Open), "9f2c4e1d7b3a5f60", 8#644),
    refused(Config, Open, "can be read by other users").

%% ---------------------------------------------------------------------------
%% Interfaces
%% ---------------------------------------------------------------------------

%% By default distribution and epmd accept connections on 127.0.0.1 only:
%% another address of the machine gets connection refused.
loopback_by_default(Config) ->
    Env = node_env(Config, "loop", []),
    ok = start_node(Config, Env),
    Dist = list_to_integer(env("EVATAR_DIST_PORT_MIN", Env)),
    Epmd = ?config(epmd_port, Config),
    ok = reachable({127, 0, 0, 1}, Dist),
    ok = reachable({127, 0, 0, 1}, Epmd),
    {error, econnrefused} = reachable({127, 0, 0, 2}, Dist),
    {error, econnrefused} = reachable({127, 0, 0, 2}, Epmd).

%% EVATAR_DIST_IP names the address: distribution listens there and not on
%% loopback; epmd there and on loopback (where epmd always listens); the
%% start script's commands still find the node.
named_interface(Config) ->
    Env = node_env(Config, "named", [{"EVATAR_DIST_IP", "127,0,0,2"}], "127.0.0.2"),
    ok = start_node(Config, Env),
    Dist = list_to_integer(env("EVATAR_DIST_PORT_MIN", Env)),
    Epmd = ?config(epmd_port, Config),
    ok = reachable({127, 0, 0, 2}, Dist),
    {error, econnrefused} = reachable({127, 0, 0, 1}, Dist),
    ok = reachable({127, 0, 0, 2}, Epmd),
    {error, econnrefused} = reachable({127, 0, 0, 3}, Epmd),
    {0, "pong" ++ _} = rel(Config, Env, ["ping"]).

%% A node named by an address it does not listen on (no one could reach
%% it, bin/evatar daemon would wait for it for ever) is refused.
name_off_the_interface_refused(Config) ->
    Env = node_env(Config, "off", [], "127.0.0.2"),
    refused(Config, Env, "has the address 127.0.0.2, but distribution listens on 127.0.0.1 only").

%% An epmd that something else started on every interface before the node
%% cannot be narrowed by the node: the start script says so.
wide_epmd_reported(Config) ->
    case os:find_executable("ss") of
        false ->
            {skip, "ss (iproute2) is not installed"};
        _ ->
            Port = integer_to_list(?config(epmd_port, Config)),
            "" = os:cmd("ERL_EPMD_PORT=" ++ Port ++ " epmd -daemon"),
            ok = evatar_test_cluster:await(fun() -> reachable({127, 0, 0, 2}, list_to_integer(Port)) =:= ok
                                           end, ?WAIT, wide_epmd),
            Env = node_env(Config, "wide", []),
            {0, Out} = rel(Config, Env, ["daemon"]),
            true = ets:insert(?config(nodes, Config), {node, Env}),
            ?assertMatch({match, _}, re:run(Out, "warning: an epmd started earlier listens on "
                                            "every interface"), Out)
    end.

%% ---------------------------------------------------------------------------
%% Cluster on one machine
%% ---------------------------------------------------------------------------

%% scripts/cluster.sh starts two nodes that share the cookie the first
%% start made, mode 0400, and form a cluster.
cluster_sh_shares_one_cookie(Config) ->
    Dir = ?config(dir, Config),
    Home = filename:join(Dir, "home"),
    ok = filelib:ensure_path(Home),
    Base = consecutive_free(2),
    DistBase = consecutive_free(2),
    Env = clean_env() ++
        [{"HOME", Home}, {"EVATAR_REL", ?config(rel, Config)},
         {"EVATAR_CLUSTER_DIR", filename:join(Dir, "cluster")},
         {"EVATAR_NAME", "dsc" ++ os:getpid() ++ "n"},
         {"EVATAR_BASE_PORT", integer_to_list(Base)},
         {"EVATAR_DIST_BASE", integer_to_list(DistBase)},
         {"ERL_EPMD_PORT", integer_to_list(?config(epmd_port, Config))}],
    Script = filename:join([evatar_test_cluster:repo_root(), "scripts", "cluster.sh"]),
    try
        {0, Started} = run(Config, Env, "bash", [Script, "start", "2"]),
        ct:pal("~s", [Started]),
        {ok, #file_info{mode = Mode}} = file:read_file_info(filename:join(Home, ".erlang.cookie")),
        ?assertEqual(8#400, Mode band 8#777),
        [] = filelib:wildcard(filename:join([Dir, "cluster", "**", "*cookie*"])),
        %% cluster.sh start returns once both daemons are launched, not
        %% once they run: until node 1 answers, its status is not yet.
        Status = fun() ->
                         case run(Config, Env, "bash",
                                  ["-c", "eval \"$(bash " ++ Script ++ " env 1)\" && "
                                   "\"$EVATAR_REL/bin/evatar\" eval 'evatar:cluster_status().'"]) of
                             {0, S} -> S;
                             {_, NotYet} -> NotYet
                         end
                 end,
        ok = evatar_test_cluster:await(fun() -> string:find(Status(), "quorum => true") =/= nomatch end,
                                       ?WAIT, cluster_formed),
        ?assertMatch({match, _}, re:run(Status(), "up => \\[[^]]*n1@[^]]*n2@"))
    after
        {_, Stopped} = run(Config, Env, "bash", [Script, "stop", "2"]),
        ct:pal("~s", [Stopped])
    end.

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

refused(Config, Env, Why) ->
    {Rc, Out} = rel(Config, Env, ["daemon"]),
    true = ets:insert(?config(nodes, Config), {node, Env}),
    ct:pal("~s:~n~s", [node_name(Env), Out]),
    ?assertEqual(1, Rc, Out),
    ?assertMatch({match, _}, re:run(Out, "evatar: refusing to start: .*" ++ Why), Out),
    {PingRc, PingOut} = rel(Config, Env, ["ping"]),
    ?assertNotEqual(0, PingRc, PingOut).

write_cookie(Home, Cookie, Mode) ->
    File = filename:join(Home, ".erlang.cookie"),
    ok = file:write_file(File, Cookie),
    ok = file:change_mode(File, Mode).

%% Calls each {M, F, A} on a fresh node (OTP peer, reached over its
%% standard I/O, not over distribution) with Cookie, which finds nodes
%% through the case's epmd: the results in order.
attack(Config, Cookie, Calls) ->
    Name = "attacker" ++ integer_to_list(erlang:unique_integer([positive])),
    {ok, Peer, _} = peer:start(#{name => Name, host => "127.0.0.1", longnames => true,
                                 connection => standard_io,
                                 args => ["-setcookie", Cookie, "-hidden"],
                                 env => [{"ERL_EPMD_PORT",
                                          integer_to_list(?config(epmd_port, Config))}]}),
    try [peer:call(Peer, M, F, A, ?WAIT) || {M, F, A} <- Calls]
    after peer:stop(Peer)
    end.

count(Bin, Pattern) ->
    length(binary:matches(Bin, list_to_binary(Pattern))).

reachable(Ip, Port) ->
    case gen_tcp:connect(Ip, Port, [binary, {active, false}], 5000) of
        {ok, S} -> gen_tcp:close(S);
        {error, _} = Error -> Error
    end.

%% remote_console in a pseudo-terminal (script(1)): it evaluates on the
%% node, and Ctrl-G q leaves it.
remote_console(Config, Env, Node) ->
    Script = os:find_executable("script"),
    Cmd = filename:join([?config(rel, Config), "bin", "evatar"]) ++ " remote_console",
    Port = open_port({spawn_executable, Script},
                     [{args, ["-qec", Cmd, "/dev/null"]}, {env, Env},
                      binary, stream, exit_status]),
    Prompt = read_until(Port, "> ", <<>>),
    ct:pal("remote console: ~s", [Prompt]),
    true = port_command(Port, "io:format(\"REMOTE ~p~n\", [node()]).\n"),
    Answer = read_until(Port, "REMOTE '" ++ Node ++ "'", <<>>),
    ct:pal("remote console: ~s", [Answer]),
    true = port_command(Port, [7]),
    _ = read_until(Port, "-->", <<>>),
    true = port_command(Port, "q\n"),
    receive {Port, {exit_status, _}} -> ok
    after ?WAIT -> ct:fail(remote_console_did_not_exit)
    end.

read_until(Port, Want, Acc) ->
    case string:find(Acc, Want) of
        nomatch ->
            receive
                {Port, {data, Data}} -> read_until(Port, Want, <<Acc/binary, Data/binary>>);
                {Port, {exit_status, S}} -> ct:fail({remote_console_exited, S, Acc})
            after ?WAIT -> ct:fail({remote_console, Want, Acc})
            end;
        _ ->
            Acc
    end.

%% A port P with P and the N - 1 ports after it free (scripts/cluster.sh
%% gives node I the port BASE + I).
consecutive_free(N) ->
    [P] = evatar_test_cluster:free_ports(1),
    Free = [gen_tcp:listen(P + I, [{ip, {127, 0, 0, 1}}]) || I <- lists:seq(1, N)],
    _ = [gen_tcp:close(L) || {ok, L} <- Free],
    case lists:all(fun(R) -> element(1, R) =:= ok end, Free) of
        true -> P;
        false -> consecutive_free(N)
    end.

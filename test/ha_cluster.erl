%% @doc Test support. Runs a cluster of EVATAR nodes on this machine for the
%% multi-node suites and the failover benchmark: every node is a real OS
%% process (`erl', or OTP's `peer'), with a fixed distribution port, a fixed
%% bridge port, and (optionally) its links to the other nodes through
%% ha_proxy, so the caller can kill a node (`kill -9'), stall it (`kill
%% -STOP', then `-CONT'), cut and heal links, and restart a node as it was.
%% Internal to the root test/ directory.
%%
%% The controller (the calling node) becomes a hidden distributed node if it
%% is not distributed yet: its connections to the cluster's nodes are
%% direct (never through the proxies) and hidden, so partitions between the
%% nodes never cut the controller off and it never counts as a member.
%%
%% ```
%%  node: down --start/restart--> up --kill--> down
%%                                 | --stall--> stalled --resume--> up
%% '''
-module(ha_cluster).
-behaviour(gen_server).

-export([start/1, stop/1, nodes/1, node/2, index/2, endpoints/1, endpoint/2, info/1,
         up/1, kill/2, stall/2, resume/2, restart/2, power_cut/1, restart_all/1,
         partition/2, isolate/2, cut/2, heal/2,
         os_pid/2, call/5, call/6, await_formed/2, await/3, ensure_distributed/0,
         release_distribution/1, repo_root/0, free_ports/1, code_path/0]).
-export([node_setup/1, watchdog/0, watchdog/1]).
-export([init/1, handle_call/3, handle_cast/2, handle_info/2, terminate/2]).

-export_type([cluster/0, opts/0]).

-type cluster() :: pid().
%% n: nodes (default 3); prefix: node names prefix (default "ha"); dir: where
%% the node logs go (required); backend: os (default) or peer; links: route
%% node-to-node connections through ha_proxy (default true); dist: inet_tcp
%% (default) or inet_tls, then ssl_optfile; evatar: extra evatar app env;
%% conn: the bridge listener's connection options; listener: more of its
%% listener options (max_connections, handshake); control: how the
%% controller reaches the nodes, dist (default) or stdio (OTP peer's
%% alternative connection over standard I/O, backend peer only: for nodes
%% whose distribution the controller cannot speak, inet_tls); config: a
%% sys.config file for the nodes (-config), whose logger settings they then
%% keep (by default each node logs to a file of its own at level info).
%% Every node keeps its catalogue of pairings on disc (mnesia) in `dir', in
%% a directory of its own that outlives kills and restarts.
-type opts() :: #{n => pos_integer(), prefix => string(), dir := file:filename(),
                  backend => os | peer, control => dist | stdio, links => boolean(),
                  config => file:filename(),
                  dist => inet_tcp | inet_tls, ssl_optfile => file:filename(),
                  evatar => [{atom(), term()}], conn => map(), listener => map(),
                  boot_timeout => pos_integer(), await_formed => boolean()}.

-record(nd, {i :: pos_integer(),
             name :: node(),
             short :: string(),
             dist_port :: inet:port_number(),
             bridge_port :: inet:port_number(),
             links = #{} :: #{pos_integer() => inet:port_number()},
             os_pid :: string() | undefined,
             port :: port() | undefined,
             peer :: pid() | undefined,
             status = down :: up | down | stalled}).

-record(s, {opts :: opts(),
            nodes :: #{pos_integer() => #nd{}},
            proxies = #{} :: #{{pos_integer(), pos_integer()} => pid()}}).

-define(CALL_TIMEOUT, 120000).

%% ---------------------------------------------------------------------------
%% API
%% ---------------------------------------------------------------------------

%% @doc Starts every node with evatar and the bridge running, and returns
%% once they are all up and connected to each other.
-spec start(opts()) -> {ok, cluster()} | {error, term()}.
start(Opts) ->
    _ = ensure_distributed(),
    {ok, C} = gen_server:start(?MODULE, Opts, []),
    case gen_server:call(C, start_all, ?CALL_TIMEOUT) of
        ok ->
            case maps:get(await_formed, Opts, true)
                     andalso await_formed(C, maps:get(boot_timeout, Opts, 60000)) of
                Formed when Formed =:= ok; Formed =:= false -> {ok, C};
                {error, _} = Error -> stop(C), Error
            end;
        {error, _} = Error ->
            stop(C),
            Error
    end.

%% @doc Kills every node (kill -9) and stops the proxies.
-spec stop(cluster()) -> ok.
stop(C) ->
    try gen_server:stop(C, normal, ?CALL_TIMEOUT)
    catch exit:noproc -> ok
    end.

-spec nodes(cluster()) -> [node()].
nodes(C) -> [N || #{name := N} <- info(C)].

%% @doc The node name of node I (1-based).
-spec node(cluster(), pos_integer()) -> node().
node(C, I) -> maps:get(name, lists:nth(I, info(C))).

%% @doc The index of a node name.
-spec index(cluster(), node()) -> pos_integer().
index(C, Node) ->
    [I] = [I || #{i := I, name := N} <- info(C), N =:= Node],
    I.

%% @doc Every node's bridge address, in node order: a client's endpoints.
-spec endpoints(cluster()) -> [{inet:ip_address(), inet:port_number()}].
endpoints(C) -> [{{127, 0, 0, 1}, P} || #{bridge_port := P} <- info(C)].

-spec endpoint(cluster(), pos_integer()) -> {inet:ip_address(), inet:port_number()}.
endpoint(C, I) -> lists:nth(I, endpoints(C)).

%% @doc One map per node: i, name, status, os_pid, bridge_port, dist_port.
-spec info(cluster()) -> [map()].
info(C) -> gen_server:call(C, info, ?CALL_TIMEOUT).

%% @doc The nodes currently up (not killed, not stalled).
-spec up(cluster()) -> [node()].
up(C) -> [N || #{name := N, status := up} <- info(C)].

-spec os_pid(cluster(), pos_integer()) -> string().
os_pid(C, I) -> maps:get(os_pid, lists:nth(I, info(C))).

%% @doc kill -9 of node I; returns once the OS process is gone.
-spec kill(cluster(), pos_integer()) -> ok.
kill(C, I) -> gen_server:call(C, {kill, I}, ?CALL_TIMEOUT).

%% @doc kill -STOP of node I: a silent stall (its sockets stay open).
-spec stall(cluster(), pos_integer()) -> ok.
stall(C, I) -> gen_server:call(C, {signal, I, "STOP", stalled}, ?CALL_TIMEOUT).

%% @doc kill -CONT of a stalled node I.
-spec resume(cluster(), pos_integer()) -> ok.
resume(C, I) -> gen_server:call(C, {signal, I, "CONT", up}, ?CALL_TIMEOUT).

%% @doc Starts a killed node I again, with the same name, ports and
%% configuration, and returns once it runs evatar and the bridge.
-spec restart(cluster(), pos_integer()) -> ok | {error, term()}.
restart(C, I) -> gen_server:call(C, {restart, I}, ?CALL_TIMEOUT).

%% @doc A power cut: kill -9 of every node that runs (or is stalled), all
%% in one command; returns once every OS process is gone.
-spec power_cut(cluster()) -> ok.
power_cut(C) -> gen_server:call(C, power_cut, ?CALL_TIMEOUT).

%% @doc Starts every node that is down, all at once (as machines coming
%% back after a power cut), and returns once each runs evatar and the
%% bridge.
-spec restart_all(cluster()) -> ok | {error, term()}.
restart_all(C) -> gen_server:call(C, restart_all, ?CALL_TIMEOUT).

%% @doc Cuts every link between nodes of different groups (lists of node
%% indexes); links within a group and to the controller stay.
-spec partition(cluster(), [[pos_integer()]]) -> ok.
partition(C, Groups) -> gen_server:call(C, {partition, Groups}, ?CALL_TIMEOUT).

%% @doc Cuts the links between each pair {I, J} (both directions).
-spec cut(cluster(), [{pos_integer(), pos_integer()}]) -> ok.
cut(C, Links) -> gen_server:call(C, {cut, Links}, ?CALL_TIMEOUT).

%% @doc Cuts node I off from every other node.
-spec isolate(cluster(), pos_integer()) -> ok.
isolate(C, I) ->
    Others = [J || #{i := J} <- info(C), J =/= I],
    partition(C, [[I], Others]).

%% @doc Heals every cut link (ha_proxy:unblock/2 explains the two modes).
-spec heal(cluster(), ha_proxy:heal()) -> ok.
heal(C, Mode) -> gen_server:call(C, {heal, Mode}, ?CALL_TIMEOUT).

%% @doc Calls M:F(A) on node I with a timeout; `{error, Reason}' when the
%% node does not answer (killed, stalled) instead of an exception.
-spec call(cluster(), pos_integer(), module(), atom(), [term()]) -> term().
call(C, I, M, F, A) ->
    call(C, I, M, F, A, 5000).

-spec call(cluster(), pos_integer(), module(), atom(), [term()], timeout()) -> term().
call(C, I, M, F, A, Timeout) ->
    Info = lists:nth(I, info(C)),
    rpc(Info, M, F, A, Timeout).

rpc(#{control := stdio, peer := Peer}, M, F, A, Timeout) when is_pid(Peer) ->
    try peer:call(Peer, M, F, A, Timeout)
    catch Class:Reason -> {error, {Class, Reason}}
    end;
rpc(#{control := stdio}, _M, _F, _A, _Timeout) ->
    {error, down};
rpc(#{name := Node}, M, F, A, Timeout) ->
    try erpc:call(Node, M, F, A, Timeout)
    catch
        error:{erpc, Why} -> {error, {erpc, Why}};
        Class:Reason -> {error, {Class, Reason}}
    end.

%% @doc Waits until every node that is up sees every other up node as up
%% (evatar:cluster_status/0).
-spec await_formed(cluster(), pos_integer()) -> ok | {error, term()}.
await_formed(C, Timeout) ->
    await(fun() ->
                  Infos = [I || #{status := up} = I <- info(C)],
                  Up = lists:sort([N || #{name := N} <- Infos]),
                  lists:all(fun(Info) ->
                                    case rpc(Info, evatar, cluster_status, [], 2000) of
                                        #{up := U} -> lists:sort(U) =:= Up;
                                        _ -> false
                                    end
                            end, Infos)
          end, Timeout, cluster_not_formed).

%% @doc Polls Fun every 50 ms until it returns true, or `{error, {timeout,
%% What}}' after Timeout ms (evatar_test_wait:poll/2, which the suites of
%% the apps use too).
-spec await(evatar_test_wait:probe(), pos_integer(), term()) -> ok | {error, term()}.
await(Fun, Timeout, What) ->
    case evatar_test_wait:poll(Fun, #{timeout => Timeout, interval => 50, what => What}) of
        ok -> ok;
        {error, {wait_timeout, _}} -> {error, {timeout, What}}
    end.

%% @doc Makes this node a hidden distributed node with a long name, unless
%% it is distributed with long names already; says which, for
%% release_distribution/1. A node distributed with short names cannot
%% reach the cluster's nodes: its distribution is restarted.
-spec ensure_distributed() -> started | already.
ensure_distributed() ->
    case node() of
        nonode@nohost ->
            _ = os:cmd("ERL_EPMD_ADDRESS=127.0.0.1 epmd -daemon"),
            %% Listens on loopback only, as the nodes it starts.
            ok = application:set_env(kernel, inet_dist_use_interface, {127, 0, 0, 1}),
            Name = list_to_atom("ha_ctl_" ++ os:getpid() ++ "@127.0.0.1"),
            {ok, _} = net_kernel:start(Name, #{name_domain => longnames, hidden => true}),
            started;
        _ ->
            case net_kernel:longnames() of
                true ->
                    already;
                false ->
                    logger:notice(#{what => restarting_distribution_with_long_names}),
                    ok = net_kernel:stop(),
                    ensure_distributed()
            end
    end.

%% @doc Stops the distribution ensure_distributed/0 started.
-spec release_distribution(started | already) -> ok.
release_distribution(started) ->
    _ = net_kernel:stop(),
    ok;
release_distribution(already) ->
    ok.

%% @doc The root of the source tree (where scripts/ is), found from where
%% the evatar application was compiled.
-spec repo_root() -> file:filename().
repo_root() ->
    evatar_test_fixtures:repo_root().

%% ---------------------------------------------------------------------------
%% Run on the cluster's nodes
%% ---------------------------------------------------------------------------

%% @private Starts evatar and the bridge on a fresh node.
-spec node_setup(map()) -> ok.
node_setup(#{log := Log, env := Env, bridge_port := Port, conn := Conn} = Setup) ->
    ok = logger:add_handler(ha_file, logger_std_h,
                            #{config => #{file => Log},
                              formatter => {logger_formatter,
                                            #{single_line => true,
                                              template => [time, " ", level, " ", pid, " ",
                                                           msg, "\n"]}}}),
    case Setup of
        #{configured := true} ->
            ok;
        #{} ->
            _ = logger:remove_handler(default),
            ok = logger:add_primary_filter(no_progress, {fun logger_filters:progress/2, stop}),
            ok = logger:set_primary_config(level, info)
    end,
    Listener = maps:get(listener, Setup, #{}),
    %% Loopback, unless the node has an address of its own (ha_netns).
    Ip = maps:get(ip, Setup, {127, 0, 0, 1}),
    evatar_test_cluster:start_evatar(#{env => Env, listener => ha,
                                       listener_opts => Listener#{ip => Ip, port => Port,
                                                                  conn => Conn}}).

%% @private Halts this node when its standard input closes: the controller
%% that started it (the owner of the pipe) is gone. Started by -eval.
-spec watchdog() -> pid().
watchdog() ->
    spawn(fun() ->
                  Port = open_port({fd, 0, 1}, [in, eof, binary]),
                  watch(Port)
          end).

watch(Port) ->
    receive
        {Port, eof} -> erlang:halt(0);
        {Port, _} -> watch(Port)
    end.

%% @private For `peer' nodes (whose standard input is not the controller's
%% pipe): halts this node once the controller's OS process is gone.
-spec watchdog(string()) -> pid().
watchdog(OsPid) ->
    spawn(fun() -> watch_pid(OsPid) end).

watch_pid(OsPid) ->
    timer:sleep(2000),
    case os:cmd("kill -0 " ++ OsPid ++ " 2>&1") of
        "" -> watch_pid(OsPid);
        _ -> erlang:halt(0)
    end.

%% ---------------------------------------------------------------------------
%% gen_server
%% ---------------------------------------------------------------------------

-spec init(opts()) -> {ok, #s{}}.
init(Opts0) ->
    process_flag(trap_exit, true),
    Opts = maps:merge(#{n => 3, prefix => "ha", backend => os, control => dist, links => true,
                        dist => inet_tcp, evatar => [], conn => #{heartbeat => 100},
                        boot_timeout => 60000}, Opts0),
    N = maps:get(n, Opts),
    Ports = free_ports(2 * N),
    {DistPorts, BridgePorts} = lists:split(N, Ports),
    Host = "127.0.0.1",
    Nodes0 = maps:from_list(
               [{I, #nd{i = I,
                        short = Short,
                        name = list_to_atom(Short ++ "@" ++ Host),
                        dist_port = lists:nth(I, DistPorts),
                        bridge_port = lists:nth(I, BridgePorts)}}
                || I <- lists:seq(1, N),
                   Short <- [maps:get(prefix, Opts) ++ integer_to_list(I)]]),
    {Nodes, Proxies} = case maps:get(links, Opts) of
                           true -> start_proxies(Nodes0);
                           false -> {Nodes0, #{}}
                       end,
    {ok, #s{opts = Opts, nodes = Nodes, proxies = Proxies}}.

-spec handle_call(term(), gen_server:from(), #s{}) -> {reply, term(), #s{}}.
handle_call(start_all, _From, #s{nodes = Nodes} = S) ->
    %% Launch every node first, then wait for them: boots overlap.
    Launched = maps:map(fun(_, Nd) -> launch(Nd, S) end, Nodes),
    case setup_all(maps:values(Launched), S) of
        {ok, Ready} -> {reply, ok, S#s{nodes = Ready}};
        {error, Why, Partial} -> {reply, {error, Why}, S#s{nodes = Partial}}
    end;
handle_call(info, _From, #s{nodes = Nodes} = S) ->
    {reply, [#{i => I, name => Nd#nd.name, status => Nd#nd.status, os_pid => Nd#nd.os_pid,
               bridge_port => Nd#nd.bridge_port, dist_port => Nd#nd.dist_port,
               peer => Nd#nd.peer, control => maps:get(control, S#s.opts)}
             || {I, Nd} <- lists:sort(maps:to_list(Nodes))], S};
handle_call({kill, I}, _From, #s{nodes = Nodes} = S) ->
    Nd = maps:get(I, Nodes),
    ok = kill_os(Nd),
    {reply, ok, S#s{nodes = Nodes#{I := down(Nd)}}};
handle_call({signal, I, Sig, Status}, _From, #s{nodes = Nodes} = S) ->
    #nd{os_pid = Pid} = Nd = maps:get(I, Nodes),
    _ = os:cmd("kill -" ++ Sig ++ " " ++ Pid),
    {reply, ok, S#s{nodes = Nodes#{I := Nd#nd{status = Status}}}};
handle_call({restart, I}, _From, #s{nodes = Nodes} = S) ->
    case maps:get(I, Nodes) of
        #nd{status = down} = Nd ->
            case setup_all([launch(Nd, S)], S) of
                {ok, Ready} -> {reply, ok, S#s{nodes = maps:merge(Nodes, Ready)}};
                {error, Why, Partial} -> {reply, {error, Why}, S#s{nodes = maps:merge(Nodes, Partial)}}
            end;
        #nd{status = Other} ->
            {reply, {error, {not_down, Other}}, S}
    end;
handle_call(power_cut, _From, #s{nodes = Nodes} = S) ->
    Running = [Nd || Nd <- maps:values(Nodes), Nd#nd.os_pid =/= undefined],
    _ = os:cmd("kill -9 " ++ lists:join(" ", [P || #nd{os_pid = P} <- Running])),
    _ = [ok = kill_os(Nd) || Nd <- Running],
    {reply, ok, S#s{nodes = maps:map(fun(_, Nd) -> down(Nd) end, Nodes)}};
handle_call(restart_all, _From, #s{nodes = Nodes} = S) ->
    Down = [launch(Nd, S) || #nd{status = down} = Nd <- maps:values(Nodes)],
    case setup_all(Down, S) of
        {ok, Ready} -> {reply, ok, S#s{nodes = maps:merge(Nodes, Ready)}};
        {error, Why, Partial} -> {reply, {error, Why}, S#s{nodes = maps:merge(Nodes, Partial)}}
    end;
handle_call({partition, Groups}, _From, #s{proxies = Proxies} = S) ->
    GroupOf = maps:from_list([{I, G} || {G, Is} <- lists:enumerate(Groups), I <- Is]),
    _ = [ok = ha_proxy:block(P)
         || {{A, B}, P} <- maps:to_list(Proxies),
            maps:get(A, GroupOf, {alone, A}) =/= maps:get(B, GroupOf, {alone, B})],
    {reply, ok, S};
handle_call({cut, Links}, _From, #s{proxies = Proxies} = S) ->
    _ = [ok = ha_proxy:block(maps:get(L, Proxies))
         || {I, J} <- Links, L <- [{I, J}, {J, I}]],
    {reply, ok, S};
handle_call({heal, Mode}, _From, #s{proxies = Proxies} = S) ->
    _ = [ok = ha_proxy:unblock(P, Mode) || P <- maps:values(Proxies), ha_proxy:blocked(P)],
    {reply, ok, S}.

-spec handle_cast(term(), #s{}) -> {noreply, #s{}}.
handle_cast(_Msg, S) -> {noreply, S}.

-spec handle_info(term(), #s{}) -> {noreply, #s{}}.
handle_info({Port, {exit_status, _}}, #s{nodes = Nodes} = S) when is_port(Port) ->
    Dead = [I || {I, #nd{port = P}} <- maps:to_list(Nodes), P =:= Port],
    {noreply, S#s{nodes = lists:foldl(fun(I, Acc) -> Acc#{I := down(maps:get(I, Acc))} end,
                                      Nodes, Dead)}};
handle_info(_Msg, S) ->
    {noreply, S}.

-spec terminate(term(), #s{}) -> ok.
terminate(_Why, #s{nodes = Nodes, proxies = Proxies}) ->
    _ = [kill_os(Nd) || Nd <- maps:values(Nodes), Nd#nd.os_pid =/= undefined],
    _ = [catch ha_proxy:stop(P) || P <- maps:values(Proxies)],
    ok.

%% ---------------------------------------------------------------------------
%% Internals
%% ---------------------------------------------------------------------------

down(Nd) -> Nd#nd{status = down, os_pid = undefined, port = undefined, peer = undefined}.

%% @doc Ports for the nodes' distribution and bridge listeners, which bind them
%% only later, when the nodes boot. They are taken below the kernel's
%% ephemeral range: a port in it, found free with listen(0) and closed, can
%% be handed to a proxy's listen(0) or to an outgoing connection before its
%% node binds it (a nemesis run once failed so: eaddrinuse at boot). Below
%% the range only an explicit bind takes a port; each is checked free.
-spec free_ports(non_neg_integer()) -> [inet:port_number()].
free_ports(N) ->
    {Min, _} = ephemeral_range(),
    High = Min - 1,
    Low = max(1024, High - 12000),
    true = High - Low >= 1000,
    pick_ports(N, Low, High, []).

pick_ports(0, _Low, _High, Acc) ->
    Acc;
pick_ports(N, Low, High, Acc) ->
    P = Low + rand:uniform(High - Low + 1) - 1,
    Free = not lists:member(P, Acc) andalso
        gen_tcp:listen(P, [{ip, {127, 0, 0, 1}}, {reuseaddr, true}]),
    case Free of
        {ok, L} ->
            ok = gen_tcp:close(L),
            pick_ports(N - 1, Low, High, [P | Acc]);
        _ ->
            pick_ports(N, Low, High, Acc)
    end.

ephemeral_range() ->
    case file:read_file("/proc/sys/net/ipv4/ip_local_port_range") of
        {ok, Bin} ->
            [Lo, Hi] = [binary_to_integer(X) || X <- string:lexemes(Bin, " \t\n")],
            {Lo, Hi};
        {error, _} ->
            {32768, 60999}
    end.

%% One proxy per ordered pair (A dials B through {A, B}).
start_proxies(Nodes) ->
    Pairs = [{A, B} || A <- maps:keys(Nodes), B <- maps:keys(Nodes), A =/= B],
    Proxies = maps:from_list([{{A, B}, element(2, {ok, _} = ha_proxy:start(
                                                     (maps:get(B, Nodes))#nd.dist_port))}
                              || {A, B} <- Pairs]),
    Linked = maps:map(fun(A, Nd) ->
                              Nd#nd{links = maps:from_list(
                                              [{B, ha_proxy:port(maps:get({A, B}, Proxies))}
                                               || B <- maps:keys(Nodes), B =/= A])}
                      end, Nodes),
    {Linked, Proxies}.

%% @doc The ebin directories a cluster's node loads: EVATAR's applications
%% of this build and the test support.
-spec code_path() -> [file:filename()].
code_path() ->
    %% This module's node_setup/1 and watchdog run on the nodes.
    evatar_test_cluster:code_path([?MODULE]).

args(#nd{dist_port = DP, links = Links}, #s{opts = Opts, nodes = Nodes}) ->
    Dist = case maps:get(dist, Opts) of
               inet_tcp -> [];
               inet_tls -> ["-proto_dist", "inet_tls",
                            "-ssl_dist_optfile", maps:get(ssl_optfile, Opts)]
           end,
    LinkArgs = lists:append([["-ha_link", (maps:get(B, Nodes))#nd.short, integer_to_list(P)]
                             || {B, P} <- lists:sort(maps:to_list(Links))]),
    Epmd = case maps:size(Links) of
               0 -> [];
               _ -> ["-epmd_module", "ha_epmd"]
           end,
    Input = case maps:get(control, Opts) of
                dist -> ["-noinput"];
                stdio -> []
            end,
    Config = case Opts of
                 #{config := File} -> ["-config", File];
                 #{} -> []
             end,
    Config ++
    ["+K", "true"]
        ++ Input ++ Epmd ++ LinkArgs ++ Dist
        %% Cookie, distribution on loopback at DP, no overlapping-partition
        %% handling, code path: evatar_test_cluster's, as every test node.
        ++ evatar_test_cluster:node_args(#{cookie => erlang:get_cookie(), dist_port => DP,
                                           code_path => code_path()}).

log_file(#nd{short = Short}, #s{opts = Opts}) ->
    filename:join(maps:get(dir, Opts), Short ++ ".log").

launch(#nd{short = Short} = Nd, #s{opts = Opts} = S) ->
    Args = args(Nd, S),
    Erl = os:find_executable("erl"),
    case maps:get(backend, Opts) of
        os ->
            %% stdin stays the port's pipe (the watchdog's eof); output goes
            %% to a file.
            Out = filename:join(maps:get(dir, Opts), Short ++ ".out"),
            Cmd = "exec " ++ lists:join(" ", [quote(A) || A <- [Erl, "-name", atom_to_list(Nd#nd.name)
                                                                   | Args]
                                                          ++ ["-eval", "ha_cluster:watchdog()"]])
                ++ " >>" ++ quote(Out) ++ " 2>&1",
            Port = open_port({spawn_executable, "/bin/sh"},
                             [{args, ["-c", lists:flatten(Cmd)]}, exit_status, binary]),
            {os_pid, OsPid} = erlang:port_info(Port, os_pid),
            Nd#nd{port = Port, os_pid = integer_to_list(OsPid), status = down};
        peer ->
            Base = #{name => Short, host => "127.0.0.1", longnames => true, exec => Erl},
            {ok, Peer, _Node} =
                case maps:get(control, Opts) of
                    dist ->
                        peer:start(Base#{args => Args ++ ["-eval", "ha_cluster:watchdog(\""
                                                          ++ os:getpid() ++ "\")"],
                                         wait_boot => false});
                    stdio ->
                        %% The node halts when its control channel closes.
                        peer:start(Base#{args => Args, connection => standard_io,
                                         wait_boot => maps:get(boot_timeout, Opts)})
                end,
            Nd#nd{peer = Peer, status = down}
    end.

%% Waits for every launched node to answer, then starts evatar and the
%% bridge on each.
setup_all(Nds, #s{opts = Opts} = S) ->
    Timeout = maps:get(boot_timeout, Opts),
    Nodes = [Nd#nd.name || Nd <- Nds],
    %% Distribution comes up before the kernel has finished starting (its
    %% logger_sup, for one): a node is ready once init says it has booted.
    Booted = fun() ->
                     lists:all(fun(#nd{peer = Peer} = Nd) when map_get(control, Opts) =:= stdio ->
                                       peer:get_state(Peer) =:= running
                                           andalso booted(Nd, S);
                                  (#nd{name = N} = Nd) ->
                                       net_adm:ping(N) =:= pong andalso booted(Nd, S)
                               end, Nds)
             end,
    case await(Booted, Timeout, {boot, Nodes}) of
        ok ->
            Ready = [setup(Nd, S) || Nd <- Nds],
            {ok, maps:from_list([{Nd#nd.i, Nd} || Nd <- Ready])};
        {error, Why} ->
            {error, Why, maps:from_list([{Nd#nd.i, Nd} || Nd <- Nds])}
    end.

booted(#nd{name = Node, peer = Peer}, #s{opts = Opts}) ->
    Info = #{name => Node, peer => Peer, control => maps:get(control, Opts)},
    rpc(Info, init, get_status, [], 5000) =:= {started, started}.

setup(#nd{name = Node} = Nd, #s{opts = Opts, nodes = All} = S) ->
    Cluster = lists:sort([X#nd.name || X <- maps:values(All)]),
    Data = filename:join(maps:get(dir, Opts), Nd#nd.short ++ ".data"),
    %% No rebalancing unless a suite asks for it: these suites assert where
    %% pairings go after their faults (netns_SUITE tests rebalancing).
    Evatar = maps:get(evatar, Opts),
    Env = [{evatar, [{cluster, Cluster} | Evatar]
                ++ [{rebalance, false} || not lists:keymember(rebalance, 1, Evatar)]},
           {agent_bridge, [{listeners, []}]},
           {mnesia, [{dir, Data}]}],
    Info = #{name => Node, peer => Nd#nd.peer, control => maps:get(control, Opts)},
    ok = rpc(Info, ?MODULE, node_setup,
             [#{log => log_file(Nd, S), env => Env, bridge_port => Nd#nd.bridge_port,
                conn => maps:get(conn, Opts), listener => maps:get(listener, Opts, #{}),
                configured => maps:is_key(config, Opts)}], 60000),
    OsPid = rpc(Info, os, getpid, [], 60000),
    Nd#nd{os_pid = OsPid, status = up}.

kill_os(#nd{os_pid = undefined}) ->
    ok;
kill_os(#nd{os_pid = Pid}) ->
    _ = os:cmd("kill -9 " ++ Pid),
    %% Gone once kill -0 fails (the runtime reaps its children at once).
    ok = await(fun() -> os:cmd("kill -0 " ++ Pid ++ " 2>&1") =/= "" end, 10000, {kill, Pid}).

quote(S) ->
    "'" ++ lists:flatten(string:replace(S, "'", "'\\''", all)) ++ "'".

%% @doc Test support, not a suite: the one cluster harness of the
%% multi-node suites (apps/evatar/test/evatar_ha_SUITE.erl, root test/'s
%% ha_SUITE, nemesis_SUITE, pause_SUITE, log_SUITE, netns_SUITE) and of the
%% failover and partition benchmarks. It starts N EVATAR nodes, each a real
%% OS process, calls them, and makes the faults a suite names: kill -9
%% (kill/2, power_cut/1), a silent stall (stall/2, resume/2: SIGSTOP,
%% SIGCONT), a restart as it was (restart/2, restart_all/1), and cuts
%% between nodes (cut/2, partition/2, isolate/2, cut_off/2, heal/1,2).
%%
%% How a cut is made is the `net' option, one fault backend per kind:
%% <ul>
%% <li>`proxy' (default): every node dials every other through a TCP proxy
%% of its own (evatar_test_net_proxy); a cut makes it silent, a heal
%% flushes what waited or resets the connections;</li>
%% <li>`cookie': direct links; a cut gives each side a wrong cookie for the
%% other and drops their connection, so every handshake fails until the
%% heal (evatar_test_net_cookie);</li>
%% <li>`netns': each node in a network namespace of its own with a link to
%% every other node and one to the clients; a cut takes links down, as a
%% pulled cable does (evatar_test_net_netns; root and `ip' only);</li>
%% <li>`none': no cuts (one node, or a suite that never cuts).</li>
%% </ul>
%% A node is launched by `erl' (`launcher => os') or by OTP's `peer'
%% (`launcher => peer'), and the controller (the calling node) reaches it
%% over distribution (`control => dist': the controller becomes a hidden
%% node, so no cut ever separates it from a node and it never counts as a
%% member) or over peer's standard I/O (`control => stdio').
%%
%% ```
%%  node: down --start/restart--> up --kill--> down
%%                                 | --stall--> stalled --resume--> up
%% '''
-module(evatar_test_cluster).
-behaviour(gen_server).

-export([start/1, stop/1, nodes/1, node/2, index/2, endpoints/1, endpoint/2, info/1,
         up/1, kill/2, stall/2, resume/2, restart/2, power_cut/1, restart_all/1,
         partition/2, isolate/2, cut_off/2, cut/2, heal/1, heal/2, links_down/1,
         os_pid/2, call/5, call/6, set_env/3, run_now/2, await_formed/2, await/3, ensure_distributed/0,
         release_distribution/1, repo_root/0, free_ports/1, code_path/1, node_args/1,
         start_evatar/1]).
-export([node_setup/1, watchdog/0, watchdog/1]).
-export([init/1, handle_call/3, handle_cast/2, handle_info/2, terminate/2]).

-export([loopback_specs/1]).

-export_type([cluster/0, opts/0, net/0, heal/0, node_spec/0, node_args/0, start/0, ctx/0]).

%% A fault backend (evatar_test_net_*): it makes the nodes' network when
%% the cluster starts (init/2: the nodes' short names and the options; what
%% each node is launched with), cuts and heals links between nodes, cuts a
%% node off from everything where it can, and undoes it all (stop/1).
%% Links are {I, J} with I < J: a cut is both directions.
-callback init([string()], opts()) -> {ok, term(), [node_spec()]} | {error, term()}.
-callback cut([{pos_integer(), pos_integer()}], ctx(), term()) ->
    {ok | {error, term()}, term()}.
-callback cut_off(pos_integer(), ctx(), term()) -> {ok | {error, term()}, term()}.
-callback heal(heal(), ctx(), term()) -> {ok, term()}.
-callback links_down(term()) -> term().
-callback stop(term()) -> ok.

-type cluster() :: pid().
-type net() :: proxy | cookie | netns | none.
-type heal() :: flush | reset.
%% How a cut heals: `flush' lets through what waited (the connections
%% survive), `reset' closes the connections that were cut. The proxy backend
%% does either; a cookie cut dropped its connections already (a reset); a
%% namespace link comes back and TCP retransmits (a flush).

%% n: nodes (default 3); prefix: node names' prefix (default "ha"; node I
%% is PrefixI_OsPid_N, its log PrefixI_OsPid_N.log in `dir'); dir:
%% where the node logs and catalogues go (required); net: the fault backend
%% (default proxy, none for one node); launcher: os (default) or peer;
%% control: dist (default) or stdio (peer only: for nodes whose
%% distribution the controller cannot speak, inet_tls, or a controller that
%% must stay undistributed); dist: inet_tcp (default) or inet_tls, then
%% ssl_optfile; evatar: evatar's application environment (the release's
%% defaults otherwise: rebalancing is on); conn: the bridge listener's
%% connection options (default heartbeat 100 ms); listener: more of its
%% listener options (max_connections, handshake); config: a sys.config
%% file for the nodes (-config), whose logger settings they then keep (by
%% default each node logs to a file of its own at level info); modules:
%% modules whose code the nodes run (the suite's own, for its funs);
%% code_path: the ebin directories the nodes load EVATAR from (default this
%% build's; this kit is always added); cookie: the cluster's cookie
%% (default the controller's, or a random one when it is not distributed).
%% Every node keeps its catalogue of pairings on disc (mnesia) in `dir', in
%% a directory of its own that outlives kills and restarts.
-type opts() :: #{n => pos_integer(), prefix => string(), dir := file:filename(),
                  net => net(), launcher => os | peer, control => dist | stdio,
                  config => file:filename(), dist => inet_tcp | inet_tls,
                  ssl_optfile => file:filename(), evatar => [{atom(), term()}],
                  conn => map(), listener => map(), modules => [module()],
                  code_path => [file:filename()], cookie => atom(),
                  boot_timeout => pos_integer(), await_formed => boolean()}.

%% What a fault backend says about node I: its address (distribution and
%% bridge listen there), its ports, the `erl' arguments it adds, and a
%% command the node runs under (`ip netns exec NS').
-type node_spec() :: #{ip := inet:ip4_address(), dist_port := inet:port_number(),
                       bridge_port := inet:port_number(), args := [string()],
                       exec_prefix := [string()]}.

-type node_args() :: #{cookie := atom(),
                       code_path := [file:filename()],
                       interface => inet:ip4_address(),
                       dist_port => inet:port_number()}.
%% `interface' (default 127.0.0.1, as a release) is the only address the
%% node's distribution listens on; `dist_port', when given, its port.

-type start() :: #{env := [{atom(), [{atom(), term()}]}],
                   listener := atom(),
                   listener_opts := agent_bridge:listener_opts()}.
%% `env' is set (persistent) before anything starts; `listener_opts' are
%% agent_bridge:start_listener/2's (ip, port, conn, ...).

%% What a backend may use of the cluster: every node's name, the cluster's
%% cookie, and a call to node I (`{error, down}' when it is not up).
-type ctx() :: #{names := #{pos_integer() => node()}, cookie := atom(),
                 call := fun((pos_integer(), module(), atom(), [term()]) -> term())}.

-record(nd, {i :: pos_integer(),
             name :: node(),
             short :: string(),
             spec :: node_spec(),
             os_pid :: string() | undefined,
             port :: port() | undefined,
             peer :: pid() | undefined,
             status = down :: up | down | stalled}).

-record(s, {opts :: opts(),
            cookie :: atom(),
            backend :: module(),
            net :: term(),
            nodes :: #{pos_integer() => #nd{}}}).

-define(CALL_TIMEOUT, 120000).

%% ---------------------------------------------------------------------------
%% API
%% ---------------------------------------------------------------------------

%% @doc Starts every node with evatar and the bridge running, and returns
%% once they are all up and connected to each other.
-spec start(opts()) -> {ok, cluster()} | {error, term()}.
start(Opts) ->
    _ = [ensure_distributed() || maps:get(control, Opts, dist) =:= dist],
    case gen_server:start(?MODULE, Opts, []) of
        {ok, C} ->
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
            end;
        {error, _} = Error ->
            Error
    end.

%% @doc Kills every node (kill -9) and undoes the backend's network.
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
endpoints(C) -> [{Ip, P} || #{ip := Ip, bridge_port := P} <- info(C)].

-spec endpoint(cluster(), pos_integer()) -> {inet:ip_address(), inet:port_number()}.
endpoint(C, I) -> lists:nth(I, endpoints(C)).

%% @doc One map per node: i, name, status, os_pid, ip, bridge_port,
%% dist_port, peer, control.
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
partition(C, Groups) ->
    GroupOf = maps:from_list([{I, G} || {G, Is} <- lists:enumerate(Groups), I <- Is]),
    Is = [I || #{i := I} <- info(C)],
    cut(C, [{A, B} || A <- Is, B <- Is, A < B,
                      maps:get(A, GroupOf, {alone, A}) =/= maps:get(B, GroupOf, {alone, B})]).

%% @doc Cuts the links between each pair {I, J} (both directions).
-spec cut(cluster(), [{pos_integer(), pos_integer()}]) -> ok.
cut(C, Links) -> gen_server:call(C, {cut, Links}, ?CALL_TIMEOUT).

%% @doc Cuts node I off from every other node; its clients (and the
%% controller) still reach it.
-spec isolate(cluster(), pos_integer()) -> ok.
isolate(C, I) ->
    Others = [J || #{i := J} <- info(C), J =/= I],
    partition(C, [[I], Others]).

%% @doc Cuts node I off from everything: the other nodes and its clients
%% (the controller's calls too). Only the netns backend can: the others
%% answer `{error, {unsupported, Net}}'.
-spec cut_off(cluster(), pos_integer()) -> ok | {error, term()}.
cut_off(C, I) -> gen_server:call(C, {cut_off, I}, ?CALL_TIMEOUT).

%% @doc heal(C, flush).
-spec heal(cluster()) -> ok.
heal(C) -> heal(C, flush).

%% @doc Heals every cut link (heal() says how each backend heals).
-spec heal(cluster(), heal()) -> ok.
heal(C, Mode) when Mode =:= flush; Mode =:= reset ->
    gen_server:call(C, {heal, Mode}, ?CALL_TIMEOUT).

%% @doc What is cut now, as the backend names it (for the logs).
-spec links_down(cluster()) -> term().
links_down(C) -> gen_server:call(C, links_down, ?CALL_TIMEOUT).

%% @doc Calls M:F(A) on node I with a timeout; `{error, Reason}' when the
%% node does not answer (killed, stalled, cut off) instead of an exception.
-spec call(cluster(), pos_integer(), module(), atom(), [term()]) -> term().
call(C, I, M, F, A) ->
    call(C, I, M, F, A, 5000).

-spec call(cluster(), pos_integer(), module(), atom(), [term()], timeout()) -> term().
call(C, I, M, F, A, Timeout) ->
    Info = lists:nth(I, info(C)),
    rpc(Info, M, F, A, Timeout).

%% @doc Sets application App's environment Env on every node that is up.
-spec set_env(cluster(), atom(), [{atom(), term()}]) -> ok.
set_env(C, App, Env) ->
    _ = [ok = rpc(Info, application, set_env, [App, K, V], 5000)
         || #{status := up} = Info <- info(C), {K, V} <- Env],
    ok.

%% @doc Fires periodic work What (evatar:run_now/1: `cluster',
%% `catalogue' or `rebalancer') on every node that is up, one node after
%% the other in index order: each node's result, once its round is done.
-spec run_now(cluster(), cluster | catalogue | rebalancer) -> [{pos_integer(), term()}].
run_now(C, What) ->
    [{I, rpc(Info, evatar, run_now, [What], evatar_test_time:guard())}
     || #{i := I, status := up} = Info <- info(C)].

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
%% What}}' after Timeout ms (evatar_test_wait:poll/2).
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

%% @doc The root of the source tree (where scripts/ is).
-spec repo_root() -> file:filename().
repo_root() ->
    evatar_test_fixtures:repo_root().

%% @doc The ebin directories an EVATAR node of a test cluster loads: the
%% apps a node runs, this kit (its helpers run on the nodes too) and the
%% directories of `Modules' (a suite's own, whose code the nodes call).
-spec code_path([module()]) -> [file:filename()].
code_path(Modules) ->
    Apps = [bil, evatar_protocol, evatar, agent_bridge, restart_backoff, sock_flow,
            evatar_test_kit],
    lists:usort([filename:join(code:lib_dir(App), "ebin") || App <- Apps]
                ++ [filename:dirname(code:which(M)) || M <- Modules]).

%% @doc The `erl' arguments every test node gets: the cluster's cookie;
%% distribution on `interface' only (and on `dist_port' when given); no
%% `prevent_overlapping_partitions' (as config/vm.args.src: EVATAR does not
%% use global, whose answer to a cut link is to cut more links); the code
%% path.
-spec node_args(node_args()) -> [string()].
node_args(#{cookie := Cookie, code_path := Dirs} = Opts) ->
    {A, B, C, D} = maps:get(interface, Opts, {127, 0, 0, 1}),
    Port = case Opts of
               #{dist_port := P} ->
                   ["-kernel", "inet_dist_listen_min", integer_to_list(P),
                    "-kernel", "inet_dist_listen_max", integer_to_list(P)];
               #{} ->
                   []
           end,
    ["-setcookie", atom_to_list(Cookie),
     "-kernel", "inet_dist_use_interface",
     lists:flatten(io_lib:format("{~b,~b,~b,~b}", [A, B, C, D])),
     "-kernel", "prevent_overlapping_partitions", "false"]
        ++ Port
        ++ lists:append([["-pa", Dir] || Dir <- Dirs]).

%% @doc Run on a node: sets the environment, starts evatar and the bridge
%% (agent_bridge starts evatar) and opens the bridge listener.
-spec start_evatar(start()) -> ok.
start_evatar(#{env := Env, listener := Name, listener_opts := Listener}) ->
    ok = application:set_env(Env, [{persistent, true}]),
    {ok, _} = application:ensure_all_started(agent_bridge),
    {ok, _} = agent_bridge:start_listener(Name, Listener),
    ok.

%% ---------------------------------------------------------------------------
%% Run on the cluster's nodes
%% ---------------------------------------------------------------------------

%% @private Starts evatar and the bridge on a fresh node.
-spec node_setup(map()) -> ok.
node_setup(#{log := Log, env := Env, bridge_port := Port, ip := Ip, conn := Conn} = Setup) ->
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
    start_evatar(#{env => Env, listener => ha,
                   listener_opts => Listener#{ip => Ip, port => Port, conn => Conn}}).

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

-spec init(opts()) -> {ok, #s{}} | {stop, term()}.
init(Opts0) ->
    process_flag(trap_exit, true),
    Net = maps:get(net, Opts0, case maps:get(n, Opts0, 3) of 1 -> none; _ -> proxy end),
    Opts = maps:merge(#{n => 3, prefix => "ha", launcher => os, control => dist,
                        dist => inet_tcp, evatar => [], conn => #{heartbeat => 100},
                        modules => [], boot_timeout => 60000}, Opts0#{net => Net}),
    Cookie = case Opts of
                 #{cookie := Ck} -> Ck;
                 #{} when node() =/= nonode@nohost -> erlang:get_cookie();
                 #{} -> evatar_test_fixtures:secret_atom()
             end,
    Backend = backend(Net),
    %% Names unique to this cluster: other runs of the same suites on this
    %% machine share its epmd and, through ~/.erlang.cookie, the
    %% controller's cookie (a run once reached another run's `nem1').
    Tag = "_" ++ os:getpid() ++ "_" ++ integer_to_list(erlang:unique_integer([positive])),
    Shorts = [maps:get(prefix, Opts) ++ integer_to_list(I) ++ Tag
              || I <- lists:seq(1, maps:get(n, Opts))],
    case Backend:init(Shorts, Opts) of
        {ok, NetState, Specs} ->
            Nodes = maps:from_list(
                      [{I, #nd{i = I, short = Short, spec = Spec,
                               name = list_to_atom(Short ++ "@" ++ inet:ntoa(Ip))}}
                       || {I, {Short, #{ip := Ip} = Spec}} <- lists:enumerate(
                                                                lists:zip(Shorts, Specs))]),
            {ok, #s{opts = Opts, cookie = Cookie, backend = Backend, net = NetState,
                    nodes = Nodes}};
        {error, Why} ->
            {stop, Why}
    end.

backend(proxy) -> evatar_test_net_proxy;
backend(cookie) -> evatar_test_net_cookie;
backend(netns) -> evatar_test_net_netns;
backend(none) -> evatar_test_net_none.

-spec handle_call(term(), gen_server:from(), #s{}) -> {reply, term(), #s{}}.
handle_call(start_all, _From, #s{nodes = Nodes} = S) ->
    %% Launch every node first, then wait for them: boots overlap.
    Launched = maps:map(fun(_, Nd) -> launch(Nd, S) end, Nodes),
    case setup_all(maps:values(Launched), S) of
        {ok, Ready} -> {reply, ok, S#s{nodes = Ready}};
        {error, Why, Partial} -> {reply, {error, Why}, S#s{nodes = Partial}}
    end;
handle_call(info, _From, #s{nodes = Nodes} = S) ->
    {reply, [info(Nd, S) || {_, Nd} <- lists:sort(maps:to_list(Nodes))], S};
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
handle_call({cut, Links}, _From, #s{backend = B, net = Net} = S) ->
    Pairs = lists:usort([{min(I, J), max(I, J)} || {I, J} <- Links, I =/= J]),
    {Reply, Net1} = B:cut(Pairs, ctx(S), Net),
    {reply, Reply, S#s{net = Net1}};
handle_call({cut_off, I}, _From, #s{backend = B, net = Net} = S) ->
    {Reply, Net1} = B:cut_off(I, ctx(S), Net),
    {reply, Reply, S#s{net = Net1}};
handle_call({heal, Mode}, _From, #s{backend = B, net = Net} = S) ->
    {Reply, Net1} = B:heal(Mode, ctx(S), Net),
    {reply, Reply, S#s{net = Net1}};
handle_call(links_down, _From, #s{backend = B, net = Net} = S) ->
    {reply, B:links_down(Net), S}.

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
terminate(_Why, #s{nodes = Nodes, backend = B, net = Net}) ->
    _ = [kill_os(Nd) || Nd <- maps:values(Nodes), Nd#nd.os_pid =/= undefined],
    B:stop(Net).

%% ---------------------------------------------------------------------------
%% Internals
%% ---------------------------------------------------------------------------

info(#nd{i = I, spec = #{ip := Ip, bridge_port := BP, dist_port := DP}} = Nd, S) ->
    #{i => I, name => Nd#nd.name, status => Nd#nd.status, os_pid => Nd#nd.os_pid,
      ip => Ip, bridge_port => BP, dist_port => DP, peer => Nd#nd.peer,
      control => maps:get(control, S#s.opts)}.

%% What a backend needs from the cluster: the nodes' names and a call to
%% a node that is up (the cookie backend works on the nodes themselves).
ctx(#s{nodes = Nodes, cookie = Cookie} = S) ->
    Infos = maps:map(fun(_, Nd) -> info(Nd, S) end, Nodes),
    #{names => maps:map(fun(_, #nd{name = N}) -> N end, Nodes),
      cookie => Cookie,
      call => fun(I, M, F, A) ->
                      case maps:get(I, Infos) of
                          #{status := up} = Info -> rpc(Info, M, F, A, 5000);
                          #{} -> {error, down}
                      end
              end}.

%% @private For the backends whose nodes run on loopback: each node's
%% spec, with free ports for its distribution and its bridge.
-spec loopback_specs(pos_integer()) -> [node_spec()].
loopback_specs(N) ->
    {DistPorts, BridgePorts} = lists:split(N, free_ports(2 * N)),
    [#{ip => {127, 0, 0, 1}, dist_port => DP, bridge_port => BP, args => [], exec_prefix => []}
     || {DP, BP} <- lists:zip(DistPorts, BridgePorts)].

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

%% The nodes' code path: the `code_path' option's directories (an earlier
%% build's, without its own copy of this kit) and this kit, or this
%% build's; the `modules' option's directories in both cases.
node_code_path(#{modules := Modules} = Opts) ->
    Kit = filename:dirname(code:which(?MODULE)),
    case Opts of
        #{code_path := Dirs} ->
            [D || D <- Dirs, string:find(D, "evatar_test_kit") =:= nomatch]
                ++ [Kit | [filename:dirname(code:which(M)) || M <- Modules]];
        #{} ->
            code_path([?MODULE | Modules])
    end.

args(#nd{spec = #{ip := Ip, dist_port := DP, args := NetArgs}}, #s{opts = Opts, cookie = Cookie}) ->
    Dist = case maps:get(dist, Opts) of
               inet_tcp -> [];
               inet_tls -> ["-proto_dist", "inet_tls",
                            "-ssl_dist_optfile", maps:get(ssl_optfile, Opts)]
           end,
    Input = case maps:get(control, Opts) of
                dist -> ["-noinput"];
                stdio -> []
            end,
    Config = case Opts of
                 #{config := File} -> ["-config", File];
                 #{} -> []
             end,
    Config ++ ["+K", "true"] ++ Input ++ NetArgs ++ Dist
        ++ node_args(#{cookie => Cookie, interface => Ip, dist_port => DP,
                       code_path => node_code_path(Opts)}).

log_file(#nd{short = Short}, #s{opts = Opts}) ->
    filename:join(maps:get(dir, Opts), Short ++ ".log").

launch(#nd{short = Short, spec = #{exec_prefix := Prefix}} = Nd, #s{opts = Opts} = S) ->
    Args = args(Nd, S),
    Erl = os:find_executable("erl"),
    case maps:get(launcher, Opts) of
        os ->
            %% stdin stays the port's pipe (the watchdog's eof); output goes
            %% to a file. A node in a namespace of its own starts its epmd
            %% there, on that namespace's port 4369: no inherited address.
            Out = filename:join(maps:get(dir, Opts), Short ++ ".out"),
            Unset = case Prefix of
                        [] -> "";
                        _ -> "unset ERL_EPMD_ADDRESS ERL_FLAGS ERL_AFLAGS ERL_ZFLAGS; "
                    end,
            Cmd = Unset ++ "exec "
                ++ lists:join(" ", [quote(A) || A <- Prefix ++ [Erl, "-name", atom_to_list(Nd#nd.name)
                                                                 | Args]
                                                ++ ["-eval", "evatar_test_cluster:watchdog()"]])
                ++ " >>" ++ quote(Out) ++ " 2>&1",
            Port = open_port({spawn_executable, "/bin/sh"},
                             [{args, ["-c", lists:flatten(Cmd)]}, exit_status, binary]),
            {os_pid, OsPid} = erlang:port_info(Port, os_pid),
            Nd#nd{port = Port, os_pid = integer_to_list(OsPid), status = down};
        peer when Prefix =:= [] ->
            Base = #{name => Short, host => inet:ntoa(maps:get(ip, Nd#nd.spec)),
                     longnames => true, exec => Erl},
            {ok, Peer, _Node} =
                case maps:get(control, Opts) of
                    dist ->
                        peer:start(Base#{args => Args ++ ["-eval", "evatar_test_cluster:watchdog(\""
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

setup(#nd{name = Node, spec = #{ip := Ip, bridge_port := Port}} = Nd,
      #s{opts = Opts, nodes = All} = S) ->
    Cluster = lists:sort([X#nd.name || X <- maps:values(All)]),
    Data = filename:join(maps:get(dir, Opts), atom_to_list(Node) ++ ".data"),
    Env = [{evatar, [{cluster, Cluster} | maps:get(evatar, Opts)]},
           {agent_bridge, [{listeners, []}]},
           {mnesia, [{dir, Data}]}],
    Info = #{name => Node, peer => Nd#nd.peer, control => maps:get(control, Opts)},
    ok = rpc(Info, ?MODULE, node_setup,
             [#{log => log_file(Nd, S), env => Env, bridge_port => Port, ip => Ip,
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

%% @doc Test support. A cluster of EVATAR nodes, each a real OS process
%% (`erl', started with `ip netns exec') in a network namespace of its own,
%% with a link of its own to every other node and a client link to the
%% controller's namespace, where the clients run: distribution goes over
%% the nodes' links, clients reach the nodes over TCP. Partitions take links
%% down, so the nodes see what a network does when a cable is pulled, not
%% what a proxy does: their own interface loses its carrier, its routes
%% stay, the kernel drops what is sent, address resolution fails (a new
%% connection gets "no route to host" after a few seconds) and an
%% established connection's retransmissions back off, so after a heal it
%% resumes only at its next retransmission. Needs root and `ip' (iproute2);
%% {@link available/0} says why not. Internal to the root test/ directory.
%%
%% Every link is a bridge in a hub namespace between two veth pairs, and a
%% cut takes the bridge's ports down (the nodes' interfaces stay up):
%% ```
%%  ns 1 [lo 10.A.B.1] m2 --- x12 |b12| x21 --- m1 [lo 10.A.B.2] ns 2
%%  ns 1 c --- y1 |bc1| z1 --- evr<tag>1 [10.A.B.254] (controller's namespace)
%% '''
%% Namespaces are named `evatar-<OS pid>-<tag>-<role>' and removed by
%% stop/1, or by sweep/0 once the OS process that made them is gone. The
%% cluster process answers ha_cluster's `info' call, so ha_cluster:call/5,
%% ha_cluster:node/2 and ha_pairing's functions work on it.
-module(ha_netns).
-behaviour(gen_server).

-export([available/0, start/1, stop/1, endpoints/1, nodes/1, cut_nodes/2, isolate/2,
         cut_link/3, heal/1, sweep/0, links_down/1]).
-export([init/1, handle_call/3, handle_cast/2, handle_info/2, terminate/2]).

-export_type([net/0, opts/0]).

-type net() :: pid().
%% n: nodes (default 3); dir: where logs and catalogues go (required);
%% evatar: extra evatar app env; conn: the bridge's connection options;
%% code_path: the ebin directories the nodes load EVATAR from (default this
%% build's; the test support is always added).
-type opts() :: #{n => pos_integer(), dir := file:filename(), evatar => [{atom(), term()}],
                  conn => map(), code_path => [file:filename()],
                  boot_timeout => pos_integer()}.

-define(BRIDGE_PORT, 7400).
-define(DIST_PORT, 9100).
-define(CALL_TIMEOUT, 120000).

-record(nd, {i :: pos_integer(), name :: node(), ip :: inet:ip4_address(), ns :: string(),
             os_pid :: string() | undefined, port :: port() | undefined,
             status = down :: up | down}).
-record(s, {opts :: opts(), tag :: string(), prefix :: string(), hub :: string(),
            net :: {byte(), byte()}, nodes :: #{pos_integer() => #nd{}},
            down = [] :: [string()]}).

%% ---------------------------------------------------------------------------
%% API
%% ---------------------------------------------------------------------------

%% @doc `ok' when this process may make namespaces (root, `ip' found, and a
%% namespace can be made and removed); else `{skip, Reason}' saying which.
-spec available() -> ok | {skip, string()}.
available() ->
    case {os:cmd("id -u"), os:find_executable("ip")} of
        {"0\n", Ip} when is_list(Ip) ->
            Probe = "evatar-probe-" ++ os:getpid(),
            case sh("ip netns add " ++ Probe ++ " && ip netns del " ++ Probe) of
                {0, _} -> ok;
                {_, Out} -> {skip, "cannot make a network namespace: " ++ Out}
            end;
        {"0\n", false} ->
            {skip, "no `ip' (iproute2) on the PATH: network namespaces cannot be made"};
        {Uid, _} ->
            {skip, "network namespaces need root; running as uid " ++ string:trim(Uid)}
    end.

%% @doc Makes the namespaces and links, starts every node with evatar and
%% the bridge, and returns once they form a cluster.
-spec start(opts()) -> {ok, net()} | {error, term()}.
start(Opts) ->
    _ = ha_cluster:ensure_distributed(),
    ok = sweep(),
    {ok, Net} = gen_server:start(?MODULE, Opts, []),
    case gen_server:call(Net, start_all, ?CALL_TIMEOUT) of
        ok ->
            case ha_cluster:await_formed(Net, maps:get(boot_timeout, Opts, 60000)) of
                ok -> {ok, Net};
                {error, _} = Error -> stop(Net), Error
            end;
        {error, _} = Error ->
            stop(Net),
            Error
    end.

%% @doc Kills every node and removes every namespace and link.
-spec stop(net()) -> ok.
stop(Net) ->
    try gen_server:stop(Net, normal, ?CALL_TIMEOUT)
    catch exit:noproc -> ok
    end.

%% @doc Every node's bridge address, in node order: a client's endpoints.
-spec endpoints(net()) -> [{inet:ip_address(), inet:port_number()}].
endpoints(Net) -> [{Ip, P} || #{ip := Ip, bridge_port := P} <- ha_cluster:info(Net)].

-spec nodes(net()) -> [node()].
nodes(Net) -> ha_cluster:nodes(Net).

%% @doc Cuts node I off from every other node; its clients still reach it.
-spec cut_nodes(net(), pos_integer()) -> ok.
cut_nodes(Net, I) -> gen_server:call(Net, {down, {nodes, I}}, ?CALL_TIMEOUT).

%% @doc Cuts node I off from everything: the other nodes and the clients
%% (the controller's own rpc to it too).
-spec isolate(net(), pos_integer()) -> ok.
isolate(Net, I) -> gen_server:call(Net, {down, {all, I}}, ?CALL_TIMEOUT).

%% @doc Cuts the one link between nodes I and J.
-spec cut_link(net(), pos_integer(), pos_integer()) -> ok.
cut_link(Net, I, J) -> gen_server:call(Net, {down, {link, I, J}}, ?CALL_TIMEOUT).

%% @doc Brings every cut link up again.
-spec heal(net()) -> ok.
heal(Net) -> gen_server:call(Net, heal, ?CALL_TIMEOUT).

%% @doc The hub ports that are down now (for the logs).
-spec links_down(net()) -> [string()].
links_down(Net) -> gen_server:call(Net, links_down, ?CALL_TIMEOUT).

%% @doc Removes the namespaces (and their processes) left by a run whose
%% OS process is gone (a run killed before its clean-up).
-spec sweep() -> ok.
sweep() ->
    Names = string:lexemes(os:cmd("ip netns list 2>/dev/null | cut -d' ' -f1"), "\n"),
    Stale = [Ns || "evatar-" ++ Rest = Ns <- Names,
                   [Pid | _] <- [string:split(Rest, "-")],
                   Pid =/= os:getpid(),
                   os:cmd("kill -0 " ++ Pid ++ " 2>&1") =/= ""],
    remove(Stale).

%% ---------------------------------------------------------------------------
%% gen_server
%% ---------------------------------------------------------------------------

-spec init(opts()) -> {ok, #s{}} | {stop, term()}.
init(Opts0) ->
    process_flag(trap_exit, true),
    Opts = maps:merge(#{n => 3, evatar => [], conn => #{heartbeat => 100},
                        boot_timeout => 60000}, Opts0),
    Tag = string:lowercase(integer_to_list(rand:uniform(36#zzzzz), 36)),
    Prefix = "evatar-" ++ os:getpid() ++ "-" ++ Tag,
    Net = free_subnet(20),
    N = maps:get(n, Opts),
    Nodes = maps:from_list(
              [{I, #nd{i = I, ip = Ip, ns = Prefix ++ "-" ++ integer_to_list(I),
                       name = list_to_atom("evns" ++ integer_to_list(I) ++ "@" ++ inet:ntoa(Ip))}}
               || I <- lists:seq(1, N), Ip <- [addr(Net, I)]]),
    S = #s{opts = Opts, tag = Tag, prefix = Prefix, hub = Prefix ++ "-hub", net = Net,
           nodes = Nodes},
    case sh(lists:join(" && ", plumbing(S))) of
        {0, _} ->
            {ok, S};
        {_, Out} ->
            _ = remove(namespaces(S)),
            {stop, {netns_setup, Out}}
    end.

-spec handle_call(term(), gen_server:from(), #s{}) -> {reply, term(), #s{}}.
handle_call(start_all, _From, #s{nodes = Nodes} = S) ->
    Launched = maps:map(fun(_, Nd) -> launch(Nd, S) end, Nodes),
    S1 = S#s{nodes = Launched},
    Names = [Nd#nd.name || Nd <- maps:values(Launched)],
    Booted = fun() -> lists:all(fun(N) -> booted(N) end, Names) end,
    case ha_cluster:await(Booted, maps:get(boot_timeout, S#s.opts), {boot, Names}) of
        ok ->
            Ready = maps:map(fun(_, Nd) -> setup(Nd, S1) end, Launched),
            {reply, ok, S1#s{nodes = Ready}};
        {error, _} = Error ->
            {reply, Error, S1}
    end;
handle_call(info, _From, #s{nodes = Nodes} = S) ->
    {reply, [#{i => I, name => Nd#nd.name, status => Nd#nd.status, os_pid => Nd#nd.os_pid,
               ip => Nd#nd.ip, ns => Nd#nd.ns, bridge_port => ?BRIDGE_PORT,
               dist_port => ?DIST_PORT, peer => undefined, control => dist}
             || {I, Nd} <- lists:sort(maps:to_list(Nodes))], S};
handle_call({down, What}, _From, #s{down = Down} = S) ->
    Ports = ports(What, S),
    {reply, hub(S, [["link set dev ", P, " down"] || P <- Ports]),
     S#s{down = lists:usort(Ports ++ Down)}};
handle_call(heal, _From, #s{down = Down} = S) ->
    {reply, hub(S, [["link set dev ", P, " up"] || P <- Down]), S#s{down = []}};
handle_call(links_down, _From, #s{down = Down} = S) ->
    {reply, Down, S}.

-spec handle_cast(term(), #s{}) -> {noreply, #s{}}.
handle_cast(_Msg, S) -> {noreply, S}.

-spec handle_info(term(), #s{}) -> {noreply, #s{}}.
handle_info({Port, {exit_status, _}}, #s{nodes = Nodes} = S) when is_port(Port) ->
    {noreply, S#s{nodes = maps:map(fun(_, #nd{port = P} = Nd) when P =:= Port ->
                                           Nd#nd{status = down, port = undefined};
                                      (_, Nd) -> Nd
                                   end, Nodes)}};
handle_info(_Msg, S) ->
    {noreply, S}.

-spec terminate(term(), #s{}) -> ok.
terminate(_Why, #s{nodes = Nodes} = S) ->
    ok = remove(namespaces(S)),
    %% Gone with the hub anyway, but only once the kernel frees it.
    _ = [os:cmd("ip link del " ++ root_if(S, I) ++ " 2>/dev/null") || I <- maps:keys(Nodes)],
    ok.

%% ---------------------------------------------------------------------------
%% Namespaces and links
%% ---------------------------------------------------------------------------

%% A /24 of 10.0.0.0/8 that no route or address of this namespace uses.
free_subnet(0) ->
    error(no_free_subnet);
free_subnet(Tries) ->
    Net = {64 + rand:uniform(128) - 1, rand:uniform(254)},
    Used = os:cmd("ip -4 route show table all; ip -4 addr show"),
    case string:find(Used, prefix(Net)) of
        nomatch -> Net;
        _ -> free_subnet(Tries - 1)
    end.

prefix({A, B}) -> "10." ++ integer_to_list(A) ++ "." ++ integer_to_list(B) ++ ".".

addr({A, B}, I) -> {10, A, B, I}.

ctl_addr(Net) -> prefix(Net) ++ "254".

ip_s(Net, I) -> prefix(Net) ++ integer_to_list(I).

namespaces(#s{hub = Hub, nodes = Nodes}) ->
    [Ns || #nd{ns = Ns} <- maps:values(Nodes)] ++ [Hub].

root_if(#s{tag = Tag}, I) -> "evr" ++ Tag ++ integer_to_list(I).

%% Every command that builds the namespaces and links, in order.
plumbing(#s{hub = Hub, nodes = Nodes, net = Net} = S) ->
    Is = lists:sort(maps:keys(Nodes)),
    NsOf = fun(I) -> (maps:get(I, Nodes))#nd.ns end,
    I2 = fun integer_to_list/1,
    Ctl = ctl_addr(Net),
    Spaces = [["ip netns add ", Ns] || Ns <- namespaces(S)]
        ++ [["ip -n ", Ns, " link set lo up"] || Ns <- namespaces(S)]
        ++ [["ip -n ", NsOf(I), " addr add ", ip_s(Net, I), "/32 dev lo"] || I <- Is],
    Mesh = lists:append(
             [[["ip link add m", I2(J), " netns ", NsOf(I), " type veth peer name x", I2(I), I2(J),
                " netns ", Hub],
               ["ip link add m", I2(I), " netns ", NsOf(J), " type veth peer name x", I2(J), I2(I),
                " netns ", Hub],
               ["ip -n ", Hub, " link add b", I2(I), I2(J), " type bridge"],
               ["ip -n ", Hub, " link set x", I2(I), I2(J), " master b", I2(I), I2(J)],
               ["ip -n ", Hub, " link set x", I2(J), I2(I), " master b", I2(I), I2(J)],
               ["ip -n ", Hub, " link set b", I2(I), I2(J), " up"],
               ["ip -n ", Hub, " link set x", I2(I), I2(J), " up"],
               ["ip -n ", Hub, " link set x", I2(J), I2(I), " up"],
               ["ip -n ", NsOf(I), " link set m", I2(J), " up"],
               ["ip -n ", NsOf(J), " link set m", I2(I), " up"],
               ["ip -n ", NsOf(I), " route add ", ip_s(Net, J), "/32 dev m", I2(J), " src ",
                ip_s(Net, I)],
               ["ip -n ", NsOf(J), " route add ", ip_s(Net, I), "/32 dev m", I2(I), " src ",
                ip_s(Net, J)]]
              || I <- Is, J <- Is, I < J]),
    Clients = lists:append(
                [[["ip link add c netns ", NsOf(I), " type veth peer name y", I2(I), " netns ", Hub],
                  ["ip link add ", root_if(S, I), " type veth peer name z", I2(I), " netns ", Hub],
                  ["ip -n ", Hub, " link add bc", I2(I), " type bridge"],
                  ["ip -n ", Hub, " link set y", I2(I), " master bc", I2(I)],
                  ["ip -n ", Hub, " link set z", I2(I), " master bc", I2(I)],
                  ["ip -n ", Hub, " link set bc", I2(I), " up"],
                  ["ip -n ", Hub, " link set y", I2(I), " up"],
                  ["ip -n ", Hub, " link set z", I2(I), " up"],
                  ["ip -n ", NsOf(I), " link set c up"],
                  ["ip -n ", NsOf(I), " route add ", Ctl, "/32 dev c src ", ip_s(Net, I)],
                  ["ip addr add ", Ctl, "/32 dev ", root_if(S, I)],
                  ["ip link set ", root_if(S, I), " up"],
                  ["ip route add ", ip_s(Net, I), "/32 dev ", root_if(S, I), " src ", Ctl]]
                 || I <- Is]),
    [lists:flatten(C) || C <- Spaces ++ Mesh ++ Clients].

%% The hub ports a cut takes down.
ports({link, I, J}, _S) ->
    I2 = fun integer_to_list/1,
    ["x" ++ I2(I) ++ I2(J), "x" ++ I2(J) ++ I2(I)];
ports({nodes, I}, #s{nodes = Nodes} = S) ->
    lists:append([ports({link, I, J}, S) || J <- maps:keys(Nodes), J =/= I]);
ports({all, I}, S) ->
    ports({nodes, I}, S) ++ ["y" ++ integer_to_list(I), "z" ++ integer_to_list(I)].

%% One `ip -batch' in the hub: every port of a cut changes at once.
hub(_S, []) ->
    ok;
hub(#s{hub = Hub}, Commands) ->
    File = filename:join("/tmp", Hub ++ ".batch"),
    ok = file:write_file(File, [[C, "\n"] || C <- Commands]),
    Result = sh("ip -n " ++ Hub ++ " -batch " ++ File),
    ok = file:delete(File),
    {0, _} = Result,
    ok.

%% Kills every process in the namespaces (the nodes and their epmds: a
%% namespace that still holds a process keeps its links), then removes
%% them; the root's end of each client link goes with its peer.
remove([]) ->
    ok;
remove(Namespaces) ->
    Pids = fun() -> lists:append([string:lexemes(os:cmd("ip netns pids " ++ Ns ++ " 2>/dev/null"),
                                                 "\n")
                                  || Ns <- Namespaces])
           end,
    _ = [os:cmd("kill -9 " ++ P) || P <- Pids()],
    _ = ha_cluster:await(fun() -> Pids() =:= [] end, 10000, netns_processes_gone),
    _ = [os:cmd("ip netns del " ++ Ns ++ " 2>/dev/null") || Ns <- Namespaces],
    ok.

sh(Cmd) ->
    Out = os:cmd(lists:flatten(Cmd) ++ " 2>&1; echo \"rc=$?\""),
    [Rc | Rest] = lists:reverse(string:lexemes(Out, "\n")),
    "rc=" ++ Code = Rc,
    {list_to_integer(Code), lists:flatten(lists:join("\n", lists:reverse(Rest)))}.

%% ---------------------------------------------------------------------------
%% Nodes
%% ---------------------------------------------------------------------------

code_path(#s{opts = Opts}) ->
    case Opts of
        #{code_path := Dirs} -> Dirs ++ [filename:dirname(code:which(M))
                                         || M <- [ha_cluster, evatar_test_wait]];
        #{} -> ha_cluster:code_path()
    end.

launch(#nd{i = I, ns = Ns, name = Name, ip = {A, B, C, D}} = Nd, #s{opts = Opts} = S) ->
    Out = filename:join(maps:get(dir, Opts), "evns" ++ integer_to_list(I) ++ ".out"),
    Args = [os:find_executable("ip"), "netns", "exec", Ns,
            os:find_executable("erl"), "-name", atom_to_list(Name), "+K", "true", "-noinput"]
        %% Distribution on the node's own address only, at ?DIST_PORT.
        ++ evatar_test_cluster:node_args(#{cookie => erlang:get_cookie(),
                                           interface => {A, B, C, D}, dist_port => ?DIST_PORT,
                                           code_path => code_path(S)})
        ++ ["-eval", "ha_cluster:watchdog()"],
    %% Its epmd starts inside the namespace, on the namespace's own port 4369.
    Cmd = "unset ERL_EPMD_ADDRESS ERL_FLAGS ERL_AFLAGS ERL_ZFLAGS; exec "
        ++ lists:join(" ", [quote(X) || X <- Args]) ++ " >>" ++ quote(Out) ++ " 2>&1",
    Port = open_port({spawn_executable, "/bin/sh"},
                     [{args, ["-c", lists:flatten(Cmd)]}, exit_status, binary]),
    Nd#nd{port = Port}.

booted(Node) ->
    net_adm:ping(Node) =:= pong andalso
        (catch erpc:call(Node, init, get_status, [], 5000)) =:= {started, started}.

setup(#nd{i = I, name = Name, ip = Ip} = Nd, #s{opts = Opts, nodes = All, tag = Tag}) ->
    Dir = maps:get(dir, Opts),
    Short = "evns" ++ integer_to_list(I),
    Cluster = lists:sort([X#nd.name || X <- maps:values(All)]),
    Env = [{evatar, [{cluster, Cluster} | maps:get(evatar, Opts)]},
           {agent_bridge, [{listeners, []}]},
           %% A catalogue belongs to one node name, and names change per run.
           {mnesia, [{dir, filename:join(Dir, Short ++ "-" ++ Tag ++ ".data")}]}],
    ok = erpc:call(Name, ha_cluster, node_setup,
                   [#{log => filename:join(Dir, Short ++ ".log"), env => Env,
                      bridge_port => ?BRIDGE_PORT, ip => Ip, conn => maps:get(conn, Opts)}],
                   60000),
    OsPid = erpc:call(Name, os, getpid, [], 60000),
    Nd#nd{os_pid = OsPid, status = up}.

quote(S) ->
    "'" ++ lists:flatten(string:replace(S, "'", "'\\''", all)) ++ "'".

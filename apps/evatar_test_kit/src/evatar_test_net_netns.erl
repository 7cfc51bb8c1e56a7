%% @doc Test support: the fault backend that puts each node in a network
%% namespace of its own (evatar_test_cluster's `net => netns'): each node is
%% a real OS process (`erl', started with `ip netns exec') with a link of
%% its own to every other node and a client link to the controller's
%% namespace, where the clients run: distribution goes over the nodes'
%% links, clients reach the nodes over TCP. Partitions take links down, so
%% the nodes see what a network does when a cable is pulled, not what a
%% proxy does: their own interface loses its carrier, its routes stay, the
%% kernel drops what is sent, address resolution fails (a new connection
%% gets "no route to host" after a few seconds) and an established
%% connection's retransmissions back off, so after a heal it resumes only
%% at its next retransmission. Only this backend can cut a node off from
%% its clients too (cut_off/3). Needs root and `ip' (iproute2);
%% {@link available/0} says why not.
%%
%% Every link is a bridge in a hub namespace between two veth pairs, and a
%% cut takes the bridge's ports down (the nodes' interfaces stay up):
%% ```
%%  ns 1 [lo 10.A.B.1] m2 --- x12 |b12| x21 --- m1 [lo 10.A.B.2] ns 2
%%  ns 1 c --- y1 |bc1| z1 --- evr<tag>1 [10.A.B.254] (controller's namespace)
%% '''
%% Namespaces are named `evatar-<OS pid>-<tag>-<role>' and removed by
%% stop/1, or by sweep/0 once the OS process that made them is gone.
-module(evatar_test_net_netns).
-behaviour(evatar_test_cluster).

-export([available/0, sweep/0]).
-export([init/2, cut/3, cut_off/3, heal/3, links_down/1, stop/1]).

%% Inside its namespace every node listens at these ports of its own address.
-define(BRIDGE_PORT, 7400).
-define(DIST_PORT, 9100).

-record(s, {tag :: string(), hub :: string(), net :: {byte(), byte()},
            ns :: #{pos_integer() => string()}, down = [] :: [string()]}).

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
%% The backend
%% ---------------------------------------------------------------------------

%% @doc Makes the namespaces and links (after sweeping those of runs that
%% are gone): node I at 10.A.B.I, distribution at 9100 and the bridge at
%% 7400 of its own address, run under `ip netns exec'.
-spec init([string()], evatar_test_cluster:opts()) ->
          {ok, #s{}, [evatar_test_cluster:node_spec()]} | {error, term()}.
init(Shorts, _Opts) ->
    ok = sweep(),
    Tag = string:lowercase(integer_to_list(rand:uniform(36#zzzzz), 36)),
    Prefix = "evatar-" ++ os:getpid() ++ "-" ++ Tag,
    Net = free_subnet(20),
    Is = lists:seq(1, length(Shorts)),
    S = #s{tag = Tag, hub = Prefix ++ "-hub", net = Net,
           ns = maps:from_list([{I, Prefix ++ "-" ++ integer_to_list(I)} || I <- Is])},
    case sh(lists:join(" && ", plumbing(S))) of
        {0, _} ->
            IpCmd = os:find_executable("ip"),
            {ok, S, [#{ip => addr(Net, I), dist_port => ?DIST_PORT, bridge_port => ?BRIDGE_PORT,
                       args => [], exec_prefix => [IpCmd, "netns", "exec", maps:get(I, S#s.ns)]}
                     || I <- Is]};
        {_, Out} ->
            _ = remove(namespaces(S)),
            {error, {netns_setup, Out}}
    end.

-spec cut([{pos_integer(), pos_integer()}], evatar_test_cluster:ctx(), #s{}) -> {ok, #s{}}.
cut(Links, _Ctx, S) ->
    down(lists:append([ports({link, I, J}, S) || {I, J} <- Links]), S).

-spec cut_off(pos_integer(), evatar_test_cluster:ctx(), #s{}) -> {ok, #s{}}.
cut_off(I, _Ctx, S) ->
    down(ports({all, I}, S), S).

%% @doc Brings every cut link up again (the mode makes no difference: TCP
%% resumes at its next retransmission).
-spec heal(evatar_test_cluster:heal(), evatar_test_cluster:ctx(), #s{}) -> {ok, #s{}}.
heal(_Mode, _Ctx, #s{down = Down} = S) ->
    {hub(S, [["link set dev ", P, " up"] || P <- Down]), S#s{down = []}}.

%% @doc The hub ports that are down now.
-spec links_down(#s{}) -> [string()].
links_down(#s{down = Down}) -> Down.

%% @doc Removes every namespace and link (and what still runs in them).
-spec stop(#s{}) -> ok.
stop(#s{ns = Ns} = S) ->
    ok = remove(namespaces(S)),
    %% Gone with the hub anyway, but only once the kernel frees it.
    _ = [os:cmd("ip link del " ++ root_if(S, I) ++ " 2>/dev/null") || I <- maps:keys(Ns)],
    ok.

down(Ports, #s{down = Down} = S) ->
    {hub(S, [["link set dev ", P, " down"] || P <- Ports]), S#s{down = lists:usort(Ports ++ Down)}}.

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

namespaces(#s{hub = Hub, ns = Ns}) ->
    maps:values(Ns) ++ [Hub].

root_if(#s{tag = Tag}, I) -> "evr" ++ Tag ++ integer_to_list(I).

%% Every command that builds the namespaces and links, in order.
plumbing(#s{hub = Hub, ns = NsMap, net = Net} = S) ->
    Is = lists:sort(maps:keys(NsMap)),
    NsOf = fun(I) -> maps:get(I, NsMap) end,
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
ports({nodes, I}, #s{ns = Ns} = S) ->
    lists:append([ports({link, I, J}, S) || J <- maps:keys(Ns), J =/= I]);
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
    _ = evatar_test_cluster:await(fun() -> Pids() =:= [] end, 10000, netns_processes_gone),
    _ = [os:cmd("ip netns del " ++ Ns ++ " 2>/dev/null") || Ns <- Namespaces],
    ok.

sh(Cmd) ->
    Out = os:cmd(lists:flatten(Cmd) ++ " 2>&1; echo \"rc=$?\""),
    [Rc | Rest] = lists:reverse(string:lexemes(Out, "\n")),
    "rc=" ++ Code = Rc,
    {list_to_integer(Code), lists:flatten(lists:join("\n", lists:reverse(Rest)))}.

%% @doc Test support, not a suite: what every multi-node harness does to
%% start an EVATAR node, whatever it starts the node with (OTP `peer' in
%% apps/evatar/test/evatar_ha_SUITE.erl, an OS process in test/ha_cluster.erl,
%% an OS process in a network namespace in test/ha_netns.erl): the code
%% path, the command-line arguments (cookie, distribution on one interface,
%% no overlapping-partition handling), and, run on the node itself, the
%% application environment and evatar with the bridge and its listener.
%% How the node is started, logged, cut off and killed stays with each
%% harness.
-module(evatar_test_cluster).

-export([code_path/1, node_args/1, start_evatar/1]).

-export_type([node_args/0, start/0]).

-type node_args() :: #{cookie := atom(),
                       code_path := [file:filename()],
                       interface => inet:ip4_address(),
                       dist_port => inet:port_number()}.
%% `interface' (default 127.0.0.1, as a release) is the only address the
%% node's distribution listens on; `dist_port', when given, its port (the
%% harness picked it, to put a proxy in front of it).

-type start() :: #{env := [{atom(), [{atom(), term()}]}],
                   listener := atom(),
                   listener_opts := agent_bridge:listener_opts()}.
%% `env' is set (persistent) before anything starts; `listener_opts' are
%% agent_bridge:start_listener/2's (ip, port, conn, ...).

%% @doc The ebin directories an EVATAR node of a test cluster loads: the
%% apps a node runs, this kit (its helpers run on the nodes too) and the
%% directories of `Modules' (the harness's or the suite's own, whose code
%% the nodes call).
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

%% @doc Run on the node: sets the environment, starts evatar and the
%% bridge (agent_bridge starts evatar) and opens the bridge listener.
-spec start_evatar(start()) -> ok.
start_evatar(#{env := Env, listener := Name, listener_opts := Listener}) ->
    ok = application:set_env(Env, [{persistent, true}]),
    {ok, _} = application:ensure_all_started(agent_bridge),
    {ok, _} = agent_bridge:start_listener(Name, Listener),
    ok.

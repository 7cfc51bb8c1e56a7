%% @doc Internal. The node_config application's supervisor. It has no
%% children: what the file declares runs under its own applications'
%% supervisors (agent_bridge_sup, evatar_pairings_sup, mqtt_avatar_sup).
-module(node_config_sup).
-behaviour(supervisor).

-export([start_link/0, init/1]).

-spec start_link() -> {ok, pid()} | ignore | {error, term()}.
start_link() ->
    supervisor:start_link({local, ?MODULE}, ?MODULE, []).

-spec init([]) -> {ok, {supervisor:sup_flags(), [supervisor:child_spec()]}}.
init([]) ->
    {ok, {#{strategy => one_for_one, intensity => 1, period => 5}, []}}.

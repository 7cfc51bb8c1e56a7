%% @doc Internal. Supervises the port connectors (agent_bridge_port). Each
%% connector does its own restarts with back-off, so its child is transient
%% here and only a crash of the connector itself counts against intensity.
-module(agent_bridge_port_sup).
-behaviour(supervisor).

-export([start_link/0, start_port/2, stop_port/1, init/1]).

-spec start_link() -> {ok, pid()} | ignore | {error, term()}.
start_link() ->
    supervisor:start_link({local, ?MODULE}, ?MODULE, []).

-spec start_port(term(), agent_bridge_port:opts()) -> {ok, pid()} | {error, term()}.
start_port(Name, Opts) ->
    Spec = #{id => {agent_bridge_port, Name},
             start => {agent_bridge_port, start_link, [Name, Opts]},
             restart => transient,
             shutdown => 5000},
    case supervisor:start_child(?MODULE, Spec) of
        {ok, Pid} -> {ok, Pid};
        {error, _} = Error -> Error
    end.

-spec stop_port(term()) -> ok | {error, not_found}.
stop_port(Name) ->
    Id = {agent_bridge_port, Name},
    case supervisor:terminate_child(?MODULE, Id) of
        ok -> supervisor:delete_child(?MODULE, Id);
        {error, not_found} -> {error, not_found}
    end.

-spec init([]) -> {ok, {supervisor:sup_flags(), [supervisor:child_spec()]}}.
init([]) ->
    Ports = application:get_env(agent_bridge, ports, []),
    Specs = [#{id => {agent_bridge_port, maps:get(name, P)},
               start => {agent_bridge_port, start_link, [maps:get(name, P), P]},
               restart => transient,
               shutdown => 5000} || P <- Ports],
    {ok, {#{strategy => one_for_one, intensity => 5, period => 10}, Specs}}.

%% @doc Internal. Top supervisor of the bridge: one agent_bridge_listener_keeper
%% per listener (it restarts its agent_bridge_listener_sup with back-off),
%% and the supervisor of port connectors.
-module(agent_bridge_sup).
-behaviour(supervisor).

-export([start_link/0, init/1, listener_spec/2, listener_spec/3]).

-spec start_link() -> {ok, pid()} | ignore | {error, term()}.
start_link() ->
    supervisor:start_link({local, ?MODULE}, ?MODULE, []).

-spec init([]) -> {ok, {supervisor:sup_flags(), [supervisor:child_spec()]}}.
init([]) ->
    %% `enabled => false' leaves a listener of the release's configuration
    %% off (the TLS one of config/sys.config.src until EVATAR_TLS=true).
    Listeners = [L || L <- application:get_env(agent_bridge, listeners, []),
                      maps:get(enabled, L, true) =/= false],
    Ports = #{id => agent_bridge_port_sup,
              start => {agent_bridge_port_sup, start_link, []},
              type => supervisor},
    Specs = [listener_spec(maps:get(name, L, {listener, N}), L)
             || {N, L} <- lists:zip(lists:seq(1, length(Listeners)), Listeners)],
    {ok, {#{strategy => one_for_one, intensity => 5, period => 10}, [Ports | Specs]}}.

%% @doc The child spec of one listener of the configuration: kept from its
%% first start (agent_bridge_listener_keeper), so a port taken at boot
%% delays the listener, not the node.
-spec listener_spec(term(), agent_bridge:listener_opts()) -> supervisor:child_spec().
listener_spec(Name, Opts) ->
    listener_spec(Name, Opts, retry).

%% @doc The same, First saying what a failed first start does.
-spec listener_spec(term(), agent_bridge:listener_opts(),
                    agent_bridge_listener_keeper:first()) -> supervisor:child_spec().
listener_spec(Name, Opts, First) ->
    #{id => {agent_bridge_listener, Name},
      start => {agent_bridge_listener_keeper, start_link, [Name, Opts, First]},
      %% Time for the listener's connections to close (the keeper waits
      %% for its supervisor).
      shutdown => 20000,
      type => worker}.

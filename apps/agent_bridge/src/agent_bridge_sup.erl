%% @doc Internal. Top supervisor of the bridge: one agent_bridge_listener_sup
%% per configured listener, and the supervisor of port connectors.
-module(agent_bridge_sup).
-behaviour(supervisor).

-export([start_link/0, init/1, listener_spec/2]).

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

%% @doc The child spec of one listener.
-spec listener_spec(term(), agent_bridge:listener_opts()) -> supervisor:child_spec().
listener_spec(Name, Opts) ->
    #{id => {agent_bridge_listener, Name},
      start => {agent_bridge_listener_sup, start_link, [Name, Opts]},
      type => supervisor}.

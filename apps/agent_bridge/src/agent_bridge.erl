%% @doc Public API of the bridge: TCP listeners and port connectors through
%% which VAs and Avatars join EVATAR pairings (docs/protocol.md). Listeners
%% named in the application environment start with the application; more
%% can be started and stopped at run time.
-module(agent_bridge).

-export([start_listener/2, stop_listener/1, address/1, listeners/0,
         start_port/2, stop_port/1, publish/2]).

-export_type([listener_opts/0, port_opts/0]).

%% `conn' holds connection options (agent_bridge_conn:default_opts/0).
-type listener_opts() :: #{ip => inet:ip_address(),
                           port => inet:port_number(),
                           acceptors => pos_integer(),
                           backlog => pos_integer(),
                           name => term(),
                           conn => agent_bridge_conn:opts()}.
-type port_opts() :: agent_bridge_port:opts().

%% @doc Starts a listener; port 0 picks a free port (see address/1).
-spec start_listener(term(), listener_opts()) -> {ok, pid()} | {error, term()}.
start_listener(Name, Opts) ->
    case supervisor:start_child(agent_bridge_sup, agent_bridge_sup:listener_spec(Name, Opts)) of
        {ok, Pid} -> {ok, Pid};
        {error, _} = Error -> Error
    end.

%% @doc Stops a listener and closes its connections.
-spec stop_listener(term()) -> ok | {error, not_found}.
stop_listener(Name) ->
    Id = {agent_bridge_listener, Name},
    case supervisor:terminate_child(agent_bridge_sup, Id) of
        ok ->
            ok = supervisor:delete_child(agent_bridge_sup, Id),
            _ = persistent_term:erase({?MODULE, address, Name}),
            ok;
        {error, not_found} ->
            {error, not_found}
    end.

%% @doc The address a listener is bound to.
-spec address(term()) -> {ok, {inet:ip_address(), inet:port_number()}} | {error, not_found}.
address(Name) ->
    case persistent_term:get({?MODULE, address, Name}, undefined) of
        undefined -> {error, not_found};
        Address -> {ok, Address}
    end.

%% @doc Every running listener with its address.
-spec listeners() -> [{term(), {inet:ip_address(), inet:port_number()}}].
listeners() ->
    [{Name, Address}
     || {{agent_bridge_listener, Name}, Pid, _, _} <- supervisor:which_children(agent_bridge_sup),
        is_pid(Pid), {ok, Address} <- [address(Name)]].

%% @doc Internal: records a listener's bound address.
-spec publish(term(), {inet:ip_address(), inet:port_number()}) -> ok.
publish(Name, Address) ->
    persistent_term:put({?MODULE, address, Name}, Address).

%% @doc Starts an external program that speaks the protocol on its
%% stdin/stdout, restarted with exponential back-off when it exits.
-spec start_port(term(), port_opts()) -> {ok, pid()} | {error, term()}.
start_port(Name, Opts) ->
    agent_bridge_port_sup:start_port(Name, Opts).

-spec stop_port(term()) -> ok | {error, not_found}.
stop_port(Name) ->
    agent_bridge_port_sup:stop_port(Name).

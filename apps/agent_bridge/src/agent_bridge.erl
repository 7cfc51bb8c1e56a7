%% @doc Public API of the bridge: TCP and TLS listeners and port connectors through
%% which VAs and Avatars join EVATAR pairings (docs/protocol.md). Listeners
%% named in the application environment start with the application; more
%% can be started and stopped at run time.
-module(agent_bridge).

-export([start_listener/2, stop_listener/1, address/1, listeners/0, metrics/0,
         start_port/2, stop_port/1, publish/2, check_listener/1]).

-export_type([listener_opts/0, handshake_opts/0, port_opts/0]).

%% `conn' holds connection options (agent_bridge_conn:default_opts/0);
%% `max_connections' and `handshake' the listener's guard's limits
%% (agent_bridge_guard_logic:default_config/0, docs/protocol.md section 7).
%% `transport' is `tcp' (the default without `tls') or `tls' (the default
%% with it); `tls' holds the certificate, key and client verification
%% options (agent_bridge_tls:tls_opts(), docs/protocol.md, "TLS").
-type listener_opts() :: #{ip => inet:ip_address(),
                           transport => tcp | tls,
                           tls => agent_bridge_tls:tls_opts(),
                           port => inet:port_number(),
                           acceptors => pos_integer(),
                           backlog => pos_integer(),
                           name => term(),
                           enabled => boolean(),
                           max_connections => pos_integer() | infinity,
                           handshake => handshake_opts(),
                           conn => agent_bridge_conn:opts(),
                           restart => restart_backoff:opts()}.
-type handshake_opts() :: #{rate => pos_integer() | infinity,
                            burst => pos_integer(),
                            failure_delay => non_neg_integer(),
                            max_failure_delay => non_neg_integer(),
                            max_failures => pos_integer(),
                            failure_window => pos_integer(),
                            lockout => non_neg_integer(),
                            max_addresses => pos_integer(),
                            summary_interval => pos_integer(),
                            max_summaries => pos_integer()}.
-type port_opts() :: agent_bridge_port:opts().

%% @doc Starts a listener; port 0 picks a free port (see address/1).
%% Options that check_listener/1 refuses give `{error, {bad_listener,
%% Message}}'; a first start that fails (a port taken) gives its error.
%% Once it has listened the listener is kept: if it stops it is started
%% again after 1 s doubling to 60 s (option `restart', restart_backoff),
%% and a crash loop is logged (`what => crash_loop'). A listener of the
%% application environment is kept from its first start.
-spec start_listener(term(), listener_opts()) -> {ok, pid()} | {error, term()}.
start_listener(Name, Opts) ->
    case check_listener(Opts) of
        ok ->
            case supervisor:start_child(agent_bridge_sup,
                                        agent_bridge_sup:listener_spec(Name, Opts, fail)) of
                {ok, Pid} -> {ok, Pid};
                {error, _} = Error -> Error
            end;
        {error, Message} ->
            {error, {bad_listener, Message}}
    end.

%% @doc Checks a listener's options (the keys of listener_opts/0, and
%% `conn' keys those of agent_bridge_conn:default_opts/0), so a mistake in
%% a configuration file is found before anything listens. The message
%% names the option and what is wrong with it. Pure but for a TLS
%% listener's certificate and key files, which it reads.
-spec check_listener(term()) -> ok | {error, binary()}.
check_listener(Opts) when is_map(Opts) ->
    case first_error([check_listener_opt(K, V) || {K, V} <- maps:to_list(Opts)]) of
        ok -> check_tls(Opts);
        Error -> Error
    end;
check_listener(_Opts) ->
    {error, <<"a listener is a map of options">>}.

check_listener_opt(ip, Ip) ->
    expect(ip, inet:is_ip_address(Ip),
           "an IP address tuple, for example {127,0,0,1}");
check_listener_opt(port, Port) ->
    expect(port, is_integer(Port) andalso Port >= 0 andalso Port =< 65535,
           "an integer from 0 to 65535 (0 picks a free port)");
check_listener_opt(acceptors, N) ->
    expect(acceptors, is_integer(N) andalso N > 0, "a positive integer");
check_listener_opt(backlog, N) ->
    expect(backlog, is_integer(N) andalso N > 0, "a positive integer");
check_listener_opt(name, _) ->
    ok;
check_listener_opt(max_connections, N) ->
    expect(max_connections, N =:= infinity orelse (is_integer(N) andalso N > 0),
           "a positive integer or infinity");
check_listener_opt(handshake, Handshake) when is_map(Handshake) ->
    Defaults = agent_bridge_guard_logic:default_config(),
    first_error([check_handshake_opt(K, V, Defaults) || {K, V} <- maps:to_list(Handshake)]);
check_listener_opt(handshake, _) ->
    {error, <<"handshake must be a map of handshake limits">>};
check_listener_opt(enabled, B) ->
    expect(enabled, is_boolean(B), "true or false");
check_listener_opt(transport, _) ->
    ok;
check_listener_opt(restart, Restart) ->
    restart_backoff:check(Restart);
check_listener_opt(tls, _) ->
    ok;
check_listener_opt(conn, Conn) when is_map(Conn) ->
    Defaults = agent_bridge_conn:default_opts(),
    first_error([check_conn_opt(K, V, Defaults) || {K, V} <- maps:to_list(Conn)]);
check_listener_opt(conn, _) ->
    {error, <<"conn must be a map of connection options">>};
check_listener_opt(Key, _) ->
    {error, iolist_to_binary(io_lib:format("unknown listener option ~0tp", [Key]))}.

check_conn_opt(Key, infinity, _Defaults)
  when Key =:= hibernate_after; Key =:= idle_timeout; Key =:= max_read_rate ->
    ok;
check_conn_opt(max_read_rate, Value, _Defaults) ->
    expect(max_read_rate, is_integer(Value) andalso Value > 0, "a positive integer or infinity");
check_conn_opt(Key, Value, Defaults) when is_map_key(Key, Defaults) ->
    expect(Key, is_integer(Value) andalso Value >= 0, "a non-negative integer");
check_conn_opt(Key, _Value, _Defaults) ->
    {error, iolist_to_binary(io_lib:format("unknown connection option ~0tp", [Key]))}.

check_handshake_opt(rate, infinity, _Defaults) ->
    ok;
check_handshake_opt(max_connections, _Value, _Defaults) ->
    {error, <<"max_connections is a listener option, not a handshake one">>};
check_handshake_opt(Key, Value, Defaults) when is_map_key(Key, Defaults) ->
    expect(Key, is_integer(Value) andalso Value >= 0, "a non-negative integer");
check_handshake_opt(Key, _Value, _Defaults) ->
    {error, iolist_to_binary(io_lib:format("unknown handshake option ~0tp", [Key]))}.
%% `transport' and `tls' together; this reads the certificate and key files.
check_tls(Opts) ->
    case agent_bridge_tls:check(Opts) of
        {ok, _} -> ok;
        {error, Reason} -> {error, agent_bridge_tls:format_error(Reason)}
    end.

expect(_Key, true, _What) -> ok;
expect(Key, false, What) -> {error, iolist_to_binary(io_lib:format("~0tp must be ~ts", [Key, What]))}.

first_error(Results) ->
    case [E || {error, _} = E <- Results] of
        [] -> ok;
        [First | _] -> First
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

%% @doc The bridge's gauges for evatar_metrics: the connections every
%% listener's guard holds now.
-spec metrics() -> [evatar_metrics:sample()].
metrics() ->
    Guards = [agent_bridge_listener_sup:guard(Sup)
              || {{agent_bridge_listener, _}, Keeper, _, _} <- supervisor:which_children(agent_bridge_sup),
                 is_pid(Keeper), Sup <- [agent_bridge_listener_keeper:listener_sup(Keeper)],
                 is_pid(Sup)],
    Open = lists:sum([maps:get(connections, agent_bridge_guard:info(G)) || G <- Guards]),
    [{evatar_bridge_connections_open, [], Open}].

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

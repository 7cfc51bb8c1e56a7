%% @doc Test support. An epmd module (`-epmd_module evatar_test_epmd') for the nodes
%% of the multi-node suites: it sends a node's connections to each peer
%% through the TCP proxy of that link (evatar_test_proxy), so a suite can cut and heal
%% the links between nodes while it still reaches every node directly.
%% Part of the
%% cluster harness (evatar_test_cluster).
%%
%% The links come from the command line, one `-ha_link ShortName Port' per
%% peer: connecting to ShortName@Host goes to 127.0.0.1:Port (the proxy),
%% which forwards to the peer's fixed distribution port. Every other call
%% (registering with the real epmd, which the test controller uses to reach
%% the node directly, and looking up nodes without a link) goes to erl_epmd.
-module(evatar_test_epmd).

-export([start_link/0, register_node/2, register_node/3, listen_port_please/2,
         port_please/2, port_please/3, address_please/3, names/0, names/1]).

%% The distribution protocol version of OTP 23 and later.
-define(DIST_VERSION, 6).

-spec start_link() -> {ok, pid()} | ignore | {error, term()}.
start_link() -> erl_epmd:start_link().

-spec register_node(string(), inet:port_number()) -> {ok, integer()} | {error, term()}.
register_node(Name, Port) -> erl_epmd:register_node(Name, Port).

-spec register_node(string(), inet:port_number(), atom()) -> {ok, integer()} | {error, term()}.
register_node(Name, Port, Family) -> erl_epmd:register_node(Name, Port, Family).

-spec listen_port_please(string(), term()) -> {ok, inet:port_number()}.
listen_port_please(Name, Host) -> erl_epmd:listen_port_please(Name, Host).

-spec port_please(string() | atom(), term()) ->
          {port, inet:port_number(), pos_integer()} | noport | closed | {error, term()}.
port_please(Name, Host) -> port_please(Name, Host, infinity).

-spec port_please(string() | atom(), term(), timeout()) ->
          {port, inet:port_number(), pos_integer()} | noport | closed | {error, term()}.
port_please(Name, Host, Timeout) ->
    case link_port(Name) of
        {ok, Port} -> {port, Port, ?DIST_VERSION};
        none -> erl_epmd:port_please(Name, Host, Timeout)
    end.

-spec address_please(string(), string() | inet:ip_address(), inet | inet6) ->
          {ok, inet:ip_address()} | {ok, inet:ip_address(), inet:port_number(), pos_integer()}
          | {error, term()}.
address_please(Name, Host, Family) ->
    case link_port(Name) of
        {ok, Port} -> {ok, {127, 0, 0, 1}, Port, ?DIST_VERSION};
        none -> erl_epmd:address_please(Name, Host, Family)
    end.

-spec names() -> {ok, [{string(), inet:port_number()}]} | {error, term()}.
names() -> erl_epmd:names().

-spec names(term()) -> {ok, [{string(), inet:port_number()}]} | {error, term()}.
names(Host) -> erl_epmd:names(Host).

link_port(Name) when is_atom(Name) ->
    link_port(atom_to_list(Name));
link_port(Name) ->
    case init:get_argument(ha_link) of
        {ok, Links} ->
            case [P || [N, P] <- Links, N =:= Name] of
                [Port | _] -> {ok, list_to_integer(Port)};
                [] -> none
            end;
        error ->
            none
    end.

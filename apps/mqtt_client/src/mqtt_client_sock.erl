%% @doc Internal. The byte transport under the client: plain TCP or TLS
%% behind one small interface, sockets in `{active, N}' mode so the owner gets
%% data as messages with flow control.
-module(mqtt_client_sock).

-export([connect/4, send/2, activate/2, top_up/2, is_passive/1, close/1, classify/2]).

-export_type([sock/0, event/0]).

-type sock() :: {tcp, gen_tcp:socket()} | {ssl, ssl:sslsocket()}.
-type event() :: {data, binary()} | passive | {closed, term()} | other.

-define(ACTIVE_N, 100).

%% @doc Opens a connection; `Tls' is false or the ssl client options.
-spec connect(inet:hostname() | inet:ip_address(), inet:port_number(),
              false | [ssl:tls_client_option()], timeout()) ->
          {ok, sock()} | {error, term()}.
connect(Host, Port, false, Timeout) ->
    case gen_tcp:connect(Host, Port, tcp_opts(), Timeout) of
        {ok, S} -> {ok, {tcp, S}};
        {error, _} = E -> E
    end;
connect(Host, Port, TlsOpts, Timeout) when is_list(TlsOpts) ->
    case ssl:connect(Host, Port, tcp_opts() ++ TlsOpts, Timeout) of
        {ok, S} -> {ok, {ssl, S}};
        {error, _} = E -> E
    end.

tcp_opts() ->
    [binary, {packet, raw}, {active, ?ACTIVE_N}, {nodelay, true}, {keepalive, true}].

%% @doc Sends iodata.
-spec send(sock(), iodata()) -> ok | {error, term()}.
send({tcp, S}, Data) -> gen_tcp:send(S, Data);
send({ssl, S}, Data) -> ssl:send(S, Data).

%% @doc Re-arms `{active, N}' after the socket went passive.
-spec activate(sock(), pos_integer()) -> ok | {error, term()}.
activate({_, S}, N) -> sock_flow:activate(S, N).

%% @doc Raises a reading socket's `{active, N}' count back to N, so that a
%% busy connection never goes passive (sock_flow:top_up/2; TLS sockets
%% and passive ones are left alone).
-spec top_up(sock(), pos_integer()) -> ok.
top_up({_, S}, N) -> sock_flow:top_up(S, N).

%% @doc Whether the socket has stopped delivering data: a passive notice
%% that a top-up overtook is stale (sock_flow:is_passive/1).
-spec is_passive(sock()) -> boolean().
is_passive({_, S}) -> sock_flow:is_passive(S).

%% @doc Closes the connection.
-spec close(sock() | undefined) -> ok.
close(undefined) -> ok;
close({tcp, S}) -> _ = gen_tcp:close(S), ok;
close({ssl, S}) -> _ = ssl:close(S), ok.

%% @doc What a process message means for this socket.
-spec classify(term(), sock() | undefined) -> event().
classify({tcp, S, Data}, {tcp, S}) -> {data, Data};
classify({tcp_passive, S}, {tcp, S}) -> passive;
classify({tcp_closed, S}, {tcp, S}) -> {closed, closed};
classify({tcp_error, S, R}, {tcp, S}) -> {closed, R};
classify({ssl, S, Data}, {ssl, S}) -> {data, Data};
classify({ssl_passive, S}, {ssl, S}) -> passive;
classify({ssl_closed, S}, {ssl, S}) -> {closed, closed};
classify({ssl_error, S, R}, {ssl, S}) -> {closed, R};
classify(_, _) -> other.

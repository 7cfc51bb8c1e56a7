%% @doc Internal. The client's socket: plain TCP, or TLS that checks the
%% server against a CA file (or the system's CAs) and/or a pinned SHA-256
%% certificate fingerprint, and can present a client certificate
%% (docs/clients.md, "TLS"). Nothing of the protocol is sent before the
%% server passed every check. Its flow control (`{active, N}') is
%% sock_flow's, as for every socket reader.
-module(agent_bridge_client_sock).

-export([connect/4, send/2, close/1, fingerprint/1,
         controlling_process/2]).

-export_type([sock/0, tls_opts/0]).

-type sock() :: gen_tcp:socket() | ssl:sslsocket().
%% `cacertfile': the CA the server's certificate must chain to (default:
%% the system's CAs, unless a pin alone is given). `pin_sha256': the
%% server certificate's SHA-256 fingerprint, hex (colons and case are
%% ignored); alone, it replaces the CA check. `certfile', `keyfile' and
%% `password': the client certificate. `server_name': the name the
%% server's certificate must carry (default: the host connected to).
-type tls_opts() :: #{cacertfile => file:filename_all(),
                      pin_sha256 => iodata(),
                      certfile => file:filename_all(),
                      keyfile => file:filename_all(),
                      password => string(),
                      server_name => string(),
                      ssl_opts => [ssl:tls_client_option()]}.

%% @doc Connects; with TLS, completes the handshake and checks the pin.
%% Errors: what gen_tcp or ssl say (`{tls_alert, {unknown_ca, _}}' for a
%% server certificate the CA did not sign, `{tls_alert,
%% {handshake_failure, _}}' for a name mismatch and the like), or
%% `{pin_mismatch, Expected, Got}'.
-spec connect(inet:socket_address() | inet:hostname(), inet:port_number(),
              [gen_tcp:connect_option()], #{tls => tls_opts() | false, timeout => timeout()}) ->
          {ok, sock()} | {error, term()}.
connect(Host, Port, SockOpts, #{tls := Tls} = Opts) when is_map(Tls) ->
    Timeout = maps:get(timeout, Opts, 5000),
    case ssl:connect(Host, Port, SockOpts ++ ssl_opts(Tls), Timeout) of
        {ok, S} ->
            case check_pin(S, Tls) of
                ok -> {ok, S};
                {error, _} = Error -> _ = ssl:close(S), Error
            end;
        {error, _} = Error ->
            Error
    end;
connect(Host, Port, SockOpts, Opts) ->
    gen_tcp:connect(Host, Port, SockOpts, maps:get(timeout, Opts, 5000)).

ssl_opts(Tls) ->
    Pinned = is_map_key(pin_sha256, Tls),
    Verify = case {maps:get(cacertfile, Tls, undefined), Pinned} of
                 {undefined, true} ->
                     %% The pin, checked after the handshake, is the trust.
                     [{verify, verify_none}];
                 {undefined, false} ->
                     [{verify, verify_peer}, {cacerts, public_key:cacerts_get()}];
                 {CaFile, _} ->
                     [{verify, verify_peer}, {cacertfile, CaFile}]
             end,
    Name = [{server_name_indication, N} || N <- [maps:get(server_name, Tls, undefined)],
                                           N =/= undefined],
    Cert = [{K, maps:get(K, Tls)} || K <- [certfile, keyfile, password], is_map_key(K, Tls)],
    Verify ++ Name        ++ Cert ++ [{versions, ['tlsv1.3', 'tlsv1.2']} | maps:get(ssl_opts, Tls, [])].

check_pin(S, #{pin_sha256 := Pin}) ->
    Expected = normalise_pin(Pin),
    case ssl:peercert(S) of
        {ok, Der} ->
            case fingerprint(Der) of
                Expected -> ok;
                Got -> {error, {pin_mismatch, Expected, Got}}
            end;
        {error, Why} ->
            {error, {pin_mismatch, Expected, Why}}
    end;
check_pin(_S, #{}) ->
    ok.

normalise_pin(Pin) ->
    string:lowercase(binary:replace(iolist_to_binary(Pin), <<":">>, <<>>, [global])).

%% @doc The SHA-256 fingerprint of a DER certificate, lowercase hex.
-spec fingerprint(binary()) -> binary().
fingerprint(Der) ->
    string:lowercase(binary:encode_hex(crypto:hash(sha256, Der))).

-spec send(sock(), iodata()) -> ok | {error, term()}.
send(S, Data) when is_port(S) -> gen_tcp:send(S, Data);
send(S, Data) -> ssl:send(S, Data).

-spec close(sock()) -> ok.
close(S) when is_port(S) -> gen_tcp:close(S);
close(S) -> _ = ssl:close(S), ok.

%% @doc Makes Pid the socket's owner: its messages go to Pid, and it
%% closes when Pid exits.
-spec controlling_process(sock(), pid()) -> ok | {error, term()}.
controlling_process(S, Pid) when is_port(S) -> gen_tcp:controlling_process(S, Pid);
controlling_process(S, Pid) -> ssl:controlling_process(S, Pid).

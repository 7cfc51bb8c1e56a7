%% @doc Internal. TLS for bridge listeners (docs/protocol.md, "TLS"): checks
%% a listener's `tls' options when it starts, upgrades each accepted TCP
%% socket in the connection's own process (so a slow handshake never holds
%% an acceptor), names the verified client certificate, and writes frames
%% through a small writer process so the connection never waits for a peer
%% that stops reading.
-module(agent_bridge_tls).

-export([conn_opts/1, check/1, format_error/1, handshake/3, failure/1, peer_cert/1,
         start_writer/2, send_fun/1, shutdown/1, stop_writer/1, abort/2, cert_identity/1]).

-export_type([tls_opts/0, writer/0]).

-include_lib("public_key/include/public_key.hrl").

%% `verify' defaults to verify_peer when a `cacertfile' is given, else
%% verify_none; `fail_if_no_peer_cert' defaults to true with verify_peer.
%% `send_timeout' (ms, default 5000) closes a connection whose peer takes
%% no TLS data for that long. `ssl_opts' are added as they are (ciphers,
%% versions and the like).
-type tls_opts() :: #{certfile := file:filename_all(),
                      keyfile := file:filename_all(),
                      password => string(),
                      cacertfile => file:filename_all(),
                      verify => verify_none | verify_peer,
                      fail_if_no_peer_cert => boolean(),
                      send_timeout => pos_integer(),
                      versions => [ssl:protocol_version()],
                      ssl_opts => [ssl:tls_server_option()]}.

-record(writer, {pid :: pid(), inflight :: atomics:atomics_ref(), tcp :: gen_tcp:socket()}).
-opaque writer() :: #writer{}.

%% Bytes handed to the writer and not yet written to TLS before the
%% connection counts the transport as busy (as inet's high watermark does
%% for TCP) and keeps frames in its own bounded queue.
-define(HIGH_WATERMARK, 65536).
-define(DEFAULT_SEND_TIMEOUT, 5000).
-define(KEYS, [certfile, keyfile, password, cacertfile, verify, fail_if_no_peer_cert,
               send_timeout, versions, ssl_opts]).

%% @doc A listener's connection options, with `tls' set to the ssl server
%% options when the listener is a TLS one. Exits `{tls, Reason}' on a bad
%% configuration, so the listener does not start.
-spec conn_opts(agent_bridge:listener_opts()) -> agent_bridge_conn:opts().
conn_opts(Opts) ->
    Conn = maps:get(conn, Opts, #{}),
    case check(Opts) of
        {ok, tcp} -> maps:remove(tls, Conn);
        {ok, {tls, SslOpts, SendTimeout}} -> Conn#{tls => {SslOpts, SendTimeout}};
        {error, Reason} -> exit({tls, Reason})
    end.

%% @doc Checks a listener's `transport' and `tls' options, reading the
%% certificate and key files so that a typo fails the start, not every
%% handshake.
-spec check(map()) -> {ok, tcp | {tls, [ssl:tls_server_option()], pos_integer()}}
                          | {error, term()}.
check(Opts) ->
    Default = case is_map_key(tls, Opts) of
                  true -> tls;
                  false -> tcp
              end,
    case maps:get(transport, Opts, Default) of
        tcp -> {ok, tcp};
        tls -> check_tls(maps:get(tls, Opts, undefined));
        Other -> {error, {bad_option, {transport, Other}}}
    end.

%% @doc A sentence for a reason of check/1.
-spec format_error(term()) -> binary().
format_error({missing, tls}) ->
    <<"transport tls needs a tls map (certfile, keyfile, ...)">>;
format_error({missing, Key}) ->
    fmt("tls option ~0tp is missing", [Key]);
format_error({unknown_option, Key}) ->
    fmt("unknown tls option ~0tp", [Key]);
format_error({bad_option, {transport, V}}) ->
    fmt("transport must be tcp or tls, not ~0tp", [V]);
format_error({bad_option, {tls, V}}) ->
    fmt("tls must be a map of TLS options, not ~0tp", [V]);
format_error({bad_option, {Key, V}}) ->
    fmt("tls option ~0tp has a bad value: ~0tp", [Key, V]);
format_error({Key, File, no_certificate}) ->
    fmt("tls ~0tp ~ts holds no PEM certificate", [Key, File]);
format_error({Key, File, no_private_key}) ->
    fmt("tls ~0tp ~ts holds no PEM private key", [Key, File]);
format_error({Key, File, Why}) ->
    fmt("tls ~0tp ~ts cannot be read: ~ts", [Key, File, file:format_error(Why)]);
format_error(Other) ->
    fmt("~0tp", [Other]).

fmt(Format, Args) -> iolist_to_binary(io_lib:format(Format, Args)).

check_tls(Tls0) when is_map(Tls0) ->
    %% An empty file name is no file: the release's configuration fills
    %% unset variables in with "".
    Tls = maps:filter(fun(_, V) -> V =/= "" andalso V =/= <<>> end, Tls0),
    Verify = maps:get(verify, Tls, case is_map_key(cacertfile, Tls) of
                                       true -> verify_peer;
                                       false -> verify_none
                                   end),
    Checks = [[{unknown_option, K} || K <- maps:keys(Tls), not lists:member(K, ?KEYS)],
              [{missing, K} || K <- [certfile, keyfile], not is_map_key(K, Tls)],
              [{bad_option, {verify, Verify}} || Verify =/= verify_peer, Verify =/= verify_none],
              [{missing, cacertfile} || Verify =:= verify_peer, not is_map_key(cacertfile, Tls)],
              [{bad_option, {K, V}} || K <- [send_timeout], V <- [maps:get(K, Tls, 1)],
                                       not (is_integer(V) andalso V > 0)],
              [{bad_option, {K, V}} || K <- [fail_if_no_peer_cert], V <- [maps:get(K, Tls, true)],
                                       not is_boolean(V)],
              [{bad_option, {K, V}} || K <- [ssl_opts, versions], V <- [maps:get(K, Tls, [])],
                                       not is_list(V)]],
    case lists:append(Checks) of
        [Error | _] ->
            {error, Error};
        [] ->
            case check_files(Tls) of
                ok -> {ok, {tls, ssl_opts(Tls, Verify),
                            maps:get(send_timeout, Tls, ?DEFAULT_SEND_TIMEOUT)}};
                {error, _} = Error -> Error
            end
    end;
check_tls(undefined) ->
    {error, {missing, tls}};
check_tls(Other) ->
    {error, {bad_option, {tls, Other}}}.

check_files(Tls) ->
    Files = [{K, maps:get(K, Tls)} || K <- [certfile, keyfile, cacertfile], is_map_key(K, Tls)],
    first_error([check_file(K, F) || {K, F} <- Files]).

check_file(Key, File) ->
    case file:read_file(File) of
        {ok, Pem} ->
            Types = [element(1, E) || E <- safe_pem_decode(Pem)],
            Wanted = case Key of
                         keyfile -> ['PrivateKeyInfo', 'ECPrivateKey', 'RSAPrivateKey',
                                     'DSAPrivateKey', 'EncryptedPrivateKeyInfo'];
                         _ -> ['Certificate']
                     end,
            case [T || T <- Types, lists:member(T, Wanted)] of
                [] -> {error, {Key, File, case Key of
                                              keyfile -> no_private_key;
                                              _ -> no_certificate
                                          end}};
                [_ | _] -> ok
            end;
        {error, Why} ->
            {error, {Key, File, Why}}
    end.

safe_pem_decode(Pem) ->
    try public_key:pem_decode(Pem)
    catch _:_ -> []
    end.

first_error(Results) ->
    case [E || {error, _} = E <- Results] of
        [] -> ok;
        [E | _] -> E
    end.

ssl_opts(Tls, Verify) ->
    Base = [{certfile, maps:get(certfile, Tls)},
            {keyfile, maps:get(keyfile, Tls)},
            {verify, Verify},
            {versions, maps:get(versions, Tls, ['tlsv1.3', 'tlsv1.2'])}],
    Password = [{password, P} || P <- [maps:get(password, Tls, undefined)], P =/= undefined],
    Peer = case Verify of
               verify_peer -> [{cacertfile, maps:get(cacertfile, Tls)},
                               {fail_if_no_peer_cert, maps:get(fail_if_no_peer_cert, Tls, true)}];
               verify_none -> []
           end,
    Base ++ Password ++ Peer ++ maps:get(ssl_opts, Tls, []).

%% @doc Runs the server side of the TLS handshake on an accepted TCP socket
%% within `Timeout' ms. The caller becomes the TLS socket's owner. A TCP
%% socket without a send timeout gets `SendTimeout', so a peer that stops
%% reading cannot hold the TLS sender (and the connection's close) forever.
-spec handshake(gen_tcp:socket(), {[ssl:tls_server_option()], pos_integer()}, timeout()) ->
          {ok, ssl:sslsocket()} | {error, term()}.
handshake(Sock, {SslOpts, SendTimeout}, Timeout) ->
    _ = case inet:getopts(Sock, [send_timeout]) of
            {ok, [{send_timeout, infinity}]} ->
                inet:setopts(Sock, [{send_timeout, SendTimeout}, {send_timeout_close, true}]);
            _ ->
                ok
        end,
    case ssl:handshake(Sock, SslOpts, Timeout) of
        {ok, SslSock} ->
            {ok, SslSock};
        {error, _} = Error ->
            _ = gen_tcp:close(Sock),
            Error
    end.

%% @doc Why a handshake failed, in a word for logs: the TLS alert
%% (certificate_required, unknown_ca, ...), timeout, closed or other. The
%% alert's text is left out: it can be long, and a client chooses some of it.
-spec failure(term()) -> atom().
failure({tls_alert, {Alert, _}}) when is_atom(Alert) -> Alert;
failure(timeout) -> timeout;
failure(closed) -> closed;
failure(_) -> other.

%% @doc The client certificate the handshake verified, or undefined.
-spec peer_cert(ssl:sslsocket()) -> evatar:peer_cert() | undefined.
peer_cert(SslSock) ->
    case ssl:peercert(SslSock) of
        {ok, Der} -> cert_identity(Der);
        {error, _} -> undefined
    end.

%% @doc A certificate's identity: the SHA-256 of its DER encoding as
%% lowercase hex and its subject's CommonName (undefined when it has none
%% or it cannot be read).
-spec cert_identity(public_key:der_encoded()) -> evatar:peer_cert().
cert_identity(Der) ->
    #{sha256 => string:lowercase(binary:encode_hex(crypto:hash(sha256, Der))),
      cn => common_name(Der)}.

common_name(Der) ->
    try public_key:pkix_decode_cert(Der, otp) of
        #'OTPCertificate'{tbsCertificate = #'OTPTBSCertificate'{subject = {rdnSequence, Rdns}}} ->
            case [V || Rdn <- Rdns,
                       #'AttributeTypeAndValue'{type = ?'id-at-commonName', value = V} <- Rdn] of
                [V | _] -> string_value(V);
                [] -> undefined
            end
    catch _:_ -> undefined
    end.

string_value({utf8String, B}) when is_binary(B) -> B;
string_value({_, S}) when is_list(S) -> unicode:characters_to_binary(S);
string_value({_, B}) when is_binary(B) -> B;
string_value(S) when is_list(S) -> unicode:characters_to_binary(S);
string_value(_) -> undefined.

%% ---------------------------------------------------------------------------
%% The writer
%% ---------------------------------------------------------------------------

%% @doc Starts the writer of a TLS socket (over TCP socket Tcp), linked to
%% the caller. ssl:send/2 waits until TLS has taken the data, so the
%% connection hands frames to this process instead and counts the bytes it
%% has not written yet.
-spec start_writer(ssl:sslsocket(), gen_tcp:socket()) -> writer().
start_writer(SslSock, Tcp) ->
    Inflight = atomics:new(1, []),
    Pid = proc_lib:spawn_link(fun() -> write_loop(SslSock, Inflight) end),
    #writer{pid = Pid, inflight = Inflight, tcp = Tcp}.

%% @doc The connection's send function: false (busy) while more than the
%% high watermark waits in the writer.
-spec send_fun(writer()) -> agent_bridge_outq:send_fun().
send_fun(#writer{pid = Pid, inflight = Inflight}) ->
    fun(Frame) ->
            case atomics:get(Inflight, 1) > ?HIGH_WATERMARK of
                true ->
                    false;
                false ->
                    Size = iolist_size(Frame),
                    ok = atomics:add(Inflight, 1, Size),
                    Pid ! {frame, Frame, Size},
                    true
            end
    end.

%% @doc Half-closes after every frame handed over so far.
-spec shutdown(writer()) -> ok.
shutdown(#writer{pid = Pid}) ->
    Pid ! shutdown,
    ok.

-spec stop_writer(writer()) -> ok.
stop_writer(#writer{pid = Pid}) ->
    unlink(Pid),
    exit(Pid, kill),
    ok.

%% @doc Closes at once, dropping unsent output (linger 0 on the TCP
%% socket under TLS): the peer sees a reset.
-spec abort(ssl:sslsocket(), writer()) -> ok.
abort(SslSock, #writer{tcp = Tcp} = Writer) ->
    ok = stop_writer(Writer),
    _ = inet:setopts(Tcp, [{linger, {true, 0}}]),
    _ = gen_tcp:close(Tcp),
    _ = ssl:close(SslSock),
    ok.

write_loop(SslSock, Inflight) ->
    receive
        {frame, Frame, Size} ->
            case ssl:send(SslSock, Frame) of
                ok ->
                    ok = atomics:sub(Inflight, 1, Size),
                    write_loop(SslSock, Inflight);
                {error, _} ->
                    %% The connection hears of the closed socket itself.
                    ok
            end;
        shutdown ->
            _ = ssl:shutdown(SslSock, write),
            ok
    end.

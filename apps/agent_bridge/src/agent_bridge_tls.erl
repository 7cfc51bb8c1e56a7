%% @doc Internal. TLS for bridge listeners (docs/protocol.md, "TLS"): checks
%% a listener's `tls' options when it starts, upgrades each accepted TCP
%% socket in the connection's own process (so a slow handshake never holds
%% an acceptor), names the verified client certificate, and writes frames
%% through a small writer process so the connection never waits for a peer
%% that stops reading.
-module(agent_bridge_tls).

-export([conn_opts/1, check/1, hardened_opts/1, format_error/1, handshake/3, failure/1, peer_cert/1,
         start_writer/2, send_fun/1, shutdown/1, stop_writer/1, abort/2, cert_identity/1]).

-export_type([tls_opts/0, writer/0]).

-include_lib("public_key/include/public_key.hrl").

%% `verify' defaults to verify_peer when a `cacertfile' is given, else
%% verify_none; `fail_if_no_peer_cert' defaults to true with verify_peer.
%% `revoked_file' names a file of client certificate SHA-256 fingerprints,
%% one a line, refused at the handshake (read at each handshake, so an
%% edit takes effect without a restart; parsed again only when its
%% content changed). A `verify_fun' in `ssl_opts' would replace that
%% check, so the two together are refused. `send_timeout' (ms, default 5000)
%% closes a connection whose peer takes no TLS data for that long.
%% `versions' is a subset of TLS 1.3 and 1.2. The ciphers, groups and
%% renegotiation rule are hardened (hardened_opts/1); `ssl_opts' replace
%% them key by key.
-type tls_opts() :: #{certfile := file:filename_all(),
                      keyfile := file:filename_all(),
                      password => string(),
                      cacertfile => file:filename_all(),
                      revoked_file => file:filename_all(),
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
-define(KEYS, [certfile, keyfile, password, cacertfile, revoked_file, verify,
               fail_if_no_peer_cert, send_timeout, versions, ssl_opts]).
-define(VERSIONS, ['tlsv1.3', 'tlsv1.2']).
%% Mozilla's "intermediate" profile, without its DHE suites: TLS 1.3's
%% AES-GCM and ChaCha20 suites (not CCM), and for TLS 1.2 ECDHE (forward
%% secrecy) with the same AEAD ciphers, on these curves. OTP 25
%% has no x25519 for TLS 1.2 (its eccs option drops it); TLS 1.3 has it.
-define(AEAD, [aes_128_gcm, aes_256_gcm, chacha20_poly1305]).
-define(TLS12_KEX, [ecdhe_ecdsa, ecdhe_rsa]).
-define(GROUPS, [x25519, secp256r1, secp384r1]).
%% OTP 25's default signature algorithms without SHA-1 and SHA-224.
-define(SIGNATURE_ALGS, [eddsa_ed25519, eddsa_ed448, ecdsa_secp521r1_sha512, ecdsa_secp384r1_sha384,
                         ecdsa_secp256r1_sha256, rsa_pss_pss_sha512, rsa_pss_pss_sha384,
                         rsa_pss_pss_sha256, rsa_pss_rsae_sha512, rsa_pss_rsae_sha384,
                         rsa_pss_rsae_sha256, {sha512, ecdsa}, {sha512, rsa}, {sha384, ecdsa},
                         {sha384, rsa}, {sha256, ecdsa}, {sha256, rsa}]).

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
format_error({bad_option, {versions, V}}) ->
    fmt("tls option versions must be a non-empty list of 'tlsv1.3' and 'tlsv1.2', not ~0tp",
        [V]);
format_error({bad_option, {tls, V}}) ->
    fmt("tls must be a map of TLS options, not ~0tp", [V]);
format_error({bad_option, {Key, V}}) ->
    fmt("tls option ~0tp has a bad value: ~0tp", [Key, V]);
format_error({Key, File, no_certificate}) ->
    fmt("tls ~0tp ~ts holds no PEM certificate", [Key, File]);
format_error({Key, File, no_private_key}) ->
    fmt("tls ~0tp ~ts holds no PEM private key", [Key, File]);
format_error({conflict, revoked_file, {ssl_opts, verify_fun}}) ->
    <<"tls ssl_opts verify_fun would replace the revoked_file check: give one of them">>;
format_error({revoked_file, File, {bad_line, N}}) ->
    fmt("tls revoked_file ~ts line ~b is not a SHA-256 fingerprint (64 hex digits)", [File, N]);
format_error({Key, File, Why}) ->
    fmt("tls ~0tp ~ts cannot be read: ~ts", [Key, File, file:format_error(Why)]);
format_error(Other) ->
    fmt("~0tp", [Other]).

fmt(Format, Args) -> iolist_to_binary(io_lib:format(Format, Args)).

check_tls(Tls0) when is_map(Tls0) ->
    %% An empty file name is no file: the release's configuration fills
    %% unset variables in with "".
    Tls = maps:filter(fun(_, V) -> V =/= "" andalso V =/= <<>> end, Tls0),
    Versions = maps:get(versions, Tls, ?VERSIONS),
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
              [{bad_option, {K, V}} || K <- [ssl_opts], V <- [maps:get(K, Tls, [])],
                                       not is_list(V)],
              [{bad_option, {versions, Versions}}
               || not is_list(Versions) orelse Versions =:= []
                      orelse Versions -- ?VERSIONS =/= []],
              [{missing, cacertfile} || is_map_key(revoked_file, Tls),
                                        not is_map_key(cacertfile, Tls)],
              [{conflict, revoked_file, {ssl_opts, verify_fun}}
               || is_map_key(revoked_file, Tls), Extra <- [maps:get(ssl_opts, Tls, [])],
                  is_list(Extra), lists:keymember(verify_fun, 1, Extra)]],
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
    Files = [{K, maps:get(K, Tls)} || K <- [certfile, keyfile, cacertfile, revoked_file],
                                      is_map_key(K, Tls)],
    first_error([check_file(K, F) || {K, F} <- Files]).

check_file(revoked_file, File) ->
    case read_revoked(File) of
        {ok, _} -> ok;
        {error, Why} -> {error, {revoked_file, File, Why}}
    end;
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
    Versions = maps:get(versions, Tls, ?VERSIONS),
    Base = [{certfile, maps:get(certfile, Tls)},
            {keyfile, maps:get(keyfile, Tls)},
            {verify, Verify},
            {versions, Versions}],
    Password = [{password, P} || P <- [maps:get(password, Tls, undefined)], P =/= undefined],
    Peer = case Verify of
               verify_peer -> [{cacertfile, maps:get(cacertfile, Tls)},
                               {fail_if_no_peer_cert, maps:get(fail_if_no_peer_cert, Tls, true)}];
               verify_none -> []
           end,
    Revoked = [{verify_fun, {fun verify_revoked/3, File}}
               || Verify =:= verify_peer, File <- [maps:get(revoked_file, Tls, undefined)],
                  File =/= undefined],
    Extra = maps:get(ssl_opts, Tls, []),
    Defaults = [O || {K, _} = O <- hardened_opts(Versions) ++ Revoked,
                     not lists:keymember(K, 1, Extra)],
    Base ++ Password ++ Peer ++ Defaults ++ Extra.

%% @doc The ssl options of the default profile for Versions: TLS 1.3's
%% suites and Mozilla "intermediate" TLS 1.2 (ECDHE with AES-GCM or
%% ChaCha20-Poly1305 only: forward secrecy, no CBC, no SHA-1 MAC, no static
%% ECDH or RSA key exchange), the curves x25519 (TLS 1.3), secp256r1 and
%% secp384r1, no SHA-1 signatures, the server's order, and no
%% renegotiation started by the client.
-spec hardened_opts([ssl:protocol_version()]) -> [ssl:tls_server_option()].
hardened_opts(Versions) ->
    Kex = [any || lists:member('tlsv1.3', Versions)]
        ++ [K || lists:member('tlsv1.2', Versions), K <- ?TLS12_KEX],
    %% All of TLS 1.3 and 1.2, filtered.
    Suites = [S || #{key_exchange := K, cipher := C} = S <- ssl:cipher_suites(all, 'tlsv1.3'),
                   lists:member(K, Kex), lists:member(C, ?AEAD)],
    %% ssl refuses an option of a version it does not offer.
    Tls13 = [{supported_groups, ?GROUPS} || lists:member('tlsv1.3', Versions)],
    Tls12 = [O || lists:member('tlsv1.2', Versions),
                  O <- [{eccs, [C || C <- ?GROUPS, C =/= x25519]},
                        {honor_ecc_order, true},
                        {secure_renegotiate, true},
                        {client_renegotiation, false}]],
    [{ciphers, Suites}, {signature_algs, ?SIGNATURE_ALGS}, {honor_cipher_order, true}]
        ++ Tls13 ++ Tls12.

%% The verify_fun of a listener with a revoked_file: the default checks,
%% then the client certificate's fingerprint against the file, read at
%% each handshake. A file that cannot be read refuses every certificate.
verify_revoked(_, {bad_cert, _} = Reason, _) ->
    {fail, Reason};
verify_revoked(_, {extension, _}, File) ->
    {unknown, File};
verify_revoked(_, valid, File) ->
    {valid, File};
verify_revoked(Cert, valid_peer, File) ->
    Sha = fingerprint(public_key:pkix_encode('OTPCertificate', Cert, otp)),
    case revoked_set(File) of
        {ok, Revoked} ->
            case is_map_key(Sha, Revoked) of
                %% ssl's alert for this reason is certificate_revoked.
                true -> {fail, {bad_cert, {revoked, revoked_file}}};
                false -> {valid, File}
            end;
        {error, _} ->
            {fail, {bad_cert, {revocation_status_undetermined, revoked_file_unreadable}}}
    end.

%% The fingerprints of File as a set, parsed again only when the file's
%% content differs from the last parsed (kept per file in a persistent
%% term: an edit rewrites it once; a handshake reads the file and compares
%% it, so a list of thousands costs one read, not a parse and a scan).
revoked_set(File) ->
    Key = {?MODULE, revoked, File},
    case file:read_file(File) of
        {ok, Text} ->
            case persistent_term:get(Key, undefined) of
                {Text, Set} ->
                    {ok, Set};
                _ ->
                    case parse_revoked(Text) of
                        {ok, List} ->
                            Set = maps:from_keys(List, []),
                            persistent_term:put(Key, {Text, Set}),
                            {ok, Set};
                        {error, _} = Error ->
                            Error
                    end
            end;
        {error, _} = Error ->
            Error
    end.

%% The fingerprints of a revoked_file: one a line, hex in either case,
%% colons allowed; blank lines and lines starting with # are skipped.
read_revoked(File) ->
    case file:read_file(File) of
        {ok, Text} -> parse_revoked(Text);
        {error, _} = Error -> Error
    end.

parse_revoked(Text) ->
    Lines = binary:split(Text, <<"\n">>, [global]),
    parse_revoked(lists:zip(lists:seq(1, length(Lines)), Lines), []).

parse_revoked([], Acc) ->
    {ok, Acc};
parse_revoked([{N, Line0} | Rest], Acc) ->
    Line = string:trim(Line0),
    case Line of
        <<>> -> parse_revoked(Rest, Acc);
        <<"#", _/binary>> -> parse_revoked(Rest, Acc);
        _ ->
            Hex = string:lowercase(binary:replace(Line, <<":">>, <<>>, [global])),
            case byte_size(Hex) =:= 64 andalso is_hex(Hex) of
                true -> parse_revoked(Rest, [Hex | Acc]);
                false -> {error, {bad_line, N}}
            end
    end.

is_hex(Bin) -> lists:all(fun(C) -> (C >= $0 andalso C =< $9) orelse (C >= $a andalso C =< $f) end,
                         binary_to_list(Bin)).

fingerprint(Der) -> string:lowercase(binary:encode_hex(crypto:hash(sha256, Der))).

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
    #{sha256 => fingerprint(Der), cn => common_name(Der)}.

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

%% @doc Test helper: runs a real mosquitto broker as an OS process on a free
%% loopback port, with a generated config (persistence, TLS listener, password
%% file) in a temporary directory. Shared by every suite that needs a broker
%% (mqtt_client, mqtt_avatar, avatar_sim, root test/); in the test kit since
%% it serves suites of several apps.
-module(evatar_test_mosquitto).

-export([start/0, start/1, stop/1, kill/2, restart/1, log/1, available/0]).

-export_type([broker/0, opts/0]).

-type opts() :: #{persistence => boolean(),
                  tls => boolean(),
                  cert_tool => openssl | public_key,
                  nodelay => boolean(),
                  users => [{binary() | string(), binary() | string()}],
                  allow_anonymous => boolean(),
                  extra_config => [iodata()],
                  port => inet:port_number(),
                  tls_port => inet:port_number(),
                  dir => file:filename()}.
%% `nodelay' (default true) sets mosquitto's `set_tcp_nodelay'. `cert_tool' picks how the TLS test CA is made (openssl falls back to
%% public_key when the binary is missing). `users' writes a password file; anonymous access is then off unless
%% `allow_anonymous => true'. `extra_config' lines are appended verbatim.

-type broker() :: #{port := inet:port_number(),
                    pid := pos_integer(),
                    dir := file:filename(),
                    keeper := pid(),
                    opts := opts(),
                    tls_port => inet:port_number(),
                    cacertfile => file:filename()}.

-define(MOSQUITTO, "/usr/sbin/mosquitto").
-define(READY_TIMEOUT, 10000).

%% @doc True when the mosquitto binary is installed.
-spec available() -> boolean().
available() ->
    mosquitto() =/= false.

%% @doc Starts a broker with default options (anonymous, no persistence).
-spec start() -> {ok, broker()} | {error, term()}.
start() ->
    start(#{}).

%% @doc Starts mosquitto and waits until its listeners accept connections.
-spec start(opts()) -> {ok, broker()} | {error, term()}.
start(Opts) ->
    case mosquitto() of
        false ->
            {error, mosquitto_not_installed};
        Exe ->
            Dir = case Opts of
                      #{dir := D} ->
                          ok = filelib:ensure_dir(filename:join(D, "x")),
                          D;
                      _ ->
                          make_dir()
                  end,
            Port = maps:get(port, Opts, free_port()),
            Tls = maps:get(tls, Opts, false),
            TlsPort = case Tls of
                          true -> maps:get(tls_port, Opts, free_port());
                          false -> undefined
                      end,
            Opts1 = Opts#{dir => Dir, port => Port},
            Opts2 = case TlsPort of
                        undefined -> Opts1;
                        _ -> Opts1#{tls_port => TlsPort}
                    end,
            ok = write_files(Dir, Opts2),
            launch(Exe, Dir, Opts2)
    end.

%% @doc Kills the broker with SIGKILL, waits until the process is gone and
%% removes its directory.
-spec stop(broker()) -> ok.
stop(#{dir := Dir} = Broker) ->
    ok = kill(Broker, kill),
    _ = file:del_dir_r(Dir),
    ok.

%% @doc Sends a real signal (`term' lets mosquitto save its persistence
%% file, `kill' does not) and waits for the process to exit. The directory
%% is kept: `start(maps:get(opts, Broker))' brings the broker back on the
%% same ports with the same persistence file.
-spec kill(broker(), term | kill | int) -> ok.
kill(#{pid := Pid, keeper := Keeper}, Signal) ->
    %% A dead keeper means this broker was already stopped: its OS pid may
    %% belong to another process by now.
    case is_process_alive(Keeper) of
        true -> kill(Pid, Keeper, Signal);
        false -> ok
    end.

kill(Pid, Keeper, Signal) ->
    Sig = case Signal of
              term -> "TERM";
              kill -> "KILL";
              int -> "INT"
          end,
    _ = os:cmd(io_lib:format("kill -~s ~b 2>/dev/null", [Sig, Pid])),
    case wait_exit(Pid, 100) of
        ok ->
            ok;
        {error, still_running} ->
            _ = os:cmd(io_lib:format("kill -KILL ~b 2>/dev/null", [Pid])),
            ok = wait_exit(Pid, 100)
    end,
    Keeper ! stop,
    ok.

%% @doc Stops the broker gracefully (SIGTERM, so persistence is written) and
%% starts it again on the same ports with the same directory and config.
-spec restart(broker()) -> {ok, broker()} | {error, term()}.
restart(#{opts := Opts} = Broker) ->
    ok = kill(Broker, term),
    start(Opts).

%% @doc The broker's log file contents.
-spec log(broker()) -> binary().
log(#{dir := Dir}) ->
    case file:read_file(filename:join(Dir, "mosquitto.log")) of
        {ok, Bin} -> Bin;
        {error, _} -> <<>>
    end.

%% Internal

mosquitto() ->
    case filelib:is_regular(?MOSQUITTO) of
        true -> ?MOSQUITTO;
        false -> os:find_executable("mosquitto")
    end.

make_dir() ->
    Base = case os:getenv("TMPDIR") of
               false -> "/tmp";
               T -> T
           end,
    Name = io_lib:format("evatar_test_mosquitto_~s_~b",
                         [os:getpid(), erlang:unique_integer([positive])]),
    Dir = filename:join(Base, lists:flatten(Name)),
    ok = filelib:ensure_dir(filename:join(Dir, "x")),
    Dir.

free_port() ->
    {ok, S} = gen_tcp:listen(0, [{ip, {127, 0, 0, 1}}, {reuseaddr, true}]),
    {ok, Port} = inet:port(S),
    ok = gen_tcp:close(S),
    Port.

write_files(Dir, Opts) ->
    Users = maps:get(users, Opts, []),
    Anonymous = maps:get(allow_anonymous, Opts, Users =:= []),
    PassLines = case Users of
                    [] -> [];
                    _ ->
                        PassFile = filename:join(Dir, "passwd"),
                        ok = write_passwords(PassFile, Users),
                        ["password_file ", PassFile, "\n"]
                end,
    Persist = case maps:get(persistence, Opts, false) of
                  true ->
                      ["persistence true\n",
                       "persistence_location ", Dir, "/\n",
                       "autosave_interval 1\n"];
                  false ->
                      ["persistence false\n"]
              end,
    TlsLines = case Opts of
                   #{tls_port := TlsPort} ->
                       {CaFile, CertFile, KeyFile} = ensure_cert(Dir, maps:get(cert_tool, Opts, openssl)),
                       ["listener ", integer_to_list(TlsPort), " 127.0.0.1\n",
                        "cafile ", CaFile, "\n",
                        "certfile ", CertFile, "\n",
                        "keyfile ", KeyFile, "\n"];
                   _ ->
                       []
               end,
    User = case os:getenv("USER") of
               false -> current_user();
               U -> U
           end,
    Conf = ["# generated by evatar_test_mosquitto (test helper)\n",
            "user ", User, "\n",
            "per_listener_settings false\n",
            "allow_anonymous ", atom_to_list(Anonymous), "\n",
            PassLines,
            Persist,
            "log_dest file ", filename:join(Dir, "mosquitto.log"), "\n",
            "log_type error\nlog_type warning\nlog_type notice\n",
            "connection_messages true\n",
            "max_queued_messages 100000\n",
            %% Without it mosquitto's Nagle meets the peer's delayed ACK and a
            %% request/response round trip takes 40 ms.
            "set_tcp_nodelay ", atom_to_list(maps:get(nodelay, Opts, true)), "\n",
            "listener ", integer_to_list(maps:get(port, Opts)), " 127.0.0.1\n",
            TlsLines,
            [[L, "\n"] || L <- maps:get(extra_config, Opts, [])]],
    file:write_file(filename:join(Dir, "mosquitto.conf"), Conf).

current_user() ->
    string:trim(os:cmd("id -un")).

write_passwords(File, Users) ->
    ok = file:write_file(File, <<>>),
    case os:find_executable("mosquitto_passwd") of
        false ->
            file:write_file(File, [pbkdf2_line(U, P) || {U, P} <- Users]);
        Exe ->
            lists:foreach(
              fun({U, P}) ->
                      Out = os:cmd(lists:flatten(
                                     io_lib:format("~s -b '~s' '~s' '~s' 2>&1",
                                                   [Exe, File, to_list(U), to_list(P)]))),
                      case Out of
                          "" -> ok;
                          _ -> io:format(user, "mosquitto_passwd: ~s~n", [Out])
                      end
              end, Users)
    end.

%% mosquitto 2.x "$7$" format: PBKDF2-HMAC-SHA512, 101 iterations.
pbkdf2_line(User, Pass) ->
    Salt = crypto:strong_rand_bytes(12),
    Hash = crypto:pbkdf2_hmac(sha512, to_bin(Pass), Salt, 101, 64),
    [to_bin(User), ":$7$101$", base64:encode(Salt), "$", base64:encode(Hash), "\n"].

to_list(B) when is_binary(B) -> binary_to_list(B);
to_list(L) -> L.

to_bin(B) when is_binary(B) -> B;
to_bin(L) -> list_to_binary(L).

%% A test CA and a server certificate it signs (CN=localhost, SAN IP
%% 127.0.0.1 and DNS localhost); clients verify with the CA as cacertfile.
ensure_cert(Dir, Tool) ->
    Ca = filename:join(Dir, "ca.pem"),
    Cert = filename:join(Dir, "cert.pem"),
    Key = filename:join(Dir, "key.pem"),
    case lists:all(fun filelib:is_regular/1, [Ca, Cert, Key]) of
        true -> ok;
        false -> ok = make_cert(Dir, Ca, Cert, Key, Tool)
    end,
    {Ca, Cert, Key}.

make_cert(Dir, Ca, Cert, Key, Tool) ->
    case Tool =:= openssl andalso os:find_executable("openssl") of
        false ->
            make_cert_public_key(Ca, Cert, Key);
        OpenSsl ->
            CaKey = filename:join(Dir, "ca.key"),
            Csr = filename:join(Dir, "server.csr"),
            Ext = filename:join(Dir, "server.ext"),
            ok = file:write_file(Ext, "subjectAltName=IP:127.0.0.1,DNS:localhost\n"),
            EcKey = "-newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes",
            Cmds = [io_lib:format("'~s' req -x509 ~s -keyout '~s' -out '~s' -days 2 "
                                  "-subj '/CN=evatar_test_mosquitto test CA'", [OpenSsl, EcKey, CaKey, Ca]),
                    io_lib:format("'~s' req ~s -keyout '~s' -out '~s' -subj /CN=localhost",
                                  [OpenSsl, EcKey, Key, Csr]),
                    io_lib:format("'~s' x509 -req -in '~s' -CA '~s' -CAkey '~s' "
                                  "-CAcreateserial -out '~s' -days 2 -extfile '~s'",
                                  [OpenSsl, Csr, Ca, CaKey, Cert, Ext])],
            lists:foreach(fun(C) -> os:cmd(lists:flatten(C) ++ " 2>/dev/null") end, Cmds),
            case filelib:is_regular(Cert) of
                true -> ok;
                false -> make_cert_public_key(Ca, Cert, Key)
            end
    end.

make_cert_public_key(Ca, Cert, Key) ->
    Curve = [{key, {namedCurve, secp256r1}}, {digest, sha256}],
    San = {'Extension', {2, 5, 29, 17}, false,
           [{iPAddress, [127, 0, 0, 1]}, {dNSName, "localhost"}]},
    %% The root made by pkix_test_data itself (a root of
    %% pkix_test_root_cert/2 breaks pkix_test_data/1's contract in OTP 25,
    %% for dialyzer): the server's CAs are both roots, and the server
    %% root ("SERVER ROOT CA") is the one that issued its certificate.
    Data = public_key:pkix_test_data(
             #{server_chain => #{root => Curve, peer => [{extensions, [San]} | Curve]},
               client_chain => #{root => Curve, peer => Curve}}),
    #{server_config := ServerOpts} = Data,
    PeerDer = proplists:get_value(cert, ServerOpts),
    [RootDer] = [C || C <- proplists:get_value(cacerts, ServerOpts),
                      public_key:pkix_is_issuer(PeerDer, C)],
    {KeyType, KeyDer} = proplists:get_value(key, ServerOpts),
    ok = file:write_file(Ca, public_key:pem_encode([{'Certificate', RootDer, not_encrypted}])),
    ok = file:write_file(Cert, public_key:pem_encode([{'Certificate', PeerDer, not_encrypted}])),
    file:write_file(Key, public_key:pem_encode([{KeyType, KeyDer, not_encrypted}])).

launch(Exe, Dir, Opts) ->
    Conf = filename:join(Dir, "mosquitto.conf"),
    Out = filename:join(Dir, "mosquitto.out"),
    Parent = self(),
    %% The keeper owns a shell that runs mosquitto in the background and kills
    %% it when its stdin closes, so the broker dies with this Erlang node.
    Keeper = spawn(fun() -> keeper(Parent, Exe, Conf, Out) end),
    receive
        {Keeper, {os_pid, Pid}} ->
            Broker0 = #{port => maps:get(port, Opts), pid => Pid, dir => Dir,
                        keeper => Keeper, opts => Opts},
            Broker = case Opts of
                         #{tls_port := TlsPort} ->
                             Broker0#{tls_port => TlsPort,
                                      cacertfile => filename:join(Dir, "ca.pem")};
                         _ ->
                             Broker0
                     end,
            Ports = [maps:get(port, Opts) | [P || #{tls_port := P} <- [Opts]]],
            case wait_ready(Pid, Ports, ?READY_TIMEOUT div 50) of
                ok ->
                    {ok, Broker};
                {error, Reason} ->
                    ok = stop(Broker),
                    {error, {Reason, log(Broker)}}
            end;
        {Keeper, {error, Reason}} ->
            {error, Reason}
    after ?READY_TIMEOUT ->
            exit(Keeper, kill),
            {error, keeper_timeout}
    end.

keeper(Parent, Exe, Conf, Out) ->
    Script = "\"$1\" -c \"$2\" >>\"$3\" 2>&1 & echo $!; read dummy; kill -9 $! 2>/dev/null",
    Port = open_port({spawn_executable, "/bin/sh"},
                     [{args, ["-c", Script, "sh", Exe, Conf, Out]},
                      {line, 256}, binary, exit_status]),
    receive
        {Port, {data, {eol, Line}}} ->
            Parent ! {self(), {os_pid, binary_to_integer(string:trim(Line))}},
            keeper_loop(Port)
    after ?READY_TIMEOUT ->
            Parent ! {self(), {error, no_pid}}
    end.

keeper_loop(Port) ->
    receive
        stop ->
            catch port_close(Port),
            ok;
        {Port, {exit_status, _}} ->
            ok;
        {Port, _} ->
            keeper_loop(Port)
    end.

wait_ready(_Pid, _Ports, 0) ->
    {error, broker_not_ready};
wait_ready(Pid, Ports, N) ->
    case alive(Pid) of
        false ->
            {error, broker_exited};
        true ->
            case lists:all(fun can_connect/1, Ports) of
                true ->
                    ok;
                false ->
                    timer:sleep(50),
                    wait_ready(Pid, Ports, N - 1)
            end
    end.

can_connect(Port) ->
    case gen_tcp:connect({127, 0, 0, 1}, Port, [], 500) of
        {ok, S} ->
            ok = gen_tcp:close(S),
            true;
        {error, _} ->
            false
    end.

alive(Pid) ->
    %% A zombie (state Z) counts as gone: the shell reaps it later.
    case os:cmd(io_lib:format("ps -o stat= -p ~b", [Pid])) of
        "" -> false;
        [$Z | _] -> false;
        _ -> true
    end.

wait_exit(_Pid, 0) ->
    {error, still_running};
wait_exit(Pid, N) ->
    case alive(Pid) of
        false ->
            ok;
        true ->
            timer:sleep(50),
            wait_exit(Pid, N - 1)
    end.

%% @doc Internal to the broker comparison (broker_bench): starts and stops
%% the systems under test as OS processes of their own, listening on
%% 127.0.0.1 on free ports, and reads their CPU time and memory from /proc.
%%
%% - `evatar': a separate `erl' node (a peer, started with the emulator
%%   flags of config/vm.args plus RabbitMQ's `+sbwt none'), running the
%%   evatar and agent_bridge applications with one bridge listener;
%% - `mosquitto': /usr/sbin/mosquitto with a generated config
%%   (`set_tcp_nodelay true', no persistence, anonymous);
%% - `rabbitmq': the Debian package's rabbitmq-server as its own instance
%%   (own base, Mnesia, log directories, node name, AMQP and distribution
%%   ports, enabled-plugins file with rabbitmq_mqtt only), run as the
%%   current user with HOME in its directory so its cookie is its own;
%% - `nats': /usr/sbin/nats-server (core NATS, no JetStream, no
%%   authentication), its log file in its directory.
%%
%% With `{transport, tls}' in the configuration, EVATAR's bridge listener
%% and mosquitto's listener are TLS listeners with the same server
%% certificate and key (`tls_dir' in the configuration, made by
%% scripts/gen-bridge-certs.sh); the sut's `tls' says what a client needs
%% (the CA file), false over TCP.
%%
%% Every started OS pid is written to RunDir/NAME.pid, so that
%% scripts/bench-brokers.sh can kill what a crashed run left behind.
-module(broker_bench_sut).

-export([start/3, stop/1, cpu_ticks/1, memory_kib/1, versions/0, profile_node/3,
         evatar_rev/0]).

-export_type([sut/0, system/0]).

-type system() :: evatar | mosquitto | rabbitmq | nats.
-type sut() :: #{system := system(), os_pid := string(), host := inet:ip_address(),
                 port := inet:port_number(), dir := file:filename(),
                 tls := false | #{cacertfile := file:filename()},
                 node => node(), peer => pid(), port_ref => port(),
                 rabbit_env => [{string(), string()}], rabbit_node => string()}.

-define(MOSQUITTO, "/usr/sbin/mosquitto").
-define(RABBIT_BIN, "/usr/lib/rabbitmq/bin/").
-define(NATS, "/usr/sbin/nats-server").
-define(READY_TIMEOUT_MS, 180000).

%% @doc Starts System with its files under RunDir. Crashes when the system
%% cannot be started: a comparison without it would mislead.
-spec start(system(), file:filename(), map()) -> sut().
start(evatar, RunDir, Cfg) ->
    OtpLib = code:lib_dir(),
    Paths = [P || P <- code:get_path(), not lists:prefix(OtpLib, P)],
    %% config/vm.args (+K true +A 8) and RabbitMQ's default of no busy
    %% waiting, so neither BEAM system is charged for spinning schedulers.
    Args = ["+K", "true", "+A", "8", "+sbwt", "none", "+sbwtdcpu", "none", "+sbwtdio", "none",
            "+P", "2000000", "+Q", "1000000", "-kernel", "logger_level", "warning",
            %% No default listener: the benchmark's own, on a free port.
            "-agent_bridge", "listeners", "[]"]
        ++ maps:get(evatar_args, Cfg, [])
        ++ lists:append([["-pa", P] || P <- Paths]),
    {ok, Peer, Node} = peer:start_link(#{name => peer:random_name(broker_bench_evatar),
                                         args => Args, wait_boot => 60000}),
    OsPid = erpc:call(Node, os, getpid, []),
    ok = write_pid(RunDir, evatar, OsPid),
    {ok, _} = erpc:call(Node, application, ensure_all_started, [evatar]),
    {ok, _} = erpc:call(Node, application, ensure_all_started, [agent_bridge]),
    Tls = case tls_files(Cfg) of
              {tls, F} -> #{tls => #{certfile => F("server.pem"), keyfile => F("server.key")}};
              tcp -> #{}
          end,
    {ok, _} = erpc:call(Node, agent_bridge, start_listener,
                        [broker_bench, Tls#{ip => {127, 0, 0, 1}, port => 0,
                                         acceptors => 8, backlog => 4096,
                                         %% mosquitto runs with max_connections -1
                                         max_connections => infinity,
                                         handshake => #{rate => infinity},
                                         %% and has no per-client rate
                                         conn => #{max_read_rate => infinity}}]),
    {ok, {Ip, Port}} = erpc:call(Node, agent_bridge, address, [broker_bench]),
    #{system => evatar, os_pid => OsPid, host => Ip, port => Port, dir => RunDir,
      tls => client_tls(Cfg), node => Node, peer => Peer};
start(mosquitto, RunDir, Cfg) ->
    Dir = filename:join(RunDir, "mosquitto"),
    ok = filelib:ensure_dir(filename:join(Dir, "x")),
    Port = free_port(),
    Conf = filename:join(Dir, "mosquitto.conf"),
    ok = file:write_file(Conf, ["listener ", integer_to_list(Port), " 127.0.0.1\n"
                                "allow_anonymous true\n"
                                "set_tcp_nodelay true\n"
                                "persistence false\n"
                                "max_connections -1\n"
                                "log_dest file ", filename:join(Dir, "mosquitto.log"), "\n"
                                "log_type error\nlog_type warning\n",
                                [["certfile ", F("server.pem"), "\n"
                                  "keyfile ", F("server.key"), "\n"
                                  %% Started by root, mosquitto becomes user
                                  %% mosquitto before it reads the key, which
                                  %% is the run's own, mode 0600, in a 0700
                                  %% directory: it stays who started it.
                                  "user ", string:trim(os:cmd("id -un")), "\n"]
                                 || {tls, F} <- [tls_files(Cfg)]]]),
    P = open_port({spawn_executable, ?MOSQUITTO},
                  [{args, ["-c", Conf]}, exit_status, stderr_to_stdout, binary]),
    {os_pid, OsPid} = erlang:port_info(P, os_pid),
    ok = write_pid(RunDir, mosquitto, integer_to_list(OsPid)),
    ok = await_listening(Port, ?READY_TIMEOUT_MS div 10),
    #{system => mosquitto, os_pid => integer_to_list(OsPid), host => {127, 0, 0, 1},
      port => Port, dir => Dir, tls => client_tls(Cfg), port_ref => P};
start(nats, RunDir, _Cfg) ->
    Dir = filename:join(RunDir, "nats"),
    ok = filelib:ensure_dir(filename:join(Dir, "x")),
    Port = free_port(),
    P = open_port({spawn_executable, ?NATS},
                  [{args, ["-a", "127.0.0.1", "-p", integer_to_list(Port),
                           "-l", filename:join(Dir, "nats.log")]},
                   exit_status, stderr_to_stdout, binary]),
    {os_pid, OsPid} = erlang:port_info(P, os_pid),
    ok = write_pid(RunDir, nats, integer_to_list(OsPid)),
    ok = await_listening(Port, ?READY_TIMEOUT_MS div 10),
    #{system => nats, os_pid => integer_to_list(OsPid), host => {127, 0, 0, 1},
      port => Port, dir => Dir, tls => false, port_ref => P};
start(rabbitmq, RunDir, _Cfg) ->
    Dir = filename:join(RunDir, "rabbitmq-" ++ integer_to_list(erlang:unique_integer([positive]))),
    Home = filename:join(Dir, "home"),
    _ = [ok = filelib:ensure_dir(filename:join(D, "x"))
         || D <- [Home, filename:join(Dir, "mnesia"), filename:join(Dir, "log")]],
    [Amqp, Dist, Mqtt] = free_ports(3),
    Node = "broker_bench_rabbit_" ++ os:getpid() ++ "@localhost",
    ok = file:write_file(filename:join(Dir, "rabbitmq.conf"),
                         ["listeners.tcp.1 = 127.0.0.1:", integer_to_list(Amqp), "\n"
                          "mqtt.listeners.tcp.1 = 127.0.0.1:", integer_to_list(Mqtt), "\n"
                          "mqtt.allow_anonymous = true\n"
                          %% the plugin's default; said here as for mosquitto
                          "mqtt.tcp_listen_options.nodelay = true\n"
                          "log.file.level = warning\n"
                          "log.console = false\n"]),
    ok = file:write_file(filename:join(Dir, "enabled_plugins"), "[rabbitmq_mqtt].\n"),
    ok = file:write_file(filename:join(Dir, "rabbitmq-env.conf"), ""),
    PidFile = filename:join(Dir, "rabbitmq.pid"),
    Env = [{"HOME", Home},
           {"RABBITMQ_BASE", Dir},
           {"RABBITMQ_CONFIG_FILE", filename:join(Dir, "rabbitmq.conf")},
           {"RABBITMQ_CONF_ENV_FILE", filename:join(Dir, "rabbitmq-env.conf")},
           {"RABBITMQ_MNESIA_BASE", filename:join(Dir, "mnesia")},
           {"RABBITMQ_LOG_BASE", filename:join(Dir, "log")},
           {"RABBITMQ_NODENAME", Node},
           {"RABBITMQ_NODE_IP_ADDRESS", "127.0.0.1"},
           {"RABBITMQ_NODE_PORT", integer_to_list(Amqp)},
           {"RABBITMQ_DIST_PORT", integer_to_list(Dist)},
           {"RABBITMQ_ENABLED_PLUGINS_FILE", filename:join(Dir, "enabled_plugins")},
           {"RABBITMQ_PID_FILE", PidFile},
           {"RABBITMQ_SERVER_ADDITIONAL_ERL_ARGS",
            "-kernel inet_dist_use_interface {127,0,0,1}"}],
    P = open_port({spawn_executable, ?RABBIT_BIN ++ "rabbitmq-server"},
                  [{env, Env}, {cd, Dir}, exit_status, stderr_to_stdout, binary]),
    Wait = rabbitmqctl(Env, Node, ["wait", PidFile, "--timeout",
                                   integer_to_list(?READY_TIMEOUT_MS div 1000)]),
    {ok, PidBin} = file:read_file(PidFile),
    OsPid = string:trim(binary_to_list(PidBin)),
    ok = write_pid(RunDir, rabbitmq, OsPid),
    case await_listening(Mqtt, 30000) of
        ok -> ok;
        {error, _} = E -> error({rabbitmq_mqtt_not_listening, E, Wait})
    end,
    #{system => rabbitmq, os_pid => OsPid, host => {127, 0, 0, 1}, port => Mqtt, dir => Dir,
      tls => false, port_ref => P, rabbit_env => Env, rabbit_node => Node}.

%% @doc Stops the system and waits for its OS process to be gone.
-spec stop(sut()) -> ok.
stop(#{system := evatar, peer := Peer, os_pid := OsPid, dir := RunDir}) ->
    _ = catch peer:stop(Peer),
    ok = await_gone(OsPid),
    _ = file:delete(pid_file(RunDir, evatar)),
    ok;
stop(#{system := Sys, os_pid := OsPid, port_ref := P, dir := Dir})
  when Sys =:= mosquitto; Sys =:= nats ->
    _ = os:cmd("kill -TERM " ++ OsPid),
    ok = await_gone(OsPid),
    _ = catch port_close(P),
    _ = file:delete(pid_file(filename:dirname(Dir), Sys)),
    ok;
stop(#{system := rabbitmq, os_pid := OsPid, port_ref := P, dir := Dir, rabbit_env := Env,
       rabbit_node := Node}) ->
    _ = rabbitmqctl(Env, Node, ["stop", filename:join(Dir, "rabbitmq.pid")]),
    case await_gone(OsPid, 100) of
        ok -> ok;
        {error, still_running} ->
            _ = os:cmd("kill -KILL " ++ OsPid),
            ok = await_gone(OsPid)
    end,
    _ = catch port_close(P),
    _ = file:delete(pid_file(filename:dirname(Dir), rabbitmq)),
    ok.

%% Over TLS, a fun from a file name in the certificate directory to its
%% path.
tls_files(#{transport := tls, tls_dir := Dir}) ->
    {tls, fun(Name) -> filename:join(Dir, Name) end};
tls_files(_) ->
    tcp.

client_tls(#{transport := tls, tls_dir := Dir}) ->
    #{cacertfile => filename:join(Dir, "ca.pem")};
client_tls(_) ->
    false.

rabbitmqctl(Env, Node, Args) ->
    Cmd = lists:flatten(
            ["env ", [[K, "='", V, "' "] || {K, V} <- Env],
             ?RABBIT_BIN, "rabbitmqctl -n '", Node, "' ",
             lists:join(" ", ["'" ++ A ++ "'" || A <- Args]), " 2>&1"]),
    os:cmd(Cmd).

write_pid(RunDir, Name, OsPid) ->
    file:write_file(pid_file(RunDir, Name), [OsPid, "\n"]).

pid_file(RunDir, Name) ->
    filename:join(RunDir, atom_to_list(Name) ++ ".pid").

await_gone(OsPid) ->
    case await_gone(OsPid, 300) of
        ok -> ok;
        {error, still_running} -> error({still_running, OsPid})
    end.

await_gone(_OsPid, 0) ->
    {error, still_running};
await_gone(OsPid, Tries) ->
    case filelib:is_dir("/proc/" ++ OsPid) andalso not zombie(OsPid) of
        false -> ok;
        true -> timer:sleep(100), await_gone(OsPid, Tries - 1)
    end.

zombie(OsPid) ->
    case file:read_file("/proc/" ++ OsPid ++ "/stat") of
        {ok, Stat} ->
            [_, After] = binary:split(Stat, <<") ">>),
            binary:first(After) =:= $Z;
        {error, _} ->
            true
    end.

await_listening(Port, Ms) when Ms =< 0 ->
    {error, {not_listening, Port}};
await_listening(Port, Ms) ->
    case gen_tcp:connect({127, 0, 0, 1}, Port, [], 1000) of
        {ok, S} ->
            gen_tcp:close(S);
        {error, _} ->
            timer:sleep(100),
            await_listening(Port, Ms - 100)
    end.

free_port() ->
    [P] = free_ports(1),
    P.

%% Distinct free loopback ports, all held open until all are picked.
free_ports(K) ->
    Socks = [begin
                 {ok, S} = gen_tcp:listen(0, [{ip, {127, 0, 0, 1}}]),
                 S
             end || _ <- lists:seq(1, K)],
    Ports = [element(2, inet:port(S)) || S <- Socks],
    _ = [gen_tcp:close(S) || S <- Socks],
    Ports.

%% ---------------------------------------------------------------------------
%% /proc
%% ---------------------------------------------------------------------------

%% @doc User plus system clock ticks (1/100 s) of an OS process.
-spec cpu_ticks(string()) -> non_neg_integer().
cpu_ticks(OsPid) ->
    {ok, Stat} = file:read_file("/proc/" ++ OsPid ++ "/stat"),
    [_, AfterComm] = binary:split(Stat, <<") ">>),
    Fields = binary:split(AfterComm, <<" ">>, [global]),
    %% utime and stime are fields 14 and 15; 12 and 13 after the comm.
    binary_to_integer(lists:nth(12, Fields)) + binary_to_integer(lists:nth(13, Fields)).

%% @doc Resident set size now and its peak (VmRSS, VmHWM), in KiB.
-spec memory_kib(string()) -> #{rss := non_neg_integer(), hwm := non_neg_integer()}.
memory_kib(OsPid) ->
    {ok, Status} = file:read_file("/proc/" ++ OsPid ++ "/status"),
    Lines = binary:split(Status, <<"\n">>, [global]),
    Get = fun(Key) ->
                  [V] = [V || L <- Lines, [K, V] <- [binary:split(L, <<":">>)], K =:= Key],
                  [Num | _] = string:lexemes(V, " \t"),
                  binary_to_integer(Num)
          end,
    #{rss => Get(<<"VmRSS">>), hwm => Get(<<"VmHWM">>)}.

%% ---------------------------------------------------------------------------
%% Versions
%% ---------------------------------------------------------------------------

%% @doc Versions of everything compared.
-spec versions() -> map().
versions() ->
    Mosq = case os:cmd(?MOSQUITTO ++ " -h 2>&1") of
               "mosquitto version " ++ Rest -> hd(string:lexemes(Rest, " \n"));
               _ -> "unknown"
           end,
    Rabbit = case string:trim(os:cmd(?RABBIT_BIN ++ "rabbitmqctl version 2>/dev/null")) of
                 "" -> "unknown";
                 V -> lists:last(string:lexemes(V, "\n"))
             end,
    Nats = case os:cmd(?NATS ++ " --version 2>&1") of
               "nats-server: v" ++ NRest -> string:trim(NRest);
               _ -> "unknown"
           end,
    #{otp => list_to_binary(erlang:system_info(otp_release)),
      erts => list_to_binary(erlang:system_info(version)),
      mosquitto => list_to_binary(Mosq),
      rabbitmq => list_to_binary(Rabbit),
      nats => list_to_binary(Nats),
      evatar => evatar_rev()}.

%% @doc The git revision of the EVATAR tree being measured, `-dirty' when
%% it has uncommitted changes.
-spec evatar_rev() -> binary().
evatar_rev() ->
    Rev = string:trim(os:cmd("git rev-parse --short HEAD 2>/dev/null")),
    Dirty = case string:trim(os:cmd("git status --porcelain --untracked-files=no 2>/dev/null")) of
                "" -> "";
                _ -> "-dirty"
            end,
    list_to_binary(case Rev of "" -> "unknown"; _ -> Rev ++ Dirty end).

%% ---------------------------------------------------------------------------
%% Profiling, run inside the EVATAR node
%% ---------------------------------------------------------------------------

%% @doc Runs in the EVATAR node (by erpc): eprof over every process of the
%% node for Seconds, or from when it sends `{ready, self()}' to Pid until
%% Pid sends it `{stop, Pid}' (answered `{stopped, self()}' once eprof has
%% stopped tracing), its total analysis sorted by time written to File.
-spec profile_node(number() | {until, pid()}, file:filename(), [pid()]) -> ok.
profile_node(Seconds, File, Exclude) ->
    {ok, Dev} = file:open(File, [write]),
    Leader = group_leader(),
    %% eprof prints to its server's group leader: the file.
    true = group_leader(Dev, self()),
    {ok, Eprof} = eprof:start(),
    true = group_leader(Leader, self()),
    Procs = [P || P <- processes(), P =/= self(), P =/= Eprof, not lists:member(P, Exclude)],
    profiling = eprof:start_profiling(Procs),
    case Seconds of
        {until, Pid} ->
            Pid ! {ready, self()},
            receive {stop, Pid} -> ok end,
            profiling_stopped = eprof:stop_profiling(),
            Pid ! {stopped, self()};
        _ ->
            timer:sleep(round(Seconds * 1000)),
            profiling_stopped = eprof:stop_profiling()
    end,
    ok = eprof:analyze(total, [{sort, time}]),
    stopped = eprof:stop(),
    file:close(Dev).

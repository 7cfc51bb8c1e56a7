%% @doc Internal. A mosquitto broker of the demo's own, for the smart home
%% over MQTT (`make demo DEMO_ARGS=mqtt'): mosquitto (Debian package
%% `mosquitto') runs as an OS process on a free loopback port, anonymous,
%% without persistence, with its config and log in a temporary directory
%% that is removed when it stops. It dies with this Erlang node.
%%
%% ```
%%  launching --port accepts connections--> running --stop/1--> (gone)
%%     |  mosquitto exited (port taken): launching again, 3 tries
%%     +--exited 3 times, or not ready in 10 s--> failed (start/1 says why)
%% '''
-module(evatar_demo_broker).
-behaviour(gen_statem).

-export([start_link/1, stop/1, address/1, log/1, executable/0]).
-export([init/1, callback_mode/0, handle_event/4, terminate/3]).

-export_type([broker/0, opts/0]).

-type broker() :: pid().
%% `executable': mosquitto's path (found by executable/0 when absent;
%% `false' says it is not installed).
-type opts() :: #{executable => file:filename() | false}.

%% The states of the machine (the diagram above).
-type state() :: launching | running | failed.

-define(READY_MS, 10000).
-define(POLL_MS, 50).
-define(TRIES, 3).
-define(STOP_MS, 5000).

-record(d, {exe :: file:filename(),
            dir :: file:filename(),
            port :: inet:port_number() | undefined,
            shell :: port() | undefined,
            os_pid :: pos_integer() | undefined,
            tries = 0 :: non_neg_integer(),
            deadline = 0 :: integer(),
            waiters = [] :: [gen_statem:from()],
            failure :: binary() | undefined}).

%% ---------------------------------------------------------------------------
%% API
%% ---------------------------------------------------------------------------

%% @doc Starts mosquitto, linked to the caller, and returns once it accepts
%% connections; `{error, Message}' (a sentence for a person) when it is not
%% installed or does not start.
-spec start_link(opts()) -> {ok, broker()} | {error, binary()}.
start_link(Opts) ->
    case maps:get(executable, Opts, executable()) of
        false ->
            {error, <<"mosquitto is not installed: the MQTT demo needs the MQTT broker "
                      "(Debian package mosquitto: sudo apt-get install mosquitto)">>};
        Exe ->
            {ok, Pid} = gen_statem:start_link(?MODULE, Exe, []),
            case gen_statem:call(Pid, await_ready, ?READY_MS * 2) of
                ok -> {ok, Pid};
                {error, _} = Error -> ok = stop(Pid), Error
            end
    end.

%% @doc Stops mosquitto, waits until it is gone and removes its directory.
-spec stop(broker()) -> ok.
stop(Broker) ->
    gen_statem:stop(Broker, normal, ?STOP_MS * 2).

%% @doc Where clients connect: `#{host => "127.0.0.1", port => Port}'.
-spec address(broker()) -> #{host := string(), port := inet:port_number()}.
address(Broker) ->
    gen_statem:call(Broker, address).

%% @doc What mosquitto wrote to its log (errors, warnings, notices).
-spec log(broker()) -> binary().
log(Broker) ->
    gen_statem:call(Broker, log).

%% @doc The mosquitto binary: /usr/sbin/mosquitto (Debian's place, often
%% not on a user's PATH), else the PATH's; `false' when not installed.
-spec executable() -> file:filename() | false.
executable() ->
    case [F || F <- ["/usr/sbin/mosquitto", "/usr/local/sbin/mosquitto"], filelib:is_regular(F)] of
        [F | _] -> F;
        [] -> os:find_executable("mosquitto")
    end.

%% ---------------------------------------------------------------------------
%% gen_statem
%% ---------------------------------------------------------------------------

-spec callback_mode() -> gen_statem:callback_mode_result().
callback_mode() -> handle_event_function.

-spec init(file:filename()) -> gen_statem:init_result(launching).
init(Exe) ->
    process_flag(trap_exit, true),
    Dir = filename:join(temp_dir(), io_lib:format("evatar-mosquitto-~s-~b",
                                                  [os:getpid(), erlang:unique_integer([positive])])),
    D = #d{exe = Exe, dir = lists:flatten(Dir),
           deadline = erlang:monotonic_time(millisecond) + ?READY_MS},
    {ok, launching, D, [{next_event, internal, launch}]}.

-spec handle_event(gen_statem:event_type(), term(), state(), #d{}) ->
          gen_statem:event_handler_result(state()).
handle_event(internal, launch, launching, D) ->
    case launch(D) of
        {ok, D1} -> {keep_state, D1, [{state_timeout, ?POLL_MS, poll}]};
        {error, Why} -> failed(Why, D)
    end;
handle_event(state_timeout, poll, launching, D) ->
    case {can_connect(D#d.port), alive(D#d.os_pid)} of
        {true, _} ->
            {next_state, running, reply_waiters(ok, D)};
        {false, false} when D#d.tries < ?TRIES ->
            %% Most likely another program took the free port first.
            {keep_state, close_shell(D), [{next_event, internal, launch}]};
        {false, false} ->
            failed(io_lib:format("mosquitto exited at once; its log says: ~s",
                                 [read_log(D)]), D);
        {false, true} ->
            case erlang:monotonic_time(millisecond) > D#d.deadline of
                true -> failed(io_lib:format("mosquitto does not accept connections on "
                                             "127.0.0.1:~b after ~b s", [D#d.port, ?READY_MS div 1000]), D);
                false -> {keep_state_and_data, [{state_timeout, ?POLL_MS, poll}]}
            end
    end;
handle_event(info, {Shell, {exit_status, _}}, _State, #d{shell = Shell} = D) ->
    %% The shell ends only when told to or when mosquitto could not be run.
    {keep_state, D#d{shell = undefined}};
handle_event(info, {Shell, {data, _}}, _State, #d{shell = Shell}) ->
    keep_state_and_data;
handle_event({call, From}, await_ready, running, _D) ->
    {keep_state_and_data, [{reply, From, ok}]};
handle_event({call, From}, await_ready, failed, D) ->
    {keep_state_and_data, [{reply, From, {error, D#d.failure}}]};
handle_event({call, From}, await_ready, launching, D) ->
    {keep_state, D#d{waiters = [From | D#d.waiters]}};
handle_event({call, From}, address, _State, D) ->
    {keep_state_and_data, [{reply, From, #{host => "127.0.0.1", port => D#d.port}}]};
handle_event({call, From}, log, _State, D) ->
    {keep_state_and_data, [{reply, From, read_log(D)}]};
handle_event(info, {'EXIT', Shell, _Why}, _State, _D) when is_port(Shell) ->
    keep_state_and_data;
handle_event(info, {'EXIT', _Parent, Why}, _State, _D) ->
    {stop, Why};
handle_event(info, _Other, _State, _D) ->
    keep_state_and_data.

-spec terminate(term(), state(), #d{}) -> ok.
terminate(_Why, _State, D) ->
    _ = close_shell(D),
    _ = file:del_dir_r(D#d.dir),
    ok.

%% ---------------------------------------------------------------------------
%% Internal
%% ---------------------------------------------------------------------------

failed(Why, D) ->
    Message = iolist_to_binary(Why),
    {next_state, failed, reply_waiters({error, Message}, D#d{failure = Message})}.

reply_waiters(Reply, #d{waiters = Ws} = D) ->
    _ = [gen_statem:reply(W, Reply) || W <- Ws],
    D#d{waiters = []}.

%% The shell starts mosquitto in the background, says its pid, then waits
%% on its standard input: a line ("stop") or end of file (this node died)
%% makes it stop mosquitto, wait for it and remove the directory.
launch(#d{exe = Exe, dir = Dir, tries = Tries} = D) ->
    ok = filelib:ensure_dir(filename:join(Dir, "x")),
    Port = free_port(),
    Conf = filename:join(Dir, "mosquitto.conf"),
    ok = file:write_file(Conf, config(Port)),
    Script = "\"$1\" -c \"$2\" >>\"$3\" 2>&1 & pid=$!; echo $pid; read line; "
             "kill -TERM $pid 2>/dev/null; wait $pid; rm -rf \"$4\"",
    Shell = open_port({spawn_executable, "/bin/sh"},
                      [{args, ["-c", Script, "sh", Exe, Conf, log_file(Dir), Dir]},
                       {line, 64}, binary, exit_status, use_stdio]),
    receive
        {Shell, {data, {eol, Line}}} ->
            OsPid = binary_to_integer(string:trim(Line)),
            {ok, D#d{port = Port, shell = Shell, os_pid = OsPid, tries = Tries + 1}};
        {Shell, {exit_status, Status}} ->
            {error, io_lib:format("could not run ~s (exit status ~b)", [Exe, Status])}
    after ?READY_MS ->
            catch port_close(Shell),
            {error, io_lib:format("could not run ~s", [Exe])}
    end.

config(Port) ->
    ["# written by evatar_demo_broker for the EVATAR demo\n",
     "listener ", integer_to_list(Port), " 127.0.0.1\n",
     "allow_anonymous true\n",
     "persistence false\n",
     %% Without it a request and its echo wait for delayed ACKs (40 ms).
     "set_tcp_nodelay true\n",
     %% Run as root, mosquitto would switch to the mosquitto user.
     "user ", current_user(), "\n",
     "log_dest stdout\n",
     "log_type error\nlog_type warning\nlog_type notice\n"].

close_shell(#d{shell = undefined} = D) ->
    D;
close_shell(#d{shell = Shell, os_pid = OsPid} = D) ->
    _ = (catch port_command(Shell, <<"stop\n">>)),
    receive
        {Shell, {exit_status, _}} -> ok
    after ?STOP_MS ->
            _ = os:cmd(io_lib:format("kill -KILL ~b 2>/dev/null", [OsPid])),
            catch port_close(Shell)
    end,
    D#d{shell = undefined}.

can_connect(Port) ->
    case gen_tcp:connect({127, 0, 0, 1}, Port, [], 500) of
        {ok, S} -> ok = gen_tcp:close(S), true;
        {error, _} -> false
    end.

%% A zombie (exited, not yet reaped by the shell) is gone.
alive(OsPid) ->
    case os:cmd(io_lib:format("ps -o stat= -p ~b", [OsPid])) of
        "" -> false;
        [$Z | _] -> false;
        _ -> true
    end.

free_port() ->
    {ok, S} = gen_tcp:listen(0, [{ip, {127, 0, 0, 1}}]),
    {ok, Port} = inet:port(S),
    ok = gen_tcp:close(S),
    Port.

log_file(Dir) -> filename:join(Dir, "mosquitto.log").

read_log(#d{dir = Dir}) ->
    case file:read_file(log_file(Dir)) of
        {ok, Bin} -> Bin;
        {error, _} -> <<>>
    end.

current_user() ->
    case os:getenv("USER") of
        false -> string:trim(os:cmd("id -un"));
        "" -> string:trim(os:cmd("id -un"));
        User -> User
    end.

temp_dir() ->
    case os:getenv("TMPDIR") of
        false -> "/tmp";
        "" -> "/tmp";
        T -> T
    end.

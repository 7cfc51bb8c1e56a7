%% @doc Internal. A port connector: keeps one external program running that
%% speaks the wire protocol on its stdin/stdout (a connection process owns
%% the port), logs each line of its stderr, and restarts it with exponential
%% back-off when it exits.
%%
%% ```
%%  running --program exits--> backoff --delay elapsed--> running
%% '''
%% The delay doubles from `backoff_min' up to `backoff_max' and starts over
%% once a run has lasted `stable_after' ms. Stderr reaches us through a named
%% pipe read by `cat' in line mode, so frames on stdout are never mixed
%% with diagnostics.
-module(agent_bridge_port).
-behaviour(gen_statem).

-export([start_link/2, runs/1]).
-export([init/1, callback_mode/0, handle_event/4, terminate/3]).

-export_type([opts/0]).

-include_lib("kernel/include/logger.hrl").

-type opts() :: #{name => term(),
                  command := file:filename_all(),
                  args => [string()],
                  env => [{string(), string()}],
                  conn => agent_bridge_conn:opts(),
                  backoff_min => pos_integer(),
                  backoff_max => pos_integer(),
                  stable_after => pos_integer()}.

-record(d, {name :: term(),
            opts :: opts(),
            conn :: pid() | undefined,
            stderr :: port() | undefined,
            fifo :: string() | undefined,
            started :: integer() | undefined,
            delay :: pos_integer(),
            runs = 0 :: non_neg_integer()}).

-spec start_link(term(), opts()) -> {ok, pid()} | {error, term()}.
start_link(Name, Opts) ->
    gen_statem:start_link(?MODULE, {Name, Opts}, []).

%% @doc How many times the program has been started.
-spec runs(pid()) -> non_neg_integer().
runs(Pid) -> gen_statem:call(Pid, runs).

%% The states of the machine (the diagram above).
-type state() :: running | backoff.

-spec callback_mode() -> gen_statem:callback_mode_result().
callback_mode() -> handle_event_function.

-spec init({term(), opts()}) -> gen_statem:init_result(state()).
init({Name, Opts}) ->
    process_flag(trap_exit, true),
    logger:update_process_metadata(#{port_connector => Name}),
    D = #d{name = Name, opts = Opts, delay = maps:get(backoff_min, Opts, 100)},
    {ok, backoff, D, [{state_timeout, 0, start}]}.

-spec handle_event(gen_statem:event_type(), term(), state(), #d{}) ->
          gen_statem:event_handler_result(state()).
handle_event(state_timeout, start, backoff, D) ->
    {next_state, running, start_program(D)};
handle_event({call, From}, runs, _State, #d{runs = N}) ->
    {keep_state_and_data, [{reply, From, N}]};
handle_event(info, {Port, {data, {Eol, Line}}}, _State, #d{stderr = Port}) ->
    ?LOG_NOTICE(#{what => program_stderr, line => Line, partial => Eol =:= noeol}),
    keep_state_and_data;
handle_event(info, {Port, {exit_status, _}}, _State, #d{stderr = Port} = D) ->
    {keep_state, D#d{stderr = undefined}};
handle_event(info, {'EXIT', Port, _}, _State, #d{stderr = Port} = D) ->
    {keep_state, D#d{stderr = undefined}};
handle_event(info, {'EXIT', Conn, Why}, running, #d{conn = Conn} = D) ->
    D1 = cleanup(D#d{conn = undefined}),
    Delay = next_delay(D1),
    ?LOG_NOTICE(#{what => program_stopped, reason => Why, restart_in_ms => Delay}),
    {next_state, backoff, D1#d{delay = Delay}, [{state_timeout, Delay, start}]};
handle_event(info, _Other, _State, _D) ->
    keep_state_and_data.

-spec terminate(term(), state(), #d{}) -> ok.
terminate(_Why, _State, #d{conn = Conn} = D) ->
    case Conn of
        undefined -> ok;
        _ -> unlink(Conn), exit(Conn, shutdown)
    end,
    _ = cleanup(D),
    ok.

start_program(#d{opts = Opts, runs = Runs} = D) ->
    Fifo = fifo_path(),
    ok = mkfifo(Fifo),
    Cat = open_port({spawn_executable, os:find_executable("cat")},
                    [{args, [Fifo]}, {line, 4096}, binary, exit_status, use_stdio,
                     stderr_to_stdout]),
    Command = to_list(maps:get(command, Opts)),
    %% sh puts the program's stderr on the pipe, then becomes the program.
    %% The FIFO is opened read-write (`2<>'), which never blocks: a plain
    %% `2>' waits for a reader, and if the reader is already gone (a restart
    %% racing a stop) sh would wait forever holding the node's own stderr.
    Args = ["-c", "exec \"$0\" \"$@\" 2<>\"$AGENT_BRIDGE_STDERR\"", Command
            | maps:get(args, Opts, [])],
    Env = [{"AGENT_BRIDGE_STDERR", Fifo} | maps:get(env, Opts, [])],
    {ok, Conn} = agent_bridge_conn:start_link({port, {"/bin/sh", Args, Env},
                                               maps:get(conn, Opts, #{})}),
    D#d{conn = Conn, stderr = Cat, fifo = Fifo, runs = Runs + 1,
        started = erlang:monotonic_time(millisecond)}.

%% Doubles the delay unless the run that just ended was long enough to count
%% as healthy.
next_delay(#d{opts = Opts, started = Started, delay = Delay}) ->
    Min = maps:get(backoff_min, Opts, 100),
    Max = maps:get(backoff_max, Opts, 30000),
    Ran = erlang:monotonic_time(millisecond) - Started,
    case Ran >= maps:get(stable_after, Opts, 30000) of
        true -> Min;
        false -> min(Max, Delay * 2)
    end.

cleanup(#d{stderr = Cat, fifo = Fifo} = D) ->
    case Cat of
        undefined -> ok;
        _ -> try port_close(Cat) catch error:badarg -> true end
    end,
    case Fifo of
        undefined -> ok;
        _ -> _ = file:delete(Fifo), ok
    end,
    D#d{stderr = undefined, fifo = undefined}.

fifo_path() ->
    Dir = case os:getenv("TMPDIR") of
              false -> "/tmp";
              Tmp -> Tmp
          end,
    filename:join(Dir, "agent_bridge_" ++ os:getpid() ++ "_"
                  ++ integer_to_list(erlang:unique_integer([positive])) ++ ".stderr").

mkfifo(Path) ->
    Port = open_port({spawn_executable, os:find_executable("mkfifo")},
                     [{args, [Path]}, exit_status]),
    receive
        {Port, {exit_status, 0}} -> ok;
        {Port, {exit_status, N}} -> {error, {mkfifo, N}}
    end.

to_list(Bin) when is_binary(Bin) -> binary_to_list(Bin);
to_list(List) -> List.

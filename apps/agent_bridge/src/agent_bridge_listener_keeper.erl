%% @doc Internal. Keeps one bridge listener (its agent_bridge_listener_sup)
%% running: starts it linked, and when it cannot start (its port is taken,
%% its address gone) or exits, starts it again after a delay from
%% restart_backoff (1 s doubling to 60 s; the listener option `restart'
%% changes the policy), never giving up. A crash loop is logged as a
%% warning (`what => crash_loop', with the count), as for MQTT Avatars.
%%
%% A listener of the application environment (the node's configuration
%% file) is kept from its first start: a node whose port is briefly taken
%% at boot still comes up and listens once the port is free. One started
%% with agent_bridge:start_listener/2 returns the first start's error to
%% its caller instead, and is kept once it has listened.
%%
%% ```
%%  (init) --first start fails, kept from boot--> waiting
%%    |  \--first start fails, started at run time--> (stops: the caller's error)
%%    v started
%%  running --listener exits--> waiting --delay elapsed--> (start) --ok--> running
%%                                 ^                          |
%%                                 +-------- fails -----------+
%% '''
-module(agent_bridge_listener_keeper).
-behaviour(gen_statem).

-include_lib("kernel/include/logger.hrl").

-export([start_link/3, status/1, listener_sup/1]).
-export([init/1, callback_mode/0, handle_event/4, terminate/3]).

-export_type([first/0, status/0]).

%% What a failed first start does: `retry' (a configured listener) or
%% `fail' (agent_bridge:start_listener/2).
-type first() :: retry | fail.
-type status() :: #{state := waiting | running,
                    starts := non_neg_integer(),
                    failures := non_neg_integer(),
                    crashes := non_neg_integer(),
                    next_delay_ms := pos_integer(),
                    last_reason := term()}.

-record(d, {name :: term(),
            opts :: agent_bridge:listener_opts(),
            sup :: pid() | undefined,
            started :: integer() | undefined,
            starts = 0 :: non_neg_integer(),
            failures = 0 :: non_neg_integer(),
            last_reason :: term(),
            backoff :: restart_backoff:backoff()}).

-spec start_link(term(), agent_bridge:listener_opts(), first()) ->
          {ok, pid()} | {error, term()}.
start_link(Name, Opts, First) ->
    gen_statem:start_link(?MODULE, {Name, Opts, First}, []).

%% @doc The keeper's state: starts, failed starts, short runs in a row and
%% the next delay.
-spec status(pid()) -> status().
status(Keeper) ->
    gen_statem:call(Keeper, status, 15000).

%% @doc The listener's supervisor while it runs.
-spec listener_sup(pid()) -> pid() | undefined.
listener_sup(Keeper) ->
    gen_statem:call(Keeper, listener_sup, 15000).

%% The states of the machine (the diagram above).
-type state() :: waiting | running.

-spec callback_mode() -> gen_statem:callback_mode_result().
callback_mode() -> handle_event_function.

-spec init({term(), agent_bridge:listener_opts(), first()}) ->
          gen_statem:init_result(state()) | {stop, term()}.
init({Name, Opts, First}) ->
    process_flag(trap_exit, true),
    logger:set_process_metadata(#{listener => Name, domain => [agent_bridge]}),
    D = #d{name = Name, opts = Opts, backoff = restart_backoff:new(maps:get(restart, Opts, #{}))},
    %% The first start is synchronous, as a supervisor's child start is:
    %% when start_listener/2 returns, the listener listens.
    case start(D) of
        {ok, D1} -> {ok, running, D1};
        {error, Reason, _D1} when First =:= fail -> {stop, Reason};
        {error, Reason, D1} ->
            {D2, Retry} = waiting(0, Reason, D1),
            {ok, waiting, D2, [Retry]}
    end.

-spec handle_event(gen_statem:event_type(), term(), state(), #d{}) ->
          gen_statem:event_handler_result(state()).
handle_event(state_timeout, start, waiting, D) ->
    case start(D) of
        {ok, D1} ->
            ?LOG_NOTICE(#{what => listener_recovered, listener => D#d.name,
                          failures => D1#d.failures}),
            {next_state, running, D1};
        {error, Reason, D1} ->
            {D2, Retry} = waiting(0, Reason, D1),
            {next_state, waiting, D2, [Retry]}
    end;
handle_event(info, {'EXIT', Sup, Reason}, running, #d{sup = Sup, started = Started} = D) ->
    _ = persistent_term:erase({agent_bridge, address, D#d.name}),
    {D1, Retry} = waiting(erlang:monotonic_time(millisecond) - Started, Reason,
                          D#d{sup = undefined}),
    {next_state, waiting, D1, [Retry]};
handle_event({call, From}, listener_sup, _State, D) ->
    {keep_state_and_data, [{reply, From, D#d.sup}]};
handle_event({call, From}, status, State, D) ->
    {keep_state_and_data,
     [{reply, From, #{state => State, starts => D#d.starts, failures => D#d.failures,
                      crashes => restart_backoff:crashes(D#d.backoff),
                      next_delay_ms => restart_backoff:next_delay(D#d.backoff),
                      last_reason => D#d.last_reason}}]};
handle_event(info, _Other, _State, _D) ->
    keep_state_and_data.

-spec terminate(term(), state(), #d{}) -> ok.
terminate(_Reason, _State, #d{sup = undefined}) ->
    ok;
terminate(_Reason, _State, #d{sup = Sup}) ->
    %% Shut the listener down as its supervisor would have: its
    %% connections get their shutdown time.
    exit(Sup, shutdown),
    receive
        {'EXIT', Sup, _} -> ok
    after 15000 ->
            exit(Sup, kill),
            receive {'EXIT', Sup, _} -> ok end
    end.

start(#d{name = Name, opts = Opts} = D) ->
    case agent_bridge_listener_sup:start_link(Name, Opts) of
        {ok, Sup} ->
            {ok, D#d{sup = Sup, started = erlang:monotonic_time(millisecond),
                     starts = D#d.starts + 1}};
        {error, Reason} ->
            {error, Reason, D#d{failures = D#d.failures + 1, last_reason = Reason}}
    end.

waiting(RanMs, Reason, #d{name = Name} = D) ->
    {Delay, Effect, B} = restart_backoff:exited(RanMs, D#d.backoff),
    ?LOG_WARNING(#{what => listener_down, listener => Name, reason => Reason,
                   ran_ms => RanMs, restart_in_ms => Delay}),
    case Effect of
        none ->
            ok;
        {crash_loop, #{crashes := N}} ->
            ?LOG_WARNING(#{what => crash_loop, listener => Name, crashes => N,
                           starts => D#d.starts, failures => D#d.failures,
                           restart_in_ms => Delay, reason => Reason,
                           message => <<"the listener keeps failing to start or stopping soon "
                                        "after it starts">>})
    end,
    {D#d{backoff = B, last_reason = Reason}, {state_timeout, Delay, start}}.

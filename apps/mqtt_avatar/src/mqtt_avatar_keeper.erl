%% @doc Internal. Keeps one MQTT Avatar running (started with
%% {@link mqtt_avatar:keep/1}, or from the `avatars' environment the node
%% configuration file fills): starts it linked, and when it exits starts
%% it again after a delay from restart_backoff (1 s doubling to 60 s),
%% so a broker that refuses or a device that crashes the Avatar costs a
%% start a minute, not a tight loop, and never gives up. A crash loop is
%% logged as a warning (`what => crash_loop', with the count).
%%
%% ```
%%  waiting --delay elapsed, started--> running --Avatar exits abnormally--> waiting
%%     ^  |                               |
%%     +--+ start refused (bad options)   +--Avatar stopped normally--> (keeper stops)
%% '''
-module(mqtt_avatar_keeper).
-behaviour(gen_statem).

-include_lib("kernel/include/logger.hrl").

-export([start_link/1, status/1, reconfigure/2]).
-export([init/1, callback_mode/0, handle_event/4, terminate/3]).

-export_type([status/0]).

-type status() :: #{entity_id := binary(),
                    state := waiting | running,
                    avatar := pid() | undefined,
                    starts := non_neg_integer(),
                    crashes := non_neg_integer(),
                    next_delay_ms := pos_integer()}.

%% The states of the machine.
-type state() :: waiting | running.

-record(d, {opts :: mqtt_avatar:opts(),
            entity :: binary(),
            avatar :: pid() | undefined,
            started :: integer() | undefined,
            starts = 0 :: non_neg_integer(),
            backoff :: restart_backoff:backoff()}).

-spec start_link(mqtt_avatar:opts()) -> {ok, pid()} | {error, term()}.
start_link(Opts) ->
    gen_statem:start_link(?MODULE, Opts, []).

-spec status(pid()) -> status().
status(Keeper) ->
    gen_statem:call(Keeper, status, 15000).

%% @doc New `description' or `overrides' (mqtt_avatar:reconfigure/2):
%% checked, then the Avatar is started again with them.
-spec reconfigure(pid(), map()) -> ok | {error, [mqtt_avatar:problem()]}.
reconfigure(Keeper, Changes) ->
    gen_statem:call(Keeper, {reconfigure, Changes}, 30000).

-spec callback_mode() -> gen_statem:callback_mode_result().
callback_mode() -> handle_event_function.

-spec init(mqtt_avatar:opts()) -> gen_statem:init_result(waiting).
init(#{entity_id := Entity} = Opts) ->
    process_flag(trap_exit, true),
    logger:set_process_metadata(#{entity => Entity, domain => [mqtt_avatar]}),
    D = #d{opts = Opts, entity = Entity,
           backoff = restart_backoff:new(maps:get(restart, Opts, #{}))},
    {ok, waiting, D, [{state_timeout, 0, start}]}.

-spec handle_event(gen_statem:event_type(), term(), state(), #d{}) ->
          gen_statem:event_handler_result(state()).
handle_event(state_timeout, start, waiting, #d{opts = Opts} = D) ->
    Started = erlang:monotonic_time(millisecond),
    case mqtt_avatar:start_link(maps:remove(restart, Opts)) of
        {ok, Pid} ->
            {next_state, running, D#d{avatar = Pid, started = Started, starts = D#d.starts + 1}};
        {error, Reason} ->
            %% A description file edited into a mistake: wait and read it again.
            backoff(0, {start_refused, Reason}, D#d{started = undefined})
    end;
handle_event(info, {'EXIT', Pid, normal}, running, #d{avatar = Pid} = D) ->
    ?LOG_NOTICE(#{what => avatar_stopped, entity => D#d.entity}),
    {stop, normal, D#d{avatar = undefined}};
handle_event(info, {'EXIT', Pid, Reason}, running, #d{avatar = Pid, started = Started} = D) ->
    backoff(erlang:monotonic_time(millisecond) - Started, Reason, D#d{avatar = undefined});
handle_event({call, From}, status, State, D) ->
    {keep_state_and_data,
     [{reply, From, #{entity_id => D#d.entity, state => State, avatar => D#d.avatar,
                      starts => D#d.starts, crashes => restart_backoff:crashes(D#d.backoff),
                      next_delay_ms => restart_backoff:next_delay(D#d.backoff)}}]};
handle_event({call, From}, {reconfigure, Changes}, _State, #d{opts = Opts, avatar = Pid} = D) ->
    New = maps:merge(Opts, Changes),
    case mqtt_avatar:check_opts(maps:remove(restart, New)) of
        ok ->
            ?LOG_NOTICE(#{what => avatar_reconfigured, entity => D#d.entity,
                          changed => maps:keys(Changes)}),
            %% Its exit is not a crash: unlinked, and no longer the Avatar
            %% (a late 'EXIT' falls to the clause below).
            _ = is_pid(Pid) andalso unlink(Pid),
            _ = is_pid(Pid) andalso (catch mqtt_avatar:stop(Pid)),
            {next_state, waiting, D#d{opts = New, avatar = undefined, started = undefined},
             [{reply, From, ok}, {state_timeout, 0, start}]};
        {error, _} = Error ->
            {keep_state_and_data, [{reply, From, Error}]}
    end;
handle_event(info, _Other, _State, _D) ->
    keep_state_and_data.

-spec terminate(term(), state(), #d{}) -> ok.
terminate(_Reason, _State, #d{avatar = undefined}) ->
    ok;
terminate(_Reason, _State, #d{avatar = Pid}) ->
    %% Leave EVATAR and the broker cleanly (Bye, DISCONNECT) when the node
    %% stops or the Avatar is removed.
    _ = catch mqtt_avatar:stop(Pid),
    ok.

backoff(RanMs, Reason, #d{entity = Entity} = D) ->
    {Delay, Effect, B} = restart_backoff:exited(RanMs, D#d.backoff),
    ?LOG_WARNING(#{what => avatar_exited, entity => Entity, reason => Reason,
                   ran_ms => RanMs, restart_in_ms => Delay}),
    case Effect of
        none ->
            ok;
        {crash_loop, #{crashes := N}} ->
            ?LOG_WARNING(#{what => crash_loop, entity => Entity, crashes => N,
                           starts => D#d.starts, restart_in_ms => Delay, reason => Reason,
                           message => <<"the MQTT Avatar keeps stopping soon after it starts">>})
    end,
    {next_state, waiting, D#d{backoff = B}, [{state_timeout, Delay, start}]}.

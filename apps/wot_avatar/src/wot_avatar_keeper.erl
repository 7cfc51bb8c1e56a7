%% @doc Internal. Keeps one WoT Avatar running (started with
%% {@link wot_avatar:keep/1}, or from the `avatars' environment the node
%% configuration file's `wot_avatars' fills): starts it linked, and when it
%% exits starts it again after a delay from restart_backoff (1 s doubling
%% to 60 s by default, option `restart'), never giving up; a crash loop is
%% logged (`what => crash_loop'). A Thing that is away does not make the
%% Avatar exit (it waits for the Thing itself, wot_avatar_fsm): this
%% back-off is for crashes.
%%
%% ```
%%  waiting --delay elapsed, started--> running --Avatar exits abnormally--> waiting
%%                                         +--Avatar stopped normally--> (keeper stops)
%% '''
-module(wot_avatar_keeper).
-behaviour(gen_statem).

-include_lib("kernel/include/logger.hrl").

-export([start_link/1, status/1]).
-export([init/1, callback_mode/0, handle_event/4, terminate/3]).

-export_type([status/0]).

-type status() :: #{entity_id := binary(), state := waiting | running, avatar := pid() | undefined,
                    starts := non_neg_integer(), crashes := non_neg_integer(),
                    next_delay_ms := pos_integer()}.

%% The states of the machine.
-type state() :: waiting | running.

-record(d, {opts :: wot_avatar:opts(),
            entity :: binary(),
            avatar :: pid() | undefined,
            started :: integer() | undefined,
            starts = 0 :: non_neg_integer(),
            backoff :: restart_backoff:backoff()}).

-spec start_link(wot_avatar:opts()) -> {ok, pid()} | {error, term()}.
start_link(Opts) ->
    gen_statem:start_link(?MODULE, Opts, []).

-spec status(pid()) -> status().
status(Keeper) ->
    gen_statem:call(Keeper, status, 15000).

-spec callback_mode() -> gen_statem:callback_mode_result().
callback_mode() -> handle_event_function.

-spec init(wot_avatar:opts()) -> gen_statem:init_result(waiting).
init(#{entity_id := Entity} = Opts) ->
    process_flag(trap_exit, true),
    logger:set_process_metadata(#{entity => Entity, domain => [wot_avatar]}),
    {ok, waiting, #d{opts = Opts, entity = Entity, backoff = restart_backoff:new(maps:get(restart, Opts, #{}))},
     [{state_timeout, 0, start}]}.

-spec handle_event(gen_statem:event_type(), term(), state(), #d{}) ->
          gen_statem:event_handler_result(state()).
handle_event(state_timeout, start, waiting, #d{opts = Opts} = D) ->
    case wot_avatar:start_link(Opts) of
        {ok, Pid} ->
            {next_state, running, D#d{avatar = Pid, started = erlang:monotonic_time(millisecond),
                                      starts = D#d.starts + 1}};
        {error, Reason} ->
            backoff(0, {start_refused, Reason}, D)
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
handle_event(info, _Other, _State, _D) ->
    keep_state_and_data.

-spec terminate(term(), state(), #d{}) -> ok.
terminate(_Reason, _State, #d{avatar = undefined}) ->
    ok;
terminate(_Reason, _State, #d{avatar = Pid}) ->
    _ = catch wot_avatar:stop(Pid),
    ok.

backoff(RanMs, Reason, #d{entity = Entity} = D) ->
    {Delay, Effect, B} = restart_backoff:exited(RanMs, D#d.backoff),
    ?LOG_WARNING(#{what => avatar_exited, entity => Entity, reason => Reason, ran_ms => RanMs,
                   restart_in_ms => Delay}),
    case Effect of
        none -> ok;
        {crash_loop, #{crashes := N}} ->
            ?LOG_WARNING(#{what => crash_loop, entity => Entity, crashes => N, starts => D#d.starts,
                           restart_in_ms => Delay, reason => Reason,
                           message => <<"the WoT Avatar keeps stopping soon after it starts">>})
    end,
    {next_state, waiting, D#d{backoff = B}, [{state_timeout, Delay, start}]}.

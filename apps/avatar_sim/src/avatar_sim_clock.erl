%% @doc Internal. The deterministic simulation clock: simulated time moves in
%% ticks, and at each tick every subscribed world gets
%% `{avatar_sim_clock, Ref, Now}' and must answer {@link ack/2} before the
%% next tick starts, so all simulated events happen at tick times in a fixed
%% order whatever the machine's load. Ticks are paced against real time by
%% a speed factor, or driven by hand ({@link advance/2}).
%%
%% ```
%%   stopped --resume--> running --next tick due--> ticking --all acked--> running
%%      ^  \                |  ^                      ^   |
%%      |   advance ------->+--|-- advance -----------+   +--acked, ticks left-> ticking
%%      +----- pause / manual / advance done ------------+
%% '''
%% `now/1' reads an atomics cell, never the process, so a world may call it
%% while it is handling a tick.
%%
%% Paced ticks (not `advance/2') can be gated, one way at a time:
%% <ul>
%% <li>`lockstep/2': a tick starts only when a quiet predicate holds, on
%% top of every world having acked the last one. The caller's predicate
%% says that nothing set going by the simulation is still on its way or
%% being handled (evatar_demo_scenario: the VAs have handled every signal
%% sent to them, the pairings have everything their entities sent, the
%% worlds every request), so what the VAs perceive and do lands at the same
%% tick whatever the machine's load: the outcome of a run is the same on an
%% idle and on a busy machine, only its real time differs.</li>
%% <li>`follow/3': ticks wait while simulated time is more than a lead ahead
%% of what an observer has perceived: for an observer that cannot be counted
%% (a VA of an SDK, a house on MQTT), which keeps real pace.</li>
%% </ul>
%% The clock asks the gate when a tick is due and, while it says no, again
%% every ?GATE_POLL real ms. That short poll is deliberate: what the gate
%% reads lives in the mediator's pairings, which must not call the
%% scenarios (rebar.config's xref layers), and in the VAs, agents as a real
%% MAS would run them, which know nothing of a clock; so nothing can tell
%% the clock that it went quiet. The gate is read only at tick boundaries,
%% never while a tick runs.
-module(avatar_sim_clock).
-behaviour(gen_statem).

-export([start_link/1, now/1, advance/2, pause/1, resume/1, set_speed/2, subscribe/2,
         ack/2, info/1, pid/1, stop/1, tick_length/1, follow/3, lockstep/2]).
-export([init/1, callback_mode/0, handle_event/4]).

-export_type([clock/0, opts/0, speed/0, seen/0, quiet/0]).

%% The states of the machine (the diagram above).
-type state() :: stopped | running | ticking.

-record(clock, {pid :: pid(), cell :: atomics:atomics_ref(), tick :: pos_integer()}).
-opaque clock() :: #clock{}.
-type speed() :: number() | manual.
%% What an observer has perceived of simulated time (ms since 1970), or
%% `undefined' before it has perceived anything.
-type seen() :: fun(() -> integer() | undefined).
%% Whether everything the simulation set going has been handled: the next
%% tick may start.
-type quiet() :: fun(() -> boolean()).
-type opts() :: #{speed => speed(),
                  tick => pos_integer(),
                  start => calendar:datetime(),
                  start_ms => non_neg_integer(),
                  paused => boolean()}.

-define(DEFAULT_START, {{2024, 11, 15}, {17, 0, 0}}).
%% How often (real ms) a clock held by its gate asks again.
-define(GATE_POLL, 2).

-record(d, {cell :: atomics:atomics_ref(),
            tick :: pos_integer(),
            speed :: speed(),
            paused :: boolean(),
            now :: integer(),
            %% Real time (ms, monotonic) and simulated time of the last re-anchoring.
            anchor :: {integer(), integer()},
            subs = #{} :: #{pid() => reference()},
            waiting = [] :: [pid()],
            tick_ref :: reference() | undefined,
            %% What paced ticks wait for: an observer followed with the lead
            %% allowed (simulated ms), or a quiet predicate (lockstep).
            gate = none :: none | {lead, seen(), non_neg_integer()} | {quiet, quiet()},
            %% Ticks still to run for advance/2, and who to answer.
            advance = none :: none | {non_neg_integer(), gen_statem:from()}}).

%% ---------------------------------------------------------------------------
%% API
%% ---------------------------------------------------------------------------

%% @doc Starts a clock; returns its handle.
-spec start_link(opts()) -> {ok, pid(), clock()}.
start_link(Opts) ->
    Cell = atomics:new(1, [{signed, true}]),
    Tick = maps:get(tick, Opts, 100),
    {ok, Pid} = gen_statem:start_link(?MODULE, {Opts, Cell}, []),
    {ok, Pid, #clock{pid = Pid, cell = Cell, tick = Tick}}.

%% @doc Simulated time: milliseconds since 1970-01-01 UTC.
-spec now(clock()) -> integer().
now(#clock{cell = Cell}) -> atomics:get(Cell, 1).

%% @doc Runs `Ms' of simulated time (rounded up to whole ticks) and returns
%% once every world has handled every tick.
-spec advance(clock(), non_neg_integer()) -> ok.
advance(#clock{pid = Pid}, Ms) when is_integer(Ms), Ms >= 0 ->
    gen_statem:call(Pid, {advance, Ms}, infinity).

-spec pause(clock()) -> ok.
pause(#clock{pid = Pid}) -> gen_statem:call(Pid, pause).

-spec resume(clock()) -> ok.
resume(#clock{pid = Pid}) -> gen_statem:call(Pid, resume).

-spec set_speed(clock(), speed()) -> ok.
set_speed(#clock{pid = Pid}, Speed) when Speed =:= manual; is_number(Speed), Speed > 0 ->
    gen_statem:call(Pid, {speed, Speed}).

%% @doc Makes `Pid' receive ticks from the next one on.
-spec subscribe(clock(), pid()) -> ok.
subscribe(#clock{pid = Pid}, Sub) -> gen_statem:call(Pid, {subscribe, Sub}, infinity).

%% @doc A subscriber has finished handling the tick `Ref'.
-spec ack(clock(), reference()) -> ok.
ack(#clock{pid = Pid}, Ref) -> gen_statem:cast(Pid, {ack, self(), Ref}).

-spec info(clock()) -> #{now := integer(), speed := speed(), paused := boolean(),
                         tick := pos_integer(), subscribers := non_neg_integer()}.
info(#clock{pid = Pid}) -> gen_statem:call(Pid, info).

%% @doc Paced ticks (speed mode, not `advance/2') from now on wait while
%% the next tick would be more than `LeadMs' simulated ms ahead of
%% `Seen()', what an observer (a VA) has perceived; `none' stops following.
%% The simulation stays the same tick by tick; only its pace changes, so an
%% observer that reacts in real time is never further behind than that.
%% Replaces the gate of a {@link lockstep/2}.
-spec follow(clock(), seen() | none, non_neg_integer()) -> ok.
follow(#clock{pid = Pid}, Seen, LeadMs)
  when (Seen =:= none orelse is_function(Seen, 0)), is_integer(LeadMs), LeadMs >= 0 ->
    gen_statem:call(Pid, {follow, Seen, LeadMs}).

%% @doc Paced ticks from now on start only when `Quiet()' is true (and every
%% world acked the last tick); `none' stops it. Replaces the gate of a {@link follow/3}.
%% `Quiet' runs in the clock's process at each tick boundary and, while it is
%% false, every few real ms: keep it a handful of calls.
-spec lockstep(clock(), quiet() | none) -> ok.
lockstep(#clock{pid = Pid}, Quiet) when Quiet =:= none; is_function(Quiet, 0) ->
    gen_statem:call(Pid, {lockstep, Quiet}).

-spec pid(clock()) -> pid().
pid(#clock{pid = Pid}) -> Pid.

-spec tick_length(clock()) -> pos_integer().
tick_length(#clock{tick = Tick}) -> Tick.

-spec stop(clock()) -> ok.
stop(#clock{pid = Pid}) -> gen_statem:stop(Pid).

%% ---------------------------------------------------------------------------
%% gen_statem
%% ---------------------------------------------------------------------------

-spec callback_mode() -> gen_statem:callback_mode_result().
callback_mode() -> handle_event_function.

-spec init({opts(), atomics:atomics_ref()}) -> gen_statem:init_result(state()).
init({Opts, Cell}) ->
    Start = case Opts of
                #{start_ms := Ms} -> Ms;
                #{} -> datetime_ms(maps:get(start, Opts, ?DEFAULT_START))
            end,
    ok = atomics:put(Cell, 1, Start),
    Speed = maps:get(speed, Opts, 1.0),
    Paused = maps:get(paused, Opts, false),
    D = #d{cell = Cell, tick = maps:get(tick, Opts, 100), speed = Speed, paused = Paused,
           now = Start, anchor = {real_now(), Start}},
    case Speed =/= manual andalso not Paused of
        true -> {ok, running, D, [next_due(D)]};
        false -> {ok, stopped, D}
    end.

-spec handle_event(gen_statem:event_type(), term(), state(), #d{}) ->
          gen_statem:event_handler_result(state()).
handle_event(state_timeout, tick, running, D) ->
    case held(D) of
        %% Re-anchored while held, so time does not rush to catch up after.
        true -> {keep_state, D#d{anchor = {real_now(), D#d.now}},
                 [{state_timeout, ?GATE_POLL, tick}]};
        false -> start_tick(D)
    end;
handle_event(cast, {ack, Pid, Ref}, ticking, #d{tick_ref = Ref} = D) ->
    acked(D#d{waiting = lists:delete(Pid, D#d.waiting)});
handle_event(cast, {ack, _Pid, _Ref}, _State, _D) ->
    keep_state_and_data;
handle_event(info, {'DOWN', MRef, process, Pid, _}, State, #d{subs = Subs} = D) ->
    case Subs of
        #{Pid := MRef} ->
            D1 = D#d{subs = maps:remove(Pid, Subs), waiting = lists:delete(Pid, D#d.waiting)},
            case State of
                ticking -> acked(D1);
                _ -> {keep_state, D1}
            end;
        #{} ->
            keep_state_and_data
    end;
handle_event({call, From}, info, _State, D) ->
    {keep_state_and_data,
     [{reply, From, #{now => D#d.now, speed => D#d.speed, paused => D#d.paused,
                      tick => D#d.tick, subscribers => map_size(D#d.subs)}}]};
%% Everything below changes the tick sequence: wait for the current tick.
handle_event({call, _}, _Request, ticking, _D) ->
    {keep_state_and_data, [postpone]};
handle_event({call, From}, {subscribe, Pid}, _State, #d{subs = Subs} = D) ->
    case Subs of
        #{Pid := _} -> {keep_state_and_data, [{reply, From, ok}]};
        #{} -> {keep_state, D#d{subs = Subs#{Pid => monitor(process, Pid)}},
                [{reply, From, ok}]}
    end;
handle_event({call, From}, {advance, Ms}, _State, D) ->
    Ticks = (Ms + D#d.tick - 1) div D#d.tick,
    case Ticks of
        0 -> {keep_state_and_data, [{reply, From, ok}]};
        _ -> start_tick(D#d{advance = {Ticks, From}})
    end;
handle_event({call, From}, pause, _State, D) ->
    {next_state, stopped, D#d{paused = true}, [{reply, From, ok}]};
handle_event({call, From}, resume, _State, D) ->
    continue(D#d{paused = false}, [{reply, From, ok}]);
handle_event({call, From}, {speed, Speed}, _State, D) ->
    continue(D#d{speed = Speed}, [{reply, From, ok}]);
handle_event({call, From}, {follow, none, _LeadMs}, _State, D) ->
    continue(D#d{gate = none}, [{reply, From, ok}]);
handle_event({call, From}, {follow, Seen, LeadMs}, _State, D) ->
    continue(D#d{gate = {lead, Seen, LeadMs}}, [{reply, From, ok}]);
handle_event({call, From}, {lockstep, none}, _State, D) ->
    continue(D#d{gate = none}, [{reply, From, ok}]);
handle_event({call, From}, {lockstep, Quiet}, _State, D) ->
    continue(D#d{gate = {quiet, Quiet}}, [{reply, From, ok}]).

%% ---------------------------------------------------------------------------
%% Internals
%% ---------------------------------------------------------------------------

start_tick(#d{subs = Subs, tick = Tick, now = Now, cell = Cell} = D) ->
    Now1 = Now + Tick,
    ok = atomics:put(Cell, 1, Now1),
    Ref = make_ref(),
    Pids = lists:sort(maps:keys(Subs)),
    _ = [Pid ! {avatar_sim_clock, Ref, Now1} || Pid <- Pids],
    acked(D#d{now = Now1, tick_ref = Ref, waiting = Pids}).

%% When every subscriber has acked, either run the next tick of an advance,
%% answer the advance, or go back to pacing.
acked(#d{waiting = [_ | _]} = D) ->
    {next_state, ticking, D};
acked(#d{advance = {1, From}} = D) ->
    continue(D#d{advance = none, tick_ref = undefined}, [{reply, From, ok}]);
acked(#d{advance = {N, From}} = D) ->
    start_tick(D#d{advance = {N - 1, From}});
acked(#d{advance = none} = D) ->
    D1 = D#d{tick_ref = undefined},
    case running(D1) of
        true -> {next_state, running, D1, [next_due(D1)]};
        false -> {next_state, stopped, D1}
    end.

%% Re-anchor real time on every change of pace, so simulated time neither
%% jumps nor tries to catch up time spent paused or advancing by hand.
continue(D, Actions) ->
    D1 = D#d{anchor = {real_now(), D#d.now}},
    case running(D1) of
        true -> {next_state, running, D1, [next_due(D1) | Actions]};
        false -> {next_state, stopped, D1, Actions}
    end.

running(#d{speed = Speed, paused = Paused}) -> Speed =/= manual andalso not Paused.

%% The gate holds the next tick: the observer followed is too far behind,
%% or what the simulation set going is not all handled yet.
held(#d{gate = none}) ->
    false;
held(#d{gate = {lead, Seen, Lead}, now = Now, tick = Tick}) ->
    case Seen() of
        T when is_integer(T) -> Now + Tick > T + Lead;
        undefined -> false
    end;
held(#d{gate = {quiet, Quiet}}) ->
    not Quiet().

next_due(#d{anchor = {Real0, Sim0}, now = Now, tick = Tick, speed = Speed}) ->
    Due = Real0 + (Now + Tick - Sim0) / Speed,
    {state_timeout, max(0, round(Due - real_now())), tick}.

real_now() -> erlang:monotonic_time(millisecond).

datetime_ms(DateTime) ->
    (calendar:datetime_to_gregorian_seconds(DateTime)
     - calendar:datetime_to_gregorian_seconds({{1970, 1, 1}, {0, 0, 0}})) * 1000.

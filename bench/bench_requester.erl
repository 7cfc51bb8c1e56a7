%% @doc Internal to the benchmarks (evatar_bench_gen, broker_bench_gen): the
%% request sender of the load generators, the same for every transport.
%% It runs in the agent's process once connected, and obeys the benchmark's
%% controller:
%%
%% - `{closed, Counters | {persistent, Key}, W}': closed loop, W requests in
%%   flight, the next sent as soon as an answer comes; each successful
%%   round trip adds 1 to counter `index' (a counters reference only works
%%   on the node that made it: another node passes a persistent_term key);
%% - `stop_loop': ends the closed loop; once the open requests are answered
%%   (or after 15 s) the controller gets `{self(), drained, #{errors,
%%   timeouts, unanswered}}';
%% - `{open, Plan}': open loop, request k due at start + phase + k *
%%   interval whatever happened to the earlier ones, due times on whole
%%   milliseconds (Erlang timers' resolution), latency counted from the due
%%   time (no coordinated omission); at the end the controller gets
%%   `{self(), samples, #{latencies, send_lags, errors, timeouts,
%%   unanswered}}' for the requests due inside the window, each latency as
%%   `{DueUs, LatencyUs}' so that a stall can be told from a spread tail.
%%   Plan:
%%   `#{start := Ms, interval := Us, phase := Us, until := Ms, window :=
%%   {FromUs, ToUs}}';
%% - `stop', or the controller going down: exits.
%%
%% The transport is two funs: `send(K)' sends request number K, and
%% `answer(Msg)' tells whether a message answers request K (`{K, ok}', or
%% `{K, error}' for an error signal, `{K, timeout}' for EVATAR's Timeout
%% feedback), or is something else (`ignore').
-module(bench_requester).

-export([run/1]).

-export_type([driver/0]).

-type kind() :: ok | error | timeout.
-type driver() :: #{parent := pid(),
                    index := pos_integer(),
                    send := fun((pos_integer()) -> ok),
                    answer := fun((term()) -> {pos_integer(), kind()} | ignore)}.

-define(DRAIN_TIMEOUT, 15000).

-record(r, {parent :: pid(),
            index :: pos_integer(),
            send :: fun((pos_integer()) -> ok),
            answer :: fun((term()) -> {pos_integer(), kind()} | ignore),
            counters :: counters:counters_ref() | undefined,
            next = 1 :: pos_integer(),
            %% request number => scheduled (open loop) or send time, in µs
            inflight = #{} :: #{pos_integer() => integer()},
            errors = 0 :: non_neg_integer(),
            timeouts = 0 :: non_neg_integer()}).

%% @doc Serves the controller until told to stop. The caller should
%% monitor the controller first.
-spec run(driver()) -> no_return().
run(#{parent := Parent, index := I, send := Send, answer := Answer}) ->
    idle(#r{parent = Parent, index = I, send = Send, answer = Answer}).

%% Between phases: waits for the controller's next command.
idle(R) ->
    receive
        {closed, CountersOrKey, W} ->
            Counters = case CountersOrKey of
                           {persistent, Key} -> persistent_term:get(Key);
                           C -> C
                       end,
            R1 = lists:foldl(fun(_, Acc) -> send_request(now_us(), Acc) end,
                             R#r{counters = Counters}, lists:seq(1, W)),
            closed(R1);
        {open, Plan} ->
            open(Plan, R);
        stop ->
            exit(normal);
        {'DOWN', _, process, _, _} ->
            exit(normal);
        Msg ->
            case answer(Msg, R) of
                {_, _, R1} -> idle(R1);
                ignore -> idle(R)
            end
    end.

closed(#r{counters = Counters, index = I} = R) ->
    receive
        stop_loop ->
            drain(R, now_us() + ?DRAIN_TIMEOUT * 1000);
        {'DOWN', _, process, _, _} ->
            exit(normal);
        Msg ->
            case answer(Msg, R) of
                {ok, _, R1} ->
                    ok = counters:add(Counters, I, 1),
                    closed(send_request(now_us(), R1));
                {_, _, R1} ->
                    closed(send_request(now_us(), R1));
                ignore ->
                    closed(R)
            end
    end.

drain(#r{inflight = F, parent = Parent} = R, Deadline)
  when map_size(F) =:= 0; Deadline =:= expired ->
    Parent ! {self(), drained, #{errors => R#r.errors, timeouts => R#r.timeouts,
                                 unanswered => map_size(F)}},
    idle(R#r{inflight = #{}, errors = 0, timeouts = 0});
drain(R, Deadline) ->
    receive
        Msg ->
            case answer(Msg, R) of
                {_, _, R1} -> drain(R1, Deadline);
                ignore -> drain(R, Deadline)
            end
    after wait_ms(Deadline) ->
            drain(R, expired)
    end.

open(#{start := StartMs, phase := Phase} = Plan, R) ->
    open(Plan, StartMs * 1000 + Phase, R, [], []).

open(#{until := Until} = Plan, DueUs, R, Lat, Lag) ->
    case DueUs div 1000 >= Until of
        true ->
            open_drain(Plan, R, Lat, Lag, now_us() + ?DRAIN_TIMEOUT * 1000);
        false ->
            TRef = erlang:start_timer(DueUs div 1000, self(), due, [{abs, true}]),
            open_wait(Plan, DueUs, TRef, R, Lat, Lag)
    end.

open_wait(#{window := {From, To}} = Plan, DueUs, TRef, R, Lat, Lag) ->
    receive
        {timeout, TRef, due} ->
            {Due1, R1, Lag1} = send_due(Plan, DueUs, R, Lag),
            open(Plan, Due1, R1, Lat, Lag1);
        {'DOWN', _, process, _, _} ->
            exit(normal);
        Msg ->
            case answer(Msg, R) of
                {_, S, R1} when S >= From, S < To ->
                    open_wait(Plan, DueUs, TRef, R1, [{S, now_us() - S} | Lat], Lag);
                {_, _, R1} ->
                    open_wait(Plan, DueUs, TRef, R1, Lat, Lag);
                ignore ->
                    open_wait(Plan, DueUs, TRef, R, Lat, Lag)
            end
    end.

%% Every request whose due millisecond has come goes now.
send_due(#{interval := Interval, window := {From, To}} = Plan, DueUs, R, Lag) ->
    Now = now_us(),
    Sched = DueUs div 1000 * 1000,
    case Sched =< Now of
        true ->
            Lag1 = case Sched >= From andalso Sched < To of
                       true -> [Now - Sched | Lag];
                       false -> Lag
                   end,
            send_due(Plan, DueUs + Interval, send_request(Sched, R), Lag1);
        false ->
            {DueUs, R, Lag}
    end.

open_drain(#{window := {From, To}}, #r{inflight = F, parent = Parent} = R, Lat, Lag, Deadline)
  when map_size(F) =:= 0; Deadline =:= expired ->
    Lost = length([S || S <- maps:values(F), S >= From, S < To]),
    Parent ! {self(), samples, #{latencies => Lat, send_lags => Lag, errors => R#r.errors,
                                 timeouts => R#r.timeouts, unanswered => Lost}},
    idle(R#r{inflight = #{}, errors = 0, timeouts = 0});
open_drain(#{window := {From, To}} = Plan, R, Lat, Lag, Deadline) ->
    receive
        Msg ->
            case answer(Msg, R) of
                {_, S, R1} when S >= From, S < To ->
                    open_drain(Plan, R1, [{S, now_us() - S} | Lat], Lag, Deadline);
                {_, _, R1} ->
                    open_drain(Plan, R1, Lat, Lag, Deadline);
                ignore ->
                    open_drain(Plan, R, Lat, Lag, Deadline)
            end
    after wait_ms(Deadline) ->
            open_drain(Plan, R, Lat, Lag, expired)
    end.

%% Monotonic time can be negative: a deadline is compared, never tested
%% against zero.
wait_ms(Deadline) -> max(0, (Deadline - now_us()) div 1000).

now_us() -> erlang:monotonic_time(microsecond).

%% Sends request number `next', remembering Sched (its due or send time).
send_request(Sched, #r{send = Send, next = K, inflight = F} = R) ->
    ok = Send(K),
    R#r{next = K + 1, inflight = F#{K => Sched}}.

%% `{Kind, Sched, R}' for the answer to an open request, else `ignore'.
answer(Msg, #r{answer = Answer, inflight = F} = R) ->
    case Answer(Msg) of
        ignore ->
            ignore;
        {K, Kind} ->
            case maps:take(K, F) of
                {Sched, F1} ->
                    R1 = R#r{inflight = F1},
                    case Kind of
                        ok -> {ok, Sched, R1};
                        error -> {error, Sched, R1#r{errors = R#r.errors + 1}};
                        timeout -> {timeout, Sched, R1#r{timeouts = R#r.timeouts + 1}}
                    end;
                error ->
                    ignore
            end
    end.

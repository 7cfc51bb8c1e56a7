%% @doc Test support: waiting for a condition with a deadline. The one
%% `wait_until' of the suites (apps/evatar_test_kit/README.md): a probe is
%% polled until it holds or the deadline passes; on failure the reason says
%% what was awaited, for how long, and the last value the probe saw, so a
%% failed wait reads as a finding rather than `{error, timeout}'.
%%
%% A probe returns `true' (done), `false' (not yet), or `{false, Seen}' (not
%% yet, and Seen is worth showing if the wait fails). until/1,2 raise on
%% timeout; poll/1,2 return `{error, ...}' for callers that handle it.
%%
%% The deadline only guards against a hang: by default the scale's hang
%% guard (evatar_test_time:guard/0, 60 s at scale 1), the same for every
%% suite, so that a wait's length never decides whether a case passes. A
%% suite has no wait_until of its own: it calls this module.
%%
%% A case that checks that a process sent nothing more waits for the
%% process to end, not for a quiet time: gone/1, then mailbox/1. A
%% process's 'DOWN' comes after every message it sent to the monitoring
%% process, so what is not in the mailbox then never comes.
-module(evatar_test_wait).

-export([until/1, until/2, poll/1, poll/2, value/3, value/4, gone/1, mailbox/1]).
-export_type([probe/0, opts/0, failure/0]).

-type probe() :: fun(() -> boolean() | {false, term()}).
%% timeout: ms until the deadline (default evatar_test_time:guard/0);
%% interval: ms between polls (default 20); what: a term naming what is
%% awaited (default: the probe's module and enclosing function).
-type opts() :: #{timeout => non_neg_integer(), interval => pos_integer(), what => term()}.
-type failure() :: {wait_timeout, #{what := term(), waited_ms := non_neg_integer(),
                                    last_seen := term(), polls := pos_integer()}}.

-define(INTERVAL, 20).

%% @doc ok once Probe holds, within the hang guard; otherwise raises failure().
-spec until(probe()) -> ok.
until(Probe) ->
    until(Probe, #{}).

%% @doc ok once Probe holds within the options' deadline; otherwise raises
%% `error(failure())', which fails a Common Test case or an EUnit test with
%% what was awaited and the last value seen.
-spec until(probe(), opts()) -> ok.
until(Probe, Opts) ->
    case poll(Probe, Opts) of
        ok -> ok;
        {error, Failure} -> erlang:error(Failure)
    end.

%% @doc As until/1, but returns the failure: for a caller that prints more
%% context first.
-spec poll(probe()) -> ok | {error, failure()}.
poll(Probe) ->
    poll(Probe, #{}).

%% @doc As until/2, but returns the failure: for a caller that prints more
%% context first, or for a wait whose timeout is not a failure.
-spec poll(probe(), opts()) -> ok | {error, failure()}.
poll(Probe, Opts) ->
    Timeout = maps:get(timeout, Opts, evatar_test_time:guard()),
    Interval = maps:get(interval, Opts, ?INTERVAL),
    Start = erlang:monotonic_time(millisecond),
    loop(Probe, Start, Start + Timeout, Interval, 1, Opts).

%% @doc ok once Pid has ended (at once if it has), within the hang guard:
%% every message Pid sent to the caller is then in the caller's mailbox
%% (for a Pid of another node, provided it was alive when gone/1 was called).
-spec gone(pid()) -> ok.
gone(Pid) ->
    Ref = erlang:monitor(process, Pid),
    receive
        {'DOWN', Ref, process, Pid, _} -> ok
    after evatar_test_time:guard() ->
            erlang:demonitor(Ref, [flush]),
            erlang:error({wait_timeout, #{what => {gone, Pid},
                                          waited_ms => evatar_test_time:guard(),
                                          last_seen => [erlang:process_info(Pid, current_stacktrace)
                                                        || node(Pid) =:= node()],
                                          polls => 1}})
    end.

%% @doc The messages now in the caller's mailbox that satisfy Pred, left
%% where they are.
-spec mailbox(fun((term()) -> boolean())) -> [term()].
mailbox(Pred) ->
    {messages, Ms} = erlang:process_info(self(), messages),
    [M || M <- Ms, Pred(M)].

%% @doc The value Fun returns once Pred holds for it, within the hang guard;
%% otherwise raises failure() with the last value.
-spec value(term(), fun(() -> V), fun((V) -> boolean())) -> V.
value(What, Fun, Pred) ->
    value(What, Fun, Pred, #{}).

%% @doc value/3 with the options of until/2 (`what' is the first argument).
-spec value(term(), fun(() -> V), fun((V) -> boolean()), opts()) -> V.
value(What, Fun, Pred, Opts) ->
    Self = self(),
    Ref = make_ref(),
    Probe = fun() ->
                    V = Fun(),
                    case Pred(V) of
                        true -> Self ! {Ref, V}, true;
                        false -> {false, V}
                    end
            end,
    ok = until(Probe, Opts#{what => What}),
    receive {Ref, V} -> V end.

loop(Probe, Start, Deadline, Interval, Polls, Opts) ->
    case Probe() of
        true -> ok;
        false -> again(Probe, Start, Deadline, Interval, Polls, Opts, false);
        {false, Seen} -> again(Probe, Start, Deadline, Interval, Polls, Opts, Seen)
    end.

again(Probe, Start, Deadline, Interval, Polls, Opts, Seen) ->
    Now = erlang:monotonic_time(millisecond),
    case Now >= Deadline of
        true ->
            {error, {wait_timeout, #{what => what(Probe, Opts), waited_ms => Now - Start,
                                     last_seen => Seen, polls => Polls}}};
        false ->
            timer:sleep(min(Interval, Deadline - Now)),
            loop(Probe, Start, Deadline, Interval, Polls + 1, Opts)
    end.

%% Without a `what', the probe's origin: its module and the function it was
%% written in (the test case, for a fun written there).
what(_Probe, #{what := What}) ->
    What;
what(Probe, #{}) ->
    {module, M} = erlang:fun_info(Probe, module),
    {name, Name} = erlang:fun_info(Probe, name),
    {probe_in, M, Name}.

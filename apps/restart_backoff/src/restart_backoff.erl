%% @doc Pure restart policy of the node's kept processes (an MQTT Avatar's
%% mqtt_avatar_keeper, a bridge listener's agent_bridge_listener_keeper):
%% how long to wait before the next start, and when a run of short-lived
%% starts is a crash loop worth a warning. A library application of its
%% own so that both apps share it without depending on each other.
%%
%% The delay starts at `min_ms' and doubles after each run shorter than
%% `stable_after_ms', up to `max_ms'; a run that lasted `stable_after_ms' or
%% more starts the count over. `loop_after' short runs in a row are a crash
%% loop: it is reported at that exit and at every further short one.
-module(restart_backoff).

-export([new/1, check/1, exited/2, crashes/1, next_delay/1, defaults/0]).

-export_type([backoff/0, opts/0, effect/0]).

-type opts() :: #{min_ms => pos_integer(), max_ms => pos_integer(),
                  stable_after_ms => pos_integer(), loop_after => pos_integer()}.
-opaque backoff() :: #{min := pos_integer(), max := pos_integer(), stable := pos_integer(),
                       loop := pos_integer(), delay := pos_integer(),
                       crashes := non_neg_integer()}.
-type effect() :: none | {crash_loop, #{crashes := pos_integer(), delay_ms := pos_integer()}}.

%% @doc The defaults: 1 s doubling to 60 s, a run of 60 s is stable, three
%% short runs in a row are a crash loop.
-spec defaults() -> #{min_ms := pos_integer(), max_ms := pos_integer(),
                      stable_after_ms := pos_integer(), loop_after := pos_integer()}.
defaults() ->
    #{min_ms => 1000, max_ms => 60000, stable_after_ms => 60000, loop_after => 3}.

%% @doc Whether Opts is a policy's options: a map of the four keys (each
%% optional), each a positive integer; the error names the first wrong one.
-spec check(term()) -> ok | {error, binary()}.
check(Opts) when is_map(Opts) ->
    Keys = maps:keys(defaults()),
    case [K || K <- maps:keys(Opts), not lists:member(K, Keys)] of
        [Unknown | _] ->
            {error, iolist_to_binary(io_lib:format("unknown restart option ~0tp (known: ~0tp)",
                                                   [Unknown, Keys]))};
        [] ->
            case [K || {K, V} <- maps:to_list(Opts), not (is_integer(V) andalso V > 0)] of
                [] -> ok;
                [Bad | _] -> {error, iolist_to_binary(io_lib:format("restart option ~0tp must be a "
                                                                    "positive integer", [Bad]))}
            end
    end;
check(_Opts) ->
    {error, <<"restart must be a map of min_ms, max_ms, stable_after_ms and loop_after">>}.

%% @doc A policy from Opts (missing keys take the defaults).
-spec new(opts()) -> backoff().
new(Opts) ->
    #{min_ms := Min, max_ms := Max, stable_after_ms := Stable, loop_after := Loop} =
        maps:merge(defaults(), Opts),
    #{min => Min, max => max(Min, Max), stable => Stable, loop => Loop, delay => Min, crashes => 0}.

%% @doc A run that lasted `RanMs' ended: the delay before the next start,
%% whether to report a crash loop, and the new state.
-spec exited(non_neg_integer(), backoff()) -> {pos_integer(), effect(), backoff()}.
exited(RanMs, #{stable := Stable, min := Min} = B) when RanMs >= Stable ->
    {Min, none, B#{crashes := 1, delay := double(Min, B)}};
exited(_RanMs, #{delay := Delay, crashes := Crashes, loop := Loop} = B) ->
    N = Crashes + 1,
    Effect = case N >= Loop of
                 true -> {crash_loop, #{crashes => N, delay_ms => Delay}};
                 false -> none
             end,
    {Delay, Effect, B#{crashes := N, delay := double(Delay, B)}}.

%% @doc Short runs in a row so far.
-spec crashes(backoff()) -> non_neg_integer().
crashes(#{crashes := N}) -> N.

%% @doc The delay the next short run would get.
-spec next_delay(backoff()) -> pos_integer().
next_delay(#{delay := D}) -> D.

double(Delay, #{max := Max}) -> min(Max, Delay * 2).

%% @doc Test support: the one time scale of the suites. Every real-time
%% figure a suite gives EVATAR (HA timings, protocol timeouts) or waits with
%% (hang guards) comes from here, multiplied by one scale, so that a slow
%% machine is handled in one place rather than by lengthening timeouts one
%% by one:
%%
%% `EVATAR_TEST_SCALE' (a positive number, default 1) sets it: on a slow
%% or busy machine, `EVATAR_TEST_SCALE=3 make test' gives EVATAR and the
%% waits three times the time, in every suite at once. It is not raised by
%% itself: every HA suite then takes about as many times as long (at 8,
%% ha_SUITE's first four cases took 9 minutes instead of about one), which
%% `make test''s time budget cannot afford on every run.
%%
%% The figures keep their ratios under any scale, so what EVATAR checks
%% between them (suspect_ms against heartbeat_ms, lease_ms against
%% suspect_ms: evatar_ha_logic) holds whatever the scale. A case that
%% tests a timeout's length itself takes the scaled figure and asserts
%% only the order of events, never a duration.
-module(evatar_test_time).

-export([scale/0, ms/1, guard/0, ha_timing/0, ha_timing/1]).

-define(KEY, {?MODULE, scale}).
%% The suites' detection timings: on a loaded machine the release's
%% 50/250/150 ms suspect live nodes, and a needless takeover moves the
%% pairings a scenario placed.
-define(HA, #{heartbeat_ms => 100, suspect_ms => 1000, lease_ms => 600}).
%% A wait's hang guard: long enough that only a hang reaches it.
-define(GUARD, 60000).

%% @doc The scale: EVATAR_TEST_SCALE, default 1; read once per node.
-spec scale() -> number().
scale() ->
    case persistent_term:get(?KEY, undefined) of
        undefined ->
            S = base(),
            persistent_term:put(?KEY, S),
            S;
        S ->
            S
    end.

%% @doc Ms milliseconds on the scale, rounded.
-spec ms(non_neg_integer()) -> non_neg_integer().
ms(Ms) ->
    round(Ms * scale()).

%% @doc The hang guard of a wait for an event (60 s on the scale).
-spec guard() -> pos_integer().
guard() ->
    ms(?GUARD).

%% @doc The suites' HA timings as evatar's environment: heartbeat_ms 100,
%% suspect_ms 1000, lease_ms 600, on the scale.
-spec ha_timing() -> [{atom(), pos_integer()}].
ha_timing() ->
    ha_timing(#{}).

%% @doc ha_timing/0 with some of the three figures replaced (unscaled
%% milliseconds, scaled like the others).
-spec ha_timing(#{heartbeat_ms => pos_integer(), suspect_ms => pos_integer(),
                  lease_ms => pos_integer()}) -> [{atom(), pos_integer()}].
ha_timing(Override) ->
    [{K, ms(V)} || {K, V} <- lists:sort(maps:to_list(maps:merge(?HA, Override)))].

base() ->
    case os:getenv("EVATAR_TEST_SCALE") of
        false ->
            1;
        Text ->
            case string:to_float(Text) of
                {F, []} when F > 0 -> F;
                _ ->
                    case string:to_integer(Text) of
                        {I, []} when I > 0 -> I;
                        _ -> erlang:error({bad_env, "EVATAR_TEST_SCALE", Text,
                                           "a positive number"})
                    end
            end
    end.

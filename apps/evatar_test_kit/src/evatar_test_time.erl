%% @doc Test support: the one time scale of the suites. Every real-time
%% figure a suite gives EVATAR (HA timings, protocol timeouts) or waits with
%% (hang guards) comes from here, multiplied by one scale, so that a slow
%% machine is handled in one place rather than by lengthening timeouts one
%% by one:
%%
%% `EVATAR_TEST_SCALE' (a positive number) sets it: on a slow or busy
%% machine, `EVATAR_TEST_SCALE=3 make test' gives EVATAR and the waits
%% three times the time, in every suite at once. Without it the scale is 1,
%% raised by itself to 3 on a node that runs cover-compiled code (`make
%% test''s Common Test and EUnit, `rebar3 ct --cover'): every line counted
%% makes that node's EVATAR and clients slower, and the protocol timeouts a
%% suite gives them (ms/1) and its hang guards (guard/0) grow with it.
%%
%% The HA timings (ha_timing/0,1) are for the nodes of the cluster harness,
%% which run the plain beams, never cover's: they follow EVATAR_TEST_SCALE
%% only, and so does cluster_ms/1, for a figure that must keep its place
%% among them (a pause longer than the lease but shorter than suspect_ms, a
%% partition that outlasts an election, a timeout given to those nodes).
%% Raising them costs time, as every HA suite then takes about as many
%% times as long (at 8, ha_SUITE's first four cases took 9 minutes instead
%% of about one), which `make test''s budget cannot afford on every run.
%%
%% The figures keep their ratios under any scale, so what EVATAR checks
%% between them (suspect_ms against heartbeat_ms, lease_ms against
%% suspect_ms: evatar_ha_logic) holds whatever the scale. A case that
%% tests a timeout's length itself takes the scaled figure and asserts
%% only the order of events, never a duration.
-module(evatar_test_time).

-export([scale/0, cluster_scale/0, ms/1, cluster_ms/1, guard/0, ha_timing/0, ha_timing/1]).

-define(KEY, {?MODULE, scale}).
%% The scale of a node running cover-compiled code, unless EVATAR_TEST_SCALE
%% says otherwise.
-define(COVER, 3).
%% The suites' detection timings: on a loaded machine the release's
%% 50/250/150 ms suspect live nodes, and a needless takeover moves the
%% pairings a scenario placed.
-define(HA, #{heartbeat_ms => 100, suspect_ms => 1000, lease_ms => 600}).
%% A wait's hang guard: long enough that only a hang reaches it.
-define(GUARD, 60000).

%% @doc This node's scale: EVATAR_TEST_SCALE; without it 3 when this node
%% runs cover-compiled code, else 1. Read once per node.
-spec scale() -> number().
scale() ->
    case persistent_term:get(?KEY, undefined) of
        undefined ->
            S = case given() of
                    undefined -> own_default();
                    Given -> Given
                end,
            persistent_term:put(?KEY, S),
            S;
        S ->
            S
    end.

%% @doc The scale of the cluster harness's nodes (plain beams):
%% EVATAR_TEST_SCALE, default 1.
-spec cluster_scale() -> number().
cluster_scale() ->
    case given() of
        undefined -> 1;
        Given -> Given
    end.

%% @doc Ms milliseconds on the scale, rounded.
-spec ms(non_neg_integer()) -> non_neg_integer().
ms(Ms) ->
    round(Ms * scale()).

%% @doc Ms milliseconds on the cluster's scale (the one of ha_timing/0),
%% rounded.
-spec cluster_ms(non_neg_integer()) -> non_neg_integer().
cluster_ms(Ms) ->
    round(Ms * cluster_scale()).

%% @doc The hang guard of a wait for an event (60 s on the scale).
-spec guard() -> pos_integer().
guard() ->
    ms(?GUARD).

%% @doc The suites' HA timings as evatar's environment: heartbeat_ms 100,
%% suspect_ms 1000, lease_ms 600, on the cluster's scale.
-spec ha_timing() -> [{atom(), pos_integer()}].
ha_timing() ->
    ha_timing(#{}).

%% @doc ha_timing/0 with some of the three figures replaced (unscaled
%% milliseconds, scaled like the others).
-spec ha_timing(#{heartbeat_ms => pos_integer(), suspect_ms => pos_integer(),
                  lease_ms => pos_integer()}) -> [{atom(), pos_integer()}].
ha_timing(Override) ->
    [{K, cluster_ms(V)} || {K, V} <- lists:sort(maps:to_list(maps:merge(?HA, Override)))].

own_default() ->
    case lists:any(fun(M) -> code:which(M) =:= cover_compiled end, [evatar, agent_bridge, bil]) of
        true -> ?COVER;
        false -> 1
    end.

given() ->
    case os:getenv("EVATAR_TEST_SCALE") of
        false ->
            undefined;
        "" ->
            undefined;
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

%% @doc Test support: runs a PropEr property inside a Common Test case or an
%% EUnit test (apps/evatar_test_kit/README.md). PropEr's output goes to the
%% terminal (`{to_file, user}'), and a failure fails the case with the
%% shrunk counterexample in its reason, not a bare `false'.
%%
%% The number of runs can be scaled for a soak without editing suites:
%% EVATAR_PROPER_FACTOR=10 runs every property ten times as often (at
%% least once); unset, each runs the count its suite gives.
-module(evatar_test_proper).

-export([check/2, check/3, numtests/1]).

%% @doc ok when Prop holds for NumTests (scaled) generated cases; otherwise
%% the case fails with `{counterexample, CounterExample}'.
-spec check(proper:outer_test(), pos_integer()) -> ok.
check(Prop, NumTests) ->
    check(Prop, NumTests, []).

%% @doc check/2 with more PropEr options (e.g. `{max_size, 20}').
-spec check(proper:outer_test(), pos_integer(), [term()]) -> ok.
check(Prop, NumTests, Opts) ->
    case proper:quickcheck(Prop, [{numtests, numtests(NumTests)}, {to_file, user},
                                  long_result | Opts]) of
        true -> ok;
        CounterExample -> exit({test_case_failed, {counterexample, CounterExample}})
    end.

%% @doc NumTests scaled by EVATAR_PROPER_FACTOR (a positive number).
-spec numtests(pos_integer()) -> pos_integer().
numtests(NumTests) ->
    case os:getenv("EVATAR_PROPER_FACTOR") of
        false ->
            NumTests;
        Factor ->
            F = try list_to_float(Factor) catch error:badarg -> list_to_integer(Factor) end,
            max(1, round(NumTests * F))
    end.

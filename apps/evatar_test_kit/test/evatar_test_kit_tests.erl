%% @doc The shared helpers fail when they should, with the reason their
%% docs promise: a helper that cannot fail would make every test that
%% uses it unable to fail.
-module(evatar_test_kit_tests).

-include_lib("proper/include/proper.hrl").
-include_lib("eunit/include/eunit.hrl").

until_returns_once_the_probe_holds_test() ->
    Counter = counters:new(1, []),
    ok = evatar_test_wait:until(fun() -> counters:add(Counter, 1, 1),
                                         counters:get(Counter, 1) >= 3 end,
                                #{interval => 1}),
    ?assertEqual(3, counters:get(Counter, 1)).

until_fails_with_what_and_the_last_value_test() ->
    {'EXIT', {{wait_timeout, #{what := answer, last_seen := 42, polls := Polls,
                               waited_ms := Waited}}, _}} =
        catch evatar_test_wait:until(fun() -> {false, 42} end,
                                     #{timeout => 50, interval => 5, what => answer}),
    ?assert(Polls >= 2),
    ?assert(Waited >= 50).

until_names_the_probe_without_a_what_test() ->
    {error, {wait_timeout, #{what := {probe_in, ?MODULE, Name}, last_seen := false}}} =
        evatar_test_wait:poll(fun() -> false end, #{timeout => 0}),
    ?assertNotEqual(nomatch, string:find(atom_to_list(Name),
                                         "until_names_the_probe_without_a_what_test")).

value_returns_the_first_good_value_test() ->
    Counter = counters:new(1, []),
    Next = fun() -> counters:add(Counter, 1, 1), counters:get(Counter, 1) end,
    ?assertEqual(4, evatar_test_wait:value(count, Next, fun(N) -> N >= 4 end)),
    ?assertError({wait_timeout, #{what := count, last_seen := 7}},
                 evatar_test_wait:value(count, fun() -> 7 end, fun(N) -> N > 7 end,
                                        #{timeout => 20})).

proper_check_passes_a_true_property_test() ->
    ok = evatar_test_proper:check(?FORALL(X, integer(), X + 0 =:= X), 50).

proper_check_fails_with_the_counterexample_test() ->
    {'EXIT', {test_case_failed, {counterexample, [N]}}} =
        catch evatar_test_proper:check(?FORALL(X, integer(), X < 10), 500),
    %% Shrunk to the smallest integer that breaks it.
    ?assertEqual(10, N).

proper_factor_scales_numtests_test() ->
    Old = os:getenv("EVATAR_PROPER_FACTOR"),
    try
        true = os:putenv("EVATAR_PROPER_FACTOR", "0.5"),
        ?assertEqual(50, evatar_test_proper:numtests(100)),
        true = os:putenv("EVATAR_PROPER_FACTOR", "3"),
        ?assertEqual(300, evatar_test_proper:numtests(100)),
        true = os:unsetenv("EVATAR_PROPER_FACTOR"),
        ?assertEqual(100, evatar_test_proper:numtests(100))
    after
        Old =:= false orelse os:putenv("EVATAR_PROPER_FACTOR", Old)
    end.

secrets_differ_test() ->
    ?assertEqual(48, length(evatar_test_fixtures:secret())),
    ?assertNotEqual(evatar_test_fixtures:secret(), evatar_test_fixtures:secret()).

%% Every harness's nodes get the cookie, distribution on the one interface
%% (loopback unless told), the port when one is given, and the code path.
cluster_node_args_test() ->
    ?assertEqual(["-setcookie", "c1", "-kernel", "inet_dist_use_interface", "{127,0,0,1}",
                  "-kernel", "prevent_overlapping_partitions", "false", "-pa", "/a", "-pa", "/b"],
                 evatar_test_cluster:node_args(#{cookie => c1, code_path => ["/a", "/b"]})),
    ?assertEqual(["-setcookie", "c2", "-kernel", "inet_dist_use_interface", "{10,7,0,2}",
                  "-kernel", "prevent_overlapping_partitions", "false",
                  "-kernel", "inet_dist_listen_min", "4370",
                  "-kernel", "inet_dist_listen_max", "4370"],
                 evatar_test_cluster:node_args(#{cookie => c2, code_path => [],
                                                 interface => {10, 7, 0, 2},
                                                 dist_port => 4370})).

%% The code path holds the apps a node runs, the kit and the callers' dirs.
cluster_code_path_test() ->
    Path = evatar_test_cluster:code_path([?MODULE]),
    [?assert(lists:member(filename:join(code:lib_dir(App), "ebin"), Path))
     || App <- [evatar, agent_bridge, evatar_test_kit]],
    ?assert(lists:member(filename:dirname(code:which(?MODULE)), Path)).

%% The partition and rebalancing figures: the longest gap between round
%% trips that begins at or after the last one before the cut, up to the
%% last one; `never' when none came after the cut.
partition_unserved_test() ->
    H = fun(Times) -> #{received_at => maps:from_list(
                                          [{<<"fb-", (integer_to_binary(T))/binary>>, [T, T + 500]}
                                           || T <- Times])}
        end,
    %% Cut at 100: 90 is the last round trip before it; 90 -> 400 is the gap.
    ?assertEqual(310, evatar_test_partition:unserved(H([10, 50, 90, 400, 420]), 100)),
    %% A long gap before the cut does not count.
    ?assertEqual(20, evatar_test_partition:unserved(H([0, 80, 90, 110]), 100)),
    ?assertEqual(never, evatar_test_partition:unserved(H([10, 50]), 100)),
    %% Signals other than feedback (sensor data) are not round trips.
    ?assertEqual(310, evatar_test_partition:unserved(
                        (H([90, 400]))#{received_at := #{<<"fb-a">> => [90], <<"s-1">> => [200],
                                                         <<"fb-b">> => [400]}}, 100)).

%% The `none' backend refuses a cut, and a heal with nothing cut is ok.
cluster_net_none_refuses_cuts_test() ->
    Ctx = #{names => #{}, cookie => c, call => fun(_, _, _, _) -> error(no_call) end},
    ?assertEqual({ok, none}, evatar_test_net_none:cut([], Ctx, none)),
    ?assertEqual({{error, {unsupported, none}}, none}, evatar_test_net_none:cut([{1, 2}], Ctx, none)),
    ?assertEqual({ok, none}, evatar_test_net_none:heal(flush, Ctx, none)).

%% The public_key fallback for the broker's TLS CA makes a CA that a client
%% verifying the server (and its 127.0.0.1 address) accepts.
mosquitto_public_key_ca_verifies_test_() ->
    case evatar_test_mosquitto:available() of
        false ->
            [];
        true ->
            {timeout, 60,
             fun() ->
                     {ok, B} = evatar_test_mosquitto:start(#{tls => true, cert_tool => public_key}),
                     try
                         {ok, _} = application:ensure_all_started(ssl),
                         #{tls_port := Port, cacertfile := Ca} = B,
                         {ok, S} = ssl:connect({127, 0, 0, 1}, Port,
                                               [{verify, verify_peer}, {cacertfile, Ca},
                                                {server_name_indication, disable}], 10000),
                         ok = ssl:close(S)
                     after
                         ok = evatar_test_mosquitto:stop(B)
                     end
             end}
    end.

%% ---------------------------------------------------------------------------
%% evatar_test_trace, evatar_test_time
%% ---------------------------------------------------------------------------

trace_test_() ->
    {foreach, fun trace_setup/0, fun trace_cleanup/1,
     [fun trace_waits_for_a_later_report/1,
      fun trace_finds_a_report_already_there/1,
      fun trace_since_a_mark_ignores_earlier_reports/1,
      fun trace_count_and_predicate/1,
      fun trace_times_out_saying_what_it_saw/1]}.

trace_setup() ->
    {ok, T} = evatar_test_trace:start(),
    ok = evatar_test_trace:attach(T),
    T.

trace_cleanup(T) ->
    ok = evatar_test_trace:stop(T).

trace_waits_for_a_later_report(T) ->
    Self = self(),
    _ = spawn(fun() -> Self ! go, logger:info(#{what => kit_later, n => 1}) end),
    receive go -> ok end,
    ?_assertMatch(#{node := N, level := info, report := #{what := kit_later, n := 1}}
                      when N =:= node(),
                  evatar_test_trace:wait(T, #{what => kit_later})).

trace_finds_a_report_already_there(T) ->
    logger:info(#{what => kit_before, pairing => <<"p">>}),
    %% A report without `what' is not a trace point.
    logger:info(#{pairing => <<"p">>}),
    #{seq := Seq} = evatar_test_trace:wait(T, #{what => kit_before, pairing => '_'}),
    [?_assertEqual(1, Seq),
     ?_assertEqual(1, length(evatar_test_trace:events(T, #{pairing => <<"p">>}))),
     ?_assertEqual([], evatar_test_trace:events(T, #{pairing => <<"p">>}, #{node => 'other@host'})),
     ?_assertEqual([], evatar_test_trace:events(T, #{pairing => <<"p">>}, #{since => Seq}))].

trace_since_a_mark_ignores_earlier_reports(T) ->
    logger:info(#{what => kit_step, n => 1}),
    _ = evatar_test_trace:wait(T, #{what => kit_step}),
    Mark = evatar_test_trace:mark(T),
    logger:info(#{what => kit_step, n => 2}),
    ?_assertMatch(#{report := #{n := 2}},
                  evatar_test_trace:wait(T, #{what => kit_step}, #{since => Mark})).

trace_count_and_predicate(T) ->
    _ = [logger:info(#{what => kit_count, n => N}) || N <- lists:seq(1, 5)],
    Odd = fun(#{what := kit_count, n := N}) -> N rem 2 =:= 1; (_) -> false end,
    Events = evatar_test_trace:wait(T, Odd, #{count => 3}),
    ?_assertEqual([1, 3, 5], [N || #{report := #{n := N}} <- Events]).

trace_times_out_saying_what_it_saw(T) ->
    logger:info(#{what => kit_seen}),
    _ = evatar_test_trace:wait(T, #{what => kit_seen}),
    ?_assertError({trace_timeout, #{what := never, seen := [{_, kit_seen}]}},
                  evatar_test_trace:wait(T, #{what => kit_never}, #{timeout => 20, what => never})).

%% Attaching lowers a stricter primary level to info for the trace, keeps
%% the default handler's output as it was, and detaching puts both back.
trace_levels_restored_test() ->
    #{level := Primary} = logger:get_primary_config(),
    try
        ok = logger:set_primary_config(level, notice),
        {ok, T} = evatar_test_trace:start(),
        ok = evatar_test_trace:attach(T),
        ?assertMatch(#{level := info}, logger:get_primary_config()),
        logger:info(#{what => kit_info}),
        ?assertMatch(#{report := #{what := kit_info}}, evatar_test_trace:wait(T, #{what => kit_info})),
        ok = evatar_test_trace:stop(T),
        ?assertMatch(#{level := notice}, logger:get_primary_config())
    after
        logger:set_primary_config(level, Primary)
    end.

time_scale_keeps_ratios_test() ->
    S = evatar_test_time:scale(),
    ?assert(S >= 1),
    C = evatar_test_time:cluster_scale(),
    ?assert(C >= 1 andalso C =< S),
    Timing = maps:from_list(evatar_test_time:ha_timing()),
    ?assertEqual(round(1000 * C), maps:get(suspect_ms, Timing)),
    ?assertEqual(round(100 * C), maps:get(heartbeat_ms, Timing)),
    ?assertEqual(round(2000 * C),
                 maps:get(suspect_ms, maps:from_list(evatar_test_time:ha_timing(#{suspect_ms => 2000})))),
    ?assertEqual(evatar_test_time:ms(60000), evatar_test_time:guard()).

%% Cover-compiled code runs slower: the scale rises by itself, the
%% cluster's (plain beams) does not.
time_scale_rises_under_cover_test() ->
    Covered = code:which(evatar) =:= cover_compiled,
    case os:getenv("EVATAR_TEST_SCALE") of
        V when V =:= false; V =:= "" ->
            ?assertEqual(case Covered of true -> 3; false -> 1 end, evatar_test_time:scale()),
            ?assertEqual(1, evatar_test_time:cluster_scale());
        _ ->
            ?assertEqual(evatar_test_time:cluster_scale(), evatar_test_time:scale())
    end.

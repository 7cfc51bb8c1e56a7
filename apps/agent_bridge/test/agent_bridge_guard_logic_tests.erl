%% EUnit tests of the listener guard's pure decisions, rule by rule.
-module(agent_bridge_guard_logic_tests).

-include_lib("eunit/include/eunit.hrl").

-define(IP, {192, 168, 1, 7}).

g(Overrides) -> agent_bridge_guard_logic:new(maps:merge(agent_bridge_guard_logic:default_config(),
                                                        Overrides)).

admit_n(Key, Now, N, G) ->
    lists:foldl(fun(_, {Acc, G0}) ->
                        {R, G1} = agent_bridge_guard_logic:admit(Key, Now, G0),
                        {[R | Acc], G1}
                end, {[], G}, lists:seq(1, N)).

count(R, Rs) -> length([X || X <- Rs, X =:= R]).

max_connections_test() ->
    {Rs, G} = admit_n(?IP, 0, 5, g(#{max_connections => 3, rate => infinity})),
    ?assertEqual(3, count(ok, Rs)),
    ?assertEqual(2, count({refuse, <<"TooManyConnections">>, 0}, Rs)),
    %% A closed socket frees its slot.
    G1 = agent_bridge_guard_logic:closed(G),
    ?assertMatch({ok, _}, agent_bridge_guard_logic:admit(?IP, 0, G1)).

rate_per_address_test() ->
    G0 = g(#{rate => 10, burst => 4}),
    {Rs, G} = admit_n(?IP, 0, 6, G0),
    ?assertEqual(4, count(ok, Rs)),
    ?assertEqual(2, count({refuse, <<"RateLimited">>, 0}, Rs)),
    %% Another address has its own bucket.
    ?assertMatch({ok, _}, agent_bridge_guard_logic:admit({10, 0, 0, 1}, 0, G)),
    %% 100 ms refill one token at 10/s.
    {Rs2, _} = admit_n(?IP, 100, 2, G),
    ?assertEqual(1, count(ok, Rs2)).

failure_delay_doubles_then_lockout_test() ->
    G0 = g(#{failure_delay => 100, max_failure_delay => 1000, max_failures => 6,
             lockout => 5000, rate => infinity}),
    {Delays, Locks, G} =
        lists:foldl(fun(_, {Ds, Ls, Gi}) ->
                            {D, L, _New, Gj} = agent_bridge_guard_logic:failed(?IP, 10, Gi),
                            {Ds ++ [D], Ls ++ [L], Gj}
                    end, {[], [], G0}, lists:seq(1, 6)),
    ?assertEqual([100, 200, 400, 800, 1000, 1000], Delays),
    ?assertEqual([0, 0, 0, 0, 0, 5000], Locks),
    %% A failure while locked out: not counted, the lockout not renewed.
    ?assertMatch({1000, 4000, false, G}, agent_bridge_guard_logic:failed(?IP, 1010, G)),
    ?assertMatch({{refuse, <<"LockedOut">>, 5000}, _},
                 agent_bridge_guard_logic:admit(?IP, 10, G)),
    ?assertEqual(5000, agent_bridge_guard_logic:locked(?IP, 10, G)),
    %% Other addresses are not locked; the lockout ends.
    ?assertMatch({ok, _}, agent_bridge_guard_logic:admit({10, 0, 0, 1}, 10, G)),
    ?assertEqual(0, agent_bridge_guard_logic:locked(?IP, 5010, G)),
    ?assertMatch({ok, _}, agent_bridge_guard_logic:admit(?IP, 5010, G)).

failures_forgotten_after_window_test() ->
    G0 = g(#{failure_delay => 100, failure_window => 1000}),
    {_, _, _, G1} = agent_bridge_guard_logic:failed(?IP, 0, G0),
    {200, _, _, G2} = agent_bridge_guard_logic:failed(?IP, 10, G1),
    ?assertMatch({100, 0, false, _}, agent_bridge_guard_logic:failed(?IP, 2000, G2)).

table_is_bounded_test() ->
    G0 = g(#{max_addresses => 100, rate => 1, burst => 1}),
    G = lists:foldl(fun(I, Gi) ->
                            {_, Gj} = agent_bridge_guard_logic:admit({10, 0, I div 256, I rem 256},
                                                                     0, Gi),
                            Gj
                    end, G0, lists:seq(1, 5000)),
    #{addresses := N} = agent_bridge_guard_logic:size(G),
    %% 100 addresses and the shared overflow entry.
    ?assertEqual(101, N),
    %% Entries with nothing to remember expire.
    #{addresses := 0} = agent_bridge_guard_logic:size(agent_bridge_guard_logic:expire(100000, G)).

ipv6_by_prefix_test() ->
    ?assertEqual(agent_bridge_guard_logic:key({16#fd00, 1, 2, 3, 4, 5, 6, 7}),
                 agent_bridge_guard_logic:key({16#fd00, 1, 2, 3, 9, 9, 9, 9})),
    ?assertNotEqual(agent_bridge_guard_logic:key({16#fd00, 1, 2, 3, 4, 5, 6, 7}),
                    agent_bridge_guard_logic:key({16#fd00, 1, 2, 4, 4, 5, 6, 7})).

refusals_summed_up_test() ->
    G0 = g(#{max_summaries => 2}),
    Refuse = fun(Key, Code, Gi) -> agent_bridge_guard_logic:refused(Key, Code, 0, Gi) end,
    {[{log, ?IP, <<"BadCredential">>, 1, first}], G1} = Refuse(?IP, <<"BadCredential">>, G0),
    {Es, G2} = lists:foldl(fun(_, {Acc, Gi}) -> {E, Gj} = Refuse(?IP, <<"BadCredential">>, Gi),
                                                {Acc ++ E, Gj}
                           end, {[], G1}, lists:seq(1, 99)),
    ?assertEqual([], Es),
    {[{log, _, <<"RateLimited">>, 1, first}], G3} = Refuse({1, 1, 1, 1}, <<"RateLimited">>, G2),
    %% Beyond max_summaries keys, the others share one.
    {[{log, overflow, <<"RateLimited">>, 1, first}], G4} = Refuse({2, 2, 2, 2}, <<"RateLimited">>, G3),
    {[], G5} = Refuse({3, 3, 3, 3}, <<"RateLimited">>, G4),
    {Summary, G6} = agent_bridge_guard_logic:flush(G5),
    ?assertEqual([{log, overflow, <<"RateLimited">>, 1, summary},
                  {log, ?IP, <<"BadCredential">>, 99, summary}], Summary),
    ?assertEqual({[], G6}, agent_bridge_guard_logic:flush(G6)).

config_from_listener_test() ->
    C = agent_bridge_guard_logic:config(#{max_connections => 7, handshake => #{rate => 3,
                                                                               bogus => 1}}),
    ?assertMatch(#{max_connections := 7, rate := 3, burst := 100}, C),
    ?assertNot(maps:is_key(bogus, C)).

log_id_truncated_test() ->
    Long = binary:copy(<<"x">>, 60000),
    Cut = evatar_log:id(Long),
    ?assert(byte_size(Cut) < 100),
    ?assertMatch(<<_:64/binary, "...(60000 bytes)">>, Cut),
    ?assertEqual(<<"short">>, evatar_log:id(<<"short">>)),
    Term = evatar_log:term({error, {bad_id, Long, [Long || _ <- lists:seq(1, 100)]}}),
    ?assert(byte_size(term_to_binary(Term)) < 2000).

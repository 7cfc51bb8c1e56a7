%% EUnit tests of the bounded outbound queue.
-module(agent_bridge_outq_tests).

-include_lib("eunit/include/eunit.hrl").

outq_limits_test() ->
    Q0 = agent_bridge_outq:new(10, 3),
    {ok, Q1} = agent_bridge_outq:push(<<"abcd">>, Q0),
    {ok, Q2} = agent_bridge_outq:push(<<"efgh">>, Q1),
    ?assertEqual({error, overflow}, agent_bridge_outq:push(<<"ijk">>, Q2)),
    {ok, Q3} = agent_bridge_outq:push(<<"ij">>, Q2),
    ?assertEqual({error, overflow}, agent_bridge_outq:push(<<>>, Q3)),
    ?assertEqual({3, 10}, agent_bridge_outq:size(Q3)).

outq_flush_stops_when_busy_test() ->
    {ok, Q1} = agent_bridge_outq:push(<<"a">>, agent_bridge_outq:new(100, 100)),
    {ok, Q2} = agent_bridge_outq:push(<<"b">>, Q1),
    {ok, Q3} = agent_bridge_outq:push(<<"c">>, Q2),
    Self = self(),
    TakeOne = fun(F) -> case get(taken) of
                            undefined -> put(taken, 1), Self ! F, true;
                            _ -> false
                        end end,
    {busy, Q4} = agent_bridge_outq:flush(TakeOne, Q3),
    ?assertEqual({2, 2}, agent_bridge_outq:size(Q4)),
    receive <<"a">> -> ok after 0 -> error(not_sent_in_order) end,
    {empty, Q5} = agent_bridge_outq:flush(fun(_) -> true end, Q4),
    ?assert(agent_bridge_outq:is_empty(Q5)).

%% write/3: straight through while nothing waits, queued behind a busy
%% transport and after what waits, within the same limits as push/2.
outq_write_test() ->
    Self = self(),
    Take = fun(F) -> Self ! {sent, F}, true end,
    Busy = fun(F) -> Self ! {refused, F}, false end,
    Q0 = agent_bridge_outq:new(10, 2),
    {empty, Q0} = agent_bridge_outq:write(Take, <<"a">>, Q0),
    receive {sent, <<"a">>} -> ok after 0 -> error(not_sent) end,
    ?assertEqual({error, overflow}, agent_bridge_outq:write(Take, <<"abcdefghijk">>, Q0)),
    {busy, Q1} = agent_bridge_outq:write(Busy, <<"b">>, Q0),
    ?assertEqual({1, 1}, agent_bridge_outq:size(Q1)),
    %% Asked once, not again at once.
    receive {refused, <<"b">>} -> ok after 0 -> error(not_offered) end,
    receive {refused, _} -> error(offered_twice) after 0 -> ok end,
    {busy, Q2} = agent_bridge_outq:write(Busy, <<"c">>, Q1),
    ?assertEqual({error, overflow}, agent_bridge_outq:write(Busy, <<"d">>, Q2)),
    {empty, Q3} = agent_bridge_outq:write(Take, <<"d">>, Q1),
    ?assert(agent_bridge_outq:is_empty(Q3)),
    %% Behind a waiting frame, the flush offers the oldest first.
    receive {refused, <<"b">>} -> ok after 0 -> error(not_offered_in_order) end,
    receive {sent, <<"b">>} -> ok after 0 -> error(not_in_order) end,
    receive {sent, <<"d">>} -> ok after 0 -> error(not_in_order) end.

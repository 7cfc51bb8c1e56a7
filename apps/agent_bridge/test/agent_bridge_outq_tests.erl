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

%% EUnit tests of the frame codec and the bounded outbound queue.
-module(agent_bridge_frame_tests).

-include_lib("eunit/include/eunit.hrl").

encode_test() ->
    ?assertEqual(<<0, 0, 0, 3, "abc">>, iolist_to_binary(agent_bridge_frame:encode([<<"a">>, "bc"]))).

decode_round_trip_test() ->
    Stream = iolist_to_binary([agent_bridge_frame:encode(<<"one">>),
                               agent_bridge_frame:encode(<<"two!">>), <<0, 0>>]),
    {ok, <<"one">>, R1} = agent_bridge_frame:decode(Stream, 10),
    {ok, <<"two!">>, R2} = agent_bridge_frame:decode(R1, 10),
    ?assertEqual({more, 2}, agent_bridge_frame:decode(R2, 10)).

decode_partial_body_test() ->
    ?assertEqual({more, 2}, agent_bridge_frame:decode(<<0, 0, 0, 5, "abc">>, 10)).

decode_errors_test_() ->
    [?_assertEqual({error, empty_frame}, agent_bridge_frame:decode(<<0, 0, 0, 0>>, 10)),
     %% The length alone condemns the stream: no need to wait for the body.
     ?_assertEqual({error, {too_large, 11}}, agent_bridge_frame:decode(<<0, 0, 0, 11>>, 10)),
     ?_assertEqual({error, {too_large, 16#47455420}},
                   agent_bridge_frame:decode(<<"GET / HTTP/1.1">>, 1048576)),
     ?_assertEqual(ok, agent_bridge_frame:check(<<"x">>, 1)),
     ?_assertEqual({error, {too_large, 2}}, agent_bridge_frame:check(<<"xy">>, 1))].

refusal_codes_test_() ->
    Code = fun(Why) -> {refused, #{code := C}} = agent_bridge_frame:refusal(Why), C end,
    [?_assertEqual(<<"Malformed">>, Code(empty_frame)),
     ?_assertEqual(<<"FrameTooLarge">>, Code({too_large, 5})),
     ?_assertEqual(<<"FrameTooLarge">>, Code(emsgsize)),
     ?_assertEqual(<<"Malformed">>, Code({malformed, #{code => malformed, message => <<"m">>}}))].

error_signal_encodes_test() ->
    S = agent_bridge_frame:error_signal(<<"va">>, <<"Malformed">>, <<"bad">>, undefined),
    {ok, S} = bil:parse_signal(iolist_to_binary(bil:encode_signal(S))).

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

%% EUnit tests of the frame codec of the wire protocol.
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

%% sock_flow on real loopback TCP sockets: the count is raised only while
%% the socket is reading, a stale passive notice is told from a real one,
%% and read_on/3 tops up once per half batch.
-module(sock_flow_tests).

-include_lib("eunit/include/eunit.hrl").

%% A connected pair: {Reader, Writer}, the reader owned by the caller.
pair() ->
    {ok, L} = gen_tcp:listen(0, [binary, {packet, 4}, {ip, {127, 0, 0, 1}}, {active, false}]),
    {ok, Port} = inet:port(L),
    {ok, W} = gen_tcp:connect({127, 0, 0, 1}, Port, [binary, {packet, 4}, {active, false}]),
    {ok, R} = gen_tcp:accept(L, 5000),
    ok = gen_tcp:close(L),
    {R, W}.

active(S) ->
    {ok, [{active, A}]} = inet:getopts(S, [active]),
    A.

close({R, W}) ->
    ok = gen_tcp:close(R),
    ok = gen_tcp:close(W).

top_up_raises_a_reading_socket_only_test() ->
    {R, _} = P = pair(),
    ok = sock_flow:activate(R, 10),
    ok = sock_flow:top_up(R, 25),
    ?assertEqual(25, active(R)),
    %% Already at or over the target: unchanged.
    ok = sock_flow:top_up(R, 5),
    ?assertEqual(25, active(R)),
    %% Passive: left for the owner to decide.
    ok = inet:setopts(R, [{active, false}]),
    ok = sock_flow:top_up(R, 25),
    ?assertEqual(false, active(R)),
    close(P).

passive_notice_can_be_stale_test() ->
    {R, W} = P = pair(),
    ok = sock_flow:activate(R, 1),
    ok = gen_tcp:send(W, <<"x">>),
    receive {tcp, R, _} -> ok after evatar_test_time:guard() -> error(no_data) end,
    receive {tcp_passive, R} -> ok after evatar_test_time:guard() -> error(no_passive_notice) end,
    ?assert(sock_flow:is_passive(R)),
    ok = sock_flow:activate(R, 4),
    %% The notice read after a re-activation is stale.
    ?assertNot(sock_flow:is_passive(R)),
    close(P),
    ?assert(sock_flow:is_passive(R)).

read_on_tops_up_every_half_batch_test() ->
    {R, W} = P = pair(),
    ok = sock_flow:activate(R, 8),
    Credit0 = sock_flow:credit(8),
    ?assertEqual(4, Credit0),
    ok = gen_tcp:send(W, <<"abc">>),
    Got = fun G(0, C) -> C;
              G(N, C) -> receive {tcp, R, _} -> G(N - 1, sock_flow:read_on(C, R, 8))
                         after evatar_test_time:guard() -> error(no_data) end
          end,
    %% One frame read: the count is not touched before the credit is used up.
    C1 = Got(1, Credit0),
    ?assertEqual(3, C1),
    ?assertEqual(7, active(R)),
    ?assertEqual(4, sock_flow:read_on(1, R, 8)),
    ?assertEqual(8, active(R)),
    close(P).

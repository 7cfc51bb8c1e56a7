%% Benchmark: 100 sequential GET /api/cluster on one kept-alive
%% connection, then 100 each on a new connection, against evatar_web on
%% a free loopback port; prints the mean of each. Run:
%%   rebar3 as bench compile
%%   ERL_LIBS=_deps erl -noshell -pa _build/bench/lib/*/ebin -pa _build/bench/extras/bench \
%%       -config config/test.config -eval 'http_keepalive_bench:main(), halt().'
%% With Nagle's algorithm on the server's sockets the kept-alive figure
%% was about 45 ms (a delayed ACK a request), 0.1 ms without.
-module(http_keepalive_bench).

-export([main/0, run/1]).

-define(N, 100).

main() ->
    ok = application:set_env(evatar_web, port, 0),
    {ok, _} = application:ensure_all_started(evatar_web),
    run(evatar_web:port()).

run(Port) ->
    Req = <<"GET /api/cluster HTTP/1.1\r\nHost: localhost\r\n\r\n">>,
    {ok, S} = gen_tcp:connect({127, 0, 0, 1}, Port, [binary, {active, false}]),
    ok = one(S, Req),
    T0 = erlang:monotonic_time(microsecond),
    [ok = one(S, Req) || _ <- lists:seq(1, ?N)],
    T1 = erlang:monotonic_time(microsecond),
    ok = gen_tcp:close(S),
    [begin
         {ok, C} = gen_tcp:connect({127, 0, 0, 1}, Port, [binary, {active, false}]),
         ok = one(C, Req),
         ok = gen_tcp:close(C)
     end || _ <- lists:seq(1, ?N)],
    T2 = erlang:monotonic_time(microsecond),
    io:format("~b requests: kept-alive connection ~.2f ms each, new connection ~.2f ms each~n",
              [?N, (T1 - T0) / (1000 * ?N), (T2 - T1) / (1000 * ?N)]).

one(S, Req) ->
    ok = gen_tcp:send(S, Req),
    read(S, <<>>).

%% One response: its head, then Content-Length bytes of body.
read(S, Acc) ->
    {ok, D} = gen_tcp:recv(S, 0, 10000),
    B = <<Acc/binary, D/binary>>,
    case binary:split(B, <<"\r\n\r\n">>) of
        [Head, Body] ->
            {match, [L]} = re:run(Head, "(?i)content-length: *([0-9]+)",
                                  [{capture, all_but_first, binary}]),
            case byte_size(Body) >= binary_to_integer(L) of
                true -> ok;
                false -> read(S, B)
            end;
        [_] ->
            read(S, B)
    end.

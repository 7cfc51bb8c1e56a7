%% Common Test: the HTTP server of evatar_web over real TCP (httpc, or a
%% raw socket for what a client library would not send): routing, static
%% files, HEAD and OPTIONS, JSON errors, limits (body, header deadline,
%% connections), keep-alive and the operator credential.
-module(evatar_web_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").

-export([all/0, groups/0, suite/0, init_per_suite/1, end_per_suite/1,
         init_per_group/2, end_per_group/2]).
-export([cluster_read/1, static_files/1, no_path_escapes/1, unknown_route/1,
         method_not_allowed/1, loopback_reads_check_host/1, body_limit/1, nodelay/1,
         chunked_body_limit/1, options_allow/1, head_requests/1, keepalive_requests/1,
         header_timeout/1, max_clients/1, refusals_are_json/1,
         bad_env_refuses_start/1, listen_failure_is_an_error/1, listening_logged/1,
         fixed_port_starts/1]).
-export([log/2]).

-define(T, evatar_web_test).

suite() -> [{timetrap, {minutes, 2}}].

all() -> [{group, server}, {group, limits}, {group, startup}].

groups() ->
    [{server, [], [cluster_read, static_files, no_path_escapes, unknown_route,
                   method_not_allowed, loopback_reads_check_host, body_limit, nodelay,
                   chunked_body_limit, options_allow, head_requests, keepalive_requests,
                   refusals_are_json]},
     %% Each restarts the server with a small limit, then the defaults.
     {limits, [], [header_timeout, max_clients]},
     {startup, [], [bad_env_refuses_start, listen_failure_is_an_error, listening_logged,
                    fixed_port_starts]}].

init_per_suite(Config) ->
    ?T:start(#{}),
    Config.

end_per_suite(_Config) ->
    ?T:stop().

init_per_group(_, Config) -> Config.
end_per_group(_, _Config) -> ok.

%% GET /api/cluster answers this node, up, and the quorum.
cluster_read(_Config) ->
    {200, #{<<"node">> := Node, <<"quorum">> := true, <<"nodes">> := Nodes,
            <<"pairings">> := Ps}} = ?T:get("/api/cluster"),
    ?assertEqual(atom_to_binary(node()), Node),
    ?assert(lists:any(fun(#{<<"node">> := N, <<"up">> := true, <<"self">> := true}) -> N =:= Node;
                         (_) -> false
                      end, Nodes)),
    true = is_list(Ps).

%% The page's files come from priv/www with their content type; / is index.html.
static_files(_Config) ->
    {200, Headers, Body} = ?T:raw(get, "/", [], none),
    "text/html; charset=utf-8" = proplists:get_value("content-type", Headers),
    "nosniff" = proplists:get_value("x-content-type-options", Headers),
    {ok, Index} = file:read_file(filename:join([code:priv_dir(evatar_web), "www", "index.html"])),
    Index = list_to_binary(Body),
    {200, _, Body} = ?T:raw(get, "/index.html", [], none).

%% No file outside priv/www is served: `..' (raw or percent-encoded), a
%% directory, a file of an unknown type.
no_path_escapes(_Config) ->
    [{404, #{<<"error">> := <<"not_found">>}} = ?T:get(P)
     || P <- ["/../../../../../etc/passwd", "/%2e%2e/%2e%2e/%2e%2e/etc/passwd",
              "/..%2f..%2f..%2fvm.args", "/www/", "/www", "/index.html%00.txt",
              "/nope.html"]],
    %% The raw request line, not normalised by a client.
    {ok, S} = gen_tcp:connect({127, 0, 0, 1}, evatar_web:port(), [binary, {active, false}]),
    ok = gen_tcp:send(S, "GET /../../../../etc/passwd HTTP/1.1\r\nHost: localhost\r\n\r\n"),
    {ok, Reply} = gen_tcp:recv(S, 0, evatar_test_time:guard()),
    ok = gen_tcp:close(S),
    nomatch = binary:match(Reply, <<"root:">>),
    {match, _} = re:run(Reply, "^HTTP/1.1 4\\d\\d").

%% An unknown /api route is a JSON 404.
unknown_route(_Config) ->
    {404, #{<<"error">> := <<"not_found">>, <<"field">> := null, <<"message">> := _}} =
        ?T:get("/api/nothing/here"),
    %% A query string that is not one counts as none.
    {400, _, Json} = parse_response(?T:raw_tcp("GET /api/events?a=%zz&pairing HTTP/1.1\r\n"
                                               "Host: localhost\r\nConnection: close\r\n\r\n")),
    {ok, #{<<"error">> := <<"missing_field">>}} = evatar_json:decode(Json).

%% A known path with another method is a JSON 405 naming the allowed ones,
%% in the message and in `Allow'; so is a method no route has (QUERY).
method_not_allowed(_Config) ->
    {405, Headers, Body} = ?T:raw(delete, "/api/cluster", [], none),
    "GET, HEAD, OPTIONS" = proplists:get_value("allow", Headers),
    "application/json" = proplists:get_value("content-type", Headers),
    {ok, #{<<"error">> := <<"method_not_allowed">>, <<"message">> := <<"allowed: GET, HEAD, OPTIONS">>}} =
        evatar_json:decode(list_to_binary(Body)),
    Reply = ?T:raw_tcp("QUERY /api/pairings HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n"),
    {405, RawHeaders, Json} = parse_response(Reply),
    <<"GET, HEAD, OPTIONS, POST">> = maps:get(<<"allow">>, RawHeaders),
    {ok, #{<<"error">> := <<"method_not_allowed">>}} = evatar_json:decode(Json).

%% OPTIONS on a known path (a route, or a file of the page) answers 204
%% with the methods in `Allow' and no body; on an unknown one the JSON 404.
options_allow(_Config) ->
    [begin
         {204, Headers, ""} = ?T:raw(options, Path, [], none),
         Allow = proplists:get_value("allow", Headers),
         undefined = proplists:get_value("content-length", Headers),
         undefined = proplists:get_value("content-type", Headers)
     end || {Path, Allow} <- [{"/api/cluster", "GET, HEAD, OPTIONS"},
                              {"/api/pairings", "GET, HEAD, OPTIONS, POST"},
                              {"/api/pairings/x", "DELETE, GET, HEAD, OPTIONS, PUT"},
                              {"/", "GET, HEAD, OPTIONS"}]],
    {404, #{<<"error">> := <<"not_found">>}} = ?T:request(options, "/api/nothing", [], none).

%% What cowboy refuses before any route runs is answered with the API's
%% JSON error too, and the connection closes: a request line that is not
%% one, a URI over 4,096 bytes, a header value over 8,192, TRACE.
refusals_are_json(_Config) ->
    Long = lists:duplicate(5000, $a),
    [begin
         {Status, Headers, Json} = parse_response(?T:raw_tcp(Request)),
         <<"application/json">> = maps:get(<<"content-type">>, Headers),
         <<"close">> = maps:get(<<"connection">>, Headers),
         {ok, #{<<"error">> := Code, <<"field">> := null, <<"message">> := <<_, _/binary>>}} =
             evatar_json:decode(Json)
     end || {Request, Status, Code} <-
                [{"GET\r\n\r\n", 400, <<"bad_request">>},
                 {["GET /", Long, " HTTP/1.1\r\nHost: localhost\r\n\r\n"], 414, <<"uri_too_long">>},
                 {["GET /api/cluster HTTP/1.1\r\nHost: localhost\r\nX-Big: ", Long, Long, "\r\n\r\n"],
                  431, <<"headers_too_large">>},
                 {"TRACE /api/cluster HTTP/1.1\r\nHost: localhost\r\n\r\n", 501, <<"not_implemented">>}]].

%% HEAD is GET without the body: the same status and headers, the length
%% of the body it would have.
head_requests(_Config) ->
    {200, GetHeaders, Body} = ?T:raw(get, "/index.html", [], none),
    {200, Headers, ""} = ?T:raw(head, "/index.html", [], none),
    Length = integer_to_list(length(Body)),
    Length = proplists:get_value("content-length", Headers),
    Type = proplists:get_value("content-type", GetHeaders),
    Type = proplists:get_value("content-type", Headers),
    {200, ApiHeaders, ""} = ?T:raw(head, "/api/cluster", [], none),
    "application/json" = proplists:get_value("content-type", ApiHeaders).

%% On a loopback listener reads need no token, but only for a loopback
%% Host: a page of another origin rebinding its name to 127.0.0.1 is refused.
loopback_reads_check_host(_Config) ->
    [{200, _} = ?T:request(get, "/api/cluster", [{"host", H}], none)
     || H <- ["localhost", "localhost:7480", "127.0.0.1", "127.0.0.2:1", "[::1]:80"]],
    [{403, #{<<"error">> := <<"bad_host">>}} = ?T:request(get, "/api/cluster", [{"host", H}], none)
     || H <- ["evil.example", "evil.example:7480", "localhost.evil.example", "10.0.0.1"]].

%% A body over max_body is refused with the JSON 413 `body_too_large'
%% before it is read: the headers alone get the answer, and the connection
%% closes. A chunked body (no declared length) that passes the limit is
%% cut off by httpd: the connection closes, with no answer or httpd's own.
body_limit(_Config) ->
    Max = application:get_env(evatar_web, max_body, 1048576),
    Reply = ?T:raw_tcp(["POST /api/cluster HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n"
                        "Content-Length: ", integer_to_list(Max + 1), "\r\n\r\n"]),
    {match, _} = re:run(Reply, "^HTTP/1.1 413"),
    {match, _} = re:run(Reply, "\r\ncontent-type: application/json\r\n", [caseless]),
    [_, Json] = binary:split(Reply, <<"\r\n\r\n">>),
    {ok, #{<<"error">> := <<"body_too_large">>, <<"field">> := null, <<"message">> := Message}} =
        evatar_json:decode(Json),
    {match, _} = re:run(Message, ["limit ", integer_to_list(Max), " bytes \\(http.max_body"]),
    %% At the limit the body is read and reaches the route.
    AtLimit = ?T:raw_tcp(["POST /api/cluster HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n"
                          "Content-Type: application/json\r\n"
                          "Content-Length: ", integer_to_list(Max), "\r\n\r\n", binary:copy(<<" ">>, Max)]),
    nomatch = re:run(AtLimit, "^HTTP/1.1 413"),
    ok.

%% A chunked body (no declared length) that passes max_body gets the same
%% JSON 413 once it does, and the connection closes: the client, still
%% sending, sees the answer and the close.
chunked_body_limit(_Config) ->
    Max = application:get_env(evatar_web, max_body, 1048576),
    {ok, S} = gen_tcp:connect({127, 0, 0, 1}, evatar_web:port(), [binary, {active, true}]),
    ok = gen_tcp:send(S, "POST /api/pairings HTTP/1.1\r\nHost: localhost\r\n"
                         "Content-Type: application/json\r\nTransfer-Encoding: chunked\r\n\r\n"),
    Chunk = ["10000\r\n", binary:copy(<<" ">>, 65536), "\r\n"],
    %% The body is sent by another process, so that this one sees the
    %% answer while it is still being sent (and its sends then fail).
    Sender = spawn_link(fun() -> [gen_tcp:send(S, Chunk) || _ <- lists:seq(1, 2 * Max div 65536)] end),
    Reply = until_closed(S, <<>>),
    unlink(Sender),
    {413, Headers, Json} = parse_response(Reply),
    <<"application/json">> = maps:get(<<"content-type">>, Headers),
    <<"close">> = maps:get(<<"connection">>, Headers),
    {ok, #{<<"error">> := <<"body_too_large">>, <<"field">> := null, <<"message">> := Message}} =
        evatar_json:decode(Json),
    {match, _} = re:run(Message, ["limit ", integer_to_list(Max), " bytes"]),
    %% A chunked body within the limit is read and reaches the route.
    Small = ?T:raw_tcp(["POST /api/pairings HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n"
                        "Content-Type: application/json\r\nTransfer-Encoding: chunked\r\n\r\n",
                        "2\r\n{}\r\n0\r\n\r\n"]),
    {403, _, _} = parse_response(Small).

%% Everything the server sends on an active socket until it closes it (a
%% guard of 30 s, whose length does not matter, fails a server that never does).
until_closed(S, Acc) ->
    receive
        {tcp, S, Data} -> until_closed(S, <<Acc/binary, Data/binary>>);
        {tcp_closed, S} -> Acc;
        {tcp_error, S, _} -> until_closed(S, Acc)
    after evatar_test_time:guard() -> ct:fail({not_closed, Acc})
    end.

%% One response: status, headers (lower-case names), body.
parse_response(Reply) ->
    [Head, Body] = binary:split(Reply, <<"\r\n\r\n">>),
    [<<"HTTP/1.1 ", Code:3/binary, _/binary>> | Lines] = binary:split(Head, <<"\r\n">>, [global]),
    Headers = maps:from_list([begin
                                  [K, V] = binary:split(L, <<":">>),
                                  {string:lowercase(K), string:trim(V)}
                              end || L <- Lines]),
    {binary_to_integer(Code), Headers, Body}.

%% The server's accepted sockets have Nagle's algorithm off: a response
%% written in more than one send must not wait for the client's delayed
%% ACK (about 40 ms a request on a kept-alive connection otherwise).
nodelay(_Config) ->
    {ok, S} = gen_tcp:connect({127, 0, 0, 1}, evatar_web:port(), [binary, {active, false}]),
    ok = gen_tcp:send(S, "GET /api/cluster HTTP/1.1\r\nHost: localhost\r\n\r\n"),
    {ok, <<"HTTP/1.1 200", _/binary>>} = gen_tcp:recv(S, 0, evatar_test_time:guard()),
    {ok, Mine} = inet:sockname(S),
    %% The server's end of this connection: the socket whose peer is us.
    [Server] = [P || P <- erlang:ports(), erlang:port_info(P, name) =:= {name, "tcp_inet"},
                     inet:peername(P) =:= {ok, Mine}],
    {ok, [{nodelay, true}]} = inet:getopts(Server, [nodelay]),
    ok = gen_tcp:close(S).

%% Twenty requests one after the other on one kept-alive connection are
%% each answered on it (the server's end is the same socket throughout,
%% with nodelay on: no answer waits for the client's delayed ACK).
keepalive_requests(_Config) ->
    {ok, S} = gen_tcp:connect({127, 0, 0, 1}, evatar_web:port(), [binary, {active, false}]),
    {ok, Mine} = inet:sockname(S),
    [begin
         ok = gen_tcp:send(S, "GET /api/cluster HTTP/1.1\r\nHost: localhost\r\n\r\n"),
         {200, _, _} = recv_response(S, <<>>)
     end || _ <- lists:seq(1, 20)],
    [Server] = [P || P <- erlang:ports(), erlang:port_info(P, name) =:= {name, "tcp_inet"},
                     inet:peername(P) =:= {ok, Mine}],
    {ok, [{nodelay, true}]} = inet:getopts(Server, [nodelay]),
    ok = gen_tcp:close(S).

%% One whole response (its content-length read) from a passive socket.
recv_response(S, Acc) ->
    case binary:split(Acc, <<"\r\n\r\n">>) of
        [Head, Rest] ->
            {Status, Headers, _} = parse_response(<<Head/binary, "\r\n\r\n">>),
            Length = binary_to_integer(maps:get(<<"content-length">>, Headers)),
            Body = recv_more(S, Rest, Length),
            {Status, Headers, Body};
        [_] ->
            {ok, More} = gen_tcp:recv(S, 0, evatar_test_time:guard()),
            recv_response(S, <<Acc/binary, More/binary>>)
    end.

recv_more(_S, Buf, Length) when byte_size(Buf) >= Length -> Buf;
recv_more(S, Buf, Length) ->
    {ok, More} = gen_tcp:recv(S, 0, evatar_test_time:guard()),
    recv_more(S, <<Buf/binary, More/binary>>, Length).

%% A client that trickles its request headers (a byte at a time, never
%% done) gets the JSON 408 `request_timeout' once header_timeout has passed
%% since it connected, and the connection closes; a client that sent
%% nothing is closed then too.
header_timeout(_Config) ->
    ok = ?T:restart(#{header_timeout => 300}),
    try
        {ok, S} = gen_tcp:connect({127, 0, 0, 1}, evatar_web:port(), [binary, {active, true}]),
        ok = gen_tcp:send(S, "GET /api/cluster HTTP/1.1\r\nHost: localhost\r\nX-Slow: "),
        Trickle = spawn_link(fun() -> trickle(S) end),
        Reply = until_closed(S, <<>>),
        unlink(Trickle),
        exit(Trickle, kill),
        {408, Headers, Json} = parse_response(Reply),
        <<"application/json">> = maps:get(<<"content-type">>, Headers),
        {ok, #{<<"error">> := <<"request_timeout">>, <<"field">> := null}} = evatar_json:decode(Json),
        {ok, Quiet} = gen_tcp:connect({127, 0, 0, 1}, evatar_web:port(), [binary, {active, true}]),
        <<>> = until_closed(Quiet, <<>>),
        %% Once the headers are in, the deadline is over for that request.
        {200, _} = ?T:get("/api/cluster")
    after
        ok = ?T:restart(#{})
    end.

%% A byte of a header value every 50 ms, until the socket is closed.
trickle(S) ->
    {ok, _} = timer:send_interval(50, byte),
    trickle_loop(S).

trickle_loop(S) ->
    receive
        byte ->
            case gen_tcp:send(S, "a") of
                ok -> trickle_loop(S);
                {error, _} -> ok
            end
    end.

%% With max_clients connections open, the next one is answered the JSON
%% 503 `too_many_clients' and closed; once one closes, a new one is served.
max_clients(_Config) ->
    ok = ?T:restart(#{max_clients => 2}),
    try
        Open = [begin
                    {ok, S} = gen_tcp:connect({127, 0, 0, 1}, evatar_web:port(), [binary, {active, false}]),
                    ok = gen_tcp:send(S, "GET /api/cluster HTTP/1.1\r\nHost: localhost\r\n\r\n"),
                    {200, _, _} = recv_response(S, <<>>),
                    S
                end || _ <- [1, 2]],
        Reply = ?T:raw_tcp("GET /api/cluster HTTP/1.1\r\nHost: localhost\r\n\r\n"),
        {503, Headers, Json} = parse_response(Reply),
        <<"application/json">> = maps:get(<<"content-type">>, Headers),
        {ok, #{<<"error">> := <<"too_many_clients">>}} = evatar_json:decode(Json),
        [First | Rest] = Open,
        ok = gen_tcp:close(First),
        %% The server sees the close in its own time: retry until served.
        ok = evatar_test_wait:until(
               fun() ->
                       {Status, _, _} = parse_response(
                                          ?T:raw_tcp("GET /api/cluster HTTP/1.1\r\nHost: localhost\r\n"
                                                     "Connection: close\r\n\r\n")),
                       Status =:= 200
               end, #{timeout => 10000, interval => 50}),
        [ok = gen_tcp:close(S) || S <- Rest]
    after
        ok = ?T:restart(#{})
    end.

%% A mistake in the environment stops the start with the key named.
bad_env_refuses_start(_Config) ->
    ok = application:stop(evatar_web),
    try
        [begin
             ok = application:set_env(evatar_web, K, V),
             {error, {{shutdown, {failed_to_start_child, evatar_web_server,
                                      {bad_http_option, K, Why}}}, _}} =
                 application:start(evatar_web),
             true = is_binary(Why),
             ok = application:set_env(evatar_web, K, Good)
         end || {K, V, Good} <- [{port, -1, 0}, {ip, "localhost", {127, 0, 0, 1}}, {max_body, 0, 1048576},
                                 {header_timeout, 0, 10000},
                                 {operator_token_hash, <<"plain">>, undefined}]],
        ok = application:set_env(evatar_web, token_file, "/nonexistent/token"),
        {error, {{shutdown, {failed_to_start_child, evatar_web_server,
                                 {token_file, _}}}, _}} = application:start(evatar_web)
    after
        ok = application:set_env(evatar_web, token_file, ""),
        ok = application:start(evatar_web)
    end.

%% A port in use is an error of the start naming it, not a crash loop.
listen_failure_is_an_error(_Config) ->
    {ok, Holder} = gen_tcp:listen(0, [{ip, {127, 0, 0, 1}}]),
    {ok, Taken} = inet:port(Holder),
    ok = application:stop(evatar_web),
    try
        ok = application:set_env(evatar_web, port, Taken),
        {error, {{shutdown, {failed_to_start_child, evatar_web_server,
                                 {http_listen_failed, {127, 0, 0, 1}, Taken, _}}}, _}} =
            application:start(evatar_web)
    after
        ok = gen_tcp:close(Holder),
        ok = application:set_env(evatar_web, port, 0),
        ok = application:start(evatar_web)
    end.

%% A configured port (what a release has) is listened on and served, with
%% nodelay on the accepted socket (OTP 25's httpd broke exactly this start,
%% while port 0 worked).
fixed_port_starts(_Config) ->
    {ok, Probe} = gen_tcp:listen(0, [{ip, {127, 0, 0, 1}}]),
    {ok, Free} = inet:port(Probe),
    ok = gen_tcp:close(Probe),
    ok = application:stop(evatar_web),
    try
        ok = application:set_env(evatar_web, port, Free),
        ok = application:start(evatar_web),
        Free = evatar_web:port(),
        {200, #{<<"quorum">> := true}} = ?T:get("/api/cluster"),
        nodelay([])
    after
        ok = application:stop(evatar_web),
        ok = application:set_env(evatar_web, port, 0),
        ok = application:start(evatar_web)
    end.

%% The start logs where it listens (the port picked for port 0) as a
%% report and a line for a person; evatar_web:url() is a string.
listening_logged(_Config) ->
    #{level := Level} = logger:get_primary_config(),
    ok = logger:set_primary_config(level, notice),
    ok = logger:add_handler(listening_probe, ?MODULE, #{config => #{pid => self()}}),
    try
        ok = application:stop(evatar_web),
        ok = application:start(evatar_web),
        Port = evatar_web:port(),
        Url = "http://127.0.0.1:" ++ integer_to_list(Port) ++ "/",
        Url = evatar_web:url(),
        true = io_lib:printable_unicode_list(evatar_web:url()),
        receive
            {listening, #{port := Port, url := Url, ip := "127.0.0.1"} = Report, Meta} ->
                #{report_cb := Cb} = Meta,
                {Format, Args} = Cb(Report),
                Line = lists:flatten(io_lib:format(Format, Args)),
                {match, _} = re:run(Line, ["listening on ", Url])
        after evatar_test_time:guard() -> ct:fail(no_listening_report)
        end
    after
        ok = logger:remove_handler(listening_probe),
        ok = logger:set_primary_config(level, Level)
    end.

%% logger handler of listening_logged/1.
log(#{msg := {report, #{what := http_listening} = Report}, meta := Meta},
    #{config := #{pid := Pid}}) ->
    Pid ! {listening, Report, Meta};
log(_, _) ->
    ok.

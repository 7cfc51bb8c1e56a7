%% @doc Internal to the broker comparison (broker_bench_gen): a minimal NATS
%% client, enough for request-reply over core NATS (no JetStream, no
%% headers, no TLS, no reconnect). One process per connection reads the
%% socket and hands each MSG to its owner as
%% `{nats, Conn, {msg, Subject, ReplyTo | undefined, Payload}}'; a closed
%% socket or a server's `-ERR' ends it with `{nats, Conn, {closed, Why}}'.
%% Publishing writes to the socket from the caller's process, as a NATS
%% client library does, so a request costs the generator no process hop.
%%
%% The protocol (docs.nats.io, "Client Protocol"): lines end in CRLF; the
%% server opens with `INFO {json}'; the client answers `CONNECT {json}'
%% (verbose false: no `+OK' per message); `SUB subject sid',
%% `PUB subject [reply-to] nbytes' CRLF payload CRLF; the server delivers
%% `MSG subject sid [reply-to] nbytes' CRLF payload CRLF, and `PING' /
%% `PONG' both ways. A PING answered by a PONG tells that the server has
%% processed everything sent before it: subscribe/3 waits for that, so a
%% request sent after it finds the responder subscribed.
-module(broker_bench_nats).

-export([connect/3, subscribe/3, publish/4, close/1]).
-export([init/4]).
-export([parse/1]).

-export_type([conn/0]).

-opaque conn() :: {nats, pid(), gen_tcp:socket()}.

-type event() :: {msg, binary(), binary() | undefined, binary()} | ping | pong
               | ok | {info, binary()} | {err, binary()}.

-define(ACTIVE_N, 100).
-define(CONNECT,
        <<"CONNECT {\"verbose\":false,\"pedantic\":false,\"lang\":\"erlang\","
          "\"version\":\"0\",\"protocol\":1,\"echo\":false}\r\n">>).

%% ---------------------------------------------------------------------------
%% API
%% ---------------------------------------------------------------------------

%% @doc Connects, reads the server's INFO, sends CONNECT and waits for the
%% PONG to a PING; the messages of the connection go to the caller.
-spec connect(inet:ip_address(), inet:port_number(), timeout()) ->
          {ok, conn()} | {error, term()}.
connect(Ip, Port, Timeout) ->
    Owner = self(),
    Pid = proc_lib:spawn_link(?MODULE, init, [Owner, Ip, Port, Timeout]),
    receive
        {Pid, {connected, Sock}} -> {ok, {nats, Pid, Sock}};
        {Pid, {failed, Why}} -> unlink(Pid), {error, Why}
    after Timeout -> unlink(Pid), exit(Pid, kill), {error, timeout}
    end.

%% @doc Subscribes to Subject under subscription id Sid; returns once the
%% server has confirmed it holds the subscription (its PONG).
-spec subscribe(conn(), binary(), pos_integer()) -> ok | {error, term()}.
subscribe({nats, Pid, _}, Subject, Sid) ->
    Ref = monitor(process, Pid),
    Pid ! {sync, self(), Ref, [<<"SUB ">>, Subject, $\s, integer_to_binary(Sid), <<"\r\n">>]},
    receive
        {Ref, ok} -> demonitor(Ref, [flush]), ok;
        {'DOWN', Ref, process, Pid, Why} -> {error, Why}
    after 60000 -> demonitor(Ref, [flush]), {error, timeout}
    end.

%% @doc Publishes Payload on Subject, with ReplyTo as its reply subject
%% unless undefined.
-spec publish(conn(), binary(), binary() | undefined, iodata()) -> ok | {error, term()}.
publish({nats, _, Sock}, Subject, ReplyTo, Payload) ->
    Len = integer_to_binary(iolist_size(Payload)),
    Head = case ReplyTo of
               undefined -> [<<"PUB ">>, Subject, $\s, Len, <<"\r\n">>];
               _ -> [<<"PUB ">>, Subject, $\s, ReplyTo, $\s, Len, <<"\r\n">>]
           end,
    gen_tcp:send(Sock, [Head, Payload, <<"\r\n">>]).

%% @doc Closes the connection and stops its process.
-spec close(conn()) -> ok.
close({nats, Pid, _}) ->
    unlink(Pid),
    exit(Pid, shutdown),
    ok.

%% ---------------------------------------------------------------------------
%% The connection's process
%% ---------------------------------------------------------------------------

%% @private
-spec init(pid(), inet:ip_address(), inet:port_number(), timeout()) -> ok.
init(Owner, Ip, Port, Timeout) ->
    case gen_tcp:connect(Ip, Port, [binary, {packet, raw}, {active, false}, {nodelay, true},
                                    {keepalive, true}], Timeout) of
        {ok, Sock} ->
            case handshake(Sock, <<>>, Timeout) of
                {ok, Rest} ->
                    ok = inet:setopts(Sock, [{active, ?ACTIVE_N}]),
                    Owner ! {self(), {connected, Sock}},
                    loop(#{owner => Owner, sock => Sock, buf => Rest,
                           conn => {nats, self(), Sock}, waiting => queue:new()});
                {error, Why} ->
                    Owner ! {self(), {failed, Why}},
                    ok
            end;
        {error, Why} ->
            Owner ! {self(), {failed, Why}},
            ok
    end.

%% INFO first; then CONNECT and PING, and everything up to the PONG.
handshake(Sock, Buf, Timeout) ->
    case parse(Buf) of
        {[{info, _} | _], Rest} ->
            ok = gen_tcp:send(Sock, [?CONNECT, <<"PING\r\n">>]),
            await_pong(Sock, Rest, Timeout);
        {[Other | _], _} ->
            {error, {unexpected, Other}};
        {[], _} ->
            case gen_tcp:recv(Sock, 0, Timeout) of
                {ok, Data} -> handshake(Sock, <<Buf/binary, Data/binary>>, Timeout);
                {error, _} = E -> E
            end
    end.

await_pong(Sock, Buf, Timeout) ->
    {Events, Rest} = parse(Buf),
    case lists:dropwhile(fun(E) -> E =/= pong end, Events) of
        [pong | After] ->
            case [E || {err, _} = E <- Events] of
                [] -> {ok, iolist_to_binary([unparse(E) || E <- After] ++ [Rest])};
                [Err | _] -> {error, Err}
            end;
        [] ->
            case [E || {err, _} = E <- Events] of
                [Err | _] -> {error, Err};
                [] ->
                    case gen_tcp:recv(Sock, 0, Timeout) of
                        {ok, Data} -> await_pong(Sock, <<Rest/binary, Data/binary>>, Timeout);
                        {error, _} = E -> E
                    end
            end
    end.

%% Nothing but PINGs or a PONG can follow the handshake's PONG before a
%% SUB; kept as bytes so the loop handles them.
unparse(ping) -> <<"PING\r\n">>;
unparse(pong) -> <<"PONG\r\n">>;
unparse(_) -> <<>>.

loop(#{sock := Sock, owner := Owner, conn := Conn} = S) ->
    receive
        {tcp, Sock, Data} ->
            #{buf := Buf} = S,
            {Events, Rest} = parse(<<Buf/binary, Data/binary>>),
            loop(handle(Events, S#{buf := Rest}));
        {tcp_passive, Sock} ->
            ok = inet:setopts(Sock, [{active, ?ACTIVE_N}]),
            loop(S);
        {tcp_closed, Sock} ->
            Owner ! {nats, Conn, {closed, tcp_closed}},
            ok;
        {tcp_error, Sock, Why} ->
            Owner ! {nats, Conn, {closed, Why}},
            ok;
        {sync, From, Ref, Bytes} ->
            #{waiting := W} = S,
            ok = gen_tcp:send(Sock, [Bytes, <<"PING\r\n">>]),
            loop(S#{waiting := queue:in({From, Ref}, W)})
    end.

handle([], S) ->
    S;
handle([{msg, Subject, Reply, Payload} | Rest], #{owner := Owner, conn := Conn} = S) ->
    Owner ! {nats, Conn, {msg, Subject, Reply, Payload}},
    handle(Rest, S);
handle([ping | Rest], #{sock := Sock} = S) ->
    ok = gen_tcp:send(Sock, <<"PONG\r\n">>),
    handle(Rest, S);
handle([pong | Rest], #{waiting := W} = S) ->
    case queue:out(W) of
        {{value, {From, Ref}}, W1} -> From ! {Ref, ok}, handle(Rest, S#{waiting := W1});
        {empty, _} -> handle(Rest, S)
    end;
handle([{err, Text} | _], #{owner := Owner, conn := Conn}) ->
    Owner ! {nats, Conn, {closed, {server_error, Text}}},
    exit(normal);
handle([_ | Rest], S) ->
    handle(Rest, S).

%% ---------------------------------------------------------------------------
%% The parser
%% ---------------------------------------------------------------------------

%% @doc The complete protocol messages at the head of Buf, and the bytes
%% of the incomplete one that follows (exported to be tried from a shell);
%% a line that is no NATS message is an `{err, Line}'.
-spec parse(binary()) -> {[event()], binary()}.
parse(Buf) ->
    parse(Buf, []).

parse(Buf, Acc) ->
    case binary:match(Buf, <<"\r\n">>) of
        nomatch ->
            {lists:reverse(Acc), Buf};
        {Pos, 2} ->
            <<Line:Pos/binary, "\r\n", After/binary>> = Buf,
            case control(Line, After) of
                {more} -> {lists:reverse(Acc), Buf};
                {Event, Rest} -> parse(Rest, [Event | Acc])
            end
    end.

control(<<"MSG ", Args/binary>>, After) ->
    {Subject, Reply, Len} = case binary:split(Args, [<<" ">>, <<"\t">>], [global, trim_all]) of
                                [Sub, _Sid, N] -> {Sub, undefined, N};
                                [Sub, _Sid, R, N] -> {Sub, R, N}
                            end,
    Size = binary_to_integer(Len),
    case After of
        <<Payload:Size/binary, "\r\n", Rest/binary>> -> {{msg, Subject, Reply, Payload}, Rest};
        _ when byte_size(After) < Size + 2 -> {more}
    end;
control(<<"PING">>, After) -> {ping, After};
control(<<"PONG">>, After) -> {pong, After};
control(<<"+OK">>, After) -> {ok, After};
control(<<"INFO ", Json/binary>>, After) -> {{info, Json}, After};
control(<<"-ERR ", Text/binary>>, After) -> {{err, Text}, After};
control(Line, After) -> {{err, Line}, After}.

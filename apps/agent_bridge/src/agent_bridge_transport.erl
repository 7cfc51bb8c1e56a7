%% @doc Internal. The transports a connection runs over: a TCP socket
%% accepted by a listener, the same upgraded to TLS (agent_bridge_tls), or
%% an Erlang port running an external program. All carry `{packet, 4}'
%% frames; writes never suspend the caller.
-module(agent_bridge_transport).

-export([accepted/3, peer_cert/1,
         send_fun/1, activate/2, top_up/2, is_passive/1, set_max_frame/2, drain/1, shutdown/1, close/1,
         abort/1, pending/1, peer/1]).

-export_type([t/0]).

%% The most messages searched for a write's reply (take_reply/1).
-define(REPLY_SEARCH, 16).

-type t() :: {tcp, gen_tcp:socket()} | {port, port()}
           | {tls, ssl:sslsocket(), agent_bridge_tls:writer()}.

%% @doc The transport of a socket a listener accepted: TCP as it is, or TLS
%% after a handshake run here, in the connection's process, within
%% `Timeout' ms (connection options with `tls', set by agent_bridge_tls).
-spec accepted(gen_tcp:socket(), map(), timeout()) -> {ok, t()} | {error, term()}.
accepted(Sock, #{tls := Tls}, Timeout) ->
    case agent_bridge_tls:handshake(Sock, Tls, Timeout) of
        {ok, SslSock} -> {ok, {tls, SslSock, agent_bridge_tls:start_writer(SslSock, Sock)}};
        {error, _} = Error -> Error
    end;
accepted(Sock, #{}, _Timeout) ->
    {ok, {tcp, Sock}}.

%% @doc The client certificate a TLS handshake verified.
-spec peer_cert(t()) -> evatar:peer_cert() | undefined.
peer_cert({tls, S, _}) -> agent_bridge_tls:peer_cert(S);
peer_cert(_) -> undefined.

%% @doc A function that writes one frame without suspending: false when the
%% transport is busy (its queue is over the high watermark). A transport
%% already closed takes the frame and drops it; the close arrives as a
%% message.
-spec send_fun(t()) -> agent_bridge_outq:send_fun().
send_fun({tls, _, Writer}) ->
    agent_bridge_tls:send_fun(Writer);
send_fun({tcp, Sock}) ->
    fun(Frame) ->
            try erlang:port_command(Sock, Frame, [nosuspend]) of
                true -> take_reply(Sock);
                false -> false
            catch error:badarg -> true
            end
    end;
send_fun({port, Port}) ->
    fun(Frame) ->
            try erlang:port_command(Port, Frame, [nosuspend])
            catch error:badarg -> true
            end
    end.

%% The inet driver answers every write with `{inet_reply, Sock, Status}',
%% usually before port_command/3 returns (the write ran on this scheduler).
%% Taken here, an `ok' costs the owner no event of its own (two of a round
%% trip's eight messages were these, bench/README.md). Only a short mailbox
%% is searched, so that an owner that is behind does not search a long one
%% at every write; a reply that is not there yet, and an error, reach the
%% owner's loop as before.
take_reply(Sock) ->
    case process_info(self(), message_queue_len) of
        {message_queue_len, N} when N =< ?REPLY_SEARCH ->
            receive {inet_reply, Sock, ok} -> true after 0 -> true end;
        _ ->
            true
    end.

%% @doc Lets the next N frames in (`once' for one). Ports cannot be paused.
-spec activate(t(), once | pos_integer()) -> ok.
activate({tcp, S}, N) -> ok_or_closed(sock_flow:activate(S, N));
activate({tls, S, _}, N) -> ok_or_closed(sock_flow:activate(S, N));
activate({port, _}, _) -> ok.

%% @doc Raises a socket's `{active, N}' count to `Target' frames still to
%% deliver (sock_flow:top_up/2: a passive socket, and TLS, are left alone).
-spec top_up(t(), integer()) -> ok.
top_up({tcp, S}, Target) -> sock_flow:top_up(S, Target);
top_up(_, _) -> ok.

%% @doc Whether a socket has stopped delivering frames (sock_flow:is_passive/1:
%% a closed one counts as passive, a TLS socket's notice is never stale).
-spec is_passive(t()) -> boolean().
is_passive({tcp, S}) -> sock_flow:is_passive(S);
is_passive({tls, S, _}) -> sock_flow:is_passive(S);
is_passive({port, _}) -> false.

-spec set_max_frame(t(), pos_integer()) -> ok.
set_max_frame({tcp, S}, Max) -> ok_or_closed(inet:setopts(S, [{packet_size, Max}]));
set_max_frame({tls, S, _}, Max) -> ok_or_closed(ssl:setopts(S, [{packet_size, Max}]));
set_max_frame({port, _}, _) -> ok.

%% @doc While closing: read what the peer still sends and throw it away, so
%% unread data is less likely to turn our close into a reset that loses our
%% last frame. Framing stays on (it applies to our output too); a nonsense
%% length ends the drain with an error, which is fine.
-spec drain(t()) -> ok.
drain(T) -> activate(T, once).

%% @doc Half-closes after the queued output; inet delays it until its queue
%% is empty, TLS's writer until it has written the frames it holds.
-spec shutdown(t()) -> ok.
shutdown({tcp, S}) -> ok_or_closed(gen_tcp:shutdown(S, write));
shutdown({tls, _, Writer}) -> agent_bridge_tls:shutdown(Writer);
shutdown({port, _}) -> ok.

-spec close(t() | undefined) -> ok.
close({tcp, S}) -> gen_tcp:close(S);
close({tls, S, Writer}) ->
    ok = agent_bridge_tls:stop_writer(Writer),
    _ = ssl:close(S),
    ok;
close({port, P}) ->
    try port_close(P) of true -> ok
    catch error:badarg -> ok
    end;
close(undefined) -> ok.

%% @doc Closes at once, dropping unsent output: a socket whose peer does
%% not read would otherwise be kept (with its descriptor) by a plain close
%% until the peer reads. The peer sees a reset.
-spec abort(t() | undefined) -> ok.
abort({tcp, S}) ->
    _ = inet:setopts(S, [{linger, {true, 0}}]),
    gen_tcp:close(S);
abort({tls, S, Writer}) ->
    agent_bridge_tls:abort(S, Writer);
abort(T) ->
    close(T).

%% @doc Whether the runtime still holds output for the socket (not yet
%% taken by the kernel).
-spec pending(t() | undefined) -> boolean().
pending({tcp, S}) ->
    case inet:getstat(S, [send_pend]) of
        {ok, [{send_pend, N}]} -> N > 0;
        _ -> false
    end;
pending(_) ->
    false.

%% @doc The peer's address for logs.
-spec peer(t()) -> binary().
peer({tls, S, _}) ->
    address(ssl:peername(S));
peer({tcp, S}) ->
    address(inet:peername(S));
peer({port, P}) ->
    iolist_to_binary(io_lib:format("~p", [P])).

address(Peername) ->
    case Peername of
        {ok, {Ip, Port}} -> iolist_to_binary([inet:ntoa(Ip), ":", integer_to_binary(Port)]);
        {error, _} -> <<"unknown">>
    end.

%% A closed socket is reported separately as tcp_closed.
ok_or_closed(ok) -> ok;
ok_or_closed({error, _}) -> ok.

%% @doc Internal to the mediator benchmark (evatar_bench). The transport
%% floor: per pairing, two relay processes owning the server sockets and a
%% middle process standing for the pairing, forwarding frames untouched
%% (no parse, no routing, no encode). Driven by the raw generator, it costs
%% what EVATAR's sockets and process hops cost with none of its work, so
%% EVATAR's figures can be read against it. In `codec' mode the relays also
%% parse each frame (bil_control:parse_frame/2) and encode what they write
%% (bil:encode_signal/1), as agent_bridge_conn does, so the codec's share
%% can be isolated. In `floor_direct' mode the middle process writes to the
%% destination socket itself instead of handing the frame to that socket's
%% relay: one process hop less per frame, the shape EVATAR would have if
%% the pairing wrote to its entities' sockets (bench/EVATAR_BENCH.md). In
%% `floor_owner' mode one process per pairing owns both sockets, reads
%% them and writes each frame to the other: no hop at all between the
%% sockets, the shape EVATAR would have if the pairing owned its entities'
%% connections; `codec_owner' adds the codec's work (parse, stamp, encode)
%% in that process, an estimate of what such a pairing could reach.
-module(evatar_bench_floor).

-export([kinds/0, listen/0, relay_pair/3, relay/3, middle/0, owner/1]).

-export_type([kind/0]).

-type kind() :: floor | codec | floor_direct | floor_owner | codec_owner.

-define(ACTIVE_N, 32).

%% @doc The generators that run against this module's relays, not EVATAR.
-spec kinds() -> [kind()].
kinds() -> [floor, codec, floor_direct, floor_owner, codec_owner].

%% @doc A listening socket for the floor on a free loopback port.
-spec listen() -> {{inet:ip_address(), inet:port_number()}, gen_tcp:socket()}.
listen() ->
    {ok, L} = gen_tcp:listen(0, [binary, {packet, 4}, {active, false}, {ip, {127, 0, 0, 1}},
                                 {reuseaddr, true}, {nodelay, true}, {backlog, 4096}]),
    {ok, Addr} = inet:sockname(L),
    {Addr, L}.

%% @doc Relays between the VA's and the Avatar's accepted sockets through a
%% middle process; returns the three processes.
-spec relay_pair(gen_tcp:socket(), gen_tcp:socket(), kind()) -> [pid()].
relay_pair(VaSock, AvSock, Kind) when Kind =:= floor_owner; Kind =:= codec_owner ->
    Owner = proc_lib:spawn(?MODULE, owner, [Kind]),
    ok = gen_tcp:controlling_process(VaSock, Owner),
    ok = gen_tcp:controlling_process(AvSock, Owner),
    Owner ! {sockets, VaSock, AvSock},
    [Owner];
relay_pair(VaSock, AvSock, Kind) ->
    Mid = proc_lib:spawn(?MODULE, middle, []),
    Va = proc_lib:spawn(?MODULE, relay, [Mid, va, Kind]),
    Av = proc_lib:spawn(?MODULE, relay, [Mid, av, Kind]),
    ok = gen_tcp:controlling_process(VaSock, Va),
    ok = gen_tcp:controlling_process(AvSock, Av),
    Va ! {socket, VaSock},
    Av ! {socket, AvSock},
    Mid ! case Kind of
              floor_direct -> {peers, Va, Av, VaSock, AvSock};
              _ -> {peers, Va, Av}
          end,
    [Va, Mid, Av].

%% @private
%% Like agent_bridge_conn: {active, 32} frames in, topped up at half the
%% batch so the socket never goes passive; nosuspend writes out.
-spec relay(pid(), va | av, floor | codec | floor_direct) -> ok.
relay(Mid, Tag, Kind) ->
    receive {socket, S} -> ok end,
    ok = evatar_bench_gen:start_reading(S, ?ACTIVE_N),
    relay_loop(S, Mid, Tag, Kind).

relay_loop(S, Mid, Tag, Kind) ->
    receive
        {tcp, S, Frame} ->
            ok = evatar_bench_gen:read_on(S, ?ACTIVE_N),
            Mid ! {Tag, decode(Kind, Frame)},
            relay_loop(S, Mid, Tag, Kind);
        {out, Msg} ->
            ok = send_frame(S, encode(Kind, Msg)),
            relay_loop(S, Mid, Tag, Kind);
        {tcp_passive, S} ->
            ok = evatar_bench_gen:reactivate(S, ?ACTIVE_N),
            relay_loop(S, Mid, Tag, Kind);
        {tcp_closed, S} ->
            Mid ! stop,
            ok;
        {inet_reply, _, _} ->
            relay_loop(S, Mid, Tag, Kind)
    end.

%% A write that does not wait while the socket takes it, and waits for room
%% when it does not.
send_frame(S, Frame) ->
    case erlang:port_command(S, Frame, [nosuspend]) of
        true -> ok;
        false -> gen_tcp:send(S, Frame)
    end.

decode(floor, Frame) ->
    Frame;
decode(floor_direct, Frame) ->
    Frame;
decode(codec, Frame) ->
    {ok, {signal, Signal}} = bil_control:parse_frame(Frame, #{}),
    %% What the pairing stamps before delivering.
    Signal#{seq := 1, epoch := 1}.

encode(floor, Frame) -> Frame;
encode(floor_direct, Frame) -> Frame;
encode(codec, Signal) -> bil:encode_signal(Signal).

%% @private
%% Stands for the pairing process: one more message hop each way.
-spec middle() -> ok.
middle() ->
    receive
        {peers, Va, Av} -> middle(Va, Av);
        {peers, Va, Av, VaSock, AvSock} -> direct(Va, Av, VaSock, AvSock)
    end.

%% Writes straight to the other side's socket; a busy socket gets the frame
%% through its relay, which then waits for room.
direct(Va, Av, VaSock, AvSock) ->
    receive
        {va, Frame} -> ok = write(AvSock, Av, Frame), direct(Va, Av, VaSock, AvSock);
        {av, Frame} -> ok = write(VaSock, Va, Frame), direct(Va, Av, VaSock, AvSock);
        {inet_reply, _, _} -> direct(Va, Av, VaSock, AvSock);
        stop -> ok
    end.

write(Sock, Relay, Frame) ->
    case erlang:port_command(Sock, Frame, [nosuspend]) of
        true -> ok;
        false -> Relay ! {out, Frame}, ok
    end.

middle(Va, Av) ->
    receive
        {va, Frame} -> Av ! {out, Frame}, middle(Va, Av);
        {av, Frame} -> Va ! {out, Frame}, middle(Va, Av);
        stop -> ok
    end.

%% @private
%% Owns both sockets of a pairing: a frame read from one is written to the
%% other by this process, with no process hop in between. Each socket is
%% topped up as agent_bridge_conn does.
-spec owner(floor_owner | codec_owner) -> ok.
owner(Kind) ->
    receive {sockets, Va, Av} -> ok end,
    _ = [ok = evatar_bench_gen:start_reading(S, ?ACTIVE_N) || S <- [Va, Av]],
    owner_loop(Kind, Va, Av).

owner_loop(Kind, Va, Av) ->
    receive
        {tcp, From, Frame} ->
            ok = evatar_bench_gen:read_on(From, ?ACTIVE_N),
            To = case From of
                     Va -> Av;
                     Av -> Va
                 end,
            Out = case Kind of
                      floor_owner -> Frame;
                      codec_owner -> encode(codec, decode(codec, Frame))
                  end,
            ok = send_frame(To, Out),
            owner_loop(Kind, Va, Av);
        {tcp_passive, S} ->
            ok = evatar_bench_gen:reactivate(S, ?ACTIVE_N),
            owner_loop(Kind, Va, Av);
        {inet_reply, _, _} ->
            owner_loop(Kind, Va, Av);
        {tcp_closed, _} ->
            ok
    end.

%% @doc Test support. A TCP proxy for one direction of a link between two
%% nodes (A dials B through it; evatar_test_epmd points A there), which a suite can
%% block and heal to make a network partition.
%% Part of the cluster harness (evatar_test_cluster).
%%
%% Blocking makes the link silent, as a partition does: the proxy stops
%% reading both sockets of every connection, so bytes stay in the kernel's
%% buffers, no FIN or RST is sent, and neither node notices anything but
%% silence; a new connection is accepted and then left unanswered. Healing
%% either lets everything through that waited (`flush': TCP's
%% retransmissions got through, the connections survive) or closes every
%% connection (`reset': TCP gave up), after which the nodes reconnect.
%%
%% ```
%%  passing --block--> blocked --unblock(flush)--> passing
%%                        |  --unblock(reset)--> passing, old connections closed
%% '''
-module(evatar_test_proxy).
-behaviour(gen_server).

-export([start/1, port/1, block/1, unblock/2, blocked/1, stop/1]).
-export([init/1, handle_call/3, handle_cast/2, handle_info/2, terminate/2]).
-export([pump_init/3]).

-type heal() :: flush | reset.
-export_type([heal/0]).

-record(s, {lsock :: gen_tcp:socket(),
            target :: inet:port_number(),
            blocked = false :: boolean(),
            pumps = #{} :: #{pid() => reference()}}).

%% @doc Starts a proxy on 127.0.0.1 (a free port) to 127.0.0.1:TargetPort.
%% Not linked: it outlives the process that started it (a CT group's init).
-spec start(inet:port_number()) -> {ok, pid()}.
start(TargetPort) ->
    gen_server:start(?MODULE, TargetPort, []).

-spec port(pid()) -> inet:port_number().
port(Proxy) -> gen_server:call(Proxy, port).

%% @doc Makes the link silent (see the module doc).
-spec block(pid()) -> ok.
block(Proxy) -> gen_server:call(Proxy, block).

%% @doc Heals the link: `flush' delivers what waited, `reset' closes the
%% connections that existed while it was blocked.
-spec unblock(pid(), heal()) -> ok.
unblock(Proxy, Mode) when Mode =:= flush; Mode =:= reset ->
    gen_server:call(Proxy, {unblock, Mode}).

-spec blocked(pid()) -> boolean().
blocked(Proxy) -> gen_server:call(Proxy, blocked).

-spec stop(pid()) -> ok.
stop(Proxy) -> gen_server:stop(Proxy).

%% ---------------------------------------------------------------------------

-spec init(inet:port_number()) -> {ok, #s{}}.
init(Target) ->
    {ok, LSock} = gen_tcp:listen(0, [binary, {ip, {127, 0, 0, 1}}, {active, false},
                                     {reuseaddr, true}, {backlog, 128}]),
    Self = self(),
    spawn_link(fun() -> accept_loop(Self, LSock) end),
    {ok, #s{lsock = LSock, target = Target}}.

-spec handle_call(term(), gen_server:from(), #s{}) -> {reply, term(), #s{}}.
handle_call(port, _From, #s{lsock = L} = S) ->
    {ok, Port} = inet:port(L),
    {reply, Port, S};
handle_call(block, _From, #s{pumps = Pumps} = S) ->
    _ = [P ! block || P <- maps:keys(Pumps)],
    {reply, ok, S#s{blocked = true}};
handle_call({unblock, Mode}, _From, #s{pumps = Pumps} = S) ->
    _ = [P ! {unblock, Mode} || P <- maps:keys(Pumps)],
    {reply, ok, S#s{blocked = false}};
handle_call(blocked, _From, S) ->
    {reply, S#s.blocked, S};
handle_call({accepted, Sock, Pump}, _From, #s{pumps = Pumps} = S) ->
    Ref = erlang:monitor(process, Pump),
    {reply, {S#s.target, S#s.blocked, Sock}, S#s{pumps = Pumps#{Pump => Ref}}}.

-spec handle_cast(term(), #s{}) -> {noreply, #s{}}.
handle_cast(_Msg, S) -> {noreply, S}.

-spec handle_info(term(), #s{}) -> {noreply, #s{}}.
handle_info({'DOWN', _, process, Pump, _}, #s{pumps = Pumps} = S) ->
    {noreply, S#s{pumps = maps:remove(Pump, Pumps)}};
handle_info(_Msg, S) ->
    {noreply, S}.

-spec terminate(term(), #s{}) -> ok.
terminate(_Why, #s{lsock = L, pumps = Pumps}) ->
    _ = [exit(P, kill) || P <- maps:keys(Pumps)],
    gen_tcp:close(L).

%% ---------------------------------------------------------------------------
%% Accepting and pumping
%% ---------------------------------------------------------------------------

accept_loop(Proxy, LSock) ->
    case gen_tcp:accept(LSock) of
        {ok, Sock} ->
            Pump = proc_lib:spawn(?MODULE, pump_init, [Proxy, Sock, self()]),
            ok = gen_tcp:controlling_process(Sock, Pump),
            Pump ! go,
            accept_loop(Proxy, LSock);
        {error, closed} ->
            ok
    end.

%% @private
-spec pump_init(pid(), gen_tcp:socket(), pid()) -> ok.
pump_init(Proxy, Down, _Acceptor) ->
    receive go -> ok end,
    {Target, Blocked, Down} = gen_server:call(Proxy, {accepted, Down, self()}),
    erlang:monitor(process, Proxy),
    case Blocked of
        false -> connect(Target, Down);
        true -> held(Target, Down)
    end.

%% A connection accepted while blocked: its bytes stay unread until healed.
held(Target, Down) ->
    receive
        block -> held(Target, Down);
        {unblock, flush} -> connect(Target, Down);
        {unblock, reset} -> gen_tcp:close(Down);
        {'DOWN', _, process, _, _} -> gen_tcp:close(Down)
    end.

connect(Target, Down) ->
    case gen_tcp:connect({127, 0, 0, 1}, Target, [binary, {active, false}, {nodelay, true}],
                         5000) of
        {ok, Up} ->
            ok = inet:setopts(Down, [{nodelay, true}]),
            _ = arm(Down),
            _ = arm(Up),
            pump(Down, Up, false, []);
        {error, _} ->
            gen_tcp:close(Down)
    end.

arm(Sock) -> inet:setopts(Sock, [{active, once}]).

%% Waiting holds what arrived while blocked, in order, with the socket it
%% came from; a closed socket while blocked is kept as `closed' in it too.
pump(Down, Up, Blocked, Waiting) ->
    receive
        {tcp, Sock, Data} when not Blocked ->
            case forward(Sock, Down, Up, Data) of
                ok ->
                    _ = arm(Sock),
                    pump(Down, Up, Blocked, Waiting);
                closed ->
                    close_both(Down, Up)
            end;
        {tcp, Sock, Data} ->
            pump(Down, Up, Blocked, [{Sock, Data} | Waiting]);
        {tcp_closed, _Sock} when not Blocked ->
            close_both(Down, Up);
        {tcp_closed, Sock} ->
            pump(Down, Up, Blocked, [{Sock, closed} | Waiting]);
        {tcp_error, _Sock, _} when not Blocked ->
            close_both(Down, Up);
        {tcp_error, Sock, _} ->
            pump(Down, Up, Blocked, [{Sock, closed} | Waiting]);
        block ->
            pump(Down, Up, true, Waiting);
        {unblock, reset} ->
            gen_tcp:close(Down),
            gen_tcp:close(Up);
        {unblock, flush} ->
            case replay(lists:reverse(Waiting), Down, Up) of
                ok ->
                    _ = arm(Down),
                    _ = arm(Up),
                    pump(Down, Up, false, []);
                closed ->
                    gen_tcp:close(Down),
                    gen_tcp:close(Up)
            end;
        {'DOWN', _, process, _, _} ->
            gen_tcp:close(Down),
            gen_tcp:close(Up)
    end.

replay([], _Down, _Up) -> ok;
replay([{_Sock, closed} | _], _Down, _Up) -> closed;
replay([{Sock, Data} | Rest], Down, Up) ->
    case forward(Sock, Down, Up, Data) of
        ok -> replay(Rest, Down, Up);
        closed -> closed
    end.

forward(Down, Down, Up, Data) -> send(Up, Data);
forward(Up, Down, Up, Data) -> send(Down, Data).

send(Sock, Data) ->
    case gen_tcp:send(Sock, Data) of
        ok -> ok;
        {error, _} -> closed
    end.

close_both(Down, Up) ->
    gen_tcp:close(Down),
    gen_tcp:close(Up).

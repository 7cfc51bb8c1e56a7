%% @doc Internal. One acceptor of a listener's pool: accepts a socket, asks
%% the listener's guard whether it may go on (else writes the refusal and
%% closes it at once), starts its connection process and hands the socket
%% over.
-module(agent_bridge_acceptor).

-export([start_link/3, loop/3]).

-include_lib("kernel/include/logger.hrl").

-spec start_link(gen_tcp:socket(), pid(), agent_bridge_conn:opts()) -> {ok, pid()}.
start_link(LSock, ListenerSup, ConnOpts) ->
    Pid = proc_lib:spawn_link(fun() ->
                                      ConnSup = agent_bridge_listener_sup:conn_sup(ListenerSup),
                                      Guard = agent_bridge_listener_sup:guard(ListenerSup),
                                      loop(LSock, ConnSup, ConnOpts#{guard => Guard})
                              end),
    {ok, Pid}.

-spec loop(gen_tcp:socket(), pid(), agent_bridge_conn:opts()) -> no_return().
loop(LSock, ConnSup, ConnOpts) ->
    case gen_tcp:accept(LSock) of
        {ok, Sock} ->
            ok = admit(Sock, ConnSup, ConnOpts);
        {error, closed} ->
            exit(normal);
        {error, Why} ->
            %% emfile and the like: back off rather than spin.
            ?LOG_WARNING(#{what => accept_failed, reason => Why}),
            timer:sleep(100)
    end,
    ?MODULE:loop(LSock, ConnSup, ConnOpts).

admit(Sock, ConnSup, #{guard := Guard} = ConnOpts) ->
    Ip = case inet:peername(Sock) of
             {ok, {Addr, _Port}} -> Addr;
             {error, _} -> unknown
         end,
    case agent_bridge_guard:admit(Guard, Ip) of
        ok -> hand_over(Sock, ConnSup, ConnOpts);
        {refuse, Code, LockedMs} -> agent_bridge_guard:refuse_socket(Sock, Code, LockedMs)
    end.

hand_over(Sock, ConnSup, #{guard := Guard} = ConnOpts) ->
    case agent_bridge_conn_sup:start_conn(ConnSup, ConnOpts) of
        {ok, Pid} ->
            ok = agent_bridge_guard:attach(Guard, Pid),
            case gen_tcp:controlling_process(Sock, Pid) of
                ok -> Pid ! {agent_bridge_shoot, Sock}, ok;
                {error, _} -> gen_tcp:close(Sock)
            end;
        {error, Why} ->
            ?LOG_WARNING(#{what => connection_not_started, reason => Why}),
            ok = agent_bridge_guard:release(Guard),
            gen_tcp:close(Sock)
    end.

%% @doc Internal. One acceptor of a listener's pool: accepts a socket,
%% starts its connection process and hands the socket over.
-module(agent_bridge_acceptor).

-export([start_link/3, loop/3]).

-include_lib("kernel/include/logger.hrl").

-spec start_link(gen_tcp:socket(), pid(), agent_bridge_conn:opts()) -> {ok, pid()}.
start_link(LSock, ListenerSup, ConnOpts) ->
    Pid = proc_lib:spawn_link(fun() ->
                                      ConnSup = agent_bridge_listener_sup:conn_sup(ListenerSup),
                                      loop(LSock, ConnSup, ConnOpts)
                              end),
    {ok, Pid}.

-spec loop(gen_tcp:socket(), pid(), agent_bridge_conn:opts()) -> no_return().
loop(LSock, ConnSup, ConnOpts) ->
    case gen_tcp:accept(LSock) of
        {ok, Sock} ->
            ok = hand_over(Sock, ConnSup, ConnOpts);
        {error, closed} ->
            exit(normal);
        {error, Why} ->
            %% emfile and the like: back off rather than spin.
            ?LOG_WARNING(#{what => accept_failed, reason => Why}),
            timer:sleep(100)
    end,
    ?MODULE:loop(LSock, ConnSup, ConnOpts).

hand_over(Sock, ConnSup, ConnOpts) ->
    case agent_bridge_conn_sup:start_conn(ConnSup, ConnOpts) of
        {ok, Pid} ->
            case gen_tcp:controlling_process(Sock, Pid) of
                ok -> Pid ! {agent_bridge_shoot, Sock}, ok;
                {error, _} -> gen_tcp:close(Sock)
            end;
        {error, Why} ->
            ?LOG_WARNING(#{what => connection_not_started, reason => Why}),
            gen_tcp:close(Sock)
    end.

%% @doc How every socket reader of EVATAR keeps its socket delivering
%% (the bridge's connections, agent_bridge_client, mqtt_client): sockets in
%% `{active, N}' mode, whose count is topped up every half batch of reads,
%% so that a busy connection never goes passive and the runtime polls its
%% socket from the schedulers instead of waking its poll thread for each
%% read (bench/EVATAR_BENCH.md); when it does go passive, the owner decides
%% whether to read on (is_passive/1 tells a stale notice from a real one).
%% TLS sockets are read by their own process, so topping them up gains
%% nothing: they go passive and are activated again.
-module(sock_flow).

-export([activate/2, top_up/2, is_passive/1, credit/1, read_on/3]).

-export_type([sock/0]).

-type sock() :: gen_tcp:socket() | ssl:sslsocket().

%% @doc Lets the next N reads in (`once' for one, `true' for all).
-spec activate(sock(), once | true | pos_integer()) -> ok | {error, term()}.
activate(S, N) when is_port(S) -> inet:setopts(S, [{active, N}]);
activate(S, N) -> ssl:setopts(S, [{active, N}]).

%% @doc Raises a TCP socket's `{active, N}' count to `Target' reads still
%% to deliver. A passive socket is left alone (its passive notice is on
%% its way, and the owner decides then), and so are TLS sockets. A closed
%% socket is reported by its own message.
-spec top_up(sock(), integer()) -> ok.
top_up(S, Target) when is_port(S) ->
    case inet:getopts(S, [active]) of
        {ok, [{active, Left}]} when is_integer(Left), Left > 0, Target > Left ->
            _ = inet:setopts(S, [{active, Target - Left}]),
            ok;
        _ ->
            ok
    end;
top_up(_S, _Target) ->
    ok.

%% @doc Whether the socket has stopped delivering (`{active, false}'): a
%% passive notice that a top-up overtook is stale. A closed socket counts
%% as passive, and so does a TLS socket after its notice (never topped up).
-spec is_passive(sock()) -> boolean().
is_passive(S) when is_port(S) ->
    case inet:getopts(S, [active]) of
        {ok, [{active, false}]} -> true;
        {ok, [{active, _}]} -> false;
        {error, _} -> true
    end;
is_passive(_S) ->
    true.

%% @doc Reads before the next top-up of a socket activated with N.
-spec credit(pos_integer()) -> pos_integer().
credit(N) -> max(1, N div 2).

%% @doc One read done out of `Credit': at the last one the socket is
%% topped up to N and a new credit starts.
-spec read_on(pos_integer(), sock(), pos_integer()) -> pos_integer().
read_on(Credit, _S, _N) when Credit > 1 ->
    Credit - 1;
read_on(_Credit, S, N) ->
    ok = top_up(S, N),
    credit(N).

%% @doc Internal. The guard of one listener: admits each accepted socket
%% or refuses it (too many connections, too many handshakes from its
%% address, address locked out), counts the sockets it admitted until their
%% connection process ends, slows down and locks out addresses that fail
%% handshakes, and logs refusals in rate-limited summaries. The decisions
%% are agent_bridge_guard_logic's; this process only holds its state, the
%% clock and the monitors.
-module(agent_bridge_guard).
-behaviour(gen_server).

-export([start_link/2, admit/2, attach/2, release/1, failed/2, locked/2, refused/4, info/1,
         refusal/2, refuse_socket/3]).
-export([init/1, handle_call/3, handle_cast/2, handle_info/2]).

-include_lib("kernel/include/logger.hrl").

-type guard() :: pid().
-export_type([guard/0]).

%% How long the acceptor waits to write a refusal to a new socket.
-define(REFUSE_SEND_TIMEOUT, 1000).
%% At most this much of a refused socket's input is read and dropped.
-define(REFUSE_DROP_MAX, 65536).

-spec start_link(term(), map()) -> {ok, pid()}.
start_link(Name, ListenerOpts) ->
    gen_server:start_link(?MODULE, {Name, ListenerOpts}, []).

%% @doc Whether a new socket from Ip may go on; `ok' counts it until
%% attach/2's process ends or release/1.
-spec admit(guard(), inet:ip_address() | term()) ->
          ok | {refuse, agent_bridge_guard_logic:refusal(), non_neg_integer()}.
admit(Guard, Ip) ->
    case gen_server:call(Guard, {admit, agent_bridge_guard_logic:key(Ip)}, infinity) of
        ok ->
            ok = evatar_metrics:inc(evatar_bridge_connections_accepted_total),
            ok;
        {refuse, Code, _} = Refuse ->
            ok = evatar_metrics:inc(evatar_bridge_connections_refused_total, Code),
            Refuse
    end.

%% @doc The connection process that holds an admitted socket.
-spec attach(guard(), pid()) -> ok.
attach(Guard, Pid) -> gen_server:cast(Guard, {attach, Pid}).

%% @doc An admitted socket that got no connection process.
-spec release(guard()) -> ok.
release(Guard) -> gen_server:cast(Guard, release).

%% @doc A failed handshake from Ip: ms to wait before the Refused, and
%% 0 or the ms the address is locked out for (agent_bridge_guard_logic:failed/3).
-spec failed(guard() | undefined, inet:ip_address() | term()) ->
          {non_neg_integer(), non_neg_integer()}.
failed(undefined, _Ip) -> {0, 0};
failed(Guard, Ip) -> gen_server:call(Guard, {failed, agent_bridge_guard_logic:key(Ip)}, infinity).

%% @doc 0, or the ms Ip stays locked out.
-spec locked(guard() | undefined, inet:ip_address() | term()) -> non_neg_integer().
locked(undefined, _Ip) -> 0;
locked(Guard, Ip) -> gen_server:call(Guard, {locked, agent_bridge_guard_logic:key(Ip)}, infinity).

%% @doc Logs (or counts for a summary) the refusal of Code to Ip; Details
%% (pairing, entity) go into the first line of an interval, cut to 64 bytes.
-spec refused(guard() | undefined, inet:ip_address() | term(), binary(), map()) -> ok.
refused(Guard, Ip, Code, Details) ->
    ok = evatar_metrics:inc(evatar_bridge_handshakes_refused_total, Code),
    refused1(Guard, Ip, Code, Details).

refused1(undefined, Ip, Code, Details) ->
    log({log, agent_bridge_guard_logic:key(Ip), Code, 1, first}, Details, undefined);
refused1(Guard, Ip, Code, Details) ->
    %% A call, so the line is written before the client sees the close.
    gen_server:call(Guard, {refused, agent_bridge_guard_logic:key(Ip), Code, Details}, infinity).

%% @doc Addresses tracked and sockets held (for tests and operators).
-spec info(guard()) -> #{addresses := non_neg_integer(), connections := non_neg_integer()}.
info(Guard) -> gen_server:call(Guard, info).

%% @doc The Refused document of one of the guard's codes.
-spec refusal(agent_bridge_guard_logic:refusal(), non_neg_integer()) ->
          {refused, #{code := binary(), message := binary()}}.
refusal(Code, LockedMs) ->
    Message = case Code of
                  <<"TooManyConnections">> -> <<"this listener has its maximum of connections">>;
                  <<"RateLimited">> -> <<"too many connections from your address; slow down">>;
                  <<"LockedOut">> ->
                      <<"too many failed handshakes from your address; retry in ",
                        (integer_to_binary((LockedMs + 999) div 1000))/binary, " s">>
              end,
    {refused, #{code => Code, message => Message}}.

%% @doc Writes Refused Code to a socket that was never handed to a
%% connection process, and closes it at once: a refused socket costs its
%% file descriptor only for this write. What the client sent already (its
%% Hello goes right after its connect) is read and dropped before the close,
%% at most ?REFUSE_DROP_MAX bytes and without waiting: a socket closed with
%% unread input is reset by the kernel instead of ended, and the reset can
%% destroy the Refused before the client has read it.
-spec refuse_socket(gen_tcp:socket(), binary(), non_neg_integer()) -> ok.
refuse_socket(Sock, Code, LockedMs) ->
    Frame = bil_control:encode(refusal(Code, LockedMs)),
    _ = inet:setopts(Sock, [{active, false}, {send_timeout, ?REFUSE_SEND_TIMEOUT},
                            {send_timeout_close, true}]),
    _ = gen_tcp:send(Sock, Frame),
    _ = gen_tcp:shutdown(Sock, write),
    ok = drop_input(Sock, ?REFUSE_DROP_MAX),
    gen_tcp:close(Sock).

drop_input(_Sock, Left) when Left =< 0 ->
    ok;
drop_input(Sock, Left) ->
    case gen_tcp:recv(Sock, 0, 0) of
        {ok, Data} -> drop_input(Sock, Left - iolist_size(Data));
        {error, _} -> ok
    end.

%% ---------------------------------------------------------------------------

-record(s, {name :: term(), interval :: pos_integer(),
            logic :: agent_bridge_guard_logic:state()}).

-spec init({term(), map()}) -> {ok, #s{}}.
init({Name, ListenerOpts}) ->
    Config = agent_bridge_guard_logic:config(ListenerOpts),
    ok = check_fd_limit(Name, maps:get(max_connections, Config)),
    ok = tick(expire, Config),
    ok = tick(summary, Config),
    {ok, #s{name = Name, interval = maps:get(summary_interval, Config),
            logic = agent_bridge_guard_logic:new(Config)}}.

-spec handle_call(term(), gen_server:from(), #s{}) -> {reply, term(), #s{}}.
handle_call({admit, Key}, _From, #s{logic = L} = S) ->
    Now = now_ms(),
    case agent_bridge_guard_logic:admit(Key, Now, L) of
        {ok, L1} ->
            {reply, ok, S#s{logic = L1}};
        {{refuse, Code, Ms}, L1} ->
            {Effects, L2} = agent_bridge_guard_logic:refused(Key, Code, Now, L1),
            ok = run(Effects, #{}, S),
            {reply, {refuse, Code, Ms}, S#s{logic = L2}}
    end;
handle_call({failed, Key}, _From, #s{logic = L} = S) ->
    {Delay, LockedMs, New, L1} = agent_bridge_guard_logic:failed(Key, now_ms(), L),
    New andalso ?LOG_WARNING(#{what => address_locked_out, listener => S#s.name,
                               address => address(Key), lockout_ms => LockedMs}),
    {reply, {Delay, LockedMs}, S#s{logic = L1}};
handle_call({locked, Key}, _From, #s{logic = L} = S) ->
    {reply, agent_bridge_guard_logic:locked(Key, now_ms(), L), S};
handle_call({refused, Key, Code, Details}, _From, #s{logic = L} = S) ->
    {Effects, L1} = agent_bridge_guard_logic:refused(Key, Code, now_ms(), L),
    ok = run(Effects, Details, S),
    {reply, ok, S#s{logic = L1}};
handle_call(info, _From, #s{logic = L} = S) ->
    {reply, agent_bridge_guard_logic:size(L), S}.

-spec handle_cast(term(), #s{}) -> {noreply, #s{}}.
handle_cast({attach, Pid}, S) ->
    _ = monitor(process, Pid),
    {noreply, S};
handle_cast(release, #s{logic = L} = S) ->
    {noreply, S#s{logic = agent_bridge_guard_logic:closed(L)}}.

-spec handle_info(term(), #s{}) -> {noreply, #s{}}.
handle_info({'DOWN', _, process, _, _}, #s{logic = L} = S) ->
    {noreply, S#s{logic = agent_bridge_guard_logic:closed(L)}};
handle_info({tick, expire, Config}, #s{logic = L} = S) ->
    ok = tick(expire, Config),
    {noreply, S#s{logic = agent_bridge_guard_logic:expire(now_ms(), L)}};
handle_info({tick, summary, Config}, #s{logic = L} = S) ->
    ok = tick(summary, Config),
    {Effects, L1} = agent_bridge_guard_logic:flush(L),
    ok = run(Effects, #{}, S),
    {noreply, S#s{logic = L1}}.

%% ---------------------------------------------------------------------------

run(Effects, Details, #s{name = Name, interval = Ms}) ->
    _ = [log(E, Details, {Name, Ms}) || E <- Effects],
    ok.

%% One line per effect, with a stable `what' (handshake_refused): the first
%% refusal of an address and reason in an interval, or the count of the
%% others over the interval (summary_ms).
log({log, Key, Code, Count, Kind}, Details, Listener) ->
    Interval = case Listener of
                   {_, Ms} when Kind =:= summary -> #{summary_ms => Ms};
                   _ -> #{}
               end,
    Report = maps:merge(evatar_log:report(maps:with([pairing, entity, role, tls], Details)),
                        Interval#{what => handshake_refused, reason => Code, count => Count,
                                  address => address(Key)}),
    Report1 = case Listener of
                  {Name, _} -> Report#{listener => Name};
                  undefined -> Report
              end,
    ?LOG_NOTICE(Report1).

tick(Kind, Config) ->
    Ms = case Kind of
             expire -> min(maps:get(failure_window, Config), 60000);
             summary -> maps:get(summary_interval, Config)
         end,
    _ = erlang:send_after(Ms, self(), {tick, Kind, Config}),
    ok.

%% A limit over the file descriptors the runtime may open is no limit: say
%% so when the listener starts.
check_fd_limit(_Name, infinity) -> ok;
check_fd_limit(Name, Max) ->
    case proplists:get_value(max_fds, erlang:system_info(check_io)) of
        Fds when is_integer(Fds), Max > Fds - 64 ->
            ?LOG_WARNING(#{what => max_connections_over_fd_limit, listener => Name,
                           max_connections => Max, max_fds => Fds});
        _ ->
            ok
    end,
    ok.

%% Milliseconds since the runtime started (never negative, unlike the
%% monotonic clock itself).
%% A peer's address for a log line.
address({v6, Prefix}) ->
    <<A:16, B:16, C:16, D:16>> = <<Prefix:64>>,
    iolist_to_binary([inet:ntoa({A, B, C, D, 0, 0, 0, 0}), "/64"]);
address(overflow) -> <<"other addresses">>;
address(local) -> <<"local">>;
address(Ip) ->
    case inet:ntoa(Ip) of
        {error, _} -> <<"unknown">>;
        S -> list_to_binary(S)
    end.

now_ms() ->
    erlang:monotonic_time(millisecond)
        - erlang:convert_time_unit(erlang:system_info(start_time), native, millisecond).

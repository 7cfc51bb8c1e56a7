%% @doc Erlang client of the EVATAR wire protocol (docs/protocol.md): joins
%% a pairing as a VA or an Avatar over TCP or TLS, sends descriptions and signals,
%% and passes what EVATAR sends to an owner process as messages:
%% `{agent_bridge, Client, {signal, Signal}}',
%% `{agent_bridge, Client, {binding, Report}}' and, last,
%% `{agent_bridge, Client, {closed, Reason}}' (only a client that had
%% connected sends it: a failed connect is the caller's error).
%%
%% With `ha => true' it speaks protocol version 2 (docs/protocol.md section
%% 9): it keeps every signal until EVATAR acknowledges it, acknowledges what
%% it receives, and when the connection goes (closed, a Refused that means
%% "try elsewhere", or a silent server) it reconnects through its endpoints,
%% starting with the next one, resumes the session, sends again what was
%% not acknowledged and passes nothing twice to the owner. When the server
%% lost the session (every node restarted) it describes itself again and
%% holds its signals until a Binding report shows another entity
%% registered. The owner then
%% also gets `{agent_bridge, Client, {reconnected, Info}}' and, with
%% `notify_acks => true', `{agent_bridge, Client, {accepted, [SignalID]}}'.
%%
%% `close/1' works in every state and any number of times: while
%% connecting it stops the attempt (the `connect/1' caller gets `{error,
%% closed}'), once connected it says Bye and waits for EVATAR's Bye (at
%% most `close_timeout' ms), so the same EntityID can connect again at
%% once. The TCP (and TLS) connect runs in a short-lived helper process, so
%% the client answers `close/1' while it waits.
%%
%% ```
%%  idle --connect/1--> connecting --TCP up, Hello/Resume sent--> handshaking --Welcome--> connected
%%                       ^   | all endpoints failed                | Refused      | closed, Refused, Bye
%%                       |   v                                     v              v
%%                       +-- next endpoint (ha: with back-off, until reconnect_limit) <--+ (ha)
%%                           (stop)                              (stop)         (stop, not ha)
%%  connected --close/1: Bye--> closing --EVATAR's Bye, closed or close_timeout--> (stop)
%%  any other state --close/1--> (stop)
%% '''
-module(agent_bridge_client).
-behaviour(gen_statem).

-export([connect/2, start/2, connect/1, describe/2, send/2, request/3, get_binding/1,
         close/1, session/1, status/1, await_acks/2]).
-export([init/1, callback_mode/0, handle_event/4, terminate/3]).

-export_type([opts/0, endpoint/0, close_reason/0, partial_signal/0, connect_error/0]).

-type endpoint() :: {inet:socket_address() | inet:hostname(), inet:port_number()}.
%% `ha' (default false) turns on protocol version 2; `reconnect_backoff'
%% (ms, doubling, default {20, 500}) and `reconnect_limit' (ms without a
%% session before giving up, default 600000: longer than a machine's
%% reboot, so clients outlast a power cut) apply to it, and so does
%% `notify_acks' (default false). `close_timeout' (ms, default 5000) bounds
%% how long close/1 waits for EVATAR's Bye. `tls' (default false: plain TCP) connects
%% with TLS and checks the server (agent_bridge_client_sock:tls_opts(),
%% docs/clients.md, "TLS").
-type opts() :: #{pairing := binary(),
                  role := agent | avatar,
                  entity_id := binary(),
                  credential := binary(),
                  tls => agent_bridge_client_sock:tls_opts() | false,
                  owner => pid(),
                  connect_timeout => timeout(),
                  handshake_timeout => timeout(),
                  close_timeout => timeout(),
                  max_frame => pos_integer(),
                  active_n => pos_integer(),
                  ha => boolean(),
                  reconnect_backoff => {pos_integer(), pos_integer()},
                  reconnect_limit => pos_integer(),
                  notify_acks => boolean()}.
%% A signal with `id', `timestamp', `in_reply_to', `seq' and `epoch' left
%% out; the client fills them in.
-type partial_signal() :: #{context => bil:signal_context(),
                            sender := binary(),
                            receiver := binary(),
                            body := bil:entry(),
                            id => binary(),
                            in_reply_to => binary() | undefined,
                            timestamp => non_neg_integer(),
                            seq => non_neg_integer() | undefined,
                            epoch => non_neg_integer() | undefined}.
-type close_reason() :: closed | normal
                      | {refused, Code :: binary(), Message :: binary()}
                      | {bye, binary()}
                      | {malformed, bil:error_reason()}
                      | {socket_error, term()}
                      | {gave_up, term()}.

%% Why connect/1,2 failed: EVATAR refused (`{refused, Code, Message}'), no
%% endpoint answered (`{unreachable, [{Endpoint, Why}]}'), close/1 was
%% called meanwhile or the client had stopped (`closed'), the client is
%% connected already (`already_connected') or another process is
%% connecting it (`connecting').
-type connect_error() :: {refused, binary(), binary()}
                       | {unreachable, [{endpoint(), term()}]}
                       | closed | already_connected | connecting.

%% Refusals after which a version 2 client tries the next endpoint.
-define(RETRY_CODES, [<<"NotActive">>, <<"Fenced">>, <<"StaleEpoch">>, <<"PairingDown">>,
                      <<"UnknownPairing">>, <<"HandshakeTimeout">>, <<"SilentLink">>,
                      <<"SessionResumed">>, <<"TooManyConnections">>, <<"RateLimited">>]).
-define(ACK_DELAY, 5).
-define(RECONNECT_LIMIT, 600000).
-define(ACK_EVERY, 32).

-record(d, {opts :: opts(),
            owner :: pid(),
            endpoints :: [endpoint()],
            failures = [] :: [{endpoint(), term()}],
            current :: endpoint() | undefined,
            sock :: agent_bridge_client_sock:sock() | undefined,
            waiter :: gen_statem:from() | undefined,
            %% The helper process making the TCP (TLS) connection.
            connector :: {pid(), reference()} | undefined,
            %% close/1 callers waiting for EVATAR's Bye.
            closers = [] :: [gen_statem:from()],
            welcome :: bil_control:welcome() | undefined,
            nonce :: binary(),
            counter = 0 :: non_neg_integer(),
            pending = #{} :: #{binary() => gen_statem:from()},
            %% Protocol version 2 only.
            ha = false :: boolean(),
            all :: [endpoint()],
            next = 0 :: non_neg_integer(),
            tried = 0 :: non_neg_integer(),
            backoff = 0 :: non_neg_integer(),
            lost_at :: integer() | undefined,
            last_reason :: term(),
            session_id :: binary() | undefined,
            epoch = 0 :: non_neg_integer(),
            last_seq = 0 :: non_neg_integer(),
            acked_seq = 0 :: non_neg_integer(),
            ack_timer = false :: boolean(),
            unacked = queue:new() :: queue:queue({binary(), iodata()}),
            unacked_n = 0 :: non_neg_integer(),
            blocked = queue:new() :: queue:queue({gen_statem:from(), {binary(), iodata()},
                                                   signal | request}),
            ack_waiters = [] :: [gen_statem:from()],
            description :: iodata() | undefined,
            heartbeat = 0 :: non_neg_integer(),
            last_rx = 0 :: integer(),
            window = 1024 :: pos_integer(),
            ever_connected = false :: boolean(),
            %% A new session after a reconnect (the server had lost the
            %% old one, e.g. every node restarted): signals wait until a
            %% Binding report shows another entity registered, instead of
            %% being refused as UnknownReceiver while it is not back yet.
            held = false :: boolean(),
            %% Frames to read before the socket's count is topped up.
            reads = 1 :: pos_integer()}).

%% ---------------------------------------------------------------------------
%% API
%% ---------------------------------------------------------------------------

%% @doc Connects to the first endpoint that answers and completes the
%% handshake: start/2 then connect/1. A Refused ends the attempt at once:
%% the same credential would be refused elsewhere too (with `ha', a refusal
%% meaning "not here", such as NotActive, moves on to the next endpoint
%% instead, with back-off, for up to `reconnect_limit' ms). On an error the
%% client's process is gone when this returns, and so is its socket.
-spec connect([endpoint()], opts()) -> {ok, pid()} | {error, connect_error()}.
connect(Endpoints, Opts) ->
    {ok, Pid} = start(Endpoints, Opts),
    case connect(Pid) of
        {ok, Pid} ->
            {ok, Pid};
        {error, _} = Error ->
            Ref = monitor(process, Pid),
            receive {'DOWN', Ref, process, Pid, _} -> Error end
    end.

%% @doc A client that has not connected yet: connect/1 connects it, and
%% close/1 (from any process) stops it, also while connect/1 runs. Its
%% owner is `owner' (default the caller); it stops when the owner does.
-spec start([endpoint()], opts()) -> {ok, pid()}.
start(Endpoints, Opts) ->
    Owner = maps:get(owner, Opts, self()),
    gen_statem:start(?MODULE, {Endpoints, Opts, Owner}, []).

%% @doc Connects a client made by start/2 and returns once EVATAR welcomed
%% it. Fails locally, without a connection, with `{error,
%% already_connected}' for a client connected before (with `ha', also one
%% that is reconnecting) and `{error, connecting}' while another process
%% connects it; `{error, closed}' when close/1 stopped it meanwhile or it
%% had stopped. After any other error the client stops.
-spec connect(pid()) -> {ok, pid()} | {error, connect_error()}.
connect(Client) ->
    call(Client, connect).

%% @doc Sends a description; returns once written (with `ha': once queued;
%% it is sent again after a reconnect that did not resume the session). The
%% Binding report comes later as a message.
-spec describe(pid(), bil:description()) -> ok | {error, closed}.
describe(Client, Description) ->
    call(Client, {describe, bil:encode_description(Description)}).

%% @doc Sends a signal, filling in what the caller left out. With `ha' it
%% returns once the signal is queued: it is kept, and sent again after a
%% reconnect, until EVATAR acknowledges it; at most the session's
%% DedupWindow signals wait for an Ack, beyond that the call waits. A
%% signal that cannot be encoded (a missing or ill-typed field, a parameter
%% name that is not an XML name) is `{error, {bad_signal, Why}}': nothing
%% is sent and the client and its session go on (request/3 alike).
-spec send(pid(), partial_signal()) -> ok | {error, closed | {bad_signal, term()}}.
send(Client, Signal) ->
    call(Client, {signal, Signal}).

%% @doc Sends a request awaiting feedback and waits for the answer:
%% `{ok, Feedback}' (possibly EVATAR's own Timeout feedback: body category
%% EVATAR, type Timeout), `{error, Signal}' for an error signal answering
%% it, `{error, timeout}' when nothing came within Timeout ms. Progress
%% signals reach the owner as usual. With `ha' the wait goes on across
%% reconnects.
-spec request(pid(), partial_signal(), timeout()) ->
          {ok, bil:signal()} | {error, timeout | closed | {bad_signal, term()} | bil:signal()}.
request(Client, Signal, Timeout) ->
    call(Client, {request, Signal, Timeout}).

%% @doc Asks EVATAR for the pairing's current Binding report (GetBinding,
%% docs/protocol.md section 2); it comes as `{agent_bridge, Client,
%% {binding, Report}}'. With `ha', while reconnecting: `ok', since a resumed
%% session is sent the report anyway.
-spec get_binding(pid()) -> ok | {error, closed}.
get_binding(Client) ->
    call(Client, get_binding).

%% @doc Closes the client, in any state, and returns `ok' once it has
%% stopped, also when it had stopped already. Connected, it says Bye and
%% waits for EVATAR's Bye or the end of the connection, at most
%% `close_timeout' ms (default 5000): EVATAR has then let go of the
%% EntityID, and a new connection with it is not refused EntityExists.
%% Waiting callers get `{error, closed}'; the owner gets `{closed, normal}'
%% when the client had connected.
-spec close(pid()) -> ok.
close(Client) ->
    Ref = monitor(process, Client),
    case call(Client, close) of
        ok -> ok;
        {error, closed} -> ok
    end,
    %% The reply comes before terminate/3: wait for the socket to be closed.
    receive {'DOWN', Ref, process, _, _} -> ok end.

%% @doc The Welcome of the current session.
-spec session(pid()) -> {ok, bil_control:welcome()} | {error, closed}.
session(Client) -> call(Client, session).

%% @doc Where the client stands: connected or not, the endpoint, the
%% session, the highest epoch seen, the signals not yet acknowledged and the
%% highest Sequence passed to the owner.
-spec status(pid()) -> {ok, map()} | {error, closed}.
status(Client) -> call(Client, status).

%% @doc Waits until every signal sent so far is acknowledged (`ha' only;
%% without it, returns ok at once).
-spec await_acks(pid(), timeout()) -> ok | {error, timeout | closed}.
await_acks(Client, Timeout) ->
    try gen_statem:call(Client, await_acks, Timeout)
    catch exit:{timeout, _} -> {error, timeout};
          exit:{noproc, _} -> {error, closed};
          exit:{normal, _} -> {error, closed}
    end.

call(Client, Request) ->
    try gen_statem:call(Client, Request)
    catch exit:{noproc, _} -> {error, closed};
          exit:{normal, _} -> {error, closed}
    end.

%% ---------------------------------------------------------------------------
%% States
%% ---------------------------------------------------------------------------

-spec callback_mode() -> gen_statem:callback_mode_result().
callback_mode() -> handle_event_function.

-spec init({[endpoint()], opts(), pid()}) -> gen_statem:init_result(idle).
init({Endpoints, Opts, Owner}) ->
    monitor(process, Owner),
    D = #d{opts = Opts, owner = Owner, endpoints = Endpoints, all = Endpoints,
           ha = maps:get(ha, Opts, false) =:= true,
           nonce = binary:encode_hex(crypto:strong_rand_bytes(4))},
    {ok, idle, D}.

-spec handle_event(gen_statem:event_type(), term(), atom(), #d{}) ->
          gen_statem:event_handler_result(atom()).
handle_event({call, From}, connect, idle, D) ->
    %% Connecting starts only now, so the outcome always has a caller to go to.
    {next_state, connecting, D#d{waiter = From, lost_at = now_ms()},
     [{next_event, internal, connect}]};
handle_event({call, From}, connect, State, #d{waiter = W, ever_connected = Ever}) ->
    Why = if State =:= closing -> closed;
             W =/= undefined, not Ever -> connecting;
             true -> already_connected
          end,
    {keep_state_and_data, [{reply, From, {error, Why}}]};
handle_event(internal, connect, connecting, #d{ha = true} = D) ->
    attempt(D);
handle_event({timeout, retry}, retry, connecting, D) ->
    attempt(D);
handle_event(internal, connect, connecting, #d{endpoints = []} = D) ->
    fail({unreachable, lists:reverse(D#d.failures)}, D);
handle_event(internal, connect, connecting, #d{endpoints = [E | Rest]} = D) ->
    try_endpoint(E, D#d{endpoints = Rest});
handle_event(info, {connected, Ref, Result, Early}, connecting, #d{connector = {_, Ref}} = D) ->
    %% What the socket said while the connector owned it is read first.
    with_events(connected_to(Result, D#d{connector = undefined}),
                [{next_event, info, M} || M <- Early]);
%% A socket message sent to us before the connector's {connected, ...}:
%% read once the socket is ours.
handle_event(info, Msg, connecting, #d{connector = {_, _}})
  when is_tuple(Msg), tuple_size(Msg) >= 2,
       (element(1, Msg) =:= ssl orelse element(1, Msg) =:= ssl_error orelse
        element(1, Msg) =:= ssl_closed orelse element(1, Msg) =:= tcp orelse
        element(1, Msg) =:= tcp_error orelse element(1, Msg) =:= tcp_closed) ->
    {keep_state_and_data, [postpone]};
%% A TLS socket's messages, read as a TCP socket's.
handle_event(info, {ssl, Sock, Frame}, State, D) ->
    handle_event(info, {tcp, Sock, Frame}, State, D);
handle_event(info, {ssl_passive, Sock}, State, D) ->
    handle_event(info, {tcp_passive, Sock}, State, D);
handle_event(info, {ssl_closed, Sock}, State, D) ->
    handle_event(info, {tcp_closed, Sock}, State, D);
handle_event(info, {ssl_error, Sock, Why}, State, D) ->
    handle_event(info, {tcp_error, Sock, Why}, State, D);
handle_event(state_timeout, E, handshaking, D) ->
    agent_bridge_client_sock:close(D#d.sock),
    next_endpoint(E, handshake_timeout, D#d{sock = undefined});
handle_event(info, {tcp, Sock, Frame}, handshaking, #d{sock = Sock} = D) ->
    case bil_control:parse_frame(Frame, #{}) of
        {ok, {control, {welcome, Welcome}}} ->
            ok = agent_bridge_client_sock:setopts(Sock, [{active, active_n(D)}]),
            reply_waiter({ok, self()}, D),
            welcomed(Welcome, D#d{welcome = Welcome, waiter = undefined,
                                  reads = max(1, active_n(D) div 2)});
        {ok, {control, {refused, #{code := Code, message := Message}}}} ->
            refused_in_handshake(Code, Message, D);
        {ok, Other} ->
            fail({refused, <<"BadHandshake">>,
                  iolist_to_binary(io_lib:format("expected Welcome, got ~p", [Other]))}, D);
        {error, Reason} ->
            fail({refused, <<"Malformed">>, bil:format_error(Reason)}, D)
    end;
handle_event(info, {tcp_closed, Sock}, handshaking, #d{sock = Sock} = D) ->
    next_endpoint(D#d.current, closed, D#d{sock = undefined});
handle_event(info, {tcp_error, Sock, Why}, handshaking, #d{sock = Sock} = D) ->
    next_endpoint(D#d.current, Why, D#d{sock = undefined});

%% Connected.
handle_event(info, {tcp, Sock, Frame}, connected, #d{sock = Sock, ha = false} = D) ->
    incoming(bil_control:parse_frame(Frame, #{}), read_on(D));
handle_event(info, {tcp, Sock, Frame}, connected, #d{sock = Sock} = D) ->
    incoming(bil_control:parse_frame(Frame, #{}), read_on(D#d{last_rx = now_ms()}));
handle_event(info, {tcp_passive, Sock}, connected, #d{sock = Sock} = D) ->
    %% A top-up made just as the socket went passive makes this notice stale.
    case agent_bridge_client_sock:getopts(Sock, [active]) of
        {ok, [{active, false}]} ->
            ok = agent_bridge_client_sock:setopts(Sock, [{active, active_n(D)}]),
            {keep_state, D#d{reads = max(1, active_n(D) div 2)}};
        _ ->
            keep_state_and_data
    end;
handle_event(info, {tcp_closed, Sock}, connected, #d{sock = Sock} = D) ->
    disconnected(closed, D);
handle_event(info, {tcp_error, Sock, Why}, connected, #d{sock = Sock} = D) ->
    disconnected({socket_error, Why}, D);
handle_event({timeout, ack}, ack, connected, D) ->
    {keep_state, send_ack(D#d{ack_timer = false})};
handle_event({timeout, ack}, ack, _State, D) ->
    {keep_state, D#d{ack_timer = false}};
handle_event({timeout, silence}, check, connected, #d{heartbeat = Hb, last_rx = Rx} = D) ->
    case now_ms() - Rx > 3 * Hb of
        true -> disconnected(server_silent, D);
        false -> {keep_state_and_data, [{{timeout, silence}, Hb, check}]}
    end;
handle_event({timeout, silence}, check, _State, _D) ->
    keep_state_and_data;

%% Requests from the owner. Once close/1 has said Bye, nothing more is
%% taken (with `ha' it would be queued and lost).
handle_event({call, From}, close, closing, D) ->
    {keep_state, D#d{closers = [From | D#d.closers]}};
handle_event({call, From}, Request, closing, _D) when Request =/= status ->
    {keep_state_and_data, [{reply, From, {error, closed}}]};
handle_event({call, From}, {describe, Doc}, State, #d{ha = true} = D) ->
    _ = [write(Doc, D) || State =:= connected],
    {keep_state, D#d{description = Doc}, [{reply, From, ok}]};
handle_event({call, From}, {describe, Doc}, connected, D) ->
    {keep_state_and_data, [{reply, From, write(Doc, D)}]};
handle_event({call, From}, {signal, Partial}, State, #d{ha = true} = D) ->
    ha_send(From, {signal, Partial}, State, D);
handle_event({call, From}, {signal, Partial}, connected, D) ->
    case encode(Partial, D) of
        {ok, _Id, Frame, D1} -> {keep_state, D1, [{reply, From, write(Frame, D1)}]};
        {error, _} = Error -> {keep_state_and_data, [{reply, From, Error}]}
    end;
handle_event({call, From}, {request, _, _} = Request, State, #d{ha = true} = D) ->
    ha_send(From, Request, State, D);
handle_event({call, From}, {request, Partial, Timeout}, connected, D) ->
    case encode(Partial#{context => request}, D) of
        {ok, Id, Frame, D1} ->
            case write(Frame, D1) of
                ok ->
                    {keep_state, D1#d{pending = maps:put(Id, From, D1#d.pending)},
                     [{{timeout, {request, Id}}, Timeout, Id}]};
                {error, _} = Error ->
                    {keep_state, D1, [{reply, From, Error}]}
            end;
        {error, _} = Error ->
            {keep_state_and_data, [{reply, From, Error}]}
    end;
handle_event({timeout, {request, Id}}, Id, _State, D) ->
    answer(Id, {error, timeout}, D);
handle_event({call, From}, get_binding, connected, D) ->
    {keep_state_and_data, [{reply, From, write(bil_control:encode({get_binding, #{}}), D)}]};
handle_event({call, From}, get_binding, _State, #d{ha = true}) ->
    {keep_state_and_data, [{reply, From, ok}]};
handle_event({call, From}, session, connected, #d{welcome = W}) ->
    {keep_state_and_data, [{reply, From, {ok, W}}]};
handle_event({call, From}, status, State, D) ->
    {keep_state_and_data, [{reply, From, {ok, status(State, D)}}]};
handle_event({call, From}, await_acks, _State, #d{unacked_n = 0, blocked = B} = D) ->
    case queue:is_empty(B) of
        true -> {keep_state_and_data, [{reply, From, ok}]};
        false -> {keep_state, D#d{ack_waiters = [From | D#d.ack_waiters]}}
    end;
handle_event({call, From}, await_acks, _State, D) ->
    {keep_state, D#d{ack_waiters = [From | D#d.ack_waiters]}};
handle_event({call, From}, close, connected, #d{sock = Sock, opts = Opts} = D) ->
    %% EVATAR answers Bye once the entity has left: waiting for it lets the
    %% same EntityID connect again at once. Its Bye, the end of the
    %% connection or the timeout ends the wait.
    case agent_bridge_client_sock:send(Sock, bil_control:encode({bye, <<>>})) of
        ok ->
            _ = agent_bridge_client_sock:setopts(Sock, [{active, true}]),
            {next_state, closing, finish_quietly(D#d{closers = [From]}),
             [{state_timeout, maps:get(close_timeout, Opts, 5000), close},
              {{timeout, silence}, cancel}, {{timeout, ack}, cancel}]};
        {error, _} ->
            {stop_and_reply, normal, [{reply, From, ok}], finish({closed, normal}, D)}
    end;
handle_event({call, From}, close, State, D) ->
    %% Not connected: an attempt in progress stops here (terminate/3 ends
    %% the helper and the socket), and its caller is told.
    reply_waiter({error, closed}, D),
    Event = case State of
                idle -> none;
                _ -> {closed, normal}
            end,
    D1 = case D#d.ever_connected of
             true when Event =/= none -> finish(Event, D);
             _ -> finish_quietly(D)
         end,
    {stop_and_reply, normal, [{reply, From, ok}], D1#d{waiter = undefined}};
handle_event(info, {tcp, Sock, Frame}, closing, #d{sock = Sock} = D) ->
    case bil_control:parse_frame(Frame, #{}) of
        {ok, {control, {bye, _}}} -> closed(D);
        _ -> keep_state_and_data
    end;
handle_event(info, {tcp_passive, Sock}, closing, #d{sock = Sock}) ->
    _ = agent_bridge_client_sock:setopts(Sock, [{active, true}]),
    keep_state_and_data;
handle_event(info, {tcp_closed, Sock}, closing, #d{sock = Sock} = D) ->
    closed(D);
handle_event(info, {tcp_error, Sock, _}, closing, #d{sock = Sock} = D) ->
    closed(D);
handle_event(state_timeout, close, closing, D) ->
    closed(D);
handle_event({call, From}, _Request, _State, _D) ->
    {keep_state_and_data, [{reply, From, {error, closed}}]};
handle_event(info, {'DOWN', _, process, Owner, _}, _State, #d{owner = Owner} = D) ->
    reply_waiter({error, closed}, D),
    _ = [gen_statem:reply(F, ok) || F <- D#d.closers],
    {stop, normal, finish_quietly(D#d{waiter = undefined})};
handle_event(info, _Other, _State, _D) ->
    keep_state_and_data.

-spec terminate(term(), atom(), #d{}) -> ok.
terminate(_Why, _State, #d{sock = Sock, connector = Connector}) ->
    _ = [agent_bridge_client_sock:close(Sock) || Sock =/= undefined],
    case Connector of
        undefined ->
            ok;
        {Pid, _} ->
            %% Gone with its socket before the client is.
            Ref = monitor(process, Pid),
            exit(Pid, kill),
            receive {'DOWN', Ref, process, Pid, _} -> ok end
    end.

%% The end of close/1 on a connected client.
closed(#d{closers = Closers} = D) ->
    {stop_and_reply, normal, [{reply, F, ok} || F <- Closers],
     notify({closed, normal}, D#d{closers = []})}.

%% ---------------------------------------------------------------------------
%% Connecting
%% ---------------------------------------------------------------------------

%% The TCP (TLS) connect runs in a helper, so that close/1 is answered
%% meanwhile; the helper hands the socket over and ends. Killed with the
%% client, it takes a socket it still owns with it.
try_endpoint({Host, Port} = E, D) ->
    Opts = D#d.opts,
    %% Active once from the start: with TLS 1.3 a server refuses a client
    %% certificate after the client's handshake, and a passive socket
    %% whose connection has ended that way loses the alert saying why.
    SockOpts = [binary, {packet, 4}, {packet_size, maps:get(max_frame, Opts, 1048576)},
                {active, once}, {nodelay, true}],
    How = #{tls => maps:get(tls, Opts, false),
            timeout => maps:get(connect_timeout, Opts, 5000)},
    Self = self(),
    Ref = make_ref(),
    Pid = spawn(fun() -> connector(Self, Ref, Host, Port, SockOpts, How) end),
    {next_state, connecting, D#d{connector = {Pid, Ref}, current = E}}.

connector(Client, Ref, Host, Port, SockOpts, How) ->
    {Result, Early} =
        case agent_bridge_client_sock:connect(Host, Port, SockOpts, How) of
            {ok, Sock} ->
                case agent_bridge_client_sock:controlling_process(Sock, Client) of
                    ok ->
                        {{ok, Sock}, early(Sock, [])};
                    {error, Why} ->
                        %% The connection ended before the hand-over (a
                        %% refused client certificate): its error says why.
                        {{error, ended_with(early(Sock, []), Why)}, []}
                end;
            {error, _} = Error ->
                {Error, []}
        end,
    Client ! {connected, Ref, Result, Early},
    ok.

ended_with([{Tag, _, Why} | _], _) when Tag =:= ssl_error; Tag =:= tcp_error ->
    Why;
ended_with([_ | Rest], Default) ->
    ended_with(Rest, Default);
ended_with([], Default) ->
    Default.

%% What the socket sent while this process owned it (at most its one
%% active-once message, and its close): the client reads it before
%% anything the socket sends it directly.
early(Sock, Acc) ->
    receive
        {Tag, Sock} = Msg when Tag =:= tcp_closed; Tag =:= ssl_closed ->
            early(Sock, [Msg | Acc]);
        {Tag, Sock, _} = Msg when Tag =:= tcp; Tag =:= tcp_error; Tag =:= ssl; Tag =:= ssl_error ->
            early(Sock, [Msg | Acc])
    after 0 ->
        lists:reverse(Acc)
    end.

%% connected_to/2 always answers {next_state, State, D, Actions}.
with_events({next_state, State, D, Actions}, Events) ->
    {next_state, State, D, Actions ++ Events}.

connected_to({ok, Sock}, #d{current = E, opts = Opts} = D) ->
    %% Active once since the connect; what came before the hand-over
    %% follows as messages from the connector.
    case agent_bridge_client_sock:send(Sock, bil_control:encode(hello(D))) of
        Sent when Sent =:= ok; not is_port(Sock) ->
            %% With TLS 1.3 a server refuses a client certificate
            %% after the client's handshake is done: the send may
            %% fail, and the reason (the TLS alert) follows as a
            %% message.
            {next_state, handshaking, D#d{sock = Sock},
             [{state_timeout, maps:get(handshake_timeout, Opts, 5000), E}]};
        {error, Why} ->
            agent_bridge_client_sock:close(Sock),
            next_endpoint(E, Why, D)
    end;
connected_to({error, Why}, #d{current = E} = D) ->
    next_endpoint(E, Why, D).

hello(#d{opts = Opts, ha = Ha, session_id = Session} = D) ->
    Hello = #{pairing => maps:get(pairing, Opts), role => maps:get(role, Opts),
              entity_id => maps:get(entity_id, Opts),
              credential => maps:get(credential, Opts),
              protocol_version => case Ha of true -> 2; false -> 1 end},
    case Session of
        undefined -> {hello, Hello};
        _ -> {resume, Hello#{session_id => Session, received => D#d.last_seq,
                             epoch => D#d.epoch}}
    end.

%% Version 2: one endpoint per attempt, round the ring, starting after the
%% one that was lost; a pause (doubling) after every full round.
attempt(#d{all = All, next = Next, tried = Tried} = D) ->
    Limit = maps:get(reconnect_limit, D#d.opts, ?RECONNECT_LIMIT),
    case now_ms() - D#d.lost_at > Limit andalso Tried > 0 of
        true ->
            give_up(D);
        false ->
            E = lists:nth(Next rem length(All) + 1, All),
            try_endpoint(E, D#d{next = Next + 1, tried = Tried + 1})
    end.

next_endpoint(E, Why, #d{ha = false} = D) ->
    {next_state, connecting, D#d{failures = [{E, Why} | D#d.failures]},
     [{next_event, internal, connect}]};
next_endpoint(E, Why, #d{all = All, tried = Tried, opts = Opts} = D) ->
    D1 = D#d{failures = [{E, Why} | D#d.failures], last_reason = Why, sock = undefined},
    {Min, Max} = maps:get(reconnect_backoff, Opts, {20, 500}),
    case Tried rem length(All) of
        0 ->
            Pause = min(Max, max(Min, D#d.backoff * 2)),
            {next_state, connecting, D1#d{backoff = Pause}, [{{timeout, retry}, Pause, retry}]};
        _ ->
            {next_state, connecting, D1, [{next_event, internal, connect}]}
    end.

refused_in_handshake(Code, Message, #d{ha = true} = D) ->
    case lists:member(Code, ?RETRY_CODES) of
        true ->
            agent_bridge_client_sock:close(D#d.sock),
            next_endpoint(D#d.current, {refused, Code, Message}, D#d{sock = undefined});
        false ->
            fail({refused, Code, Message}, D)
    end;
refused_in_handshake(Code, Message, D) ->
    fail({refused, Code, Message}, D).

fail(Reason, #d{ever_connected = true} = D) ->
    {stop, normal, finish({closed, Reason}, D)};
fail(Reason, D) ->
    reply_waiter({error, Reason}, D),
    {stop, normal, finish_quietly(D#d{waiter = undefined})}.

give_up(#d{ever_connected = false} = D) ->
    fail({unreachable, lists:reverse(D#d.failures)}, D);
give_up(#d{last_reason = Why} = D) ->
    fail({gave_up, Why}, D).

reply_waiter(_Reply, #d{waiter = undefined}) -> ok;
reply_waiter(Reply, #d{waiter = From}) -> gen_statem:reply(From, Reply).

welcomed(_Welcome, #d{ha = false} = D) ->
    {next_state, connected, D#d{ever_connected = true}};
welcomed(Welcome, D) when not is_map_key(ha, Welcome) ->
    fail({refused, <<"BadHandshake">>, <<"the server does not speak ProtocolVersion 2">>}, D);
welcomed(#{session_id := Sid, ha := Ha}, #d{ever_connected = Again} = D) ->
    #{epoch := Epoch, resumed := Resumed, last_accepted := Last, dedup_window := Window,
      heartbeat := Hb} = Ha,
    D1 = case Resumed of
             true ->
                 drop_accepted(Last, D#d{epoch = max(Epoch, D#d.epoch)});
             false ->
                 %% A new session: the server knows nothing of this client.
                 D#d{session_id = Sid, epoch = Epoch, last_seq = 0, acked_seq = 0}
         end,
    D2 = D1#d{ever_connected = true, tried = 0, backoff = 0, failures = [],
              heartbeat = Hb, window = max(1, Window), last_rx = now_ms(), held = false},
    %% Described again only when the session is new; then everything not
    %% acknowledged goes again (the server drops what it already accepted),
    %% once the other side is registered again (held until a Binding
    %% report says so).
    Describe = [Desc || not Resumed, Desc <- [D2#d.description], Desc =/= undefined],
    _ = [write(Desc, D2) || Desc <- Describe],
    Held = Again andalso Describe =/= [],
    _ = [write(Frame, D2) || not Held, {_, Frame} <- queue:to_list(D2#d.unacked)],
    D3 = case Again of
             true -> notify({reconnected, #{endpoint => D2#d.current, resumed => Resumed,
                                            epoch => D2#d.epoch, session_id => Sid,
                                            reason => D#d.last_reason}}, D2#d{held = Held});
             false -> D2
         end,
    Silence = [{{timeout, silence}, Hb, check} || Hb > 0],
    {next_state, connected, D3, Silence}.

%% ---------------------------------------------------------------------------
%% Traffic
%% ---------------------------------------------------------------------------

active_n(#d{opts = Opts}) -> maps:get(active_n, Opts, 32).

%% Every half batch the socket's `{active, N}' count is topped up to N, so
%% a busy connection never goes passive and the runtime polls its socket
%% from the schedulers instead of waking its poll thread for each frame
%% (bench/EVATAR_BENCH.md).
read_on(#d{reads = R} = D) when R > 1 ->
    D#d{reads = R - 1};
read_on(#d{sock = Sock} = D) ->
    N = active_n(D),
    case agent_bridge_client_sock:getopts(Sock, [active]) of
        {ok, [{active, Left}]} when is_integer(Left), Left > 0, Left < N ->
            _ = agent_bridge_client_sock:setopts(Sock, [{active, N - Left}]),
            ok;
        _ ->
            ok
    end,
    D#d{reads = max(1, N div 2)}.

incoming({ok, {signal, S}}, #d{ha = true} = D) ->
    ha_signal(S, D);
incoming({ok, {signal, #{in_reply_to := Id, context := Ctx} = S}}, #d{pending = P} = D)
  when is_map_key(Id, P), (Ctx =:= feedback orelse Ctx =:= error) ->
    answer(Id, case Ctx of feedback -> {ok, S}; error -> {error, S} end, D);
incoming({ok, {signal, S}}, D) ->
    {keep_state, notify({signal, S}, D)};
incoming({ok, {control, {binding, Report}}}, D) ->
    {keep_state, notify({binding, Report}, release_held(Report, D))};
incoming({ok, {control, {ack, Ack}}}, #d{ha = true} = D) ->
    case Ack of
        #{accepted := Id} -> {keep_state, acknowledged(Id, D)};
        #{} -> {keep_state, D}
    end;
incoming({ok, {control, {refused, #{code := Code, message := Message}}}}, D) ->
    disconnected({refused, Code, Message}, D);
incoming({ok, {control, {bye, Reason}}}, D) ->
    disconnected({bye, Reason}, D);
incoming({ok, Other}, D) ->
    logger:notice(#{what => unexpected_document, document => Other}),
    {keep_state, D};
incoming({error, Reason}, D) ->
    disconnected({malformed, Reason}, D).

%% After a new session the signals not acknowledged go once another
%% entity is registered again.
release_held(#{entities := Entities}, #d{held = true, opts = Opts} = D) ->
    case [E || E <- Entities, E =/= maps:get(entity_id, Opts)] of
        [] ->
            D;
        [_ | _] ->
            _ = [write(Frame, D) || {_, Frame} <- queue:to_list(D#d.unacked)],
            D#d{held = false}
    end;
release_held(_Report, D) ->
    D.

%% Nothing twice: a signal redelivered after a resume (Sequence already
%% passed to the owner) or from an older epoch than one seen is dropped.
ha_signal(#{seq := Seq}, #d{last_seq = Last} = D) when is_integer(Seq), Seq =< Last ->
    {keep_state, D};
ha_signal(#{epoch := Epoch}, #d{epoch = Mine} = D) when is_integer(Epoch), Epoch < Mine ->
    {keep_state, D};
ha_signal(#{seq := Seq} = S, D) ->
    D1 = case Seq of
             N when is_integer(N) -> D#d{last_seq = N};
             _ -> D
         end,
    D2 = case maps:get(epoch, S, undefined) of
             E when is_integer(E), E > D1#d.epoch -> D1#d{epoch = E};
             _ -> D1
         end,
    {D3, Actions} = schedule_ack(D2),
    case S of
        #{in_reply_to := Id, context := Ctx} when is_map_key(Id, D3#d.pending),
                                                  (Ctx =:= feedback orelse Ctx =:= error) ->
            {keep_state, D4, More} = answer(Id, case Ctx of feedback -> {ok, S};
                                                             error -> {error, S}
                                                 end, D3),
            {keep_state, D4, Actions ++ More};
        _ ->
            {keep_state, notify({signal, S}, D3), Actions}
    end.

schedule_ack(#d{last_seq = Last, acked_seq = Acked} = D) when Last - Acked >= ?ACK_EVERY ->
    {send_ack(D), []};
schedule_ack(#d{ack_timer = true} = D) ->
    {D, []};
schedule_ack(D) ->
    {D#d{ack_timer = true}, [{{timeout, ack}, ?ACK_DELAY, ack}]}.

send_ack(#d{last_seq = Last, acked_seq = Last} = D) ->
    D;
send_ack(#d{last_seq = Last} = D) ->
    _ = write(bil_control:encode({ack, #{received => Last}}), D),
    D#d{acked_seq = Last}.

%% The server accepted everything up to `Id' in send order.
acknowledged(Id, #d{unacked = Q} = D) ->
    case lists:keymember(Id, 1, queue:to_list(Q)) of
        true -> drop_through(Id, Q, D, []);
        false -> D
    end.

drop_through(Id, Q, D, Acc) ->
    {{value, {I, _}}, Q1} = queue:out(Q),
    case I of
        Id -> after_acks(lists:reverse([I | Acc]), D#d{unacked = Q1,
                                                        unacked_n = queue:len(Q1)});
        _ -> drop_through(Id, Q1, D, [I | Acc])
    end.

drop_accepted(<<>>, D) -> D;
drop_accepted(Last, D) -> acknowledged(Last, D).

after_acks(Ids, #d{opts = Opts} = D) ->
    D1 = case maps:get(notify_acks, Opts, false) of
             true -> notify({accepted, Ids}, D);
             false -> D
         end,
    unblock(D1).

%% Callers that waited for room in the window go on.
unblock(#d{unacked_n = N, window = W, blocked = B} = D) when N < W ->
    case queue:out(B) of
        {{value, {From, Signal, request}}, B1} ->
            unblock(keep(From, Signal, D#d{blocked = B1}));
        {{value, {From, Signal, signal}}, B1} ->
            D1 = keep(none, Signal, D#d{blocked = B1}),
            gen_statem:reply(From, ok),
            unblock(D1);
        {empty, _} when N =:= 0 ->
            _ = [gen_statem:reply(F, ok) || F <- D#d.ack_waiters],
            D#d{ack_waiters = []};
        {empty, _} ->
            D
    end;
unblock(D) ->
    D.

%% The signal is completed (id, time) at once; it waits in `blocked' while
%% the window of unacknowledged signals is full. A request's timer runs from
%% the call.
ha_send(From, Request, State, D) ->
    Partial = case Request of
                  {signal, P} -> P;
                  {request, P, _} -> P#{context => request}
              end,
    case encode(Partial, D) of
        {ok, Id, Frame, D1} ->
            Timers = case Request of
                         {signal, _} -> [];
                         {request, _, Timeout} -> [{{timeout, {request, Id}}, Timeout, Id}]
                     end,
            ha_keep(From, Request, State, {Id, Frame}, Timers, D1);
        {error, _} = Error ->
            {keep_state_and_data, [{reply, From, Error}]}
    end.

ha_keep(From, Request, State, Signal, Timers, #d{unacked_n = N, window = W, blocked = B} = D1) ->
    case N >= W orelse not queue:is_empty(B) of
        true ->
            {keep_state, D1#d{blocked = queue:in({From, Signal, element(1, Request)}, B)},
             Timers};
        false ->
            _ = State,
            case Request of
                {signal, _} ->
                    {keep_state, keep(none, Signal, D1), [{reply, From, ok} | Timers]};
                {request, _, _} ->
                    {keep_state, keep(From, Signal, D1), Timers}
            end
    end.

%% Keeps the signal until it is acknowledged and writes it when connected.
%% `Waiter' is the request/3 caller awaiting the feedback, or `none' for a
%% signal given to send/2: its feedback goes to the owner like any signal.
keep(Waiter, {Id, Frame}, #d{unacked = Q, unacked_n = N} = D) ->
    _ = [write(Frame, D) || D#d.welcome =/= undefined, not D#d.held],
    D1 = D#d{unacked = queue:in({Id, Frame}, Q), unacked_n = N + 1},
    case Waiter of
        none -> D1;
        From -> D1#d{pending = (D1#d.pending)#{Id => From}}
    end.

answer(Id, Reply, #d{pending = P} = D) ->
    case maps:take(Id, P) of
        {From, P1} ->
            {keep_state, D#d{pending = P1},
             [{reply, From, Reply}, {{timeout, {request, Id}}, cancel}]};
        error ->
            {keep_state, D, []}
    end.

%% Without `ha' the session ends here. With it, reconnect through the
%% endpoints (starting after this one) unless the refusal is final.
disconnected(Reason, #d{ha = true, sock = Sock} = D) ->
    Retry = case Reason of
                {refused, Code, _} -> lists:member(Code, ?RETRY_CODES);
                {malformed, _} -> false;
                _ -> true
            end,
    case Retry of
        true ->
            _ = [agent_bridge_client_sock:close(Sock) || Sock =/= undefined],
            Next = index_of(D#d.current, D#d.all) + 1,
            {next_state, connecting,
             D#d{sock = undefined, welcome = undefined, next = Next, tried = 0,
                 backoff = 0, lost_at = now_ms(), last_reason = Reason, ack_timer = false},
             [{next_event, internal, connect}, {{timeout, silence}, cancel},
              {{timeout, ack}, cancel}]};
        false ->
            {stop, normal, finish({closed, Reason}, D)}
    end;
disconnected(Reason, D) ->
    {stop, normal, finish({closed, Reason}, D)}.

index_of(E, List) -> index_of(E, List, 0).
index_of(_E, [], _N) -> 0;
index_of(E, [E | _], N) -> N;
index_of(E, [_ | Rest], N) -> index_of(E, Rest, N + 1).

%% Every waiting caller gets `{error, closed}', the owner `{closed, Reason}'.
finish(Event, D) ->
    notify(Event, finish_quietly(D)).

finish_quietly(#d{pending = P, blocked = B, ack_waiters = W} = D) ->
    _ = [gen_statem:reply(From, {error, closed}) || From <- maps:values(P), From =/= undefined],
    _ = [gen_statem:reply(From, {error, closed}) || {From, _} <- queue:to_list(B)],
    _ = [gen_statem:reply(From, {error, closed}) || From <- W],
    D#d{pending = #{}, blocked = queue:new(), ack_waiters = []}.

notify(Event, #d{owner = Owner} = D) ->
    Owner ! {agent_bridge, self(), Event},
    D.

write(_Doc, #d{sock = undefined}) ->
    {error, closed};
write(Doc, #d{sock = Sock}) ->
    case agent_bridge_client_sock:send(Sock, Doc) of
        ok -> ok;
        {error, _} -> {error, closed}
    end.

%% The signal completed and encoded, or why it cannot be: bad input from
%% the caller is its error, not the end of the client and its session.
encode(Partial, D) when is_map(Partial) ->
    {#{id := Id} = Signal, D1} = complete(Partial, D),
    try bil:encode_signal(Signal) of
        Frame -> {ok, Id, Frame, D1}
    catch
        error:Why -> {error, {bad_signal, Why}}
    end;
encode(Partial, _D) ->
    {error, {bad_signal, {not_a_map, Partial}}}.

complete(Partial, #d{counter = N} = D) ->
    Defaults = #{context => request_no_feedback,
                 id => signal_id(N + 1, D),
                 timestamp => os:system_time(millisecond),
                 in_reply_to => undefined, seq => undefined, epoch => undefined},
    {maps:merge(Defaults, Partial), D#d{counter = N + 1}}.

signal_id(N, #d{opts = Opts, nonce = Nonce}) ->
    iolist_to_binary([maps:get(entity_id, Opts), "-", Nonce, "-", integer_to_binary(N)]).

status(State, D) ->
    #{connected => State =:= connected, endpoint => D#d.current, epoch => D#d.epoch,
      session_id => D#d.session_id, unacked => D#d.unacked_n, last_seq => D#d.last_seq}.

now_ms() -> erlang:monotonic_time(millisecond).

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
%% This module is the process: it owns the socket, the connect helper and
%% the timers, and carries out what agent_bridge_client_session (pure: the
%% version, the endpoint ring, the unacknowledged window, de-duplication,
%% requests, heartbeats, the resume) decides; agent_bridge_client_sock is
%% the TCP or TLS socket.
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

-export([connect/2, start/2, connect/1, describe/2, describe_document/2, send/2, request/3, get_binding/1,
         close/1, session/1, status/1, await_acks/2]).
-export([init/1, callback_mode/0, handle_event/4, terminate/3]).

-export_type([opts/0, endpoint/0, close_reason/0, partial_signal/0, connect_error/0]).

-type endpoint() :: {inet:socket_address() | inet:hostname(), inet:port_number()}.
%% `ha' (default false) turns on protocol version 2; `reconnect_backoff'
%% (ms, doubling, default {20, 500}) and `reconnect_limit' (ms without a
%% session before giving up, default 600000: longer than a machine's
%% reboot, so clients outlast a power cut) apply to it, and so does
%% `notify_acks' (default false). `handshake_timeout' (ms, default 5000)
%% bounds the wait from connected to Welcome, doubled after each handshake
%% given up in a row, up to 8 times, until a Welcome
%% (agent_bridge_client_session:handshake_timeout/1). `close_timeout' (ms, default 5000) bounds
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

%% The states of the machine (the diagram above).
-type state() :: idle | connecting | handshaking | connected | closing.

-record(d, {opts :: opts(),
            owner :: pid(),
            %% The protocol's decisions: agent_bridge_client_session.
            session :: agent_bridge_client_session:session(),
            sock :: agent_bridge_client_sock:sock() | undefined,
            %% The connect/1 caller awaiting the Welcome.
            waiter :: gen_statem:from() | undefined,
            %% The helper process making the TCP (TLS) connection.
            connector :: {pid(), reference()} | undefined,
            %% close/1 callers waiting for EVATAR's Bye.
            closers = [] :: [gen_statem:from()],
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

%% @doc describe/2 of a description already encoded (bil:encode_description/1),
%% for a caller that measured the document first: one encoding, not two.
-spec describe_document(pid(), iodata()) -> ok | {error, closed}.
describe_document(Client, Document) ->
    call(Client, {describe, Document}).

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
    Nonce = binary:encode_hex(crypto:strong_rand_bytes(4)),
    {ok, idle, #d{opts = Opts, owner = Owner,
                  session = agent_bridge_client_session:new(Endpoints, Opts, Nonce)}}.

-spec handle_event(gen_statem:event_type(), term(), state(), #d{}) ->
          gen_statem:event_handler_result(state()).
handle_event({call, From}, connect, idle, D) ->
    %% Connecting starts only now, so the outcome always has a caller to go to.
    {next_state, connecting, D#d{waiter = From}, [{next_event, internal, connect}]};
handle_event({call, From}, connect, State, #d{waiter = W, session = S}) ->
    Ever = agent_bridge_client_session:ever_connected(S),
    Why = if State =:= closing -> closed;
             W =/= undefined, not Ever -> connecting;
             true -> already_connected
          end,
    {keep_state_and_data, [{reply, From, {error, Why}}]};
handle_event(internal, connect, connecting, D) ->
    attempt(D);
handle_event({timeout, retry}, retry, connecting, D) ->
    attempt(D);
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

%% Handshaking.
handle_event(state_timeout, handshake, handshaking, D) ->
    attempt_failed(handshake_timeout, drop_sock(D));
handle_event(info, {tcp, Sock, Frame}, handshaking, #d{sock = Sock, session = S} = D) ->
    case bil_control:parse_frame(Frame, #{}) of
        {ok, {control, {welcome, Welcome}}} ->
            ok = sock_flow:activate(Sock, active_n(D)),
            reply_waiter({ok, self()}, D),
            D1 = D#d{waiter = undefined, reads = sock_flow:credit(active_n(D))},
            case agent_bridge_client_session:welcomed(Welcome, now_ms(), S) of
                {ok, Effects, S1} ->
                    {D2, Actions} = run(Effects, D1#d{session = S1}),
                    {next_state, connected, D2, Actions};
                {error, Reason} ->
                    fail(Reason, D1)
            end;
        {ok, {control, {refused, #{code := Code, message := Message}}}} ->
            case agent_bridge_client_session:refused_in_handshake(Code, Message, S) of
                retry -> attempt_failed({refused, Code, Message}, drop_sock(D));
                final -> fail({refused, Code, Message}, D)
            end;
        {ok, Other} ->
            fail({refused, <<"BadHandshake">>,
                  iolist_to_binary(io_lib:format("expected Welcome, got ~p", [Other]))}, D);
        {error, Reason} ->
            fail({refused, <<"Malformed">>, bil:format_error(Reason)}, D)
    end;
handle_event(info, {tcp_closed, Sock}, handshaking, #d{sock = Sock} = D) ->
    attempt_failed(closed, D#d{sock = undefined});
handle_event(info, {tcp_error, Sock, Why}, handshaking, #d{sock = Sock} = D) ->
    attempt_failed(Why, D#d{sock = undefined});

%% Connected.
handle_event(info, {tcp, Sock, Frame}, connected, #d{sock = Sock, session = S} = D) ->
    D1 = read_on(D),
    case agent_bridge_client_session:incoming(bil_control:parse_frame(Frame, #{}), now_ms(), S) of
        {ok, Effects, S1} -> keep(run(Effects, D1#d{session = S1}));
        {lost, Reason, S1} -> disconnected(Reason, D1#d{session = S1})
    end;
handle_event(info, {tcp_passive, Sock}, connected, #d{sock = Sock} = D) ->
    %% A top-up made just as the socket went passive makes this notice stale.
    case sock_flow:is_passive(Sock) of
        true ->
            %% A closed socket says so in its own message.
            _ = sock_flow:activate(Sock, active_n(D)),
            {keep_state, D#d{reads = sock_flow:credit(active_n(D))}};
        false ->
            keep_state_and_data
    end;
handle_event(info, {tcp_closed, Sock}, connected, #d{sock = Sock} = D) ->
    disconnected(closed, D);
handle_event(info, {tcp_error, Sock, Why}, connected, #d{sock = Sock} = D) ->
    disconnected({socket_error, Why}, D);
handle_event({timeout, ack}, ack, _State, #d{session = S} = D) ->
    keep(run(agent_bridge_client_session:ack_due(S), D));
handle_event({timeout, silence}, silence, connected, #d{session = S} = D) ->
    case agent_bridge_client_session:silence_check(now_ms(), S) of
        {ok, Effects} -> keep(run({Effects, S}, D));
        {lost, Reason} -> disconnected(Reason, D)
    end;
handle_event({timeout, silence}, silence, _State, _D) ->
    keep_state_and_data;
handle_event({timeout, {request, Id}}, _, _State, #d{session = S} = D) ->
    keep(run(agent_bridge_client_session:request_timeout(Id, S), D));

%% Requests from the owner. Once close/1 has said Bye, nothing more is
%% taken (with `ha' it would be queued and lost).
handle_event({call, From}, close, closing, D) ->
    {keep_state, D#d{closers = [From | D#d.closers]}};
handle_event({call, From}, Request, closing, _D) when Request =/= status ->
    {keep_state_and_data, [{reply, From, {error, closed}}]};
handle_event({call, From}, {describe, Doc}, _State, #d{session = S} = D) ->
    keep(run(agent_bridge_client_session:describe(From, Doc, S), D));
handle_event({call, From}, {signal, Partial}, _State, #d{session = S} = D) ->
    keep(run(agent_bridge_client_session:send(From, Partial, wall_ms(), S), D));
handle_event({call, From}, {request, Partial, Timeout}, _State, #d{session = S} = D) ->
    keep(run(agent_bridge_client_session:request(From, Partial, Timeout, wall_ms(), S), D));
handle_event({call, From}, get_binding, _State, #d{session = S} = D) ->
    keep(run({agent_bridge_client_session:get_binding(From, S), S}, D));
handle_event({call, From}, session, connected, #d{session = S}) ->
    {keep_state_and_data, [{reply, From, {ok, agent_bridge_client_session:welcome(S)}}]};
handle_event({call, From}, status, State, #d{session = S}) ->
    {keep_state_and_data,
     [{reply, From, {ok, agent_bridge_client_session:status(State =:= connected, S)}}]};
handle_event({call, From}, await_acks, _State, #d{session = S} = D) ->
    keep(run(agent_bridge_client_session:await_acks(From, S), D));
handle_event({call, From}, close, connected, #d{sock = Sock, opts = Opts} = D) ->
    %% EVATAR answers Bye once the entity has left: waiting for it lets the
    %% same EntityID connect again at once. Its Bye, the end of the
    %% connection or the timeout ends the wait.
    case agent_bridge_client_sock:send(Sock, bil_control:encode({bye, <<>>})) of
        ok ->
            _ = sock_flow:activate(Sock, true),
            {next_state, closing, finish_quietly(D#d{closers = [From]}),
             [{state_timeout, maps:get(close_timeout, Opts, 5000), close},
              {{timeout, silence}, cancel}, {{timeout, ack}, cancel}]};
        {error, _} ->
            {stop_and_reply, normal, [{reply, From, ok}], finish({closed, normal}, D)}
    end;
handle_event({call, From}, close, State, #d{session = S} = D) ->
    %% Not connected: an attempt in progress stops here (terminate/3 ends
    %% the helper and the socket), and its caller is told.
    reply_waiter({error, closed}, D),
    D1 = case agent_bridge_client_session:ever_connected(S) of
             true when State =/= idle -> finish({closed, normal}, D);
             _ -> finish_quietly(D)
         end,
    {stop_and_reply, normal, [{reply, From, ok}], D1#d{waiter = undefined}};

%% Closing.
handle_event(info, {tcp, Sock, Frame}, closing, #d{sock = Sock} = D) ->
    case bil_control:parse_frame(Frame, #{}) of
        {ok, {control, {bye, _}}} -> closed(D);
        _ -> keep_state_and_data
    end;
handle_event(info, {tcp_passive, Sock}, closing, #d{sock = Sock}) ->
    _ = sock_flow:activate(Sock, true),
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

-spec terminate(term(), state(), #d{}) -> ok.
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

%% The endpoint the session chose next, or the end of the attempts.
attempt(#d{session = S} = D) ->
    case agent_bridge_client_session:next_attempt(now_ms(), S) of
        {connect, E, S1} -> try_endpoint(E, D#d{session = S1});
        {give_up, Reason} -> fail(Reason, D)
    end.

attempt_failed(Why, #d{session = S} = D) ->
    case agent_bridge_client_session:attempt_failed(Why, now_ms(), S) of
        {now, S1} ->
            {next_state, connecting, D#d{session = S1}, [{next_event, internal, connect}]};
        {{retry, Pause}, S1} ->
            {next_state, connecting, D#d{session = S1}, [{{timeout, retry}, Pause, retry}]}
    end.

drop_sock(#d{sock = Sock} = D) ->
    _ = [agent_bridge_client_sock:close(Sock) || Sock =/= undefined],
    D#d{sock = undefined}.

%% The TCP (TLS) connect runs in a helper, so that close/1 is answered
%% meanwhile; the helper hands the socket over and ends. Killed with the
%% client, it takes a socket it still owns with it.
try_endpoint({Host, Port}, D) ->
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
    {next_state, connecting, D#d{connector = {Pid, Ref}}}.

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

connected_to({ok, Sock}, #d{session = S} = D) ->
    %% Active once since the connect; what came before the hand-over
    %% follows as messages from the connector.
    %% A failed send is not the answer: the socket's own messages are. With
    %% TLS 1.3 a server refuses a client certificate after the client's
    %% handshake is done, and the reason (the TLS alert) follows as a
    %% message; a listener that refuses at accept (TooManyConnections,
    %% RateLimited, LockedOut) has written its Refused and closed before
    %% the Hello went, which then fails, and the Refused is still to be
    %% read. The handshake timeout ends a socket that says nothing.
    _ = agent_bridge_client_sock:send(Sock, agent_bridge_client_session:hello(S)),
    {next_state, handshaking, D#d{sock = Sock},
     [{state_timeout, agent_bridge_client_session:handshake_timeout(S), handshake}]};
connected_to({error, Why}, D) ->
    attempt_failed(Why, D).

%% Connecting ends here: a client that had connected tells its owner, one
%% that had not its connect/1 caller.
fail(Reason, #d{session = S} = D) ->
    case agent_bridge_client_session:ever_connected(S) of
        true ->
            {stop, normal, finish({closed, Reason}, D)};
        false ->
            reply_waiter({error, Reason}, D),
            {stop, normal, finish_quietly(D#d{waiter = undefined})}
    end.

reply_waiter(_Reply, #d{waiter = undefined}) -> ok;
reply_waiter(Reply, #d{waiter = From}) -> gen_statem:reply(From, Reply).

%% ---------------------------------------------------------------------------
%% Traffic
%% ---------------------------------------------------------------------------

active_n(#d{opts = Opts}) -> maps:get(active_n, Opts, 32).

%% Every half batch the socket's `{active, N}' count is topped up to N
%% (sock_flow), so a busy connection never goes passive.
read_on(#d{reads = R, sock = Sock} = D) ->
    D#d{reads = sock_flow:read_on(R, Sock, active_n(D))}.

%% Without `ha' the session ends here. With it, reconnect through the
%% endpoints (starting after this one) unless the refusal is final.
disconnected(Reason, #d{session = S} = D) ->
    case agent_bridge_client_session:lost(Reason, now_ms(), S) of
        {reconnect, Effects, S1} ->
            {D1, Actions} = run(Effects, drop_sock(D#d{session = S1})),
            {next_state, connecting, D1, [{next_event, internal, connect} | Actions]};
        stop ->
            {stop, normal, finish({closed, Reason}, D)}
    end.

%% Carries out the session's effects in order; timers become actions.
run({Effects, S}, D) ->
    run(Effects, D#d{session = S});
run(Effects, D) ->
    run(Effects, D, []).

run([], D, Actions) ->
    {D, lists:reverse(Actions)};
run([{send, Frame} | Rest], D, Actions) ->
    _ = write(Frame, D),
    run(Rest, D, Actions);
run([{send, Frame, {reply, From}} | Rest], D, Actions) ->
    gen_statem:reply(From, write(Frame, D)),
    run(Rest, D, Actions);
run([{send, Frame, {request, Id}} | Rest], #d{session = S} = D, Actions) ->
    case write(Frame, D) of
        ok ->
            run(Rest, D, Actions);
        {error, closed} ->
            {More, S1} = agent_bridge_client_session:sent_failed(Id, S),
            run(More ++ Rest, D#d{session = S1}, Actions)
    end;
run([{reply, From, Reply} | Rest], D, Actions) ->
    gen_statem:reply(From, Reply),
    run(Rest, D, Actions);
run([{notify, Event} | Rest], D, Actions) ->
    run(Rest, notify(Event, D), Actions);
run([{timer, Name, Ms} | Rest], D, Actions) ->
    run(Rest, D, [{{timeout, Name}, Ms, Name} | Actions]);
run([{cancel, Name} | Rest], D, Actions) ->
    run(Rest, D, [{{timeout, Name}, cancel} | Actions]);
run([{log, notice, Report} | Rest], D, Actions) ->
    logger:notice(Report),
    run(Rest, D, Actions).

keep({D, Actions}) ->
    {keep_state, D, Actions}.

%% Every waiting caller gets `{error, closed}', the owner `{closed, Reason}'.
finish(Event, D) ->
    notify(Event, finish_quietly(D)).

finish_quietly(#d{session = S} = D) ->
    {D1, _} = run(agent_bridge_client_session:finish(S), D),
    D1.

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

now_ms() -> erlang:monotonic_time(millisecond).

wall_ms() -> os:system_time(millisecond).

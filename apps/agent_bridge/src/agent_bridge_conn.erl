%% @doc Internal. One client connection (a TCP socket or an external
%% program's port): decodes frames, runs the handshake, then relays signals
%% and descriptions to the client's pairing and the pairing's traffic back.
%%
%% ```
%%  start --shoot/open--> handshaking --Hello ok / Welcome--> joined
%%                          |  bad Hello, timeout             | description accepted
%%                          v                                 v
%%                       closing <--Refused/Bye/dropped---- active
%%                          ^
%%                          +--delay-- penalty <--wrong credential-- handshaking
%% '''
%% `penalty' holds back the Refused of a wrong credential for the delay the
%% listener's guard (agent_bridge_guard) gives, which grows with the
%% address's failures. A slow consumer's socket is aborted (linger 0), not
%% kept until its client reads; so is a socket still holding output when
%% the connection ends. A version 1 session with no frame in either
%% direction for `idle_timeout' is closed with `Refused IdleTimeout'.
%% `joined' waits for the first accepted description (the pairing enforces
%% the join timeout and drops the entity); `active' relays in both
%% directions; `closing' sends the last frame, half-closes, drains what the
%% peer still sends for a short linger, then stops. Writes never block:
%% see agent_bridge_outq and docs/protocol.md, "Backpressure".
%%
%% A version 2 session (high availability, docs/protocol.md section 11) may
%% start with a Resume instead of a Hello; it gets `Ack' documents for the
%% signals the pairing accepted, passes the client's Acks to the pairing, and
%% sends an empty Ack as a heartbeat when it has sent nothing for
%% `heartbeat' ms.
-module(agent_bridge_conn).
-behaviour(gen_statem).

-export([start_link/1, default_opts/0]).
-export([init/1, callback_mode/0, handle_event/4, terminate/3]).

-export_type([opts/0]).

-include_lib("kernel/include/logger.hrl").

-type opts() :: #{handshake_timeout => pos_integer(),
                  handshake_max_frame => pos_integer(),
                  max_frame => pos_integer(),
                  max_out_bytes => pos_integer(),
                  max_out_frames => pos_integer(),
                  pairing_watermark => pos_integer(),
                  active_n => pos_integer(),
                  max_read_rate => pos_integer() | infinity,
                  linger => non_neg_integer(),
                  retry_interval => pos_integer(),
                  heartbeat => pos_integer(),
                  idle_timeout => pos_integer() | infinity,
                  hibernate_after => timeout(),
                  %% Set by the acceptor: its listener's agent_bridge_guard.
                  guard => pid()}.

-type start_arg() :: {tcp, opts()}
                   | {port, {file:filename_all(), [string()], [{string(), string()}]}, opts()}.

%% The states of the machine (the diagram above).
-type state() :: handshaking | penalty | joined | active | closing.

-record(d, {transport :: agent_bridge_transport:t() | undefined,
            opts :: map(),
            outq :: agent_bridge_outq:outq(),
            flushing = false :: boolean(),
            session :: term(),
            pairing :: binary() | undefined,
            pairing_pid :: pid() | undefined,
            monitor :: reference() | undefined,
            entity = <<>> :: binary(),
            %% The client certificate a TLS handshake verified.
            peer_cert :: evatar:peer_cert() | undefined,
            peer_closed = false :: boolean(),
            version = 1 :: 1 | 2,
            sent = false :: boolean(),
            %% A frame arrived since the last idle check (version 1).
            heard = false :: boolean(),
            ip :: inet:ip_address() | undefined,
            %% Frames to read before the next top-up (0: not reading
            %% in `{active, N}' mode).
            credit = 0 :: non_neg_integer(),
            %% The read rate's token bucket (`max_read_rate'): when it
            %% was last charged (monotonic ms) and the frames it then
            %% allowed; the frames read since.
            bucket = {0, 0} :: {integer(), number()},
            unpaced = 0 :: non_neg_integer(),
            paced_logged = false :: boolean()}).

%% @doc Defaults of every connection option (docs/protocol.md, "Limits").
-spec default_opts() -> opts().
default_opts() ->
    #{handshake_timeout => 5000,
      handshake_max_frame => 65536,
      max_frame => 1048576,
      max_out_bytes => 4194304,
      max_out_frames => 8192,
      pairing_watermark => 5000,
      active_n => 32,
      max_read_rate => 1000,
      linger => 1000,
      retry_interval => 10,
      heartbeat => 150,
      idle_timeout => 600000,
      hibernate_after => 5000}.

-spec start_link(start_arg()) -> {ok, pid()}.
%% An idle connection compacts its heap (hibernates) after
%% `hibernate_after' ms without a message: thousands of quiet devices then
%% cost a few KiB each. Version 2 connections send heartbeats, so they stay
%% awake.
start_link(Arg) ->
    Opts = maps:merge(default_opts(), element(tuple_size(Arg), Arg)),
    gen_statem:start_link(?MODULE, Arg, [{hibernate_after, maps:get(hibernate_after, Opts)}]).

-spec callback_mode() -> gen_statem:callback_mode_result().
callback_mode() -> handle_event_function.

-spec init(start_arg()) -> gen_statem:init_result(handshaking).
init(Arg) ->
    process_flag(trap_exit, true),
    Opts = maps:merge(default_opts(), element(tuple_size(Arg), Arg)),
    D = #d{opts = Opts,
           outq = agent_bridge_outq:new(maps:get(max_out_bytes, Opts),
                                        maps:get(max_out_frames, Opts))},
    Timeout = {state_timeout, maps:get(handshake_timeout, Opts), handshake},
    case Arg of
        {tcp, _} -> {ok, handshaking, D, [Timeout]};
        {port, Spec, _} -> {ok, handshaking, D, [Timeout, {next_event, internal, {open, Spec}}]}
    end.

%% ---------------------------------------------------------------------------
%% Events
%% ---------------------------------------------------------------------------

-spec handle_event(gen_statem:event_type(), term(), state(), #d{}) ->
          gen_statem:event_handler_result(state()).
handle_event(info, {agent_bridge_shoot, Sock}, handshaking, #d{transport = undefined} = D) ->
    Ip = case inet:peername(Sock) of
             {ok, {Addr, _}} -> Addr;
             {error, _} -> undefined
         end,
    case agent_bridge_transport:accepted(Sock, D#d.opts, opt(handshake_timeout, D)) of
        {ok, T} ->
            ok = agent_bridge_transport:set_max_frame(T, opt(handshake_max_frame, D)),
            ok = agent_bridge_transport:activate(T, once),
            logger:update_process_metadata(#{peer => agent_bridge_transport:peer(T)}),
            {keep_state, D#d{transport = T, ip = Ip,
                             peer_cert = agent_bridge_transport:peer_cert(T)}};
        {error, Why} ->
            %% The client got the TLS alert; nothing of the protocol was
            %% said. Logged like every refusal, in rate-limited summaries.
            ok = agent_bridge_guard:refused(opt_guard(D), Ip, <<"TlsHandshakeFailed">>,
                                            #{tls => agent_bridge_tls:failure(Why)}),
            {stop, normal, D}
    end;
handle_event(internal, {open, {Exe, Args, Env}}, handshaking, D) ->
    Port = open_port({spawn_executable, Exe},
                     [{args, Args}, {env, Env}, {packet, 4}, binary, exit_status, use_stdio]),
    T = {port, Port},
    logger:update_process_metadata(#{peer => agent_bridge_transport:peer(T)}),
    {keep_state, D#d{transport = T}};

%% A TLS socket's messages, read as a TCP socket's; an oversized frame is
%% an invalid packet there.
handle_event(info, {ssl, S, Frame}, State, D) ->
    handle_event(info, {tcp, S, Frame}, State, D);
handle_event(info, {ssl_passive, S}, State, D) ->
    handle_event(info, {tcp_passive, S}, State, D);
handle_event(info, {ssl_closed, S}, State, D) ->
    handle_event(info, {tcp_closed, S}, State, D);
handle_event(info, {ssl_error, S, {invalid_packet, _}}, State, D) ->
    handle_event(info, {tcp_error, S, emsgsize}, State, D);
handle_event(info, {ssl_error, S, Why}, State, D) ->
    handle_event(info, {tcp_error, S, Why}, State, D);

%% Frames in.
handle_event(info, {tcp, _, Frame}, State, D) when State =/= closing, State =/= penalty ->
    D1 = read_on(D#d{heard = true}),
    with_data(D1, frame(Frame, State, D1));
handle_event(info, {Port, {data, Frame}}, State, #d{transport = {port, Port}} = D)
  when State =/= closing, State =/= penalty ->
    frame(Frame, State, D#d{heard = true});
handle_event(info, {tcp_passive, _}, State, #d{transport = T} = D) when State =/= closing ->
    %% A top-up made just as the socket went passive makes this notice
    %% stale: the socket reads on.
    case agent_bridge_transport:is_passive(T) of
        true -> resume_reading(D#d{credit = 0});
        false -> keep_state_and_data
    end;
handle_event({timeout, resume}, _, State, D) when State =/= closing ->
    resume_reading(D);
handle_event({timeout, resume}, _, closing, _D) ->
    keep_state_and_data;
handle_event(info, {tcp_error, _, emsgsize}, State, D) when State =/= closing ->
    refuse(frame_refusal(State, D), D);

%% Traffic from the pairing.
handle_event(info, {evatar, P, {signal, Signal}}, State, #d{pairing = P} = D)
  when State =/= closing ->
    send(bil:encode_signal(Signal), D);
handle_event(info, {evatar, P, {bound, Report}}, State, #d{pairing = P} = D)
  when State =/= closing ->
    send(bil_control:encode({binding, Report}), D);
handle_event(info, {evatar, P, {ack, SignalId}}, State, #d{pairing = P} = D)
  when State =/= closing ->
    send(bil_control:encode({ack, #{accepted => SignalId}}), D);
%% The check runs every half period: a frame sent just after one check is
%% followed, if nothing else goes out, by a heartbeat at most one period
%% later (checking once per period let the gap reach two). A heartbeat
%% counts as sent, so an idle session gets one per period, not two.
handle_event({timeout, heartbeat}, beat, State, #d{sent = Sent} = D) when State =/= closing ->
    Beat = heartbeat_check(D),
    case Sent of
        true ->
            {keep_state, D#d{sent = false}, [Beat]};
        false ->
            case enqueue(bil_control:encode({ack, #{}}), D) of
                {ok, D1, Actions} -> {keep_state, D1#d{sent = true}, [Beat | Actions]};
                overflow -> slow_consumer(D)
            end
    end;
handle_event({timeout, heartbeat}, beat, closing, _D) ->
    keep_state_and_data;
handle_event({timeout, idle}, check, State, #d{heard = false, sent = false} = D)
  when State =/= closing ->
    ?LOG_INFO(#{what => idle_timeout}),
    close(refused(<<"IdleTimeout">>, <<"no frame either way within the idle timeout">>), D);
handle_event({timeout, idle}, check, State, D) when State =/= closing ->
    {keep_state, D#d{heard = false, sent = false}, [idle_check(D)]};
handle_event({timeout, idle}, check, closing, _D) ->
    keep_state_and_data;
handle_event(state_timeout, {refuse, Last}, penalty, D) ->
    %% Logged when the credential was found wrong.
    close(Last, D);
handle_event(info, {evatar, P, {dropped, Code, Reason}}, State, #d{pairing = P} = D)
  when State =/= closing ->
    ?LOG_NOTICE(#{what => dropped_by_pairing, code => Code, reason => Reason}),
    close(refused(dropped_code(Code), Reason), forget_session(D));
handle_event(info, {evatar, _, _}, closing, _D) ->
    keep_state_and_data;
handle_event(info, {'DOWN', Ref, process, _, Why}, State, #d{monitor = Ref} = D) ->
    D1 = D#d{monitor = undefined, session = undefined},
    case {State, Why} of
        {closing, _} -> {keep_state, D1};
        {_, Normal} when Normal =:= normal; Normal =:= shutdown;
                         element(1, Normal) =:= shutdown ->
            close({bye, <<"the pairing was stopped">>}, D1);
        _ ->
            ?LOG_WARNING(#{what => pairing_down, reason => Why}),
            close({refused, #{code => <<"PairingDown">>,
                              message => <<"the pairing stopped unexpectedly">>}}, D1)
    end;

%% Writes.
handle_event({timeout, flush}, _, State, D) ->
    flush(State, D#d{flushing = false});
handle_event(internal, flush, State, D) ->
    flush(State, D);
handle_event(info, {inet_reply, _, ok}, _State, _D) ->
    keep_state_and_data;
handle_event(info, {inet_reply, _, {error, _}}, _State, D) ->
    {stop, normal, D};

%% Timeouts and endings.
handle_event(state_timeout, handshake, handshaking, D) ->
    refuse({refused, #{code => <<"HandshakeTimeout">>,
                       message => <<"no Hello within the handshake timeout">>}}, D);
handle_event(state_timeout, linger, closing, D) ->
    {stop, normal, D};
handle_event(info, {tcp, _, _}, closing, #d{transport = T}) ->
    ok = agent_bridge_transport:drain(T),
    keep_state_and_data;
handle_event(info, {tcp, _, _}, penalty, _D) ->
    keep_state_and_data;
handle_event(info, {tcp_closed, _}, closing, D) ->
    maybe_done(D#d{peer_closed = true});
handle_event(info, {tcp_error, _, _}, closing, D) ->
    maybe_done(D#d{peer_closed = true});
handle_event(info, {tcp_closed, _}, _State, D) ->
    {stop, normal, D};
handle_event(info, {tcp_error, _, Why}, _State, D) ->
    ?LOG_INFO(#{what => socket_error, reason => Why}),
    {stop, normal, D};
handle_event(info, {Port, {exit_status, Status}}, _State, #d{transport = {port, Port}} = D) ->
    ?LOG_NOTICE(#{what => program_exited, status => Status}),
    {stop, {shutdown, {exit_status, Status}}, D#d{transport = undefined}};
handle_event(info, {'EXIT', Port, Why}, _State, #d{transport = {port, Port}} = D) ->
    {stop, {shutdown, {port_closed, Why}}, D#d{transport = undefined}};
handle_event(info, Other, _State, _D) ->
    ?LOG_DEBUG(#{what => unexpected_message, message => Other}),
    keep_state_and_data.

-spec terminate(term(), state(), #d{}) -> ok.
terminate(_Why, _State, #d{transport = T, outq = Q}) ->
    %% Output still queued here or in the socket belongs to a peer that did
    %% not read it within the linger: a plain close would keep the socket
    %% (and its descriptor) until the peer reads.
    case agent_bridge_outq:is_empty(Q) andalso not agent_bridge_transport:pending(T) of
        true -> agent_bridge_transport:close(T);
        false -> agent_bridge_transport:abort(T)
    end.

%% ---------------------------------------------------------------------------
%% Inbound frames
%% ---------------------------------------------------------------------------

frame(Frame, State, D) ->
    Max = case State of
              handshaking -> opt(handshake_max_frame, D);
              _ -> opt(max_frame, D)
          end,
    case agent_bridge_frame:check(Frame, Max) of
        ok -> document(parse(Frame), State, D);
        {error, Why} when State =:= handshaking -> refuse(agent_bridge_frame:refusal(Why), D);
        {error, Why} -> close(agent_bridge_frame:refusal(Why), D)
    end.

%% A description over the bil application's max_description_size is
%% refused as a description (DescriptionRefused naming the limit), not as
%% a malformed document: the client can act on it.
parse(Frame) ->
    case bil_control:parse_frame(Frame, #{}) of
        {error, #{code := too_large, message := M}} = Error ->
            case bil_control:root_name(Frame) of
                {ok, <<"description">>} ->
                    {description_too_large,
                     iolist_to_binary(["the description ", M, " (max_description_size of the "
                                       "bil application)"])};
                _ ->
                    Error
            end;
        Parsed ->
            Parsed
    end.

%% The Refused of a frame the socket found over its packet size: the limit
%% and the listener option that sets it.
frame_refusal(State, D) ->
    Key = case State of
              handshaking -> handshake_max_frame;
              _ -> max_frame
          end,
    {refused, #{code => <<"FrameTooLarge">>,
                message => iolist_to_binary(["frame length is over the limit of ",
                                             integer_to_binary(opt(Key, D)), " bytes (the "
                                             "listener's ", atom_to_binary(Key), ")"])}}.

document({description_too_large, _}, handshaking, D) ->
    refuse(refused(<<"BadHandshake">>, <<"the first frame must be a Hello">>), D);
document({description_too_large, Message}, _State, D) ->
    ?LOG_NOTICE(#{what => description_refused, reason => Message}),
    send(bil:encode_signal(error_signal(<<"DescriptionRefused">>, Message, D)), D);
document({ok, {control, {hello, Hello}}}, handshaking, D) ->
    hello(Hello, D);
document({ok, {control, {resume, Resume}}}, handshaking, D) ->
    hello(Resume, D);
document({ok, _}, handshaking, D) ->
    refuse(refused(<<"BadHandshake">>, <<"the first frame must be a Hello">>), D);
document({error, Reason}, handshaking, D) ->
    refuse(agent_bridge_frame:refusal({malformed, Reason}), D);
document({ok, {signal, Signal}}, _State, #d{session = Session}) ->
    ok = evatar:send(Session, Signal),
    keep_state_and_data;
document({ok, {description, Description}}, _State, #d{session = Session} = D) ->
    case evatar:describe(Session, Description) of
        ok ->
            {next_state, active, D};
        {error, Reason} ->
            ?LOG_NOTICE(#{what => description_refused, reason => evatar_log:term(Reason)}),
            send(bil:encode_signal(error_signal(<<"DescriptionRefused">>, Reason, D)), D)
    end;
document({ok, {control, {bye, _}}}, _State, D) ->
    close({bye, <<>>}, D);
document({ok, {control, {ack, Ack}}}, _State, #d{version = 2, session = Session}) ->
    _ = [evatar:ack(Session, N) || #{received := N} <- [Ack], Session =/= undefined],
    keep_state_and_data;
document({ok, {control, {get_binding, _}}}, _State, #d{session = Session}) ->
    ok = evatar:report_binding(Session),
    keep_state_and_data;
document({ok, {control, {ack, Ack}}}, _State, #d{version = 1}) when map_size(Ack) =:= 0 ->
    %% A version 1 client's keepalive (it resets the idle timeout).
    keep_state_and_data;
document({ok, {control, {Other, _}}}, _State, D) ->
    Message = <<"a client does not send ", (atom_to_binary(Other))/binary, " documents">>,
    send(bil:encode_signal(error_signal(<<"UnexpectedDocument">>, Message, D)), D);
document({error, Reason}, _State, D) ->
    ?LOG_INFO(#{what => malformed_document, reason => evatar_log:term(Reason)}),
    Signal = error_signal(<<"Malformed">>, bil:format_error(Reason), D),
    send(bil:encode_signal(Signal), D).

hello(#{protocol_version := V}, D) when V =/= 1, V =/= 2 ->
    refuse(refused(<<"BadHandshake">>, <<"this server speaks ProtocolVersion 1 and 2">>), D);
hello(#{protocol_version := 1, session_id := _}, D) ->
    refuse(refused(<<"BadHandshake">>, <<"Resume needs ProtocolVersion 2">>), D);
hello(Hello, D) ->
    join(Hello, D).

join(#{pairing := P, role := Role, entity_id := E, credential := C,
       protocol_version := V} = Hello, D) ->
    Auth = #{credential => C, peer_cert => D#d.peer_cert},
    {SessionId, Result} =
        case Hello of
            #{session_id := S, received := R, epoch := Ep} ->
                {S, evatar:resume(P, Role, E, Auth, #{session => S, received => R, epoch => Ep})};
            #{} when V =:= 2 ->
                S = session_id(),
                {S, evatar:join(P, Role, E, Auth, #{session => S})};
            #{} ->
                {session_id(), evatar:join(P, Role, E, Auth)}
        end,
    case locked_out(Result, D) of
        {locked, Ms, Session} ->
            %% A handshake under way when its address was locked out gets
            %% no verdict, right or wrong.
            ok = evatar:leave(Session),
            refuse(locked_refusal(Ms), D#d{pairing = P, entity = E}, #{role => Role});
        {ok, Session} ->
            Pid = evatar:session_pid(Session),
            Info = evatar:session_info(Session),
            logger:update_process_metadata(#{pairing => evatar_log:id(P),
                                             entity => evatar_log:id(E)}),
            ?LOG_INFO(#{what => joined, role => Role, protocol_version => V,
                        resumed => maps:get(resumed, Info), peer_cert => D#d.peer_cert}),
            D1 = D#d{session = Session, pairing = P, pairing_pid = Pid,
                     monitor = monitor(process, Pid), entity = E, version = V},
            Welcome0 = #{pairing => P, entity_id => E, session_id => SessionId,
                         join_timeout => maps:get(join_timeout, Info),
                         max_frame => opt(max_frame, D)},
            Welcome = case V of
                          1 -> Welcome0;
                          2 -> Welcome0#{ha => #{epoch => maps:get(epoch, Info),
                                                 resumed => maps:get(resumed, Info),
                                                 last_accepted => maps:get(last_accepted, Info),
                                                 dedup_window => maps:get(dedup_window, Info),
                                                 heartbeat => opt(heartbeat, D)}}
                      end,
            ok = agent_bridge_transport:set_max_frame(D1#d.transport, opt(max_frame, D)),
            ok = agent_bridge_transport:activate(D1#d.transport, opt(active_n, D)),
            D1a = D1#d{credit = sock_flow:credit(opt(active_n, D)),
                       bucket = full_bucket(D)},
            Beat = case V of
                       2 -> [heartbeat_check(D)];
                       %% A port's program is the operator's, and its exit is seen.
                       1 -> [idle_check(D) || opt(idle_timeout, D) =/= infinity,
                                              element(1, D1#d.transport) =/= port]
                   end,
            %% A resumed session has described itself already.
            Next = case maps:get(resumed, Info) of
                       true -> active;
                       false -> joined
                   end,
            case enqueue(bil_control:encode({welcome, Welcome}), D1a) of
                {ok, D2, Actions} -> {next_state, Next, D2, Beat ++ Actions};
                overflow -> slow_consumer(D1a)
            end;
        {error, bad_credential} ->
            %% Slowed down: the Refused waits for a delay that grows with
            %% the failures of this address (docs/protocol.md, section 7).
            {Delay, LockedMs} = agent_bridge_guard:failed(opt_guard(D), D#d.ip),
            Last = case LockedMs of
                       0 -> join_refusal(bad_credential);
                       _ -> locked_refusal(LockedMs)
                   end,
            ok = log_refusal(Last, D#d{pairing = P, entity = E}, #{role => Role}),
            case Delay of
                0 -> close(Last, D);
                _ -> {next_state, penalty, D, [{state_timeout, Delay, {refuse, Last}}]}
            end;
        {error, Why} ->
            refuse(join_refusal(Why), D#d{pairing = P, entity = E}, #{role => Role})
    end.

join_refusal(unknown_pairing) -> refused(<<"UnknownPairing">>, <<"no such pairing">>);
join_refusal(bad_credential) -> refused(<<"BadCredential">>, <<"wrong credential">>);
join_refusal(id_too_long) ->
    refused(<<"IdTooLong">>, <<"the EntityID is longer than the pairing's max_id_length">>);
join_refusal(reserved_id) ->
    refused(<<"ReservedId">>, <<"the EntityID reads as EVATAR, the sender of EVATAR's own "
                                "signals">>);
join_refusal(occupied) ->
    refused(<<"Occupied">>, <<"this pairing already has its agent">>);
join_refusal(entity_exists) ->
    refused(<<"EntityExists">>, <<"an entity with this id is already joined">>);
join_refusal(too_many_entities) ->
    refused(<<"TooManyEntities">>, <<"this pairing is full">>);
join_refusal(stale_epoch) ->
    refused(<<"StaleEpoch">>, <<"this node's instance of the pairing is older than one "
                                "you have seen; try another endpoint">>);
join_refusal(busy) ->
    refused(<<"Busy">>, <<"the pairing did not answer in time (busy with a large operation); "
                          "try again">>);
join_refusal(fenced) ->
    refused(<<"Fenced">>, <<"this node lost the majority of the cluster; try another "
                            "endpoint">>);
join_refusal({not_active, Node}) ->
    refused(<<"NotActive">>, <<"this node holds the pairing's standby; the active is on ",
                               (atom_to_binary(Node))/binary>>).

%% The Refused code of each of the pairing's drop codes (docs/protocol.md).
-spec dropped_code(evatar:drop_code()) -> binary().
dropped_code(join_timeout) -> <<"JoinTimeout">>;
dropped_code(pairing_deleted) -> <<"PairingDeleted">>;
dropped_code(slow_consumer) -> <<"SlowConsumer">>;
dropped_code(not_active) -> <<"NotActive">>;
dropped_code(fenced) -> <<"Fenced">>;
dropped_code(stale_epoch) -> <<"StaleEpoch">>;
dropped_code(silent_link) -> <<"SilentLink">>;
dropped_code(session_resumed) -> <<"SessionResumed">>.

refused(Code, Message) -> {refused, #{code => Code, message => Message}}.

locked_refusal(Ms) ->
    agent_bridge_guard:refusal(<<"LockedOut">>, Ms).

%% A successful join from an address locked out meanwhile.
locked_out({ok, Session} = Ok, #d{ip = Ip} = D) ->
    case agent_bridge_guard:locked(opt_guard(D), Ip) of
        0 -> Ok;
        Ms -> {locked, Ms, Session}
    end;
locked_out(Error, _D) ->
    Error.

%% A refusal during the handshake: logged through the listener's guard, in
%% rate-limited summaries, then closed.
refuse(Last, D) ->
    refuse(Last, D, #{}).

refuse(Last, D, Details) ->
    ok = log_refusal(Last, D, Details),
    close(Last, D).

log_refusal({refused, #{code := Code}}, #d{ip = Ip, pairing = P, entity = E} = D, Details) ->
    Ids = maps:from_list([{K, V} || {K, V} <- [{pairing, P}, {entity, E}], V =/= undefined,
                                    V =/= <<>>]),
    agent_bridge_guard:refused(opt_guard(D), Ip, Code, maps:merge(Details, Ids)).

opt_guard(#d{opts = Opts}) -> maps:get(guard, Opts, undefined).

idle_check(D) -> {{timeout, idle}, opt(idle_timeout, D), check}.

heartbeat_check(D) -> {{timeout, heartbeat}, max(1, opt(heartbeat, D) div 2), beat}.

error_signal(Type, Message, #d{entity = E}) ->
    agent_bridge_frame:error_signal(E, Type, Message, undefined).

session_id() ->
    binary:encode_hex(crypto:strong_rand_bytes(16)).

%% Counts a frame read in `{active, N}' mode and, every half batch, tops
%% the socket's count up again while the pairing keeps up. A socket that
%% never goes passive stays in the runtime's poll set, which lets the
%% runtime move it to the pollset its schedulers check themselves, and no
%% poll thread has to wake up for each frame (on a two-core machine those
%% wake-ups cost a fifth of a round trip: bench/EVATAR_BENCH.md). The
%% top-up counts what the socket may still deliver and what already waits
%% in this process's mailbox, so at most `active_n' frames are ever on
%% their way, as with a plain `{active, N}'. While the pairing is behind,
%% the count runs out, the socket goes passive, and resume_reading/1 takes
%% over.
read_on(#d{credit = 0} = D) ->
    %% Handshaking ({active, once}) or passive.
    D;
read_on(#d{credit = C, unpaced = U} = D) when C > 1 ->
    D#d{credit = C - 1, unpaced = U + 1};
read_on(#d{pairing_pid = Pid, transport = T, unpaced = U} = D0) ->
    {Pace, D} = pace(D0#d{unpaced = U + 1}),
    N = opt(active_n, D),
    case Pace =:= ok andalso pairing_backlog(Pid) =< opt(pairing_watermark, D) of
        false ->
            ok;
        true ->
            {message_queue_len, Waiting} = process_info(self(), message_queue_len),
            ok = agent_bridge_transport:top_up(T, N - Waiting)
    end,
    D#d{credit = sock_flow:credit(N)}.

%% A result that keeps the data keeps the read count updated before it.
with_data(D, keep_state_and_data) -> {keep_state, D};
with_data(_D, Result) -> Result.

%% Stops reading while the pairing has more than the watermark waiting, so
%% a flooding client cannot grow the pairing's mailbox without bound.
resume_reading(D0) ->
    case pace(D0) of
        {{wait, Ms}, D} -> {keep_state, D, [{{timeout, resume}, Ms, resume}]};
        {ok, D} -> resume_below_watermark(D)
    end.

resume_below_watermark(#d{pairing_pid = Pid, transport = T} = D) ->
    case pairing_backlog(Pid) > opt(pairing_watermark, D) of
        true ->
            {keep_state, D, [{{timeout, resume}, opt(retry_interval, D), resume}]};
        false ->
            ok = agent_bridge_transport:activate(T, opt(active_n, D)),
            {keep_state, D#d{credit = sock_flow:credit(opt(active_n, D))}}
    end.

%% The read rate: a token bucket of `max_read_rate' frames a second,
%% holding at most one second's worth, charged with the frames read since
%% its last charge at every top-up and before every resumption. Once it
%% is empty the connection lets its socket's count run out and reads again
%% when the bucket has refilled to zero, so that a client sending faster
%% than the rate is slowed by TCP flow control, as for the watermark, and
%% cannot take more than its share of the node's CPU (docs/protocol.md
%% section 8). Nothing is refused or dropped.
pace(D) ->
    case opt(max_read_rate, D) of
        infinity -> {ok, D};
        Rate -> charge(Rate, D)
    end.

charge(Rate, #d{bucket = {T0, Tokens0}, unpaced = U} = D) ->
    Now = erlang:monotonic_time(millisecond),
    Tokens = min(Rate, Tokens0 + (Now - T0) * Rate / 1000) - U,
    D1 = D#d{bucket = {Now, Tokens}, unpaced = 0},
    case Tokens >= 0 of
        true ->
            {ok, D1};
        false ->
            {{wait, max(1, ceil(-Tokens * 1000 / Rate))}, paced_log(Rate, D1)}
    end.

paced_log(_Rate, #d{paced_logged = true} = D) ->
    D;
paced_log(Rate, D) ->
    ?LOG_INFO(#{what => read_rate_reached, max_read_rate => Rate,
                text => "the client sends faster than max_read_rate; reading is paced"}),
    D#d{paced_logged = true}.

full_bucket(D) ->
    case opt(max_read_rate, D) of
        infinity -> {0, 0};
        Rate -> {erlang:monotonic_time(millisecond), Rate}
    end.

pairing_backlog(Pid) when is_pid(Pid), node(Pid) =:= node() ->
    case erlang:process_info(Pid, message_queue_len) of
        {message_queue_len, N} -> N;
        undefined -> 0
    end;
pairing_backlog(_) ->
    0.

%% ---------------------------------------------------------------------------
%% Outbound frames and closing
%% ---------------------------------------------------------------------------

send(Doc, D) ->
    case enqueue(Doc, D) of
        {ok, D1, Actions} -> {keep_state, D1, Actions};
        overflow -> slow_consumer(D)
    end.

enqueue(Doc, #d{outq = Q, transport = T} = D) ->
    case agent_bridge_outq:write(agent_bridge_transport:send_fun(T), Doc, Q) of
        {error, overflow} -> overflow;
        Flushed -> flushed(Flushed, D#d{sent = true})
    end.

try_flush(#d{outq = Q, transport = T} = D) ->
    flushed(agent_bridge_outq:flush(agent_bridge_transport:send_fun(T), Q), D).

flushed(Flushed, D) ->
    case Flushed of
        {empty, Q1} ->
            {ok, D#d{outq = Q1}, []};
        {busy, Q1} when D#d.flushing ->
            {ok, D#d{outq = Q1}, []};
        {busy, Q1} ->
            {ok, D#d{outq = Q1, flushing = true},
             [{{timeout, flush}, opt(retry_interval, D), flush}]}
    end.

%% The peer stopped reading: the Refused goes out only if the transport
%% happens to take it, and the socket is aborted at once (linger 0), so it
%% is not kept until the peer reads.
slow_consumer(#d{outq = Q, transport = T} = D) ->
    {C, B} = agent_bridge_outq:size(Q),
    ?LOG_WARNING(#{what => slow_consumer, frames => C, bytes => B}),
    Refused = bil_control:encode(refused(<<"SlowConsumer">>, <<"the outbound queue is full">>)),
    _ = (agent_bridge_transport:send_fun(T))(Refused),
    ok = leave(D),
    ok = agent_bridge_transport:abort(T),
    {stop, normal, (forget_session(D))#d{transport = undefined}}.

flush(closing, D) ->
    case try_flush(D) of
        {ok, #d{outq = Q} = D1, Actions} ->
            case agent_bridge_outq:is_empty(Q) of
                true ->
                    ok = agent_bridge_transport:shutdown(D1#d.transport),
                    case maybe_done(D1) of
                        {keep_state, D2} -> {keep_state, D2, Actions};
                        Stop -> Stop
                    end;
                false ->
                    {keep_state, D1, Actions}
            end
    end;
flush(_State, D) ->
    {ok, D1, Actions} = try_flush(D),
    {keep_state, D1, Actions}.

%% Sends Last, leaves the pairing and lingers in `closing'.
close(Last, #d{transport = T} = D) ->
    ok = leave(D),
    D1 = forget_session(D),
    case agent_bridge_outq:push(bil_control:encode(Last), D1#d.outq) of
        {ok, Q} ->
            ok = agent_bridge_transport:drain(T),
            {next_state, closing, D1#d{outq = Q},
             [{state_timeout, opt(linger, D), linger},
              {next_event, internal, flush}]};
        {error, overflow} ->
            {stop, normal, D1}
    end.

maybe_done(#d{peer_closed = true, outq = Q} = D) ->
    case agent_bridge_outq:is_empty(Q) of
        true -> {stop, normal, D};
        false -> {keep_state, D}
    end;
maybe_done(D) ->
    {keep_state, D}.

leave(#d{session = undefined}) -> ok;
%% Without waiting: the connection is ending, and a busy pairing must not
%% hold it (the Leave reaches the pairing before this process's exit).
leave(#d{session = Session}) -> evatar:leave_async(Session).

forget_session(#d{monitor = undefined} = D) ->
    D#d{session = undefined};
forget_session(#d{monitor = Ref} = D) ->
    demonitor(Ref, [flush]),
    D#d{session = undefined, monitor = undefined}.

opt(Key, #d{opts = Opts}) -> maps:get(Key, Opts).

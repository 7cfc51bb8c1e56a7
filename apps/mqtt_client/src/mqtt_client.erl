%% @doc An MQTT 3.1.1 and 5.0 client: one process per broker connection,
%% with QoS 0 and 1 both ways, an in-flight window, retransmission, keepalive,
%% reconnect with back-off and resubscription, persistent sessions, will
%% messages and TLS. Messages reach the owner as `{mqtt_client, Pid, Event}'.
%%
%% ```
%%                 start_link / start (returns at once)
%%                        |
%%                        v
%%   +-------------> connecting -- socket or CONNACK failed, connect_timeout --+
%%   |                    |          (fatal CONNACK or reconnect => false:     |
%%   |                    |           notify owner, stop normal)               |
%%   |                    | CONNACK accepted: resend in-flight (DUP),          |
%%   |                    | resubscribe unless the session was kept            |
%%   |                    v                                                    |
%%   |                connected -- socket closed, broker silent for a         |
%%   |                    |        keepalive, malformed packet, server        |
%%   |                    |        DISCONNECT --------------------------------+
%%   |                    |                                                    |
%%   |                    | stop/1: DISCONNECT, close, stop normal             v
%%   +---- back-off timer (min_ms doubling to max_ms, jittered) ---------- backoff
%% '''
%% While not connected, QoS 1 publishes are queued and sent on connection,
%% QoS 0 publishes fail with `{error, not_connected}' (async ones are
%% dropped), and subscribe/unsubscribe calls wait for the connection.
-module(mqtt_client).
-behaviour(gen_statem).

-include_lib("kernel/include/logger.hrl").

-export([start_link/1, start/1, await_connected/2, subscribe/2, subscribe/3,
         unsubscribe/2, unsubscribe/3, publish/4, publish_async/4, stop/1, info/1]).
-export([init/1, callback_mode/0, handle_event/4, terminate/3]).

-export_type([opts/0, publish_opts/0, message/0, event/0]).

-type opts() :: #{host := inet:hostname() | inet:ip_address(),
                  port := inet:port_number(),
                  protocol => v311 | v5,
                  client_id => binary(),
                  clean_start => boolean(),
                  session_expiry => non_neg_integer(),
                  username => binary(),
                  password => binary(),
                  keepalive => non_neg_integer(),
                  will => #{topic := binary(), payload := binary(),
                            qos => 0 | 1, retain => boolean()},
                  tls => false | [ssl:tls_client_option()],
                  owner => pid(),
                  reconnect => false | #{min_ms => pos_integer(), max_ms => pos_integer()},
                  inflight_window => pos_integer(),
                  retry_interval => pos_integer(),
                  connect_timeout => pos_integer(),
                  max_packet_size => pos_integer()}.
-type publish_opts() :: #{qos => 0 | 1, retain => boolean(), ref => term(),
                          timeout => timeout(), properties => map()}.
-type message() :: #{topic := binary(), payload := binary(), qos := 0 | 1 | 2,
                     retain := boolean(), dup := boolean(), properties := map()}.
-type event() :: {connected, #{session_present := boolean()}}
               | {disconnected, term()}
               | {publish, message()}
               | {puback, term()}
               | {puback_error, term(), term()}.

%% The states of the machine (the diagram above).
-type state() :: connecting | connected | backoff.

-define(CALL_TIMEOUT, 30000).
-define(BATCH, 64).
-define(ACTIVE_N, 100).
-define(NO_EXPIRY, 16#FFFFFFFF).

-record(d, {owner :: pid(),
            owner_mon :: reference(),
            host :: inet:hostname() | inet:ip_address(),
            port :: inet:port_number(),
            tls :: false | list(),
            version :: v311 | v5,
            client_id :: binary(),
            clean_start :: boolean(),
            session_expiry :: non_neg_integer(),
            username :: binary() | undefined,
            password :: binary() | undefined,
            will :: map() | undefined,
            keepalive :: non_neg_integer(),
            connect_timeout :: pos_integer(),
            reconnect :: false | {pos_integer(), pos_integer()},
            backoff :: pos_integer(),
            window :: pos_integer(),
            retry_ms :: pos_integer(),
            max_packet :: pos_integer() | undefined,
            sock :: mqtt_client_sock:sock() | undefined,
            parser :: mqtt_client_codec:parser() | undefined,
            session :: mqtt_client_session:session(),
            subs = [] :: [{binary(), 0 | 1}],
            waiters = [] :: [gen_statem:from()],
            out = [] :: [iodata()],
            out_n = 0 :: non_neg_integer(),
            flush_pending = false :: boolean(),
            last_topic :: binary() | undefined,
            sent = false :: boolean(),
            received = false :: boolean(),
            ping_pending = false :: boolean(),
            %% Reads before the socket's count is topped up again.
            reads = ?ACTIVE_N div 2 :: pos_integer()}).

%%====================================================================
%% API
%%====================================================================

%% @doc Starts a client linked to the caller. Returns at once; connecting
%% happens in the process (see {@link await_connected/2}).
-spec start_link(opts()) -> {ok, pid()} | {error, term()}.
start_link(Opts) ->
    start(Opts, [link]).

%% @doc Starts a client without a link.
-spec start(opts()) -> {ok, pid()} | {error, term()}.
start(Opts) ->
    start(Opts, []).

start(Opts, Link) ->
    case check_opts(Opts) of
        ok ->
            Owner = maps:get(owner, Opts, self()),
            case Link of
                [link] -> gen_statem:start_link(?MODULE, {Opts, Owner}, []);
                [] -> gen_statem:start(?MODULE, {Opts, Owner}, [])
            end;
        {error, _} = E ->
            E
    end.

%% @doc Waits until the client is connected. Fails at once when the client
%% gave up (a fatal CONNACK, or a failure with `reconnect => false').
-spec await_connected(pid(), timeout()) -> ok | {error, term()}.
await_connected(Pid, Timeout) ->
    call(Pid, await_connected, Timeout).

%% @doc Subscribes; returns the broker's reason code per filter (the granted
%% QoS, or 128 and above for a refusal). Granted filters are remembered and
%% subscribed again after a reconnect.
-spec subscribe(pid(), [{binary(), 0 | 1}]) ->
          {ok, [0 | 1 | 128 | non_neg_integer()]} | {error, term()}.
subscribe(Pid, Topics) ->
    subscribe(Pid, Topics, ?CALL_TIMEOUT).

%% @doc {@link subscribe/2} with a timeout.
-spec subscribe(pid(), [{binary(), 0 | 1}], timeout()) ->
          {ok, [0 | 1 | 128 | non_neg_integer()]} | {error, term()}.
subscribe(Pid, Topics, Timeout) ->
    case check_filters(Topics) of
        ok -> call(Pid, {subscribe, Topics}, Timeout);
        {error, _} = E -> E
    end.

%% @doc Unsubscribes and forgets the filters.
-spec unsubscribe(pid(), [binary()]) -> ok | {error, term()}.
unsubscribe(Pid, Filters) ->
    unsubscribe(Pid, Filters, ?CALL_TIMEOUT).

%% @doc {@link unsubscribe/2} with a timeout.
-spec unsubscribe(pid(), [binary()], timeout()) -> ok | {error, term()}.
unsubscribe(Pid, Filters, Timeout) ->
    case check_filters([{F, 0} || F <- Filters]) of
        ok -> call(Pid, {unsubscribe, Filters}, Timeout);
        {error, _} = E -> E
    end.

%% @doc Publishes. QoS 0 returns when the packet is handed to the socket;
%% QoS 1 returns after the PUBACK, or `{error, timeout}' after `timeout' ms
%% (default 30000; the message stays queued and may still be delivered).
-spec publish(pid(), binary(), iodata(), publish_opts()) -> ok | {error, term()}.
publish(Pid, Topic, Payload, Opts) ->
    case check_publish(Topic, Payload, Opts) of
        ok -> call(Pid, {publish, Topic, Payload, Opts}, maps:get(timeout, Opts, ?CALL_TIMEOUT));
        {error, _} = E -> E
    end.

%% @doc Publishes without waiting. For QoS 1 with a `ref', the owner gets
%% `{mqtt_client, Pid, {puback, Ref}}' (or `{puback_error, Ref, Reason}' for a
%% 5.0 error code). Invalid topics or options are dropped with a warning.
-spec publish_async(pid(), binary(), iodata(), publish_opts()) -> ok.
publish_async(Pid, Topic, Payload, Opts) ->
    gen_statem:cast(Pid, {publish, Topic, Payload, Opts}).

%% @doc Sends DISCONNECT (so the broker drops the will) and stops.
-spec stop(pid()) -> ok.
stop(Pid) ->
    case call(Pid, stop, ?CALL_TIMEOUT) of
        ok -> ok;
        {error, _} -> ok
    end.

%% @doc A snapshot for inspection: state, client id, in-flight and queued
%% QoS 1 messages, remembered subscriptions.
-spec info(pid()) -> map() | {error, term()}.
info(Pid) ->
    call(Pid, info, ?CALL_TIMEOUT).

call(Pid, Req, Timeout) ->
    try
        gen_statem:call(Pid, Req, Timeout)
    catch
        exit:{timeout, _} -> {error, timeout};
        exit:{noproc, _} -> {error, not_running};
        exit:{normal, _} -> {error, stopped};
        exit:{{shutdown, R}, _} -> {error, R};
        exit:{R, _} -> {error, R}
    end.

%%====================================================================
%% Option checks (in the caller, so bad options fail start)
%%====================================================================

check_opts(#{host := _, port := Port} = Opts) when is_integer(Port), Port > 0, Port < 65536 ->
    Checks = [{protocol, fun(V) -> V =:= v311 orelse V =:= v5 end},
              {client_id, fun(V) -> is_binary(V) andalso mqtt_client_codec:valid_utf8(V)
                                        andalso byte_size(V) < 65536 end},
              {clean_start, fun is_boolean/1},
              {session_expiry, fun(V) -> is_integer(V) andalso V >= 0 andalso V =< ?NO_EXPIRY end},
              {username, fun(V) -> is_binary(V) andalso mqtt_client_codec:valid_utf8(V) end},
              {password, fun(V) -> is_binary(V) andalso byte_size(V) < 65536 end},
              {keepalive, fun(V) -> is_integer(V) andalso V >= 0 andalso V < 65536 end},
              {will, fun check_will/1},
              {tls, fun(V) -> V =:= false orelse is_list(V) end},
              {owner, fun is_pid/1},
              {reconnect, fun(false) -> true;
                             (#{} = M) -> lists:all(fun(K) -> pos_int(maps:get(K, M, 1)) end,
                                                    [min_ms, max_ms]);
                             (_) -> false
                          end},
              {inflight_window, fun(V) -> pos_int(V) andalso V =< 65535 end},
              {retry_interval, fun pos_int/1},
              {connect_timeout, fun pos_int/1},
              {max_packet_size, fun(V) -> pos_int(V) andalso V =< 16#FFFFFFFF end}],
    Bad = [K || {K, F} <- Checks, is_map_key(K, Opts), not F(maps:get(K, Opts))],
    case Bad of
        [] -> ok;
        [K | _] -> {error, {bad_option, K}}
    end;
check_opts(_) ->
    {error, {bad_option, host_and_port}}.

pos_int(V) -> is_integer(V) andalso V > 0.

check_will(#{topic := T, payload := P} = W) when is_binary(P) ->
    mqtt_client_codec:validate_topic_name(T) =:= ok
        andalso lists:member(maps:get(qos, W, 0), [0, 1])
        andalso is_boolean(maps:get(retain, W, false));
check_will(_) ->
    false.

check_filters([]) ->
    {error, no_topics};
check_filters(Topics) when is_list(Topics) ->
    Bad = [T || T <- Topics,
                case T of
                    {F, Q} when Q =:= 0; Q =:= 1 ->
                        mqtt_client_codec:validate_topic_filter(F) =/= ok;
                    _ -> true
                end],
    case Bad of
        [] -> ok;
        [B | _] -> {error, {bad_topic_filter, B}}
    end;
check_filters(_) ->
    {error, no_topics}.

check_publish(Topic, Payload, Opts) when is_map(Opts) ->
    case mqtt_client_codec:validate_topic_name(Topic) of
        ok ->
            QoS = maps:get(qos, Opts, 0),
            Retain = maps:get(retain, Opts, false),
            Props = maps:get(properties, Opts, #{}),
            case (QoS =:= 0 orelse QoS =:= 1) andalso is_boolean(Retain) andalso is_map(Props) of
                true ->
                    try iolist_size(Payload) of
                        _ -> ok
                    catch
                        error:badarg -> {error, bad_payload}
                    end;
                false -> {error, bad_publish_options}
            end;
        {error, R} ->
            {error, {bad_topic, R}}
    end;
check_publish(_, _, _) ->
    {error, bad_publish_options}.

%% Casts are checked in the client; a run of messages to the same topic
%% checks the topic once.
check_publish_cast(Topic, Payload, #{qos := QoS} = Opts, #d{last_topic = Topic})
  when (QoS =:= 0 orelse QoS =:= 1), is_binary(Payload), map_size(Opts) =< 3 ->
    case Opts of
        #{retain := R} when not is_boolean(R) -> {error, bad_publish_options};
        #{properties := P} when not is_map(P) -> {error, bad_publish_options};
        _ -> ok
    end;
check_publish_cast(Topic, Payload, Opts, _D) ->
    check_publish(Topic, Payload, Opts).

%%====================================================================
%% gen_statem
%%====================================================================

%% @private
-spec callback_mode() -> gen_statem:callback_mode_result().
callback_mode() -> handle_event_function.

%% @private
-spec init({opts(), pid()}) -> gen_statem:init_result(connecting).
init({Opts, Owner}) ->
    ClientId = case Opts of
                   #{client_id := Id} -> Id;
                   _ -> generate_client_id()
               end,
    logger:set_process_metadata(#{mqtt_client => ClientId, domain => [mqtt_client]}),
    {Min, Max} = case maps:get(reconnect, Opts, #{}) of
                     false -> {100, 5000};
                     R -> {maps:get(min_ms, R, 100), max(maps:get(min_ms, R, 100),
                                                          maps:get(max_ms, R, 5000))}
                 end,
    Window = maps:get(inflight_window, Opts, 32),
    D = #d{owner = Owner,
           owner_mon = erlang:monitor(process, Owner),
           host = maps:get(host, Opts),
           port = maps:get(port, Opts),
           tls = maps:get(tls, Opts, false),
           version = maps:get(protocol, Opts, v311),
           client_id = ClientId,
           clean_start = maps:get(clean_start, Opts, true),
           session_expiry = maps:get(session_expiry, Opts, ?NO_EXPIRY),
           username = maps:get(username, Opts, undefined),
           password = maps:get(password, Opts, undefined),
           will = maps:get(will, Opts, undefined),
           keepalive = maps:get(keepalive, Opts, 60),
           connect_timeout = maps:get(connect_timeout, Opts, 10000),
           reconnect = case maps:get(reconnect, Opts, #{}) of
                           false -> false;
                           _ -> {Min, Max}
                       end,
           backoff = Min,
           window = Window,
           retry_ms = maps:get(retry_interval, Opts, 5000),
           max_packet = maps:get(max_packet_size, Opts, undefined),
           session = mqtt_client_session:new(Window)},
    {ok, connecting, D, [{next_event, internal, connect}]}.

generate_client_id() ->
    <<"mqttc-", (integer_to_binary(rand:uniform(1 bsl 48), 36))/binary>>.

%% @private
-spec handle_event(gen_statem:event_type(), term(), state(), #d{}) ->
          gen_statem:event_handler_result(state()).
%% Connecting: open the socket, send CONNECT, wait for CONNACK.
handle_event(internal, connect, connecting, D) ->
    case D#d.tls of
        false -> ok;
        _ -> {ok, _} = application:ensure_all_started(ssl), ok
    end,
    case mqtt_client_sock:connect(D#d.host, D#d.port, D#d.tls, D#d.connect_timeout) of
        {ok, Sock} ->
            Parser = mqtt_client_codec:parser(
                       maps:merge(#{version => D#d.version},
                                  case D#d.max_packet of
                                      undefined -> #{};
                                      M -> #{max_packet_size => M}
                                  end)),
            case mqtt_client_sock:send(Sock, mqtt_client_codec:encode(connect_packet(D),
                                                                        D#d.version)) of
                ok ->
                    {keep_state, D#d{sock = Sock, parser = Parser},
                     [{state_timeout, D#d.connect_timeout, connack_timeout}]};
                {error, R} ->
                    failed({send_failed, R}, D#d{sock = Sock})
            end;
        {error, R} ->
            failed({connect_failed, R}, D)
    end;
handle_event(state_timeout, connack_timeout, connecting, D) ->
    failed(connack_timeout, D);
handle_event(state_timeout, reconnect, backoff, D) ->
    {next_state, connecting, D, [{next_event, internal, connect}]};

%% API calls
handle_event({call, From}, await_connected, connected, _D) ->
    {keep_state_and_data, [{reply, From, ok}]};
handle_event({call, From}, await_connected, _, D) ->
    {keep_state, D#d{waiters = [From | D#d.waiters]}};
handle_event({call, From}, info, State, D) ->
    {keep_state_and_data,
     [{reply, From, #{state => State, client_id => D#d.client_id,
                      protocol => D#d.version,
                      inflight => mqtt_client_session:inflight_count(D#d.session),
                      queued => mqtt_client_session:queue_len(D#d.session),
                      subscriptions => D#d.subs}}]};
handle_event({call, From}, stop, State, D) ->
    ok = disconnect(State, 0, D),
    give_up(stopped, false, D#d{sock = undefined}),
    {stop_and_reply, normal, [{reply, From, ok}]};
handle_event(info, {'DOWN', Ref, process, _, _}, State, #d{owner_mon = Ref} = D) ->
    ok = disconnect(State, 0, D),
    {stop, normal, D#d{sock = undefined}};
handle_event({call, From}, {publish, Topic, Payload, Opts}, State, D) ->
    publish_event(State, {reply, From}, Topic, Payload, Opts, D);
handle_event(cast, {publish, Topic, Payload, Opts}, State, D) ->
    case check_publish_cast(Topic, Payload, Opts, D) of
        ok ->
            Notify = case Opts of
                         #{ref := Ref} -> {ref, Ref};
                         _ -> none
                     end,
            publish_event(State, Notify, Topic, Payload, Opts, D#d{last_topic = Topic});
        {error, R} ->
            ?LOG_WARNING(#{what => publish_dropped, reason => R}),
            keep_state_and_data
    end;
handle_event({call, From}, {subscribe, Topics}, connected, D) ->
    {Id, S} = mqtt_client_session:request({subscribe, From, Topics}, D#d.session),
    D1 = buffer(subscribe_packet(Id, Topics, D), D#d{session = S}),
    after_event(D1, []);
handle_event({call, From}, {unsubscribe, Filters}, connected, D) ->
    {Id, S} = mqtt_client_session:request({unsubscribe, From, Filters}, D#d.session),
    Subs = [Sub || {F, _} = Sub <- D#d.subs, not lists:member(F, Filters)],
    D1 = buffer(mqtt_client_codec:encode(#{type => unsubscribe, packet_id => Id,
                                           topics => Filters, properties => #{}},
                                         D#d.version),
                D#d{session = S, subs = Subs}),
    after_event(D1, []);
handle_event({call, _}, {Op, _}, _State, _D) when Op =:= subscribe; Op =:= unsubscribe ->
    {keep_state_and_data, [postpone]};

%% Socket events
handle_event(info, Msg, State, #d{sock = Sock} = D) when Sock =/= undefined,
                                                       element(2, Msg) =:= element(2, Sock) ->
    case mqtt_client_sock:classify(Msg, Sock) of
        {data, Bin} ->
            case mqtt_client_codec:parse(Bin, D#d.parser) of
                {ok, Packets, Parser} ->
                    packets(State, Packets, read_on(D#d{parser = Parser, received = true}));
                {error, R} ->
                    protocol_error(State, {malformed_packet, R}, D)
            end;
        passive ->
            case mqtt_client_sock:is_passive(Sock) of
                true ->
                    case mqtt_client_sock:activate(Sock, ?ACTIVE_N) of
                        ok -> {keep_state, D#d{reads = ?ACTIVE_N div 2}};
                        {error, R} -> lost(State, R, D)
                    end;
                false ->
                    keep_state_and_data
            end;
        {closed, R} ->
            lost(State, R, D);
        other ->
            keep_state_and_data
    end;

%% Timers while connected
handle_event({timeout, keepalive}, tick, connected, D) ->
    if
        D#d.ping_pending, not D#d.received ->
            lost(connected, keepalive_timeout, D);
        not D#d.sent; not D#d.received ->
            D1 = buffer(mqtt_client_codec:encode_pingreq(), D),
            after_event(D1#d{sent = false, received = false, ping_pending = true},
                        keepalive_timer(D));
        true ->
            after_event(D#d{sent = false, received = false, ping_pending = false},
                        keepalive_timer(D))
    end;
handle_event({timeout, retry}, tick, connected, D) ->
    {Outs, S} = mqtt_client_session:retry(now_ms(), D#d.retry_ms, D#d.session),
    after_event(send_outs(Outs, D#d{session = S}), retry_timer(D));
handle_event(info, '$mqtt_client_flush', connected, D) ->
    case flush(D#d{flush_pending = false}) of
        {ok, D1} -> {keep_state, D1};
        {error, R} -> lost(connected, {send_failed, R}, D)
    end;
handle_event(info, '$mqtt_client_flush', _State, D) ->
    {keep_state, D#d{flush_pending = false}};
handle_event({timeout, _}, tick, _State, _D) ->
    keep_state_and_data;
handle_event(info, _Other, _State, _D) ->
    keep_state_and_data.

%% @private
-spec terminate(term(), state(), #d{}) -> ok.
terminate(_Reason, _State, D) ->
    mqtt_client_sock:close(D#d.sock).

%%====================================================================
%% Publishing
%%====================================================================

publish_event(State, Notify, Topic, Payload, Opts, D) ->
    QoS = maps:get(qos, Opts, 0),
    Retain = maps:get(retain, Opts, false),
    Props = maps:get(properties, Opts, #{}),
    case {QoS, State} of
        {0, connected} ->
            D1 = buffer(mqtt_client_codec:encode_publish(D#d.version, false, 0, Retain,
                                                         undefined, Topic, Payload, Props),
                        D),
            case Notify of
                {reply, From} ->
                    case flush(D1) of
                        {ok, D2} ->
                            {keep_state, D2, [{reply, From, ok}]};
                        {error, R} ->
                            gen_statem:reply(From, {error, R}),
                            lost(State, {send_failed, R}, D1#d{out = [], out_n = 0})
                    end;
                _ ->
                    after_event(D1, [])
            end;
        {0, _} ->
            case Notify of
                {reply, From} -> {keep_state_and_data, [{reply, From, {error, not_connected}}]};
                _ -> keep_state_and_data
            end;
        {1, _} ->
            Msg = {Topic, Payload, Retain, Props, Notify},
            {Outs, S} = mqtt_client_session:publish(Msg, now_ms(), State =:= connected,
                                                    D#d.session),
            D1 = send_outs(Outs, D#d{session = S}),
            case State of
                connected -> after_event(D1, []);
                _ -> {keep_state, D1}
            end
    end.

send_outs([], D) ->
    D;
send_outs([{publish, Id, {Topic, Payload, Retain, Props, _}, Dup} | Rest], D) ->
    Packet = mqtt_client_codec:encode_publish(D#d.version, Dup, 1, Retain, Id, Topic,
                                              Payload, Props),
    send_outs(Rest, buffer(Packet, D));
send_outs([{request, Id, {subscribe, _, Topics}} | Rest], D) ->
    send_outs(Rest, buffer(subscribe_packet(Id, Topics, D), D));
send_outs([{request, Id, {resubscribe, Topics}} | Rest], D) ->
    send_outs(Rest, buffer(subscribe_packet(Id, Topics, D), D));
send_outs([{request, Id, {unsubscribe, _, Filters}} | Rest], D) ->
    Packet = mqtt_client_codec:encode(#{type => unsubscribe, packet_id => Id,
                                        topics => Filters, properties => #{}}, D#d.version),
    send_outs(Rest, buffer(Packet, D)).

subscribe_packet(Id, Topics, D) ->
    mqtt_client_codec:encode(
      #{type => subscribe, packet_id => Id, properties => #{},
        topics => [{F, #{qos => Q, no_local => false, retain_as_published => false,
                         retain_handling => 0}} || {F, Q} <- Topics]},
      D#d.version).

%%====================================================================
%% Incoming packets
%%====================================================================

%% Every half batch of reads the socket's count is topped up
%% (mqtt_client_sock:top_up/2).
read_on(#d{reads = R} = D) when R > 1 ->
    D#d{reads = R - 1};
read_on(#d{sock = Sock} = D) ->
    ok = mqtt_client_sock:top_up(Sock, ?ACTIVE_N),
    D#d{reads = ?ACTIVE_N div 2}.

packets(connecting, [#{type := connack} = Ack | Rest], D) ->
    connack(Ack, Rest, D);
packets(connecting, [], D) ->
    {keep_state, D};
packets(connecting, [P | _], D) ->
    failed({protocol_error, {expected_connack, maps:get(type, P)}}, D);
packets(connected, Packets, D) ->
    case handle_packets(Packets, D) of
        {ok, D1} -> after_event(D1, []);
        {lost, R, D1} -> lost(connected, R, D1)
    end;
packets(_State, _Packets, _D) ->
    keep_state_and_data.

connack(#{reason_code := 0, session_present := SP, properties := Props}, Rest, D) ->
    KA = maps:get(server_keep_alive, Props, D#d.keepalive),
    Session0 = case Props of
                   #{receive_maximum := RM} ->
                       mqtt_client_session:set_window(min(RM, D#d.window), D#d.session);
                   _ ->
                       D#d.session
               end,
    Kept = SP andalso not D#d.clean_start,
    {Outs, Session1} = mqtt_client_session:resume(now_ms(), Session0),
    {Session2, Resub} =
        case {Kept, D#d.subs} of
            {false, [_ | _] = Subs} ->
                {Id, S} = mqtt_client_session:request({resubscribe, Subs}, Session1),
                {S, [{request, Id, {resubscribe, Subs}}]};
            _ ->
                {Session1, []}
        end,
    D1 = D#d{keepalive = KA, session = Session2, backoff = min_backoff(D),
             sent = true, received = true, ping_pending = false},
    %% Subscriptions first, so that replayed requests find them in place.
    D2 = send_outs(Resub ++ Outs, D1),
    [gen_statem:reply(W, ok) || W <- lists:reverse(D#d.waiters)],
    notify({connected, #{session_present => SP}}, D),
    ?LOG_INFO(#{what => connected, host => D#d.host, port => D#d.port,
                session_present => SP}),
    Timers = [{state_timeout, cancel} | keepalive_timer(D1) ++
                  case D#d.version of
                      v311 -> retry_timer(D1);
                      v5 -> []
                  end],
    case handle_packets(Rest, D2#d{waiters = []}) of
        {ok, D3} ->
            case flush(D3) of
                {ok, D4} ->
                    {next_state, connected, D4, Timers};
                {error, R} ->
                    failed({send_failed, R}, D3)
            end;
        {lost, R, D3} ->
            failed(R, D3)
    end;
connack(#{reason_code := Code}, _Rest, D) ->
    Name = case D#d.version of
               v311 -> mqtt_client_codec:reason_name({v311, Code});
               v5 -> mqtt_client_codec:reason_name(Code)
           end,
    Fatal = lists:member(Name, [unacceptable_protocol_version, identifier_rejected,
                                bad_username_or_password, not_authorized,
                                unsupported_protocol_version, client_identifier_not_valid,
                                banned, bad_authentication_method]),
    case Fatal of
        true ->
            ok = mqtt_client_sock:close(D#d.sock),
            ?LOG_WARNING(#{what => connection_refused, reason => Name}),
            give_up({connack_error, Name}, true, D#d{sock = undefined}),
            {stop, normal, D#d{sock = undefined}};
        false ->
            failed({connack_error, Name}, D)
    end.

handle_packets([], D) ->
    {ok, D};
handle_packets([P | Rest], D) ->
    case handle_packet(P, D) of
        {ok, D1} -> handle_packets(Rest, D1);
        {lost, _, _} = L -> L
    end.

handle_packet(#{type := publish, topic := T, payload := Pl, qos := QoS, retain := R,
                dup := Dup, packet_id := Id, properties := Props}, D) ->
    notify({publish, #{topic => T, payload => Pl, qos => QoS, retain => R, dup => Dup,
                       properties => Props}}, D),
    case QoS of
        0 -> {ok, D};
        1 -> {ok, buffer(mqtt_client_codec:encode_puback(D#d.version, Id), D)};
        2 -> {ok, buffer(mqtt_client_codec:encode(#{type => pubrec, packet_id => Id},
                                                   D#d.version), D)}
    end;
handle_packet(#{type := puback, packet_id := Id, reason_code := RC}, D) ->
    case mqtt_client_session:puback(Id, now_ms(), D#d.session) of
        {ok, {_, _, _, _, Notify}, Outs, S} ->
            completed(Notify, RC, D),
            {ok, send_outs(Outs, D#d{session = S})};
        {error, unknown_packet_id} ->
            ?LOG_DEBUG(#{what => unexpected_puback, packet_id => Id}),
            {ok, D}
    end;
handle_packet(#{type := pubrel, packet_id := Id}, D) ->
    {ok, buffer(mqtt_client_codec:encode(#{type => pubcomp, packet_id => Id}, D#d.version), D)};
handle_packet(#{type := suback, packet_id := Id, reason_codes := Codes}, D) ->
    case mqtt_client_session:request_done(Id, D#d.session) of
        {ok, {subscribe, From, Topics}, S} ->
            gen_statem:reply(From, {ok, Codes}),
            Granted = [T || {{_, _} = T, C} <- lists:zip(Topics, pad(Codes, length(Topics))),
                            C < 16#80],
            {ok, D#d{session = S, subs = merge_subs(Granted, D#d.subs)}};
        {ok, {resubscribe, Topics}, S} ->
            Refused = [F || {{F, _}, C} <- lists:zip(Topics, pad(Codes, length(Topics))),
                            C >= 16#80],
            Refused =:= [] orelse ?LOG_WARNING(#{what => resubscribe_refused, filters => Refused}),
            {ok, D#d{session = S}};
        _ ->
            {ok, D}
    end;
handle_packet(#{type := unsuback, packet_id := Id}, D) ->
    case mqtt_client_session:request_done(Id, D#d.session) of
        {ok, {unsubscribe, From, _}, S} ->
            gen_statem:reply(From, ok),
            {ok, D#d{session = S}};
        _ ->
            {ok, D}
    end;
handle_packet(#{type := pingresp}, D) ->
    {ok, D#d{ping_pending = false}};
handle_packet(#{type := disconnect, reason_code := RC}, D) ->
    {lost, {server_disconnect, mqtt_client_codec:reason_name(RC)}, D};
handle_packet(#{type := Type}, D) when Type =:= pubrec; Type =:= pubcomp ->
    {ok, D};
handle_packet(#{type := Type}, D) ->
    {lost, {protocol_error, {unexpected_packet, Type}}, D}.

pad(Codes, N) when length(Codes) >= N -> lists:sublist(Codes, N);
pad(Codes, N) -> Codes ++ lists:duplicate(N - length(Codes), 16#80).

merge_subs(New, Subs) ->
    lists:foldl(fun({F, Q}, Acc) -> lists:keystore(F, 1, Acc, {F, Q}) end, Subs, New).

completed({reply, From}, RC, _D) when RC < 16#80 ->
    gen_statem:reply(From, ok);
completed({reply, From}, RC, _D) ->
    gen_statem:reply(From, {error, {puback, mqtt_client_codec:reason_name(RC)}});
completed({ref, Ref}, RC, D) when RC < 16#80 ->
    notify({puback, Ref}, D);
completed({ref, Ref}, RC, D) ->
    notify({puback_error, Ref, mqtt_client_codec:reason_name(RC)}, D);
completed(none, _RC, _D) ->
    ok.

%%====================================================================
%% Connection loss
%%====================================================================

protocol_error(State, R, D) ->
    ?LOG_WARNING(#{what => protocol_error, reason => R}),
    ok = case D#d.version of
             v5 -> disconnect(State, 16#81, D);  % malformed packet
             v311 -> mqtt_client_sock:close(D#d.sock)
         end,
    lost(State, {protocol_error, R}, D#d{sock = undefined}).

%% Sends what is buffered and a DISCONNECT (when connected), then closes.
disconnect(connected, Reason, D) ->
    _ = flush(D),
    _ = mqtt_client_sock:send(D#d.sock, mqtt_client_codec:encode(
                                          #{type => disconnect, reason_code => Reason,
                                            properties => #{}}, D#d.version)),
    mqtt_client_sock:close(D#d.sock);
disconnect(_State, _Reason, D) ->
    mqtt_client_sock:close(D#d.sock).

lost(connected, R, D) ->
    notify({disconnected, R}, D),
    ?LOG_INFO(#{what => disconnected, reason => R}),
    failed(R, D#d{out = [], out_n = 0});
lost(_State, R, D) ->
    failed(R, D).

%% A connection attempt or a connection failed: back off, or give up.
failed(R, D) ->
    ok = mqtt_client_sock:close(D#d.sock),
    D1 = D#d{sock = undefined, parser = undefined, out = [], out_n = 0},
    Cancel = [{{timeout, keepalive}, cancel}, {{timeout, retry}, cancel}],
    case D#d.reconnect of
        false ->
            give_up(R, true, D1),
            {stop, normal, D1};
        {_Min, Max} ->
            Delay = jitter(D#d.backoff),
            ?LOG_DEBUG(#{what => reconnect_wait, reason => R, delay_ms => Delay}),
            {next_state, backoff, D1#d{backoff = min(D#d.backoff * 2, Max)},
             [{state_timeout, Delay, reconnect} | Cancel]}
    end.

%% Stopping for good: tell the owner (unless it asked), fail everyone waiting.
give_up(R, Notify, D) ->
    Notify andalso notify({disconnected, R}, D),
    [gen_statem:reply(W, {error, R}) || W <- D#d.waiters],
    {Msgs, Reqs, _} = mqtt_client_session:drain(D#d.session),
    [completed_error(N, R, D) || {_, _, _, _, N} <- Msgs],
    [gen_statem:reply(From, {error, R}) || {Op, From, _} <- Reqs,
                                          Op =:= subscribe orelse Op =:= unsubscribe],
    ok.

completed_error({reply, From}, R, _D) -> gen_statem:reply(From, {error, R});
completed_error({ref, Ref}, R, D) -> notify({puback_error, Ref, R}, D);
completed_error(none, _R, _D) -> ok.

min_backoff(#d{reconnect = {Min, _}}) -> Min;
min_backoff(#d{backoff = B}) -> B.

jitter(Ms) ->
    Ms - Ms div 5 + rand:uniform(max(1, (2 * Ms) div 5)).

%%====================================================================
%% Output buffering
%%====================================================================

%% Packets queue up in `out'; a flush message to self is written behind
%% whatever is already in the mailbox, so a burst of casts or a chunk of
%% incoming packets becomes one socket write, with no added wait when idle.
%% Every ?BATCH packets the buffer is written at once.
buffer(Packet, #d{out = Out, out_n = N} = D) ->
    D#d{out = [Packet | Out], out_n = N + 1}.

after_event(#d{out = []} = D, Actions) ->
    {keep_state, D, Actions};
after_event(#d{out_n = N} = D, Actions) when N >= ?BATCH ->
    case flush(D) of
        {ok, D1} -> {keep_state, D1, Actions};
        {error, R} -> lost(connected, {send_failed, R}, D)
    end;
after_event(#d{flush_pending = true} = D, Actions) ->
    {keep_state, D, Actions};
after_event(D, Actions) ->
    self() ! '$mqtt_client_flush',
    {keep_state, D#d{flush_pending = true}, Actions}.

flush(#d{out = []} = D) ->
    {ok, D};
flush(#d{out = Out, sock = Sock} = D) ->
    case mqtt_client_sock:send(Sock, lists:reverse(Out)) of
        ok -> {ok, D#d{out = [], out_n = 0, sent = true}};
        {error, _} = E -> E
    end.

%%====================================================================
%% Helpers
%%====================================================================

connect_packet(D) ->
    Props0 = case {D#d.version, D#d.clean_start} of
                 {v5, false} -> #{session_expiry_interval => D#d.session_expiry};
                 _ -> #{}
             end,
    %% 5.0 brokers drop (rather than send) what exceeds our limit.
    Props = case {D#d.version, D#d.max_packet} of
                {v5, Max} when is_integer(Max) -> Props0#{maximum_packet_size => Max};
                _ -> Props0
            end,
    P0 = #{type => connect, proto => D#d.version, clean_start => D#d.clean_start,
           keepalive => D#d.keepalive, client_id => D#d.client_id, properties => Props},
    P1 = case D#d.will of
             undefined -> P0;
             W -> P0#{will => #{topic => maps:get(topic, W), payload => maps:get(payload, W),
                                qos => maps:get(qos, W, 0), retain => maps:get(retain, W, false),
                                properties => #{}}}
         end,
    maps:merge(P1, maps:filter(fun(_, V) -> V =/= undefined end,
                               #{username => D#d.username, password => D#d.password})).

keepalive_timer(#d{keepalive = 0}) ->
    [];
keepalive_timer(#d{keepalive = KA}) ->
    [{{timeout, keepalive}, KA * 500, tick}].

retry_timer(#d{retry_ms = Ms}) ->
    [{{timeout, retry}, Ms, tick}].

notify(Event, #d{owner = Owner}) ->
    Owner ! {mqtt_client, self(), Event},
    ok.

now_ms() ->
    erlang:monotonic_time(millisecond).

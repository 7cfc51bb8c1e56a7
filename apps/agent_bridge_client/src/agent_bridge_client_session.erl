%% @doc Internal. The client side of an EVATAR session as pure data (no
%% pids, sockets or timers; the time is an argument): which version it
%% speaks, the endpoint ring, the window of signals EVATAR has not yet
%% acknowledged, de-duplication of what it delivers, request correlation,
%% the heartbeat check and the resume. Functions return what to do as
%% {@type effect()}s; agent_bridge_client, the process, carries them out.
%% Versions 1 and 2 (docs/protocol.md section 9) are kept apart: each entry
%% point chooses its version once, and the two halves of this module share
%% only the signal encoder and the request table.
-module(agent_bridge_client_session).

-export([new/3, version/1, ever_connected/1, welcome/1, endpoint/1, hello/1,
         next_attempt/2, attempt_failed/3, handshake_timeout/1, refused_in_handshake/3, welcomed/3,
         incoming/3, lost/3, describe/3, send/4, request/5, get_binding/2,
         request_timeout/2, sent_failed/2, ack_due/1, silence_check/2,
         await_acks/2, finish/1, status/2]).

-export_type([session/0, effect/0, from/0]).

-type from() :: gen_statem:from().
-type timer() :: ack | silence | retry | {request, binary()}.
%% `{send, Frame}': write it on the current connection. `{send, Frame,
%% {reply, From}}': write it and answer From `ok' or `{error, closed}'.
%% `{send, Frame, {request, Id}}': write it; when that fails, tell
%% sent_failed/2. `{notify, Event}': `{agent_bridge, Client, Event}' to the
%% owner. Timers are the process's named timeouts; firing, they come back
%% as ack_due/1, silence_check/2, next_attempt/2 or request_timeout/2.
-type effect() :: {send, iodata()}
                | {send, iodata(), {reply, from()} | {request, binary()}}
                | {reply, from(), term()}
                | {notify, term()}
                | {timer, timer(), non_neg_integer()}
                | {cancel, timer()}
                | {log, notice, map()}.

%% Refusals after which a version 2 client tries the next endpoint.
-define(RETRY_CODES, [<<"NotActive">>, <<"Fenced">>, <<"StaleEpoch">>, <<"PairingDown">>,
                      <<"UnknownPairing">>, <<"HandshakeTimeout">>, <<"SilentLink">>,
                      <<"SessionResumed">>, <<"TooManyConnections">>, <<"RateLimited">>]).
-define(ACK_DELAY, 5).
-define(ACK_EVERY, 32).
-define(RECONNECT_LIMIT, 600000).
%% A handshake timeout doubles after each one in a row, up to this many
%% doublings (8 times `handshake_timeout').
-define(MAX_SLOW_DOUBLINGS, 3).

-record(s, {opts :: agent_bridge_client:opts(),
            version :: 1 | 2,
            nonce :: binary(),
            counter = 0 :: non_neg_integer(),
            %% Endpoints: version 1 tries each once, in order; version 2
            %% goes round the ring.
            endpoints :: [agent_bridge_client:endpoint()],
            all :: [agent_bridge_client:endpoint()],
            current :: agent_bridge_client:endpoint() | undefined,
            failures = [] :: [{agent_bridge_client:endpoint(), term()}],
            next = 0 :: non_neg_integer(),
            tried = 0 :: non_neg_integer(),
            backoff = 0 :: non_neg_integer(),
            lost_at :: integer() | undefined,
            last_reason :: term(),
            %% Handshakes given up in a row (no Welcome within the
            %% handshake timeout) since the last Welcome.
            slow = 0 :: non_neg_integer(),
            ever_connected = false :: boolean(),
            %% The Welcome of the live connection; undefined between two.
            welcome :: bil_control:welcome() | undefined,
            %% request/3 callers awaiting feedback, by SignalID.
            pending = #{} :: #{binary() => from()},
            %% Version 2 only.
            session_id :: binary() | undefined,
            epoch = 0 :: non_neg_integer(),
            last_seq = 0 :: non_neg_integer(),
            acked_seq = 0 :: non_neg_integer(),
            ack_timer = false :: boolean(),
            unacked = queue:new() :: queue:queue({binary(), iodata()}),
            unacked_n = 0 :: non_neg_integer(),
            blocked = queue:new() :: queue:queue({from(), {binary(), iodata()},
                                                   signal | request}),
            ack_waiters = [] :: [from()],
            description :: iodata() | undefined,
            heartbeat = 0 :: non_neg_integer(),
            last_rx = 0 :: integer(),
            window = 1024 :: pos_integer(),
            %% A new session after a reconnect (the server had lost the
            %% old one, e.g. every node restarted): signals wait until a
            %% Binding report shows another entity registered, instead of
            %% being refused as UnknownReceiver while it is not back yet.
            held = false :: boolean()}).
-opaque session() :: #s{}.

%% @doc A session not connected yet; `Nonce' makes its SignalIDs unique.
-spec new([agent_bridge_client:endpoint()], agent_bridge_client:opts(), binary()) -> session().
new(Endpoints, Opts, Nonce) ->
    #s{opts = Opts, nonce = Nonce, endpoints = Endpoints, all = Endpoints,
       version = case maps:get(ha, Opts, false) of true -> 2; false -> 1 end}.

-spec version(session()) -> 1 | 2.
version(#s{version = V}) -> V.

%% @doc Whether a Welcome ever came (connect/1 has returned).
-spec ever_connected(session()) -> boolean().
ever_connected(#s{ever_connected = E}) -> E.

%% @doc The live connection's Welcome, or undefined between connections.
-spec welcome(session()) -> bil_control:welcome() | undefined.
welcome(#s{welcome = W}) -> W.

%% @doc The endpoint of the current (or last) attempt.
-spec endpoint(session()) -> agent_bridge_client:endpoint() | undefined.
endpoint(#s{current = E}) -> E.

%% @doc The first frame on a new connection: a Hello, or in version 2 a
%% Resume once there is a session to resume.
-spec hello(session()) -> iodata().
hello(#s{opts = Opts, version = V, session_id = Session} = S) ->
    Hello = #{pairing => maps:get(pairing, Opts), role => maps:get(role, Opts),
              entity_id => maps:get(entity_id, Opts),
              credential => maps:get(credential, Opts), protocol_version => V},
    bil_control:encode(case Session of
                           undefined -> {hello, Hello};
                           _ -> {resume, Hello#{session_id => Session,
                                                received => S#s.last_seq,
                                                epoch => S#s.epoch}}
                       end).

%% ---------------------------------------------------------------------------
%% The endpoint ring
%% ---------------------------------------------------------------------------

%% @doc Where to connect next, or why to stop trying: `{unreachable,
%% [{Endpoint, Why}]}' before any Welcome, `{gave_up, LastReason}' after.
%% Version 1 tries every endpoint once, in order; version 2 one endpoint
%% per attempt round the ring, starting after the one it lost, until
%% `reconnect_limit' ms have passed since it was lost.
-spec next_attempt(integer(), session()) ->
          {connect, agent_bridge_client:endpoint(), session()} | {give_up, term()}.
next_attempt(Now, #s{version = 1} = S) -> v1_next_attempt(Now, S);
next_attempt(Now, #s{version = 2} = S) -> v2_next_attempt(Now, S).

%% @doc The attempt at the current endpoint failed (no connection, no
%% Welcome): try the next one now or after a pause (`{retry, Ms}': a
%% version 2 client pauses after every full round, doubling up to the
%% back-off's maximum).
-spec attempt_failed(term(), integer(), session()) -> {now | {retry, pos_integer()}, session()}.
attempt_failed(handshake_timeout = Why, Now, #s{slow = Slow} = S) ->
    attempt_failed1(Why, Now, S#s{slow = Slow + 1});
attempt_failed(Why, Now, S) ->
    attempt_failed1(Why, Now, S).

attempt_failed1(Why, _Now, #s{version = 1, current = E} = S) ->
    {now, S#s{failures = [{E, Why} | S#s.failures]}};
attempt_failed1(Why, _Now, #s{version = 2} = S) ->
    v2_attempt_failed(Why, S).

%% @doc How long the next handshake may take (connected to Welcome or
%% Refused): `handshake_timeout' (default 5,000 ms), doubled after each
%% handshake given up in a row since the last Welcome, up to 8 times it.
%% A node too busy to answer a crowd of clients in time (every client of
%% a failed node resuming on it at once, on a loaded machine) would
%% otherwise get the same crowd again and again: each Resume it answers
%% too late is work done for a client that has left, and it falls further
%% behind; with longer waits the crowd thins until its answers arrive in
%% time. Refusals do not reset it: a node that refuses at once says
%% nothing of how fast the node that serves answers.
-spec handshake_timeout(session()) -> timeout().
handshake_timeout(#s{opts = Opts, slow = Slow}) ->
    case maps:get(handshake_timeout, Opts, 5000) of
        infinity -> infinity;
        Ms -> Ms bsl min(Slow, ?MAX_SLOW_DOUBLINGS)
    end.

%% @doc A Refused instead of the Welcome: another endpoint may serve us
%% (`retry', version 2 only, for a refusal meaning "not here"), or the same
%% credential would be refused everywhere (`final').
-spec refused_in_handshake(binary(), binary(), session()) -> retry | final.
refused_in_handshake(Code, _Message, #s{version = 2}) ->
    case lists:member(Code, ?RETRY_CODES) of
        true -> retry;
        false -> final
    end;
refused_in_handshake(_Code, _Message, #s{version = 1}) ->
    final.

%% @doc The Welcome came: the session is up. A version 2 client resumed
%% drops what the server accepted already and sends again the rest; with a
%% new session it describes itself again first, and after a reconnect holds
%% its signals until a Binding report shows another entity.
-spec welcomed(bil_control:welcome(), integer(), session()) ->
          {ok, [effect()], session()} | {error, term()}.
welcomed(Welcome, _Now, #s{version = 1} = S) ->
    {ok, [], S#s{welcome = Welcome, ever_connected = true, slow = 0}};
welcomed(Welcome, Now, #s{version = 2} = S) ->
    v2_welcomed(Welcome, Now, S#s{slow = 0}).

%% @doc The connection ended (`closed', `{socket_error, _}', `{refused,
%% Code, Message}', `{bye, Reason}', `{malformed, _}', `server_silent'):
%% version 2 reconnects unless the refusal is final or the server sent
%% nonsense; version 1 stops, and its owner is told `{closed, Reason}'.
-spec lost(term(), integer(), session()) -> {reconnect, [effect()], session()} | stop.
lost(_Reason, _Now, #s{version = 1}) ->
    stop;
lost(Reason, Now, #s{version = 2} = S) ->
    v2_lost(Reason, Now, S).

%% ---------------------------------------------------------------------------
%% Traffic
%% ---------------------------------------------------------------------------

%% @doc A frame from the live connection, parsed (bil_control:parse_frame/2).
-spec incoming({ok, term()} | {error, term()}, integer(), session()) ->
          {ok, [effect()], session()} | {lost, term(), session()}.
incoming(Parsed, _Now, #s{version = 1} = S) -> v1_incoming(Parsed, S);
incoming(Parsed, Now, #s{version = 2} = S) -> v2_incoming(Parsed, S#s{last_rx = Now}).

%% @doc describe/2: version 1 writes it now (or answers `{error, closed}');
%% version 2 keeps it, for a new session after a reconnect, and writes it
%% when connected.
-spec describe(from(), iodata(), session()) -> {[effect()], session()}.
describe(From, _Doc, #s{version = 1, welcome = undefined} = S) ->
    {[{reply, From, {error, closed}}], S};
describe(From, Doc, #s{version = 1} = S) ->
    {[{send, Doc, {reply, From}}], S};
describe(From, Doc, #s{version = 2} = S) ->
    {[{send, Doc} || S#s.welcome =/= undefined] ++ [{reply, From, ok}],
     S#s{description = Doc}}.

%% @doc send/2, with `Wall' the time (ms since 1970) for a Timestamp left
%% out.
-spec send(from(), term(), integer(), session()) -> {[effect()], session()}.
send(From, _Partial, _Wall, #s{version = 1, welcome = undefined} = S) ->
    {[{reply, From, {error, closed}}], S};
send(From, Partial, Wall, #s{version = 1} = S) ->
    case encode(Partial, Wall, S) of
        {ok, _Id, Frame, S1} -> {[{send, Frame, {reply, From}}], S1};
        {error, _} = Error -> {[{reply, From, Error}], S}
    end;
send(From, Partial, Wall, #s{version = 2} = S) ->
    v2_send(From, signal, Partial, [], Wall, S).

%% @doc request/3: the answer goes to From when the feedback (or an error
%% signal) answering it comes, or `{error, timeout}' after Timeout ms.
-spec request(from(), term(), timeout(), integer(), session()) -> {[effect()], session()}.
request(From, _Partial, _Timeout, _Wall, #s{version = 1, welcome = undefined} = S) ->
    {[{reply, From, {error, closed}}], S};
request(From, Partial, Timeout, Wall, #s{version = 1} = S) when is_map(Partial) ->
    case encode(Partial#{context => request}, Wall, S) of
        {ok, Id, Frame, S1} ->
            {[{send, Frame, {request, Id}}, {timer, {request, Id}, Timeout}],
             S1#s{pending = (S1#s.pending)#{Id => From}}};
        {error, _} = Error ->
            {[{reply, From, Error}], S}
    end;
request(From, Partial, _Timeout, _Wall, #s{version = 1} = S) ->
    {[{reply, From, {error, {bad_signal, {not_a_map, Partial}}}}], S};
request(From, Partial, Timeout, Wall, #s{version = 2} = S) when is_map(Partial) ->
    v2_send(From, request, Partial#{context => request}, Timeout, Wall, S);
request(From, Partial, _Timeout, _Wall, #s{version = 2} = S) ->
    {[{reply, From, {error, {bad_signal, {not_a_map, Partial}}}}], S}.

%% @doc get_binding/1: a GetBinding when connected; while a version 2
%% client reconnects, `ok' (a resumed session is sent the report anyway).
-spec get_binding(from(), session()) -> [effect()].
get_binding(From, #s{welcome = undefined, version = 1}) ->
    [{reply, From, {error, closed}}];
get_binding(From, #s{welcome = undefined, version = 2}) ->
    [{reply, From, ok}];
get_binding(From, #s{}) ->
    [{send, bil_control:encode({get_binding, #{}}), {reply, From}}].

%% @doc A request's timer fired: its caller gets `{error, timeout}'.
-spec request_timeout(binary(), session()) -> {[effect()], session()}.
request_timeout(Id, #s{pending = P, blocked = B} = S) when not is_map_key(Id, P) ->
    %% Still waiting for room in the window: it is never sent.
    case lists:partition(fun({_, {I, _}, K}) -> I =:= Id andalso K =:= request end,
                         queue:to_list(B)) of
        {[{From, _, _}], Rest} ->
            {[{reply, From, {error, timeout}}], S#s{blocked = queue:from_list(Rest)}};
        {[], _} ->
            {[], S}
    end;
request_timeout(Id, S) ->
    answer(Id, {error, timeout}, S).

%% @doc Writing a version 1 request failed: its caller gets `{error, closed}'.
-spec sent_failed(binary(), session()) -> {[effect()], session()}.
sent_failed(Id, S) ->
    answer(Id, {error, closed}, S).

%% @doc The ack timer fired: acknowledge what was passed to the owner.
-spec ack_due(session()) -> {[effect()], session()}.
ack_due(#s{welcome = undefined} = S) ->
    {[], S#s{ack_timer = false}};
ack_due(S) ->
    send_ack(S#s{ack_timer = false}).

%% @doc The heartbeat timer fired: a server silent for three heartbeats is
%% lost.
-spec silence_check(integer(), session()) -> {ok, [effect()]} | {lost, server_silent}.
silence_check(_Now, #s{welcome = undefined}) ->
    {ok, []};
silence_check(Now, #s{heartbeat = Hb, last_rx = Rx}) ->
    case Now - Rx > 3 * Hb of
        true -> {lost, server_silent};
        false -> {ok, [{timer, silence, Hb}]}
    end.

%% @doc await_acks/2: at once when nothing waits for an Ack.
-spec await_acks(from(), session()) -> {[effect()], session()}.
await_acks(From, #s{unacked_n = 0, blocked = B} = S) ->
    case queue:is_empty(B) of
        true -> {[{reply, From, ok}], S};
        false -> {[], S#s{ack_waiters = [From | S#s.ack_waiters]}}
    end;
await_acks(From, S) ->
    {[], S#s{ack_waiters = [From | S#s.ack_waiters]}}.

%% @doc The client stops: every waiting caller gets `{error, closed}'.
-spec finish(session()) -> {[effect()], session()}.
finish(#s{pending = P, blocked = B, ack_waiters = W} = S) ->
    Froms = maps:values(P) ++ [From || {From, _, _} <- queue:to_list(B)] ++ W,
    {[{reply, From, {error, closed}} || From <- Froms],
     S#s{pending = #{}, blocked = queue:new(), ack_waiters = []}}.

%% @doc status/1's map.
-spec status(boolean(), session()) -> map().
status(Connected, S) ->
    #{connected => Connected, endpoint => S#s.current, epoch => S#s.epoch,
      session_id => S#s.session_id, unacked => S#s.unacked_n, last_seq => S#s.last_seq}.

%% ---------------------------------------------------------------------------
%% Version 1
%% ---------------------------------------------------------------------------

v1_next_attempt(_Now, #s{endpoints = []} = S) ->
    {give_up, {unreachable, lists:reverse(S#s.failures)}};
v1_next_attempt(_Now, #s{endpoints = [E | Rest]} = S) ->
    {connect, E, S#s{endpoints = Rest, current = E}}.

v1_incoming({ok, {signal, #{in_reply_to := Id, context := Ctx} = Sig}}, #s{pending = P} = S)
  when is_map_key(Id, P), (Ctx =:= feedback orelse Ctx =:= error) ->
    ok(answer(Id, reply_of(Sig), S));
v1_incoming({ok, {signal, Sig}}, S) ->
    {ok, [{notify, {signal, Sig}}], S};
v1_incoming({ok, {control, {binding, Report}}}, S) ->
    {ok, [{notify, {binding, Report}}], S};
v1_incoming(Parsed, S) ->
    common_incoming(Parsed, S).

%% ---------------------------------------------------------------------------
%% Version 2
%% ---------------------------------------------------------------------------

v2_next_attempt(Now, #s{all = All, next = Next, tried = Tried} = S) ->
    Limit = maps:get(reconnect_limit, S#s.opts, ?RECONNECT_LIMIT),
    case Now - lost_at(Now, S) > Limit andalso Tried > 0 of
        true when S#s.ever_connected ->
            {give_up, {gave_up, S#s.last_reason}};
        true ->
            {give_up, {unreachable, lists:reverse(S#s.failures)}};
        false ->
            E = lists:nth(Next rem length(All) + 1, All),
            {connect, E, S#s{next = Next + 1, tried = Tried + 1, current = E,
                             lost_at = lost_at(Now, S)}}
    end.

%% The first attempt starts the clock.
lost_at(Now, #s{lost_at = undefined}) -> Now;
lost_at(_Now, #s{lost_at = At}) -> At.

v2_attempt_failed(Why, #s{all = All, tried = Tried, opts = Opts, current = E} = S) ->
    S1 = S#s{failures = [{E, Why} | S#s.failures], last_reason = Why},
    {Min, Max} = maps:get(reconnect_backoff, Opts, {20, 500}),
    case Tried rem length(All) of
        0 ->
            Pause = min(Max, max(Min, S#s.backoff * 2)),
            {{retry, Pause}, S1#s{backoff = Pause}};
        _ ->
            {now, S1}
    end.

v2_welcomed(Welcome, _Now, _S) when not is_map_key(ha, Welcome) ->
    {error, {refused, <<"BadHandshake">>, <<"the server does not speak ProtocolVersion 2">>}};
v2_welcomed(#{session_id := Sid, ha := Ha} = Welcome, Now, #s{ever_connected = Again} = S) ->
    #{epoch := Epoch, resumed := Resumed, last_accepted := Last, dedup_window := Window,
      heartbeat := Hb} = Ha,
    {Acked, S1} = case Resumed of
                      true ->
                          drop_accepted(Last, S#s{epoch = max(Epoch, S#s.epoch)});
                      false ->
                          %% A new session: the server knows nothing of this client.
                          {[], S#s{session_id = Sid, epoch = Epoch, last_seq = 0,
                                   acked_seq = 0}}
                  end,
    S2 = S1#s{welcome = Welcome, ever_connected = true, tried = 0, backoff = 0,
              failures = [], heartbeat = Hb, window = max(1, Window), last_rx = Now},
    %% Described again only when the session is new; then everything not
    %% acknowledged goes again (the server drops what it already accepted),
    %% once the other side is registered again (held until a Binding
    %% report says so). A resumed session stays held if it was: resuming
    %% the new session on another node (a handover) says nothing of the
    %% other side, and the Binding report that follows the Welcome does.
    Describe = [Desc || not Resumed, Desc <- [S2#s.description], Desc =/= undefined],
    Held = case Resumed of
               true -> S#s.held;
               false -> Again andalso Describe =/= []
           end,
    Resend = [{send, Frame} || not Held, {_, Frame} <- queue:to_list(S2#s.unacked)],
    Reconnected = [{notify, {reconnected, #{endpoint => S2#s.current, resumed => Resumed,
                                           epoch => S2#s.epoch, session_id => Sid,
                                           reason => S#s.last_reason}}} || Again],
    Silence = [{timer, silence, Hb} || Hb > 0],
    {ok, Acked ++ [{send, D} || D <- Describe] ++ Resend ++ Reconnected ++ Silence,
     S2#s{held = Held}}.

v2_lost(Reason, Now, #s{current = Current, all = All} = S) ->
    Retry = case Reason of
                {refused, Code, _} -> lists:member(Code, ?RETRY_CODES);
                {malformed, _} -> false;
                _ -> true
            end,
    case Retry of
        true ->
            {reconnect, [{cancel, silence}, {cancel, ack}],
             S#s{welcome = undefined, next = index_of(Current, All) + 1, tried = 0,
                 backoff = 0, lost_at = Now, last_reason = Reason, ack_timer = false}};
        false ->
            stop
    end.

v2_incoming({ok, {signal, Sig}}, S) ->
    deliver(Sig, S);
v2_incoming({ok, {control, {binding, Report}}}, S) ->
    {Effects, S1} = release_held(Report, S),
    {ok, Effects ++ [{notify, {binding, Report}}], S1};
v2_incoming({ok, {control, {ack, #{accepted := Id}}}}, S) ->
    ok(acknowledged(Id, S));
v2_incoming({ok, {control, {ack, #{}}}}, S) ->
    {ok, [], S};
v2_incoming(Parsed, S) ->
    common_incoming(Parsed, S).

%% Nothing twice: a signal redelivered after a resume (Sequence already
%% passed to the owner) or from an older epoch than one seen is dropped.
deliver(#{seq := Seq}, #s{last_seq = Last} = S) when is_integer(Seq), Seq =< Last ->
    {ok, [], S};
deliver(#{epoch := Epoch}, #s{epoch = Mine} = S) when is_integer(Epoch), Epoch < Mine ->
    {ok, [], S};
deliver(Sig, S) ->
    S1 = case maps:get(seq, Sig, undefined) of
             N when is_integer(N) -> S#s{last_seq = N};
             _ -> S
         end,
    S2 = case maps:get(epoch, Sig, undefined) of
             E when is_integer(E), E > S1#s.epoch -> S1#s{epoch = E};
             _ -> S1
         end,
    {Ack, S3} = schedule_ack(S2),
    case Sig of
        #{in_reply_to := Id, context := Ctx} when is_map_key(Id, S3#s.pending),
                                                  (Ctx =:= feedback orelse Ctx =:= error) ->
            {Answer, S4} = answer(Id, reply_of(Sig), S3),
            {ok, Ack ++ Answer, S4};
        _ ->
            {ok, Ack ++ [{notify, {signal, Sig}}], S3}
    end.

schedule_ack(#s{last_seq = Last, acked_seq = Acked} = S) when Last - Acked >= ?ACK_EVERY ->
    send_ack(S);
schedule_ack(#s{ack_timer = true} = S) ->
    {[], S};
schedule_ack(S) ->
    {[{timer, ack, ?ACK_DELAY}], S#s{ack_timer = true}}.

send_ack(#s{last_seq = Last, acked_seq = Last} = S) ->
    {[], S};
send_ack(#s{last_seq = Last} = S) ->
    {[{send, bil_control:encode({ack, #{received => Last}})}], S#s{acked_seq = Last}}.

%% After a new session the signals not acknowledged go once another
%% entity is registered again.
release_held(#{entities := Entities}, #s{held = true, opts = Opts} = S) ->
    case [E || E <- Entities, E =/= maps:get(entity_id, Opts)] of
        [] -> {[], S};
        [_ | _] -> {[{send, Frame} || {_, Frame} <- queue:to_list(S#s.unacked)],
                    S#s{held = false}}
    end;
release_held(_Report, S) ->
    {[], S}.

%% The server accepted everything up to `Id' in send order.
acknowledged(Id, #s{unacked = Q} = S) ->
    case lists:keymember(Id, 1, queue:to_list(Q)) of
        true -> drop_through(Id, Q, S, []);
        false -> {[], S}
    end.

drop_through(Id, Q, S, Acc) ->
    {{value, {I, _}}, Q1} = queue:out(Q),
    case I of
        Id -> after_acks(lists:reverse([I | Acc]),
                         S#s{unacked = Q1, unacked_n = queue:len(Q1)});
        _ -> drop_through(Id, Q1, S, [I | Acc])
    end.

drop_accepted(<<>>, S) -> {[], S};
drop_accepted(Last, S) -> acknowledged(Last, S).

after_acks(Ids, #s{opts = Opts} = S) ->
    Notify = [{notify, {accepted, Ids}} || maps:get(notify_acks, Opts, false)],
    {More, S1} = unblock(S, []),
    {Notify ++ More, S1}.

%% Callers that waited for room in the window go on.
unblock(#s{unacked_n = N, window = W, blocked = B} = S, Acc) when N < W ->
    case queue:out(B) of
        {{value, {From, Signal, request}}, B1} ->
            {Sent, S1} = keep(From, Signal, S#s{blocked = B1}),
            unblock(S1, lists:reverse(Sent, Acc));
        {{value, {From, Signal, signal}}, B1} ->
            {Sent, S1} = keep(none, Signal, S#s{blocked = B1}),
            unblock(S1, [{reply, From, ok} | lists:reverse(Sent, Acc)]);
        {empty, _} when N =:= 0 ->
            {lists:reverse(Acc, [{reply, F, ok} || F <- S#s.ack_waiters]),
             S#s{ack_waiters = []}};
        {empty, _} ->
            {lists:reverse(Acc), S}
    end;
unblock(S, Acc) ->
    {lists:reverse(Acc), S}.

%% The signal is completed (id, time) at once; it waits in `blocked' while
%% the window of unacknowledged signals is full. A request's timer runs from
%% the call.
v2_send(From, Kind, Partial, Timeout, Wall, S) ->
    case encode(Partial, Wall, S) of
        {ok, Id, Frame, S1} ->
            Timers = [{timer, {request, Id}, Timeout} || Kind =:= request],
            #s{unacked_n = N, window = W, blocked = B} = S1,
            case N >= W orelse not queue:is_empty(B) of
                true ->
                    {Timers, S1#s{blocked = queue:in({From, {Id, Frame}, Kind}, B)}};
                false when Kind =:= signal ->
                    {Sent, S2} = keep(none, {Id, Frame}, S1),
                    {Sent ++ [{reply, From, ok} | Timers], S2};
                false ->
                    {Sent, S2} = keep(From, {Id, Frame}, S1),
                    {Sent ++ Timers, S2}
            end;
        {error, _} = Error ->
            {[{reply, From, Error}], S}
    end.

%% Keeps the signal until it is acknowledged and writes it when connected.
%% `Waiter' is the request/3 caller awaiting the feedback, or `none' for a
%% signal given to send/2: its feedback goes to the owner like any signal.
keep(Waiter, {Id, Frame}, #s{unacked = Q, unacked_n = N} = S) ->
    Sent = [{send, Frame} || S#s.welcome =/= undefined, not S#s.held],
    S1 = S#s{unacked = queue:in({Id, Frame}, Q), unacked_n = N + 1},
    case Waiter of
        none -> {Sent, S1};
        From -> {Sent, S1#s{pending = (S1#s.pending)#{Id => From}}}
    end.

index_of(E, List) -> index_of(E, List, 0).
index_of(_E, [], _N) -> 0;
index_of(E, [E | _], N) -> N;
index_of(E, [_ | Rest], N) -> index_of(E, Rest, N + 1).

%% ---------------------------------------------------------------------------
%% Both versions
%% ---------------------------------------------------------------------------

common_incoming({ok, {control, {refused, #{code := Code, message := Message}}}}, S) ->
    {lost, {refused, Code, Message}, S};
common_incoming({ok, {control, {bye, Reason}}}, S) ->
    {lost, {bye, Reason}, S};
common_incoming({ok, Other}, S) ->
    {ok, [{log, notice, #{what => unexpected_document, document => Other}}], S};
common_incoming({error, Reason}, S) ->
    {lost, {malformed, Reason}, S}.

ok({Effects, S}) -> {ok, Effects, S}.

reply_of(#{context := feedback} = Sig) -> {ok, Sig};
reply_of(#{context := error} = Sig) -> {error, Sig}.

answer(Id, Reply, #s{pending = P} = S) ->
    case maps:take(Id, P) of
        {From, P1} -> {[{reply, From, Reply}, {cancel, {request, Id}}], S#s{pending = P1}};
        error -> {[], S}
    end.

%% The signal completed and encoded, or why it cannot be: bad input from
%% the caller is its error, not the end of the client and its session.
encode(Partial, Wall, S) when is_map(Partial) ->
    {#{id := Id} = Signal, S1} = complete(Partial, Wall, S),
    try bil:encode_signal(Signal) of
        Frame -> {ok, Id, Frame, S1}
    catch
        error:Why -> {error, {bad_signal, Why}}
    end;
encode(Partial, _Wall, _S) ->
    {error, {bad_signal, {not_a_map, Partial}}}.

complete(Partial, Wall, #s{counter = N, opts = Opts, nonce = Nonce} = S) ->
    Id = iolist_to_binary([maps:get(entity_id, Opts), "-", Nonce, "-",
                           integer_to_binary(N + 1)]),
    Defaults = #{context => request_no_feedback, id => Id, timestamp => Wall,
                 in_reply_to => undefined, seq => undefined, epoch => undefined},
    {maps:merge(Defaults, Partial), S#s{counter = N + 1}}.

%% @doc Internal. The client side of an MQTT session as pure data: packet
%% identifiers, the QoS 1 in-flight window with its overflow queue, and the
%% SUBSCRIBE/UNSUBSCRIBE requests awaiting their acknowledgement. Functions
%% return what must go on the wire; the process module sends it.
-module(mqtt_client_session).

-export([new/1, set_window/2, publish/4, puback/3, request/2, request_done/2,
         resume/2, retry/3, drain/1, inflight_count/1, queue_len/1]).

-export_type([session/0, out/0]).

-type packet_id() :: 1..65535.
-type out() :: {publish, packet_id(), Msg :: term(), Dup :: boolean()}
             | {request, packet_id(), Req :: term()}.

-record(session, {window :: pos_integer(),
                  inflight = #{} :: #{packet_id() => {Seq :: non_neg_integer(),
                                                      SentAt :: integer(),
                                                      Msg :: term()}},
                  queue = queue:new() :: queue:queue(term()),
                  qlen = 0 :: non_neg_integer(),
                  requests = #{} :: #{packet_id() => term()},
                  next_id = 1 :: packet_id(),
                  seq = 0 :: non_neg_integer()}).
-opaque session() :: #session{}.

%% @doc An empty session with an in-flight window of `Window' messages.
-spec new(pos_integer()) -> session().
new(Window) when is_integer(Window), Window > 0, Window =< 65535 ->
    #session{window = Window}.

%% @doc Changes the window (the broker's receive maximum may lower it);
%% takes effect from the next {@link resume/2} or acknowledgement.
-spec set_window(pos_integer(), session()) -> session().
set_window(Window, S) when is_integer(Window), Window > 0 ->
    S#session{window = min(Window, 65535)}.

%% @doc A QoS 1 message to publish. Sent at once when `Online' and the window
%% has room, queued otherwise.
-spec publish(term(), integer(), boolean(), session()) -> {[out()], session()}.
publish(Msg, Now, true, #session{inflight = In, window = W, qlen = 0} = S)
  when map_size(In) < W ->
    send(Msg, Now, false, S);
publish(Msg, _Now, _Online, #session{queue = Q, qlen = N} = S) ->
    {[], S#session{queue = queue:in(Msg, Q), qlen = N + 1}}.

%% @doc A PUBACK arrived: the acknowledged message and what the freed window
%% slot lets out of the queue.
-spec puback(packet_id(), integer(), session()) ->
          {ok, term(), [out()], session()} | {error, unknown_packet_id}.
puback(Id, Now, #session{inflight = In} = S) ->
    case maps:take(Id, In) of
        {{_, _, Msg}, In1} ->
            {Outs, S1} = fill(Now, S#session{inflight = In1}, []),
            {ok, Msg, Outs, S1};
        error ->
            {error, unknown_packet_id}
    end.

%% @doc Registers a SUBSCRIBE or UNSUBSCRIBE request; returns its packet id.
-spec request(term(), session()) -> {packet_id(), session()}.
request(Req, #session{requests = R} = S) ->
    {Id, S1} = alloc_id(S),
    {Id, S1#session{requests = R#{Id => Req}}}.

%% @doc The acknowledgement of a request arrived.
-spec request_done(packet_id(), session()) -> {ok, term(), session()} | error.
request_done(Id, #session{requests = R} = S) ->
    case maps:take(Id, R) of
        {Req, R1} -> {ok, Req, S#session{requests = R1}};
        error -> error
    end.

%% @doc The connection is (re)established: every unacknowledged message is
%% sent again with DUP set, in its original order, then the window is filled
%% from the queue, and pending requests are sent again.
-spec resume(integer(), session()) -> {[out()], session()}.
resume(Now, #session{inflight = In, requests = R} = S) ->
    Resend = lists:sort([{Seq, Id, Msg} || {Id, {Seq, _, Msg}} <- maps:to_list(In)]),
    In1 = maps:from_list([{Id, {Seq, Now, Msg}} || {Seq, Id, Msg} <- Resend]),
    Outs0 = [{publish, Id, Msg, true} || {_, Id, Msg} <- Resend],
    {Outs1, S1} = fill(Now, S#session{inflight = In1}, []),
    Reqs = [{request, Id, Req} || {Id, Req} <- lists:sort(maps:to_list(R))],
    {Outs0 ++ Outs1 ++ Reqs, S1}.

%% @doc Messages unacknowledged for `RetryMs' or longer, to be sent again
%% with DUP set.
-spec retry(integer(), non_neg_integer(), session()) -> {[out()], session()}.
retry(Now, RetryMs, #session{inflight = In} = S) ->
    Due = lists:sort([{Seq, Id, Msg} || {Id, {Seq, SentAt, Msg}} <- maps:to_list(In),
                                        Now - SentAt >= RetryMs]),
    In1 = lists:foldl(fun({Seq, Id, Msg}, Acc) -> Acc#{Id := {Seq, Now, Msg}} end,
                      In, Due),
    {[{publish, Id, Msg, true} || {_, Id, Msg} <- Due], S#session{inflight = In1}}.

%% @doc Empties the session: every message (in flight, then queued) and
%% every pending request, for failing their waiters.
-spec drain(session()) -> {[term()], [term()], session()}.
drain(#session{inflight = In, queue = Q, requests = R, window = W}) ->
    Msgs = [Msg || {_, _, Msg} <- lists:sort(maps:values(In))] ++ queue:to_list(Q),
    {Msgs, maps:values(R), new(W)}.

%% @doc Messages awaiting PUBACK.
-spec inflight_count(session()) -> non_neg_integer().
inflight_count(#session{inflight = In}) -> map_size(In).

%% @doc Messages waiting for room in the window.
-spec queue_len(session()) -> non_neg_integer().
queue_len(#session{qlen = N}) -> N.

%% Internal

fill(Now, #session{inflight = In, window = W, qlen = N, queue = Q} = S, Acc)
  when N > 0, map_size(In) < W ->
    {{value, Msg}, Q1} = queue:out(Q),
    {[Out], S1} = send(Msg, Now, false, S#session{queue = Q1, qlen = N - 1}),
    fill(Now, S1, [Out | Acc]);
fill(_Now, S, Acc) ->
    {lists:reverse(Acc), S}.

send(Msg, Now, Dup, #session{inflight = In, seq = Seq} = S) ->
    {Id, S1} = alloc_id(S),
    {[{publish, Id, Msg, Dup}],
     S1#session{inflight = In#{Id => {Seq, Now, Msg}}, seq = Seq + 1}}.

%% The window is at most 65535 and requests are few, so a free id exists.
alloc_id(#session{next_id = Id, inflight = In, requests = R} = S) ->
    Next = case Id of 65535 -> 1; _ -> Id + 1 end,
    case is_map_key(Id, In) orelse is_map_key(Id, R) of
        true -> alloc_id(S#session{next_id = Next});
        false -> {Id, S#session{next_id = Next}}
    end.

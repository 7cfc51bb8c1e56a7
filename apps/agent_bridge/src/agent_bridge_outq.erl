%% @doc Internal. The bounded outbound queue of one connection. Frames go to
%% the transport with `nosuspend', so a peer that stops reading never blocks
%% the connection process; what the transport refuses waits here, within a
%% byte and a frame limit (docs/protocol.md, "Backpressure").
-module(agent_bridge_outq).

-export([new/2, push/2, flush/2, write/3, is_empty/1, size/1]).

-export_type([outq/0, send_fun/0]).

-record(outq, {frames = queue:new() :: queue:queue(iodata()),
               bytes = 0 :: non_neg_integer(),
               count = 0 :: non_neg_integer(),
               max_bytes :: pos_integer(),
               max_count :: pos_integer()}).

-opaque outq() :: #outq{}.
%% Returns false when the transport is busy and did not take the frame.
-type send_fun() :: fun((iodata()) -> boolean()).

-spec new(pos_integer(), pos_integer()) -> outq().
new(MaxBytes, MaxCount) -> #outq{max_bytes = MaxBytes, max_count = MaxCount}.

%% @doc Queues one frame, or says the peer is too slow to keep up.
-spec push(iodata(), outq()) -> {ok, outq()} | {error, overflow}.
push(Frame, #outq{frames = Q, bytes = B, count = C, max_bytes = MB, max_count = MC} = O) ->
    Size = iolist_size(Frame),
    case B + Size > MB orelse C + 1 > MC of
        true -> {error, overflow};
        false -> {ok, O#outq{frames = queue:in(Frame, Q), bytes = B + Size, count = C + 1}}
    end.

%% @doc Hands queued frames to Send in order until it refuses one or none are
%% left.
-spec flush(send_fun(), outq()) -> {empty | busy, outq()}.
flush(Send, #outq{frames = Q, bytes = B, count = C} = O) ->
    case queue:out(Q) of
        {empty, _} ->
            {empty, O};
        {{value, Frame}, Q1} ->
            case Send(Frame) of
                true -> flush(Send, O#outq{frames = Q1, bytes = B - iolist_size(Frame),
                                           count = C - 1});
                false -> {busy, O}
            end
    end.

%% @doc Queues one frame and flushes (push/2, then flush/2). With nothing
%% queued, a frame Send takes at once never enters the queue.
-spec write(send_fun(), iodata(), outq()) -> {empty | busy, outq()} | {error, overflow}.
write(Send, Frame, #outq{count = 0, max_bytes = MB} = O) ->
    case iolist_size(Frame) =< MB andalso Send(Frame) of
        true ->
            {empty, O};
        false ->
            %% Over the limit (overflow), or refused by a busy transport:
            %% queued, without asking it again at once.
            case push(Frame, O) of
                {ok, O1} -> {busy, O1};
                {error, overflow} = Error -> Error
            end
    end;
write(Send, Frame, O) ->
    case push(Frame, O) of
        {ok, O1} -> flush(Send, O1);
        {error, overflow} = Error -> Error
    end.

-spec is_empty(outq()) -> boolean().
is_empty(#outq{count = C}) -> C =:= 0.

%% @doc Frames and bytes waiting.
-spec size(outq()) -> {non_neg_integer(), non_neg_integer()}.
size(#outq{count = C, bytes = B}) -> {C, B}.

%% @doc Test support, not a suite: runs the `make demo' narratives
%% (evatar_demo:main/1) with their output kept by a minimal I/O
%% server (it keeps what is written and refuses to read), for the suites
%% that check what the demo tells.
-module(evatar_demo_capture).

-export([run/1, start/0, peek/1]).

%% @doc Runs the demo with this process's group leader replaced by the
%% capture; the processes the demo starts inherit it. The demo must return
%% ok; gives all it wrote.
-spec run([string()]) -> {ok, binary()}.
run(Args) ->
    Old = group_leader(),
    Capture = start(),
    true = group_leader(Capture, self()),
    Result = try evatar_demo:main(Args)
             after true = group_leader(Old, self())
             end,
    ok = Result,
    Capture ! {done, self()},
    receive {output, Capture, Text} -> {ok, Text} end.

%% @doc A new capture, linked to the caller, to use as a group leader.
-spec start() -> pid().
start() ->
    spawn_link(fun() -> capture([]) end).

%% @doc What was written to Capture so far.
-spec peek(pid()) -> binary().
peek(Capture) ->
    Capture ! {peek, self()},
    receive {output, Capture, Text} -> Text end.

capture(Acc) ->
    receive
        {io_request, From, ReplyAs, Request} ->
            {Reply, Acc1} = io_request(Request, Acc),
            From ! {io_reply, ReplyAs, Reply},
            capture(Acc1);
        {peek, From} ->
            From ! {output, self(), iolist_to_binary(lists:reverse(Acc))},
            capture(Acc);
        {done, From} ->
            From ! {output, self(), iolist_to_binary(lists:reverse(Acc))}
    end.

io_request({put_chars, Encoding, Chars}, Acc) ->
    {ok, [unicode:characters_to_binary(Chars, Encoding) | Acc]};
io_request({put_chars, Encoding, M, F, A}, Acc) ->
    io_request({put_chars, Encoding, apply(M, F, A)}, Acc);
io_request({put_chars, Chars}, Acc) ->
    io_request({put_chars, latin1, Chars}, Acc);
io_request({put_chars, M, F, A}, Acc) ->
    io_request({put_chars, latin1, apply(M, F, A)}, Acc);
io_request({requests, Requests}, Acc) ->
    lists:foldl(fun(R, {_, A}) -> io_request(R, A) end, {ok, Acc}, Requests);
io_request(_Other, Acc) ->
    {{error, enotsup}, Acc}.

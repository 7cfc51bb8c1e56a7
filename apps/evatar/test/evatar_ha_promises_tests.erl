%% @doc The promises' log on disc (evatar_ha_promises): what is written is
%% read back after a reopen, the last record of a pairing wins, a torn tail
%% is dropped and overwritten, compaction keeps every pairing's record, and
%% a node without a data directory keeps them in memory.
-module(evatar_ha_promises_tests).

-include_lib("eunit/include/eunit.hrl").

rec(P, H) -> #{promised => P, holder => H, conf => {P, 1}, registered => true}.

%% A directory of its own, made by open/1 (with its parents), removed
%% after the test.
with_dir(Test) ->
    Top = filename:join(["/tmp", "evatar_ha_promises_tests-" ++ os:getpid() ++ "-"
                         ++ integer_to_list(erlang:unique_integer([positive]))]),
    try Test(filename:join(Top, "data"))
    after ok = file:del_dir_r(Top)
    end.

read_back(Dir) ->
    {ok, _, Entries} = evatar_ha_promises:open(Dir),
    lists:sort(Entries).

reopen_test() -> with_dir(fun reopen/1).
reopen(Dir) ->
    {ok, L0, []} = evatar_ha_promises:open(Dir),
    {ok, L1} = evatar_ha_promises:write(L0, [{<<"a">>, rec(2, x)}, {<<"b">>, rec(1, y)}]),
    {ok, _} = evatar_ha_promises:write(L1, [{<<"a">>, rec(3, z)}]),
    ?assertEqual([{<<"a">>, rec(3, z)}, {<<"b">>, rec(1, y)}], read_back(Dir)),
    %% Made readable by this node's user only.
    {ok, Info} = file:read_file_info(Dir),
    ?assertEqual(8#700, element(8, Info) band 8#777).

torn_tail_test() -> with_dir(fun torn_tail/1).
torn_tail(Dir) ->
    {ok, L0, []} = evatar_ha_promises:open(Dir),
    {ok, _} = evatar_ha_promises:write(L0, [{<<"a">>, rec(2, x)}]),
    Path = filename:join(Dir, "ha_promises.log"),
    {ok, Good} = file:read_file(Path),
    %% A write cut short by a power loss: half a frame.
    ok = file:write_file(Path, [Good, binary:part(Good, 0, 10)]),
    {ok, L1, [{<<"a">>, _}]} = evatar_ha_promises:open(Dir),
    ?assertEqual({ok, byte_size(Good)}, {ok, filelib:file_size(Path)}),
    {ok, _} = evatar_ha_promises:write(L1, [{<<"b">>, rec(1, y)}]),
    ?assertEqual([{<<"a">>, rec(2, x)}, {<<"b">>, rec(1, y)}], read_back(Dir)).

corrupt_frame_test() -> with_dir(fun corrupt_frame/1).
corrupt_frame(Dir) ->
    {ok, L0, []} = evatar_ha_promises:open(Dir),
    {ok, L1} = evatar_ha_promises:write(L0, [{<<"a">>, rec(2, x)}]),
    {ok, _} = evatar_ha_promises:write(L1, [{<<"a">>, rec(3, x)}]),
    Path = filename:join(Dir, "ha_promises.log"),
    {ok, Bin} = file:read_file(Path),
    Last = byte_size(Bin) - 1,
    <<Head:Last/binary, B>> = Bin,
    ok = file:write_file(Path, <<Head/binary, (B bxor 1)>>),
    ?assertEqual([{<<"a">>, rec(2, x)}], read_back(Dir)).

compaction_test() -> with_dir(fun compaction/1).
compaction(Dir) ->
    {ok, L0, []} = evatar_ha_promises:open(Dir),
    L1 = lists:foldl(fun(K, L) ->
                             {ok, L2} = evatar_ha_promises:write(L, [{<<"a">>, rec(K, x)}]),
                             L2
                     end, L0, lists:seq(1, 1024)),
    ?assert(evatar_ha_promises:needs_compaction(L1, 1)),
    {ok, L3} = evatar_ha_promises:compact(L1, [{<<"a">>, rec(1024, x)}]),
    ?assertNot(evatar_ha_promises:needs_compaction(L3, 1)),
    {ok, _} = evatar_ha_promises:write(L3, [{<<"b">>, rec(1, y)}]),
    ?assertEqual([{<<"a">>, rec(1024, x)}, {<<"b">>, rec(1, y)}], read_back(Dir)).

in_memory_test() ->
    {ok, L, []} = evatar_ha_promises:open(undefined),
    ?assertMatch({ok, _}, evatar_ha_promises:write(L, [{<<"a">>, rec(1, x)}])),
    ?assertNot(evatar_ha_promises:needs_compaction(L, 0)).

%% The voter's effects: a changed record is persisted before the reply; a
%% retry that changes nothing, and a refusal, write nothing.
answer_test_() ->
    New = evatar_ha_core:new_record(),
    {granted, Promised} = evatar_ha_core:vote(New, 2, b, {1, 1}, false),
    [?_assertEqual([{persist, Promised}, {reply, granted}],
                   evatar_ha_core:answer({vote, 2, b, {1, 1}, false}, New)),
     ?_assertEqual([{reply, granted}], evatar_ha_core:answer({vote, 2, b, {1, 1}, false}, Promised)),
     ?_assertEqual([{reply, {refused, {promised, 2}}}],
                   evatar_ha_core:answer({vote, 2, c, {1, 1}, false}, Promised)),
     ?_assertMatch([{persist, #{registered := true}}, {reply, ok}],
                   evatar_ha_core:answer({register, 2, 1, b}, Promised)),
     ?_assertEqual([{reply, {refused, {promised, 2}}}],
                   evatar_ha_core:answer({register, 1, 2, a}, Promised))].

%% Common Test suite of evatar_json, jiffy as the node reads input: PropEr
%% round trip and robustness properties (random and mutated bytes give an
%% error, never an exception), the RFC 8259 cases that must be refused, and
%% the limits (size, depth, long numbers) checked before or after jiffy.
-module(evatar_json_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("proper/include/proper.hrl").

-compile([export_all, nowarn_export_all]).

suite() -> [{timetrap, {seconds, 120}}].

all() ->
    [round_trip, whitespace_is_ignored, random_bytes_never_crash, mutated_json_never_crash,
     refused_documents, accepted_documents, no_atoms_from_input, limits, long_numbers].

numtests() ->
    case os:getenv("EVATAR_LONG_TESTS") of
        false -> 300;
        _ -> 5000
    end.

%% @doc Every JSON value the encoder writes decodes to the same value.
round_trip(_Config) ->
    P = ?FORALL(V, json(),
                begin
                    Text = iolist_to_binary(evatar_json:encode(V)),
                    {ok, V1} = evatar_json:decode(Text),
                    equal(V, V1)
                end),
    ok = evatar_test_proper:check(P, numtests()).

%% @doc Whitespace between tokens does not change the value.
whitespace_is_ignored(_Config) ->
    P = ?FORALL({V, Ws}, {json(), list(oneof([<<" ">>, <<"\n">>, <<"\t">>, <<"\r">>]))},
                begin
                    Text = iolist_to_binary(evatar_json:encode(V)),
                    Spaced = spread(Text, Ws),
                    {ok, V1} = evatar_json:decode(Spaced),
                    equal(V, V1)
                end),
    ok = evatar_test_proper:check(P, numtests()).

%% @doc Random bytes give {ok, _} or {error, {Code, Offset}}, never raise.
random_bytes_never_crash(_Config) ->
    P = ?FORALL(B, binary(), well_behaved(B)),
    ok = evatar_test_proper:check(P, numtests() * 3).

%% @doc Valid JSON with bytes flipped, cut or inserted never makes the
%% decoder raise.
mutated_json_never_crash(_Config) ->
    P = ?FORALL({V, Mutations}, {json(), non_empty(list({oneof([flip, cut, insert]), nat(), byte()}))},
                begin
                    Text = iolist_to_binary(evatar_json:encode(V)),
                    well_behaved(mutate(Text, Mutations))
                end),
    ok = evatar_test_proper:check(P, numtests()).

%% @doc Documents RFC 8259 refuses are refused, with a code and an offset.
refused_documents(_Config) ->
    Bad = [<<>>, <<"  ">>, <<"[1,]">>, <<"{\"a\":1,}">>, <<"{a:1}">>, <<"'x'">>, <<"01">>,
           <<"-">>, <<"1.">>, <<".5">>, <<"1e">>, <<"+1">>, <<"NaN">>, <<"Infinity">>,
           <<"\"\\x\"">>, <<"\"\\u12\"">>, <<"\"\\ud800\"">>, <<"\"\\udc00\"">>,
           <<"\"a\nb\"">>, <<"\"", 16#ff, "\"">>, <<"[1 2]">>, <<"{\"a\" 1}">>, <<"tru">>,
           <<"nul">>, <<"[">>, <<"{">>, <<"\"abc">>, <<"1 2">>, <<"1e400">>,
           binary:copy(<<"9">>, 1025)],
    [] = [{B, R} || B <- Bad, R <- [evatar_json:decode(B)],
                    not (element(1, R) =:= error andalso is_atom(element(1, element(2, R))))],
    <<"invalid JSON at byte 3: unexpected character">> =
        evatar_json:format_error(element(2, evatar_json:decode(<<"[1,]">>))),
    {error, {unexpected_end, 2}} = evatar_json:decode(<<"  ">>),
    {error, {trailing_data, 2}} = evatar_json:decode(<<"1 2">>),
    {error, {bad_string, 1}} = evatar_json:decode(<<"\"", 16#ff, "\"">>),
    {error, {not_binary, 0}} = evatar_json:decode("[]"),
    [<<"invalid JSON", _/binary>> = evatar_json:format_error(R)
     || B <- Bad, {error, R} <- [evatar_json:decode(B)]].

%% @doc What devices actually send decodes as expected.
accepted_documents(_Config) ->
    {ok, #{<<"state">> := <<"ON">>, <<"brightness">> := 254, <<"color">> := #{<<"x">> := 0.5}}} =
        evatar_json:decode(<<" {\"state\":\"ON\",\"brightness\":254,\"color\":{\"x\":0.5}} ">>),
    {ok, [true, false, null, -0.0, 1.0e-7, 12345678901234567890]} =
        evatar_json:decode(<<"[true,false,null,-0.0,1E-7,12345678901234567890]">>),
    {ok, <<"é😀/\"\\\b\f\n\r\t"/utf8>>} =
        evatar_json:decode(<<"\"\\u00e9\\ud83d\\ude00\\/\\\"\\\\\\b\\f\\n\\r\\t\"">>),
    {ok, <<"21.5">>} = {ok, evatar_json:to_text(element(2, evatar_json:decode(<<"21.5">>)))},
    {ok, 7} = evatar_json:get_path([<<"a">>, <<"1">>, <<"b">>],
                                        element(2, evatar_json:decode(
                                                     <<"{\"a\":[{},{\"b\":7}]}">>))),
    error = evatar_json:get_path([<<"a">>, <<"5">>], #{<<"a">> => [1]}).

%% @doc Keys that happen to be atom names stay binaries, and decoding
%% never creates an atom.
no_atoms_from_input(_Config) ->
    Before = erlang:system_info(atom_count),
    Keys = [iolist_to_binary(["evatar_never_an_atom_", integer_to_list(I)]) || I <- lists:seq(1, 200)],
    Doc = iolist_to_binary(evatar_json:encode(maps:from_list([{K, K} || K <- Keys]))),
    {ok, M} = evatar_json:decode(Doc),
    true = lists:all(fun is_binary/1, maps:keys(M)),
    Before = erlang:system_info(atom_count),
    {ok, #{<<"ok">> := true}} = evatar_json:decode(<<"{\"ok\":true}">>).

%% @doc Depth and size limits are enforced before any damage is done.
limits(_Config) ->
    Deep = iolist_to_binary([binary:copy(<<"[">>, 100), binary:copy(<<"]">>, 100)]),
    {error, {too_deep, _}} = evatar_json:decode(Deep),
    {ok, _} = evatar_json:decode(Deep, #{max_depth => 200}),
    {error, {too_large, 0}} = evatar_json:decode(<<"[1,2,3]">>, #{max_size => 3}),
    Depth = fun(N) -> iolist_to_binary([binary:copy(<<"{\"a\":[">>, N), binary:copy(<<"]}">>, N)]) end,
    {ok, _} = evatar_json:decode(Depth(32)),
    {error, {too_deep, _}} = evatar_json:decode(Depth(33)),
    {ok, [[1]]} = evatar_json:decode(<<"[[1]]">>, #{max_depth => 2}),
    {error, {too_deep, _}} = evatar_json:decode(<<"[[[]]]">>, #{max_depth => 2}).

%% @doc A number of more than 1,024 digits is refused before jiffy reads it
%% (a million digits would keep it busy for seconds), where it starts;
%% digits inside a string are text, escaped quotes and all.
long_numbers(_Config) ->
    D1024 = binary:copy(<<"7">>, 1024),
    D1025 = binary:copy(<<"7">>, 1025),
    {ok, [_, -1.5]} = evatar_json:decode(<<"[", D1024/binary, ",-1.5]">>),
    {ok, [_, _]} = evatar_json:decode(<<"[", D1024/binary, ",", D1024/binary, "]">>),
    {error, {bad_number, 5}} = evatar_json:decode(<<"[1, -", D1025/binary, "]">>),
    {error, {bad_number, 3}} = evatar_json:decode(<<"[0.", D1025/binary, "]">>),
    {error, {bad_number, 0}} = evatar_json:decode(binary:copy(<<"9">>, 1000000), #{max_size => 2000000}),
    {ok, #{<<"id">> := <<"x", D1025:1025/binary, "\\">>, <<"n">> := 2}} =
        evatar_json:decode(<<"{\"id\":\"x", D1025/binary, "\\\\\",\"n\":2}">>),
    {ok, [<<"\"", D1025:1025/binary>>, <<D1025:1025/binary>>]} =
        evatar_json:decode(<<"[\"\\\"", D1025/binary, "\", \"", D1025/binary, "\"]">>),
    {error, {bad_number, 8}} =
        evatar_json:decode(<<"[\"a\\\\\", ", D1025/binary, "]">>).

%% ---------------------------------------------------------------------------
%% Generators and helpers
%% ---------------------------------------------------------------------------

json() ->
    ?SIZED(Size, json(min(Size, 24))).

%% Containers of up to 5 elements, nesting while the size lasts: big
%% enough to nest, small enough to stay far below the 1 MiB limit.
json(Size) when Size < 4 ->
    scalar();
json(Size) ->
    frequency([{3, scalar()},
               {1, ?LAZY(?LET(N, range(0, 5), vector(N, json(Size div 2))))},
               {1, ?LAZY(?LET(N, range(0, 5),
                              ?LET(Pairs, vector(N, {utf8_text(), json(Size div 2)}),
                                   maps:from_list(Pairs))))}]).

scalar() ->
    oneof([true, false, null, int(), integer(-(1 bsl 100), 1 bsl 100), real_float(), utf8_text()]).

real_float() ->
    ?LET(F, float(), F).

utf8_text() ->
    ?LET(Chars, list(oneof([range(0, 16#7f), range(16#80, 16#7ff), range(16#800, 16#d7ff),
                            range(16#e000, 16#fffd), range(16#10000, 16#10ffff),
                            elements([$", $\\, $/, 0, 8, 12, 10, 13, 9, 16#1f])])),
         unicode:characters_to_binary(Chars)).

%% Floats compare with ==, so 1.0 and 1 would differ in type: keep =:=
%% except for zero's sign.
equal(A, B) when is_float(A), is_float(B) -> A == B;
equal(A, B) when is_list(A), is_list(B), length(A) =:= length(B) ->
    lists:all(fun({X, Y}) -> equal(X, Y) end, lists:zip(A, B));
equal(A, B) when is_map(A), is_map(B) ->
    lists:sort(maps:keys(A)) =:= lists:sort(maps:keys(B))
        andalso lists:all(fun(K) -> equal(maps:get(K, A), maps:get(K, B)) end, maps:keys(A));
equal(A, B) -> A =:= B.

well_behaved(B) ->
    case evatar_json:decode(B) of
        {ok, _} -> true;
        {error, {Code, Offset}} when is_atom(Code), is_integer(Offset), Offset >= 0,
                                     Offset =< byte_size(B) -> true
    end.

%% Puts whitespace after structural characters outside strings.
spread(Text, []) ->
    Text;
spread(Text, Ws) ->
    spread(Text, Ws, false, []).

spread(<<>>, _Ws, _InString, Acc) ->
    iolist_to_binary(lists:reverse(Acc));
spread(<<$\\, C, Rest/binary>>, Ws, true, Acc) ->
    spread(Rest, Ws, true, [<<$\\, C>> | Acc]);
spread(<<$", Rest/binary>>, Ws, InString, Acc) ->
    spread(Rest, Ws, not InString, [$" | Acc]);
spread(<<C, Rest/binary>>, [W | Ws], false, Acc) when C =:= $[; C =:= ${; C =:= $,; C =:= $: ->
    spread(Rest, Ws ++ [W], false, [W, C | Acc]);
spread(<<C, Rest/binary>>, Ws, InString, Acc) ->
    spread(Rest, Ws, InString, [C | Acc]).

mutate(Text, []) ->
    Text;
mutate(<<>>, _) ->
    <<>>;
mutate(Text, [{Op, Pos0, Byte} | Rest]) ->
    Pos = Pos0 rem byte_size(Text),
    <<Before:Pos/binary, At, After/binary>> = Text,
    Next = case Op of
               flip -> <<Before/binary, (At bxor (Byte bor 1)), After/binary>>;
               cut -> Before;
               insert -> <<Before/binary, Byte, At, After/binary>>
           end,
    mutate(Next, Rest).

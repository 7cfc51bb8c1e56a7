%% Common Test suite of the MQTT Avatar's JSON codec: PropEr round trip
%% and robustness properties (random and mutated bytes give an error,
%% never an exception), and the RFC 8259 cases that must be refused.
-module(mqtt_avatar_json_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("proper/include/proper.hrl").

-compile([export_all, nowarn_export_all]).

suite() -> [{timetrap, {seconds, 120}}].

all() ->
    [round_trip, whitespace_is_ignored, random_bytes_never_crash, mutated_json_never_crash,
     refused_documents, accepted_documents, no_atoms_from_input, limits].

numtests() ->
    case os:getenv("EVATAR_LONG_TESTS") of
        false -> 300;
        _ -> 5000
    end.

%% @doc Every JSON value the encoder writes decodes to the same value.
round_trip(_Config) ->
    P = ?FORALL(V, json(),
                begin
                    Text = iolist_to_binary(mqtt_avatar_json:encode(V)),
                    {ok, V1} = mqtt_avatar_json:decode(Text),
                    equal(V, V1)
                end),
    ok = evatar_test_proper:check(P, numtests()).

%% @doc Whitespace between tokens does not change the value.
whitespace_is_ignored(_Config) ->
    P = ?FORALL({V, Ws}, {json(), list(oneof([<<" ">>, <<"\n">>, <<"\t">>, <<"\r">>]))},
                begin
                    Text = iolist_to_binary(mqtt_avatar_json:encode(V)),
                    Spaced = spread(Text, Ws),
                    {ok, V1} = mqtt_avatar_json:decode(Spaced),
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
                    Text = iolist_to_binary(mqtt_avatar_json:encode(V)),
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
           binary:copy(<<"9">>, 100)],
    [] = [{B, R} || B <- Bad, R <- [mqtt_avatar_json:decode(B)],
                    not (element(1, R) =:= error andalso is_atom(element(1, element(2, R))))],
    <<"invalid JSON at byte 3: unexpected character">> =
        mqtt_avatar_json:format_error(element(2, mqtt_avatar_json:decode(<<"[1,]">>))).

%% @doc What devices actually send decodes as expected.
accepted_documents(_Config) ->
    {ok, #{<<"state">> := <<"ON">>, <<"brightness">> := 254, <<"color">> := #{<<"x">> := 0.5}}} =
        mqtt_avatar_json:decode(<<" {\"state\":\"ON\",\"brightness\":254,\"color\":{\"x\":0.5}} ">>),
    {ok, [true, false, null, -0.0, 1.0e-7, 12345678901234567890]} =
        mqtt_avatar_json:decode(<<"[true,false,null,-0.0,1E-7,12345678901234567890]">>),
    {ok, <<"é😀/\"\\\b\f\n\r\t"/utf8>>} =
        mqtt_avatar_json:decode(<<"\"\\u00e9\\ud83d\\ude00\\/\\\"\\\\\\b\\f\\n\\r\\t\"">>),
    {ok, <<"21.5">>} = {ok, mqtt_avatar_json:to_text(element(2, mqtt_avatar_json:decode(<<"21.5">>)))},
    {ok, 7} = mqtt_avatar_json:get_path([<<"a">>, <<"1">>, <<"b">>],
                                        element(2, mqtt_avatar_json:decode(
                                                     <<"{\"a\":[{},{\"b\":7}]}">>))),
    error = mqtt_avatar_json:get_path([<<"a">>, <<"5">>], #{<<"a">> => [1]}).

%% @doc Keys that happen to be atom names stay binaries, and decoding
%% never creates an atom.
no_atoms_from_input(_Config) ->
    Before = erlang:system_info(atom_count),
    Keys = [iolist_to_binary(["evatar_never_an_atom_", integer_to_list(I)]) || I <- lists:seq(1, 200)],
    Doc = iolist_to_binary(mqtt_avatar_json:encode(maps:from_list([{K, K} || K <- Keys]))),
    {ok, M} = mqtt_avatar_json:decode(Doc),
    true = lists:all(fun is_binary/1, maps:keys(M)),
    Before = erlang:system_info(atom_count),
    {ok, #{<<"ok">> := true}} = mqtt_avatar_json:decode(<<"{\"ok\":true}">>).

%% @doc Depth and size limits are enforced before any damage is done.
limits(_Config) ->
    Deep = iolist_to_binary([binary:copy(<<"[">>, 100), binary:copy(<<"]">>, 100)]),
    {error, {too_deep, _}} = mqtt_avatar_json:decode(Deep),
    {ok, _} = mqtt_avatar_json:decode(Deep, #{max_depth => 200}),
    {error, {too_large, 0}} = mqtt_avatar_json:decode(<<"[1,2,3]">>, #{max_size => 3}).

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
    case mqtt_avatar_json:decode(B) of
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

%% @doc Internal. A small JSON codec (RFC 8259) for MQTT payloads and
%% discovery messages, since OTP 25 has no json module. Objects decode to
%% maps with binary keys, arrays to lists, strings to UTF-8 binaries, and
%% `true', `false', `null' to those three atoms: no atom is ever made from
%% input. Decoding never raises; it returns `{error, Reason}' with the byte
%% offset of the problem.
-module(mqtt_avatar_json).

-export([decode/1, decode/2, encode/1, get_path/2, to_text/1, format_error/1]).

-export_type([json/0, error_reason/0, opts/0]).

-type json() :: #{binary() => json()} | [json()] | binary() | number()
              | true | false | null.
-type error_reason() :: {Code :: atom(), Offset :: non_neg_integer()}.
-type opts() :: #{max_depth => pos_integer(), max_size => pos_integer()}.

-define(MAX_DEPTH, 64).
-define(MAX_SIZE, 1048576).
%% Digits beyond this make a number an error rather than a huge bignum.
-define(MAX_NUMBER, 64).

-define(IS_WS(C), (C =:= $\s orelse C =:= $\t orelse C =:= $\n orelse C =:= $\r)).
-define(IS_DIGIT(C), (C >= $0 andalso C =< $9)).

%% ---------------------------------------------------------------------------
%% API
%% ---------------------------------------------------------------------------

%% @doc Decodes one JSON text (surrounding whitespace allowed), with the
%% default limits: 1 MiB, nesting depth 64.
-spec decode(binary()) -> {ok, json()} | {error, error_reason()}.
decode(Bin) ->
    decode(Bin, #{}).

%% @doc Decodes with explicit `max_depth' and `max_size'.
-spec decode(binary(), opts()) -> {ok, json()} | {error, error_reason()}.
decode(Bin, Opts) when is_binary(Bin) ->
    case byte_size(Bin) > maps:get(max_size, Opts, ?MAX_SIZE) of
        true ->
            {error, {too_large, 0}};
        false ->
            Depth = maps:get(max_depth, Opts, ?MAX_DEPTH),
            try
                {Value, Rest} = value(skip_ws(Bin), Bin, Depth),
                case skip_ws(Rest) of
                    <<>> -> {ok, Value};
                    More -> {error, {trailing_data, offset(Bin, More)}}
                end
            catch
                throw:{json_error, Code, Rest1} -> {error, {Code, offset(Bin, Rest1)}}
            end
    end;
decode(_, _) ->
    {error, {not_binary, 0}}.

%% @doc Encodes a term built by a program. Object keys may be binaries or
%% atoms; strings must be UTF-8 binaries. Raises `badarg' on anything else
%% (a program error, not input).
-spec encode(json() | #{atom() => json()}) -> iodata().
encode(true) -> <<"true">>;
encode(false) -> <<"false">>;
encode(null) -> <<"null">>;
encode(I) when is_integer(I) -> integer_to_binary(I);
encode(F) when is_float(F) -> float_to_binary(F, [short]);
encode(B) when is_binary(B) -> string(B);
encode(L) when is_list(L) -> [$[, join([encode(V) || V <- L]), $]];
encode(M) when is_map(M) ->
    Pairs = [[string(key(K)), $:, encode(V)] || {K, V} <- lists:sort(maps:to_list(M))],
    [${, join(Pairs), $}];
encode(Other) -> error(badarg, [Other]).

%% @doc Looks up a path of object keys (array elements by decimal index)
%% in a decoded value.
-spec get_path([binary()], json()) -> {ok, json()} | error.
get_path([], V) ->
    {ok, V};
get_path([K | Rest], M) when is_map(M) ->
    case maps:find(K, M) of
        {ok, V} -> get_path(Rest, V);
        error -> error
    end;
get_path([K | Rest], L) when is_list(L) ->
    case string:to_integer(K) of
        {I, <<>>} when I >= 0, I < length(L) -> get_path(Rest, lists:nth(I + 1, L));
        _ -> error
    end;
get_path(_, _) ->
    error.

%% @doc A value as the text a BIL parameter carries: strings as they are,
%% numbers and literals written as in JSON, objects and arrays encoded.
-spec to_text(json()) -> binary().
to_text(B) when is_binary(B) -> B;
to_text(V) -> iolist_to_binary(encode(V)).

%% @doc One line for a person.
-spec format_error(error_reason()) -> binary().
format_error({too_large, _}) ->
    %% Valid or not, it was not read: no byte offset.
    <<"the payload is over the size limit of JSON decoding (1 MiB unless raised), not read">>;
format_error({Code, Offset}) ->
    Text = case Code of
               not_binary -> "not a binary";
               unexpected_end -> "the text ends before the JSON value does";
               unexpected_char -> "unexpected character";
               trailing_data -> "data after the JSON value";
               too_deep -> "arrays or objects nested too deep";
               bad_number -> "malformed or out-of-range number";
               bad_escape -> "malformed escape in a string";
               bad_utf8 -> "a string is not valid UTF-8";
               control_char -> "unescaped control character in a string";
               _ -> atom_to_list(Code)
           end,
    iolist_to_binary(io_lib:format("invalid JSON at byte ~b: ~s", [Offset, Text])).

%% ---------------------------------------------------------------------------
%% Decoder
%% ---------------------------------------------------------------------------

offset(Whole, Rest) -> byte_size(Whole) - byte_size(Rest).

-spec fail(atom(), binary()) -> no_return().
fail(Code, Rest) -> throw({json_error, Code, Rest}).

skip_ws(<<C, Rest/binary>>) when ?IS_WS(C) -> skip_ws(Rest);
skip_ws(Bin) -> Bin.

value(Bin, _, 0) -> fail(too_deep, Bin);
value(<<${, Rest/binary>>, Whole, Depth) -> object(skip_ws(Rest), Whole, Depth - 1, #{});
value(<<$[, Rest/binary>>, Whole, Depth) -> array(skip_ws(Rest), Whole, Depth - 1, []);
value(<<$", Rest/binary>>, _Whole, _Depth) -> string_body(Rest, []);
value(<<"true", Rest/binary>>, _, _) -> {true, Rest};
value(<<"false", Rest/binary>>, _, _) -> {false, Rest};
value(<<"null", Rest/binary>>, _, _) -> {null, Rest};
value(<<C, _/binary>> = Bin, _, _) when C =:= $-; ?IS_DIGIT(C) -> number(Bin);
value(<<>>, _, _) -> fail(unexpected_end, <<>>);
value(Bin, _, _) -> fail(unexpected_char, Bin).

object(<<$}, Rest/binary>>, _Whole, _Depth, Acc) ->
    {Acc, Rest};
object(Bin, Whole, Depth, Acc) ->
    case Bin of
        <<$", Rest/binary>> ->
            {Key, Rest1} = string_body(Rest, []),
            case skip_ws(Rest1) of
                <<$:, Rest2/binary>> ->
                    {Value, Rest3} = value(skip_ws(Rest2), Whole, Depth),
                    Acc1 = Acc#{Key => Value},
                    case skip_ws(Rest3) of
                        <<$,, Rest4/binary>> -> object_key(skip_ws(Rest4), Whole, Depth, Acc1);
                        <<$}, Rest4/binary>> -> {Acc1, Rest4};
                        <<>> -> fail(unexpected_end, <<>>);
                        Other -> fail(unexpected_char, Other)
                    end;
                <<>> -> fail(unexpected_end, <<>>);
                Other -> fail(unexpected_char, Other)
            end;
        <<>> -> fail(unexpected_end, <<>>);
        Other -> fail(unexpected_char, Other)
    end.

%% After a comma a key must follow (no trailing comma).
object_key(<<$}, _/binary>> = Bin, _, _, _) -> fail(unexpected_char, Bin);
object_key(Bin, Whole, Depth, Acc) -> object(Bin, Whole, Depth, Acc).

array(<<$], Rest/binary>>, _Whole, _Depth, []) ->
    {[], Rest};
array(Bin, Whole, Depth, Acc) ->
    {Value, Rest} = value(Bin, Whole, Depth),
    case skip_ws(Rest) of
        <<$,, Rest1/binary>> -> array(skip_ws(Rest1), Whole, Depth, [Value | Acc]);
        <<$], Rest1/binary>> -> {lists:reverse([Value | Acc]), Rest1};
        <<>> -> fail(unexpected_end, <<>>);
        Other -> fail(unexpected_char, Other)
    end.

string_body(Bin, Acc) ->
    case scan_plain(Bin, 0) of
        {N, <<$", Rest/binary>>} ->
            <<Plain:N/binary, _/binary>> = Bin,
            {finish_string([Acc, Plain], Bin), Rest};
        {N, <<$\\, Esc/binary>> = At} ->
            <<Plain:N/binary, _/binary>> = Bin,
            {Char, Rest} = escape(Esc, At),
            string_body(Rest, [Acc, Plain, Char]);
        {_N, <<C, _/binary>> = At} when C < 16#20 ->
            fail(control_char, At);
        {_N, <<>>} ->
            fail(unexpected_end, <<>>)
    end.

scan_plain(Bin, N) ->
    case Bin of
        <<_:N/binary, C, _/binary>> when C =/= $", C =/= $\\, C >= 16#20 -> scan_plain(Bin, N + 1);
        <<_:N/binary, Rest/binary>> -> {N, Rest}
    end.

finish_string(IoData, At) ->
    Bin = iolist_to_binary(IoData),
    case unicode:characters_to_binary(Bin) of
        Bin -> Bin;
        _ -> fail(bad_utf8, At)
    end.

escape(<<$", R/binary>>, _) -> {<<$">>, R};
escape(<<$\\, R/binary>>, _) -> {<<$\\>>, R};
escape(<<$/, R/binary>>, _) -> {<<$/>>, R};
escape(<<$b, R/binary>>, _) -> {<<8>>, R};
escape(<<$f, R/binary>>, _) -> {<<12>>, R};
escape(<<$n, R/binary>>, _) -> {<<10>>, R};
escape(<<$r, R/binary>>, _) -> {<<13>>, R};
escape(<<$t, R/binary>>, _) -> {<<9>>, R};
escape(<<$u, H:4/binary, R/binary>>, At) ->
    case hex(H, At) of
        Hi when Hi >= 16#D800, Hi =< 16#DBFF ->
            case R of
                <<$\\, $u, L:4/binary, R1/binary>> ->
                    case hex(L, At) of
                        Lo when Lo >= 16#DC00, Lo =< 16#DFFF ->
                            Cp = 16#10000 + ((Hi - 16#D800) bsl 10) + (Lo - 16#DC00),
                            {<<Cp/utf8>>, R1};
                        _ -> fail(bad_escape, At)
                    end;
                _ -> fail(bad_escape, At)
            end;
        Lo when Lo >= 16#DC00, Lo =< 16#DFFF ->
            fail(bad_escape, At);
        Cp ->
            {<<Cp/utf8>>, R}
    end;
escape(_, At) ->
    fail(bad_escape, At).

hex(H, At) ->
    lists:foldl(fun(C, N) -> N * 16 + hex_digit(C, At) end, 0, binary_to_list(H)).

hex_digit(C, _) when ?IS_DIGIT(C) -> C - $0;
hex_digit(C, _) when C >= $a, C =< $f -> C - $a + 10;
hex_digit(C, _) when C >= $A, C =< $F -> C - $A + 10;
hex_digit(_, At) -> fail(bad_escape, At).

number(Bin) ->
    {Sign, R0} = case Bin of
                     <<$-, AfterSign/binary>> -> {<<"-">>, AfterSign};
                     _ -> {<<>>, Bin}
                 end,
    {Int, R1} = case R0 of
                    <<$0, AfterZero/binary>> -> {<<"0">>, AfterZero};
                    <<C, _/binary>> when ?IS_DIGIT(C) -> digits(R0);
                    _ -> fail(bad_number, R0)
                end,
    {Frac, R2} = case R1 of
                     <<$., AfterDot/binary>> ->
                         case digits(AfterDot) of
                             {<<>>, _} -> fail(bad_number, AfterDot);
                             FracDigits -> FracDigits
                         end;
                     _ -> {undefined, R1}
                 end,
    {Exp, R4} = case R2 of
                    <<E, AfterE/binary>> when E =:= $e; E =:= $E ->
                        {ESign, R6} = case AfterE of
                                          <<S, AfterES/binary>> when S =:= $+; S =:= $- ->
                                              {<<S>>, AfterES};
                                          _ -> {<<>>, AfterE}
                                      end,
                        case digits(R6) of
                            {<<>>, _} -> fail(bad_number, R6);
                            {ED, R8} -> {<<ESign/binary, ED/binary>>, R8}
                        end;
                    _ -> {undefined, R2}
                end,
    case byte_size(Bin) - byte_size(R4) > ?MAX_NUMBER of
        true -> fail(bad_number, Bin);
        false -> ok
    end,
    case {Frac, Exp} of
        {undefined, undefined} ->
            {binary_to_integer(<<Sign/binary, Int/binary>>), R4};
        _ ->
            FracText = case Frac of undefined -> <<"0">>; _ -> Frac end,
            ExpText = case Exp of undefined -> <<"0">>; _ -> Exp end,
            Text = <<Sign/binary, Int/binary, ".", FracText/binary, "e", ExpText/binary>>,
            try {binary_to_float(Text), R4}
            catch error:badarg -> fail(bad_number, Bin)
            end
    end.

digits(Bin) -> digits(Bin, 0).

digits(Bin, N) ->
    case Bin of
        <<_:N/binary, C, _/binary>> when ?IS_DIGIT(C) -> digits(Bin, N + 1);
        <<D:N/binary, Rest/binary>> -> {D, Rest}
    end.

%% ---------------------------------------------------------------------------
%% Encoder
%% ---------------------------------------------------------------------------

key(K) when is_binary(K) -> K;
key(K) when is_atom(K) -> atom_to_binary(K);
key(K) -> error(badarg, [K]).

join([]) -> [];
join([H | T]) -> [H | [[$, | X] || X <- T]].

string(B) ->
    [$", escape_string(B, 0, B, []), $"].

%% Copies runs of plain bytes and escapes `"', `\' and control characters.
escape_string(Bin, N, Orig, Acc) ->
    case Bin of
        <<_:N/binary, C, _/binary>> when C =:= $"; C =:= $\\; C < 16#20 ->
            <<Run:N/binary, _, Rest/binary>> = Bin,
            escape_string(Rest, 0, Orig, [Acc, Run, escape_char(C)]);
        <<_:N/binary, _, _/binary>> ->
            escape_string(Bin, N + 1, Orig, Acc);
        _ ->
            [Acc, Bin]
    end.

escape_char($") -> <<"\\\"">>;
escape_char($\\) -> <<"\\\\">>;
escape_char($\n) -> <<"\\n">>;
escape_char($\r) -> <<"\\r">>;
escape_char($\t) -> <<"\\t">>;
escape_char(C) -> io_lib:format("\\u~4.16.0b", [C]).

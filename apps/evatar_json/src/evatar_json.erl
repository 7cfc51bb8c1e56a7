%% @doc JSON for every app of the node, through Debian's erlang-jiffy (OTP 25
%% has no json module): MQTT payloads and discovery messages, WoT bodies and
%% Thing Descriptions, the simulated devices' messages, the HTTP API. A
%% library application of its own so that the device side and the HTTP side
%% share it without depending on each other.
%%
%% Objects decode to maps with binary keys (jiffy's `return_maps': no atom
%% is ever made from input), arrays to lists, strings to UTF-8 binaries,
%% `true', `false' and `null' to those atoms. Decoding never raises: bad
%% input is `{error, {Code, Offset}}', and format_error/1 says it for a
%% person. Before jiffy reads a text it must be within `max_size' (1 MiB
%% unless raised) and hold no number of more than 1,024 digits in a row
%% (jiffy would turn a million digits into a bignum for seconds; what
%% devices send has at most 20); after, its arrays and objects must nest at
%% most `max_depth' deep (64 unless raised).
-module(evatar_json).

-export([decode/1, decode/2, encode/1, get_path/2, to_text/1, format_error/1]).

-export_type([json/0, error_reason/0, opts/0]).

-type json() :: #{binary() => json()} | [json()] | binary() | number()
              | true | false | null.
-type error_reason() :: {Code :: atom(), Offset :: non_neg_integer()}.
-type opts() :: #{max_depth => pos_integer(), max_size => pos_integer()}.

-define(MAX_DEPTH, 64).
-define(MAX_SIZE, 1048576).

%% @doc Decodes one JSON text (surrounding whitespace allowed), with the
%% default limits: 1 MiB, nesting depth 64.
-spec decode(binary()) -> {ok, json()} | {error, error_reason()}.
decode(Bin) ->
    decode(Bin, #{}).

%% @doc Decodes with explicit `max_depth' and `max_size'.
-spec decode(binary(), opts()) -> {ok, json()} | {error, error_reason()}.
decode(Bin, Opts) when is_binary(Bin) ->
    case byte_size(Bin) > maps:get(max_size, Opts, ?MAX_SIZE) of
        true -> {error, {too_large, 0}};
        false ->
            case long_number(Bin) of
                {yes, Offset} -> {error, {bad_number, Offset}};
                no -> jiffy_decode(Bin, maps:get(max_depth, Opts, ?MAX_DEPTH))
            end
    end;
decode(_, _) ->
    {error, {not_binary, 0}}.

%% @doc Encodes a term built by a program: maps with binary or atom keys,
%% lists, binaries, numbers, `true', `false', `null' (other atoms as
%% strings). Text that is not UTF-8 is replaced, not refused: what a node
%% sends or shows must not crash it. Raises on a term that has no JSON form
%% (a program error, not input).
-spec encode(term()) -> binary().
encode(Term) ->
    iolist_to_binary(jiffy:encode(Term, [force_utf8])).

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
%% numbers as Erlang writes them shortest (`21.5', `1.0e-7'), literals,
%% objects and arrays encoded.
-spec to_text(json()) -> binary().
to_text(B) when is_binary(B) -> B;
to_text(I) when is_integer(I) -> integer_to_binary(I);
to_text(F) when is_float(F) -> float_to_binary(F, [short]);
to_text(V) -> encode(V).

%% @doc One line for a person.
-spec format_error(error_reason()) -> binary().
format_error({too_large, _}) ->
    %% Valid or not, it was not read: no byte offset.
    <<"the payload is over the size limit of JSON decoding (1 MiB unless raised), not read">>;
format_error({number_out_of_range, _}) ->
    <<"invalid JSON: a number is out of the range of a double">>;
format_error({Code, Offset}) ->
    Text = case Code of
               not_binary -> "not a binary";
               unexpected_end -> "the text ends before the JSON value does";
               unexpected_char -> "unexpected character";
               trailing_data -> "data after the JSON value";
               too_deep -> "arrays or objects nested too deep";
               bad_number -> "malformed number, or one of more than 1024 digits";
               bad_string -> "malformed string (a bad escape, a control character or not UTF-8)";
               _ -> atom_to_list(Code)
           end,
    iolist_to_binary(io_lib:format("invalid JSON at byte ~b: ~s", [Offset, Text])).

%% ---------------------------------------------------------------------------
%% Internal
%% ---------------------------------------------------------------------------

jiffy_decode(Bin, MaxDepth) ->
    try jiffy:decode(Bin, [return_maps]) of
        Value ->
            case byte_size(Bin) =< MaxDepth orelse depth_within(Value, MaxDepth) of
                true -> {ok, Value};
                false -> {error, {too_deep, 0}}
            end
    catch
        %% jiffy's positions count from 1.
        error:{Pos, Why} when is_integer(Pos), is_atom(Why) -> {error, {code(Why), max(Pos - 1, 0)}};
        %% A number whose exponent takes it past a double, found after the
        %% parse: jiffy does not say where.
        error:{range, _} -> {error, {number_out_of_range, 0}}
    end.

code(truncated_json) -> unexpected_end;
code(invalid_trailing_data) -> trailing_data;
code(invalid_number) -> bad_number;
code(invalid_string) -> bad_string;
code(_) -> unexpected_char.

%% Whether arrays and objects nest at most Max deep (a scalar at the top is
%% depth 0, `[]' depth 1).
depth_within(V, Max) when is_map(V) ->
    Max > 0 andalso lists:all(fun(E) -> depth_within(E, Max - 1) end, maps:values(V));
depth_within(V, Max) when is_list(V) ->
    Max > 0 andalso lists:all(fun(E) -> depth_within(E, Max - 1) end, V);
depth_within(_, _) ->
    true.

%% The offset of the first run of more than 1,024 digits outside a string,
%% if any: none in a shorter text, so the frequent small payloads are not
%% scanned. A run inside a string is text, harmless; which side of a string
%% a run is on is asked only when there is one (rarely), counting the
%% unescaped quotes from one run to the next (a run's first byte is a digit,
%% so no escape spans two segments).
long_number(Bin) when byte_size(Bin) =< 1024 ->
    no;
long_number(Bin) ->
    case re:run(Bin, "[0-9]{1025}", [global, {capture, first, index}]) of
        nomatch -> no;
        {match, Runs} -> outside_string([P || [{P, _}] <- Runs], 0, 0, Bin)
    end.

outside_string([], _, _, _) ->
    no;
outside_string([P | Rest], From, Quotes0, Bin) ->
    Quotes = Quotes0 + quotes(binary:part(Bin, From, P - From)),
    case Quotes rem 2 of
        0 -> {yes, P};
        1 -> outside_string(Rest, P, Quotes, Bin)
    end.

%% Quotes not escaped: after an even number of backslashes.
quotes(Segment) ->
    case re:run(Segment, "(?<!\\\\)(?:\\\\\\\\)*\"", [global, {capture, first, index}]) of
        nomatch -> 0;
        {match, Found} -> length(Found)
    end.

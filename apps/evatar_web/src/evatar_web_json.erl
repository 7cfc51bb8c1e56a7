%% @doc Internal. JSON through Debian's erlang-jiffy: objects are maps with
%% binary keys, strings binaries, `null' the atom. Decoding input never
%% crashes: bad input is `{error, {bad_json, Why}}'. Decoding returns maps
%% (`return_maps'), so keys stay binaries and no atom is made from input.
%% OTP 25 has no `json' module; jiffy is a small NIF library packaged by
%% Debian, and the release ships it (lib/jiffy-1.1.1 with its
%% priv/jiffy.so).
-module(evatar_web_json).

-export([encode/1, decode/1]).

%% @doc Encodes a JSON-ready term (maps with atom or binary keys, lists,
%% binaries, numbers, true/false/null, other atoms as strings). Text that is
%% not UTF-8 is replaced, not refused: what a node shows must not crash it.
-spec encode(term()) -> binary().
encode(Term) ->
    iolist_to_binary(jiffy:encode(Term, [force_utf8])).

%% @doc Decodes a request body; never creates an atom (keys stay binaries).
-spec decode(binary()) -> {ok, term()} | {error, {bad_json, binary()}}.
decode(Bin) when is_binary(Bin) ->
    try jiffy:decode(Bin, [return_maps, dedupe_keys]) of
        {has_trailer, _, _} -> {error, {bad_json, <<"text after the JSON value">>}};
        Term -> {ok, Term}
    catch
        throw:{error, {Pos, Why}} when is_integer(Pos) ->
            {error, {bad_json, iolist_to_binary(io_lib:format("~ts at byte ~b", [why(Why), Pos]))}};
        throw:{error, Why} ->
            {error, {bad_json, iolist_to_binary(why(Why))}};
        error:_ ->
            {error, {bad_json, <<"not JSON">>}}
    end.

why(A) when is_atom(A) -> string:replace(atom_to_list(A), "_", " ", all);
why(Other) -> io_lib:format("~0tp", [Other]).

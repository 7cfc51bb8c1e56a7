%% @doc Internal. Reads a node configuration file: Erlang terms, each
%% `{Section, [Entry, ...]}.', with the line of every entry, and without
%% creating an atom the file spells (a first pass finds every atom; each
%% must be a known word or already exist). node_config_check decides what
%% the entries mean.
-module(node_config_file).

-export([read/2, parse/2]).

-export_type([section/0]).

%% A section: its name, its line, and its entries with their lines. A
%% value that is not a list is one entry at the section's line, marked
%% `not_a_list'.
-type section() :: {atom(), pos_integer(), [{pos_integer(), term()}] | {not_a_list, term()}}.

%% @doc Reads and parses `File'; `Known' are the words (keys and values) the
%% file may use besides atoms that already exist.
-spec read(file:filename(), [atom()]) -> {ok, [section()]} | {error, binary()}.
read(File, Known) ->
    case file:read_file(File) of
        {ok, Bin} ->
            case unicode:characters_to_list(Bin) of
                Text when is_list(Text) -> parse(Text, Known);
                _ -> {error, <<"not UTF-8 text">>}
            end;
        {error, Reason} ->
            {error, iolist_to_binary(["cannot be read: ", file:format_error(Reason)])}
    end.

%% @doc Parses the text of a configuration file.
-spec parse(string(), [atom()]) -> {ok, [section()]} | {error, binary()}.
parse(Text, Known) ->
    KnownNames = [atom_to_list(A) || A <- Known],
    case [{L, W} || {L, W} <- atoms(Text, 1, []), not lists:member(W, KnownNames),
                    not exists(W)] of
        [] ->
            case erl_scan:string(Text, 1) of
                {ok, Tokens, _} ->
                    Groups = split(Tokens, []),
                    case lists:reverse(lists:append(Groups)) of
                        [] ->
                            {ok, []};
                        [{dot, _} | _] ->
                            sections(Groups, []);
                        [Last | _] ->
                            First = hd(lists:last(Groups)),
                            {error, at(erl_anno:line(element(2, Last)),
                                       io_lib:format("the file ends inside the entry that starts at "
                                                     "line ~b: a }, ] or the final full stop is missing",
                                                     [erl_anno:line(element(2, First))]))}
                    end;
                {error, {L, M, D}, _} -> {error, at(L, M:format_error(D))}
            end;
        [{L, W} | _] ->
            {error, at(L, io_lib:format("unknown word ~ts (keys are plain words like port; text goes in "
                                        "double quotes: \"~ts\")", [W, W]))}
    end.

exists(Name) ->
    try list_to_existing_atom(Name) of
        _ -> true
    catch error:badarg -> false
    end.

%% The atoms of an Erlang text, with their lines, as strings: unquoted words
%% starting with a lower-case letter, and quoted ones. Strings, comments,
%% character literals, variables and numbers are skipped.
atoms([], _L, Acc) -> lists:reverse(Acc);
atoms([$\n | T], L, Acc) -> atoms(T, L + 1, Acc);
atoms([$% | T], L, Acc) -> atoms(lists:dropwhile(fun(C) -> C =/= $\n end, T), L, Acc);
atoms([$" | T], L, Acc) ->
    {_, T1, L1} = quoted($", T, L, []),
    atoms(T1, L1, Acc);
atoms([$' | T], L, Acc) ->
    {Name, T1, L1} = quoted($', T, L, []),
    atoms(T1, L1, [{L, Name} | Acc]);
atoms([$$, $\\, _ | T], L, Acc) -> atoms(T, L, Acc);
atoms([$$, $\n | T], L, Acc) -> atoms(T, L + 1, Acc);
atoms([$$, _ | T], L, Acc) -> atoms(T, L, Acc);
atoms([C | T], L, Acc) ->
    case kind(C) of
        lower ->
            {Word, T1} = lists:splitwith(fun(X) -> kind(X) =/= other end, T),
            atoms(T1, L, [{L, [C | Word]} | Acc]);
        Skip when Skip =:= upper; Skip =:= digit ->
            atoms(lists:dropwhile(fun(X) -> kind(X) =/= other end, T), L, Acc);
        other ->
            atoms(T, L, Acc)
    end.

quoted(_Q, [], L, Acc) -> {lists:reverse(Acc), [], L};
quoted(Q, [Q | T], L, Acc) -> {lists:reverse(Acc), T, L};
quoted(Q, [$\\, C | T], L, Acc) -> quoted(Q, T, L + newline(C), [C | Acc]);
quoted(Q, [C | T], L, Acc) -> quoted(Q, T, L + newline(C), [C | Acc]).

newline($\n) -> 1;
newline(_) -> 0.

kind(C) when C >= $a, C =< $z; C >= 223, C =< 255, C =/= 247 -> lower;
kind(C) when C >= $A, C =< $Z; C =:= $_; C >= 192, C =< 222, C =/= 215 -> upper;
kind(C) when C >= $0, C =< $9 -> digit;
kind($@) -> upper;
kind(_) -> other.

split([], []) -> [];
split([], Acc) -> [lists:reverse(Acc)];
split([{dot, _} = Dot | T], Acc) -> [lists:reverse([Dot | Acc]) | split(T, [])];
split([Tok | T], Acc) -> split(T, [Tok | Acc]).

sections([], Acc) ->
    {ok, lists:reverse(Acc)};
sections([Tokens | Rest], Acc) ->
    L = erl_anno:line(element(2, hd(Tokens))),
    case erl_parse:parse_exprs(Tokens) of
        {ok, [{tuple, TL, [{atom, _, Name}, Value]}]} ->
            case entries(Value) of
                {ok, Entries} -> sections(Rest, [{Name, erl_anno:line(TL), Entries} | Acc]);
                {error, EL} -> {error, at(EL, "only plain values here (text, numbers, words, "
                                          "lists, tuples, maps), no variables or calls")}
            end;
        {ok, _} ->
            {error, at(L, "each entry of the file is {section, [...]}., for example "
                          "{pairings, [#{id => \"home\", ...}]}.")};
        {error, {EL, M, D}} ->
            {error, at(EL, M:format_error(D))}
    end.

entries({nil, _}) ->
    {ok, []};
entries({cons, _, _, _} = Cons) ->
    cons(Cons, []);
entries(Expr) ->
    case value(Expr) of
        {ok, V} -> {ok, {not_a_list, V}};
        Error -> Error
    end.

cons({nil, _}, Acc) ->
    {ok, lists:reverse(Acc)};
cons({cons, _, H, T}, Acc) ->
    case value(H) of
        {ok, V} -> cons(T, [{erl_anno:line(element(2, H)), V} | Acc]);
        Error -> Error
    end;
cons(Tail, _Acc) ->
    {error, erl_anno:line(element(2, Tail))}.

value(Expr) ->
    try {ok, erl_parse:normalise(Expr)}
    catch _:_ -> {error, erl_anno:line(element(2, Expr))}
    end.

at(Line, Message) ->
    iolist_to_binary(io_lib:format("line ~b: ~ts", [loc_line(Line), Message])).

loc_line({L, _}) -> L;
loc_line(L) -> L.

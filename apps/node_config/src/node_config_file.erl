%% @doc Internal. Reads a node configuration file: Erlang terms, each
%% `{Section, [Entry, ...]}.', with the line of every entry, and without
%% creating an atom the file spells (a first pass finds every atom; each
%% must be a known word or already exist). node_config_check decides what
%% the entries mean.
-module(node_config_file).

-export([read/2, parse/2]).

-export_type([section/0, problem/0]).

%% The atom a word that is neither known nor an existing atom is replaced
%% with before erl_scan reads the text (rewrite/5).
-define(MARKER, '$evatar_unknown_word').
-define(MARKER_NAME, "$evatar_unknown_word").
%% Unknown words named at most (then "and N more unknown words").
-define(MAX_WORDS, 20).

%% A section: its name, its line, and its entries with their lines. A
%% value that is not a list is one entry at the section's line, marked
%% `not_a_list'.
%% A mistake and its line.
-type problem() :: {pos_integer(), binary()}.
-type section() :: {atom(), pos_integer(), [{pos_integer(), term()}] | {not_a_list, term()}}.

%% @doc Reads and parses `File'; `Known' are the words (keys and values) the
%% file may use besides atoms that already exist. A word neither known nor
%% an existing atom is a mistake (one of the returned problems, with its
%% line) and the reading goes on: in a map's key it is left out, as a value
%% it reads as the text it spells, so the checks still judge the rest of
%% its entry (and a value that would be wrong even as text). At most
%% ?MAX_WORDS such words are named.
-spec read(file:filename(), [atom()]) -> {ok, [section()], [problem()]} | {error, binary()}.
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

%% @doc Parses the text of a configuration file (read/2).
-spec parse(string(), [atom()]) -> {ok, [section()], [problem()]} | {error, binary()}.
parse(Text, Known) ->
    KnownNames = [atom_to_list(A) || A <- Known],
    IsKnown = fun(W) -> W =/= ?MARKER_NAME andalso (lists:member(W, KnownNames) orelse exists(W)) end,
    {Safe, Unknown} = rewrite(Text, 1, IsKnown, [], []),
    Problems = word_problems(Unknown),
    case erl_scan:string(Safe, 1) of
        {ok, Tokens, _} ->
            Groups = split(Tokens, []),
            case lists:reverse(lists:append(Groups)) of
                [] ->
                    {ok, [], Problems};
                [{dot, _} | _] ->
                    case sections(Groups, []) of
                        {ok, Sections} -> {ok, Sections, Problems};
                        {error, _} = Error -> Error
                    end;
                [Last | _] ->
                    First = hd(lists:last(Groups)),
                    {error, at(erl_anno:line(element(2, Last)),
                               io_lib:format("the file ends inside the entry that starts at "
                                             "line ~b: a }, ] or the final full stop is missing",
                                             [erl_anno:line(element(2, First))]))}
            end;
        {error, {L, M, D}, _} -> {error, at(L, M:format_error(D))}
    end.

word_problems(Unknown) ->
    Named = [{L, at(L, io_lib:format("unknown word ~ts (keys are plain words like port; text goes in "
                                     "double quotes: \"~ts\")", [W, W]))}
             || {L, W} <- lists:sublist(Unknown, ?MAX_WORDS)],
    case length(Unknown) - ?MAX_WORDS of
        More when More > 0 ->
            {L, _} = lists:nth(?MAX_WORDS + 1, Unknown),
            Named ++ [{L, at(L, io_lib:format("and ~b more unknown words", [More]))}];
        _ ->
            Named
    end.

exists(Name) ->
    try list_to_existing_atom(Name) of
        _ -> true
    catch error:badarg -> false
    end.

%% The text with every atom that is not a known word replaced by a
%% marker, {'$evatar_unknown_word', "word"} (then the same number of line
%% ends, for a quoted atom that spans lines), so that erl_scan makes no
%% atom the file spells; and those words, with their lines. Atoms are
%% unquoted words starting with a lower-case letter, and quoted ones (a
%% quoted one with a backslash is never taken as known: its escapes are
%% not decoded here). Strings, comments, character literals, variables and
%% numbers are copied as they are.
rewrite([], _L, _IsKnown, Out, Ws) ->
    {lists:reverse(Out), lists:reverse(Ws)};
rewrite([$\n | T], L, IsKnown, Out, Ws) ->
    rewrite(T, L + 1, IsKnown, [$\n | Out], Ws);
rewrite([$% | T], L, IsKnown, Out, Ws) ->
    {Comment, T1} = lists:splitwith(fun(C) -> C =/= $\n end, T),
    rewrite(T1, L, IsKnown, lists:reverse(Comment, [$% | Out]), Ws);
rewrite([$" | T], L, IsKnown, Out, Ws) ->
    {_, Raw, T1, L1} = quoted($", T, L, [], []),
    rewrite(T1, L1, IsKnown, lists:reverse(Raw, [$" | Out]), Ws);
rewrite([$' | T], L, IsKnown, Out, Ws) ->
    {Name, Raw, T1, L1} = quoted($', T, L, [], []),
    case not lists:member($\\, Raw) andalso IsKnown(Name) of
        true -> rewrite(T1, L1, IsKnown, lists:reverse(Raw, [$' | Out]), Ws);
        false -> rewrite(T1, L1, IsKnown, marker(Name, L1 - L, Out), [{L, Name} | Ws])
    end;
rewrite([$$, $\\, C | T], L, IsKnown, Out, Ws) ->
    rewrite(T, L + newline(C), IsKnown, [C, $\\, $$ | Out], Ws);
rewrite([$$, C | T], L, IsKnown, Out, Ws) ->
    rewrite(T, L + newline(C), IsKnown, [C, $$ | Out], Ws);
rewrite([C | T], L, IsKnown, Out, Ws) ->
    case kind(C) of
        lower ->
            {Word, T1} = lists:splitwith(fun(X) -> kind(X) =/= other end, T),
            Name = [C | Word],
            case IsKnown(Name) of
                true -> rewrite(T1, L, IsKnown, lists:reverse(Name, Out), Ws);
                false -> rewrite(T1, L, IsKnown, marker(Name, 0, Out), [{L, Name} | Ws])
            end;
        Skip when Skip =:= upper; Skip =:= digit ->
            {Word, T1} = lists:splitwith(fun(X) -> kind(X) =/= other end, T),
            rewrite(T1, L, IsKnown, lists:reverse([C | Word], Out), Ws);
        other ->
            rewrite(T, L, IsKnown, [C | Out], Ws)
    end.

marker(Name, Newlines, Out) ->
    Text = lists:flatten(io_lib:format("{'~ts',~tp}", [?MARKER_NAME, Name])),
    lists:duplicate(Newlines, $\n) ++ lists:reverse(Text, Out).

%% A quoted text: its characters (escapes taken loosely: only for the
%% known-word check), the raw text up to and with the closing quote, the
%% rest, the line after it.
quoted(_Q, [], L, Acc, Raw) -> {lists:reverse(Acc), lists:reverse(Raw), [], L};
quoted(Q, [Q | T], L, Acc, Raw) -> {lists:reverse(Acc), lists:reverse([Q | Raw]), T, L};
quoted(Q, [$\\, C | T], L, Acc, Raw) -> quoted(Q, T, L + newline(C), [C | Acc], [C, $\\ | Raw]);
quoted(Q, [C | T], L, Acc, Raw) -> quoted(Q, T, L + newline(C), [C | Acc], [C | Raw]).

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
        {ok, [{tuple, _, [{tuple, _, [{atom, _, ?MARKER}, _]}, _]}]} ->
            %% An unknown section's name, already named.
            sections(Rest, Acc);
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
    try erl_parse:normalise(Expr) of
        V -> {ok, unmark(V)}
    catch _:_ -> {error, erl_anno:line(element(2, Expr))}
    end.

%% An unknown word (already named): left out as a map's key, the text it
%% spells as a value, so that the checks judge the rest.
unmark({?MARKER, Name}) ->
    Name;
unmark(M) when is_map(M) ->
    maps:from_list([{unmark(K), unmark(V)} || {K, V} <- maps:to_list(M),
                                             not is_tuple(K) orelse element(1, K) =/= ?MARKER
                                                 orelse tuple_size(K) =/= 2]);
unmark(L) when is_list(L) ->
    unmark_list(L);
unmark(T) when is_tuple(T) ->
    list_to_tuple([unmark(E) || E <- tuple_to_list(T)]);
unmark(V) ->
    V.

%% A list, proper or not.
unmark_list([H | T]) -> [unmark(H) | unmark_list(T)];
unmark_list([]) -> [];
unmark_list(Tail) -> unmark(Tail).

at(Line, Message) ->
    iolist_to_binary(io_lib:format("line ~b: ~ts", [loc_line(Line), Message])).

loc_line({L, _}) -> L;
loc_line(L) -> L.

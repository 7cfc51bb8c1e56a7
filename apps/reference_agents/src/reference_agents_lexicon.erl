%% @doc Internal. The coordinator's lexicon, pure: from what each robot VA
%% anchored (symbol, colour approximation, position) it groups the
%% sightings that are the same object (same colour, close enough) and gives
%% each object one shared word, such as `red-ball', together with the local
%% symbol every agent uses for it. The lexicon is a plain value so that
%% three VAs can be shown to hold the same one.
-module(reference_agents_lexicon).

-export([build/1, words/1, local/3, word_for/3, entry/2, agreed/1, encode/1]).

-export_type([lexicon/0, entry/0, report/0]).

-type position() :: {number(), number()}.
%% One agent's description of what it anchored.
-type report() :: {Agent :: binary(),
                   [#{symbol := binary(), colour := binary(), position := position()}]}.
-type entry() :: #{word := binary(), colour := binary(), position := position(),
                   names := #{Agent :: binary() => Symbol :: binary()}}.
-type lexicon() :: [entry()].

%% Sightings of one colour further apart than this are different objects.
-define(SAME_OBJECT_MM, 400).

%% @doc Builds the lexicon, sorted by word. Objects are ordered by colour,
%% then position, so the same reports give the same words whatever order
%% they arrive in.
-spec build([report()]) -> lexicon().
build(Reports) ->
    Sightings = lists:sort([{reference_agents_activity:keyword(C), P, Agent, Sym, C}
                            || {Agent, Anchors} <- Reports,
                               #{symbol := Sym, colour := C, position := P} <- Anchors]),
    Groups = group(Sightings, []),
    ByColour = lists:foldl(fun(G, Acc) ->
                                   {K, _, _, _, _} = hd(G),
                                   maps:update_with(K, fun(L) -> L ++ [G] end, [G], Acc)
                           end, #{}, Groups),
    Entries = lists:append(
                [entries(Groups1) || {_, Groups1} <- lists:sort(maps:to_list(ByColour))]),
    lists:sort(fun(#{word := A}, #{word := B}) -> A =< B end, Entries).

%% Greedy clustering: each sighting joins the first group of its colour
%% whose first sighting is close enough, and an agent is in a group once.
group([], Groups) ->
    lists:reverse(Groups);
group([{K, P, Agent, _, _} = S | Rest], Groups) ->
    case lists:splitwith(
           fun([{K1, P1, _, _, _} | _] = G) ->
                   not (K1 =:= K andalso distance(P1, P) =< ?SAME_OBJECT_MM
                        andalso not lists:keymember(Agent, 3, G))
           end, Groups) of
        {Before, [G | After]} -> group(Rest, Before ++ [G ++ [S] | After]);
        {_, []} -> group(Rest, [[S] | Groups])
    end.

entries([Group]) ->
    [make_entry(Group, <<>>)];
entries(Groups) ->
    [make_entry(G, <<"-", (integer_to_binary(I))/binary>>)
     || {I, G} <- lists:zip(lists:seq(1, length(Groups)), Groups)].

make_entry([{K, _, _, _, Colour} | _] = Group, Suffix) ->
    Xs = [X || {_, {X, _}, _, _, _} <- Group],
    Ys = [Y || {_, {_, Y}, _, _, _} <- Group],
    #{word => <<K/binary, "-ball", Suffix/binary>>,
      colour => Colour,
      position => {round(lists:sum(Xs) / length(Xs)), round(lists:sum(Ys) / length(Ys))},
      names => maps:from_list([{Agent, Sym} || {_, _, Agent, Sym, _} <- Group])}.

%% @doc The words, sorted.
-spec words(lexicon()) -> [binary()].
words(Lexicon) -> [W || #{word := W} <- Lexicon].

-spec entry(binary(), lexicon()) -> {ok, entry()} | error.
entry(Word, Lexicon) ->
    case [E || #{word := W} = E <- Lexicon, W =:= Word] of
        [E] -> {ok, E};
        [] -> error
    end.

%% @doc The symbol `Agent' uses for `Word', if it has seen that object.
-spec local(binary(), binary(), lexicon()) -> {ok, binary()} | error.
local(Word, Agent, Lexicon) ->
    case entry(Word, Lexicon) of
        {ok, #{names := #{Agent := Sym}}} -> {ok, Sym};
        _ -> error
    end.

%% @doc The word for `Agent''s symbol.
-spec word_for(binary(), binary(), lexicon()) -> {ok, binary()} | error.
word_for(Agent, Symbol, Lexicon) ->
    case [W || #{word := W, names := #{Agent := S}} <- Lexicon, S =:= Symbol] of
        [W] -> {ok, W};
        [] -> error
    end.

%% @doc True when every lexicon given is the same (and there is one).
-spec agreed([lexicon()]) -> boolean().
agreed([L | Ls]) -> lists:all(fun(X) -> X =:= L end, Ls);
agreed([]) -> false.

%% @doc One line per word, for people.
-spec encode(lexicon()) -> iodata().
encode(Lexicon) ->
    lists:join(", ", [[W, " (", C, ")"] || #{word := W, colour := C} <- Lexicon]).

distance({X1, Y1}, {X2, Y2}) ->
    math:sqrt((X1 - X2) * (X1 - X2) + (Y1 - Y2) * (Y1 - Y2)).

%% @doc Internal. Anchoring after Coradeschi and Saffiotti, pure: the link
%% between what a robot's sensors perceive of an object (its colour
%% approximation, where it was seen) and a symbol the VA uses to think and
%% talk about it, created once (find, else acquire) and maintained while
%% the object is seen again (track) or found again after a while or
%% elsewhere (reacquire).
-module(reference_agents_anchor).

-export([new/1, perceive/2, anchors/1, lookup/2, moved/4, describe/1]).

-export_type([anchors/0, anchor/0, percept/0, outcome/0]).

-type position() :: {number(), number()}.
%% A perceived object: its colour approximation, where it is, and when.
-type percept() :: #{colour := binary(), position := position(), time := integer(),
                     luminosity => integer()}.
%% An anchor: the symbol and the object's last perceptual values.
-type anchor() :: #{symbol := binary(), colour := binary(), position := position(),
                    first_seen := integer(), last_seen := integer(), seen := pos_integer()}.
-type outcome() :: {acquired | tracked | reacquired, Symbol :: binary()}.

-record(st, {prefix :: binary(),
             next = 1 :: pos_integer(),
             anchors = [] :: [anchor()]}).
-opaque anchors() :: #st{}.

%% Two sightings of the same colour closer than this are the same object.
-define(SAME_PLACE_MM, 250).
%% An object not seen for this long may have been moved: a sighting of its
%% colour elsewhere reacquires it rather than anchoring a new object.
-define(STALE_MS, 20000).

%% @doc An empty set of anchors whose symbols start with `Prefix'.
-spec new(binary()) -> anchors().
new(Prefix) when is_binary(Prefix) -> #st{prefix = Prefix}.

%% @doc Anchors one percept: the same object seen again near its anchor is
%% tracked; an object of that colour not seen for a while and now seen
%% elsewhere is reacquired (it was moved); anything else is a new object.
-spec perceive(percept(), anchors()) -> {anchors(), outcome()}.
perceive(#{colour := Colour, position := Pos, time := T}, #st{anchors = As} = S) ->
    Key = reference_agents_activity:keyword(Colour),
    Same = lists:sort([{distance(P, Pos), A} || #{colour := C, position := P} = A <- As,
                                                 reference_agents_activity:keyword(C) =:= Key]),
    case Same of
        [{D, #{symbol := Sym} = A} | _] when D =< ?SAME_PLACE_MM ->
            {replace(A#{position := Pos, last_seen := T, seen := maps:get(seen, A) + 1}, S),
             {tracked, Sym}};
        _ ->
            case [A || {_, #{last_seen := L} = A} <- Same, T - L >= ?STALE_MS] of
                [#{symbol := Sym} = A | _] ->
                    {replace(A#{position := Pos, last_seen := T,
                                seen := maps:get(seen, A) + 1}, S),
                     {reacquired, Sym}};
                [] ->
                    Sym = <<(S#st.prefix)/binary, "-obj", (integer_to_binary(S#st.next))/binary>>,
                    A = #{symbol => Sym, colour => Colour, position => Pos,
                          first_seen => T, last_seen => T, seen => 1},
                    {S#st{next = S#st.next + 1, anchors = As ++ [A]}, {acquired, Sym}}
            end
    end.

%% @doc Every anchor, in the order they were acquired.
-spec anchors(anchors()) -> [anchor()].
anchors(#st{anchors = As}) -> As.

-spec lookup(binary(), anchors()) -> {ok, anchor()} | error.
lookup(Symbol, #st{anchors = As}) ->
    case [A || #{symbol := S} = A <- As, S =:= Symbol] of
        [A] -> {ok, A};
        [] -> error
    end.

%% @doc The VA moved the object itself (it carried it): the anchor follows.
-spec moved(binary(), position(), integer(), anchors()) -> anchors().
moved(Symbol, Pos, T, S) ->
    case lookup(Symbol, S) of
        {ok, A} -> replace(A#{position := Pos, last_seen := T}, S);
        error -> S
    end.

%% @doc What the VA tells others about what it anchored: symbol, colour
%% and position, without its private bookkeeping.
-spec describe(anchors()) -> [#{symbol := binary(), colour := binary(), position := position()}].
describe(#st{anchors = As}) ->
    [maps:with([symbol, colour, position], A) || A <- As].

replace(#{symbol := Sym} = A, #st{anchors = As} = S) ->
    S#st{anchors = [case X of #{symbol := Sym} -> A; _ -> X end || X <- As]}.

distance({X1, Y1}, {X2, Y2}) ->
    math:sqrt((X1 - X2) * (X1 - X2) + (Y1 - Y2) * (Y1 - Y2)).

%% @doc Internal. Between BIL parameters and the JSON a Thing's forms carry,
%% following a shape (wot_avatar_generate:shape()): a request's parameters
%% become the body sent (checked against the schema's type, range and
%% enum, so a bad value is refused before it reaches the Thing), and the
%% body a Thing answers becomes the parameters of the Feedback or reading.
%% docs/wot.md section 6. Pure.
-module(wot_avatar_codec).

-export([body/2, params/2]).

%% @doc The JSON body of a request (`none': send no body), or why the
%% parameters do not fit the schema.
-spec body(wot_avatar_generate:shape(), [bil:parameter()]) -> {ok, none | binary()} | {error, binary()}.
body(none, _Params) ->
    {ok, none};
body({value, F}, Params) ->
    case value(<<"Value">>, F, Params) of
        {ok, undefined} -> {error, <<"parameter Value is missing">>};
        {ok, V} -> {ok, encode(V)};
        {error, _} = E -> E
    end;
body({object, Fields}, Params) ->
    Values = [{J, value(B, F, Params)} || {B, J, F} <- Fields],
    case [E || {_, {error, _} = E} <- Values] of
        [E | _] -> E;
        [] -> {ok, encode(maps:from_list([{J, V} || {J, {ok, V}} <- Values, V =/= undefined]))}
    end.

value(Name, F, Params) ->
    K = bil:keyword(Name),
    case [V || {N, V} <- Params, bil:keyword(N) =:= K] of
        [Text | _] ->
            case typed(maps:get(type, F), Text) of
                {ok, V} -> check(Name, V, F);
                error -> {error, <<"parameter ", Name/binary, " is not ", (article(maps:get(type, F)))/binary>>}
            end;
        [] ->
            {ok, maps:get(default, F, undefined)}
    end.

typed(<<"string">>, T) -> {ok, T};
typed(<<"integer">>, T) ->
    case string:to_integer(T) of
        {I, <<>>} when is_integer(I) -> {ok, I};
        _ -> error
    end;
typed(<<"number">>, T) ->
    case string:to_float(T) of
        {F, <<>>} when is_float(F) -> {ok, F};
        _ -> typed(<<"integer">>, T)
    end;
typed(<<"boolean">>, T) ->
    case string:lowercase(T) of
        B when B =:= <<"true">>; B =:= <<"yes">>; B =:= <<"on">> -> {ok, true};
        B when B =:= <<"false">>; B =:= <<"no">>; B =:= <<"off">> -> {ok, false};
        _ -> error
    end;
typed(<<"null">>, _) -> {ok, null};
typed(undefined, T) ->
    %% No type: JSON if it reads as JSON, else the text as a string.
    case evatar_json:decode(T) of
        {ok, V} -> {ok, V};
        {error, _} -> {ok, T}
    end.

article(<<"integer">>) -> <<"an integer">>;
article(T) when is_binary(T) -> <<"a ", T/binary>>;
article(undefined) -> <<"JSON">>.

check(Name, V, F) ->
    Min = maps:get(minimum, F, undefined),
    Max = maps:get(maximum, F, undefined),
    Enum = maps:get(enum, F, undefined),
    if
        is_number(V), is_number(Min), V < Min ->
            {error, <<"parameter ", Name/binary, " is below its minimum ", (text(Min))/binary>>};
        is_number(V), is_number(Max), V > Max ->
            {error, <<"parameter ", Name/binary, " is above its maximum ", (text(Max))/binary>>};
        is_list(Enum) ->
            case lists:any(fun(E) -> E == V end, Enum) of
                true -> {ok, V};
                false -> {error, <<"parameter ", Name/binary, " is not one of its Values">>}
            end;
        true ->
            {ok, V}
    end.

%% @doc The parameters of what a Thing answered (a JSON body, or text).
-spec params(wot_avatar_generate:shape(), binary()) -> [bil:parameter()].
params(_Shape, <<>>) ->
    [];
params(Shape, Body) ->
    case {Shape, evatar_json:decode(Body)} of
        {{object, Fields}, {ok, #{} = Object}} ->
            [{B, text(maps:get(J, Object))} || {B, J, _} <- Fields, is_map_key(J, Object)];
        {_, {ok, V}} ->
            [{<<"Value">>, text(V)}];
        {_, {error, _}} ->
            [{<<"Value">>, Body}]
    end.

text(V) -> evatar_json:to_text(V).

encode(V) -> evatar_json:encode(V).

%% @doc Internal. Reading request parameters (decimal text, yes/no) and
%% writing answer parameters, for the simulated devices. Bad values give
%% `{error, Message}' for a `BadParameter' error signal.
-module(avatar_sim_param).

-export([number/3, number/2, yes_no/3, text/3, list/2, fmt/1, params/1, hhmm/1, hhmmss/1]).

-export_type([params/0]).

-type params() :: [{binary(), binary()}].

%% @doc A number parameter, or `Default' when absent.
-spec number(binary(), params(), number()) -> {ok, number()} | {error, binary()}.
number(Name, Params, Default) ->
    case lists:keyfind(Name, 1, Params) of
        false -> {ok, Default};
        {_, Value} -> parse_number(Name, Value)
    end.

%% @doc A required number parameter.
-spec number(binary(), params()) -> {ok, number()} | {error, binary()}.
number(Name, Params) ->
    case lists:keyfind(Name, 1, Params) of
        false -> {error, <<"missing parameter ", Name/binary>>};
        {_, Value} -> parse_number(Name, Value)
    end.

parse_number(Name, Value) ->
    Text = string:trim(binary_to_list(Value)),
    case string:to_float(Text) of
        {F, []} -> {ok, F};
        _ ->
            case string:to_integer(Text) of
                {I, []} when is_integer(I) -> {ok, I};
                _ -> {error, <<"parameter ", Name/binary, " is not a number: '",
                               (printable(Value))/binary, "'">>}
            end
    end.

%% @doc A yes/no parameter (case-insensitive), or `Default' when absent.
-spec yes_no(binary(), params(), boolean()) -> {ok, boolean()} | {error, binary()}.
yes_no(Name, Params, Default) ->
    case lists:keyfind(Name, 1, Params) of
        false -> {ok, Default};
        {_, Value} ->
            case string:lowercase(string:trim(Value)) of
                <<"yes">> -> {ok, true};
                <<"no">> -> {ok, false};
                _ -> {error, <<"parameter ", Name/binary, " must be yes or no, not '",
                               (printable(Value))/binary, "'">>}
            end
    end.

%% @doc A text parameter, or `Default' when absent.
-spec text(binary(), params(), binary()) -> binary().
text(Name, Params, Default) ->
    case lists:keyfind(Name, 1, Params) of
        false -> Default;
        {_, Value} -> Value
    end.

%% @doc A comma-separated list parameter, trimmed, empty items dropped.
-spec list(binary(), params()) -> [binary()].
list(Name, Params) ->
    [I || I0 <- binary:split(text(Name, Params, <<>>), <<",">>, [global]),
          I <- [string:trim(I0)], I =/= <<>>].

%% @doc Formats a value for an answer parameter.
-spec fmt(term()) -> binary().
fmt(true) -> <<"yes">>;
fmt(false) -> <<"no">>;
fmt(V) when is_integer(V) -> integer_to_binary(V);
fmt(V) when is_float(V) -> integer_to_binary(round(V));
fmt(V) when is_atom(V) -> atom_to_binary(V);
fmt(V) when is_binary(V) -> V;
fmt(V) when is_list(V) -> unicode:characters_to_binary(V).

%% @doc Formats a property list of answer parameters.
-spec params([{binary(), term()}]) -> params().
params(Props) -> [{K, fmt(V)} || {K, V} <- Props].

-spec hhmm(non_neg_integer()) -> binary().
hhmm(SecondsOfDay) ->
    list_to_binary(io_lib:format("~2..0B:~2..0B",
                                 [SecondsOfDay div 3600, SecondsOfDay rem 3600 div 60])).

-spec hhmmss(non_neg_integer()) -> binary().
hhmmss(SecondsOfDay) ->
    list_to_binary(io_lib:format("~2..0B:~2..0B:~2..0B",
                                 [SecondsOfDay div 3600, SecondsOfDay rem 3600 div 60,
                                  SecondsOfDay rem 60])).

printable(Value) when byte_size(Value) > 40 -> <<(binary:part(Value, 0, 40))/binary, "...">>;
printable(Value) -> Value.

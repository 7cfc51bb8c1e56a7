%% @doc Public (evatar's, for the apps that log what clients sent:
%% agent_bridge, evatar_web). Bounds what a client sent before it reaches a
%% log line:
%% ids are cut to 64 bytes with a marker that says how long they were, and
%% any term (a parse error's reason, say) has its binaries cut alike, its
%% lists shortened and its depth limited, so a 60 KB id never writes 60 KB
%% of log.
-module(evatar_log).

-export([id/1, term/1, report/1]).

-define(MAX_ID, 64).
-define(MAX_LIST, 16).
-define(MAX_DEPTH, 6).

%% @doc An id (or any binary) of at most 64 bytes, else its first 64 bytes
%% and `...(N bytes)'.
-spec id(term()) -> term().
id(Bin) when is_binary(Bin), byte_size(Bin) > ?MAX_ID ->
    <<(binary:part(Bin, 0, ?MAX_ID))/binary, "...(", (integer_to_binary(byte_size(Bin)))/binary,
      " bytes)">>;
id(Other) ->
    Other.

%% @doc Term with every binary cut as id/1, lists cut to 16 elements and
%% nesting below 6 levels replaced by '...'.
-spec term(term()) -> term().
term(T) -> term(T, ?MAX_DEPTH).

term(_, 0) -> '...';
term(B, _) when is_binary(B) -> id(B);
term(L, D) when is_list(L) ->
    case io_lib:printable_unicode_list(L) of
        true when length(L) > ?MAX_ID -> lists:sublist(L, ?MAX_ID) ++ "...";
        true -> L;
        false -> list(L, D, ?MAX_LIST)
    end;
term(T, D) when is_tuple(T) ->
    list_to_tuple(list(tuple_to_list(T), D, ?MAX_LIST));
term(M, D) when is_map(M) ->
    maps:from_list([{term(K, D - 1), term(V, D - 1)}
                    || {K, V} <- lists:sublist(maps:to_list(M), ?MAX_LIST)]);
term(Other, _) ->
    Other.

list([], _D, _N) -> [];
list(_, _D, 0) -> ['...'];
list([H | T], D, N) -> [term(H, D - 1) | list(T, D, N - 1)];
list(Improper, D, _N) -> term(Improper, D - 1).

%% @doc A log report with every value bounded by term/1.
-spec report(map()) -> map().
report(Report) ->
    maps:map(fun(_, V) -> term(V) end, Report).

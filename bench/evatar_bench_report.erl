%% @doc Internal to the mediator benchmark (evatar_bench): percentiles,
%% number formatting, and the results written as JSON and markdown (OTP 25
%% has no json module, so a small encoder for maps, lists, numbers, atoms
%% and binaries is here).
-module(evatar_bench_report).

-export([percentiles/2, latency_figures/2, json/1, fmt/2, int/1, kib/1, ms/1, table/2, md_table/2,
         write/3, write/4]).

%% @doc The values at the given fractions (0 < Q =< 1) of a list of
%% samples, nearest rank; `undefined' for each when there are none.
-spec percentiles([number()], [float()]) -> [number() | undefined].
percentiles([], Qs) ->
    [undefined || _ <- Qs];
percentiles(Samples, Qs) ->
    T = list_to_tuple(lists:sort(Samples)),
    N = tuple_size(T),
    [element(max(1, min(N, ceil(Q * N))), T) || Q <- Qs].

%% @doc The figures of an open-loop window of `Secs' seconds from its
%% agents' samples (bench_requester): latency percentiles and the send
%% lag's, in µs, and `slow_span_ms', the ms between the earliest and the
%% latest due time of the requests at or above p99.9. A single stall packs
%% those into a few tens of ms; a tail spread over the window spans most
%% of it.
-spec latency_figures([map()], number()) -> map().
latency_figures(Samples, Secs) ->
    Timed = lists:append([L || #{latencies := L} <- Samples]),
    Lat = [L || {_, L} <- Timed],
    Lag = lists:append([L || #{send_lags := L} <- Samples]),
    [P50, P99, P999, Max] = percentiles(Lat, [0.5, 0.99, 0.999, 1.0]),
    [Lag50, Lag99, LagMax] = percentiles(Lag, [0.5, 0.99, 1.0]),
    #{samples => length(Lat), achieved => length(Lat) / Secs,
      p50 => P50, p99 => P99, p999 => P999, max => Max,
      send_lag_p50 => Lag50, send_lag_p99 => Lag99, send_lag_max => LagMax,
      slow_span_ms => span_ms([S || {S, L} <- Timed, L >= P999])}.

span_ms([]) -> undefined;
span_ms(Dues) -> (lists:max(Dues) - lists:min(Dues)) / 1000.

%% @doc One JSON document.
-spec json(term()) -> iodata().
json(M) when is_map(M) ->
    Pairs = [[json(key(K)), $:, json(V)] || {K, V} <- lists:sort(maps:to_list(M))],
    [${, lists:join($,, Pairs), $}];
json(L) when is_list(L) ->
    [$[, lists:join($,, [json(E) || E <- L]), $]];
json(true) -> <<"true">>;
json(false) -> <<"false">>;
json(undefined) -> <<"null">>;
json(A) when is_atom(A) -> json(atom_to_binary(A));
json(I) when is_integer(I) -> integer_to_binary(I);
json(F) when is_float(F) -> float_to_binary(F, [{decimals, 4}, compact]);
json(B) when is_binary(B) -> [$", escape(B), $"];
json(T) when is_tuple(T) -> json(tuple_to_list(T)).

key(K) when is_atom(K) -> atom_to_binary(K);
key(K) when is_integer(K) -> integer_to_binary(K);
key(K) when is_binary(K) -> K.

escape(B) ->
    [case C of
         $" -> <<"\\\"">>;
         $\\ -> <<"\\\\">>;
         $\n -> <<"\\n">>;
         C when C < 16#20 -> io_lib:format("\\u~4.16.0b", [C]);
         C -> <<C/utf8>>
     end || <<C/utf8>> <= B].

%% @doc io_lib:format/2 to a flat string.
-spec fmt(string(), [term()]) -> string().
fmt(F, A) -> lists:flatten(io_lib:format(F, A)).

%% @doc An integer with thousands separators ("12,345"); "-" for undefined.
-spec int(number() | undefined) -> string().
int(undefined) -> "-";
int(N) when is_float(N) -> int(round(N));
int(N) when N < 0 -> "-" ++ int(-N);
int(N) ->
    S = integer_to_list(N),
    group(lists:reverse(S), []).

group([A, B, C, D | Rest], Acc) -> group([D | Rest], [$,, C, B, A | Acc]);
group(Rest, Acc) -> lists:reverse(Rest) ++ Acc.

%% @doc Bytes as KiB with one decimal.
-spec kib(number() | undefined) -> string().
kib(undefined) -> "-";
kib(B) -> fmt("~.1f", [B / 1024]).

%% @doc Microseconds as milliseconds with two or three decimals.
-spec ms(number() | undefined) -> string().
ms(undefined) -> "-";
ms(Us) when Us < 10000 -> fmt("~.3f", [Us / 1000]);
ms(Us) -> fmt("~.1f", [Us / 1000]).

%% @doc A plain-text table: header row and rows of strings, columns padded
%% to their widest cell, the first column left-aligned.
-spec table([string()], [[string()]]) -> iodata().
table(Header, Rows) ->
    Widths = widths([Header | Rows]),
    [line(Header, Widths), line([lists:duplicate(W, $-) || W <- Widths], Widths)
     | [line(R, Widths) || R <- Rows]].

line([First | Cells], [W1 | Ws]) ->
    [string:pad(First, W1, trailing),
     [["  ", string:pad(C, W, leading)] || {C, W} <- lists:zip(Cells, Ws)], $\n].

widths(Rows) ->
    lists:foldl(fun(R, Acc) -> [max(string:length(C), W) || {C, W} <- lists:zip(R, Acc)] end,
                [0 || _ <- hd(Rows)], Rows).

%% @doc The same table in markdown.
-spec md_table([string()], [[string()]]) -> iodata().
md_table(Header, Rows) ->
    Row = fun(Cells) -> ["| ", lists:join(" | ", Cells), " |\n"] end,
    [Row(Header), Row(["---" || _ <- Header]) | [Row(R) || R <- Rows]].

%% @doc Writes Results as JSON and Markdown as markdown under Dir, named
%% with the date and time; returns the two file names.
-spec write(file:filename(), map(), iodata()) -> {string(), string()}.
write(Dir, Results, Markdown) ->
    write(Dir, "evatar", Results, Markdown).

%% @doc The same, the file names starting with Prefix instead of `evatar'.
-spec write(file:filename(), string(), map(), iodata()) -> {string(), string()}.
write(Dir, Prefix, Results, Markdown) ->
    ok = filelib:ensure_dir(filename:join(Dir, "x")),
    {{Y, Mo, D}, {H, Mi, S}} = calendar:local_time(),
    Stamp = fmt("~4..0b-~2..0b-~2..0b-~2..0b~2..0b~2..0b", [Y, Mo, D, H, Mi, S]),
    Json = filename:join(Dir, Prefix ++ "-" ++ Stamp ++ ".json"),
    Md = filename:join(Dir, Prefix ++ "-" ++ Stamp ++ ".md"),
    ok = file:write_file(Json, [json(Results), $\n]),
    ok = file:write_file(Md, Markdown),
    {Json, Md}.

%% @doc Internal. Formats the inspection results of `evatar' as plain text
%% tables for an operator's remote shell (`evatar:print_pairings()' and
%% friends). Output only; the data functions live in `evatar'.
-module(evatar_print).

-export([pairings/1, bindings/1, registry/1, stats/1, table/2]).

%% @doc Prints the pairing summaries.
-spec pairings([evatar:pairing_summary()]) -> ok.
pairings(Summaries) ->
    Rows = [[maps:get(id, S), maps:get(state, S), maps:get(agent, S, '-'),
             maps:get(avatars, S, '-'), maps:get(registered, S, '-'),
             maps:get(bound, S, '-'), maps:get(unbound, S, '-'),
             maps:get(pending, S, '-'), maps:get(pid, S), maps:get(role, S, '-'),
             maps:get(epoch, S, '-')] || S <- Summaries],
    table(["PAIRING", "STATE", "AGENT", "AVATARS", "REGISTERED", "BOUND", "UNBOUND",
           "PENDING", "PID", "ROLE", "EPOCH"], Rows).

%% @doc Prints a Body Mapping Registry.
-spec bindings(evatar:binding_report()) -> ok.
bindings(#{bound := Bound, unbound := Unbound}) ->
    io:format("Bound (~b)~n", [length(Bound)]),
    table(["CONSUMER", "PROVIDER", "CATEGORY", "TYPE", "SCORE", "CANDIDATES"],
          [[endpoint(C), endpoint(P), Cat, T, S, N]
           || #{consumer := C, provider := P, category := Cat, type := T,
                score := S, candidates := N} <- Bound]),
    io:format("~nUnbound (~b)~n", [length(Unbound)]),
    table(["CONSUMER", "CATEGORY", "TYPE", "REASON"],
          [[endpoint(C), Cat, T, R]
           || #{consumer := C, category := Cat, type := T, reason := R} <- Unbound]).

%% @doc Prints a Service Registration List: one row per service or consumed
%% entry, entities without a description on a row of their own.
-spec registry([map()]) -> ok.
registry(Entries) ->
    Rows = lists:append([entity_rows(E) || E <- Entries]),
    table(["ENTITY", "ROLE", "COMPONENT", "KIND", "CATEGORY", "TYPE", "PARAMETERS"], Rows).

entity_rows(#{entity := Id, role := Role, description := undefined}) ->
    [[Id, Role, "-", "(not registered yet)", "", "", ""]];
entity_rows(#{entity := Id, role := Role, description := #{components := Cs}}) ->
    [[Id, Role, C, Kind, Cat, T, params(Ps)]
     || #{id := C, services := S, consumes := U} <- Cs,
        {Kind, Entries} <- [{service, S}, {consumes, U}],
        #{category := Cat, type := T, parameters := Ps} <- Entries].

params(Ps) ->
    lists:join(" ", [[N, "=", V] || {N, V} <- Ps]).

%% @doc Prints pairing counters.
-spec stats(map()) -> ok.
stats(#{routed := Routed, errors := Errors} = Stats) ->
    Other = maps:without([routed, errors], Stats),
    table(["COUNTER", "VALUE"],
          [[["routed ", atom_to_list(Ctx)], N] || {Ctx, N} <- lists:sort(maps:to_list(Routed))] ++
          [[["error ", Code], N] || {Code, N} <- lists:sort(maps:to_list(Errors))] ++
          [[atom_to_list(K), V] || {K, V} <- lists:sort(maps:to_list(Other))]).

endpoint(#{entity := E, component := C}) -> [E, "/", C].

%% @doc Prints rows under a header, columns padded to their widest cell.
-spec table([string()], [[term()]]) -> ok.
table(Header, Rows) ->
    Cells = [[cell(C) || C <- Row] || Row <- [Header | Rows]],
    Widths = lists:foldl(fun(Row, Ws) ->
                                 [max(W, string:length(C)) || {W, C} <- lists:zip(Ws, Row)]
                         end, [0 || _ <- Header], Cells),
    lists:foreach(fun(Row) ->
                          Line = [[C, lists:duplicate(W - string:length(C) + 2, $\s)]
                                  || {W, C} <- lists:zip(Widths, Row)],
                          io:format("~ts~n", [string:trim(Line, trailing)])
                  end, Cells).

cell(B) when is_binary(B) -> unicode:characters_to_list(B);
cell(A) when is_atom(A) -> atom_to_list(A);
cell(I) when is_integer(I) -> integer_to_list(I);
cell(P) when is_pid(P) -> pid_to_list(P);
cell(L) when is_list(L) -> unicode:characters_to_list(L);
cell(Other) -> lists:flatten(io_lib:format("~p", [Other])).

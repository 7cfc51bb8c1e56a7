%% @doc Internal. The release's operator commands (`bin/evatar cluster',
%% `pairings', `pairing ID', `create ID', `delete ID', `rotate ID WHO',
%% `bindings ID', `mqtt_problems [NAME]', `wot_problems [NAME]'; README.md,
%% "Operator commands"):
%% run by config/extensions/evatar_ctl in a short-lived hidden Erlang node,
%% which reaches the running node through distribution with the cookie of
%% `$HOME/.erlang.cookie' (never on a command line), calls {@link evatar_ops}
%% there and prints the answer as text, or as JSON with `--json'.
%%
%% New credentials never come from the command line: they are generated and
%% printed once, or read from the first line of a file.
-module(evatar_cli).

-export([main/0, usage/0, run/2, format/2, format_error/1]).

-ifdef(TEST).
-export([parse/1]).
-endif.

-define(TIMEOUT, 30000).

%% Exit codes: 0 done, 1 refused by the node (the message says why),
%% 2 bad usage, 3 node not reachable.
-define(USAGE,
        "Usage: bin/evatar COMMAND [--json]\n"
        "  cluster                     the cluster: nodes, quorum, each pairing's active and standby\n"
        "  pairings                    every pairing of the node\n"
        "  pairing ID                  one pairing: its entities, counts, state\n"
        "  bindings ID                 the binding report: what is bound to what, every unbound\n"
        "                              entry with its reason and the parameters that did not match\n"
        "  create ID [--agent-credential-file F] [--avatar-credential-file F] [KEY=VALUE ...]\n"
        "                              a new pairing; credentials not given in a file are generated\n"
        "                              and printed once (KEY=VALUE: join_timeout=5000, ...)\n"
        "  delete ID                   deletes a pairing\n"
        "  rotate ID agent|avatar|ENTITY [--credential-file F]\n"
        "                              a new credential for a role or one identity, generated and\n"
        "                              printed once unless read from F\n"
        "  mqtt_problems [NAME]        the MQTT Avatars' problems (one Avatar's with NAME)\n"
        "  wot_problems [NAME]         the WoT Avatars' problems (one Avatar's with NAME)\n").

%% @doc The entry point of the extension script: the command and its
%% arguments are the plain arguments (`-extra'), the node to reach is
%% `$EVATAR_CTL_TARGET'. Returns the exit code. (Not `status': relx's own
%% `bin/evatar status' pings the node with erl_call, whose command line
%% holds the cookie.)
-spec main() -> 0..3.
main() ->
    Args = init:get_plain_arguments(),
    Json = lists:member("--json", Args),
    case parse([A || A <- Args, A =/= "--json"]) of
        {ok, Command} ->
            Target = list_to_atom(os:getenv("EVATAR_CTL_TARGET", "evatar@127.0.0.1")),
            case net_kernel:connect_node(Target) of
                true ->
                    {Code, Out} = run(Target, Command),
                    Text = case Code of
                               0 -> format(Command, Out);
                               _ -> format_error(Out)
                           end,
                    print(Code, Text, Out, Json);
                _ ->
                    io:format(standard_error,
                              "evatar: cannot reach the node ~ts: is it running, and does "
                              "$HOME/.erlang.cookie hold the cluster's cookie? (bin/evatar ping)~n",
                              [Target]),
                    3
            end;
        {error, Message} ->
            io:format(standard_error, "evatar: ~ts~n~ts", [Message, ?USAGE]),
            2
    end.

%% @doc The commands and their arguments.
-spec usage() -> string().
usage() ->
    ?USAGE.

print(0, Text, _Out, false) ->
    io:put_chars(Text),
    0;
print(0, _Text, Out, true) ->
    io:put_chars([evatar_json:encode(Out), $\n]),
    0;
print(Code, _Text, Out, true) ->
    io:put_chars([evatar_json:encode(Out), $\n]),
    Code;
print(Code, Text, _Out, false) ->
    io:put_chars(standard_error, Text),
    Code.

%% ---------------------------------------------------------------------------
%% Commands
%% ---------------------------------------------------------------------------

-type command() :: cluster | pairings | {pairing, binary()} | {bindings, binary()}
                 | {create, binary(), map(), [binary()]} | {delete, binary()}
                 | {rotate, binary(), binary(), map(), boolean()}
                 | {mqtt_problems, binary() | all} | {wot_problems, binary() | all}.

parse(["cluster"]) -> {ok, cluster};
parse(["pairings"]) -> {ok, pairings};
parse(["pairing", Id]) -> {ok, {pairing, bin(Id)}};
parse(["bindings", Id]) -> {ok, {bindings, bin(Id)}};
parse(["delete", Id]) -> {ok, {delete, bin(Id)}};
parse(["mqtt_problems"]) -> {ok, {mqtt_problems, all}};
parse(["mqtt_problems", Name]) -> {ok, {mqtt_problems, bin(Name)}};
parse(["wot_problems"]) -> {ok, {wot_problems, all}};
parse(["wot_problems", Name]) -> {ok, {wot_problems, bin(Name)}};
parse(["create", Id | Rest]) -> create_args(bin(Id), Rest, #{}, [agent, avatar]);
parse(["rotate", Id, Who | Rest]) -> rotate_args(bin(Id), bin(Who), Rest);
parse([]) -> {error, "no command"};
parse([Cmd | _]) -> {error, ["unknown command or arguments: ", Cmd]}.

create_args(Id, ["--agent-credential-file", F | Rest], Body, Gen) ->
    with_secret(F, fun(S) -> create_args(Id, Rest, Body#{<<"agent_credential">> => S},
                                         Gen -- [agent]) end);
create_args(Id, ["--avatar-credential-file", F | Rest], Body, Gen) ->
    with_secret(F, fun(S) -> create_args(Id, Rest, Body#{<<"avatar_credential">> => S},
                                         Gen -- [avatar]) end);
create_args(Id, [KV | Rest], Body, Gen) ->
    case string:split(KV, "=") of
        [K, V] when K =/= "" ->
            create_args(Id, Rest, Body#{bin(K) => value(V)}, Gen);
        _ ->
            {error, ["not KEY=VALUE: ", KV]}
    end;
create_args(Id, [], Body, Gen) ->
    Generated = maps:from_list([{role_key(R), secret()} || R <- Gen]),
    {ok, {create, Id, maps:merge(Body, Generated), maps:keys(Generated)}}.

rotate_args(Id, Who, ["--credential-file", F]) ->
    with_secret(F, fun(S) -> {ok, {rotate, Id, Who, #{<<"credential">> => S}, false}} end);
rotate_args(Id, Who, []) ->
    {ok, {rotate, Id, Who, #{<<"credential">> => secret()}, true}};
rotate_args(_Id, _Who, [Other | _]) ->
    {error, ["unknown argument: ", Other]}.

role_key(agent) -> <<"agent_credential">>;
role_key(avatar) -> <<"avatar_credential">>.

%% A secret from the first line of a file (not from the command line,
%% where every local user sees it).
with_secret(File, Then) ->
    case file:read_file(File) of
        {ok, Bin} ->
            case string:trim(hd(binary:split(Bin, <<"\n">>)), trailing, "\r") of
                <<>> -> {error, ["the first line of ", File, " is empty"]};
                Secret -> Then(Secret)
            end;
        {error, Why} ->
            {error, ["cannot read ", File, ": ", file:format_error(Why)]}
    end.

%% 24 random bytes in hexadecimal: 192 bits, typed nowhere.
secret() ->
    string:lowercase(binary:encode_hex(crypto:strong_rand_bytes(24))).

value(V) ->
    case string:to_integer(V) of
        {I, ""} -> I;
        _ -> bin(V)
    end.

bin(S) -> unicode:characters_to_binary(S).

%% @doc Runs a command on node Target: `{0, Result}' or `{1, Error}'
%% (evatar_ops's error map), both JSON-ready.
-spec run(node(), command()) -> {0 | 1, term()}.
run(Target, Command) ->
    {F, A} = case Command of
                 cluster -> {cluster, []};
                 pairings -> {pairings, []};
                 {pairing, Id} -> {pairing, [Id]};
                 {bindings, Id} -> {bindings, [Id]};
                 {delete, Id} -> {delete, [Id]};
                 {create, Id, Body, _} -> {create, [Id, Body]};
                 {rotate, Id, Who, Body, _} -> {rotate, [Id, who(Who, Body)]};
                 {mqtt_problems, all} -> {mqtt_avatars, []};
                 {mqtt_problems, Name} -> {problems, [Name]};
                 {wot_problems, all} -> {wot_avatars, []};
                 {wot_problems, Name} -> {wot_problems, [Name]}
             end,
    try call(Target, Command, F, A) of
        {error, Error} -> {1, Error};
        {ok, Result} -> {0, with_secrets(Command, Result)};
        ok -> {0, with_secrets(Command, #{})};
        Result -> {0, with_secrets(Command, Result)}
    catch
        %% Never the call's arguments in a message: they may hold a secret.
        error:{exception, undef, [{evatar_ops, F, _, _} | _]} ->
            {1, failed(io_lib:format("the node has no evatar_ops:~ts/~b (another version?)",
                                     [F, length(A)]))};
        error:{exception, Reason, _Stack} when is_atom(Reason) ->
            {1, failed(io_lib:format("the call failed on the node (~ts); its log has the details",
                                     [Reason]))};
        error:{exception, _Reason, _Stack} ->
            {1, failed("the call failed on the node; its log has the details")};
        error:{erpc, Why} when is_atom(Why) ->
            {1, failed(io_lib:format("the call to ~ts failed: ~ts", [Target, Why]))};
        _:_ ->
            {1, failed(io_lib:format("the call to ~ts failed", [Target]))}
    end.

failed(Message) ->
    #{error => <<"failed">>, field => null, message => iolist_to_binary(Message)}.

call(Target, {Kind, all}, F, A) when Kind =:= mqtt_problems; Kind =:= wot_problems ->
    %% Every kept Avatar with its problems.
    Problems = case Kind of
                   mqtt_problems -> problems;
                   wot_problems -> wot_problems
               end,
    [Status#{problems => case erpc:call(Target, evatar_ops, Problems, [E], ?TIMEOUT) of
                             {ok, Ps} -> Ps;
                             {error, _} -> []
                         end}
     || #{entity_id := E} = Status <- erpc:call(Target, evatar_ops, F, A, ?TIMEOUT)];
call(Target, _Command, F, A) ->
    erpc:call(Target, evatar_ops, F, A, ?TIMEOUT).

who(<<"agent">>, Body) -> Body#{<<"role">> => <<"agent">>};
who(<<"avatar">>, Body) -> Body#{<<"role">> => <<"avatar">>};
who(Entity, Body) -> Body#{<<"entity">> => Entity}.

%% What was generated here is shown once, with the node's answer.
with_secrets({create, _, Body, Generated}, Result) when Generated =/= [], is_map(Result) ->
    Result#{generated_credentials => maps:with(Generated, Body)};
with_secrets({rotate, _, _, #{<<"credential">> := S}, true}, Result) when is_map(Result) ->
    Result#{generated_credential => S};
with_secrets(_Command, Result) ->
    Result.

%% ---------------------------------------------------------------------------
%% Text
%% ---------------------------------------------------------------------------

%% @doc The readable text of a command's answer (an error map for a
%% refused one).
-spec format(command(), term()) -> iodata().
format(Command, Result) ->
    R = normalise(Result),
    case {Command, R} of
        {{bindings, Id}, _} ->
            bindings(Id, R);
        {{create, Id, _, _}, _} ->
            [secrets(R), "Created pairing ", Id, ".\n", generic(maps:without(secret_keys(), R))];
        {{rotate, Id, Who, _, _}, _} ->
            [secrets(R), "Rotated the credential of ", Who, " in pairing ", Id, ".\n",
             generic(maps:without(secret_keys(), R))];
        {{delete, Id}, _} ->
            ["Deleted pairing ", Id, ".\n"];
        {{mqtt_problems, all}, _} when is_list(R) ->
            avatars_problems("MQTT", R);
        {{wot_problems, all}, _} when is_list(R) ->
            avatars_problems("WoT", R);
        {{Kind, _Name}, _} when is_list(R), Kind =:= mqtt_problems orelse Kind =:= wot_problems ->
            problems(R, "");
        _ ->
            generic(R)
    end.

%% @doc The text of a refusal: its code, the field it names, its message.
-spec format_error(term()) -> iodata().
format_error(Error) ->
    case normalise(Error) of
        #{<<"error">> := Code, <<"message">> := Message} = E ->
            Field = case maps:get(<<"field">>, E, null) of
                        null -> "";
                        F -> [" (", scalar(F), ")"]
                    end,
            ["evatar: refused: ", scalar(Code), Field, ": ", scalar(Message), "\n"];
        Other ->
            ["evatar: refused: ", inline(Other), "\n"]
    end.

secret_keys() ->
    [<<"generated_credentials">>, <<"generated_credential">>].

secrets(#{<<"generated_credentials">> := Creds}) ->
    ["New credentials (shown once; keep them now):\n",
     [["  ", K, ": ", V, "\n"] || {K, V} <- lists:sort(maps:to_list(Creds))]];
secrets(#{<<"generated_credential">> := S}) ->
    ["New credential (shown once; keep it now): ", S, "\n"];
secrets(_) ->
    [].

%% JSON-ready terms with binary keys and values only (atoms as strings),
%% as a script reading --json sees them.
normalise(Term) ->
    Bin = evatar_json:encode(Term),
    %% Our own output: no limit but its own size.
    {ok, T} = evatar_json:decode(Bin, #{max_size => byte_size(Bin), max_depth => byte_size(Bin)}),
    T.

%% Every kept MQTT (or WoT) Avatar as a table row with its problem count,
%% then each Avatar's problems one a line (a problem is a map, which a
%% table column cannot show).
avatars_problems(Kind, []) ->
    ["No ", Kind, " Avatars on this node.\n"];
avatars_problems(_Kind, Avatars) ->
    Rows = [maps:without([<<"problems">>], A#{<<"problem_count">> => length(list(<<"problems">>, A))})
            || A <- Avatars],
    [generic(Rows),
     [["\nProblems of ", scalar(maps:get(<<"entity_id">>, A, null)), " (",
       integer_to_binary(length(list(<<"problems">>, A))), ")\n",
       problems(list(<<"problems">>, A), "  ")]
      || A <- Avatars, list(<<"problems">>, A) =/= []]].

%% One line a problem: its time (UTC), what it is, then what else it carries.
problems([], Indent) ->
    [Indent, "No problems.\n"];
problems(Problems, Indent) ->
    [[Indent, problem_time(maps:get(<<"time">>, P, null)), "  ",
      scalar(maps:get(<<"what">>, P, <<"?">>)),
      [["  ", K, ": ", inline(V)]
       || {K, V} <- lists:sort(maps:to_list(maps:without([<<"time">>, <<"what">>], P)))], "\n"]
     || P <- Problems].

problem_time(Ms) when is_integer(Ms) ->
    calendar:system_time_to_rfc3339(Ms, [{unit, millisecond}, {offset, "Z"}]);
problem_time(Other) ->
    scalar(Other).

%% The binding report: each bound consumer -> service -> provider, then
%% each unbound entry with its reason and whatever else it carries (the
%% parameters that did not match).
bindings(Id, R) ->
    Bound = list(<<"bound">>, R),
    Unbound = list(<<"unbound">>, R),
    [io_lib:format("Pairing ~ts: ~b bound, ~b unbound~n", [Id, length(Bound), length(Unbound)]),
     case Bound of
         [] -> "";
         _ -> ["\nBound\n",
               table([<<"CONSUMER">>, <<"">>, <<"SERVICE">>, <<"">>, <<"PROVIDER">>,
                      <<"SCORE">>, <<"CANDIDATES">>],
                     [[endpoint(maps:get(<<"consumer">>, B, null)), <<"->">>, service(B),
                       <<"->">>, endpoint(maps:get(<<"provider">>, B, null)),
                       maps:get(<<"score">>, B, <<>>), maps:get(<<"candidates">>, B, <<>>)]
                      || B <- Bound], "  ")]
     end,
     case Unbound of
         [] -> "";
         _ -> ["\nUnbound\n",
               [["  ", endpoint(maps:get(<<"consumer">>, U, null)), "  ", service(U), "  ",
                 scalar(maps:get(<<"reason">>, U, <<"?">>)), "\n",
                 [candidate(C) || C <- list(<<"candidates">>, U)],
                 [["      ", K, ": ", inline(V), "\n"]
                  || {K, V} <- lists:sort(maps:to_list(
                                            maps:without([<<"consumer">>, <<"category">>,
                                                          <<"type">>, <<"reason">>,
                                                          <<"candidates">>], U)))]]
                || U <- Unbound]]
     end,
     generic(maps:without([<<"bound">>, <<"unbound">>], R))].

%% A provider that could have served an unbound entry, and each parameter
%% it did not satisfy.
candidate(#{<<"provider">> := P} = C) ->
    ["      candidate ", endpoint(P), ": ",
     case list(<<"mismatches">>, C) of
         [] -> "no parameter differs";
         Ms -> lists:join("; ", [[scalar(maps:get(<<"name">>, M, <<"?">>)), " wanted ",
                                  inline(maps:get(<<"wanted">>, M, null)), ", offered ",
                                  inline(maps:get(<<"offered">>, M, null))] || M <- Ms])
     end, "\n"];
candidate(Other) ->
    ["      candidate ", inline(Other), "\n"].

list(Key, R) when is_map(R) ->
    case maps:get(Key, R, []) of
        L when is_list(L) -> L;
        _ -> []
    end;
list(_Key, _R) ->
    [].

endpoint(#{<<"entity">> := E, <<"component">> := C}) ->
    iolist_to_binary([scalar(E), "/", scalar(C)]);
endpoint(Other) ->
    iolist_to_binary(inline(Other)).

service(M) ->
    iolist_to_binary([scalar(maps:get(<<"category">>, M, <<"?">>)), "/",
                      scalar(maps:get(<<"type">>, M, <<"?">>))]).

%% Any answer: scalars as `key: value', lists of objects as tables,
%% other nesting indented.
generic(R) ->
    generic(R, "").

generic(M, Indent) when is_map(M) ->
    {Scalars, Nested} = lists:partition(fun({_, V}) -> not is_map(V) andalso not is_list(V)
                                                           orelse V =:= [] end,
                                        lists:sort(maps:to_list(M))),
    [[[Indent, K, ": ", inline(V), "\n"] || {K, V} <- Scalars],
     [[Indent, K, ":\n", generic(V, [Indent, "  "])] || {K, V} <- Nested]];
generic([#{} | _] = L, Indent) ->
    case lists:all(fun is_map/1, L) of
        true ->
            Keys = lists:usort(lists:append([[K || {K, V} <- maps:to_list(M), flat(V)]
                                             || M <- L])),
            table([string:uppercase(K) || K <- Keys],
                  [[maps:get(K, M, <<"-">>) || K <- Keys] || M <- L], Indent);
        false ->
            [[Indent, "- ", inline(V), "\n"] || V <- L]
    end;
generic(L, Indent) when is_list(L) ->
    [[Indent, "- ", inline(V), "\n"] || V <- L];
generic(V, Indent) ->
    [Indent, inline(V), "\n"].

flat(V) -> not is_map(V) andalso not is_list(V) orelse V =:= [] orelse
               (is_list(V) andalso lists:all(fun(X) -> not is_map(X) andalso not is_list(X) end, V)).

inline(V) when is_map(V); is_list(V) -> evatar_json:encode(V);
inline(V) -> scalar(V).

scalar(null) -> <<"-">>;
scalar(true) -> <<"yes">>;
scalar(false) -> <<"no">>;
scalar(V) when is_binary(V) -> V;
scalar(V) when is_integer(V) -> integer_to_binary(V);
scalar(V) when is_float(V) -> float_to_binary(V, [short]);
scalar(V) when is_atom(V) -> atom_to_binary(V);
scalar(V) -> evatar_json:encode(V).

%% Rows under a header, each column as wide as its widest cell.
table(Header, Rows, Indent) ->
    Cells = [[cell(C) || C <- Row] || Row <- [Header | Rows]],
    Widths = lists:foldl(fun(Row, Ws) -> [max(W, string:length(C)) || {W, C} <- lists:zip(Ws, Row)]
                         end, [0 || _ <- Header], Cells),
    [[Indent, string:trim([[C, lists:duplicate(W - string:length(C) + 2, $\s)]
                           || {W, C} <- lists:zip(Widths, Row)], trailing), "\n"]
     || Row <- Cells].

cell(V) when is_list(V) -> unicode:characters_to_binary(inline_list(V));
cell(V) -> unicode:characters_to_binary(inline(V)).

inline_list(L) ->
    case lists:all(fun(X) -> not is_map(X) andalso not is_list(X) end, L) of
        true -> lists:join(",", [scalar(X) || X <- L]);
        false -> inline(L)
    end.

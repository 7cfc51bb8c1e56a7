%% @doc Common Test suite of the BIL generated for zigbee2mqtt's real
%% device database: every definition of zigbee-herdsman-converters (npm, the
%% exact version package-lock.json in the data directory pins, installed by
%% the suite with `npm ci'), printed by `devices.js' as the entry of
%% `bridge/devices' zigbee2mqtt publishes for it, is fed to the generator as
%% a one-device network and must give one component that EVATAR's parser
%% reads back (docs/mqtt.md section 2.2, "The real device database").
-module(mqtt_avatar_z2m_db_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").

-export([all/0, suite/0, init_per_suite/1, end_per_suite/1]).
-export([every_definition_is_valid_bil/1, sirens_get_their_services/1]).

suite() -> [{timetrap, {minutes, 10}}].

all() -> [every_definition_is_valid_bil, sirens_get_their_services].

init_per_suite(Config) ->
    case {os:find_executable("node"), os:find_executable("npm")} of
        {false, _} -> {skip, "node is not installed (scripts/ensure-deps.sh installs it)"};
        {_, false} -> {skip, "npm is not installed (scripts/ensure-deps.sh installs it)"};
        {Node, _} ->
            Dir = ?config(data_dir, Config),
            ok = npm_install(Dir),
            Out = filename:join(?config(priv_dir, Config), "devices.jsonl"),
            Cmd = io_lib:format("cd '~ts' && '~ts' devices.js > '~ts' 2>&1; echo status=$?",
                                [Dir, Node, Out]),
            Status = os:cmd(lists:flatten(Cmd)),
            {ok, Bin} = file:read_file(Out),
            case string:find(Status, "status=0") of
                nomatch -> ct:fail({devices_js_failed, Status, binary:part(Bin, 0, min(2000, byte_size(Bin)))});
                _ -> ok
            end,
            ct:log("~b definitions printed by devices.js", [length(lines(Bin))]),
            %% The file, not its lines: Common Test prints a case's Config
            %% into its log, which took 12-30 s a case for these megabytes.
            [{definitions_file, Out} | Config]
    end.

end_per_suite(_Config) ->
    ok.

%% zigbee-herdsman-converters at the version package-lock.json pins,
%% installed next to the script when missing (a clean clone).
npm_install(Dir) ->
    case filelib:is_dir(filename:join([Dir, "node_modules", "zigbee-herdsman-converters"])) of
        true ->
            ok;
        false ->
            Out = os:cmd("cd '" ++ Dir ++ "' && npm ci --no-audit --no-fund --ignore-scripts 2>&1; "
                         "echo status=$?"),
            ct:log("npm ci: ~ts", [Out]),
            case string:find(Out, "status=0") of
                nomatch -> {error, {npm_ci_failed, Out}};
                _ -> ok
            end
    end.

%% ---------------------------------------------------------------------------
%% Cases
%% ---------------------------------------------------------------------------

%% Every definition of the database gives valid BIL: one component, no
%% problem of the generated description, and a document EVATAR's parser
%% reads back. Prints how many were expressed and why the others were not.
every_definition_is_valid_bil(Config) ->
    Lines = definitions(Config),
    Results = [definition(L) || L <- Lines],
    Failed = [{Name, Why} || {error, Name, Why} <- Results],
    Expressed = length(Lines) - length(Failed),
    Reasons = lists:foldl(fun({_, Why}, Acc) -> maps:update_with(reason(Why), fun(N) -> N + 1 end, 1, Acc)
                          end, #{}, Failed),
    ct:print("~b definitions, ~b expressed; not expressed: ~p", [length(Lines), Expressed, Reasons]),
    ct:log("not expressed: ~p", [Failed]),
    ?assert(length(Lines) > 4000),
    ?assertEqual([], Failed).

%% Every siren of the database (a settable `warning' or `squawk' composite,
%% a settable binary `alarm') gets the services a user expects of it:
%% StartWarning and StopWarning, Squawk, TurnSirenOn and TurnSirenOff, in
%% valid BIL. Prints how many sirens there are.
sirens_get_their_services(Config) ->
    Sirens = [{Name, Expected, Dev} || L <- definitions(Config),
                                       {ok, #{<<"definition">> := Def} = Dev} <- [evatar_json:decode(L, #{})],
                                       Name <- [iolist_to_binary([maps:get(<<"vendor">>, Def, <<"?">>), " ",
                                                                  maps:get(<<"model">>, Def, <<"?">>)])],
                                       Expected <- [siren_services(maps:get(<<"exposes">>, Def))],
                                       Expected =/= []],
    Missing = [{Name, Expected -- Types, Problems}
               || {Name, Expected, Dev} <- Sirens,
                  {Types, Problems} <- [services([Dev])],
                  Expected -- Types =/= [] orelse Problems =/= []],
    ct:print("~b sirens, ~b with every expected service", [length(Sirens), length(Sirens) - length(Missing)]),
    ?assert(length(Sirens) >= 15),
    ?assertEqual([], Missing).

siren_services(Exposes) ->
    lists:usort(lists:append(
                  [case X of
                       #{<<"type">> := <<"composite">>, <<"property">> := <<"warning">>} ->
                           [<<"StartWarning">>, <<"StopWarning">>];
                       #{<<"type">> := <<"composite">>, <<"property">> := <<"squawk">>} ->
                           [<<"Squawk">>];
                       #{<<"type">> := <<"binary">>, <<"property">> := <<"alarm">>} ->
                           [<<"TurnSirenOn">>, <<"TurnSirenOff">>];
                       _ ->
                           []
                   end || #{<<"access">> := A} = X <- Exposes, is_integer(A), A band 2 =/= 0])).

%% The service types of the one component generated for the device, and
%% the problems (of the generation, of writing and reading its BIL back).
services(Devs) ->
    Payload = evatar_json:encode(Devs),
    {D, Problems} = mqtt_avatar:generate([{<<"zigbee2mqtt/bridge/devices">>, Payload}],
                                         #{entity_id => <<"z2m-db">>}),
    RoundTrip = case mqtt_avatar_spec:round_trip(D) of
                    ok -> [];
                    {error, M} -> [M]
                end,
    case maps:get(components, D) of
        [#{services := Services}] -> {[T || #{type := T} <- Services], Problems ++ RoundTrip};
        Cs -> {[], [{components, length(Cs)} | Problems ++ RoundTrip]}
    end.

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

definition(Line) ->
    {ok, Dev} = evatar_json:decode(Line, #{}),
    Def = maps:get(<<"definition">>, Dev, #{}),
    Name = iolist_to_binary([maps:get(<<"vendor">>, Def, <<"?">>), " ",
                             maps:get(<<"model">>, Def, <<"?">>)]),
    case Dev of
        #{<<"error">> := E} ->
            {error, iolist_to_binary([maps:get(<<"vendor">>, Dev, <<"?">>), " ",
                                      maps:get(<<"model">>, Dev, <<"?">>)]), {exposes, E}};
        _ ->
            Payload = <<"[", Line/binary, "]">>,
            {D, Problems} = mqtt_avatar:generate([{<<"zigbee2mqtt/bridge/devices">>, Payload}],
                                                 #{entity_id => <<"z2m-db">>}),
            case {Problems, maps:get(components, D)} of
                {[], [_]} ->
                    case mqtt_avatar_spec:round_trip(D) of
                        ok -> {ok, Name};
                        {error, M} -> {error, Name, {round_trip, M}}
                    end;
                {[], Cs} ->
                    {error, Name, {components, length(Cs)}};
                {_, _} ->
                    {error, Name, {problems, [{W, M} || #{what := W, message := M} <- Problems]}}
            end
    end.

reason({problems, [{W, M} | _]}) -> {W, first_words(M)};
reason({round_trip, M}) -> {round_trip, first_words(M)};
reason(Other) -> element(1, Other).

first_words(M) ->
    iolist_to_binary(lists:join(" ", lists:sublist(string:lexemes(M, " "), 6))).

definitions(Config) ->
    {ok, Bin} = file:read_file(?config(definitions_file, Config)),
    lines(Bin).

lines(Bin) ->
    [L || L <- binary:split(Bin, <<"\n">>, [global]), L =/= <<>>].

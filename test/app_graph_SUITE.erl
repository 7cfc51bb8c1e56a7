%% The app graph of docs/architecture.md section 1, read from the compiled
%% code: every app declares in its `.app' `applications' each app its
%% modules call (and calls each project app it declares), and the
%% `xref_queries' of rebar.config, which `rebar3 xref' runs, hold on the
%% code and fail, each with the calls at fault, on modules that break them.
-module(app_graph_SUITE).

-include_lib("common_test/include/ct.hrl").

-export([all/0, suite/0]).
-export([declared_dependencies/1, xref_queries_hold/1, wrong_way_calls_are_caught/1]).

%% node_config fills the other apps' environment before they start, so it
%% cannot list the apps whose pure checks it calls: they would start first
%% (node_config.app.src). No other app may call what it does not declare.
-define(UNDECLARED, #{node_config => [agent_bridge, evatar, evatar_web, mqtt_avatar, wot_avatar]}).

%% OTP applications (and Debian's jiffy, and cowboy, ranch and cowlib from
%% _deps/) the project's apps may call.
-define(OTP, [kernel, stdlib, crypto, ssl, public_key, mnesia, inets, sasl, xmerl,
              runtime_tools, compiler, tools, syntax_tools, asn1, os_mon, jiffy,
              cowboy, ranch, cowlib]).

all() -> [declared_dependencies, xref_queries_hold, wrong_way_calls_are_caught].

suite() -> [{timetrap, {minutes, 3}}].

%% @doc Each app's `applications' names every app it calls (OTP's too), and
%% each app of the release names only project apps it calls (the test kit,
%% in no release, may name apps whose types it uses); node_config's
%% exception is exactly the five apps it checks the configuration of.
declared_dependencies(_Config) ->
    Apps = project_apps(),
    Released = released_apps(),
    {ok, X} = xref:start([{xref_mode, modules}]),
    try
        ok = xref:set_default(X, [{warnings, false}, {verbose, false}]),
        _ = [{ok, _} = xref:add_application(X, code:lib_dir(A), [{name, A}])
             || A <- Apps ++ ?OTP, is_list(code:lib_dir(A))],
        {ok, AE} = xref:q(X, "AE"),
        Wrong = lists:append([check_declared(A, AE, Apps, lists:member(A, Released))
                              || A <- Apps]),
        [] = Wrong
    after
        xref:stop(X)
    end.

check_declared(App, AE, Apps, Released) ->
    Calls = lists:usort([B || {A, B} <- AE, A =:= App, B =/= App]),
    {ok, [{application, App, Props}]} =
        file:consult(filename:join(code:lib_dir(App, ebin), atom_to_list(App) ++ ".app")),
    Declared = proplists:get_value(applications, Props),
    Allowed = maps:get(App, ?UNDECLARED, []),
    [{App, calls_but_does_not_declare, Calls -- (Declared ++ Allowed)} || Calls -- (Declared ++ Allowed) =/= []]
        ++ [{App, declares_but_does_not_call, Unused}
            || Released,
               Unused <- [[D || D <- Declared, lists:member(D, Apps), not lists:member(D, Calls)]],
               Unused =/= []]
        ++ [{App, stale_exception, Allowed -- Calls} || Allowed -- Calls =/= []].

%% @doc Every query of rebar.config answers what it expects on the code as
%% it is (what `rebar3 xref' checks).
xref_queries_hold(_Config) ->
    Answers = run_queries([]),
    [] = [{Q, Expected, Answer} || {Q, Expected, Answer} <- Answers, Answer =/= Expected].

%% @doc Modules that break each rule (compiled here, never shipped) make
%% exactly the query of that rule answer with their calls: a call from a
%% library, the core, an edge or a scenario to a higher layer, a simulator
%% calling the mediator, an agent calling the demo that wires it up, an app
%% calling the test kit, the language calling another app, a call into
%% another app's internal module, and a module of no app.
wrong_way_calls_are_caught(Config) ->
    Dir = ?config(priv_dir, Config),
    Fixtures = [{bil_wrong_way_fixture, "f() -> evatar:pairings()."},
                {evatar_wrong_way_fixture, "f() -> agent_bridge:address(x)."},
                {mqtt_avatar_wrong_way_fixture, "f() -> avatar_sim:now(x)."},
                {reference_agents_wrong_way_fixture,
                 "f() -> node_config:file(). g() -> evatar_demo:stop()."},
                {node_config_wrong_way_fixture, "f() -> evatar_test_wait:until(x)."},
                {avatar_sim_wrong_way_fixture,
                 "f() -> evatar:pairings(). g() -> mqtt_avatar_z2m:parse(<<>>, <<>>)."},
                {wrong_way_fixture, "f() -> ok."}],
    ok = lists:foreach(fun({M, Body}) -> ok = compile_fixture(Dir, M, Body) end, Fixtures),
    Answers = maps:from_list([{name(Q), Answer} || {Q, _, Answer} <- run_queries([Dir])]),
    Call = fun(M, F, To) -> {{M, F, 0}, To} end,
    Expected = #{'LibrariesCallUpward' =>
                     [Call(bil_wrong_way_fixture, f, {evatar, pairings, 0})],
                 'StandaloneLibrariesCallOtherApps' =>
                     [Call(bil_wrong_way_fixture, f, {evatar, pairings, 0})],
                 'CoreCallsUpward' =>
                     [Call(evatar_wrong_way_fixture, f, {agent_bridge, address, 1})],
                 'EdgesCallUpward' =>
                     [Call(mqtt_avatar_wrong_way_fixture, f, {avatar_sim, now, 1})],
                 'ScenariosCallBoot' =>
                     [Call(reference_agents_wrong_way_fixture, f, {node_config, file, 0})],
                 'ProductCallsTestKit' =>
                     [Call(node_config_wrong_way_fixture, f, {evatar_test_wait, until, 1})],
                 'DeviceSideCallsMediator' =>
                     [Call(avatar_sim_wrong_way_fixture, f, {evatar, pairings, 0})],
                 'AgentsCallWiring' =>
                     [Call(reference_agents_wrong_way_fixture, g, {evatar_demo, stop, 0})],
                 'CallsIntoOtherAppsInternals' =>
                     [Call(avatar_sim_wrong_way_fixture, g, {mqtt_avatar_z2m, parse, 2})],
                 'ModulesOfNoApp' => [wrong_way_fixture]},
    %% Every query of rebar.config is one of these rules, each caught.
    Names = lists:sort(maps:keys(Answers)),
    Names = lists:sort(maps:keys(Expected)),
    [] = [{Name, Want, maps:get(Name, Answers)} || {Name, Want} <- maps:to_list(Expected),
                                                  maps:get(Name, Answers) =/= Want].

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

%% The queries of rebar.config, in order (the first names the sets the
%% others use), on the project's modules as `rebar3 xref' loads them, plus
%% the modules of `Extra' directories: [{Query, Expected, Answer}].
run_queries(Extra) ->
    {ok, Terms} = file:consult(filename:join(repo_root(), "rebar.config")),
    Queries = proplists:get_value(xref_queries, Terms),
    true = length(Queries) > 1,
    {ok, X} = xref:start([{xref_mode, functions}]),
    try
        ok = xref:set_default(X, [{warnings, false}, {verbose, false}]),
        _ = [{ok, _} = xref:add_directory(X, D)
             || D <- [code:lib_dir(A, ebin) || A <- project_apps()] ++ Extra],
        [begin
             {ok, Answer} = xref:q(X, Q),
             {Q, Expected, Answer}
         end || {Q, Expected} <- Queries]
    after
        xref:stop(X)
    end.

%% A query's name: the variable it assigns last ("Name := ...").
name(Query) ->
    [Last | _] = lists:reverse(string:split(Query, ",", all)),
    [Name, _] = string:split(string:trim(Last), " := "),
    list_to_atom(Name).

compile_fixture(Dir, Mod, Body) ->
    Src = lists:flatten(io_lib:format("-module(~s).~n-export([f/0, g/0]).~n~s~n~s~n",
                                      [Mod, Body, case string:find(Body, "g()") of
                                                      nomatch -> "g() -> ok.";
                                                      _ -> ""
                                                  end])),
    Forms = forms(Src),
    {ok, Mod, Beam} = compile:forms(Forms, [debug_info, binary, return_errors]),
    file:write_file(filename:join(Dir, atom_to_list(Mod) ++ ".beam"), Beam).

forms(Src) ->
    {ok, Tokens, _} = erl_scan:string(Src),
    [begin {ok, F} = erl_parse:parse_form(Ts), F end || Ts <- split_dots(Tokens, [], [])].

split_dots([], [], Acc) -> lists:reverse(Acc);
split_dots([{dot, _} = Dot | Rest], Cur, Acc) -> split_dots(Rest, [], [lists:reverse([Dot | Cur]) | Acc]);
split_dots([T | Rest], Cur, Acc) -> split_dots(Rest, [T | Cur], Acc).

%% The applications of the release (rebar.config's relx), loaded or started.
released_apps() ->
    {ok, Terms} = file:consult(filename:join(repo_root(), "rebar.config")),
    [{release, _, Apps} | _] = proplists:get_value(relx, Terms),
    [case A of {Name, _} -> Name; Name -> Name end || A <- Apps].

%% The applications under apps/.
project_apps() ->
    lists:sort([list_to_atom(filename:basename(D))
                || D <- filelib:wildcard(filename:join([repo_root(), "apps", "*"])),
                   filelib:is_dir(filename:join(D, "src"))]).

%% The root of the source tree, from where the evatar application was
%% compiled (apps/evatar/src/evatar.erl).
repo_root() ->
    Src = proplists:get_value(source, evatar:module_info(compile)),
    filename:dirname(filename:dirname(filename:dirname(filename:dirname(Src)))).

%% @doc Test support: the release and the tarball under test, built once.
%% Suites that drive EVATAR as an operator does (dist, release_commands,
%% disk_full, node_config, three_machines) need the release of `rebar3
%% release' or the tarball of `make tar'. `make test' (scripts/test.sh)
%% builds both before Common Test starts and names them in `EVATAR_REL' and
%% `EVATAR_TAR'; a suite run alone gets them from here, built the first time
%% a suite of the node asks and reused by the next ones, so a run of several
%% such suites builds each once.
%%
%% The build's output goes to a log beside it (its name in the failure).
-module(evatar_test_release).

-export([dir/0, tarball/0]).

%% @doc The release directory: `EVATAR_REL', or `rebar3 release''s
%% (_build/default/rel/evatar, under REBAR_BASE_DIR when set).
-spec dir() -> file:filename().
dir() ->
    built("EVATAR_REL", "release", ["default", "rel", "evatar"]).

%% @doc The tarball with its ERTS: `EVATAR_TAR', or `rebar3 as prod tar''s
%% (_build/prod/rel/evatar/evatar-VSN.tar.gz).
-spec tarball() -> file:filename().
tarball() ->
    Vsn = release_vsn(),
    built("EVATAR_TAR", "as prod tar", ["prod", "rel", "evatar", "evatar-" ++ Vsn ++ ".tar.gz"]).

built(Var, Args, Path) ->
    case os:getenv(Var) of
        Given when is_list(Given), Given =/= "" ->
            Given;
        _ ->
            Key = {?MODULE, Var},
            case persistent_term:get(Key, undefined) of
                undefined ->
                    Built = build(Args, filename:join([base_dir() | Path])),
                    persistent_term:put(Key, Built),
                    Built;
                Built ->
                    Built
            end
    end.

build(Args, Result) ->
    Root = evatar_test_fixtures:repo_root(),
    Log = filename:join(base_dir(),
                        "test-rebar3-" ++ lists:flatten(string:replace(Args, " ", "-", all)) ++ ".log"),
    ok = filelib:ensure_dir(Log),
    Cmd = "cd '" ++ Root ++ "' && rebar3 " ++ Args ++ " > '" ++ Log ++ "' 2>&1; echo rc=$?",
    case os:cmd(Cmd) of
        "rc=0\n" ->
            case filelib:is_file(Result) of
                true -> Result;
                false -> erlang:error({not_built, Result, Log})
            end;
        Rc ->
            erlang:error({rebar3_failed, Args, string:trim(Rc), Log})
    end.

base_dir() ->
    case os:getenv("REBAR_BASE_DIR") of
        B when is_list(B), B =/= "" -> B;
        _ -> filename:join(evatar_test_fixtures:repo_root(), "_build")
    end.

%% The release's version, from rebar.config's relx entry.
release_vsn() ->
    {ok, Terms} = file:consult(filename:join(evatar_test_fixtures:repo_root(), "rebar.config")),
    Relx = proplists:get_value(relx, Terms),
    {release, {evatar, Vsn}, _} = lists:keyfind(release, 1, Relx),
    Vsn.

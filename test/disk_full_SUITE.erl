%% Common Test suite of a node whose data directory fills (docs/ha.md
%% section 6, "A full disk"), on a real full file system: the release of
%% evatar_test_release:dir/0 (EVATAR_REL, or `rebar3 release'), node A's EVATAR_DATA_DIR a
%% 2 MiB tmpfs filled to the last block with a file, node B's an ordinary
%% directory.
%%
%% - running_node_fills: A says `disk_full' with the directory, refuses to
%%   create or delete a pairing (`{error, {disk_full, Dir}}', nothing
%%   started or stopped), keeps its pairing active, holds in memory a
%%   pairing created on B meanwhile; once the file is removed it says
%%   `disk_space_back' at its next check of the directory (fired:
%%   evatar:run_now(catalogue)), writes what it held, and the refused create
%%   succeeds. A restarted alone then has all three pairings from its disc.
%% - restart_over_full_disk: A started over its full data directory waits
%%   before mnesia starts, saying `disk_full' (no erl_crash.dump, mnesia's
%%   log untouched, no "Corrupt logfile"), and starts with its catalogue
%%   once there is room.
%%
%% Skipped, saying why, when not run as root (mount).
-module(disk_full_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").

-export([suite/0, all/0, init_per_suite/1, end_per_suite/1,
         init_per_testcase/2, end_per_testcase/2]).
-export([running_node_fills/1, restart_over_full_disk/1]).

-import(rel_node, [node_env/3, env/2, start_node/2, stop_node/2, rel/3, console_log/1]).

-define(WAIT, evatar_test_time:guard()).
-define(CRED, "<<\"secret-cred\">>").

suite() -> [{timetrap, {minutes, 5}}].

all() -> [running_node_fills, restart_over_full_disk].

init_per_suite(Config) ->
    case os:cmd("id -u") of
        "0\n" ->
            ct:timetrap({minutes, 10}),
            [{rel, evatar_test_release:dir()} | Config];
        _ ->
            {skip, "needs root: the data directory is a tmpfs mounted for the case"}
    end.

end_per_suite(_Config) ->
    ok.

init_per_testcase(Case, Config0) ->
    Config = rel_node:init_case(Case, Config0),
    Data = filename:join([?config(dir, Config), "a", "data"]),
    ok = filelib:ensure_path(Data),
    "" = os:cmd("mount -t tmpfs -o size=2m,mode=0700 tmpfs " ++ Data ++ " 2>&1"),
    [{data, Data} | Config].

end_per_testcase(_Case, Config) ->
    ok = rel_node:end_case(Config),
    _ = os:cmd("umount " ++ ?config(data, Config)),
    ok.

%% ---------------------------------------------------------------------------
%% Cases
%% ---------------------------------------------------------------------------

%% A running node over a full disk refuses changes, serves, holds what
%% peers send, and catches up when there is room.
running_node_fills(Config) ->
    Data = ?config(data, Config),
    {A, B} = two_nodes(Config),
    ok = start_node(Config, A),
    ok = start_node(Config, B),
    ok = await(fun() -> eval(Config, A, "maps:get(quorum, evatar:cluster_status()).") =:= "true" end,
               quorum),
    "{ok,<" ++ _ = strip(eval(Config, A, create("p1"))),
    fill(Data),
    ?assertEqual(lists:flatten(io_lib:format("{error,{disk_full,~p}}", [Data])),
                 strip(eval(Config, A, create("p2")))),
    ?assertEqual(lists:flatten(io_lib:format("{error,{disk_full,~p}}", [Data])),
                 strip(eval(Config, A, "evatar:delete_pairing(<<\"p1\">>)."))),
    ok = await_log(A, <<"what: disk_full">>),
    ok = await_log(A, list_to_binary("dir: " ++ Data)),
    %% Still served: p1 active on A, p2 started nowhere, the metric says so.
    "active" = eval(Config, A, "{ok, #{role := R}} = evatar:ha_status(<<\"p1\">>), R."),
    "undefined" = eval(Config, A, "evatar_registry:whereis_name(<<\"p2\">>)."),
    "true" = eval(Config, A, metric("evatar_data_dir_full 1")),
    %% Created on B meanwhile: A learns it, in memory only.
    "{ok,<" ++ _ = strip(eval(Config, B, create("p3"))),
    ok = await_log(A, <<"pairing: <<\"p3\">>, reason: disk_full, what: catalogue_held">>),
    false = lists:member(<<"p3">>, live_entries(Config, A)),
    ok = file:delete(filename:join(Data, "fill")),
    %% The room is found at the catalogue's next check of the directory
    %% (every disk_check_ms, 5 s), fired here instead of waited for.
    "ok" = eval(Config, A, "evatar:run_now(catalogue)."),
    ok = await_log(A, <<"what: disk_space_back, written: 1">>),
    "true" = eval(Config, A, metric("evatar_data_dir_full 0")),
    "{ok,<" ++ _ = strip(eval(Config, A, create("p2"))),
    %% From A's disc alone.
    ok = stop_node(B, Config),
    ok = stop_node(A, Config),
    ok = start_node(Config, A),
    ?assertEqual([<<"p1">>, <<"p2">>, <<"p3">>], live_entries(Config, A)).

%% A node restarted over its full data directory waits before mnesia
%% starts, keeps its catalogue, and starts once there is room.
restart_over_full_disk(Config) ->
    Data = ?config(data, Config),
    {A, _B} = two_nodes(Config),
    Alone = lists:keystore("EVATAR_PEERS", 1, A, {"EVATAR_PEERS", false}),
    ok = start_node(Config, Alone),
    "{ok,<" ++ _ = strip(eval(Config, Alone, create("p1"))),
    ok = stop_node(Alone, Config),
    Before = lists:sort(filelib:wildcard("*", Data)),
    Rel = ?config(rel, Config),
    Cores = filelib:wildcard(filename:join(Rel, "MnesiaCore*")),
    Dump = env("ERL_CRASH_DUMP", Alone),
    fill(Data),
    {0, _} = rel(Config, Alone, ["daemon"]),
    ok = await_log(Alone, <<"phase: boot, what: disk_full">>),
    false = filelib:is_file(Dump),
    ?assertEqual(Cores, filelib:wildcard(filename:join(Rel, "MnesiaCore*"))),
    ?assertEqual(lists:sort(["fill" | Before]), lists:sort(filelib:wildcard("*", Data))),
    ok = file:delete(filename:join(Data, "fill")),
    ok = await(fun() -> lists:member(<<"p1">>, live_entries(Config, Alone)) end, restored),
    nomatch = binary:match((console_log(Alone))(), <<"Corrupt">>),
    false = filelib:is_file(Dump).

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

%% A on the tmpfs, B beside it; one HOME (one cookie) for both.
two_nodes(Config) ->
    %% A crash dump of its own (the release's directory may hold others').
    A0 = node_env(Config, "a", [{"ERL_CRASH_DUMP",
                                 filename:join(?config(dir, Config), "a/erl_crash.dump")}]),
    B0 = node_env(Config, "b", [{"HOME", env("HOME", A0)}]),
    Peers = env("EVATAR_NODE", A0) ++ "," ++ env("EVATAR_NODE", B0),
    {lists:keystore("EVATAR_PEERS", 1, A0, {"EVATAR_PEERS", Peers}),
     lists:keystore("EVATAR_PEERS", 1, B0, {"EVATAR_PEERS", Peers})}.

create(Id) ->
    "evatar:create_pairing(<<\"" ++ Id ++ "\">>, #{agent_credential => " ++ ?CRED
        ++ ", avatar_credential => " ++ ?CRED ++ "}).".

metric(Line) ->
    "binary:match(iolist_to_binary(evatar_metrics:render()), <<\"\n" ++ Line
        ++ "\n\">>) =/= nomatch.".

%% Fills the file system to its last block.
fill(Dir) ->
    _ = os:cmd("dd if=/dev/zero of=" ++ filename:join(Dir, "fill") ++ " bs=64k 2>/dev/null"),
    {error, {disk_full, Dir}} = evatar_data_dir:check(Dir),
    ok.

eval(Config, Env, Expr) ->
    case rel(Config, Env, ["eval", Expr]) of
        {0, Out} -> string:trim(Out);
        {Rc, Out} -> ct:fail({eval, Expr, Rc, Out})
    end.

strip(S) -> [C || C <- S, C =/= $\s, C =/= $\n].

%% The live ids of a node's catalogue; none while it cannot say.
live_entries(Config, Env) ->
    Expr = "lists:flatten(lists:join($,, [binary_to_list(Id) || {Id, _, {live, _, _}} <- evatar_catalogue:entries()])).",
    case rel(Config, Env, ["eval", Expr]) of
        {0, "\"" ++ Out} ->
            [list_to_binary(Id) || Id <- string:lexemes(string:trim(Out, trailing, "\"\n"), ",")];
        {_, _} ->
            []
    end.

await(Fun, What) ->
    evatar_test_cluster:await(Fun, ?WAIT, What).

await_log(Env, Text) ->
    Log = console_log(Env),
    await(fun() -> binary:match(Log(), Text) =/= nomatch end, {log, Text}).

%% @doc Every Common Test suite of the tree (`apps/*/test/*_SUITE.erl',
%% `test/*_SUITE.erl') keeps STYLE.md's "Tests" points, read from its
%% parsed code (epp: macros expanded, included files read): suite/0 returns
%% a timetrap; each case that all/0 and groups/0 name has a comment directly
%% above its first clause (or above its -spec); and no suite waits for a
%% time: no `timer:sleep'/`ct:sleep', no `receive ... after' a literal other
%% than 0 (a deadline comes from evatar_test_time). What breaks a rule today
%% is listed in ?EXEMPT with the reason, so that a new one fails. It runs
%% with every EUnit run (`make check', `make test'); alone:
%% `rebar3 eunit --module evatar_test_suites_tests'.
-module(evatar_test_suites_tests).

-include_lib("eunit/include/eunit.hrl").

%% What may break a rule, and why: {Where, Rule, Detail, Why}. Where is a
%% suite's path from the root of the tree, or a directory (every suite
%% below it); Rule and Detail as problems/2 names them (Detail '_' for
%% any). An entry that excuses nothing fails "every exemption is needed".
-define(EXEMPT,
        [{"apps/agent_bridge/test/agent_bridge_attack_SUITE.erl", sleep, {idle_v1_keepalive, 1},
          "the pause between keepalives (a tenth of the idle timeout) is the case's subject"},
         {"apps/agent_bridge/test/agent_bridge_SUITE.erl", sleep, {flooding_client, 1},
          "samples a paused reader's mailbox over time: that waiting lets no more in is the subject"},
         {"apps/evatar/test/evatar_pairing_SUITE.erl", sleep, {answer_in_time, 3},
          "real time must pass the feedback timeout while progress signals move its deadline"},
         {"test/pause_SUITE.erl", sleep, {pause, 3},
          "the length of a SIGSTOP is what the cases are about; no event marks its end"},
         {"test/ha_SUITE.erl", receive_after, {never_started, 4},
          "a watcher sampling a node until told to stop: its period is not a wait"},
         {"test/ha_SUITE.erl", receive_after, {watch_loop, 4},
          "a watcher sampling the roles until told to stop: its period is not a wait"}]).

-type rule() :: timetrap | undocumented | no_function | sleep | receive_after | unreadable.
-type problem() :: {File :: string(), rule(), Detail :: term(), Line :: non_neg_integer()}.

%% ---------------------------------------------------------------------------
%% The tree
%% ---------------------------------------------------------------------------

%% One test a suite, named by its path, so that a failure says which; then
%% that the globs found suites in both places (none would pass) and that
%% each exemption still excuses something (a rule fixed is taken off the
%% list, a suite moved takes its entries along). Every suite is read once,
%% here.
suites_keep_the_rules_test_() ->
    Root = root(),
    Files = suites(Root),
    Problems = [{File, problems(Root, File)} || File <- Files],
    All = lists:append([Ps || {_, Ps} <- Problems]),
    [{File, ?_assertEqual([], unexcused(Ps))} || {File, Ps} <- Problems]
        ++ [{"suites found in apps/*/test and test/",
             ?_assert(lists:any(fun(F) -> lists:prefix("apps/", F) end, Files)
                      andalso lists:any(fun(F) -> lists:prefix("test/", F) end, Files))},
            {"every exemption is needed",
             ?_assertEqual([], [{Where, Rule, Detail}
                                || {Where, Rule, Detail, _Why} <- ?EXEMPT,
                                   not lists:any(fun(P) -> excuses(Where, Rule, Detail, P) end,
                                                 All)])}].

%% ---------------------------------------------------------------------------
%% The checker checked: a suite that breaks each rule is caught
%% ---------------------------------------------------------------------------

%% A suite breaking every rule, beside each form the rules accept.
a_broken_suite_is_caught_test() ->
    with_fixture(
      [{"bad_SUITE.erl",
        "-module(bad_SUITE).\n"                                     % 1
        "-define(MS, 250).\n"
        "suite() -> [{require, x}].\n"
        "all() -> [documented, bare, {group, g}, spaced, tagged, specced, missing].\n"
        "groups() -> [{g, [], [in_group, {testcase, repeated, [{repeat, 2}]}]}].\n"
        "%% @doc Checks that the documented case is documented.\n" % 6
        "documented(_) -> receive x -> ok after 0 -> ok end.\n"
        "bare(_) -> timer:sleep(10).\n"                             % 8
        "in_group(_) -> ct:sleep(1).\n"                             % 9
        "%% Repeated, and documented.\n"
        "repeated(_) -> receive x -> ok after ?MS -> ok end.\n"     % 11
        "%% A blank line below.\n"
        "\n"
        "spaced(_) -> receive x -> ok after 2 * 500 -> ok end.\n"   % 14
        "%% @private\n"
        "tagged(_) -> receive x -> ok after evatar_test_time:guard() -> ok end.\n" % 16
        "%% Documented above its spec.\n"
        "-spec specced(list()) -> ok.\n"
        "specced(_) -> ok.\n"
        "helper() -> receive after 5 -> ok end.\n"}],              % 20
      fun(Dir) ->
              File = "bad_SUITE.erl",
              ?assertEqual(lists:sort([{File, timetrap, suite, 3},
                                       {File, undocumented, bare, 8},
                                       {File, undocumented, in_group, 9},
                                       {File, undocumented, spaced, 14},
                                       {File, undocumented, tagged, 16},
                                       {File, no_function, missing, 0},
                                       {File, sleep, {bare, 1}, 8},
                                       {File, sleep, {in_group, 1}, 9},
                                       {File, receive_after, {repeated, 1}, 11},
                                       {File, receive_after, {spaced, 1}, 14},
                                       {File, receive_after, {helper, 0}, 20}]),
                           lists:sort(problems(Dir, "bad_SUITE.erl")))
      end).

%% suite/0 and the timetrap may come from an included file, and a suite
%% without suite/0 has no timetrap.
timetrap_through_an_include_test() ->
    with_fixture(
      [{"inc_SUITE.erl",
        "-module(inc_SUITE).\n-include(\"inc.hrl\").\nall() -> [].\n"},
       {"inc.hrl", "suite() -> [{timetrap, {seconds, 10 * 6}}].\n"},
       {"none_SUITE.erl", "-module(none_SUITE).\nall() -> [].\n"},
       {"broken_SUITE.erl", "-module(broken_SUITE).\nall() -> [.\n"}],
      fun(Dir) ->
              ?assertEqual([], problems(Dir, "inc_SUITE.erl")),
              ?assertMatch([{_, timetrap, suite, 0}], problems(Dir, "none_SUITE.erl")),
              ?assertMatch([{_, unreadable, _, _}], problems(Dir, "broken_SUITE.erl"))
      end).

%% An exemption excuses its rule in its file or below its directory, and
%% nothing else.
exemptions_match_path_rule_and_detail_test() ->
    P = {"apps/a/test/x_SUITE.erl", sleep, {f, 1}, 7},
    ?assert(excuses("apps/a/test/x_SUITE.erl", sleep, {f, 1}, P)),
    ?assert(excuses("apps/a/test", sleep, '_', P)),
    ?assert(excuses("apps/a/test/", sleep, '_', P)),
    ?assertNot(excuses("apps/a/tes", sleep, '_', P)),
    ?assertNot(excuses("apps/a/test/x_SUITE.erl", sleep, {g, 1}, P)),
    ?assertNot(excuses("apps/a/test/x_SUITE.erl", receive_after, '_', P)).

%% ---------------------------------------------------------------------------
%% The checker
%% ---------------------------------------------------------------------------

%% The suites, by their paths from Root.
-spec suites(file:filename()) -> [string()].
suites(Root) ->
    lists:sort(filelib:wildcard("apps/*/test/*_SUITE.erl", Root)
               ++ filelib:wildcard("test/*_SUITE.erl", Root)).

-spec unexcused([problem()]) -> [problem()].
unexcused(Problems) ->
    [P || P <- Problems,
          not lists:any(fun({Where, Rule, Detail, _Why}) -> excuses(Where, Rule, Detail, P) end,
                        ?EXEMPT)].

excuses(Where, Rule, Detail, {File, Rule, Got, _Line}) ->
    (Detail =:= '_' orelse Detail =:= Got)
        andalso (File =:= Where
                 orelse lists:prefix(string:trim(Where, trailing, "/") ++ "/", File));
excuses(_, _, _, _) ->
    false.

%% What breaks a rule in the suite File (a path from Root), each with the
%% line it is on (0: nowhere in particular).
-spec problems(file:filename(), string()) -> [problem()].
problems(Root, File) ->
    Path = filename:join(Root, File),
    Dir = filename:dirname(Path),
    Includes = [Dir, filename:join(filename:dirname(Dir), "include"), Root],
    case epp:parse_file(Path, [{includes, Includes}, {macros, ['TEST']}]) of
        {ok, Forms} ->
            case [E || {error, E} <- Forms] of
                [] -> check(File, Path, Forms);
                [{Line, _, _} = E | _] -> [{File, unreadable, E, line(Line)}];
                [E | _] -> [{File, unreadable, E, 0}]
            end;
        {error, Reason} ->
            [{File, unreadable, Reason, 0}]
    end.

check(File, Path, Forms0) ->
    Forms = erl_expand_records:module(Forms0, []),
    Funs = functions(Path, Forms),
    timetrap(File, Forms, Funs) ++ undocumented(File, Forms, Funs) ++ waits(File, Funs).

%% #{{Name, Arity} => {SourceFile, Line, Form}}, SourceFile being where the
%% function is written (the suite or a file it includes).
functions(Path, Forms) ->
    {_, Funs} = lists:foldl(
                  fun({attribute, _, file, {F, _}}, {_, Acc}) -> {F, Acc};
                     ({function, A, Name, Arity, _} = Form, {F, Acc}) ->
                          {F, Acc#{{Name, Arity} => {F, line(A), Form}}};
                     (_, Acc) -> Acc
                  end, {Path, #{}}, Forms),
    Funs.

%% (a) suite/0 returns a list with {timetrap, _}.
timetrap(File, Forms, Funs) ->
    case maps:find({suite, 0}, Funs) of
        error ->
            [{File, timetrap, suite, 0}];
        {ok, {_, Line, _}} ->
            case eval(Forms, suite, []) of
                {ok, Info} when is_list(Info) ->
                    [{File, timetrap, suite, Line} || not lists:keymember(timetrap, 1, Info)];
                {ok, Other} -> [{File, timetrap, {returns, Other}, Line}];
                {error, E} -> [{File, unreadable, {suite, E}, Line}]
            end
    end.

%% (b) Every case of all/0 and groups/0 has a comment directly above its
%% first clause, or above a -spec that is directly above it.
undocumented(File, Forms, Funs) ->
    case cases(Forms, Funs) of
        {error, E} ->
            [{File, unreadable, E, 0}];
        Cases ->
            lists:append(
              [case maps:find({Case, 1}, Funs) of
                   error -> [{File, no_function, Case, 0}];
                   {ok, {Source, Line, _}} ->
                       [{File, undocumented, Case, Line} || not documented(Source, Case, Line)]
               end || Case <- Cases])
    end.

%% The cases all/0 and groups/0 name, in their order.
cases(Forms, Funs) ->
    Groups = case maps:is_key({groups, 0}, Funs) of
                 true -> eval(Forms, groups, []);
                 false -> {ok, []}
             end,
    case {eval(Forms, all, []), Groups} of
        {{ok, All}, {ok, Gs}} when is_list(All), is_list(Gs) ->
            lists:usort(entries(All) ++ entries(Gs));
        {{ok, {skip, _}}, {ok, Gs}} when is_list(Gs) ->
            lists:usort(entries(Gs));
        Other ->
            {error, {all_or_groups, Other}}
    end.

%% The case names among Common Test's entries: a case, a group reference, a
%% repeated case, a group defined in place (its entries).
entries(Entries) ->
    lists:append([entry(E) || E <- Entries]).

entry(Case) when is_atom(Case) -> [Case];
entry({testcase, Case, _}) when is_atom(Case) -> [Case];
entry({group, _}) -> [];
entry({group, _, _}) -> [];
entry({group, _, _, _}) -> [];
entry({Name, _Props, Es}) when is_atom(Name), is_list(Es) -> entries(Es);
entry({Name, Es}) when is_atom(Name), is_list(Es) -> entries(Es);
entry(_) -> [].

%% The comment block that ends on the line above Line (or above the case's
%% -spec, if that ends there) says something: more than an edoc tag or a
%% rule of dashes.
documented(Source, Case, Line) ->
    {Comments, Specs} = layout(Source),
    Above = case maps:find(Line - 1, Specs) of
                {ok, {Case, Start}} -> Start - 1;
                _ -> Line - 1
            end,
    lists:any(fun says_something/1, block(Above, Comments)).

block(Line, Comments) ->
    case maps:find(Line, Comments) of
        {ok, Text} -> [Text | block(Line - 1, Comments)];
        error -> []
    end.

says_something(Text) ->
    case string:trim(string:trim(Text, leading, "%"), both) of
        "@doc" ++ Rest -> says_something(Rest);
        "@" ++ _ -> false;
        T -> lists:any(fun(C) -> (C >= $a andalso C =< $z) orelse (C >= $A andalso C =< $Z) end, T)
    end.

%% A source file's whole-line comments (#{Line => Text}) and its -spec
%% attributes (#{EndLine => {Name, StartLine}}), from its tokens.
layout(Source) ->
    {ok, Bin} = file:read_file(Source),
    {ok, Tokens, _} = erl_scan:string(unicode:characters_to_list(Bin), {1, 1}, [return_comments]),
    {_, Comments} = lists:foldl(
                      fun(T, {Last, Acc}) ->
                              L = line(element(2, T)),
                              Acc1 = case T of
                                         {comment, _, Text} when L =/= Last -> Acc#{L => Text};
                                         _ -> Acc
                                     end,
                              {L, Acc1}
                      end, {0, #{}}, Tokens),
    Code = [T || T <- Tokens, element(1, T) =/= comment],
    {Comments, specs(Code, #{})}.

specs([{'-', A}, {atom, _, spec}, {atom, _, Name} | Rest], Acc) ->
    {End, Rest1} = to_dot(Rest),
    specs(Rest1, Acc#{End => {Name, line(A)}});
specs([], Acc) ->
    Acc;
specs(Tokens, Acc) ->
    {_, Rest} = to_dot(Tokens),
    specs(Rest, Acc).

to_dot([{dot, A} | Rest]) -> {line(A), Rest};
to_dot([_ | Rest]) -> to_dot(Rest);
to_dot([]) -> {0, []}.

%% (c) No sleep and no `receive ... after' a literal other than 0, in every
%% function of the suite (and of the files it includes).
waits(File, Funs) ->
    lists:append([waits(File, FA, Form) || {FA, {_, _, Form}} <- lists:sort(maps:to_list(Funs))]).

waits(File, FA, Form) ->
    lists:usort(walk(Form, fun(E) -> wait(File, FA, E) end)).

wait(File, FA, {call, A, {remote, _, {atom, _, M}, {atom, _, sleep}}, [_]})
  when M =:= timer; M =:= ct ->
    [{File, sleep, FA, line(A)}];
wait(File, FA, {'receive', A, _, After, _}) ->
    case literal(After) of
        {ok, 0} -> [];
        {ok, _} -> [{File, receive_after, FA, line(A)}];
        error -> []
    end;
wait(_, _, _) ->
    [].

walk(T, Check) when is_tuple(T) ->
    Check(T) ++ lists:append([walk(E, Check) || E <- tuple_to_list(T)]);
walk(L, Check) when is_list(L) ->
    lists:append([walk(E, Check) || E <- L]);
walk(_, _) ->
    [].

%% The value of an expression made of integer literals and arithmetic.
literal({integer, _, N}) ->
    {ok, N};
literal({op, _, Op, A}) ->
    case literal(A) of
        {ok, N} -> {ok, erlang:Op(N)};
        error -> error
    end;
literal({op, _, Op, A, B}) ->
    case {literal(A), literal(B)} of
        {{ok, N}, {ok, M}} -> {ok, erlang:Op(N, M)};
        _ -> error
    end;
literal(_) ->
    error.

line(Anno) -> erl_anno:line(Anno).

%% The value of the suite's own Name(Args...), evaluated from its forms
%% (the module is not loaded): its local calls, and its calls to itself by
%% name, are evaluated the same way.
eval(Forms, Name, Args) ->
    Module = hd([M || {attribute, _, module, M} <- Forms]),
    try {ok, call(Forms, Module, Name, Args)}
    catch Class:Reason -> {error, {Name, Class, Reason}}
    end.

call(Forms, Module, Name, Args) ->
    Arity = length(Args),
    [Clauses] = [Cs || {function, _, N, A, Cs} <- Forms, N =:= Name, A =:= Arity],
    Local = {value, fun(N, As) -> call(Forms, Module, N, As) end},
    Remote = {value, fun({M, F}, As) when M =:= Module -> call(Forms, Module, F, As);
                        ({M, F}, As) -> apply(M, F, As);
                        (F, As) when is_function(F) -> apply(F, As)
                     end},
    {value, Fun, _} = erl_eval:expr({'fun', 0, {clauses, Clauses}}, erl_eval:new_bindings(),
                                    Local, Remote),
    apply(Fun, Args).

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

%% The root of the tree, from where the test kit was compiled
%% (apps/evatar_test_kit/src/evatar_test_wait.erl).
root() ->
    Src = proplists:get_value(source, evatar_test_wait:module_info(compile)),
    filename:dirname(filename:dirname(filename:dirname(filename:dirname(Src)))).

%% Files written in a new temporary directory for Test(Dir), removed after.
with_fixture(Files, Test) ->
    Dir = filename:join(filename:basedir(user_cache, "evatar_test_suites"),
                        integer_to_list(erlang:unique_integer([positive]))),
    try
        [ok = filelib:ensure_dir(filename:join(Dir, F)) || {F, _} <- Files],
        [ok = file:write_file(filename:join(Dir, F), Text) || {F, Text} <- Files],
        Test(Dir)
    after
        file:del_dir_r(Dir)
    end.

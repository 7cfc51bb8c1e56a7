%% The people's script: term checking, the text format and due times.
-module(avatar_sim_script_tests).
-include_lib("eunit/include/eunit.hrl").

%% Every form of the text format parses to the same steps as terms.
text_format_test() ->
    Text = <<"# a comment\n"
             "17:30      resident go hall\n"
             "+2m        resident go living   # trailing comment\n"
             "\n"
             "+30s       resident say keep the light on\n"
             "18:10:05   resident still\n"
             "@1h        intruder keypad 0000\n"
             "+500ms     intruder moving\r\n">>,
    {ok, Steps} = avatar_sim_script:parse(Text),
    ?assertEqual([{{at, 63000}, <<"resident">>, {go, <<"hall">>}},
                  {{delay, 120000}, <<"resident">>, {go, <<"living">>}},
                  {{delay, 30000}, <<"resident">>, {say, <<"keep the light on">>}},
                  {{at, 65405}, <<"resident">>, still},
                  {{offset, 3600000}, <<"intruder">>, {keypad, <<"0000">>}},
                  {{delay, 500}, <<"intruder">>, moving}], Steps).

%% A bad line is named by its number with a readable reason.
text_errors_test() ->
    ?assertMatch({error, {script, 2, <<"bad time", _/binary>>}},
                 avatar_sim_script:parse(<<"17:30 a go hall\n25:00 a go hall\n">>)),
    ?assertMatch({error, {script, 1, <<"unknown action", _/binary>>}},
                 avatar_sim_script:parse(<<"17:30 a fly hall\n">>)),
    ?assertMatch({error, {script, 3, <<"wrong number", _/binary>>}},
                 avatar_sim_script:parse(<<"\n\n+1s a go\n">>)),
    ?assertMatch({error, {script, 1, <<"bad unit", _/binary>>}},
                 avatar_sim_script:parse(<<"+5d a still\n">>)),
    ?assertMatch({error, {script, 1, <<"expected", _/binary>>}},
                 avatar_sim_script:parse(<<"17:30 a\n">>)).

%% Term scripts are checked step by step.
term_check_test() ->
    {ok, [{{at, 61200}, <<"a">>, still}]} = avatar_sim_script:check([{{at, "17:00"}, <<"a">>, still}]),
    ?assertMatch({error, {script, 2, _}},
                 avatar_sim_script:check([{{delay, 1}, <<"a">>, still}, {{delay, 1}, a, still}])),
    ?assertMatch({error, {script, 1, _}}, avatar_sim_script:check([{{delay, 1}, <<"a">>, fly}])),
    ?assertMatch({error, {script, 1, _}}, avatar_sim_script:check([{{at, "7pm"}, <<"a">>, still}])).

%% Due times: after the previous step, since the start, or the next time the clock shows it.
due_test() ->
    Start = 1731690000000,                       % 2024-11-15 17:00 UTC
    ?assertEqual(Start + 5000, avatar_sim_script:due({{delay, 5000}, <<"a">>, still}, Start, Start, 0)),
    ?assertEqual(Start + 7000, avatar_sim_script:due({{offset, 7000}, <<"a">>, still}, Start + 9000, Start, 0)),
    ?assertEqual(Start + 1800000, avatar_sim_script:due({{at, 63000}, <<"a">>, still}, Start, Start, 0)),
    %% 16:00 has passed: tomorrow.
    ?assertEqual(Start + 23 * 3600000, avatar_sim_script:due({{at, 57600}, <<"a">>, still}, Start, Start, 0)),
    %% 18:30 local at UTC+2 is 16:30 UTC, already passed: tomorrow.
    ?assertEqual(Start - 1800000 + 86400000,
                 avatar_sim_script:due({{at, 66600}, <<"a">>, still}, Start, Start, 120)).

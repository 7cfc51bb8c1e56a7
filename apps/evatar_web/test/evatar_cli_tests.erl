%% EUnit tests of the release commands' parsing and text (evatar_cli): the
%% commands against a running release are test/release_commands_SUITE.
-module(evatar_cli_tests).

-include_lib("eunit/include/eunit.hrl").

%% Secrets: generated (long, random) unless read from a file's first line;
%% never taken from an argument.
secrets_test() ->
    {ok, {create, <<"home">>, Body, Generated}} = evatar_cli:parse(["create", "home"]),
    ?assertEqual([<<"agent_credential">>, <<"avatar_credential">>], lists:sort(Generated)),
    #{<<"agent_credential">> := A, <<"avatar_credential">> := B} = Body,
    ?assert(byte_size(A) >= 32 andalso A =/= B),
    File = filename:join(os:getenv("TMPDIR", "/tmp"),
                         "evatar_cli_tests." ++ os:getpid()),
    ok = file:write_file(File, <<"from file\r\nsecond line\n">>),
    try
        {ok, {create, _, #{<<"agent_credential">> := <<"from file">>,
                           <<"join_timeout">> := 9000}, [<<"avatar_credential">>]}} =
            evatar_cli:parse(["create", "home", "--agent-credential-file", File,
                              "join_timeout=9000"]),
        {ok, {rotate, <<"home">>, <<"va-1">>, #{<<"credential">> := <<"from file">>}, false}} =
            evatar_cli:parse(["rotate", "home", "va-1", "--credential-file", File])
    after
        file:delete(File)
    end,
    {ok, {rotate, _, <<"agent">>, #{<<"credential">> := S}, true}} =
        evatar_cli:parse(["rotate", "home", "agent"]),
    ?assert(byte_size(S) >= 32),
    {error, _} = evatar_cli:parse(["rotate", "home", "agent", "plain-secret"]),
    {error, _} = evatar_cli:parse(["create", "home", "--agent-credential-file", "/no/such"]),
    {error, _} = evatar_cli:parse(["create", "home", "not-a-pair"]),
    {error, _} = evatar_cli:parse(["pairing"]),
    {error, _} = evatar_cli:parse([]).

%% The binding report reads as consumer -> service -> provider, and each
%% unbound entry shows its reason and what else it carries.
bindings_text_test() ->
    Report = #{bound => [#{consumer => #{entity => <<"va">>, component => <<"Lamp">>},
                           provider => #{entity => <<"av">>, component => <<"Light01">>},
                           category => <<"ACTUATOR">>, type => <<"TurnLightOn">>,
                           score => 2, candidates => 1}],
               unbound => [#{consumer => #{entity => <<"va">>, component => <<"Door">>},
                             category => <<"ACTUATOR">>, type => <<"OpenDoor">>,
                             reason => parameters_mismatch,
                             mismatched => [#{name => <<"Width">>, wanted => <<"90">>}]}]},
    Text = lists:flatten(io_lib:format("~ts", [evatar_cli:format({bindings, <<"home">>}, Report)])),
    ?assertMatch({match, _}, re:run(Text, "1 bound, 1 unbound")),
    ?assertMatch({match, _}, re:run(Text, "va/Lamp +-> +ACTUATOR/TurnLightOn +-> +av/Light01")),
    ?assertMatch({match, _}, re:run(Text, "va/Door +ACTUATOR/OpenDoor +parameters_mismatch")),
    ?assertMatch({match, _}, re:run(Text, "mismatched: .*Width")).

%% Lists of objects are tables; errors name their code and field.
generic_text_test() ->
    Text = lists:flatten(io_lib:format("~ts", [evatar_cli:format(
                                                 pairings,
                                                 [#{id => <<"home">>, state => bound, epoch => 1},
                                                  #{id => <<"flat">>, state => waiting}])])),
    ?assertMatch({match, _}, re:run(Text, "EPOCH +ID +STATE")),
    ?assertMatch({match, _}, re:run(Text, "- +flat +waiting")),
    Error = lists:flatten(io_lib:format("~ts", [evatar_cli:format_error(
                                                  #{error => <<"not_found">>, field => <<"id">>,
                                                    message => <<"no such pairing">>,
                                                    status => 404})])),
    ?assertEqual("evatar: refused: not_found (id): no such pairing\n", Error).

%% mqtt_problems without a NAME shows every Avatar's problem count and each
%% problem on a line of its own (a map column used to vanish from the
%% table); with a NAME and none it says so; times are UTC dates.
mqtt_problems_text_test() ->
    Problem = fun(Topic) -> #{what => bad_discovery, topic => Topic,
                              reason => <<"no state_topic">>, time => 1795671585650} end,
    All = [#{entity_id => <<"house">>, state => running, running => true, starts => 1,
             crashes => 0, next_delay_ms => 1000,
             problems => [Problem(<<"homeassistant/sensor/a/config">>),
                          Problem(<<"homeassistant/sensor/b/config">>)]},
           #{entity_id => <<"flat">>, state => running, running => true, starts => 1,
             crashes => 0, next_delay_ms => 1000, problems => []}],
    Text = lists:flatten(io_lib:format("~ts", [evatar_cli:format({mqtt_problems, all}, All)])),
    ?assertMatch({match, _}, re:run(Text, "PROBLEM_COUNT")),
    ?assertMatch({match, _}, re:run(Text, "house .* 2 ")),
    ?assertMatch({match, _}, re:run(Text, "Problems of house \\(2\\)")),
    [?assertMatch({match, _},
                  re:run(Text, "2026-11-26T\\d\\d:\\d\\d:\\d\\d\\.650Z  bad_discovery  "
                               "reason: no state_topic  topic: homeassistant/sensor/" ++ T ++ "/config"))
     || T <- ["a", "b"]],
    ?assertEqual(nomatch, re:run(Text, "Problems of flat")),
    One = lists:flatten(io_lib:format("~ts", [evatar_cli:format({mqtt_problems, <<"house">>},
                                                                 [Problem(<<"t">>)])])),
    ?assertMatch({match, _}, re:run(One, "^\\S+Z  bad_discovery  reason: no state_topic  topic: t\n$")),
    ?assertEqual("No problems.\n",
                 lists:flatten(io_lib:format("~ts", [evatar_cli:format({mqtt_problems, <<"flat">>},
                                                                        [])]))).

%% wot_problems reads like mqtt_problems: every WoT Avatar with its
%% problem count and its problems a line each, or one Avatar's.
wot_problems_text_test() ->
    {ok, {wot_problems, all}} = evatar_cli:parse(["wot_problems"]),
    {ok, {wot_problems, <<"wot-lamp">>}} = evatar_cli:parse(["wot_problems", "wot-lamp"]),
    Problem = #{what => unsupported_scheme, affordance => <<"blink">>,
                message => <<"a form uses coap: only the HTTP binding (http, https) is supported">>},
    All = [#{entity_id => <<"wot-lamp">>, state => running, running => true, starts => 1,
             crashes => 0, next_delay_ms => 1000, problems => [Problem]}],
    Text = lists:flatten(io_lib:format("~ts", [evatar_cli:format({wot_problems, all}, All)])),
    ?assertMatch({match, _}, re:run(Text, "wot-lamp .* 1 ")),
    ?assertMatch({match, _}, re:run(Text, "Problems of wot-lamp \\(1\\)\n  -  unsupported_scheme  "
                                          "affordance: blink  message: a form uses coap")),
    ?assertEqual("No WoT Avatars on this node.\n",
                 lists:flatten(io_lib:format("~ts", [evatar_cli:format({wot_problems, all}, [])]))),
    ?assertEqual("No problems.\n",
                 lists:flatten(io_lib:format("~ts", [evatar_cli:format({wot_problems, <<"x">>}, [])]))).

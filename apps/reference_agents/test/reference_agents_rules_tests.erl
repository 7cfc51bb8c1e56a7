%% @doc EUnit tests of the rules file parser (docs/rules.md): every kind of
%% line, the shipped rules file, and malformed files refused with an error
%% naming the line.
-module(reference_agents_rules_tests).

-include_lib("eunit/include/eunit.hrl").

parse(Lines) ->
    reference_agents_rules:parse(iolist_to_binary([[L, "\n"] || L <- Lines])).

error_line(Lines) ->
    {error, #{line := L, message := M}} = parse(Lines),
    ?assert(is_binary(M)),
    L.

shipped_rules_file_parses_test() ->
    File = filename:join(code:priv_dir(reference_agents), "home.rules"),
    {ok, R} = reference_agents_rules:parse_file(File),
    ?assertEqual([<<"holiday">>, <<"away">>, <<"sleep">>], reference_agents_rules:policies(R)),
    [#{name := <<"intruder">>, parts := [<<"motion">>, <<"failed_authorisation">>],
       unless := [<<"authorisation">>], window := 120000}] = reference_agents_rules:complex(R).

simple_line_test() ->
    {ok, R} = parse(["simple failed when PasswordInput WrongPassword=yes Room=\"the hall\""]),
    ?assertMatch([#{name := <<"failed">>, service := <<"PasswordInput">>,
                    params := [{<<"WrongPassword">>, <<"yes">>}, {<<"Room">>, <<"the hall">>}],
                    line := 1}], reference_agents_rules:simple(R)).

simple_alternatives_share_a_name_test() ->
    {ok, R} = parse(["simple on when VoiceCommand Text=\"keep the light on\"",
                     "simple on when VoiceCommand Text=\"leave the light on\""]),
    ?assertEqual(2, length(reference_agents_rules:simple(R))).

complex_line_with_units_test_() ->
    [?_assertMatch({ok, _}, parse(["simple a when A", "simple b when B",
                                   "complex c when a and b within " ++ W]))
     || W <- ["90 s", "90s", "2 min", "2m", "1 h", "3 hours", "10 seconds"]].

complex_window_in_ms_test() ->
    {ok, R} = parse(["simple a when A", "simple b when B", "simple x when X",
                     "complex c when a and b within 90 s unless x"]),
    ?assertMatch([#{window := 90000, unless := [<<"x">>]}], reference_agents_rules:complex(R)).

policy_lines_test() ->
    {ok, R} = parse(["simple m when MotionDetected",
                     "policy p on m in hall if dark and between 22:00 and 06:30 do "
                     "photos 2, email \"Seen \\\"you\\\"\" with photos, sms \"hi\", alarm, "
                     "say \"go\", light all on",
                     "policy p at 18:05 do light living off"]),
    [#{trigger := {activity, <<"m">>, <<"hall">>},
       conditions := [dark, {between, 1320, 390}],
       actions := [{photos, 2}, {email, <<"Seen \"you\"">>, with_photos}, {sms, <<"hi">>},
                   alarm, {say, <<"go">>}, {light, <<"all">>, on}]},
     #{trigger := {at, 1085}, conditions := [], actions := [{light, <<"living">>, off}]}] =
        reference_agents_rules:policy_rules(<<"p">>, R).

comments_blank_lines_and_crlf_test() ->
    {ok, R} = reference_agents_rules:parse(
                <<"# a comment\r\n\r\n   \r\nsimple m when Motion # trailing\r\n">>),
    ?assertMatch([#{line := 4}], reference_agents_rules:simple(R)).

format_rule_reads_back_test() ->
    Text = "policy p on m in hall if dark do photos 2, email \"x\" with photos, alarm",
    {ok, R} = parse(["simple m when M", Text]),
    [Rule] = reference_agents_rules:policy_rules(<<"p">>, R),
    ?assertEqual(list_to_binary(Text),
                 iolist_to_binary(["policy ", reference_agents_rules:format_rule(Rule)])).

%% Each malformed file is refused with the number of its bad line.
malformed_lines_name_the_line_test_() ->
    Ok = "simple m when MotionDetected",
    Cases = [{2, [Ok, "complex c when m and nope within 2 min"]},
             {2, [Ok, "simple m2 when"]},
             {3, [Ok, "", "explode now"]},
             {2, [Ok, "policy p on m do explode"]},
             {2, [Ok, "policy p on m do photos 99"]},
             {2, [Ok, "policy p at 25:00 do alarm"]},
             {2, [Ok, "policy p on m do say \"unterminated"]},
             {2, [Ok, "complex c when m within 2 min"]},
             {2, [Ok, "complex c when m and m within 2 min"]},
             {3, [Ok, "simple n when N", "complex c when m and n within 0 s"]},
             {3, [Ok, "simple n when N", "complex c when m and n within 5 fortnights"]},
             {2, [Ok, "complex m when m and m within 1 min"]},
             {2, [Ok, "complex c when m and m2 within 1 min", "simple m2 when M2"]},
             {2, [Ok, "policy p on nothing do alarm"]},
             {2, [Ok, "simple 9lives when X"]},
             {2, [Ok, "policy p on m if sunny do alarm"]},
             {2, [Ok, "policy p on m do light living dim"]},
             {2, [Ok, "policy p on m do email \"x\" with pictures"]},
             {2, [Ok, "simple x when X A=1 A=2"]},
             {2, [Ok, "policy p on m do alarm alarm"]},
             {1, ["= = ="]}],
    [?_assertEqual(Line, error_line(Lines)) || {Line, Lines} <- Cases].

a_simple_name_reused_by_a_complex_is_refused_test() ->
    {error, #{line := 4, message := M}} =
        parse(["simple a when A", "simple b when B", "simple c when C",
               "complex a when b and c within 1 min"]),
    ?assertNotEqual(nomatch, binary:match(M, <<"already defined on line 1">>)).

invalid_utf8_names_the_line_test() ->
    {error, #{line := 2}} = reference_agents_rules:parse(<<"simple a when A\nsimple \xff when B\n">>).

too_large_test() ->
    {error, #{line := 0}} = reference_agents_rules:parse(binary:copy(<<"#">>, 1048577)).

format_error_test() ->
    {error, E} = parse(["simple m when M", "policy p on m do explode"]),
    <<"home.rules:2: unknown action explode", _/binary>> =
        reference_agents_rules:format_error("home.rules", E),
    <<"line 2: ", _/binary>> = reference_agents_rules:format_error(E),
    <<"nope.rules: cannot read: ", _/binary>> =
        reference_agents_rules:format_error("nope.rules", {file, enoent}).

missing_file_test() ->
    ?assertEqual({error, {file, enoent}},
                 reference_agents_rules:parse_file("/nonexistent/dir/home.rules")).

%% Words from the file never become atoms.
no_atoms_from_the_file_test() ->
    Words = [io_lib:format("zz_unheard_of_word_~b", [I]) || I <- lists:seq(1, 50)],
    Text = ["simple m when M\n" | [["policy ", W, " on m do say \"", W, "\"\n"] || W <- Words]],
    {ok, _} = reference_agents_rules:parse(iolist_to_binary(Text)),
    Before = erlang:system_info(atom_count),
    {ok, _} = reference_agents_rules:parse(iolist_to_binary(
                                             [Text, "simple zz_another_new_one when Q\n"])),
    {error, _} = reference_agents_rules:parse(<<"zz_bad_word_never_seen at all\n">>),
    ?assertEqual(Before, erlang:system_info(atom_count)).

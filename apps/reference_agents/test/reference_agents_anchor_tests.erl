%% @doc EUnit tests of anchoring (percept to symbol, maintained over time)
%% and of the coordinator's lexicon built from two robots' anchors.
-module(reference_agents_anchor_tests).

-include_lib("eunit/include/eunit.hrl").

see(Colour, X, Y, T, As) ->
    reference_agents_anchor:perceive(#{colour => Colour, position => {X, Y}, time => T}, As).

acquire_then_track_test() ->
    A0 = reference_agents_anchor:new(<<"r1">>),
    {A1, {acquired, <<"r1-obj1">>}} = see(<<"red">>, 1000, 450, 0, A0),
    {A2, {tracked, <<"r1-obj1">>}} = see(<<"RED">>, 1040, 470, 500, A1),
    {A3, {acquired, <<"r1-obj2">>}} = see(<<"green">>, 550, 1050, 600, A2),
    [#{symbol := <<"r1-obj1">>, position := {1040, 470}, last_seen := 500, seen := 2,
       first_seen := 0},
     #{symbol := <<"r1-obj2">>}] = reference_agents_anchor:anchors(A3).

same_colour_far_away_is_another_object_while_fresh_test() ->
    {A1, _} = see(<<"red">>, 100, 100, 0, reference_agents_anchor:new(<<"r">>)),
    {_, {acquired, <<"r-obj2">>}} = see(<<"red">>, 1500, 1000, 1000, A1).

a_stale_anchor_is_reacquired_elsewhere_test() ->
    {A1, _} = see(<<"red">>, 100, 100, 0, reference_agents_anchor:new(<<"r">>)),
    {A2, {reacquired, <<"r-obj1">>}} = see(<<"red">>, 1500, 1000, 60000, A1),
    {ok, #{position := {1500, 1000}}} = reference_agents_anchor:lookup(<<"r-obj1">>, A2).

moved_follows_the_carried_object_test() ->
    {A1, _} = see(<<"blue">>, 1450, 800, 0, reference_agents_anchor:new(<<"r">>)),
    A2 = reference_agents_anchor:moved(<<"r-obj1">>, {1000, 1300}, 9000, A1),
    ?assertEqual([#{symbol => <<"r-obj1">>, colour => <<"blue">>, position => {1000, 1300}}],
                 reference_agents_anchor:describe(A2)),
    ?assertEqual(A2, reference_agents_anchor:moved(<<"nope">>, {0, 0}, 1, A2)).

reports() ->
    [{<<"va1">>, [#{symbol => <<"r1-obj1">>, colour => <<"blue">>, position => {1440, 790}},
                  #{symbol => <<"r1-obj2">>, colour => <<"red">>, position => {990, 460}}]},
     {<<"va2">>, [#{symbol => <<"r2-obj1">>, colour => <<"green">>, position => {560, 1040}},
                  #{symbol => <<"r2-obj2">>, colour => <<"red">>, position => {1010, 440}}]}].

lexicon_merges_the_same_object_test() ->
    L = reference_agents_lexicon:build(reports()),
    ?assertEqual([<<"blue-ball">>, <<"green-ball">>, <<"red-ball">>], reference_agents_lexicon:words(L)),
    {ok, #{names := Names, position := {1000, 450}}} = reference_agents_lexicon:entry(<<"red-ball">>, L),
    ?assertEqual(#{<<"va1">> => <<"r1-obj2">>, <<"va2">> => <<"r2-obj2">>}, Names),
    ?assertEqual({ok, <<"r2-obj2">>}, reference_agents_lexicon:local(<<"red-ball">>, <<"va2">>, L)),
    ?assertEqual(error, reference_agents_lexicon:local(<<"blue-ball">>, <<"va2">>, L)),
    ?assertEqual({ok, <<"green-ball">>}, reference_agents_lexicon:word_for(<<"va2">>, <<"r2-obj1">>, L)).

two_objects_of_one_colour_get_two_words_test() ->
    L = reference_agents_lexicon:build(
          [{<<"a">>, [#{symbol => <<"a1">>, colour => <<"red">>, position => {100, 100}},
                      #{symbol => <<"a2">>, colour => <<"red">>, position => {1800, 1300}}]}]),
    ?assertEqual([<<"red-ball-1">>, <<"red-ball-2">>], reference_agents_lexicon:words(L)).

agreement_test() ->
    L = reference_agents_lexicon:build(reports()),
    ?assert(reference_agents_lexicon:agreed([L, L, L])),
    ?assertNot(reference_agents_lexicon:agreed([L, tl(L)])),
    ?assertNot(reference_agents_lexicon:agreed([])).

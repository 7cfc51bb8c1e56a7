%% @doc The collaborative LEGO robots scenario end to end (paper, section
%% 3.1): two simulated robots join EVATAR over TCP, two VAs embody
%% themselves in them, a coordinator VA without an Avatar has them explore,
%% builds and distributes the lexicon, and commands every ball to its zone.
%% Checked against the simulated arena's truth.
-module(evatar_demo_lego_scenario_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").

-export([all/0, suite/0, init_per_suite/1, end_per_suite/1]).
-export([every_robot_embodied/1, lexicon_agreed_by_all_three/1, anchors_in_the_lexicon/1,
         every_ball_at_its_target/1, other_balls_other_targets/1]).

suite() -> [{timetrap, {seconds, 120}}].

all() ->
    [every_robot_embodied, lexicon_agreed_by_all_three, anchors_in_the_lexicon,
     every_ball_at_its_target, other_balls_other_targets].

init_per_suite(Config) ->
    {ok, Outcome} = evatar_demo_lego_scenario:run(#{seed => 7, timeout => 90000}),
    [{outcome, Outcome} | Config].

end_per_suite(_Config) ->
    ok.

%% @doc Both robot VAs passed the embodiment test (every tested relationship
%% answered; GoTo is left for its first use).
every_robot_embodied(Config) ->
    #{robots := Robots} = ?config(outcome, Config),
    [#{verdict := embodied, failed := [], untested := [#{service := <<"GoTo">>}]} =
         maps:get(embodiment, R) || R <- maps:values(Robots)],
    ?assertEqual(2, maps:size(Robots)).

%% @doc The coordinator and both robot VAs hold the same lexicon, with a
%% word for each of the three balls.
lexicon_agreed_by_all_three(Config) ->
    #{coordinator := #{mind := #{lexicon := L, phase := done}}, robots := Robots} =
        ?config(outcome, Config),
    Lexicons = [L | [maps:get(lexicon, maps:get(mind, R)) || R <- maps:values(Robots)]],
    ?assert(reference_agents:lexicons_agreed(Lexicons)),
    ?assertEqual([<<"blue-ball">>, <<"green-ball">>, <<"red-ball">>],
                 reference_agents_lexicon:words(L)).

%% @doc Every anchor a robot VA made (its own symbols) is named in the
%% lexicon, by the word of its colour.
anchors_in_the_lexicon(Config) ->
    #{coordinator := #{mind := #{lexicon := L}}, robots := Robots} = ?config(outcome, Config),
    [begin
         {ok, W} = reference_agents_lexicon:word_for(Name, Sym, L),
         ?assertEqual(<<(reference_agents_activity:keyword(C))/binary, "-ball">>, W)
     end || {Name, #{mind := #{anchors := As}}} <- maps:to_list(Robots),
            #{symbol := Sym, colour := C} <- As],
    ?assert(lists:sum([length(maps:get(anchors, maps:get(mind, R))) || R <- maps:values(Robots)]) >= 3).

%% @doc The arena's truth: every ball lies in the zone the task gives its
%% colour, and no robot holds one.
every_ball_at_its_target(Config) ->
    #{arena := #{balls := Balls}, summary := #{given_up := GivenUp}} = ?config(outcome, Config),
    Targets = evatar_demo_lego_scenario:default_targets(),
    ?assertEqual([], GivenUp),
    [?assertEqual({C, maps:get(C, Targets), none}, {C, Z, H})
     || #{colour := C, zone := Z, held_by := H} <- Balls].

%% @doc Another task (the balls to other zones) and another seed: the
%% coordinator follows the task it is given.
other_balls_other_targets(_Config) ->
    Targets = #{<<"red">> => <<"nw">>, <<"green">> => <<"n">>, <<"blue">> => <<"se">>},
    {ok, #{arena := #{balls := Balls}}} =
        evatar_demo_lego_scenario:run(#{seed => 11, targets => Targets, timeout => 90000}),
    [?assertEqual({C, maps:get(C, Targets)}, {C, Z}) || #{colour := C, zone := Z} <- Balls].

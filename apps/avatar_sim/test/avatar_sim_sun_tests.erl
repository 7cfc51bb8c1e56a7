%% Sunrise and sunset against published times for London (UTC, no DST).
-module(avatar_sim_sun_tests).
-include_lib("eunit/include/eunit.hrl").

-define(LONDON, #{lat => 51.5074, lon => -0.1278, utc_offset => 0}).

near(Expected, Seconds) -> abs(Seconds - Expected) =< 180.

hm(H, M) -> H * 3600 + M * 60.

%% Midsummer: sunrise 03:43 UTC, sunset 20:21 UTC.
midsummer_test() ->
    {Rise, Set} = avatar_sim_sun:times({2024, 6, 21}, ?LONDON),
    ?assert(near(hm(3, 43), Rise)),
    ?assert(near(hm(20, 21), Set)).

%% Midwinter: sunrise 08:04, sunset 15:53.
midwinter_test() ->
    {Rise, Set} = avatar_sim_sun:times({2024, 12, 21}, ?LONDON),
    ?assert(near(hm(8, 4), Rise)),
    ?assert(near(hm(15, 53), Set)).

%% Equinox: sunset about 18:12 UTC.
equinox_test() ->
    {_, Set} = avatar_sim_sun:times({2024, 3, 20}, ?LONDON),
    ?assert(near(hm(18, 12), Set)).

%% The UTC offset moves local times by as much.
offset_test() ->
    {R0, S0} = avatar_sim_sun:times({2024, 12, 21}, ?LONDON),
    {R1, S1} = avatar_sim_sun:times({2024, 12, 21}, ?LONDON#{utc_offset => 60}),
    ?assertEqual({R0 + 3600, S0 + 3600}, {R1, S1}).

%% Polar night and midnight sun.
polar_test() ->
    ?assertEqual({43200, 43200}, avatar_sim_sun:times({2024, 12, 21}, #{lat => 80, lon => 0, utc_offset => 0})),
    ?assertEqual({0, 86400}, avatar_sim_sun:times({2024, 6, 21}, #{lat => 80, lon => 0, utc_offset => 0})).

%% Dark before sunrise and from sunset on.
is_dark_test() ->
    ?assert(avatar_sim_sun:is_dark({2024, 11, 15}, hm(17, 0), ?LONDON)),
    ?assertNot(avatar_sim_sun:is_dark({2024, 11, 15}, hm(12, 0), ?LONDON)),
    ?assert(avatar_sim_sun:is_dark({2024, 11, 15}, hm(5, 0), ?LONDON)).

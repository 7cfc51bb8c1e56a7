%% @doc Common Test suite of avatar_sim_scene: the worlds running on the
%% node as the dashboard draws them, found through the application
%% environment's `dashboard_scenes' as evatar_web finds them.
-module(avatar_sim_scene_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").

-export([all/0, suite/0, init_per_suite/1, end_per_suite/1]).
-export([home_and_arena/1]).

suite() -> [{timetrap, {minutes, 1}}].

all() -> [home_and_arena].

init_per_suite(Config) ->
    {ok, _} = application:ensure_all_started(avatar_sim),
    Config.

end_per_suite(_Config) ->
    ok.

scenes() ->
    {ok, {M, F, A}} = application:get_env(avatar_sim, dashboard_scenes),
    apply(M, F, A).

%% @doc A home (a person in the kitchen, a light turned on, a photo taken)
%% and an arena: the floor plan's rooms with devices, light, motion and
%% people; the arena's robots, balls and zones; gone once stopped. (Worlds
%% another suite left running in this node come first and are let be.)
home_and_arena(Config) ->
    Before = length(scenes()),
    Spool = filename:join(?config(priv_dir, Config), "spool"),
    {ok, Home} = avatar_sim:start_home(#{people => #{<<"alice">> => <<"kitchen">>},
                                         spool => Spool}),
    {ok, Arena} = avatar_sim:start_arena(#{}),
    [#{kind := <<"home">>, rooms := Rooms, people := [#{name := <<"alice">>,
                                                       room := <<"kitchen">>}],
       alarm := #{attempts := 0, keypad := []}, photos := []},
     #{kind := <<"arena">>, width := 2000, height := 1500, robots := [R1, _],
       balls := [_, _, _], zones := [#{name := <<"nw">>} | _]}] = lists:nthtail(Before, scenes()),
    [#{people := [<<"alice">>], light := <<"off">>, devices := Devices}] =
        [R || #{name := <<"kitchen">>} = R <- Rooms],
    ?assert(lists:member(<<"light">>, Devices)),
    #{entity := <<"lego-nxt-01">>, x := _, y := _, heading := _} = R1,
    %% Every value is one the JSON encoder takes.
    ok = json_ready(scenes()),
    ok = avatar_sim:stop(Home),
    ok = avatar_sim:stop(Arena),
    Before = length(scenes()).

json_ready(M) when is_map(M) ->
    _ = [ok = json_ready(K) || K <- maps:keys(M), not is_atom(K)],
    lists:foreach(fun(V) -> ok = json_ready(V) end, maps:values(M));
json_ready(L) when is_list(L) -> lists:foreach(fun(V) -> ok = json_ready(V) end, L);
json_ready(B) when is_binary(B); is_number(B); is_boolean(B); B =:= null -> ok;
json_ready(Other) -> ct:fail({not_json, Other}).

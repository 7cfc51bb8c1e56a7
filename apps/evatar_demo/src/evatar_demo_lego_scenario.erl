%% @doc Internal. The collaborative LEGO robots scenario (paper, section
%% 3.1): two simulated robots join EVATAR, each in its own pairing; two VAs
%% embody themselves in them (lego_va.xml) and a coordinator VA without an
%% Avatar sends them to explore, builds the lexicon from what they anchored,
%% distributes it, and has them pick every ball and place it at its target
%% zone. VA-to-VA messages go directly between the Erlang processes.
-module(evatar_demo_lego_scenario).

-export([start/1, run_to_end/2, outcome/1, stop/1, run/1, default_targets/0]).
-export([anchors/0]).

-export_type([opts/0]).

-type opts() :: #{speed => number(), seed => integer(), explore => pos_integer(),
                  targets => #{binary() => binary()}, feedback_timeout => pos_integer(),
                  print => boolean(), io => pid() | atom(), timeout => pos_integer()}.

-define(COORDINATOR, <<"coordinator">>).

%% @doc The task: which zone each colour of ball goes to.
-spec default_targets() -> #{binary() => binary()}.
default_targets() ->
    #{<<"red">> => <<"se">>, <<"green">> => <<"nw">>, <<"blue">> => <<"n">>}.

%% @doc Sets everything up and starts the story: the robots join, the VAs
%% embody themselves, and the coordinator takes over.
-spec start(opts()) -> {ok, evatar_demo_scenario:scenario()} | {error, term()}.
start(Opts) ->
    %% Slow while the VAs test their bodies, at full speed after.
    {ok, S1} = evatar_demo_scenario:start(
                 (maps:with([print, io], Opts))#{name => robots, clock => #{speed => 2}}),
    Clock = evatar_demo_scenario:get(clock, S1),
    Robots = [{N, <<"robot", (integer_to_binary(N))/binary>>,
               <<"robot-secret-", (integer_to_binary(N))/binary>>,
               <<"va-secret-", (integer_to_binary(N))/binary>>} || N <- [1, 2]],
    Timeout = maps:get(feedback_timeout, Opts, 5000),
    S2 = lists:foldl(fun({_, P, AvCred, VaCred}, Acc) ->
                             evatar_demo_scenario:pairing(
                               P, #{agent_credential => VaCred, avatar_credential => AvCred,
                                    feedback_timeout => Timeout}, Acc)
                     end, S1, Robots),
    {ok, Arena} = avatar_sim:start_arena(
                    #{clock => Clock, seed => maps:get(seed, Opts, 1),
                      endpoints => [evatar_demo_scenario:endpoint(S2)],
                      robots => [#{pairing => P, credential => AvCred} || {_, P, AvCred, _} <- Robots]}),
    S3 = evatar_demo_scenario:add(arena, Arena,
                                  evatar_demo_scenario:add(avatars, [Arena], S2)),
    #{zones := Zones} = avatar_sim:state(Arena),
    Names = [va_name(N) || {N, _, _, _} <- Robots],
    Targets = maps:get(targets, Opts, default_targets()),
    evatar_demo_scenario:say(S3, info,
                             io_lib:format("two LEGO robots joined pairings robot1 and robot2; "
                                           "task: ~s",
                                           [lists:join(", ", [[C, " ball to zone ", Z]
                                                              || {C, Z} <- lists:sort(maps:to_list(Targets))])])),
    {Coordinator, S4} = evatar_demo_scenario:start_va(
                          #{name => ?COORDINATOR, mind => reference_agents_coordinator,
                            mind_args => #{robots => Names, targets => Targets,
                                           zones => maps:from_list([{Z, {X, Y}} || #{name := Z, x := X, y := Y} <- Zones]),
                                           explore => maps:get(explore, Opts, 120)},
                            body => none}, S3),
    Lego = evatar_demo_scenario:body("lego_va.xml"),
    {Vas, S5} = lists:foldl(
                  fun({N, P, _, VaCred}, {Acc, SAcc}) ->
                          Name = va_name(N),
                          Body = Lego#{entity_id := Name},
                          {Va, SAcc1} = evatar_demo_scenario:start_va(
                                          #{name => Name, mind => reference_agents_robot_mind,
                                            mind_args => #{name => Name, body => Body,
                                                           coordinator => ?COORDINATOR},
                                            body => Body, pairing => P, credential => VaCred,
                                            peers => #{?COORDINATOR => Coordinator}}, SAcc),
                          {Acc#{Name => Va}, SAcc1}
                  end, {#{}, S4}, Robots),
    ok = reference_agents:introduce(Coordinator, Vas),
    S6 = evatar_demo_scenario:add(coordinator, Coordinator,
                                  evatar_demo_scenario:add(robot_vas, Vas, S5)),
    %% For the dashboard (anchors/0): the robot VAs of the running story.
    %% evatar_web finds anchors/0 in this application's environment
    %% (dashboard_scenes), there only once the application is loaded: the
    %% demo calls this module without starting or loading it.
    ok = load_application(),
    ok = application:set_env(evatar_demo, robot_vas, Vas),
    Embodied = [evatar_demo_scenario:await_va_state(Va, [embodied], 20000, {embodied, Name})
                || {Name, Va} <- maps:to_list(Vas)],
    case [E || {error, _} = E <- Embodied] of
        [] ->
            ok = avatar_sim:set_speed(Clock, maps:get(speed, Opts, 40)),
            {ok, S6};
        [E | _] ->
            ok = stop(S6),
            E
    end.

load_application() ->
    case application:load(evatar_demo) of
        ok -> ok;
        {error, {already_loaded, evatar_demo}} -> ok
    end.

va_name(N) -> <<"golem-lego-va-0", (integer_to_binary(N))/binary>>.

%% @doc Waits (real time) for the coordinator to say every ball is placed.
-spec run_to_end(evatar_demo_scenario:scenario(), pos_integer()) ->
          {ok, map()} | {error, timeout}.
run_to_end(_S, Timeout) ->
    receive
        {reference_agents, ?COORDINATOR, {done, Summary}} -> {ok, Summary}
    after Timeout -> {error, timeout}
    end.

%% @doc The three VAs' views and the arena's truth.
-spec outcome(evatar_demo_scenario:scenario()) -> map().
outcome(S) ->
    Vas = evatar_demo_scenario:get(robot_vas, S),
    #{coordinator => reference_agents:inspect(evatar_demo_scenario:get(coordinator, S)),
      robots => maps:map(fun(_, Va) -> reference_agents:inspect(Va) end, Vas),
      arena => avatar_sim:state(evatar_demo_scenario:get(arena, S)),
      story => reference_agents_narrator:events(evatar_demo_scenario:narrator(S))}.

-spec stop(evatar_demo_scenario:scenario()) -> ok.
stop(S) ->
    ok = application:unset_env(evatar_demo, robot_vas),
    evatar_demo_scenario:stop(S).

%% @doc The names the robot VAs of the running story anchored, as a scene
%% for the dashboard (docs/dashboard.md; named in the application
%% environment's `dashboard_scenes', so evatar_web need not depend on this
%% application): each VA's symbols with the colour and place it last saw.
-spec anchors() -> [map()].
anchors() ->
    Vas = lists:sort(maps:to_list(application:get_env(evatar_demo, robot_vas, #{}))),
    Agents = [#{name => Name,
                anchors => [#{symbol => Sym, colour => C, x => X, y => Y, seen => N}
                            || #{symbol := Sym, colour := C, position := {X, Y}, seen := N}
                                   <- maps:get(anchors, Mind, [])]}
              || {Name, Va} <- Vas, #{mind := Mind} <- [inspect(Va)]],
    case Agents of
        [] -> [];
        _ -> [#{kind => <<"anchors">>, agents => Agents}]
    end.

inspect(Va) ->
    try reference_agents:inspect(Va)
    catch exit:_ -> #{}
    end.

%% @doc Start, wait for the end (10 minutes of real time at most), outcome,
%% stop.
-spec run(opts()) -> {ok, map()} | {error, term()}.
run(Opts) ->
    case start(Opts) of
        {ok, S} ->
            try run_to_end(S, maps:get(timeout, Opts, 600000)) of
                {ok, Summary} -> {ok, (outcome(S))#{summary => Summary}};
                {error, timeout} -> {error, {timeout, outcome(S)}}
            after
                stop(S)
            end;
        {error, _} = E -> E
    end.

%% @doc Runs the `make demo' narratives (evatar_demo:main/1) with
%% their output captured, and checks that each tells the story it promises
%% and cleans up after itself: the smart home on holiday (the default), the
%% robots, and the BIL and EVATAR tour (the binding, the round trips, the
%% timeout, the NotBound refusal, the operator's tables); `--keep' prints
%% how to reach the node.
-module(evatar_demo_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").

-export([all/0, suite/0, init_per_suite/1, end_per_suite/1, init_per_testcase/2,
         end_per_testcase/2]).

-define(APPS, [agent_bridge, evatar, avatar_sim]).

-export([demo_from_scratch/1, demo_on_running_node/1, home_demo/1, robots_demo/1,
         keep_prints_the_remote_shell_command/1]).

suite() ->
    [{timetrap, {seconds, 90}}].

all() ->
    [demo_from_scratch, demo_on_running_node, home_demo, robots_demo,
     keep_prints_the_remote_shell_command].

%% The suites that run after this one load the applications themselves.
init_per_suite(Config) ->
    Loaded = [App || {App, _, _} <- application:loaded_applications()],
    [{loaded_before, [App || App <- ?APPS, lists:member(App, Loaded)]} | Config].

end_per_suite(Config) ->
    _ = [application:unload(App) || App <- ?APPS,
                                    not lists:member(App, ?config(loaded_before, Config))],
    ok.

init_per_testcase(_Case, Config) ->
    #{level := Level} = logger:get_primary_config(),
    [{logger_level, Level} | Config].

end_per_testcase(_Case, _Config) ->
    _ = application:stop(agent_bridge),
    _ = application:stop(evatar),
    _ = application:stop(avatar_sim),
    ok.

%% @doc On a node where EVATAR is not running, the tour (`bil') starts it,
%% narrates every step, returns ok and stops what it started.
demo_from_scratch(Config) ->
    _ = application:stop(agent_bridge),
    _ = application:stop(evatar),
    {ok, Output} = evatar_demo_capture:run(["bil"]),
    ok = check_story(Output),
    ?assertNot(lists:keymember(agent_bridge, 1, application:which_applications())),
    ?assertNot(lists:keymember(evatar, 1, application:which_applications())),
    ?assertEqual(?config(logger_level, Config), maps:get(level, logger:get_primary_config())).

%% @doc On a node already running EVATAR with other pairings, the tour uses
%% its own listener and pairing, and leaves the rest running as it was.
demo_on_running_node(Config) ->
    ok = evatar_test_node:start([]),
    {ok, _} = evatar_test_fixtures:create_pairing(<<"bystander">>, #{}),
    Listeners = agent_bridge:listeners(),
    Pairings = [Id || #{id := Id} <- evatar:pairings()],
    true = lists:member(<<"bystander">>, Pairings),
    {ok, Output} = evatar_demo_capture:run(["bil"]),
    ok = check_story(Output),
    ?assert(lists:keymember(agent_bridge, 1, application:which_applications())),
    ?assertEqual(Pairings, [Id || #{id := Id} <- evatar:pairings()]),
    ?assertEqual(Listeners, agent_bridge:listeners()),
    ?assertEqual(?config(logger_level, Config), maps:get(level, logger:get_primary_config())),
    ok = evatar:delete_pairing(<<"bystander">>).

%% @doc The default demo: the holiday evening narrated with simulated
%% times (each perceived activity, decision and actuation), ending with
%% where the e-mail and its photos are; nothing left running.
home_demo(Config) ->
    _ = application:stop(agent_bridge),
    _ = application:stop(evatar),
    {ok, Output} = evatar_demo_capture:run([]),
    ct:log("~ts", [Output]),
    Patterns = ["\\[18:0[0-9]:[0-9]{2}\\] house-va +DECIDE +policy holiday at 18:00 if dark do light living on",
                "\\[21:4[0-9]:[0-9]{2}\\] house-va +PERCEIVE +activity failed_authorisation in hall",
                "PERCEIVE +complex activity intruder in hall: motion at 21:4",
                "DECIDE +policy holiday on intruder do photos 3, email \"INTRUSION\" with photos",
                "ACT +take 3 photos \\(TakePhoto via CameraEmulator01\\)",
                "ACT +sound the alarm",
                "PERCEIVE +e-mail written to .*/spool/[0-9]{8}-[0-9]{6}-[0-9]+\\.eml \\(3 attachment",
                "Where it all landed",
                "e-mail \"INTRUSION\": /.*\\.eml\n    attached photo-[0-9]{4}\\.png: /.*/spool/photos/photo-[0-9]{4}\\.png"],
    ?assertEqual([], [P || P <- Patterns, re:run(Output, P) =:= nomatch]),
    ?assertEqual(?config(logger_level, Config), maps:get(level, logger:get_primary_config())),
    ?assertNot(lists:keymember(agent_bridge, 1, application:which_applications())).

%% @doc `robots': the robots explore, the lexicon is agreed, every ball is
%% placed, and the summary says so.
robots_demo(_Config) ->
    {ok, Output} = evatar_demo_capture:run(["robots"]),
    ct:log("~ts", [Output]),
    Expected = ["coordinator", "every robot VA is embodied", "lexicon built: blue-ball (blue), "
                "green-ball (green), red-ball (red)", "every ball is at its target",
                "held by all three VAs: yes", "red ball at (1750, 250): zone se"],
    ?assertEqual([], [E || E <- Expected, string:find(Output, E) =:= nomatch]).

%% @doc `--keep' leaves the node running after the demo, prints the node's
%% name and the command to reach it from a remote shell, and returns once
%% evatar_demo:stop/0 is called.
keep_prints_the_remote_shell_command(Config) ->
    Old = group_leader(),
    Capture = evatar_demo_capture:start(),
    true = group_leader(Capture, self()),
    Self = self(),
    Demo = spawn(fun() -> Self ! {result, self(), evatar_demo:main(["bil", "--keep"])} end),
    true = group_leader(Old, self()),
    {ok, Text} = evatar_demo_scenario:await(
                   fun() ->
                           T = evatar_demo_capture:peek(Capture),
                           case string:find(T, "evatar_demo:stop()") of
                               nomatch -> false;
                               _ -> {true, T}
                           end
                   end, 60000, kept),
    ct:log("~ts", [Text]),
    ?assert(is_process_alive(Demo)),
    ?assertNotEqual(nomatch, string:find(Text, "The node keeps running")),
    case node() of
        nonode@nohost -> ok;
        Node -> ?assertNotEqual(nomatch, string:find(Text, "-remsh " ++ atom_to_list(Node)))
    end,
    ok = evatar_demo:stop(),
    receive {result, Demo, Result} -> ?assertEqual(ok, Result)
    after evatar_test_time:guard() -> ct:fail(demo_did_not_return)
    end,
    ?assertEqual(?config(logger_level, Config), maps:get(level, logger:get_primary_config())).

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

check_story(Output) ->
    ct:log("~ts", [Output]),
    Expected = [%% Part one (BIL) is still there.
                "1. BIL descriptions and signals",
                "refused in",
                %% Joining, and the Welcome's join timeout.
                "agent  golem-lego-va-01 joined",
                "avatar lego-nxt-01 joined",
                "must describe itself within 5000 ms",
                %% The binding: what is bound and what is not.
                "bound: 23 consumer/provider pairs",
                "unbound: 1",
                "lego-nxt-01/TouchSensor",
                %% The round trips, fine and coarse grain.
                "feedback MotorA -> MotorAEmulator: ACTUATOR/ACTION FEEDBACK Done=yes",
                "round trip",
                "progress ForwardBehaviour -> ForwardBehaviourEmulator",
                "Value=55",
                "feedback EVATAR -> GrabBehaviourEmulator",
                "EVATAR/Timeout",
                "ERROR/NotBound",
                "rebound at once: 25 bound, 0 unbound",
                %% The operator's tables.
                "Bound (25)",
                "pairing deleted, listener stopped"],
    Missing = [E || E <- Expected, string:find(Output, E) =:= nomatch],
    ?assertEqual([], Missing),
    %% Table columns are as wide as their widest cell: match loosely.
    Patterns = ["golem-lego-va-01/MotorAEmulator +-> lego-nxt-01/MotorA +ACTUATOR/Rotate",
                "round trip [0-9]+\\.[0-9]{2} ms",
                "PAIRING +STATE +AGENT",
                "demo-lego +bound +golem-lego-va-01 +1 +2 +25 +0 +0",
                "timeouts +1\n",
                "error NotBound +1\n"],
    ?assertEqual([], [P || P <- Patterns, re:run(Output, P) =:= nomatch]),
    %% Nothing of the demo is left on the node.
    {error, not_found} = agent_bridge_address(),
    ok.

agent_bridge_address() ->
    case lists:keymember(agent_bridge, 1, application:which_applications()) of
        true -> agent_bridge:address(evatar_demo_tour);
        false -> {error, not_found}
    end.

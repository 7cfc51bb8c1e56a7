%% @doc Public API of the demo: the wiring around the reference VAs
%% (reference_agents) that gives them a world to live in, on one node that
%% runs EVATAR: listeners, pairings, the simulated Avatars (avatar_sim), a
%% mosquitto for the MQTT home, and the paper's scenarios
%% (docs/scenarios.md). {@link holiday/1}, {@link robots/1} and
%% {@link rooms/1} run a scenario to its end and return what happened.
%%
%% It is also the `make demo' entry point (scripts/demo.sh calls {@link
%% main/1} with the words of `DEMO_ARGS'). Without arguments it runs the
%% smart-home holiday scenario with an intrusion and narrates every
%% perceived activity, decision and actuation with its simulated time;
%% `robots' runs the collaborative LEGO robots instead, `bil' the tour of
%% BIL and EVATAR over TCP; `mqtt' runs the holiday with the house's
%% devices on MQTT (a mosquitto of the demo's own). `--keep' leaves the
%% node running for inspection from a remote shell. docs/scenarios.md says
%% what a person sees.
-module(evatar_demo).

-export([main/1, inspect/0, stop/0]).
-export([holiday/1, robots/1, rooms/1]).
-export([quietly/1]).

-define(KEPT, {?MODULE, kept}).

%% @doc Runs the demonstration chosen by `Args' and returns `ok' (with
%% `--keep', only after {@link stop/0}, or never if the node is stopped
%% first).
-spec main([string()]) -> ok.
main(Args) ->
    case parse(Args, #{what => home, keep => false, mqtt => false}) of
        {ok, #{what := What, keep := Keep}} ->
            case quietly(fun() -> run(What, Keep) end) of
                ok ->
                    ok;
                {error, Message} ->
                    io:format(standard_error, "The demo could not start: ~ts~n", [Message]),
                    erlang:halt(1)
            end;
        {error, Message} ->
            io:format(standard_error, "~s~n~s", [Message, usage()]),
            erlang:halt(2)
    end.

parse([], #{mqtt := true, what := home} = Acc) -> {ok, Acc#{what := mqtt}};
parse([], #{mqtt := true}) -> {error, "the mqtt option runs the smart home on holiday only"};
parse([], Acc) -> {ok, Acc};
parse(["--keep" | Rest], Acc) -> parse(Rest, Acc#{keep := true});
parse(["mqtt" | Rest], Acc) -> parse(Rest, Acc#{mqtt := true});
parse([Word | Rest], Acc) when Word =:= "home"; Word =:= "holiday" ->
    parse(Rest, Acc#{what := home});
parse(["robots" | Rest], Acc) -> parse(Rest, Acc#{what := robots});
parse(["bil" | Rest], Acc) -> parse(Rest, Acc#{what := bil});
parse(["rooms" | Rest], Acc) -> parse(Rest, Acc#{what := rooms});
parse([Other | _], _Acc) -> {error, ["unknown demo option: ", Other]}.

usage() ->
    "usage: make demo [DEMO_ARGS=\"[home|mqtt|robots|rooms|bil] [--keep]\"]\n"
    "  home     the smart home on holiday, with an intrusion (the default)\n"
    "  mqtt     the same, with the house's devices on MQTT (a mosquitto of the demo's own)\n"
    "  robots   two LEGO robots and a coordinator: explore, agree on a lexicon, place the balls\n"
    "  rooms    one VA per room: lights follow the resident, voice commands override\n"
    "  bil      the tour of BIL and EVATAR over TCP\n"
    "  --keep   keep the node running afterwards, for a remote shell; Ctrl-C or a SIGTERM\n"
    "           to make demo stops it (scripts/demo.sh --help)\n".

%% @doc Internal (the demo's modules). Runs Fun with the logger at `error':
%% pairings log a warning for every feedback timeout (the tour provokes
%% one on purpose), and application starts and joins their info reports,
%% which would bury the narration. The level is restored however Fun ends.
-spec quietly(fun(() -> T)) -> T.
quietly(Fun) ->
    #{level := Level} = logger:get_primary_config(),
    ok = logger:set_primary_config(level, error),
    try Fun()
    after ok = logger:set_primary_config(level, Level)
    end.

run(bil, Keep) ->
    ok = evatar_demo_tour:main(),
    keep(Keep, none);
run(mqtt, Keep) ->
    header("The easy smart home on holiday, its devices on MQTT (paper, section 3.2)",
           ["Nobody is home. This time the house's devices are MQTT devices, as most cheap "
            "smart-home devices are today (zigbee2mqtt, Tasmota, ESPHome): the demo starts a "
            "mosquitto broker on a loopback port, and each simulated device (camera, light "
            "switches, socket lamp, microphone, time sensor, speaker, keypad) has its own MQTT "
            "session, publishes its Home Assistant discovery config and its state, and takes "
            "commands on its topics. The MQTT Avatar discovers them, writes their BIL "
            "description and joins EVATAR; the notifier, a PC, joins over TCP. The house VA is "
            "the one of the plain `make demo', unchanged: it runs the holiday policy of "
            "apps/reference_agents/priv/home.rules, lights on and off in the evening when it "
            "is dark, and at 21:40 somebody who does not know the code tries the door.",
            "Simulated time runs 1000 times faster than real time; each line starts with it."]),
    case evatar_demo_holiday:start(#{print => true, spool => "spool", mqtt => true}) of
        {ok, S} ->
            ok = evatar_demo_holiday:run_until(S, "22:05"),
            #{home := Home, va := Va} = Outcome = evatar_demo_holiday:outcome(S),
            mqtt_summary(Outcome, Keep),
            home_summary(Home, Va),
            ok = login_note(Keep, S),
            finish(Keep, S, fun evatar_demo_holiday:stop/1);
        {error, {broker, Message}} ->
            {error, Message};
        {error, Why} ->
            {error, io_lib:format("~tp", [Why])}
    end;
run(home, Keep) ->
    header("The easy smart home on holiday (paper, section 3.2)",
           ["Nobody is home. The house VA is embodied in the simulated smart home (camera, "
            "light switches, socket lamp, microphone, notifier, time sensor, speaker, keypad) "
            "through EVATAR over TCP. It runs the holiday policy of "
            "apps/reference_agents/priv/home.rules: lights on and off in the evening, when it is "
            "dark, so that the house looks inhabited; and at 21:40 somebody who does not know "
            "the code tries the door.",
            "Simulated time runs 1000 times faster than real time; each line starts with it."]),
    {ok, S} = evatar_demo_holiday:start(#{print => true, spool => "spool"}),
    ok = evatar_demo_holiday:run_until(S, "22:05"),
    #{home := Home, va := Va} = evatar_demo_holiday:outcome(S),
    home_summary(Home, Va),
    ok = login_note(Keep, S),
    finish(Keep, S, fun evatar_demo_holiday:stop/1);
run(rooms, Keep) ->
    header("Light control, one VA per room (paper, section 3.2)",
           ["The living room, the kitchen and the bedroom each have their own VA, embodied in "
            "that room's devices. The resident comes home before sunset and walks about; the "
            "room VAs switch lights on when it is dark, hand the resident over to each other, "
            "and obey voice commands in the living room."]),
    {ok, S} = evatar_demo_rooms:start(#{print => true, spool => "spool"}),
    ok = evatar_demo_rooms:run_until(S, "16:45"),
    #{home := #{light_log := Log}} = evatar_demo_rooms:outcome(S),
    section("What the lights did"),
    [io:format("  ~s  ~-8s ~s~n", [reference_agents_narrator:format_time(T), Room, State])
     || #{time := T, room := Room, state := State} <- Log],
    finish(Keep, S, fun evatar_demo_rooms:stop/1);
run(robots, Keep) ->
    header("Collaborative LEGO robots (paper, section 3.1)",
           ["Two simulated LEGO robots and three balls of unknown colours in a 2 x 1.5 m arena. "
            "Two VAs are embodied in the robots through EVATAR; a coordinator VA has no body. "
            "The robots explore and anchor what they see, the coordinator builds a lexicon from "
            "their reports and shares it, then has them place every ball in its zone.",
            "Simulated time runs 40 times faster than real time."]),
    {ok, S} = evatar_demo_lego_scenario:start(#{print => true}),
    Result = evatar_demo_lego_scenario:run_to_end(S, 300000),
    Outcome = evatar_demo_lego_scenario:outcome(S),
    robots_summary(Result, Outcome),
    finish(Keep, S, fun evatar_demo_lego_scenario:stop/1).

%% A kept house is for a VA of one's own (docs/clients.md): a pairing has
%% one agent, so the house VA, its story told, leaves it.
login_note(false, _S) ->
    ok;
login_note(true, S) ->
    ok = reference_agents:stop_va(evatar_demo_scenario:get(va, S)),
    #{endpoint := {Ip, Port}, pairing := Pairing, credential := Credential} =
        evatar_demo_holiday:login(S),
    section("Your own VA"),
    io:format("  The house VA has left the pairing: a VA of your own can take its place.~n"
              "  EVATAR listens on ~s:~b, pairing ~s, credential ~s (docs/clients.md).~n",
              [inet:ntoa(Ip), Port, Pairing, Credential]).

finish(false, S, Stop) ->
    ok = Stop(S),
    ok;
finish(true, S, Stop) ->
    ok = keep(true, S),
    ok = Stop(S).

keep(false, _S) ->
    ok;
keep(true, S) ->
    persistent_term:put(?KEPT, {S, self()}),
    Node = atom_to_list(node()),
    section("The node keeps running"),
    case node() of
        nonode@nohost ->
            io:format("  This node has no name (start it with -name to connect a remote shell).~n");
        _ ->
            [_, Host] = string:split(Node, "@"),
            NameFlag = case net_kernel:longnames() of
                           true -> "-name";
                           false -> "-sname"
                       end,
            io:format("  Node: ~s~n"
                      "  From another terminal:  erl ~s probe@~s -remsh ~s~n"
                      "  Then for example:       evatar:print_pairings().  "
                      "evatar_demo:inspect().~n", [Node, NameFlag, Host, Node])
    end,
    io:format("  Stop it with Ctrl-C here, a SIGTERM to make demo (scripts/demo.sh --help), "
              "or evatar_demo:stop(). from the remote shell.~n"),
    receive
        {?MODULE, stop} ->
            _ = persistent_term:erase(?KEPT),
            ok
    end.

%% @doc Ends a demo kept with `--keep': it cleans up and `make demo' exits.
-spec stop() -> ok.
stop() ->
    case persistent_term:get(?KEPT, none) of
        none -> ok;
        {_S, Pid} -> Pid ! {?MODULE, stop}, ok
    end.

%% @doc On a node kept with `--keep': what each VA of the demo says of
%% itself (its state, embodiment and mind).
-spec inspect() -> ok.
inspect() ->
    case persistent_term:get(?KEPT, none) of
        none ->
            io:format("no demo scenario is kept on this node~n");
        {none, _Pid} ->
            io:format("the bil tour keeps no VA; evatar:print_pairings() shows the node~n");
        {S, _Pid} ->
            Vas = lists:append([maps:values(X) || X <- [safe_get(room_vas, S), safe_get(robot_vas, S)]])
                ++ [V || K <- [va, coordinator], V <- [safe_get(K, S)], is_pid(V)],
            [io:format("~p~n", [reference_agents:inspect(Va)]) || Va <- Vas],
            ok
    end.

safe_get(Key, S) ->
    try evatar_demo_scenario:get(Key, S)
    catch error:{badkey, _} -> #{}
    end.

%% @doc Runs the smart-home scenario with one house VA (holiday policy and
%% an intrusion by default) and returns what happened.
-spec holiday(evatar_demo_holiday:opts()) -> {ok, map()} | {error, term()}.
holiday(Opts) -> evatar_demo_holiday:run(Opts).

%% @doc Runs the collaborative robots scenario to its end.
-spec robots(evatar_demo_lego_scenario:opts()) -> {ok, map()} | {error, term()}.
robots(Opts) -> evatar_demo_lego_scenario:run(Opts).

%% @doc Runs the one-VA-per-room light control scenario until `until'
%% (16:45 by default) and returns what happened.
-spec rooms(evatar_demo_rooms:opts()) -> {ok, map()} | {error, term()}.
rooms(Opts) ->
    case evatar_demo_rooms:start(maps:remove(until, Opts)) of
        {ok, S} ->
            try
                ok = evatar_demo_rooms:run_until(S, maps:get(until, Opts, "16:45")),
                {ok, evatar_demo_rooms:outcome(S)}
            after
                evatar_demo_rooms:stop(S)
            end;
        {error, _} = E -> E
    end.

%% ---------------------------------------------------------------------------
%% Summaries
%% ---------------------------------------------------------------------------

home_summary(#{emails := Emails, photos := Photos, light_log := Log, played := Played,
               spool := Spool}, #{mind := #{activities := Activities}}) ->
    section("Where it all landed"),
    io:format("  spool directory: ~s~n", [filename:absname(Spool)]),
    lists:foreach(
      fun(#{file := File, subject := Subject, attachments := Attached}) ->
              io:format("  e-mail \"~s\": ~s~n", [Subject, File]),
              [io:format("    attached ~s: ~s~n", [Id, photo_file(Id, Photos)]) || Id <- Attached]
      end, Emails),
    case Emails of
        [] -> io:format("  no e-mail was sent~n");
        _ -> ok
    end,
    %% The house logs changes only: an "off" sent to a light already off is
    %% answered (Changed=false) but changes nothing.
    io:format("  lights changed state: ~b times (~s); commands to a light already in"
              " that state change nothing~n",
              [length(Log), lists:join(", ", [[reference_agents_narrator:format_time(T), " ", R, " ",
                                                atom_to_list(St)]
                                               || #{time := T, room := R, state := St} <- Log])]),
    io:format("  the speaker played: ~s~n",
              [lists:join("; ", [[W] || #{what := W, volume := V} <- Played, V > 0])]),
    io:format("  activities perceived: ~b (~s)~n",
              [length(Activities),
               lists:join(", ", lists:usort([A || #{activity := A} <- Activities]))]),
    io:format("~n  Open the .eml file with any mail reader to see the photos of the intruder.~n").

mqtt_summary(#{mqtt := #{host := Host, port := Port},
               mqtt_avatar := #{status := Status, problems := Problems}}, Keep) ->
    section("The MQTT side"),
    io:format("  broker: mosquitto at ~s:~b, started for the demo~s~n",
              [Host, Port, case Keep of
                               true -> "";
                               false -> " and stopped with it"
                           end]),
    io:format("  MQTT Avatar: ~b components discovered (~s)~n",
              [length(maps:get(components, Status, [])),
               lists:join(", ", [to_list(C) || C <- maps:get(components, Status, [])])]),
    io:format("  its problems: ~s~n",
              [case [P || #{what := W} = P <- Problems, W =/= unused_override] of
                   [] -> "none";
                   Ps -> lists:join("; ", [maps:get(message, P, io_lib:format("~p", [W]))
                                           || #{what := W} = P <- Ps])
               end]),
    case Keep of
        true ->
            io:format("  watch the devices talk: mosquitto_sub -h ~s -p ~b -t '#' -v~n", [Host, Port]);
        false ->
            ok
    end.

to_list(B) when is_binary(B) -> binary_to_list(B);
to_list(Other) -> io_lib:format("~p", [Other]).

photo_file(Id, Photos) ->
    case [F || #{id := I, file := F} <- Photos, I =:= Id] of
        [F | _] -> F;
        [] -> "(not in the spool)"
    end.

robots_summary(Result, #{coordinator := #{mind := C}, robots := Robots,
                         arena := #{balls := Balls}}) ->
    section("Outcome"),
    case Result of
        {ok, _} -> ok;
        {error, timeout} -> io:format("  the coordinator did not finish in time~n")
    end,
    Lexicons = [maps:get(lexicon, C) | [maps:get(lexicon, maps:get(mind, R)) || R <- maps:values(Robots)]],
    io:format("  lexicon: ~s~n", [case maps:get(lexicon, C) of
                                      undefined -> "none";
                                      L -> reference_agents:lexicon_text(L)
                                  end]),
    io:format("  held by all three VAs: ~s~n",
              [case reference_agents:lexicons_agreed(Lexicons) of true -> "yes"; false -> "NO" end]),
    [io:format("  ~s ball at (~b, ~b): ~s~n",
               [Col, round(X), round(Y), case Z of none -> "not in a zone"; _ -> ["zone ", Z] end])
     || #{colour := Col, x := X, y := Y, zone := Z} <- Balls],
    ok.

header(Title, Paragraphs) ->
    io:format("~n~s~n~s~n", [Title, lists:duplicate(length(Title), $=)]),
    [io:format("~s~n", [wrap(P, 100)]) || P <- Paragraphs],
    io:format("~n").

section(Title) ->
    io:format("~n~s~n~s~n", [Title, lists:duplicate(length(Title), $-)]).

wrap(Text, Width) ->
    Words = string:lexemes(Text, " "),
    {Lines, Last} = lists:foldl(fun(W, {Ls, ""}) -> {Ls, W};
                                   (W, {Ls, Cur}) when length(Cur) + 1 + length(W) > Width ->
                                        {[Cur | Ls], W};
                                   (W, {Ls, Cur}) -> {Ls, Cur ++ " " ++ W}
                                end, {[], ""}, Words),
    lists:join("\n", lists:reverse([Last | Lines])).

%% @doc Internal. The mind of a room VA for automatic light control (paper,
%% section 3.2), pure. Each room has its own VA embodied in that room's
%% devices (motion camera, light switch or socket lamp, time sensor, maybe
%% a microphone). Motion in the room when it is dark switches the light on
%% and tells the other room VAs that the user is here; a VA told so checks
%% its own room for motion (a ReadMotion request) and switches its light
%% off only when nobody moves there. Voice commands override the policy:
%% keep the light on, keep it off, or back to automatic. The activity names
%% it reacts to come from the rules file: `motion', `no_motion',
%% `keep_light_on', `keep_light_off' and `light_auto'. A room VA whose body
%% has the house's time sensor shares each time reading with the others.
-module(reference_agents_room).
-behaviour(reference_agents_mind).

-export([init/1, probe/2, choose/3, inspect/1]).

-export_type([args/0]).

-type args() :: #{room := binary(),
                  body := bil:description(),
                  rules := reference_agents_rules:rules(),
                  peers := [binary()]}.

-record(r, {room :: binary(),
            peers :: [binary()],
            emulators :: reference_agents_emulator:table(),
            recogniser :: reference_agents_activity:state(),
            daytime = reference_agents_daytime:new() :: reference_agents_daytime:daytime(),
            light = unknown :: on | off | unknown,
            override = none :: none | keep_on | keep_off,
            occupied = false :: boolean(),
            checks = 0 :: non_neg_integer(),
            log = [] :: [map()]}).

-spec init(args()) -> {ok, #r{}}.
init(#{room := Room, body := Body, rules := Rules, peers := Peers}) ->
    {ok, #r{room = Room, peers = Peers, emulators = reference_agents_emulator:new(Body),
            recogniser = reference_agents_activity:new(Rules)}}.

-spec probe(reference_agents_emulator:link(), #r{}) -> reference_agents_embodiment:probe().
probe(#{type := Type}, _R) ->
    reference_agents_home:probe_service(Type, room).

-spec choose(reference_agents_mind:observation(), integer(), #r{}) ->
          {#r{}, [reference_agents_mind:act()]}.
choose({embodied, _}, _Now, R) ->
    {R, read_time(R)};
choose({disembodied, Why}, _Now, R) ->
    {R, [{narrate, info, ["light control paused: ", Why]}]};
choose({percept, #{service := S, params := Ps} = P}, Now, R) ->
    case reference_agents_activity:keyword(S) of
        K when K =:= <<"timeofday">>; K =:= <<"sunset">> ->
            {D, _} = reference_agents_daytime:update(Ps, R#r.daytime),
            {R#r{daytime = D}, [{tell, Peer, {time, Ps}} || Peer <- R#r.peers]};
        _ -> perceive(P, Now, R)
    end;
choose({result, read_time, {ok, Ps}}, _Now, R) ->
    {D, _} = reference_agents_daytime:update(Ps, R#r.daytime),
    {R#r{daytime = D}, [{tell, Peer, {time, Ps}} || Peer <- R#r.peers]};
choose({result, {light, State, Why}, {ok, _}}, Now, R) ->
    {log(Now, {light, State, Why}, R),
     [{narrate, perceive, io_lib:format("the ~s light is ~s", [R#r.room, State])},
      {notify, {light, R#r.room, State}}]};
choose({result, {check, From}, {ok, Ps}}, Now, R) ->
    case lists:keyfind(<<"Motion">>, 1, Ps) of
        {_, <<"no">>} when R#r.override =:= keep_on ->
            {R, [{narrate, decide, "no motion here, but the light is kept on by voice command"}]};
        {_, <<"no">>} ->
            {log(Now, {handoff, From}, R#r{light = off}),
             [{narrate, decide, ["no motion in the ", R#r.room, " since ", From,
                                 " took over: switching off"]}
              | light(off, {handoff, From}, R)]};
        _ ->
            {R, [{narrate, decide, ["somebody still moves in the ", R#r.room,
                                    ": the light stays on"]}]}
    end;
choose({result, {light, State, _}, {failed, Why}}, _Now, R) ->
    %% The switch may or may not have changed: find out at the next motion.
    {R#r{light = unknown},
     [{narrate, perceive, io_lib:format("switching the light ~s failed: ~s", [State, Why])}]};
choose({result, Tag, {failed, Why}}, _Now, R) ->
    {R, [{narrate, perceive, io_lib:format("~0p failed: ~s", [Tag, Why])}]};
choose({result, _Tag, {ok, _}}, _Now, R) ->
    {R, []};
choose({progress, _, _}, _Now, R) ->
    {R, []};
choose({message, From, {entered, Room}}, Now, R) ->
    handoff(From, Room, Now, R);
choose({message, _From, {time, Ps}}, _Now, R) ->
    {D, _} = reference_agents_daytime:update(Ps, R#r.daytime),
    {R#r{daytime = D}, []};
choose({message, _From, _Other}, _Now, R) ->
    {R, []};
choose({signal, _}, _Now, R) ->
    {R, []}.

-spec inspect(#r{}) -> map().
inspect(R) ->
    #{room => R#r.room, light => R#r.light, override => R#r.override, occupied => R#r.occupied,
      dark => reference_agents_daytime:dark(R#r.daytime), log => lists:reverse(R#r.log)}.

perceive(#{service := Service, params := Ps, time := T}, Now, R) ->
    {Rec, Found} = reference_agents_activity:perceive(
                     #{service => Service, params => Ps, time => T}, R#r.recogniser),
    lists:foldl(fun(#{activity := A}, {RAcc, Acts}) ->
                        {RAcc1, More} = activity(A, Now, RAcc),
                        {RAcc1, Acts ++ More}
                end, {R#r{recogniser = Rec}, []}, Found).

activity(<<"motion">>, Now, #r{room = Room} = R) ->
    %% The other rooms hear about it when somebody arrives, not at every
    %% repeated report of the same person moving.
    {Seen, Tell} = case R#r.occupied of
                       false -> {[{narrate, perceive, ["motion in the ", Room]}],
                                 [{tell, P, {entered, Room}} || P <- R#r.peers]};
                       true -> {[], []}
                   end,
    R1 = R#r{occupied = true},
    Dark = reference_agents_daytime:dark(R#r.daytime),
    if
        R#r.light =:= on ->
            {R1, Seen ++ Tell};
        R#r.override =:= keep_off ->
            {R1, Seen ++ [{narrate, decide, "the light is kept off by voice command"} || Seen =/= []]
                 ++ Tell};
        not Dark ->
            {R1, Seen ++ [{narrate, decide, "it is not dark: no light needed"} || Seen =/= []]
                 ++ Tell};
        true ->
            {log(Now, {motion, on}, R1#r{light = on}),
             Seen ++ [{narrate, decide, "dark and somebody here: light on"}
                      | light(on, motion, R)] ++ Tell}
    end;
activity(<<"no_motion">>, _Now, R) ->
    {R#r{occupied = false}, [{narrate, perceive, ["nobody moves in the ", R#r.room, " any more"]}]};
activity(<<"keep_light_on">>, Now, R) ->
    {log(Now, {voice, keep_on}, R#r{override = keep_on, light = on}),
     [{narrate, perceive, "voice command: keep the light on"},
      {narrate, decide, "the light stays on whatever the policy says"} | light(on, voice, R)]};
activity(<<"keep_light_off">>, Now, R) ->
    {log(Now, {voice, keep_off}, R#r{override = keep_off, light = off}),
     [{narrate, perceive, "voice command: keep the light off"},
      {narrate, decide, "the light stays off whatever the policy says"} | light(off, voice, R)]};
activity(<<"light_auto">>, Now, R) ->
    {log(Now, {voice, none}, R#r{override = none}),
     [{narrate, perceive, "voice command: lights automatic"},
      {narrate, decide, "back to the automatic light policy"}]};
activity(_Other, _Now, R) ->
    {R, []}.

handoff(From, Room, Now, #r{light = Light, override = Override} = R) ->
    Told = {narrate, perceive, [From, " says the user is now in the ", Room]},
    if
        Light =/= on ->
            {R, []};
        Override =:= keep_on ->
            {log(Now, {handoff_ignored, From}, R),
             [Told, {narrate, decide, "the light is kept on by voice command: ignoring"}]};
        true ->
            case reference_agents_emulator:find(<<"SENSOR">>, <<"ReadMotion">>, [],
                                                R#r.emulators) of
                [E | _] ->
                    {R#r{checks = R#r.checks + 1},
                     [Told, {narrate, decide, ["checking the ", R#r.room, " for motion first"]},
                      {request, {check, From}, E, <<"ReadMotion">>, []}]};
                [] ->
                    {R, [Told | light(off, {handoff, From}, R)]}
            end
    end.

light(State, Why, #r{room = Room, emulators = Es}) ->
    {Service, Alt} = case State of
                         on -> {<<"TurnLightOn">>, <<"SwitchSocketOn">>};
                         off -> {<<"TurnLightOff">>, <<"SwitchSocketOff">>}
                     end,
    Filter = [{<<"Room">>, Room}],
    case {reference_agents_emulator:find(<<"ACTUATOR">>, Service, Filter, Es),
          reference_agents_emulator:find(<<"ACTUATOR">>, Alt, Filter, Es)} of
        {[E | _], _} -> [{narrate, act, [Service, " via ", E]}, {request, {light, State, Why}, E, Service, []}];
        {[], [E | _]} -> [{narrate, act, [Alt, " via ", E]}, {request, {light, State, Why}, E, Alt, []}];
        {[], []} -> [{narrate, act, ["no light to switch in the ", Room]}]
    end.

read_time(#r{emulators = Es}) ->
    case reference_agents_emulator:find(<<"SENSOR">>, <<"ReadTime">>, [], Es) of
        [E | _] -> [{request, read_time, E, <<"ReadTime">>, []}];
        [] -> []
    end.

log(Now, What, R) ->
    R#r{log = [#{time => Now, what => What} | R#r.log]}.

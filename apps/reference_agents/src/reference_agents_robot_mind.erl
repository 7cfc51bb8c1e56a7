%% @doc Internal. The mind of a VA embodied in a LEGO robot (paper, section
%% 3.1), pure. The robot is cheap: it can drive to a point, turn, grab and
%% read its light sensor; the VA does the thinking.
%%
%% Exploring: told by the coordinator which lanes of the arena to search,
%% the VA drives the robot along them (the GoTo behaviour) and anchors what
%% the light sensor perceives: each ball colour seen at the claw becomes a
%% symbol of its own (acquire), or updates the anchor it already has (track,
%% reacquire). When the bumper touches something, the VA looks (a light
%% reading), turns the claw across what it touched to see it, anchors it if
%% it is a ball, and drives round it. At the end it reports its anchors.
%%
%% It adopts the lexicon the coordinator sends, and carries out "pick WORD
%% and place it at ZONE": stop short of the ball facing it, move in until
%% the bumper touches it, check its colour (turning the claw across it if
%% needed), grab it, carry it to the zone, release it, and report where it
%% landed. A failed try (no ball at the claw, the claw closed on nothing,
%% the wrong ball) is followed by going round and approaching again from
%% another side, four tries in all.
-module(reference_agents_robot_mind).
-behaviour(reference_agents_mind).

-export([init/1, probe/2, choose/3, inspect/1]).
-export([placement/3, waypoints/3]).

-export_type([args/0]).

-type args() :: #{name := binary(), body := bil:description(), coordinator := binary()}.
-type point() :: {number(), number()}.

%% The claw point is this far ahead of the robot's centre.
-define(CLAW_MM, 110).
%% Where a pick stops before moving in on the ball.
-define(STANDOFF_MM, 170).
-define(MAX_TRIES, 4).
-define(MAX_DETOURS, 3).
%% Turns (degrees) that sweep the claw 90 degrees to the left, then to the
%% right, in steps small enough for the light sensor to see a ball anywhere
%% on the front half of the bumper.
-define(SCAN, [10, 10, 10, 10, 10, 10, 10, 10, 10, -100, -10, -10, -10, -10, -10, -10, -10, -10]).
%% Colours of the arena itself, not of objects: floor, zones, walls.
-define(BACKGROUND, [<<"grey">>, <<"white">>, <<"black">>]).

-record(rb, {name :: binary(),
             coordinator :: binary(),
             emulators :: reference_agents_emulator:table(),
             anchors :: reference_agents_anchor:anchors(),
             lexicon = undefined :: reference_agents_lexicon:lexicon() | undefined,
             pose = undefined :: {number(), number(), number()} | undefined,
             embodied = false :: boolean(),
             task = idle :: idle | {explore, map()} | {pick, map()},
             done = [] :: [map()]}).

-spec init(args()) -> {ok, #rb{}}.
init(#{name := Name, body := Body, coordinator := Coordinator}) ->
    Suffix = case binary:split(Name, <<"-">>, [global]) of
                 Parts when length(Parts) > 1 -> lists:last(Parts);
                 _ -> Name
             end,
    {ok, #rb{name = Name, coordinator = Coordinator,
             emulators = reference_agents_emulator:new(Body),
             anchors = reference_agents_anchor:new(<<"r", Suffix/binary>>)}}.

%% @doc Requests that move nothing: zero angles and distances, a stop, an
%% explore of no duration, sensor reads. GoTo needs a place to go, so it is
%% tested when first used.
-spec probe(reference_agents_emulator:link(), #rb{}) -> reference_agents_embodiment:probe().
probe(#{category := Cat, type := Type}, _R) ->
    Zero = fun(Names) -> {request, [{N, <<"0">>} || N <- Names]} end,
    case {key(Cat), key(Type)} of
        {<<"actuator">>, <<"rotate">>} -> Zero([<<"Angle">>]);
        {<<"behaviour">>, <<"forward">>} -> Zero([<<"Distance">>]);
        {<<"behaviour">>, <<"rotate">>} -> Zero([<<"Angle">>]);
        {<<"behaviour">>, <<"stop">>} -> {request, []};
        {<<"behaviour">>, <<"explore">>} -> Zero([<<"Duration">>]);
        {<<"behaviour">>, <<"grab">>} -> Zero([<<"Angle">>]);
        {<<"behaviour">>, <<"release">>} -> Zero([<<"Angle">>]);
        {<<"sensor">>, <<"readlight">>} -> {request, []};
        {<<"sensor">>, <<"readtouch">>} -> {request, []};
        _ -> skip
    end.

-spec choose(reference_agents_mind:observation(), integer(), #rb{}) ->
          {#rb{}, [reference_agents_mind:act()]}.
choose({embodied, _}, _Now, R) ->
    %% A Stop tells where the robot is; the coordinator hears it is ready.
    {R#rb{embodied = true}, behaviour(locate, <<"Stop">>, [], R)};
choose({disembodied, Why}, _Now, R) ->
    {R#rb{embodied = false}, [{narrate, info, ["waiting for the robot: ", Why]}]};
choose({percept, #{service := S, params := Ps, time := T}}, _Now, R) ->
    case key(S) of
        <<"colourapproximation">> -> sighting(Ps, T, R);
        _ -> {R, []}
    end;
choose({message, From, Message}, Now, #rb{coordinator = From} = R) ->
    command(Message, Now, R);
choose({message, _From, _Message}, _Now, R) ->
    {R, []};
choose({result, Tag, Result}, Now, R) ->
    step(Tag, Result, Now, pose(Result, R));
choose({progress, _Tag, Ps}, _Now, R) ->
    {pose({ok, Ps}, R), []};
choose({signal, _}, _Now, R) ->
    {R, []}.

-spec inspect(#rb{}) -> map().
inspect(R) ->
    #{name => R#rb.name, anchors => reference_agents_anchor:anchors(R#rb.anchors),
      lexicon => R#rb.lexicon, pose => R#rb.pose,
      task => case R#rb.task of idle -> idle; {Kind, _} -> Kind end,
      done => lists:reverse(R#rb.done)}.

%% ---------------------------------------------------------------------------
%% Orders from the coordinator
%% ---------------------------------------------------------------------------

command({explore, Seconds, #{lanes := Lanes, x := Xs}}, Now, R) ->
    Points = waypoints(R#rb.pose, Lanes, Xs),
    T = #{deadline => Now + Seconds * 1000, points => Points, detours => 0},
    next_waypoint(R#rb{task = {explore, T}},
                  [{narrate, decide,
                    io_lib:format("the coordinator says: explore for ~b s; sweeping ~b lane(s) "
                                  "at y = ~s", [Seconds, length(Lanes),
                                                lists:join(", ", [integer_to_list(Y) || Y <- Lanes])])}],
                  Now);
command({lexicon, Lexicon}, _Now, #rb{name = Me} = R) ->
    Mine = [[W, " = ", S] || #{word := W} <- Lexicon,
                             {ok, S} <- [reference_agents_lexicon:local(W, Me, Lexicon)]],
    {R#rb{lexicon = Lexicon},
     [{narrate, decide, ["adopted the lexicon: ", reference_agents_lexicon:encode(Lexicon),
                         case Mine of
                             [] -> [];
                             _ -> ["; my anchors: ", lists:join(", ", Mine)]
                         end]},
      {tell, R#rb.coordinator, {lexicon_ack, Me, erlang:phash2(Lexicon)}}]};
command({pick_place, Word, Zone, At}, _Now, R) ->
    Say = {narrate, decide, ["the coordinator says: pick ", Word, " and place it at ", Zone]},
    case target(Word, R) of
        {ok, Colour, Ball} ->
            T = #{word => Word, colour => Colour, zone => Zone, at => At, ball => Ball,
                  tries => 1, detours => 0},
            {R1, Acts} = approach(R#rb{task = {pick, T}}),
            {R1, [Say | Acts]};
        error ->
            {R, [Say, {narrate, decide, ["no object called ", Word, " in my lexicon"]},
                 {tell, R#rb.coordinator, {failed, R#rb.name, Word, <<"unknown word">>}}]}
    end;
command(Other, _Now, R) ->
    {R, [{narrate, info, io_lib:format("unknown order ~0p", [Other])}]}.

%% Where the VA believes the ball is: its own anchor, else the lexicon's.
target(Word, #rb{lexicon = Lexicon, name = Me, anchors = As}) when Lexicon =/= undefined ->
    case reference_agents_lexicon:entry(Word, Lexicon) of
        {ok, #{colour := Colour, position := LexPos}} ->
            Pos = case reference_agents_lexicon:local(Word, Me, Lexicon) of
                      {ok, Sym} ->
                          case reference_agents_anchor:lookup(Sym, As) of
                              {ok, #{position := P}} -> P;
                              error -> LexPos
                          end;
                      error -> LexPos
                  end,
            {ok, Colour, Pos};
        error -> error
    end;
target(_Word, _R) ->
    error.

%% ---------------------------------------------------------------------------
%% Anchoring
%% ---------------------------------------------------------------------------

%% A ball colour at the claw point: anchor it (a new symbol, or the anchor
%% it already has follows it).
sighting(Ps, T, R) ->
    case {param(<<"Colour">>, Ps), number(<<"X">>, Ps), number(<<"Y">>, Ps)} of
        {Colour, X, Y} when is_binary(Colour), is_number(X), is_number(Y) ->
            case is_object(Colour) of
                true -> anchor(Colour, {X, Y}, T, R);
                false -> {R, []}
            end;
        _ -> {R, []}
    end.

anchor(Colour, Pos, T, R) ->
    {As, {How, Sym}} = reference_agents_anchor:perceive(
                         #{colour => Colour, position => Pos, time => T}, R#rb.anchors),
    Say = case How of
              tracked -> [];
              _ -> [{narrate, decide, io_lib:format("~s the ~s object as ~s at ~s",
                                                    [How, Colour, Sym, pos(Pos)])}]
          end,
    {R#rb{anchors = As}, Say}.

is_object(Colour) -> not lists:member(key(Colour), ?BACKGROUND).

%% ---------------------------------------------------------------------------
%% Exploring: lanes swept with GoTo
%% ---------------------------------------------------------------------------

%% @doc The points of a serpentine sweep of the lanes (y values) between
%% x = X0 and X1, starting with the lane and the end nearest to the robot.
-spec waypoints({number(), number(), number()} | undefined, [number()], {number(), number()}) ->
          [point()].
waypoints(Pose, Lanes, {X0, X1}) ->
    {PX, PY} = case Pose of
                   {X, Y, _} -> {X, Y};
                   undefined -> {X0, hd(Lanes)}
               end,
    Sorted = lists:sort(Lanes),
    Ordered = case abs(PY - hd(Sorted)) =< abs(PY - lists:last(Sorted)) of
                  true -> Sorted;
                  false -> lists:reverse(Sorted)
              end,
    Ends = case abs(PX - X0) =< abs(PX - X1) of
               true -> [X0, X1];
               false -> [X1, X0]
           end,
    serpentine(Ordered, Ends).

serpentine([], _Ends) -> [];
serpentine([Y | Rest], [A, B]) -> [{A, Y}, {B, Y} | serpentine(Rest, [B, A])].

next_waypoint(#rb{task = {explore, #{deadline := D, points := Points} = T}} = R, Acts, Now) ->
    case Points of
        [P | _] when Now < D ->
            {R#rb{task = {explore, T#{detours := 0}}},
             Acts ++ behaviour({sweep, P}, <<"GoTo">>, xy(P), R)};
        _ ->
            Anchors = reference_agents_anchor:describe(R#rb.anchors),
            {R#rb{task = idle},
             Acts ++ [{narrate, decide,
                       io_lib:format("exploration over: ~b object(s) anchored; reporting to ~s",
                                     [length(Anchors), R#rb.coordinator])},
                      {tell, R#rb.coordinator, {anchors, R#rb.name, Anchors, R#rb.pose}}]}
    end.

drop_waypoint(#rb{task = {explore, #{points := [_ | Rest]} = T}} = R) ->
    R#rb{task = {explore, T#{points := Rest}}};
drop_waypoint(R) -> R.

%% ---------------------------------------------------------------------------
%% Steps: what a result means for the task at hand
%% ---------------------------------------------------------------------------

step(locate, _Result, _Now, R) ->
    {R, [{tell, R#rb.coordinator, {ready, R#rb.name, R#rb.pose}}]};

%% Sweeping.
step({sweep, _P}, {ok, Ps}, Now, #rb{task = {explore, _}} = R) ->
    case param(<<"Result">>, Ps) of
        <<"contact">> -> investigate(explore, R);
        _ -> next_waypoint(drop_waypoint(R), [], Now)
    end;
step({sweep, _P}, {failed, Why}, Now, #rb{task = {explore, _}} = R) ->
    next_waypoint(drop_waypoint(R), [{narrate, perceive, ["GoTo failed: ", Why]}], Now);

%% Something touched the bumper: look, then turn the claw across it.
step({look, Why, Scan}, {ok, Ps}, Now, R) ->
    Colour = param(<<"Colour">>, Ps),
    Pos = {number(<<"X">>, Ps), number(<<"Y">>, Ps)},
    case is_binary(Colour) andalso is_object(Colour) of
        true ->
            looked(Why, {found, Colour, Pos}, Now, R);
        false ->
            case Scan of
                [] -> looked(Why, nothing, Now, R);
                [Angle | Rest] ->
                    {R, behaviour({turn, Why, Rest}, <<"Rotate">>,
                                  [{<<"Angle">>, integer_to_binary(Angle)}], R)}
            end
    end;
step({look, Why, _}, {failed, _}, Now, R) ->
    looked(Why, nothing, Now, R);
step({turn, Why, Rest}, _Result, _Now, R) ->
    {R, sensor({look, Why, Rest}, R)};

%% Driving round an obstacle: back, left, ahead, then on.
step({avoid, back, Then}, _Result, _Now, R) ->
    {R, behaviour({avoid, left, Then}, <<"Rotate">>, [{<<"Angle">>, <<"90">>}], R)};
step({avoid, left, Then}, _Result, _Now, R) ->
    {R, behaviour({avoid, ahead, Then}, <<"Forward">>, [{<<"Distance">>, <<"0.25">>}], R)};
step({avoid, ahead, explore}, _Result, Now, #rb{task = {explore, #{detours := N}}} = R) ->
    case N + 1 >= ?MAX_DETOURS of
        true -> next_waypoint(drop_waypoint(R), [], Now);
        false ->
            {R1, Acts} = next_waypoint(R, [], Now),
            case R1#rb.task of
                {explore, T1} -> {R1#rb{task = {explore, T1#{detours := N + 1}}}, Acts};
                _ -> {R1, Acts}
            end
    end;
step({avoid, ahead, pick}, _Result, _Now, #rb{task = {pick, T}} = R) ->
    approach(R#rb{task = {pick, T}});
step({avoid, ahead, carry}, _Result, _Now, #rb{task = {pick, _}} = R) ->
    carry(R);

%% Picking.
step(approach, {ok, Ps}, _Now, #rb{task = {pick, _}} = R) ->
    case param(<<"Result">>, Ps) of
        <<"contact">> -> investigate(pick, R);
        _ -> {R, behaviour(close_in, <<"Forward">>, [{<<"Distance">>, <<"0.12">>},
                                                     {<<"Speed">>, <<"0.08">>}], R)}
    end;
step(close_in, {ok, _Ps}, _Now, #rb{task = {pick, _}} = R) ->
    investigate(pick, R);
step(grab, {ok, Ps}, Now, #rb{task = {pick, #{colour := Colour, zone := Zone, at := At}}} = R) ->
    case {param(<<"Holding">>, Ps), key(param(<<"Colour">>, Ps)) =:= key(Colour)} of
        {<<"yes">>, true} ->
            {R1, Acts} = carry(R),
            {R1, [{narrate, act, io_lib:format("holding the ~s ball: carrying it to ~s ~s",
                                               [Colour, Zone, pos(At)])} | Acts]};
        {<<"yes">>, false} ->
            {R, [{narrate, perceive, ["grabbed the wrong ball (", param(<<"Colour">>, Ps),
                                      "): putting it down"]}
                 | behaviour(drop_wrong, <<"Release">>, [], R)]};
        _ ->
            retry("the claw closed on nothing", Now, R)
    end;
step(drop_wrong, _Result, Now, R) ->
    retry("grabbed the wrong ball", Now, R);
step(carry, {ok, Ps}, _Now, #rb{task = {pick, #{detours := N} = T}} = R) ->
    case param(<<"Result">>, Ps) of
        <<"done">> ->
            {R, [{narrate, act, "at the zone: releasing"} | behaviour(release, <<"Release">>, [], R)]};
        Other when N < ?MAX_DETOURS ->
            {R#rb{task = {pick, T#{detours := N + 1}}},
             [{narrate, perceive, ["carrying: ", Other, "; going round"]} | avoid(carry, R)]};
        Other ->
            fail(["could not reach the zone: ", Other], R)
    end;
step(release, {ok, Ps}, Now, #rb{task = {pick, #{word := Word, zone := Zone}}} = R) ->
    Where = {number(<<"BallX">>, Ps), number(<<"BallY">>, Ps)},
    As = case reference_agents_lexicon:local(Word, R#rb.name, lexicon(R)) of
             {ok, Sym} when is_number(element(1, Where)) ->
                 reference_agents_anchor:moved(Sym, Where, Now, R#rb.anchors);
             _ -> R#rb.anchors
         end,
    Done = #{word => Word, zone => Zone, at => Where},
    {R#rb{task = idle, anchors = As, done = [Done | R#rb.done]},
     [{narrate, act, io_lib:format("placed ~s at ~s ~s", [Word, Zone, pos(Where)])},
      {tell, R#rb.coordinator, {placed, R#rb.name, Word, Zone, Where}}
      | behaviour(back_off, <<"Forward">>, [{<<"Distance">>, <<"-0.2">>}], R)]};
step(Tag, {failed, Why}, _Now, #rb{task = {pick, _}} = R) ->
    fail(io_lib:format("~0p failed: ~s", [Tag, Why]), R);
step(_Tag, _Result, _Now, R) ->
    {R, []}.

investigate(Why, R) ->
    {R, sensor({look, Why, ?SCAN}, R)}.

%% What the look found, and what the task does with it.
looked(explore, {found, Colour, Pos}, Now, R) ->
    {R1, Say} = anchor(Colour, Pos, Now, R),
    {R1, Say ++ avoid(explore, R1)};
looked(explore, nothing, _Now, R) ->
    {R, [{narrate, perceive, "bumped into something that is not a ball: going round"}
         | avoid(explore, R)]};
looked(pick, {found, Seen, Pos}, Now, #rb{task = {pick, #{colour := Colour}}} = R) ->
    {R1, _} = anchor(Seen, Pos, Now, R),
    case key(Seen) =:= key(Colour) of
        true ->
            {R1, [{narrate, decide, ["the ", Colour, " ball is at the claw: grabbing it"]}
                  | behaviour(grab, <<"Grab">>, [], R1)]};
        false ->
            {R1, [{narrate, perceive, ["in the way: the ", Seen, " ball; going round"]}
                  | avoid(pick, R1)]}
    end;
looked(pick, nothing, Now, R) ->
    retry("no ball at the claw", Now, R).

avoid(Then, R) ->
    behaviour({avoid, back, Then}, <<"Forward">>, [{<<"Distance">>, <<"-0.12">>}], R).

approach(#rb{task = {pick, #{ball := Ball, tries := N}}, pose = Pose} = R) ->
    Stand = placement(Pose, Ball, ?STANDOFF_MM),
    Heading = case Pose of
                  undefined -> [];
                  _ -> [{<<"Heading">>, integer_to_binary(round(bearing(Stand, Ball)))}]
              end,
    {R, [{narrate, act, io_lib:format("going to the ball at ~s (try ~b)", [pos(Ball), N])}
         | behaviour(approach, <<"GoTo">>, xy(Stand) ++ Heading, R)]}.

carry(#rb{task = {pick, #{at := At}}, pose = Pose} = R) ->
    {R, behaviour(carry, <<"GoTo">>, xy(placement(Pose, At, ?CLAW_MM)), R)}.

%% A failed try is not repeated from where it failed: the robot backs off
%% and goes round (as round an obstacle), then approaches again from where
%% it then is, so from another stand-off point and another side. Repeating
%% the same approach met the same obstacle (the other robot parked in the
%% way) or the same miss every time.
retry(Why, _Now, #rb{task = {pick, #{tries := N} = T}} = R) when N < ?MAX_TRIES ->
    R1 = R#rb{task = {pick, T#{tries := N + 1}}},
    {R1, [{narrate, perceive, [Why, ": going round to try again from another side"]}
          | avoid(pick, R1)]};
retry(Why, _Now, R) ->
    fail(Why, R).

fail(Why, #rb{task = {pick, #{word := Word}}} = R) ->
    Text = iolist_to_binary(Why),
    {R#rb{task = idle},
     [{narrate, decide, ["giving up on ", Word, ": ", Text]},
      {tell, R#rb.coordinator, {failed, R#rb.name, Word, Text}}]}.

%% @doc Where the robot's centre must stop to be `Short' mm before Target,
%% coming from Pose (for the claw point to be on Target, Short is the claw's
%% distance).
-spec placement({number(), number(), number()} | undefined, point(), number()) -> point().
placement(undefined, Target, _Short) -> Target;
placement({X, Y, _H}, {TX, TY}, Short) ->
    D = math:sqrt((TX - X) * (TX - X) + (TY - Y) * (TY - Y)),
    case D =< Short of
        true -> {TX, TY};
        false -> {TX - Short * (TX - X) / D, TY - Short * (TY - Y) / D}
    end.

bearing({X, Y}, {TX, TY}) ->
    Deg = math:atan2(TY - Y, TX - X) * 180 / math:pi(),
    case Deg < 0 of
        true -> Deg + 360;
        false -> Deg
    end.

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

behaviour(Tag, Service, Params, R) ->
    case reference_agents_emulator:find(<<"BEHAVIOUR">>, Service, [], R#rb.emulators) of
        [E | _] -> [{request, Tag, E, Service, Params}];
        [] -> [{narrate, info, ["no emulator for the behaviour ", Service]}]
    end.

sensor(Tag, R) ->
    case reference_agents_emulator:find(<<"SENSOR">>, <<"ReadLight">>, [], R#rb.emulators) of
        [E | _] -> [{request, Tag, E, <<"ReadLight">>, []}];
        [] -> []
    end.

pose({ok, Ps}, R) ->
    case {number(<<"X">>, Ps), number(<<"Y">>, Ps), number(<<"Heading">>, Ps)} of
        {X, Y, H} when is_number(X), is_number(Y), is_number(H) -> R#rb{pose = {X, Y, H}};
        _ -> R
    end;
pose(_, R) ->
    R.

lexicon(#rb{lexicon = undefined}) -> [];
lexicon(#rb{lexicon = L}) -> L.

xy({X, Y}) ->
    [{<<"X">>, integer_to_binary(round(X))}, {<<"Y">>, integer_to_binary(round(Y))}].

pos({X, Y}) when is_number(X), is_number(Y) -> io_lib:format("(~b, ~b)", [round(X), round(Y)]);
pos(_) -> "(?)".

param(Name, Ps) ->
    case lists:keyfind(Name, 1, Ps) of
        {_, V} -> V;
        false -> undefined
    end.

number(Name, Ps) ->
    case param(Name, Ps) of
        undefined -> undefined;
        V ->
            case string:to_float(V) of
                {F, <<>>} -> F;
                _ ->
                    case string:to_integer(V) of
                        {I, <<>>} -> I;
                        _ -> undefined
                    end
            end
    end.

key(undefined) -> <<>>;
key(B) -> reference_agents_activity:keyword(B).

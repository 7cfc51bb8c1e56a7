%% @doc Internal. The mind of the coordinator VA of the robot scenario
%% (paper, section 3.1), pure. It has no Avatar: it talks with the robot
%% VAs only, as MAS messages. When every robot VA says it is embodied it
%% sends them to explore; from their reports (what each anchored) it builds
%% the lexicon, distributes it and waits until every robot has adopted it;
%% then it commands "pick WORD and place it at ZONE", one ball at a time,
%% until every ball whose colour has a target zone is placed.
-module(reference_agents_coordinator).
-behaviour(reference_agents_mind).

-export([init/1, probe/2, choose/3, inspect/1]).

-export_type([args/0]).

%% `targets': the task, the zone each colour of ball goes to; `zones': where
%% the zones are; `arena': its width and height (mm); `explore': seconds per
%% exploration round; `rounds': how many rounds at most while a colour of
%% the task is still unseen.
-type args() :: #{robots := [binary()],
                  targets := #{binary() => binary()},
                  zones := #{binary() => {number(), number()}},
                  arena => {number(), number()},
                  explore => pos_integer(),
                  rounds => pos_integer()}.

%% Lanes of a sweep are this far apart: a robot's bumper touches every ball
%% whose centre is within 110 mm of its path.
-define(LANE_MM, 200).

-record(c, {robots :: [binary()],
            targets :: #{binary() => binary()},
            zones :: #{binary() => {number(), number()}},
            arena :: {number(), number()},
            explore :: pos_integer(),
            rounds :: pos_integer(),
            round = 0 :: non_neg_integer(),
            phase = waiting :: waiting | exploring | agreeing | commanding | done,
            ready = [] :: [binary()],
            reports = #{} :: #{binary() => list()},
            poses = #{} :: #{binary() => term()},
            lexicon = undefined :: reference_agents_lexicon:lexicon() | undefined,
            acks = #{} :: #{binary() => integer()},
            current = undefined :: {binary(), binary()} | undefined,
            attempts = #{} :: #{binary() => [binary()]},
            placed = #{} :: #{binary() => {binary(), binary(), term()}},
            given_up = [] :: [binary()]}).

-spec init(args()) -> {ok, #c{}}.
init(#{robots := Robots, targets := Targets, zones := Zones} = Args) ->
    {ok, #c{robots = Robots, targets = Targets, zones = Zones,
            arena = maps:get(arena, Args, {2000, 1500}),
            explore = maps:get(explore, Args, 90), rounds = maps:get(rounds, Args, 5)}}.

-spec probe(reference_agents_emulator:link(), #c{}) -> reference_agents_embodiment:probe().
probe(_Link, _C) -> skip.

-spec choose(reference_agents_mind:observation(), integer(), #c{}) ->
          {#c{}, [reference_agents_mind:act()]}.
choose({message, From, Message}, _Now, C) ->
    case lists:member(From, C#c.robots) of
        true -> message(From, Message, C);
        false -> {C, []}
    end;
choose(_Observation, _Now, C) ->
    {C, []}.

-spec inspect(#c{}) -> map().
inspect(C) ->
    #{phase => C#c.phase, lexicon => C#c.lexicon, round => C#c.round,
      placed => C#c.placed, given_up => C#c.given_up,
      acks => C#c.acks}.

message(From, {ready, From, Pose}, #c{phase = waiting} = C) ->
    Ready = lists:usort([From | C#c.ready]),
    C1 = C#c{ready = Ready, poses = (C#c.poses)#{From => Pose}},
    case Ready =:= lists:sort(C#c.robots) of
        true -> explore(C1, [{narrate, decide, "every robot VA is embodied"}]);
        false -> {C1, [{narrate, perceive, [From, " is embodied"]}]}
    end;
message(From, {anchors, From, Anchors, Pose}, #c{phase = exploring} = C) ->
    C1 = C#c{reports = (C#c.reports)#{From => Anchors}, poses = (C#c.poses)#{From => Pose}},
    Say = {narrate, perceive,
           [From, " reports ", integer_to_binary(length(Anchors)), " object(s): ",
            lists:join(", ", [[S, " ", Col] || #{symbol := S, colour := Col} <- Anchors])]},
    case lists:sort(maps:keys(C1#c.reports)) =:= lists:sort(C#c.robots) of
        true -> lexicon(C1, [Say]);
        false -> {C1, [Say]}
    end;
message(From, {lexicon_ack, From, Hash}, #c{phase = agreeing, lexicon = L} = C) ->
    Acks = (C#c.acks)#{From => Hash},
    C1 = C#c{acks = Acks},
    Agreed = lists:all(fun(R) -> maps:get(R, Acks, none) =:= erlang:phash2(L) end, C#c.robots),
    case Agreed of
        true -> next(C1#c{phase = commanding},
                     [{narrate, decide, "every robot VA holds the same lexicon: commanding"}]);
        false -> {C1, []}
    end;
message(From, {placed, From, Word, Zone, Where}, #c{phase = commanding} = C) ->
    C1 = C#c{placed = (C#c.placed)#{Word => {Zone, From, Where}}, current = undefined},
    next(C1, [{narrate, perceive, [From, " placed ", Word, " at ", Zone]}]);
message(From, {failed, From, Word, Why}, #c{phase = commanding} = C) ->
    next(C#c{current = undefined},
         [{narrate, perceive, [From, " could not place ", Word, ": ", Why]}]);
message(_From, _Message, C) ->
    {C, []}.

%% The arena is cut into lanes, shared out by where the robots are (the one
%% furthest south takes the southern lanes); every other round they swap.
explore(#c{round = N, arena = {W, H}} = C, Acts) ->
    Lanes = lists:seq(150, round(H) - 150, ?LANE_MM),
    ByY = [R || {_, R} <- lists:sort([{y(maps:get(R, C#c.poses, undefined)), R}
                                      || R <- C#c.robots])],
    Order = case N rem 2 of 0 -> ByY; 1 -> lists:reverse(ByY) end,
    Shares = share(Lanes, length(Order)),
    Orders = [{tell, R, {explore, C#c.explore, #{lanes => L, x => {150, round(W) - 150}}}}
              || {R, L} <- lists:zip(Order, Shares)],
    {C#c{phase = exploring, round = N + 1, reports = #{}},
     Acts ++ [{narrate, decide, io_lib:format("round ~b: the robots sweep the arena, "
                                              "~b lanes ~b mm apart, for ~b s at most",
                                              [N + 1, length(Lanes), ?LANE_MM, C#c.explore])}
              | Orders]}.

y({_X, Y, _H}) -> Y;
y(_) -> 0.

%% Lanes in N consecutive shares, as even as can be.
share(Lanes, N) ->
    Size = length(Lanes) div N,
    Extra = length(Lanes) rem N,
    share(Lanes, N, Size, Extra).

share(_Lanes, 0, _Size, _Extra) -> [];
share(Lanes, N, Size, Extra) ->
    Take = Size + case Extra > 0 of true -> 1; false -> 0 end,
    {Mine, Rest} = lists:split(min(Take, length(Lanes)), Lanes),
    [Mine | share(Rest, N - 1, Size, max(0, Extra - 1))].

lexicon(C, Acts) ->
    Lexicon = reference_agents_lexicon:build(maps:to_list(C#c.reports)),
    Seen = [reference_agents_activity:keyword(Col) || #{colour := Col} <- Lexicon],
    Missing = [Col || Col <- lists:sort(maps:keys(C#c.targets)),
                      not lists:member(reference_agents_activity:keyword(Col), Seen)],
    Say = {narrate, decide, ["lexicon built: ", reference_agents_lexicon:encode(Lexicon)]},
    case Missing of
        [_ | _] when C#c.round < C#c.rounds ->
            explore(C, Acts ++ [Say, {narrate, decide, ["no ", lists:join(", ", Missing),
                                                       " ball seen yet: exploring again"]}]);
        _ ->
            Unseen = [<<Col/binary, " (never seen)">> || Col <- Missing],
            {C#c{phase = agreeing, lexicon = Lexicon, acks = #{},
                 given_up = C#c.given_up ++ Unseen},
             Acts ++ [Say, {narrate, act, "sending the lexicon to every robot VA"}
                      | [{tell, R, {lexicon, Lexicon}} || R <- C#c.robots]]}
    end.

%% The next ball to place: the first by word whose colour has a target and
%% that is neither placed nor given up; the robot that anchored it goes,
%% the other if that one failed.
next(#c{lexicon = L} = C, Acts) ->
    Todo = [E || #{word := W, colour := Col} = E <- L,
                 target(Col, C) =/= none,
                 not maps:is_key(W, C#c.placed), not lists:member(W, C#c.given_up)],
    case Todo of
        [] ->
            Summary = #{lexicon => L, placed => C#c.placed, given_up => C#c.given_up},
            {C#c{phase = done},
             Acts ++ [{narrate, decide,
                       case C#c.given_up of
                           [] -> "every ball is at its target";
                           G -> ["done, but could not place ", lists:join(", ", G)]
                       end},
                      {notify, {done, Summary}}]};
        [#{word := W, colour := Col, names := Names} | _] ->
            Tried = maps:get(W, C#c.attempts, []),
            Order = [R || R <- C#c.robots, maps:is_key(R, Names)]
                ++ [R || R <- C#c.robots, not maps:is_key(R, Names)],
            case [R || R <- Order, not lists:member(R, Tried)] of
                [Robot | _] ->
                    Zone = target(Col, C),
                    At = maps:get(Zone, C#c.zones),
                    {C#c{current = {Robot, W}, attempts = (C#c.attempts)#{W => [Robot | Tried]}},
                     Acts ++ [{narrate, act, [Robot, ": pick ", W, " and place it at ", Zone]},
                              {tell, Robot, {pick_place, W, Zone, At}}]};
                [] ->
                    next(C#c{given_up = [W | C#c.given_up]}, Acts)
            end
    end.

target(Colour, #c{targets = T}) ->
    K = reference_agents_activity:keyword(Colour),
    case [Z || {Col, Z} <- maps:to_list(T), reference_agents_activity:keyword(Col) =:= K] of
        [Z | _] -> Z;
        [] -> none
    end.

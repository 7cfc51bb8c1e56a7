%% @doc Internal. The LEGO robots of the arena as a pure model run by
%% {@link avatar_sim_world}: a LeJOS-like remote API per robot (motors A, B,
%% C; light and touch sensors; preprogrammed behaviours forward, rotate,
%% stop, explore, go to, grab, release), advanced tick by tick over
%% {@link avatar_sim_arena}'s geometry. Requests and answers are as
%% docs/avatars.md section 3 says.
-module(avatar_sim_robots).
-behaviour(avatar_sim_world).

-export([init/2, tick/2, request/3, bound/4, command/3, state/2]).

-define(EPS, 1.0e-6).
-define(K, (avatar_sim_arena:wheel_mm_per_deg())).

-type robot_opts() :: #{index := pos_integer(), entity := binary(),
                        description := bil:description(),
                        x => number(), y => number(), heading => number()}.
-export_type([robot_opts/0]).

-record(m, {arena :: avatar_sim_arena:arena(),
            robots :: #{pos_integer() => map()},
            comps :: #{binary() => {pos_integer(), binary()}},
            rand :: rand:state(),
            now :: integer(),
            progress :: pos_integer(),
            light_period :: non_neg_integer()}).

%% ---------------------------------------------------------------------------
%% Model callbacks
%% ---------------------------------------------------------------------------

-spec init(map(), integer()) -> #m{}.
init(Opts, Now) ->
    Arena0 = avatar_sim_arena:new(Opts),
    RobotOpts = maps:get(robots, Opts),
    Poses = maps:from_list([{I, #{x => float(X), y => float(Y),
                                  h => avatar_sim_arena:normalise(H)}}
                            || #{index := I, x := X, y := Y, heading := H} <- RobotOpts]),
    Arena = Arena0#{poses := Poses},
    LightPeriod = maps:get(light_period, Opts, 1000),
    Robots = maps:from_list([{I, robot(R, Now, LightPeriod)} || #{index := I} = R <- RobotOpts]),
    Comps = maps:from_list([{Id, {I, Base}} || #{index := I} <- RobotOpts,
                                               Base <- bases(),
                                               Id <- [avatar_sim_desc:robot_component(I, Base)]]),
    M = #m{arena = Arena, robots = Robots, comps = Comps,
           rand = rand:seed_s(exsss, maps:get(seed, Opts, 1)), now = Now,
           progress = maps:get(progress_interval, Opts, 1000), light_period = LightPeriod},
    %% A first reading for every robot, so "once when bound" has something
    %% to send without drawing random numbers between ticks.
    lists:foldl(fun(I, Acc) -> {Acc1, _} = read_light(I, Acc), Acc1 end, M,
                lists:sort(maps:keys(Robots))).

robot(#{index := I, entity := E, description := Desc}, Now, LightPeriod) ->
    Fb = maps:from_list([{Base, feedback_body(Desc, I, Base)} || Base <- bases()]),
    #{index => I, entity => E, holding => none, claw => 0.0, touch => false,
      tacho => #{a => 0.0, b => 0.0, c => 0.0}, reading => undefined, track => none,
      claw_task => none, fb => Fb,
      next_light => case LightPeriod of 0 -> infinity; _ -> Now + LightPeriod end}.

bases() ->
    [<<"MotorA">>, <<"MotorB">>, <<"MotorC">>, <<"LightSensor">>, <<"TouchSensor">>,
     <<"ForwardBehaviour">>, <<"RotateBehaviour">>, <<"StopBehaviour">>,
     <<"ExploreBehaviour">>, <<"GoToBehaviour">>, <<"GrabBehaviour">>,
     <<"ReleaseBehaviour">>].

feedback_body(Desc, I, <<"LightSensor">>) ->
    {<<"SENSOR">>, type_or(Desc, I, <<"LightSensor">>, <<"colourapproximation">>,
                           <<"ColourApproximation">>)};
feedback_body(Desc, I, <<"TouchSensor">>) ->
    {<<"SENSOR">>, type_or(Desc, I, <<"TouchSensor">>, <<"touch">>, <<"Touch">>)};
feedback_body(Desc, I, Base) ->
    Id = avatar_sim_desc:robot_component(I, Base),
    Cat = case avatar_sim_desc:feedback_category(Desc, Id) of
              undefined -> <<"ACTUATOR">>;
              C -> C
          end,
    {Cat, <<"ACTION FEEDBACK">>}.

type_or(Desc, I, Base, Keyword, Default) ->
    case avatar_sim_desc:consumes_type(Desc, avatar_sim_desc:robot_component(I, Base),
                                       Keyword) of
        undefined -> Default;
        T -> T
    end.

-spec tick(integer(), #m{}) -> {#m{}, [avatar_sim_world:effect()]}.
tick(Now, #m{now = Before} = M) ->
    Dt = max(0, Now - Before),
    {M1, Effects} = lists:foldl(fun(I, {Acc, Es}) ->
                                        {Acc1, Es1} = tick_robot(I, Dt, Acc#m{now = Now}),
                                        {Acc1, Es ++ Es1}
                                end, {M#m{now = Now}, []},
                                lists:sort(maps:keys(M#m.robots))),
    {M1, Effects}.

-spec request(bil:signal(), integer(), #m{}) -> {#m{}, [avatar_sim_world:effect()]}.
request(#{receiver := Receiver, body := #{type := Type, parameters := P}} = Req, Now, M0) ->
    M = M0#m{now = Now},
    case M#m.comps of
        #{Receiver := {I, Base}} ->
            case keyword(Type) =:= service(Base) of
                true -> handle(Base, I, Req, P, M);
                false -> {M, [error_answer(Req, <<"UnknownService">>,
                                           <<Receiver/binary, " does not provide '",
                                             Type/binary, "'">>)]}
            end;
        #{} ->
            {M, []}
    end.

-spec bound(binary(), binary(), integer(), #m{}) -> {#m{}, [avatar_sim_world:effect()]}.
bound(Component, Type, _Now, M) ->
    case {M#m.comps, keyword(Type)} of
        {#{Component := {I, <<"LightSensor">>}}, <<"colourapproximation">>} ->
            #{reading := Reading} = robot_of(I, M),
            {M, [colour_push(I, Reading)]};
        _ ->
            {M, []}
    end.

-spec command(term(), integer(), #m{}) -> {term(), #m{}, [avatar_sim_world:effect()]}.
command({place_ball, Colour, X, Y}, _Now, #m{arena = #{balls := Balls} = A} = M) ->
    Balls1 = case [B || #{colour := C, held_by := none} = B <- Balls, C =:= Colour] of
                 [#{id := Id} | _] ->
                     [case B of
                          #{id := Id} -> B#{x := float(X), y := float(Y)};
                          _ -> B
                      end || B <- Balls];
                 [] ->
                     Balls ++ [#{id => length(Balls) + 1, colour => Colour, x => float(X),
                                 y => float(Y), held_by => none}]
             end,
    {ok, M#m{arena = A#{balls := Balls1}}, []};
command(_Other, _Now, M) ->
    {{error, unknown_command}, M, []}.

-spec state(integer(), #m{}) -> map().
state(Now, #m{arena = A, robots = Robots}) ->
    #{poses := Poses, balls := Balls, zones := Zones} = A,
    #{time => Now,
      robots => [begin
                     #{x := X, y := Y, h := H} = maps:get(I, Poses),
                     #{entity := E, claw := Claw, holding := Hold, touch := T,
                       tacho := Tacho} = R,
                     #{index => I, entity => E, x => X, y => Y, heading => H,
                       behaviour => track_name(R), claw => round(Claw),
                       holding => case Hold of
                                      none -> none;
                                      Id -> maps:get(colour, ball(Id, A))
                                  end,
                       touch => T, tacho => maps:map(fun(_, V) -> round(V) end, Tacho)}
                 end || {I, R} <- lists:sort(maps:to_list(Robots))],
      balls => [#{colour => C, x => BX, y => BY, held_by => HB,
                  zone => avatar_sim_arena:zone_of(A, BX, BY)}
                || #{colour := C, held_by := HB} = B0 <- Balls,
                   {BX, BY} <- [ball_position(B0, A)]],
      zones => Zones, width => maps:get(width, A), height => maps:get(height, A)}.

track_name(#{track := none}) -> none;
track_name(#{track := {motors, _}}) -> motors;
track_name(#{track := {behaviour, #{kind := K}}}) -> K.

%% ---------------------------------------------------------------------------
%% Requests
%% ---------------------------------------------------------------------------

service(<<"Motor", _>>) -> <<"rotate">>;
service(<<"LightSensor">>) -> <<"readlight">>;
service(<<"TouchSensor">>) -> <<"readtouch">>;
service(<<"ForwardBehaviour">>) -> <<"forward">>;
service(<<"RotateBehaviour">>) -> <<"rotate">>;
service(<<"StopBehaviour">>) -> <<"stop">>;
service(<<"ExploreBehaviour">>) -> <<"explore">>;
service(<<"GoToBehaviour">>) -> <<"goto">>;
service(<<"GrabBehaviour">>) -> <<"grab">>;
service(<<"ReleaseBehaviour">>) -> <<"release">>.

handle(Base, I, Req, P, M) ->
    case parse(Base, P) of
        {ok, Args} -> start(Base, Args, I, Req, M);
        {error, Message} -> {M, [error_answer(Req, <<"BadParameter">>, Message)]}
    end.

parse(<<"ForwardBehaviour">>, P) ->
    with([avatar_sim_param:number(<<"Distance">>, P, 0.5),
          avatar_sim_param:number(<<"Speed">>, P, 0.15)],
         fun([D, S]) -> {forward, D * 1000, clamp(S * 1000, 10, 400)} end);
parse(<<"RotateBehaviour">>, P) ->
    with([avatar_sim_param:number(<<"Angle">>, P, 90),
          avatar_sim_param:number(<<"Speed">>, P, 90)],
         fun([A, S]) -> {rotate, A, clamp(S, 5, 360)} end);
parse(<<"StopBehaviour">>, _P) ->
    {ok, stop};
parse(<<"ExploreBehaviour">>, P) ->
    with([avatar_sim_param:number(<<"Duration">>, P, 60),
          avatar_sim_param:yes_no(<<"UntilObject">>, P, true)],
         fun([D, U]) ->
                 {explore, round(D * 1000), U,
                  [string:lowercase(C) || C <- avatar_sim_param:list(<<"Ignore">>, P)]}
         end);
parse(<<"GoToBehaviour">>, P) ->
    Heading = case lists:keymember(<<"Heading">>, 1, P) of
                  true -> avatar_sim_param:number(<<"Heading">>, P);
                  false -> {ok, none}
              end,
    with([avatar_sim_param:number(<<"X">>, P), avatar_sim_param:number(<<"Y">>, P), Heading],
         fun([X, Y, H]) -> {goto, float(X), float(Y), H} end);
parse(<<"GrabBehaviour">>, P) ->
    with([avatar_sim_param:number(<<"Angle">>, P, 90),
          avatar_sim_param:number(<<"Speed">>, P, 180)],
         fun([A, S]) -> {claw, grab, abs(A), clamp(S, 5, 900)} end);
parse(<<"ReleaseBehaviour">>, P) ->
    with([avatar_sim_param:number(<<"Angle">>, P, 90),
          avatar_sim_param:number(<<"Speed">>, P, 180)],
         fun([A, S]) -> {claw, release, -abs(A), clamp(S, 5, 900)} end);
parse(<<"Motor", Port>>, P) ->
    case {lists:keymember(<<"Angle">>, 1, P), lists:keymember(<<"Duration">>, 1, P)} of
        {false, false} -> {error, <<"Rotate needs Angle or Duration">>};
        {HasAngle, _} ->
            Amount = case HasAngle of
                         true -> avatar_sim_param:number(<<"Angle">>, P);
                         false -> avatar_sim_param:number(<<"Duration">>, P)
                     end,
            with([Amount, avatar_sim_param:number(<<"Speed">>, P, 360)],
                 fun([Am, S0]) ->
                         S = clamp(abs(S0), 1, 900),
                         Angle = case HasAngle of
                                     true -> Am;
                                     false -> sign(S0) * S * Am / 1000
                                 end,
                         {motor, port(Port), float(Angle), S}
                 end)
    end;
parse(_Sensor, _P) ->
    {ok, read}.

port($A) -> a;
port($B) -> b;
port($C) -> c.

with(Results, F) ->
    case [E || {error, E} <- Results] of
        [E | _] -> {error, E};
        [] -> {ok, F([V || {ok, V} <- Results])}
    end.

start(<<"LightSensor">>, read, I, Req, M) ->
    #{reading := Reading} = robot_of(I, M),
    {M, [answer(I, <<"LightSensor">>, Req, feedback, light_params(Reading), M)]};
start(<<"TouchSensor">>, read, I, Req, M) ->
    #{touch := T} = robot_of(I, M),
    {M, [answer(I, <<"TouchSensor">>, Req, feedback, [{<<"Pressed">>, T}], M)]};
start(<<"StopBehaviour">>, stop, I, Req, M) ->
    {M1, Es} = end_track(I, stopped, M),
    {M1, Es ++ [answer(I, <<"StopBehaviour">>, Req, feedback,
                       [{<<"Result">>, done} | pose_params(I, M1)], M1)]};
start(Base, {claw, Kind, Delta, Speed}, I, Req, M) ->
    claw_task(I, #{req => Req, base => Base, kind => Kind, delta => Delta, speed => Speed}, M);
start(<<"MotorB">> = Base, {motor, b, Angle, Speed}, I, Req, M) ->
    claw_task(I, #{req => Req, base => Base, kind => motor, delta => Angle, speed => Speed}, M);
start(Base, {motor, Port, Angle, Speed}, I, Req, M) ->
    R = robot_of(I, M),
    {M1, Es} = case R of
                   #{track := {motors, _}} -> {M, []};
                   #{} -> end_track(I, preempted, M)
               end,
    R1 = robot_of(I, M1),
    Motors0 = case R1 of
                  #{track := {motors, Ms}} -> Ms;
                  #{} -> #{}
              end,
    Es1 = case Motors0 of
              #{Port := #{req := Old, base := OldBase}} ->
                  [motor_answer(I, OldBase, Old, preempted, Port, 0.0, M1)];
              #{} -> []
          end,
    Motor = #{req => Req, base => Base, togo => Angle, speed => Speed, turned => 0.0},
    M2 = put_robot(I, R1#{track := {motors, Motors0#{Port => Motor}}}, M1),
    {M2, Es ++ Es1};
start(Base, Args, I, Req, M) ->
    {M1, Es} = end_track(I, preempted, M),
    B = behaviour(Args, Base, Req, M1),
    R = robot_of(I, M1),
    {put_robot(I, R#{track := {behaviour, B}}, M1), Es}.

behaviour(Args, Base, Req, #m{now = Now, progress = Every}) ->
    B0 = #{base => Base, req => Req, cur => undefined, travelled => 0.0, started => Now,
           next_progress => infinity, deadline => infinity},
    case Args of
        {forward, Mm, Speed} ->
            B0#{kind => forward, phases => [{drive, Mm, Speed}], total => abs(Mm),
                next_progress => Now + Every};
        {rotate, Angle, Speed} ->
            B0#{kind => rotate, phases => [{turn, Angle, Speed}]};
        {explore, DurationMs, Until, Ignore} ->
            B0#{kind => explore, phases => [], until => Until, ignore => Ignore,
                deadline => Now + DurationMs, next_progress => Now + Every};
        {goto, X, Y, H} ->
            Last = case H of none -> []; _ -> [{turn_to, H}] end,
            B0#{kind => goto, phases => [{turn_towards, X, Y}, {drive_to, X, Y} | Last],
                target => {X, Y}, next_progress => Now + Every}
    end.

%% Ends whatever drives the wheels, answering its request(s) with `Result'.
end_track(I, Result, M) ->
    R = robot_of(I, M),
    case R of
        #{track := none} ->
            {M, []};
        #{track := {behaviour, B}} ->
            finish(I, B, Result, [], put_robot(I, R#{track := none}, M));
        #{track := {motors, Motors}} ->
            M1 = put_robot(I, R#{track := none}, M),
            {M1, [motor_answer(I, Base, Req, Result, Port, T, M1)
                  || {Port, #{req := Req, base := Base, turned := T}}
                         <- lists:sort(maps:to_list(Motors))]}
    end.

finish(I, #{base := Base, req := Req} = B, Result, Extra, M) ->
    Params = [{<<"Result">>, Result} | Extra] ++ behaviour_params(B, I, M),
    {M, [answer(I, Base, Req, feedback, Params, M)]}.

behaviour_params(#{kind := rotate}, I, M) -> pose_params(I, M);
behaviour_params(#{kind := goto}, I, M) -> pose_params(I, M);
behaviour_params(#{travelled := T}, I, M) -> [{<<"Travelled">>, T} | pose_params(I, M)].

claw_task(I, Task0, M) ->
    R = robot_of(I, M),
    Es = case R of
             #{claw_task := #{} = Old} ->
                 [claw_answer(I, Old, preempted, 0.0, M)];
             #{} -> []
         end,
    #{claw := Claw} = R,
    #{delta := Delta} = Task0,
    Target = clamp(Claw + Delta, 0.0, 90.0),
    Task = Task0#{target => Target, from => Claw},
    {put_robot(I, R#{claw_task := Task}, M), Es}.

%% ---------------------------------------------------------------------------
%% Ticks
%% ---------------------------------------------------------------------------

tick_robot(I, Dt, M) ->
    {M1, E1} = wheels(I, Dt, M),
    {M2, E2} = claw(I, Dt, M1),
    {M3, E3} = sense(I, M2),
    {M4, E4} = timers(I, M3),
    %% What the sensors perceived after this tick's motion goes out before
    %% the answers it caused: the bumper before the behaviour's "contact".
    {M4, E3 ++ E1 ++ E2 ++ E4}.

%% Wheel motion for this tick: what the behaviour's current phase or the
%% motors ask, then as much of it as the arena allows.
wheels(I, Dt, M) ->
    R = robot_of(I, M),
    case R of
        #{track := none} ->
            {M, []};
        #{track := {behaviour, B0}} ->
            case resolve(B0, I, M) of
                {done, B} ->
                    finish(I, B, done, [], put_robot(I, R#{track := none}, M));
                {ok, #{cur := #{l := L, r := Rr, speed := S}} = B} ->
                    Step = S * Dt / 1000,
                    DL = clampabs(L, Step), DR = clampabs(Rr, Step),
                    {F, M1} = move(I, DL, DR, M),
                    Cur = maps:get(cur, B),
                    B1 = B#{cur := Cur#{l := L - DL * F, r := Rr - DR * F},
                            travelled := maps:get(travelled, B) + abs(DL + DR) / 2 * F * ?K},
                    R1 = robot_of(I, M1),
                    case F < 1.0 - ?EPS of
                        true -> contact(I, B1, R1, M1);
                        false -> {put_robot(I, R1#{track := {behaviour, phase_done(B1)}}, M1),
                                  []}
                    end
            end;
        #{track := {motors, Motors}} ->
            Step = fun(Port) ->
                           case Motors of
                               #{Port := #{togo := Rem, speed := S}} ->
                                   clampabs(Rem, S * Dt / 1000);
                               #{} -> 0.0
                           end
                   end,
            DL = Step(a), DR = Step(c),
            {F, M1} = move(I, DL, DR, M),
            Moved = maps:map(fun(a, Mo) -> advance_motor(Mo, DL * F);
                                (c, Mo) -> advance_motor(Mo, DR * F)
                             end, Motors),
            R1 = robot_of(I, M1),
            Stalled = F < 1.0 - ?EPS,
            {Done, Running} = lists:partition(
                                fun({_, #{togo := Rem}}) -> Stalled orelse abs(Rem) < ?EPS end,
                                lists:sort(maps:to_list(Moved))),
            Result = case Stalled of true -> stalled; false -> done end,
            Track = case Running of
                        [] -> none;
                        _ -> {motors, maps:from_list(Running)}
                    end,
            M2 = put_robot(I, R1#{track := Track}, M1),
            {M2, [motor_answer(I, Base, Req, Result, Port, T, M2)
                  || {Port, #{req := Req, base := Base, turned := T}} <- Done]}
    end.

advance_motor(#{togo := Rem, turned := T} = Mo, D) -> Mo#{togo := Rem - D, turned := T + D}.

move(_I, DL, DR, M) when abs(DL) < ?EPS, abs(DR) < ?EPS ->
    {1.0, M};
move(I, DL, DR, #m{arena = A} = M) ->
    {F, A1} = avatar_sim_arena:drive(A, I, DL, DR),
    R = robot_of(I, M),
    #{tacho := #{a := TA, c := TC} = Tacho} = R,
    {F, put_robot(I, R#{tacho := Tacho#{a := TA + DL * F, c := TC + DR * F}},
                  M#m{arena = A1})}.

%% The current phase, resolved against the pose when it starts. Explore
%% makes up its next moves from the seeded random state.
resolve(#{cur := #{}} = B, _I, _M) ->
    {ok, B};
resolve(#{phases := [Spec | Rest]} = B, I, M) ->
    case phase(Spec, pose(I, M)) of
        skip -> resolve(B#{phases := Rest}, I, M);
        Cur -> {ok, B#{phases := Rest, cur := Cur}}
    end;
resolve(#{phases := [], kind := explore} = B, _I, _M) ->
    %% The next moves are made up by wander/2 at the end of this tick; this
    %% tick is spent standing still.
    {ok, B#{cur := #{l => 0.0, r => 0.0, speed => 0.0}}};
resolve(#{phases := []} = B, _I, _M) ->
    {done, B}.

phase_done(#{cur := #{l := L, r := R}} = B) when abs(L) < ?EPS, abs(R) < ?EPS ->
    B#{cur := undefined};
phase_done(B) -> B.

phase({drive, Mm, Speed}, _Pose) when abs(Mm) < ?EPS; Speed =< 0 -> skip;
phase({drive, Mm, Speed}, _Pose) ->
    Deg = Mm / ?K,
    #{l => Deg, r => Deg, speed => Speed / ?K};
phase({turn, Angle, _Speed}, _Pose) when abs(Angle) < ?EPS -> skip;
phase({turn, Angle, Speed}, _Pose) ->
    Half = avatar_sim_arena:track() / 2,
    Deg = Angle * math:pi() / 180 * Half / ?K,
    #{l => -Deg, r => Deg, speed => Speed * math:pi() / 180 * Half / ?K};
phase({turn_towards, X, Y}, #{x := PX, y := PY, h := H}) ->
    case math:sqrt((X - PX) * (X - PX) + (Y - PY) * (Y - PY)) < 1.0 of
        true -> skip;
        false ->
            Target = math:atan2(Y - PY, X - PX) * 180 / math:pi(),
            phase({turn, delta(Target, H), 90}, undefined)
    end;
phase({drive_to, X, Y}, #{x := PX, y := PY}) ->
    phase({drive, math:sqrt((X - PX) * (X - PX) + (Y - PY) * (Y - PY)), 150}, undefined);
phase({turn_to, H1}, #{h := H}) ->
    phase({turn, delta(H1, H), 90}, undefined).

delta(Target, H) ->
    D = avatar_sim_arena:normalise(Target - H),
    case D > 180 of true -> D - 360; false -> D end.

%% The bumper touched something.
contact(I, #{kind := explore} = B, R, M) ->
    %% Back off and turn away, unless this was already backing off.
    {Turn, Rand} = rand:uniform_s(90, M#m.rand),
    Sign = case Turn rem 2 of 0 -> 1; 1 -> -1 end,
    Away = {turn, Sign * (90 + Turn), 90},
    Phases = case B of
                 #{cur := #{l := L}} when L > 0 -> [{drive, -100, 150}, Away];
                 #{} -> [Away]
             end,
    {put_robot(I, R#{track := {behaviour, B#{cur := undefined, phases := Phases}}},
               M#m{rand = Rand}), []};
contact(I, B, R, M) ->
    finish(I, B, contact, [], put_robot(I, R#{track := none}, M)).

%% The claw moves towards its target; it takes a ball when it closes past
%% 60 degrees on one, and lets it go when it opens below 30.
claw(I, Dt, M) ->
    R = robot_of(I, M),
    case R of
        #{claw_task := none} ->
            {M, []};
        #{claw_task := #{target := Target, speed := S} = Task, claw := Claw} ->
            Step = clampabs(Target - Claw, S * Dt / 1000),
            Claw1 = Claw + Step,
            #{tacho := #{b := TB} = Tacho} = R,
            R1 = R#{claw := Claw1, tacho := Tacho#{b := TB + Step}},
            M1 = grip(I, Claw, Claw1, put_robot(I, R1, M)),
            case abs(Target - Claw1) < ?EPS of
                true ->
                    #{claw_task := Task1} = R2 = robot_of(I, M1),
                    #{from := From} = Task,
                    M2 = put_robot(I, R2#{claw_task := none}, M1),
                    {M2, [claw_answer(I, Task1, done, Claw1 - From, M2)]};
                false ->
                    {M1, []}
            end
    end.

grip(I, Before, After, #m{arena = A} = M) ->
    R = robot_of(I, M),
    case R of
        #{holding := none} when Before < 60, After >= 60 ->
            case avatar_sim_arena:ball_at_claw(A, I) of
                {ok, #{id := Id}} ->
                    put_robot(I, R#{holding := Id},
                              M#m{arena = set_ball(Id, #{held_by => I}, A)});
                none -> M
            end;
        #{holding := Id} when Id =/= none, Before >= 30, After < 30 ->
            {CX, CY} = avatar_sim_arena:claw_point(pose(I, M)),
            {X, Y} = avatar_sim_arena:clamp_ball(A, CX, CY),
            Task = maps:get(claw_task, R),
            put_robot(I, R#{holding := none, claw_task := Task#{released => Id}},
                      M#m{arena = set_ball(Id, #{held_by => none, x => X, y => Y}, A)});
        #{} ->
            M
    end.

%% Light and touch after this tick's motion.
sense(I, M) ->
    #{reading := Old, touch := Touch0} = robot_of(I, M),
    {M1, Reading} = read_light(I, M),
    ColourEs = case Old of
                   #{colour := C} when C =:= map_get(colour, Reading) -> [];
                   _ -> [colour_push(I, Reading)]
               end,
    Touch = avatar_sim_arena:clearance(M1#m.arena, I, pose(I, M1)) < 1.0,
    R = robot_of(I, M1),
    TouchEs = case Touch =:= Touch0 of
                  true -> [];
                  false -> [push(I, <<"TouchSensor">>, event, <<"Touch">>,
                                 [{<<"Pressed">>, Touch} | pose_params(I, M1)])]
              end,
    M2 = put_robot(I, R#{touch := Touch}, M1),
    {M3, FoundEs} = found(I, Reading, M2),
    {M3, ColourEs ++ TouchEs ++ FoundEs}.

read_light(I, #m{arena = A, rand = Rand} = M) ->
    R = robot_of(I, M),
    {Reading, Rand1} = avatar_sim_arena:light(A, I, {maps:get(holding, R), Rand}),
    {put_robot(I, R#{reading := Reading}, M#m{rand = Rand1}), Reading}.

%% Explore with UntilObject stops when the sensor sees a ball it may stop for.
found(I, #{source := {ball, Id}, colour := C} = Reading, M) ->
    R = robot_of(I, M),
    case R of
        #{track := {behaviour, #{kind := explore, until := true, ignore := Ignore} = B},
          holding := Holding} when Holding =/= Id ->
            case lists:member(C, Ignore) of
                true -> {M, []};
                false ->
                    #{x := OX, y := OY, luminosity := Lum} = Reading,
                    finish(I, B, found, [{<<"Colour">>, C}, {<<"Luminosity">>, Lum},
                                         {<<"ObjectX">>, OX}, {<<"ObjectY">>, OY}],
                           put_robot(I, R#{track := none}, M))
            end;
        #{} ->
            {M, []}
    end;
found(_I, _Reading, M) ->
    {M, []}.

%% Progress, explore's deadline and next moves, the luminosity stream.
timers(I, #m{now = Now} = M) ->
    R = robot_of(I, M),
    {M1, Es} = case R of
                   #{track := {behaviour, #{deadline := D} = B}} when Now >= D ->
                       finish(I, B, timeout, [], put_robot(I, R#{track := none}, M));
                   #{track := {behaviour, #{next_progress := P} = B}} when Now >= P ->
                       {put_robot(I, R#{track := {behaviour, B#{next_progress := P + M#m.progress}}},
                                  M),
                        [answer(I, maps:get(base, B), maps:get(req, B), progress,
                                progress_params(B, I, M), M)]};
                   #{} ->
                       {M, []}
               end,
    M2 = wander(I, M1),
    R2 = robot_of(I, M2),
    case R2 of
        #{next_light := NL, reading := #{luminosity := Lum}} when Now >= NL ->
            {put_robot(I, R2#{next_light := NL + M#m.light_period}, M2),
             Es ++ [push(I, <<"LightSensor">>, sensor_data, <<"Luminosity">>,
                         [{<<"Luminosity">>, Lum}, {<<"Unit">>, <<"percent">>}])]};
        #{} ->
            {M2, Es}
    end.

wander(I, M) ->
    R = robot_of(I, M),
    case R of
        #{track := {behaviour, #{kind := explore, phases := [], cur := undefined} = B}} ->
            {Len, Rand1} = rand:uniform_s(500, M#m.rand),
            {Turn, Rand2} = rand:uniform_s(240, Rand1),
            Phases = [{drive, 200 + Len, 150}, {turn, Turn - 120, 90}],
            put_robot(I, R#{track := {behaviour, B#{cur := undefined, phases := Phases}}},
                      M#m{rand = Rand2});
        #{} ->
            M
    end.

progress_params(#{kind := forward, travelled := T, total := Total}, I, M) ->
    Percent = case Total < ?EPS of true -> 100; false -> min(100, round(100 * T / Total)) end,
    [{<<"Travelled">>, T}, {<<"Percent">>, Percent} | pose_params(I, M)];
progress_params(#{kind := explore, travelled := T, started := S}, I, #m{now = Now} = M) ->
    [{<<"Travelled">>, T}, {<<"Elapsed">>, Now - S} | pose_params(I, M)];
progress_params(#{kind := goto, target := {X, Y}}, I, M) ->
    #{x := PX, y := PY} = pose(I, M),
    [{<<"Remaining">>, math:sqrt((X - PX) * (X - PX) + (Y - PY) * (Y - PY))}
     | pose_params(I, M)];
progress_params(_B, I, M) ->
    pose_params(I, M).

%% ---------------------------------------------------------------------------
%% Signals
%% ---------------------------------------------------------------------------

answer(I, Base, #{body := #{type := Requested}} = Req, Context, Params, M) ->
    #{fb := #{Base := {Cat, Type}}} = robot_of(I, M),
    {answer, Req, Context,
     #{category => Cat, type => Type,
       parameters => avatar_sim_param:params([{<<"Service">>, Requested} | Params])}}.

motor_answer(I, Base, Req, Result, Port, Turned, M) ->
    #{tacho := Tacho} = robot_of(I, M),
    answer(I, Base, Req, feedback,
           [{<<"Result">>, Result}, {<<"Port">>, string:uppercase(atom_to_binary(Port))},
            {<<"Angle">>, Turned}, {<<"Tacho">>, maps:get(Port, Tacho)}], M).

claw_answer(I, #{base := Base, req := Req, kind := motor}, Result, Turned, M) ->
    motor_answer(I, Base, Req, Result, b, Turned, M);
claw_answer(I, #{base := Base, req := Req, kind := grab}, Result, _Turned, M) ->
    #{holding := H} = robot_of(I, M),
    Extra = case H of
                none -> [{<<"Holding">>, false}];
                Id -> [{<<"Holding">>, true},
                       {<<"Colour">>, maps:get(colour, ball(Id, M#m.arena))}]
            end,
    answer(I, Base, Req, feedback, [{<<"Result">>, Result} | Extra], M);
claw_answer(I, #{base := Base, req := Req, kind := release} = Task, Result, _Turned, M) ->
    Extra = case Task of
                #{released := Id} ->
                    #{colour := C, x := X, y := Y} = ball(Id, M#m.arena),
                    [{<<"Released">>, C}, {<<"BallX">>, X}, {<<"BallY">>, Y}];
                #{} ->
                    [{<<"Released">>, <<"none">>}]
            end,
    answer(I, Base, Req, feedback, [{<<"Result">>, Result} | Extra], M).

error_answer(Req, Code, Message) ->
    {answer, Req, error, #{category => <<"ERROR">>, type => Code,
                           parameters => [{<<"Message">>, Message}]}}.

push(I, Base, Context, Type, Params) ->
    {push, avatar_sim_desc:robot_component(I, Base), Context,
     #{category => <<"SENSOR">>, type => Type, parameters => avatar_sim_param:params(Params)}}.

colour_push(I, Reading) ->
    push(I, <<"LightSensor">>, sensor_data, <<"ColourApproximation">>, light_params(Reading)).

light_params(#{colour := C, luminosity := L, rgb := {R, G, B}, x := X, y := Y}) ->
    [{<<"Colour">>, C}, {<<"Luminosity">>, L}, {<<"R">>, R}, {<<"G">>, G}, {<<"B">>, B},
     {<<"X">>, X}, {<<"Y">>, Y}].

pose_params(I, M) ->
    #{x := X, y := Y, h := H} = pose(I, M),
    [{<<"X">>, X}, {<<"Y">>, Y}, {<<"Heading">>, round(H) rem 360}].

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

robot_of(I, #m{robots = Robots}) -> maps:get(I, Robots).
put_robot(I, R, #m{robots = Robots} = M) -> M#m{robots = Robots#{I := R}}.
pose(I, #m{arena = #{poses := Poses}}) -> maps:get(I, Poses).

ball(Id, #{balls := Balls}) ->
    [B] = [B || #{id := I} = B <- Balls, I =:= Id],
    B.

set_ball(Id, Changes, #{balls := Balls} = A) ->
    A#{balls := [case B of
                     #{id := Id} -> maps:merge(B, Changes);
                     _ -> B
                 end || B <- Balls]}.

ball_position(#{held_by := none, x := X, y := Y}, _A) -> {X, Y};
ball_position(#{held_by := I}, #{poses := Poses}) ->
    avatar_sim_arena:claw_point(maps:get(I, Poses)).

clamp(V, Lo, Hi) -> max(Lo, min(Hi, V)).

clampabs(V, Max) when V > Max -> float(Max);
clampabs(V, Max) when V < -Max -> float(-Max);
clampabs(V, _Max) -> float(V).

sign(V) when V < 0 -> -1;
sign(_) -> 1.

keyword(Bin) -> string:lowercase(<< <<C>> || <<C>> <= Bin, is_alnum(C) >>).

is_alnum(C) -> (C >= $a andalso C =< $z) orelse (C >= $A andalso C =< $Z)
                   orelse (C >= $0 andalso C =< $9).

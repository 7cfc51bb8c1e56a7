%% @doc Internal. Pure geometry of the LEGO arena (paper 3.1): walls, round
%% robots driven by two wheels, balls, white zones on a grey floor; moving a
%% robot as far as it can go before a contact, the claw point, and the light
%% sensor's noisy RGB reading with its colour approximation.
-module(avatar_sim_arena).

-export([new/1, drive/4, clearance/3, claw_point/1, light/3, classify/1, palette/0,
         ball_at_claw/2, zone_of/3, surface/3, clamp_ball/3, normalise/1,
         robot_radius/0, ball_radius/0, wheel_mm_per_deg/0, track/0]).

-export_type([arena/0, pose/0, ball/0, rgb/0]).

-type pose() :: #{x := float(), y := float(), h := float()}.
-type ball() :: #{id := pos_integer(), colour := binary(), x := float(), y := float(),
                  held_by := none | pos_integer()}.
-type rgb() :: {0..255, 0..255, 0..255}.
-type arena() :: #{width := number(), height := number(), zones := [map()], balls := [ball()],
                   poses := #{pos_integer() => pose()}}.

-define(ROBOT_R, 80.0).
-define(BALL_R, 30.0).
-define(CLAW, 110.0).            % robot radius + ball radius
-define(WHEEL_D, 56.0).
-define(TRACK, 120.0).
-define(SEE, 45.0).              % a ball is seen when its centre is this close to the claw point
-define(GRAB, 40.0).             % and can be grabbed when this close
-define(NOISE, 8.0).

-spec robot_radius() -> float().
robot_radius() -> ?ROBOT_R.
-spec ball_radius() -> float().
ball_radius() -> ?BALL_R.
%% @doc Millimetres travelled per degree of wheel rotation.
-spec wheel_mm_per_deg() -> float().
wheel_mm_per_deg() -> math:pi() * ?WHEEL_D / 360.
-spec track() -> float().
track() -> ?TRACK.

%% @doc A new arena from options (docs/avatars.md section 3.1).
-spec new(map()) -> arena().
new(Opts) ->
    Balls = maps:get(balls, Opts,
                     [#{colour => <<"red">>, x => 1000, y => 450},
                      #{colour => <<"green">>, x => 550, y => 1050},
                      #{colour => <<"blue">>, x => 1450, y => 800}]),
    Zones = maps:get(zones, Opts,
                     [#{name => <<"nw">>, x => 250, y => 1250},
                      #{name => <<"n">>, x => 1000, y => 1300},
                      #{name => <<"se">>, x => 1750, y => 250}]),
    #{width => maps:get(width, Opts, 2000), height => maps:get(height, Opts, 1500),
      zones => [Z#{x := float(X), y := float(Y), r => float(maps:get(r, Z, 150))}
                || #{x := X, y := Y} = Z <- Zones],
      balls => [#{id => I, colour => C, x => float(X), y => float(Y), held_by => none}
                || {I, #{colour := C, x := X, y := Y}} <- lists:zip(lists:seq(1, length(Balls)),
                                                                   Balls)],
      poses => #{}}.

%% @doc Moves robot `Index' by turning its left and right wheels `DL' and
%% `DR' degrees, or by as large a part of that as it can before touching
%% something. Returns the part done, in [0, 1], and the new arena.
-spec drive(arena(), pos_integer(), float(), float()) -> {float(), arena()}.
drive(#{poses := Poses} = A, Index, DL, DR) ->
    Pose = maps:get(Index, Poses),
    Try = fun(F) -> integrate(Pose, F * DL, F * DR) end,
    Floor = min(0.0, clearance(A, Index, Pose)) - 1.0e-6,
    Ok = fun(F) -> clearance(A, Index, Try(F)) >= Floor end,
    %% Check the path every 5 mm or less, so a long move cannot jump over
    %% an obstacle, then close in on the first contact.
    Steps = max(1, ceil(max(abs(DL), abs(DR)) * wheel_mm_per_deg() / 5)),
    F = first_contact(Ok, 0.0, [I / Steps || I <- lists:seq(1, Steps)]),
    {F, A#{poses := Poses#{Index := Try(F)}}}.

first_contact(_Ok, _Last, []) -> 1.0;
first_contact(Ok, Last, [F | Rest]) ->
    case Ok(F) of
        true -> first_contact(Ok, F, Rest);
        false -> bisect(Ok, Last, F, 14)
    end.

bisect(_Ok, Lo, _Hi, 0) -> Lo;
bisect(Ok, Lo, Hi, N) ->
    Mid = (Lo + Hi) / 2,
    case Ok(Mid) of
        true -> bisect(Ok, Mid, Hi, N - 1);
        false -> bisect(Ok, Lo, Mid, N - 1)
    end.

%% Differential drive: arc lengths of the wheels give the turn and the
%% distance, applied at the mean heading.
integrate(#{x := X, y := Y, h := H}, DL, DR) ->
    K = wheel_mm_per_deg(),
    SL = DL * K, SR = DR * K,
    DTheta = (SR - SL) / ?TRACK,
    DS = (SL + SR) / 2,
    Mid = rad(H) + DTheta / 2,
    #{x => X + DS * math:cos(Mid), y => Y + DS * math:sin(Mid),
      h => normalise(H + DTheta * 180 / math:pi())}.

%% @doc How far robot `Index' at `Pose' is from touching anything (mm;
%% negative when overlapping): walls, free balls, other robots.
-spec clearance(arena(), pos_integer(), pose()) -> float().
clearance(#{width := W, height := H, balls := Balls, poses := Poses}, Index,
          #{x := X, y := Y}) ->
    Walls = [X - ?ROBOT_R, W - X - ?ROBOT_R, Y - ?ROBOT_R, H - Y - ?ROBOT_R],
    BallGaps = [dist(X, Y, BX, BY) - ?ROBOT_R - ?BALL_R
                || #{x := BX, y := BY, held_by := none} <- Balls],
    RobotGaps = [dist(X, Y, RX, RY) - 2 * ?ROBOT_R
                 || {I, #{x := RX, y := RY}} <- maps:to_list(Poses), I =/= Index],
    lists:min(Walls ++ BallGaps ++ RobotGaps).

%% @doc The point the claw and the light sensor look at.
-spec claw_point(pose()) -> {float(), float()}.
claw_point(#{x := X, y := Y, h := H}) ->
    {X + ?CLAW * math:cos(rad(H)), Y + ?CLAW * math:sin(rad(H))}.

%% @doc The free ball that a closing claw would take, if any.
-spec ball_at_claw(arena(), pos_integer()) -> {ok, ball()} | none.
ball_at_claw(#{balls := Balls, poses := Poses}, Index) ->
    {CX, CY} = claw_point(maps:get(Index, Poses)),
    nearest([B || #{x := BX, y := BY, held_by := none} = B <- Balls,
                  dist(CX, CY, BX, BY) =< ?GRAB], CX, CY).

%% @doc What the light sensor of robot `Index' looks at: `{ball, Ball}' (held
%% or within sight of the claw point) or `{floor | zone | wall, RGB}'.
-spec surface(arena(), pos_integer(), none | pos_integer()) ->
          {ball, ball()} | {floor | zone | wall, rgb()}.
surface(#{balls := Balls} = A, Index, Holding) ->
    {CX, CY} = claw_point(maps:get(Index, maps:get(poses, A))),
    Held = [B || #{id := Id} = B <- Balls, Id =:= Holding],
    Seen = nearest([B || #{x := BX, y := BY, held_by := none} = B <- Balls,
                         dist(CX, CY, BX, BY) =< ?SEE], CX, CY),
    case {Held, Seen} of
        {[B | _], _} -> {ball, B};
        {[], {ok, B}} -> {ball, B};
        {[], none} ->
            #{width := W, height := H} = A,
            case CX < 0 orelse CY < 0 orelse CX > W orelse CY > H of
                true -> {wall, rgb(<<"black">>)};
                false ->
                    case zone_of(A, CX, CY) of
                        none -> {floor, rgb(<<"grey">>)};
                        _ -> {zone, rgb(<<"white">>)}
                    end
            end
    end.

%% @doc A light reading: the true colour plus Gaussian noise from `Rand',
%% classified. Returns `{Reading, Rand1}'.
-spec light(arena(), pos_integer(), {none | pos_integer(), rand:state()}) ->
          {#{colour := binary(), luminosity := integer(), rgb := rgb(), x := float(),
             y := float(), source := term()}, rand:state()}.
light(A, Index, {Holding, Rand}) ->
    {Source, True} = case surface(A, Index, Holding) of
                         {ball, #{id := Id, colour := C}} -> {{ball, Id}, rgb(C)};
                         {Kind, RGB} -> {Kind, RGB}
                     end,
    {R, Rand1} = noisy(element(1, True), Rand),
    {G, Rand2} = noisy(element(2, True), Rand1),
    {B, Rand3} = noisy(element(3, True), Rand2),
    {CX, CY} = claw_point(maps:get(Index, maps:get(poses, A))),
    {#{colour => classify({R, G, B}), luminosity => round((R + G + B) / 7.65),
       rgb => {R, G, B}, x => CX, y => CY, source => Source}, Rand3}.

noisy(V, Rand) ->
    {N, Rand1} = rand:normal_s(Rand),
    {max(0, min(255, round(V + N * ?NOISE))), Rand1}.

%% @doc The palette colour nearest to an RGB reading.
-spec classify(rgb()) -> binary().
classify({R, G, B}) ->
    {_, Name} = lists:min([{(R - PR) * (R - PR) + (G - PG) * (G - PG) + (B - PB) * (B - PB), N}
                           || {N, {PR, PG, PB}} <- palette()]),
    Name.

-spec palette() -> [{binary(), rgb()}].
palette() ->
    [{<<"red">>, {200, 40, 40}}, {<<"green">>, {40, 170, 60}}, {<<"blue">>, {40, 60, 200}},
     {<<"yellow">>, {220, 200, 40}}, {<<"white">>, {235, 235, 235}},
     {<<"grey">>, {128, 128, 128}}, {<<"black">>, {25, 25, 25}}].

rgb(Name) ->
    case lists:keyfind(Name, 1, palette()) of
        {_, RGB} -> RGB;
        false -> {128, 128, 128}
    end.

-spec zone_of(arena(), float(), float()) -> none | binary().
zone_of(#{zones := Zones}, X, Y) ->
    case [N || #{name := N, x := ZX, y := ZY, r := R} <- Zones, dist(X, Y, ZX, ZY) =< R] of
        [N | _] -> N;
        [] -> none
    end.

%% @doc Where a released ball comes to rest: the point, kept inside the walls.
-spec clamp_ball(arena(), float(), float()) -> {float(), float()}.
clamp_ball(#{width := W, height := H}, X, Y) ->
    {max(?BALL_R, min(W - ?BALL_R, X)), max(?BALL_R, min(H - ?BALL_R, Y))}.

%% @doc An angle in degrees brought into [0, 360).
-spec normalise(number()) -> float().
normalise(H) ->
    M = math:fmod(float(H), 360.0),
    case M < 0 of true -> M + 360.0; false -> M end.

nearest([], _X, _Y) -> none;
nearest(Balls, X, Y) ->
    {_, _, B} = lists:min([{dist(X, Y, BX, BY), Id, Ball}
                           || #{x := BX, y := BY, id := Id} = Ball <- Balls]),
    {ok, B}.

dist(X1, Y1, X2, Y2) -> math:sqrt((X1 - X2) * (X1 - X2) + (Y1 - Y2) * (Y1 - Y2)).

rad(Deg) -> Deg * math:pi() / 180.

%% @doc Internal. The simulated worlds running on this node as JSON-ready
%% maps, for the dashboard (docs/dashboard.md): the home as a floor plan
%% (rooms with their devices and lights, last motion, people, the keypad's
%% alarm state, sounds played, photos taken) and the LEGO arena (its size,
%% zones, robots, balls). avatar_sim names {@link scenes/0} in its
%% application environment (`dashboard_scenes'); evatar_web calls what it
%% finds there, so neither application depends on the other.
-module(avatar_sim_scene).

-export([scenes/0, scene/2]).

-define(MAX_LIST, 50).

%% @doc Every running world, in start order of their supervisors.
-spec scenes() -> [map()].
scenes() ->
    %% which_children/1 lists the newest first.
    Worlds = [W || {_, Sup, supervisor, _} <- lists:reverse(supervisor:which_children(avatar_sim_sup)),
                   is_pid(Sup),
                   {world, W, _, _} <- children(Sup), is_pid(W)],
    lists:append([scene_of(W) || W <- Worlds]).

children(Sup) ->
    try supervisor:which_children(Sup)
    catch exit:_ -> []
    end.

scene_of(World) ->
    try avatar_sim_world:call(World, scene) of
        {Model, State} -> [scene(Model, State)]
    catch
        exit:_ -> []
    end.

%% @doc One world's state (avatar_sim:state/1) as a scene.
-spec scene(module(), map()) -> map().
scene(avatar_sim_house, S) ->
    #{kind => <<"home">>, time => maps:get(time, S),
      rooms => [#{name => R, devices => [atom_to_binary(K) || K <- Kinds],
                  light => light(maps:get(R, maps:get(lights, S), none)),
                  last_motion => null_never(maps:get(R, maps:get(motion, S, #{}), never)),
                  people => lists:sort([P || {P, #{room := PR}} <- maps:to_list(maps:get(people, S)),
                                             PR =:= R])}
                || {R, Kinds} <- lists:sort(maps:to_list(maps:get(rooms, S, #{})))],
      people => [#{name => P, room => R, moving => M}
                 || {P, #{room := R, moving := M}} <- lists:sort(maps:to_list(maps:get(people, S)))],
      alarm => #{attempts => maps:get(attempts, S, 0),
                 keypad => [#{time => T, who => W, wrong => Wr}
                            || #{time := T, who := W, wrong := Wr} <- last(maps:get(keypad, S))],
                 played => [json_map(P) || P <- last(maps:get(played, S))],
                 emails => length(maps:get(emails, S)), sms => length(maps:get(sms, S))},
      photos => [#{id => Id, room => R, time => T, people => Ps}
                 || #{id := Id, room := R, time := T, people := Ps} <- last(maps:get(photos, S))]};
scene(avatar_sim_robots, S) ->
    #{kind => <<"arena">>, time => maps:get(time, S),
      width => maps:get(width, S, 2000), height => maps:get(height, S, 1500),
      zones => [json_map(Z) || Z <- maps:get(zones, S)],
      robots => [#{index => I, entity => E, x => X, y => Y, heading => H,
                   behaviour => atom_text(B), holding => atom_text(Hold), claw => C}
                 || #{index := I, entity := E, x := X, y := Y, heading := H, behaviour := B,
                      holding := Hold, claw := C} <- maps:get(robots, S)],
      balls => [#{colour => Col, x => X, y => Y, zone => atom_text(Z), held => HB =/= none}
                || #{colour := Col, x := X, y := Y, zone := Z, held_by := HB} <- maps:get(balls, S)]};
scene(Model, _S) ->
    #{kind => atom_to_binary(Model)}.

last(L) -> lists:nthtail(max(0, length(L) - ?MAX_LIST), L).

light(on) -> <<"on">>;
light(off) -> <<"off">>;
light(_) -> null.

null_never(never) -> null;
null_never(T) -> T.

atom_text(none) -> null;
atom_text(A) when is_atom(A) -> atom_to_binary(A);
atom_text(B) -> B.

%% Values the JSON encoder takes: atoms as text, tuples as lists.
json_map(M) when is_map(M) -> maps:map(fun(_, V) -> json(V) end, M).

json(V) when is_map(V) -> json_map(V);
json(V) when is_list(V) -> [json(X) || X <- V];
json(V) when is_tuple(V) -> [json(X) || X <- tuple_to_list(V)];
json(V) when V =:= true; V =:= false; V =:= null -> V;
json(V) when is_atom(V) -> atom_to_binary(V);
json(V) -> V.

%% @doc The generator of MQTT Avatar descriptions as it was before it ran
%% in batches of short-lived processes with its ComponentIDs in maps: a
%% copy of mqtt_avatar_generate at that time, kept for mqtt_gen_bench to
%% compare with. Not part of the product.
-module(mqtt_gen_bench_old).

-export([components/2, description/3]).

-export_type([overrides/0, override/0]).

-type override() :: #{component => binary(),
                      room => binary(),
                      skip => boolean(),
                      parameters => [bil:parameter()],
                      services => [bil:entry()],
                      consumes => [bil:entry()],
                      feedback => none | binary()}.
%% Keyed by a device key (`ha:<identifier>', `z2m:<ieee address>', with or
%% without the prefix), a device name, or an entity's unique id (HA `unique_id', zigbee2mqtt
%% `<friendly_name>/<property>').
-type overrides() :: #{binary() => override()}.

-define(ROOM, <<"Room">>).

-import(mqtt_avatar_part, [entry/3, camel/1, first_name/1, source/1]).

%% @doc A complete description: `Static' components (hand-written, with
%% their own `Mqtt*' parameters) first, then the generated ones. A generated
%% component whose ComponentID a static one already has is left out.
-spec description(#{entity_id := binary(), static => [bil:component()],
                    overrides => overrides(), api_name => binary()},
                  [mqtt_avatar_discovery:device()], [map()]) ->
          {bil:description(), [map()]}.
description(Opts, Devices, Problems0) ->
    Static = maps:get(static, Opts, []),
    {Generated0, Problems1} = components(Devices, maps:get(overrides, Opts, #{})),
    %% What cannot be checked or written as BIL (a control character in a
    %% topic, an override with a bad parameter) stays out, with a reason.
    Checked = [{C, check(C)} || C <- Generated0],
    Generated = [C || {C, ok} <- Checked],
    Problems = Problems1 ++ lists:append([Ps || {_, {error, Ps}} <- Checked]),
    Taken = [Id || #{id := Id} <- Static],
    Kept = [C || #{id := Id} = C <- Generated, not lists:member(Id, Taken)],
    Clashes = [#{what => component_clash, component => Id,
                 message => <<"a discovered device has the ComponentID of a hand-written "
                              "component; the hand-written one is kept">>}
               || #{id := Id} <- Generated, lists:member(Id, Taken)],
    {#{entity_id => maps:get(entity_id, Opts),
       api_name => maps:get(api_name, Opts, <<"MQTT AVATAR">>),
       entity_type => avatar,
       context => <<"MqttDescription">>,
       components => Static ++ Kept},
     Problems0 ++ Problems ++ Clashes}.

%% @doc One component per device, plus problems (overrides that match
%% nothing).
-spec components([mqtt_avatar_discovery:device()], overrides()) -> {[bil:component()], [map()]}.
components(Devices, Overrides) ->
    {Components, _Used, Keys} =
        lists:foldl(fun(D, {Acc, Used, KeysAcc}) ->
                            {C, Ks} = device(D, Overrides, Used),
                            {Acc ++ [C], [maps:get(id, C) | Used], KeysAcc ++ Ks}
                    end, {[], [], []}, Devices),
    Unused = [#{what => unused_override, key => K,
                message => <<"this override matches no discovered device or entity (yet)">>}
              || K <- lists:sort(maps:keys(Overrides)), not lists:member(K, Keys)],
    {Components, Unused}.

check(#{id := Id} = C) ->
    case mqtt_avatar_spec:from_description(#{components => [C]}) of
        {error, Problems} ->
            {error, [P#{what => bad_mqtt_parameters, message => mqtt_avatar_spec:format_problem(P)}
                     || P <- Problems]};
        {ok, _} ->
            One = #{entity_id => <<"check">>, api_name => <<>>, entity_type => avatar,
                    context => <<>>, components => [C]},
            case mqtt_avatar_spec:round_trip(One) of
                ok -> ok;
                {error, Message} ->
                    {error, [#{what => bad_component, component => Id, message => Message}]}
            end
    end.

%% ---------------------------------------------------------------------------
%% Devices
%% ---------------------------------------------------------------------------

device(#{key := Key, entities := Entities} = D, Overrides, Used) ->
    Name = maps:get(name, D),
    Bare = case binary:split(Key, <<":">>) of
               [_, B] -> B;
               _ -> Key
           end,
    {DevOverride, DevKeys} = lookup([Key, Bare, Name], Overrides),
    Id = unique(case DevOverride of
                    #{component := C} -> C;
                    _ -> first_name([Name, maps:get(model, D), first_entity_name(Entities), Key])
                end, Used),
    Room = case DevOverride of
               #{room := R} -> R;
               _ -> lower(maps:get(room, D))
           end,
    RoomParams = [{?ROOM, Room} || Room =/= undefined],
    Ctx = #{room => RoomParams, device => D},
    {Parts, EntityKeys} =
        lists:foldl(fun(#{uid := Uid} = E, {Acc, Ks}) ->
                            case lookup([Uid], Overrides) of
                                {#{skip := true}, K} ->
                                    {Acc, Ks ++ K};
                                {Override, K} ->
                                    {Acc ++ [apply_override(mqtt_avatar_family:generate(E, Ctx), Override)], Ks ++ K}
                            end
                    end, {[], []}, Entities),
    Services0 = lists:append([S || #{services := S} <- Parts]),
    Streams = lists:append([S || #{consumes := S} <- Parts]),
    SensorParams = lists:append([P || #{sensor := P} <- Parts]),
    Feedback = case [F || #{feedback := F} <- Parts, F =/= none] of
                   [F1 | _] ->
                       [entry(<<"ACTUATOR">>, <<"ACTION FEEDBACK">>,
                              [{<<"Feedback">>, <<"yes">>}, {<<"Device">>, F1}] ++ RoomParams)];
                   [] -> []
               end,
    Combined = combined_read(D, Name, SensorParams, Services0, RoomParams),
    Services1 = Services0 ++ Combined,
    Services = case Services1 of
                   [] -> [entry(<<"SENSOR">>, <<"Read", (camel(Id))/binary>>, RoomParams)];
                   _ -> Services1
               end,
    Avail = availability_params(maps:get(availability, D)),
    [First | Rest] = Services,
    %% A parameter twice in one entry is invalid BIL: a read service names
    %% each value once, though two exposes give it (a power meter's
    %% `power' on two endpoints, a sensor's name and its device class).
    Component = #{id => Id,
                  services => [distinct(E) || E <- [add_params(First, Avail) | Rest]],
                  consumes => [distinct(E) || E <- Streams ++ Feedback]},
    {Component, DevKeys ++ EntityKeys}.

lookup(Keys, Overrides) ->
    case [{K, O} || K <- Keys, is_binary(K), {ok, O} <- [maps:find(K, Overrides)]] of
        [{K, O} | _] -> {O, [K]};
        [] -> {#{}, []}
    end.

apply_override(Part, Override) ->
    Part1 = case Override of
                #{services := S} -> Part#{services := S};
                #{parameters := Ps} ->
                    Part#{services := [set_params(E, Ps) || E <- maps:get(services, Part)]};
                _ -> Part
            end,
    Part2 = case Override of
                #{consumes := C} -> Part1#{consumes := C};
                _ -> Part1
            end,
    %% `feedback': the Device of the component's ACTION FEEDBACK entry, or
    %% `none' for an entity that needs none (a sensor's switch).
    case Override of
        #{feedback := F} -> Part2#{feedback := F};
        _ -> Part2
    end.

combined_read(_D, _Name, [], _Services, _Room) ->
    [];
combined_read(D, Name, SensorParams, Services, Room) ->
    Base = camel(first_name([maps:get(model, D), Name, <<"Device">>])),
    Type = <<"Read", Base/binary>>,
    case lists:any(fun(#{type := T}) -> T =:= Type end, Services) of
        true -> [];
        false -> [entry(<<"SENSOR">>, Type, [{P, <<"yes">>} || P <- SensorParams] ++ Room)]
    end.

avail_source({template, Text}) -> <<"template:", Text/binary>>;
avail_source(V) -> source(V).

availability_params(undefined) ->
    [];
availability_params(#{mode := Mode, entries := Entries}) ->
    %% The first entry's names are bare, the next ones' end in 2, 3 ...
    {Params, _} =
        lists:foldl(fun(#{topic := T, online := On, offline := Off, value := V}, {Acc, N}) ->
                            S = case N of 1 -> <<>>; _ -> integer_to_binary(N) end,
                            {Acc ++ [{<<"MqttAvailabilityTopic", S/binary>>, T},
                                     {<<"MqttPayloadAvailable", S/binary>>, On},
                                     {<<"MqttPayloadNotAvailable", S/binary>>, Off},
                                     {<<"MqttAvailabilityValue", S/binary>>, avail_source(V)}],
                             N + 1}
                    end, {[], 1}, Entries),
    Params ++ [{<<"MqttAvailabilityMode">>, atom_to_binary(Mode)} || Mode =/= latest].

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

add_params(#{parameters := Ps} = E, Extra) ->
    E#{parameters := Ps ++ [P || {N, _} = P <- Extra, not lists:keymember(N, 1, Ps)]}.

set_params(#{parameters := Ps} = E, Set) ->
    Replaced = [case lists:keyfind(N, 1, Set) of
                    {N, V1} -> {N, V1};
                    false -> {N, V}
                end || {N, V} <- Ps],
    E#{parameters := Replaced ++ [P || {N, _} = P <- Set, not lists:keymember(N, 1, Ps)]}.

%% The entry with each parameter kept once, at its first place, when
%% every other occurrence has the same value (a different value stays, and
%% the check then reports the component).
distinct(#{parameters := Ps} = E) ->
    {Kept, _} = lists:foldl(fun(P, {Acc, Seen}) ->
                                    case maps:is_key(P, Seen) of
                                        true -> {Acc, Seen};
                                        false -> {[P | Acc], Seen#{P => true}}
                                    end
                            end, {[], #{}}, Ps),
    E#{parameters := lists:reverse(Kept)}.

first_entity_name(Entities) ->
    case [N || #{name := N} <- Entities, is_binary(N)] of
        [N | _] -> N;
        [] -> undefined
    end.


lower(undefined) -> undefined;
lower(B) -> string:lowercase(B).

unique(Base0, Used) ->
    Base = case camel(Base0) of
               <<>> -> <<"Device">>;
               B -> B
           end,
    unique(Base, Used, 1).

unique(Base, Used, N) ->
    Id = case N of
             1 -> Base;
             _ -> <<Base/binary, (integer_to_binary(N))/binary>>
         end,
    case lists:member(Id, Used) of
        true -> unique(Base, Used, N + 1);
        false -> Id
    end.

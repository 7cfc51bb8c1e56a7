%% @doc Internal. Turns discovered devices into BIL components with the
%% reserved `Mqtt*' parameters (docs/mqtt.md section 4 lists the rules), so
%% devices join EVATAR without anyone writing BIL; per-device and
%% per-entity overrides adapt the result to a VA's body.
%%
%% Devices are generated and checked in batches of ?BATCH, each in a
%% short-lived process: generating a device makes some hundred times its
%% components' size in garbage, and a process that holds thousands of
%% components while it makes that garbage spends most of its time in
%% garbage collection (3,000 devices took 25 times as long as 300).
%% ComponentIDs and the overrides used are kept in maps, so the whole is
%% n log n (docs/mqtt.md section 6, "Large homes"). No other side effect.
-module(mqtt_avatar_generate).

-export([components/2, description/3, build/3]).

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
-type opts() :: #{entity_id := binary(), static => [bil:component()],
                  overrides => overrides(), api_name => binary()}.

-define(ROOM, <<"Room">>).
%% Devices generated and checked by one short-lived process.
-define(BATCH, 64).

-import(mqtt_avatar_part, [entry/3, camel/1, first_name/1, source/1]).

%% @doc A complete description: `Static' components (hand-written, with
%% their own `Mqtt*' parameters) first, then the generated ones. A generated
%% component whose ComponentID a static one already has is left out.
-spec description(opts(), [mqtt_avatar_discovery:device()], [map()]) ->
          {bil:description(), [map()]}.
description(Opts, Devices, Problems0) ->
    {Description, _Specs, Problems} = generate(Opts, Devices, Problems0),
    {Description, Problems}.

%% @doc As `description/3', with the description's runtime spec (what
%% `mqtt_avatar_spec:from_description/1' gives for it, made from the
%% generated components' checks instead of a second pass). The static
%% components must be valid.
-spec build(opts(), [mqtt_avatar_discovery:device()], [map()]) ->
          {bil:description(), mqtt_avatar_spec:spec(), [map()]}.
build(Opts, Devices, Problems0) ->
    {ok, #{components := StaticSpecs}} =
        mqtt_avatar_spec:from_description(#{components => maps:get(static, Opts, [])}),
    {Description, Specs, Problems} = generate(Opts, Devices, Problems0),
    {Description, mqtt_avatar_spec:of_components(StaticSpecs ++ Specs), Problems}.

generate(Opts, Devices, Problems0) ->
    Static = maps:get(static, Opts, []),
    Overrides = maps:get(overrides, Opts, #{}),
    Taken = maps:from_list([{Id, true} || #{id := Id} <- Static]),
    {Results, Unused} = run(Devices, Overrides),
    %% What cannot be checked or written as BIL (a control character in a
    %% topic, an override with a bad parameter) stays out, with a reason.
    Kept = [{C, S} || {#{id := Id} = C, {ok, S}} <- Results, not maps:is_key(Id, Taken)],
    Bad = lists:append([Ps || {_, {error, Ps}} <- Results]),
    Clashes = [#{what => component_clash, component => Id,
                 message => <<"a discovered device has the ComponentID of a hand-written "
                              "component; the hand-written one is kept">>}
               || {#{id := Id}, {ok, _}} <- Results, maps:is_key(Id, Taken)],
    {#{entity_id => maps:get(entity_id, Opts),
       api_name => maps:get(api_name, Opts, <<"MQTT AVATAR">>),
       entity_type => avatar,
       context => <<"MqttDescription">>,
       components => Static ++ [C || {C, _} <- Kept]},
     [S || {_, S} <- Kept],
     lists:append([Problems0, Unused, Bad, Clashes])}.

%% @doc One component per device, plus problems (overrides that match
%% nothing).
-spec components([mqtt_avatar_discovery:device()], overrides()) -> {[bil:component()], [map()]}.
components(Devices, Overrides) ->
    {Results, Unused} = run(Devices, Overrides),
    {[C || {C, _} <- Results], Unused}.

%% Every device's component with its check, in order, and the overrides
%% that matched nothing. The ComponentIDs are chosen here, in device
%% order, so the batches are independent.
run(Devices, Overrides) ->
    {Named, _Ids, UsedKeys} =
        lists:foldl(fun(D, {Acc, Ids, Keys}) ->
                            {Id, Ks, Ids1} = device_id(D, Overrides, Ids),
                            {[{D, Id} | Acc], Ids1, add_keys(Ks, Keys)}
                    end, {[], {#{}, #{}}, #{}}, Devices),
    {Results, EntityKeys} = batches(lists:reverse(Named), Overrides, [], []),
    Used = add_keys(EntityKeys, UsedKeys),
    Unused = [#{what => unused_override, key => K,
                message => <<"this override matches no discovered device or entity (yet)">>}
              || K <- lists:sort(maps:keys(Overrides)), not maps:is_key(K, Used)],
    {Results, Unused}.

add_keys(Ks, Map) -> lists:foldl(fun(K, M) -> M#{K => true} end, Map, Ks).

batches([], _Overrides, Acc, Keys) ->
    {lists:append(lists:reverse(Acc)), lists:append(Keys)};
batches(Named, Overrides, Acc, Keys) ->
    {Batch, Rest} = case length(Named) > ?BATCH of
                        true -> lists:split(?BATCH, Named);
                        false -> {Named, []}
                    end,
    {Results, Ks} = isolated(fun() -> batch(Batch, Overrides) end),
    batches(Rest, Overrides, [Results | Acc], [Ks | Keys]).

batch(Named, Overrides) ->
    Generated = [device(D, Id, Overrides) || {D, Id} <- Named],
    {[{C, check(C)} || {C, _} <- Generated], lists:append([Ks || {_, Ks} <- Generated])}.

%% `Fun()' in a process of its own, whose garbage goes with it; its
%% result is copied back. A crash there is a crash here.
isolated(Fun) ->
    Parent = self(),
    Tag = make_ref(),
    {Pid, Ref} = spawn_monitor(fun() -> Parent ! {Tag, Fun()} end),
    receive
        {Tag, Result} ->
            demonitor(Ref, [flush]),
            Result;
        {'DOWN', Ref, process, Pid, Reason} ->
            exit(Reason)
    end.

check(#{id := Id} = C) ->
    case mqtt_avatar_spec:from_description(#{components => [C]}) of
        {error, Problems} ->
            {error, [P#{what => bad_mqtt_parameters, message => mqtt_avatar_spec:format_problem(P)}
                     || P <- Problems]};
        {ok, #{components := [Spec]}} ->
            One = #{entity_id => <<"check">>, api_name => <<>>, entity_type => avatar,
                    context => <<>>, components => [C]},
            case mqtt_avatar_spec:round_trip(One) of
                ok -> {ok, Spec};
                {error, Message} ->
                    {error, [#{what => bad_component, component => Id, message => Message}]}
            end
    end.

%% ---------------------------------------------------------------------------
%% Devices
%% ---------------------------------------------------------------------------

%% The device's ComponentID, the override keys its own override matched,
%% and the ComponentIDs taken so far (a set, and the next suffix to try
%% for each base name, so a thousand devices of one name stay linear).
device_id(#{key := Key, entities := Entities} = D, Overrides, {Used, Next}) ->
    {DevOverride, DevKeys} = lookup(device_keys(D), Overrides),
    Base = case DevOverride of
               #{component := C} -> C;
               _ -> first_name([maps:get(name, D), maps:get(model, D), first_entity_name(Entities),
                                Key])
           end,
    {Id, Next1} = unique(Base, Used, Next),
    {Id, DevKeys, {Used#{Id => true}, Next1}}.

device_keys(#{key := Key} = D) ->
    Bare = case binary:split(Key, <<":">>) of
               [_, B] -> B;
               _ -> Key
           end,
    [Key, Bare, maps:get(name, D)].

device(#{entities := Entities} = D, Id, Overrides) ->
    Name = maps:get(name, D),
    {DevOverride, _} = lookup(device_keys(D), Overrides),
    Room = case DevOverride of
               #{room := R} -> R;
               _ -> lower(maps:get(room, D))
           end,
    RoomParams = [{?ROOM, Room} || Room =/= undefined],
    Ctx = #{room => RoomParams, device => D},
    Looked = [{E, lookup([Uid], Overrides)} || #{uid := Uid} = E <- Entities],
    Parts = [apply_override(mqtt_avatar_family:generate(E, Ctx), Override)
             || {E, {Override, _}} <- Looked, maps:get(skip, Override, false) =/= true],
    EntityKeys = lists:append([K || {_, {_, K}} <- Looked]),
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
    {Component, EntityKeys}.

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

unique(Base0, Used, Next) ->
    Base = case camel(Base0) of
               <<>> -> <<"Device">>;
               B -> B
           end,
    unique(Base, Used, Next, maps:get(Base, Next, 1)).

unique(Base, Used, Next, N) ->
    Id = case N of
             1 -> Base;
             _ -> <<Base/binary, (integer_to_binary(N))/binary>>
         end,
    case maps:is_key(Id, Used) of
        true -> unique(Base, Used, Next, N + 1);
        false -> {Id, Next#{Base => N + 1}}
    end.

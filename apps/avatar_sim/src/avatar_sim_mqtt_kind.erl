%% @doc Internal. How each device of the simulated smart home looks on MQTT
%% (docs/mqtt.md section 7): its Home Assistant discovery configs, topics,
%% last will, retained states, how commands on `.../set' become requests to
%% the simulated device and how its answers and readings become state
%% messages. Lights speak zigbee2mqtt's JSON, the socket Tasmota's raw
%% `cmnd/.../POWER' and `stat/.../POWER', the rest JSON. Pure.
-module(avatar_sim_mqtt_kind).

-export([kind/1, device/3, topics/2, command/4, answer/5, push/4, overrides/2, device_name/1,
         node_name/1]).

-export_type([kind/0, device/0, ctx/0]).

-type kind() :: motion | camera | light | socket | microphone | time | speaker | keypad.
-type ctx() :: #{prefix := binary(), discovery_prefix := binary()}.
-type publish() :: {Topic :: binary(), Payload :: iodata(), Retain :: boolean()}.
-type device() :: #{id := binary(),
                    kind := kind(),
                    room := binary() | undefined,
                    availability := #{topic := binary(), online := binary(), offline := binary()},
                    discovery := [{binary(), map()}],
                    commands := [binary()],
                    initial := [publish()]}.

%% ---------------------------------------------------------------------------
%% Devices
%% ---------------------------------------------------------------------------

%% @doc The kind of a smart_home.xml component, told by the services it
%% offers; `none' for what is not an MQTT device here (the notifier is a
%% PC on the network).
-spec kind(bil:component()) -> kind() | none.
kind(#{services := Services}) ->
    Types = [T || #{type := T} <- Services],
    Kinds = [{<<"ReadMotion">>, motion}, {<<"TakePhoto">>, camera}, {<<"TurnLightOn">>, light},
             {<<"SwitchSocketOn">>, socket}, {<<"ListenForCommands">>, microphone},
             {<<"ReadTime">>, time}, {<<"PlaySound">>, speaker}, {<<"ReadKeypad">>, keypad}],
    case [K || {T, K} <- Kinds, lists:member(T, Types)] of
        [K | _] -> K;
        [] -> none
    end.

%% @doc The MQTT face of a component: discovery configs, command topics,
%% availability (last will) and the retained states it starts with.
-spec device(bil:component(), kind(), ctx()) -> device().
device(#{id := Id} = C, Kind, Ctx) ->
    Room = room(C),
    Node = node_name(Id),
    Base = base(Id, Ctx),
    Avail = case Kind of
                socket -> #{topic => <<"tele/", (tasmota(Id, Ctx))/binary, "/LWT">>,
                            online => <<"Online">>, offline => <<"Offline">>};
                _ -> #{topic => <<Base/binary, "/availability">>,
                       online => <<"online">>, offline => <<"offline">>}
            end,
    Dev = #{<<"identifiers">> => [Node], <<"name">> => device_name(Id),
            <<"model">> => model(Kind), <<"manufacturer">> => <<"EVATAR simulation">>},
    Dev1 = case Room of
               undefined -> Dev;
               _ -> Dev#{<<"suggested_area">> => capitalise(Room)}
           end,
    Common = #{<<"availability_topic">> => maps:get(topic, Avail),
               <<"payload_available">> => maps:get(online, Avail),
               <<"payload_not_available">> => maps:get(offline, Avail),
               <<"device">> => Dev1},
    {Entities, Commands, Initial} = entities(Kind, Id, Base, Ctx),
    Prefix = maps:get(discovery_prefix, Ctx),
    #{id => Id, kind => Kind, room => Room, availability => Avail,
      discovery => [{<<Prefix/binary, "/", Component/binary, "/", Node/binary, "/", Object/binary,
                       "/config">>,
                     maps:merge(Common, Config#{<<"unique_id">> => <<Node/binary, "-", Object/binary>>})}
                    || {Component, Object, Config} <- Entities],
      commands => Commands, initial => Initial}.

entities(motion, _Id, Base, _Ctx) ->
    {[{<<"binary_sensor">>, <<"motion">>,
       #{<<"name">> => <<"Motion">>, <<"device_class">> => <<"motion">>,
         <<"state_topic">> => <<Base/binary, "/state">>,
         <<"json_attributes_topic">> => <<Base/binary, "/state">>,
         <<"value_template">> => <<"{{ value_json.motion }}">>,
         <<"payload_on">> => true, <<"payload_off">> => false}}],
     [], []};
entities(camera, _Id, Base, _Ctx) ->
    {[{<<"button">>, <<"photo">>,
       #{<<"name">> => <<"Take photo">>, <<"command_topic">> => <<Base/binary, "/photo/set">>,
         <<"payload_press">> => <<"PRESS">>}}],
     [<<Base/binary, "/photo/set">>], []};
entities(light, _Id, Base, _Ctx) ->
    {[{<<"light">>, <<"light">>,
       #{<<"name">> => null, <<"schema">> => <<"json">>, <<"~">> => Base,
         <<"state_topic">> => <<"~/state">>, <<"command_topic">> => <<"~/set">>,
         <<"json_attributes_topic">> => <<"~/state">>}}],
     [<<Base/binary, "/set">>],
     [{<<Base/binary, "/state">>, json(#{<<"state">> => <<"OFF">>}), true}]};
entities(socket, Id, _Base, Ctx) ->
    T = tasmota(Id, Ctx),
    {[{<<"switch">>, <<"relay">>,
       #{<<"name">> => <<"Socket">>, <<"device_class">> => <<"outlet">>,
         <<"state_topic">> => <<"stat/", T/binary, "/POWER">>,
         <<"command_topic">> => <<"cmnd/", T/binary, "/POWER">>,
         <<"payload_on">> => <<"ON">>, <<"payload_off">> => <<"OFF">>}}],
     [<<"cmnd/", T/binary, "/POWER">>],
     [{<<"stat/", T/binary, "/POWER">>, <<"OFF">>, true}]};
entities(microphone, _Id, Base, _Ctx) ->
    {[{<<"event">>, <<"voice">>,
       #{<<"name">> => <<"Voice command">>, <<"state_topic">> => <<Base/binary, "/voice">>,
         <<"event_types">> => [<<"voice_command">>]}},
      {<<"switch">>, <<"listen">>,
       #{<<"name">> => <<"Listen for commands">>, <<"state_topic">> => <<Base/binary, "/listen">>,
         <<"command_topic">> => <<Base/binary, "/listen/set">>}}],
     [<<Base/binary, "/listen/set">>],
     [{<<Base/binary, "/listen">>, <<"ON">>, true}]};
entities(time, _Id, Base, _Ctx) ->
    {[{<<"sensor">>, <<"time_of_day">>,
       #{<<"name">> => <<"Time of day">>, <<"state_topic">> => <<Base/binary, "/time_of_day">>,
         <<"json_attributes_topic">> => <<Base/binary, "/time_of_day">>,
         <<"value_template">> => <<"{{ value_json.time_of_day }}">>}},
      {<<"sensor">>, <<"sunset">>,
       #{<<"name">> => <<"Sunset">>, <<"state_topic">> => <<Base/binary, "/sunset">>,
         <<"json_attributes_topic">> => <<Base/binary, "/sunset">>,
         <<"value_template">> => <<"{{ value_json.sunset }}">>}}],
     [], []};
entities(speaker, _Id, Base, _Ctx) ->
    {[{<<"siren">>, <<"sound">>,
       #{<<"name">> => <<"Play sound">>, <<"command_topic">> => <<Base/binary, "/sound/set">>,
         <<"state_topic">> => <<Base/binary, "/sound">>,
         <<"json_attributes_topic">> => <<Base/binary, "/sound">>,
         <<"available_tones">> => [<<"alarm">>, <<"chime">>, <<"doorbell">>],
         <<"support_volume_set">> => true, <<"support_duration">> => true}},
      {<<"notify">>, <<"voice">>,
       #{<<"name">> => <<"Play voice message">>, <<"command_topic">> => <<Base/binary, "/voice/set">>}}],
     [<<Base/binary, "/sound/set">>, <<Base/binary, "/voice/set">>], []};
entities(keypad, _Id, Base, _Ctx) ->
    {[{<<"event">>, <<"input">>,
       #{<<"name">> => <<"Password input">>, <<"state_topic">> => <<Base/binary, "/input">>,
         <<"event_types">> => [<<"password_input">>]}}],
     [], []}.

%% @doc What a person adds to the discovered BIL so that the home binds to
%% smart_home_va.xml as the TCP home does: request parameters that Home
%% Assistant's entities cannot carry (a photo count, a language, a volume
%% for voice messages) and the echoes that answer them. Keyed by the
%% entities' unique ids.
-spec overrides([device()], ctx()) -> mqtt_avatar_generate:overrides().
overrides(Devices, Ctx) ->
    maps:from_list(lists:append([override(D, Ctx) || D <- Devices])).

override(#{id := Id, kind := camera}, Ctx) ->
    Base = base(Id, Ctx),
    [{<<(node_name(Id))/binary, "-photo">>,
      #{parameters => [{<<"Count">>, <<"yes">>}, {<<"Interval">>, <<"yes">>},
                       {<<"MqttCommand">>, <<"json:{}">>},
                       {<<"MqttCommandArgs">>, <<"Count=count Interval=interval">>},
                       {<<"MqttStateTopic">>, <<Base/binary, "/photo">>},
                       {<<"MqttExpect">>, <<"json:state=done">>},
                       {<<"MqttProgress">>, <<"json:state=taking">>},
                       {<<"MqttAttributes">>, <<"all">>}]}}];
override(#{id := Id, kind := microphone, room := Room}, Ctx) ->
    Base = base(Id, Ctx),
    [{<<(node_name(Id))/binary, "-listen">>,
      #{services => [#{category => <<"SENSOR">>, type => <<"ListenForCommands">>,
                       parameters => [{<<"Language">>, <<"en">>}, {<<"Listen">>, <<"yes">>}]
                                     ++ [{<<"Room">>, Room} || Room =/= undefined]
                                     ++ [{<<"MqttCommandTopic">>, <<Base/binary, "/listen/set">>},
                                         {<<"MqttCommand">>, <<"raw:ON">>},
                                         {<<"MqttCommandArgs">>, <<"Listen">>},
                                         {<<"MqttStateTopic">>, <<Base/binary, "/listen">>},
                                         {<<"MqttExpect">>, <<"any">>},
                                         {<<"MqttValue">>, <<"Listening=raw">>},
                                         {<<"MqttMap">>, <<"ON=yes OFF=no">>}]}],
        feedback => none}}];
override(#{id := Id, kind := speaker}, Ctx) ->
    Base = base(Id, Ctx),
    [{<<(node_name(Id))/binary, "-voice">>,
      #{parameters => [{<<"Volume">>, <<"yes">>},
                       {<<"MqttCommand">>, <<"json:{}">>},
                       {<<"MqttCommandArgs">>, <<"Message=message Volume=volume">>},
                       {<<"MqttStateTopic">>, <<Base/binary, "/voice">>},
                       {<<"MqttExpect">>, <<"any">>},
                       {<<"MqttAttributes">>, <<"all">>}]}}];
override(_, _Ctx) ->
    [].

%% ---------------------------------------------------------------------------
%% Traffic
%% ---------------------------------------------------------------------------

%% @doc A message on one of the device's command topics: the request to
%% make of the simulated device (its ServiceType and parameters), or
%% `{error, Why}' for a payload the device does not understand.
-spec command(kind(), binary(), binary(), ctx()) ->
          {request, binary(), [bil:parameter()]} | {error, binary()}.
command(light, _Topic, Payload, _Ctx) ->
    case evatar_json:decode(Payload) of
        {ok, #{<<"state">> := S}} when is_binary(S) ->
            case string:uppercase(S) of
                <<"ON">> -> {request, <<"TurnLightOn">>, []};
                <<"OFF">> -> {request, <<"TurnLightOff">>, []};
                _ -> {error, <<"state must be ON or OFF">>}
            end;
        _ -> {error, <<"expected a JSON object with state">>}
    end;
command(socket, _Topic, Payload, _Ctx) ->
    case on_off(Payload) of
        {ok, true} -> {request, <<"SwitchSocketOn">>, []};
        {ok, false} -> {request, <<"SwitchSocketOff">>, []};
        error -> {error, <<"expected ON or OFF">>}
    end;
command(camera, _Topic, Payload, _Ctx) ->
    case evatar_json:decode(Payload) of
        {ok, M} when is_map(M) ->
            {request, <<"TakePhoto">>, params(M, [{<<"count">>, <<"Count">>},
                                                 {<<"interval">>, <<"Interval">>}])};
        _ -> {request, <<"TakePhoto">>, []}
    end;
command(microphone, _Topic, Payload, _Ctx) ->
    case on_off(Payload) of
        {ok, true} -> {request, <<"ListenForCommands">>, [{<<"Listen">>, <<"yes">>}]};
        {ok, false} -> {request, <<"ListenForCommands">>, [{<<"Listen">>, <<"no">>}]};
        error -> {error, <<"expected ON or OFF">>}
    end;
command(speaker, _Topic, <<>>, _Ctx) ->
    {error, <<"empty command">>};
command(speaker, Topic, Payload, _Ctx) ->
    Json = evatar_json:decode(Payload),
    case binary:longest_common_suffix([Topic, <<"/sound/set">>]) =:= 10 of
        true -> sound(Json);
        false -> voice(Json, Payload)
    end;
command(Kind, _Topic, _Payload, _Ctx) ->
    {error, <<"a ", (atom_to_binary(Kind))/binary, " takes no commands">>}.

sound({ok, M}) when is_map(M) ->
    {request, <<"PlaySound">>, params(M, [{<<"tone">>, <<"Sound">>}, {<<"volume_level">>, <<"Volume">>},
                                          {<<"duration">>, <<"Duration">>}])};
sound(_) ->
    {request, <<"PlaySound">>, []}.

voice({ok, M}, _Payload) when is_map(M) ->
    {request, <<"PlayVoiceMessage">>, params(M, [{<<"message">>, <<"Message">>},
                                                 {<<"volume">>, <<"Volume">>}])};
voice(_, Payload) ->
    {request, <<"PlayVoiceMessage">>, [{<<"Message">>, Payload}]}.

%% @doc What the device publishes when the simulated device answers a
%% request (`progress', `feedback' or `error').
-spec answer(kind(), binary(), progress | feedback | error, [bil:parameter()], map()) ->
          [publish()].
answer(light, _Type, feedback, Ps, #{base := Base, ts := Ts}) ->
    [{<<Base/binary, "/state">>,
      json(#{<<"state">> => string:uppercase(get(<<"Light">>, Ps, <<"off">>)),
             <<"changed">> => get(<<"Changed">>, Ps, <<"no">>) =:= <<"yes">>, <<"ts">> => Ts}),
      true}];
answer(socket, _Type, feedback, Ps, #{tasmota := T}) ->
    [{<<"stat/", T/binary, "/POWER">>, string:uppercase(get(<<"Socket">>, Ps, <<"off">>)), true}];
answer(camera, _Type, progress, Ps, #{base := Base, ts := Ts}) ->
    [{<<Base/binary, "/photo">>, json((values(Ps))#{<<"state">> => <<"taking">>, <<"ts">> => Ts}),
      false}];
answer(camera, _Type, feedback, Ps, #{base := Base, ts := Ts}) ->
    [{<<Base/binary, "/photo">>, json((values(Ps))#{<<"state">> => <<"done">>, <<"ts">> => Ts}),
      false}];
answer(microphone, _Type, feedback, Ps, #{base := Base}) ->
    State = case get(<<"Listening">>, Ps, <<"yes">>) of
                <<"no">> -> <<"OFF">>;
                _ -> <<"ON">>
            end,
    [{<<Base/binary, "/listen">>, State, true}];
answer(speaker, <<"PlaySound">>, feedback, Ps, #{base := Base, ts := Ts}) ->
    [{<<Base/binary, "/sound">>, json((values(Ps))#{<<"state">> => <<"OFF">>, <<"ts">> => Ts}),
      false}];
answer(speaker, <<"PlayVoiceMessage">>, feedback, Ps, #{base := Base, ts := Ts}) ->
    [{<<Base/binary, "/voice">>, json((values(Ps))#{<<"ts">> => Ts}), false}];
answer(_Kind, _Type, _Context, _Ps, _Ctx) ->
    %% Errors and other answers: a real device would just not confirm, so
    %% the command's echo never comes and EVATAR's timeout answers.
    [].

%% @doc What the device publishes for a reading or an event the simulated
%% device pushed (`SensorData' or `Event' of type `Type').
-spec push(kind(), binary(), [bil:parameter()], map()) -> [publish()].
push(motion, <<"MotionDetected">>, Ps, #{base := Base, ts := Ts}) ->
    [{<<Base/binary, "/state">>,
      json((values(Ps, [<<"Room">>, <<"Motion">>]))#{<<"motion">> => get(<<"Motion">>, Ps, <<"no">>) =:= <<"yes">>,
                                                     <<"ts">> => Ts}), true}];
push(keypad, <<"PasswordInput">>, Ps, #{base := Base, ts := Ts}) ->
    Wrong = get(<<"WrongPassword">>, Ps, <<"no">>) =:= <<"yes">>,
    [{<<Base/binary, "/input">>,
      json((values(Ps, [<<"Room">>]))#{<<"event_type">> => <<"password_input">>,
                                       <<"last_input">> => case Wrong of true -> <<"wrong">>;
                                                                         false -> <<"right">> end,
                                       <<"ts">> => Ts}), false}];
push(microphone, <<"VoiceCommand">>, Ps, #{base := Base, ts := Ts}) ->
    [{<<Base/binary, "/voice">>,
      json((values(Ps, [<<"Room">>]))#{<<"event_type">> => <<"voice_command">>, <<"ts">> => Ts}),
      false}];
push(time, <<"TimeOfDay">>, Ps, #{base := Base, ts := Ts}) ->
    [{<<Base/binary, "/time_of_day">>, json((values(Ps))#{<<"ts">> => Ts}), true}];
push(time, <<"Sunset">>, Ps, #{base := Base, ts := Ts}) ->
    [{<<Base/binary, "/sunset">>, json((values(Ps))#{<<"ts">> => Ts}), true}];
push(_Kind, _Type, _Ps, _Ctx) ->
    [].

%% ---------------------------------------------------------------------------
%% Names and topics
%% ---------------------------------------------------------------------------

%% @doc `HallMotionSensor01' gives `Hall Motion Sensor 01', whose
%% CamelCase is the ComponentID again.
-spec device_name(binary()) -> binary().
device_name(Id) ->
    Words = re:split(Id, <<"(?<=[a-z])(?=[A-Z0-9])|(?<=[0-9])(?=[A-Z])">>, [{return, binary}]),
    iolist_to_binary(lists:join(<<" ">>, [W || W <- Words, W =/= <<>>])).

%% @doc `HallMotionSensor01' gives `hall_motion_sensor_01'.
-spec node_name(binary()) -> binary().
node_name(Id) ->
    string:lowercase(iolist_to_binary(lists:join(<<"_">>, binary:split(device_name(Id), <<" ">>,
                                                                       [global])))).

%% @doc The topic roots of a device, for `answer/5' and `push/4'.
-spec topics(binary(), ctx()) -> #{base := binary(), tasmota := binary()}.
topics(Id, Ctx) ->
    #{base => base(Id, Ctx), tasmota => tasmota(Id, Ctx)}.

base(Id, #{prefix := P}) -> <<P/binary, "/", (node_name(Id))/binary>>.

tasmota(Id, #{prefix := P}) -> <<P/binary, "_", (node_name(Id))/binary>>.

model(motion) -> <<"Camera">>;
model(camera) -> <<"Camera">>;
model(light) -> <<"LightSwitch">>;
model(socket) -> <<"SocketSwitch">>;
model(microphone) -> <<"Microphone">>;
model(time) -> <<"Time">>;
model(speaker) -> <<"Speaker">>;
model(keypad) -> <<"Keypad">>.

room(#{services := S, consumes := C}) ->
    case [V || #{parameters := Ps} <- S ++ C, {<<"Room">>, V} <- Ps] of
        [R | _] -> R;
        [] -> undefined
    end.

capitalise(<<C, Rest/binary>>) when C >= $a, C =< $z -> <<(C - 32), Rest/binary>>;
capitalise(B) -> B.

%% ---------------------------------------------------------------------------
%% Payloads
%% ---------------------------------------------------------------------------

json(Map) -> evatar_json:encode(Map).

on_off(Payload) ->
    case string:uppercase(string:trim(Payload)) of
        P when P =:= <<"ON">>; P =:= <<"YES">>; P =:= <<"TRUE">>; P =:= <<"1">> -> {ok, true};
        P when P =:= <<"OFF">>; P =:= <<"NO">>; P =:= <<"FALSE">>; P =:= <<"0">> -> {ok, false};
        _ -> error
    end.

%% JSON fields to request parameters (text, as BIL carries them).
params(M, Fields) ->
    [{Param, evatar_json:to_text(V)} || {Field, Param} <- Fields,
                                             {ok, V} <- [maps:find(Field, M)], V =/= null].

get(Name, Ps, Default) ->
    case lists:keyfind(Name, 1, Ps) of
        {_, V} -> V;
        false -> Default
    end.

values(Ps) -> values(Ps, []).

%% BIL parameters as JSON fields: `LastMotion' gives `last_motion'; yes and
%% no become booleans, decimal text becomes numbers.
values(Ps, Except) ->
    maps:from_list([{snake(N), json_value(V)} || {N, V} <- Ps, not lists:member(N, Except)]).

snake(Name) ->
    string:lowercase(re:replace(Name, <<"(?<=[a-z0-9])(?=[A-Z])">>, <<"_">>,
                                [global, {return, binary}])).

json_value(<<"yes">>) -> true;
json_value(<<"no">>) -> false;
json_value(V) ->
    case re:run(V, <<"^-?(0|[1-9][0-9]{0,17})$">>) of
        {match, _} -> binary_to_integer(V);
        nomatch -> V
    end.

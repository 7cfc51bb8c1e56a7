%% Common Test suite of a large home against the limits on the way from
%% the MQTT Avatar to a pairing (docs/mqtt.md section 6, "Limits"): a real
%% mosquitto, a zigbee2mqtt device list published on it, real bridge
%% listeners and pairings of this node. A description over the listener's
%% max_frame or the bil application's max_description_size is a problem
%% naming the limit, reported once through the operator's view
%% (evatar_ops:problems/1, which GET /api/mqtt_avatars/:id/problems and
%% `bin/evatar mqtt_problems' call), and the Avatar's joins back off
%% instead of looping; with every limit raised as the docs say, a
%% description over the defaults (1 MiB) joins and binds.
-module(mqtt_avatar_limits_SUITE).

-include_lib("stdlib/include/assert.hrl").

-compile(nowarn_unused_import).

-define(LIVE_LISTENER, mqtt_avatar_limits_suite).
-define(LIVE_CASE_PREFIX, "lim_").
-define(LIVE_FEEDBACK_MS, 1500).
-include("mqtt_avatar_live_suite.hrl").

all() ->
    [over_max_frame, over_max_description_size, raised_limits_join].

%% ---------------------------------------------------------------------------
%% Cases
%% ---------------------------------------------------------------------------

%% A description over the listener's max_frame is not sent: the kept
%% Avatar's problems name max_frame once, and every join that ends so
%% doubles the delay before the next one (the old code reset it at each
%% connect and joined about four times a second).
over_max_frame(Config) ->
    Addr = evatar_test_node:listen(lim_small_frame, #{conn => #{max_frame => 16384}}),
    try
        Entity = kept_home(Config, Addr, 40),
        #{message := M} = wait_problem(Entity, description_too_large),
        ?assertNotEqual(nomatch, binary:match(M, <<"max_frame">>)),
        ?assertNotEqual(nomatch, binary:match(M, <<"max_description_size">>)),
        Status = wait_joins(Entity, 4),
        %% 200 ms doubled at each of the joins: not reset by a connect.
        ?assert(maps:get(retry, Status) >= 200 * 8),
        ?assertEqual(1, length(problems(Entity, description_too_large))),
        ?assertEqual([], avatars_registered(Config))
    after
        ok = mqtt_avatar:unkeep(entity(Config)),
        ok = agent_bridge:stop_listener(lim_small_frame)
    end.

%% A description within max_frame but over the bil application's
%% max_description_size is refused by the bridge as DescriptionRefused
%% naming max_description_size (the old bridge answered Malformed, "document
%% is N bytes, over the limit"); the pairing then drops the entity at its
%% join timeout, and the joins back off.
over_max_description_size(Config) ->
    Pairing = ?config(pairing, Config),
    ok = evatar:delete_pairing(Pairing),
    {ok, _} = evatar_test_fixtures:create_pairing(Pairing, #{join_timeout => evatar_test_time:ms(200)}),
    {ok, Old} = application:get_env(bil, max_description_size),
    ok = application:set_env(bil, max_description_size, 16384),
    try
        Entity = kept_home(Config, ?config(addr, Config), 40),
        #{code := <<"DescriptionRefused">>, message := M} = wait_problem(Entity, evatar_error),
        ?assertNotEqual(nomatch, binary:match(M, <<"(max_description_size">>)),
        ?assertNotEqual(nomatch, binary:match(M, <<"max_frame">>)),
        Status = wait_joins(Entity, 4),
        ?assert(maps:get(retry, Status) >= 200 * 8),
        ?assertEqual(1, length(problems(Entity, evatar_error)))
    after
        ok = application:set_env(bil, max_description_size, Old),
        ok = mqtt_avatar:unkeep(entity(Config))
    end.

%% A home whose description is over every default (1 MiB: max_frame,
%% max_description_size, max_binding_report; and max_consumes) joins and
%% binds once each is raised as docs/mqtt.md section 6 says, without a
%% problem.
raised_limits_join(Config) ->
    Pairing = ?config(pairing, Config),
    ok = evatar:delete_pairing(Pairing),
    {ok, _} = evatar_test_fixtures:create_pairing(Pairing, #{max_consumes => 65536,
                                                             max_binding_report => 67108864}),
    Big = 8 * 1048576,
    Addr = evatar_test_node:listen(lim_big_frame, #{conn => #{max_frame => Big}}),
    {ok, Old} = application:get_env(bil, max_description_size),
    ok = application:set_env(bil, max_description_size, Big),
    try
        Entity = kept_home(Config, Addr, 320),
        ok = evatar_test_wait:until(fun() -> [] =/= [E || #{description := #{}} = E
                                                                <- avatars_registered(Config)]
                                    end),
        [#{description := Public}] = avatars_registered(Config),
        Size = iolist_size(bil:encode_description(Public)),
        ct:log("description of ~b components: ~b bytes",
               [length(maps:get(components, Public)), Size]),
        ?assert(Size > 1048576),
        %% Bound: the back-off starts over.
        ok = evatar_test_wait:until(fun() -> maps:get(retry, status(Entity)) =:= 200 end),
        ?assertEqual([], [P || #{what := W} = P <- all_problems(Entity),
                               W =:= description_too_large orelse W =:= evatar_error
                                   orelse W =:= join_failed])
    after
        ok = application:set_env(bil, max_description_size, Old),
        ok = mqtt_avatar:unkeep(entity(Config)),
        ok = agent_bridge:stop_listener(lim_big_frame)
    end.

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

entity(Config) ->
    <<"home-", (?config(prefix, Config))/binary>>.

%% A zigbee2mqtt network of N sensors published (retained) on the suite's
%% broker, and a kept MQTT Avatar reading it and joining the case's pairing
%% at Addr. Returns its entity id.
kept_home(Config, Addr, N) ->
    Base = <<"z2m_", (?config(prefix, Config))/binary>>,
    {ok, Dev} = mqtt_avatar_test_device:start(?SETUP:broker_port(Config), #{}),
    remember(devices, Dev),
    ok = mqtt_avatar_test_device:publish(Dev, <<Base/binary, "/bridge/devices">>,
                                         evatar_json:encode(devices(N)),
                                         true),
    Entity = entity(Config),
    {ok, _} = mqtt_avatar:keep(#{entity_id => Entity, mqtt => ?SETUP:mqtt(Config),
                                 evatar => #{endpoints => [Addr],
                                             pairing => ?config(pairing, Config),
                                             credential => evatar_test_fixtures:avatar_credential()},
                                 discovery => #{homeassistant => false, zigbee2mqtt => Base},
                                 settle => 200, discovery_wait => 10000}),
    Entity.

devices(N) ->
    [#{<<"type">> => <<"Coordinator">>, <<"friendly_name">> => <<"Coordinator">>}
     | [device(I) || I <- lists:seq(1, N)]].

device(I) ->
    Num = fun(Name, Unit) ->
                  #{<<"type">> => <<"numeric">>, <<"name">> => Name, <<"property">> => Name,
                    <<"access">> => 1, <<"unit">> => Unit}
          end,
    #{<<"type">> => <<"EndDevice">>,
      <<"friendly_name">> => iolist_to_binary(io_lib:format("room_~b_sensor", [I])),
      <<"ieee_address">> => iolist_to_binary(io_lib:format("0x~16.16.0b", [I])),
      <<"definition">> =>
          #{<<"model">> => <<"WSDCGQ11LM">>, <<"vendor">> => <<"Aqara">>,
            <<"description">> => <<"Temperature, humidity and pressure sensor">>,
            <<"exposes">> =>
                [#{<<"type">> => <<"binary">>, <<"name">> => <<"occupancy">>,
                   <<"property">> => <<"occupancy">>, <<"access">> => 1,
                   <<"value_on">> => true, <<"value_off">> => false},
                 Num(<<"temperature">>, <<"C">>), Num(<<"humidity">>, <<"%">>),
                 Num(<<"pressure">>, <<"hPa">>), Num(<<"battery">>, <<"%">>),
                 Num(<<"voltage">>, <<"mV">>), Num(<<"linkquality">>, <<"lqi">>)]}}.

%% The kept Avatar's problems as the operator sees them.
all_problems(Entity) ->
    {ok, Ps} = evatar_ops:problems(Entity),
    Ps.

problems(Entity, What) ->
    [P || #{what := W} = P <- all_problems(Entity), W =:= What].

wait_problem(Entity, What) ->
    evatar_test_wait:value({problem, What}, fun() -> problems(Entity, What) end,
                           fun(Ps) -> Ps =/= [] end),
    hd(problems(Entity, What)).

status(Entity) ->
    [Pid] = [A || #{entity_id := E, avatar := A} <- mqtt_avatar:kept(), E =:= Entity,
                  is_pid(A)],
    mqtt_avatar:status(Pid).

wait_joins(Entity, N) ->
    evatar_test_wait:value({joins, N}, fun() -> status(Entity) end,
                           fun(#{joins := J}) -> J >= N end).

avatars_registered(Config) ->
    {ok, Registry} = evatar:registry(?config(pairing, Config)),
    [E || #{role := avatar} = E <- Registry].

%% @doc The smart home of docs/avatars.md section 4 with its devices on
%% MQTT: every device of smart_home.xml but the notifier (a PC) becomes a
%% simulated MQTT device (Home Assistant discovery, retained states, last
%% will; avatar_sim_mqtt_kind says how each looks), and an MQTT Avatar
%% (apps/mqtt_avatar) discovers them and joins EVATAR, so a VA whose body
%% is smart_home_va.xml works unchanged. The people, the clock, the script
%% and the devices' behaviour are avatar_sim's own home, reached through a
%% private EVATAR pairing (the devices' "hardware"). That pairing is the
%% caller's: a simulator does not drive the mediator, so the scenario's
%% set-up creates it and deletes it (evatar_demo_mqtt_home does both).
%% docs/mqtt.md section 7.
%%
%% ```
%%  VA --EVATAR pairing--> MQTT Avatar --mosquitto--> simulated MQTT devices
%%                                                      | hardware requests
%%  (Notifier01 joins the VA's pairing over TCP)        v
%%                    avatar_sim home <--private pairing-- this process
%% '''
%% Lifecycle:
%% ```
%%  starting --pairing, home, devices started--> waiting_devices
%%     --every device online (or 10 s)--> running  (MQTT Avatar started)
%% '''
-module(avatar_sim_mqtt_home).
-behaviour(gen_statem).

-include_lib("kernel/include/logger.hrl").

-export([start/1, stop/1, house/1, avatar/1, devices/1, power_off/2, power_on/2, info/1,
         overrides/1, hardware_pairing_id/1, entity_id/1]).
-export([hardware_request/5]).
-export([start_link/1, init/1, callback_mode/0, handle_event/4, terminate/3]).

-export_type([opts/0, home/0, hardware/0]).

-type home() :: pid().
-type hardware() :: #{pairing := binary(), agent_credential := binary(),
                      avatar_credential := binary()}.
%% `mqtt': the broker (`#{host, port}' and any other mqtt_client option),
%% assumed running. `endpoints': EVATAR's bridge on this node. `pairing' and
%% `credential': the VA's pairing, which the MQTT Avatar and the notifier
%% join. `hardware': the private pairing between the simulated house (its
%% Avatar credential) and the devices' firmware link (its agent
%% credential), made by the caller, running, and used by nothing else.
%% The options of avatar_sim:start_home/1 (`clock', `seed', `script',
%% `script_file', `people', `spool', `password', `location'...) go to the
%% simulated house.
-type opts() :: #{mqtt := map(),
                  endpoints := [agent_bridge_client:endpoint()],
                  pairing := binary(),
                  hardware := hardware(),
                  credential => binary(),
                  entity_id => binary(),
                  prefix => binary(),
                  discovery_prefix => binary(),
                  notifier => tcp | none,
                  avatar => boolean(),
                  avatar_opts => map(),
                  atom() => term()}.

%% The states of the machine (the diagram above).
-type state() :: starting | waiting_devices | running | failed.

-define(HOUSE_OPTS, [clock, seed, spool, password, email_to, email_from, script, script_file,
                     people, location, time_period, motion_repeat, motion_quiet, retry]).
-define(READY_TIMEOUT, 30000).
-define(DEVICES_TIMEOUT, 10000).

-record(d, {opts :: opts(),
            entity :: binary(),
            ctx :: avatar_sim_mqtt_kind:ctx(),
            hw_pairing :: binary(),
            hw_entity :: binary(),
            fw_entity :: binary(),
            house :: pid() | undefined,
            client :: pid() | undefined,
            bound = [] :: [bil:binding()],
            devices = #{} :: #{binary() => pid()},
            specs = [] :: [avatar_sim_mqtt_kind:device()],
            online = [] :: [binary()],
            avatar :: pid() | undefined,
            requests = #{} :: #{binary() => {pid(), reference()}},
            counter = 0 :: non_neg_integer(),
            waiters = [] :: [gen_statem:from()],
            failure :: term()}).

%% ---------------------------------------------------------------------------
%% API
%% ---------------------------------------------------------------------------

%% @doc Starts the MQTT home and returns once its MQTT Avatar has joined
%% EVATAR (or, with `avatar => false', once every device is online). For
%% `make demo' (evatar_demo_mqtt_home:start/1 makes `hardware'):
%% `avatar_sim_mqtt_home:start(#{mqtt => #{host => "127.0.0.1",
%% port => 1883}, endpoints => [{{127,0,0,1}, 7400}], pairing => <<"home">>,
%% credential => <<"...">>, hardware => #{pairing => <<"home-hw">>,
%% agent_credential => <<"...">>, avatar_credential => <<"...">>}, clock =>
%% Clock, script => Script})'.
-spec start(opts()) -> {ok, home()} | {error, term()}.
start(#{mqtt := #{host := _, port := _}, endpoints := [_ | _], pairing := P,
        hardware := #{pairing := HP, agent_credential := AC, avatar_credential := VC}} = Opts)
  when is_binary(P), is_binary(HP), is_binary(AC), is_binary(VC) ->
    {ok, _} = application:ensure_all_started(avatar_sim),
    {ok, _} = application:ensure_all_started(mqtt_avatar),
    {ok, Pid} = avatar_sim_sup:start_child(#{start => {?MODULE, start_link, [Opts]}}),
    case gen_statem:call(Pid, await_ready, ?READY_TIMEOUT + ?DEVICES_TIMEOUT) of
        ok -> {ok, Pid};
        {error, _} = Error -> stop(Pid), Error
    end;
start(_Opts) ->
    {error, <<"mqtt => #{host, port}, endpoints => [Endpoint], pairing => Binary and "
              "hardware => #{pairing, agent_credential, avatar_credential} are required">>}.

%% @doc The id of the private hardware pairing a home of entity `EntityId'
%% uses by convention (the set-up that creates it may choose another).
-spec hardware_pairing_id(binary()) -> binary().
hardware_pairing_id(EntityId) -> <<"mqtt-hardware-", EntityId/binary>>.

%% @doc The entity id of a home started with `Opts' (`easy-home-mqtt').
-spec entity_id(map()) -> binary().
entity_id(Opts) -> maps:get(entity_id, Opts, <<"easy-home-mqtt">>).

%% @doc Stops the MQTT Avatar, the devices (each says offline) and the house.
-spec stop(home()) -> ok.
stop(Home) ->
    Ref = monitor(process, Home),
    gen_statem:stop(Home),
    receive {'DOWN', Ref, process, Home, _} -> ok end.

%% @doc The simulated house: use avatar_sim's functions on it (`state/1',
%% `act/3', `log/1', `mute/2'...).
-spec house(home()) -> avatar_sim:avatar().
house(Home) -> gen_statem:call(Home, house).

%% @doc The MQTT Avatar (mqtt_avatar's functions: `description/1',
%% `print_description/1', `problems/1', `status/1').
-spec avatar(home()) -> pid() | undefined.
avatar(Home) -> gen_statem:call(Home, avatar).

%% @doc Every device: component, kind, state, topics.
-spec devices(home()) -> [map()].
devices(Home) ->
    [avatar_sim_mqtt_device:info(Pid) || {_, Pid} <- gen_statem:call(Home, devices)].

%% @doc Cuts a device's power: its MQTT session dies without DISCONNECT, so
%% the broker publishes its last will (offline).
-spec power_off(home(), binary()) -> ok | {error, unknown_component}.
power_off(Home, Component) -> power(Home, Component, off).

%% @doc Powers a device on again: it reconnects and says online.
-spec power_on(home(), binary()) -> ok | {error, unknown_component}.
power_on(Home, Component) -> power(Home, Component, on).

power(Home, Component, OnOff) ->
    case lists:keyfind(Component, 1, gen_statem:call(Home, devices)) of
        {_, Pid} -> avatar_sim_mqtt_device:power(Pid, OnOff);
        false -> {error, unknown_component}
    end.

%% @doc Pairings, entities and counters, for the demo and tests.
-spec info(home()) -> map().
info(Home) -> gen_statem:call(Home, info).

%% @doc The overrides the home gives its MQTT Avatar (docs/mqtt.md section
%% 7): what Home Assistant discovery cannot say about these devices.
%% `Opts': `prefix', `discovery_prefix'.
-spec overrides(map()) -> mqtt_avatar_generate:overrides().
overrides(Opts) ->
    Ctx = ctx(Opts),
    avatar_sim_mqtt_kind:overrides(device_specs(Ctx), Ctx).

%% @doc Internal (avatar_sim_mqtt_device): a command for the simulated
%% hardware; answers come back with the tag.
-spec hardware_request(home(), binary(), binary(), [bil:parameter()], {pid(), reference()}) -> ok.
hardware_request(Home, Component, Type, Params, Tag) ->
    gen_statem:cast(Home, {hardware_request, Component, Type, Params, Tag}).

%% ---------------------------------------------------------------------------
%% gen_statem
%% ---------------------------------------------------------------------------

-spec start_link(opts()) -> {ok, pid()}.
start_link(Opts) ->
    gen_statem:start_link(?MODULE, Opts, []).

-spec callback_mode() -> gen_statem:callback_mode_result().
callback_mode() -> handle_event_function.

-spec init(opts()) -> gen_statem:init_result(starting).
init(Opts) ->
    process_flag(trap_exit, true),
    Entity = entity_id(Opts),
    logger:update_process_metadata(#{domain => [avatar_sim, mqtt_home], entity => Entity}),
    #{hardware := #{pairing := HwPairing}} = Opts,
    D = #d{opts = Opts, entity = Entity, ctx = ctx(Opts),
           hw_pairing = HwPairing,
           hw_entity = <<Entity/binary, "-hardware">>,
           fw_entity = <<Entity/binary, "-firmware">>},
    {ok, starting, D, [{next_event, internal, setup}]}.

-spec handle_event(gen_statem:event_type(), term(), state(), #d{}) ->
          gen_statem:event_handler_result(state()).
handle_event(internal, setup, starting, D) ->
    case setup(D) of
        {ok, D1} ->
            {next_state, waiting_devices, D1, [{state_timeout, ?DEVICES_TIMEOUT, devices}]};
        {error, Why, D1} ->
            ?LOG_ERROR(#{what => mqtt_home_failed, reason => Why}),
            {next_state, failed, reply_waiters({error, Why}, D1#d{failure = Why})}
    end;
handle_event(info, {device_online, Id}, waiting_devices, D) ->
    Online = lists:usort([Id | D#d.online]),
    case length(Online) =:= map_size(D#d.devices) of
        true -> start_avatar(D#d{online = Online});
        false -> {keep_state, D#d{online = Online}}
    end;
handle_event(info, {device_online, Id}, _State, D) ->
    {keep_state, D#d{online = lists:usort([Id | D#d.online])}};
handle_event(state_timeout, devices, waiting_devices, D) ->
    ?LOG_WARNING(#{what => devices_slow, online => D#d.online,
                   message => <<"not every device is online yet; starting the MQTT Avatar">>}),
    start_avatar(D);

%% The hardware link (private pairing, role agent).
handle_event(info, {agent_bridge, C, {binding, #{bound := Bound}}}, _State, #d{client = C} = D) ->
    {keep_state, D#d{bound = Bound}};
handle_event(info, {agent_bridge, C, {signal, Signal}}, _State, #d{client = C} = D) ->
    {keep_state, from_hardware(Signal, D)};
handle_event(info, {agent_bridge, C, {closed, Reason}}, _State, #d{client = C} = D) ->
    ?LOG_WARNING(#{what => hardware_link_closed, reason => Reason}),
    {keep_state, D#d{client = undefined}, [{{timeout, relink}, 500, relink}]};
handle_event({timeout, relink}, relink, _State, D) ->
    case hardware_link(D) of
        {ok, D1} -> {keep_state, D1};
        {error, _} -> {keep_state_and_data, [{{timeout, relink}, 1000, relink}]}
    end;
handle_event(cast, {hardware_request, Comp, Type, Params, Tag}, _State, D) ->
    {keep_state, to_hardware(Comp, Type, Params, Tag, D)};

%% Inspection.
handle_event({call, From}, await_ready, running, _D) ->
    {keep_state_and_data, [{reply, From, ok}]};
handle_event({call, From}, await_ready, failed, D) ->
    {keep_state_and_data, [{reply, From, {error, D#d.failure}}]};
handle_event({call, From}, await_ready, _State, D) ->
    {keep_state, D#d{waiters = [From | D#d.waiters]}};
handle_event({call, From}, house, _State, D) ->
    {keep_state_and_data, [{reply, From, D#d.house}]};
handle_event({call, From}, avatar, _State, D) ->
    {keep_state_and_data, [{reply, From, D#d.avatar}]};
handle_event({call, From}, devices, _State, D) ->
    {keep_state_and_data, [{reply, From, lists:sort(maps:to_list(D#d.devices))}]};
handle_event({call, From}, info, State, D) ->
    Info = #{state => State, entity => D#d.entity, pairing => maps:get(pairing, D#d.opts),
             hardware_pairing => D#d.hw_pairing, devices => lists:sort(maps:keys(D#d.devices)),
             online => D#d.online, pending => map_size(D#d.requests), avatar => D#d.avatar,
             house => D#d.house},
    {keep_state_and_data, [{reply, From, Info}]};
handle_event(info, {'EXIT', Pid, Why}, _State, D) ->
    case lists:keyfind(Pid, 2, maps:to_list(D#d.devices)) of
        {Id, _} -> {stop, {device_down, Id, Why}};
        false when Pid =:= D#d.avatar -> {stop, {mqtt_avatar_down, Why}};
        false -> keep_state_and_data
    end;
handle_event(info, _Other, _State, _D) ->
    keep_state_and_data.

-spec terminate(term(), state(), #d{}) -> ok.
terminate(_Why, _State, D) ->
    _ = [catch mqtt_avatar:stop(A) || A <- [D#d.avatar], A =/= undefined],
    _ = [catch gen_statem:stop(P) || P <- maps:values(D#d.devices)],
    _ = [catch agent_bridge_client:close(C) || C <- [D#d.client], C =/= undefined],
    _ = [catch avatar_sim:stop(H) || H <- [D#d.house], H =/= undefined],
    ok.

%% ---------------------------------------------------------------------------
%% Setup
%% ---------------------------------------------------------------------------

setup(#d{opts = Opts, ctx = Ctx} = D) ->
    #{hardware := #{agent_credential := AgentCred, avatar_credential := AvatarCred}} = Opts,
    Specs = device_specs(Ctx),
    Devices = maps:from_list([{Id, start_device(Spec, D)} || #{id := Id} = Spec <- Specs]),
    D1 = D#d{specs = Specs, devices = Devices, opts = Opts#{hw_agent_credential => AgentCred}},
    case start_house(AvatarCred, Specs, D1) of
        {ok, House} ->
            case hardware_link(D1#d{house = House}) of
                {ok, D2} -> {ok, D2};
                {error, Why} -> {error, {hardware_link, Why}, D1#d{house = House}}
            end;
        {error, Why} ->
            {error, {house, Why}, D1}
    end.

start_device(Spec, #d{ctx = Ctx, opts = Opts}) ->
    Home = self(),
    {ok, Pid} = avatar_sim_mqtt_device:start_link(Home, Spec, Ctx, maps:get(mqtt, Opts)),
    Pid.

start_house(AvatarCred, Specs, #d{opts = Opts} = D) ->
    Endpoints = maps:get(endpoints, Opts),
    Hardware = #{pairing => D#d.hw_pairing, credential => AvatarCred, entity_id => D#d.hw_entity,
                 components => [Id || #{id := Id} <- Specs]},
    Notifier = case maps:get(notifier, Opts, tcp) of
                   tcp -> [#{pairing => maps:get(pairing, Opts),
                             credential => maps:get(credential, Opts, <<>>),
                             entity_id => <<(D#d.entity)/binary, "-notifier">>,
                             components => [<<"Notifier01">>]}];
                   none -> []
               end,
    avatar_sim:start_home((maps:with(?HOUSE_OPTS, Opts))#{endpoints => Endpoints,
                                                         gateways => [Hardware | Notifier]}).

%% The firmware side of the private pairing: the VA body of the home, so
%% each device's emulator there sends its requests.
hardware_link(#d{opts = Opts} = D) ->
    {ok, Xml} = file:read_file(filename:join([code:priv_dir(bil), "examples", "smart_home_va.xml"])),
    {ok, Body} = bil:parse_description(Xml),
    case agent_bridge_client:connect(maps:get(endpoints, Opts),
                                     #{pairing => D#d.hw_pairing, role => agent,
                                       entity_id => D#d.fw_entity,
                                       credential => maps:get(hw_agent_credential, Opts),
                                       owner => self()}) of
        {ok, C} ->
            ok = agent_bridge_client:describe(C, Body#{entity_id := D#d.fw_entity}),
            {ok, D#d{client = C}};
        {error, _} = Error ->
            Error
    end.

start_avatar(#d{opts = Opts, ctx = Ctx} = D) ->
    case maps:get(avatar, Opts, true) of
        false ->
            {next_state, running, reply_waiters(ok, D)};
        true ->
            AvatarOpts = maps:merge(
                           #{entity_id => D#d.entity,
                             mqtt => maps:get(mqtt, Opts),
                             evatar => #{endpoints => maps:get(endpoints, Opts),
                                         pairing => maps:get(pairing, Opts),
                                         credential => maps:get(credential, Opts, <<>>)},
                             discovery => #{homeassistant => maps:get(discovery_prefix, Ctx),
                                            zigbee2mqtt => false},
                             overrides => avatar_sim_mqtt_kind:overrides(D#d.specs, Ctx),
                             timestamp_field => <<"ts">>,
                             settle => 300},
                           maps:get(avatar_opts, Opts, #{})),
            case mqtt_avatar:start_link(AvatarOpts) of
                {ok, A} ->
                    case mqtt_avatar:await_ready(A, ?READY_TIMEOUT) of
                        ok -> {next_state, running, reply_waiters(ok, D#d{avatar = A})};
                        {error, Why} -> fail({mqtt_avatar, Why}, D#d{avatar = A})
                    end;
                {error, Why} ->
                    fail({mqtt_avatar, Why}, D)
            end
    end.

fail(Why, D) ->
    {next_state, failed, reply_waiters({error, Why}, D#d{failure = Why})}.

reply_waiters(Reply, #d{waiters = W} = D) ->
    _ = [gen_statem:reply(From, Reply) || From <- W],
    D#d{waiters = []}.

ctx(Opts) ->
    #{prefix => maps:get(prefix, Opts, <<"evatar-sim">>),
      discovery_prefix => maps:get(discovery_prefix, Opts, <<"homeassistant">>)}.

device_specs(Ctx) ->
    {ok, Xml} = file:read_file(filename:join([code:priv_dir(bil), "examples", "smart_home.xml"])),
    {ok, #{components := Components}} = bil:parse_description(Xml),
    [avatar_sim_mqtt_kind:device(C, K, Ctx)
     || C <- Components, K <- [avatar_sim_mqtt_kind:kind(C)], K =/= none].

%% ---------------------------------------------------------------------------
%% Routing between the devices and the simulated hardware
%% ---------------------------------------------------------------------------

to_hardware(Comp, Type, Params, {Device, Tag}, #d{client = C} = D) ->
    Route = [{E, Cat} || #{consumer := #{entity := FE, component := E},
                           provider := #{entity := HE, component := P},
                           category := Cat, type := T} <- D#d.bound,
                         FE =:= D#d.fw_entity, HE =:= D#d.hw_entity, P =:= Comp,
                         bil:keyword(T) =:= bil:keyword(Type)],
    case {C, Route} of
        {undefined, _} ->
            ?LOG_NOTICE(#{what => hardware_unreachable, component => Comp, service => Type}),
            D;
        {_, []} ->
            ?LOG_NOTICE(#{what => hardware_not_bound, component => Comp, service => Type}),
            D;
        {_, [{Emulator, Cat} | _]} ->
            N = D#d.counter + 1,
            Id = <<(D#d.fw_entity)/binary, "-", (integer_to_binary(N))/binary>>,
            _ = agent_bridge_client:send(C, #{id => Id, context => request, sender => Emulator,
                                              receiver => Comp,
                                              body => #{category => Cat, type => Type,
                                                        parameters => Params}}),
            D#d{counter = N, requests = maps:put(Id, {Device, Tag}, D#d.requests)}
    end.

from_hardware(#{context := Ctx, in_reply_to := Id, timestamp := Ts,
                body := #{parameters := Ps}}, D)
  when Ctx =:= feedback; Ctx =:= progress; Ctx =:= error ->
    case maps:find(Id, D#d.requests) of
        {ok, {Device, Tag}} ->
            ok = avatar_sim_mqtt_device:hardware_answer(Device, Tag, Ctx, Ps, Ts),
            case Ctx of
                progress -> D;
                _ -> D#d{requests = maps:remove(Id, D#d.requests)}
            end;
        error ->
            D
    end;
from_hardware(#{context := Ctx, sender := Comp, timestamp := Ts,
                body := #{type := Type, parameters := Ps}}, D)
  when Ctx =:= sensor_data; Ctx =:= event ->
    case maps:find(Comp, D#d.devices) of
        {ok, Device} -> ok = avatar_sim_mqtt_device:hardware_push(Device, Type, Ps, Ts);
        error -> ok
    end,
    D;
from_hardware(_Signal, D) ->
    D.

%% @doc Internal. One simulated MQTT device of the MQTT home: its own MQTT
%% session with a last will on its availability topic, retained discovery
%% configs, commands turned into requests to the simulated hardware (through
%% avatar_sim_mqtt_home), and the hardware's answers and readings published
%% as state messages (avatar_sim_mqtt_kind says how). Power can be cut: the
%% session dies without DISCONNECT, so the broker publishes the will.
%%
%% ```
%%  connecting --connected: discovery, initial states, online--> online
%%      ^                                                          |
%%      +---------------- power_on <-- off <-- power_off ----------+
%% '''
%% While `online' the MQTT client reconnects by itself and the device says
%% `online' again after each reconnection, as Tasmota and zigbee2mqtt do.
-module(avatar_sim_mqtt_device).
-behaviour(gen_statem).

-include_lib("kernel/include/logger.hrl").

-export([start_link/4, power/2, hardware_answer/5, hardware_push/4, info/1]).
-export([init/1, callback_mode/0, handle_event/4, terminate/3]).

%% The states of the machine (the diagram above).
-type state() :: connecting | online | off.

-record(d, {home :: pid(),
            device :: avatar_sim_mqtt_kind:device(),
            ctx :: avatar_sim_mqtt_kind:ctx(),
            mqtt :: map(),
            client :: pid() | undefined,
            announced = false :: boolean(),
            %% The current client has subscribed to the command topics (it
            %% subscribes again by itself after its own reconnections).
            subscribed = false :: boolean(),
            tags = #{} :: #{reference() => binary()},
            published = 0 :: non_neg_integer(),
            refused = 0 :: non_neg_integer()}).

%% ---------------------------------------------------------------------------
%% API
%% ---------------------------------------------------------------------------

-spec start_link(pid(), avatar_sim_mqtt_kind:device(), avatar_sim_mqtt_kind:ctx(), map()) ->
          {ok, pid()}.
start_link(Home, Device, Ctx, Mqtt) ->
    gen_statem:start_link(?MODULE, {Home, Device, Ctx, Mqtt}, []).

%% @doc `off' cuts the MQTT session abruptly (the broker publishes the
%% will); `on' connects again.
-spec power(pid(), on | off) -> ok.
power(Device, OnOff) -> gen_statem:call(Device, {power, OnOff}, 10000).

%% @doc The simulated hardware answered the request tagged `Tag'.
-spec hardware_answer(pid(), reference(), progress | feedback | error, [bil:parameter()],
                      integer()) -> ok.
hardware_answer(Device, Tag, Context, Params, Ts) ->
    gen_statem:cast(Device, {answer, Tag, Context, Params, Ts}).

%% @doc The simulated hardware pushed a reading or an event.
-spec hardware_push(pid(), binary(), [bil:parameter()], integer()) -> ok.
hardware_push(Device, Type, Params, Ts) ->
    gen_statem:cast(Device, {push, Type, Params, Ts}).

-spec info(pid()) -> map().
info(Device) -> gen_statem:call(Device, info, 10000).

%% ---------------------------------------------------------------------------
%% gen_statem
%% ---------------------------------------------------------------------------

-spec callback_mode() -> gen_statem:callback_mode_result().
callback_mode() -> handle_event_function.

-spec init({pid(), avatar_sim_mqtt_kind:device(), avatar_sim_mqtt_kind:ctx(), map()}) ->
          gen_statem:init_result(connecting).
init({Home, #{id := Id} = Device, Ctx, Mqtt}) ->
    logger:update_process_metadata(#{domain => [avatar_sim, mqtt_device], component => Id}),
    {ok, connecting, #d{home = Home, device = Device, ctx = Ctx, mqtt = Mqtt},
     [{next_event, internal, connect}]}.

-spec handle_event(gen_statem:event_type(), term(), state(), #d{}) ->
          gen_statem:event_handler_result(state()).
handle_event(internal, connect, connecting, #d{device = Dev, mqtt = Mqtt} = D) ->
    #{id := Id, availability := #{topic := A, offline := Off}} = Dev,
    Opts = Mqtt#{owner => self(),
                 client_id => iolist_to_binary(["evatar-sim-", avatar_sim_mqtt_kind:node_name(Id), "-",
                                                binary:encode_hex(crypto:strong_rand_bytes(3))]),
                 will => #{topic => A, payload => Off, qos => 1, retain => true},
                 reconnect => maps:get(reconnect, Mqtt, #{min_ms => 100, max_ms => 2000})},
    {ok, C} = mqtt_client:start(Opts),
    monitor(process, C),
    {keep_state, D#d{client = C}};
handle_event(info, {mqtt_client, C, {connected, _}}, State, #d{client = C, device = Dev} = D)
  when State =:= connecting; State =:= online ->
    #{availability := #{topic := A, online := On}, commands := Commands} = Dev,
    D0 = case D#d.announced of
             false ->
                 %% The first time: who I am, and the states I start in.
                 _ = [publish(D, T, evatar_json:encode(J), true)
                      || {T, J} <- maps:get(discovery, Dev)],
                 _ = [publish(D, T, P, R) || {T, P, R} <- maps:get(initial, Dev)],
                 D#d{announced = true};
             true ->
                 D
         end,
    D1 = case D0#d.subscribed of
             false ->
                 _ = [{ok, _} = mqtt_client:subscribe(C, [{T, 1}]) || T <- Commands],
                 D0#d{subscribed = true};
             true ->
                 D0
         end,
    publish(D1, A, On, true),
    D1#d.home ! {device_online, maps:get(id, Dev)},
    {next_state, online, D1};
handle_event(info, {mqtt_client, C, {publish, #{topic := T, payload := P}}}, online,
             #d{client = C, device = #{id := Id, kind := Kind}} = D) ->
    case avatar_sim_mqtt_kind:command(Kind, T, P, D#d.ctx) of
        {request, Type, Params} ->
            Tag = make_ref(),
            ok = avatar_sim_mqtt_home:hardware_request(D#d.home, Id, Type, Params, {self(), Tag}),
            {keep_state, D#d{tags = maps:put(Tag, Type, D#d.tags)}};
        {error, Why} ->
            ?LOG_NOTICE(#{what => command_refused, component => Id, topic => T, reason => Why}),
            {keep_state, D#d{refused = D#d.refused + 1}}
    end;
handle_event(info, {mqtt_client, _, _}, _State, _D) ->
    keep_state_and_data;
handle_event(cast, {answer, Tag, Context, Params, Ts}, State, #d{device = Dev} = D)
  when State =/= off ->
    case maps:find(Tag, D#d.tags) of
        {ok, Type} ->
            Ctx = (avatar_sim_mqtt_kind:topics(maps:get(id, Dev), D#d.ctx))#{ts => Ts},
            Out = avatar_sim_mqtt_kind:answer(maps:get(kind, Dev), Type, Context, Params, Ctx),
            _ = [publish(D, T, P, R) || {T, P, R} <- Out],
            Tags = case Context of
                       progress -> D#d.tags;
                       _ -> maps:remove(Tag, D#d.tags)
                   end,
            {keep_state, D#d{tags = Tags, published = D#d.published + length(Out)}};
        error ->
            keep_state_and_data
    end;
handle_event(cast, {push, Type, Params, Ts}, State, #d{device = Dev} = D) when State =/= off ->
    %% (While connecting, QoS 1 publishes wait in the client's queue.)
    Ctx = (avatar_sim_mqtt_kind:topics(maps:get(id, Dev), D#d.ctx))#{ts => Ts},
    Out = avatar_sim_mqtt_kind:push(maps:get(kind, Dev), Type, Params, Ctx),
    _ = [publish(D, T, P, R) || {T, P, R} <- Out],
    {keep_state, D#d{published = D#d.published + length(Out)}};
handle_event(cast, _Other, _State, _D) ->
    %% Powered off: the hardware's answers and readings go nowhere.
    keep_state_and_data;
handle_event({call, From}, {power, off}, State, #d{client = C} = D) when State =/= off ->
    Mon = monitor(process, C),
    exit(C, kill),
    receive {'DOWN', Mon, process, C, _} -> ok end,
    {next_state, off, D#d{client = undefined, subscribed = false, tags = #{}}, [{reply, From, ok}]};
handle_event({call, From}, {power, on}, off, D) ->
    {next_state, connecting, D, [{reply, From, ok}, {next_event, internal, connect}]};
handle_event({call, From}, {power, _}, _State, _D) ->
    {keep_state_and_data, [{reply, From, ok}]};
handle_event({call, From}, info, State, #d{device = Dev} = D) ->
    Info = #{component => maps:get(id, Dev), kind => maps:get(kind, Dev), state => State,
             availability => maps:get(availability, Dev), commands => maps:get(commands, Dev),
             discovery => [T || {T, _} <- maps:get(discovery, Dev)],
             published => D#d.published, refused => D#d.refused},
    {keep_state_and_data, [{reply, From, Info}]};
handle_event(info, {'DOWN', _, process, C, Why}, _State, #d{client = C} = D) ->
    %% The client gave up (it only does so on a fatal CONNACK).
    ?LOG_WARNING(#{what => mqtt_client_down, component => maps:get(id, D#d.device), reason => Why}),
    {next_state, off, D#d{client = undefined, subscribed = false}};
handle_event(info, _Other, _State, _D) ->
    keep_state_and_data.

-spec terminate(term(), state(), #d{}) -> ok.
terminate(_Why, _State, #d{client = undefined}) -> ok;
terminate(_Why, _State, #d{client = C, device = Dev} = D) ->
    %% A clean stop sends DISCONNECT, so the broker drops the will: say
    %% offline first, as a device switched off properly does.
    #{availability := #{topic := A, offline := Off}} = Dev,
    publish(D, A, Off, true),
    _ = mqtt_client:stop(C),
    ok.

%% ---------------------------------------------------------------------------
%% Internals
%% ---------------------------------------------------------------------------

publish(#d{client = C}, Topic, Payload, Retain) ->
    ok = mqtt_client:publish_async(C, Topic, Payload, #{qos => 1, retain => Retain}).

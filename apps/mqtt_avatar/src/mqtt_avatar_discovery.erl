%% @doc Internal. Collects discovery messages (Home Assistant configs and
%% zigbee2mqtt's device list) into one list of devices, each a set of
%% entities, for mqtt_avatar_generate. Pure: the state is a value; bad
%% messages give problems and leave the state as it was.
-module(mqtt_avatar_discovery).

-export([new/1, subscriptions/1, handle/3, devices/1, is_empty/1]).

-export([max_device_list_limit/0]).

-export_type([state/0, opts/0, device/0, device_info/0, entity/0, kind/0, problem/0]).

%% Largest discovery config read, in bytes (option max_config_size); the
%% zigbee2mqtt device list has its own limit (max_device_list_size).
-define(MAX_CONFIG, 65536).
%% zigbee2mqtt's bridge/devices, one message for the whole network: about
%% 5 KB a device, so 4 MiB holds some 800 (docs/mqtt.md section 2.2); the
%% option may raise it to 64 MiB.
-define(MAX_DEVICE_LIST, 4194304).
-define(MAX_DEVICE_LIST_LIMIT, 67108864).
%% Topics whose last problems are remembered (so not reported again).
-define(MAX_REPORTED, 4096).

-type opts() :: #{homeassistant => binary() | false, zigbee2mqtt => binary() | false,
                  max_config_size => pos_integer(), max_device_list_size => pos_integer()}.
%% An entity: the keys every family has, and its family's own
%% (mqtt_avatar_family_*: `on'/`off' for on/off actuators, `press' for
%% buttons...).
-type kind() :: light | switch | binary_sensor | sensor | button | text | event | siren | notify
              | cover | valve | climate | fan | humidifier | lock | number | select
              | alarm_control_panel | scene | vacuum.
-type entity() :: #{uid := binary(),
                    kind := kind(),
                    name := binary() | undefined,
                    device_class := binary() | undefined,
                    state_topic := binary() | undefined,
                    command_topic := binary() | undefined,
                    value := mqtt_avatar_spec:source(),
                    attributes := boolean(),
                    on_change := boolean(),
                    unit := binary() | undefined,
                    atom() => term()}.
-type device_info() :: #{key := binary(),
                         name := binary() | undefined,
                         room := binary() | undefined,
                         model := binary() | undefined,
                         availability := mqtt_avatar_spec:availability() | undefined}.
-type device() :: #{key := binary(),
                    name := binary() | undefined,
                    room := binary() | undefined,
                    model := binary() | undefined,
                    availability := mqtt_avatar_spec:availability() | undefined,
                    entities := [entity()]}.
-type problem() :: #{what := bad_discovery, topic := binary(), message := binary()}.
-opaque state() :: #{ha_prefix := binary() | false,
                     z2m_base := binary() | false,
                     max_config := pos_integer(),
                     max_device_list := pos_integer(),
                     %% the problems last reported per topic, not reported again
                     reported := #{binary() => [binary()]},
                     %% by config topic; a device-based config's
                     %% components by {topic, component key}
                     ha := #{binary() | {binary(), binary()} => {device_info(), entity()}},
                     z2m := [device()]}.

%% @doc Discovery on the given prefixes (defaults: `homeassistant' and
%% `zigbee2mqtt'; `false' turns one off).
-spec new(opts()) -> state().
new(Opts) ->
    #{ha_prefix => maps:get(homeassistant, Opts, <<"homeassistant">>),
      z2m_base => maps:get(zigbee2mqtt, Opts, <<"zigbee2mqtt">>),
      max_config => maps:get(max_config_size, Opts, ?MAX_CONFIG),
      max_device_list => case maps:get(max_device_list_size, Opts, ?MAX_DEVICE_LIST) of
                             N when is_integer(N), N >= 1, N =< ?MAX_DEVICE_LIST_LIMIT -> N;
                             _ -> ?MAX_DEVICE_LIST
                         end,
      reported => #{},
      ha => #{}, z2m => []}.

%% @doc The default and the largest value of `max_device_list_size'.
-spec max_device_list_limit() -> {Default :: pos_integer(), Limit :: pos_integer()}.
max_device_list_limit() -> {?MAX_DEVICE_LIST, ?MAX_DEVICE_LIST_LIMIT}.

%% @doc The topic filters to subscribe to.
-spec subscriptions(state()) -> [binary()].
subscriptions(#{ha_prefix := Ha, z2m_base := Z}) ->
    [<<P/binary, F/binary>> || P <- [Ha], P =/= false, F <- [<<"/+/+/config">>, <<"/+/+/+/config">>]]
        ++ [<<B/binary, "/bridge/devices">> || B <- [Z], B =/= false].

%% @doc True when nothing has been discovered.
-spec is_empty(state()) -> boolean().
is_empty(#{ha := Ha, z2m := Z}) -> map_size(Ha) =:= 0 andalso Z =:= [].

%% @doc One message. `ignore' when the topic is not a discovery topic. A
%% problem is given when it appears on its topic, not again while the
%% topic keeps sending the same mistake (a device re-announcing itself).
-spec handle(binary(), binary(), state()) ->
          ignore | {changed | unchanged, state(), [problem()]}.
handle(Topic, Payload, S) ->
    case handle_one(Topic, Payload, S) of
        ignore ->
            ignore;
        {Changed, #{reported := Reported} = S1, Problems} ->
            Before = maps:get(Topic, Reported, []),
            Messages = [M || #{message := M} <- Problems],
            Reported1 = if
                            Messages =:= [] -> maps:remove(Topic, Reported);
                            map_size(Reported) >= ?MAX_REPORTED -> Reported;
                            true -> Reported#{Topic => Messages}
                        end,
            {Changed, S1#{reported := Reported1},
             [P || #{message := M} = P <- Problems, not lists:member(M, Before)]}
    end.

handle_one(Topic, Payload, #{z2m_base := Z, max_device_list := Max} = S)
  when Z =/= false, Topic =:= <<Z/binary, "/bridge/devices">>, byte_size(Payload) > Max ->
    {unchanged, S, [problem(Topic, iolist_to_binary(
                                     ["the device list is ", integer_to_list(byte_size(Payload)),
                                      " bytes, over max_device_list_size (", integer_to_list(Max),
                                      " bytes); ignored, the last list read stays (raise the "
                                      "discovery option max_device_list_size, docs/mqtt.md section 6)"]))]};
handle_one(Topic, Payload, #{z2m_base := Z, max_device_list := Max} = S)
  when Z =/= false, Topic =:= <<Z/binary, "/bridge/devices">> ->
    case mqtt_avatar_z2m:parse(Z, Payload, #{max_size => Max}) of
        {ok, Devices, Messages} ->
            Problems = [problem(Topic, M) || M <- Messages],
            case Devices =:= maps:get(z2m, S) of
                true -> {unchanged, S, Problems};
                false -> {changed, S#{z2m := Devices}, Problems}
            end;
        {error, M} ->
            {unchanged, S, [problem(Topic, M)]}
    end;
handle_one(Topic, Payload, #{max_config := Max} = S) when byte_size(Payload) > Max ->
    case is_ha_config(Topic, S) of
        true ->
            {unchanged, S, [problem(Topic, iolist_to_binary(
                                             ["the config is ", integer_to_list(byte_size(Payload)),
                                              " bytes, over max_config_size (",
                                              integer_to_list(Max), " bytes); skipped"]))]};
        false ->
            ignore
    end;
handle_one(Topic, Payload, #{ha_prefix := Prefix, ha := Ha, max_config := Max} = S)
  when Prefix =/= false ->
    case mqtt_avatar_ha:parse(Prefix, Topic, Payload, #{max_size => Max}) of
        ignore ->
            ignore;
        {ok, remove} ->
            Gone = [K || K <- maps:keys(Ha), K =:= Topic orelse of_device(K, Topic)],
            case Gone of
                [] -> {unchanged, S, []};
                _ -> {changed, S#{ha := maps:without(Gone, Ha)}, []}
            end;
        {ok, {entities, Entities, Messages}} ->
            Problems = [problem(Topic, M) || M <- Messages],
            Old = maps:filter(fun(K, _) -> of_device(K, Topic) end, Ha),
            New = maps:from_list([{{Topic, Key}, {Info, E}} || {Key, Info, E} <- Entities]),
            case Old =:= New of
                true -> {unchanged, S, Problems};
                false -> {changed, S#{ha := maps:merge(maps:without(maps:keys(Old), Ha), New)},
                          Problems}
            end;
        {ok, {entity, Info, Entity}} ->
            case maps:get(Topic, Ha, undefined) of
                {Info, Entity} -> {unchanged, S, []};
                _ -> {changed, S#{ha := Ha#{Topic => {Info, Entity}}}, []}
            end;
        {error, M} ->
            {unchanged, S, [problem(Topic, M)]}
    end;
handle_one(_Topic, _Payload, _S) ->
    ignore.

%% Whether a topic is a Home Assistant discovery config's (an empty payload
%% is read without looking at anything else).
is_ha_config(_Topic, #{ha_prefix := false}) -> false;
is_ha_config(Topic, #{ha_prefix := Prefix}) -> mqtt_avatar_ha:parse(Prefix, Topic, <<>>) =/= ignore.

%% @doc Every device discovered, Home Assistant devices first, each sorted
%% by key; a device's entities in topic order.
-spec devices(state()) -> [device()].
devices(#{ha := Ha, z2m := Z}) ->
    Grouped = lists:foldl(fun({_Topic, {#{key := K} = Info, Entity}}, Acc) ->
                                  case maps:find(K, Acc) of
                                      {ok, #{entities := Es, availability := A} = D} ->
                                          A1 = case A of
                                                   undefined -> maps:get(availability, Info);
                                                   _ -> A
                                               end,
                                          Acc#{K := D#{entities := Es ++ [Entity],
                                                       availability := A1}};
                                      error ->
                                          Acc#{K => Info#{entities => [Entity]}}
                                  end
                          end, #{}, lists:sort(maps:to_list(Ha))),
    [D || {_, D} <- lists:sort(maps:to_list(Grouped))]
        ++ [D || {_, D} <- lists:sort([{K, D} || #{key := K} = D <- Z])].

%% A key of a component of the device-based config on `Topic'.
of_device({Topic, _Key}, Topic) -> true;
of_device(_, _) -> false.

problem(Topic, Message) ->
    #{what => bad_discovery, topic => Topic, message => Message}.

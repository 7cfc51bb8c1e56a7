%% @doc Internal. Reads zigbee2mqtt's retained device list
%% (`<base>/bridge/devices': a JSON array of devices with `friendly_name',
%% `ieee_address' and `definition.exposes') into the neutral device terms
%% of mqtt_avatar_discovery. Devices publish their state as one JSON object
%% on `<base>/<friendly_name>', take commands on `.../set' and report
%% availability on `.../availability'. Pure; never raises on input.
-module(mqtt_avatar_z2m).

-export([parse/2, parse/3]).
%% For the families (mqtt_avatar_family_*): reading their exposes.
-export([setting/4, entity/3, text/1, text/2, source/1]).

-export_type([ctx/0]).

%% The device an expose belongs to: its state topic and friendly name.
-type ctx() :: #{topic := binary(), device := binary()}.

%% `access' bits of an expose (zigbee2mqtt's documentation of exposes).
-define(ACCESS_STATE, 1).
-define(ACCESS_SET, 2).

%% @doc Parses the device list. Devices that cannot be read are left out
%% and reported, each with the reason.
-spec parse(binary(), binary()) ->
          {ok, [mqtt_avatar_discovery:device()], [binary()]} | {error, binary()}.
parse(Base, Payload) ->
    parse(Base, Payload, #{}).

%% @doc As `parse/2', the JSON decoded with `Opts' (`max_size').
-spec parse(binary(), binary(), evatar_json:opts()) ->
          {ok, [mqtt_avatar_discovery:device()], [binary()]} | {error, binary()}.
parse(Base, Payload, Opts) ->
    case evatar_json:decode(Payload, Opts) of
        {ok, List} when is_list(List) ->
            Results = [device(Base, D) || D <- List],
            {ok, [Dev || {ok, Dev} <- Results, Dev =/= skip], [M || {error, M} <- Results]};
        {ok, _} ->
            {error, <<"bridge/devices is not a JSON array">>};
        {error, R} ->
            {error, evatar_json:format_error(R)}
    end.

device(Base, #{<<"type">> := <<"Coordinator">>}) ->
    _ = Base,
    {ok, skip};
device(Base, #{<<"friendly_name">> := Name} = D) when is_binary(Name), Name =/= <<>> ->
    case maps:get(<<"definition">>, D, null) of
        #{<<"exposes">> := Exposes} = Def when is_list(Exposes) ->
            case valid_topic(Name) of
                false ->
                    {error, <<"device ", Name/binary, ": a friendly_name with + or # cannot be a topic">>};
                true ->
                    Topic = <<Base/binary, "/", Name/binary>>,
                    Description = text(maps:get(<<"description">>, Def, undefined)),
                    Entities = [outlet(E, Description)
                                || E <- lists:append([expose(Topic, Name, X, Exposes)
                                                      || X <- Exposes, is_map(X)])],
                    Ieee = case maps:get(<<"ieee_address">>, D, undefined) of
                               I when is_binary(I) -> I;
                               _ -> Name
                           end,
                    {ok, #{key => <<"z2m:", Ieee/binary>>,
                           name => Name,
                           room => undefined,
                           model => text(maps:get(<<"model">>, Def, undefined)),
                           availability => availability(Base, Topic),
                           entities => Entities}}
            end;
        _ ->
            {error, <<"device ", Name/binary, " has no definition (not interviewed or "
                      "unsupported); skipped">>}
    end;
device(_Base, _) ->
    {error, <<"an entry without friendly_name; skipped">>}.

%% A device is reachable when the bridge is up and the device itself is
%% (zigbee2mqtt's availability feature, when enabled, publishes the latter;
%% both as JSON `{"state":"online"}', or plain `online' before 1.28). A
%% topic never heard from does not count (docs/mqtt.md section 3.1).
availability(Base, Topic) ->
    Entry = fun(T) -> #{topic => T, online => <<"online">>, offline => <<"offline">>,
                        value => {json, [<<"state">>]}}
            end,
    #{mode => all, entries => [Entry(<<Topic/binary, "/availability">>),
                               Entry(<<Base/binary, "/bridge/state">>)]}.

%% Composite exposes of the other families, and settable numbers and
%% enums, are read by their family; so are sirens (a `warning' or `squawk'
%% composite, a settable binary `alarm', which stays a sensor too).
expose(Topic, Dev, #{<<"type">> := <<"composite">>, <<"property">> := P, <<"access">> := A} = E,
       _Exposes)
  when (P =:= <<"warning">> orelse P =:= <<"squawk">>), is_integer(A), A band ?ACCESS_SET =/= 0 ->
    mqtt_avatar_family_siren:from_z2m(E, #{topic => Topic, device => Dev});
expose(Topic, Dev, #{<<"type">> := <<"binary">>, <<"property">> := <<"alarm">>,
                     <<"access">> := A} = E, Exposes)
  when is_integer(A), A band ?ACCESS_SET =/= 0 ->
    expose(Topic, Dev, E#{<<"access">> := A band (bnot ?ACCESS_SET)}, Exposes)
        ++ mqtt_avatar_family_siren:from_z2m(E, #{topic => Topic, device => Dev});
expose(Topic, Dev, #{<<"type">> := Type} = E, _Exposes)
  when Type =:= <<"cover">>; Type =:= <<"lock">>; Type =:= <<"climate">>; Type =:= <<"fan">> ->
    Ctx = #{topic => Topic, device => Dev},
    case Type of
        <<"cover">> -> mqtt_avatar_family_cover:from_z2m(E, Ctx);
        <<"lock">> -> mqtt_avatar_family_lock:from_z2m(E, Ctx);
        <<"climate">> -> mqtt_avatar_family_climate:from_z2m(E, Ctx);
        <<"fan">> -> mqtt_avatar_family_fan:from_z2m(E, Ctx)
    end;
expose(Topic, Dev, #{<<"type">> := Type, <<"property">> := Prop, <<"access">> := A} = E, _Exposes)
  when (Type =:= <<"numeric">> orelse Type =:= <<"enum">>), is_binary(Prop), is_integer(A),
       A band ?ACCESS_SET =/= 0, A band ?ACCESS_STATE =/= 0, Prop =/= <<"action">> ->
    Ctx = #{topic => Topic, device => Dev},
    case Type of
        <<"numeric">> -> mqtt_avatar_family_number:from_z2m(E, Ctx);
        <<"enum">> -> mqtt_avatar_family_select:from_z2m(E, Ctx)
    end;
%% Composite exposes (light, switch) carry their state in a feature.
expose(Topic, Dev, #{<<"type">> := Type, <<"features">> := Features} = E, Exposes)
  when (Type =:= <<"light">> orelse Type =:= <<"switch">>), is_list(Features) ->
    case [F || #{<<"property">> := P} = F <- Features, is_map(F), is_binary(P),
               maps:get(<<"name">>, F, P) =:= <<"state">>] of
        [State | _] ->
            Kind = binary_to_kind(Type),
            Uid = iolist_to_binary([Dev, "/", maps:get(<<"property">>, State)]),
            Entity = base_entity(Topic, Uid, Kind, State, E),
            case Kind of
                %% The light as z2m announces it to Home Assistant (JSON schema).
                light -> [Entity#{light => mqtt_avatar_light:from_z2m(
                                             Topic, E#{<<"features">> := [F || F <- Features, is_map(F)]},
                                             [X || X <- Exposes, is_map(X)])}];
                switch -> [Entity]
            end;
        [] ->
            []
    end;
expose(Topic, Dev, #{<<"type">> := Type, <<"property">> := Prop} = E, _Exposes) when is_binary(Prop) ->
    Access = case maps:get(<<"access">>, E, ?ACCESS_STATE) of
                 A when is_integer(A) -> A;
                 _ -> 0
             end,
    Uid = iolist_to_binary([Dev, "/", Prop]),
    case {Type, Access band ?ACCESS_STATE =/= 0} of
        {_, false} -> [];
        {<<"binary">>, true} -> [(base_entity(Topic, Uid, binary_sensor, E, E))
                                 #{device_class => binary_class(Prop)}];
        {<<"enum">>, true} when Prop =:= <<"action">> -> [(base_entity(Topic, Uid, event, E, E))];
        {<<"numeric">>, true} ->
            %% Its values are numbers (zigbee2mqtt announces them to HA
            %% with a unit or a state class): MqttNumeric.
            [(base_entity(Topic, Uid, sensor, E, E))#{numeric => true}];
        {T, true} when T =:= <<"enum">>; T =:= <<"text">> ->
            [base_entity(Topic, Uid, sensor, E, E)];
        _ -> []
    end;
expose(_Topic, _Dev, _E, _Exposes) ->
    [].

base_entity(Topic, Uid, Kind, Feature, Expose) ->
    Prop = maps:get(<<"property">>, Feature),
    On = text(maps:get(<<"value_on">>, Feature, null), <<"ON">>),
    Off = text(maps:get(<<"value_off">>, Feature, null), <<"OFF">>),
    Settable = case maps:get(<<"access">>, Feature, 0) of
                   A when is_integer(A) -> A band ?ACCESS_SET =/= 0 andalso is_path_key(Prop);
                   _ -> false
               end,
    #{uid => Uid,
      kind => Kind,
      name => text(maps:get(<<"label">>, Expose, maps:get(<<"name">>, Expose, Prop))),
      device_class => undefined,
      state_topic => Topic,
      command_topic => case Settable of
                           true -> <<Topic/binary, "/set">>;
                           false -> undefined
                       end,
      value => source(Prop),
      json_command => true,
      on => On, off => Off, state_on => On, state_off => Off,
      press => <<"PRESS">>,
      attributes => false,
      on_change => Kind =/= event,
      volume => false, duration => false,
      unit => text(maps:get(<<"unit">>, Feature, undefined))}.

%% zigbee2mqtt has no device class for plugs; its description says so.
outlet(#{kind := switch} = E, Description) when is_binary(Description) ->
    case re:run(Description, <<"plug|socket|outlet">>, [caseless]) of
        {match, _} -> E#{device_class => <<"outlet">>};
        nomatch -> E
    end;
outlet(E, _) ->
    E.

%% @doc A feature as a family's setting (mqtt_avatar_part:setting()):
%% read from the device's JSON state when its `access' has the state bit,
%% set through `.../set' when it has the set bit; checked against
%% value_min..value_max or its enum values. `[]' when it is neither.
-spec setting(map(), binary(), binary(), ctx()) -> [mqtt_avatar_part:setting()].
setting(#{<<"property">> := P} = F, Param, Service, #{topic := Topic}) when is_binary(P) ->
    Access = case maps:get(<<"access">>, F, ?ACCESS_STATE) of
                 A when is_integer(A) -> A;
                 _ -> 0
             end,
    Check = case F of
                #{<<"value_min">> := Lo, <<"value_max">> := Hi} when is_number(Lo), is_number(Hi),
                                                                    Lo =< Hi ->
                    <<(text(Lo))/binary, "..", (text(Hi))/binary>>;
                #{<<"values">> := Vs} when is_list(Vs) ->
                    mqtt_avatar_part:one_of([V || V <- [text(V0) || V0 <- Vs], is_binary(V)]);
                _ -> <<>>
            end,
    S = maps:from_list([{state, #{topic => Topic, source => source(P)}}
                        || Access band ?ACCESS_STATE =/= 0]
                       ++ [{control, #{topic => <<Topic/binary, "/set">>, field => P}}
                           || Access band ?ACCESS_SET =/= 0, is_path_key(P)]),
    case map_size(S) of
        0 -> [];
        _ -> [S#{param => Param, service => Service, check => Check}]
    end;
setting(_, _, _, _) ->
    [].

%% @doc The shared keys of an entity of family `Kind' of the device,
%% named `<friendly_name>/<Suffix>'. zigbee2mqtt publishes the whole state
%% on every change, so its streams send only changes.
-spec entity(mqtt_avatar_discovery:kind(), binary(), ctx()) -> mqtt_avatar_discovery:entity().
entity(Kind, Suffix, #{topic := Topic, device := Dev}) ->
    #{uid => iolist_to_binary([Dev, "/", Suffix]),
      kind => Kind,
      name => undefined,
      device_class => undefined,
      state_topic => Topic,
      command_topic => <<Topic/binary, "/set">>,
      value => raw,
      attributes => false,
      on_change => true,
      unit => undefined}.

binary_to_kind(<<"light">>) -> light;
binary_to_kind(<<"switch">>) -> switch.

binary_class(P) when P =:= <<"occupancy">>; P =:= <<"presence">>; P =:= <<"motion">> ->
    <<"motion">>;
binary_class(P) ->
    P.

%% @doc A JSON scalar as text, `Default' for null and non-scalars: an on
%% or off value a device list gives as null is the usual ON/OFF, not a
%% command nobody can send (it crashed the description's generation).
-spec text(term(), binary()) -> binary().
text(V, Default) ->
    case text(V) of
        undefined -> Default;
        T -> T
    end.

%% @doc A JSON scalar as text (`undefined' for null and non-scalars).
-spec text(term()) -> binary() | undefined.
text(undefined) -> undefined;
text(null) -> undefined;
text(true) -> <<"true">>;
text(false) -> <<"false">>;
text(V) when is_binary(V) -> V;
text(V) when is_number(V) -> evatar_json:to_text(V);
text(_) -> undefined.

%% @doc Where a property is read from the device's JSON state: a path, or,
%% for a property a path cannot name (`ntc status' of EFEKTA's sensors: a
%% space, a dot), a template reading that key (docs/mqtt.md section 2.2).
-spec source(binary()) -> mqtt_avatar_spec:source().
source(P) ->
    case {is_path_key(P), binary:match(P, <<"'">>)} of
        {true, _} -> {json, [P]};
        {false, nomatch} -> {template, <<"{{ value_json['", P/binary, "'] }}">>};
        {false, _} -> {template, <<"{{ value_json[\"", P/binary, "\"] }}">>}
    end.

is_path_key(P) ->
    P =/= <<>> andalso
        lists:all(fun(C) -> (C >= $a andalso C =< $z) orelse (C >= $A andalso C =< $Z)
                                orelse (C >= $0 andalso C =< $9) orelse C =:= $_ orelse C =:= $-
                  end, binary_to_list(P)).

valid_topic(T) -> binary:match(T, [<<"+">>, <<"#">>, <<0>>]) =:= nomatch.

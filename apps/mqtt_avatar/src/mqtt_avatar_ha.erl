%% @doc Internal. Reads Home Assistant MQTT discovery messages
%% (`<prefix>/<component>/[<node_id>/]<object_id>/config', JSON, with HA's
%% key abbreviations and the `~' base topic) into the neutral entity terms
%% of mqtt_avatar_discovery. Pure; never raises on input.
-module(mqtt_avatar_ha).

-export([parse/3, template/1, components/0]).

-type parsed() :: {entity, mqtt_avatar_discovery:device_info(), mqtt_avatar_discovery:entity()}
                | remove.

%% The HA components an MQTT Avatar turns into BIL.
-define(COMPONENTS, [<<"light">>, <<"switch">>, <<"binary_sensor">>, <<"sensor">>, <<"button">>,
                     <<"text">>, <<"event">>, <<"siren">>, <<"notify">>]).

%% @doc The HA components understood.
-spec components() -> [binary()].
components() -> ?COMPONENTS.

%% @doc Parses one discovery message. `ignore' for topics that are not
%% discovery configs; `{error, Message}' says what is wrong with one that is.
-spec parse(binary(), binary(), binary()) -> {ok, parsed()} | ignore | {error, binary()}.
parse(Prefix, Topic, Payload) ->
    PrefixParts = binary:split(Prefix, <<"/">>, [global]),
    Parts = binary:split(Topic, <<"/">>, [global]),
    case lists:split(min(length(PrefixParts), length(Parts)), Parts) of
        {PrefixParts, Rest} -> config_topic(Rest, Payload);
        _ -> ignore
    end.

config_topic([Component, Object, <<"config">>], Payload) ->
    config(Component, undefined, Object, Payload);
config_topic([Component, Node, Object, <<"config">>], Payload) ->
    config(Component, Node, Object, Payload);
config_topic(_, _) ->
    ignore.

config(_Component, _Node, _Object, <<>>) ->
    {ok, remove};
config(Component, Node, Object, Payload) ->
    case lists:member(Component, ?COMPONENTS) of
        false ->
            {error, iolist_to_binary(["component ", printable(Component), " is not supported "
                                      "(supported: ", lists:join(", ", ?COMPONENTS), "); skipped"])};
        true ->
            case mqtt_avatar_json:decode(Payload) of
                {ok, Json} when is_map(Json) ->
                    entity(Component, Node, Object, expand(Json));
                {ok, _} ->
                    {error, <<"the config is not a JSON object">>};
                {error, R} ->
                    {error, mqtt_avatar_json:format_error(R)}
            end
    end.

entity(Component, Node, Object, C) ->
    Uid = case str(<<"unique_id">>, C) of
              undefined -> iolist_to_binary([Component, "/", [[Node, "/"] || Node =/= undefined],
                                             Object]);
              U -> U
          end,
    Kind = binary_to_existing_kind(Component),
    Results = [topic(<<"state_topic">>, C), topic(<<"command_topic">>, C),
               topic(<<"json_attributes_topic">>, C), availability(C),
               value_source(C)],
    case [M || {error, M} <- Results] of
        [] ->
            [{ok, State}, {ok, Command}, {ok, Attrs}, {ok, Avail}, {ok, Value}] = Results,
            required(Kind, State, Command, Uid, Value, Attrs, Avail, C);
        [M | _] ->
            {error, iolist_to_binary([Uid, ": ", M])}
    end.

required(Kind, State, Command, Uid, Value, Attrs, Avail, C) ->
    NeedsState = lists:member(Kind, [binary_sensor, sensor, event]),
    NeedsCommand = lists:member(Kind, [light, switch, button, text, siren, notify]),
    if
        NeedsState, State =:= undefined ->
            {error, <<Uid/binary, ": a ", (atom_to_binary(Kind))/binary, " needs state_topic">>};
        NeedsCommand, Command =:= undefined ->
            {error, <<Uid/binary, ": a ", (atom_to_binary(Kind))/binary, " needs command_topic">>};
        true ->
            Json = Kind =:= light andalso str(<<"schema">>, C) =:= <<"json">>,
            On = str(<<"payload_on">>, C, <<"ON">>),
            Off = str(<<"payload_off">>, C, <<"OFF">>),
            Value1 = case {Json, Value} of
                         {true, raw} -> {json, [<<"state">>]};
                         _ -> Value
                     end,
            Entity = #{uid => Uid,
                       kind => Kind,
                       name => entity_name(C),
                       device_class => str(<<"device_class">>, C),
                       state_topic => State,
                       command_topic => Command,
                       value => Value1,
                       json_command => Json,
                       on => On, off => Off,
                       state_on => str(<<"state_on">>, C, On),
                       state_off => str(<<"state_off">>, C, Off),
                       press => str(<<"payload_press">>, C, <<"PRESS">>),
                       attributes => Attrs =/= undefined andalso Attrs =:= State
                                     orelse Kind =:= event,
                       volume => maps:get(<<"support_volume_set">>, C, false) =:= true,
                       duration => maps:get(<<"support_duration">>, C, false) =:= true,
                       on_change => false,
                       unit => str(<<"unit_of_measurement">>, C)},
            {ok, {entity, device(C, Uid, Avail), Entity}}
    end.

binary_to_existing_kind(<<"light">>) -> light;
binary_to_existing_kind(<<"switch">>) -> switch;
binary_to_existing_kind(<<"binary_sensor">>) -> binary_sensor;
binary_to_existing_kind(<<"sensor">>) -> sensor;
binary_to_existing_kind(<<"button">>) -> button;
binary_to_existing_kind(<<"text">>) -> text;
binary_to_existing_kind(<<"event">>) -> event;
binary_to_existing_kind(<<"siren">>) -> siren;
binary_to_existing_kind(<<"notify">>) -> notify.

entity_name(C) ->
    case maps:get(<<"name">>, C, undefined) of
        N when is_binary(N), N =/= <<>> -> N;
        _ -> undefined
    end.

device(C, Uid, Avail) ->
    case maps:get(<<"device">>, C, undefined) of
        D when is_map(D) ->
            Ids = case maps:get(<<"identifiers">>, D, undefined) of
                      L when is_list(L) -> [I || I <- L, is_binary(I)];
                      I when is_binary(I) -> [I];
                      _ -> []
                  end,
            Key = case Ids of
                      [Id | _] -> <<"ha:", Id/binary>>;
                      [] -> <<"ha-entity:", Uid/binary>>
                  end,
            #{key => Key, name => str(<<"name">>, D), room => str(<<"suggested_area">>, D),
              model => str(<<"model">>, D), availability => Avail};
        _ ->
            #{key => <<"ha-entity:", Uid/binary>>, name => undefined, room => undefined,
              model => undefined, availability => Avail}
    end.

availability(C) ->
    Item = case maps:get(<<"availability">>, C, undefined) of
               [First | _] when is_map(First) -> expand(First);
               _ -> #{}
           end,
    Topic = case maps:get(<<"topic">>, Item, undefined) of
                T when is_binary(T) -> T;
                _ -> str(<<"availability_topic">>, C)
            end,
    Get = fun(K, Default) ->
                  case maps:get(K, Item, undefined) of
                      V when is_binary(V) -> V;
                      _ -> str(K, C, Default)
                  end
          end,
    case Topic of
        undefined ->
            {ok, undefined};
        _ ->
            case valid_topic(Topic) of
                false ->
                    {error, <<"availability topic ", (printable(Topic))/binary,
                              " is empty or has a wildcard">>};
                true ->
                    Template = case maps:get(<<"value_template">>, Item, undefined) of
                                   V when is_binary(V) -> V;
                                   _ -> str(<<"availability_template">>, C)
                               end,
                    case source(Template) of
                        {ok, Source} ->
                            {ok, #{topic => Topic,
                                   online => Get(<<"payload_available">>, <<"online">>),
                                   offline => Get(<<"payload_not_available">>, <<"offline">>),
                                   value => Source}};
                        {error, M} ->
                            {error, M}
                    end
            end
    end.

value_source(C) ->
    Template = case str(<<"state_value_template">>, C) of
                   undefined -> str(<<"value_template">>, C);
                   T -> T
               end,
    source(Template).

source(undefined) -> {ok, raw};
source(Template) ->
    case template(Template) of
        {ok, S} -> {ok, S};
        error -> {error, <<"value template ", (printable(Template))/binary, " is not supported: "
                           "use {{ value }} or {{ value_json.field }} (edit MqttValue in the "
                           "generated BIL for anything else)">>}
    end.

%% @doc Understands the templates devices actually send:
%% `{{ value }}', `{{ value_json.a.b }}', `{{ value_json["a"] }}',
%% `{{ value_json['a'] }}', each optionally followed by simple filters
%% (`| int', `| float', `| lower', `| round(1)'...), which are ignored.
-spec template(binary()) -> {ok, mqtt_avatar_spec:source()} | error.
template(Text) ->
    case re:run(Text, <<"^\\s*\\{\\{\\s*(value_json(?:\\.[A-Za-z0-9_]+|\\[\\s*['\"][^'\"]+['\"]\\s*\\]|\\[[0-9]+\\])*|value)"
                       "\\s*(\\|\\s*[a-z_]+(\\([^)]*\\))?\\s*)*\\}\\}\\s*$">>,
                [{capture, [1], binary}, unicode]) of
        {match, [<<"value">>]} ->
            {ok, raw};
        {match, [<<"value_json", Rest/binary>>]} ->
            Segments = [S || S <- re:split(Rest, <<"[.\\[\\]'\" ]+">>, [{return, binary}]),
                             S =/= <<>>],
            {ok, {json, Segments}};
        _ ->
            error
    end.

topic(Key, C) ->
    case maps:get(Key, C, undefined) of
        undefined -> {ok, undefined};
        T when is_binary(T) ->
            case valid_topic(T) of
                true -> {ok, T};
                false -> {error, <<Key/binary, " is empty or has a wildcard">>}
            end;
        _ -> {error, <<Key/binary, " is not a string">>}
    end.

valid_topic(<<>>) -> false;
valid_topic(T) -> binary:match(T, [<<"+">>, <<"#">>, <<0>>]) =:= nomatch.

str(Key, C) -> str(Key, C, undefined).

str(Key, C, Default) ->
    case maps:get(Key, C, undefined) of
        V when is_binary(V) -> V;
        V when is_integer(V) -> integer_to_binary(V);
        true when Default =/= undefined -> <<"true">>;
        false when Default =/= undefined -> <<"false">>;
        _ -> Default
    end.

printable(B) ->
    case byte_size(B) > 80 of
        true -> <<(binary:part(B, 0, 80))/binary, "...">>;
        false -> B
    end.

%% ---------------------------------------------------------------------------
%% Abbreviations and the base topic
%% ---------------------------------------------------------------------------

expand(C) ->
    Full = maps:fold(fun(K, V, Acc) -> Acc#{full_key(K) => expand_value(K, V)} end, #{}, C),
    case maps:get(<<"~">>, Full, undefined) of
        Base when is_binary(Base) ->
            maps:map(fun(K, V) -> base_topic(K, V, Base) end, Full);
        _ ->
            Full
    end.

expand_value(K, V) when is_map(V), K =:= <<"dev">> orelse K =:= <<"device">> ->
    maps:fold(fun(K1, V1, Acc) -> Acc#{full_key(K1) => V1} end, #{}, V);
expand_value(_K, V) ->
    V.

base_topic(K, V, Base) when is_binary(V) ->
    case binary:longest_common_suffix([K, <<"topic">>]) =:= 5 of
        true ->
            case V of
                <<"~", Rest/binary>> -> <<Base/binary, Rest/binary>>;
                %% An empty topic is left for validation to report, not taken apart.
                _ when byte_size(V) > 0 ->
                    case binary:last(V) of
                        $~ -> <<(binary:part(V, 0, byte_size(V) - 1))/binary, Base/binary>>;
                        _ -> V
                    end;
                _ -> V
            end;
        false -> V
    end;
base_topic(<<"availability">>, L, Base) when is_list(L) ->
    [case I of
         #{<<"topic">> := _} -> maps:map(fun(K, V) -> base_topic(K, V, Base) end, I);
         #{<<"t">> := T} -> maps:map(fun(K, V) -> base_topic(K, V, Base) end,
                                     maps:put(<<"topic">>, T, maps:remove(<<"t">>, I)));
         _ -> I
     end || I <- L];
base_topic(_K, V, _Base) ->
    V.

full_key(K) ->
    case lists:keyfind(K, 1, abbreviations()) of
        {_, Full} -> Full;
        false -> K
    end.

abbreviations() ->
    [{<<"avty">>, <<"availability">>}, {<<"avty_t">>, <<"availability_topic">>},
     {<<"avty_tpl">>, <<"availability_template">>}, {<<"avty_mode">>, <<"availability_mode">>},
     {<<"pl_avail">>, <<"payload_available">>}, {<<"pl_not_avail">>, <<"payload_not_available">>},
     {<<"cmd_t">>, <<"command_topic">>}, {<<"cmd_tpl">>, <<"command_template">>},
     {<<"stat_t">>, <<"state_topic">>}, {<<"stat_tpl">>, <<"state_template">>},
     {<<"stat_val_tpl">>, <<"state_value_template">>}, {<<"val_tpl">>, <<"value_template">>},
     {<<"pl_on">>, <<"payload_on">>}, {<<"pl_off">>, <<"payload_off">>},
     {<<"stat_on">>, <<"state_on">>}, {<<"stat_off">>, <<"state_off">>},
     {<<"pl_prs">>, <<"payload_press">>}, {<<"dev_cla">>, <<"device_class">>},
     {<<"uniq_id">>, <<"unique_id">>}, {<<"obj_id">>, <<"object_id">>},
     {<<"dev">>, <<"device">>}, {<<"unit_of_meas">>, <<"unit_of_measurement">>},
     {<<"json_attr_t">>, <<"json_attributes_topic">>},
     {<<"json_attr_tpl">>, <<"json_attributes_template">>},
     {<<"evt_typ">>, <<"event_types">>}, {<<"av_tones">>, <<"available_tones">>},
     {<<"sup_vol">>, <<"support_volume_set">>}, {<<"sup_dur">>, <<"support_duration">>},
     {<<"t">>, <<"topic">>}, {<<"ret">>, <<"retain">>}, {<<"opt">>, <<"optimistic">>}, {<<"stat_cla">>, <<"state_class">>},
     %% inside `device'
     {<<"ids">>, <<"identifiers">>}, {<<"cns">>, <<"connections">>},
     {<<"mf">>, <<"manufacturer">>}, {<<"mdl">>, <<"model">>}, {<<"sa">>, <<"suggested_area">>},
     {<<"sw">>, <<"sw_version">>}, {<<"hw">>, <<"hw_version">>}].

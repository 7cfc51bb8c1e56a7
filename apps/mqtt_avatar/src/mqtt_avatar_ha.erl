%% @doc Internal. Reads Home Assistant MQTT discovery messages
%% (`<prefix>/<component>/[<node_id>/]<object_id>/config', JSON, with HA's
%% key abbreviations and the `~' base topic) into the neutral entity terms
%% of mqtt_avatar_discovery. Pure; never raises on input.
-module(mqtt_avatar_ha).

-export([parse/3, parse/4, template/1, components/0]).
%% For the families (mqtt_avatar_family_*): reading their keys.
-export([str/2, str/3, topic/2, source/1, command_template/1, require/3, on_off/1, bool/3,
         number/3, strings/2, command_and_state/3, with_command_template/2,
         read/2, settings/2]).

%% `{entities, [{ComponentKey, Info, Entity}], Problems}': a device-based
%% discovery message (`<prefix>/device/<id>/config' with `cmps'), one
%% entity per component read, and what was wrong with the others.
-type parsed() :: {entity, mqtt_avatar_discovery:device_info(), mqtt_avatar_discovery:entity()}
                | {entities, [{binary(), mqtt_avatar_discovery:device_info(),
                               mqtt_avatar_discovery:entity()}], [binary()]}
                | remove.

%% Entries of an `availability' list an entity may have (docs/mqtt.md 3.1).
-define(MAX_AVAILABILITY, 8).

%% @doc The HA components understood.
-spec components() -> [binary()].
components() -> mqtt_avatar_family:components().

%% @doc Parses one discovery message. `ignore' for topics that are not
%% discovery configs; `{error, Message}' says what is wrong with one that is.
-spec parse(binary(), binary(), binary()) -> {ok, parsed()} | ignore | {error, binary()}.
parse(Prefix, Topic, Payload) ->
    parse(Prefix, Topic, Payload, #{}).

%% @doc As `parse/3', the JSON decoded with `Opts' (`max_size').
-spec parse(binary(), binary(), binary(), evatar_json:opts()) ->
          {ok, parsed()} | ignore | {error, binary()}.
parse(Prefix, Topic, Payload, Opts) ->
    PrefixParts = binary:split(Prefix, <<"/">>, [global]),
    Parts = binary:split(Topic, <<"/">>, [global]),
    case lists:split(min(length(PrefixParts), length(Parts)), Parts) of
        {PrefixParts, Rest} -> config_topic(Rest, Payload, Opts);
        _ -> ignore
    end.

config_topic([<<"device">>, Object, <<"config">>], Payload, Opts) ->
    device_config(undefined, Object, Payload, Opts);
config_topic([<<"device">>, Node, Object, <<"config">>], Payload, Opts) ->
    device_config(Node, Object, Payload, Opts);
config_topic([Component, Object, <<"config">>], Payload, Opts) ->
    config(Component, undefined, Object, Payload, Opts);
config_topic([Component, Node, Object, <<"config">>], Payload, Opts) ->
    config(Component, Node, Object, Payload, Opts);
config_topic(_, _, _) ->
    ignore.

config(_Component, _Node, _Object, <<>>, _Opts) ->
    {ok, remove};
config(Component, Node, Object, Payload, Opts) ->
    case mqtt_avatar_family:module(Component) of
        error ->
            {error, iolist_to_binary(["component ", printable(Component), " is not supported "
                                      "(supported: ", lists:join(", ", components()), "); skipped"])};
        {ok, Kind, _Mod} ->
            case evatar_json:decode(Payload, Opts) of
                {ok, Json} when is_map(Json) ->
                    entity(Component, Kind, Node, Object,
                           expand(Json, mqtt_avatar_family:abbreviations(Component)));
                {ok, _} ->
                    {error, <<"the config is not a JSON object">>};
                {error, R} ->
                    {error, evatar_json:format_error(R)}
            end
    end.

%% HA's device-based discovery: one message for a device, its components
%% in `cmps' (`components'), each with its platform in `p' (`platform').
%% Every other top-level key (`dev', `o', `avty', `stat_t', `~', `qos'...)
%% is shared: a component takes it unless it sets the key itself, as HA
%% does. A component with no key but its platform is one HA removes: left
%% out. Each component is then read as a config of its platform.
device_config(_Node, _Object, <<>>, _Opts) ->
    {ok, remove};
device_config(Node, Object, Payload, Opts) ->
    case evatar_json:decode(Payload, Opts) of
        {ok, Json} when is_map(Json) ->
            Cmps = maps:get(<<"cmps">>, Json, maps:get(<<"components">>, Json, undefined)),
            Shared = maps:without([<<"cmps">>, <<"components">>], Json),
            case Cmps of
                M when is_map(M) ->
                    Results = [device_component(Node, Object, Key, Shared, C)
                               || {Key, C} <- lists:sort(maps:to_list(M))],
                    {ok, {entities, [E || {ok, E} <- Results], [P || {error, P} <- Results]}};
                _ ->
                    {error, <<"a device discovery config needs cmps, an object of components">>}
            end;
        {ok, _} ->
            {error, <<"the config is not a JSON object">>};
        {error, R} ->
            {error, evatar_json:format_error(R)}
    end.

device_component(Node, Object, Key, Shared, C) when is_map(C) ->
    Own = maps:without([<<"p">>, <<"platform">>], C),
    case maps:get(<<"p">>, C, maps:get(<<"platform">>, C, undefined)) of
        _ when map_size(Own) =:= 0 ->
            skip;
        Platform when is_binary(Platform) ->
            In = fun(M) -> <<"component ", (printable(Key))/binary, ": ", M/binary>> end,
            case mqtt_avatar_family:module(Platform) of
                error ->
                    {error, In(iolist_to_binary(["platform ", printable(Platform),
                                                 " is not supported (supported: ",
                                                 lists:join(", ", components()), "); skipped"]))};
                {ok, Kind, _Mod} ->
                    %% HA's object id of a device's component is its key.
                    Parent = case Node of
                                 undefined -> Object;
                                 _ -> <<Node/binary, "/", Object/binary>>
                             end,
                    %% Keys in full before merging (a component's `stat_t'
                    %% overrides a shared `state_topic'), then `~' once.
                    Abbr = mqtt_avatar_family:abbreviations(Platform),
                    Merged = expand(maps:merge(expand(Shared, Abbr), expand(Own, Abbr)), Abbr),
                    case entity(Platform, Kind, Parent, Key, Merged) of
                        {ok, {entity, Info, E}} -> {ok, {Key, Info, E}};
                        {error, M} -> {error, In(M)}
                    end
            end;
        _ ->
            {error, <<"component ", (printable(Key))/binary, ": p (platform) must be a component "
                      "name such as sensor">>}
    end;
device_component(_Node, _Object, Key, _Shared, _C) ->
    {error, <<"component ", (printable(Key))/binary, " is not a JSON object">>}.

%% The keys every family shares; the family reads the rest.
entity(Component, Kind, Node, Object, C) ->
    Uid = case str(<<"unique_id">>, C) of
              undefined -> iolist_to_binary([Component, "/", [[Node, "/"] || Node =/= undefined],
                                             Object]);
              U -> U
          end,
    %% A light reads its templates itself (mqtt_avatar_light), in every schema.
    Results = [topic(<<"state_topic">>, C), topic(<<"command_topic">>, C),
               topic(<<"json_attributes_topic">>, C), availability(C),
               case Kind of
                   light -> {ok, raw};
                   _ -> value_source(C)
               end],
    case [M || {error, M} <- Results] of
        [] ->
            [{ok, State}, {ok, Command}, {ok, Attrs}, {ok, Avail}, {ok, Value}] = Results,
            Base = #{uid => Uid,
                     kind => Kind,
                     name => entity_name(C),
                     device_class => str(<<"device_class">>, C),
                     state_topic => State,
                     command_topic => Command,
                     value => Value,
                     attributes => Attrs =/= undefined andalso Attrs =:= State,
                     on_change => false,
                     unit => str(<<"unit_of_measurement">>, C),
                     state_class => str(<<"state_class">>, C)},
            case mqtt_avatar_family:from_ha(Component, C, Base) of
                {ok, Entity} -> {ok, {entity, device(C, Uid, Avail), Entity}};
                {error, M} -> {error, <<Uid/binary, ": ", M/binary>>}
            end;
        [M | _] ->
            {error, iolist_to_binary([Uid, ": ", M])}
    end.

%% @doc `ok' when the entity has topic `Key' (`state_topic' or
%% `command_topic'), else the error its family gives.
-spec require(state_topic | command_topic, map(), fun(() -> {ok, map()} | {error, binary()})) ->
          {ok, map()} | {error, binary()}.
require(Key, #{kind := Kind} = Base, Then) ->
    case maps:get(Key, Base) of
        undefined -> {error, <<"a ", (atom_to_binary(Kind))/binary, " needs ",
                               (atom_to_binary(Key))/binary>>};
        _ -> Then()
    end.

%% @doc A family commanded on `command_topic' whose state, when it has one,
%% is the entity's own `state_topic' read by its `value_template' (lock,
%% valve): `Then' gets these topics (`command', and `state') once the
%% command topic is known to be there.
-spec command_and_state(map(), map(),
                        fun((#{command := mqtt_avatar_part:control(),
                               state => mqtt_avatar_part:state()}) ->
                                   {ok, map()} | {error, binary()})) ->
          {ok, map()} | {error, binary()}.
command_and_state(C, Base, Then) ->
    require(command_topic, Base, fun() ->
        {ok, #{command := _} = T} = read(C, [{command, {control, <<"command_topic">>}}]),
        case maps:get(state_topic, Base) of
            undefined -> Then(T);
            ST -> Then(T#{state => #{topic => ST, source => maps:get(value, Base)}})
        end
    end).

%% @doc `E' with HA's `command_template' of config `C' (checked here,
%% applied to every command) as its `template'; an unusable template is
%% the entity's error (number, select).
-spec with_command_template(map(), map()) -> {ok, map()} | {error, binary()}.
with_command_template(C, E) ->
    case command_template(str(<<"command_template">>, C)) of
        {ok, undefined} -> {ok, E};
        {ok, T} -> {ok, E#{template => T}};
        {error, _} = Error -> Error
    end.

%% @doc Reads a family's topics: `{state, TopicKey, TemplateKey}' gives a
%% mqtt_avatar_part:state() (the template says where the value is),
%% `{control, TopicKey}' a mqtt_avatar_part:control() (the payload is the
%% value). Absent topics are left out of the map; a bad topic or an
%% unsupported template is an error.
-spec read(map(), [{atom(), {state, binary(), binary() | undefined} | {control, binary()}}]) ->
          {ok, #{atom() => mqtt_avatar_part:state() | mqtt_avatar_part:control()}}
        | {error, binary()}.
read(C, Specs) ->
    lists:foldl(fun(_, {error, _} = E) -> E;
                   ({Name, Spec}, {ok, Acc}) ->
                        case read_one(C, Spec) of
                            {ok, undefined} -> {ok, Acc};
                            {ok, V} -> {ok, Acc#{Name => V}};
                            {error, _} = E -> E
                        end
                end, {ok, #{}}, Specs).

%% @doc A family's settings (mqtt_avatar_part:setting()), from
%% `{Param, Service, CommandKey, StateKey, TemplateKey, Check}'; a setting
%% with neither topic is left out.
-spec settings(map(), [{binary(), binary(), binary() | undefined, binary() | undefined,
                        binary() | undefined, binary()}]) ->
          {ok, [mqtt_avatar_part:setting()]} | {error, binary()}.
settings(C, Specs) ->
    lists:foldr(fun(_, {error, _} = E) -> E;
                   ({Param, Service, CmdKey, StateKey, TplKey, Check}, {ok, Acc}) ->
                        Read = [{control, {control, CmdKey}} || CmdKey =/= undefined]
                            ++ [{state, {state, StateKey, TplKey}} || StateKey =/= undefined],
                        case read(C, Read) of
                            {ok, M} when map_size(M) =:= 0 -> {ok, Acc};
                            {ok, M} -> {ok, [M#{param => Param, service => Service, check => Check}
                                             | Acc]};
                            {error, _} = E -> E
                        end
                end, {ok, []}, Specs).

read_one(C, {control, Key}) ->
    case topic(Key, C) of
        {ok, undefined} -> {ok, undefined};
        {ok, T} ->
            %% `mode_command_topic' has its `mode_command_template'...
            TplKey = binary:replace(Key, <<"_topic">>, <<"_template">>),
            case command_template(str(TplKey, C)) of
                {ok, undefined} -> {ok, #{topic => T, field => undefined}};
                {ok, Tpl} -> {ok, #{topic => T, field => undefined, template => Tpl}};
                {error, _} = E -> E
            end;
        {error, _} = E -> E
    end;
read_one(C, {state, Key, TemplateKey}) ->
    case topic(Key, C) of
        {ok, undefined} -> {ok, undefined};
        {ok, T} ->
            Template = case TemplateKey of
                           undefined -> undefined;
                           _ -> str(TemplateKey, C)
                       end,
            case source(Template) of
                {ok, S} -> {ok, #{topic => T, source => S}};
                {error, _} = E -> E
            end;
        {error, _} = E -> E
    end.

%% @doc The on/off payloads and states of lights, switches, fans...
-spec on_off(map()) -> #{on := binary(), off := binary(), state_on := binary(),
                         state_off := binary()}.
on_off(C) ->
    On = str(<<"payload_on">>, C, <<"ON">>),
    Off = str(<<"payload_off">>, C, <<"OFF">>),
    #{on => On, off => Off,
      state_on => str(<<"state_on">>, C, On),
      state_off => str(<<"state_off">>, C, Off)}.

%% @doc A boolean key.
-spec bool(binary(), map(), boolean()) -> boolean().
bool(Key, C, Default) ->
    case maps:get(Key, C, Default) of
        B when is_boolean(B) -> B;
        _ -> Default
    end.

%% @doc A number key, as text (`Default' when absent or not a number).
-spec number(binary(), map(), binary() | undefined) -> binary() | undefined.
number(Key, C, Default) ->
    case maps:get(Key, C, undefined) of
        N when is_number(N) -> evatar_json:to_text(N);
        _ -> Default
    end.

%% @doc A list of strings (`Default' when absent or not one).
-spec strings(binary(), map()) -> [binary()] | undefined.
strings(Key, C) ->
    case maps:get(Key, C, undefined) of
        L when is_list(L) -> [V || V <- L, is_binary(V)];
        _ -> undefined
    end.

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

%% HA's `availability' list (each entry with its own payloads, default
%% online/offline, and `value_template'), with `availability_mode'; or the
%% single `availability_topic' with the top-level payloads and
%% `availability_template'.
availability(C) ->
    Items = case maps:get(<<"availability">>, C, undefined) of
                L when is_list(L), L =/= [] ->
                    {list, [expand(I, []) || I <- L, is_map(I)]};
                _ ->
                    case str(<<"availability_topic">>, C) of
                        undefined -> none;
                        T -> {list, [#{<<"topic">> => T,
                                       <<"payload_available">> => str(<<"payload_available">>, C),
                                       <<"payload_not_available">> =>
                                           str(<<"payload_not_available">>, C),
                                       <<"value_template">> => str(<<"availability_template">>, C)}]}
                    end
            end,
    Mode = case str(<<"availability_mode">>, C, <<"latest">>) of
               <<"latest">> -> {ok, latest};
               <<"all">> -> {ok, all};
               <<"any">> -> {ok, any};
               Other -> {error, <<"availability_mode ", (printable(Other))/binary,
                                  " is not all, any or latest">>}
           end,
    case Items of
        none ->
            {ok, undefined};
        {list, Is} when length(Is) > ?MAX_AVAILABILITY ->
            {error, <<"more than 8 availability entries">>};
        {list, Is} ->
            Entries = [availability_entry(I) || I <- Is],
            case [M || {error, M} <- [Mode | Entries]] of
                [] when Entries =:= [] -> {ok, undefined};
                [] -> {ok, #{mode => element(2, Mode), entries => [E || {ok, E} <- Entries]}};
                [M | _] -> {error, M}
            end
    end.

availability_entry(Item) ->
    Get = fun(K, Default) ->
                  case str(K, Item) of
                      undefined -> Default;
                      V -> V
                  end
          end,
    case str(<<"topic">>, Item) of
        undefined ->
            {error, <<"an availability entry without topic">>};
        Topic ->
            case valid_topic(Topic) of
                false ->
                    {error, <<"availability topic ", (printable(Topic))/binary,
                              " is empty or has a wildcard">>};
                true ->
                    %% A plain path is read as one; any other template is
                    %% rendered at each message and compared with the payloads.
                    case source(str(<<"value_template">>, Item)) of
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

%% @doc Where a state template reads its value (`undefined': the whole
%% payload): a plain path when it is one, else the template itself,
%% evaluated for every message by mqtt_avatar_template (docs/mqtt.md
%% section 2.3); a template it cannot evaluate is an error.
-spec source(binary() | undefined) -> {ok, mqtt_avatar_spec:source()} | {error, binary()}.
source(Template) ->
    case path_source(Template) of
        {ok, S} -> {ok, S};
        {error, _} ->
            case mqtt_avatar_template:parse(Template) of
                {ok, _} -> {ok, {template, Template}};
                {error, M} -> {error, <<"value template ", (printable(Template))/binary,
                                        " is not supported: ", M/binary, " (docs/mqtt.md "
                                        "section 2.3 lists the forms supported; an override "
                                        "can set MqttValueTemplate)">>}
            end
    end.

%% @doc A command template (`undefined' when there is none), checked.
-spec command_template(binary() | undefined) -> {ok, binary() | undefined} | {error, binary()}.
command_template(undefined) -> {ok, undefined};
command_template(Template) ->
    case mqtt_avatar_template:parse(Template) of
        {ok, _} -> {ok, Template};
        {error, M} -> {error, <<"command template ", (printable(Template))/binary,
                                " cannot be used: ", M/binary>>}
    end.

%% Availability payloads are compared, not evaluated: a plain path only.
path_source(undefined) -> {ok, raw};
path_source(Template) ->
    case template(Template) of
        {ok, S} -> {ok, S};
        error -> {error, <<"value template ", (printable(Template))/binary, " is not supported: "
                           "use {{ value }} or {{ value_json.field }} (edit MqttValue in the "
                           "generated BIL for anything else)">>}
    end.

%% @doc Understands the templates devices actually send:
%% `{{ value }}', `{{ value_json.a.b }}', `{{ value_json["a"] }}',
%% `{{ value_json['a'] }}', each optionally followed by filters that do not
%% change a value read as text (`| int', `| float', `| string', `| trim',
%% `| lower', `| upper', `| round(1)'), which are ignored. Any other filter
%% is not a path: the evaluator evaluates it, or refuses it by name
%% (`format').
-spec template(binary()) -> {ok, mqtt_avatar_spec:source()} | error.
template(Text) ->
    case re:run(Text, <<"^\\s*\\{\\{\\s*(value_json(?:\\.[A-Za-z0-9_]+|\\[\\s*['\"][^'\"]+['\"]\\s*\\]|\\[[0-9]+\\])*|value)"
                       "\\s*(\\|\\s*(?:int|float|string|trim|lower|upper|round)(\\([^)]*\\))?\\s*)*"
                       "\\}\\}\\s*$">>,
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

%% @doc A topic key: `undefined' when absent, an error for a bad topic.
-spec topic(binary(), map()) -> {ok, binary() | undefined} | {error, binary()}.
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

%% @doc A text key (numbers as text).
-spec str(binary(), map()) -> binary() | undefined.
str(Key, C) -> str(Key, C, undefined).

-spec str(binary(), map(), binary() | undefined) -> binary() | undefined.

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

expand(C, Extra) ->
    Full = maps:fold(fun(K, V, Acc) -> Acc#{full_key(K, Extra) => expand_value(K, V)} end, #{}, C),
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

full_key(K) -> full_key(K, []).

full_key(K, Extra) ->
    case lists:keyfind(K, 1, abbreviations()) of
        {_, Full} -> Full;
        false ->
            case lists:keyfind(K, 1, Extra) of
                {_, Full} -> Full;
                false -> K
            end
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

%% @doc Internal. Home Assistant's MQTT light, in its three schemas
%% (`default', `json', `template'), as pure functions: `config/1' reads a
%% light config (HA's keys, as in a discovery message or the `MqttLight'
%% parameter), `command/3' turns a VA's TurnLightOn/TurnLightOff parameters
%% into the publishes HA would make, `read/4' folds a state message into
%% the light's state, `params/1' gives that state as BIL parameters.
%% zigbee2mqtt lights are given as the JSON-schema config z2m itself
%% announces (`from_z2m/3'). docs/mqtt.md section 2.7 is the reference.
-module(mqtt_avatar_light).

-export([config/1, command/3, read/4, params/1, state_topics/1, capabilities/1,
         from_z2m/3, config_keys/0, satisfied/3, optimistic/1, command_topic/1]).

-export_type([light/0, state/0, wait/0]).

-type tpl() :: mqtt_avatar_template:template().
-type feature() :: brightness | rgb | hs | xy | color_temp | effect.
-opaque light() :: #{schema := default | json | template,
                     command_topic := binary(),
                     state_topic := binary() | undefined,
                     on := binary(), off := binary(),
                     on_command_type := last | first | brightness,
                     scale := pos_integer(),
                     features := [feature()],
                     transition := boolean(),
                     kelvin := boolean(),
                     mireds := {pos_integer(), pos_integer()},
                     kelvins := {pos_integer(), pos_integer()},
                     effects := [binary()],
                     topics := #{feature() => {binary() | undefined, binary() | undefined}},
                     templates := #{atom() => tpl()}}.
%% The light's known state: BIL parameter name => value.
-type state() :: #{binary() => binary()}.
%% What a command waits for: the on/off state on the state topic, after a
%% message on each topic named (a topic named twice: two messages);
%% `assumed' is the state the command asks for (what an optimistic light
%% reports).
-type wait() :: #{state := binary(), topics := [binary()], assumed := state()}.

-define(MAX_TRANSITION, 3600).

%% Keys of HA's light config kept in `MqttLight' (abbreviations expanded).
-define(KEYS, [<<"schema">>, <<"command_topic">>, <<"state_topic">>, <<"payload_on">>,
               <<"payload_off">>, <<"state_value_template">>, <<"on_command_type">>,
               <<"brightness_command_topic">>, <<"brightness_command_template">>,
               <<"brightness_state_topic">>, <<"brightness_value_template">>,
               <<"brightness_scale">>, <<"brightness">>,
               <<"rgb_command_topic">>, <<"rgb_command_template">>, <<"rgb_state_topic">>,
               <<"rgb_value_template">>, <<"hs_command_topic">>, <<"hs_command_template">>,
               <<"hs_state_topic">>, <<"hs_value_template">>, <<"xy_command_topic">>,
               <<"xy_command_template">>, <<"xy_state_topic">>, <<"xy_value_template">>,
               <<"color_temp_command_topic">>, <<"color_temp_command_template">>,
               <<"color_temp_state_topic">>, <<"color_temp_value_template">>,
               <<"color_temp_kelvin">>, <<"min_mireds">>, <<"max_mireds">>, <<"min_kelvin">>,
               <<"max_kelvin">>, <<"effect_command_topic">>, <<"effect_command_template">>,
               <<"effect_state_topic">>, <<"effect_value_template">>, <<"effect_list">>,
               <<"effect">>, <<"supported_color_modes">>, <<"color_temp">>, <<"rgb">>,
               <<"hs">>, <<"xy">>, <<"command_on_template">>, <<"command_off_template">>,
               <<"state_template">>, <<"brightness_template">>, <<"red_template">>,
               <<"green_template">>, <<"blue_template">>, <<"color_temp_template">>,
               <<"effect_template">>, <<"optimistic">>]).

%% ---------------------------------------------------------------------------
%% Config
%% ---------------------------------------------------------------------------

%% @doc The HA keys a light config may have (full names).
-spec config_keys() -> [binary()].
config_keys() -> ?KEYS.

%% @doc Reads a light config: a map with HA's full key names.
-spec config(#{binary() => evatar_json:json()}) -> {ok, light()} | {error, binary()}.
config(C) when is_map(C) ->
    try
        {ok, light(C)}
    catch
        throw:{light_error, Message} -> {error, iolist_to_binary(Message)}
    end;
config(_) ->
    {error, <<"a light config must be a JSON object">>}.

light(C) ->
    Schema = case str(<<"schema">>, C, <<"default">>) of
                 <<"default">> -> default;
                 <<"basic">> -> default;
                 <<"json">> -> json;
                 <<"template">> -> template;
                 Other -> fail(["light schema ", Other, " is not default, json or template"])
             end,
    Kelvin = maps:get(<<"color_temp_kelvin">>, C, false) =:= true,
    {Mireds, Kelvins} = mireds(C),
    Base = #{schema => Schema,
             command_topic => topic(<<"command_topic">>, C, required),
             state_topic => case maps:get(<<"optimistic">>, C, false) of
                                true -> undefined;
                                _ -> topic(<<"state_topic">>, C, optional)
                            end,
             on => str(<<"payload_on">>, C, <<"ON">>),
             off => str(<<"payload_off">>, C, <<"OFF">>),
             on_command_type => case str(<<"on_command_type">>, C, <<"last">>) of
                                    <<"last">> -> last;
                                    <<"first">> -> first;
                                    <<"brightness">> -> brightness;
                                    T -> fail(["on_command_type ", T, " is not last, first or brightness"])
                                end,
             scale => scale(C),
             kelvin => Kelvin,
             mireds => Mireds,
             kelvins => Kelvins,
             effects => [E || E <- list(<<"effect_list">>, C), is_binary(E)]
                 ++ [evatar_json:to_text(E) || E <- list(<<"effect_list">>, C), is_number(E)],
             topics => #{},
             templates => #{}},
    schema(Schema, C, Base).

schema(default, C, L) ->
    Features = [brightness, rgb, hs, xy, color_temp, effect],
    Topics = maps:from_list(
               [{F, {topic(<<(atom_to_binary(F))/binary, "_command_topic">>, C, optional),
                     topic(<<(atom_to_binary(F))/binary, "_state_topic">>, C, optional)}}
                || F <- Features]),
    Templates = templates(C, [{state, <<"state_value_template">>}]
                          ++ lists:append([[{{command, F}, <<(atom_to_binary(F))/binary, "_command_template">>},
                                            {{value, F}, <<(atom_to_binary(F))/binary, "_value_template">>}]
                                           || F <- Features])),
    Supported = [F || F <- Features, element(1, maps:get(F, Topics)) =/= undefined],
    L#{features => Supported, transition => false, topics => Topics, templates => Templates};
schema(json, C, L) ->
    Modes = [M || M <- list(<<"supported_color_modes">>, C), is_binary(M)],
    Legacy = fun(K) -> maps:get(K, C, false) =:= true end,
    Colour = [F || {F, Mode} <- [{rgb, <<"rgb">>}, {hs, <<"hs">>}, {xy, <<"xy">>}],
                   lists:member(Mode, Modes) orelse Legacy(Mode)],
    Temp = [color_temp || lists:member(<<"color_temp">>, Modes) orelse Legacy(<<"color_temp">>)],
    Brightness = [brightness || Legacy(<<"brightness">>)
                                    orelse [M || M <- Modes, M =/= <<"onoff">>] =/= []],
    Effect = [effect || Legacy(<<"effect">>)],
    L#{features => Brightness ++ Colour ++ Temp ++ Effect, transition => true};
schema(template, C, L) ->
    Templates = templates(C, [{on, <<"command_on_template">>}, {off, <<"command_off_template">>},
                              {state, <<"state_template">>}, {brightness, <<"brightness_template">>},
                              {red, <<"red_template">>}, {green, <<"green_template">>},
                              {blue, <<"blue_template">>}, {color_temp, <<"color_temp_template">>},
                              {effect, <<"effect_template">>}]),
    maps:is_key(on, Templates) orelse fail("a template light needs command_on_template"),
    maps:is_key(off, Templates) orelse fail("a template light needs command_off_template"),
    Has = fun(K) -> maps:is_key(K, Templates) end,
    Features = [brightness || Has(brightness)]
        ++ [F || F <- [rgb, hs], Has(red) andalso Has(green) andalso Has(blue)]
        ++ [color_temp || Has(color_temp)]
        ++ [effect || maps:get(effects, L) =/= [] orelse Has(effect)],
    L#{features => Features, transition => true, templates => Templates}.

templates(C, Keys) ->
    maps:from_list([{K, template(Name, T)} || {K, Name} <- Keys, T <- [maps:get(Name, C, undefined)],
                                              T =/= undefined]).

template(Name, T) when is_binary(T) ->
    case mqtt_avatar_template:parse(T) of
        {ok, P} -> P;
        {error, M} -> fail([Name, ": ", M])
    end;
template(Name, _) ->
    fail([Name, " is not a string"]).

mireds(C) ->
    Num = fun(K, D) -> case maps:get(K, C, D) of
                           N when is_number(N), N > 0, N < 1000000 -> N;
                           _ -> fail([K, " must be a positive number"])
                       end
          end,
    %% The range in the unit the config gives it, converted to the other.
    case maps:is_key(<<"min_kelvin">>, C) orelse maps:is_key(<<"max_kelvin">>, C) of
        true ->
            {MinK, MaxK} = {round(Num(<<"min_kelvin">>, 2000)), round(Num(<<"max_kelvin">>, 6535))},
            MinK =< MaxK orelse fail("the colour temperature range is empty (min above max)"),
            {{max(1, round(1000000 / MaxK)), max(1, round(1000000 / MinK))}, {MinK, MaxK}};
        false ->
            {Min, Max} = {round(Num(<<"min_mireds">>, 153)), round(Num(<<"max_mireds">>, 500))},
            Min =< Max orelse fail("the colour temperature range is empty (min above max)"),
            {{max(1, Min), max(1, Max)}, {max(1, ceil(1000000 / Max)), max(1, floor(1000000 / max(1, Min)))}}
    end.

scale(C) ->
    case maps:get(<<"brightness_scale">>, C, 255) of
        N when is_integer(N), N > 0, N =< 65535 -> N;
        _ -> fail("brightness_scale must be an integer from 1 to 65535")
    end.

topic(Key, C, Need) ->
    case maps:get(Key, C, undefined) of
        undefined when Need =:= required -> fail(["a light needs ", Key]);
        undefined -> undefined;
        T when is_binary(T), T =/= <<>> ->
            binary:match(T, [<<"+">>, <<"#">>, <<0>>]) =:= nomatch
                orelse fail([Key, " has a wildcard"]),
            T;
        _ -> fail([Key, " must be a non-empty string"])
    end.

str(Key, C, Default) ->
    case maps:get(Key, C, Default) of
        V when is_binary(V) -> V;
        V when is_integer(V) -> integer_to_binary(V);
        true -> <<"true">>;
        false -> <<"false">>;
        _ -> fail([Key, " must be a string"])
    end.

list(Key, C) ->
    case maps:get(Key, C, []) of
        L when is_list(L) -> L;
        _ -> fail([Key, " must be a list"])
    end.

%% @doc The BIL capabilities of a light's TurnLightOn service.
-spec capabilities(light()) -> [bil:parameter()].
capabilities(#{features := F, transition := T}) ->
    [{<<"Light">>, <<"yes">>}]
        ++ [{<<"Brightness">>, <<"yes">>} || lists:member(brightness, F)]
        ++ [{<<"ColorRGB">>, <<"yes">>} || colour(F) =/= []]
        ++ [{<<"ColorHS">>, <<"yes">>} || colour(F) =/= []]
        ++ [{<<"ColorXY">>, <<"yes">>} || colour(F) =/= []]
        ++ [{P, <<"yes">>} || lists:member(color_temp, F), P <- [<<"ColorTemp">>, <<"ColorTempKelvin">>]]
        ++ [{<<"Effect">>, <<"yes">>} || lists:member(effect, F)]
        ++ [{<<"Transition">>, <<"yes">>} || T].

colour(F) -> [C || C <- F, lists:member(C, [rgb, hs, xy])].

%% @doc Every topic the light's state arrives on.
-spec state_topics(light()) -> [binary()].
state_topics(#{schema := default, state_topic := S, topics := Ts}) ->
    lists:usort([T || T <- [S | [ST || {_, ST} <- maps:values(Ts)]], T =/= undefined]);
state_topics(#{state_topic := undefined}) -> [];
state_topics(#{state_topic := S}) -> [S].

%% ---------------------------------------------------------------------------
%% zigbee2mqtt
%% ---------------------------------------------------------------------------

%% @doc The JSON-schema config of a zigbee2mqtt `light' expose (its
%% features `state', `brightness', `color_temp', `color_xy', `color_hs'),
%% with the device's `effect' enum expose when it has one.
-spec from_z2m(binary(), map(), [map()]) -> #{binary() => evatar_json:json()}.
from_z2m(Topic, #{<<"features">> := Features}, Exposes) ->
    Names = [N || #{<<"name">> := N} <- Features, is_binary(N)],
    Modes = [M || {Name, M} <- [{<<"color_xy">>, <<"xy">>}, {<<"color_hs">>, <<"hs">>},
                                {<<"color_temp">>, <<"color_temp">>}],
                  lists:member(Name, Names)],
    Brightness = [B || #{<<"name">> := <<"brightness">>} = B <- Features],
    Temp = [T || #{<<"name">> := <<"color_temp">>} = T <- Features],
    Effects = lists:append([[V || V <- Vs, is_binary(V)]
                            || #{<<"type">> := <<"enum">>, <<"property">> := <<"effect">>,
                                 <<"values">> := Vs} <- Exposes, is_list(Vs)]),
    maps:from_list(
      [{<<"schema">>, <<"json">>}, {<<"command_topic">>, <<Topic/binary, "/set">>},
       {<<"state_topic">>, Topic},
       {<<"supported_color_modes">>, case {Modes, Brightness} of
                                         {[], []} -> [<<"onoff">>];
                                         {[], _} -> [<<"brightness">>];
                                         _ -> Modes
                                     end}]
      ++ [{<<"brightness_scale">>, Max} || #{<<"value_max">> := Max} <- Brightness, is_integer(Max),
                                             Max > 0]
      ++ [{<<"min_mireds">>, Min} || #{<<"value_min">> := Min} <- Temp, is_integer(Min), Min > 0]
      ++ [{<<"max_mireds">>, Max} || #{<<"value_max">> := Max} <- Temp, is_integer(Max), Max > 0]
      ++ [{<<"effect">>, true} || Effects =/= []]
      ++ [{<<"effect_list">>, Effects} || Effects =/= []]);
from_z2m(Topic, _Expose, Exposes) ->
    from_z2m(Topic, #{<<"features">> => []}, Exposes).

%% ---------------------------------------------------------------------------
%% Commands
%% ---------------------------------------------------------------------------

%% @doc The publishes for TurnLightOn (`on') or TurnLightOff (`off') with the
%% request's parameters, and what confirms them; `{error, Message}' names
%% a parameter that is malformed, out of range or not supported.
-spec command(light(), on | off, [bil:parameter()]) ->
          {ok, [{binary(), binary()}], wait()} | {error, binary()}.
command(L, OnOff, Params) ->
    try
        Req = request(L, OnOff, Params),
        Publishes = publishes(L, OnOff, Req),
        Assumed = assumed(OnOff, Req),
        {ok, Publishes, #{state => atom_to_binary(OnOff), topics => wait_topics(L, OnOff, Req),
                          assumed => Assumed}}
    catch
        throw:{light_error, Message} -> {error, iolist_to_binary(Message)}
    end.

%% @doc The light's main command topic (its identity within a component).
-spec command_topic(light()) -> binary().
command_topic(#{command_topic := T}) -> T.

%% @doc True for a light without a state topic: a command is done once the
%% broker has it, and the light is assumed to be as asked.
-spec optimistic(light()) -> boolean().
optimistic(#{state_topic := S}) -> S =:= undefined.

%% In the default schema each publish is answered on its feature's state
%% topic (several features may share one, as Tasmota's RESULT): one state
%% message per publish, so that the feedback has every value asked for.
wait_topics(#{schema := default, topics := Ts, state_topic := S, on_command_type := Type} = L,
            on, Req) ->
    Features = [brightness || maps:is_key(brightness, Req) orelse Type =:= brightness]
        ++ [element(1, convert(C, colour(maps:get(features, L)))) || {ok, C} <- [maps:find(color, Req)]]
        ++ [F || F <- [color_temp, effect], maps:is_key(F, Req)],
    [T || F <- Features, {_, T} <- [maps:get(F, Ts)], T =/= undefined]
        ++ [S || Type =/= brightness];
wait_topics(#{state_topic := S}, _OnOff, _Req) ->
    [S].

assumed(OnOff, Req) ->
    S0 = #{<<"Light">> => atom_to_binary(OnOff)},
    S1 = case maps:find(brightness, Req) of
             {ok, B} -> S0#{<<"Brightness">> => integer_to_binary(round(B))};
             error -> S0
         end,
    S2 = case maps:find(color, Req) of
             {ok, C} -> put_colour(C, S1);
             error -> S1
         end,
    S3 = case maps:find(color_temp, Req) of
             {ok, M} -> put_temp(M, S2);
             error -> S2
         end,
    case maps:find(effect, Req) of
        {ok, E} -> S3#{<<"Effect">> => E};
        error -> S3
    end.

%% @doc True when the light's state and the topics heard since the command
%% satisfy what it waits for.
-spec satisfied(wait(), state(), [binary()]) -> boolean().
satisfied(#{state := On, topics := Topics}, State, Heard) ->
    maps:get(<<"Light">>, State, undefined) =:= On andalso Topics -- Heard =:= [].

%% Validated request values, in device-independent units:
%% brightness 0..100, color {rgb|hs|xy, Value}, mireds, effect, transition.
request(L, OnOff, Params) ->
    #{features := F, transition := T} = L,
    Given = [{N, utf8_trim(N, V)} || {N, V} <- Params, is_binary(V),
                                    lists:member(N, [<<"Brightness">>, <<"ColorRGB">>, <<"ColorHS">>,
                                                     <<"ColorXY">>, <<"ColorTemp">>,
                                                     <<"ColorTempKelvin">>, <<"Effect">>,
                                                     <<"Transition">>])],
    OffOk = [<<"Transition">>],
    [fail(["TurnLightOff takes only Transition, not ", N]) || OnOff =:= off, {N, _} <- Given,
                                                              not lists:member(N, OffOk)],
    ColourGiven = [N || {N, _} <- Given, lists:member(N, [<<"ColorRGB">>, <<"ColorHS">>, <<"ColorXY">>,
                                                         <<"ColorTemp">>, <<"ColorTempKelvin">>])],
    length(ColourGiven) =< 1
        orelse fail(["give one of ColorRGB, ColorHS, ColorXY, ColorTemp, ColorTempKelvin, not ",
                     lists:join(" and ", ColourGiven)]),
    maps:from_list([value(N, V, L, F, T) || {N, V} <- Given]).

value(<<"Brightness">> = N, V, _L, F, _T) ->
    need(brightness, F, N, "brightness"),
    {brightness, number(N, V, 0, 100)};
value(<<"ColorRGB">> = N, V, _L, F, _T) ->
    colour(F) =/= [] orelse fail([N, ": this light has no colour"]),
    Rgb = case V of
              <<"#", Hex/binary>> when byte_size(Hex) =:= 6 ->
                  try [binary_to_integer(binary:part(Hex, I, 2), 16) || I <- [0, 2, 4]]
                  catch error:badarg -> fail([N, " must be r,g,b (0..255 each) or #RRGGBB, got ", V])
                  end;
              _ -> [round(X) || X <- numbers(N, V, 3, "r,g,b (0..255 each) or #RRGGBB", [{0, 255}, {0, 255}, {0, 255}])]
          end,
    {color, {rgb, list_to_tuple(Rgb)}};
value(<<"ColorHS">> = N, V, _L, F, _T) ->
    colour(F) =/= [] orelse fail([N, ": this light has no colour"]),
    [H, S] = numbers(N, V, 2, "hue,saturation (0..360, 0..100)", [{0, 360}, {0, 100}]),
    {color, {hs, {float(H), float(S)}}};
value(<<"ColorXY">> = N, V, _L, F, _T) ->
    colour(F) =/= [] orelse fail([N, ": this light has no colour"]),
    [X, Y] = numbers(N, V, 2, "x,y (0..1 each)", [{0, 1}, {0, 1}]),
    {color, {xy, {float(X), float(Y)}}};
value(<<"ColorTemp">> = N, V, #{mireds := {Min, Max}}, F, _T) ->
    need(color_temp, F, N, "colour temperature"),
    {color_temp, round(number(N, V, Min, Max))};
value(<<"ColorTempKelvin">> = N, V, #{mireds := {Min, Max}, kelvins := {MinK, MaxK}}, F, _T) ->
    need(color_temp, F, N, "colour temperature"),
    K = number(N, V, MinK, MaxK),
    {color_temp, min(Max, max(Min, round(1000000 / K)))};
value(<<"Effect">> = N, V, #{effects := Effects}, F, _T) ->
    need(effect, F, N, "effects"),
    V =/= <<>> orelse fail([N, " is empty"]),
    Effects =:= [] orelse lists:member(V, Effects)
        orelse fail([N, " ", V, " is not one of this light's effects: ", lists:join(", ", Effects)]),
    {effect, V};
value(<<"Transition">> = N, V, _L, _F, T) ->
    T orelse fail([N, ": this light's schema (default) has no transition"]),
    {transition, number(N, V, 0, ?MAX_TRANSITION)}.

utf8_trim(N, V) ->
    case unicode:characters_to_binary(V) of
        V -> string:trim(V);
        _ -> fail([N, " is not UTF-8 text"])
    end.

need(Feature, F, N, What) ->
    lists:member(Feature, F) orelse fail([N, ": this light has no ", What]).

number(N, V, Min, Max) ->
    case to_number(V) of
        {ok, X} when X >= Min, X =< Max -> X;
        _ -> fail([N, " must be a number from ", num(Min), " to ", num(Max), ", got ", printable(V)])
    end.

numbers(N, V, Count, Form, Ranges) ->
    Parts = [string:trim(P) || P <- binary:split(V, <<",">>, [global])],
    Nums = [to_number(P) || P <- Parts],
    case length(Parts) =:= Count andalso lists:all(fun({ok, _}) -> true; (_) -> false end, Nums) of
        true ->
            Xs = [X || {ok, X} <- Nums],
            lists:all(fun({X, {Lo, Hi}}) -> X >= Lo andalso X =< Hi end, lists:zip(Xs, Ranges))
                orelse fail([N, " must be ", Form, ", got ", printable(V)]),
            Xs;
        false ->
            fail([N, " must be ", Form, ", got ", printable(V)])
    end.

to_number(V) ->
    case evatar_json:decode(V) of
        {ok, X} when is_number(X) -> {ok, X};
        _ -> error
    end.

publishes(#{schema := json} = L, OnOff, Req) ->
    #{command_topic := T, scale := Scale, features := F, kelvin := K} = L,
    State = case OnOff of on -> <<"ON">>; off -> <<"OFF">> end,
    Fields = [{<<"state">>, State}]
        ++ [{<<"brightness">>, device_brightness(B, Scale)} || {ok, B} <- [maps:find(brightness, Req)]]
        ++ [{<<"color">>, json_colour(C, colour(F))} || {ok, C} <- [maps:find(color, Req)]]
        ++ [{<<"color_temp">>, temp_out(M, K)} || {ok, M} <- [maps:find(color_temp, Req)]]
        ++ [{<<"effect">>, E} || {ok, E} <- [maps:find(effect, Req)]]
        ++ [{<<"transition">>, Tr} || {ok, Tr} <- [maps:find(transition, Req)]],
    [{T, evatar_json:encode(maps:from_list(Fields))}];
publishes(#{schema := template} = L, OnOff, Req) ->
    #{command_topic := T, scale := Scale, templates := Tpls, kelvin := K} = L,
    Vars = maps:from_list(
             [{<<"state">>, atom_to_binary(OnOff)}]
             ++ [{<<"brightness">>, device_brightness(B, Scale)} || {ok, B} <- [maps:find(brightness, Req)]]
             ++ lists:append([template_colour(C) || {ok, C} <- [maps:find(color, Req)]])
             ++ [{<<"color_temp">>, temp_out(M, K)} || {ok, M} <- [maps:find(color_temp, Req)]]
             ++ [{<<"effect">>, E} || {ok, E} <- [maps:find(effect, Req)]]
             ++ [{<<"transition">>, Tr} || {ok, Tr} <- [maps:find(transition, Req)]]),
    [{T, render(maps:get(OnOff, Tpls), Vars, command_template)}];
publishes(#{schema := default} = L, off, _Req) ->
    [{maps:get(command_topic, L), maps:get(off, L)}];
publishes(#{schema := default} = L, on, Req) ->
    #{command_topic := T, on := On, on_command_type := Type, scale := Scale, topics := Topics,
      features := F, templates := Tpls, kelvin := K} = L,
    Req1 = case Type =:= brightness andalso not maps:is_key(brightness, Req) of
               true -> Req#{brightness => 100};
               false -> Req
           end,
    Feature = fun(Name, Value, Default) ->
                      {CT, _} = maps:get(Name, Topics),
                      Payload = case maps:find({command, Name}, Tpls) of
                                    {ok, Tpl} -> render(Tpl, Value, <<(atom_to_binary(Name))/binary,
                                                                       "_command_template">>);
                                    error -> Default
                                end,
                      {CT, Payload}
              end,
    Parts = [Feature(brightness, #{<<"value">> => device_brightness(B, Scale)},
                     integer_to_binary(device_brightness(B, Scale)))
             || {ok, B} <- [maps:find(brightness, Req1)]]
        ++ [default_colour(Feature, C, colour(F)) || {ok, C} <- [maps:find(color, Req1)]]
        ++ [Feature(color_temp, #{<<"value">> => temp_out(M, K)}, text(temp_out(M, K)))
            || {ok, M} <- [maps:find(color_temp, Req1)]]
        ++ [Feature(effect, #{<<"value">> => E}, E) || {ok, E} <- [maps:find(effect, Req1)]],
    case Type of
        last -> Parts ++ [{T, On}];
        first -> [{T, On} | Parts];
        brightness -> Parts
    end.

device_brightness(Pct, Scale) -> round(Pct * Scale / 100).

temp_out(Mireds, true) -> round(1000000 / Mireds);
temp_out(Mireds, false) -> Mireds.

%% The colour in the form the light takes: the one given when it takes it,
%% else converted to the first it takes.
convert({Form, _} = C, Supported) ->
    case lists:member(Form, Supported) of
        true -> C;
        false -> to(hd(Supported), C)
    end.

json_colour(C, Supported) ->
    case convert(C, Supported) of
        {rgb, {R, G, B}} -> #{<<"r">> => R, <<"g">> => G, <<"b">> => B};
        {hs, {H, S}} -> #{<<"h">> => round_to(H, 2), <<"s">> => round_to(S, 2)};
        {xy, {X, Y}} -> #{<<"x">> => round_to(X, 4), <<"y">> => round_to(Y, 4)}
    end.

template_colour(C) ->
    {rgb, {R, G, B}} = to(rgb, C),
    {hs, {H, S}} = to(hs, C),
    [{<<"red">>, R}, {<<"green">>, G}, {<<"blue">>, B}, {<<"hue">>, round_to(H, 2)},
     {<<"sat">>, round_to(S, 2)}].

default_colour(Feature, C, Supported) ->
    case convert(C, Supported) of
        {rgb, {R, G, B}} ->
            Feature(rgb, #{<<"red">> => R, <<"green">> => G, <<"blue">> => B},
                    iolist_to_binary(lists:join(",", [integer_to_binary(X) || X <- [R, G, B]])));
        {hs, {H, S}} ->
            Feature(hs, #{<<"hue">> => round_to(H, 2), <<"sat">> => round_to(S, 2)},
                    <<(text(round_to(H, 2)))/binary, ",", (text(round_to(S, 2)))/binary>>);
        {xy, {X, Y}} ->
            Feature(xy, #{<<"x">> => round_to(X, 4), <<"y">> => round_to(Y, 4)},
                    <<(text(round_to(X, 4)))/binary, ",", (text(round_to(Y, 4)))/binary>>)
    end.

render(Tpl, Vars, Name) ->
    case mqtt_avatar_template:render(Tpl, Vars) of
        {ok, Out} -> Out;
        {error, M} -> fail([Name, ": ", M])
    end.

%% ---------------------------------------------------------------------------
%% Colour conversions (sRGB, D65)
%% ---------------------------------------------------------------------------

to(Form, {Form, _} = C) -> C;
to(rgb, {hs, {H, S}}) -> {rgb, hs_to_rgb(H, S)};
to(rgb, {xy, {X, Y}}) -> {rgb, xy_to_rgb(X, Y)};
to(hs, {rgb, RGB}) -> {hs, rgb_to_hs(RGB)};
to(xy, {rgb, RGB}) -> {xy, rgb_to_xy(RGB)};
to(Form, C) -> to(Form, to(rgb, C)).

hs_to_rgb(H, S) ->
    Sat = S / 100,
    Hh = (H - 360 * floor(H / 360)) / 60,
    I = floor(Hh),
    Fr = Hh - I,
    P = 1 - Sat,
    Q = 1 - Sat * Fr,
    T = 1 - Sat * (1 - Fr),
    {R, G, B} = case I rem 6 of
                    0 -> {1, T, P};
                    1 -> {Q, 1, P};
                    2 -> {P, 1, T};
                    3 -> {P, Q, 1};
                    4 -> {T, P, 1};
                    5 -> {1, P, Q}
                end,
    {round(R * 255), round(G * 255), round(B * 255)}.

rgb_to_hs({R0, G0, B0}) ->
    [R, G, B] = [X / 255 || X <- [R0, G0, B0]],
    Max = lists:max([R, G, B]),
    Min = lists:min([R, G, B]),
    D = Max - Min,
    H = if
            D == 0 -> 0.0;
            Max == R -> 60 * fmod((G - B) / D, 6);
            Max == G -> 60 * ((B - R) / D + 2);
            true -> 60 * ((R - G) / D + 4)
        end,
    S = case Max == 0 of
            true -> 0.0;
            false -> D / Max * 100
        end,
    {float(H), float(S)}.

fmod(A, B) -> A - B * floor(A / B).

rgb_to_xy({R0, G0, B0}) ->
    [R, G, B] = [linear(X / 255) || X <- [R0, G0, B0]],
    X = R * 0.4124 + G * 0.3576 + B * 0.1805,
    Y = R * 0.2126 + G * 0.7152 + B * 0.0722,
    Z = R * 0.0193 + G * 0.1192 + B * 0.9505,
    case X + Y + Z of
        Sum when Sum == 0 -> {0.3127, 0.329};
        Sum -> {X / Sum, Y / Sum}
    end.

xy_to_rgb(X, Y0) ->
    Y = max(Y0, 0.0001),
    Xc = X / Y,
    Zc = (1 - X - Y) / Y,
    R = Xc * 3.2406 - 1.5372 - Zc * 0.4986,
    G = -Xc * 0.9689 + 1.8758 + Zc * 0.0415,
    B = Xc * 0.0557 - 0.2040 + Zc * 1.0570,
    Gamma = [gamma(max(0.0, C)) || C <- [R, G, B]],
    Max = max(lists:max(Gamma), 1.0e-9),
    list_to_tuple([min(255, round(C / Max * 255)) || C <- Gamma]).

linear(C) when C =< 0.04045 -> C / 12.92;
linear(C) -> math:pow((C + 0.055) / 1.055, 2.4).

gamma(C) when C =< 0.0031308 -> 12.92 * C;
gamma(C) -> 1.055 * math:pow(C, 1 / 2.4) - 0.055.

round_to(X, Digits) ->
    F = math:pow(10, Digits),
    round(X * F) / F.

%% ---------------------------------------------------------------------------
%% State
%% ---------------------------------------------------------------------------

%% @doc Folds one message on `Topic' into the light's state. `{error,
%% Message}' for a payload that cannot be read (the state is then kept).
-spec read(light(), binary(), binary(), state()) -> {ok, state()} | {error, binary()}.
read(L, Topic, Payload, State) ->
    try
        {ok, read1(L, Topic, Payload, State)}
    catch
        throw:{light_error, Message} -> {error, iolist_to_binary(Message)}
    end.

read1(#{schema := json, state_topic := Topic} = L, Topic, Payload, State) ->
    J = case evatar_json:decode(Payload) of
            {ok, M} when is_map(M) -> M;
            {ok, _} -> fail("the light's state is not a JSON object");
            {error, R} -> fail(evatar_json:format_error(R))
        end,
    #{scale := Scale, kelvin := K} = L,
    S1 = case maps:get(<<"state">>, J, undefined) of
             undefined -> State;
             null -> maps:remove(<<"Light">>, State);
             V -> put_state(on_off(V, <<"ON">>, <<"OFF">>), State)
         end,
    S2 = case maps:get(<<"brightness">>, J, undefined) of
             B when is_number(B) -> S1#{<<"Brightness">> => pct(B, Scale)};
             _ -> S1
         end,
    S3 = case maps:get(<<"color_temp">>, J, undefined) of
             T when is_number(T), T > 0 -> put_temp(temp_in(T, K), S2);
             _ -> S2
         end,
    S4 = case maps:get(<<"color">>, J, undefined) of
             C when is_map(C) -> put_json_colour(C, S3);
             _ -> S3
         end,
    case maps:get(<<"effect">>, J, undefined) of
        E when is_binary(E) -> S4#{<<"Effect">> => E};
        _ -> S4
    end;
read1(#{schema := template, state_topic := Topic} = L, Topic, Payload, State) ->
    #{templates := Tpls, scale := Scale, kelvin := K} = L,
    Vars = mqtt_avatar_template:payload_vars(Payload),
    Get = fun(Key) ->
                  case maps:find(Key, Tpls) of
                      {ok, Tpl} -> string:trim(render(Tpl, Vars, template_name(Key)));
                      error -> <<>>
                  end
          end,
    S1 = case Get(state) of
             <<>> -> State;
             V -> put_state(on_off(V, <<"on">>, <<"off">>), State)
         end,
    S2 = case to_number(Get(brightness)) of
             {ok, B} -> S1#{<<"Brightness">> => pct(B, Scale)};
             error -> S1
         end,
    S3 = case [to_number(Get(X)) || X <- [red, green, blue]] of
             [{ok, R}, {ok, G}, {ok, Bl}] -> put_colour({rgb, {round(R), round(G), round(Bl)}}, S2);
             _ -> S2
         end,
    S4 = case to_number(Get(color_temp)) of
             {ok, T} when T > 0 -> put_temp(temp_in(T, K), S3);
             _ -> S3
         end,
    case Get(effect) of
        <<>> -> S4;
        E -> S4#{<<"Effect">> => E}
    end;
read1(#{schema := default} = L, Topic, Payload, State) ->
    #{state_topic := ST, topics := Topics, templates := Tpls, on := On, off := Off, scale := Scale,
      kelvin := K} = L,
    Vars = mqtt_avatar_template:payload_vars(Payload),
    Value = fun(Key) ->
                    case maps:find(Key, Tpls) of
                        {ok, Tpl} -> string:trim(render(Tpl, Vars, template_name(Key)));
                        error -> string:trim(text_payload(Payload))
                    end
            end,
    S1 = case ST =:= Topic of
             true ->
                 case Value(state) of
                     <<>> -> State;
                     <<"None">> -> maps:remove(<<"Light">>, State);
                     V -> put_state(on_off(V, On, Off), State)
                 end;
             false -> State
         end,
    lists:foldl(fun(F, Acc) ->
                        case maps:get(F, Topics) of
                            {_, Topic} -> default_feature(F, Value({value, F}), Scale, K, Acc);
                            _ -> Acc
                        end
                end, S1, [brightness, rgb, hs, xy, color_temp, effect]);
read1(_L, _Topic, _Payload, State) ->
    State.

default_feature(_F, <<>>, _Scale, _K, S) ->
    S;
default_feature(brightness, V, Scale, _K, S) ->
    case to_number(V) of
        {ok, B} -> S#{<<"Brightness">> => pct(B, Scale)};
        error -> fail(["brightness ", printable(V), " is not a number"])
    end;
default_feature(effect, V, _Scale, _K, S) ->
    S#{<<"Effect">> => V};
default_feature(color_temp, V, _Scale, K, S) ->
    case to_number(V) of
        {ok, T} when T > 0 -> put_temp(temp_in(T, K), S);
        _ -> fail(["colour temperature ", printable(V), " is not a positive number"])
    end;
default_feature(Form, V, _Scale, _K, S) ->
    N = case Form of rgb -> 3; _ -> 2 end,
    case [to_number(string:trim(P)) || P <- binary:split(V, <<",">>, [global])] of
        Nums when length(Nums) =:= N ->
            case [X || {ok, X} <- Nums] of
                Xs when length(Xs) =:= N ->
                    C = case {Form, Xs} of
                            {rgb, [R, G, B]} -> {rgb, {round(R), round(G), round(B)}};
                            {hs, [H, Sa]} -> {hs, {float(H), float(Sa)}};
                            {xy, [X, Y]} -> {xy, {float(X), float(Y)}}
                        end,
                    put_colour(C, S);
                _ -> fail([atom_to_binary(Form), " colour ", printable(V), " is not numbers"])
            end;
        _ -> fail([atom_to_binary(Form), " colour ", printable(V), " does not have ",
                   integer_to_list(N), " numbers"])
    end.

template_name(state) -> <<"state template">>;
template_name({value, F}) -> <<(atom_to_binary(F))/binary, "_value_template">>;
template_name(K) -> <<(atom_to_binary(K))/binary, "_template">>.

text_payload(Payload) ->
    case unicode:characters_to_binary(Payload) of
        Payload -> Payload;
        _ -> fail("the payload is not UTF-8 text")
    end.

on_off(V, _On, _Off) when not is_binary(V) ->
    fail(["state ", to_text(V), " is not text"]);
on_off(V, On, Off) ->
    X = string:casefold(string:trim(V)),
    case {X =:= string:casefold(On), X =:= string:casefold(Off)} of
        {true, _} -> <<"on">>;
        {_, true} -> <<"off">>;
        _ -> fail(["state ", printable(V), " is neither ", On, " nor ", Off])
    end.

put_state(V, S) -> S#{<<"Light">> => V}.

%% Values from the device are clamped before any arithmetic (no overflow).
pct(B, Scale) -> integer_to_binary(round(max(0, min(B, Scale)) * 100 / Scale)).

temp_in(T, true) -> 1000000 / max(1, min(T, 1000000));
temp_in(T, false) -> max(1, min(T, 1000000)).

put_temp(Mireds, S) ->
    M = round(Mireds),
    S#{<<"ColorTemp">> => integer_to_binary(M),
       <<"ColorTempKelvin">> => integer_to_binary(round(1000000 / max(1, M)))}.

put_json_colour(C, S) ->
    Get = fun(Keys) -> [V || K <- Keys, V <- [maps:get(K, C, undefined)], is_number(V)] end,
    case {Get([<<"r">>, <<"g">>, <<"b">>]), Get([<<"h">>, <<"s">>]), Get([<<"hue">>, <<"saturation">>]),
          Get([<<"x">>, <<"y">>])} of
        {[R, G, B], _, _, _} -> put_colour({rgb, {round(R), round(G), round(B)}}, S);
        {_, [H, Sa], _, _} -> put_colour({hs, {float(H), float(Sa)}}, S);
        {_, _, [H, Sa], _} -> put_colour({hs, {float(H), float(Sa)}}, S);
        {_, _, _, [X, Y]} -> put_colour({xy, {float(X), float(Y)}}, S);
        _ -> S
    end.

%% A colour reported in any form is given in all three.
put_colour(C0, S) ->
    C = clamp(C0),
    {rgb, {R, G, B}} = to(rgb, C),
    {hs, {H, Sa}} = case C of {hs, _} -> C; _ -> to(hs, {rgb, {R, G, B}}) end,
    {xy, {X, Y}} = case C of {xy, _} -> C; _ -> to(xy, {rgb, {R, G, B}}) end,
    S#{<<"ColorRGB">> => iolist_to_binary(lists:join(",", [integer_to_binary(V) || V <- [R, G, B]])),
       <<"ColorHS">> => <<(text(round_to(H, 1)))/binary, ",", (text(round_to(Sa, 1)))/binary>>,
       <<"ColorXY">> => <<(text(round_to(X, 4)))/binary, ",", (text(round_to(Y, 4)))/binary>>}.

clamp({rgb, {R, G, B}}) -> {rgb, {bound(R, 0, 255), bound(G, 0, 255), bound(B, 0, 255)}};
clamp({hs, {H, S}}) -> {hs, {float(bound(H, 0, 360)), float(bound(S, 0, 100))}};
clamp({xy, {X, Y}}) -> {xy, {float(bound(X, 0, 1)), float(bound(Y, 0, 1))}}.

bound(X, Lo, Hi) -> max(Lo, min(Hi, X)).

to_text(V) -> evatar_json:encode(V).

%% @doc The light's state as BIL parameters, in a fixed order.
-spec params(state()) -> [bil:parameter()].
params(State) ->
    [{N, V} || N <- [<<"Light">>, <<"Brightness">>, <<"ColorRGB">>, <<"ColorHS">>, <<"ColorXY">>,
                     <<"ColorTemp">>, <<"ColorTempKelvin">>, <<"Effect">>],
               {ok, V} <- [maps:find(N, State)]].

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

text(N) -> evatar_json:to_text(N).

num(N) -> text(N).

printable(B) when byte_size(B) > 40 -> <<(binary:part(B, 0, 40))/binary, "...">>;
printable(B) -> B.

-spec fail(iodata()) -> no_return().
fail(Message) -> throw({light_error, Message}).

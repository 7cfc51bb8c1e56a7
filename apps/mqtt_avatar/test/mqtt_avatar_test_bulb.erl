%% Test helper: a colour bulb on a real broker (an mqtt_avatar_test_device)
%% that behaves as real ones do in each of Home Assistant's light schemas
%% and as a zigbee2mqtt bulb: it applies every command it understands to
%% its state (power, brightness, colour, colour temperature, effect) and
%% publishes that state, retained.
%%
%% - `json': HA's JSON schema; commands and state are JSON on ~/set, ~/state.
%% - `default': a Tasmota bulb; cmnd/<p>/POWER, Dimmer (0..100), Color2
%%   (r,g,b), CT (mireds), Scheme (effect); every command answered with the
%%   whole state as JSON on stat/<p>/RESULT.
%% - `template': a Shelly-like bulb taking {"turn":"on","brightness":..,
%%   "rgb":[..],"ct":..,"fx":..} and publishing {"ison":..,...}.
%% - `z2m': zigbee2mqtt; JSON commands on <base>/<name>/set (colour as xy or
%%   hue/saturation), the state on <base>/<name>.
-module(mqtt_avatar_test_bulb).

-export([start/3, discovery/3]).

%% @doc Starts a bulb of `Schema' whose topics start with `P'; discovery
%% configs (HA's) go under `<<"ha_", P>>', z2m's device list under `P'.
start(Port, Schema, P) ->
    {Discovery, Commands, State0} = discovery(Schema, P, #{}),
    {ok, Dev} = mqtt_avatar_test_device:start(
                  Port, #{discovery => Discovery, commands => Commands,
                          reply => fun(T, Payload) -> reply(Schema, P, T, Payload) end}),
    [ok = mqtt_avatar_test_device:publish(Dev, T, Pl, true) || {T, Pl} <- State0],
    Dev.

%% @doc The retained discovery messages, the command topics and the first
%% state of a bulb; `Extra' is merged into its HA config.
discovery(json, P, Extra) ->
    Base = <<P/binary, "/bulb">>,
    Config = maps:merge(#{<<"name">> => null, <<"uniq_id">> => <<P/binary, "-json">>, <<"~">> => Base,
                          <<"schema">> => <<"json">>, <<"cmd_t">> => <<"~/set">>, <<"stat_t">> => <<"~/state">>,
                          <<"sup_clrm">> => [<<"rgb">>, <<"color_temp">>], <<"brightness">> => true,
                          <<"effect">> => true, <<"fx_list">> => [<<"rainbow">>, <<"blink">>],
                          <<"min_mirs">> => 153, <<"max_mirs">> => 500,
                          <<"dev">> => device(P, <<"Kitchen Bulb">>, <<"Kitchen">>)}, Extra),
    {[{<<"ha_", P/binary, "/light/", P/binary, "/json/config">>, encode(Config)}],
     [<<Base/binary, "/set">>],
     [{<<Base/binary, "/state">>, <<"{\"state\":\"OFF\"}">>}]};
discovery(default, P, Extra) ->
    Config = maps:merge(#{<<"name">> => null, <<"uniq_id">> => <<P/binary, "-tasmota">>,
                          <<"cmd_t">> => <<"cmnd/", P/binary, "/POWER">>,
                          <<"stat_t">> => <<"stat/", P/binary, "/RESULT">>,
                          <<"stat_val_tpl">> => <<"{{ value_json.POWER }}">>,
                          <<"bri_cmd_t">> => <<"cmnd/", P/binary, "/Dimmer">>,
                          <<"bri_stat_t">> => <<"stat/", P/binary, "/RESULT">>,
                          <<"bri_val_tpl">> => <<"{{ value_json.Dimmer }}">>, <<"bri_scl">> => 100,
                          <<"rgb_cmd_t">> => <<"cmnd/", P/binary, "/Color2">>,
                          <<"rgb_stat_t">> => <<"stat/", P/binary, "/RESULT">>,
                          <<"rgb_val_tpl">> => <<"{{ value_json.Color }}">>,
                          <<"clr_temp_cmd_t">> => <<"cmnd/", P/binary, "/CT">>,
                          <<"clr_temp_stat_t">> => <<"stat/", P/binary, "/RESULT">>,
                          <<"clr_temp_val_tpl">> => <<"{{ value_json.CT }}">>,
                          <<"fx_cmd_t">> => <<"cmnd/", P/binary, "/Scheme">>,
                          <<"fx_cmd_tpl">> => <<"{{ value | upper }}">>,
                          <<"fx_stat_t">> => <<"stat/", P/binary, "/RESULT">>,
                          <<"fx_val_tpl">> => <<"{{ value_json.Scheme | lower }}">>,
                          <<"fx_list">> => [<<"wakeup">>, <<"cycle">>],
                          <<"dev">> => device(P, <<"Hall Bulb">>, <<"Hall">>)}, Extra),
    {[{<<"ha_", P/binary, "/light/", P/binary, "/tasmota/config">>, encode(Config)}],
     [<<"cmnd/", P/binary, "/#">>],
     [{<<"stat/", P/binary, "/RESULT">>, <<"{\"POWER\":\"OFF\",\"Dimmer\":100}">>}]};
discovery(template, P, Extra) ->
    Base = <<P/binary, "/shelly">>,
    On = <<"{\"turn\":\"on\"{% if brightness is defined %},\"brightness\":{{ brightness }}{% endif %}"
           "{% if red is defined %},\"rgb\":[{{ red }},{{ green }},{{ blue }}]{% endif %}"
           "{% if color_temp is defined %},\"ct\":{{ color_temp }}{% endif %}"
           "{% if effect is defined %},\"fx\":\"{{ effect }}\"{% endif %}"
           "{% if transition is defined %},\"transition\":{{ (transition * 1000) | int }}{% endif %}}">>,
    Config = maps:merge(#{<<"name">> => null, <<"uniq_id">> => <<P/binary, "-shelly">>,
                          <<"schema">> => <<"template">>, <<"~">> => Base,
                          <<"cmd_t">> => <<"~/set">>, <<"stat_t">> => <<"~/status">>,
                          <<"cmd_on_tpl">> => On, <<"cmd_off_tpl">> => <<"{\"turn\":\"off\"}">>,
                          <<"stat_tpl">> => <<"{% if value_json.ison %}on{% else %}off{% endif %}">>,
                          <<"bri_tpl">> => <<"{{ value_json.brightness }}">>,
                          <<"r_tpl">> => <<"{{ value_json.rgb[0] }}">>,
                          <<"g_tpl">> => <<"{{ value_json.rgb[1] }}">>,
                          <<"b_tpl">> => <<"{{ value_json.rgb[2] }}">>,
                          <<"clr_temp_tpl">> => <<"{{ value_json.ct }}">>,
                          <<"fx_tpl">> => <<"{{ value_json.fx }}">>,
                          <<"fx_list">> => [<<"candle">>, <<"fire">>],
                          <<"dev">> => device(P, <<"Bedroom Bulb">>, <<"Bedroom">>)}, Extra),
    {[{<<"ha_", P/binary, "/light/", P/binary, "/shelly/config">>, encode(Config)}],
     [<<Base/binary, "/set">>],
     [{<<Base/binary, "/status">>, <<"{\"ison\":false,\"brightness\":255}">>}]};
discovery(z2m, P, _Extra) ->
    Devices = [#{<<"type">> => <<"Router">>, <<"friendly_name">> => <<"garage_bulb">>,
                 <<"ieee_address">> => <<"0x0017880100000001">>,
                 <<"definition">> =>
                     #{<<"model">> => <<"9290022166">>, <<"vendor">> => <<"Philips">>,
                       <<"description">> => <<"Hue white and color ambiance E26/E27">>,
                       <<"exposes">> =>
                           [#{<<"type">> => <<"light">>,
                              <<"features">> =>
                                  [#{<<"type">> => <<"binary">>, <<"name">> => <<"state">>,
                                     <<"property">> => <<"state">>, <<"access">> => 7,
                                     <<"value_on">> => <<"ON">>, <<"value_off">> => <<"OFF">>},
                                   #{<<"type">> => <<"numeric">>, <<"name">> => <<"brightness">>,
                                     <<"property">> => <<"brightness">>, <<"access">> => 7,
                                     <<"value_min">> => 0, <<"value_max">> => 254},
                                   #{<<"type">> => <<"numeric">>, <<"name">> => <<"color_temp">>,
                                     <<"property">> => <<"color_temp">>, <<"access">> => 7,
                                     <<"value_min">> => 153, <<"value_max">> => 500, <<"unit">> => <<"mired">>},
                                   #{<<"type">> => <<"composite">>, <<"name">> => <<"color_xy">>,
                                     <<"property">> => <<"color">>, <<"access">> => 7,
                                     <<"features">> => [#{<<"name">> => <<"x">>, <<"property">> => <<"x">>},
                                                        #{<<"name">> => <<"y">>, <<"property">> => <<"y">>}]},
                                   #{<<"type">> => <<"composite">>, <<"name">> => <<"color_hs">>,
                                     <<"property">> => <<"color">>, <<"access">> => 7}]},
                            #{<<"type">> => <<"enum">>, <<"name">> => <<"effect">>,
                              <<"property">> => <<"effect">>, <<"access">> => 2,
                              <<"values">> => [<<"blink">>, <<"breathe">>, <<"okay">>]}]}}],
    Base = <<"z2m_", P/binary>>,
    {[{<<Base/binary, "/bridge/devices">>, encode(Devices)}],
     [<<Base/binary, "/garage_bulb/set">>],
     [{<<Base/binary, "/garage_bulb">>, <<"{\"state\":\"OFF\",\"brightness\":254}">>}]}.

device(P, Name, Area) ->
    #{<<"ids">> => [<<P/binary, "-", Name/binary>>], <<"name">> => Name, <<"sa">> => Area,
      <<"mdl">> => <<"Bulb">>}.

%% ---------------------------------------------------------------------------
%% The bulb (runs in the device's process: its state is in the process
%% dictionary)
%% ---------------------------------------------------------------------------

state() ->
    case get(bulb) of
        undefined -> #{power => false, brightness => 1.0, color => {rgb, 255, 255, 255},
                       ct => 300, effect => null};
        S -> S
    end.

save(S) -> put(bulb, S), S.

reply(json, P, _T, Payload) ->
    {ok, C} = evatar_json:decode(Payload),
    S = apply_json(C, <<"h">>, <<"s">>, 255),
    [{<<P/binary, "/bulb/state">>, encode(json_state(S, 255, false)), true}];
reply(z2m, P, _T, Payload) ->
    {ok, C} = evatar_json:decode(Payload),
    S = apply_json(C, <<"hue">>, <<"saturation">>, 254),
    [{<<"z2m_", P/binary, "/garage_bulb">>, encode(json_state(S, 254, true)), true}];
reply(default, P, T, Payload) ->
    S0 = state(),
    [_, _, Cmd] = binary:split(T, <<"/">>, [global]),
    S = save(case Cmd of
                 <<"POWER">> -> S0#{power := Payload =:= <<"ON">>};
                 <<"Dimmer">> -> S0#{power := true, brightness := binary_to_integer(Payload) / 100};
                 <<"Color2">> ->
                     [R, G, B] = [binary_to_integer(X) || X <- binary:split(Payload, <<",">>, [global])],
                     S0#{power := true, color := {rgb, R, G, B}};
                 <<"CT">> -> S0#{power := true, ct := binary_to_integer(Payload), color := ct};
                 <<"Scheme">> -> S0#{effect := string:lowercase(Payload)}
             end),
    #{power := On, brightness := Bri, ct := Ct, effect := Fx} = S,
    Colour = case maps:get(color, S) of
                 {rgb, R1, G1, B1} -> [{<<"Color">>, iolist_to_binary(io_lib:format("~b,~b,~b", [R1, G1, B1]))}];
                 _ -> []
             end,
    Result = maps:from_list([{<<"POWER">>, on_off(On)}, {<<"Dimmer">>, round(Bri * 100)}, {<<"CT">>, Ct}]
                            ++ Colour ++ [{<<"Scheme">>, string:uppercase(Fx)} || Fx =/= null]),
    [{<<"stat/", P/binary, "/RESULT">>, encode(Result), false}];
reply(template, P, _T, Payload) ->
    {ok, C} = evatar_json:decode(Payload),
    S0 = state(),
    S = save(maps:fold(fun(<<"turn">>, V, A) -> A#{power := V =:= <<"on">>};
                          (<<"brightness">>, V, A) -> A#{brightness := V / 255};
                          (<<"rgb">>, [R, G, B], A) -> A#{color := {rgb, R, G, B}};
                          (<<"ct">>, V, A) -> A#{ct := V, color := ct};
                          (<<"fx">>, V, A) -> A#{effect := V};
                          (_, _, A) -> A
                       end, S0, C)),
    #{power := On, brightness := Bri, ct := Ct, effect := Fx} = S,
    Rgb = case maps:get(color, S) of
              {rgb, R1, G1, B1} -> [{<<"rgb">>, [R1, G1, B1]}];
              _ -> []
          end,
    State = maps:from_list([{<<"ison">>, On}, {<<"brightness">>, round(Bri * 255)}, {<<"ct">>, Ct}]
                           ++ Rgb ++ [{<<"fx">>, Fx} || Fx =/= null]),
    [{<<P/binary, "/shelly/status">>, encode(State), true}].

apply_json(C, HKey, SKey, Scale) ->
    S0 = state(),
    save(maps:fold(fun(<<"state">>, V, A) -> A#{power := V =:= <<"ON">>};
                      (<<"brightness">>, V, A) -> A#{brightness := V / Scale};
                      (<<"color_temp">>, V, A) -> A#{ct := V, color := ct};
                      (<<"effect">>, V, A) -> A#{effect := V};
                      (<<"color">>, #{<<"r">> := R, <<"g">> := G, <<"b">> := B}, A) ->
                           A#{color := {rgb, R, G, B}};
                      (<<"color">>, #{<<"x">> := X, <<"y">> := Y}, A) -> A#{color := {xy, X, Y}};
                      (<<"color">>, #{HKey := H, SKey := Sa}, A) -> A#{color := {hs, H, Sa}};
                      (<<"color">>, #{<<"h">> := H, <<"s">> := Sa}, A) -> A#{color := {hs, H, Sa}};
                      (_, _, A) -> A
                   end, S0, C)).

%% The state as HA's JSON schema (or zigbee2mqtt, `Z2m') writes it.
json_state(S, Scale, Z2m) ->
    #{power := On, brightness := Bri, ct := Ct, effect := Fx, color := Colour} = S,
    {Mode, Color} = case Colour of
                        ct -> {<<"color_temp">>, []};
                        {rgb, R, G, B} -> {<<"rgb">>, [{<<"color">>, #{<<"r">> => R, <<"g">> => G, <<"b">> => B}}]};
                        {xy, X, Y} -> {<<"xy">>, [{<<"color">>, #{<<"x">> => X, <<"y">> => Y}}]};
                        {hs, H, Sa} when Z2m ->
                            {<<"hs">>, [{<<"color">>, #{<<"hue">> => H, <<"saturation">> => Sa}}]};
                        {hs, H, Sa} -> {<<"hs">>, [{<<"color">>, #{<<"h">> => H, <<"s">> => Sa}}]}
                    end,
    maps:from_list([{<<"state">>, on_off(On)}, {<<"brightness">>, round(Bri * Scale)},
                    {<<"color_mode">>, Mode}, {<<"color_temp">>, Ct}]
                   ++ Color ++ [{<<"effect">>, Fx} || Fx =/= null]).

on_off(true) -> <<"ON">>;
on_off(false) -> <<"OFF">>.

encode(J) -> evatar_json:encode(J).

%% EUnit tests of mqtt_avatar_light, rule by rule: configs of the three
%% schemas, the publishes HA would make, what confirms them, reading
%% states, colour conversions; and a PropEr property that random request
%% parameters and state payloads never raise.
-module(mqtt_avatar_light_tests).

-include_lib("proper/include/proper.hrl").
-include_lib("eunit/include/eunit.hrl").

light(Config) ->
    {ok, L} = mqtt_avatar_light:config(Config),
    L.

json() ->
    light(#{<<"schema">> => <<"json">>, <<"command_topic">> => <<"l/set">>, <<"state_topic">> => <<"l">>,
            <<"supported_color_modes">> => [<<"xy">>, <<"color_temp">>], <<"brightness_scale">> => 254,
            <<"color_temp_kelvin">> => true, <<"min_kelvin">> => 2000, <<"max_kelvin">> => 6500,
            <<"effect">> => true, <<"effect_list">> => [<<"blink">>]}).

default() ->
    light(#{<<"command_topic">> => <<"p">>, <<"state_topic">> => <<"s">>,
            <<"brightness_command_topic">> => <<"b">>, <<"brightness_state_topic">> => <<"bs">>,
            <<"brightness_command_template">> => <<"{{ (value / 2.55) | round | int }}">>,
            <<"hs_command_topic">> => <<"hs">>, <<"hs_state_topic">> => <<"hss">>,
            <<"on_command_type">> => <<"first">>}).

config_test_() ->
    E = fun(C) -> {error, M} = mqtt_avatar_light:config(C), M end,
    [?_assertEqual(<<"a light needs command_topic">>, E(#{})),
     ?_assertEqual(<<"light schema fancy is not default, json or template">>,
                   E(#{<<"schema">> => <<"fancy">>, <<"command_topic">> => <<"x">>})),
     ?_assertEqual(<<"state_topic has a wildcard">>,
                   E(#{<<"command_topic">> => <<"x">>, <<"state_topic">> => <<"a/#">>})),
     ?_assertMatch(<<"a template light needs command_off_template">>,
                   E(#{<<"schema">> => <<"template">>, <<"command_topic">> => <<"x">>,
                       <<"command_on_template">> => <<"on">>})),
     ?_assertMatch(<<"state_template: unsupported filter 'format'", _/binary>>,
                   E(#{<<"schema">> => <<"template">>, <<"command_topic">> => <<"x">>,
                       <<"command_on_template">> => <<"on">>, <<"command_off_template">> => <<"off">>,
                       <<"state_template">> => <<"{{ value | format }}">>})),
     ?_assertEqual(<<"the colour temperature range is empty (min above max)">>,
                   E(#{<<"command_topic">> => <<"x">>, <<"min_mireds">> => 400, <<"max_mireds">> => 200})),
     ?_assertEqual([{<<"Light">>, <<"yes">>}, {<<"Brightness">>, <<"yes">>}, {<<"ColorRGB">>, <<"yes">>},
                    {<<"ColorHS">>, <<"yes">>}, {<<"ColorXY">>, <<"yes">>}, {<<"ColorTemp">>, <<"yes">>},
                    {<<"ColorTempKelvin">>, <<"yes">>}, {<<"Effect">>, <<"yes">>},
                    {<<"Transition">>, <<"yes">>}],
                   mqtt_avatar_light:capabilities(json())),
     ?_assertEqual([{<<"Light">>, <<"yes">>}],
                   mqtt_avatar_light:capabilities(light(#{<<"command_topic">> => <<"x">>})))].

json_command_test_() ->
    C = fun(OnOff, Ps) ->
                {ok, [{<<"l/set">>, P}], W} = mqtt_avatar_light:command(json(), OnOff, Ps),
                {ok, J} = evatar_json:decode(P),
                {J, W}
        end,
    [?_assertMatch({#{<<"state">> := <<"ON">>, <<"brightness">> := 127,
                      <<"color">> := #{<<"x">> := 0.6401, <<"y">> := 0.33}},
                    #{state := <<"on">>, topics := [<<"l">>]}},
                   C(on, [{<<"Brightness">>, <<"50">>}, {<<"ColorRGB">>, <<"255,0,0">>}])),
     %% kelvin lights get kelvin
     ?_assertMatch({#{<<"color_temp">> := 2500}, _}, C(on, [{<<"ColorTemp">>, <<"400">>}])),
     ?_assertMatch({#{<<"state">> := <<"OFF">>, <<"transition">> := 3}, #{state := <<"off">>}},
                   C(off, [{<<"Transition">>, <<"3">>}])),
     ?_assertEqual({error, <<"TurnLightOff takes only Transition, not Brightness">>},
                   mqtt_avatar_light:command(json(), off, [{<<"Brightness">>, <<"3">>}])),
     ?_assertEqual({error, <<"ColorTempKelvin must be a number from 2000 to 6500, got 9000">>},
                   mqtt_avatar_light:command(json(), on, [{<<"ColorTempKelvin">>, <<"9000">>}]))].

default_command_test_() ->
    {ok, Ps, Wait} = mqtt_avatar_light:command(default(), on, [{<<"Brightness">>, <<"50">>},
                                                               {<<"ColorRGB">>, <<"0,0,255">>}]),
    [%% on_command_type first; brightness through its template; rgb converted to hs
     ?_assertEqual([{<<"p">>, <<"ON">>}, {<<"b">>, <<"50">>}, {<<"hs">>, <<"240.0,100.0">>}], Ps),
     ?_assertEqual([<<"bs">>, <<"hss">>, <<"s">>], lists:sort(maps:get(topics, Wait))),
     ?_assertEqual({error, <<"Effect: this light has no effects">>},
                   mqtt_avatar_light:command(default(), on, [{<<"Effect">>, <<"x">>}]))].

read_test_() ->
    L = default(),
    {ok, S1} = mqtt_avatar_light:read(L, <<"s">>, <<"ON">>, #{}),
    {ok, S2} = mqtt_avatar_light:read(L, <<"bs">>, <<"128">>, S1),
    {ok, S3} = mqtt_avatar_light:read(L, <<"hss">>, <<"120,100">>, S2),
    J = json(),
    {ok, SJ} = mqtt_avatar_light:read(J, <<"l">>, <<"{\"state\":\"ON\",\"brightness\":254,"
                                                     "\"color_temp\":4000,\"color\":{\"hue\":0,\"saturation\":100}}">>, #{}),
    [?_assertEqual([{<<"Light">>, <<"on">>}, {<<"Brightness">>, <<"50">>}, {<<"ColorRGB">>, <<"0,255,0">>},
                    {<<"ColorHS">>, <<"120.0,100.0">>}, {<<"ColorXY">>, <<"0.3,0.6">>}],
                   mqtt_avatar_light:params(S3)),
     ?_assert(mqtt_avatar_light:satisfied(#{state => <<"on">>, topics => [<<"bs">>], assumed => #{}},
                                          S3, [<<"bs">>, <<"s">>])),
     ?_assertNot(mqtt_avatar_light:satisfied(#{state => <<"on">>, topics => [<<"s">>, <<"s">>],
                                               assumed => #{}}, S3, [<<"s">>])),
     ?_assertEqual([{<<"Light">>, <<"on">>}, {<<"Brightness">>, <<"100">>}, {<<"ColorRGB">>, <<"255,0,0">>},
                    {<<"ColorHS">>, <<"0.0,100.0">>}, {<<"ColorXY">>, <<"0.6401,0.33">>},
                    {<<"ColorTemp">>, <<"250">>}, {<<"ColorTempKelvin">>, <<"4000">>}],
                   mqtt_avatar_light:params(SJ)),
     ?_assertEqual({error, <<"state MAYBE is neither ON nor OFF">>},
                   mqtt_avatar_light:read(L, <<"s">>, <<"MAYBE">>, #{})),
     ?_assertEqual({error, <<"brightness dim is not a number">>},
                   mqtt_avatar_light:read(L, <<"bs">>, <<"dim">>, #{})),
     ?_assertEqual({ok, #{}}, mqtt_avatar_light:read(L, <<"s">>, <<"None">>, #{<<"Light">> => <<"on">>}))].

z2m_test() ->
    Config = mqtt_avatar_light:from_z2m(
               <<"z/bulb">>, #{<<"features">> => [#{<<"name">> => <<"state">>},
                                                 #{<<"name">> => <<"brightness">>, <<"value_max">> => 254},
                                                 #{<<"name">> => <<"color_temp">>, <<"value_min">> => 150,
                                                   <<"value_max">> => 454},
                                                 #{<<"name">> => <<"color_xy">>}]},
               [#{<<"type">> => <<"enum">>, <<"property">> => <<"effect">>, <<"values">> => [<<"blink">>]}]),
    ?assertEqual(#{<<"schema">> => <<"json">>, <<"command_topic">> => <<"z/bulb/set">>,
                   <<"state_topic">> => <<"z/bulb">>, <<"brightness_scale">> => 254,
                   <<"supported_color_modes">> => [<<"xy">>, <<"color_temp">>], <<"min_mireds">> => 150,
                   <<"max_mireds">> => 454, <<"effect">> => true, <<"effect_list">> => [<<"blink">>]},
                 Config),
    {ok, _} = mqtt_avatar_light:config(Config).

%% Random parameters and payloads: an answer, never an exception.
never_raises_test_() ->
    {timeout, 60, ?_assertEqual(ok, evatar_test_proper:check(prop_never_raises(), 300))}.

prop_never_raises() ->
    Lights = [json(), default(),
              light(#{<<"schema">> => <<"template">>, <<"command_topic">> => <<"t">>,
                      <<"state_topic">> => <<"ts">>,
                      <<"command_on_template">> => <<"{{ brightness | default(1) * 2 }},{{ red }}">>,
                      <<"command_off_template">> => <<"off">>,
                      <<"state_template">> => <<"{{ value_json.s }}">>,
                      <<"brightness_template">> => <<"{{ value_json.b | float }}">>,
                      <<"red_template">> => <<"{{ value_json.r }}">>,
                      <<"green_template">> => <<"{{ value_json.g }}">>,
                      <<"blue_template">> => <<"{{ value_json.b }}">>})],
    Names = [<<"Brightness">>, <<"ColorRGB">>, <<"ColorHS">>, <<"ColorXY">>, <<"ColorTemp">>,
             <<"ColorTempKelvin">>, <<"Effect">>, <<"Transition">>],
    Value = oneof([binary(), <<"50">>, <<"1,2,3">>, <<"0.3,0.3">>, <<"120,50">>, <<"300">>, <<"-1">>,
                   <<"1e400">>, <<"#ff0000">>, <<"blink">>]),
    Payload = oneof([binary(), <<"ON">>, <<"{\"state\":\"ON\",\"brightness\":3}">>,
                     <<"{\"s\":\"on\",\"b\":\"x\",\"r\":1,\"g\":2}">>,
                     <<"{\"color\":{\"x\":\"a\"},\"color_temp\":0}">>]),
    Topic = oneof([<<"l">>, <<"s">>, <<"bs">>, <<"hss">>, <<"ts">>]),
    ?FORALL({L, Ps, OnOff, T, P}, {oneof(Lights), list({oneof(Names), Value}), oneof([on, off]), Topic,
                                   Payload},
            begin
                C = mqtt_avatar_light:command(L, OnOff, Ps),
                R = mqtt_avatar_light:read(L, T, P, #{}),
                (element(1, C) =:= ok orelse element(1, C) =:= error)
                    andalso (element(1, R) =:= ok orelse element(1, R) =:= error)
            end).

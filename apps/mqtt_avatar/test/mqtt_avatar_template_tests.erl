%% EUnit tests of mqtt_avatar_template: the Jinja forms HA users write,
%% the clear errors for everything else, the limits, and a PropEr property
%% that random templates over random payloads never raise.
-module(mqtt_avatar_template_tests).

-include_lib("proper/include/proper.hrl").
-include_lib("eunit/include/eunit.hrl").

%% Renders Template against the MQTT payload Payload.
r(Template, Payload) ->
    {ok, T} = mqtt_avatar_template:parse(Template),
    mqtt_avatar_template:render(T, mqtt_avatar_template:payload_vars(Payload)).

rv(Template, Vars) ->
    {ok, T} = mqtt_avatar_template:parse(Template),
    mqtt_avatar_template:render(T, Vars).

ok(Template, Payload) ->
    {ok, Out} = r(Template, Payload),
    Out.

value_test_() ->
    J = <<"{\"a\":{\"b\":[7,8]},\"t\":\"21.46\",\"on\":true,\"n\":null,\"key\":\"K\"}">>,
    [?_assertEqual(<<"hello">>, ok(<<"{{ value }}">>, <<"hello">>)),
     ?_assertEqual(<<"x=hello!">>, ok(<<"x={{value}}!">>, <<"hello">>)),
     ?_assertEqual(<<"7">>, ok(<<"{{ value_json.a.b[0] }}">>, J)),
     ?_assertEqual(<<"8">>, ok(<<"{{ value_json.a.b[-1] }}">>, J)),
     ?_assertEqual(<<"8">>, ok(<<"{{ value_json['a'][\"b\"][1] }}">>, J)),
     ?_assertEqual(<<"K">>, ok(<<"{{ value_json.key }}">>, J)),
     ?_assertEqual(<<"True">>, ok(<<"{{ value_json.on }}">>, J)),
     ?_assertEqual(<<"None">>, ok(<<"{{ value_json.n }}">>, J)),
     %% A missing key renders as nothing, as in HA.
     ?_assertEqual(<<>>, ok(<<"{{ value_json.missing.deeper }}">>, J)),
     ?_assertEqual(<<>>, ok(<<"{{ value_json.a }}">>, <<"not json">>))].

filter_test_() ->
    J = <<"{\"t\":\"21.46\",\"i\":3,\"f\":2.5,\"s\":\"MiXeD\",\"neg\":-4}">>,
    [?_assertEqual(<<"21.46">>, ok(<<"{{ value_json.t | float }}">>, J)),
     ?_assertEqual(<<"21">>, ok(<<"{{ value_json.t | int }}">>, J)),
     ?_assertEqual(<<"21.5">>, ok(<<"{{ value_json.t | float | round(1) }}">>, J)),
     ?_assertEqual(<<"21.0">>, ok(<<"{{ value_json.t | round }}">>, J)),
     ?_assertEqual(<<"21.4">>, ok(<<"{{ value_json.t | round(1, 'floor') }}">>, J)),
     ?_assertEqual(<<"3.0">>, ok(<<"{{ value_json.f | round(0, 'ceil') }}">>, J)),
     ?_assertEqual(<<"0">>, ok(<<"{{ value_json.nope | int(0) }}">>, J)),
     ?_assertEqual(<<"0">>, ok(<<"{{ value_json.s | int(0) }}">>, J)),
     ?_assertEqual(<<"dflt">>, ok(<<"{{ value_json.nope | default('dflt') }}">>, J)),
     ?_assertEqual(<<"3">>, ok(<<"{{ value_json.i | d(9) }}">>, J)),
     ?_assertEqual(<<"mixed MIXED">>, ok(<<"{{ value_json.s | lower }} {{ value_json.s | upper }}">>, J)),
     ?_assertEqual(<<"4">>, ok(<<"{{ value_json.neg | abs }}">>, J)),
     ?_assertEqual(<<"3x">>, ok(<<"{{ value_json.i | string ~ 'x' }}">>, J)),
     ?_assertEqual(<<"7.5">>, ok(<<"{{ value_json.f | multiply(3) }}">>, J)),
     ?_assertEqual(<<"5">>, ok(<<"{{ value_json.s | length }}">>, J)),
     ?_assertEqual(<<"Ma">>, ok(<<"{{ value_json.s | replace('iXeD', 'a') }}">>, J)),
     ?_assertEqual(<<"on">>, ok(<<"{{ (value_json.i > 2) | iif('on', 'off') }}">>, J)),
     ?_assertEqual(<<"2.5">>, ok(<<"{{ float(value_json.f) }}">>, J)),
     ?_assertEqual(<<"0">>, ok(<<"{{ int(value_json.s, 0) }}">>, J)),
     ?_assertEqual(<<"3">>, ok(<<"{{ value_json.i | is_defined }}">>, J)),
     ?_assertMatch({error, <<"a value tested with is_defined is undefined">>},
                   r(<<"{{ value_json.x | is_defined }}">>, J)),
     ?_assertMatch({error, <<"cannot convert the string 'MiXeD' to a number with float", _/binary>>},
                   r(<<"{{ value_json.s | float }}">>, J))].

arithmetic_test_() ->
    Vars = #{<<"brightness">> => 128, <<"x">> => 7, <<"s">> => <<"ab">>},
    [?_assertEqual({ok, <<"50">>}, rv(<<"{{ (brightness / 255 * 100) | round | int }}">>, Vars)),
     ?_assertEqual({ok, <<"3 1 -7 2.3333333333333335">>},
                   rv(<<"{{ x // 2 }} {{ x % 2 }} {{ -x }} {{ x / 3 }}">>, Vars)),
     ?_assertEqual({ok, <<"-4 2">>}, rv(<<"{{ -x // 2 }} {{ -x % 3 }}">>, Vars)),
     ?_assertEqual({ok, <<"17">>}, rv(<<"{{ 3 + x * 2 }}">>, Vars)),
     ?_assertEqual({ok, <<"27">>}, rv(<<"{{ (3 + 6) * 3 }}">>, Vars)),
     ?_assertEqual({ok, <<"abab">>}, rv(<<"{{ s + s }}">>, Vars)),
     ?_assertEqual({ok, <<"1.5e-5">>}, rv(<<"{{ 1.5e-5 }}">>, Vars)),
     ?_assertMatch({error, <<"division by zero">>}, rv(<<"{{ x / 0 }}">>, Vars)),
     ?_assertMatch({error, <<"'*' needs numbers, got the string 'ab'", _/binary>>},
                   rv(<<"{{ s * 2 }}">>, Vars)),
     ?_assertMatch({error, <<"an undefined value in '+'", _/binary>>}, rv(<<"{{ nope + 1 }}">>, Vars))].

logic_test_() ->
    Vars = #{<<"x">> => 7, <<"state">> => <<"on">>, <<"l">> => [1, 2], <<"m">> => #{<<"k">> => 1}},
    [?_assertEqual({ok, <<"True False True">>},
                   rv(<<"{{ x > 5 and x < 10 }} {{ not x }} {{ x == 7.0 }}">>, Vars)),
     ?_assertEqual({ok, <<"big">>}, rv(<<"{{ 'big' if x > 5 else 'small' }}">>, Vars)),
     ?_assertEqual({ok, <<"7">>}, rv(<<"{{ 0 or x }}">>, Vars)),
     ?_assertEqual({ok, <<"True True True False">>},
                   rv(<<"{{ 2 in l }} {{ 'k' in m }} {{ 'n' in state }} {{ 'k' not in m }}">>, Vars)),
     ?_assertEqual({ok, <<"True False True True">>},
                   rv(<<"{{ x is defined }} {{ y is defined }} {{ y is not defined }} "
                        "{{ x is number }}">>, Vars)),
     ?_assertMatch({error, <<"cannot compare the number 7 and the string 'on' with '<'">>},
                   rv(<<"{{ x < state }}">>, Vars))].

if_test_() ->
    T = <<"{% if value_json.state == 'ON' %}on{% elif value_json.state == 'OFF' %}off"
          "{% else %}unknown{% endif %}">>,
    [?_assertEqual(<<"on">>, ok(T, <<"{\"state\":\"ON\"}">>)),
     ?_assertEqual(<<"off">>, ok(T, <<"{\"state\":\"OFF\"}">>)),
     ?_assertEqual(<<"unknown">>, ok(T, <<"{}">>)),
     ?_assertEqual(<<"{\"turn\": \"on\", \"brightness\": 50}">>,
                   begin
                       {ok, P} = mqtt_avatar_template:parse(
                                   <<"{\"turn\": \"on\"\n  {%- if brightness is defined -%}\n"
                                     "  , \"brightness\": {{ brightness | float | multiply(0.3922) "
                                     "| round(0) | int }}\n  {%- endif -%}\n}">>),
                       {ok, Out} = mqtt_avatar_template:render(P, #{<<"brightness">> => 128}),
                       Out
                   end),
     ?_assertEqual(<<"ab">>, ok(<<"a{# a comment #}b">>, <<>>)),
     ?_assertEqual(<<"nested">>,
                   ok(<<"{% if 1 %}{% if 0 %}no{% else %}nested{% endif %}{% endif %}">>, <<>>))].

value_and_path_test_() ->
    P = fun(T) -> {ok, X} = mqtt_avatar_template:parse(T), mqtt_avatar_template:path(X) end,
    V = fun(T, Vars) -> {ok, X} = mqtt_avatar_template:parse(T), mqtt_avatar_template:value(X, Vars) end,
    [?_assertEqual({ok, raw}, P(<<"{{ value }}">>)),
     ?_assertEqual({ok, {json, [<<"a">>, <<"0">>, <<"b">>]}}, P(<<" {{ value_json.a[0]['b'] | float }} ">>)),
     ?_assertEqual(error, P(<<"{{ value_json.a | lower }}">>)),
     ?_assertEqual(error, P(<<"x{{ value }}">>)),
     ?_assertEqual({ok, 42}, V(<<"{{ 40 + 2 }}">>, #{})),
     ?_assertEqual({ok, <<"40 + 2">>}, V(<<"40 + 2">>, #{}))].

%% Which variables a template reads, anywhere in it (a payload that is not
%% JSON is reported as such when the template reads value_json).
reads_test_() ->
    R = fun(T, N) -> {ok, X} = mqtt_avatar_template:parse(T), mqtt_avatar_template:reads(X, N) end,
    [?_assert(R(<<"{{ value_json.t | float }}">>, <<"value_json">>)),
     ?_assert(R(<<"{% if x %}{{ 1 + (value_json['a'] | int(0)) }}{% endif %}">>, <<"value_json">>)),
     ?_assertNot(R(<<"{{ value | float }}">>, <<"value_json">>)),
     ?_assertNot(R(<<"{{ 'value_json' }} value_json">>, <<"value_json">>)),
     ?_assert(R(<<"{{ value }}">>, <<"value">>))].

%% Everything outside the subset is a clear error naming the construct.
unsupported_test_() ->
    E = fun(T) -> {error, M} = mqtt_avatar_template:parse(T), M end,
    [?_assertMatch(<<"unsupported construct '{% for %}'", _/binary>>,
                   E(<<"{% for x in value_json %}{{ x }}{% endfor %}">>)),
     ?_assertMatch(<<"unsupported construct '{% set %}'", _/binary>>, E(<<"{% set a = 1 %}">>)),
     ?_assertMatch(<<"unsupported filter 'format'", _/binary>>,
                   E(<<"{{ '%02X' | format(red) }}">>)),
     ?_assertMatch(<<"method calls such as '.split()' are not supported", _/binary>>,
                   E(<<"{{ value.split(',')[0] }}">>)),
     ?_assertMatch(<<"slices are not supported", _/binary>>, E(<<"{{ value[0:2] }}">>)),
     ?_assertMatch(<<"keyword arguments are not supported", _/binary>>, E(<<"{{ value | int(base=16) }}">>)),
     ?_assertMatch(<<"unsupported function 'states()'", _/binary>>, E(<<"{{ states('sun.sun') }}">>)),
     ?_assertMatch(<<"unsupported test 'is even'", _/binary>>, E(<<"{{ 2 is even }}">>)),
     ?_assertMatch(<<"unsupported operator '**'", _/binary>>, E(<<"{{ 2 ** 8 }}">>)),
     ?_assertMatch(<<"'{{' at offset 0 is never closed", _/binary>>, E(<<"{{ value ">>)),
     ?_assertMatch(<<"'{% if %}' without '{% endif %}'">>, E(<<"{% if 1 %}x">>)),
     ?_assertMatch(<<"'{% endif %}' without '{% if %}'", _/binary>>, E(<<"x{% endif %}">>)),
     ?_assertMatch(<<"the expression ends too early", _/binary>>, E(<<"{{ 1 + }}">>)),
     ?_assertMatch(<<"unexpected character", _/binary>>, E(<<"{{ value ; 1 }}">>)),
     ?_assertMatch(<<"string at offset", _/binary>>, E(<<"{{ 'abc }}">>)),
     ?_assertMatch(<<"template is not UTF-8 text">>, E(<<"{{ '", 255, "' }}">>))].

limits_test_() ->
    Deep = iolist_to_binary(["{{ ", lists:duplicate(100, "("), "1", lists:duplicate(100, ")"), " }}"]),
    Long = iolist_to_binary(["{{ ", lists:join(" + ", lists:duplicate(1500, "1")), " }}"]),
    {ok, LongT} = mqtt_avatar_template:parse(Long, #{max_size => 10000}),
    [?_assertEqual({error, <<"expression nested too deeply">>}, mqtt_avatar_template:parse(Deep)),
     ?_assertMatch({error, <<"template longer than 4096 bytes">>},
                   mqtt_avatar_template:parse(binary:copy(<<"a">>, 5000))),
     ?_assertEqual({ok, <<"1500">>}, mqtt_avatar_template:render(LongT, #{})),
     ?_assertEqual({error, <<"evaluation takes too many steps">>},
                   mqtt_avatar_template:render(LongT, #{}, #{max_steps => 100})),
     ?_assertMatch({error, <<"output longer than 10 bytes">>},
                   mqtt_avatar_template:render(element(2, mqtt_avatar_template:parse(<<"{{ value }}">>)),
                                               #{<<"value">> => binary:copy(<<"x">>, 11)},
                                               #{max_output => 10})),
     ?_assertMatch({error, <<"number out of range">>},
                   rv(<<"{{ 9999999999 * 9999999999 }}">>, #{})),
     ?_assertEqual(#{max_size => 4096, max_depth => 32, max_steps => 10000, max_output => 65536},
                   mqtt_avatar_template:limits())].

%% ---------------------------------------------------------------------------
%% Property: random templates (made of the grammar's pieces, so many parse)
%% rendered over random JSON payloads return {ok, _} or {error, _}, never
%% raise, and never make an atom.
%% ---------------------------------------------------------------------------

never_raises_test_() ->
    {timeout, 60, ?_test(ok = evatar_test_proper:check(prop_never_raises(), numtests()))}.

numtests() ->
    case os:getenv("EVATAR_LONG_TESTS") of
        false -> 500;
        _ -> 20000
    end.

prop_never_raises() ->
    ?FORALL({Pieces, Payload}, {list(piece()), payload()},
            begin
                Template = iolist_to_binary(Pieces),
                Atoms = erlang:system_info(atom_count),
                Result = case mqtt_avatar_template:parse(Template) of
                             {ok, T} ->
                                 Vars = mqtt_avatar_template:payload_vars(Payload),
                                 R1 = mqtt_avatar_template:render(T, Vars),
                                 R2 = mqtt_avatar_template:value(T, Vars#{<<"brightness">> => 3}),
                                 _ = mqtt_avatar_template:path(T),
                                 ok_or_error(R1) andalso ok_or_error(R2);
                             {error, M} ->
                                 is_binary(M)
                         end,
                Result andalso erlang:system_info(atom_count) =:= Atoms
            end).

ok_or_error({ok, _}) -> true;
ok_or_error({error, M}) -> is_binary(M).

piece() ->
    oneof(["{{ ", " }}", "{% if ", "{% elif ", " %}", "{% else %}", "{% endif %}", "{#", "#}",
           "{{-", "-}}", "value", "value_json", ".a", ".b", "[0]", "['a']", "[-1]", " | float",
           " | int", " | round(1)", " | default(2)", " | lower", " | upper", " | string",
           " | abs", " | length", " | is_defined", " | iif(1, 2)", " | multiply(2)",
           " + ", " - ", " * ", " / ", " // ", " % ", " ~ ", " == ", " != ", " < ", " >= ",
           " and ", " or ", " not ", " in ", " if ", " else ", " is defined", " is not none",
           "(", ")", "1", "0", "2.5", "-", "'x'", "\"ON\"", "true", "none", "brightness",
           "float(", "int(", ",", "]", "[", "x", " ", "\n", "{", "}", "%", "|", binary()]).

payload() ->
    oneof([binary(),
           ?LET(J, json(3), evatar_json:encode(J))]).

json(0) ->
    oneof([int(), real(), utf8(), bool(), null]);
json(N) ->
    frequency([{3, json(0)},
               {1, ?LET(L, list({oneof([<<"a">>, <<"b">>, <<"state">>]), json(N - 1)}), maps:from_list(L))},
               {1, list(json(N - 1))}]).

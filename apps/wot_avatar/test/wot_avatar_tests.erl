%% EUnit tests of the WoT Avatar's pure parts: a TD read (wot_avatar_td),
%% its BIL description and routes (wot_avatar_generate), and the values
%% carried between BIL parameters and the Thing's JSON (wot_avatar_codec).
-module(wot_avatar_tests).

-include_lib("eunit/include/eunit.hrl").

-define(BASE, "http://127.0.0.1:8080/lamp").

td(Extra) ->
    Base = #{<<"@context">> => <<"https://www.w3.org/2022/wot/td/v1.1">>,
             <<"title">> => <<"lamp">>,
             <<"securityDefinitions">> => #{<<"nosec_sc">> => #{<<"scheme">> => <<"nosec">>}},
             <<"security">> => [<<"nosec_sc">>]},
    evatar_json:encode(maps:merge(Base, Extra)).

form(Href) -> form(Href, #{}).
form(Href, More) -> maps:merge(#{<<"href">> => list_to_binary(Href)}, More).

%% A lamp as node-wot's HTTP binding exposes it.
lamp() ->
    td(#{<<"properties">> =>
             #{<<"brightness">> =>
                   #{<<"type">> => <<"integer">>, <<"minimum">> => 0, <<"maximum">> => 100,
                     <<"unit">> => <<"%">>, <<"observable">> => true,
                     <<"forms">> => [form(?BASE "/properties/brightness",
                                          #{<<"op">> => [<<"readproperty">>, <<"writeproperty">>]}),
                                     form(?BASE "/properties/brightness/observable",
                                          #{<<"op">> => [<<"observeproperty">>],
                                            <<"subprotocol">> => <<"longpoll">>})]},
               <<"on">> =>
                   #{<<"type">> => <<"boolean">>, <<"readOnly">> => true,
                     <<"forms">> => [form(?BASE "/properties/on")]}},
         <<"actions">> =>
             #{<<"toggle">> =>
                   #{<<"forms">> => [form(?BASE "/actions/toggle")]},
               <<"fade">> =>
                   #{<<"input">> => #{<<"type">> => <<"object">>,
                                      <<"properties">> =>
                                          #{<<"to">> => #{<<"type">> => <<"integer">>, <<"minimum">> => 0,
                                                          <<"maximum">> => 100},
                                            <<"mode">> => #{<<"type">> => <<"string">>,
                                                            <<"enum">> => [<<"linear">>, <<"ease">>]}}},
                     <<"output">> => #{<<"type">> => <<"integer">>},
                     <<"forms">> => [form(?BASE "/actions/fade")]}},
         <<"events">> =>
             #{<<"overheated">> =>
                   #{<<"data">> => #{<<"type">> => <<"number">>},
                     <<"forms">> => [form(?BASE "/events/overheated",
                                          #{<<"subprotocol">> => <<"sse">>})]}}}).

describe(Td) -> describe(Td, #{}).
describe(Td, Opts) ->
    wot_avatar:describe(Td, maps:merge(#{entity_id => <<"wot-lamp">>,
                                         source_url => <<?BASE>>}, Opts)).

service(Type, #{components := [#{services := Ss}]}) ->
    [S] = [S || #{type := T} = S <- Ss, T =:= Type],
    S.

%% Actions are ACTUATOR services with their input's fields and ranges;
%% properties Read and Set services and a stream; events a stream; one
%% ACTION FEEDBACK entry.
lamp_description_test() ->
    {ok, D, Routes, []} = describe(lamp()),
    #{entity_id := <<"wot-lamp">>, entity_type := avatar, context := <<"WotDescription">>,
      components := [#{id := <<"Lamp">>, services := Ss, consumes := Cs}]} = D,
    ?assertEqual([<<"Fade">>, <<"Toggle">>, <<"ReadBrightness">>, <<"SetBrightness">>, <<"ReadOn">>,
                  <<"ReadOverheated">>],
                 [T || #{type := T} <- Ss]),
    #{category := <<"ACTUATOR">>, parameters := Fade} = service(<<"Fade">>, D),
    ?assertEqual([{<<"Mode">>, <<"yes">>}, {<<"ModeType">>, <<"string">>}, {<<"ModeValues">>, <<"linear|ease">>},
                  {<<"To">>, <<"yes">>}, {<<"ToType">>, <<"integer">>}, {<<"ToMin">>, <<"0">>},
                  {<<"ToMax">>, <<"100">>}], Fade),
    #{parameters := []} = service(<<"Toggle">>, D),
    #{category := <<"SENSOR">>, parameters := [{<<"Value">>, <<"yes">>}]} = service(<<"ReadOn">>, D),
    #{category := <<"ACTUATOR">>, parameters := Set} = service(<<"SetBrightness">>, D),
    ?assertEqual({<<"ValueUnit">>, <<"%">>}, lists:keyfind(<<"ValueUnit">>, 1, Set)),
    ?assertEqual([{<<"SENSOR">>, <<"Brightness">>}, {<<"SENSOR">>, <<"On">>},
                  {<<"SENSOR">>, <<"Overheated">>}, {<<"ACTUATOR">>, <<"ACTION FEEDBACK">>}],
                 [{C, T} || #{category := C, type := T} <- Cs]),
    %% Routes: the forms, methods and how each stream is fed.
    #{component := <<"Lamp">>, services := #{<<"fade">> := Fade1, <<"setbrightness">> := SetR,
                                              <<"readon">> := ReadOn},
      streams := [Bright, On, Over]} = Routes,
    #{op := invokeaction, form := #{href := <<?BASE "/actions/fade">>, method := <<"POST">>}} = Fade1,
    #{op := writeproperty, form := #{method := <<"PUT">>}} = SetR,
    #{op := readproperty, form := #{method := <<"GET">>}} = ReadOn,
    #{type := <<"Brightness">>, context := sensor_data, mode := longpoll,
      form := #{href := <<?BASE "/properties/brightness/observable">>}} = Bright,
    #{type := <<"On">>, mode := {poll, 10000}} = On,
    #{type := <<"Overheated">>, context := event, mode := sse} = Over.

%% The description is valid BIL: it encodes and parses back the same.
round_trip_test() ->
    {ok, D, _, _} = describe(lamp(), #{room => <<"bedroom">>}),
    {ok, D} = bil:parse_description(iolist_to_binary(bil:encode_description(D))),
    #{parameters := Ps} = service(<<"Toggle">>, D),
    ?assertEqual([{<<"Room">>, <<"bedroom">>}], Ps).

%% poll_ms 0: a property without observe gets no stream.
no_polling_test() ->
    {ok, _, #{streams := Streams}, []} = describe(lamp(), #{poll_ms => 0}),
    ?assertEqual([<<"Brightness">>, <<"Overheated">>], [T || #{type := T} <- Streams]).

%% Relative hrefs resolve against base; a form to another host is refused
%% unless allowed_hosts names it.
hosts_test() ->
    Td = td(#{<<"base">> => <<"http://thing.example:8080/">>,
              <<"actions">> => #{<<"go">> => #{<<"forms">> => [form("actions/go")]}},
              <<"properties">> => #{<<"far">> => #{<<"forms">> => [form("http://10.0.0.9/secret")]}}}),
    {error, P1} = describe(Td, #{source_url => <<"http://127.0.0.1/td">>}),
    ?assertEqual([host_not_allowed, host_not_allowed, nothing_usable], [W || #{what := W} <- P1]),
    {ok, _, #{services := S2}, [#{what := host_not_allowed, affordance := <<"far">>}]} =
        describe(Td, #{allowed_hosts => [<<"THING.example:8080">>]}),
    #{<<"go">> := #{form := #{href := <<"http://thing.example:8080/actions/go">>}}} = S2,
    %% A port of its own: not the same endpoint.
    {error, _} = describe(Td, #{allowed_hosts => [<<"thing.example:80">>]}).

%% What the WoT Avatar cannot drive is a problem of its affordance: CoAP,
%% a broker not allowed, an unknown security scheme, an array schema, a
%% name with no letters. The rest is kept.
problems_test() ->
    Td = td(#{<<"securityDefinitions">> => #{<<"nosec_sc">> => #{<<"scheme">> => <<"nosec">>},
                                              <<"psk_sc">> => #{<<"scheme">> => <<"psk">>}},
              <<"actions">> =>
                  #{<<"coap">> => #{<<"forms">> => [form("coap://127.0.0.1/x")]},
                    <<"mqtt">> => #{<<"forms">> => [form("mqtt://broker.example/x")]},
                    <<"psk">> => #{<<"forms">> => [form(?BASE "/x", #{<<"security">> => <<"psk_sc">>})]},
                    <<"list">> => #{<<"input">> => #{<<"type">> => <<"array">>},
                                    <<"forms">> => [form(?BASE "/list")]},
                    <<"%%%">> => #{<<"forms">> => [form(?BASE "/pct")]},
                    <<"ok">> => #{<<"forms">> => [form(?BASE "/ok")]}}}),
    {ok, D, #{services := S}, Problems} = describe(Td),
    ?assertEqual([<<"ok">>], maps:keys(S)),
    ?assertEqual([{unsupported_scheme, <<"coap">>}, {host_not_allowed, <<"mqtt">>},
                  {unsupported_security, <<"psk">>}, {bad_name, <<"%%%">>}, {unsupported_schema, undefined}],
                 [{W, maps:get(affordance, P, undefined)} || #{what := W} = P <- Problems]),
    [#{services := [#{type := <<"Ok">>}]}] = maps:get(components, D).

%% A TD whose only security is one it cannot speak: every affordance out,
%% the scheme named once.
unsupported_thing_security_test() ->
    Td = td(#{<<"securityDefinitions">> => #{<<"o">> => #{<<"scheme">> => <<"oauth2">>}},
              <<"security">> => <<"o">>,
              <<"actions">> => #{<<"go">> => #{<<"forms">> => [form(?BASE "/go")]}}}),
    {error, [#{what := unsupported_security, message := M}, #{what := unsupported_security},
             #{what := nothing_usable}]} = describe(Td),
    ?assertMatch({match, _}, re:run(M, "oauth2")).

%% Bearer and basic are spoken (in the header); an apikey in the query is not.
security_test() ->
    Bearer = td(#{<<"securityDefinitions">> => #{<<"b">> => #{<<"scheme">> => <<"bearer">>}},
                  <<"security">> => <<"b">>,
                  <<"actions">> => #{<<"go">> => #{<<"forms">> => [form(?BASE "/go")]}}}),
    {ok, _, #{services := #{<<"go">> := #{form := #{security := bearer}}}}, []} = describe(Bearer),
    Query = td(#{<<"securityDefinitions">> => #{<<"b">> => #{<<"scheme">> => <<"basic">>,
                                                             <<"in">> => <<"query">>}},
                 <<"security">> => <<"b">>}),
    {error, [#{what := unsupported_security}, #{what := nothing_usable}]} = describe(Query).

%% Input that is no TD is refused with a reason; hostile strings stay out
%% of the description and of the problems.
bad_input_test() ->
    {error, [#{what := not_json}]} = describe(<<"<td/>">>),
    {error, [#{what := not_a_td}]} = describe(<<"[1,2]">>),
    {error, [#{what := not_a_td}]} = describe(<<"{\"title\": \"x\"}">>),
    {error, [#{what := not_a_td}]} = describe(<<"{\"security\": [], \"securityDefinitions\": {}}">>),
    {error, [#{what := not_a_td}]} = describe(td(#{<<"security">> => [<<"missing">>]})),
    {error, [#{what := too_large}]} = describe(lamp(), #{max_size => 100}),
    Many = maps:from_list([{integer_to_binary(N), #{<<"forms">> => [form(?BASE)]}} || N <- lists:seq(1, 200)]),
    {error, [#{what := too_large, message := M}]} = describe(td(#{<<"actions">> => Many})),
    ?assertMatch({match, _}, re:run(M, "max_affordances 128")),
    Hostile = td(#{<<"title">> => <<"x</EntityID><evil/>\n">>,
                   <<"actions">> =>
                       #{<<"a\nb<c>">> =>
                             #{<<"input">> => #{<<"type">> => <<"string">>,
                                                <<"enum">> => [<<"x\n">>, <<"y">>]},
                               <<"forms">> => [form(?BASE "/a")]},
                         binary:copy(<<"long">>, 40) => #{<<"forms">> => [form(?BASE "/l")]}}}),
    {ok, D, _, Problems} = describe(Hostile),
    #{components := [#{id := <<"XEntityIDEvil">>, services := [#{type := <<"ABC">>, parameters := Ps}]}]} = D,
    %% The enum with a control character is not described (still checked).
    ?assertEqual(false, lists:keymember(<<"ValueValues">>, 1, Ps)),
    [#{what := bad_name, affordance := Shown}] = Problems,
    ?assertEqual(<<"(a name that cannot be shown)">>, Shown).

%% Two affordances whose names meet as BIL keywords: the first is kept.
clash_test() ->
    Td = td(#{<<"actions">> => #{<<"read-on">> => #{<<"forms">> => [form(?BASE "/a")]}},
              <<"properties">> => #{<<"on">> => #{<<"readOnly">> => true, <<"forms">> => [form(?BASE "/on")]}}}),
    {ok, _, #{services := #{<<"readon">> := #{op := invokeaction}}}, [#{what := name_clash}]} =
        describe(Td, #{poll_ms => 0}).

%% A request's parameters become the body, checked against the schema.
body_test() ->
    {ok, _, #{services := #{<<"fade">> := #{input := In, output := Out},
                            <<"setbrightness">> := #{input := Value}}}, _} = describe(lamp()),
    {ok, Body} = wot_avatar_codec:body(In, [{<<"To">>, <<"40">>}, {<<"Mode">>, <<"ease">>}]),
    {ok, #{<<"to">> := 40, <<"mode">> := <<"ease">>}} = evatar_json:decode(Body),
    {ok, <<"{\"to\":3}">>} = wot_avatar_codec:body(In, [{<<"to">>, <<"3">>}]),
    {error, <<"parameter To is above its maximum 100">>} = wot_avatar_codec:body(In, [{<<"To">>, <<"101">>}]),
    {error, <<"parameter To is not an integer">>} = wot_avatar_codec:body(In, [{<<"To">>, <<"x">>}]),
    {error, <<"parameter Mode is not one of its Values">>} =
        wot_avatar_codec:body(In, [{<<"Mode">>, <<"fast">>}]),
    {ok, <<"55">>} = wot_avatar_codec:body(Value, [{<<"Value">>, <<"55">>}]),
    {error, <<"parameter Value is missing">>} = wot_avatar_codec:body(Value, []),
    {ok, none} = wot_avatar_codec:body(none, [{<<"Room">>, <<"x">>}]),
    %% What the Thing answers becomes the Feedback's parameters.
    [{<<"Value">>, <<"40">>}] = wot_avatar_codec:params(Out, <<"40">>),
    [{<<"Mode">>, <<"ease">>}, {<<"To">>, <<"7">>}] =
        wot_avatar_codec:params(In, <<"{\"to\":7,\"mode\":\"ease\",\"other\":1}">>),
    [{<<"Value">>, <<"not json">>}] = wot_avatar_codec:params(none, <<"not json">>),
    [] = wot_avatar_codec:params(none, <<>>).

camel_test() ->
    {ok, <<"SetPoint">>} = wot_avatar_generate:camel(<<"set-point">>),
    {ok, <<"N2ndFloor">>} = wot_avatar_generate:camel(<<"2nd floor">>),
    {ok, <<"TimeOfDay">>} = wot_avatar_generate:camel(<<"TimeOfDay">>),
    {error, _} = wot_avatar_generate:camel(<<"ü">>).

%% ---------------------------------------------------------------------------
%% wot_avatar_route: requests, answers, SSE
%% ---------------------------------------------------------------------------

req(Type, Params) ->
    #{id => <<"s1">>, sender => <<"Va">>, receiver => <<"Lamp">>, context => request,
      body => #{category => <<"ACTUATOR">>, type => Type, parameters => Params}}.

%% A request becomes its form's HTTP request, or is answered at once: an
%% unknown service, a value the schema refuses (never sent to the Thing).
route_request_test() ->
    {ok, _, Routes, []} = describe(lamp()),
    {http, #{method := <<"PUT">>, url := <<?BASE "/properties/brightness">>, body := <<"42">>}, P} =
        wot_avatar_route:request(req(<<"SetBrightness">>, [{<<"Value">>, <<"42">>}]), Routes, #{}),
    [#{context := feedback, in_reply_to := <<"s1">>,
       body := #{type := <<"ACTION FEEDBACK">>, parameters := Ps}}] =
        wot_avatar_route:answer(P, <<>>, #{component => <<"Lamp">>}),
    ?assertEqual([{<<"Service">>, <<"SetBrightness">>}, {<<"Result">>, <<"done">>}, {<<"Value">>, <<"42">>}], Ps),
    {answer, [#{context := error, body := #{type := <<"BadParameter">>}}]} =
        wot_avatar_route:request(req(<<"SetBrightness">>, [{<<"Value">>, <<"142">>}]), Routes, #{}),
    {answer, [#{body := #{type := <<"UnknownService">>}}]} =
        wot_avatar_route:request(req(<<"Explode">>, []), Routes, #{}),
    {answer, [#{body := #{type := <<"UnknownComponent">>}}]} =
        wot_avatar_route:request((req(<<"Toggle">>, []))#{receiver => <<"Other">>}, Routes, #{}),
    %% An HTTP error or a timeout is the request's Error; no feedback asked, no answer.
    [#{context := error, body := #{type := <<"DeviceError">>, parameters := [{_, M}]}}] =
        wot_avatar_route:failure(P, {status, 500, <<"boom\n">>}, #{component => <<"Lamp">>}),
    ?assertEqual(<<"the Thing answered HTTP 500: boom ">>, M),
    [#{body := #{type := <<"DeviceTimeout">>}}] = wot_avatar_route:failure(P, timeout, #{component => <<"Lamp">>}),
    [] = wot_avatar_route:failure(P#{awaiting := false}, timeout, #{component => <<"Lamp">>}),
    %% An event's Read service is answered from the last event.
    {last, <<"Overheated">>, L} = wot_avatar_route:request(req(<<"ReadOverheated">>, []), Routes, #{}),
    [#{body := #{type := <<"NoReading">>}}] = wot_avatar_route:last(L, none, #{component => <<"Lamp">>}).

%% Basic and bearer credentials go in the Authorization header.
route_headers_test() ->
    Form = #{content_type => <<"application/json">>, subprotocol => none, security => bearer},
    ?assertEqual([{"accept", "application/json"}, {"authorization", "Bearer t0k"}],
                 wot_avatar_route:headers(Form, #{token => <<"t0k">>})),
    ?assertEqual([{"accept", "text/event-stream"}, {"authorization", "Basic dTpw"}],
                 wot_avatar_route:headers(Form#{security := basic, subprotocol := sse},
                                          #{username => <<"u">>, password => <<"p">>})).

%% SSE: complete events' data (multi-line joined), the rest kept; a
%% partial event over the limit is refused.
route_sse_test() ->
    ?assertEqual({[<<"1">>, <<"a\nb">>], <<"data: 3">>},
                 wot_avatar_route:sse(<<": hi\n\ndata: 1\r\n\r\nevent: x\ndata:a\ndata: b\n\ndata: 3">>, 100)),
    ?assertEqual(too_large, wot_avatar_route:sse(binary:copy(<<"x">>, 101), 100)),
    %% A reading goes to the bound components, with the Room.
    {ok, _, #{streams := [Bright | _]}, []} = describe(lamp()),
    Bound = [#{consumer => #{entity => <<"wot-lamp">>, component => <<"Lamp">>},
               provider => #{entity => <<"va">>, component => <<"VaLamp">>},
               category => <<"SENSOR">>, type => <<"brightness">>, score => 1, candidates => 1}],
    [<<"VaLamp">>] = R = wot_avatar_route:receivers(<<"wot-lamp">>, <<"Lamp">>, <<"Brightness">>, Bound),
    {[{<<"Value">>, <<"7">>}, {<<"Room">>, <<"hall">>}], [#{context := sensor_data, receiver := <<"VaLamp">>}]} =
        wot_avatar_route:reading(Bright, <<"7">>, R, #{component => <<"Lamp">>, room => <<"hall">>}).

%% MQTT forms: publish to invoke and write, subscribe to observe and for
%% events (the defaults when mqv:controlPacket is left out), the broker's
%% port 1883 by default; a topic with a wildcard, a read, a packet that
%% does not fit its op, credentials: a problem of the affordance.
mqtt_forms_test() ->
    M = fun(Topic, More) -> form("mqtt://broker.example/" ++ Topic, More) end,
    Td = td(#{<<"actions">> =>
                  #{<<"go">> => #{<<"forms">> => [M("lamp/actions/go", #{})]},
                    <<"wild">> => #{<<"forms">> => [M("lamp/%2B/go", #{})]},
                    <<"sub">> => #{<<"forms">> => [M("lamp/sub", #{<<"mqv:controlPacket">> => <<"subscribe">>})]}},
              <<"properties">> =>
                  #{<<"level">> => #{<<"type">> => <<"integer">>, <<"observable">> => true,
                                     <<"forms">> => [M("lamp/level", #{<<"op">> => [<<"observeproperty">>]}),
                                                     M("lamp/level/set", #{<<"op">> => [<<"writeproperty">>]})]},
                    <<"read">> => #{<<"type">> => <<"integer">>, <<"readOnly">> => true,
                                    <<"forms">> => [M("lamp/read", #{<<"op">> => [<<"readproperty">>]})]}},
              <<"events">> => #{<<"ring">> => #{<<"forms">> => [M("lamp/ring", #{})]}}}),
    {ok, _D, #{services := S, streams := Streams}, Problems} =
        describe(Td, #{allowed_hosts => [<<"broker.example:1883">>]}),
    #{<<"go">> := #{form := #{method := <<"PUBLISH">>, href := <<"mqtt://broker.example/lamp/actions/go">>}},
      <<"setlevel">> := #{form := #{method := <<"PUBLISH">>}}} = S,
    [#{type := <<"Ring">>, mode := mqtt, context := event}, #{type := <<"Level">>, mode := mqtt}] =
        lists:sort([maps:with([type, mode, context], St) || St <- Streams]),
    ?assertEqual([{bad_href, <<"wild">>}, {unsupported_form, <<"read">>}, {unsupported_form, <<"sub">>}],
                 lists:sort([{W, A} || #{what := W, affordance := A} <- Problems])),
    %% Credentials over MQTT are not sent: the affordance is left out.
    Basic = td(#{<<"securityDefinitions">> => #{<<"b">> => #{<<"scheme">> => <<"basic">>}},
                 <<"security">> => <<"b">>,
                 <<"actions">> => #{<<"go">> => #{<<"forms">> => [M("lamp/go", #{})]},
                                    <<"ok">> => #{<<"forms">> => [form(?BASE "/ok")]}}}),
    {ok, _, _, [#{what := unsupported_security, affordance := <<"go">>}]} =
        describe(Basic, #{allowed_hosts => [<<"broker.example">>]}).

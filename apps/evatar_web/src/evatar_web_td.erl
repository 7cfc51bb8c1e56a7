%% @doc Internal. Pure: the W3C Thing Description (TD 1.1, JSON-LD) of one
%% described Avatar entity of a pairing, and the counterpart description the
%% node's WoT consumer registers as the pairing's agent (docs/wot.md).
%%
%% Every `Service' of the Avatar is an action (input: its
%% ServiceParameters; output: the parameters of the component's
%% `ACTION FEEDBACK' consumer); every `SENSOR' data service a component
%% consumes (the stream it pushes) is a read-only property holding its
%% last reading. The forms point at the node's HTTP binding
%% (evatar_web_things), secured by the operator's bearer token. For an
%% MQTT Avatar (mqtt_avatar) kept by the node, an action or property whose
%% device has a topic also gets the device's own MQTT binding form
%% (`mqv:' vocabulary of the WoT Binding Templates: `mqtt://HOST:PORT/TOPIC',
%% `mqv:controlPacket' publish to the command topic, subscribe to the
%% state topic), beside the HTTP one.
-module(evatar_web_td).

-export([thing/4, thing/5, directory/2, thing_id/3, affordances/1, counterpart/2, component_id/1, directory_entry/1]).

-export_type([affordance/0, mqtt/0]).

%% What one TD interaction is in BIL terms.
-type affordance() :: #{kind := action | property,
                        name := binary(),
                        component := binary(),
                        entry := bil:entry(),
                        feedback => bil:entry() | undefined}.

%% An MQTT Avatar's broker (as its options name it) and its description as
%% it generated it, the Mqtt* parameters included (which the pairing's copy
%% has not: mqtt_avatar takes them out).
-type mqtt() :: none | #{host := binary(), port := inet:port_number(), description := bil:description()}.

-define(CONTEXT, [<<"https://www.w3.org/2019/wot/td/v1">>,
                  <<"https://www.w3.org/2022/wot/td/v1.1">>,
                  #{<<"@language">> => <<"en">>,
                    <<"htv">> => <<"http://www.w3.org/2011/http#">>,
                    <<"mqv">> => <<"http://www.example.org/mqtt-binding#">>,
                    <<"bil">> => <<"urn:evatar:bil:1#">>}]).

%% @doc The TD of Avatar description `Desc' in pairing `Pairing' of node
%% `Node', its forms relative to `Base' ("http://host:port/").
-spec thing(node(), binary(), bil:description(), binary()) -> map().
thing(Node, Pairing, Desc, Base) ->
    thing(Node, Pairing, Desc, Base, none).

%% @doc thing/4, with the MQTT forms of an MQTT Avatar's devices.
-spec thing(node(), binary(), bil:description(), binary(), mqtt()) -> map().
thing(Node, Pairing, #{entity_id := Entity} = Desc, Base, Mqtt) ->
    Affs = affordances(Desc),
    Path = fun(Parts) -> iolist_to_binary(lists:join("/", [<<"api/things">> | [enc(P) || P <- [Pairing, Entity | Parts]]])) end,
    Topics = topics(Mqtt),
    Actions = maps:from_list([{N, mqtt_action(action(A, Path), A, Topics)}
                              || #{kind := action, name := N} = A <- Affs]),
    Props = maps:from_list([{N, mqtt_property(property(A, Path), A, Topics)}
                            || #{kind := property, name := N} = A <- Affs]),
    #{<<"@context">> => ?CONTEXT,
      <<"@type">> => <<"Thing">>,
      <<"id">> => thing_id(Node, Pairing, Entity),
      <<"title">> => Entity,
      <<"description">> => iolist_to_binary(["The Avatar entity ", Entity, " of EVATAR pairing ",
                                              Pairing, " (", maps:get(api_name, Desc, <<>>),
                                              "): every operation is a BIL request in the pairing"]),
      <<"base">> => Base,
      <<"securityDefinitions">> => security(),
      <<"security">> => [<<"bearer_sc">>],
      <<"schemaDefinitions">> => #{<<"error">> => error_schema()},
      <<"forms">> => [#{<<"href">> => Path([]), <<"op">> => [<<"readallproperties">>],
                        <<"contentType">> => <<"application/json">>,
                        <<"htv:methodName">> => <<"GET">>}],
      <<"actions">> => Actions,
      <<"properties">> => Props}.

%% @doc The node's own TD (served at /.well-known/wot): one property,
%% `things', the TDs it exports (GET /api/things).
-spec directory(node(), binary()) -> map().
directory(Node, Base) ->
    #{<<"@context">> => ?CONTEXT,
      <<"@type">> => <<"Thing">>,
      <<"id">> => iolist_to_binary(["urn:evatar:node:", enc(atom_to_binary(Node))]),
      <<"title">> => iolist_to_binary(["EVATAR node ", atom_to_binary(Node)]),
      <<"description">> => <<"an EVATAR node: the Things it exports, one per described Avatar of a pairing with a WoT consumer">>,
      <<"base">> => Base,
      <<"securityDefinitions">> => security(),
      <<"security">> => [<<"bearer_sc">>],
      <<"properties">> =>
          #{<<"things">> => #{<<"title">> => <<"Thing Descriptions">>,
                              <<"description">> => <<"every TD this node exports">>,
                              <<"type">> => <<"array">>,
                              <<"items">> => #{<<"type">> => <<"object">>},
                              <<"readOnly">> => true, <<"writeOnly">> => false,
                              <<"observable">> => false,
                              <<"forms">> => [#{<<"href">> => <<"api/things">>,
                                                <<"op">> => [<<"readproperty">>],
                                                <<"contentType">> => <<"application/json">>,
                                                <<"htv:methodName">> => <<"GET">>}]}}}.

security() ->
    #{<<"bearer_sc">> => #{<<"scheme">> => <<"bearer">>, <<"in">> => <<"header">>,
                           <<"name">> => <<"Authorization">>, <<"format">> => <<"opaque">>,
                           <<"description">> => <<"the node's HTTP operator token (docs/api.md, Authentication)">>}}.

%% @doc The TD's id: a URN naming the node, the pairing and the entity
%% (each part percent-encoded).
-spec thing_id(node(), binary(), binary()) -> binary().
thing_id(Node, Pairing, Entity) ->
    iolist_to_binary(["urn:evatar:thing:", enc(atom_to_binary(Node)), ":", enc(Pairing), ":", enc(Entity)]).

%% @doc A short listing entry of a TD (GET /api/things).
-spec directory_entry(map()) -> map().
directory_entry(#{<<"id">> := Id, <<"title">> := T, <<"actions">> := A, <<"properties">> := P}) ->
    #{<<"id">> => Id, <<"title">> => T, <<"actions">> => lists:sort(maps:keys(A)),
      <<"properties">> => lists:sort(maps:keys(P))}.

%% @doc Every action and property of a description, names unique.
-spec affordances(bil:description()) -> [affordance()].
affordances(#{components := Cs}) ->
    Raw = lists:append(
            [[#{kind => action, name => <<Id/binary, ".", T/binary>>, component => Id, entry => S,
                feedback => feedback(Consumes)}
              || #{type := T} = S <- Services]
             ++ [#{kind => property, name => <<Id/binary, ".", T/binary>>, component => Id, entry => E}
                 || #{category := Cat, type := T} = E <- Consumes,
                    bil:keyword(Cat) =:= <<"sensor">>]
             || #{id := Id, services := Services, consumes := Consumes} <- Cs]),
    unique(Raw, #{}).

unique([], _) -> [];
unique([#{name := N} = A | Rest], Seen) ->
    case Seen of
        #{N := K} ->
            N1 = <<N/binary, "-", (integer_to_binary(K + 1))/binary>>,
            [A#{name := N1} | unique(Rest, Seen#{N := K + 1})];
        #{} ->
            [A | unique(Rest, Seen#{N => 1})]
    end.

feedback(Consumes) ->
    case [E || #{type := T} = E <- Consumes, bil:keyword(T) =:= <<"actionfeedback">>] of
        [E | _] -> E;
        [] -> undefined
    end.

%% @doc The component of the WoT consumer's description that stands in for
%% Avatar component `Id' (consumes its services, provides its feedback and
%% sensor data services).
-spec component_id(binary()) -> binary().
component_id(Id) -> <<"wot.", Id/binary>>.

%% @doc The WoT consumer's agent description: for each component of the
%% Avatar descriptions, one emulator that consumes its services (with its
%% parameters, `any' as no constraint) and provides what it consumes (its
%% ACTION FEEDBACK and SENSOR data services), so that binding pairs them.
-spec counterpart(binary(), [bil:description()]) -> bil:description().
counterpart(EntityId, Avatars) ->
    Components = [#{id => component_id(Id),
                    consumes => [E#{parameters := [{N, consumer_value(V)} || {N, V} <- Ps]}
                                 || #{parameters := Ps} = E <- Services],
                    services => [E#{parameters := [{N, provider_value(V)} || {N, V} <- Ps]}
                                 || #{parameters := Ps} = E <- Consumes]}
                  || #{components := Cs} <- Avatars,
                     #{id := Id, services := Services, consumes := Consumes} <- Cs,
                     Services =/= [] orelse Consumes =/= []],
    %% A component must provide a Service: one without gets a marker.
    #{entity_id => EntityId, api_name => <<"EVATAR WoT consumer">>, entity_type => agent,
      context => <<"WoT">>,
      components => [C#{services := case S of
                                        [] -> [#{category => <<"WOT">>, type => <<"Consumer">>, parameters => []}];
                                        _ -> S
                                    end} || #{services := S} = C <- Components]}.

consumer_value(V) ->
    case bil:keyword(V) of
        <<"any">> -> <<"no">>;
        _ -> V
    end.

%% A `no' consumer value is no constraint; as a provider value it would not
%% meet a `yes', so it offers `any'.
provider_value(V) ->
    case bil:keyword(V) of
        <<"no">> -> <<"any">>;
        _ -> V
    end.

%% ---------------------------------------------------------------------------
%% Affordances
%% ---------------------------------------------------------------------------

action(#{component := C, entry := #{category := Cat, type := T, parameters := Ps}} = A, Path) ->
    Output = case maps:get(feedback, A) of
                 #{parameters := Fs} -> Fs;
                 undefined -> []
             end,
    #{<<"title">> => T,
      <<"description">> => iolist_to_binary([Cat, " service ", T, " of component ", C,
                                              "; the feedback's parameters are the output"]),
      <<"input">> => #{<<"type">> => <<"object">>,
                       <<"properties">> => maps:from_list([{N, param(N, V, <<"the request's">>)} || {N, V} <- Ps]),
                       <<"additionalProperties">> => false},
      <<"output">> => #{<<"type">> => <<"object">>,
                        <<"properties">> => maps:from_list([{N, param(N, V, <<"the feedback's">>)} || {N, V} <- Output]
                                                          ++ [timestamp()]),
                        <<"additionalProperties">> => #{<<"type">> => <<"string">>}},
      <<"safe">> => false,
      <<"idempotent">> => false,
      <<"synchronous">> => true,
      <<"forms">> => [#{<<"href">> => Path([<<"actions">>, C, T]),
                        <<"op">> => [<<"invokeaction">>],
                        <<"contentType">> => <<"application/json">>,
                        <<"htv:methodName">> => <<"POST">>,
                        <<"additionalResponses">> => [error_response()]}]}.

property(#{component := C, entry := #{type := T, parameters := Ps}}, Path) ->
    #{<<"title">> => T,
      <<"description">> => iolist_to_binary(["the last SENSOR ", T, " reading component ", C,
                                              " pushed (its parameters, and timestamp: ms since 1970)"]),
      <<"type">> => <<"object">>,
      <<"properties">> => maps:from_list([{N, param(N, V, <<"the reading's">>)} || {N, V} <- Ps]
                                        ++ [timestamp()]),
      <<"additionalProperties">> => true,
      <<"readOnly">> => true,
      <<"writeOnly">> => false,
      <<"observable">> => false,
      <<"forms">> => [#{<<"href">> => Path([<<"properties">>, C, T]),
                        <<"op">> => [<<"readproperty">>],
                        <<"contentType">> => <<"application/json">>,
                        <<"htv:methodName">> => <<"GET">>,
                        <<"additionalResponses">> => [error_response()]}]}.

%% ---------------------------------------------------------------------------
%% The MQTT binding of an MQTT Avatar's devices
%% ---------------------------------------------------------------------------

%% Per component, kind and entry type: the device's command topic (with what it
%% publishes there) and its state topic. A topic not on the entry is the
%% first its component gives (docs/mqtt.md section 3.1).
topics(none) ->
    none;
topics(#{host := Host, port := Port, description := #{components := Cs}}) ->
    Base = iolist_to_binary(["mqtt://", Host, ":", integer_to_binary(Port), "/"]),
    Entries = maps:from_list(
                [{{Id, Kind, T}, #{command => mqtt_param(<<"MqttCommandTopic">>, E, Services ++ Consumes),
                                   command_text => mqtt_param(<<"MqttCommand">>, E, [E]),
                                   state => mqtt_param(<<"MqttStateTopic">>, E, Services ++ Consumes)}}
                 || #{id := Id, services := Services, consumes := Consumes} <- Cs,
                    {Kind, Group} <- [{action, Services}, {property, Consumes}],
                    #{type := T} = E <- Group]),
    #{base => Base, entries => Entries}.

mqtt_param(Name, #{parameters := Ps}, Component) ->
    case lists:keyfind(Name, 1, Ps) of
        {_, V} -> V;
        false -> case [V || #{parameters := Ps1} <- Component, {N, V} <- Ps1, N =:= Name] of
                     [V | _] -> V;
                     [] -> undefined
                 end
    end.

%% An action whose device takes commands on a topic: a publish there. The
%% payload is the device's (`bil:mqttCommand', docs/mqtt.md section 3.2),
%% not the HTTP form's input: this form drives the device without EVATAR.
mqtt_action(Td, #{component := C, entry := #{type := T}}, #{base := Base, entries := Es}) ->
    case Es of
        #{{C, action, T} := #{command := Topic, command_text := Command}}
          when is_binary(Topic), is_binary(Command) ->
            Form = #{<<"href">> => <<Base/binary, (topic_path(Topic))/binary>>,
                     <<"op">> => [<<"invokeaction">>],
                     <<"mqv:controlPacket">> => <<"publish">>,
                     <<"mqv:qos">> => <<"1">>,
                     <<"mqv:retain">> => false,
                     <<"contentType">> => <<"text/plain">>,
                     <<"bil:mqttCommand">> => Command},
            add_form(Td, Form);
        #{} ->
            Td
    end;
mqtt_action(Td, _, none) ->
    Td.

%% A property whose device publishes its readings on a topic: subscribe
%% there (its messages are the device's, before EVATAR reads them).
mqtt_property(Td, #{component := C, entry := #{type := T}}, #{base := Base, entries := Es}) ->
    case Es of
        #{{C, property, T} := #{state := Topic}} when is_binary(Topic) ->
            Form = #{<<"href">> => <<Base/binary, (topic_path(Topic))/binary>>,
                     <<"op">> => [<<"observeproperty">>],
                     <<"mqv:controlPacket">> => <<"subscribe">>,
                     <<"contentType">> => <<"text/plain">>},
            (add_form(Td, Form))#{<<"observable">> => true};
        #{} ->
            Td
    end;
mqtt_property(Td, _, none) ->
    Td.

add_form(#{<<"forms">> := Forms} = Td, Form) ->
    Td#{<<"forms">> := Forms ++ [Form]}.

%% A topic as a URI path: each level percent-encoded.
topic_path(Topic) ->
    iolist_to_binary(lists:join("/", [enc(L) || L <- binary:split(Topic, <<"/">>, [global])])).

param(N, V, Whose) ->
    #{<<"type">> => <<"string">>,
      <<"description">> => iolist_to_binary([Whose, " ", N, " (described as ", V, ")"])}.

timestamp() ->
    {<<"timestamp">>, #{<<"type">> => <<"integer">>,
                        <<"description">> => <<"the signal's Timestamp, ms since 1970">>}}.

error_response() ->
    #{<<"success">> => false, <<"contentType">> => <<"application/json">>,
      <<"schema">> => <<"error">>}.

%% The API's error body (docs/api.md section 3); `feedback_timeout' (504)
%% when the Avatar did not answer in the pairing's feedback timeout.
error_schema() ->
    #{<<"type">> => <<"object">>,
      <<"description">> => <<"an error: 503 not_joined or provider_gone, 504 feedback_timeout, "
                             "502 device_error, 409 not_bound, 400 bad_request, 401/403 the token">>,
      <<"properties">> => #{<<"error">> => #{<<"type">> => <<"string">>},
                            <<"field">> => #{<<"description">> => <<"the request's field at fault, or null">>},
                            <<"message">> => #{<<"type">> => <<"string">>}},
      <<"required">> => [<<"error">>, <<"message">>]}.

%% Percent-encodes every byte but RFC 3986's unreserved characters, so an
%% id from a client is one path segment or URN part whatever it holds.
enc(Bin) ->
    << <<(enc_byte(B))/binary>> || <<B>> <= Bin >>.

enc_byte(B) when B >= $a, B =< $z; B >= $A, B =< $Z; B >= $0, B =< $9;
                 B =:= $-; B =:= $.; B =:= $_; B =:= $~ ->
    <<B>>;
enc_byte(B) ->
    list_to_binary(io_lib:format("%~2.16.0B", [B])).

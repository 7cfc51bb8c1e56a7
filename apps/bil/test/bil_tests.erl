%% @doc End-to-end EUnit tests of the bil API: the examples of docs/bil.md
%% parse to the exact terms shown there, encoders and parsers agree,
%% bil:format_error/1 renders each kind of error, and the size and depth
%% limits apply per call and through the `bil' application environment.
-module(bil_tests).

-include_lib("eunit/include/eunit.hrl").

%% docs/bil.md, section 2, verbatim.
-define(DOC_DESCRIPTION, <<"<?xml version=\"1.0\" encoding=\"UTF-8\"?>
<bil:description xmlns:bil=\"urn:evatar:bil:1\">
  <bil:context>
    <EntityID>7008</EntityID>
    <APIName>LIGHT ACTUATOR</APIName>
    <EntityType>Avatar</EntityType>
    <Context>ActuatorDescription</Context>
  </bil:context>
  <bil:types>
    <bil:Component>
      <ComponentID>HomeLightActuator01</ComponentID>
      <Service>
        <ServiceCategory>ACTUATOR</ServiceCategory>
        <ServiceType>TurnLightOn</ServiceType>
        <ServiceParameters>
          <Light>yes</Light>
          <Email>no</Email>
        </ServiceParameters>
      </Service>
      <Consumes>
        <ServiceCategory>ACTUATOR</ServiceCategory>
        <ServiceType>ACTION FEEDBACK</ServiceType>
        <ServiceParameters>
          <Feedback>yes</Feedback>
        </ServiceParameters>
      </Consumes>
    </bil:Component>
  </bil:types>
</bil:description>
">>).

%% docs/bil.md, section 3, verbatim.
-define(DOC_SIGNAL, <<"<?xml version=\"1.0\" encoding=\"UTF-8\"?>
<bil:Envelope xmlns:bil=\"urn:evatar:bil:1\">
  <bil:Header>
    <SignalID>va1-000042</SignalID>
    <Context>RequestAwaitingFeedback</Context>
    <Sender>LightEmulator01</Sender>
    <Receiver>HomeLightActuator01</Receiver>
    <Timestamp>1763800000000</Timestamp>
    <Sequence>42</Sequence>
    <Epoch>1</Epoch>
  </bil:Header>
  <bil:Body>
    <ServiceCategory>ACTUATOR</ServiceCategory>
    <ServiceType>TurnLightOn</ServiceType>
    <ServiceParameters>
      <Light>yes</Light>
      <Room>kitchen</Room>
    </ServiceParameters>
  </bil:Body>
</bil:Envelope>
">>).

%% The term docs/bil.md, section 2, shows.
doc_description() ->
    #{entity_id => <<"7008">>, api_name => <<"LIGHT ACTUATOR">>, entity_type => avatar,
      context => <<"ActuatorDescription">>,
      components => [#{id => <<"HomeLightActuator01">>,
                       services => [#{category => <<"ACTUATOR">>, type => <<"TurnLightOn">>,
                                      parameters => [{<<"Light">>, <<"yes">>},
                                                     {<<"Email">>, <<"no">>}]}],
                       consumes => [#{category => <<"ACTUATOR">>,
                                      type => <<"ACTION FEEDBACK">>,
                                      parameters => [{<<"Feedback">>, <<"yes">>}]}]}]}.

%% The term section 3 describes in words.
doc_signal() ->
    #{id => <<"va1-000042">>, context => request, sender => <<"LightEmulator01">>,
      receiver => <<"HomeLightActuator01">>, in_reply_to => undefined,
      timestamp => 1763800000000, seq => 42, epoch => 1,
      body => #{category => <<"ACTUATOR">>, type => <<"TurnLightOn">>,
                parameters => [{<<"Light">>, <<"yes">>}, {<<"Room">>, <<"kitchen">>}]}}.

%% ---------------------------------------------------------------------------
%% The examples of docs/bil.md
%% ---------------------------------------------------------------------------

doc_description_test() ->
    ?assertEqual({ok, doc_description()}, bil:parse_description(?DOC_DESCRIPTION)),
    ?assertEqual({ok, doc_description()}, bil:parse_description(?DOC_DESCRIPTION, #{})).

doc_signal_test() ->
    ?assertEqual({ok, doc_signal()}, bil:parse_signal(?DOC_SIGNAL)),
    ?assertEqual({ok, doc_signal()}, bil:parse_signal(?DOC_SIGNAL, #{})).

%% Section 2: a missing ServiceParameters parses as []; the encoder writes it.
missing_service_parameters_test() ->
    Doc = binary:replace(?DOC_DESCRIPTION,
                         <<"<ServiceParameters>\n          <Feedback>yes</Feedback>\n"
                           "        </ServiceParameters>\n">>, <<>>),
    {ok, #{components := [#{consumes := [Consumes]}]} = D} = bil:parse_description(Doc),
    ?assertEqual([], maps:get(parameters, Consumes)),
    Encoded = iolist_to_binary(bil:encode_description(D)),
    ?assertMatch({_, _}, binary:match(Encoded, <<"<ServiceParameters/>">>)),
    ?assertEqual({ok, D}, bil:parse_description(Encoded)).

encode_parse_description_test() ->
    Encoded = bil:encode_description(doc_description()),
    ?assertEqual({ok, doc_description()},
                 bil:parse_description(iolist_to_binary(Encoded))).

encode_parse_signal_test() ->
    Encoded = iolist_to_binary(bil:encode_signal(doc_signal())),
    ?assertEqual({ok, doc_signal()}, bil:parse_signal(Encoded)),
    %% Compact: no whitespace between elements.
    ?assertEqual(nomatch, binary:match(Encoded, [<<"> ">>, <<">\n">>])),
    ?assertMatch(<<"<?xml version=\"1.0\" encoding=\"UTF-8\"?>"
                   "<bil:Envelope xmlns:bil=\"urn:evatar:bil:1\">", _/binary>>, Encoded).

%% Every context survives the wire, through its fixed name.
signal_contexts_test() ->
    ?assertEqual([request, request_no_feedback, feedback, progress, sensor_data, event,
                  error], bil:signal_contexts()),
    Reply = fun(C) -> (doc_signal())#{context := C, in_reply_to := <<"va1-000041">>} end,
    [?assertEqual({ok, Reply(C)},
                  bil:parse_signal(iolist_to_binary(bil:encode_signal(Reply(C)))))
     || C <- bil:signal_contexts()].

namespace_test() ->
    ?assertEqual(<<"urn:evatar:bil:1">>, bil:namespace()).

%% Values are kept exactly, markup characters and unicode included.
exact_text_test() ->
    Signal = doc_signal(),
    Odd = <<"  <a & \"b\" 'c'> ]]> \r\n\t é 中 😀  "/utf8>>,
    S = Signal#{sender := Odd,
                body := #{category => <<" ">>, type => <<"x">>,
                          parameters => [{<<"Größe"/utf8>>, Odd}, {<<"empty">>, <<>>}]}},
    ?assertEqual({ok, S}, bil:parse_signal(iolist_to_binary(bil:encode_signal(S)))).

%% ---------------------------------------------------------------------------
%% Errors
%% ---------------------------------------------------------------------------

format_error_path_test() ->
    Doc = binary:replace(?DOC_SIGNAL, <<"<Timestamp>1763800000000</Timestamp>">>,
                         <<"<Timestamp>soon</Timestamp>">>),
    {error, Reason} = bil:parse_signal(Doc),
    ?assertMatch(#{code := bad_value, path := <<"/Envelope/Header/Timestamp">>}, Reason),
    Line = bil:format_error(Reason),
    ?assertMatch(<<"bad_value at /Envelope/Header/Timestamp: ", _/binary>>, Line),
    ?assertMatch({_, _}, binary:match(Line, <<"soon">>)).

format_error_line_column_test() ->
    {error, #{code := Code, line := 2, column := _} = Reason} =
        bil:parse_signal(<<"<bil:Envelope xmlns:bil=\"urn:evatar:bil:1\">\n<bil:Header>">>),
    Line = bil:format_error(Reason),
    Prefix = <<(atom_to_binary(Code))/binary, " at line 2, column ">>,
    ?assertMatch(<<Prefix:(byte_size(Prefix))/binary, _/binary>>, Line).

format_error_plain_test() ->
    {error, #{code := too_large} = Reason} = bil:parse_signal(?DOC_SIGNAL, #{max_size => 10}),
    ?assertEqual(<<"too_large: ", (maps:get(message, Reason))/binary>>,
                 bil:format_error(Reason)).

not_binary_test() ->
    ?assertMatch({error, #{code := not_binary, message := <<_, _/binary>>}},
                 bil:parse_signal(binary_to_list(?DOC_SIGNAL))),
    ?assertMatch({error, #{code := not_binary}}, bil:parse_description(undefined)).

doctype_refused_test() ->
    Doc = <<"<!DOCTYPE x [<!ENTITY a \"aaaa\">]>", ?DOC_SIGNAL/binary>>,
    ?assertMatch({error, #{code := doctype_refused}}, bil:parse_signal(Doc)).

%% The wrong kind of document names what it found.
wrong_kind_test() ->
    ?assertMatch({error, #{code := wrong_root, path := <<"/Envelope">>}},
                 bil:parse_description(?DOC_SIGNAL)),
    ?assertMatch({error, #{code := wrong_root, path := <<"/description">>}},
                 bil:parse_signal(?DOC_DESCRIPTION)).

%% ---------------------------------------------------------------------------
%% Limits
%% ---------------------------------------------------------------------------

max_size_per_call_test() ->
    Size = byte_size(?DOC_SIGNAL),
    ?assertMatch({error, #{code := too_large}}, bil:parse_signal(?DOC_SIGNAL, #{max_size => Size - 1})),
    ?assertEqual({ok, doc_signal()}, bil:parse_signal(?DOC_SIGNAL, #{max_size => Size})),
    DSize = byte_size(?DOC_DESCRIPTION),
    ?assertMatch({error, #{code := too_large}},
                 bil:parse_description(?DOC_DESCRIPTION, #{max_size => DSize - 1})),
    ?assertEqual({ok, doc_description()},
                 bil:parse_description(?DOC_DESCRIPTION, #{max_size => DSize})).

%% Size is checked before parsing: an oversize document is too_large even
%% when it is not XML at all.
max_size_before_parsing_test() ->
    ?assertMatch({error, #{code := too_large}},
                 bil:parse_signal(binary:copy(<<0>>, 65537))),
    ?assertMatch({error, #{code := too_large}},
                 bil:parse_description(binary:copy(<<"<">>, 1048577))).

%% Envelope is depth 1, Body 2, ServiceParameters 3, a parameter 4.
max_depth_per_call_test() ->
    ?assertEqual({ok, doc_signal()}, bil:parse_signal(?DOC_SIGNAL, #{max_depth => 4})),
    ?assertMatch({error, #{code := too_deep}}, bil:parse_signal(?DOC_SIGNAL, #{max_depth => 3})),
    %% description, types, Component, Service, ServiceParameters, parameter.
    ?assertEqual({ok, doc_description()},
                 bil:parse_description(?DOC_DESCRIPTION, #{max_depth => 6})),
    ?assertMatch({error, #{code := too_deep}},
                 bil:parse_description(?DOC_DESCRIPTION, #{max_depth => 5})).

application_env_test_() ->
    {foreach,
     fun() ->
             _ = application:load(bil),
             [{K, application:get_env(bil, K)}
              || K <- [max_signal_size, max_description_size, max_depth]]
     end,
     fun(Saved) ->
             [case V of
                  {ok, Value} -> application:set_env(bil, K, Value);
                  undefined -> application:unset_env(bil, K)
              end || {K, V} <- Saved]
     end,
     [{"max_signal_size from the environment; the call's map wins",
       fun() ->
               Size = byte_size(?DOC_SIGNAL),
               ok = application:set_env(bil, max_signal_size, Size - 1),
               ?assertMatch({error, #{code := too_large}}, bil:parse_signal(?DOC_SIGNAL)),
               ?assertEqual({ok, doc_signal()}, bil:parse_signal(?DOC_SIGNAL, #{max_size => Size})),
               %% The signal limit does not apply to descriptions.
               ?assertEqual({ok, doc_description()}, bil:parse_description(?DOC_DESCRIPTION)),
               ok = application:set_env(bil, max_signal_size, Size),
               ?assertEqual({ok, doc_signal()}, bil:parse_signal(?DOC_SIGNAL))
       end},
      {"max_description_size from the environment",
       fun() ->
               ok = application:set_env(bil, max_description_size, 100),
               ?assertMatch({error, #{code := too_large}},
                            bil:parse_description(?DOC_DESCRIPTION)),
               ?assertEqual({ok, doc_signal()}, bil:parse_signal(?DOC_SIGNAL))
       end},
      {"max_depth from the environment; the call's map wins",
       fun() ->
               ok = application:set_env(bil, max_depth, 3),
               ?assertMatch({error, #{code := too_deep}}, bil:parse_signal(?DOC_SIGNAL)),
               ?assertEqual({ok, doc_signal()}, bil:parse_signal(?DOC_SIGNAL, #{max_depth => 4}))
       end},
      {"the defaults: 64 KiB signals",
       fun() ->
               ok = application:unset_env(bil, max_signal_size),
               Padding = binary:copy(<<" ">>, 65536 - byte_size(?DOC_SIGNAL)),
               ?assertEqual({ok, doc_signal()},
                            bil:parse_signal(<<?DOC_SIGNAL/binary, Padding/binary>>)),
               ?assertMatch({error, #{code := too_large}},
                            bil:parse_signal(<<?DOC_SIGNAL/binary, Padding/binary, " ">>))
       end}]}.

%% ---------------------------------------------------------------------------
%% Shipped examples
%% ---------------------------------------------------------------------------

%% The shipped descriptions (priv/examples) parse and round trip.
examples_test_() ->
    Files = filelib:wildcard(filename:join([code:priv_dir(bil), "examples", "*.xml"])),
    [{filename:basename(F),
      fun() ->
              {ok, Bin} = file:read_file(F),
              case bil:parse_description(Bin) of
                  {ok, D} ->
                      ?assertEqual({ok, D}, bil:parse_description(
                                              iolist_to_binary(bil:encode_description(D))));
                  {error, #{code := wrong_root}} ->
                      {ok, S} = bil:parse_signal(Bin),
                      ?assertEqual({ok, S}, bil:parse_signal(
                                              iolist_to_binary(bil:encode_signal(S))))
              end
      end} || F <- Files].

%% The light actuator example is the paper's Fig. 3, as docs/bil.md shows it.
light_actuator_example_test() ->
    File = filename:join([code:priv_dir(bil), "examples", "light_actuator.xml"]),
    {ok, Bin} = file:read_file(File),
    {ok, D} = bil:parse_description(Bin),
    ?assertMatch(#{entity_id := <<"7008">>, entity_type := avatar,
                           components := [#{id := <<"HomeLightActuator01">>,
                                            services := [#{type := <<"TurnLightOn">>,
                                                           parameters := [{<<"Light">>, <<"yes">>} | _]}],
                                            consumes := [#{type := <<"ACTION FEEDBACK">>}]}]},
                 D).

%% EUnit tests of bil_control: control documents and frame dispatch.
-module(bil_control_tests).

-include_lib("eunit/include/eunit.hrl").

-define(NS, "xmlns:bil=\"urn:evatar:bil:1\"").

hello() ->
    {hello, #{pairing => <<"kitchen">>, role => agent, entity_id => <<"va-1">>,
              credential => <<"s3cr&t <x>">>, protocol_version => 1}}.

report() ->
    #{entities => [<<"va-1">>, <<"7008">>],
      bound => [#{consumer => #{entity => <<"va-1">>, component => <<"LightEmulator01">>},
                  provider => #{entity => <<"7008">>, component => <<"HomeLightActuator01">>},
                  category => <<"ACTUATOR">>, type => <<"TurnLightOn">>,
                  score => 2, candidates => 1}],
      unbound => [#{consumer => #{entity => <<"7008">>, component => <<"HomeLightActuator01">>},
                    category => <<"ACTUATOR">>, type => <<"ACTION FEEDBACK">>,
                    reason => no_provider},
                  #{consumer => #{entity => <<"va-1">>, component => <<"C2">>},
                    category => <<"SENSOR">>, type => <<"Temp">>,
                    reason => parameters_mismatch}]}.

controls() ->
    [hello(),
     {hello, #{pairing => <<"p">>, role => avatar, entity_id => <<"é-1"/utf8>>,
               credential => <<>>, protocol_version => 1}},
     {welcome, #{pairing => <<"kitchen">>, entity_id => <<"va-1">>, session_id => <<"ABCD">>,
                 join_timeout => 5000, max_frame => 1048576}},
     {refused, #{code => <<"BadCredential">>, message => <<"wrong credential">>}},
     {refused, #{code => <<"Malformed">>, message => <<>>}},
     {binding, report()},
     {binding, #{entities => [], bound => [], unbound => []}},
     {bye, <<>>},
     {bye, <<"the pairing was stopped">>},
     {welcome, #{pairing => <<"kitchen">>, entity_id => <<"va-1">>, session_id => <<"ABCD">>,
                 join_timeout => 5000, max_frame => 1048576,
                 ha => #{epoch => 3, resumed => true, last_accepted => <<"va-1-7">>,
                         dedup_window => 1024, heartbeat => 500}}},
     {welcome, #{pairing => <<"k">>, entity_id => <<"v">>, session_id => <<"S">>,
                 join_timeout => 0, max_frame => 1,
                 ha => #{epoch => 1, resumed => false, last_accepted => <<>>,
                         dedup_window => 0, heartbeat => 0}}},
     {resume, #{pairing => <<"kitchen">>, role => avatar, entity_id => <<"7008">>,
                credential => <<"c">>, protocol_version => 2, session_id => <<"ABCD">>,
                received => 42, epoch => 2}},
     {ack, #{}},
     {ack, #{accepted => <<"va-1-9">>}},
     {ack, #{received => 17}},
     {ack, #{accepted => <<"a&b">>, received => 0}}].

parse(Bin) -> bil_control:parse(Bin, #{}).

round_trip_test_() ->
    [?_assertEqual({ok, C}, parse(iolist_to_binary(bil_control:encode(C)))) || C <- controls()].

frame_round_trip_test_() ->
    [?_assertEqual({ok, {control, C}},
                   bil_control:parse_frame(iolist_to_binary(bil_control:encode(C)), #{}))
     || C <- controls()].

hello_bytes_test() ->
    ?assertEqual(<<"<bil:Hello " ?NS "><Pairing>kitchen</Pairing><Role>agent</Role>"
                   "<EntityID>va-1</EntityID><Credential>s3cr&amp;t &lt;x&gt;</Credential>"
                   "<ProtocolVersion>1</ProtocolVersion></bil:Hello>">>,
                 iolist_to_binary(bil_control:encode(hello()))).

indented_with_prolog_test() ->
    Doc = <<"\xEF\xBB\xBF<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<!-- hi -->\n"
            "<b:Refused xmlns:b=\"urn:evatar:bil:1\">\n  <Code>Occupied</Code>\n"
            "  <Message>taken</Message>\n</b:Refused>\n">>,
    ?assertEqual({ok, {control, {refused, #{code => <<"Occupied">>, message => <<"taken">>}}}},
                 bil_control:parse_frame(Doc, #{})).

trailing_fields_ignored_test() ->
    Doc = <<"<bil:Bye " ?NS "><Reason>r</Reason><Later>x</Later></bil:Bye>">>,
    ?assertEqual({ok, {bye, <<"r">>}}, parse(Doc)).

%% A Bye without a Reason but with a field of a later protocol is still a Bye.
later_field_without_reason_test() ->
    Doc = <<"<bil:Bye " ?NS "><Later>x</Later></bil:Bye>">>,
    ?assertEqual({ok, {bye, <<>>}}, parse(Doc)).

signal() ->
    #{id => <<"va1-1">>, context => request, sender => <<"LightEmulator01">>,
      receiver => <<"HomeLightActuator01">>, in_reply_to => undefined,
      timestamp => 1763800000000, seq => undefined, epoch => undefined,
      body => #{category => <<"ACTUATOR">>, type => <<"TurnLightOn">>,
                parameters => [{<<"Light">>, <<"yes">>}]}}.

description() ->
    #{entity_id => <<"7008">>, api_name => <<"LIGHT">>, entity_type => avatar,
      context => <<"ActuatorDescription">>,
      components => [#{id => <<"HomeLightActuator01">>,
                       services => [#{category => <<"ACTUATOR">>, type => <<"TurnLightOn">>,
                                      parameters => []}],
                       consumes => []}]}.

dispatch_signal_test() ->
    Bin = iolist_to_binary(bil:encode_signal(signal())),
    ?assertEqual({ok, {signal, signal()}}, bil_control:parse_frame(Bin, #{})).

dispatch_description_test() ->
    Bin = iolist_to_binary(bil:encode_description(description())),
    ?assertEqual({ok, {description, description()}}, bil_control:parse_frame(Bin, #{})).

signal_limit_applies_to_signals_only_test() ->
    Sig = iolist_to_binary(bil:encode_signal(signal())),
    Desc = iolist_to_binary(bil:encode_description(description())),
    Small = #{signal => #{max_size => 100}},
    ?assertMatch({error, #{code := too_large}}, bil_control:parse_frame(Sig, Small)),
    ?assertMatch({ok, {description, _}}, bil_control:parse_frame(Desc, Small)).

error_code(Bin) ->
    case bil_control:parse_frame(Bin, #{}) of
        {error, #{code := Code, message := M}} when is_binary(M) -> Code;
        Other -> {unexpected, Other}
    end.

errors_test_() ->
    Cases =
        [{malformed, <<"GET / HTTP/1.1\r\n\r\n">>},
         {wrong_root, <<"<bil:Hi " ?NS "/>">>},
         {wrong_namespace, <<"<Hello><Pairing>p</Pairing></Hello>">>},
         {wrong_namespace, <<"<bil:Hello xmlns:bil=\"urn:other\"/>">>},
         {missing_element, <<"<bil:Hello " ?NS "><Pairing>p</Pairing></bil:Hello>">>},
         {unexpected_element, <<"<bil:Hello " ?NS "><Role>agent</Role></bil:Hello>">>},
         {bad_value, <<"<bil:Hello " ?NS "><Pairing>p</Pairing><Role>admin</Role>"
                       "<EntityID>e</EntityID><Credential>c</Credential>"
                       "<ProtocolVersion>1</ProtocolVersion></bil:Hello>">>},
         {bad_value, <<"<bil:Hello " ?NS "><Pairing></Pairing><Role>agent</Role>"
                       "<EntityID>e</EntityID><Credential>c</Credential>"
                       "<ProtocolVersion>1</ProtocolVersion></bil:Hello>">>},
         {bad_value, <<"<bil:Hello " ?NS "><Pairing>p</Pairing><Role>agent</Role>"
                       "<EntityID>e</EntityID><Credential>c</Credential>"
                       "<ProtocolVersion>-1</ProtocolVersion></bil:Hello>">>},
         {bad_value, <<"<bil:Welcome " ?NS "><Pairing>p</Pairing><EntityID>e</EntityID>"
                       "<SessionID>s</SessionID><JoinTimeout>123456789012345678901</JoinTimeout>"
                       "<MaxFrame>1</MaxFrame></bil:Welcome>">>},
         {unexpected_element, <<"<bil:Refused " ?NS "><Code><x/></Code>"
                                "<Message>m</Message></bil:Refused>">>},
         {wrong_namespace, <<"<bil:Refused " ?NS "><bil:Code>c</bil:Code>"
                             "<Message>m</Message></bil:Refused>">>},
         {unexpected_element, <<"<bil:Bye " ?NS ">text</bil:Bye>">>},
         {missing_element, <<"<bil:Binding " ?NS "/>">>},
         {bad_value, <<"<bil:Binding " ?NS "><Entities/><Unbound><ConsumerEntity>a</ConsumerEntity>"
                       "<ConsumerComponent>b</ConsumerComponent>"
                       "<ServiceCategory>c</ServiceCategory><ServiceType>d</ServiceType>"
                       "<Reason>because</Reason></Unbound></bil:Binding>">>},
         {unexpected_element, <<"<bil:Binding " ?NS "><Entities><X>a</X></Entities></bil:Binding>">>},
         {doctype_refused, <<"<!DOCTYPE x [<!ENTITY a \"b\">]><bil:Bye " ?NS "/>">>},
         {malformed, <<"<bil:Bye " ?NS ">">>},
         {malformed, <<>>},
         {not_binary, [<<"<bil:Bye/>">>]}],
    [{atom_to_list(Code), ?_assertMatch(Code, simplify(Code, error_code(Bin)))}
     || {Code, Bin} <- Cases].

%% The XML layer may say truncated where a frame is cut short.
simplify(malformed, truncated) -> malformed;
simplify(_, Code) -> Code.

bound_row_must_precede_unbound_test() ->
    Bound = iolist_to_binary(bil_control:encode({binding, report()})),
    %% Only Bound rows before the first Unbound count; a Bound after it ends
    %% the known part and is ignored like any later field.
    {ok, {binding, R}} = parse(Bound),
    ?assertEqual(report(), R).

control_size_limit_test() ->
    Bin = iolist_to_binary(bil_control:encode({bye, binary:copy(<<"x">>, 200)})),
    ?assertMatch({error, #{code := too_large}},
                 bil_control:parse_frame(Bin, #{control => #{max_size => 100}})).

root_name_test_() ->
    [?_assertEqual({ok, <<"Envelope">>}, bil_control:root_name(<<"  <bil:Envelope>">>)),
     ?_assertEqual({ok, <<"description">>}, bil_control:root_name(<<"<description/>">>)),
     ?_assertEqual({ok, <<"Hello">>},
                   bil_control:root_name(<<"<?xml version=\"1.0\"?><!--c--><x:Hello a='1'>">>)),
     ?_assertEqual(error, bil_control:root_name(<<"<!DOCTYPE x><a/>">>)),
     ?_assertEqual(error, bil_control:root_name(<<"<!-- never closed">>)),
     ?_assertEqual(error, bil_control:root_name(<<"<:Hello/>">>)),
     ?_assertEqual(error, bil_control:root_name(<<0, 0, 0, 1>>))].

ack_bytes_test_() ->
    [?_assertEqual(<<"<bil:Ack " ?NS "><Accepted>x-1</Accepted></bil:Ack>">>,
                   iolist_to_binary(bil_control:encode({ack, #{accepted => <<"x-1">>}}))),
     ?_assertEqual(<<"<bil:Ack " ?NS "><Received>5</Received></bil:Ack>">>,
                   iolist_to_binary(bil_control:encode({ack, #{received => 5}}))),
     ?_assertEqual(<<"<bil:Ack " ?NS "></bil:Ack>">>,
                   iolist_to_binary(bil_control:encode({ack, #{}})))].

%% A later version may append fields: a reader ignores them.
ack_ignores_unknown_fields_test() ->
    ?assertEqual({ok, {ack, #{received => 3}}},
                 parse(<<"<bil:Ack " ?NS "><Received>3</Received><Later>x</Later></bil:Ack>">>)),
    ?assertEqual({ok, {ack, #{}}}, parse(<<"<bil:Ack " ?NS "/>">>)).

ack_bad_values_test_() ->
    [?_assertMatch({error, #{code := bad_value}},
                   parse(<<"<bil:Ack " ?NS "><Received>-1</Received></bil:Ack>">>)),
     ?_assertMatch({error, #{code := bad_value}},
                   parse(<<"<bil:Ack " ?NS "><Accepted></Accepted></bil:Ack>">>)),
     ?_assertMatch({error, #{code := unexpected_element}},
                   parse(<<"<bil:Ack " ?NS ">text</bil:Ack>">>))].

%% A version 1 reader's view of a version 2 Welcome: the appended fields are
%% optional, all or none.
welcome_ha_fields_test_() ->
    V1 = <<"<Pairing>p</Pairing><EntityID>e</EntityID><SessionID>s</SessionID>"
           "<JoinTimeout>1</JoinTimeout><MaxFrame>2</MaxFrame>">>,
    [?_assertMatch({ok, {welcome, #{ha := #{epoch := 4, resumed := false}}}},
                   parse(<<"<bil:Welcome " ?NS ">", V1/binary, "<Epoch>4</Epoch>"
                           "<Resumed>false</Resumed><LastAccepted></LastAccepted>"
                           "<DedupWindow>8</DedupWindow><Heartbeat>9</Heartbeat>"
                           "</bil:Welcome>">>)),
     ?_assertMatch({error, #{code := missing_element}},
                   parse(<<"<bil:Welcome " ?NS ">", V1/binary, "<Epoch>4</Epoch></bil:Welcome>">>)),
     ?_assertMatch({error, #{code := bad_value}},
                   parse(<<"<bil:Welcome " ?NS ">", V1/binary, "<Epoch>4</Epoch>"
                           "<Resumed>yes</Resumed><LastAccepted/><DedupWindow>8</DedupWindow>"
                           "<Heartbeat>9</Heartbeat></bil:Welcome>">>)),
     ?_assertEqual({ok, {welcome, #{pairing => <<"p">>, entity_id => <<"e">>,
                                    session_id => <<"s">>, join_timeout => 1, max_frame => 2}}},
                   parse(<<"<bil:Welcome " ?NS ">", V1/binary, "<Other>4</Other></bil:Welcome>">>))].

resume_missing_field_test() ->
    ?assertMatch({error, #{code := missing_element, path := <<"/Resume/Epoch">>}},
                 parse(<<"<bil:Resume " ?NS "><Pairing>p</Pairing><Role>agent</Role>"
                         "<EntityID>e</EntityID><Credential/><ProtocolVersion>2</ProtocolVersion>"
                         "<SessionID>s</SessionID><Received>0</Received></bil:Resume>">>)).

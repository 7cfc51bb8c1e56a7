#!/usr/bin/env escript
%%! -noshell
%% Generates test/vectors/ (vectors.json, documents/, frames/) from the real
%% Erlang implementation: every document is parsed (and, when canonical,
%% written) by the bil and bil_control codecs, every frame by
%% agent_bridge_frame, and the transcripts and error answers are recorded
%% from a real EVATAR node over real TCP sockets on 127.0.0.1.
%%
%% Run it ONCE, after a change to the protocol, with `make vectors'; review
%% the diff, commit it. Tests never regenerate: they check the committed files
%% (apps/agent_bridge/test/agent_bridge_vectors_SUITE.erl, and the Python and
%% Java suites). The meaning written to `expect' is defined in README.md and
%% computed by apps/agent_bridge/test/agent_bridge_vectors.erl.
-mode(compile).

-define(PAIRING, <<"vectors">>).
-define(AGENT_CRED, <<"va-secret">>).
-define(AVATAR_CRED, <<"avatar-secret">>).
-define(TS, 1763800000000).
-define(QUIET, 400).

main(_) ->
    Dir = filename:dirname(filename:absname(escript:script_name())),
    Root = filename:dirname(filename:dirname(Dir)),
    Base = case os:getenv("REBAR_BASE_DIR") of
               B when is_list(B), B =/= "" -> B;
               _ -> filename:join(Root, "_build")
           end,
    code:add_pathsa(filelib:wildcard(filename:join([Base, "default", "lib", "*", "ebin"]))),
    load_helper(filename:join([Root, "apps", "agent_bridge", "test", "agent_bridge_vectors.erl"])),
    {ok, [Config]} = file:consult(filename:join([Root, "config", "test.config"])),
    [ok = application:set_env(App, K, V, [{persistent, true}])
     || {App, Env} <- Config, App =/= kernel, {K, V} <- Env],
    ok = logger:set_primary_config(level, warning),
    {ok, _} = application:ensure_all_started(evatar),
    {ok, _} = application:ensure_all_started(agent_bridge),
    {ok, _} = evatar:create_pairing(?PAIRING, #{agent_credential => ?AGENT_CRED,
                                                avatar_credential => ?AVATAR_CRED}),
    %% Heartbeat 500, as scripts/test-node.sh (test/vectors/README.md section 3).
    {ok, _} = agent_bridge:start_listener(vectors, #{ip => {127, 0, 0, 1}, port => 0,
                                                     conn => #{heartbeat => 500}}),
    {ok, {_, Port}} = agent_bridge:address(vectors),
    [begin _ = file:del_dir_r(filename:join(Dir, Sub)), ok = file:make_dir(filename:join(Dir, Sub)) end
     || Sub <- ["documents", "frames"]],
    put(dir, Dir),
    Vectors = lists:append([frames(), signals(), controls(), descriptions(),
                            transcripts(Port), errors(Port), invalid()]),
    Names = [N || {obj, [{<<"name">>, N} | _]} <- Vectors],
    length(Names) =:= length(lists:usort(Names)) orelse error(duplicate_names),
    ok = file:write_file(filename:join(Dir, "vectors.json"),
                         agent_bridge_vectors:pretty({obj, [{<<"version">>, 1},
                                                            {<<"vectors">>, Vectors}]})),
    Kinds = lists:foldl(fun({obj, [_, {<<"kind">>, K} | _]}, Acc) ->
                                maps:update_with(K, fun(N) -> N + 1 end, 1, Acc)
                        end, #{}, Vectors),
    io:format("~b vectors: ~p~n", [length(Vectors), Kinds]),
    halt(0).

load_helper(Source) ->
    {ok, Mod, Bin} = compile:file(Source, [binary, report]),
    {module, Mod} = code:load_binary(Mod, Source, Bin).

%% ---------------------------------------------------------------------------
%% The documents
%% ---------------------------------------------------------------------------

sig(Id, Context, Sender, Receiver, InReplyTo, Seq, Epoch, Cat, Type, Params) ->
    #{id => Id, context => Context, sender => Sender, receiver => Receiver,
      in_reply_to => InReplyTo, timestamp => ?TS, seq => Seq, epoch => Epoch,
      body => #{category => Cat, type => Type, parameters => Params}}.

request() ->
    sig(<<"va-1-000042">>, request, <<"LightEmulator01">>, <<"HomeLightActuator01">>,
        undefined, undefined, undefined, <<"ACTUATOR">>, <<"TurnLightOn">>,
        [{<<"Light">>, <<"yes">>}, {<<"Room">>, <<"kitchen">>}]).

hello(Role, Entity, Cred, Version) ->
    {hello, #{pairing => ?PAIRING, role => Role, entity_id => Entity, credential => Cred,
              protocol_version => Version}}.

agent_description() ->
    #{entity_id => <<"va-1">>, api_name => <<"LIGHT VA">>, entity_type => agent,
      context => <<"EmulatorDescription">>,
      components =>
          [#{id => <<"LightEmulator01">>,
             services => [#{category => <<"ACTUATOR">>, type => <<"ACTION FEEDBACK">>,
                            parameters => [{<<"Feedback">>, <<"yes">>}]}],
             consumes => [#{category => <<"ACTUATOR">>, type => <<"TurnLightOn">>,
                            parameters => [{<<"Light">>, <<"yes">>}]}]},
           #{id => <<"LightSensorEmulator01">>,
             services => [#{category => <<"SENSOR">>, type => <<"LightLevel">>,
                            parameters => []}],
             consumes => []}]}.

avatar_description() ->
    #{entity_id => <<"7008">>, api_name => <<"LIGHT ACTUATOR">>, entity_type => avatar,
      context => <<"ActuatorDescription">>,
      components =>
          [#{id => <<"HomeLightActuator01">>,
             services => [#{category => <<"ACTUATOR">>, type => <<"TurnLightOn">>,
                            parameters => [{<<"Light">>, <<"yes">>}, {<<"Email">>, <<"no">>}]}],
             consumes => [#{category => <<"ACTUATOR">>, type => <<"ACTION FEEDBACK">>,
                            parameters => [{<<"Feedback">>, <<"yes">>}]}]},
           #{id => <<"LightSensor01">>,
             services => [#{category => <<"SENSOR">>, type => <<"ReadLightLevel">>,
                            parameters => []}],
             consumes => [#{category => <<"SENSOR">>, type => <<"LightLevel">>,
                            parameters => []}]}]}.

%% ---------------------------------------------------------------------------
%% Vectors of one document
%% ---------------------------------------------------------------------------

write(Sub, Name, Ext, Bytes) ->
    Rel = Sub ++ "/" ++ Name ++ Ext,
    ok = file:write_file(filename:join(get(dir), Rel), Bytes),
    list_to_binary(Rel).

%% A document vector whose `expect' is what the real parser makes of Bytes.
%% `canonical' is true exactly when the real encoder writes Bytes back.
doc(Name, Kind, Bytes0, Notes) ->
    Bytes = iolist_to_binary(Bytes0),
    {ok, Term} = bil_control:parse_frame(Bytes, #{}),
    Expect = agent_bridge_vectors:to_json(Term),
    Kind = agent_bridge_vectors:kind(Expect),
    Canonical = agent_bridge_vectors:encode(Expect) =:= Bytes,
    File = write("documents", Name, ".xml", Bytes),
    {obj, [{<<"name">>, list_to_binary(Name)}, {<<"kind">>, Kind}, {<<"file">>, File},
           {<<"canonical">>, Canonical}, {<<"notes">>, list_to_binary(Notes)},
           {<<"expect">>, Expect}]}.

%% A canonical vector: the document the encoder writes for Term.
canon(Name, Kind, Term, Notes) ->
    Bytes = body(frame_of(Term)),
    V = doc(Name, Kind, Bytes, Notes),
    {obj, [_, _, _, {<<"canonical">>, true} | _]} = V,
    V.

frames() ->
    Frame = fun(Name, Doc0, Notes) ->
                    Doc = iolist_to_binary(Doc0),
                    Bytes = iolist_to_binary(agent_bridge_frame:encode(Doc)),
                    {ok, Doc, <<>>} = agent_bridge_frame:decode(Bytes, 1048576),
                    DocFile = write("documents", Name, ".xml", Doc),
                    File = write("frames", Name, ".bin", Bytes),
                    {obj, [{<<"name">>, list_to_binary(Name)}, {<<"kind">>, <<"frame">>},
                           {<<"file">>, File}, {<<"notes">>, list_to_binary(Notes)},
                           {<<"expect">>, {obj, [{<<"length">>, byte_size(Doc)},
                                                 {<<"document">>, DocFile}]}}]}
            end,
    [Frame("frame_hello", bil_control:encode(
                            {hello, #{pairing => <<"kitchen">>, role => agent,
                                      entity_id => <<"va-1">>, credential => <<"s3cret">>,
                                      protocol_version => 1}}),
           "the Hello of docs/protocol.md section 2: 00 00 00 BC, then 188 bytes"),
     Frame("frame_welcome", bil_control:encode(
                              {welcome, #{pairing => <<"kitchen">>, entity_id => <<"va-1">>,
                                          session_id => <<"5F1C0A9E3B7D4C21A8E0F6B2D9C47E13">>,
                                          join_timeout => 5000, max_frame => 1048576}}),
           "the version 1 Welcome of docs/protocol.md section 2: 00 00 00 DD, then 221 bytes"),
     Frame("frame_refused", bil_control:encode(
                              {refused, #{code => <<"BadCredential">>,
                                          message => <<"wrong credential">>}}),
           "the Refused of docs/protocol.md section 2: 00 00 00 75, then 117 bytes"),
     Frame("frame_signal_request", bil:encode_signal(request()),
           "a request signal as EVATAR's encoder writes it"),
     Frame("frame_description", bil:encode_description(avatar_description()),
           "an Avatar's description (multi-line, as the encoder writes it)"),
     Frame("frame_ack_heartbeat", bil_control:encode({ack, #{}}),
           "the empty Ack EVATAR sends as a version 2 heartbeat"),
     Frame("frame_utf8", bil:encode_signal(
                           (request())#{body := #{category => <<"ACTUATOR">>,
                                                  type => <<"Say">>,
                                                  parameters => [{<<"Text">>,
                                                                  <<"Grüße, 世界 🙂"/utf8>>}]}}),
           "the length counts bytes, not characters: non-ASCII UTF-8 text")].

signals() ->
    R = request(),
    Answer = fun(Context, Params) ->
                     R#{id := <<"av-77">>, context := Context,
                        sender := <<"HomeLightActuator01">>, receiver := <<"LightEmulator01">>,
                        in_reply_to := <<"va-1-000042">>, timestamp := ?TS + 50,
                        body := #{category => <<"ACTUATOR">>, type => <<"ACTION FEEDBACK">>,
                                  parameters => Params}}
             end,
    [canon("signal_request", <<"signal">>, {signal, R},
           "RequestAwaitingFeedback from a VA emulator to an Avatar actuator; no InReplyTo, "
           "Sequence or Epoch (a client does not send them)"),
     canon("signal_request_no_feedback", <<"signal">>,
           {signal, R#{id := <<"va-1-000043">>, context := request_no_feedback}},
           "context Request: no answer expected"),
     canon("signal_feedback", <<"signal">>, {signal, Answer(feedback, [{<<"Done">>, <<"yes">>}])},
           "Feedback answering va-1-000042 (InReplyTo)"),
     canon("signal_progress", <<"signal">>,
           {signal, Answer(progress, [{<<"Percent">>, <<"50">>}])},
           "Progress: the request stays open"),
     canon("signal_sensor_data", <<"signal">>,
           {signal, sig(<<"av-78">>, sensor_data, <<"LightSensor01">>,
                        <<"LightSensorEmulator01">>, undefined, undefined, undefined,
                        <<"SENSOR">>, <<"LightLevel">>, [{<<"Lux">>, <<"312">>}])},
           "SensorData from an Avatar sensor to a VA emulator"),
     canon("signal_event", <<"signal">>,
           {signal, sig(<<"av-79">>, event, <<"Door01">>, <<"DoorEmulator01">>, undefined,
                        undefined, undefined, <<"SENSOR">>, <<"DoorOpened">>, [])},
           "Event with no parameters: written <ServiceParameters/>"),
     canon("signal_error", <<"signal">>,
           {signal, sig(<<"av-80">>, error, <<"HomeLightActuator01">>, <<"LightEmulator01">>,
                        <<"va-1-000042">>, undefined, undefined, <<"ERROR">>,
                        <<"bulb_broken">>, [{<<"Message">>, <<"the bulb is broken">>}])},
           "Error answering a request: category ERROR, type a code, a Message parameter"),
     canon("signal_delivered", <<"signal">>,
           {signal, R#{seq := 7, epoch := 2}},
           "a signal as EVATAR delivers it: with Sequence and Epoch"),
     canon("signal_evatar_timeout", <<"signal">>,
           {signal, (sig(<<"evatar-12">>, feedback, <<"EVATAR">>, <<"LightEmulator01">>,
                         <<"va-1-000042">>, 3, 1, <<"EVATAR">>, <<"Timeout">>,
                         [{<<"Message">>, <<"no feedback within 5000 ms">>}]))#{origin => evatar}},
           "the Feedback EVATAR sends when a request's deadline passes (docs/protocol.md "
           "section 4), marked Origin EVATAR: no entity can send that mark"),
     canon("signal_escaped", <<"signal">>,
           {signal, R#{id := <<"a&b<c>\"d'">>,
                       body := #{category => <<"ACTUATOR">>, type => <<"Say">>,
                                 parameters => [{<<"Text">>, <<"1 < 2 & 3 > 2\r\nnew line \"q\" 'a'">>},
                                                {<<"Unicode">>, <<"Grüße 世界 🙂"/utf8>>}]}}},
           "text escaping: the encoder writes & < > as &amp; &lt; &gt; and CR as &#13;, "
           "and nothing else (quotes, LF and non-ASCII are written as they are)"),
     doc("signal_pretty", <<"signal">>,
         <<"<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
           "<bil:Envelope xmlns:bil=\"urn:evatar:bil:1\">\n"
           "  <bil:Header>\n"
           "    <SignalID>va-1-000042</SignalID>\n"
           "    <Context>RequestAwaitingFeedback</Context>\n"
           "    <Sender>LightEmulator01</Sender>\n"
           "    <Receiver>HomeLightActuator01</Receiver>\n"
           "    <Timestamp>1763800000000</Timestamp>\n"
           "  </bil:Header>\n"
           "  <bil:Body>\n"
           "    <ServiceCategory>ACTUATOR</ServiceCategory>\n"
           "    <ServiceType>TurnLightOn</ServiceType>\n"
           "    <ServiceParameters>\n"
           "      <Light>yes</Light>\n"
           "      <Room>kitchen</Room>\n"
           "    </ServiceParameters>\n"
           "  </bil:Body>\n"
           "</bil:Envelope>\n">>,
         "the signal of signal_request, indented: same meaning, other bytes"),
     doc("signal_other_prefix", <<"signal">>,
         <<"<e:Envelope xmlns:e='urn:evatar:bil:1' version='9'><!-- a comment -->"
           "<e:Header x='1'><SignalID>va-1-000042</SignalID><Context>RequestAwaitingFeedback</Context>"
           "<Sender>LightEmulator01</Sender><Receiver>HomeLightActuator01</Receiver>"
           "<Timestamp>1763800000000</Timestamp></e:Header><?pi ignored?>"
           "<e:Body><ServiceCategory>ACTUATOR</ServiceCategory><ServiceType>TurnLightOn</ServiceType>"
           "<ServiceParameters><Light>yes</Light><Room>kitchen</Room></ServiceParameters>"
           "</e:Body></e:Envelope>">>,
         "another prefix, single quotes, attributes, a comment and a processing instruction: "
         "all ignored; no XML declaration"),
     doc("signal_references", <<"signal">>,
         <<"<bil:Envelope xmlns:bil=\"urn:evatar:bil:1\"><bil:Header><SignalID>&#118;a-1</SignalID>"
           "<Context>Request</Context><Sender>A&amp;B</Sender><Receiver>&#x43;</Receiver>"
           "<Timestamp>0</Timestamp></bil:Header><bil:Body><ServiceCategory>X</ServiceCategory>"
           "<ServiceType>Y</ServiceType><ServiceParameters><Text><![CDATA[<b>&amp;</b>]]></Text>"
           "<Quote>&quot;&apos;&lt;&gt;</Quote><Space>  two  </Space><Empty/></ServiceParameters>"
           "</bil:Body></bil:Envelope>">>,
         "character references, the five predefined entities, CDATA (its text is literal), "
         "whitespace kept in a leaf, an empty parameter"),
     doc("signal_no_parameters_element", <<"signal">>,
         <<"<bil:Envelope xmlns:bil=\"urn:evatar:bil:1\"><bil:Header><SignalID>s1</SignalID>"
           "<Context>Event</Context><Sender>Door01</Sender><Receiver>DoorEmulator01</Receiver>"
           "<Timestamp>1763800000000</Timestamp></bil:Header><bil:Body>"
           "<ServiceCategory>SENSOR</ServiceCategory><ServiceType>DoorOpened</ServiceType>"
           "</bil:Body></bil:Envelope>">>,
         "ServiceParameters left out means no parameters (the encoder writes "
         "<ServiceParameters/>, so not canonical)")].

controls() ->
    Session = <<"5F1C0A9E3B7D4C21A8E0F6B2D9C47E13">>,
    Welcome = #{pairing => <<"kitchen">>, entity_id => <<"va-1">>, session_id => Session,
                join_timeout => 5000, max_frame => 1048576},
    Ha = #{epoch => 2, resumed => true, last_accepted => <<"va-1-000042">>,
           dedup_window => 1024, heartbeat => 500},
    C = fun(Name, Term, Notes) -> canon(Name, <<"control">>, {control, Term}, Notes) end,
    [C("control_hello_v1", {hello, #{pairing => <<"kitchen">>, role => agent,
                                    entity_id => <<"va-1">>, credential => <<"s3cret">>,
                                    protocol_version => 1}},
       "a VA's Hello, protocol version 1"),
     C("control_hello_v2_avatar", {hello, #{pairing => <<"kitchen">>, role => avatar,
                                           entity_id => <<"7008">>, credential => <<>>,
                                           protocol_version => 2}},
       "an Avatar's version 2 Hello with an empty Credential (written <Credential></Credential>)"),
     C("control_resume", {resume, #{pairing => <<"kitchen">>, role => agent,
                                   entity_id => <<"va-1">>, credential => <<"s3cret">>,
                                   protocol_version => 2, session_id => Session,
                                   received => 41, epoch => 2}},
       "Resume: the Hello's fields, then SessionID, Received, Epoch"),
     C("control_welcome_v1", {welcome, Welcome}, "a version 1 Welcome: five fields"),
     C("control_welcome_v2_resumed", {welcome, Welcome#{ha => Ha}},
       "a version 2 Welcome: ten fields; the session continues"),
     C("control_welcome_v2_new", {welcome, Welcome#{ha => Ha#{epoch => 1, resumed => false,
                                                                last_accepted => <<>>}}},
       "a version 2 Welcome of a new session: LastAccepted empty (written "
       "<LastAccepted></LastAccepted>)"),
     C("control_refused", {refused, #{code => <<"BadCredential">>,
                                      message => <<"wrong credential">>}}, "Refused"),
     C("control_refused_unknown_code", {refused, #{code => <<"SomeFutureCode">>,
                                                   message => <<"a code this client "
                                                                 "does not know">>}},
       "a client must accept Refused codes it does not know"),
     C("control_binding", {binding, #{entities => [<<"va-1">>, <<"7008">>],
                                      bound => [#{consumer => #{entity => <<"va-1">>,
                                                                component => <<"LightEmulator01">>},
                                                  provider => #{entity => <<"7008">>,
                                                                component => <<"HomeLightActuator01">>},
                                                  category => <<"ACTUATOR">>,
                                                  type => <<"TurnLightOn">>, score => 1,
                                                  candidates => 1}],
                                      unbound => [#{consumer => #{entity => <<"7008">>,
                                                                  component => <<"HomeLightActuator01">>},
                                                    category => <<"ACTUATOR">>,
                                                    type => <<"ACTION FEEDBACK">>,
                                                    reason => no_provider},
                                                  #{consumer => #{entity => <<"7008">>,
                                                                  component => <<"Door01">>},
                                                    category => <<"ACTUATOR">>,
                                                    type => <<"OpenDoor">>,
                                                    reason => parameters_mismatch}]}},
       "the Binding of docs/protocol.md section 2, with one more Unbound row "
       "(ParametersMismatch)"),
     C("control_binding_alone", {binding, #{entities => [<<"va-1">>], bound => [],
                                            unbound => []}},
       "a Binding with one entity and no rows"),
     C("control_ack_accepted", {ack, #{accepted => <<"va-1-000042">>}},
       "EVATAR to client: everything up to va-1-000042 is accepted"),
     C("control_ack_received", {ack, #{received => 17}},
       "client to EVATAR: everything up to Sequence 17 is processed"),
     C("control_ack_both", {ack, #{accepted => <<"va-1-000042">>, received => 17}},
       "both Ack fields, Accepted first"),
     C("control_ack_heartbeat", {ack, #{}}, "the empty Ack: a heartbeat"),
     C("control_bye", {bye, <<>>}, "Bye without a Reason: reason \"\""),
     C("control_get_binding", {get_binding, #{}},
       "GetBinding (revision 3): no fields; EVATAR answers with the current Binding report"),
     C("control_bye_reason", {bye, <<"the pairing was stopped">>},
       "Bye with a Reason"),
     doc("control_hello_pretty", <<"control">>,
         <<"<?xml version=\"1.0\"?>\n<bil:Hello xmlns:bil=\"urn:evatar:bil:1\">\n"
           "  <Pairing>kitchen</Pairing>\n  <Role>agent</Role>\n  <EntityID>va-1</EntityID>\n"
           "  <Credential/>\n  <ProtocolVersion>1</ProtocolVersion>\n"
           "  <FutureField>ignored</FutureField>\n</bil:Hello>\n">>,
         "whitespace between fields, an XML declaration, <Credential/>, and an unknown "
         "field after the last known one (ignored)"),
     doc("control_bye_reason_empty", <<"control">>,
         <<"<bil:Bye xmlns:bil=\"urn:evatar:bil:1\"><Reason></Reason></bil:Bye>">>,
         "an empty Reason means the same as none; the encoder leaves the field out"),
     doc("control_welcome_v2_extra", <<"control">>,
         <<"<bil:Welcome xmlns:bil=\"urn:evatar:bil:1\"><Pairing>kitchen</Pairing>"
           "<EntityID>va-1</EntityID><SessionID>5F1C0A9E3B7D4C21A8E0F6B2D9C47E13</SessionID>"
           "<JoinTimeout>5000</JoinTimeout><MaxFrame>1048576</MaxFrame><Epoch>2</Epoch>"
           "<Resumed>false</Resumed><LastAccepted/><DedupWindow>1024</DedupWindow>"
           "<Heartbeat>500</Heartbeat><Later>3</Later></bil:Welcome>">>,
         "a version 2 Welcome with a field from a later version (ignored)")].

descriptions() ->
    D = fun(Name, Term, Notes) -> canon(Name, <<"description">>, {description, Term}, Notes) end,
    {ok, Example} = file:read_file(filename:join([filename:dirname(filename:dirname(get(dir))),
                                                  "apps", "bil", "priv", "examples",
                                                  "light_va.xml"])),
    [D("description_avatar", avatar_description(),
       "an Avatar: two components, services and consumes, parameters"),
     D("description_agent", agent_description(),
       "a VA: an emulator and a sensor emulator whose service has no parameters"),
     D("description_empty", #{entity_id => <<"va-9">>, api_name => <<>>, entity_type => agent,
                              context => <<>>, components => []},
       "no components (written <bil:types/>), empty APIName and Context"),
     doc("description_example_light_va", <<"description">>, Example,
         "apps/bil/priv/examples/light_va.xml as it is: a comment, indentation"),
     doc("description_compact", <<"description">>,
         <<"<bil:description xmlns:bil=\"urn:evatar:bil:1\"><bil:context><EntityID>7008</EntityID>"
           "<APIName>LIGHT ACTUATOR</APIName><EntityType>Avatar</EntityType>"
           "<Context>ActuatorDescription</Context></bil:context><bil:types><bil:Component>"
           "<ComponentID>HomeLightActuator01</ComponentID><Service>"
           "<ServiceCategory>ACTUATOR</ServiceCategory><ServiceType>TurnLightOn</ServiceType>"
           "<ServiceParameters><Light>yes</Light></ServiceParameters></Service>"
           "</bil:Component></bil:types></bil:description>">>,
         "the description of docs/protocol.md section 3 on one line")].

%% ---------------------------------------------------------------------------
%% Transcripts, recorded from the node
%% ---------------------------------------------------------------------------

transcripts(Port) ->
    [transcript_v1(Port), transcript_v2(Port), transcript_requests(Port)].

%% A recorder: connections by name; every frame sent and received is a step.
-record(rec, {name, port, conns = #{}, steps = [], n = 0, keep_beat = false}).

%% Sends one frame on Conn, then reads one frame on each connection of
%% Replies, in that order (heartbeats skipped), and checks that nothing else
%% comes: the recording is the same on every run.
client(R0, Conn, Frame0, Replies) ->
    Frame = iolist_to_binary(Frame0),
    R1 = case maps:is_key(Conn, R0#rec.conns) of
             true -> R0;
             false -> R0#rec{conns = maps:put(Conn, agent_bridge_vectors:connect(R0#rec.port),
                                              R0#rec.conns)}
         end,
    ok = agent_bridge_vectors:send_frame(maps:get(Conn, R1#rec.conns), Frame),
    R2 = lists:foldl(fun(From, Acc) ->
                             S = maps:get(From, Acc#rec.conns),
                             {ok, F} = agent_bridge_vectors:recv_frame_skipping(S, 5000, false),
                             step(Acc, <<"server">>, From, F)
                     end, step(R1, <<"client">>, Conn, Frame), Replies),
    [{quiet, C, true} = {quiet, C, lists:member(
                                     agent_bridge_vectors:recv_frame_skipping(S, ?QUIET, false),
                                     [timeout, closed])}
     || {C, S} <- maps:to_list(R2#rec.conns)],
    R2.

client_doc(R, Conn, Term, Replies) ->
    client(R, Conn, agent_bridge_vectors:frame(Term), Replies).

heartbeat_step(R, Conn) ->
    {ok, F} = agent_bridge_vectors:recv_frame_skipping(maps:get(Conn, R#rec.conns), 5000, true),
    {ok, {control, {ack, #{}}}} = bil_control:parse_frame(body(F), #{}),
    step(R, <<"server">>, Conn, F).

body(Frame) -> agent_bridge_vectors:body(Frame).

step(#rec{name = Name, n = N, steps = Steps} = R, From, Conn, Frame) ->
    {ok, Term} = bil_control:parse_frame(body(Frame), #{}),
    Expect = agent_bridge_vectors:to_json(Term),
    File = write("frames", lists:flatten(io_lib:format("~s_~2..0b_~s_~s",
                                                       [Name, N + 1, From, Conn])),
                 ".bin", Frame),
    Step = {obj, [{<<"from">>, From}, {<<"connection">>, list_to_binary(Conn)},
                  {<<"file">>, File}, {<<"expect">>, Expect}]},
    R#rec{n = N + 1, steps = [Step | Steps]}.

finish(#rec{name = Name, steps = Steps, conns = Conns}, Notes) ->
    [gen_tcp:close(S) || S <- maps:values(Conns)],
    timer:sleep(200),
    {obj, [{<<"name">>, list_to_binary(Name)}, {<<"kind">>, <<"transcript">>},
           {<<"notes">>, list_to_binary(Notes)},
           {<<"steps">>, lists:reverse(Steps)}]}.

%% The session of docs/protocol.md section 3, both entities on version 1.
transcript_v1(Port) ->
    R0 = #rec{name = "transcript_v1", port = Port},
    Req = (request())#{id := <<"va-1-000001">>},
    Answer = fun(Id, Context, Params) ->
                     {signal, Req#{id := Id, context := Context,
                                   sender := <<"HomeLightActuator01">>,
                                   receiver := <<"LightEmulator01">>,
                                   in_reply_to := <<"va-1-000001">>, timestamp := ?TS + 50,
                                   body := #{category => <<"ACTUATOR">>,
                                             type => <<"ACTION FEEDBACK">>,
                                             parameters => Params}}}
             end,
    R1 = client_doc(R0, "agent", {control, hello(agent, <<"va-1">>, ?AGENT_CRED, 1)}, ["agent"]),
    R2 = client_doc(R1, "avatar", {control, hello(avatar, <<"7008">>, ?AVATAR_CRED, 1)}, ["avatar"]),
    R3 = client_doc(R2, "agent", {description, agent_description()}, ["agent"]),
    R4 = client_doc(R3, "avatar", {description, avatar_description()}, ["agent", "avatar"]),
    R5 = client_doc(R4, "agent", {signal, Req}, ["avatar"]),
    R6 = client_doc(R5, "avatar", Answer(<<"av-000001">>, progress, [{<<"Percent">>, <<"50">>}]), ["agent"]),
    R7 = client_doc(R6, "avatar", Answer(<<"av-000002">>, feedback, [{<<"Feedback">>, <<"yes">>}]), ["agent"]),
    R8 = client_doc(R7, "avatar", {signal, sig(<<"av-000003">>, sensor_data, <<"LightSensor01">>,
                                               <<"LightSensorEmulator01">>, undefined, undefined,
                                               undefined, <<"SENSOR">>, <<"LightLevel">>,
                                               [{<<"Lux">>, <<"312">>}])}, ["agent"]),
    R9 = client_doc(R8, "agent", {control, {bye, <<>>}}, ["agent", "avatar"]),
    R10 = client_doc(R9, "avatar", {control, {bye, <<>>}}, ["avatar"]),
    finish(R10, "docs/protocol.md section 3 recorded from a node: a VA (connection agent) and "
                "an Avatar (connection avatar) join pairing vectors with version 1, describe "
                "themselves, get Bindings; a request goes to the Avatar, Progress and Feedback "
                "come back, the Avatar pushes sensor data; both say Bye").

%% Version 2 for the VA: Acks, Ack Received, a Resume on a second connection
%% that takes the session over (the first gets Refused SessionResumed), the
%% redelivery of what was not acknowledged, a heartbeat.
transcript_v2(Port) ->
    R0 = #rec{name = "transcript_v2", port = Port},
    Req = (request())#{id := <<"va-1-000001">>},
    R1 = client_doc(R0, "agent", {control, hello(agent, <<"va-1">>, ?AGENT_CRED, 2)}, ["agent"]),
    #rec{steps = [{obj, [_, _, _, {<<"expect">>, #{<<"session_id">> := Session}}]} | _]} = R1,
    R2 = client_doc(R1, "agent", {description, agent_description()}, ["agent"]),
    R3 = client_doc(R2, "avatar", {control, hello(avatar, <<"7008">>, ?AVATAR_CRED, 1)}, ["avatar"]),
    R4 = client_doc(R3, "avatar", {description, avatar_description()}, ["agent", "avatar"]),
    R5 = client_doc(R4, "agent", {signal, Req}, ["agent", "avatar"]),
    R6 = client_doc(R5, "avatar",
                    {signal, Req#{id := <<"av-000001">>, context := feedback,
                                  sender := <<"HomeLightActuator01">>,
                                  receiver := <<"LightEmulator01">>,
                                  in_reply_to := <<"va-1-000001">>, timestamp := ?TS + 50,
                                  body := #{category => <<"ACTUATOR">>,
                                            type => <<"ACTION FEEDBACK">>,
                                            parameters => [{<<"Feedback">>, <<"yes">>}]}}}, ["agent"]),
    Seq1 = last_sequence(R6, "agent"),
    R7 = client_doc(R6, "agent", {control, {ack, #{received => Seq1}}}, []),
    R8 = client_doc(R7, "avatar", {signal, sig(<<"av-000002">>, sensor_data, <<"LightSensor01">>,
                                               <<"LightSensorEmulator01">>, undefined, undefined,
                                               undefined, <<"SENSOR">>, <<"LightLevel">>,
                                               [{<<"Lux">>, <<"312">>}])}, ["agent"]),
    R9 = client_doc(R8, "agent_resumed",
                    {control, {resume, #{pairing => ?PAIRING, role => agent,
                                         entity_id => <<"va-1">>, credential => ?AGENT_CRED,
                                         protocol_version => 2, session_id => Session,
                                         received => Seq1, epoch => 1}}},
                    ["agent", "agent_resumed", "agent_resumed", "agent_resumed"]),
    Seq2 = last_sequence(R9, "agent_resumed"),
    true = Seq2 > Seq1,
    R10 = client_doc(R9, "agent_resumed", {control, {ack, #{received => Seq2}}}, []),
    R11 = heartbeat_step(R10, "agent_resumed"),
    R12 = client_doc(R11, "agent_resumed", {control, {bye, <<>>}}, ["agent_resumed", "avatar"]),
    R13 = client_doc(R12, "avatar", {control, {bye, <<>>}}, ["avatar"]),
    finish(R13, "version 2 recorded from a node: the VA (connection agent) says Hello with "
                "ProtocolVersion 2 and gets a version 2 Welcome; its request is acknowledged "
                "(Ack Accepted); it acknowledges the Feedback (Ack Received); a SensorData it "
                "does not acknowledge is delivered again after it resumes the session on a "
                "second connection (agent_resumed), which makes EVATAR refuse the first with "
                "SessionResumed; after the Welcome comes the current Binding report (revision "
                "3), then the redelivery; an empty Ack (heartbeat) arrives; Bye. The Avatar "
                "speaks version 1").

%% Revision 3, version 1: GetBinding, a request nobody answers (Feedback
%% Timeout to the requester, Event RequestClosed to the provider), and the
%% provider's late Feedback refused NoOpenRequest.
transcript_requests(Port) ->
    R0 = #rec{name = "transcript_requests", port = Port},
    Req = (request())#{id := <<"va-1-000001">>},
    R1 = client_doc(R0, "agent", {control, hello(agent, <<"va-1">>, ?AGENT_CRED, 1)}, ["agent"]),
    R2 = client_doc(R1, "avatar", {control, hello(avatar, <<"7008">>, ?AVATAR_CRED, 1)}, ["avatar"]),
    R3 = client_doc(R2, "agent", {description, agent_description()}, ["agent"]),
    R4 = client_doc(R3, "avatar", {description, avatar_description()}, ["agent", "avatar"]),
    R5 = client_doc(R4, "avatar", {control, {get_binding, #{}}}, ["avatar"]),
    %% Nobody answers: the pairing's feedback timeout (5 s) passes.
    R6 = client(R5, "agent", agent_bridge_vectors:frame({signal, Req}), ["avatar"]),
    R7 = await(R6, ["agent", "avatar"], 15000),
    R8 = client_doc(R7, "avatar",
                    {signal, Req#{id := <<"av-000001">>, context := feedback,
                                  sender := <<"HomeLightActuator01">>,
                                  receiver := <<"LightEmulator01">>,
                                  in_reply_to := <<"va-1-000001">>, timestamp := ?TS + 6000,
                                  body := #{category => <<"ACTUATOR">>,
                                            type => <<"ACTION FEEDBACK">>,
                                            parameters => [{<<"Feedback">>, <<"yes">>}]}}},
                    ["avatar"]),
    R9 = client_doc(R8, "agent", {control, {bye, <<>>}}, ["agent", "avatar"]),
    R10 = client_doc(R9, "avatar", {control, {bye, <<>>}}, ["avatar"]),
    finish(R10, "revision 3 recorded from a node, version 1: the Avatar asks GetBinding and gets "
                "the current Binding report; the VA's request gets no answer, so after the "
                "pairing's feedback timeout (5 s) the VA gets EVATAR's Feedback Timeout and the "
                "Avatar the Event RequestClosed (Reason Timeout); the Avatar's Feedback after "
                "that is answered with the error NoOpenRequest, not delivered; both say Bye").

%% Reads one frame on each connection of Conns, waiting up to Ms for each.
await(R0, Conns, Ms) ->
    R = lists:foldl(fun(Conn, Acc) ->
                            S = maps:get(Conn, Acc#rec.conns),
                            {ok, F} = agent_bridge_vectors:recv_frame_skipping(S, Ms, false),
                            step(Acc, <<"server">>, Conn, F)
                    end, R0, Conns),
    R.

last_sequence(#rec{steps = Steps}, Conn) ->
    Want = list_to_binary(Conn),
    hd([Seq || {obj, [{_, <<"server">>}, {_, C}, _, {_, #{<<"sequence">> := Seq}}]} <- Steps,
               C =:= Want, is_integer(Seq)]).

%% ---------------------------------------------------------------------------
%% Error answers, recorded from the node
%% ---------------------------------------------------------------------------

frame_of(Term) -> agent_bridge_vectors:frame(Term).

raw_frame(Doc) -> iolist_to_binary(agent_bridge_frame:encode(Doc)).

errors(Port) ->
    Hello = frame_of({control, hello(agent, <<"va-1">>, ?AGENT_CRED, 1)}),
    E = fun(Name, Setup, Bytes, Notes) -> error_vector(Port, Name, Setup, Bytes, Notes) end,
    [E("error_bad_credential", none,
       frame_of({control, hello(agent, <<"va-1">>, <<"wrong">>, 1)}),
       "a Hello with the wrong credential"),
     E("error_unknown_pairing", none,
       frame_of({control, {hello, #{pairing => <<"no-such-pairing">>, role => agent,
                                    entity_id => <<"va-1">>, credential => ?AGENT_CRED,
                                    protocol_version => 1}}}),
       "a Hello naming a pairing the node does not have"),
     E("error_second_agent", agent_connected,
       frame_of({control, hello(agent, <<"va-2">>, ?AGENT_CRED, 1)}),
       "a second VA while another VA (va-1) is connected to the pairing"),
     E("error_entity_exists", avatar_connected,
       frame_of({control, hello(avatar, <<"7008">>, ?AVATAR_CRED, 1)}),
       "an Avatar with the EntityID of an Avatar that is connected"),
     E("error_garbage_http", none, <<"GET / HTTP/1.1\r\nHost: localhost\r\n\r\n">>,
       "not frames: the first 4 bytes read as a length of 1,195,725,856"),
     E("error_oversize_frame", none,
       <<65537:32/big, (binary:copy(<<"x">>, 100))/binary>>,
       "a length of 65,537 before the handshake (the limit is 65,536); refused from the "
       "4 length bytes alone"),
     E("error_oversize_after_welcome", none,
       <<Hello/binary, 1048577:32/big, (binary:copy(<<"x">>, 100))/binary>>,
       "a good Hello, then a length of 1,048,577: over MaxFrame"),
     E("error_empty_frame", none, <<0:32>>, "a frame of length 0"),
     E("error_doctype_hello", none,
       raw_frame(<<"<!DOCTYPE bil:Hello [<!ENTITY a \"aaaaaaaaaa\">]>"
                   "<bil:Hello xmlns:bil=\"urn:evatar:bil:1\"><Pairing>vectors</Pairing>"
                   "<Role>agent</Role><EntityID>va-1</EntityID><Credential>va-secret</Credential>"
                   "<ProtocolVersion>1</ProtocolVersion></bil:Hello>">>),
       "a Hello with a DOCTYPE: refused before any entity is expanded"),
     E("error_garbage_document", none, raw_frame(<<"hello?">>),
       "a well-framed first frame that is not XML"),
     E("error_bad_role", none,
       raw_frame(<<"<bil:Hello xmlns:bil=\"urn:evatar:bil:1\"><Pairing>vectors</Pairing>"
                   "<Role>robot</Role><EntityID>va-1</EntityID><Credential>va-secret</Credential>"
                   "<ProtocolVersion>1</ProtocolVersion></bil:Hello>">>),
       "a Hello whose Role is neither agent nor avatar"),
     E("error_first_frame_not_hello", none, frame_of({signal, request()}),
       "a signal before the Hello"),
     E("error_protocol_version_3", none,
       frame_of({control, hello(agent, <<"va-1">>, ?AGENT_CRED, 3)}),
       "a ProtocolVersion the server does not speak"),
     E("error_resume_version_1", none,
       frame_of({control, {resume, #{pairing => ?PAIRING, role => agent, entity_id => <<"va-1">>,
                                     credential => ?AGENT_CRED, protocol_version => 1,
                                     session_id => <<"5F1C0A9E3B7D4C21A8E0F6B2D9C47E13">>,
                                     received => 0, epoch => 1}}}),
       "a Resume with ProtocolVersion 1"),
     E("error_malformed_after_welcome", none, <<Hello/binary, (raw_frame(<<"<oops">>))/binary>>,
       "a good Hello, then a frame that is not well-formed: an Error signal, the connection "
       "stays"),
     E("error_doctype_after_welcome", none,
       <<Hello/binary, (raw_frame(<<"<!DOCTYPE x><bil:Bye xmlns:bil=\"urn:evatar:bil:1\"/>">>))/binary>>,
       "a good Hello, then a DOCTYPE: an Error signal Malformed, the connection stays"),
     E("error_description_refused", none,
       <<Hello/binary, (frame_of({description, (agent_description())#{entity_id := <<"other">>}}))/binary>>,
       "a good Hello, then a description whose EntityID is not the Hello's"),
     E("error_hello_empty_entity", none,
       raw_frame(<<"<bil:Hello xmlns:bil=\"urn:evatar:bil:1\"><Pairing>vectors</Pairing>"
                   "<Role>agent</Role><EntityID></EntityID><Credential>va-secret</Credential>"
                   "<ProtocolVersion>1</ProtocolVersion></bil:Hello>">>),
       "a Hello with an empty EntityID"),
     E("error_hello_missing_credential", none,
       raw_frame(<<"<bil:Hello xmlns:bil=\"urn:evatar:bil:1\"><Pairing>vectors</Pairing>"
                   "<Role>agent</Role><EntityID>va-1</EntityID>"
                   "<ProtocolVersion>1</ProtocolVersion></bil:Hello>">>),
       "a Hello without its Credential field (an empty one must be written)"),
     E("error_hello_fields_out_of_order", none,
       raw_frame(<<"<bil:Hello xmlns:bil=\"urn:evatar:bil:1\"><Role>agent</Role>"
                   "<Pairing>vectors</Pairing><EntityID>va-1</EntityID><Credential>va-secret"
                   "</Credential><ProtocolVersion>1</ProtocolVersion></bil:Hello>">>),
       "a Hello whose fields are not in the documented order"),
     E("error_hello_version_not_digits", none,
       raw_frame(<<"<bil:Hello xmlns:bil=\"urn:evatar:bil:1\"><Pairing>vectors</Pairing>"
                   "<Role>agent</Role><EntityID>va-1</EntityID><Credential>va-secret</Credential>"
                   "<ProtocolVersion>v1</ProtocolVersion></bil:Hello>">>),
       "a Hello whose ProtocolVersion is not digits"),
     E("error_hello_unknown_root", none,
       raw_frame(<<"<bil:Hi xmlns:bil=\"urn:evatar:bil:1\"></bil:Hi>">>),
       "a first frame whose root no document of the protocol has"),
     E("error_bye_first", none, frame_of({control, {bye, <<>>}}),
       "a Bye before the Hello: a valid document, but not a Hello"),
     E("error_hello_reserved_id", none,
       frame_of({control, hello(avatar, <<"e-v-a-t-a-r">>, ?AVATAR_CRED, 1)}),
       "a Hello whose EntityID reads EVATAR once case and non-alphanumerics are ignored"),
     E("error_hello_id_too_long", none,
       frame_of({control, hello(avatar, binary:copy(<<"x">>, 129), ?AVATAR_CRED, 1)}),
       "a Hello whose EntityID is over max_id_length (128 bytes)"),
     E("error_second_hello", none,
       <<Hello/binary, (frame_of({control, hello(agent, <<"va-1">>, ?AGENT_CRED, 1)}))/binary>>,
       "a good Hello, then a second Hello"),
     E("error_v1_ack_with_field", none,
       <<Hello/binary, (frame_of({control, {ack, #{received => 1}}}))/binary>>,
       "a good version 1 Hello, then an Ack Received (version 2 only)"),
     E("error_unknown_root_after_welcome", none,
       <<Hello/binary, (raw_frame(<<"<bil:Hi xmlns:bil=\"urn:evatar:bil:1\"></bil:Hi>">>))/binary>>,
       "a good Hello, then a document whose root the protocol does not have: Malformed, the "
       "connection stays"),
     E("error_unexpected_document", none,
       <<Hello/binary, (frame_of({control, {welcome, #{pairing => ?PAIRING, entity_id => <<"va-1">>,
                                                      session_id => <<"00">>, join_timeout => 1,
                                                      max_frame => 1}}}))/binary>>,
       "a good Hello, then a Welcome (a client does not send one)")].

%% Connects, sends Bytes, and records the answer (agent_bridge_vectors:error_answer/3).
error_vector(Port, Name, Setup, Bytes, Notes) ->
    SetupJson = case Setup of
                    none -> null;
                    _ -> atom_to_binary(Setup)
                end,
    {Code, Close} = agent_bridge_vectors:error_answer(Port, SetupJson, Bytes),
    File = write("frames", Name, ".bin", Bytes),
    io:format("~s: ~s close=~p~n", [Name, Code, Close]),
    {obj, [{<<"name">>, list_to_binary(Name)}, {<<"kind">>, <<"error">>}, {<<"file">>, File},
           {<<"setup">>, SetupJson}, {<<"notes">>, list_to_binary(Notes)},
           {<<"expect">>, {obj, [{<<"error">>, Code}, {<<"close">>, Close}]}}]}.

%% ---------------------------------------------------------------------------
%% Invalid input every decoder refuses (checked offline)
%% ---------------------------------------------------------------------------

invalid() ->
    F = fun(Name, Bytes, Notes) -> invalid_vector(Name, "frames", ".bin", Bytes, Notes) end,
    D = fun(Name, Bytes, Notes) -> invalid_vector(Name, "documents", ".xml", Bytes, Notes) end,
    Hello = <<"<bil:Hello xmlns:bil=\"urn:evatar:bil:1\"><Pairing>p</Pairing><Role>agent</Role>"
              "<EntityID>e</EntityID><Credential>c</Credential>">>,
    [F("invalid_frame_empty", <<0:32>>, "length 0"),
     F("invalid_frame_oversize", <<65537:32/big, "<bil:Bye xmlns:bil=\"urn:evatar:bil:1\"/>">>,
       "a length over 65,536 (the limit before the handshake), refused before the body"),
     F("invalid_frame_http", <<"GET / HTTP/1.1\r\n\r\n">>, "not a frame: an HTTP request"),
     F("invalid_frame_truncated", <<100:32/big, "<bil:Bye xmlns:bil=\"urn:evatar:bil:1\"/>">>,
       "the stream ends before the 100 bytes the length promises"),
     F("invalid_frame_short_prefix", <<0, 0>>, "the stream ends inside the length prefix"),
     D("invalid_doctype", <<"<?xml version=\"1.0\"?><!DOCTYPE lolz [<!ENTITY lol \"lol\">"
                            "<!ENTITY lol2 \"&lol;&lol;&lol;&lol;\">]>"
                            "<bil:Bye xmlns:bil=\"urn:evatar:bil:1\"><Reason>&lol2;</Reason></bil:Bye>">>,
       "a DOCTYPE (here the start of a billion laughs)"),
     D("invalid_unknown_entity", <<"<bil:Bye xmlns:bil=\"urn:evatar:bil:1\"><Reason>&nbsp;</Reason></bil:Bye>">>,
       "an entity reference other than the five predefined ones"),
     D("invalid_bad_utf8", <<"<bil:Bye xmlns:bil=\"urn:evatar:bil:1\"><Reason>caf", 16#E9,
                             "</Reason></bil:Bye>">>,
       "a Latin-1 byte (0xE9) where UTF-8 is required"),
     D("invalid_control_character", <<"<bil:Bye xmlns:bil=\"urn:evatar:bil:1\"><Reason>a", 1,
                                      "</Reason></bil:Bye>">>,
       "a control character (0x01) that XML forbids"),
     D("invalid_not_well_formed", <<"<bil:Bye xmlns:bil=\"urn:evatar:bil:1\"><Reason>x</Reasn></bil:Bye>">>,
       "mismatched end tag"),
     D("invalid_truncated_document", <<Hello/binary, "<ProtocolVer">>,
       "the document ends inside a tag"),
     D("invalid_wrong_namespace", <<"<bil:Bye xmlns:bil=\"urn:evatar:bil:2\"/>">>,
       "a root element in another namespace"),
     D("invalid_fields_in_default_namespace",
       <<"<Hello xmlns=\"urn:evatar:bil:1\"><Pairing>p</Pairing><Role>agent</Role>"
         "<EntityID>e</EntityID><Credential>c</Credential><ProtocolVersion>1</ProtocolVersion>"
         "</Hello>">>,
       "BIL as the default namespace puts the fields in it: refused (bind BIL to a prefix)"),
     D("invalid_unknown_root", <<"<bil:Goodbye xmlns:bil=\"urn:evatar:bil:1\"/>">>,
       "a root element that is no BIL document"),
     D("invalid_missing_field", <<"<bil:Refused xmlns:bil=\"urn:evatar:bil:1\"><Code>X</Code></bil:Refused>">>,
       "a Refused without its Message"),
     D("invalid_number", <<Hello/binary, "<ProtocolVersion>-1</ProtocolVersion></bil:Hello>">>,
       "a number that is not 1 to 20 decimal digits"),
     D("invalid_signal_context",
       <<"<bil:Envelope xmlns:bil=\"urn:evatar:bil:1\"><bil:Header><SignalID>s</SignalID>"
         "<Context>Shout</Context><Sender>a</Sender><Receiver>b</Receiver><Timestamp>1</Timestamp>"
         "</bil:Header><bil:Body><ServiceCategory>c</ServiceCategory><ServiceType>t</ServiceType>"
         "</bil:Body></bil:Envelope>">>,
       "a signal Context that is not one of the seven"),
     D("invalid_signal_origin",
       <<"<bil:Envelope xmlns:bil=\"urn:evatar:bil:1\"><bil:Header><SignalID>s</SignalID>"
         "<Context>Event</Context><Sender>a</Sender><Receiver>b</Receiver><Timestamp>1</Timestamp>"
         "<Origin>lamp</Origin></bil:Header><bil:Body><ServiceCategory>c</ServiceCategory>"
         "<ServiceType>t</ServiceType></bil:Body></bil:Envelope>">>,
       "an Origin other than EVATAR (the only value: EVATAR's mark on its own signals)"),
     D("invalid_duplicate_parameter",
       <<"<bil:Envelope xmlns:bil=\"urn:evatar:bil:1\"><bil:Header><SignalID>s</SignalID>"
         "<Context>Event</Context><Sender>a</Sender><Receiver>b</Receiver><Timestamp>1</Timestamp>"
         "</bil:Header><bil:Body><ServiceCategory>c</ServiceCategory><ServiceType>t</ServiceType>"
         "<ServiceParameters><A>1</A><A>2</A></ServiceParameters></bil:Body></bil:Envelope>">>,
       "two parameters with one name"),
     D("invalid_too_deep", [<<"<bil:Bye xmlns:bil=\"urn:evatar:bil:1\"><Reason>">>,
                            lists:duplicate(40, <<"<a>">>), lists:duplicate(40, <<"</a>">>),
                            <<"</Reason></bil:Bye>">>],
       "elements nested deeper than 32")].

invalid_vector(Name, Sub, Ext, Bytes0, Notes) ->
    Bytes = iolist_to_binary(Bytes0),
    Class = case Sub of
                "frames" ->
                    case agent_bridge_frame:decode(Bytes, 65536) of
                        {error, empty_frame} -> <<"empty_frame">>;
                        {error, {too_large, _}} -> <<"frame_too_large">>;
                        {more, _} -> <<"truncated_frame">>
                    end;
                "documents" ->
                    {error, #{code := Code}} = bil_control:parse_frame(Bytes, #{}),
                    atom_to_binary(Code)
            end,
    File = write(Sub, Name, Ext, Bytes),
    {obj, [{<<"name">>, list_to_binary(Name)}, {<<"kind">>, <<"invalid">>}, {<<"file">>, File},
           {<<"notes">>, list_to_binary(Notes)},
           {<<"expect">>, {obj, [{<<"error">>, Class}]}}]}.

%% @doc Checks the XML Schema apps/bil/priv/bil.xsd and the example documents
%% of apps/bil/priv/examples/ against each other, against the BIL parser and
%% against the binder: every example is schema-valid, parses and binds as
%% docs/bil.md says, and typical mistakes are refused by schema and parser.
-module(bil_schema_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("xmerl/include/xmerl.hrl").

-export([all/0, groups/0, suite/0, init_per_group/2, end_per_group/2]).
%% schema
-export([example_set_is_complete/1, examples_are_valid/1,
         signal_examples_cover_every_context/1]).
%% invalid: one case per entry of invalid/0
-export([wrong_entity_type/1, entity_type_wrong_case/1, missing_service_type/1,
         fields_out_of_order/1, header_fields_out_of_order/1,
         non_digit_timestamp/1, timestamp_over_20_digits/1, signed_sequence/1,
         unknown_signal_context/1, field_in_bil_namespace/1,
         header_field_in_bil_namespace/1, structural_element_wrong_namespace/1,
         duplicate_component_id/1, empty_component_id/1, empty_sender/1,
         component_without_service/1, unknown_header_field/1,
         text_in_structural_element/1, unknown_root/1]).
%% parser
-export([examples_parse/1, light_actuator_term/1, signal_request_term/1,
         signal_examples_terms/1, encoder_output_is_valid/1,
         invalid_documents_refused_by_parser/1,
         schema_gaps_refused_by_parser/1]).
%% binding
-export([light_pair_binds/1, lego_pair_binds/1, smart_home_pair_binds/1,
         docs_unbound_examples/1, docs_several_candidates_example/1]).
%% xmllint
-export([xmllint_accepts_examples/1, xmllint_rejects_invalid/1]).

-define(NS, "urn:evatar:bil:1").

%% ---------------------------------------------------------------------------
%% Common Test
%% ---------------------------------------------------------------------------

suite() ->
    [{timetrap, {minutes, 2}}].

all() ->
    [{group, schema}, {group, invalid}, {group, parser}, {group, binding},
     {group, xmllint}].

groups() ->
    [{schema, [parallel],
      [example_set_is_complete, examples_are_valid,
       signal_examples_cover_every_context]},
     {invalid, [parallel], [Name || {Name, _, _, _} <- invalid()]},
     {parser, [parallel],
      [examples_parse, light_actuator_term, signal_request_term,
       signal_examples_terms, encoder_output_is_valid,
       invalid_documents_refused_by_parser, schema_gaps_refused_by_parser]},
     {binding, [parallel],
      [light_pair_binds, lego_pair_binds, smart_home_pair_binds,
       docs_unbound_examples, docs_several_candidates_example]},
     {xmllint, [parallel],
      [xmllint_accepts_examples, xmllint_rejects_invalid]}].

%% xmllint is a second, independent validator: it shows the schema is
%% standard XML Schema and not shaped around xmerl_xsd's gaps alone.
init_per_group(xmllint, Config) ->
    case os:find_executable("xmllint") of
        false -> {skip, "xmllint not installed (Debian package libxml2-utils)"};
        Path -> [{xmllint, Path} | Config]
    end;
init_per_group(_Group, Config) ->
    Config.

end_per_group(_Group, _Config) ->
    ok.

%% ---------------------------------------------------------------------------
%% The examples
%% ---------------------------------------------------------------------------

descriptions() ->
    ["light_actuator.xml", "light_va.xml", "lego_robot.xml", "lego_va.xml",
     "smart_home.xml", "smart_home_va.xml"].

%% Each signal example and the context it carries.
signals() ->
    [{"signal_request.xml", request},
     {"signal_request_no_feedback.xml", request_no_feedback},
     {"signal_feedback.xml", feedback},
     {"signal_progress.xml", progress},
     {"signal_sensor_data.xml", sensor_data},
     {"signal_event.xml", event},
     {"signal_error.xml", error}].

examples() ->
    descriptions() ++ [F || {F, _} <- signals()].

%% ---------------------------------------------------------------------------
%% schema
%% ---------------------------------------------------------------------------

%% @doc The examples directory holds exactly the documented examples.
example_set_is_complete(_Config) ->
    Found = lists:sort(filelib:wildcard("*.xml", examples_dir())),
    Expected = lists:sort(examples()),
    case Found of
        Expected -> ok;
        _ -> ct:fail({example_set, {missing, Expected -- Found}, {extra, Found -- Expected}})
    end.

%% @doc Every example validates against bil.xsd and has the right root.
examples_are_valid(_Config) ->
    Schema = schema(),
    Results = [{File, validate_file(example(File), Schema)} || File <- examples()],
    case [{F, R} || {F, R} <- Results, R =/= ok] of
        [] -> ok;
        Bad -> ct:fail({invalid_examples, Bad})
    end,
    [{?NS, "description"} = root(example(F)) || F <- descriptions()],
    [{?NS, "Envelope"} = root(example(F)) || {F, _} <- signals()],
    ok.

%% @doc There is one signal example per signal context.
signal_examples_cover_every_context(_Config) ->
    Contexts = lists:sort(bil:signal_contexts()),
    Contexts = lists:sort([C || {_, C} <- signals()]).

%% ---------------------------------------------------------------------------
%% invalid: a valid example with one mistake, the replacements that make it,
%% and the xmerl_xsd reason expected among the errors
%% ---------------------------------------------------------------------------

invalid() ->
    [{wrong_entity_type, "light_actuator.xml",
      [{"<EntityType>Avatar</EntityType>", "<EntityType>Robot</EntityType>"}],
      enumeration},
     {entity_type_wrong_case, "light_actuator.xml",
      [{"<EntityType>Avatar</EntityType>", "<EntityType>avatar</EntityType>"}],
      enumeration},
     {missing_service_type, "light_actuator.xml",
      [{"<ServiceType>TurnLightOn</ServiceType>", ""}],
      missing_mandatory_elements},
     {fields_out_of_order, "light_actuator.xml",
      [{"<EntityID>7008</EntityID>\n    <APIName>LIGHT ACTUATOR</APIName>",
        "<APIName>LIGHT ACTUATOR</APIName>\n    <EntityID>7008</EntityID>"}],
      missing_mandatory_elements},
     {header_fields_out_of_order, "signal_request.xml",
      [{"<Sequence>42</Sequence>\n    <Epoch>1</Epoch>",
        "<Epoch>1</Epoch>\n    <Sequence>42</Sequence>"}],
      unexpected_rest},
     {non_digit_timestamp, "signal_request.xml",
      [{"<Timestamp>1763800000000</Timestamp>",
        "<Timestamp>2025-11-22T08:26:40Z</Timestamp>"}],
      pattern_mismatch},
     {timestamp_over_20_digits, "signal_request.xml",
      [{"<Timestamp>1763800000000</Timestamp>",
        "<Timestamp>123456789012345678901</Timestamp>"}],
      maxLength},
     {signed_sequence, "signal_request.xml",
      [{"<Sequence>42</Sequence>", "<Sequence>+42</Sequence>"}],
      pattern_mismatch},
     {unknown_signal_context, "signal_request.xml",
      [{"<Context>RequestAwaitingFeedback</Context>", "<Context>Reply</Context>"}],
      enumeration},
     {field_in_bil_namespace, "light_actuator.xml",
      [{"<EntityID>7008</EntityID>", "<bil:EntityID>7008</bil:EntityID>"}],
      unqualified_name_required},
     {header_field_in_bil_namespace, "signal_feedback.xml",
      [{"<InReplyTo>va1-000042</InReplyTo>", "<bil:InReplyTo>va1-000042</bil:InReplyTo>"}],
      unqualified_name_required},
     {structural_element_wrong_namespace, "light_actuator.xml",
      [{"<bil:types>", "<x:types xmlns:x=\"urn:example:other\">"},
       {"</bil:types>", "</x:types>"}],
      missing_mandatory_elements},
     {duplicate_component_id, "lego_robot.xml",
      [{"<ComponentID>MotorB</ComponentID>", "<ComponentID>MotorA</ComponentID>"}],
      key_value_not_unique},
     {empty_component_id, "light_actuator.xml",
      [{"<ComponentID>HomeLightActuator01</ComponentID>", "<ComponentID></ComponentID>"}],
      minLength},
     {empty_sender, "signal_request.xml",
      [{"<Sender>LightEmulator01</Sender>", "<Sender/>"}],
      minLength},
     {component_without_service, "light_actuator.xml",
      [{"<Service>", "<Consumes>"}, {"</Service>", "</Consumes>"}],
      missing_mandatory_elements},
     {unknown_header_field, "signal_request.xml",
      [{"<Timestamp>", "<Priority>high</Priority>\n    <Timestamp>"}],
      missing_mandatory_elements},
     {text_in_structural_element, "light_actuator.xml",
      [{"<bil:types>", "<bil:types>lights"}],
      match_failure},
     {unknown_root, "signal_request.xml",
      [{"bil:Envelope", "bil:Message"}],
      element_not_in_schema}].

%% @doc An EntityType other than Agent or Avatar is refused.
wrong_entity_type(Config) -> rejected(?FUNCTION_NAME, Config).
%% @doc EntityType is exact: `avatar' is not `Avatar'.
entity_type_wrong_case(Config) -> rejected(?FUNCTION_NAME, Config).
%% @doc An entry without ServiceType is refused.
missing_service_type(Config) -> rejected(?FUNCTION_NAME, Config).
%% @doc Fields of bil:context in another order are refused.
fields_out_of_order(Config) -> rejected(?FUNCTION_NAME, Config).
%% @doc Header fields in another order (Epoch before Sequence) are refused.
header_fields_out_of_order(Config) -> rejected(?FUNCTION_NAME, Config).
%% @doc A Timestamp that is not decimal digits is refused.
non_digit_timestamp(Config) -> rejected(?FUNCTION_NAME, Config).
%% @doc A Timestamp of 21 digits is refused.
timestamp_over_20_digits(Config) -> rejected(?FUNCTION_NAME, Config).
%% @doc A sign in a number field is refused.
signed_sequence(Config) -> rejected(?FUNCTION_NAME, Config).
%% @doc A signal Context outside the seven is refused.
unknown_signal_context(Config) -> rejected(?FUNCTION_NAME, Config).
%% @doc A description field in the BIL namespace is refused.
field_in_bil_namespace(Config) -> rejected(?FUNCTION_NAME, Config).
%% @doc A header field in the BIL namespace is refused.
header_field_in_bil_namespace(Config) -> rejected(?FUNCTION_NAME, Config).
%% @doc A structural element in another namespace is refused.
structural_element_wrong_namespace(Config) -> rejected(?FUNCTION_NAME, Config).
%% @doc Two components with the same ComponentID are refused (xs:unique).
duplicate_component_id(Config) -> rejected(?FUNCTION_NAME, Config).
%% @doc An empty ComponentID is refused.
empty_component_id(Config) -> rejected(?FUNCTION_NAME, Config).
%% @doc An empty Sender is refused.
empty_sender(Config) -> rejected(?FUNCTION_NAME, Config).
%% @doc A component must provide at least one Service.
component_without_service(Config) -> rejected(?FUNCTION_NAME, Config).
%% @doc A header field BIL does not define is refused.
unknown_header_field(Config) -> rejected(?FUNCTION_NAME, Config).
%% @doc Text inside a structural element is refused.
text_in_structural_element(Config) -> rejected(?FUNCTION_NAME, Config).
%% @doc A root element BIL does not define is refused.
unknown_root(Config) -> rejected(?FUNCTION_NAME, Config).

rejected(Name, Config) ->
    {Name, Base, _Edits, Expected} = lists:keyfind(Name, 1, invalid()),
    File = invalid_file(Name, Config),
    %% The unmodified example is valid, so the edit is what is refused.
    ok = validate_file(example(Base), schema()),
    case validate_file(File, schema()) of
        ok ->
            ct:fail({accepted_by_schema, Name});
        {error, Errors} ->
            Reasons = reasons(Errors),
            case lists:member(Expected, Reasons) of
                true -> ok;
                false -> ct:fail({unexpected_reasons, Name, Expected, Errors})
            end
    end.

%% ---------------------------------------------------------------------------
%% parser
%% ---------------------------------------------------------------------------

%% @doc Every example parses with bil:parse_description/1 or parse_signal/1.
examples_parse(_Config) ->
    Results = [{F, parse(F)} || F <- examples()],
    case [{F, R} || {F, {error, _} = R} <- Results] of
        [] -> ok;
        Bad -> ct:fail({parse_errors, Bad})
    end.

%% @doc The light actuator parses to exactly the term of Fig. 3.
light_actuator_term(_Config) ->
    Expected =
        #{entity_id => <<"7008">>, api_name => <<"LIGHT ACTUATOR">>,
          entity_type => avatar, context => <<"ActuatorDescription">>,
          components =>
              [#{id => <<"HomeLightActuator01">>,
                 services =>
                     [#{category => <<"ACTUATOR">>, type => <<"TurnLightOn">>,
                        parameters => [{<<"Light">>, <<"yes">>}, {<<"Email">>, <<"no">>},
                                       {<<"TextMsg">>, <<"no">>},
                                       {<<"RotationSpeed">>, <<"no">>},
                                       {<<"Duration">>, <<"no">>}, {<<"Angle">>, <<"no">>},
                                       {<<"Speed">>, <<"no">>}]}],
                 consumes =>
                     [#{category => <<"ACTUATOR">>, type => <<"ACTION FEEDBACK">>,
                        parameters => [{<<"Feedback">>, <<"yes">>}]}]}]},
    {ok, Expected} = parse("light_actuator.xml").

%% @doc The request of Fig. 4 parses to the term docs/bil.md describes.
signal_request_term(_Config) ->
    Expected = #{id => <<"va1-000042">>, context => request,
                 sender => <<"LightEmulator01">>, receiver => <<"HomeLightActuator01">>,
                 in_reply_to => undefined, timestamp => 1763800000000, seq => 42,
                 epoch => 1,
                 body => #{category => <<"ACTUATOR">>, type => <<"TurnLightOn">>,
                           parameters => [{<<"Light">>, <<"yes">>},
                                          {<<"Room">>, <<"kitchen">>}]}},
    {ok, Expected} = parse("signal_request.xml").

%% @doc Each signal example carries its context, and answers name a request.
signal_examples_terms(_Config) ->
    Answers = [feedback, progress, error],
    lists:foreach(
      fun({File, Context}) ->
              {ok, #{context := Context, in_reply_to := InReplyTo,
                     timestamp := Ts, body := #{category := Category}}} = parse(File),
              true = is_integer(Ts) andalso Ts > 0,
              case lists:member(Context, Answers) of
                  true -> true = is_binary(InReplyTo);
                  false -> undefined = InReplyTo
              end,
              case Context of
                  error -> <<"ERROR">> = Category;
                  _ -> ok
              end
      end, signals()),
    {ok, #{body := #{parameters := ErrorParams}}} = parse("signal_error.xml"),
    {<<"Message">>, _} = lists:keyfind(<<"Message">>, 1, ErrorParams),
    ok.

%% @doc Encoding a parsed example gives a schema-valid document that parses
%% back to the same term.
encoder_output_is_valid(Config) ->
    Schema = schema(),
    lists:foreach(
      fun(File) ->
              {ok, Term} = parse(File),
              Encoded = iolist_to_binary(encode(File, Term)),
              {ok, Term} = parse(File, Encoded),
              Out = filename:join(?config(priv_dir, Config), "encoded_" ++ File),
              ok = file:write_file(Out, Encoded),
              case validate_file(Out, Schema) of
                  ok -> ok;
                  Err -> ct:fail({encoded_invalid, File, Err})
              end
      end, examples()).

%% @doc The parser refuses every document the schema refuses above.
invalid_documents_refused_by_parser(Config) ->
    Accepted = [Name || {Name, Base, _, _} <- invalid(),
                        element(1, parse(Base, read(invalid_file(Name, Config)))) =:= ok],
    [] = Accepted.

%% @doc The parser refuses what xmerl_xsd lets through: fields under a
%% default BIL namespace, a prefixed parameter, an unprefixed structural
%% element, and (no schema can refuse it) a structural element as root.
schema_gaps_refused_by_parser(Config) ->
    lists:foreach(
      fun({Name, Code}) ->
              {error, #{code := Code}} =
                  bil:parse_description(read(gap_file(Name, Config)))
      end,
      [{default_namespace, wrong_namespace}, {prefixed_parameter, wrong_namespace},
       {unqualified_structural, wrong_namespace}, {component_as_root, wrong_root}]).

%% ---------------------------------------------------------------------------
%% binding
%% ---------------------------------------------------------------------------

%% @doc The light actuator and its VA bind both ways, as docs/bil.md works out.
light_pair_binds(_Config) ->
    #{bound := Bound, unbound := []} =
        bil:bind([description("light_actuator.xml"), description("light_va.xml")]),
    [#{consumer := #{entity := <<"7008">>, component := <<"HomeLightActuator01">>},
       provider := #{entity := <<"golem-light-va-01">>, component := <<"LightEmulator01">>},
       category := <<"ACTUATOR">>, type := <<"ACTION FEEDBACK">>,
       score := 1, candidates := 1},
     #{consumer := #{entity := <<"golem-light-va-01">>, component := <<"LightEmulator01">>},
       provider := #{entity := <<"7008">>, component := <<"HomeLightActuator01">>},
       category := <<"actuator">>, type := <<"TurnLightOn">>,
       score := 2, candidates := 1}] = Bound.

%% @doc Every consumer of the LEGO robot and of its VA binds to its partner.
lego_pair_binds(_Config) ->
    Robot = ["MotorA", "MotorB", "MotorC", "LightSensor", "TouchSensor",
             "ForwardBehaviour", "RotateBehaviour", "StopBehaviour",
             "ExploreBehaviour", "GoToBehaviour", "GrabBehaviour", "ReleaseBehaviour"],
    pair_binds("lego_robot.xml", "lego_va.xml",
               [{C, C ++ "Emulator"} || C <- Robot]).

%% @doc Every consumer of the smart home and of its VA binds to its partner.
smart_home_pair_binds(_Config) ->
    pair_binds("smart_home.xml", "smart_home_va.xml",
               [{"HallMotionSensor01", "MotionEmulator01"},
                {"HallCamera01", "CameraEmulator01"},
                {"LivingLightSwitch01", "LivingLightEmulator01"},
                {"KitchenLightSwitch01", "KitchenLightEmulator01"},
                {"BedroomSocketSwitch01", "LampEmulator01"},
                {"LivingMicrophone01", "MicrophoneEmulator01"},
                {"Notifier01", "NotifierEmulator01"},
                {"TimeSensor01", "TimeEmulator01"},
                {"HallSpeaker01", "SpeakerEmulator01"},
                {"DoorKeypad01", "KeypadEmulator01"},
                {"LivingMotionSensor01", "LivingMotionEmulator01"},
                {"KitchenMotionSensor01", "KitchenMotionEmulator01"},
                {"BedroomMotionSensor01", "BedroomMotionEmulator01"}]).

%% @doc The unbound entries of docs/bil.md's worked example, one per reason.
docs_unbound_examples(_Config) ->
    Va = add_consumes(description("light_va.xml"),
                      [entry(<<"ACTUATOR">>, <<"TurnLightOff">>, [{<<"Light">>, <<"yes">>}]),
                       entry(<<"ACTUATOR">>, <<"TurnLightOn">>, [{<<"Room">>, <<"kitchen">>}])]),
    Emulator = #{entity => <<"golem-light-va-01">>, component => <<"LightEmulator01">>},
    #{bound := [_, _],
      unbound := [#{consumer := Emulator, type := <<"TurnLightOff">>, reason := no_provider},
                  #{consumer := Emulator, type := <<"TurnLightOn">>,
                    reason := parameters_mismatch}]} =
        bil:bind([description("light_actuator.xml"), Va]).

%% @doc docs/bil.md's several-candidates example: score first, then
%% registration order, then document order.
docs_several_candidates_example(_Config) ->
    Light = [{<<"Light">>, <<"yes">>}],
    Va = #{entity_id => <<"golem-home-va-02">>, api_name => <<>>, entity_type => agent,
           context => <<>>,
           components =>
               [#{id => <<"AnyLight">>, services => [feedback_service()],
                  consumes => [entry(<<"ACTUATOR">>, <<"TurnLightOn">>, Light)]},
                #{id => <<"QuietLight">>, services => [feedback_service()],
                  consumes => [entry(<<"ACTUATOR">>, <<"TurnLightOn">>,
                                     Light ++ [{<<"Email">>, <<"no">>}])]},
                #{id => <<"KitchenLight">>, services => [feedback_service()],
                  consumes => [entry(<<"ACTUATOR">>, <<"TurnLightOn">>,
                                     Light ++ [{<<"Room">>, <<"kitchen">>}])]}]},
    #{bound := Bound} = bil:bind([description("smart_home.xml"),
                                  description("light_actuator.xml"), Va]),
    Mine = [{C, P, S, N} || #{consumer := #{entity := <<"golem-home-va-02">>, component := C},
                              provider := #{component := P}, score := S,
                              candidates := N} <- Bound],
    [{<<"AnyLight">>, <<"LivingLightSwitch01">>, 1, 3},
     {<<"QuietLight">>, <<"HomeLightActuator01">>, 2, 3},
     {<<"KitchenLight">>, <<"KitchenLightSwitch01">>, 2, 1}] = Mine.

pair_binds(AvatarFile, VaFile, Partners) ->
    Avatar = description(AvatarFile),
    Va = description(VaFile),
    #{bound := Bound, unbound := Unbound} = bil:bind([Avatar, Va]),
    [] = Unbound,
    Consumers = count_consumes(Avatar) + count_consumes(Va),
    Consumers = length(Bound),
    Pairs = [{list_to_binary(A), list_to_binary(V)} || {A, V} <- Partners],
    Wrong = [B || #{consumer := #{component := C}, provider := #{component := P},
                    candidates := N} = B <- Bound,
                  N =/= 1 orelse not (lists:member({C, P}, Pairs)
                                      orelse lists:member({P, C}, Pairs))],
    case Wrong of
        [] -> ok;
        _ -> ct:fail({unexpected_bindings, Wrong})
    end.

count_consumes(#{components := Components}) ->
    lists:sum([length(Cs) || #{consumes := Cs} <- Components]).

add_consumes(#{components := [C = #{consumes := Cs}]} = D, More) ->
    D#{components := [C#{consumes := Cs ++ More}]}.

entry(Category, Type, Parameters) ->
    #{category => Category, type => Type, parameters => Parameters}.

feedback_service() ->
    entry(<<"ACTUATOR">>, <<"ACTION FEEDBACK">>, [{<<"Feedback">>, <<"yes">>}]).

%% ---------------------------------------------------------------------------
%% xmllint
%% ---------------------------------------------------------------------------

%% @doc A standard validator accepts every example.
xmllint_accepts_examples(Config) ->
    Bad = [F || F <- examples(), xmllint(example(F), Config) =/= 0],
    [] = Bad.

%% @doc A standard validator refuses every invalid document, including those
%% xmerl_xsd lets through.
xmllint_rejects_invalid(Config) ->
    Files = [invalid_file(Name, Config) || {Name, _, _, _} <- invalid()]
        ++ [gap_file(Name, Config)
            || Name <- [default_namespace, prefixed_parameter, unqualified_structural]],
    Accepted = [F || F <- Files, xmllint(F, Config) =:= 0],
    [] = Accepted.

xmllint(File, Config) ->
    Port = open_port({spawn_executable, ?config(xmllint, Config)},
                     [{args, ["--noout", "--nonet", "--schema", schema_file(), File]},
                      exit_status, stderr_to_stdout, binary]),
    xmllint_status(Port).

xmllint_status(Port) ->
    receive
        {Port, {data, _}} -> xmllint_status(Port);
        {Port, {exit_status, Status}} -> Status
    end.

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

examples_dir() ->
    filename:join(code:priv_dir(bil), "examples").

example(File) ->
    filename:join(examples_dir(), File).

schema_file() ->
    filename:join(code:priv_dir(bil), "bil.xsd").

%% xmerl_xsd keeps the schema in an ETS table owned by the calling process,
%% so each case processes its own.
schema() ->
    {ok, Schema} = xmerl_xsd:process_schema(schema_file()),
    Schema.

%% Trusted files only: xmerl_scan makes atoms of element names.
validate_file(File, Schema) ->
    {Element, _Rest} = xmerl_scan:file(File),
    case xmerl_xsd:validate(Element, Schema) of
        {error, Errors} -> {error, Errors};
        {#xmlElement{}, _State} -> ok
    end.

%% The namespace and local name of a document's root.
root(File) ->
    {#xmlElement{nsinfo = {Prefix, Local}, namespace = #xmlNamespace{nodes = Nodes}}, _} =
        xmerl_scan:file(File),
    {Prefix, Ns} = lists:keyfind(Prefix, 1, Nodes),
    {atom_to_list(Ns), Local}.

%% The reason tags in xmerl_xsd's errors, which come as
%% {Path, xmerl_xsd, {Tag, ...}} or as a bare facet error {Tag, ...}.
reasons(Errors) ->
    [reason(E) || E <- Errors].

reason({_Path, xmerl_xsd, Reason}) when is_tuple(Reason) -> element(1, Reason);
reason({_Path, xmerl_xsd, Reason}) -> Reason;
reason(Reason) when is_tuple(Reason) -> element(1, Reason);
reason(Reason) -> Reason.

read(File) ->
    {ok, Bin} = file:read_file(File),
    Bin.

is_signal("signal_" ++ _) -> true;
is_signal(_) -> false.

parse(File) ->
    parse(File, read(example(File))).

parse(File, Bin) ->
    case is_signal(File) of
        true -> bil:parse_signal(Bin);
        false -> bil:parse_description(Bin)
    end.

encode(File, Term) ->
    case is_signal(File) of
        true -> bil:encode_signal(Term);
        false -> bil:encode_description(Term)
    end.

description(File) ->
    {ok, D} = bil:parse_description(read(example(File))),
    D.

%% Writes the invalid document `Name' of invalid/0 and returns its path.
invalid_file(Name, Config) ->
    {Name, Base, Edits, _} = lists:keyfind(Name, 1, invalid()),
    write_doc(Name, apply_edits(Name, read(example(Base)), Edits), Config).

%% Documents that xmerl_xsd accepts although BIL refuses them. xmerl_xsd
%% gives an unprefixed element the namespace of its nearest prefixed
%% ancestor, and does not check a wildcard's namespace.
gap_file(default_namespace, Config) ->
    Bin = apply_edits(default_namespace, read(example("light_actuator.xml")),
                      [{"bil:", ""}, {"xmlns:bil=", "xmlns="}]),
    write_doc(default_namespace, Bin, Config);
gap_file(prefixed_parameter, Config) ->
    Bin = apply_edits(prefixed_parameter, read(example("light_actuator.xml")),
                      [{"<Light>yes</Light>", "<bil:Light>yes</bil:Light>"}]),
    write_doc(prefixed_parameter, Bin, Config);
gap_file(unqualified_structural, Config) ->
    Bin = apply_edits(unqualified_structural, read(example("light_actuator.xml")),
                      [{"<bil:types>", "<types>"}, {"</bil:types>", "</types>"}]),
    write_doc(unqualified_structural, Bin, Config);
gap_file(component_as_root, Config) ->
    Bin = <<"<bil:Component xmlns:bil=\"urn:evatar:bil:1\">"
            "<ComponentID>Lone</ComponentID><Service><ServiceCategory>ACTUATOR"
            "</ServiceCategory><ServiceType>Beep</ServiceType></Service>"
            "</bil:Component>">>,
    write_doc(component_as_root, Bin, Config).

%% Every edit must apply, or the test would check an unchanged document.
apply_edits(Name, Bin, Edits) ->
    lists:foldl(
      fun({From, To}, Acc) ->
              F = list_to_binary(From),
              case binary:match(Acc, F) of
                  nomatch -> ct:fail({edit_does_not_apply, Name, From});
                  _ -> binary:replace(Acc, F, list_to_binary(To), [global])
              end
      end, Bin, Edits).

write_doc(Name, Bin, Config) ->
    File = filename:join(?config(priv_dir, Config), atom_to_list(Name) ++ ".xml"),
    ok = file:write_file(File, Bin),
    File.

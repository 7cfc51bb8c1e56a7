%% @doc Checks the description and signal codecs (bil_description,
%% bil_signal) against docs/bil.md sections 1-3: encode/parse round trips,
%% mutated documents that must never crash the parser, documents written in
%% other legal styles (prefixes, indentation, comments, attributes, references)
%% that must parse to the same term, every structural error code with its
%% path, and the shipped examples.
-module(bil_codec_SUITE).

%% The PropEr runner the suites share (apps/evatar_test_kit).
-import(evatar_test_proper, [check/2]).

-include_lib("common_test/include/ct.hrl").
-include_lib("proper/include/proper.hrl").
-include_lib("stdlib/include/assert.hrl").

-export([all/0, groups/0, suite/0]).
-export([round_trip_description/1, round_trip_signal/1, round_trip_entry_as_body/1,
         fuzz_description/1, fuzz_signal/1, fuzz_structure_description/1,
         fuzz_structure_signal/1, fuzz_messages_utf8/1,
         styles_description/1, styles_signal/1,
         wrong_root/1, wrong_namespace_structural/1, wrong_namespace_default/1,
         wrong_namespace_field/1, missing_element/1, unexpected_element/1,
         unexpected_text/1, duplicate_element/1, bad_value_description/1,
         bad_value_signal/1, duplicate_component/1, encoding_layout/1,
         encode_bad_parameter_name/1, examples/1]).

-define(NUMTESTS_ROUND_TRIP, 1000).
-define(NUMTESTS_FUZZ, 2000).
-define(NUMTESTS_STYLES, 1000).

-define(NS, "urn:evatar:bil:1").

%% A guard against a hang, not a speed limit: the fuzz group's five
%% properties run in parallel, and with cover at load 15 the slowest took
%% 103 s (fuzz_structure_description), a third of the old 5 minutes.
suite() ->
    [{timetrap, {minutes, 10}}].

all() ->
    [{group, round_trip}, {group, fuzz}, {group, styles}, {group, errors},
     {group, encoding}, examples].

groups() ->
    [{round_trip, [parallel],
      [round_trip_description, round_trip_signal, round_trip_entry_as_body]},
     {fuzz, [parallel],
      [fuzz_description, fuzz_signal, fuzz_structure_description, fuzz_structure_signal,
       fuzz_messages_utf8]},
     {styles, [parallel], [styles_description, styles_signal]},
     {errors, [parallel],
      [wrong_root, wrong_namespace_structural, wrong_namespace_default,
       wrong_namespace_field, missing_element, unexpected_element, unexpected_text,
       duplicate_element, bad_value_description, bad_value_signal,
       duplicate_component]},
     {encoding, [parallel], [encoding_layout, encode_bad_parameter_name]}].

%% ---------------------------------------------------------------------------
%% Round trips
%% ---------------------------------------------------------------------------

%% @doc Every valid description survives encode then parse unchanged.
round_trip_description(_Config) ->
    check(?FORALL(D, bil_gen:description(),
                  round_trips(D, bil:parse_description(
                                   iolist_to_binary(bil:encode_description(D))))),
          ?NUMTESTS_ROUND_TRIP).

%% @doc Every valid signal survives encode then parse unchanged.
round_trip_signal(_Config) ->
    check(?FORALL(S, bil_gen:signal(),
                  round_trips(S, bil:parse_signal(
                                   iolist_to_binary(bil:encode_signal(S))))),
          ?NUMTESTS_ROUND_TRIP).

%% @doc Any generated entry is a valid body for every context.
round_trip_entry_as_body(_Config) ->
    check(?FORALL({Body, Context}, {bil_gen:entry(), bil_gen:signal_context()},
                  begin
                      S = #{id => <<"s">>, context => Context, sender => <<"a">>,
                            receiver => <<"b">>, in_reply_to => undefined,
                            timestamp => 0, seq => undefined, epoch => undefined,
                            body => Body},
                      round_trips(S, bil:parse_signal(
                                       iolist_to_binary(bil:encode_signal(S))))
                  end),
          ?NUMTESTS_ROUND_TRIP div 2).

round_trips(Term, Parsed) ->
    ?WHENFAIL(ct:pal("term:~n~p~nparsed:~n~p", [Term, Parsed]),
              Parsed =:= {ok, Term}).

%% ---------------------------------------------------------------------------
%% Fuzzing
%% ---------------------------------------------------------------------------

%% @doc Mutated descriptions never crash the parser; what still parses round trips.
fuzz_description(_Config) ->
    check(prop_fuzz(bil_gen:description(), fun bil:encode_description/1,
                    fun bil:parse_description/1),
          ?NUMTESTS_FUZZ).

%% @doc Mutated signals never crash the parser; what still parses round trips.
fuzz_signal(_Config) ->
    check(prop_fuzz(bil_gen:signal(), fun bil:encode_signal/1, fun bil:parse_signal/1),
          ?NUMTESTS_FUZZ).

prop_fuzz(Gen, Encode, Parse) ->
    ?FORALL({Term, Mutations}, {Gen, list_of(1, 4, mutation())},
            begin
                Bin = lists:foldl(fun mutate/2, iolist_to_binary(Encode(Term)), Mutations),
                Result = try Parse(Bin)
                         catch Class:Reason:Stack -> {raised, Class, Reason, Stack}
                         end,
                ?WHENFAIL(ct:pal("document:~n~p~nresult:~n~p", [Bin, Result]),
                          acceptable(Result, Encode, Parse))
            end).

%% @doc Descriptions with elements dropped, repeated, swapped, renamed, moved
%% between namespaces or given odd text never crash the parser; what still
%% parses round trips.
fuzz_structure_description(_Config) ->
    check(prop_fuzz_structure(bil_gen:description(), fun description_tree/2,
                              fun bil:encode_description/1, fun bil:parse_description/1),
          ?NUMTESTS_FUZZ).

%% @doc Signals with elements dropped, repeated, swapped, renamed, moved
%% between namespaces or given odd text never crash the parser; what still
%% parses round trips.
fuzz_structure_signal(_Config) ->
    check(prop_fuzz_structure(bil_gen:signal(), fun signal_tree/2,
                              fun bil:encode_signal/1, fun bil:parse_signal/1),
          ?NUMTESTS_FUZZ).

prop_fuzz_structure(Gen, ToTree, Encode, Parse) ->
    ?FORALL({Term, Style, Edits}, {Gen, style(), list_of(1, 3, edit())},
            begin
                Tree = lists:foldl(fun edit/2, ToTree(Term, Style), Edits),
                Bin = iolist_to_binary(write(Tree, Style)),
                Result = try Parse(Bin)
                         catch Class:Reason:Stack -> {raised, Class, Reason, Stack}
                         end,
                ?WHENFAIL(ct:pal("document:~n~ts~nresult:~n~p", [Bin, Result]),
                          acceptable(Result, Encode, Parse))
            end).

%% @doc Error messages are valid UTF-8 even when the document is not: they
%% end up in logs and error signals.
fuzz_messages_utf8(_Config) ->
    Gen = oneof([?LET(S, bil_gen:signal(), {fun bil:parse_signal/1, bil:encode_signal(S)}),
                 ?LET(D, bil_gen:description(),
                      {fun bil:parse_description/1, bil:encode_description(D)})]),
    check(?FORALL({{Parse, Encoded}, Mutations}, {Gen, list_of(1, 4, mutation())},
                  begin
                      Bin = lists:foldl(fun mutate/2, iolist_to_binary(Encoded), Mutations),
                      case Parse(Bin) of
                          {ok, _} ->
                              true;
                          {error, #{message := Message} = Reason} ->
                              ?WHENFAIL(ct:pal("document:~n~p~nreason:~n~p", [Bin, Reason]),
                                        unicode:characters_to_binary(Message) =:= Message)
                      end
                  end),
          ?NUMTESTS_FUZZ).

%% A parse either fails with a well-formed reason or gives a valid term,
%% which must then round trip itself.
acceptable({ok, Term}, Encode, Parse) ->
    Parse(iolist_to_binary(Encode(Term))) =:= {ok, Term};
acceptable({error, #{code := Code, message := Message} = Reason}, _, _) ->
    lists:member(Code, error_codes())
        andalso is_binary(Message) andalso Message =/= <<>>
        andalso lists:all(fun valid_reason_key/1, maps:to_list(Reason));
acceptable(_, _, _) ->
    false.

valid_reason_key({code, _}) -> true;
valid_reason_key({message, _}) -> true;
valid_reason_key({line, L}) -> is_integer(L) andalso L > 0;
valid_reason_key({column, C}) -> is_integer(C) andalso C > 0;
valid_reason_key({path, P}) -> is_binary(P) andalso binary:first(P) =:= $/;
valid_reason_key(_) -> false.

error_codes() ->
    [too_large, not_binary, doctype_refused, entity_refused, too_deep, truncated,
     malformed, bad_encoding, wrong_namespace, wrong_root, missing_element,
     unexpected_element, duplicate_element, bad_value, duplicate_component].

%% Positions are fractions of the document's length, so they shrink well.
mutation() ->
    oneof([{flip, position(), range(1, 255)},
           {insert, position(), oneof([fragment(), binary()])},
           {delete, position(), range(1, 16)},
           {truncate, position()},
           {swap, position(), position()}]).

position() -> float(0.0, 1.0).

fragment() ->
    elements([<<"<">>, <<">">>, <<"&">>, <<"</">>, <<"/>">>, <<"<x>">>, <<"<x/>">>,
              <<"<!DOCTYPE x>">>, <<"&foo;">>, <<"&#0;">>, <<"&#x110000;">>, <<"&#65;">>,
              <<"<![CDATA[">>, <<"]]>">>, <<"<!--">>, <<"-->">>, <<"<?">>, <<"?>">>,
              <<"\"">>, <<" xmlns=\"\"">>, <<" xmlns:bil=\"urn:other\"">>, <<"bil:">>,
              <<0>>, <<255>>, <<16#C3>>, <<16#ED, 16#A0, 16#80>>, <<"\r">>,
              <<"<ServiceParameters>">>, <<"<Sequence>1</Sequence>">>]).

mutate({flip, Pos, Mask}, Bin) when Bin =/= <<>> ->
    At = at(Pos, byte_size(Bin) - 1),
    <<Before:At/binary, Byte, After/binary>> = Bin,
    <<Before/binary, (Byte bxor Mask), After/binary>>;
mutate({insert, Pos, Fragment}, Bin) ->
    At = at(Pos, byte_size(Bin)),
    <<Before:At/binary, After/binary>> = Bin,
    <<Before/binary, Fragment/binary, After/binary>>;
mutate({delete, Pos, Len}, Bin) ->
    At = at(Pos, byte_size(Bin)),
    <<Before:At/binary, After/binary>> = Bin,
    <<Before/binary, (binary:part(After, min(Len, byte_size(After)),
                                  byte_size(After) - min(Len, byte_size(After))))/binary>>;
mutate({truncate, Pos}, Bin) ->
    binary:part(Bin, 0, at(Pos, byte_size(Bin)));
mutate({swap, P1, P2}, Bin) when byte_size(Bin) > 1 ->
    A = at(min(P1, P2), byte_size(Bin) - 1),
    B = at(max(P1, P2), byte_size(Bin) - 1),
    case B > A of
        true ->
            Gap = B - A - 1,
            <<Before:A/binary, X, Middle:Gap/binary, Y, After/binary>> = Bin,
            <<Before/binary, Y, Middle/binary, X, After/binary>>;
        false ->
            Bin
    end;
mutate(_, Bin) ->
    Bin.

at(Fraction, Max) -> min(Max, trunc(Fraction * (Max + 1))).

%% Edits of the neutral tree (see description_tree/2), applied to the node at
%% a fraction of the preorder, never the root.
edit() ->
    {position(),
     oneof([delete, duplicate, swap, to_other_kind,
            {rename, elements(element_names())},
            {text, elements([<<>>, <<" ">>, <<"x">>, <<"-1">>, <<"007">>, <<"Avatar">>,
                             <<"Request">>, <<"123456789012345678901">>])}])}.

element_names() ->
    [<<"description">>, <<"context">>, <<"types">>, <<"Component">>, <<"Envelope">>,
     <<"Header">>, <<"Body">>, <<"EntityID">>, <<"APIName">>, <<"EntityType">>,
     <<"Context">>, <<"ComponentID">>, <<"Service">>, <<"Consumes">>,
     <<"ServiceCategory">>, <<"ServiceType">>, <<"ServiceParameters">>, <<"SignalID">>,
     <<"Sender">>, <<"Receiver">>, <<"InReplyTo">>, <<"Timestamp">>, <<"Sequence">>,
     <<"Epoch">>, <<"Junk">>].

edit({Position, Op}, Tree) ->
    Count = count_nodes(Tree),
    case Count > 1 of
        true ->
            {[Edited], _} = walk([Tree], 1 + at(Position, Count - 2), Op),
            Edited;
        false ->
            Tree
    end.

count_nodes({_, _, Children}) when is_list(Children) ->
    1 + lists:sum([count_nodes(C) || C <- Children]);
count_nodes(_) ->
    1.

%% Walks siblings in preorder, counting down to the node to edit.
walk(Nodes, N, _) when N < 0 ->
    {Nodes, N};
walk([], N, _) ->
    {[], N};
walk([Node | Rest], 0, Op) ->
    {apply_edit(Op, Node, Rest), -1};
walk([Node | Rest], N, Op) ->
    {Node1, N1} = case Node of
                      {Kind, Local, Children} when is_list(Children) ->
                          {C1, M} = walk(Children, N - 1, Op),
                          {{Kind, Local, C1}, M};
                      _ ->
                          {Node, N - 1}
                  end,
    {Rest1, N2} = walk(Rest, N1, Op),
    {[Node1 | Rest1], N2}.

apply_edit(delete, _, Rest) -> Rest;
apply_edit(duplicate, Node, Rest) -> [Node, Node | Rest];
apply_edit(swap, Node, [Next | Rest]) -> [Next, Node | Rest];
apply_edit(swap, Node, []) -> [Node];
apply_edit(to_other_kind, {bil, Local, Children}, Rest) -> [{plain, Local, Children} | Rest];
apply_edit(to_other_kind, {plain, Local, Children}, Rest) -> [{bil, Local, Children} | Rest];
apply_edit(to_other_kind, {leaf, Local, Text}, Rest) ->
    [{plain, Local, [{leaf, <<"Inner">>, Text}]} | Rest];
apply_edit(to_other_kind, Node, Rest) -> [Node | Rest];
apply_edit({rename, Name}, {Kind, _, Content}, Rest) -> [{Kind, Name, Content} | Rest];
apply_edit({rename, _}, Node, Rest) -> [Node | Rest];
apply_edit({text, Text}, {leaf, Local, _}, Rest) -> [{leaf, Local, Text} | Rest];
apply_edit({text, Text}, {Kind, Local, Children}, Rest) ->
    [{Kind, Local, [{text, Text} | Children]} | Rest];
apply_edit({text, _}, Node, Rest) -> [Node | Rest].

%% ---------------------------------------------------------------------------
%% Other legal ways to write the same document
%% ---------------------------------------------------------------------------

%% @doc Descriptions written with other prefixes, layouts, comments, attributes
%% and references parse to the same term.
styles_description(_Config) ->
    check(?FORALL({D, Style}, {bil_gen:description(), style()},
                  begin
                      Bin = iolist_to_binary(write(description_tree(D, Style), Style)),
                      ?WHENFAIL(ct:pal("style ~p~n~ts", [Style, Bin]),
                                round_trips(D, bil:parse_description(Bin)))
                  end),
          ?NUMTESTS_STYLES).

%% @doc Signals written with other prefixes, layouts, comments, attributes,
%% references and leading zeros parse to the same term.
styles_signal(_Config) ->
    check(?FORALL({S, Style}, {bil_gen:signal(), style()},
                  begin
                      Bin = iolist_to_binary(write(signal_tree(S, Style), Style)),
                      ?WHENFAIL(ct:pal("style ~p~n~ts", [Style, Bin]),
                                round_trips(S, bil:parse_signal(Bin)))
                  end),
          ?NUMTESTS_STYLES).

style() ->
    ?LET({Prefix, Redeclare, Prolog, Indent, Misc, Attributes, Text, Empty,
          OmitParameters, Zeros, SplitText},
         {elements([<<"bil">>, <<"b">>, <<"x">>, <<"ns0">>, <<"é"/utf8>>, default]),
          boolean(),
          elements([none, decl, decl_encoding, bom, bom_decl]),
          elements([none, spaces, tabs, crlf]),
          boolean(), boolean(),
          elements([entities, references, cdata]),
          elements([self_closing, pair]),
          boolean(), range(0, 3), boolean()},
         #{prefix => Prefix, redeclare => Redeclare, prolog => Prolog, indent => Indent,
           misc => Misc, attributes => Attributes, text => Text, empty => Empty,
           omit_parameters => OmitParameters, zeros => Zeros, split_text => SplitText}).

%% A neutral tree: {bil, Local, Children} for structural elements,
%% {plain, Local, Children} for entries and ServiceParameters,
%% {leaf, Local, Text} for fields and parameters.
description_tree(#{entity_id := Id, api_name := Api, entity_type := Type,
                   context := Context, components := Components}, Style) ->
    {bil, <<"description">>,
     [{bil, <<"context">>,
       [{leaf, <<"EntityID">>, Id}, {leaf, <<"APIName">>, Api},
        {leaf, <<"EntityType">>, case Type of agent -> <<"Agent">>; avatar -> <<"Avatar">> end},
        {leaf, <<"Context">>, Context}]},
      {bil, <<"types">>,
       [{bil, <<"Component">>,
         [{leaf, <<"ComponentID">>, CId}]
         ++ [entry_tree(<<"Service">>, E, Style) || E <- Services]
         ++ [entry_tree(<<"Consumes">>, E, Style) || E <- Consumes]}
        || #{id := CId, services := Services, consumes := Consumes} <- Components]}]}.

signal_tree(#{id := Id, context := Context, sender := Sender, receiver := Receiver,
              in_reply_to := InReplyTo, timestamp := Timestamp, seq := Seq,
              epoch := Epoch, body := Body}, Style) ->
    Number = fun(N) ->
                     Digits = integer_to_binary(N),
                     Zeros = min(maps:get(zeros, Style), 20 - byte_size(Digits)),
                     <<(binary:copy(<<"0">>, Zeros))/binary, Digits/binary>>
             end,
    Optional = fun(_, undefined, _) -> [];
                  (Local, Value, F) -> [{leaf, Local, F(Value)}]
               end,
    Same = fun(V) -> V end,
    {bil, <<"Envelope">>,
     [{bil, <<"Header">>,
       [{leaf, <<"SignalID">>, Id},
        {leaf, <<"Context">>, wire(Context)},
        {leaf, <<"Sender">>, Sender},
        {leaf, <<"Receiver">>, Receiver}]
       ++ Optional(<<"InReplyTo">>, InReplyTo, Same)
       ++ [{leaf, <<"Timestamp">>, Number(Timestamp)}]
       ++ Optional(<<"Sequence">>, Seq, Number)
       ++ Optional(<<"Epoch">>, Epoch, Number)},
      setelement(1, entry_tree(<<"Body">>, Body, Style), bil)]}.

entry_tree(Local, #{category := Category, type := Type, parameters := Parameters},
           Style) ->
    ParametersTree = case {Parameters, maps:get(omit_parameters, Style)} of
                         {[], true} -> [];
                         _ -> [{plain, <<"ServiceParameters">>,
                                [{leaf, N, V} || {N, V} <- Parameters]}]
                     end,
    {plain, Local,
     [{leaf, <<"ServiceCategory">>, Category}, {leaf, <<"ServiceType">>, Type}
      | ParametersTree]}.

wire(request) -> <<"RequestAwaitingFeedback">>;
wire(request_no_feedback) -> <<"Request">>;
wire(feedback) -> <<"Feedback">>;
wire(progress) -> <<"Progress">>;
wire(sensor_data) -> <<"SensorData">>;
wire(event) -> <<"Event">>;
wire(error) -> <<"Error">>.

write(Tree, Style) ->
    [prolog(maps:get(prolog, Style)), misc(Style),
     element(Tree, 0, true, Style), misc(Style), <<"\n">>].

prolog(none) -> <<>>;
prolog(decl) -> <<"<?xml version=\"1.0\"?>\n">>;
prolog(decl_encoding) -> <<"<?xml version='1.0' encoding='utf-8' standalone='yes'?>\n">>;
prolog(bom) -> <<16#EF, 16#BB, 16#BF>>;
prolog(bom_decl) -> <<16#EF, 16#BB, 16#BF, "<?xml version=\"1.0\" encoding=\"UTF-8\"?>">>.

element({Kind, Local, Children}, Depth, Root, Style) when Kind =:= bil; Kind =:= plain ->
    Name = qname(Kind, Local, Style),
    Attributes = [namespace(Kind, Root, Style), attributes(Style)],
    case Children of
        [] ->
            case maps:get(empty, Style) of
                self_closing -> [$<, Name, Attributes, <<"/>">>];
                pair -> [$<, Name, Attributes, $>, $<, $/, Name, $>]
            end;
        _ ->
            [$<, Name, Attributes, $>,
             [[indent(Depth + 1, Style), misc(Style), element(C, Depth + 1, false, Style)]
              || C <- Children],
             indent(Depth, Style), $<, $/, Name, $>]
    end;
element({text, Text}, _, _, Style) ->
    text(Text, Style);
element({leaf, Local, Text}, _, _, Style) ->
    Attributes = [namespace(plain, false, Style), attributes(Style)],
    case {Text, maps:get(empty, Style)} of
        {<<>>, self_closing} -> [$<, Local, Attributes, <<"/>">>];
        _ -> [$<, Local, Attributes, $>, text(Text, Style), $<, $/, Local, $>]
    end.

qname(bil, Local, #{prefix := default}) -> Local;
qname(bil, Local, #{prefix := Prefix}) -> [Prefix, $:, Local];
qname(plain, Local, _) -> Local.

%% With BIL as the default namespace, every element in no namespace must
%% undeclare it.
namespace(bil, Root, #{prefix := Prefix, redeclare := Redeclare}) ->
    case Root orelse Redeclare of
        true when Prefix =:= default -> <<" xmlns=\"" ?NS "\"">>;
        true -> [<<" xmlns:">>, Prefix, <<"=\"" ?NS "\"">>];
        false -> <<>>
    end;
namespace(plain, _, #{prefix := default}) -> <<" xmlns=''">>;
namespace(plain, _, _) -> <<>>.

attributes(#{attributes := false}) -> <<>>;
attributes(#{attributes := true}) ->
    <<" id=\"1\" xmlns:o=\"urn:other\" o:note='a &amp; &lt;b&gt;' xml:lang=\"en\"">>.

misc(#{misc := false}) -> <<>>;
misc(#{misc := true}) -> <<"<!-- a comment, <not> an element --><?pi some data?>">>.

indent(_, #{indent := none}) -> <<>>;
indent(Depth, #{indent := spaces}) -> [$\n, binary:copy(<<"  ">>, Depth)];
indent(Depth, #{indent := tabs}) -> [$\n, binary:copy(<<"\t">>, Depth)];
indent(Depth, #{indent := crlf}) -> [<<"\r\n">>, binary:copy(<<" ">>, Depth)].

%% A comment in the middle of a leaf's text must not split or drop it.
text(Text, #{split_text := true} = Style) when byte_size(Text) > 1 ->
    Chars = unicode:characters_to_list(Text),
    {A, B} = lists:split(length(Chars) div 2, Chars),
    Plain = Style#{split_text := false},
    [text(unicode:characters_to_binary(A), Plain), <<"<!--split-->">>,
     text(unicode:characters_to_binary(B), Plain)];
text(Text, #{text := entities}) ->
    [entity(C) || C <- unicode:characters_to_list(Text)];
text(Text, #{text := references}) ->
    [reference(C) || C <- unicode:characters_to_list(Text)];
text(Text, #{text := cdata} = Style) ->
    case binary:match(Text, [<<"]]>">>, <<"\r">>]) of
        _ when Text =:= <<>> -> <<>>;
        nomatch -> [<<"<![CDATA[">>, Text, <<"]]>">>];
        _ -> text(Text, Style#{text := entities})
    end.

entity($<) -> <<"&lt;">>;
entity($>) -> <<"&gt;">>;
entity($&) -> <<"&amp;">>;
entity($") -> <<"&quot;">>;
entity($') -> <<"&apos;">>;
entity($\r) -> <<"&#13;">>;
entity(C) -> <<C/utf8>>.

%% Letters stay; everything else alternates decimal and hexadecimal forms.
reference(C) when C >= $a, C =< $z; C >= $A, C =< $Z -> C;
reference(C) when C rem 2 =:= 0 -> [<<"&#">>, integer_to_binary(C), $;];
reference(C) -> [<<"&#x">>, integer_to_binary(C, 16), $;].

%% ---------------------------------------------------------------------------
%% Structural errors
%% ---------------------------------------------------------------------------

%% @doc A root other than the expected one is wrong_root, named in the path.
wrong_root(_Config) ->
    Signal = signal(header(), body()),
    Description = description(context(), types(component())),
    error_is(wrong_root, <<"/Envelope">>, bil:parse_description(Signal)),
    error_is(wrong_root, <<"/description">>, bil:parse_signal(Description)),
    error_is(wrong_root, <<"/foo">>, bil:parse_signal(<<"<foo/>">>)),
    error_is(wrong_root, <<"/Header">>,
             bil:parse_signal(<<"<bil:Header xmlns:bil='" ?NS "'/>">>)),
    {error, #{message := Message}} = bil:parse_description(Signal),
    match(<<"signal">>, Message).

%% @doc Structural elements outside the BIL namespace are wrong_namespace.
wrong_namespace_structural(_Config) ->
    error_is(wrong_namespace, <<"/Envelope">>,
             bil:parse_signal(<<"<Envelope><Header/><Body/></Envelope>">>)),
    error_is(wrong_namespace, <<"/description">>,
             bil:parse_description(<<"<o:description xmlns:o='urn:other'/>">>)),
    error_is(wrong_namespace, <<"/Envelope/Header">>,
             bil:parse_signal(
               <<"<bil:Envelope xmlns:bil='" ?NS "' xmlns:o='urn:other'>",
                 "<o:Header>", (header())/binary, "</o:Header>",
                 "<bil:Body>", (body())/binary, "</bil:Body></bil:Envelope>">>)),
    error_is(wrong_namespace, <<"/Envelope/Body">>,
             bil:parse_signal(
               <<"<bil:Envelope xmlns:bil='" ?NS "'>",
                 "<bil:Header>", (header())/binary, "</bil:Header>",
                 "<Body>", (body())/binary, "</Body></bil:Envelope>">>)),
    error_is(wrong_namespace, <<"/description/types/Component[2]">>,
             bil:parse_description(
               description(context(), types([component(), <<"<Component/>">>])))),
    error_is(wrong_namespace, <<"/description/context">>,
             bil:parse_description(
               <<"<bil:description xmlns:bil='" ?NS "'><context>",
                 (context())/binary, "</context>", (types(component()))/binary,
                 "</bil:description>">>)),
    {error, #{message := Message}} =
        bil:parse_signal(<<"<Envelope><Header/><Body/></Envelope>">>),
    match(<<?NS>>, Message).

%% @doc BIL as the default namespace puts the fields in it: refused, with
%% advice to bind BIL to a prefix; undeclaring it on the fields is fine.
wrong_namespace_default(_Config) ->
    Doc = <<"<Envelope xmlns='" ?NS "'><Header>", (header())/binary, "</Header>",
            "<Body>", (body())/binary, "</Body></Envelope>">>,
    error_is(wrong_namespace, <<"/Envelope/Header/SignalID">>, bil:parse_signal(Doc)),
    {error, #{message := Message}} = bil:parse_signal(Doc),
    match(<<"prefix">>, Message),
    Description = <<"<description xmlns='" ?NS "'><context>", (context())/binary,
                    "</context><types/></description>">>,
    error_is(wrong_namespace, <<"/description/context/EntityID">>,
             bil:parse_description(Description)),
    Undeclared = <<"<Envelope xmlns='" ?NS "'><Header>",
                   "<SignalID xmlns=''>s1</SignalID><Context xmlns=''>Event</Context>",
                   "<Sender xmlns=''>a</Sender><Receiver xmlns=''>b</Receiver>",
                   "<Timestamp xmlns=''>5</Timestamp></Header>",
                   "<Body><ServiceCategory xmlns=''>C</ServiceCategory>",
                   "<ServiceType xmlns=''>T</ServiceType></Body></Envelope>">>,
    {ok, #{id := <<"s1">>, context := event, timestamp := 5,
           body := #{parameters := []}}} = bil:parse_signal(Undeclared).

%% @doc Fields and parameters in any namespace are wrong_namespace.
wrong_namespace_field(_Config) ->
    error_is(wrong_namespace, <<"/Envelope/Header/Sender">>,
             bil:parse_signal(signal(header(#{<<"Sender">> =>
                                                  <<"<o:Sender xmlns:o='urn:other'>a</o:Sender>">>}),
                                     body()))),
    error_is(wrong_namespace, <<"/Envelope/Header/InReplyTo">>,
             bil:parse_signal(signal(header(#{<<"InReplyTo">> =>
                                                  <<"<bil:InReplyTo>x</bil:InReplyTo>">>}),
                                     body()))),
    error_is(wrong_namespace, <<"/Envelope/Body/ServiceParameters/Light">>,
             bil:parse_signal(signal(header(), body(<<"<bil:Light>yes</bil:Light>">>)))),
    error_is(wrong_namespace, <<"/Envelope/Body/ServiceParameters">>,
             bil:parse_signal(signal(header(),
                                     <<"<ServiceCategory>C</ServiceCategory>",
                                       "<ServiceType>T</ServiceType>",
                                       "<bil:ServiceParameters/>">>))),
    error_is(wrong_namespace, <<"/description/types/Component[1]/Service[1]">>,
             bil:parse_description(
               description(context(), types(<<"<bil:Component><ComponentID>c</ComponentID>",
                                              "<bil:Service/></bil:Component>">>)))).

%% @doc A required element that is absent is missing_element, at its own path.
missing_element(_Config) ->
    error_is(missing_element, <<"/Envelope/Header/Timestamp">>,
             bil:parse_signal(signal(header(#{<<"Timestamp">> => <<>>}), body()))),
    error_is(missing_element, <<"/Envelope/Header/SignalID">>,
             bil:parse_signal(signal(header(#{<<"SignalID">> => <<>>}), body()))),
    error_is(missing_element, <<"/Envelope/Body">>,
             bil:parse_signal(<<"<bil:Envelope xmlns:bil='" ?NS "'><bil:Header>",
                                (header())/binary, "</bil:Header></bil:Envelope>">>)),
    error_is(missing_element, <<"/Envelope/Header">>,
             bil:parse_signal(<<"<bil:Envelope xmlns:bil='" ?NS "'/>">>)),
    error_is(missing_element, <<"/Envelope/Body/ServiceCategory">>,
             bil:parse_signal(signal(header(), <<"<ServiceType>T</ServiceType>">>))),
    error_is(missing_element, <<"/description/types">>,
             bil:parse_description(<<"<bil:description xmlns:bil='" ?NS "'>",
                                     (context_element())/binary, "</bil:description>">>)),
    %% A misspelt field is reported as the missing one, naming what was found.
    Misspelt = binary:replace(context(), <<"EntityID>">>, <<"EntityId>">>, [global]),
    error_is(missing_element, <<"/description/context/EntityID">>,
             bil:parse_description(description(Misspelt, types(component())))),
    {error, #{message := Message}} =
        bil:parse_description(description(Misspelt, types(component()))),
    match(<<"EntityId">>, Message),
    error_is(missing_element, <<"/description/types/Component[1]/Service[1]">>,
             bil:parse_description(
               description(context(), types(<<"<bil:Component><ComponentID>c</ComponentID>",
                                              "</bil:Component>">>)))),
    %% The example path of docs/bil.md.
    error_is(missing_element, <<"/description/types/Component[2]/Service[1]/ServiceType">>,
             bil:parse_description(
               description(context(),
                           types([component(),
                                  <<"<bil:Component><ComponentID>c2</ComponentID>",
                                    "<Service><ServiceCategory>S</ServiceCategory>",
                                    "<ServiceParameters/></Service></bil:Component>">>])))),
    error_is(missing_element, <<"/description/types/Component[1]/Consumes[2]/ServiceType">>,
             bil:parse_description(
               description(context(),
                           types(<<"<bil:Component><ComponentID>c</ComponentID>",
                                   (entry(<<"Service">>))/binary,
                                   (entry(<<"Consumes">>))/binary,
                                   "<Consumes><ServiceCategory>S</ServiceCategory>",
                                   "</Consumes></bil:Component>">>)))).

%% @doc Extra and out-of-order elements are unexpected_element.
unexpected_element(_Config) ->
    error_is(unexpected_element, <<"/Envelope/Header/Sender">>,
             bil:parse_signal(
               signal(<<"<SignalID>s</SignalID><Sender>a</Sender><Context>Event</Context>"
                        "<Receiver>b</Receiver><Timestamp>1</Timestamp>">>, body()))),
    error_is(unexpected_element, <<"/Envelope/Header/Extra">>,
             bil:parse_signal(signal(<<(header())/binary, "<Extra/>">>, body()))),
    error_is(unexpected_element, <<"/Envelope/Header/Sequence">>,
             bil:parse_signal(signal(<<(header())/binary, "<Epoch>1</Epoch>",
                                       "<Sequence>1</Sequence>">>, body()))),
    error_is(unexpected_element, <<"/Envelope/Extra">>,
             bil:parse_signal(<<"<bil:Envelope xmlns:bil='" ?NS "'><bil:Header>",
                                (header())/binary, "</bil:Header><bil:Body>",
                                (body())/binary, "</bil:Body><Extra/></bil:Envelope>">>)),
    error_is(unexpected_element, <<"/Envelope/Header/SignalID/b">>,
             bil:parse_signal(signal(header(#{<<"SignalID">> =>
                                                  <<"<SignalID>a<b/>c</SignalID>">>}),
                                     body()))),
    error_is(unexpected_element, <<"/Envelope/Header/Receiver/Inner">>,
             bil:parse_signal(signal(header(#{<<"Receiver">> =>
                                                  <<"<Receiver><Inner>b</Inner></Receiver>">>}),
                                     body()))),
    error_is(unexpected_element, <<"/Envelope/Header/Context/Inner">>,
             bil:parse_signal(signal(header(#{<<"Context">> =>
                                                  <<"<Context><Inner/></Context>">>}),
                                     body()))),
    error_is(unexpected_element, <<"/Envelope/Body/ServiceParameters/Light/on">>,
             bil:parse_signal(signal(header(), body(<<"<Light><on/></Light>">>)))),
    error_is(unexpected_element, <<"/description/types/Component[1]/Service">>,
             bil:parse_description(
               description(context(),
                           types(<<"<bil:Component><ComponentID>c</ComponentID>",
                                   (entry(<<"Service">>))/binary,
                                   (entry(<<"Consumes">>))/binary,
                                   (entry(<<"Service">>))/binary,
                                   "</bil:Component>">>)))),
    error_is(unexpected_element, <<"/description/types/Widget">>,
             bil:parse_description(description(context(), types(<<"<Widget/>">>)))),
    error_is(unexpected_element, <<"/description/context/Context">>,
             bil:parse_description(
               description(<<(context())/binary, "<Context>again</Context>">>,
                           types(component())))).

%% @doc Non-whitespace text among elements is refused; whitespace is not.
unexpected_text(_Config) ->
    error_is(unexpected_element, <<"/Envelope/Header">>,
             bil:parse_signal(signal(<<"junk", (header())/binary>>, body()))),
    error_is(unexpected_element, <<"/description/types">>,
             bil:parse_description(description(context(), types(<<"text">>)))),
    error_is(unexpected_element, <<"/Envelope/Body/ServiceParameters">>,
             bil:parse_signal(signal(header(), body(<<"<A>1</A>loose">>)))),
    {error, #{message := Message}} =
        bil:parse_signal(signal(<<"junk", (header())/binary>>, body())),
    match(<<"junk">>, Message),
    {ok, #{components := []}} =
        bil:parse_description(description(context(), types(<<" \n\t ">>))),
    {ok, #{body := #{parameters := []}}} =
        bil:parse_signal(signal(header(), body(<<"\r\n ">>))).

%% @doc A parameter name repeated in one ServiceParameters is duplicate_element,
%% for short and long parameter lists alike.
duplicate_element(_Config) ->
    error_is(duplicate_element, <<"/Envelope/Body/ServiceParameters/Light">>,
             bil:parse_signal(signal(header(),
                                     body(<<"<Light>yes</Light><Room>k</Room>",
                                            "<Light>no</Light>">>)))),
    Many = iolist_to_binary([[<<"<P">>, integer_to_binary(I), <<">v</P">>,
                              integer_to_binary(I), <<">">>] || I <- lists:seq(1, 40)]),
    {ok, #{body := #{parameters := Parameters}}} =
        bil:parse_signal(signal(header(), body(Many))),
    40 = length(Parameters),
    error_is(duplicate_element,
             <<"/description/types/Component[1]/Consumes[1]/ServiceParameters/P3">>,
             bil:parse_description(
               description(context(),
                           types(<<"<bil:Component><ComponentID>c</ComponentID>",
                                   (entry(<<"Service">>))/binary,
                                   "<Consumes><ServiceCategory>S</ServiceCategory>",
                                   "<ServiceType>T</ServiceType><ServiceParameters>",
                                   Many/binary, "<P3>again</P3></ServiceParameters>",
                                   "</Consumes></bil:Component>">>)))),
    %% Names differing only in case are different parameters.
    {ok, #{body := #{parameters := [{<<"a">>, <<"1">>}, {<<"A">>, <<"2">>}]}}} =
        bil:parse_signal(signal(header(), body(<<"<a>1</a><A>2</A>">>))).

%% @doc Bad entity types and empty required texts in descriptions are bad_value.
bad_value_description(_Config) ->
    BadType = fun(Type) ->
                      bil:parse_description(
                        description(binary:replace(context(), <<">Avatar<">>,
                                                   <<">", Type/binary, "<">>),
                                    types(component())))
              end,
    [error_is(bad_value, <<"/description/context/EntityType">>, BadType(T))
     || T <- [<<"avatar">>, <<"AVATAR">>, <<" Avatar">>, <<"Avatar ">>, <<>>, <<"Robot">>]],
    {ok, #{entity_type := agent}} = BadType(<<"Agent">>),
    error_is(bad_value, <<"/description/context/EntityID">>,
             bil:parse_description(
               description(binary:replace(context(), <<"<EntityID>7008</EntityID>">>,
                                          <<"<EntityID/>">>),
                           types(component())))),
    error_is(bad_value, <<"/description/types/Component[1]/ComponentID">>,
             bil:parse_description(
               description(context(),
                           types(binary:replace(component(), <<">HomeLight<">>, <<"><">>))))),
    error_is(bad_value, <<"/description/types/Component[1]/Service[1]/ServiceType">>,
             bil:parse_description(
               description(context(),
                           types(binary:replace(component(), <<">TurnLightOn<">>,
                                                <<"><">>))))),
    %% APIName and Context may be empty; whitespace-only text is not empty.
    {ok, #{api_name := <<>>, context := <<>>, entity_id := <<" ">>}} =
        bil:parse_description(
          description(<<"<EntityID> </EntityID><APIName/><EntityType>Agent</EntityType>"
                        "<Context></Context>">>, types(<<>>))).

%% @doc Bad numbers, unknown contexts and empty required texts in signals are
%% bad_value; 20 digits and leading zeros are fine.
bad_value_signal(_Config) ->
    With = fun(Field, Element) -> bil:parse_signal(signal(header(#{Field => Element}), body())) end,
    Timestamp = fun(Text) -> With(<<"Timestamp">>, <<"<Timestamp>", Text/binary, "</Timestamp>">>) end,
    [error_is(bad_value, <<"/Envelope/Header/Timestamp">>, Timestamp(T))
     || T <- [<<>>, <<"12a">>, <<" 12">>, <<"12 ">>, <<"+12">>, <<"-1">>, <<"1.5">>,
              <<"1e3">>, <<"&#x661;">>, <<"123456789012345678901">>]],
    {ok, #{timestamp := 99999999999999999999}} = Timestamp(<<"99999999999999999999">>),
    {ok, #{timestamp := 7}} = Timestamp(<<"00000000000000000007">>),
    {ok, #{timestamp := 12}} = Timestamp(<<"1<!-- c -->2">>),
    error_is(bad_value, <<"/Envelope/Header/Sequence">>,
             With(<<"Sequence">>, <<"<Sequence>x</Sequence>">>)),
    error_is(bad_value, <<"/Envelope/Header/Epoch">>,
             With(<<"Epoch">>, <<"<Epoch></Epoch>">>)),
    {error, #{message := Long}} = Timestamp(<<"123456789012345678901">>),
    match(<<"21 digits">>, Long),
    Context = fun(Text) -> With(<<"Context">>, <<"<Context>", Text/binary, "</Context>">>) end,
    [error_is(bad_value, <<"/Envelope/Header/Context">>, Context(C))
     || C <- [<<"request">>, <<"Requests">>, <<"RequestAwaitingFeedback ">>, <<>>,
              <<"request_no_feedback">>]],
    [{ok, #{context := Atom}} = Context(Wire)
     || {Wire, Atom} <- [{<<"RequestAwaitingFeedback">>, request},
                         {<<"Request">>, request_no_feedback}, {<<"Feedback">>, feedback},
                         {<<"Progress">>, progress}, {<<"SensorData">>, sensor_data},
                         {<<"Event">>, event}, {<<"Error">>, error}]],
    [error_is(bad_value, <<"/Envelope/Header/", F/binary>>,
              With(F, <<"<", F/binary, "/>">>))
     || F <- [<<"SignalID">>, <<"Sender">>, <<"Receiver">>, <<"InReplyTo">>]],
    error_is(bad_value, <<"/Envelope/Body/ServiceCategory">>,
             bil:parse_signal(signal(header(), <<"<ServiceCategory/><ServiceType>T</ServiceType>">>))).

%% @doc A ComponentID used twice is duplicate_component at the second one.
duplicate_component(_Config) ->
    Other = binary:replace(component(), <<">HomeLight<">>, <<">Other<">>),
    error_is(duplicate_component, <<"/description/types/Component[3]/ComponentID">>,
             bil:parse_description(
               description(context(), types([component(), Other, component()])))),
    {error, #{message := Message}} =
        bil:parse_description(description(context(), types([component(), Other, component()]))),
    match(<<"Component[1]">>, Message),
    %% Exact comparison: ids differing by whitespace are distinct.
    Spaced = binary:replace(component(), <<">HomeLight<">>, <<">HomeLight <">>),
    {ok, #{components := [_, _]}} =
        bil:parse_description(description(context(), types([component(), Spaced]))).

%% ---------------------------------------------------------------------------
%% Encoding
%% ---------------------------------------------------------------------------

%% @doc Signals are compact, descriptions indented; optional fields are
%% omitted and ServiceParameters is always written.
encoding_layout(_Config) ->
    Signal = #{id => <<"a<b">>, context => progress, sender => <<"s">>, receiver => <<"r">>,
               in_reply_to => undefined, timestamp => 12, seq => undefined, epoch => 3,
               body => #{category => <<"C">>, type => <<"T">>, parameters => []}},
    <<"<?xml version=\"1.0\" encoding=\"UTF-8\"?>"
      "<bil:Envelope xmlns:bil=\"urn:evatar:bil:1\"><bil:Header>"
      "<SignalID>a&lt;b</SignalID><Context>Progress</Context><Sender>s</Sender>"
      "<Receiver>r</Receiver><Timestamp>12</Timestamp><Epoch>3</Epoch></bil:Header>"
      "<bil:Body><ServiceCategory>C</ServiceCategory><ServiceType>T</ServiceType>"
      "<ServiceParameters/></bil:Body></bil:Envelope>">> =
        iolist_to_binary(bil:encode_signal(Signal)),
    Description = #{entity_id => <<"e">>, api_name => <<>>, entity_type => agent,
                    context => <<"c">>,
                    components => [#{id => <<"x">>,
                                     services => [#{category => <<"C">>, type => <<"T">>,
                                                    parameters => [{<<"P">>, <<"v">>}]}],
                                     consumes => [#{category => <<"C">>, type => <<"U">>,
                                                    parameters => []}]}]},
    <<"<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
      "<bil:description xmlns:bil=\"urn:evatar:bil:1\">\n"
      "  <bil:context>\n"
      "    <EntityID>e</EntityID>\n"
      "    <APIName></APIName>\n"
      "    <EntityType>Agent</EntityType>\n"
      "    <Context>c</Context>\n"
      "  </bil:context>\n"
      "  <bil:types>\n"
      "    <bil:Component>\n"
      "      <ComponentID>x</ComponentID>\n"
      "      <Service>\n"
      "        <ServiceCategory>C</ServiceCategory>\n"
      "        <ServiceType>T</ServiceType>\n"
      "        <ServiceParameters>\n"
      "          <P>v</P>\n"
      "        </ServiceParameters>\n"
      "      </Service>\n"
      "      <Consumes>\n"
      "        <ServiceCategory>C</ServiceCategory>\n"
      "        <ServiceType>U</ServiceType>\n"
      "        <ServiceParameters/>\n"
      "      </Consumes>\n"
      "    </bil:Component>\n"
      "  </bil:types>\n"
      "</bil:description>\n">> = iolist_to_binary(bil:encode_description(Description)),
    {match, _} = re:run(bil:encode_description(Description#{components := []}),
                        <<"\n  <bil:types/>\n</bil:description>\n$">>).

%% @doc A parameter name that is not an XML name makes the encoders raise.
encode_bad_parameter_name(_Config) ->
    Body = fun(Name) -> #{category => <<"C">>, type => <<"T">>,
                          parameters => [{<<"ok">>, <<"1">>}, {Name, <<"v">>}]} end,
    Signal = fun(Name) -> #{id => <<"i">>, context => event, sender => <<"s">>,
                            receiver => <<"r">>, in_reply_to => undefined, timestamp => 1,
                            seq => undefined, epoch => undefined, body => Body(Name)} end,
    Description = fun(Name) -> #{entity_id => <<"e">>, api_name => <<>>,
                                 entity_type => avatar, context => <<>>,
                                 components => [#{id => <<"c">>, services => [Body(Name)],
                                                  consumes => []}]} end,
    [begin
         ?assertError({bad_parameter_name, Name}, bil:encode_signal(Signal(Name))),
         ?assertError({bad_parameter_name, Name}, bil:encode_description(Description(Name)))
     end
     || Name <- [<<>>, <<"1abc">>, <<"a b">>, <<"a:b">>, <<"-x">>, <<"a<b">>, <<".x">>,
                 <<"a&b">>, <<16#FF>>, <<"é"/utf8, 16#FF>>, not_a_binary]],
    [_ | _] = bil:encode_signal(Signal(<<"Größe_1.b-c"/utf8>>)).

%% ---------------------------------------------------------------------------
%% Examples
%% ---------------------------------------------------------------------------

%% @doc Every shipped example parses, as a description or a signal, and
%% round trips through the encoder.
examples(_Config) ->
    Files = filelib:wildcard(filename:join([code:priv_dir(bil), "examples", "*.xml"])),
    case Files of
        [] -> {skip, "no examples in priv/examples"};
        _ -> lists:foreach(fun example/1, Files)
    end.

example(File) ->
    {ok, Bin} = file:read_file(File),
    Result = case bil:parse_description(Bin) of
                 {ok, D} ->
                     {ok, D} =:= bil:parse_description(
                                   iolist_to_binary(bil:encode_description(D)));
                 {error, #{code := wrong_root}} ->
                     {ok, S} = bil:parse_signal(Bin),
                     {ok, S} =:= bil:parse_signal(iolist_to_binary(bil:encode_signal(S)));
                 Error ->
                     Error
             end,
    case Result of
        true -> ok;
        _ -> ct:fail({example, File, Result})
    end.

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

list_of(Min, Max, Type) ->
    ?LET(N, range(Min, Max), vector(N, Type)).

error_is(Code, Path, Result) ->
    case Result of
        {error, #{code := Code, path := Path, message := Message}} when is_binary(Message) ->
            ok;
        _ ->
            ct:fail({expected, Code, Path, got, Result})
    end.

match(Part, Message) ->
    case binary:match(Message, Part) of
        nomatch -> ct:fail({message_lacks, Part, Message});
        _ -> ok
    end.

%% Documents are built from small valid pieces so that each case changes one thing.
signal(Header, Body) ->
    <<"<bil:Envelope xmlns:bil='" ?NS "'><bil:Header>", Header/binary,
      "</bil:Header><bil:Body>", Body/binary, "</bil:Body></bil:Envelope>">>.

header() -> header(#{}).

%% Replaces the fields named in `Replace' by the given elements (<<>> drops one).
header(Replace) ->
    Fields = [{<<"SignalID">>, <<"<SignalID>s1</SignalID>">>},
              {<<"Context">>, <<"<Context>RequestAwaitingFeedback</Context>">>},
              {<<"Sender">>, <<"<Sender>a</Sender>">>},
              {<<"Receiver">>, <<"<Receiver>b</Receiver>">>},
              {<<"InReplyTo">>, <<>>},
              {<<"Timestamp">>, <<"<Timestamp>1763800000000</Timestamp>">>},
              {<<"Sequence">>, <<>>},
              {<<"Epoch">>, <<>>}],
    iolist_to_binary([maps:get(Name, Replace, Element) || {Name, Element} <- Fields]).

body() -> body(<<"<Light>yes</Light>">>).

body(Parameters) ->
    <<"<ServiceCategory>ACTUATOR</ServiceCategory><ServiceType>TurnLightOn</ServiceType>"
      "<ServiceParameters>", Parameters/binary, "</ServiceParameters>">>.

description(Context, Types) ->
    <<"<bil:description xmlns:bil='" ?NS "'><bil:context>", Context/binary,
      "</bil:context>", Types/binary, "</bil:description>">>.

context() ->
    <<"<EntityID>7008</EntityID><APIName>LIGHT ACTUATOR</APIName>"
      "<EntityType>Avatar</EntityType><Context>ActuatorDescription</Context>">>.

context_element() ->
    <<"<bil:context>", (context())/binary, "</bil:context>">>.

types(Components) ->
    iolist_to_binary([<<"<bil:types>">>, Components, <<"</bil:types>">>]).

component() ->
    <<"<bil:Component><ComponentID>HomeLight</ComponentID>",
      (entry(<<"Service">>))/binary, (entry(<<"Consumes">>))/binary, "</bil:Component>">>.

entry(Tag) ->
    <<"<", Tag/binary, "><ServiceCategory>ACTUATOR</ServiceCategory>"
      "<ServiceType>TurnLightOn</ServiceType><ServiceParameters><Light>yes</Light>"
      "</ServiceParameters></", Tag/binary, ">">>.

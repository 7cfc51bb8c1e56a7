%% @doc Internal. Parses and encodes BIL descriptions (docs/bil.md, section 2),
%% and holds the tree-walking helpers bil_signal shares with it: element and
%% field matching, the `Service'/`Consumes' entry codec, parameter name checks
%% and the construction of structural errors (with a `path').
-module(bil_description).

-export([parse/2, encode/1]).
%% Shared with bil_signal.
-export([struct/3, field/3, required/3, number/3, finish/4, wrong_namespace/4,
         entry/2, encode_parameters/1, root_error/2, not_binary/0, fail/3, quote/1,
         valid_name/1, esc/1]).

-export_type([content/0]).

-define(NS, <<"urn:evatar:bil:1">>).
%% Structural errors are thrown from deep inside the walk and caught once,
%% in parse/2 here and in bil_signal:parse/2, which uses the same tag.
-define(TAG, bil_structure).
%% Longest piece of a value quoted in an error message, in characters.
-define(QUOTE_MAX, 60).

%% The children of an element as bil_xml returns them.
-type content() :: [xml_element() | binary()].
-type xml_element() :: {{binary() | undefined, binary()}, [{term(), binary()}], content()}.
-type known() :: [{binary() | undefined, binary()}].

%% ---------------------------------------------------------------------------
%% Parsing
%% ---------------------------------------------------------------------------

-spec parse(binary(), bil_limits:resolved()) ->
          {ok, bil:description()} | {error, bil:error_reason()}.
parse(Bin, Limits) when is_binary(Bin) ->
    case bil_xml:parse(Bin, Limits) of
        {ok, {{?NS, <<"description">>}, _, Children}} ->
            try
                {ok, description(Children)}
            catch
                throw:{?TAG, Reason} -> {error, Reason}
            end;
        {ok, {Name, _, _}} ->
            {error, root_error(<<"description">>, Name)};
        {error, _} = Error ->
            Error
    end;
parse(_, _) ->
    {error, not_binary()}.

description(C0) ->
    P = <<"/description">>,
    {ContextContent, C1} = struct(<<"context">>, C0, P),
    Description = context(ContextContent, <<"/description/context">>),
    {TypesContent, C2} = struct(<<"types">>, C1, P),
    Components = types(TypesContent, <<"/description/types">>, 1, #{}, []),
    finish(C2, P, [{?NS, <<"context">>}, {?NS, <<"types">>}], <<"context, then types">>),
    Description#{components => Components}.

context(C0, P) ->
    {Id, C1} = required(<<"EntityID">>, C0, P),
    {ApiName, C2} = field(<<"APIName">>, C1, P),
    {TypeText, C3} = field(<<"EntityType">>, C2, P),
    Type = entity_type(TypeText, P),
    {Context, C4} = field(<<"Context">>, C3, P),
    finish(C4, P, [{undefined, <<"EntityID">>}, {undefined, <<"APIName">>},
                   {undefined, <<"EntityType">>}, {undefined, <<"Context">>}],
           <<"EntityID, APIName, EntityType, Context, in that order">>),
    #{entity_id => Id, api_name => ApiName, entity_type => Type, context => Context}.

entity_type(<<"Agent">>, _) -> agent;
entity_type(<<"Avatar">>, _) -> avatar;
entity_type(Other, P) ->
    fail(bad_value, child(P, <<"EntityType">>),
         [<<"EntityType must be Agent or Avatar, found ">>, quote(Other)]).

types([{{?NS, <<"Component">>}, _, Content} | Rest], P, I, Seen, Acc) ->
    CP = indexed(P, <<"Component">>, I),
    #{id := Id} = Component = component(Content, CP),
    case Seen of
        #{Id := First} ->
            fail(duplicate_component, child(CP, <<"ComponentID">>),
                 [<<"ComponentID ">>, quote(Id), <<" is already used by Component[">>,
                  integer_to_binary(First),
                  <<"]; ComponentIDs must be unique within a description">>]);
        #{} ->
            types(Rest, P, I + 1, Seen#{Id => I}, [Component | Acc])
    end;
types([{{Ns, <<"Component">>}, _, _} | _], P, I, _, _) ->
    wrong_namespace(<<"Component">>, ?NS, Ns, indexed(P, <<"Component">>, I));
types([Text | Rest], P, I, Seen, Acc) when is_binary(Text) ->
    blank(Text, P),
    types(Rest, P, I, Seen, Acc);
types(Rest, P, _, _, Acc) ->
    finish(Rest, P, [], <<"only Component elements">>),
    lists:reverse(Acc).

component(C0, P) ->
    {Id, C1} = required(<<"ComponentID">>, C0, P),
    {Services, C2} = entries(<<"Service">>, C1, P, 1, []),
    case Services of
        [] -> absent({undefined, <<"Service">>}, C2, P, indexed(P, <<"Service">>, 1));
        _ -> ok
    end,
    {Consumes, C3} = entries(<<"Consumes">>, C2, P, 1, []),
    finish(C3, P, [{undefined, <<"ComponentID">>}, {undefined, <<"Service">>},
                   {undefined, <<"Consumes">>}],
           <<"ComponentID, then one or more Service, then zero or more Consumes">>),
    #{id => Id, services => Services, consumes => Consumes}.

entries(Local, [{{undefined, Local}, _, Content} | Rest], P, I, Acc) ->
    entries(Local, Rest, P, I + 1, [entry(Content, indexed(P, Local, I)) | Acc]);
entries(Local, [Text | Rest], P, I, Acc) when is_binary(Text) ->
    blank(Text, P),
    entries(Local, Rest, P, I, Acc);
entries(_, Rest, _, _, Acc) ->
    {lists:reverse(Acc), Rest}.

%% @doc A `Service' or `Consumes' entry, or a signal's `Body': the content of
%% the element at path `P'.
-spec entry(content(), binary()) -> bil:entry().
entry(C0, P) ->
    {Category, C1} = required(<<"ServiceCategory">>, C0, P),
    {Type, C2} = required(<<"ServiceType">>, C1, P),
    {Parameters, C3} =
        case C2 of
            [{{undefined, <<"ServiceParameters">>}, _, Content} | Rest] ->
                {parameters(Content, P, []), Rest};
            _ ->
                {[], C2}
        end,
    finish(C3, P, [{undefined, <<"ServiceCategory">>}, {undefined, <<"ServiceType">>},
                   {undefined, <<"ServiceParameters">>}],
           <<"ServiceCategory, ServiceType, then optionally ServiceParameters">>),
    #{category => Category, type => Type, parameters => Parameters}.

%% `P' is the entry's path: the parameters' paths are built only on error.
parameters([{{undefined, Name}, _, [Value]} | Rest], P, Acc) when is_binary(Value) ->
    parameters(Rest, P, [{Name, Value} | Acc]);
parameters([{{undefined, Name}, _, []} | Rest], P, Acc) ->
    parameters(Rest, P, [{Name, <<>>} | Acc]);
parameters([{{undefined, Name}, _, Content} | Rest], P, Acc) ->
    Value = text(Content, parameters_path(P), Name),
    parameters(Rest, P, [{Name, Value} | Acc]);
parameters([{{Ns, Name}, _, _} | _], P, _) ->
    wrong_namespace(Name, undefined, Ns, child(parameters_path(P), Name));
parameters([Text | Rest], P, Acc) when is_binary(Text) ->
    blank(Text, parameters_path(P)),
    parameters(Rest, P, Acc);
parameters([], P, Acc) ->
    Parameters = lists:reverse(Acc),
    unique_names(Parameters, P),
    Parameters.

%% maps:from_list/1 runs in C, so the common all-unique case is cheap for
%% any number of parameters; the duplicate is looked for only when there is one.
unique_names([], _) ->
    ok;
unique_names([_], _) ->
    ok;
unique_names(Parameters, P) ->
    case map_size(maps:from_list(Parameters)) =:= length(Parameters) of
        true -> ok;
        false -> find_duplicate(Parameters, P, #{})
    end.

find_duplicate([{Name, _} | Rest], P, Seen) ->
    case is_map_key(Name, Seen) of
        true -> duplicate_parameter(Name, P);
        false -> find_duplicate(Rest, P, Seen#{Name => true})
    end.

-spec duplicate_parameter(binary(), binary()) -> no_return().
duplicate_parameter(Name, P) ->
    fail(duplicate_element, child(parameters_path(P), Name),
         [<<"parameter ">>, Name, <<" appears more than once in ServiceParameters;">>,
          <<" parameter names must be unique within one ServiceParameters">>]).

parameters_path(P) -> child(P, <<"ServiceParameters">>).

%% ---------------------------------------------------------------------------
%% Shared walking helpers
%% ---------------------------------------------------------------------------

%% @doc Takes the structural element `Local' (in the BIL namespace) from the
%% head of `Content', whose parent is at path `P'; returns its content and
%% the rest.
-spec struct(binary(), content(), binary()) -> {content(), content()}.
struct(Local, [{{?NS, Local}, _, Content} | Rest], _) ->
    {Content, Rest};
struct(Local, [Text | Rest], P) when is_binary(Text) ->
    blank(Text, P),
    struct(Local, Rest, P);
struct(Local, Content, P) ->
    absent({?NS, Local}, Content, P, child(P, Local)).

%% @doc Takes the field `Local' (no namespace, text only) from the head of
%% `Content'; returns its text, kept exactly, and the rest.
-spec field(binary(), content(), binary()) -> {binary(), content()}.
field(Local, [{{undefined, Local}, _, Content} | Rest], P) ->
    {text(Content, P, Local), Rest};
field(Local, [Text | Rest], P) when is_binary(Text) ->
    blank(Text, P),
    field(Local, Rest, P);
field(Local, Content, P) ->
    absent({undefined, Local}, Content, P, child(P, Local)).

%% @doc Like field/3 for a field whose text must not be empty.
-spec required(binary(), content(), binary()) -> {binary(), content()}.
required(Local, Content, P) ->
    case field(Local, Content, P) of
        {<<>>, _} ->
            fail(bad_value, child(P, Local), [Local, <<" must not be empty">>]);
        Found ->
            Found
    end.

%% @doc The value of the number field `Local' of the element at `P': decimal
%% digits only, at most 20 of them.
-spec number(binary(), binary(), binary()) -> non_neg_integer().
number(Text, P, Local) ->
    case digits(Text, 0) of
        N when N >= 1, N =< 20 ->
            binary_to_integer(Text);
        N when N > 20 ->
            fail(bad_value, child(P, Local),
                 [Local, <<" has ">>, integer_to_binary(N),
                  <<" digits; at most 20 are allowed">>]);
        _ ->
            fail(bad_value, child(P, Local),
                 [Local, <<" must be decimal digits only (no sign, no spaces), found ">>,
                  quote(Text)])
    end.

digits(<<C, Rest/binary>>, N) when C >= $0, C =< $9 -> digits(Rest, N + 1);
digits(<<>>, N) -> N;
digits(_, _) -> -1.

%% @doc Checks that nothing but whitespace is left in the element at `P'.
%% `Known' lists the element names it allows, so that one of them in the
%% wrong namespace is reported as such; `Allowed' says in words what the
%% element may contain.
-spec finish(content(), binary(), known(), binary()) -> ok.
finish([], _, _, _) ->
    ok;
finish([Text | Rest], P, Known, Allowed) when is_binary(Text) ->
    blank(Text, P),
    finish(Rest, P, Known, Allowed);
finish([{{Ns, Local}, _, _} | _], P, Known, Allowed) ->
    case lists:keyfind(Local, 2, Known) of
        {WantNs, _} when WantNs =/= Ns ->
            wrong_namespace(Local, WantNs, Ns, child(P, Local));
        _ ->
            fail(unexpected_element, child(P, Local),
                 [<<"unexpected element ">>, Local, <<" in ">>, last(P), <<": ">>,
                  last(P), <<" contains ">>, Allowed])
    end.

%% Explains why the element `Want' (namespace and local name) is not at
%% the head of `Content': missing, out of order, or in the wrong namespace.
%% `P' is the parent's path, `WantPath' the path the element should have had.
-spec absent({binary() | undefined, binary()}, content(), binary(), binary()) ->
          no_return().
absent(Want, [Text | Rest], P, WantPath) when is_binary(Text) ->
    blank(Text, P),
    absent(Want, Rest, P, WantPath);
absent({WantNs, Local}, [{{Ns, Local}, _, _} | _], _, WantPath) ->
    wrong_namespace(Local, WantNs, Ns, WantPath);
absent({_, Local}, [], P, WantPath) ->
    fail(missing_element, WantPath,
         [<<"missing element ">>, Local, <<": ">>, last(P), <<" ends before it">>]);
absent({_, Local}, [{{_, Found}, _, _} | Rest], P, WantPath) ->
    case lists:any(fun({{_, L}, _, _}) -> L =:= Local; (_) -> false end, Rest) of
        true ->
            fail(unexpected_element, child(P, Found),
                 [<<"unexpected element ">>, Found, <<" in ">>, last(P), <<": expected ">>,
                  Local, <<" here (elements must come in the documented order)">>]);
        false ->
            fail(missing_element, WantPath,
                 [<<"missing element ">>, Local, <<" in ">>, last(P), <<": found ">>,
                  Found, <<" where ">>, Local, <<" was expected">>])
    end.

%% @doc Fails with `wrong_namespace': element `Local' at `Path' should be in
%% namespace `WantNs' (`undefined' for none) but is in `Ns'.
-spec wrong_namespace(binary(), binary() | undefined, binary() | undefined, binary()) ->
          no_return().
wrong_namespace(Local, undefined, ?NS, Path) ->
    fail(wrong_namespace, Path,
         [Local, <<" is in the BIL namespace, but fields and parameters must be in">>,
          <<" no namespace: bind BIL to a prefix (xmlns:bil=\"">>, ?NS,
          <<"\", then bil:Envelope or bil:description...) instead of declaring it">>,
          <<" as the default namespace">>]);
wrong_namespace(Local, undefined, Ns, Path) ->
    fail(wrong_namespace, Path,
         [Local, <<" must be in no namespace, found it in namespace ">>, Ns]);
wrong_namespace(Local, WantNs, undefined, Path) ->
    fail(wrong_namespace, Path,
         [Local, <<" must be in the BIL namespace ">>, WantNs, <<" (for example bil:">>,
          Local, <<" with xmlns:bil=\"">>, WantNs, <<"\"), found it in no namespace">>]);
wrong_namespace(Local, WantNs, Ns, Path) ->
    fail(wrong_namespace, Path,
         [Local, <<" must be in the BIL namespace ">>, WantNs,
          <<", found it in namespace ">>, Ns]).

%% @doc The error for a document whose root is `Found' where `Want' (in the
%% BIL namespace) was expected.
-spec root_error(binary(), {binary() | undefined, binary()}) -> bil:error_reason().
root_error(Want, Found) ->
    try root_fail(Want, Found)
    catch throw:{?TAG, Reason} -> Reason
    end.

-spec root_fail(binary(), {binary() | undefined, binary()}) -> no_return().
root_fail(Want, {Ns, Want}) ->
    wrong_namespace(Want, ?NS, Ns, <<"/", Want/binary>>);
root_fail(Want, {Ns, Local}) ->
    What = case {Ns, Local} of
               {?NS, <<"Envelope">>} -> <<"a BIL signal (Envelope)">>;
               {?NS, <<"description">>} -> <<"a BIL description">>;
               _ -> [<<"element ">>, Local]
           end,
    fail(wrong_root, <<"/", Local/binary>>,
         [<<"expected the root element ">>, Want, <<" in namespace ">>, ?NS,
          <<", found ">>, What]).

-spec not_binary() -> bil:error_reason().
not_binary() ->
    #{code => not_binary, message => <<"the document must be a binary">>}.

%% @doc Throws a structural error; caught by parse/2.
-spec fail(bil:error_code(), binary(), iodata()) -> no_return().
fail(Code, Path, Message) ->
    throw({?TAG, #{code => Code, path => Path, message => iolist_to_binary(Message)}}).

%% The text of a leaf element `Local' whose parent is at `P'. bil_xml gives
%% `[]' or one binary; several binaries are joined to be safe.
text([], _, _) ->
    <<>>;
text([Text], _, _) when is_binary(Text) ->
    Text;
text(Content, P, Local) ->
    case [Name || {{_, Name}, _, _} <- Content] of
        [] ->
            iolist_to_binary(Content);
        [Name | _] ->
            fail(unexpected_element, child(child(P, Local), Name),
                 [Local, <<" must contain only text, found element ">>, Name])
    end.

%% Whitespace between elements is ignored; other text is refused.
blank(Text, P) ->
    case is_blank(Text) of
        true ->
            ok;
        false ->
            fail(unexpected_element, P,
                 [<<"unexpected text ">>, quote(Text), <<" in ">>, last(P),
                  <<": only elements are allowed here">>])
    end.

is_blank(<<C, Rest/binary>>) when C =:= $\s; C =:= $\t; C =:= $\n; C =:= $\r ->
    is_blank(Rest);
is_blank(<<>>) -> true;
is_blank(_) -> false.

child(P, Local) -> <<P/binary, "/", Local/binary>>.

indexed(P, Local, I) ->
    <<P/binary, "/", Local/binary, "[", (integer_to_binary(I))/binary, "]">>.

last(P) ->
    lists:last(binary:split(P, <<"/">>, [global])).

%% @doc At most 60 characters of a value, quoted, for an error message.
-spec quote(binary()) -> iodata().
quote(Text) ->
    [$", truncate(Text, ?QUOTE_MAX, 0), $"].

truncate(Text, 0, Bytes) when Bytes < byte_size(Text) ->
    [binary:part(Text, 0, Bytes), <<"...">>];
truncate(Text, N, Bytes) ->
    case Text of
        <<_:Bytes/binary, C/utf8, _/binary>> ->
            truncate(Text, N - 1, Bytes + byte_size(<<C/utf8>>));
        _ ->
            binary:part(Text, 0, Bytes)
    end.

%% ---------------------------------------------------------------------------
%% Encoding
%% ---------------------------------------------------------------------------

-spec encode(bil:description()) -> iodata().
encode(#{entity_id := Id, api_name := ApiName, entity_type := Type, context := Context,
         components := Components}) ->
    [<<"<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
       "<bil:description xmlns:bil=\"urn:evatar:bil:1\">\n"
       "  <bil:context>\n"
       "    <EntityID>">>, esc(Id), <<"</EntityID>\n"
       "    <APIName>">>, esc(ApiName), <<"</APIName>\n"
       "    <EntityType>">>, encode_entity_type(Type), <<"</EntityType>\n"
       "    <Context>">>, esc(Context), <<"</Context>\n"
       "  </bil:context>\n">>,
     case Components of
         [] -> <<"  <bil:types/>\n">>;
         _ -> [<<"  <bil:types>\n">>, [encode_component(C) || C <- Components],
               <<"  </bil:types>\n">>]
     end,
     <<"</bil:description>\n">>].

encode_entity_type(agent) -> <<"Agent">>;
encode_entity_type(avatar) -> <<"Avatar">>.

encode_component(#{id := Id, services := Services, consumes := Consumes}) ->
    [<<"    <bil:Component>\n"
       "      <ComponentID>">>, esc(Id), <<"</ComponentID>\n">>,
     [encode_entry(<<"Service">>, E) || E <- Services],
     [encode_entry(<<"Consumes">>, E) || E <- Consumes],
     <<"    </bil:Component>\n">>].

encode_entry(Tag, #{category := Category, type := Type, parameters := Parameters}) ->
    [<<"      <">>, Tag, <<">\n"
       "        <ServiceCategory>">>, esc(Category), <<"</ServiceCategory>\n"
       "        <ServiceType>">>, esc(Type), <<"</ServiceType>\n">>,
     case Parameters of
         [] ->
             <<"        <ServiceParameters/>\n">>;
         _ ->
             [<<"        <ServiceParameters>\n">>,
              [[<<"          <">>, check_name(N), $>, esc(V), <<"</">>, N, <<">\n">>]
               || {N, V} <- Parameters],
              <<"        </ServiceParameters>\n">>]
     end,
     <<"      </">>, Tag, <<">\n">>].

%% @doc The `ServiceParameters' element of a signal body, without whitespace.
%% Raises `{bad_parameter_name, Name}' if a name is not an XML name.
-spec encode_parameters([bil:parameter()]) -> iodata().
encode_parameters([]) ->
    <<"<ServiceParameters/>">>;
encode_parameters(Parameters) ->
    [<<"<ServiceParameters>">>, encode_parameters_(Parameters), <<"</ServiceParameters>">>].

encode_parameters_([{Name, Value} | Rest]) ->
    [$<, check_name(Name), $>, esc(Value), <<"</">>, Name, $> | encode_parameters_(Rest)];
encode_parameters_([]) ->
    [].

%% @doc Escapes text for an element's content. Encoding is the hot path of
%% every signal sent, and almost every value is short and has nothing to
%% escape: a plain byte scan settles that faster than the general escaper's
%% pattern lookup and search, which long or special text still goes to.
-spec esc(binary()) -> iodata().
esc(Text) when byte_size(Text) =< 128 ->
    case plain(Text) of
        true -> Text;
        false -> bil_xml:escape_text(Text)
    end;
esc(Text) ->
    bil_xml:escape_text(Text).

plain(<<C, Rest/binary>>) when C =/= $&, C =/= $<, C =/= $>, C =/= $\r -> plain(Rest);
plain(<<>>) -> true;
plain(_) -> false.

%% `Name' if it can be written as an element name in no namespace (an
%% XML NCName), else raises `{bad_parameter_name, Name}': a term with such a
%% name is a programmer error, never the result of parsing.
-spec check_name(binary()) -> binary().
check_name(Name) ->
    case valid_name(Name) of
        true -> Name;
        false -> error({bad_parameter_name, Name})
    end.

%% @doc Whether `Name' is an XML name without a colon (an NCName), per
%% XML 1.0 fifth edition.
-spec valid_name(term()) -> boolean().
%% ASCII first, with plain guards: names are almost always ASCII.
valid_name(<<C, Rest/binary>>) when C >= $a, C =< $z; C >= $A, C =< $Z; C =:= $_ ->
    name_rest(Rest);
valid_name(<<C/utf8, Rest/binary>>) when C >= 16#80 ->
    name_start(C) andalso name_rest(Rest);
valid_name(_) ->
    false.

name_rest(<<C, Rest/binary>>) when C >= $a, C =< $z; C >= $A, C =< $Z; C >= $0, C =< $9;
                                   C =:= $_; C =:= $-; C =:= $. ->
    name_rest(Rest);
name_rest(<<>>) ->
    true;
name_rest(<<C/utf8, Rest/binary>>) when C >= 16#80 ->
    (name_start(C) orelse name_char(C)) andalso name_rest(Rest);
name_rest(_) ->
    false.

name_start(C) when C >= $a, C =< $z; C >= $A, C =< $Z; C =:= $_ -> true;
name_start(C) when C < 16#C0 -> false;
name_start(C) when C =< 16#D6; C >= 16#D8, C =< 16#F6; C >= 16#F8, C =< 16#2FF;
                   C >= 16#370, C =< 16#37D; C >= 16#37F, C =< 16#1FFF;
                   C >= 16#200C, C =< 16#200D; C >= 16#2070, C =< 16#218F;
                   C >= 16#2C00, C =< 16#2FEF; C >= 16#3001, C =< 16#D7FF;
                   C >= 16#F900, C =< 16#FDCF; C >= 16#FDF0, C =< 16#FFFD;
                   C >= 16#10000, C =< 16#EFFFF -> true;
name_start(_) -> false.

name_char(C) when C >= $0, C =< $9; C =:= $-; C =:= $.; C =:= 16#B7;
                  C >= 16#300, C =< 16#36F; C >= 16#203F, C =< 16#2040 -> true;
name_char(_) -> false.

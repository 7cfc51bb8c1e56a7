%% @doc Public (app evatar_protocol, with agent_bridge_frame). The control
%% documents of the EVATAR wire protocol (Hello, Resume, Welcome, Refused,
%% Binding, GetBinding, Ack, Bye: docs/protocol.md) parsed from and encoded
%% to BIL XML, and `parse_frame/2', which routes one frame to the control,
%% signal or description parser by its root element. Uses only bil's API.
-module(bil_control).

-export([parse/2, encode/1, parse_frame/2, root_name/1]).

-export_type([control/0, hello/0, resume/0, welcome/0, welcome_ha/0, refused/0,
              binding_report/0, ack/0, role/0, frame/0, frame_limits/0]).

-type role() :: agent | avatar.
-type hello() :: #{pairing := binary(),
                   role := role(),
                   entity_id := binary(),
                   credential := binary(),
                   protocol_version := non_neg_integer()}.
%% Resuming a session (protocol version 2): the Hello's fields, then the
%% session to resume, the highest Sequence the client has processed in it
%% and the highest Epoch it has seen.
-type resume() :: #{pairing := binary(),
                    role := role(),
                    entity_id := binary(),
                    credential := binary(),
                    protocol_version := non_neg_integer(),
                    session_id := binary(),
                    received := non_neg_integer(),
                    epoch := non_neg_integer()}.
%% The fields a version 2 Welcome appends: all of them or none.
-type welcome_ha() :: #{epoch := non_neg_integer(),
                        resumed := boolean(),
                        last_accepted := binary(),
                        dedup_window := non_neg_integer(),
                        heartbeat := non_neg_integer()}.
-type welcome() :: #{pairing := binary(),
                     entity_id := binary(),
                     session_id := binary(),
                     join_timeout := non_neg_integer(),
                     max_frame := non_neg_integer(),
                     ha => welcome_ha()}.
%% Both fields optional: `accepted' (EVATAR to client: every signal the
%% client sent up to this SignalID is accepted), `received' (client to
%% EVATAR: every signal up to this Sequence is processed). An empty Ack is a
%% heartbeat.
-type ack() :: #{accepted => binary(), received => non_neg_integer()}.
%% `code' stays a binary: a client must cope with codes newer than itself.
-type refused() :: #{code := binary(), message := binary()}.
-type binding_report() :: #{bound := [bil:binding()],
                            unbound := [bil:unbound()],
                            entities := [binary()]}.
-type control() :: {hello, hello()}
                 | {resume, resume()}
                 | {welcome, welcome()}
                 | {ack, ack()}
                 | {refused, refused()}
                 | {binding, binding_report()}
                 | {get_binding, #{}}
                 | {bye, Reason :: binary()}.
-type frame() :: {control, control()}
               | {signal, bil:signal()}
               | {description, bil:description()}.
%% Per-kind limits; a missing kind takes the defaults (signal 64 KiB,
%% description 1 MiB, control 1 MiB since a Binding report can be long).
-type frame_limits() :: #{signal => bil:limits(),
                          description => bil:limits(),
                          control => bil:limits()}.

-define(CONTROL_MAX_SIZE, 1048576).
-define(MAX_DIGITS, 20).

%% ---------------------------------------------------------------------------
%% Frames
%% ---------------------------------------------------------------------------

%% @doc Parses one frame's document: a control document, a signal
%% (`bil:Envelope') or a description (`bil:description'). Only the root
%% element's name is looked at before the right parser, with the right size
%% limit, takes the whole document.
-spec parse_frame(binary(), frame_limits()) ->
          {ok, frame()} | {error, bil:error_reason()}.
parse_frame(Bin, Limits) when is_binary(Bin) ->
    case root_name(Bin) of
        {ok, <<"Envelope">>} ->
            tag(signal, bil:parse_signal(Bin, maps:get(signal, Limits, #{})));
        {ok, <<"description">>} ->
            tag(description,
                bil:parse_description(Bin, maps:get(description, Limits, #{})));
        _ ->
            tag(control, parse(Bin, maps:get(control, Limits, #{})))
    end;
parse_frame(_, _) ->
    {error, #{code => not_binary, message => <<"a frame must be a binary">>}}.

tag(Kind, {ok, Term}) -> {ok, {Kind, Term}};
tag(_, {error, _} = Error) -> Error.

%% @doc The local name of a document's root element, found by skipping only
%% a byte order mark, whitespace, the XML declaration, comments and
%% processing instructions. `error' when that is not enough; the full
%% parser then says exactly what is wrong.
-spec root_name(binary()) -> {ok, binary()} | error.
%% How bil:encode_signal/1 and the SDKs begin every signal, named without
%% a scan (the parser checks the rest).
root_name(<<"<?xml version=\"1.0\" encoding=\"UTF-8\"?><bil:Envelope", C, _/binary>>)
  when C =:= $\s; C =:= $\t; C =:= $\r; C =:= $\n; C =:= $/; C =:= $> ->
    {ok, <<"Envelope">>};
root_name(<<16#EF, 16#BB, 16#BF, Rest/binary>>) -> prolog(Rest);
root_name(Bin) -> prolog(Bin).

prolog(<<C, Rest/binary>>) when C =:= $\s; C =:= $\t; C =:= $\r; C =:= $\n ->
    prolog(Rest);
prolog(<<"<?", Rest/binary>>) -> skip_past(Rest, <<"?>">>);
prolog(<<"<!--", Rest/binary>>) -> skip_past(Rest, <<"-->">>);
prolog(<<"<", C, _/binary>> = Bin) when (C >= $a andalso C =< $z);
                                         (C >= $A andalso C =< $Z); C =:= $_ ->
    element_name(binary:part(Bin, 1, byte_size(Bin) - 1), 1);
prolog(_) -> error.

skip_past(Bin, Marker) ->
    case binary:match(Bin, Marker) of
        {Pos, Len} -> prolog(binary:part(Bin, Pos + Len, byte_size(Bin) - Pos - Len));
        nomatch -> error
    end.

element_name(Bin, N) ->
    case Bin of
        <<_:N/binary, C, _/binary>> when C =:= $\s; C =:= $\t; C =:= $\r;
                                         C =:= $\n; C =:= $/; C =:= $> ->
            local_name(binary:part(Bin, 0, N));
        <<_:N/binary, _, _/binary>> when N < 256 -> element_name(Bin, N + 1);
        _ -> error
    end.

local_name(<<>>) -> error;
local_name(QName) ->
    case binary:split(QName, <<":">>) of
        [Prefix, Local] when Prefix =/= <<>>, Local =/= <<>> -> {ok, Local};
        [Local] -> {ok, Local};
        _ -> error
    end.

%% ---------------------------------------------------------------------------
%% Parsing
%% ---------------------------------------------------------------------------

%% @doc Parses a control document. Fields are in no namespace, in the order
%% docs/protocol.md gives; elements after the last known field are ignored
%% so later protocol versions can append fields.
-spec parse(binary(), bil:limits()) -> {ok, control()} | {error, bil:error_reason()}.
parse(Bin, Limits) when is_binary(Bin) ->
    XmlLimits = #{max_size => maps:get(max_size, Limits, ?CONTROL_MAX_SIZE),
                  max_depth => maps:get(max_depth, Limits,
                                        application:get_env(bil, max_depth, 32))},
    case bil:parse_xml(Bin, XmlLimits) of
        {ok, {{Ns, Local}, _Attrs, Children}} ->
            case Ns =:= bil:namespace() of
                true -> root(Local, Children);
                false -> err(wrong_namespace, <<"the root element is not in the BIL namespace">>,
                             <<"/", Local/binary>>)
            end;
        {error, _} = Error ->
            Error
    end;
parse(_, _) ->
    {error, #{code => not_binary, message => <<"a control document must be a binary">>}}.

root(<<"Hello">>, Children) ->
    maybe_fields(Children, <<"/Hello">>,
                 [{<<"Pairing">>, text}, {<<"Role">>, role}, {<<"EntityID">>, text},
                  {<<"Credential">>, any_text}, {<<"ProtocolVersion">>, integer}],
                 fun([Pairing, Role, Entity, Credential, Version]) ->
                         {hello, #{pairing => Pairing, role => Role, entity_id => Entity,
                                   credential => Credential, protocol_version => Version}}
                 end);
root(<<"Resume">>, Children) ->
    maybe_fields(Children, <<"/Resume">>,
                 [{<<"Pairing">>, text}, {<<"Role">>, role}, {<<"EntityID">>, text},
                  {<<"Credential">>, any_text}, {<<"ProtocolVersion">>, integer},
                  {<<"SessionID">>, text}, {<<"Received">>, integer}, {<<"Epoch">>, integer}],
                 fun([Pairing, Role, Entity, Credential, Version, Session, Received, Epoch]) ->
                         {resume, #{pairing => Pairing, role => Role, entity_id => Entity,
                                    credential => Credential, protocol_version => Version,
                                    session_id => Session, received => Received,
                                    epoch => Epoch}}
                 end);
root(<<"Welcome">>, Children) ->
    Path = <<"/Welcome">>,
    case fields(Children, [{<<"Pairing">>, text}, {<<"EntityID">>, text},
                           {<<"SessionID">>, text}, {<<"JoinTimeout">>, integer},
                           {<<"MaxFrame">>, integer}], Path, []) of
        {ok, [Pairing, Entity, Session, JoinTimeout, MaxFrame], Rest} ->
            Welcome = #{pairing => Pairing, entity_id => Entity, session_id => Session,
                        join_timeout => JoinTimeout, max_frame => MaxFrame},
            case Rest of
                [{{_, <<"Epoch">>}, _, _} | _] ->
                    case fields(Rest, [{<<"Epoch">>, integer}, {<<"Resumed">>, boolean},
                                       {<<"LastAccepted">>, any_text},
                                       {<<"DedupWindow">>, integer},
                                       {<<"Heartbeat">>, integer}], Path, []) of
                        {ok, [Epoch, Resumed, Last, Window, Heartbeat], _} ->
                            {ok, {welcome, Welcome#{ha => #{epoch => Epoch, resumed => Resumed,
                                                            last_accepted => Last,
                                                            dedup_window => Window,
                                                            heartbeat => Heartbeat}}}};
                        {error, _} = Error ->
                            Error
                    end;
                _ ->
                    {ok, {welcome, Welcome}}
            end;
        {error, _} = Error ->
            Error
    end;
root(<<"Ack">>, Children) ->
    ack(Children, <<"/Ack">>);
root(<<"Refused">>, Children) ->
    maybe_fields(Children, <<"/Refused">>,
                 [{<<"Code">>, text}, {<<"Message">>, any_text}],
                 fun([Code, Message]) -> {refused, #{code => Code, message => Message}} end);
%% Reason is optional; like every reader here, elements after the known
%% fields are ignored (docs/protocol.md section 2), so a later protocol may
%% add some.
root(<<"Bye">>, []) ->
    {ok, {bye, <<>>}};
root(<<"Bye">>, [{{_, Name}, _, _} | _]) when Name =/= <<"Reason">> ->
    {ok, {bye, <<>>}};
root(<<"Bye">>, Children) ->
    maybe_fields(Children, <<"/Bye">>, [{<<"Reason">>, any_text}],
                 fun([Reason]) -> {bye, Reason} end);
root(<<"Binding">>, Children) ->
    binding(Children);
%% No fields yet; like every reader here, elements in it are ignored.
root(<<"GetBinding">>, _Children) ->
    {ok, {get_binding, #{}}};
root(Local, _) ->
    err(wrong_root, <<"expected Hello, Resume, Welcome, Refused, Binding, GetBinding, Ack, Bye, "
                      "Envelope or description">>,
        <<"/", Local/binary>>).

maybe_fields(Children, Path, Spec, Build) ->
    case fields(Children, Spec, Path, []) of
        {ok, Values, _Ignored} -> {ok, Build(Values)};
        {error, _} = Error -> Error
    end.

%% Reads the fields of Spec in order; returns the elements left after them.
fields(Rest, [], _Path, Acc) ->
    {ok, lists:reverse(Acc), Rest};
fields([{{Ns, Name}, _, Content} | Rest], [{Name, Kind} | Spec], Path, Acc) ->
    FieldPath = <<Path/binary, "/", Name/binary>>,
    case no_namespace(Ns) of
        false ->
            err(wrong_namespace, <<"field elements are in no namespace">>, FieldPath);
        true ->
            case value(Kind, Content, FieldPath) of
                {ok, Value} -> fields(Rest, Spec, Path, [Value | Acc]);
                {error, _} = Error -> Error
            end
    end;
fields([{{_, Other}, _, _} | _], [{Name, _} | _], Path, _) ->
    err(unexpected_element, <<"expected ", Name/binary, ", found ", Other/binary>>,
        <<Path/binary, "/", Other/binary>>);
fields([Text | _], _, Path, _) when is_binary(Text) ->
    err(unexpected_element, <<"text is not allowed here">>, Path);
fields([], [{Name, _} | _], Path, _) ->
    err(missing_element, <<Name/binary, " is missing">>, <<Path/binary, "/", Name/binary>>).

no_namespace(Ns) -> Ns =:= <<>> orelse Ns =:= undefined.

value(Kind, Content, Path) ->
    case text(Content) of
        {ok, Text} -> typed(Kind, Text, Path);
        error -> err(unexpected_element, <<"a field holds text only">>, Path)
    end.

text([]) -> {ok, <<>>};
text([Text]) when is_binary(Text) -> {ok, Text};
text(_) -> error.

typed(any_text, Text, _Path) -> {ok, Text};
typed(text, <<>>, Path) -> err(bad_value, <<"must not be empty">>, Path);
typed(text, Text, _Path) -> {ok, Text};
typed(role, <<"agent">>, _Path) -> {ok, agent};
typed(role, <<"avatar">>, _Path) -> {ok, avatar};
typed(role, _, Path) -> err(bad_value, <<"Role is agent or avatar">>, Path);
typed(boolean, <<"true">>, _Path) -> {ok, true};
typed(boolean, <<"false">>, _Path) -> {ok, false};
typed(boolean, _, Path) -> err(bad_value, <<"expected true or false">>, Path);
typed(reason, <<"NoProvider">>, _Path) -> {ok, no_provider};
typed(reason, <<"ParametersMismatch">>, _Path) -> {ok, parameters_mismatch};
typed(reason, _, Path) -> err(bad_value, <<"Reason is NoProvider or ParametersMismatch">>, Path);
typed(integer, Text, Path) ->
    case byte_size(Text) =< ?MAX_DIGITS andalso digits(Text) of
        true -> {ok, binary_to_integer(Text)};
        false -> err(bad_value, <<"expected 1 to 20 decimal digits">>, Path)
    end;
typed(positive, Text, Path) ->
    case typed(integer, Text, Path) of
        {ok, 0} -> err(bad_value, <<"must be at least 1">>, Path);
        Other -> Other
    end.

digits(<<>>) -> false;
digits(Text) -> lists:all(fun(C) -> C >= $0 andalso C =< $9 end, binary_to_list(Text)).

%% Both fields are optional, in this order; what follows them is ignored.
ack(Children, Path) ->
    case optional(Children, <<"Accepted">>, text, Path) of
        {ok, Accepted, Rest} ->
            case optional(Rest, <<"Received">>, integer, Path) of
                {ok, Received, _Ignored} ->
                    {ok, {ack, maps:from_list([{accepted, Accepted} || Accepted =/= none] ++
                                              [{received, Received} || Received =/= none])}};
                {error, _} = Error ->
                    Error
            end;
        {error, _} = Error ->
            Error
    end.

optional([{{_, Name}, _, _} | _] = Children, Name, Kind, Path) ->
    case fields(Children, [{Name, Kind}], Path, []) of
        {ok, [Value], Rest} -> {ok, Value, Rest};
        {error, _} = Error -> Error
    end;
optional([Text | _], _Name, _Kind, Path) when is_binary(Text) ->
    err(unexpected_element, <<"text is not allowed here">>, Path);
optional(Children, _Name, _Kind, _Path) ->
    {ok, none, Children}.

binding(Children) ->
    Path = <<"/Binding">>,
    case Children of
        [{{Ns, <<"Entities">>}, _, Entities} | Rows] ->
            case no_namespace(Ns) andalso entities(Entities, Path, []) of
                false -> err(wrong_namespace, <<"field elements are in no namespace">>,
                             <<Path/binary, "/Entities">>);
                {ok, Ids} -> rows(Rows, Path, Ids, [], [], 1);
                {error, _} = Error -> Error
            end;
        _ ->
            err(missing_element, <<"Entities must come first">>, <<Path/binary, "/Entities">>)
    end.

entities([], _Path, Acc) ->
    {ok, lists:reverse(Acc)};
entities([{{Ns, <<"EntityID">>}, _, Content} | Rest], Path, Acc) ->
    FieldPath = <<Path/binary, "/Entities/EntityID">>,
    case no_namespace(Ns) andalso value(text, Content, FieldPath) of
        {ok, Id} -> entities(Rest, Path, [Id | Acc]);
        false -> err(wrong_namespace, <<"field elements are in no namespace">>, FieldPath);
        {error, _} = Error -> Error
    end;
entities(_, Path, _) ->
    err(unexpected_element, <<"Entities holds EntityID elements only">>,
        <<Path/binary, "/Entities">>).

-define(BOUND_SPEC, [{<<"ConsumerEntity">>, text}, {<<"ConsumerComponent">>, text},
                     {<<"ProviderEntity">>, text}, {<<"ProviderComponent">>, text},
                     {<<"ServiceCategory">>, text}, {<<"ServiceType">>, text},
                     {<<"Score">>, integer}, {<<"Candidates">>, positive}]).
-define(UNBOUND_SPEC, [{<<"ConsumerEntity">>, text}, {<<"ConsumerComponent">>, text},
                       {<<"ServiceCategory">>, text}, {<<"ServiceType">>, text},
                       {<<"Reason">>, reason}]).

%% Bound rows come before Unbound rows; anything after them is ignored.
rows([{{Ns, <<"Bound">>}, _, Content} | Rest], Path, Ids, Bound, [], N) ->
    RowPath = iolist_to_binary([Path, "/Bound[", integer_to_binary(N), "]"]),
    case no_namespace(Ns) andalso fields(Content, ?BOUND_SPEC, RowPath, []) of
        {ok, [CE, CC, PE, PC, Cat, Type, Score, Cands], _} ->
            Row = #{consumer => #{entity => CE, component => CC},
                    provider => #{entity => PE, component => PC},
                    category => Cat, type => Type, score => Score, candidates => Cands},
            rows(Rest, Path, Ids, [Row | Bound], [], N + 1);
        false -> err(wrong_namespace, <<"field elements are in no namespace">>, RowPath);
        {error, _} = Error -> Error
    end;
rows([{{Ns, <<"Unbound">>}, _, Content} | Rest], Path, Ids, Bound, Unbound, _) ->
    RowPath = iolist_to_binary([Path, "/Unbound[", integer_to_binary(length(Unbound) + 1), "]"]),
    case no_namespace(Ns) andalso fields(Content, ?UNBOUND_SPEC, RowPath, []) of
        {ok, [CE, CC, Cat, Type, Reason], _} ->
            Row = #{consumer => #{entity => CE, component => CC},
                    category => Cat, type => Type, reason => Reason},
            rows(Rest, Path, Ids, Bound, [Row | Unbound], 0);
        false -> err(wrong_namespace, <<"field elements are in no namespace">>, RowPath);
        {error, _} = Error -> Error
    end;
rows([Text | _], Path, _, _, _, _) when is_binary(Text) ->
    err(unexpected_element, <<"text is not allowed here">>, Path);
rows(_Ignored, _Path, Ids, Bound, Unbound, _) ->
    {ok, {binding, #{entities => Ids, bound => lists:reverse(Bound),
                     unbound => lists:reverse(Unbound)}}}.

err(Code, Message, Path) ->
    {error, #{code => Code, message => Message, path => Path}}.

%% ---------------------------------------------------------------------------
%% Encoding
%% ---------------------------------------------------------------------------

%% @doc Encodes a control document as UTF-8 iodata, on one line, without an
%% XML declaration.
-spec encode(control()) -> iodata().
encode({hello, #{pairing := P, role := Role, entity_id := E, credential := C,
                 protocol_version := V}}) ->
    document(<<"Hello">>, [field(<<"Pairing">>, P), field(<<"Role">>, atom_to_binary(Role)),
                       field(<<"EntityID">>, E), field(<<"Credential">>, C),
                       field(<<"ProtocolVersion">>, integer_to_binary(V))]);
encode({resume, #{pairing := P, role := Role, entity_id := E, credential := C,
                  protocol_version := V, session_id := S, received := R, epoch := Ep}}) ->
    document(<<"Resume">>, [field(<<"Pairing">>, P), field(<<"Role">>, atom_to_binary(Role)),
                        field(<<"EntityID">>, E), field(<<"Credential">>, C),
                        field(<<"ProtocolVersion">>, integer_to_binary(V)),
                        field(<<"SessionID">>, S), field(<<"Received">>, integer_to_binary(R)),
                        field(<<"Epoch">>, integer_to_binary(Ep))]);
encode({welcome, #{pairing := P, entity_id := E, session_id := S, join_timeout := J,
                   max_frame := M} = W}) ->
    Ha = case W of
             #{ha := #{epoch := Ep, resumed := Res, last_accepted := L, dedup_window := Win,
                       heartbeat := Hb}} ->
                 [field(<<"Epoch">>, integer_to_binary(Ep)),
                  field(<<"Resumed">>, atom_to_binary(Res)),
                  field(<<"LastAccepted">>, L),
                  field(<<"DedupWindow">>, integer_to_binary(Win)),
                  field(<<"Heartbeat">>, integer_to_binary(Hb))];
             #{} ->
                 []
         end,
    document(<<"Welcome">>, [field(<<"Pairing">>, P), field(<<"EntityID">>, E),
                         field(<<"SessionID">>, S),
                         field(<<"JoinTimeout">>, integer_to_binary(J)),
                         field(<<"MaxFrame">>, integer_to_binary(M)) | Ha]);
encode({ack, Ack}) ->
    document(<<"Ack">>, [[field(<<"Accepted">>, A) || #{accepted := A} <- [Ack]],
                     [field(<<"Received">>, integer_to_binary(R)) || #{received := R} <- [Ack]]]);
encode({refused, #{code := Code, message := Message}}) ->
    document(<<"Refused">>, [field(<<"Code">>, Code), field(<<"Message">>, Message)]);
encode({bye, <<>>}) ->
    document(<<"Bye">>, []);
encode({get_binding, #{}}) ->
    document(<<"GetBinding">>, []);
encode({bye, Reason}) ->
    document(<<"Bye">>, [field(<<"Reason">>, Reason)]);
encode({binding, #{entities := Ids, bound := Bound, unbound := Unbound}}) ->
    document(<<"Binding">>,
         [[<<"<Entities>">>, [field(<<"EntityID">>, Id) || Id <- Ids], <<"</Entities>">>],
          [bound_row(Row) || Row <- Bound],
          [unbound_row(Row) || Row <- Unbound]]).

bound_row(#{consumer := #{entity := CE, component := CC},
            provider := #{entity := PE, component := PC},
            category := Cat, type := Type, score := Score, candidates := Cands}) ->
    [<<"<Bound>">>,
     field(<<"ConsumerEntity">>, CE), field(<<"ConsumerComponent">>, CC),
     field(<<"ProviderEntity">>, PE), field(<<"ProviderComponent">>, PC),
     field(<<"ServiceCategory">>, Cat), field(<<"ServiceType">>, Type),
     field(<<"Score">>, integer_to_binary(Score)),
     field(<<"Candidates">>, integer_to_binary(Cands)),
     <<"</Bound>">>].

unbound_row(#{consumer := #{entity := CE, component := CC}, category := Cat, type := Type,
              reason := Reason}) ->
    [<<"<Unbound>">>,
     field(<<"ConsumerEntity">>, CE), field(<<"ConsumerComponent">>, CC),
     field(<<"ServiceCategory">>, Cat), field(<<"ServiceType">>, Type),
     field(<<"Reason">>, case Reason of
                             no_provider -> <<"NoProvider">>;
                             parameters_mismatch -> <<"ParametersMismatch">>
                         end),
     <<"</Unbound>">>].

document(Name, Fields) ->
    [<<"<bil:">>, Name, <<" xmlns:bil=\"">>, bil:namespace(), <<"\">">>, Fields,
     <<"</bil:">>, Name, <<">">>].

field(Name, Value) ->
    [$<, Name, $>, bil:escape_text(Value), $<, $/, Name, $>].

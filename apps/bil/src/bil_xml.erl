%% @doc Internal. The XML parser behind every BIL document: a fast,
%% namespace-aware parser for the XML subset of docs/bil.md section 1 that
%% refuses DTDs and entities and never raises on bad input.
%%
%% Elements come back as `{{NsUri, Local}, Attributes, Children}' with names
%% and text as sub-binaries of the input (no atoms). Error positions are
%% 1-based; a column counts characters (Unicode code points, a byte order
%% mark not included) from the start of the line, where CR LF, CR and LF end
%% a line.
-module(bil_xml).

-export([parse/2, escape_text/1, escape_attr/1, error_at/4]).

-export_type([name/0, element/0, attribute/0]).

-include_lib("kernel/include/logger.hrl").

-type name() :: {Ns :: binary() | undefined, Local :: binary()}.
-type element() :: {name(), [attribute()], [element() | binary()]}.
%% Namespace declarations (`xmlns', `xmlns:p') are not attributes here.
-type attribute() :: {name(), Value :: binary()}.

%% How it is fast: the hot path (names, text, tags of elements without
%% attributes) walks one binary match context from function head to
%% function head, counting offsets into the input, and cuts sub-binaries
%% (binary_part/3) only for the names and text it returns. Every byte is
%% checked on the way (UTF-8, control characters), so there is no separate
%% validation pass. Rarer constructs (comments, PIs, CDATA, references,
%% attributes, the XML declaration) work from offsets with binary:match/3
%% and ordinary binary matching.

-define(XML_NS, <<"http://www.w3.org/XML/1998/namespace">>).
-define(XMLNS_NS, <<"http://www.w3.org/2000/xmlns/">>).
%% A scope is {DefaultNs, [{Prefix, Ns}]}, innermost declarations first.
-define(ROOT_SCOPE, {undefined, [{<<"xml">>, ?XML_NS}]}).
-define(PATTERNS_KEY, {?MODULE, patterns}).
-define(MAX_CHAR, 16#10FFFF).

-define(IS_WS(C), (C =:= $\s orelse C =:= $\n orelse C =:= $\t orelse C =:= $\r)).
-define(IS_NAME_START(C),
        ((C >= $a andalso C =< $z) orelse (C >= $A andalso C =< $Z) orelse C =:= $_)).
-define(IS_NAME_CHAR(C),
        ((C >= $a andalso C =< $z) orelse (C >= $A andalso C =< $Z) orelse
         (C >= $0 andalso C =< $9) orelse C =:= $_ orelse C =:= $- orelse C =:= $.)).
%% XML 1.0 (fifth edition) NameStartChar and NameChar beyond ASCII.
-define(IS_NAME_START_CP(C),
        ((C >= 16#C0 andalso C =< 16#D6) orelse (C >= 16#D8 andalso C =< 16#F6) orelse
         (C >= 16#F8 andalso C =< 16#2FF) orelse (C >= 16#370 andalso C =< 16#37D) orelse
         (C >= 16#37F andalso C =< 16#1FFF) orelse (C >= 16#200C andalso C =< 16#200D) orelse
         (C >= 16#2070 andalso C =< 16#218F) orelse (C >= 16#2C00 andalso C =< 16#2FEF) orelse
         (C >= 16#3001 andalso C =< 16#D7FF) orelse (C >= 16#F900 andalso C =< 16#FDCF) orelse
         (C >= 16#FDF0 andalso C =< 16#FFFD) orelse (C >= 16#10000 andalso C =< 16#EFFFF))).
-define(IS_NAME_CHAR_CP(C),
        (?IS_NAME_START_CP(C) orelse C =:= 16#B7 orelse (C >= 16#300 andalso C =< 16#36F) orelse
         (C >= 16#203F andalso C =< 16#2040))).
%% Text bytes that need no attention: ASCII other than '<', '&', ']', CR
%% and control characters.
-define(IS_PLAIN(C), ((C >= 16#3D andalso C =< 16#7F andalso C =/= $]) orelse
                      (C >= 16#27 andalso C =< 16#3B) orelse (C >= 16#20 andalso C =< 16#25) orelse
                      C =:= $\n orelse C =:= $\t)).
%% Attribute value bytes the fast path takes as they are (quoted by Q).
-define(IS_VALUE_CHAR(C, Q), (C >= 16#20 andalso C =< 16#7F andalso C =/= $< andalso C =/= $&
                              andalso C =/= Q)).
%% C0 controls other than tab, LF and CR: never allowed in XML 1.0.
-define(IS_BAD_CONTROL(C), (C < 16#20 andalso C =/= $\t andalso C =/= $\n andalso C =/= $\r)).
%% A decoded non-ASCII character that XML allows (surrogates and values
%% past U+10FFFF never decode from UTF-8).
-define(IS_LEGAL_CP(C), (C >= 16#80 andalso C =/= 16#FFFE andalso C =/= 16#FFFF)).

%% Compiled binary:match patterns, built once per node (see patterns/0).
%% The scanning patterns also stop at control bytes and at bytes >= 0x80,
%% so that the scanners validate what they skip.
-record(pats, {cdata, comment, pi, esc_text, esc_attr}).

-record(st, {bin :: binary(),
             max_depth :: pos_integer()}).

%% An open element's frame, for its content: {Depth, Scope, QName,
%% StartOffset}. QName is the raw tag name, for the end tag.
-define(DEPTH(F), element(1, F)).
-define(SCOPE(F), element(2, F)).
-define(QNAME(F), element(3, F)).
-define(START(F), element(4, F)).
-define(SCOPE_DEFAULT(Scope), element(1, Scope)).

%% ---------------------------------------------------------------------------
%% API
%% ---------------------------------------------------------------------------

%% @doc Parses one UTF-8 XML document. The size limit is checked before any
%% parsing; the root element is at depth 1.
-spec parse(binary(), #{max_size := pos_integer(), max_depth := pos_integer()}) ->
          {ok, element()} | {error, bil:error_reason()}.
parse(Bin, #{max_size := MaxSize, max_depth := MaxDepth}) when is_binary(Bin) ->
    case byte_size(Bin) of
        Size when Size > MaxSize ->
            {error, #{code => too_large,
                      message => iolist_to_binary(
                                   io_lib:format("document is ~b bytes, over the limit of ~b bytes",
                                                 [Size, MaxSize]))}};
        _ ->
            guarded(Bin, MaxDepth)
    end;
parse(_NotBinary, _Limits) ->
    {error, #{code => not_binary, message => <<"the document is not a binary">>}}.

%% @doc Escapes character data for use as element content: `&', `<' and
%% `>', and CR as `&#13;' so that it survives line-end normalisation.
-spec escape_text(binary()) -> iodata().
escape_text(Bin) ->
    escape(Bin, (patterns())#pats.esc_text).

%% @doc Escapes a value for use inside a double-quoted attribute: `&', `<',
%% `>', `"', and tab, LF and CR as character references so that attribute
%% value normalisation leaves them alone.
-spec escape_attr(binary()) -> iodata().
escape_attr(Bin) ->
    escape(Bin, (patterns())#pats.esc_attr).

%% @doc Builds an error located at byte `Offset' of `Bin', with the 1-based
%% line and column (in characters) computed from the offset.
-spec error_at(binary(), non_neg_integer(), bil:error_code(), iodata()) ->
          {error, bil:error_reason()}.
error_at(Bin, Offset, Code, Message) ->
    {Line, Column} = line_column(Bin, max(0, min(Offset, byte_size(Bin)))),
    {error, #{code => Code, message => iolist_to_binary(Message),
              line => Line, column => Column}}.

%% ---------------------------------------------------------------------------
%% Document
%% ---------------------------------------------------------------------------

-ifdef(TEST).
%% In tests an internal crash must surface, so that the fuzz properties
%% prove the last-resort handler below is never needed.
guarded(Bin, MaxDepth) ->
    document(Bin, MaxDepth).
-else.
guarded(Bin, MaxDepth) ->
    try
        document(Bin, MaxDepth)
    catch
        Class:Reason:Stack ->
            ?LOG_ERROR(#{what => bil_xml_internal_error, class => Class,
                         reason => Reason, stacktrace => Stack,
                         size => byte_size(Bin)}),
            {error, #{code => malformed,
                      message => <<"the XML parser failed on this document (internal error, logged)">>}}
    end.
-endif.

document(Bin, MaxDepth) ->
    S = #st{bin = Bin, max_depth = MaxDepth},
    B0 = case Bin of
             <<16#EF, 16#BB, 16#BF, R/binary>> -> R;
             _ -> Bin
         end,
    case xml_decl(B0, S) of
        {ok, B1} -> prolog(B1, S);
        Error -> Error
    end.

prolog(B, S) ->
    case misc(B, S) of
        {ok, <<>>} ->
            err(malformed, <<>>, S, "the document has no root element");
        {ok, <<"<!", _/binary>> = R} ->
            bad_markup(R, S, "a start tag for the root element");
        {ok, <<$<, R/binary>> = Lt} ->
            case element(R, pos(Lt, S) + 1, 1, ?ROOT_SCOPE, S) of
                {ok, Root, Next} when Next =:= byte_size(S#st.bin) -> {ok, Root};
                {ok, Root, Next} -> epilog(rest(Next, S), Root, S);
                Error -> Error
            end;
        {ok, R} ->
            unexpected(R, S, "the root element");
        Error ->
            Error
    end.

epilog(B, Root, S) ->
    case misc(B, S) of
        {ok, <<>>} ->
            {ok, Root};
        {ok, <<"<!", _/binary>> = R} ->
            bad_markup(R, S, "only comments and processing instructions after the root element");
        {ok, <<$<, _/binary>> = R} ->
            err(malformed, R, S, "a second root element: only comments and processing "
                "instructions may follow the root element");
        {ok, R} ->
            unexpected(R, S, "only whitespace, comments and processing instructions after "
                       "the root element");
        Error ->
            Error
    end.

%% Whitespace, comments and processing instructions around the root.
misc(<<C, R/binary>>, S) when ?IS_WS(C) ->
    misc(R, S);
misc(<<"<!--", _/binary>> = B, S) ->
    Pos = pos(B, S),
    case comment(Pos + 4, Pos, S) of
        {ok, Next} -> misc(rest(Next, S), S);
        Error -> Error
    end;
misc(<<"<?", _/binary>> = B, S) ->
    Pos = pos(B, S),
    case pi(Pos + 2, Pos, S) of
        {ok, Next} -> misc(rest(Next, S), S);
        Error -> Error
    end;
misc(<<"<!DOCTYPE", _/binary>> = B, S) ->
    doctype(B, S);
misc(B, _S) ->
    {ok, B}.

doctype(At, S) ->
    err(doctype_refused, At, S,
        "document type declarations (<!DOCTYPE ...>) are refused: BIL does no DTD "
        "processing, so no entity can be declared").

%% `<!' followed by something that is not allowed here.
bad_markup(B, S, Expected) ->
    case is_prefix_at_end(B, [<<"<!--">>, <<"<![CDATA[">>, <<"<!DOCTYPE">>]) of
        true ->
            err(truncated, <<>>, S, "the input ended inside markup starting with '<!'");
        false ->
            case B of
                <<"<![CDATA[", _/binary>> ->
                    err(malformed, B, S, ["a CDATA section is not allowed here; expected ",
                                          Expected]);
                _ ->
                    err(malformed, B, S, ["unknown markup '<!'; expected ", Expected])
            end
    end.

is_prefix_at_end(B, Candidates) ->
    Size = byte_size(B),
    lists:any(fun(C) -> Size < byte_size(C) andalso binary:part(C, 0, Size) =:= B end,
              Candidates).

%% ---------------------------------------------------------------------------
%% XML declaration
%% ---------------------------------------------------------------------------

%% The declarations BIL's own encoders write take a shortcut.
xml_decl(<<"<?xml version=\"1.0\" encoding=\"UTF-8\"?>", Rest/binary>>, _S) ->
    {ok, Rest};
xml_decl(<<"<?xml version=\"1.0\"?>", Rest/binary>>, _S) ->
    {ok, Rest};
xml_decl(<<"<?xml", C, _/binary>> = B, S) when ?IS_WS(C) ->
    <<_:5/binary, R/binary>> = B,
    case pseudo_attrs(R, B, S, []) of
        {ok, Attrs, Rest} -> check_decl(lists:reverse(Attrs), Rest, S);
        Error -> Error
    end;
xml_decl(B, _S) ->
    {ok, B}.

pseudo_attrs(B0, Decl, S, Acc) ->
    B = skip_ws(B0),
    case B of
        <<"?>", Rest/binary>> ->
            {ok, Acc, Rest};
        _ when byte_size(B) =:= byte_size(B0), Acc =/= [] ->
            unexpected(B, S, "whitespace or '?>' in the XML declaration");
        _ ->
            case ncname(B) of
                0 ->
                    unexpected(B, S, "a pseudo-attribute or '?>' in the XML declaration");
                N ->
                    <<Name:N/binary, R0/binary>> = B,
                    case eq(R0, S) of
                        {ok, <<Q, R1/binary>>} when Q =:= $"; Q =:= $' ->
                            case binary:match(R1, <<Q>>) of
                                nomatch ->
                                    err(truncated, <<>>, S, ["the input ended inside the XML "
                                                             "declaration started at ",
                                                             where(Decl, S)]);
                                {End, 1} ->
                                    <<Value:End/binary, _, R2/binary>> = R1,
                                    pseudo_attrs(R2, Decl, S, [{Name, Value, B} | Acc])
                            end;
                        {ok, R1} ->
                            unexpected(R1, S, "a quoted value in the XML declaration");
                        Error ->
                            Error
                    end
            end
    end.

check_decl([{<<"version">>, V, At} | T], Rest, S) ->
    case is_version(V) of
        true -> check_decl_encoding(T, Rest, S);
        false -> err(malformed, At, S, ["unsupported XML version '", show(V), "'"])
    end;
check_decl(_, _Rest, S) ->
    err(malformed, 0, S, "the XML declaration must start with version=\"1.0\"").

check_decl_encoding([{<<"encoding">>, E, At} | T], Rest, S) ->
    case is_encoding_name(E) of
        false ->
            err(malformed, At, S, "the encoding name in the XML declaration is not valid");
        true ->
            case is_utf8_label(E) of
                true -> check_decl_standalone(T, Rest, S);
                false -> err(bad_encoding, At, S, ["the document declares encoding '", E,
                                                   "'; only UTF-8 is accepted"])
            end
    end;
check_decl_encoding(T, Rest, S) ->
    check_decl_standalone(T, Rest, S).

check_decl_standalone([{<<"standalone">>, V, At} | T], Rest, S) ->
    case V =:= <<"yes">> orelse V =:= <<"no">> of
        true -> check_decl_end(T, Rest, S);
        false -> err(malformed, At, S, "standalone must be \"yes\" or \"no\"")
    end;
check_decl_standalone(T, Rest, S) ->
    check_decl_end(T, Rest, S).

check_decl_end([], Rest, _S) ->
    {ok, Rest};
check_decl_end([{Name, _, At} | _], _Rest, S) ->
    err(malformed, At, S, ["unexpected '", show(Name), "' in the XML declaration (allowed: "
                           "version, encoding, standalone, in that order)"]).

%% EncName ::= [A-Za-z] ([A-Za-z0-9._] | '-')*
is_encoding_name(<<C, R/binary>>) when (C >= $a andalso C =< $z) orelse
                                       (C >= $A andalso C =< $Z) ->
    byte_size(R) =:= ncname_rest(R, 0);
is_encoding_name(_) ->
    false.

is_utf8_label(<<U, T, F, "-8">>) ->
    (U =:= $u orelse U =:= $U) andalso (T =:= $t orelse T =:= $T) andalso
        (F =:= $f orelse F =:= $F);
is_utf8_label(_) ->
    false.

is_version(<<"1.", Digits/binary>>) when Digits =/= <<>> ->
    is_digits(Digits);
is_version(_) ->
    false.

is_digits(<<D, R/binary>>) when D >= $0, D =< $9 -> is_digits(R);
is_digits(<<>>) -> true;
is_digits(_) -> false.

%% ---------------------------------------------------------------------------
%% Comments, processing instructions, CDATA (offset based)
%% ---------------------------------------------------------------------------

%% From is just after "<!--", Start at its '<'. Returns the offset after "-->".
comment(From, Start, S) ->
    Bin = S#st.bin,
    case scan(Bin, From, (patterns())#pats.comment) of
        {bad, At} ->
            bad_char(At, S);
        {At, $-} ->
            case Bin of
                <<_:At/binary, "-->", _/binary>> ->
                    {ok, At + 3};
                <<_:At/binary, "--">> ->
                    err(truncated, <<>>, S, ["the input ended inside the comment started at ",
                                             where(Start, S)]);
                _ ->
                    err(malformed, At, S, "'--' is not allowed inside a comment")
            end;
        nomatch ->
            err(truncated, <<>>, S, ["the input ended inside the comment started at ",
                                     where(Start, S)])
    end.

%% From is just after "<?". Returns the offset after "?>".
pi(From, Start, S) ->
    Bin = S#st.bin,
    R = rest(From, S),
    case ncname(R) of
        0 ->
            unexpected(R, S, "a processing instruction target after '<?'");
        N ->
            <<Target:N/binary, R1/binary>> = R,
            case is_xml_target(Target) of
                true ->
                    err(malformed, Start, S, "an XML declaration is only allowed at the very "
                        "start of the document");
                false ->
                    case R1 of
                        <<"?>", _/binary>> ->
                            {ok, From + N + 2};
                        <<C, _/binary>> when ?IS_WS(C) ->
                            case scan(Bin, From + N, (patterns())#pats.pi) of
                                {bad, At} ->
                                    bad_char(At, S);
                                {At, $?} ->
                                    {ok, At + 2};
                                nomatch ->
                                    err(truncated, <<>>, S, ["the input ended inside the processing "
                                                             "instruction started at ",
                                                             where(Start, S)])
                            end;
                        _ ->
                            unexpected(R1, S, "whitespace or '?>' after the processing "
                                       "instruction target")
                    end
            end
    end.

%% Targets spelt [Xx][Mm][Ll] are reserved (XML 1.0 section 2.6).
is_xml_target(<<X, M, L>>) ->
    (X =:= $x orelse X =:= $X) andalso (M =:= $m orelse M =:= $M) andalso
        (L =:= $l orelse L =:= $L);
is_xml_target(_) ->
    false.

%% From is just after "<![CDATA["; returns the text with line ends
%% normalised and the offset after "]]>".
cdata(From, Start, S) ->
    cdata(From, From, Start, S, []).

cdata(Piece, From, Start, S, Acc) ->
    Bin = S#st.bin,
    case scan(Bin, From, (patterns())#pats.cdata) of
        {bad, At} ->
            bad_char(At, S);
        {At, $]} ->
            {ok, join(Acc, binary_part(Bin, Piece, At - Piece)), At + 3};
        {At, $\r} ->
            Next = case Bin of
                       <<_:At/binary, "\r\n", _/binary>> -> At + 2;
                       _ -> At + 1
                   end,
            cdata(Next, Next, Start, S, [<<"\n">>, binary_part(Bin, Piece, At - Piece) | Acc]);
        nomatch ->
            err(truncated, <<>>, S, ["the input ended inside the CDATA section started at ",
                                     where(Start, S)])
    end.

join([], Text) -> Text;
join(Acc, Text) -> iolist_to_binary(lists:reverse(Acc, [Text])).

%% ---------------------------------------------------------------------------
%% Elements: the hot path
%% ---------------------------------------------------------------------------

%% R follows a '<' that starts an element; Pos is R's offset. Returns
%% {ok, Element, OffsetAfterIt}.
element(<<C, R/bits>>, Pos, Depth, Scope, S)
  when ?IS_NAME_START(C), Depth =< S#st.max_depth ->
    ename(R, Pos, 1, Depth, Scope, S);
element(<<Cp/utf8, R/bits>>, Pos, Depth, Scope, S)
  when ?IS_NAME_START_CP(Cp), Depth =< S#st.max_depth ->
    ename(R, Pos, utf8_len(Cp), Depth, Scope, S);
element(_R, Pos, Depth, _Scope, S) when Depth > S#st.max_depth ->
    err(too_deep, Pos - 1, S, io_lib:format("elements are nested deeper than the limit of ~b "
                                            "(the root element is depth 1)", [S#st.max_depth]));
element(_R, Pos, _Depth, _Scope, S) ->
    unexpected(rest(Pos, S), S, "an element name after '<'").

%% The element name from offset Pos, Len bytes so far.
%%
%% In the hot path literal bytes are matched into variables and tested in
%% guards: OTP 25 compiles a literal in a binary pattern to a
%% bs_match_string instruction, which the JIT turns into a C call.
%%
%% The loops are unrolled four times with nested cases: a failing byte
%% then costs no refetch, unlike a four-byte clause that backtracks.
ename(<<C1, R1/bits>>, Pos, Len, Depth, Scope, S) when ?IS_NAME_CHAR(C1) ->
    case R1 of
        <<C2, R2/bits>> when ?IS_NAME_CHAR(C2) ->
            case R2 of
                <<C3, R3/bits>> when ?IS_NAME_CHAR(C3) ->
                    case R3 of
                        <<C4, R4/bits>> when ?IS_NAME_CHAR(C4) ->
                            ename(R4, Pos, Len + 4, Depth, Scope, S);
                        _ ->
                            ename_end(R3, Pos, Len + 3, Depth, Scope, S)
                    end;
                _ ->
                    ename_end(R2, Pos, Len + 2, Depth, Scope, S)
            end;
        _ ->
            ename_end(R1, Pos, Len + 1, Depth, Scope, S)
    end;
ename(R, Pos, Len, Depth, Scope, S) ->
    ename_end(R, Pos, Len, Depth, Scope, S).

%% What follows the name's ASCII characters.
ename_end(<<C, R/bits>>, Pos, Len, Depth, Scope, S) when C =:= $> ->
    Local = binary_part(S#st.bin, Pos, Len),
    leaf(R, Pos + Len + 1, 0, Local, Len, Depth, Scope, S);
ename_end(<<C, D, _/bits>>, Pos, Len, _Depth, Scope, S) when C =:= $/, D =:= $> ->
    {ok, {{?SCOPE_DEFAULT(Scope), binary_part(S#st.bin, Pos, Len)}, [], []}, Pos + Len + 2};
ename_end(<<C, R/bits>>, Pos, Len, Depth, Scope, S) when C =:= $: ->
    lname(R, Pos, Len, Depth, Scope, S);
ename_end(<<Cp/utf8, R/bits>>, Pos, Len, Depth, Scope, S) when ?IS_NAME_CHAR_CP(Cp) ->
    ename(R, Pos, Len + utf8_len(Cp), Depth, Scope, S);
ename_end(R, Pos, Len, Depth, Scope, S) ->
    Local = binary_part(S#st.bin, Pos, Len),
    At = Pos + Len,
    fattrs(R, At, At, [], [], {Pos - 1, <<>>, Local, Local, Depth, Scope}, S).

%% The local part after "Prefix:"; the prefix is PLen bytes at Pos.
lname(<<C, R/bits>>, Pos, PLen, Depth, Scope, S) when ?IS_NAME_START(C) ->
    lname(R, Pos, PLen, 1, Depth, Scope, S);
lname(<<Cp/utf8, R/bits>>, Pos, PLen, Depth, Scope, S) when ?IS_NAME_START_CP(Cp) ->
    lname(R, Pos, PLen, utf8_len(Cp), Depth, Scope, S);
lname(_R, Pos, PLen, _Depth, _Scope, S) ->
    unexpected(rest(Pos + PLen + 1, S), S, "a local name after the prefix in an element name").

lname(<<C1, R1/bits>>, Pos, PLen, Len, Depth, Scope, S) when ?IS_NAME_CHAR(C1) ->
    case R1 of
        <<C2, R2/bits>> when ?IS_NAME_CHAR(C2) ->
            case R2 of
                <<C3, R3/bits>> when ?IS_NAME_CHAR(C3) ->
                    case R3 of
                        <<C4, R4/bits>> when ?IS_NAME_CHAR(C4) ->
                            lname(R4, Pos, PLen, Len + 4, Depth, Scope, S);
                        _ ->
                            lname_end(R3, Pos, PLen, Len + 3, Depth, Scope, S)
                    end;
                _ ->
                    lname_end(R2, Pos, PLen, Len + 2, Depth, Scope, S)
            end;
        _ ->
            lname_end(R1, Pos, PLen, Len + 1, Depth, Scope, S)
    end;
lname(R, Pos, PLen, Len, Depth, Scope, S) ->
    lname_end(R, Pos, PLen, Len, Depth, Scope, S).

lname_end(<<C, R/bits>>, Pos, PLen, Len, Depth, Scope, S) when C =:= $> ->
    %% A prefixed start tag without attributes.
    QName = binary_part(S#st.bin, Pos, PLen + 1 + Len),
    <<Prefix:PLen/binary, _, Local/binary>> = QName,
    case resolve(Prefix, Scope) of
        '$unbound' ->
            unbound(Prefix, Pos - 1, S);
        Ns ->
            F = {Depth, Scope, QName, Pos - 1},
            case content(R, Pos + PLen + Len + 2, F, S, [], [], true, false) of
                {ok, Children, Next} -> {ok, {{Ns, Local}, [], Children}, Next};
                Error -> Error
            end
    end;
lname_end(<<Cp/utf8, R/bits>>, Pos, PLen, Len, Depth, Scope, S) when ?IS_NAME_CHAR_CP(Cp) ->
    lname(R, Pos, PLen, Len + utf8_len(Cp), Depth, Scope, S);
lname_end(R, Pos, PLen, Len, Depth, Scope, S) ->
    QLen = PLen + 1 + Len,
    QName = binary_part(S#st.bin, Pos, QLen),
    <<Prefix:PLen/binary, _, Local/binary>> = QName,
    At = Pos + QLen,
    fattrs(R, At, At, [], [], {Pos - 1, Prefix, Local, QName, Depth, Scope}, S).

%% After "<Local>": a field's plain text (no references, CR or markup) up
%% to its end tag is the common case and is cut out directly. Anything
%% else is parsed again from the start of the content by content/8.
leaf(<<C1, R1/bits>>, TPos, TLen, Local, N, Depth, Scope, S) when ?IS_PLAIN(C1) ->
    case R1 of
        <<C2, R2/bits>> when ?IS_PLAIN(C2) ->
            case R2 of
                <<C3, R3/bits>> when ?IS_PLAIN(C3) ->
                    case R3 of
                        <<C4, R4/bits>> when ?IS_PLAIN(C4) ->
                            leaf(R4, TPos, TLen + 4, Local, N, Depth, Scope, S);
                        _ ->
                            leaf_end(R3, TPos, TLen + 3, Local, N, Depth, Scope, S)
                    end;
                _ ->
                    leaf_end(R2, TPos, TLen + 2, Local, N, Depth, Scope, S)
            end;
        _ ->
            leaf_end(R1, TPos, TLen + 1, Local, N, Depth, Scope, S)
    end;
leaf(R, TPos, TLen, Local, N, Depth, Scope, S) ->
    leaf_end(R, TPos, TLen, Local, N, Depth, Scope, S).

%% Local is N bytes long.
leaf_end(<<C, D, R/bits>>, TPos, TLen, Local, N, Depth, Scope, S) when C =:= $<, D =:= $/ ->
    case R of
        <<Local:N/binary, E, _/bits>> when E =:= $>, TLen =:= 0 ->
            {ok, {{?SCOPE_DEFAULT(Scope), Local}, [], []}, TPos + N + 3};
        <<Local:N/binary, E, _/bits>> when E =:= $> ->
            {ok, {{?SCOPE_DEFAULT(Scope), Local}, [], [binary_part(S#st.bin, TPos, TLen)]},
             TPos + TLen + N + 3};
        _ ->
            unprefixed_content(TPos, Local, Depth, Scope, S)
    end;
leaf_end(_R, TPos, _TLen, Local, _N, Depth, Scope, S) ->
    unprefixed_content(TPos, Local, Depth, Scope, S).

unprefixed_content(Pos, Local, Depth, Scope, S) ->
    F = {Depth, Scope, Local, Pos - byte_size(Local) - 2},
    <<_:Pos/binary, R/bits>> = S#st.bin,
    case content(R, Pos, F, S, [], [], true, false) of
        {ok, Children, Next} -> {ok, {{?SCOPE_DEFAULT(Scope), Local}, [], Children}, Next};
        Error -> Error
    end.

%% Element content at offset Pos, for the frame F. Kids holds finished
%% children (reversed); Run holds the pieces of the current text run
%% (reversed: binaries, or {Offset, Length} for whitespace not cut out
%% yet, see run_text/2) and RunWs says whether they are all whitespace;
%% HasElem whether a child element has been seen, which decides how text
%% is kept (see finish/6).
content(<<C, R/bits>>, Pos, F, S, Kids, Run, RunWs, HasElem) when C =:= $< ->
    markup(R, Pos, F, S, Kids, Run, RunWs, HasElem);
content(<<>>, _Pos, F, S, _Kids, _Run, _RunWs, _HasElem) ->
    unclosed(F, S);
content(R, Pos, F, S, Kids, Run, RunWs, HasElem) ->
    text_ws(R, Pos, 0, F, S, Kids, Run, RunWs, HasElem).

%% Resumes content at offset Pos, after a construct handled by offset.
resume(Pos, F, S, Kids, Run, RunWs, HasElem) ->
    <<_:Pos/binary, R/bits>> = S#st.bin,
    content(R, Pos, F, S, Kids, Run, RunWs, HasElem).

%% Whitespace at the start of a text piece at Pos, Len bytes so far.
%% Indentation (a line end, then spaces) is the common case.
text_ws(<<C1, R1/bits>>, Pos, Len, F, S, Kids, Run, RunWs, HasElem)
  when C1 =:= $\n; C1 =:= $\s; C1 =:= $\t ->
    case R1 of
        <<Spaces:32, R2/bits>> when Spaces =:= 16#20202020 ->
            text_ws(R2, Pos, Len + 5, F, S, Kids, Run, RunWs, HasElem);
        <<C2, R2/bits>> when C2 =:= $\s; C2 =:= $\n; C2 =:= $\t ->
            text_ws(R2, Pos, Len + 2, F, S, Kids, Run, RunWs, HasElem);
        <<C2, R2/bits>> when C2 =:= $< ->
            markup(R2, Pos + Len + 1, F, S, Kids, lazy_piece(Pos, Len + 1, Run), RunWs, HasElem);
        _ ->
            text(R1, Pos, Len + 1, F, S, Kids, Run, RunWs, HasElem)
    end;
text_ws(<<C, R/bits>>, Pos, Len, F, S, Kids, Run, RunWs, HasElem) when C =:= $< ->
    markup(R, Pos + Len, F, S, Kids, lazy_piece(Pos, Len, Run), RunWs, HasElem);
text_ws(R, Pos, Len, F, S, Kids, Run, RunWs, HasElem) ->
    text(R, Pos, Len, F, S, Kids, Run, RunWs, HasElem).

%% The rest of a text piece; consuming anything but whitespace here makes
%% the run not whitespace only.
text(<<C1, R1/bits>>, Pos, Len, F, S, Kids, Run, _RunWs, HasElem) when ?IS_PLAIN(C1) ->
    case R1 of
        <<C2, R2/bits>> when ?IS_PLAIN(C2) ->
            case R2 of
                <<C3, R3/bits>> when ?IS_PLAIN(C3) ->
                    case R3 of
                        <<C4, R4/bits>> when ?IS_PLAIN(C4) ->
                            text(R4, Pos, Len + 4, F, S, Kids, Run, false, HasElem);
                        _ ->
                            text_end(R3, Pos, Len + 3, F, S, Kids, Run, false, HasElem)
                    end;
                _ ->
                    text_end(R2, Pos, Len + 2, F, S, Kids, Run, false, HasElem)
            end;
        _ ->
            text_end(R1, Pos, Len + 1, F, S, Kids, Run, false, HasElem)
    end;
text(R, Pos, Len, F, S, Kids, Run, RunWs, HasElem) ->
    text_end(R, Pos, Len, F, S, Kids, Run, RunWs, HasElem).

%% What ends a stretch of plain text.
text_end(<<C, R/bits>>, Pos, Len, F, S, Kids, Run, RunWs, HasElem) when C =:= $< ->
    markup(R, Pos + Len, F, S, Kids, piece(Pos, Len, Run, S), RunWs, HasElem);
text_end(<<C, _/bits>>, Pos, Len, F, S, Kids, Run, RunWs, HasElem) when C =:= $& ->
    case reference(Pos + Len + 1, S) of
        {ok, Char, Next} ->
            resume(Next, F, S, Kids, [Char | piece(Pos, Len, Run, S)],
                   RunWs andalso is_ws(Char), HasElem);
        Error ->
            Error
    end;
text_end(<<C, R/bits>>, Pos, Len, F, S, Kids, Run, RunWs, HasElem) when C =:= $\r ->
    %% Line ends are normalised: CR LF and CR become LF.
    Run1 = [<<"\n">> | piece(Pos, Len, Run, S)],
    case R of
        <<D, R1/bits>> when D =:= $\n ->
            content(R1, Pos + Len + 2, F, S, Kids, Run1, RunWs, HasElem);
        _ ->
            resume(Pos + Len + 1, F, S, Kids, Run1, RunWs, HasElem)
    end;
text_end(<<"]]>", _/bits>>, Pos, Len, _F, S, _Kids, _Run, _RunWs, _HasElem) ->
    err(malformed, Pos + Len, S, "']]>' is not allowed in text (write ']]&gt;')");
text_end(<<C, R/bits>>, Pos, Len, F, S, Kids, Run, _RunWs, HasElem) when C =:= $] ->
    text(R, Pos, Len + 1, F, S, Kids, Run, false, HasElem);
text_end(<<Cp/utf8, R/bits>>, Pos, Len, F, S, Kids, Run, _RunWs, HasElem) when ?IS_LEGAL_CP(Cp) ->
    text(R, Pos, Len + utf8_len(Cp), F, S, Kids, Run, false, HasElem);
text_end(<<>>, _Pos, _Len, F, S, _Kids, _Run, _RunWs, _HasElem) ->
    unclosed(F, S);
text_end(_R, Pos, Len, _F, S, _Kids, _Run, _RunWs, _HasElem) ->
    bad_char(Pos + Len, S).

piece(_Pos, 0, Run, _S) -> Run;
piece(Pos, Len, Run, S) -> [binary_part(S#st.bin, Pos, Len) | Run].

%% Whitespace before markup is usually dropped, so it is cut out only if
%% it is kept (run_text/2).
lazy_piece(_Pos, 0, Run) -> Run;
lazy_piece(Pos, Len, Run) -> [{Pos, Len} | Run].

%% R follows a '<' at offset Pos in element content.
markup(<<C, R/bits>>, Pos, F, S, Kids, Run, RunWs, HasElem) when C =:= $/ ->
    QName = ?QNAME(F),
    case R of
        <<QName:(byte_size(QName))/binary, E, _/bits>> when E =:= $> ->
            finish(Pos + byte_size(QName) + 3, Kids, Run, RunWs, HasElem, S);
        _ ->
            end_tag(Pos, F, S, Kids, Run, RunWs, HasElem)
    end;
markup(<<C, _/bits>>, Pos, F, S, Kids, Run, RunWs, HasElem) when C =:= $!; C =:= $? ->
    special(Pos, F, S, Kids, Run, RunWs, HasElem);
markup(<<C, R/bits>>, Pos, F, S, Kids, Run, RunWs, _HasElem)
  when ?IS_NAME_START(C), ?DEPTH(F) < S#st.max_depth ->
    %% A child element ends the text run: whitespace-only runs are dropped
    %% because this element now has element children.
    cname(R, Pos + 1, 1, F, S, child_kids(Kids, Run, RunWs, S));
markup(_R, Pos, F, S, Kids, Run, RunWs, _HasElem) ->
    child(Pos, F, S, child_kids(Kids, Run, RunWs, S)).

child_kids(Kids, _Run, true, _S) -> Kids;
child_kids(Kids, Run, false, S) -> [run_text(Run, S) | Kids].

%% A child element at offset Pos ('<'), parsed by element/5.
child(Pos, F, S, Kids) ->
    <<_:Pos/binary, _, R/bits>> = S#st.bin,
    case element(R, Pos + 1, ?DEPTH(F) + 1, ?SCOPE(F), S) of
        {ok, Child, Next} -> resume(Next, F, S, [Child | Kids], [], true, true);
        Error -> Error
    end.

%% Children of the form <Name>plain text</Name> (the fields of BIL) are
%% parsed here without leaving the parent's content loop; any other child
%% is handed to child/4 from its '<'. The name is at Pos, Len bytes so far.
cname(<<C1, R1/bits>>, Pos, Len, F, S, Kids) when ?IS_NAME_CHAR(C1) ->
    case R1 of
        <<C2, R2/bits>> when ?IS_NAME_CHAR(C2) ->
            case R2 of
                <<C3, R3/bits>> when ?IS_NAME_CHAR(C3) ->
                    case R3 of
                        <<C4, R4/bits>> when ?IS_NAME_CHAR(C4) ->
                            cname(R4, Pos, Len + 4, F, S, Kids);
                        _ ->
                            cname_end(R3, Pos, Len + 3, F, S, Kids)
                    end;
                _ ->
                    cname_end(R2, Pos, Len + 2, F, S, Kids)
            end;
        _ ->
            cname_end(R1, Pos, Len + 1, F, S, Kids)
    end;
cname(R, Pos, Len, F, S, Kids) ->
    cname_end(R, Pos, Len, F, S, Kids).

cname_end(<<C, R/bits>>, Pos, Len, F, S, Kids) when C =:= $> ->
    cleaf(R, Pos + Len + 1, 0, Pos, Len, F, S, Kids);
cname_end(_R, Pos, _Len, F, S, Kids) ->
    child(Pos - 1, F, S, Kids).

%% The child's text at TPos, TLen bytes so far; its name is N bytes at NPos.
cleaf(<<C1, R1/bits>>, TPos, TLen, NPos, N, F, S, Kids) when ?IS_PLAIN(C1) ->
    case R1 of
        <<C2, R2/bits>> when ?IS_PLAIN(C2) ->
            case R2 of
                <<C3, R3/bits>> when ?IS_PLAIN(C3) ->
                    case R3 of
                        <<C4, R4/bits>> when ?IS_PLAIN(C4) ->
                            cleaf(R4, TPos, TLen + 4, NPos, N, F, S, Kids);
                        _ ->
                            cleaf_end(R3, TPos, TLen + 3, NPos, N, F, S, Kids)
                    end;
                _ ->
                    cleaf_end(R2, TPos, TLen + 2, NPos, N, F, S, Kids)
            end;
        _ ->
            cleaf_end(R1, TPos, TLen + 1, NPos, N, F, S, Kids)
    end;
cleaf(R, TPos, TLen, NPos, N, F, S, Kids) ->
    cleaf_end(R, TPos, TLen, NPos, N, F, S, Kids).

cleaf_end(<<C, D, R/bits>>, TPos, TLen, NPos, N, F, S, Kids) when C =:= $<, D =:= $/ ->
    %% One match cuts both sub-binaries: cheaper than two binary_part/3.
    <<_:NPos/binary, Local:N/binary, _, Text:TLen/binary, _/bits>> = S#st.bin,
    case R of
        <<Local:N/binary, E, Rest/bits>> when E =:= $> ->
            Child = case TLen of
                        0 -> {{?SCOPE_DEFAULT(?SCOPE(F)), Local}, [], []};
                        _ -> {{?SCOPE_DEFAULT(?SCOPE(F)), Local}, [], [Text]}
                    end,
            text_ws(Rest, TPos + TLen + N + 3, 0, F, S, [Child | Kids], [], true, true);
        _ ->
            child(NPos - 1, F, S, Kids)
    end;
cleaf_end(_R, _TPos, _TLen, NPos, _N, F, S, Kids) ->
    child(NPos - 1, F, S, Kids).

%% Comments, CDATA sections and processing instructions at offset Pos.
special(Pos, F, S, Kids, Run, RunWs, HasElem) ->
    case rest(Pos + 1, S) of
        <<"!--", _/binary>> ->
            case comment(Pos + 4, Pos, S) of
                {ok, Next} -> resume(Next, F, S, Kids, Run, RunWs, HasElem);
                Error -> Error
            end;
        <<"![CDATA[", _/binary>> ->
            case cdata(Pos + 9, Pos, S) of
                {ok, <<>>, Next} ->
                    resume(Next, F, S, Kids, Run, RunWs, HasElem);
                {ok, Text, Next} ->
                    resume(Next, F, S, Kids, [Text | Run], RunWs andalso is_ws(Text), HasElem);
                Error ->
                    Error
            end;
        <<"!DOCTYPE", _/binary>> ->
            doctype(Pos, S);
        <<"?", _/binary>> ->
            case pi(Pos + 2, Pos, S) of
                {ok, Next} -> resume(Next, F, S, Kids, Run, RunWs, HasElem);
                Error -> Error
            end;
        _ ->
            bad_markup(rest(Pos, S), S, ["content or the end tag </", show(?QNAME(F)), ">"])
    end.

run_text([Text], _S) when is_binary(Text) -> Text;
run_text([{Pos, Len}], S) -> binary_part(S#st.bin, Pos, Len);
run_text(Run, S) -> iolist_to_binary(lists:reverse([cut_piece(P, S) || P <- Run])).

cut_piece({Pos, Len}, S) -> binary_part(S#st.bin, Pos, Len);
cut_piece(Text, _S) -> Text.

%% In an element with element children a whitespace-only run is dropped;
%% in a leaf the run is the element's one text child.
finish(Next, Kids, _Run, true, true, _S) ->
    {ok, lists:reverse(Kids), Next};
finish(Next, Kids, Run, false, true, S) ->
    {ok, lists:reverse(Kids, [run_text(Run, S)]), Next};
finish(Next, [], [], _RunWs, false, _S) ->
    {ok, [], Next};
finish(Next, [], Run, _RunWs, false, S) ->
    {ok, [run_text(Run, S)], Next}.

%% The end tag at Pos is not simply "</QName>".
end_tag(Pos, F, S, Kids, Run, RunWs, HasElem) ->
    QName = ?QNAME(F),
    Len = byte_size(QName),
    case rest(Pos + 2, S) of
        <<QName:Len/binary, C, R/binary>> when ?IS_WS(C) ->
            case skip_ws(R) of
                <<$>, Rest/binary>> -> finish(pos(Rest, S), Kids, Run, RunWs, HasElem, S);
                R1 -> unexpected(R1, S, ["'>' to close the end tag </", show(QName), ">"])
            end;
        R ->
            Size = byte_size(R),
            case Size =< Len andalso binary:part(QName, 0, Size) =:= R of
                true ->
                    err(truncated, <<>>, S, ["the input ended inside the end tag </",
                                             show(QName), ">"]);
                false ->
                    case qname(R) of
                        {_, _, Other, _} ->
                            err(malformed, Pos, S, ["end tag </", show(Other),
                                                    "> does not match start tag <", show(QName),
                                                    "> opened at ", where(?START(F), S)]);
                        error ->
                            unexpected(R, S, ["the name of the end tag </", show(QName), ">"])
                    end
            end
    end.

unclosed(F, S) ->
    err(truncated, <<>>, S, ["the input ended before the end tag </", show(?QNAME(F)),
                             "> of the element opened at ", where(?START(F), S)]).

%% ---------------------------------------------------------------------------
%% Start tags with attributes
%% ---------------------------------------------------------------------------

%% Attributes of the start tag T = {Lt, Prefix, Local, QName, Depth, Scope}
%% from offset Pos, in the hot style: ASCII names, values of plain ASCII
%% text. Anything else (references, whitespace to normalise, non-ASCII,
%% errors) parses the tag's attributes again from Start with the general
%% code, slow_attrs/3, which alone reports errors.
fattrs(<<C, R/bits>>, Pos, Start, Raw, Decls, T, S) when ?IS_WS(C) ->
    fattr_ws(R, Pos + 1, Start, Raw, Decls, T, S);
fattrs(<<C, _/bits>>, Pos, _Start, Raw, Decls, T, S) when C =:= $> ->
    start_tag_end(Raw, Decls, false, Pos + 1, T, S);
fattrs(<<C, D, _/bits>>, Pos, _Start, Raw, Decls, T, S) when C =:= $/, D =:= $> ->
    start_tag_end(Raw, Decls, true, Pos + 2, T, S);
fattrs(_R, _Pos, Start, _Raw, _Decls, T, S) ->
    slow_attrs(Start, T, S).

fattr_ws(<<C, R/bits>>, Pos, Start, Raw, Decls, T, S) when ?IS_WS(C) ->
    fattr_ws(R, Pos + 1, Start, Raw, Decls, T, S);
fattr_ws(<<C, R/bits>>, Pos, Start, Raw, Decls, T, S) when ?IS_NAME_START(C) ->
    fattr_name(R, Pos, 1, Start, Raw, Decls, T, S);
fattr_ws(R, Pos, Start, Raw, Decls, T, S) ->
    fattrs(R, Pos, Start, Raw, Decls, T, S).

%% The name at NPos, Len bytes so far.
fattr_name(<<C, R/bits>>, NPos, Len, Start, Raw, Decls, T, S) when ?IS_NAME_CHAR(C) ->
    fattr_name(R, NPos, Len + 1, Start, Raw, Decls, T, S);
fattr_name(<<C, D, R/bits>>, NPos, PLen, Start, Raw, Decls, T, S)
  when C =:= $:, ?IS_NAME_START(D) ->
    fattr_local(R, NPos, PLen, 1, Start, Raw, Decls, T, S);
fattr_name(R, NPos, Len, Start, Raw, Decls, T, S) ->
    fattr_eq(R, NPos + Len, NPos, 0, Len, Start, Raw, Decls, T, S).

fattr_local(<<C, R/bits>>, NPos, PLen, Len, Start, Raw, Decls, T, S) when ?IS_NAME_CHAR(C) ->
    fattr_local(R, NPos, PLen, Len + 1, Start, Raw, Decls, T, S);
fattr_local(R, NPos, PLen, Len, Start, Raw, Decls, T, S) ->
    fattr_eq(R, NPos + PLen + 1 + Len, NPos, PLen, Len, Start, Raw, Decls, T, S).

%% Optional whitespace, '=', optional whitespace and the opening quote; the
%% name is PLen (0 for none) and LLen bytes at NPos.
fattr_eq(<<C, R/bits>>, Pos, NPos, PLen, LLen, Start, Raw, Decls, T, S) when ?IS_WS(C) ->
    fattr_eq(R, Pos + 1, NPos, PLen, LLen, Start, Raw, Decls, T, S);
fattr_eq(<<C, R/bits>>, Pos, NPos, PLen, LLen, Start, Raw, Decls, T, S) when C =:= $= ->
    fattr_quote(R, Pos + 1, NPos, PLen, LLen, Start, Raw, Decls, T, S);
fattr_eq(_R, _Pos, _NPos, _PLen, _LLen, Start, _Raw, _Decls, T, S) ->
    slow_attrs(Start, T, S).

fattr_quote(<<C, R/bits>>, Pos, NPos, PLen, LLen, Start, Raw, Decls, T, S) when ?IS_WS(C) ->
    fattr_quote(R, Pos + 1, NPos, PLen, LLen, Start, Raw, Decls, T, S);
fattr_quote(<<Q, R/bits>>, Pos, NPos, PLen, LLen, Start, Raw, Decls, T, S)
  when Q =:= $"; Q =:= $' ->
    fattr_value(R, Pos + 1, 0, Q, NPos, PLen, LLen, Start, Raw, Decls, T, S);
fattr_quote(_R, _Pos, _NPos, _PLen, _LLen, Start, _Raw, _Decls, T, S) ->
    slow_attrs(Start, T, S).

%% The value at VPos, VLen bytes so far, quoted by Q.
fattr_value(<<C1, R1/bits>>, VPos, VLen, Q, NPos, PLen, LLen, Start, Raw, Decls, T, S)
  when ?IS_VALUE_CHAR(C1, Q) ->
    case R1 of
        <<C2, R2/bits>> when ?IS_VALUE_CHAR(C2, Q) ->
            fattr_value(R2, VPos, VLen + 2, Q, NPos, PLen, LLen, Start, Raw, Decls, T, S);
        _ ->
            fattr_value(R1, VPos, VLen + 1, Q, NPos, PLen, LLen, Start, Raw, Decls, T, S)
    end;
fattr_value(<<C, R/bits>>, VPos, VLen, Q, NPos, PLen, LLen, Start, Raw, Decls, T, S)
  when C =:= Q ->
    %% One match cuts the name and the value.
    NLen = case PLen of
               0 -> LLen;
               _ -> PLen + 1 + LLen
           end,
    Gap = VPos - NPos - NLen,
    <<_:NPos/binary, QName:NLen/binary, _:Gap/binary, Value:VLen/binary, _/bits>> = S#st.bin,
    Next = VPos + VLen + 1,
    case PLen of
        0 when QName =:= <<"xmlns">> ->
            fattrs(R, Next, Start, Raw, [{<<>>, Value, NPos} | Decls], T, S);
        0 ->
            fattrs(R, Next, Start, [{<<>>, QName, Value, NPos} | Raw], Decls, T, S);
        _ ->
            case QName of
                <<"xmlns:", Local/binary>> ->
                    fattrs(R, Next, Start, Raw, [{Local, Value, NPos} | Decls], T, S);
                <<Prefix:PLen/binary, _, Local/binary>> ->
                    fattrs(R, Next, Start, [{Prefix, Local, Value, NPos} | Raw], Decls, T, S)
            end
    end;
fattr_value(_R, _VPos, _VLen, _Q, _NPos, _PLen, _LLen, Start, _Raw, _Decls, T, S) ->
    slow_attrs(Start, T, S).

slow_attrs(Start, {Lt, _Prefix, _Local, QName, _Depth, _Scope} = T, S) ->
    case attributes(rest(Start, S), QName, Lt, S, [], []) of
        {ok, Raw, Decls, Empty, Rest} -> start_tag_end(Raw, Decls, Empty, pos(Rest, S), T, S);
        Error -> Error
    end.

%% The start tag ended at offset Next ("/>" if Empty).
start_tag_end(Raw, Decls, Empty, Next, {Lt, Prefix, Local, QName, Depth, Scope}, S) ->
    case declare(Decls, Scope, S) of
        {ok, Scope1} ->
            case resolve(Prefix, Scope1) of
                '$unbound' ->
                    unbound(Prefix, Lt, S);
                Ns ->
                    case resolve_attributes(Raw, Scope1, S) of
                        {ok, Attrs} when Empty ->
                            {ok, {{Ns, Local}, Attrs, []}, Next};
                        {ok, Attrs} ->
                            F = {Depth, Scope1, QName, Lt},
                            case resume(Next, F, S, [], [], true, false) of
                                {ok, Children, Next1} ->
                                    {ok, {{Ns, Local}, Attrs, Children}, Next1};
                                Error ->
                                    Error
                            end;
                        Error ->
                            Error
                    end
            end;
        Error ->
            Error
    end.

resolve(<<>>, {Default, _}) ->
    Default;
resolve(Prefix, {_, Prefixes}) ->
    case lists:keyfind(Prefix, 1, Prefixes) of
        {_, Ns} -> Ns;
        false -> '$unbound'
    end.

unbound(Prefix, At, S) ->
    err(malformed, At, S, ["the namespace prefix '", show(Prefix), "' is not declared"]).

%% The general attribute parser, for what the fast path leaves (see
%% fattrs/7). Raw attributes are {Prefix, Local, Value, At}; namespace
%% declarations are {Prefix, Value, At} with <<>> for the default
%% namespace. At locates the attribute's name for messages: an offset, or
%% here the rest of the input from it.
attributes(B0, QName, Lt, S, Raw, Decls) ->
    B = skip_ws(B0),
    case B of
        <<$>, Rest/binary>> ->
            {ok, Raw, Decls, false, Rest};
        <<"/>", Rest/binary>> ->
            {ok, Raw, Decls, true, Rest};
        <<>> ->
            err(truncated, <<>>, S, ["the input ended inside the start tag <", show(QName),
                                     "> opened at ", where(Lt, S)]);
        _ when byte_size(B) =:= byte_size(B0) ->
            unexpected(B, S, ["whitespace, '>' or '/>' in the start tag <", show(QName), ">"]);
        _ ->
            case qname(B) of
                error ->
                    unexpected(B, S, ["an attribute name, '>' or '/>' in the start tag <",
                                      show(QName), ">"]);
                {Prefix, Local, AName, R0} ->
                    case eq(R0, S) of
                        {ok, <<Q, R1/binary>>} when Q =:= $"; Q =:= $' ->
                            case attr_value(R1, Q, S, B) of
                                {ok, Value, Rest} when Prefix =:= <<>>, Local =:= <<"xmlns">> ->
                                    attributes(Rest, QName, Lt, S, Raw, [{<<>>, Value, B} | Decls]);
                                {ok, Value, Rest} when Prefix =:= <<"xmlns">> ->
                                    attributes(Rest, QName, Lt, S, Raw, [{Local, Value, B} | Decls]);
                                {ok, Value, Rest} ->
                                    attributes(Rest, QName, Lt, S,
                                               [{Prefix, Local, Value, B} | Raw], Decls);
                                Error ->
                                    Error
                            end;
                        {ok, R1} ->
                            unexpected(R1, S, ["a quoted value for the attribute ", show(AName)]);
                        Error ->
                            Error
                    end
            end
    end.

%% Optional whitespace, '=', optional whitespace.
eq(B0, S) ->
    case skip_ws(B0) of
        <<$=, R/binary>> -> {ok, skip_ws(R)};
        B -> unexpected(B, S, "'='")
    end.

%% Attribute value after its opening quote, with references decoded and
%% literal tab, LF, CR and CR LF each turned into one space (XML 1.0 3.3.3).
attr_value(B, Q, S, Start) ->
    attr_value(B, attr_len(B, 0), Q, S, Start, []).

attr_value(B, At, Q, S, Start, Acc) ->
    case B of
        <<Text:At/binary, Q, Rest/binary>> ->
            case Acc of
                [] -> {ok, Text, Rest};
                _ -> {ok, iolist_to_binary(lists:reverse(Acc, [Text])), Rest}
            end;
        <<Text:At/binary, $&, R/binary>> ->
            case reference(pos(R, S), S) of
                {ok, Char, Next} ->
                    Rest = rest(Next, S),
                    attr_value(Rest, attr_len(Rest, 0), Q, S, Start, [Char, Text | Acc]);
                Error ->
                    Error
            end;
        <<_:At/binary, $<, _/binary>> ->
            err(malformed, pos(B, S) + At, S,
                "'<' is not allowed in an attribute value (write '&lt;')");
        <<Text:At/binary, "\r\n", Rest/binary>> ->
            attr_value(Rest, attr_len(Rest, 0), Q, S, Start, [<<" ">>, Text | Acc]);
        <<Text:At/binary, C, Rest/binary>> when C =:= $\r; C =:= $\n; C =:= $\t ->
            attr_value(Rest, attr_len(Rest, 0), Q, S, Start, [<<" ">>, Text | Acc]);
        <<_:At/binary, C, R/binary>> when C =:= $"; C =:= $' ->
            attr_value(B, At + 1 + attr_len(R, 0), Q, S, Start, Acc);
        <<_:At/binary, Cp/utf8, R/binary>> when ?IS_LEGAL_CP(Cp) ->
            attr_value(B, At + utf8_len(Cp) + attr_len(R, 0), Q, S, Start, Acc);
        <<_:At/binary, _, _/binary>> ->
            bad_char(pos(B, S) + At, S);
        _ ->
            err(truncated, <<>>, S, ["the input ended inside the value of the attribute at ",
                                     where(Start, S)])
    end.

%% Length of the plain value text at the start of B: ASCII characters
%% other than quotes, '<', '&', tab, LF, CR and control characters.
attr_len(<<C, R/binary>>, N) when C >= 16#3D, C =< 16#7F; C >= 16#28, C =< 16#3B;
                                  C >= 16#23, C =< 16#25; C =:= 16#20; C =:= 16#21 ->
    attr_len(R, N + 1);
attr_len(_, N) ->
    N.

declare([], Scope, _S) ->
    {ok, Scope};
declare([_] = Decls, Scope, S) ->
    declare_each(Decls, Scope, S);
declare(Decls, Scope, S) ->
    case first_duplicate(lists:reverse(Decls), fun({P, _, _}) -> P end) of
        {P, _, At} ->
            err(malformed, At, S, case P of
                                      <<>> -> "the default namespace is declared twice";
                                      _ -> ["the prefix '", show(P), "' is declared twice"]
                                  end);
        none ->
            declare_each(Decls, Scope, S)
    end.

declare_each([], Scope, _S) ->
    {ok, Scope};
declare_each([{Prefix, Uri, At} | T], {Default, Prefixes}, S) ->
    case check_ns_decl(Prefix, Uri) of
        ok when Prefix =:= <<>>, Uri =:= <<>> ->
            declare_each(T, {undefined, Prefixes}, S);
        ok when Prefix =:= <<>> ->
            declare_each(T, {Uri, Prefixes}, S);
        ok ->
            declare_each(T, {Default, [{Prefix, Uri} | Prefixes]}, S);
        {error, Message} ->
            err(malformed, At, S, Message)
    end.

%% Sizes are compared first: most names are neither reserved one.
check_ns_decl(Prefix, Uri) ->
    IsXml = byte_size(Prefix) =:= 3 andalso Prefix =:= <<"xml">>,
    IsXmlns = byte_size(Prefix) =:= 5 andalso Prefix =:= <<"xmlns">>,
    IsXmlNs = byte_size(Uri) =:= byte_size(?XML_NS) andalso Uri =:= ?XML_NS,
    IsXmlnsNs = byte_size(Uri) =:= byte_size(?XMLNS_NS) andalso Uri =:= ?XMLNS_NS,
    if
        IsXml, IsXmlNs -> ok;
        IsXml -> {error, "the prefix 'xml' cannot be bound to another namespace"};
        IsXmlns -> {error, "the prefix 'xmlns' cannot be declared"};
        IsXmlNs -> {error, "the XML namespace can only be bound to the prefix 'xml'"};
        IsXmlnsNs -> {error, "the xmlns namespace cannot be declared"};
        byte_size(Prefix) =:= 0 -> ok;
        byte_size(Uri) =:= 0 ->
            {error, ["the prefix '", show(Prefix), "' cannot be bound to an empty namespace "
                     "name"]};
        true -> ok
    end.

%% Raw is in reverse document order. Positions are kept only when a
%% duplicate is possible (two or more attributes).
resolve_attributes([], _Scope, _S) ->
    {ok, []};
resolve_attributes([{Prefix, Local, Value, At}], Scope, S) ->
    case resolve_attribute(Prefix, Scope) of
        '$unbound' -> unbound(Prefix, At, S);
        Ns -> {ok, [{{Ns, Local}, Value}]}
    end;
resolve_attributes(Raw, Scope, S) ->
    resolve_all(Raw, Scope, S, []).

resolve_all([], _Scope, S, Acc) ->
    case first_duplicate(Acc, fun({Name, _, _}) -> Name end) of
        none ->
            {ok, [{Name, Value} || {Name, Value, _} <- Acc]};
        {{undefined, Local}, _, At} ->
            err(malformed, At, S, ["the attribute '", show(Local), "' appears twice"]);
        {{Ns, Local}, _, At} ->
            err(malformed, At, S, ["two attributes are named '", show(Local),
                                   "' in the namespace '", show(Ns), "'"])
    end;
resolve_all([{Prefix, Local, Value, At} | T], Scope, S, Acc) ->
    case resolve_attribute(Prefix, Scope) of
        '$unbound' -> unbound(Prefix, At, S);
        Ns -> resolve_all(T, Scope, S, [{{Ns, Local}, Value, At} | Acc])
    end.

%% Unprefixed attributes are in no namespace, whatever the default is.
resolve_attribute(<<>>, _Scope) ->
    undefined;
resolve_attribute(Prefix, {_, Prefixes}) ->
    case lists:keyfind(Prefix, 1, Prefixes) of
        {_, Ns} -> Ns;
        false -> '$unbound'
    end.

%% The first element (in list order) whose key was already seen.
first_duplicate(List, KeyFun) ->
    first_duplicate(List, KeyFun, #{}).

first_duplicate([], _KeyFun, _Seen) ->
    none;
first_duplicate([X | T], KeyFun, Seen) ->
    Key = KeyFun(X),
    case Seen of
        #{Key := _} -> X;
        _ -> first_duplicate(T, KeyFun, Seen#{Key => true})
    end.

%% ---------------------------------------------------------------------------
%% References
%% ---------------------------------------------------------------------------

%% From is just after '&'. Returns the decoded character (UTF-8) and the
%% offset after the ';'.
reference(From, S) ->
    case rest(From, S) of
        <<"lt;", _/binary>> -> {ok, <<"<">>, From + 3};
        <<"gt;", _/binary>> -> {ok, <<">">>, From + 3};
        <<"amp;", _/binary>> -> {ok, <<"&">>, From + 4};
        <<"quot;", _/binary>> -> {ok, <<"\"">>, From + 5};
        <<"apos;", _/binary>> -> {ok, <<"'">>, From + 5};
        <<"#x", R/binary>> -> char_ref(hex(R, 0, 0), R, From - 1, From + 2, S);
        <<"#", R/binary>> -> char_ref(dec(R, 0, 0), R, From - 1, From + 1, S);
        R -> entity_ref(R, From, S)
    end.

entity_ref(R, From, S) ->
    case name_len(R) of
        0 when R =:= <<>> ->
            err(truncated, <<>>, S, "the input ended inside a reference");
        0 ->
            err(malformed, From - 1, S, "'&' must start a reference (write '&amp;' for a "
                "literal ampersand)");
        N ->
            case R of
                <<Name:N/binary, $;, _/binary>> ->
                    err(entity_refused, From - 1, S,
                        ["the entity reference &", show(Name), "; is refused: only &lt; &gt; "
                         "&amp; &quot; &apos; and character references are decoded"]);
                <<_:N/binary>> ->
                    err(truncated, <<>>, S, "the input ended inside a reference");
                <<Name:N/binary, _/binary>> ->
                    err(malformed, From - 1, S, ["the reference &", show(Name),
                                                 " is not terminated by ';'"])
            end
    end.

%% {Value, DigitCount}; values past the Unicode range are clamped so that a
%% long run of digits never builds a bignum.
hex(<<C, R/binary>>, V, N) when C >= $0, C =< $9 -> hex(R, clamp(V * 16 + C - $0), N + 1);
hex(<<C, R/binary>>, V, N) when C >= $a, C =< $f -> hex(R, clamp(V * 16 + C - $a + 10), N + 1);
hex(<<C, R/binary>>, V, N) when C >= $A, C =< $F -> hex(R, clamp(V * 16 + C - $A + 10), N + 1);
hex(_, V, N) -> {V, N}.

dec(<<C, R/binary>>, V, N) when C >= $0, C =< $9 -> dec(R, clamp(V * 10 + C - $0), N + 1);
dec(_, V, N) -> {V, N}.

clamp(V) when V > ?MAX_CHAR -> ?MAX_CHAR + 1;
clamp(V) -> V.

%% R follows "&#" or "&#x" (at offset Digits); Amp is the '&'.
char_ref({Cp, N}, R, Amp, Digits, S) ->
    case R of
        <<_:N/binary, $;, _/binary>> when N > 0 ->
            case is_xml_char(Cp) of
                true ->
                    {ok, <<Cp/utf8>>, Digits + N + 1};
                false ->
                    err(bad_encoding, Amp, S,
                        ["the character reference ",
                         show(binary_part(S#st.bin, Amp, Digits + N + 1 - Amp)),
                         " does not denote a character allowed in XML"])
            end;
        <<_:N/binary>> ->
            err(truncated, <<>>, S, "the input ended inside a character reference");
        _ ->
            err(malformed, Amp, S, "malformed character reference (expected '&#' digits ';' "
                "or '&#x' hex digits ';')")
    end.

is_xml_char(C) when C >= 16#20, C =< 16#D7FF -> true;
is_xml_char(C) when C =:= $\t; C =:= $\n; C =:= $\r -> true;
is_xml_char(C) when C >= 16#E000, C =< 16#FFFD -> true;
is_xml_char(C) when C >= 16#10000, C =< ?MAX_CHAR -> true;
is_xml_char(_) -> false.

%% ---------------------------------------------------------------------------
%% Names and whitespace (for the paths that work on binaries)
%% ---------------------------------------------------------------------------

%% {Prefix, Local, QName, Rest} with Prefix <<>> when there is none.
qname(B) ->
    case ncname(B) of
        0 ->
            error;
        N1 ->
            case B of
                <<Prefix:N1/binary, $:, R/binary>> ->
                    case ncname(R) of
                        0 ->
                            error;
                        N2 ->
                            Len = N1 + 1 + N2,
                            <<QName:Len/binary, Rest/binary>> = B,
                            <<Local:N2/binary, _/binary>> = R,
                            {Prefix, Local, QName, Rest}
                    end;
                <<Local:N1/binary, Rest/binary>> ->
                    {<<>>, Local, Local, Rest}
            end
    end.

%% Byte length of the NCName (a name without ':') at the start of B, or 0.
ncname(<<C, R/binary>>) when ?IS_NAME_START(C) ->
    ncname_rest(R, 1);
ncname(<<Cp/utf8, R/binary>>) when ?IS_NAME_START_CP(Cp) ->
    ncname_rest(R, utf8_len(Cp));
ncname(_) ->
    0.

ncname_rest(<<C, R/binary>>, N) when ?IS_NAME_CHAR(C) ->
    ncname_rest(R, N + 1);
ncname_rest(<<Cp/utf8, R/binary>>, N) when ?IS_NAME_CHAR_CP(Cp) ->
    ncname_rest(R, N + utf8_len(Cp));
ncname_rest(_, N) ->
    N.

%% A Name (':' allowed), for entity references.
name_len(B) ->
    case ncname(B) of
        0 -> 0;
        N -> name_tail(B, N)
    end.

name_tail(B, N) ->
    case B of
        <<_:N/binary, $:, R/binary>> -> name_tail(B, N + 1 + ncname_rest(R, 0));
        _ -> N
    end.

%% Only called for non-ASCII characters.
utf8_len(C) when C < 16#800 -> 2;
utf8_len(C) when C < 16#10000 -> 3;
utf8_len(_) -> 4.

skip_ws(<<C, R/binary>>) when ?IS_WS(C) -> skip_ws(R);
skip_ws(B) -> B.

is_ws(<<C, R/binary>>) when ?IS_WS(C) -> is_ws(R);
is_ws(<<>>) -> true;
is_ws(_) -> false.

%% ---------------------------------------------------------------------------
%% Scanning and character validation
%% ---------------------------------------------------------------------------

%% Finds the first delimiter of Pat in Bin at or after From, checking that
%% every byte skipped is a legal XML character in valid UTF-8. Returns the
%% delimiter's offset and first byte, or {bad, Offset} for an illegal byte
%% (callers match {bad, _} first: {At, C} would match it too).
scan(Bin, From, Pat) ->
    case binary:match(Bin, Pat, [{scope, {From, byte_size(Bin) - From}}]) of
        nomatch ->
            nomatch;
        {At, _} ->
            case binary:at(Bin, At) of
                C when C >= 16#80 ->
                    <<_:At/binary, R/binary>> = Bin,
                    case skip_utf8(R, At) of
                        {ok, Next} -> scan(Bin, Next, Pat);
                        {bad, _} = Bad -> Bad
                    end;
                C when ?IS_BAD_CONTROL(C) ->
                    {bad, At};
                C ->
                    {At, C}
            end
    end.

%% Skips a run of non-ASCII characters starting at offset At.
skip_utf8(<<Cp/utf8, R/binary>>, At) when ?IS_LEGAL_CP(Cp) ->
    skip_utf8(R, At + utf8_len(Cp));
skip_utf8(<<C, _/binary>>, At) when C >= 16#80 ->
    {bad, At};
skip_utf8(_, At) ->
    {ok, At}.

%% An illegal byte at offset At.
bad_char(At, S) ->
    err(bad_encoding, At, S, describe_bad(rest(At, S))).

describe_bad(<<C, _/binary>>) when C < 16#80 ->
    io_lib:format("the control character U+~4.16.0B is not allowed in XML", [C]);
describe_bad(<<Cp/utf8, _/binary>>) ->
    io_lib:format("the character U+~4.16.0B is not allowed in XML", [Cp]);
describe_bad(<<C, _/binary>>) ->
    io_lib:format("invalid UTF-8 (byte 16#~2.16.0B); documents must be UTF-8", [C]).

%% An unexpected byte (or the end of input) where Expected was wanted.
unexpected(<<>>, S, Expected) ->
    err(truncated, <<>>, S, ["the input ended; expected ", Expected]);
unexpected(<<C, _/binary>> = B, S, _Expected) when ?IS_BAD_CONTROL(C) ->
    err(bad_encoding, B, S, describe_bad(B));
unexpected(<<Cp/utf8, _/binary>> = B, S, Expected) when ?IS_LEGAL_CP(Cp) ->
    err(malformed, B, S, ["unexpected character '", <<Cp/utf8>>, "'; expected ", Expected]);
unexpected(<<C, _/binary>> = B, S, _Expected) when C >= 16#80 ->
    err(bad_encoding, B, S, describe_bad(B));
unexpected(<<C, _/binary>> = B, S, Expected) ->
    err(malformed, B, S, ["unexpected '", C, "'; expected ", Expected]).

%% ---------------------------------------------------------------------------
%% Offsets, errors and positions
%% ---------------------------------------------------------------------------

%% The offset of B, a suffix of the input.
pos(B, S) ->
    byte_size(S#st.bin) - byte_size(B).

%% The input from offset Pos.
rest(Pos, S) ->
    Bin = S#st.bin,
    binary_part(Bin, Pos, byte_size(Bin) - Pos).

%% At is an offset or the rest of the input where the error is (<<>> for
%% its end).
err(Code, At, S, Message) when is_binary(At) ->
    err(Code, pos(At, S), S, Message);
err(Code, At, S, Message) ->
    error_at(S#st.bin, At, Code, Message).

where(At, S) when is_binary(At) ->
    where(pos(At, S), S);
where(At, S) ->
    {Line, Column} = line_column(S#st.bin, At),
    io_lib:format("line ~b, column ~b", [Line, Column]).

line_column(Bin, Offset) ->
    Before = binary:part(Bin, 0, Offset),
    {Line, LineStart} =
        case binary:matches(Before, [<<"\r\n">>, <<"\n">>, <<"\r">>]) of
            [] -> {1, 0};
            Breaks -> {P, L} = lists:last(Breaks), {length(Breaks) + 1, P + L}
        end,
    Chars = chars(binary:part(Before, LineStart, Offset - LineStart), 0),
    Bom = case Bin of
              <<16#EF, 16#BB, 16#BF, _/binary>> when LineStart =:= 0, Offset >= 3 -> 1;
              _ -> 0
          end,
    {Line, Chars - Bom + 1}.

%% Characters counted as UTF-8 lead bytes (continuation bytes skipped).
chars(<<C, R/binary>>, N) when C >= 16#80, C < 16#C0 -> chars(R, N);
chars(<<_, R/binary>>, N) -> chars(R, N + 1);
chars(<<>>, N) -> N.

%% A name or value for a message: cut short (on a character boundary),
%% with control characters and invalid UTF-8 written as \xHH so that the
%% message stays one line of valid UTF-8.
show(Bin) when byte_size(Bin) =< 60 ->
    printable(Bin, []);
show(Bin) ->
    [printable(binary:part(Bin, 0, cut(Bin, 60)), []), "..."].

printable(<<C, R/binary>>, Acc) when C >= 16#20, C < 16#7F ->
    printable(R, [C | Acc]);
printable(<<Cp/utf8, R/binary>>, Acc) when Cp >= 16#A0 ->
    printable(R, [<<Cp/utf8>> | Acc]);
printable(<<C, R/binary>>, Acc) ->
    printable(R, [io_lib:format("\\x~2.16.0B", [C]) | Acc]);
printable(<<>>, Acc) ->
    lists:reverse(Acc).

cut(Bin, N) when N > 0 ->
    case binary:at(Bin, N) of
        C when C >= 16#80, C < 16#C0 -> cut(Bin, N - 1);
        _ -> N
    end;
cut(_Bin, N) ->
    N.

%% ---------------------------------------------------------------------------
%% Escaping
%% ---------------------------------------------------------------------------

escape(Bin, Pat) ->
    case binary:match(Bin, Pat) of
        nomatch -> Bin;
        {At, 1} -> escape(Bin, Pat, 0, At, [])
    end.

escape(Bin, Pat, From, At, Acc) ->
    Acc1 = [entity(binary:at(Bin, At)), binary:part(Bin, From, At - From) | Acc],
    Next = At + 1,
    case binary:match(Bin, Pat, [{scope, {Next, byte_size(Bin) - Next}}]) of
        nomatch -> lists:reverse(Acc1, [binary:part(Bin, Next, byte_size(Bin) - Next)]);
        {At1, 1} -> escape(Bin, Pat, Next, At1, Acc1)
    end.

entity($&) -> <<"&amp;">>;
entity($<) -> <<"&lt;">>;
entity($>) -> <<"&gt;">>;
entity($") -> <<"&quot;">>;
entity($\t) -> <<"&#9;">>;
entity($\n) -> <<"&#10;">>;
entity($\r) -> <<"&#13;">>.

%% ---------------------------------------------------------------------------
%% Patterns
%% ---------------------------------------------------------------------------

%% binary:compile_pattern/1 results cannot be literals; they are compiled
%% on first use and kept in persistent_term (written once per node).
patterns() ->
    case persistent_term:get(?PATTERNS_KEY, undefined) of
        undefined ->
            Pats = compile_patterns(),
            persistent_term:put(?PATTERNS_KEY, Pats),
            Pats;
        Pats ->
            Pats
    end.

compile_patterns() ->
    Illegal = [<<C>> || C <- lists:seq(0, 16#1F) ++ lists:seq(16#80, 16#FF),
                        C =/= $\t, C =/= $\n, C =/= $\r],
    Scan = fun(Delims) -> binary:compile_pattern(Delims ++ Illegal) end,
    #pats{cdata = Scan([<<"]]>">>, <<"\r">>]),
          comment = Scan([<<"--">>]),
          pi = Scan([<<"?>">>]),
          esc_text = binary:compile_pattern([<<"&">>, <<"<">>, <<">">>, <<"\r">>]),
          esc_attr = binary:compile_pattern([<<"&">>, <<"<">>, <<">">>, <<"\"">>, <<"\t">>,
                                             <<"\n">>, <<"\r">>])}.

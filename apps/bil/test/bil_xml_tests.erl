%% @doc EUnit tests for bil_xml: every construct of BIL's XML subset and
%% every error code, with the positions errors are reported at.
-module(bil_xml_tests).

-include_lib("eunit/include/eunit.hrl").

-define(L, #{max_size => 65536, max_depth => 8}).
-define(XML_NS, <<"http://www.w3.org/XML/1998/namespace">>).

parse(Bin) -> bil_xml:parse(Bin, ?L).

ok(Bin) ->
    {ok, Tree} = parse(Bin),
    Tree.

%% {Code, Line, Column} of a refused document.
err(Bin) ->
    {error, #{code := Code, message := Message} = Reason} = parse(Bin),
    ?assert(is_binary(Message) andalso byte_size(Message) > 0),
    {Code, maps:get(line, Reason, none), maps:get(column, Reason, none)}.

message(Bin) ->
    {error, #{message := Message}} = parse(Bin),
    Message.

leaf(Name, Text) -> {{undefined, Name}, [], Text}.

%% ---------------------------------------------------------------------------
%% Documents and prolog
%% ---------------------------------------------------------------------------

minimal_test_() ->
    [?_assertEqual(leaf(<<"a">>, []), ok(<<"<a/>">>)),
     ?_assertEqual(leaf(<<"a">>, []), ok(<<"<a></a>">>)),
     ?_assertEqual(leaf(<<"a">>, []), ok(<<"<a ></a >">>)),
     ?_assertEqual(leaf(<<"a">>, []), ok(<<"<a\n/>">>)),
     ?_assertEqual(leaf(<<"a">>, [<<"x">>]), ok(<<"<a>x</a>">>))].

prolog_test_() ->
    A = leaf(<<"a">>, []),
    [{"BOM", ?_assertEqual(A, ok(<<16#EF, 16#BB, 16#BF, "<a/>">>))},
     {"declaration", ?_assertEqual(A, ok(<<"<?xml version=\"1.0\"?><a/>">>))},
     {"declaration with encoding",
      ?_assertEqual(A, ok(<<"<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<a/>">>))},
     {"encoding in any case, single quotes, standalone",
      ?_assertEqual(A, ok(<<"<?xml version='1.0' encoding='utf-8' standalone='no' ?><a/>">>))},
     {"BOM then declaration",
      ?_assertEqual(A, ok(<<16#EF, 16#BB, 16#BF, "<?xml version='1.0'?><a/>">>))},
     {"comments, PIs and whitespace around the root",
      ?_assertEqual(A, ok(<<"<?xml version='1.0'?>\r\n<!-- c --><?pi data?>\n<a/>\n<!--e--><?p?> ">>))},
     {"version 1.1 syntax accepted",
      ?_assertEqual(A, ok(<<"<?xml version='1.1'?><a/>">>))}].

prolog_error_test_() ->
    [{"other encoding", ?_assertEqual({bad_encoding, 1, 21},
                                      err(<<"<?xml version=\"1.0\" encoding=\"ISO-8859-1\"?><a/>">>))},
     {"UTF-16 label", ?_assertEqual({bad_encoding, 1, 21},
                                    err(<<"<?xml version='1.0' encoding='UTF-16'?><a/>">>))},
     {"UTF-16 BOM", ?_assertMatch({bad_encoding, 1, 1}, err(<<16#FF, 16#FE, "<", 0, "a", 0>>))},
     {"declaration not first", ?_assertEqual({malformed, 1, 2},
                                             err(<<" <?xml version='1.0'?><a/>">>))},
     {"declaration after root", ?_assertEqual({malformed, 1, 5},
                                              err(<<"<a/><?xml version='1.0'?>">>))},
     {"XML-ish PI target", ?_assertEqual({malformed, 1, 1}, err(<<"<?XmL x?><a/>">>))},
     {"no version", ?_assertEqual({malformed, 1, 1}, err(<<"<?xml encoding='UTF-8'?><a/>">>))},
     {"bad version", ?_assertEqual({malformed, 1, 7}, err(<<"<?xml version='2.0'?><a/>">>))},
     {"bad standalone", ?_assertEqual({malformed, 1, 21},
                                      err(<<"<?xml version='1.0' standalone='maybe'?><a/>">>))},
     {"pseudo-attributes out of order",
      ?_assertEqual({malformed, 1, 38},
                    err(<<"<?xml version='1.0' standalone='yes' encoding='UTF-8'?><a/>">>))},
     {"unterminated declaration", ?_assertEqual({truncated, 1, 16}, err(<<"<?xml version='">>))},
     {"empty document", ?_assertEqual({malformed, 1, 1}, err(<<>>))},
     {"only a BOM", ?_assertEqual({malformed, 1, 1}, err(<<16#EF, 16#BB, 16#BF>>))},
     {"no root", ?_assertEqual({malformed, 2, 9}, err(<<"<!-- -->\n<?pi x?>">>))},
     {"text before root", ?_assertEqual({malformed, 1, 1}, err(<<"x<a/>">>))},
     {"two roots", ?_assertEqual({malformed, 2, 1}, err(<<"<a/>\n<b/>">>))},
     {"text after root", ?_assertEqual({malformed, 1, 6}, err(<<"<a/> x">>))},
     {"CDATA after root", ?_assertEqual({malformed, 1, 5}, err(<<"<a/><![CDATA[x]]>">>))},
     {"unknown markup in prolog", ?_assertEqual({malformed, 1, 1}, err(<<"<!ELEMENT a ANY><a/>">>))},
     {"message names the problem",
      ?_assertEqual(<<"the document declares encoding 'latin1'; only UTF-8 is accepted">>,
                    message(<<"<?xml version='1.0' encoding='latin1'?><a/>">>))}].

not_binary_test_() ->
    [?_assertMatch({error, #{code := not_binary, message := <<_/binary>>}},
                   bil_xml:parse("<a/>", ?L)),
     ?_assertMatch({error, #{code := not_binary}}, bil_xml:parse(undefined, ?L))].

too_large_test_() ->
    Doc = <<"<a>0123456789</a>">>,
    [?_assertMatch({ok, _}, bil_xml:parse(Doc, #{max_size => byte_size(Doc), max_depth => 2})),
     ?_assertEqual({error, #{code => too_large,
                             message => <<"document is 17 bytes, over the limit of 16 bytes">>}},
                   bil_xml:parse(Doc, #{max_size => 16, max_depth => 2})),
     {"size is checked before anything else",
      ?_assertMatch({error, #{code := too_large}},
                    bil_xml:parse(<<"<!DOCTYPE a><a/>">>, #{max_size => 4, max_depth => 2}))}].

%% ---------------------------------------------------------------------------
%% Content
%% ---------------------------------------------------------------------------

children_test_() ->
    B = leaf(<<"b">>, []),
    [{"whitespace between elements dropped",
      ?_assertEqual({{undefined, <<"a">>}, [], [B, B]}, ok(<<"<a>\n  <b/>\n  <b/>\n</a>">>))},
     {"whitespace-only leaf kept",
      ?_assertEqual(leaf(<<"a">>, [<<" \n\t ">>]), ok(<<"<a> \n\t </a>">>))},
     {"mixed text kept in order",
      ?_assertEqual({{undefined, <<"a">>}, [], [<<" x ">>, B, <<"y">>, B]},
                    ok(<<"<a> x <b/>y<b/> </a>">>))},
     {"whitespace from a reference counts as whitespace",
      ?_assertEqual({{undefined, <<"a">>}, [], [B]}, ok(<<"<a>&#32;&#x9;<b/>&#10;</a>">>))},
     {"leaf text is one binary",
      ?_assertEqual(leaf(<<"a">>, [<<"xyz<&AB\"'>">>]),
                    ok(<<"<a>x<!--c-->y<?p q?>z<![CDATA[<&]]>&#65;&#x42;&quot;&apos;&gt;</a>">>))},
     {"comment-only leaf is empty",
      ?_assertEqual(leaf(<<"a">>, []), ok(<<"<a><!-- c --></a>">>))},
     {"empty CDATA leaf is empty",
      ?_assertEqual(leaf(<<"a">>, []), ok(<<"<a><![CDATA[]]></a>">>))},
     {"whitespace CDATA beside elements dropped",
      ?_assertEqual({{undefined, <<"a">>}, [], [B]}, ok(<<"<a><![CDATA[ ]]><b/></a>">>))},
     {"CDATA keeps markup characters",
      ?_assertEqual(leaf(<<"a">>, [<<"<b>&amp;]]">>]), ok(<<"<a><![CDATA[<b>&amp;]]]]></a>">>))},
     {"lone > and ] in text",
      ?_assertEqual(leaf(<<"a">>, [<<"a>b]c]]d">>]), ok(<<"<a>a>b]c]]d</a>">>))},
     {"nested", ?_assertEqual({{undefined, <<"a">>}, [],
                               [{{undefined, <<"b">>}, [], [leaf(<<"c">>, [<<"t">>])]}]},
                              ok(<<"<a><b><c>t</c></b></a>">>))},
     {"text is a sub-binary of the input",
      fun() ->
              {ok, {_, _, [Text]}} = parse(<<"<a>some text</a>">>),
              ?assertEqual(<<"some text">>, Text)
      end}].

line_ends_test_() ->
    [?_assertEqual(leaf(<<"a">>, [<<"1\n2\n3\n\n4">>]), ok(<<"<a>1\r\n2\r3\n\r\n4</a>">>)),
     ?_assertEqual(leaf(<<"a">>, [<<"x\n">>]), ok(<<"<a>x\r</a>">>)),
     {"in CDATA", ?_assertEqual(leaf(<<"a">>, [<<"1\n2\n">>]), ok(<<"<a><![CDATA[1\r\n2\r]]></a>">>))},
     {"a reference keeps CR", ?_assertEqual(leaf(<<"a">>, [<<"1\r\n">>]), ok(<<"<a>1&#13;&#10;</a>">>))}].

unicode_test_() ->
    [?_assertEqual(leaf(<<"é中"/utf8>>, [<<"é中😀\x{7F}\x{85}"/utf8>>]),
                   ok(<<"<é中>é中😀\x{7F}\x{85}</é中>"/utf8>>)),
     ?_assertEqual(leaf(<<"a">>, [<<"😀中"/utf8>>]), ok(<<"<a>&#x1F600;&#20013;</a>">>)),
     ?_assertEqual(leaf(<<"a·b"/utf8>>, []), ok(<<"<a·b/>"/utf8>>))].

comment_test_() ->
    [?_assertEqual(leaf(<<"a">>, []), ok(<<"<a><!----></a>">>)),
     ?_assertEqual(leaf(<<"a">>, []), ok(<<"<a><!-- - a-b <b> & --></a>">>)),
     {"-- inside", ?_assertEqual({malformed, 1, 9}, err(<<"<a><!-- --x --></a>">>))},
     {"ends with ---", ?_assertEqual({malformed, 1, 10}, err(<<"<a><!-- x---></a>">>))},
     {"unterminated", ?_assertEqual({truncated, 1, 12}, err(<<"<a><!-- x -">>))},
     {"bad markup", ?_assertEqual({malformed, 1, 4}, err(<<"<a><!- x --></a>">>))}].

pi_test_() ->
    [?_assertEqual(leaf(<<"a">>, [<<"xy">>]), ok(<<"<a>x<?pi?>y</a>">>)),
     ?_assertEqual(leaf(<<"a">>, []), ok(<<"<a><?xml-stylesheet href='s.css'?></a>">>)),
     ?_assertEqual(leaf(<<"a">>, []), ok(<<"<a><?pi <b>?x ? ?></a>">>)),
     {"no space after target", ?_assertEqual({malformed, 1, 8}, err(<<"<a><?pi!x?></a>">>))},
     {"no target", ?_assertEqual({malformed, 1, 6}, err(<<"<a><? x?></a>">>))},
     {"unterminated", ?_assertEqual({truncated, 1, 11}, err(<<"<a><?pi x?">>))}].

cdata_test_() ->
    [{"CDATA in prolog", ?_assertEqual({malformed, 1, 1}, err(<<"<![CDATA[x]]><a/>">>))},
     {"unterminated", ?_assertEqual({truncated, 1, 15}, err(<<"<a><![CDATA[x]">>))},
     {"]]> in text", ?_assertEqual({malformed, 1, 5}, err(<<"<a>x]]>y</a>">>))},
     {"lower-case cdata", ?_assertEqual({malformed, 1, 4}, err(<<"<a><![cdata[x]]></a>">>))}].

%% ---------------------------------------------------------------------------
%% References
%% ---------------------------------------------------------------------------

references_test_() ->
    [?_assertEqual(leaf(<<"a">>, [<<"<>&\"'">>]), ok(<<"<a>&lt;&gt;&amp;&quot;&apos;</a>">>)),
     ?_assertEqual(leaf(<<"a">>, [<<"AA\tZ">>]), ok(<<"<a>&#65;&#x41;&#9;&#x5a;</a>">>)),
     ?_assertEqual(leaf(<<"a">>, [<<"\x{10FFFF}"/utf8>>]), ok(<<"<a>&#x10FFFF;</a>">>)),
     ?_assertEqual(leaf(<<"a">>, [<<"A">>]), ok(<<"<a>&#0000065;</a>">>)),
     {"undeclared entity", ?_assertEqual({entity_refused, 1, 6}, err(<<"<a>x &nbsp; y</a>">>))},
     {"entity with a colon", ?_assertEqual({entity_refused, 1, 4}, err(<<"<a>&a:b;</a>">>))},
     {"entity in attribute", ?_assertEqual({entity_refused, 1, 7}, err(<<"<a x='&ent;'/>">>))},
     {"message names the entity",
      ?_assertMatch(<<"the entity reference &nbsp; is refused", _/binary>>,
                    message(<<"<a>&nbsp;</a>">>))},
     {"NUL", ?_assertEqual({bad_encoding, 1, 4}, err(<<"<a>&#0;</a>">>))},
     {"control", ?_assertEqual({bad_encoding, 1, 4}, err(<<"<a>&#x1B;</a>">>))},
     {"surrogate", ?_assertEqual({bad_encoding, 1, 4}, err(<<"<a>&#xD800;</a>">>))},
     {"FFFE", ?_assertEqual({bad_encoding, 1, 4}, err(<<"<a>&#xFFFE;</a>">>))},
     {"beyond Unicode", ?_assertEqual({bad_encoding, 1, 4}, err(<<"<a>&#x110000;</a>">>))},
     {"huge number", ?_assertEqual({bad_encoding, 1, 4},
                                   err(<<"<a>&#99999999999999999999999999999999999;</a>">>))},
     {"no digits", ?_assertEqual({malformed, 1, 4}, err(<<"<a>&#;</a>">>))},
     {"no hex digits", ?_assertEqual({malformed, 1, 4}, err(<<"<a>&#x;</a>">>))},
     {"upper-case X", ?_assertEqual({malformed, 1, 4}, err(<<"<a>&#X41;</a>">>))},
     {"bad digit", ?_assertEqual({malformed, 1, 4}, err(<<"<a>&#12a;</a>">>))},
     {"no semicolon", ?_assertEqual({malformed, 1, 4}, err(<<"<a>&lt </a>">>))},
     {"bare ampersand", ?_assertEqual({malformed, 1, 4}, err(<<"<a>& b</a>">>))},
     {"ampersand at end", ?_assertEqual({truncated, 1, 5}, err(<<"<a>&">>))},
     {"unterminated name", ?_assertEqual({truncated, 1, 8}, err(<<"<a>&amp">>))},
     {"unterminated number", ?_assertEqual({truncated, 1, 9}, err(<<"<a>&#123">>))}].

%% ---------------------------------------------------------------------------
%% Attributes
%% ---------------------------------------------------------------------------

attributes_test_() ->
    [?_assertEqual({{undefined, <<"a">>},
                    [{{undefined, <<"x">>}, <<"1">>}, {{undefined, <<"y">>}, <<"2\"'">>},
                     {{undefined, <<"z">>}, <<>>}], []},
                   ok(<<"<a x='1' y = \"2&quot;'\"\n\tz=''/>">>)),
     {"normalisation of literal whitespace, not of references",
      ?_assertEqual({{undefined, <<"a">>}, [{{undefined, <<"x">>}, <<"1 2 3 4\t5\n6\r">>}], []},
                    ok(<<"<a x='1\t2\n3\r\n4&#9;5&#10;6&#13;'/>">>))},
     {"lone CR", ?_assertEqual({{undefined, <<"a">>}, [{{undefined, <<"x">>}, <<"1 2">>}], []},
                               ok(<<"<a x='1\r2'/>">>))},
     {"> and the other quote are literal",
      ?_assertEqual({{undefined, <<"a">>}, [{{undefined, <<"x">>}, <<"a>b\"c">>}], []},
                    ok(<<"<a x='a>b\"c'/>">>))},
     {"attributes with content",
      ?_assertEqual({{undefined, <<"a">>}, [{{undefined, <<"x">>}, <<"é"/utf8>>}], [<<"t">>]},
                    ok(<<"<a x='é'>t</a>"/utf8>>))},
     {"< in value", ?_assertEqual({malformed, 1, 8}, err(<<"<a x='1<'/>">>))},
     {"no quotes", ?_assertEqual({malformed, 1, 6}, err(<<"<a x=1/>">>))},
     {"no value", ?_assertEqual({malformed, 1, 5}, err(<<"<a x/>">>))},
     {"no space between", ?_assertEqual({malformed, 1, 9}, err(<<"<a x='1'y='2'/>">>))},
     {"duplicate", ?_assertEqual({malformed, 1, 10}, err(<<"<a x='1' x='2'/>">>))},
     {"duplicate message",
      ?_assertEqual(<<"the attribute 'x' appears twice">>, message(<<"<a x='1' x='2'/>">>))},
     {"unterminated value", ?_assertEqual({truncated, 1, 9}, err(<<"<a x='12">>))},
     {"unterminated tag", ?_assertEqual({truncated, 1, 9}, err(<<"<a x='1'">>))},
     {"space before name", ?_assertEqual({malformed, 1, 2}, err(<<"< a/>">>))}].

%% ---------------------------------------------------------------------------
%% Namespaces
%% ---------------------------------------------------------------------------

namespaces_test_() ->
    [{"prefixed", ?_assertEqual({{<<"urn:x">>, <<"a">>}, [], []},
                                ok(<<"<p:a xmlns:p='urn:x'/>">>))},
     {"default", ?_assertEqual({{<<"urn:d">>, <<"a">>}, [], [{{<<"urn:d">>, <<"b">>}, [], []}]},
                               ok(<<"<a xmlns='urn:d'><b/></a>">>))},
     {"declarations are not attributes, unprefixed attributes have no namespace",
      ?_assertEqual({{<<"urn:d">>, <<"a">>},
                     [{{undefined, <<"x">>}, <<"1">>}, {{<<"urn:p">>, <<"y">>}, <<"2">>}], []},
                    ok(<<"<a x='1' xmlns='urn:d' p:y='2' xmlns:p='urn:p'/>">>))},
     {"scoping and redeclaration",
      ?_assertEqual({{<<"u1">>, <<"a">>}, [],
                     [{{<<"u2">>, <<"b">>}, [], [{{<<"u2">>, <<"c">>}, [], []}]},
                      {{<<"u1">>, <<"d">>}, [], []}]},
                    ok(<<"<p:a xmlns:p='u1'><p:b xmlns:p='u2'><p:c/></p:b><p:d/></p:a>">>))},
     {"undeclaring the default",
      ?_assertEqual({{<<"u">>, <<"a">>}, [], [{{undefined, <<"b">>}, [], [leaf(<<"c">>, [])]}]},
                    ok(<<"<a xmlns='u'><b xmlns=''><c/></b></a>">>))},
     {"xml prefix is pre-bound",
      ?_assertEqual({{undefined, <<"a">>}, [{{?XML_NS, <<"lang">>}, <<"en">>}], []},
                    ok(<<"<a xml:lang='en'/>">>))},
     {"xml prefix may be declared to its own namespace",
      ?_assertEqual(leaf(<<"a">>, []),
                    ok(<<"<a xmlns:xml='http://www.w3.org/XML/1998/namespace'/>">>))},
     {"namespace names are decoded",
      ?_assertEqual({{<<"urn:a&b">>, <<"a">>}, [], []}, ok(<<"<p:a xmlns:p='urn:a&amp;b'/>">>))},
     {"same local name in two namespaces",
      ?_assertEqual({{undefined, <<"a">>},
                     [{{<<"u1">>, <<"x">>}, <<"1">>}, {{<<"u2">>, <<"x">>}, <<"2">>},
                      {{undefined, <<"x">>}, <<"3">>}], []},
                    ok(<<"<a xmlns:p='u1' xmlns:q='u2' p:x='1' q:x='2' x='3'/>">>))},
     {"end tag with prefix",
      ?_assertEqual({{<<"u">>, <<"a">>}, [], [<<"t">>]}, ok(<<"<p:a xmlns:p='u'>t</p:a >">>))}].

namespace_error_test_() ->
    [{"unbound element prefix", ?_assertEqual({malformed, 2, 3}, err(<<"<a>\n  <p:b/></a>">>))},
     {"unbound attribute prefix", ?_assertEqual({malformed, 1, 4}, err(<<"<a p:x='1'/>">>))},
     {"unbound prefix on a field", ?_assertEqual({malformed, 1, 4}, err(<<"<a><p:b>x</p:b></a>">>))},
     {"unbound message",
      ?_assertEqual(<<"the namespace prefix 'p' is not declared">>, message(<<"<p:a/>">>))},
     {"prefix out of scope", ?_assertEqual({malformed, 1, 20},
                                           err(<<"<a><b xmlns:p='u'/><p:c/></a>">>))},
     {"same namespace twice", ?_assertEqual({malformed, 1, 36},
                                            err(<<"<a xmlns:p='u' xmlns:q='u' p:x='1' q:x='2'/>">>))},
     {"prefix declared twice", ?_assertEqual({malformed, 1, 16},
                                             err(<<"<a xmlns:p='u' xmlns:p='v'/>">>))},
     {"default declared twice", ?_assertEqual({malformed, 1, 14},
                                              err(<<"<a xmlns='u' xmlns='v'/>">>))},
     {"empty prefixed namespace", ?_assertEqual({malformed, 1, 4}, err(<<"<a xmlns:p=''/>">>))},
     {"xml bound elsewhere", ?_assertEqual({malformed, 1, 4}, err(<<"<a xmlns:xml='u'/>">>))},
     {"xmlns declared", ?_assertEqual({malformed, 1, 4}, err(<<"<a xmlns:xmlns='u'/>">>))},
     {"XML namespace to another prefix",
      ?_assertEqual({malformed, 1, 4},
                    err(<<"<a xmlns:p='http://www.w3.org/XML/1998/namespace'/>">>))},
     {"xmlns namespace", ?_assertEqual({malformed, 1, 4},
                                       err(<<"<a xmlns='http://www.w3.org/2000/xmlns/'/>">>))},
     {"xmlns element prefix", ?_assertEqual({malformed, 1, 1}, err(<<"<xmlns:a/>">>))},
     {"empty local name", ?_assertEqual({malformed, 1, 4}, err(<<"<p:/>">>))},
     {"two colons", ?_assertEqual({malformed, 1, 5}, err(<<"<p:a:b xmlns:p='u'/>">>))},
     {"leading colon", ?_assertEqual({malformed, 1, 2}, err(<<"<:a/>">>))}].

%% ---------------------------------------------------------------------------
%% Names, end tags, structure
%% ---------------------------------------------------------------------------

names_test_() ->
    [?_assertEqual(leaf(<<"_a-b.c9">>, []), ok(<<"<_a-b.c9/>">>)),
     {"digit first", ?_assertEqual({malformed, 1, 2}, err(<<"<9a/>">>))},
     {"dash first", ?_assertEqual({malformed, 1, 2}, err(<<"<-a/>">>))},
     {"non-letter symbol", ?_assertEqual({malformed, 1, 3}, err(<<"<a×b/>"/utf8>>))},
     {"bad character message",
      ?_assertEqual(<<"unexpected character '×'; expected whitespace, '>' or '/>' in the start "
                      "tag <a>"/utf8>>, message(<<"<a×b/>"/utf8>>))}].

end_tag_test_() ->
    [{"mismatch", ?_assertEqual({malformed, 3, 3}, err(<<"<a>\n  <b>\n  </c>\n</a>">>))},
     {"mismatch message",
      ?_assertEqual(<<"end tag </b> does not match start tag <a> opened at line 2, column 3">>,
                    message(<<"<r>\n  <a></b></r>">>))},
     {"longer end name", ?_assertEqual({malformed, 1, 4}, err(<<"<a></ab>">>))},
     {"shorter end name", ?_assertEqual({malformed, 1, 5}, err(<<"<ab></a>">>))},
     {"prefix differs", ?_assertEqual({malformed, 1, 30},
                                      err(<<"<p:a xmlns:p='u' xmlns:q='u'></q:a>">>))},
     {"space after </", ?_assertEqual({malformed, 1, 6}, err(<<"<a></ a>">>))},
     {"junk in end tag", ?_assertEqual({malformed, 1, 8}, err(<<"<a></a x>">>))},
     {"unclosed", ?_assertEqual({truncated, 2, 4}, err(<<"<a>\n<b>">>))},
     {"unclosed message",
      ?_assertEqual(<<"the input ended before the end tag </b> of the element opened at line 2, "
                      "column 1">>, message(<<"<a>\n<b>">>))},
     {"truncated end tag", ?_assertEqual({truncated, 1, 7}, err(<<"<a></a">>))},
     {"truncated end name", ?_assertEqual({truncated, 1, 9}, err(<<"<abc></a">>))},
     {"stray end tag", ?_assertEqual({malformed, 1, 2}, err(<<"</a>">>))},
     {"long names are cut short in messages, on a character boundary",
      fun() ->
              Long = binary:copy(<<"é"/utf8>>, 70),
              Message = message(<<"<", Long/binary, "></x>">>),
              ?assertEqual(<<"end tag </x> does not match start tag <",
                             (binary:copy(<<"é"/utf8>>, 30))/binary, "...> opened at line 1, "
                             "column 1">>, Message)
      end}].

depth_test_() ->
    Nest = fun(N) -> iolist_to_binary([lists:duplicate(N, "<a>"), lists:duplicate(N, "</a>")]) end,
    [{"at the limit", ?_assertMatch({ok, _}, parse(Nest(8)))},
     {"one over", ?_assertEqual({too_deep, 1, 25}, err(Nest(9)))},
     {"root is depth 1",
      ?_assertMatch({ok, _}, bil_xml:parse(<<"<a>t</a>">>, #{max_size => 100, max_depth => 1}))},
     {"empty elements count",
      ?_assertMatch({error, #{code := too_deep}},
                    bil_xml:parse(<<"<a><b/></a>">>, #{max_size => 100, max_depth => 1}))}].

doctype_test_() ->
    [?_assertEqual({doctype_refused, 1, 1}, err(<<"<!DOCTYPE a><a/>">>)),
     ?_assertEqual({doctype_refused, 2, 1},
                   err(<<"<?xml version='1.0'?>\n<!DOCTYPE a [<!ENTITY e 'x'>]><a>&e;</a>">>)),
     {"inside content", ?_assertEqual({doctype_refused, 1, 4}, err(<<"<a><!DOCTYPE a></a>">>))},
     {"after the root", ?_assertEqual({doctype_refused, 1, 5}, err(<<"<a/><!DOCTYPE a>">>))},
     {"inside a comment it is text", ?_assertMatch({ok, _}, parse(<<"<a><!-- <!DOCTYPE a> --></a>">>))}].

%% ---------------------------------------------------------------------------
%% Encoding
%% ---------------------------------------------------------------------------

encoding_test_() ->
    [{"Latin-1 byte in text", ?_assertEqual({bad_encoding, 1, 5}, err(<<"<a>x", 16#E9, "</a>">>))},
     {"Latin-1 byte in a name", ?_assertEqual({bad_encoding, 1, 3}, err(<<"<a", 16#E9, "/>">>))},
     {"Latin-1 byte in an attribute",
      ?_assertEqual({bad_encoding, 1, 7}, err(<<"<a x='", 16#E9, "'/>">>))},
     {"Latin-1 byte in a comment",
      ?_assertEqual({bad_encoding, 1, 8}, err(<<"<a><!--", 16#E9, "--></a>">>))},
     {"Latin-1 byte in a PI", ?_assertEqual({bad_encoding, 1, 9}, err(<<"<a><?p x", 16#E9, "?></a>">>))},
     {"Latin-1 byte in CDATA",
      ?_assertEqual({bad_encoding, 1, 13}, err(<<"<a><![CDATA[", 16#E9, "]]></a>">>))},
     {"Latin-1 byte after root", ?_assertEqual({bad_encoding, 1, 5}, err(<<"<a/>", 16#E9>>))},
     {"overlong encoding", ?_assertEqual({bad_encoding, 1, 4}, err(<<"<a>", 16#C0, 16#BC, "</a>">>))},
     {"encoded surrogate",
      ?_assertEqual({bad_encoding, 1, 4}, err(<<"<a>", 16#ED, 16#A0, 16#80, "</a>">>))},
     {"beyond U+10FFFF",
      ?_assertEqual({bad_encoding, 1, 4}, err(<<"<a>", 16#F4, 16#90, 16#80, 16#80, "</a>">>))},
     {"U+FFFF", ?_assertEqual({bad_encoding, 1, 5}, err(<<"<a>x", 16#EF, 16#BF, 16#BF, "</a>">>))},
     {"truncated sequence", ?_assertEqual({bad_encoding, 1, 4}, err(<<"<a>", 16#E4, 16#B8, "</a>">>))},
     {"NUL", ?_assertEqual({bad_encoding, 1, 4}, err(<<"<a>", 0, "</a>">>))},
     {"escape character", ?_assertEqual({bad_encoding, 2, 1}, err(<<"<a>\n", 27, 27, "</a>">>))},
     {"control in attribute", ?_assertEqual({bad_encoding, 1, 8}, err(<<"<a x='1", 1, "'/>">>))},
     {"control in tag", ?_assertEqual({bad_encoding, 1, 3}, err(<<"<a", 1, "/>">>))},
     {"message",
      ?_assertEqual(<<"the control character U+001B is not allowed in XML">>,
                    message(<<"<a>", 27, "</a>">>))},
     {"column counts characters",
      ?_assertEqual({bad_encoding, 1, 6}, err(<<"<a>é中"/utf8, 1, "</a>">>))}].

positions_test_() ->
    [{"CRLF lines", ?_assertEqual({entity_refused, 3, 2}, err(<<"<a>\r\n\r\n &e;</a>">>))},
     {"CR lines", ?_assertEqual({entity_refused, 3, 2}, err(<<"<a>\r\r &e;</a>">>))},
     {"BOM is not a column", ?_assertEqual({entity_refused, 1, 4},
                                           err(<<16#EF, 16#BB, 16#BF, "<a>&e;</a>">>))},
     {"error_at",
      ?_assertEqual({error, #{code => bad_value, message => <<"m">>, line => 2, column => 3}},
                    bil_xml:error_at(<<"ab\ncdé"/utf8>>, 5, bad_value, ["m"]))},
     {"error_at counts characters",
      ?_assertEqual({error, #{code => malformed, message => <<"x">>, line => 1, column => 3}},
                    bil_xml:error_at(<<"é中x"/utf8>>, 5, malformed, <<"x">>))},
     {"error_at past the end is clamped",
      ?_assertEqual({error, #{code => malformed, message => <<"x">>, line => 1, column => 3}},
                    bil_xml:error_at(<<"ab">>, 10, malformed, <<"x">>))}].

%% ---------------------------------------------------------------------------
%% Escaping
%% ---------------------------------------------------------------------------

escape_test_() ->
    Text = <<"a<b>&c\"d'\r\n\té"/utf8>>,
    [?_assertEqual(<<"plain">>, iolist_to_binary(bil_xml:escape_text(<<"plain">>))),
     ?_assertEqual(<<"a&lt;b&gt;&amp;c\"d'&#13;\n\té"/utf8>>,
                   iolist_to_binary(bil_xml:escape_text(Text))),
     ?_assertEqual(<<"a&lt;b&gt;&amp;c&quot;d'&#13;&#10;&#9;é"/utf8>>,
                   iolist_to_binary(bil_xml:escape_attr(Text))),
     ?_assertEqual(<<>>, iolist_to_binary(bil_xml:escape_attr(<<>>))),
     {"escaped text and attributes survive a parse",
      fun() ->
              Doc = iolist_to_binary(["<a x=\"", bil_xml:escape_attr(Text), "\">",
                                      bil_xml:escape_text(Text), "</a>"]),
              ?assertEqual({{undefined, <<"a">>}, [{{undefined, <<"x">>}, Text}], [Text]},
                           ok(Doc))
      end},
     {"]]> is escaped in text",
      ?_assertEqual(leaf(<<"a">>, [<<"]]>">>]),
                    ok(iolist_to_binary(["<a>", bil_xml:escape_text(<<"]]>">>), "</a>"])))}].

%% ---------------------------------------------------------------------------
%% The BIL example documents
%% ---------------------------------------------------------------------------

examples_test_() ->
    Dir = filename:join(code:priv_dir(bil), "examples"),
    Files = filelib:wildcard(filename:join(Dir, "*.xml")),
    [{filename:basename(F),
      fun() ->
              {ok, Bin} = file:read_file(F),
              ?assertMatch({ok, _}, bil_xml:parse(Bin, #{max_size => 1048576, max_depth => 32})),
              ?assertEqual(bil_xml_ref:parse(Bin),
                           bil_xml:parse(Bin, #{max_size => 1048576, max_depth => 32}))
      end} || F <- Files, not is_invalid_example(F)].

%% Examples meant to be refused are exercised by the codec tests.
is_invalid_example(File) ->
    string:find(filename:basename(File), "invalid") =/= nomatch orelse
        string:find(filename:basename(File), "bad") =/= nomatch.

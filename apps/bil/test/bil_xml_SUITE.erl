%% @doc Properties and attack documents for bil_xml: differential testing
%% against an xmerl_sax_parser reference on generated well-formed
%% documents, fuzzing for robustness, atom-table safety, and the classic
%% entity-expansion and resource-exhaustion attacks.
-module(bil_xml_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("proper/include/proper.hrl").

-export([all/0, groups/0, suite/0, init_per_suite/1, end_per_suite/1]).
-export([differential/1, differential_signals/1,
         fuzz_mutations/1, fuzz_random_bytes/1, fuzz_prefixes/1,
         atoms_not_created/1,
         billion_laughs/1, quadratic_blowup/1, external_entity/1, parameter_entities/1,
         too_large/1, too_deep/1, million_deep/1,
         many_attributes/1, long_name/1, big_text/1]).

-define(LIMITS, #{max_size => 1048576, max_depth => 32}).
-define(NAMESPACES, [<<"urn:evatar:bil:1">>, <<"urn:a">>, <<"urn:b">>,
                     <<"http://example.com/ns?x=1&y=2">>]).

suite() ->
    [{timetrap, {minutes, 5}}].

all() ->
    [{group, differential}, {group, fuzz}, {group, attacks}, {group, limits}].

groups() ->
    [{differential, [], [differential, differential_signals]},
     {fuzz, [], [fuzz_mutations, fuzz_random_bytes, fuzz_prefixes, atoms_not_created]},
     {attacks, [], [billion_laughs, quadratic_blowup, external_entity, parameter_entities]},
     {limits, [], [too_large, too_deep, million_deep, many_attributes, long_name, big_text]}].

init_per_suite(Config) ->
    {ok, _} = application:ensure_all_started(xmerl),
    Config.

end_per_suite(_Config) ->
    ok.

%% ---------------------------------------------------------------------------
%% Differential
%% ---------------------------------------------------------------------------

%% Generated well-formed documents parse to the same tree as with xmerl.
differential(_Config) ->
    ok = evatar_test_proper:check(prop_differential(), 600).

%% Generated BIL-shaped documents (prefixed structure, leaf fields, CRLF and
%% indentation) parse to the same tree as with xmerl.
differential_signals(_Config) ->
    ok = evatar_test_proper:check(prop_differential_signal(), 200).

prop_differential() ->
    ?FORALL(Doc, document(), same_as_reference(Doc)).

prop_differential_signal() ->
    ?FORALL(Doc, signal_like(), same_as_reference(Doc)).

same_as_reference(Doc) ->
    Ours = bil_xml:parse(Doc, ?LIMITS),
    Ref = bil_xml_ref:parse(Doc),
    ?WHENFAIL(ct:pal("document:~n~p~nbil_xml: ~p~nreference: ~p", [Doc, Ours, Ref]),
              is_tuple(Ref) andalso element(1, Ref) =:= ok andalso Ours =:= Ref).

%% ---------------------------------------------------------------------------
%% Fuzz
%% ---------------------------------------------------------------------------

%% Byte flips, insertions and deletions in well-formed documents never make
%% the parser raise or return anything but ok or a well-formed error.
fuzz_mutations(_Config) ->
    ok = evatar_test_proper:check(prop_fuzz_mutations(), 2500).

%% Random bytes (biased towards XML syntax) never make the parser raise.
fuzz_random_bytes(_Config) ->
    ok = evatar_test_proper:check(prop_fuzz_random(), 2000).

%% Every prefix of several documents is refused as truncated or parses, never raises.
fuzz_prefixes(_Config) ->
    %% Generated documents vary in size: take them until they hold at least
    %% 1,000 bytes, so the prefix count below does not depend on luck.
    Generated = generated_documents(1000, []),
    Docs = Generated ++ [signal_example(), description_example(),
            <<"<?xml version='1.0'?><a:b xmlns:a='u' x=\"1&amp;\"><![CDATA[c]]><!--d--><?e f?>"
              "&#x41;&lt;\r\n</a:b>"/utf8>>,
            <<"<r>é中😀<é x='é'/></r>"/utf8>>],
    Counts = [check_prefixes(Doc) || Doc <- Docs],
    ct:log("prefixes checked: ~p", [Counts]),
    true = lists:sum(Counts) > 2000.

generated_documents(Bytes, Acc) when Bytes =< 0 ->
    Acc;
generated_documents(Bytes, Acc) ->
    {ok, Doc} = proper_gen:pick(document(), 30),
    generated_documents(Bytes - byte_size(Doc), [Doc | Acc]).

%% A prefix either fails with a well-formed error or, once the root element
%% is complete, gives the same tree as the whole document.
check_prefixes(Doc) ->
    Size = byte_size(Doc),
    {ok, Tree} = bil_xml:parse(Doc, ?LIMITS),
    lists:foreach(
      fun(N) ->
              Prefix = binary:part(Doc, 0, N),
              case bil_xml:parse(Prefix, ?LIMITS) of
                  {error, Reason} ->
                      true = well_formed_error(Reason);
                  {ok, Tree} ->
                      ok;
                  Other ->
                      ct:fail({prefix_parsed_differently, Prefix, Other})
              end
      end, lists:seq(0, Size - 1)),
    Size.

prop_fuzz_mutations() ->
    ?FORALL({Doc, Mutations}, {resize(10, document()), resize(4, list(mutation()))},
            begin
                Mutated = mutate(Doc, Mutations),
                ?WHENFAIL(ct:pal("input: ~p", [Mutated]), valid_result(Mutated))
            end).

prop_fuzz_random() ->
    ?FORALL(Bin, random_input(), ?WHENFAIL(ct:pal("input: ~p", [Bin]), valid_result(Bin))).

%% Runs in this process: an exception fails the property (bil_xml has no
%% last-resort handler in TEST builds) and the suite's timetrap catches hangs.
valid_result(Bin) ->
    case bil_xml:parse(Bin, #{max_size => 65536, max_depth => 8}) of
        {ok, Element} -> valid_element(Element);
        {error, Reason} -> well_formed_error(Reason)
    end.

valid_element({{Ns, Local}, Attrs, Children}) ->
    (Ns =:= undefined orelse is_binary(Ns)) andalso is_binary(Local) andalso
        lists:all(fun({{ANs, ALocal}, Value}) ->
                          (ANs =:= undefined orelse is_binary(ANs)) andalso is_binary(ALocal)
                              andalso is_binary(Value)
                  end, Attrs) andalso
        lists:all(fun(C) when is_binary(C) -> C =/= <<>>;
                     (C) -> valid_element(C)
                  end, Children);
valid_element(_) ->
    false.

well_formed_error(#{code := Code, message := Message} = Reason) ->
    Codes = [too_large, not_binary, doctype_refused, entity_refused, too_deep, truncated,
             malformed, bad_encoding],
    lists:member(Code, Codes) andalso is_binary(Message) andalso Message =/= <<>> andalso
        is_binary(unicode:characters_to_binary(Message)) andalso
        case Reason of
            #{line := L, column := C} -> is_integer(L) andalso L > 0 andalso
                                             is_integer(C) andalso C > 0;
            _ -> not maps:is_key(line, Reason) andalso not maps:is_key(column, Reason)
        end;
well_formed_error(_) ->
    false.

mutation() ->
    {oneof([flip, insert, delete, insert_token]), non_neg_integer(), byte(),
     elements([<<"<">>, <<">">>, <<"&">>, <<"&#">>, <<"]]>">>, <<"<!--">>, <<"--">>,
               <<"<![CDATA[">>, <<"<!DOCTYPE">>, <<"<?">>, <<"?>">>, <<"</">>, <<"/>">>,
               <<"'">>, <<"\"">>, <<"=">>, <<":">>, <<"xmlns:p='u'">>, <<"\r">>,
               <<16#C3>>, <<16#EF, 16#BF, 16#BF>>, <<16#F4, 16#90, 16#80, 16#80>>, <<0>>,
               <<"&#0;">>, <<"&#x110000;">>, <<"&amp;">>, <<"&e;">>])}.

mutate(Doc, []) ->
    Doc;
mutate(<<>>, [{_, _, Byte, Token} | T]) ->
    mutate(<<Byte, Token/binary>>, T);
mutate(Doc, [{Op, Pos0, Byte, Token} | T]) ->
    Pos = Pos0 rem byte_size(Doc),
    <<Before:Pos/binary, At, After/binary>> = Doc,
    Mutated = case Op of
                  flip -> <<Before/binary, (At bxor (1 bsl (Byte rem 8))), After/binary>>;
                  insert -> <<Before/binary, Byte, At, After/binary>>;
                  delete -> <<Before/binary, After/binary>>;
                  insert_token -> <<Before/binary, Token/binary, At, After/binary>>
              end,
    mutate(Mutated, T).

random_input() ->
    oneof([binary(),
           ?LET(Parts, list(elements([<<"<">>, <<">">>, <<"/">>, <<"a">>, <<"b:c">>, <<" ">>,
                                      <<"=">>, <<"'">>, <<"\"">>, <<"&">>, <<";">>, <<"#">>,
                                      <<"x">>, <<"!">>, <<"?">>, <<"-">>, <<"[">>, <<"]">>,
                                      <<"CDATA">>, <<"DOCTYPE">>, <<"xml">>, <<"xmlns">>,
                                      <<"\r\n">>, <<16#E9>>, <<16#C3, 16#A9>>, <<0>>,
                                      <<"1">>])),
                iolist_to_binary(Parts))]).

%% ---------------------------------------------------------------------------
%% Atoms
%% ---------------------------------------------------------------------------

%% Parsing 100,000 documents with distinct names creates no atom.
atoms_not_created(_Config) ->
    {ok, _} = bil_xml:parse(atom_doc(0), ?LIMITS),
    {error, _} = bil_xml:parse(atom_bad_doc(0), ?LIMITS),
    Before = erlang:system_info(atom_count),
    ok = parse_atom_docs(1, 100000),
    After = erlang:system_info(atom_count),
    ct:log("atom_count before ~b, after ~b", [Before, After]),
    Before = After.

parse_atom_docs(N, Max) when N > Max ->
    ok;
parse_atom_docs(N, Max) when N rem 4 =:= 0 ->
    {error, _} = bil_xml:parse(atom_bad_doc(N), ?LIMITS),
    parse_atom_docs(N + 1, Max);
parse_atom_docs(N, Max) ->
    {ok, _} = bil_xml:parse(atom_doc(N), ?LIMITS),
    parse_atom_docs(N + 1, Max).

atom_doc(N) ->
    I = integer_to_binary(N),
    <<"<e", I/binary, " xmlns:p", I/binary, "='urn:", I/binary, "' a", I/binary, "='v' p", I/binary,
      ":b", I/binary, "='w'><p", I/binary, ":f", I/binary, ">t</p", I/binary, ":f", I/binary,
      "></e", I/binary, ">">>.

%% Errors quote names back in their messages: still no atoms.
atom_bad_doc(N) ->
    I = integer_to_binary(N),
    case N rem 3 of
        0 -> <<"<e", I/binary, ">&ent", I/binary, ";</e", I/binary, ">">>;
        1 -> <<"<q", I/binary, ":e/>">>;
        2 -> <<"<e", I/binary, "></f", I/binary, ">">>
    end.

%% ---------------------------------------------------------------------------
%% Attacks
%% ---------------------------------------------------------------------------

%% The classic ten-level "billion laughs" document is refused before any expansion.
billion_laughs(_Config) ->
    Entities = [io_lib:format("  <!ENTITY lol~b \"~s\">~n",
                              [I, lists:append(lists:duplicate(10, io_lib:format("&lol~b;",
                                                                                 [I - 1])))])
                || I <- lists:seq(1, 9)],
    Doc = iolist_to_binary(["<?xml version=\"1.0\"?>\n<!DOCTYPE lolz [\n",
                            "  <!ENTITY lol \"lol\">\n  <!ELEMENT lolz (#PCDATA)>\n",
                            Entities, "]>\n<lolz>&lol9;</lolz>\n"]),
    {error, #{code := doctype_refused, line := 2, column := 1}} =
        in_small_heap(fun() -> bil_xml:parse(Doc, ?LIMITS) end).

%% One big entity referenced many times (quadratic blowup) is refused.
quadratic_blowup(_Config) ->
    Big = binary:copy(<<"a">>, 50000),
    Refs = binary:copy(<<"&a;">>, 20000),
    Doc = <<"<?xml version=\"1.0\"?><!DOCTYPE kaboom [<!ENTITY a \"", Big/binary,
            "\">]><kaboom>", Refs/binary, "</kaboom>">>,
    {error, #{code := doctype_refused, line := 1, column := 22}} =
        in_small_heap(fun() -> bil_xml:parse(Doc, ?LIMITS) end).

%% An external entity (XXE) is refused, and so is referencing it without a DTD.
external_entity(_Config) ->
    Doc = <<"<?xml version=\"1.0\"?>\n<!DOCTYPE foo [ <!ELEMENT foo ANY >\n"
            "<!ENTITY xxe SYSTEM \"file:///etc/passwd\" >]>\n<foo>&xxe;</foo>">>,
    {error, #{code := doctype_refused}} = in_small_heap(fun() -> bil_xml:parse(Doc, ?LIMITS) end),
    Public = <<"<!DOCTYPE foo PUBLIC \"-//X//Y\" \"http://127.0.0.1:1/x.dtd\"><foo/>">>,
    {error, #{code := doctype_refused}} = bil_xml:parse(Public, ?LIMITS),
    {error, #{code := entity_refused, line := 1, column := 6}} =
        bil_xml:parse(<<"<foo>&xxe;</foo>">>, ?LIMITS).

%% Parameter entities, internal or external, are refused.
parameter_entities(_Config) ->
    Docs = [<<"<!DOCTYPE foo [<!ENTITY % pe SYSTEM \"http://127.0.0.1:1/evil.dtd\"> %pe;]><foo/>">>,
            <<"<!DOCTYPE foo [<!ENTITY % a \"<!ENTITY b 'x'>\"> %a;]><foo>&b;</foo>">>,
            <<"<?xml version=\"1.0\"?><!-- c --><!DOCTYPE foo SYSTEM \"file:///etc/passwd\"><foo/>">>],
    [{error, #{code := doctype_refused}} = in_small_heap(fun() -> bil_xml:parse(Doc, ?LIMITS) end)
     || Doc <- Docs],
    ok.

%% Runs Fun in a process whose heap may not pass about 4 MB: an attack that
%% made the parser expand or build anything big would kill it.
in_small_heap(Fun) ->
    Parent = self(),
    {Pid, Ref} = spawn_monitor(
                   fun() ->
                           process_flag(max_heap_size, #{size => 500000, kill => true,
                                                         error_logger => false}),
                           Parent ! {self(), Fun()}
                   end),
    receive
        {Pid, Result} ->
            receive {'DOWN', Ref, process, Pid, _} -> Result end;
        {'DOWN', Ref, process, Pid, Reason} ->
            ct:fail({parser_process_died, Reason})
    end.

%% ---------------------------------------------------------------------------
%% Limits
%% ---------------------------------------------------------------------------

%% A document of 1 MiB + 1 byte is refused as too_large before parsing.
too_large(_Config) ->
    Filler = binary:copy(<<"a">>, 1048576 + 1 - byte_size(<<"<a></a>">>)),
    Doc = <<"<a>", Filler/binary, "</a>">>,
    1048577 = byte_size(Doc),
    {error, #{code := too_large, message := Message} = Reason} = bil_xml:parse(Doc, ?LIMITS),
    false = maps:is_key(line, Reason),
    {match, _} = re:run(Message, "1048577.*1048576"),
    %% Exactly at the limit it parses.
    <<_, Exact/binary>> = Filler,
    {ok, _} = bil_xml:parse(<<"<a>", Exact/binary, "</a>">>, ?LIMITS).

%% 100,000 nested elements are refused as too_deep at depth 33.
too_deep(_Config) ->
    Doc = iolist_to_binary([lists:duplicate(100000, "<a>"), lists:duplicate(100000, "</a>")]),
    {error, #{code := too_deep, line := 1, column := 97}} = bil_xml:parse(Doc, ?LIMITS),
    Ok = iolist_to_binary([lists:duplicate(32, "<a>"), lists:duplicate(32, "</a>")]),
    {ok, _} = bil_xml:parse(Ok, ?LIMITS).

%% A million nested elements under a large size limit are refused at depth 33,
%% within a small heap.
million_deep(_Config) ->
    Doc = binary:copy(<<"<a>">>, 1000000),
    {error, #{code := too_deep, column := 97}} =
        in_small_heap(fun() -> bil_xml:parse(Doc, #{max_size => 4000000, max_depth => 32}) end),
    {error, #{code := truncated}} = bil_xml:parse(Doc, #{max_size => 4000000,
                                                          max_depth => 2000000}).

%% An element with 10,000 attributes parses, attributes in document order.
many_attributes(_Config) ->
    Attrs = [[" a", integer_to_list(I), "=\"", integer_to_list(I), "\""]
             || I <- lists:seq(1, 10000)],
    Doc = iolist_to_binary(["<e", Attrs, "/>"]),
    {ok, {{undefined, <<"e">>}, Parsed, []}} = bil_xml:parse(Doc, ?LIMITS),
    10000 = length(Parsed),
    Expected = [{{undefined, <<"a", (integer_to_binary(I))/binary>>}, integer_to_binary(I)}
                || I <- lists:seq(1, 10000)],
    Expected = Parsed,
    %% A duplicate at the very end is still found.
    Dup = iolist_to_binary(["<e", Attrs, " a5000=\"x\"/>"]),
    {error, #{code := malformed}} = bil_xml:parse(Dup, ?LIMITS).

%% A 100,000-character element name parses.
long_name(_Config) ->
    Name = binary:copy(<<"n">>, 100000),
    Doc = <<"<p:", Name/binary, " xmlns:p='urn:a'>x</p:", Name/binary, ">">>,
    {ok, {{<<"urn:a">>, Name}, [], [<<"x">>]}} = bil_xml:parse(Doc, ?LIMITS).

%% A 60 KiB text node with references and line ends parses to one binary.
big_text(_Config) ->
    Chunk = <<"abc &amp; &#x4E2D; é\r\n"/utf8>>,
    Decoded = <<"abc & 中 é\n"/utf8>>,
    N = 61440 div byte_size(Chunk),
    Doc = <<"<t>", (binary:copy(Chunk, N))/binary, "</t>">>,
    Expected = binary:copy(Decoded, N),
    {ok, {{undefined, <<"t">>}, [], [Expected]}} = bil_xml:parse(Doc, ?LIMITS).

%% ---------------------------------------------------------------------------
%% Generators: well-formed documents
%% ---------------------------------------------------------------------------

%% Abstract trees are generated first and serialised afterwards, so that
%% the serialiser can add the namespace declarations that prefixes need and
%% drop attributes that would clash.

document() ->
    ?LET({Bom, Decl, Before, Root, After},
         {bool(), xml_decl(), resize(3, list(misc())), ?SIZED(S, elem(min(S, 40))),
          resize(3, list(misc()))},
         iolist_to_binary([case Bom of true -> <<16#EF, 16#BB, 16#BF>>; false -> [] end,
                           Decl, Before, serialise(Root, #{}), After])).

xml_decl() ->
    elements([<<>>, <<"<?xml version=\"1.0\"?>">>,
              <<"<?xml version=\"1.0\" encoding=\"UTF-8\"?>">>,
              <<"<?xml version='1.0' encoding='utf-8' standalone='yes'?>\r\n">>,
              <<"<?xml  version = \"1.0\"\n encoding=\"Utf-8\" ?>\n">>]).

misc() ->
    oneof([ws(), comment(), pi()]).

ws() ->
    elements([<<" ">>, <<"\n">>, <<"\r\n">>, <<"\t">>, <<"\n    ">>, <<"\r\n  ">>, <<"\r">>]).

ws0() ->
    oneof([<<>>, ws()]).

comment() ->
    ?LET(Chars, resize(8, list(comment_char())),
         ["<!--", fix_comment(Chars), "-->"]).

comment_char() ->
    oneof([raw_char(), $-]).

%% No "--" and no trailing '-' in a comment.
fix_comment(Chars) ->
    Fixed = fix_dashes(Chars),
    unicode:characters_to_binary(case lists:reverse(Fixed) of
                                     [$- | _] -> Fixed ++ " ";
                                     _ -> Fixed
                                 end).

fix_dashes([$-, $- | T]) -> [$-, $\s | fix_dashes([$- | T])];
fix_dashes([C | T]) -> [C | fix_dashes(T)];
fix_dashes([]) -> [].

%% Always with a space after the target, which never starts with "xml":
%% xmerl_sax_parser refuses "<?target?>" and "<?xml-stylesheet ?>", which are
%% well-formed (the EUnit tests cover those forms).
pi() ->
    ?LET({Target, Chars}, {elements(["pi", "tgt", "x", "a-b.c", [16#E9]]),
                           resize(6, list(oneof([raw_char(), $?])))},
         ["<?", unicode:characters_to_binary(Target), " ",
          unicode:characters_to_binary(fix_pi(Chars)), "?>"]).

fix_pi([$?, $> | T]) -> [$?, $\s | fix_pi([$> | T])];
fix_pi([$?]) -> [$?, $\s];
fix_pi([C | T]) -> [C | fix_pi(T)];
fix_pi([]) -> [].

%% {elem, Name, Decls, Attrs, Content, EndWs, SelfClose}
elem(Size) ->
    ?LET({Name, Decls, Attrs, Content, EndWs, SelfClose},
         {qname(), resize(2, list(decl())), resize(4, list(attr())), content(Size), ws0(),
          bool()},
         {elem, Name, Decls, Attrs, Content, EndWs, SelfClose}).

content(Size) when Size < 4 ->
    resize(3, list(leaf_item()));
content(Size) ->
    ?LET(N, choose(0, 5),
         vector(N, frequency([{4, ?LAZY(elem(Size div (N + 1)))}, {4, leaf_item()}]))).

leaf_item() ->
    frequency([{5, text()}, {3, ws()}, {1, cdata()}, {1, comment()}, {1, pi()}]).

qname() ->
    {elements([none, none, <<"p">>, <<"q">>, <<"bil">>, <<"n-s.1">>]), local_name()}.

attr() ->
    {elements([none, none, none, <<"p">>, <<"q">>, <<"xml">>]), local_name(),
     resize(6, list(text_char())), elements([$", $']), ws(), ws0(), ws0(), int()}.

decl() ->
    {elements([default, <<"p">>, <<"q">>, <<"r">>]), elements([<<>> | ?NAMESPACES]),
     elements([$", $']), int()}.

local_name() ->
    ?LET({First, Rest}, {elements("abcxyzABZ_" ++ [16#E9, 16#3C9, 16#4E2D]),
                         resize(5, list(elements("abz09-._" ++ [16#E9, 16#B7])))},
         unicode:characters_to_binary([First | Rest])).

text() ->
    ?LET(Chars, resize(10, non_empty(list(text_char()))), {text, Chars}).

cdata() ->
    ?LET(Chars, resize(8, list(oneof([raw_char(), $]]))),
         {cdata, unicode:characters_to_binary(fix_cdata(Chars))}).

fix_cdata([$], $], $> | T]) -> [$], $], $\s | fix_cdata([$> | T])];
fix_cdata([C | T]) -> [C | fix_cdata(T)];
fix_cdata([]) -> [].

%% {Char, Style}: how the character is written is chosen with it.
text_char() ->
    {frequency([{10, elements("abcXYZ019 .;#-_")}, {3, elements("<>&\"'")},
                {3, elements("\t\n\r")}, {1, $]},
                {2, elements([16#E9, 16#3C9, 16#4E2D, 16#1F600, 16#FFFD, 16#7F])}]),
     elements([literal, literal, literal, dec, hex, entity])}.

raw_char() ->
    ?LET({C, _Style}, text_char(), C).

serialise_chars(Chars, Context) ->
    serialise_chars(Chars, Context, none, []).

serialise_chars([], _Context, _Prev, Acc) ->
    unicode:characters_to_binary(lists:reverse(Acc));
serialise_chars([{C, Style} | T], Context, Prev, Acc) ->
    Out = case must_escape(C, Context, Prev) orelse Style =/= literal of
              false -> [C];
              true -> char_ref(C, Style)
          end,
    serialise_chars(T, Context, C, [Out | Acc]);
serialise_chars([C | T], Context, Prev, Acc) when is_integer(C) ->
    serialise_chars([{C, literal} | T], Context, Prev, Acc).

must_escape($<, _, _) -> true;
must_escape($&, _, _) -> true;
must_escape($>, text, $]) -> true;
must_escape(Q, {attr, Q}, _) -> true;
must_escape(_, _, _) -> false.

char_ref($<, entity) -> "&lt;";
char_ref($>, entity) -> "&gt;";
char_ref($&, entity) -> "&amp;";
char_ref($", entity) -> "&quot;";
char_ref($', entity) -> "&apos;";
char_ref(C, hex) -> io_lib:format("&#x~.16b;", [C]);
char_ref(C, _) -> io_lib:format("&#~b;", [C]).

%% Scope maps a prefix (or default) to a namespace.
serialise({elem, {Prefix, Local}, Decls0, Attrs0, Content, EndWs, SelfClose}, Scope0) ->
    Decls1 = dedupe([{P, Uri, Q, Key} || {P, Uri, Q, Key} <- Decls0,
                     not (P =/= default andalso Uri =:= <<>>)]),
    Declared = maps:from_list([{P, Uri} || {P, Uri, _, _} <- Decls1]),
    Scope1 = maps:merge(Scope0, Declared),
    Needed = lists:usort([P || P <- [Prefix | [AP || {AP, _, _, _, _, _, _, _} <- Attrs0]],
                               P =/= none, P =/= <<"xml">>,
                               not maps:is_key(P, Scope1)]),
    Auto = [{P, <<"urn:auto:", P/binary>>, $", -1} || P <- Needed],
    Scope = maps:merge(Scope1, maps:from_list([{P, U} || {P, U, _, _} <- Auto])),
    Attrs = unique_attrs(Attrs0, Scope, #{}),
    QName = qname_bin(Prefix, Local),
    DeclItems = [{Key, [ws_pick(Key), decl_name(P), "=", Q, escape_uri(Uri, Q), Q]}
                 || {P, Uri, Q, Key} <- Auto ++ Decls1],
    AttrItems = [{Key, [Ws, qname_bin(AP, AL), Ws1, "=", Ws2, Q,
                        serialise_chars(Chars, {attr, Q}), Q]}
                 || {AP, AL, Chars, Q, Ws, Ws1, Ws2, Key} <- Attrs],
    Items = [Item || {_, Item} <- lists:keysort(1, DeclItems ++ AttrItems)],
    case {Content, SelfClose} of
        {[], true} ->
            ["<", QName, Items, EndWs, "/>"];
        _ ->
            ["<", QName, Items, EndWs, ">",
             [serialise_item(I, Scope) || I <- Content],
             "</", QName, EndWs, ">"]
    end.

serialise_item({text, Chars}, _Scope) -> serialise_chars(Chars, text);
serialise_item({cdata, Bin}, _Scope) -> ["<![CDATA[", Bin, "]]>"];
serialise_item({elem, _, _, _, _, _, _} = E, Scope) -> serialise(E, Scope);
serialise_item(Other, _Scope) -> Other.

dedupe(Decls) ->
    dedupe(Decls, #{}).

dedupe([], _Seen) -> [];
dedupe([{P, _, _, _} = D | T], Seen) ->
    case Seen of
        #{P := _} -> dedupe(T, Seen);
        _ -> [D | dedupe(T, Seen#{P => true})]
    end.

%% Drops attributes whose resolved name was already used.
unique_attrs([], _Scope, _Seen) ->
    [];
unique_attrs([{P, L, _, _, _, _, _, _} = A | T], Scope, Seen) ->
    Name = case P of
               none -> {undefined, L};
               <<"xml">> -> {xml, L};
               _ -> {maps:get(P, Scope), L}
           end,
    case Seen of
        #{Name := _} -> unique_attrs(T, Scope, Seen);
        _ -> [A | unique_attrs(T, Scope, Seen#{Name => true})]
    end.

ws_pick(Key) ->
    lists:nth(1 + abs(Key) rem 4, [<<" ">>, <<"\n  ">>, <<"\r\n\t">>, <<"  ">>]).

decl_name(default) -> "xmlns";
decl_name(P) -> ["xmlns:", P].

escape_uri(Uri, Q) ->
    serialise_chars([{C, literal} || C <- binary_to_list(Uri)], {attr, Q}).

qname_bin(none, Local) -> Local;
qname_bin(Prefix, Local) -> [Prefix, ":", Local].

%% ---------------------------------------------------------------------------
%% Generators: BIL-shaped documents
%% ---------------------------------------------------------------------------

signal_like() ->
    ?LET({Nl, Indent, Fields, Params, Prefix},
         {elements(["\n", "\r\n", ""]), elements(["", "  ", "\t"]),
          resize(8, list({field_name(), resize(12, list(text_char()))})),
          resize(4, list({field_name(), resize(8, list(text_char()))})),
          elements([<<"bil">>, <<"b">>, <<"evatar-bil">>])},
         begin
             Field = fun(Level, {Name, Chars}) ->
                             [Nl, lists:duplicate(Level, Indent), "<", Name, ">",
                              serialise_chars(Chars, text), "</", Name, ">"]
                     end,
             iolist_to_binary(
               ["<?xml version=\"1.0\" encoding=\"UTF-8\"?>", Nl,
                "<", Prefix, ":Envelope xmlns:", Prefix, "=\"urn:evatar:bil:1\">",
                Nl, Indent, "<", Prefix, ":Header>", [Field(2, F) || F <- Fields],
                Nl, Indent, "</", Prefix, ":Header>",
                Nl, Indent, "<", Prefix, ":Body>",
                Nl, Indent, Indent, "<ServiceParameters>", [Field(3, P) || P <- Params],
                Nl, Indent, Indent, "</ServiceParameters>",
                Nl, Indent, "</", Prefix, ":Body>", Nl,
                "</", Prefix, ":Envelope>", Nl])
         end).

field_name() ->
    elements([<<"SignalID">>, <<"Context">>, <<"Sender">>, <<"Receiver">>, <<"Timestamp">>,
              <<"Light">>, <<"Room">>, <<"Température"/utf8>>]).

signal_example() ->
    <<"<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
      "<bil:Envelope xmlns:bil=\"urn:evatar:bil:1\">\n"
      "  <bil:Header>\n"
      "    <SignalID>va1-000042</SignalID>\n"
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
      "    </ServiceParameters>\n"
      "  </bil:Body>\n"
      "</bil:Envelope>\n">>.

description_example() ->
    <<"<?xml version=\"1.0\" encoding=\"UTF-8\"?>\r\n"
      "<bil:description xmlns:bil=\"urn:evatar:bil:1\">\r\n"
      "  <bil:context>\r\n"
      "    <EntityID>7008</EntityID>\r\n"
      "    <APIName>LIGHT ACTUATOR</APIName>\r\n"
      "    <EntityType>Avatar</EntityType>\r\n"
      "    <Context>ActuatorDescription</Context>\r\n"
      "  </bil:context>\r\n"
      "  <bil:types>\r\n"
      "    <bil:Component>\r\n"
      "      <ComponentID>HomeLightActuator01</ComponentID>\r\n"
      "      <Service>\r\n"
      "        <ServiceCategory>ACTUATOR</ServiceCategory>\r\n"
      "        <ServiceType>TurnLightOn</ServiceType>\r\n"
      "        <ServiceParameters><Light>yes</Light><Email>no</Email></ServiceParameters>\r\n"
      "      </Service>\r\n"
      "    </bil:Component>\r\n"
      "  </bil:types>\r\n"
      "</bil:description>\r\n">>.

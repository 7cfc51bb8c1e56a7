%% @doc PropEr properties of the wire protocol's codecs: every control
%% document (Hello, Resume, Welcome with and without its version 2 fields,
%% Refused, Binding, Ack, Bye; docs/protocol.md section
%% 2) survives encode then parse, frames of any kind reach the right parser,
%% and mutated, truncated or random bytes never make bil_control:parse_frame/2
%% or the frame layer (agent_bridge_frame) raise: they answer with a result of
%% the documented shape, and whatever they accept is a valid term that round
%% trips.
-module(bil_control_SUITE).

%% The PropEr runner the suites share (apps/evatar_test_kit).
-import(evatar_test_proper, [check/2]).

-include_lib("common_test/include/ct.hrl").
-include_lib("proper/include/proper.hrl").

-export([all/0, groups/0, suite/0]).
-export([round_trip_control/1, round_trip_frame/1, fuzz_control_mutated/1,
         fuzz_frame_mutated/1, fuzz_frame_random/1, frame_stream_round_trip/1,
         frame_decode_fuzz/1, connection_pipeline_fuzz/1]).

-define(NUMTESTS_ROUND_TRIP, 1000).
-define(NUMTESTS_FUZZ, 2000).

%% The codes of bil:error_code(); a parser answering anything else is wrong.
-define(ERROR_CODES, [too_large, not_binary, doctype_refused, entity_refused, too_deep,
                      truncated, malformed, bad_encoding, wrong_namespace, wrong_root,
                      missing_element, unexpected_element, duplicate_element, bad_value,
                      duplicate_component]).

%% Markup that, dropped into a document, breaks it in interesting ways.
-define(FRAGMENTS, [<<"<">>, <<">">>, <<"&">>, <<"&amp;">>, <<"&lol;">>, <<"&#0;">>,
                    <<"&#x110000;">>, <<"]]>">>, <<"<![CDATA[x]]>">>, <<"<!--">>, <<"-->">>,
                    <<"<!DOCTYPE x [<!ENTITY a \"b\">]>">>, <<"<?pi x?>">>, <<"</">>,
                    <<"<bil:Hello xmlns:bil=\"urn:evatar:bil:1\">">>, <<"</bil:Hello>">>,
                    <<"<Pairing>">>, <<"</Pairing>">>, <<"<Bound>">>, <<"<Unbound>">>,
                    <<"<Accepted>">>, <<"<Received>7</Received>">>, <<"<Epoch>">>,
                    <<"<Resumed>true</Resumed>">>,
                    <<"xmlns=\"urn:evatar:bil:1\"">>, <<"xmlns:bil=\"urn:other\"">>,
                    <<"\"">>, <<"'">>, <<" a=\"1\"">>, <<16#C3>>, <<16#FF, 16#FE>>,
                    <<0>>, <<"\r\n">>, <<"99999999999999999999999">>, <<"-1">>]).

suite() ->
    [{timetrap, {minutes, 5}}].

all() ->
    [{group, round_trip}, {group, fuzz}, {group, frames}].

groups() ->
    [{round_trip, [parallel], [round_trip_control, round_trip_frame]},
     {fuzz, [parallel], [fuzz_control_mutated, fuzz_frame_mutated, fuzz_frame_random]},
     {frames, [parallel],
      [frame_stream_round_trip, frame_decode_fuzz, connection_pipeline_fuzz]}].

%% ---------------------------------------------------------------------------
%% Round trips
%% ---------------------------------------------------------------------------

%% @doc Every valid control document survives encode then parse unchanged.
round_trip_control(_Config) ->
    check(?FORALL(C, control(),
                  same(C, bil_control:parse(iolist_to_binary(bil_control:encode(C)), #{}))),
          ?NUMTESTS_ROUND_TRIP).

%% @doc parse_frame/2 hands every kind of document (control, signal,
%% description) to its own parser and tags the result with the kind.
round_trip_frame(_Config) ->
    check(?FORALL({Kind, Term} = Frame, frame(),
                  same(Frame, bil_control:parse_frame(encode(Kind, Term), #{}))),
          ?NUMTESTS_ROUND_TRIP).

%% ---------------------------------------------------------------------------
%% Fuzz: bil_control
%% ---------------------------------------------------------------------------

%% @doc Mutated control documents: bil_control:parse/2 answers `{ok, _}' or
%% an error reason of the documented shape, and anything it accepts round trips.
fuzz_control_mutated(_Config) ->
    check(?FORALL({C, Mutations, Limits}, {control(), mutations(), limits()},
                  begin
                      Bin = mutate(iolist_to_binary(bil_control:encode(C)), Mutations),
                      ?WHENFAIL(ct:pal("input: ~p", [Bin]),
                                control_result_ok(
                                  safe(fun() ->
                                               bil_control:parse(Bin, maps:get(control, Limits,
                                                                               #{}))
                                       end)))
                  end),
          ?NUMTESTS_FUZZ).

%% @doc Mutated and truncated frames of every kind: parse_frame/2 never
%% raises, answers `{ok, _}' or `{error, #{code, message}}', and what it
%% accepts is a valid term that round trips.
fuzz_frame_mutated(_Config) ->
    check(?FORALL({{Kind, Term}, Mutations, Limits}, {frame(), mutations(), limits()},
                  begin
                      Bin = mutate(encode(Kind, Term), Mutations),
                      ?WHENFAIL(ct:pal("input: ~p", [Bin]), parse_frame_ok(Bin, Limits))
                  end),
          ?NUMTESTS_FUZZ).

%% @doc Random bytes, alone or after a plausible start of a document, never
%% make parse_frame/2 raise.
fuzz_frame_random(_Config) ->
    check(?FORALL({Bin, Limits}, {random_document(), limits()},
                  ?WHENFAIL(ct:pal("input: ~p", [Bin]), parse_frame_ok(Bin, Limits))),
          ?NUMTESTS_FUZZ).

%% ---------------------------------------------------------------------------
%% Frames: agent_bridge_frame
%% ---------------------------------------------------------------------------

%% @doc Frames written one after another and read back from a stream cut
%% into arbitrary chunks give the same documents, in order, and nothing else.
frame_stream_round_trip(_Config) ->
    check(?FORALL({Docs, Cuts}, {list(non_empty(binary())), list(range(0, 64))},
                  begin
                      Stream = iolist_to_binary([agent_bridge_frame:encode(D) || D <- Docs]),
                      Max = lists:max([1 | [byte_size(D) || D <- Docs]]),
                      Docs =:= read_stream(chunks(Stream, Cuts), <<>>, Max, [])
                  end),
          ?NUMTESTS_FUZZ).

%% @doc agent_bridge_frame:decode/2 on any bytes never raises, and each of
%% its answers is the right one for the length prefix it saw.
frame_decode_fuzz(_Config) ->
    check(?FORALL({Bin, Max}, {stream_bytes(), max_frame()},
                  ?WHENFAIL(ct:pal("input: ~p, max ~b", [Bin, Max]), decode_ok(Bin, Max))),
          ?NUMTESTS_FUZZ).

%% @doc What a connection does with an untrusted byte stream: split frames,
%% check each, parse it, and turn every error into a Refused document. No
%% step raises, and every Refused encodes and parses back.
connection_pipeline_fuzz(_Config) ->
    check(?FORALL({Stream, Max, Limits}, {byte_stream(), max_frame(), limits()},
                  ?WHENFAIL(ct:pal("stream: ~p, max ~b", [Stream, Max]),
                            pipeline(Stream, Max, Limits))),
          ?NUMTESTS_FUZZ div 2).

%% ---------------------------------------------------------------------------
%% Checks
%% ---------------------------------------------------------------------------

same(Expected, {ok, Expected}) ->
    true;
same(Expected, Got) ->
    ct:pal("expected ~p~ngot ~p", [{ok, Expected}, Got]),
    false.

%% Calls F, turning an exception into a value the checks reject.
safe(F) ->
    try F()
    catch Class:Reason:Stack -> {raised, Class, Reason, Stack}
    end.

parse_frame_ok(Bin, Limits) ->
    case safe(fun() -> bil_control:parse_frame(Bin, Limits) end) of
        {ok, {control, C}} -> control_result_ok({ok, C});
        {ok, {signal, S}} -> same(S, bil:parse_signal(iolist_to_binary(bil:encode_signal(S))));
        {ok, {description, D}} ->
            same(D, bil:parse_description(iolist_to_binary(bil:encode_description(D))));
        Other -> error_ok(Other)
    end.

%% An accepted control document is a valid term: it encodes, and parses back
%% to itself.
control_result_ok({ok, C}) ->
    case safe(fun() -> bil_control:parse(iolist_to_binary(bil_control:encode(C)), #{}) end) of
        {ok, C} -> true;
        Other -> ct:pal("accepted ~p~nbut its encoding parses as ~p", [C, Other]), false
    end;
control_result_ok(Other) ->
    error_ok(Other).

error_ok({error, #{code := Code, message := Message} = Reason})
  when is_atom(Code), is_binary(Message) ->
    lists:member(Code, ?ERROR_CODES) andalso is_binary(bil:format_error(Reason))
        orelse begin ct:pal("bad error reason ~p", [Reason]), false end;
error_ok(Other) ->
    ct:pal("not {ok, _} nor an error reason: ~p", [Other]),
    false.

decode_ok(Bin, Max) ->
    case safe(fun() -> agent_bridge_frame:decode(Bin, Max) end) of
        {ok, Doc, Tail} ->
            Len = byte_size(Doc),
            Len >= 1 andalso Len =< Max andalso Bin =:= <<Len:32, Doc/binary, Tail/binary>>;
        {more, N} when is_integer(N), N > 0 ->
            case Bin of
                <<Len:32, Body/binary>> ->
                    Len >= 1 andalso Len =< Max andalso N =:= Len - byte_size(Body);
                _ ->
                    N =:= 4 - byte_size(Bin)
            end;
        {error, empty_frame} ->
            match =:= case Bin of <<0:32, _/binary>> -> match; _ -> nomatch end;
        {error, {too_large, Len}} ->
            Len > Max andalso match =:= case Bin of <<Len:32, _/binary>> -> match;
                                                     _ -> nomatch
                                        end;
        Other ->
            ct:pal("decode/2 answered ~p", [Other]),
            false
    end.

%% Reads frames as agent_bridge_conn does, until the stream ends or breaks.
pipeline(Stream, Max, Limits) ->
    case safe(fun() -> agent_bridge_frame:decode(Stream, Max) end) of
        {ok, Doc, Tail} ->
            ok = agent_bridge_frame:check(Doc, Max),
            case safe(fun() -> bil_control:parse_frame(Doc, Limits) end) of
                {ok, _} ->
                    pipeline(Tail, Max, Limits);
                {error, Reason} = Error ->
                    error_ok(Error) andalso refusal_ok({malformed, Reason})
                        andalso pipeline(Tail, Max, Limits);
                Other ->
                    error_ok(Other)
            end;
        {more, N} when is_integer(N), N > 0 ->
            true;
        {error, Why} ->
            decode_ok(Stream, Max) andalso refusal_ok(Why);
        Other ->
            ct:pal("decode/2 answered ~p", [Other]),
            false
    end.

refusal_ok(Why) ->
    case safe(fun() -> agent_bridge_frame:refusal(Why) end) of
        {refused, #{code := Code, message := Message}} = Refused
          when is_binary(Code), is_binary(Message) ->
            {ok, {control, Refused}} =:=
                bil_control:parse_frame(iolist_to_binary(bil_control:encode(Refused)), #{});
        Other ->
            ct:pal("refusal(~p) answered ~p", [Why, Other]),
            false
    end.

read_stream([Chunk | Rest], Buffer, Max, Acc) ->
    split(<<Buffer/binary, Chunk/binary>>, Rest, Max, Acc);
read_stream([], <<>>, _Max, Acc) ->
    lists:reverse(Acc);
read_stream([], Leftover, _Max, _Acc) ->
    {leftover, Leftover}.

split(Buffer, Rest, Max, Acc) ->
    case agent_bridge_frame:decode(Buffer, Max) of
        {ok, Doc, Tail} -> split(Tail, Rest, Max, [Doc | Acc]);
        {more, _} -> read_stream(Rest, Buffer, Max, Acc);
        {error, _} = Error -> Error
    end.

%% Cuts a binary into pieces of the given sizes (the last piece takes what
%% is left).
chunks(Bin, [Size | Sizes]) when byte_size(Bin) > Size ->
    <<Chunk:Size/binary, Rest/binary>> = Bin,
    [Chunk | chunks(Rest, Sizes)];
chunks(Bin, _) ->
    [Bin].

encode(control, C) -> iolist_to_binary(bil_control:encode(C));
encode(signal, S) -> iolist_to_binary(bil:encode_signal(S));
encode(description, D) -> iolist_to_binary(bil:encode_description(D)).

%% ---------------------------------------------------------------------------
%% Generators
%% ---------------------------------------------------------------------------

control() ->
    oneof([hello(), welcome(), refused(), binding(), bye(), resume(), ack()]).

hello() ->
    ?LET({Pairing, Role, Entity, Credential, Version},
         {bil_gen:nonempty_text(), oneof([agent, avatar]), bil_gen:nonempty_text(),
          bil_gen:text(), frequency([{4, 1}, {1, bil_gen:decimal()}])},
         {hello, #{pairing => Pairing, role => Role, entity_id => Entity,
                   credential => Credential, protocol_version => Version}}).

welcome() ->
    ?LET({Pairing, Entity, Session, JoinTimeout, MaxFrame, Ha},
         {bil_gen:nonempty_text(), bil_gen:nonempty_text(), bil_gen:nonempty_text(),
          bil_gen:decimal(), bil_gen:decimal(), oneof([none, welcome_ha()])},
         begin
             W = #{pairing => Pairing, entity_id => Entity, session_id => Session,
                   join_timeout => JoinTimeout, max_frame => MaxFrame},
             {welcome, case Ha of none -> W; _ -> W#{ha => Ha} end}
         end).

welcome_ha() ->
    ?LET({Epoch, Resumed, Last, Window, Heartbeat},
         {bil_gen:decimal(), boolean(), bil_gen:text(), bil_gen:decimal(), bil_gen:decimal()},
         #{epoch => Epoch, resumed => Resumed, last_accepted => Last, dedup_window => Window,
           heartbeat => Heartbeat}).

resume() ->
    ?LET({{hello, Hello}, Session, Received, Epoch},
         {hello(), bil_gen:nonempty_text(), bil_gen:decimal(), bil_gen:decimal()},
         {resume, Hello#{session_id => Session, received => Received, epoch => Epoch}}).

ack() ->
    ?LET({Accepted, Received},
         {oneof([none, bil_gen:nonempty_text()]), oneof([none, bil_gen:decimal()])},
         {ack, maps:from_list([{accepted, Accepted} || Accepted =/= none] ++
                              [{received, Received} || Received =/= none])}).

refused() ->
    ?LET({Code, Message},
         {oneof([elements([<<"BadCredential">>, <<"UnknownPairing">>, <<"Occupied">>,
                           <<"JoinTimeout">>, <<"PairingDeleted">>, <<"SlowConsumer">>,
                           <<"NotActive">>, <<"Fenced">>, <<"StaleEpoch">>]),
                 bil_gen:nonempty_text()]),
          bil_gen:text()},
         {refused, #{code => Code, message => Message}}).

binding() ->
    ?LET({Entities, Bound, Unbound},
         {list_of(0, 4, bil_gen:nonempty_text()), list_of(0, 4, bound_row()),
          list_of(0, 4, unbound_row())},
         {binding, #{entities => Entities, bound => Bound, unbound => Unbound}}).

bound_row() ->
    ?LET({CE, CC, PE, PC, Cat, Type, Score, Candidates},
         {bil_gen:nonempty_text(), bil_gen:nonempty_text(), bil_gen:nonempty_text(),
          bil_gen:nonempty_text(), bil_gen:nonempty_text(), bil_gen:nonempty_text(),
          bil_gen:decimal(), ?SUCHTHAT(N, bil_gen:decimal(), N > 0)},
         #{consumer => #{entity => CE, component => CC},
           provider => #{entity => PE, component => PC},
           category => Cat, type => Type, score => Score, candidates => Candidates}).

unbound_row() ->
    ?LET({CE, CC, Cat, Type, Reason},
         {bil_gen:nonempty_text(), bil_gen:nonempty_text(), bil_gen:nonempty_text(),
          bil_gen:nonempty_text(), oneof([no_provider, parameters_mismatch])},
         #{consumer => #{entity => CE, component => CC},
           category => Cat, type => Type, reason => Reason}).

bye() ->
    ?LET(Reason, bil_gen:text(), {bye, Reason}).

%% A document of any kind a frame can carry, with its kind.
frame() ->
    frequency([{3, {control, control()}},
               {2, {signal, bil_gen:signal()}},
               {1, {description, bil_gen:description()}}]).

%% The parsers' default limits, or small ones so that the size and depth
%% refusals are reached too.
limits() ->
    frequency([{3, #{}},
               {1, ?LET({Size, Depth}, {range(1, 400), range(1, 6)},
                        #{signal => #{max_size => Size, max_depth => Depth},
                          description => #{max_size => Size, max_depth => Depth},
                          control => #{max_size => Size, max_depth => Depth}})}]).

%% 1 to 4 edits; positions are taken modulo the length when applied. Byte
%% edits mostly break the syntax; leaf edits keep it and break the structure
%% (a field missing, repeated, renamed, or holding a bad value).
mutations() ->
    list_of(1, 4, mutation()).

mutation() ->
    frequency([{2, {truncate, pos()}},
               {2, {flip, pos(), octet()}},
               {2, {delete, pos(), range(1, 40)}},
               {1, {duplicate, pos(), range(1, 40)}},
               {2, {insert, pos(), oneof([elements(?FRAGMENTS), binary()])}},
               {1, {swap, pos(), pos(), range(1, 20)}},
               {6, {leaf, pos(), leaf_edit()}}]).

leaf_edit() ->
    oneof([delete, duplicate, empty,
           {text, oneof([elements([<<"0">>, <<"-1">>, <<"agent">>, <<"Agent">>, <<"x">>,
                                   <<"true">>, <<"false">>,
                                   <<"NoProvider">>, <<"123456789012345678901">>,
                                   <<"<x/>">>, <<" 5">>]),
                         bil_gen:text()])},
           {rename, elements([<<"Pairing">>, <<"Role">>, <<"Code">>, <<"Reason">>,
                              <<"Score">>, <<"EntityID">>, <<"SignalID">>, <<"Context">>,
                              <<"ServiceType">>, <<"x">>, <<"bil:Bye">>, <<"Accepted">>,
                              <<"Received">>, <<"Epoch">>, <<"Resumed">>])}]).

pos() -> range(0, 1 bsl 20).

octet() -> range(0, 255).

random_document() ->
    ?LET({Prefix, Bytes},
         {elements([<<>>, <<"<">>, <<"<?xml version=\"1.0\"?>">>, <<16#EF, 16#BB, 16#BF>>,
                    <<"<bil:Envelope xmlns:bil=\"urn:evatar:bil:1\">">>,
                    <<"<bil:description xmlns:bil=\"urn:evatar:bil:1\">">>,
                    <<"<bil:Binding xmlns:bil=\"urn:evatar:bil:1\"><Entities>">>,
                    <<"<bil:Hello xmlns:bil=\"urn:evatar:bil:1\"><Pairing>">>,
                    <<"<bil:Ack xmlns:bil=\"urn:evatar:bil:1\">">>,
                    <<"<bil:Resume xmlns:bil=\"urn:evatar:bil:1\"><Pairing>">>,
                    <<"<!-- x --><x:Bye xmlns:x=\"urn:evatar:bil:1\"">>]),
          oneof([binary(), ?LET(Parts, list(elements(?FRAGMENTS)), iolist_to_binary(Parts))])},
         <<Prefix/binary, Bytes/binary>>).

%% Bytes for decode/2: random, or starting with a length prefix that is
%% zero, small, near the limit or huge.
stream_bytes() ->
    oneof([binary(),
           ?LET({Len, Body}, {length_prefix(), binary()}, <<Len:32, Body/binary>>)]).

length_prefix() ->
    oneof([0, range(1, 64), range(65, 70000), range(16#7FFFFFF0, 16#FFFFFFFF)]).

max_frame() ->
    oneof([range(1, 64), 65536, 1048576]).

%% What a hostile or broken client may send: valid frames holding valid or
%% mutated documents, frames with lying lengths, and raw garbage.
byte_stream() ->
    ?LET(Pieces, list_of(1, 5, stream_piece()), iolist_to_binary(Pieces)).

stream_piece() ->
    frequency([{4, ?LET({{Kind, Term}, Mutations}, {frame(), list_of(0, 2, mutation())},
                        agent_bridge_frame:encode(mutate(encode(Kind, Term), Mutations)))},
               {1, ?LET({Len, Body}, {length_prefix(), binary()}, <<Len:32, Body/binary>>)},
               {1, random_document()}]).

list_of(Min, Max, Type) ->
    ?LET(N, range(Min, Max), vector(N, Type)).

%% ---------------------------------------------------------------------------
%% Mutations
%% ---------------------------------------------------------------------------

mutate(Bin, Mutations) ->
    lists:foldl(fun apply_mutation/2, Bin, Mutations).

apply_mutation(_, <<>>) ->
    <<>>;
apply_mutation({truncate, P}, Bin) ->
    binary:part(Bin, 0, P rem byte_size(Bin));
apply_mutation({flip, P, Byte}, Bin) ->
    At = P rem byte_size(Bin),
    <<Before:At/binary, _, After/binary>> = Bin,
    <<Before/binary, Byte, After/binary>>;
apply_mutation({delete, P, Len}, Bin) ->
    At = P rem byte_size(Bin),
    N = min(Len, byte_size(Bin) - At),
    <<Before:At/binary, _:N/binary, After/binary>> = Bin,
    <<Before/binary, After/binary>>;
apply_mutation({duplicate, P, Len}, Bin) ->
    At = P rem byte_size(Bin),
    N = min(Len, byte_size(Bin) - At),
    <<Before:At/binary, Part:N/binary, After/binary>> = Bin,
    <<Before/binary, Part/binary, Part/binary, After/binary>>;
apply_mutation({insert, P, Bytes}, Bin) ->
    At = P rem (byte_size(Bin) + 1),
    <<Before:At/binary, After/binary>> = Bin,
    <<Before/binary, Bytes/binary, After/binary>>;
apply_mutation({leaf, P, Edit}, Bin) ->
    %% A leaf element: a name, text without markup, the same name closed.
    case re:run(Bin, <<"<([A-Za-z][A-Za-z0-9:]*)>[^<]*</\\1>">>, [global, {capture, first}]) of
        {match, Leaves} ->
            [{At, Len}] = lists:nth(P rem length(Leaves) + 1, Leaves),
            <<Before:At/binary, Leaf:Len/binary, After/binary>> = Bin,
            <<Before/binary, (edit_leaf(Edit, Leaf))/binary, After/binary>>;
        nomatch ->
            Bin
    end;
apply_mutation({swap, P1, P2, Len}, Bin) ->
    %% Moves a piece elsewhere: elements end up out of order or misnested.
    At = P1 rem byte_size(Bin),
    N = min(Len, byte_size(Bin) - At),
    <<Before:At/binary, Part:N/binary, After/binary>> = Bin,
    Rest = <<Before/binary, After/binary>>,
    To = P2 rem (byte_size(Rest) + 1),
    <<B2:To/binary, A2/binary>> = Rest,
    <<B2/binary, Part/binary, A2/binary>>.

edit_leaf(delete, _Leaf) ->
    <<>>;
edit_leaf(duplicate, Leaf) ->
    <<Leaf/binary, Leaf/binary>>;
edit_leaf(empty, Leaf) ->
    edit_leaf({text, <<>>}, Leaf);
edit_leaf({text, Text}, Leaf) ->
    Name = leaf_name(Leaf),
    <<"<", Name/binary, ">", Text/binary, "</", Name/binary, ">">>;
edit_leaf({rename, New}, Leaf) ->
    Name = leaf_name(Leaf),
    Inner = binary:part(Leaf, byte_size(Name) + 2, byte_size(Leaf) - 2 * byte_size(Name) - 5),
    <<"<", New/binary, ">", Inner/binary, "</", New/binary, ">">>.

leaf_name(<<"<", Rest/binary>>) ->
    [Name | _] = binary:split(Rest, <<">">>),
    Name.

%% @doc PropEr generators of valid BIL terms: bil:description(), bil:signal()
%% and bil:entry(), with awkward but legal content (unicode, markup
%% characters, surrounding and whitespace-only text, long values, numbers of
%% up to 20 digits). Shared by the codec, binding and benchmark tests.
%%
%% Every generated term is valid, so it must survive an encode/parse round
%% trip, and every generated signal encodes to less than the default 64 KiB
%% signal limit. Text uses only characters XML 1.0 allows. Parameter and
%% component names are unique where BIL requires it; parameter names are
%% NCNames, sometimes with non-ASCII letters, never starting with `xml'
%% (reserved by XML). Sizes are bounded explicitly, not by PropEr's size.
-module(bil_gen).

-include_lib("proper/include/proper.hrl").

-export([description/0, signal/0, entry/0, component/0, signal_context/0,
         text/0, nonempty_text/0, parameter_name/0, parameters/0, decimal/0]).

%% Characters that need escaping or look like markup.
-define(MARKUP, [$<, $&, $>, $", $']).
%% Whitespace XML keeps in leaf text. Carriage return is included: it must be
%% written as a character reference, or a parser would turn it into a line feed.
-define(SPACES, [$\s, $\t, $\n, $\r]).
%% Non-ASCII samples: Latin, Greek, Cyrillic, CJK, an astral emoji, a
%% no-break space, a zero-width no-break space (a BOM in the middle of text)
%% and a combining accent.
-define(UNICODE, [16#E9, 16#DF, 16#3A9, 16#416, 16#4E2D, 16#1F600, 16#A0, 16#FEFF, 16#301]).
%% Fragments that look like markup once written, to catch missing escapes.
-define(FRAGMENTS, [<<"]]>">>, <<"&amp;">>, <<"&lt;">>, <<"<!--">>, <<"-->">>,
                    <<"<![CDATA[">>, <<"&#65;">>, <<"<bil:x/>">>, <<"\r\n">>]).

%% @doc A description with 0..4 components, each with a unique `ComponentID',
%% 1..3 services and 0..3 consumes.
-spec description() -> proper_types:type().
description() ->
    ?LET({Id, ApiName, Type, Context, Components},
         {nonempty_text(), text(), oneof([agent, avatar]), text(),
          list_of(0, 4, component())},
         #{entity_id => Id, api_name => ApiName, entity_type => Type,
           context => Context, components => unique_ids(Components)}).

%% @doc One component; the description generator makes the ids unique.
-spec component() -> proper_types:type().
component() ->
    ?LET({Id, Services, Consumes},
         {nonempty_text(), list_of(1, 3, entry()), list_of(0, 3, entry())},
         #{id => Id, services => Services, consumes => Consumes}).

%% @doc One `Service' or `Consumes' entry, also the shape of a signal body.
-spec entry() -> proper_types:type().
entry() ->
    ?LET({Category, Type, Parameters}, {nonempty_text(), nonempty_text(), parameters()},
         #{category => Category, type => Type, parameters => Parameters}).

%% @doc A signal of any context, with each optional field sometimes undefined.
-spec signal() -> proper_types:type().
signal() ->
    ?LET({{Id, Context, Sender, Receiver, InReplyTo}, {Timestamp, Seq, Epoch}, Body},
         {{nonempty_text(), signal_context(), nonempty_text(), nonempty_text(),
           optional(nonempty_text())},
          {decimal(), optional(decimal()), optional(decimal())},
          entry()},
         #{id => Id, context => Context, sender => Sender, receiver => Receiver,
           in_reply_to => InReplyTo, timestamp => Timestamp, seq => Seq, epoch => Epoch,
           body => Body}).

%% @doc Any signal context.
-spec signal_context() -> proper_types:type().
signal_context() ->
    oneof(bil:signal_contexts()).

%% @doc 0..6 parameters (rarely up to 20) with unique names and any text.
-spec parameters() -> proper_types:type().
parameters() ->
    ?LET(Parameters,
         frequency([{6, list_of(0, 6, {parameter_name(), text()})},
                    {1, list_of(7, 20, {parameter_name(), short_text()})}]),
         unique_names(Parameters)).

%% @doc An NCName: a letter or `_', then letters, digits, `-', `.', `_',
%% sometimes non-ASCII letters, a combining mark or a middle dot.
-spec parameter_name() -> proper_types:type().
parameter_name() ->
    ?SUCHTHAT(Name,
              ?LET({Start, Rest}, {name_start(), list_of(0, 12, name_char())},
                   unicode:characters_to_binary([Start | Rest])),
              not reserved(Name)).

%% @doc Text of a field or parameter value, possibly empty.
-spec text() -> proper_types:type().
text() ->
    frequency([{1, <<>>}, {8, nonempty_text()}]).

%% @doc Text that is not empty, but may be only whitespace.
-spec nonempty_text() -> proper_types:type().
nonempty_text() ->
    frequency([{6, short_text()},
               {1, blank_text()},
               {2, padded_text()},
               {1, long_text()}]).

%% @doc A non-negative integer of 1 to 20 decimal digits, often a millisecond timestamp.
-spec decimal() -> proper_types:type().
decimal() ->
    frequency([{3, range(0, 1000)},
               {3, range(1600000000000, 1900000000000)},
               {2, ?LET(N, range(1, 20),
                        ?LET(Digits, vector(N, range($0, $9)), list_to_integer(Digits)))},
               {1, elements([0, 18446744073709551615, 18446744073709551616,
                             99999999999999999999])}]).

%% ---------------------------------------------------------------------------
%% Internal
%% ---------------------------------------------------------------------------

short_text() ->
    ?LET(Pieces, list_of(1, 16, piece()), iolist_to_binary(Pieces)).

blank_text() ->
    ?LET(Spaces, list_of(1, 6, elements(?SPACES)), list_to_binary(Spaces)).

padded_text() ->
    ?LET({Before, Text, After}, {blank_text(), short_text(), blank_text()},
         <<Before/binary, Text/binary, After/binary>>).

long_text() ->
    ?LET(Chars, list_of(100, 600, xml_char()), unicode:characters_to_binary(Chars)).

piece() ->
    frequency([{12, ?LET(C, xml_char(), unicode:characters_to_binary([C]))},
               {1, elements(?FRAGMENTS)}]).

%% Any character XML 1.0 allows, biased towards the interesting ones.
xml_char() ->
    frequency([{12, range($\s, $~)},
               {3, elements(?MARKUP)},
               {2, elements(?SPACES)},
               {3, elements(?UNICODE)},
               {1, range(16#A0, 16#D7FF)},
               {1, range(16#E000, 16#FFFD)},
               {1, range(16#10000, 16#10FFFF)}]).

name_start() ->
    frequency([{10, range($a, $z)},
               {6, range($A, $Z)},
               {1, $_},
               {2, elements([16#E9, 16#C5, 16#3A9, 16#416, 16#4E2D, 16#10400])}]).

name_char() ->
    frequency([{10, range($a, $z)},
               {3, range($A, $Z)},
               {3, range($0, $9)},
               {1, elements([$-, $., $_, 16#B7, 16#301, 16#E9, 16#4E2D])}]).

reserved(<<X, M, L, _/binary>>) ->
    string:lowercase([X, M, L]) =:= "xml";
reserved(_) ->
    false.

optional(Type) ->
    frequency([{1, undefined}, {2, Type}]).

list_of(Min, Max, Type) ->
    ?LET(N, range(Min, Max), vector(N, Type)).

%% Keeps the first of each name, as BIL requires names to be unique.
unique_names(Parameters) ->
    unique(Parameters, fun({Name, _}) -> Name end).

unique_ids(Components) ->
    unique(Components, fun(#{id := Id}) -> Id end).

unique(Items, Key) ->
    {Unique, _} = lists:foldl(fun(Item, {Acc, Seen}) ->
                                      K = Key(Item),
                                      case Seen of
                                          #{K := _} -> {Acc, Seen};
                                          #{} -> {[Item | Acc], Seen#{K => true}}
                                      end
                              end, {[], #{}}, Items),
    lists:reverse(Unique).

%% @doc Test only. A reference for bil_xml built on xmerl_sax_parser: turns
%% a trusted document into the same element() tree bil_xml:parse/2 gives
%% (namespaces resolved from xmerl's events, same whitespace rule), so that
%% properties can compare the two parsers. Never use it on untrusted input.
-module(bil_xml_ref).

-export([parse/1]).

%% One open element: its name, attributes, finished children (reversed),
%% the pieces of the current text run (reversed) and whether it has seen a
%% child element.
-record(open, {name, attrs, kids = [], run = [], has_elem = false}).

%% @doc Parses Bin with xmerl_sax_parser; {error, Reason} if xmerl refuses it.
-spec parse(binary()) -> {ok, bil_xml:element()} | {error, term()}.
parse(Bin) ->
    case xmerl_sax_parser:stream(Bin, [{event_fun, fun event/3},
                                       {event_state, {[], undefined}}]) of
        {ok, {[], Root}, _Rest} when Root =/= undefined -> {ok, Root};
        {ok, Other, _Rest} -> {error, {unexpected_state, Other}};
        Error -> {error, Error}
    end.

event({startElement, Uri, Local, _QName, Attrs}, _Loc, {Stack, Root}) ->
    Open = #open{name = {ns(Uri), bin(Local)},
                 attrs = [{{ns(AUri), bin(ALocal)}, bin(Value)}
                          || {AUri, _Prefix, ALocal, Value} <- Attrs]},
    {[Open | flush_into_parent(Stack)], Root};
event({endElement, _Uri, _Local, _QName}, _Loc, {[Open | Stack], Root}) ->
    Element = {Open#open.name, Open#open.attrs, children(Open)},
    case Stack of
        [] -> {[], Element};
        [Parent | Up] -> {[Parent#open{kids = [Element | Parent#open.kids]} | Up], Root}
    end;
event({characters, Chars}, _Loc, State) ->
    text(Chars, State);
event({ignorableWhitespace, Chars}, _Loc, State) ->
    text(Chars, State);
event(_Other, _Loc, State) ->
    State.

text(Chars, {[Open | Stack], Root}) ->
    {[Open#open{run = [bin(Chars) | Open#open.run]} | Stack], Root};
text(_Chars, State) ->
    State.

%% A child element starts: the parent's text run so far becomes a child
%% unless it is whitespace only.
flush_into_parent([]) ->
    [];
flush_into_parent([Parent | Up]) ->
    Text = iolist_to_binary(lists:reverse(Parent#open.run)),
    Kids = case is_ws(Text) of
               true -> Parent#open.kids;
               false -> [Text | Parent#open.kids]
           end,
    [Parent#open{kids = Kids, run = [], has_elem = true} | Up].

children(#open{has_elem = true} = Open) ->
    [#open{kids = Kids}] = flush_into_parent([Open]),
    lists:reverse(Kids);
children(#open{run = Run}) ->
    case iolist_to_binary(lists:reverse(Run)) of
        <<>> -> [];
        Text -> [Text]
    end.

is_ws(Bin) ->
    lists:all(fun(C) -> lists:member(C, " \t\r\n") end, binary_to_list(Bin)).

ns([]) -> undefined;
ns(Uri) -> bin(Uri).

bin(Chars) -> unicode:characters_to_binary(Chars).

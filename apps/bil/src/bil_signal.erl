%% @doc Internal. Parses and encodes BIL signals (docs/bil.md, section 3).
%% Signals are EVATAR's hot path: the parser walks bil_xml's tree once with
%% direct pattern matching, and the encoder builds one compact iolist.
-module(bil_signal).

-export([parse/2, encode/1]).

-define(NS, <<"urn:evatar:bil:1">>).
%% Same tag as bil_description, whose helpers throw structural errors.
-define(TAG, bil_structure).
-define(HEADER, <<"/Envelope/Header">>).

%% ---------------------------------------------------------------------------
%% Parsing
%% ---------------------------------------------------------------------------

-spec parse(binary(), bil_limits:resolved()) ->
          {ok, bil:signal()} | {error, bil:error_reason()}.
parse(Bin, Limits) when is_binary(Bin) ->
    case bil_xml:parse(Bin, Limits) of
        {ok, {{?NS, <<"Envelope">>}, _, Children}} ->
            try
                {ok, envelope(Children)}
            catch
                throw:{?TAG, Reason} -> {error, Reason}
            end;
        {ok, {Name, _, _}} ->
            {error, bil_description:root_error(<<"Envelope">>, Name)};
        {error, _} = Error ->
            Error
    end;
parse(_, _) ->
    {error, bil_description:not_binary()}.

envelope([{{?NS, <<"Header">>}, _, Header}, {{?NS, <<"Body">>}, _, Body}]) ->
    (header(Header))#{body := body(Body)};
envelope(C0) ->
    P = <<"/Envelope">>,
    {Header, C1} = bil_description:struct(<<"Header">>, C0, P),
    Signal = header(Header),
    {Body, C2} = bil_description:struct(<<"Body">>, C1, P),
    Entry = body(Body),
    bil_description:finish(C2, P, [{?NS, <<"Header">>}, {?NS, <<"Body">>}],
                           <<"Header, then Body">>),
    Signal#{body := Entry}.

%% The signal without its body (`undefined' until envelope/1 sets it).
header(C0) ->
    {Id, C1} = required(<<"SignalID">>, C0),
    {ContextText, C2} = field(<<"Context">>, C1),
    Context = context(ContextText),
    {Sender, C3} = required(<<"Sender">>, C2),
    {Receiver, C4} = required(<<"Receiver">>, C3),
    {InReplyTo, C5} = optional(<<"InReplyTo">>, C4),
    case InReplyTo of
        <<>> ->
            bil_description:fail(bad_value, <<?HEADER/binary, "/InReplyTo">>,
                                 <<"InReplyTo must not be empty: it names the SignalID"
                                   " this signal answers">>);
        _ ->
            ok
    end,
    {TimestampText, C6} = field(<<"Timestamp">>, C5),
    Timestamp = bil_description:number(TimestampText, ?HEADER, <<"Timestamp">>),
    {SeqText, C7} = optional(<<"Sequence">>, C6),
    Seq = optional_number(SeqText, <<"Sequence">>),
    {EpochText, C8} = optional(<<"Epoch">>, C7),
    Epoch = optional_number(EpochText, <<"Epoch">>),
    {OriginText, C9} = optional(<<"Origin">>, C8),
    finish_header(C9),
    Signal = #{id => Id, context => Context, sender => Sender, receiver => Receiver,
               in_reply_to => InReplyTo, timestamp => Timestamp, seq => Seq, epoch => Epoch,
               body => undefined},
    case OriginText of
        undefined -> Signal;
        <<"EVATAR">> -> Signal#{origin => evatar};
        Other -> bil_description:fail(bad_value, <<?HEADER/binary, "/Origin">>,
                                      [<<"Origin must be EVATAR; found ">>,
                                       bil_description:quote(Other)])
    end.

body(Content) ->
    bil_description:entry(Content, <<"/Envelope/Body">>).

finish_header([]) ->
    ok;
finish_header(Rest) ->
    bil_description:finish(
      Rest, ?HEADER,
      [{undefined, F} || F <- [<<"SignalID">>, <<"Context">>, <<"Sender">>, <<"Receiver">>,
                                <<"InReplyTo">>, <<"Timestamp">>, <<"Sequence">>,
                                <<"Epoch">>, <<"Origin">>]],
      <<"SignalID, Context, Sender, Receiver, optional InReplyTo, Timestamp,"
        " optional Sequence, optional Epoch, optional Origin, in that order">>).

%% The header's fields: local copies of the common case, falling back to
%% bil_description for whitespace and errors.
field(Local, [{{undefined, Local}, _, [Text]} | Rest]) when is_binary(Text) ->
    {Text, Rest};
field(Local, Content) ->
    bil_description:field(Local, Content, ?HEADER).

required(Local, [{{undefined, Local}, _, [Text]} | Rest]) when is_binary(Text), Text =/= <<>> ->
    {Text, Rest};
required(Local, Content) ->
    bil_description:required(Local, Content, ?HEADER).

optional(Local, [{{undefined, Local}, _, _} | _] = Content) ->
    field(Local, Content);
optional(Local, [{{Ns, Local}, _, _} | _]) ->
    bil_description:wrong_namespace(Local, undefined, Ns, <<?HEADER/binary, "/", Local/binary>>);
optional(_, Content) ->
    {undefined, Content}.

optional_number(undefined, _) -> undefined;
optional_number(Text, Local) -> bil_description:number(Text, ?HEADER, Local).

%% The wire names of the contexts, both ways; never an atom made from input.
context(<<"RequestAwaitingFeedback">>) -> request;
context(<<"Request">>) -> request_no_feedback;
context(<<"Feedback">>) -> feedback;
context(<<"Progress">>) -> progress;
context(<<"SensorData">>) -> sensor_data;
context(<<"Event">>) -> event;
context(<<"Error">>) -> error;
context(Other) ->
    bil_description:fail(
      bad_value, <<?HEADER/binary, "/Context">>,
      [<<"Context must be one of RequestAwaitingFeedback, Request, Feedback, Progress,">>,
       <<" SensorData, Event, Error; found ">>, bil_description:quote(Other)]).

wire(request) -> <<"RequestAwaitingFeedback">>;
wire(request_no_feedback) -> <<"Request">>;
wire(feedback) -> <<"Feedback">>;
wire(progress) -> <<"Progress">>;
wire(sensor_data) -> <<"SensorData">>;
wire(event) -> <<"Event">>;
wire(error) -> <<"Error">>.

%% ---------------------------------------------------------------------------
%% Encoding
%% ---------------------------------------------------------------------------

-spec encode(bil:signal()) -> iodata().
encode(#{} = Signal) ->
    encode(Signal, maps:get(origin, Signal, undefined)).

encode(#{id := Id, context := Context, sender := Sender, receiver := Receiver,
         in_reply_to := InReplyTo, timestamp := Timestamp, seq := Seq, epoch := Epoch,
         body := #{category := Category, type := Type, parameters := Parameters}}, Origin)
  when is_integer(Timestamp), Timestamp >= 0, (Origin =:= undefined orelse Origin =:= evatar) ->
    [<<"<?xml version=\"1.0\" encoding=\"UTF-8\"?>"
       "<bil:Envelope xmlns:bil=\"urn:evatar:bil:1\"><bil:Header><SignalID>">>,
     bil_description:esc(Id),
     <<"</SignalID><Context>">>, wire(Context),
     <<"</Context><Sender>">>, bil_description:esc(Sender),
     <<"</Sender><Receiver>">>, bil_description:esc(Receiver),
     case InReplyTo of
         undefined -> <<"</Receiver><Timestamp>">>;
         _ -> [<<"</Receiver><InReplyTo>">>, bil_description:esc(InReplyTo),
               <<"</InReplyTo><Timestamp>">>]
     end,
     integer_to_binary(Timestamp),
     <<"</Timestamp>">>,
     encode_number(<<"<Sequence>">>, Seq, <<"</Sequence>">>),
     encode_number(<<"<Epoch>">>, Epoch, <<"</Epoch>">>),
     case Origin of
         evatar -> <<"<Origin>EVATAR</Origin>">>;
         undefined -> <<>>
     end,
     <<"</bil:Header><bil:Body><ServiceCategory>">>, bil_description:esc(Category),
     <<"</ServiceCategory><ServiceType>">>, bil_description:esc(Type),
     <<"</ServiceType>">>,
     bil_description:encode_parameters(Parameters),
     <<"</bil:Body></bil:Envelope>">>].

encode_number(_, undefined, _) -> <<>>;
encode_number(Open, N, Close) when is_integer(N), N >= 0 ->
    [Open, integer_to_binary(N), Close].

%% @doc Internal. What the WoT Avatar's process (wot_avatar_fsm) does with
%% a VA's request and a Thing's answer, decided without I/O: a request
%% signal becomes the HTTP request of its route (checked against the
%% schema first, so a value out of range is refused before it reaches the
%% Thing) or an error answer; the Thing's answer, or why there is none,
%% becomes the Feedback (or Error); a stream's reading becomes the
%% SensorData or Event signals to the components bound to it; a binding
%% report tells who the readings go to. Also the Server-Sent Events
%% parser of SSE streams. docs/wot.md section 6. Pure.
-module(wot_avatar_route).

-export([request/3, answer/3, last/3, failure/3, reading/4, receivers/4, sse/2, headers/2]).

-export_type([http/0, pending/0, outcome/0]).

%% One HTTP request to make: method, URL, headers, body (`none': none).
-type http() :: #{method := binary(), url := binary(), headers := [{string(), string()}],
                  content_type := binary(), body := none | binary()}.
%% What a request in flight must remember to answer.
-type pending() :: #{id := binary(), requester := binary(), awaiting := boolean(),
                     route := wot_avatar_generate:route(), sent := [bil:parameter()]}.
%% Why a request got no answer: a timeout, an HTTP error status, a body too
%% large, or a Thing that cannot be reached (`gone').
-type outcome() :: timeout | {status, pos_integer(), binary()} | too_large | {gone, binary()}.
%% `username' and `password' (basic) or `token' (bearer), for the Thing.
-type credentials() :: #{username => binary(), password => binary(), token => binary()}.

-define(MAX_ERROR_TEXT, 200).

%% @doc A VA's request to the component: the HTTP request to make and what
%% to remember, the stream whose last reading answers it (`last': an
%% event's Read service), or the signals that answer it at once (an
%% unknown component or service, a parameter the schema refuses).
-spec request(bil:signal(), wot_avatar_generate:routes(), #{room => binary(),
                                                            thing_credentials => credentials()}) ->
          {http, http(), pending()} | {last, binary(), pending()}
        | {answer, [agent_bridge_client:partial_signal()]}.
request(#{id := Id, sender := From, receiver := To, context := Ctx,
          body := #{type := Type, parameters := Args}}, #{component := Comp, services := Services},
        Opts) ->
    Awaiting = Ctx =:= request,
    Error = fun(Code, Message) -> {answer, err(Awaiting, To, From, Id, Code, Message)} end,
    case {To =:= Comp, maps:find(bil:keyword(Type), Services)} of
        {false, _} ->
            Error(<<"UnknownComponent">>, <<"no such component in this WoT Avatar">>);
        {true, error} ->
            Error(<<"UnknownService">>, <<"component ", Comp/binary, " has no service ", Type/binary>>);
        {true, {ok, #{op := readevent, stream := Stream} = Route}} ->
            {last, Stream, #{id => Id, requester => From, awaiting => Awaiting, route => Route, sent => []}};
        {true, {ok, #{form := Form, input := In} = Route}} ->
            case wot_avatar_codec:body(In, Args) of
                {error, Message} ->
                    Error(<<"BadParameter">>, Message);
                {ok, Body} ->
                    Sent = [{N, V} || {N, V} <- Args, lists:member(bil:keyword(N), names(In))],
                    Http = #{method => maps:get(method, Form), url => maps:get(href, Form),
                             headers => headers(Form, maps:get(thing_credentials, Opts, #{})),
                             content_type => maps:get(content_type, Form), body => Body},
                    {http, Http, #{id => Id, requester => From, awaiting => Awaiting, route => Route,
                                   sent => Sent}}
            end
    end.

%% @doc The Feedback of a request the Thing answered with a 2xx body: the
%% Thing's output as parameters (or, when it answers nothing, the values
%% written), `Service' and `Result'.
-spec answer(pending(), binary(), #{component := binary(), room => binary()}) ->
          [agent_bridge_client:partial_signal()].
answer(#{route := #{output := Out}, sent := Sent} = P, Body, Opts) ->
    Values = case wot_avatar_codec:params(Out, Body) of
                 [] -> Sent;
                 Ps -> Ps
             end,
    feedback(P, Values, Opts).

%% @doc The Feedback of a request answered with `Values' (an event's Read
%% service: the last event's parameters, Room included), or, with none
%% yet, its Error.
-spec last(pending(), [bil:parameter()] | none, #{component := binary(), room => binary()}) ->
          [agent_bridge_client:partial_signal()].
last(#{id := Id, requester := R, awaiting := A}, none, #{component := C}) ->
    err(A, C, R, Id, <<"NoReading">>, <<"no event of the Thing since the Avatar joined">>);
last(P, Values, Opts) ->
    feedback(P, [V || {N, _} = V <- Values, N =/= <<"Room">>], Opts).

feedback(#{awaiting := false}, _Values, _Opts) ->
    [];
feedback(#{id := Id, requester := R, route := #{type := Type} = Route}, Values, #{component := C} = Opts) ->
    {Cat, FType} = case maps:get(op, Route) of
                       invokeaction -> {<<"ACTUATOR">>, <<"ACTION FEEDBACK">>};
                       writeproperty -> {<<"ACTUATOR">>, <<"ACTION FEEDBACK">>};
                       _ -> {<<"SENSOR">>, Type}
                   end,
    [#{context => feedback, sender => C, receiver => R, in_reply_to => Id,
       body => #{category => Cat, type => FType,
                 parameters => [{<<"Service">>, Type}, {<<"Result">>, <<"done">>}] ++ Values
                     ++ room(Opts)}}].

%% @doc The Error answering a request the Thing did not answer.
-spec failure(pending(), outcome(), #{component := binary()}) -> [agent_bridge_client:partial_signal()].
failure(#{id := Id, requester := R, awaiting := A}, Outcome, #{component := C}) ->
    {Code, Message} = case Outcome of
                          timeout ->
                              {<<"DeviceTimeout">>, <<"the Thing did not answer within request_timeout">>};
                          {status, S, Text} ->
                              {<<"DeviceError">>, iolist_to_binary(["the Thing answered HTTP ",
                                                                    integer_to_binary(S), short(Text)])};
                          too_large ->
                              {<<"DeviceError">>, <<"the Thing's answer is over max_body">>};
                          {gone, Why} ->
                              {<<"DeviceUnavailable">>, <<"the Thing cannot be reached: ", Why/binary>>}
                      end,
    err(A, C, R, Id, Code, Message).

%% @doc The signals of a reading (a body of stream `Stream'), to each of
%% `Receivers'.
-spec reading(wot_avatar_generate:stream(), binary(), [binary()], #{component := binary(), room => binary()}) ->
          {[bil:parameter()], [agent_bridge_client:partial_signal()]}.
reading(#{type := Type, context := Ctx, output := Out}, Body, Receivers, #{component := C} = Opts) ->
    Params = wot_avatar_codec:params(Out, Body) ++ room(Opts),
    {Params, [#{context => Ctx, sender => C, receiver => R,
                body => #{category => <<"SENSOR">>, type => Type, parameters => Params}}
              || R <- Receivers]}.

%% @doc The components a Binding report binds to the Avatar's Consumes
%% entry SENSOR/`Type' of `Comp': who its readings go to.
-spec receivers(binary(), binary(), binary(), [bil:binding()]) -> [binary()].
receivers(Entity, Comp, Type, Bound) ->
    K = bil:keyword(Type),
    lists:usort([P || #{consumer := #{entity := E, component := CC}, provider := #{component := P},
                        category := <<"SENSOR">>, type := T} <- Bound,
                      E =:= Entity, CC =:= Comp, bil:keyword(T) =:= K]).

%% @doc Server-Sent Events: the data of the events complete in `Buffer'
%% (each event's `data:' lines joined by newlines) and what is left.
-spec sse(binary(), non_neg_integer()) -> {[binary()], binary()} | too_large.
sse(Buffer, Max) ->
    Normal = binary:replace(Buffer, <<"\r\n">>, <<"\n">>, [global]),
    case binary:split(Normal, <<"\n\n">>, [global]) of
        [Rest] when byte_size(Rest) > Max ->
            too_large;
        Parts ->
            {Events, [Rest]} = lists:split(length(Parts) - 1, Parts),
            Datas = [iolist_to_binary(lists:join(<<"\n">>, Ds))
                     || E <- Events,
                        Ds <- [[data(L) || <<"data:", _/binary>> = L <- binary:split(E, <<"\n">>, [global])]],
                        Ds =/= []],
            {Datas, Rest}
    end.

data(<<"data: ", D/binary>>) -> D;
data(<<"data:", D/binary>>) -> D.

%% @doc The request headers of a form: Accept and, for a form that asks
%% for it, Authorization.
-spec headers(wot_avatar_td:form(), credentials()) -> [{string(), string()}].
headers(#{content_type := CT, subprotocol := Sub, security := Sec}, Creds) ->
    Accept = case Sub of
                 sse -> "text/event-stream";
                 _ -> binary_to_list(CT)
             end,
    [{"accept", Accept}] ++ auth(Sec, Creds).

auth(basic, #{username := U, password := P}) ->
    [{"authorization", "Basic " ++ base64:encode_to_string(<<U/binary, ":", P/binary>>)}];
auth(bearer, #{token := T}) ->
    [{"authorization", "Bearer " ++ binary_to_list(T)}];
auth(_, _) ->
    [].

names(none) -> [];
names({value, _}) -> [bil:keyword(<<"Value">>)];
names({object, Fields}) -> [bil:keyword(B) || {B, _, _} <- Fields].

room(#{room := R}) when is_binary(R) -> [{<<"Room">>, R}];
room(_) -> [].

err(true, C, R, Id, Code, Message) ->
    [#{context => error, sender => C, receiver => R, in_reply_to => Id,
       body => #{category => <<"ERROR">>, type => Code, parameters => [{<<"Message">>, Message}]}}];
err(false, _C, _R, _Id, _Code, _Message) ->
    [].

%% A Thing's error body, shortened and made printable for a message.
short(<<>>) -> <<>>;
short(Text) ->
    T = case unicode:characters_to_binary(Text) of
            B when is_binary(B) -> B;
            _ -> <<"(not UTF-8)">>
        end,
    Clean = << <<(case C < 32 of true -> $\s; false -> C end)>> || <<C>> <= T >>,
    case string:length(Clean) > ?MAX_ERROR_TEXT of
        true -> <<": ", (unicode:characters_to_binary(string:slice(Clean, 0, ?MAX_ERROR_TEXT)))/binary, "...">>;
        false -> <<": ", Clean/binary>>
    end.

%% @doc Internal. Reads a W3C Thing Description (TD 1.1, JSON) into the
%% affordances a WoT Avatar can drive over the HTTP binding, or the MQTT
%% binding (`mqtt://HOST:PORT/TOPIC', `mqv:controlPacket' publish to
%% invoke and write, subscribe to observe and for events): every form
%% resolved against the TD's `base' (or the address it was fetched from),
%% checked against the hosts the operator allows, its method and
%% subprotocol settled. What cannot be driven (another scheme, a security
%% scheme beyond nosec/basic/bearer, a form to a host not allowed) is a
%% problem of its affordance, never a crash; only input that is no TD at
%% all is refused. docs/wot.md section 6 lists the rules and limits. Pure.
-module(wot_avatar_td).

-export([read/2, limits/0]).

-export_type([thing/0, affordance/0, form/0, schema/0, opts/0, problem/0]).

%% `allowed_hosts': `<<"host">>' or `<<"host:port">>' entries (any case)
%% a form may point at; the host and port of `source_url' are allowed too.
-type opts() :: #{source_url => binary(),
                  allowed_hosts => [binary()],
                  max_size => pos_integer(),
                  max_affordances => pos_integer()}.
%% An MQTT form: `method' <<"PUBLISH">> (subprotocol none) or subscribe
%% (subprotocol mqtt), its href the broker and topic.
-type form() :: #{href := binary(), method := binary(), content_type := binary(),
                  subprotocol := none | longpoll | sse | mqtt, security := security()}.
%% A data schema as the TD has it (a JSON object), only read, never trusted.
-type schema() :: #{binary() => term()}.
-type affordance() :: #{name := binary(), schema := schema(), forms := #{atom() => form()},
                        read_only => boolean(), observable => boolean()}.
-type security() :: nosec | basic | bearer.
-type thing() :: #{title := binary(), id := binary() | undefined,
                   actions := [affordance()], properties := [affordance()],
                   events := [affordance()]}.
-type problem() :: #{what := atom(), message := binary(), affordance => binary()}.

-define(MAX_SIZE, 262144).
-define(SIZE_LIMIT, 1048576).
-define(MAX_AFFORDANCES, 128).
-define(MAX_NAME, 64).

%% @doc The defaults of `max_size' (bytes of TD text) and `max_affordances'
%% (actions, properties and events together), and the largest `max_size'.
-spec limits() -> #{max_size := pos_integer(), size_limit := pos_integer(),
                    max_affordances := pos_integer(), max_name := pos_integer()}.
limits() ->
    #{max_size => ?MAX_SIZE, size_limit => ?SIZE_LIMIT, max_affordances => ?MAX_AFFORDANCES,
      max_name => ?MAX_NAME}.

%% @doc The Thing a TD text describes, with the problems of the
%% affordances left out; `{error, Problems}' when the text is no TD.
-spec read(binary(), opts()) -> {ok, thing(), [problem()]} | {error, [problem()]}.
read(Text, Opts) when is_binary(Text) ->
    Max = min(maps:get(max_size, Opts, ?MAX_SIZE), ?SIZE_LIMIT),
    case byte_size(Text) > Max of
        true ->
            {error, [problem(too_large, "the TD is ~B bytes, over max_size ~B", [byte_size(Text), Max])]};
        false ->
            case evatar_json:decode(Text) of
                {ok, #{} = Td} -> thing(Td, Opts);
                {ok, _} -> {error, [problem(not_a_td, "the TD is JSON but not an object", [])]};
                {error, {Code, Offset}} ->
                    {error, [problem(not_json, "the TD is not JSON (~ts at byte ~B)", [Code, Offset])]}
            end
    end.

thing(#{<<"title">> := Title} = Td, Opts) when is_binary(Title) ->
    case security(Td) of
        {error, P} ->
            {error, [P]};
        {ok, Security, Problems0} ->
            Ctx = #{base => base(Td, Opts), allowed => allowed(Opts), security => Security,
                    definitions => maps:get(<<"securityDefinitions">>, Td)},
            Counts = [map_size(M) || K <- [<<"actions">>, <<"properties">>, <<"events">>],
                                     #{} = M <- [maps:get(K, Td, #{})]],
            Max = maps:get(max_affordances, Opts, ?MAX_AFFORDANCES),
            case lists:sum(Counts) > Max of
                true ->
                    {error, [problem(too_large, "the TD has ~B affordances, over max_affordances ~B",
                                     [lists:sum(Counts), Max])]};
                false ->
                    {Actions, P1} = affordances(<<"actions">>, Td, Ctx),
                    {Props, P2} = affordances(<<"properties">>, Td, Ctx),
                    {Events, P3} = affordances(<<"events">>, Td, Ctx),
                    Id = case maps:get(<<"id">>, Td, undefined) of
                             I when is_binary(I) -> I;
                             _ -> undefined
                         end,
                    {ok, #{title => Title, id => Id, actions => Actions, properties => Props,
                           events => Events},
                     Problems0 ++ P1 ++ P2 ++ P3}
            end
    end;
thing(_, _) ->
    {error, [problem(not_a_td, "the TD has no title (a string): it is not a Thing Description", [])]}.

%% The Thing's `security': the names of its securityDefinitions, each of a
%% scheme the HTTP client speaks.
security(#{<<"securityDefinitions">> := #{} = Defs, <<"security">> := Sec}) ->
    Names = if is_binary(Sec) -> [Sec]; is_list(Sec) -> Sec; true -> bad end,
    case Names of
        bad -> {error, problem(not_a_td, "the TD's security is neither a name nor a list of names", [])};
        _ -> scheme_of(Names, Defs)
    end;
security(_) ->
    {error, problem(not_a_td, "the TD has no securityDefinitions and security: it is not a TD 1.1", [])}.

scheme_of(Names, Defs) ->
    Schemes = [scheme(N, Defs) || N <- Names],
    NotTd = [P || {error, #{what := not_a_td} = P} <- Schemes],
    case [S || {ok, S} <- Schemes] of
        _ when Schemes =:= [] ->
            {error, problem(not_a_td, "the TD's security names no securityDefinitions entry", [])};
        _ when NotTd =/= [] ->
            {error, hd(NotTd)};
        [] ->
            {ok, unsupported, [P || {error, P} <- Schemes]};
        Ok ->
            %% All of them apply (TD 1.1 5.3.1.4): one credential scheme at most.
            case lists:usort(Ok) -- [nosec] of
                [] -> {ok, nosec, [P || {error, P} <- Schemes]};
                [One] -> {ok, One, [P || {error, P} <- Schemes]};
                _ -> {ok, unsupported, [problem(unsupported_security, "the TD asks for basic and bearer "
                                                "together; the WoT Avatar sends one", [])]}
            end
    end.

scheme(Name, Defs) when is_binary(Name) ->
    case maps:get(Name, Defs, undefined) of
        #{<<"scheme">> := <<"nosec">>} -> {ok, nosec};
        #{<<"scheme">> := <<"basic">>} = D -> in_header(basic, D);
        #{<<"scheme">> := <<"bearer">>} = D -> in_header(bearer, D);
        #{<<"scheme">> := S} when is_binary(S) ->
            {error, problem(unsupported_security, "security scheme ~ts is not supported (nosec, basic "
                            "and bearer are)", [text(S)])};
        _ ->
            {error, problem(not_a_td, "security names ~ts, which securityDefinitions does not define",
                            [text(Name)])}
    end;
scheme(_, _) ->
    {error, problem(not_a_td, "the TD's security holds something that is not a name", [])}.

in_header(Scheme, D) ->
    case maps:get(<<"in">>, D, <<"header">>) of
        <<"header">> -> {ok, Scheme};
        In -> {error, problem(unsupported_security, "~ts credentials in ~ts are not supported (in the "
                              "Authorization header they are)", [Scheme, text(In)])}
    end.

base(Td, Opts) ->
    case maps:get(<<"base">>, Td, undefined) of
        B when is_binary(B) -> B;
        _ -> maps:get(source_url, Opts, undefined)
    end.

allowed(Opts) ->
    Source = case maps:get(source_url, Opts, undefined) of
                 undefined -> [];
                 U -> case endpoint(U) of
                          {ok, _Scheme, Host, Port} -> [{Host, Port}];
                          error -> []
                      end
             end,
    Source ++ [allowed_entry(string:lowercase(H)) || H <- maps:get(allowed_hosts, Opts, [])].

allowed_entry(Entry) ->
    case string:split(Entry, <<":">>, trailing) of
        [H, P] ->
            case string:to_integer(P) of
                {N, <<>>} -> {H, N};
                _ -> {Entry, any}
            end;
        [H] -> {H, any}
    end.

affordances(Kind, Td, Ctx) ->
    case maps:get(Kind, Td, #{}) of
        #{} = M ->
            Results = [affordance(Kind, Name, A, Ctx) || {Name, A} <- lists:sort(maps:to_list(M))],
            {[A || {ok, A} <- Results], lists:append([Ps || {error, Ps} <- Results])};
        _ ->
            {[], [problem(not_a_td, "~ts is not an object", [Kind])]}
    end.

affordance(Kind, Name, #{} = A, Ctx) ->
    Schema = case Kind of
                 <<"events">> -> maps:get(<<"data">>, A, #{});
                 _ -> A
             end,
    ReadOnly = maps:get(<<"readOnly">>, A, false) =:= true,
    WriteOnly = maps:get(<<"writeOnly">>, A, false) =:= true,
    Ops = case Kind of
              <<"actions">> -> [invokeaction];
              <<"events">> -> [subscribeevent];
              <<"properties">> when ReadOnly -> [readproperty, observeproperty];
              <<"properties">> when WriteOnly -> [writeproperty];
              <<"properties">> -> [readproperty, writeproperty, observeproperty]
          end,
    Forms = case maps:get(<<"forms">>, A, []) of
                L when is_list(L) -> L;
                _ -> []
            end,
    {Chosen, Why} = choose(Ops, Kind, Forms, Ctx),
    case maps:size(Chosen) of
        0 ->
            {error, [affordance_problem(Name, W) || W <- nonempty(Why, Kind)]};
        _ ->
            {ok, #{name => Name, schema => maps:without([<<"forms">>], Schema), forms => Chosen,
                   read_only => ReadOnly, observable => maps:get(<<"observable">>, A, false) =:= true}}
    end;
affordance(_Kind, Name, _, _Ctx) ->
    {error, [affordance_problem(Name, {not_a_td, <<"the affordance is not an object">>})]}.

nonempty([], Kind) ->
    [{no_form, iolist_to_binary(io_lib:format("no form of these ~ts the WoT Avatar can use", [Kind]))}];
nonempty(Why, _) ->
    lists:usort(Why).

%% For each operation, the first form naming it that the WoT Avatar can
%% use, and why the others cannot be used.
choose(Ops, Kind, Forms, Ctx) ->
    lists:foldl(fun(Op, {Acc, Why}) ->
                        Named = [F || #{} = F <- Forms, lists:member(Op, ops(F, Kind))],
                        Tried = [form(Op, F, Ctx) || F <- Named],
                        case [F || {ok, F} <- Tried] of
                            [F | _] -> {Acc#{Op => F}, Why};
                            [] -> {Acc, Why ++ [W || {error, W} <- Tried]}
                        end
                end, {#{}, []}, Ops).

ops(#{<<"op">> := Op}, _) when is_binary(Op) -> [op(Op)];
ops(#{<<"op">> := Ops}, _) when is_list(Ops) -> [op(O) || O <- Ops];
ops(_, <<"actions">>) -> [invokeaction];
ops(_, <<"events">>) -> [subscribeevent];
ops(_, <<"properties">>) -> [readproperty, writeproperty].

%% A whitelist: op names from the TD never become atoms.
op(<<"readproperty">>) -> readproperty;
op(<<"writeproperty">>) -> writeproperty;
op(<<"observeproperty">>) -> observeproperty;
op(<<"invokeaction">>) -> invokeaction;
op(<<"subscribeevent">>) -> subscribeevent;
op(_) -> other.

form(Op, #{<<"href">> := Href} = F, #{base := Base, allowed := Allowed} = Ctx) when is_binary(Href) ->
    case resolve(Href, Base) of
        error ->
            {error, {bad_href, <<"a form's href is not a URL (relative, with no base to resolve it)">>}};
        {ok, Url} ->
            case endpoint(Url) of
                {ok, Scheme, Host, Port} when Scheme =:= <<"http">>; Scheme =:= <<"https">> ->
                    case lists:any(fun({H, P}) -> H =:= Host andalso (P =:= any orelse P =:= Port) end,
                                   Allowed) of
                        false ->
                            {error, {host_not_allowed,
                                     iolist_to_binary(io_lib:format("a form points at ~ts:~B, not an allowed "
                                                                    "host (allowed_hosts)", [text(Host), Port]))}};
                        true ->
                            form_at(Op, Url, F, Ctx)
                    end;
                {ok, <<"mqtt">>, Host, Port} ->
                    case lists:any(fun({H, P}) -> H =:= Host andalso (P =:= any orelse P =:= Port) end,
                                   Allowed) of
                        false ->
                            {error, {host_not_allowed,
                                     iolist_to_binary(io_lib:format("a form points at the broker ~ts:~B, not "
                                                                    "an allowed host (allowed_hosts)",
                                                                    [text(Host), Port]))}};
                        true ->
                            mqtt_form(Op, Url, F, Ctx)
                    end;
                {ok, Scheme, _, _} ->
                    {error, {unsupported_scheme,
                             iolist_to_binary(io_lib:format("a form uses ~ts: only the HTTP binding (http, "
                                                            "https) and MQTT (mqtt) are supported",
                                                            [text(Scheme)]))}};
                error ->
                    {error, {bad_href, <<"a form's href is not a URL the WoT Avatar can reach">>}}
            end
    end;
form(_Op, _, _) ->
    {error, {bad_href, <<"a form has no href">>}}.

form_at(Op, Url, F, #{security := Thing, definitions := Defs}) ->
    Security = case maps:get(<<"security">>, F, undefined) of
                   undefined -> {ok, Thing, []};
                   S when is_binary(S); is_list(S) ->
                       case scheme_of(if is_binary(S) -> [S]; true -> S end, Defs) of
                           {ok, FormScheme, _} -> {ok, FormScheme, []};
                           {error, _} -> {ok, unsupported, []}
                       end;
                   _ -> {ok, unsupported, []}
               end,
    Method = maps:get(<<"htv:methodName">>, F, default_method(Op)),
    Sub = maps:get(<<"subprotocol">>, F, undefined),
    CT = maps:get(<<"contentType">>, F, <<"application/json">>),
    case {Security, method(Method), subprotocol(Op, Sub), CT} of
        {{ok, unsupported, _}, _, _, _} ->
            {error, {unsupported_security, <<"the form's security scheme is not supported (nosec, basic "
                                             "and bearer are)">>}};
        {_, error, _, _} ->
            {error, {unsupported_form, <<"the form's htv:methodName is not GET, PUT, POST or DELETE">>}};
        {_, _, error, _} ->
            {error, {unsupported_form, <<"the form's subprotocol is not longpoll or sse">>}};
        {{ok, Sc, _}, {ok, M}, {ok, SubP}, <<"application/json", _/binary>>} ->
            {ok, #{href => Url, method => M, content_type => <<"application/json">>, subprotocol => SubP,
                   security => Sc}};
        {{ok, Sc, _}, {ok, M}, {ok, SubP}, <<"text/plain", _/binary>>} ->
            {ok, #{href => Url, method => M, content_type => <<"text/plain">>, subprotocol => SubP,
                   security => Sc}};
        _ ->
            {error, {unsupported_form, <<"the form's contentType is neither application/json nor text/plain">>}}
    end.

%% The MQTT binding: a publish to invoke or write, a subscribe to observe
%% or for events (the Binding Templates' defaults when mqv:controlPacket
%% is left out); a topic with no wildcard; no credentials (nosec).
mqtt_form(Op, Url, F, #{security := Thing}) ->
    Packet = maps:get(<<"mqv:controlPacket">>, F, default_packet(Op)),
    Topic = case uri_string:parse(Url) of
                #{path := <<"/", T/binary>>} -> uri_string:percent_decode(T);
                _ -> <<>>
            end,
    CT = case maps:get(<<"contentType">>, F, <<"application/json">>) of
             <<"application/json", _/binary>> -> {ok, <<"application/json">>};
             <<"text/plain", _/binary>> -> {ok, <<"text/plain">>};
             _ -> error
         end,
    Security = case maps:get(<<"security">>, F, undefined) of
                   undefined -> Thing;
                   _ -> unsupported
               end,
    case {Op, Packet} of
        _ when not is_binary(Topic); Topic =:= <<>> ->
            {error, {bad_href, <<"an MQTT form's href names no topic (mqtt://host:port/topic)">>}};
        _ when Security =/= nosec ->
            {error, {unsupported_security, <<"an MQTT form with credentials is not supported (nosec is)">>}};
        _ when CT =:= error ->
            {error, {unsupported_form, <<"the form's contentType is neither application/json nor text/plain">>}};
        _ ->
            case binary:match(Topic, [<<"+">>, <<"#">>, <<0>>]) of
                nomatch -> mqtt_op(Op, Packet, Url, element(2, CT));
                _ -> {error, {bad_href, <<"an MQTT form's topic has a wildcard (+ or #)">>}}
            end
    end.

mqtt_op(Op, <<"publish">>, Url, CT) when Op =:= invokeaction; Op =:= writeproperty ->
    {ok, #{href => Url, method => <<"PUBLISH">>, content_type => CT, subprotocol => none, security => nosec}};
mqtt_op(Op, <<"subscribe">>, Url, CT) when Op =:= observeproperty; Op =:= subscribeevent ->
    {ok, #{href => Url, method => <<"SUBSCRIBE">>, content_type => CT, subprotocol => mqtt, security => nosec}};
mqtt_op(readproperty, _, _, _) ->
    {error, {unsupported_form, <<"readproperty over MQTT is not supported (observeproperty, a subscribe, is)">>}};
mqtt_op(_, _, _, _) ->
    {error, {unsupported_form, <<"the form's mqv:controlPacket does not fit its op (publish: invokeaction, "
                                 "writeproperty; subscribe: observeproperty, subscribeevent)">>}}.

default_packet(Op) when Op =:= observeproperty; Op =:= subscribeevent -> <<"subscribe">>;
default_packet(_) -> <<"publish">>.

default_method(readproperty) -> <<"GET">>;
default_method(writeproperty) -> <<"PUT">>;
default_method(observeproperty) -> <<"GET">>;
default_method(invokeaction) -> <<"POST">>;
default_method(subscribeevent) -> <<"GET">>.

method(M) when M =:= <<"GET">>; M =:= <<"PUT">>; M =:= <<"POST">>; M =:= <<"DELETE">> -> {ok, M};
method(_) -> error.

subprotocol(Op, undefined) when Op =:= observeproperty; Op =:= subscribeevent -> {ok, longpoll};
subprotocol(_, undefined) -> {ok, none};
subprotocol(_, <<"longpoll">>) -> {ok, longpoll};
subprotocol(_, <<"sse">>) -> {ok, sse};
subprotocol(_, _) -> error.

resolve(Href, Base) ->
    case endpoint(Href) of
        {ok, _, _, _} -> {ok, Href};
        error when is_binary(Base) ->
            case uri_string:resolve(Href, Base) of
                R when is_binary(R) -> {ok, R};
                _ -> error
            end;
        error -> error
    end.

%% Scheme, lowercase host and port of an absolute URL.
endpoint(Url) ->
    case uri_string:parse(Url) of
        #{scheme := S, host := H} = U when is_binary(S), is_binary(H), H =/= <<>> ->
            Scheme = string:lowercase(S),
            Port = case U of
                       #{port := P} when is_integer(P) -> P;
                       _ when Scheme =:= <<"https">> -> 443;
                       _ when Scheme =:= <<"mqtt">> -> 1883;
                       _ -> 80
                   end,
            {ok, Scheme, string:lowercase(H), Port};
        _ -> error
    end.

affordance_problem(Name, {What, Message}) ->
    #{what => What, message => Message, affordance => text(Name)}.

problem(What, Format, Args) ->
    #{what => What, message => iolist_to_binary(io_lib:format(Format, Args))}.

%% A string from the TD as it may appear in a problem: at most ?MAX_NAME
%% bytes, control characters replaced.
text(S) when is_atom(S) -> atom_to_binary(S);
text(S) when is_binary(S) ->
    Clean = << <<(if C < 32; C =:= 127 -> $?; true -> C end)>> || <<C>> <= S >>,
    case unicode:characters_to_binary(Clean) of
        Clean when byte_size(Clean) > ?MAX_NAME -> <<(string:slice(Clean, 0, ?MAX_NAME))/binary, "...">>;
        Clean -> Clean;
        _ -> <<"(not UTF-8)">>
    end;
text(_) -> <<"?">>.

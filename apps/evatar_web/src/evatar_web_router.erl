%% @doc Internal. The server's one cowboy middleware (execute/2, in the
%% request's process): matches method and path against routes/0 (HEAD as
%% GET; OPTIONS answers 204 with `Allow'; another method of a known path
%% the 405 with `Allow'), checks the operator credential
%% (evatar_web_auth), reads the body up to `max_body' (a declared length
%% over it, or a chunked body that passes it, gets the 413 and the
%% connection closes), and calls the route's handler with a request map;
%% any other GET serves a file of priv/www/. Every error is JSON:
%% `{"error": Code, "field": Name | null, "message": Text}'.
%%
%% A handler is `Module:Function(Request)' and returns
%% `{Status, JsonTerm}', `{error, Status, Code, Field, Message}',
%% `{raw, Status, Headers, Body}', or `{done, Req}' for one that answered
%% on the request itself (a stream, with cowboy_req:stream_reply/3).
-module(evatar_web_router).
-behaviour(cowboy_middleware).

-include_lib("kernel/include/logger.hrl").

-export([execute/2, routes/0, match/3, max_body/0]).

-export_type([request/0, reply/0]).

-type request() :: #{method := binary(),
                     path := binary(),
                     bindings := #{binary() => binary()},
                     query := [{binary(), binary() | true}],
                     body := binary(),
                     headers := #{binary() => binary()},
                     req := cowboy_req:req()}.
-type reply() :: {100..599, term()}
               | {error, 400..599, binary(), binary() | null, binary()}
               | {raw, 100..599, [{string(), string()}], iodata()}
               | {done, cowboy_req:req()}.
-type route() :: {binary(), binary(), module(), atom()}.

%% @doc Every route: method, path pattern (a segment `:name' binds
%% `name'), handler module and function. GET is a read; every other
%% method is a change and needs the operator token. Add a route here.
-spec routes() -> [route()].
routes() ->
    [{<<"GET">>, <<"/api/cluster">>, evatar_web_api, cluster},
     %% The node's counters, Prometheus text format (docs/metrics.md).
     {<<"GET">>, <<"/metrics">>, evatar_web_metrics, scrape},
     %% The dashboard's (docs/dashboard.md).
     {<<"GET">>, <<"/api/events">>, evatar_web_events, stream},
     {<<"GET">>, <<"/api/scenes">>, evatar_web_scenes, scenes},
     {<<"GET">>, <<"/api/pairings/:id/graph">>, evatar_web_graph, graph},
     {<<"GET">>, <<"/api/openapi.json">>, evatar_web_api, openapi},
     {<<"GET">>, <<"/api/pairings">>, evatar_web_api, pairings},
     {<<"POST">>, <<"/api/pairings">>, evatar_web_api, create},
     {<<"GET">>, <<"/api/pairings/:id">>, evatar_web_api, pairing},
     {<<"PUT">>, <<"/api/pairings/:id">>, evatar_web_api, change},
     {<<"DELETE">>, <<"/api/pairings/:id">>, evatar_web_api, delete},
     {<<"GET">>, <<"/api/pairings/:id/bindings">>, evatar_web_api, bindings},
     {<<"POST">>, <<"/api/pairings/:id/rotate">>, evatar_web_api, rotate},
     {<<"GET">>, <<"/api/mqtt_avatars">>, evatar_web_api, mqtt_avatars},
     {<<"GET">>, <<"/api/mqtt_avatars/:id">>, evatar_web_api, mqtt_avatar},
     {<<"GET">>, <<"/api/mqtt_avatars/:id/problems">>, evatar_web_api, problems},
     {<<"PUT">>, <<"/api/mqtt_avatars/:id/description">>, evatar_web_api, override_description},
     {<<"GET">>, <<"/api/wot_avatars">>, evatar_web_api, wot_avatars},
     {<<"GET">>, <<"/api/wot_avatars/:id/problems">>, evatar_web_api, wot_problems}]
    ++ evatar_web_things_routes().

%% The Web of Things binding (docs/wot.md).
evatar_web_things_routes() ->
    T = <<"/api/things/:pairing/:entity">>,
    [{<<"GET">>, <<"/.well-known/wot">>, evatar_web_things, well_known},
     {<<"GET">>, <<"/api/things">>, evatar_web_things, list},
     {<<"GET">>, T, evatar_web_things, td},
     {<<"GET">>, <<T/binary, "/properties">>, evatar_web_things, read_all},
     {<<"GET">>, <<T/binary, "/properties/:component/:service">>, evatar_web_things, read},
     {<<"POST">>, <<T/binary, "/actions/:component/:service">>, evatar_web_things, invoke}].

%% @private cowboy's middleware callback: the whole request, answered here.
-spec execute(cowboy_req:req(), cowboy_middleware:env()) -> {stop, cowboy_req:req()}.
execute(Req0, _Env) ->
    %% The body first, whatever the route: a body over the limit gets the
    %% 413 before anything else is decided.
    case body(Req0, max_body()) of
        {ok, Body, Req} ->
            {stop, respond(route(Req, Body), Req)};
        {error, too_large} ->
            #{message := Message} = body_too_large(max_body()),
            %% The rest of the body is never read: the connection closes
            %% after the answer.
            {stop, respond({error, 413, <<"body_too_large">>, null, Message,
                            [{"connection", "close"}]}, Req0)}
    end.

body_too_large(Max) ->
    #{error => <<"body_too_large">>, field => null,
      message => iolist_to_binary(io_lib:format("the request body is larger than the limit ~b bytes "
                                                "(http.max_body, docs/api.md)", [Max]))}.

route(Req, Body) ->
    M = cowboy_req:method(Req),
    Path = cowboy_req:path(Req),
    %% HEAD is GET without the body (cowboy leaves it out).
    Method = case M of
                 <<"HEAD">> -> <<"GET">>;
                 _ -> M
             end,
    case match(Method, Path, routes()) of
        {ok, Module, Function, Bindings} ->
            handle(Method, Path, Bindings, Module, Function, Req, Body);
        {error, method_not_allowed, Allowed} when M =:= <<"OPTIONS">> ->
            {raw, 204, [{"allow", allow(Allowed)}], <<>>};
        {error, method_not_allowed, Allowed} ->
            method_not_allowed(Allowed);
        {error, not_found} ->
            case {Method, static_path(Path)} of
                {<<"GET">>, true} -> static(Path);
                {<<"OPTIONS">>, true} ->
                    case static(Path) of
                        {raw, 200, _, _} -> {raw, 204, [{"allow", allow([<<"GET">>])}], <<>>};
                        NotFound -> NotFound
                    end;
                {_, true} ->
                    case static(Path) of
                        {raw, 200, _, _} -> method_not_allowed([<<"GET">>]);
                        NotFound -> NotFound
                    end;
                {_, false} ->
                    not_found(Path)
            end
    end.

%% The page's files hold no data: open, even where reads of the API need
%% the token.
static_path(<<"/api">>) -> false;
static_path(<<"/api/", _/binary>>) -> false;
static_path(_) -> true.

method_not_allowed(Allowed) ->
    Allow = allow(Allowed),
    {error, 405, <<"method_not_allowed">>, null, iolist_to_binary(["allowed: ", Allow]),
     [{"allow", Allow}]}.

%% The methods of a path as its Allow header: its routes', HEAD with GET,
%% and OPTIONS.
allow(Methods) ->
    Head = [<<"HEAD">> || lists:member(<<"GET">>, Methods)],
    binary_to_list(iolist_to_binary(lists:join(", ", lists:usort(Methods ++ Head ++ [<<"OPTIONS">>])))).

handle(Method, Path, Bindings, Module, Function, Req, Body) ->
    Kind = case Method of
               <<"GET">> -> read;
               _ -> change
           end,
    with_auth(Kind, Req,
              fun() ->
                      call(Module, Function,
                           #{method => Method, path => Path, bindings => Bindings,
                             query => query(Req), body => Body,
                             headers => cowboy_req:headers(Req), req => Req})
              end).

%% The body, at most Max bytes: a declared length over it is refused
%% before a byte is read; a chunked one as soon as it passes the limit.
body(Req, Max) ->
    case cowboy_req:has_body(Req) of
        false -> {ok, <<>>, Req};
        true ->
            case cowboy_req:body_length(Req) of
                N when is_integer(N), N > Max -> {error, too_large};
                _ -> read_body(Req, Max, [], 0)
            end
    end.

read_body(Req, Max, Acc, Size) ->
    {More, Data, Req1} = cowboy_req:read_body(Req, #{length => min(Max + 1 - Size, 65536)}),
    Size1 = Size + byte_size(Data),
    case {More, Size1 > Max} of
        {_, true} -> {error, too_large};
        {ok, false} -> {ok, iolist_to_binary([Acc, Data]), Req1};
        {more, false} -> read_body(Req1, Max, [Acc, Data], Size1)
    end.

%% A query string cowboy cannot parse counts as none.
query(Req) ->
    try cowboy_req:parse_qs(Req)
    catch
        exit:{request_error, qs, _} -> [];
        error:_ -> []
    end.

%% A handler that crashed is our defect, not the client's: it gets a JSON
%% 500 and the log gets the crash; the server goes on.
call(Module, Function, Request) ->
    try
        Module:Function(Request)
    catch
        Class:Reason:Stack ->
            ?LOG_ERROR(#{what => http_handler_crashed, handler => {Module, Function},
                         path => maps:get(path, Request), class => Class, reason => Reason,
                         stacktrace => Stack}),
            {error, 500, <<"internal">>, null,
             <<"the request failed inside the node; its log has the details">>}
    end.

with_auth(Kind, Req, Fun) ->
    case evatar_web_auth:check(Kind, header(<<"authorization">>, Req), header(<<"host">>, Req)) of
        ok -> Fun();
        {error, Status, Code, Message} -> {error, Status, Code, null, Message}
    end.

header(Name, Req) ->
    case cowboy_req:header(Name, Req) of
        undefined -> undefined;
        V -> binary_to_list(V)
    end.

%% @doc The body limit in bytes (`max_body'), of the running server or
%% else of the environment.
-spec max_body() -> pos_integer().
max_body() ->
    case evatar_web_server:info() of
        #{max_body := M} -> M;
        undefined -> application:get_env(evatar_web, max_body, 1048576)
    end.

not_found(Path) ->
    {error, 404, <<"not_found">>, null, <<"no such route or file: ", Path/binary>>}.

%% @doc Pure: the route of a method and a (percent-encoded) path.
-spec match(binary(), binary(), [route()]) ->
          {ok, module(), atom(), #{binary() => binary()}}
        | {error, not_found} | {error, method_not_allowed, [binary()]}.
match(Method, Path, Routes) ->
    Segments = segments(Path),
    Matching = [{M, Mod, F, B} || {M, Pattern, Mod, F} <- Routes,
                                  {ok, B} <- [bind(segments(Pattern), Segments, #{})]],
    case [X || {M, _, _, _} = X <- Matching, M =:= Method] of
        [{_, Mod, F, B} | _] -> {ok, Mod, F, B};
        [] when Matching =:= [] -> {error, not_found};
        [] -> {error, method_not_allowed, lists:usort([M || {M, _, _, _} <- Matching])}
    end.

segments(Path) ->
    [S || S <- binary:split(Path, <<"/">>, [global]), S =/= <<>>].

bind([], [], Acc) -> {ok, Acc};
bind([<<":", Name/binary>> | Ps], [S | Ss], Acc) ->
    case uri_string:percent_decode(S) of
        {error, _} -> error;
        Value when is_binary(Value) -> bind(Ps, Ss, Acc#{Name => Value})
    end;
bind([P | Ps], [P | Ss], Acc) -> bind(Ps, Ss, Acc);
bind(_, _, _) -> error.

%% ---------------------------------------------------------------------------
%% Static files of priv/www/: no directory listing, no `..', known types only.
%% ---------------------------------------------------------------------------

static(Path) ->
    Segments = [uri_string:percent_decode(S) || S <- segments(Path)],
    Safe = lists:all(fun(S) when is_binary(S) ->
                             S =/= <<"..">> andalso S =/= <<".">> andalso
                                 binary:match(S, [<<"/">>, <<"\\">>, <<0>>]) =:= nomatch;
                        (_) -> false
                     end, Segments),
    Rel = case Segments of
              [] -> [<<"index.html">>];
              _ -> Segments
          end,
    File = filename:join([code:priv_dir(evatar_web), "www" | Rel]),
    case Safe andalso content_type(filename:extension(File)) of
        false ->
            not_found(Path);
        undefined ->
            not_found(Path);
        Type ->
            case file:read_file(File) of
                {ok, Bin} -> {raw, 200, [{"content-type", Type}, {"cache-control", "no-cache"}], Bin};
                {error, _} -> not_found(Path)
            end
    end.

content_type(Ext) ->
    case string:lowercase(unicode:characters_to_list(Ext)) of
        ".html" -> "text/html; charset=utf-8";
        ".js" -> "text/javascript; charset=utf-8";
        ".mjs" -> "text/javascript; charset=utf-8";
        ".css" -> "text/css; charset=utf-8";
        ".json" -> "application/json";
        ".svg" -> "image/svg+xml";
        ".png" -> "image/png";
        ".jpg" -> "image/jpeg";
        ".ico" -> "image/x-icon";
        ".txt" -> "text/plain; charset=utf-8";
        ".woff2" -> "font/woff2";
        _ -> undefined
    end.

%% ---------------------------------------------------------------------------
%% Responses
%% ---------------------------------------------------------------------------

respond({done, Req}, _Req0) ->
    Req;
respond({raw, Status, Headers, Body}, Req) ->
    B = iolist_to_binary(Body),
    Length = case Status of
                 204 -> #{};
                 %% Set here for HEAD, whose body cowboy leaves out.
                 _ -> #{<<"content-length">> => integer_to_binary(byte_size(B))}
             end,
    Head = maps:merge(Length#{<<"x-content-type-options">> => <<"nosniff">>,
                              <<"referrer-policy">> => <<"no-referrer">>},
                      maps:from_list([{list_to_binary(K), list_to_binary(V)} || {K, V} <- Headers])),
    cowboy_req:reply(Status, Head, B, Req);
respond({error, Status, Code, Field, Message}, Req) ->
    respond({error, Status, Code, Field, Message, []}, Req);
respond({error, Status, Code, Field, Message, Extra}, Req) ->
    json(Status, #{error => Code, field => Field, message => Message},
         case Status of
             401 -> [{"www-authenticate", "Bearer realm=\"evatar\""} | Extra];
             _ -> Extra
         end, Req);
respond({Status, Term}, Req) when is_integer(Status) ->
    json(Status, Term, [], Req).

json(Status, Term, Extra, Req) ->
    respond({raw, Status, [{"content-type", "application/json"}, {"cache-control", "no-store"} | Extra],
             evatar_json:encode(Term)}, Req).

%% @doc Internal. The one httpd module of the server (its `do/1' callback):
%% matches method and path against routes/0, checks the operator
%% credential (evatar_web_auth), and calls the route's handler with a
%% request map; any other GET serves a file of priv/www/. Every error is
%% JSON: `{"error": Code, "field": Name | null, "message": Text}'.
%%
%% A handler is `Module:Function(Request)' and returns
%% `{Status, JsonTerm}', `{error, Status, Code, Field, Message}',
%% `{raw, Status, Headers, Body}', or `{proceed, HttpdData}' for one that
%% answered on the socket itself (a stream).
-module(evatar_web_router).

-include_lib("inets/include/httpd.hrl").
-include_lib("kernel/include/logger.hrl").

-export([do/1, routes/0, match/3, max_body/0]).

-export_type([request/0, reply/0]).

-type request() :: #{method := binary(),
                     path := binary(),
                     bindings := #{binary() => binary()},
                     query := [{binary(), binary() | true}],
                     body := binary(),
                     headers := [{string(), string()}],
                     mod := #mod{}}.
-type reply() :: {100..599, term()}
               | {error, 400..599, binary(), binary() | null, binary()}
               | {raw, 100..599, [{string(), string()}], iodata()}
               | {proceed, list()}.
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
     {<<"PUT">>, <<"/api/mqtt_avatars/:id/description">>, evatar_web_api, override_description}]
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

%% @private
-spec do(#mod{}) -> {proceed, list()}.
do(#mod{parsed_header = Headers} = Mod) ->
    ok = nodelay(Mod),
    case header(evatar_web_limit:too_large_header(), Headers) of
        undefined -> route(Mod);
        Declared -> too_large(Declared, Mod)
    end.

%% httpd writes a response's head and body in two sends: with Nagle's
%% algorithm the body waited for the client's delayed ACK (about 40 ms a
%% request on a kept-alive connection). Set on every request (one
%% setsockopt), since httpd gives no hook at accept.
nodelay(#mod{socket_type = ip_comm, socket = Socket}) ->
    _ = inet:setopts(Socket, [{nodelay, true}]),
    ok;
nodelay(#mod{socket = Socket}) ->
    _ = ssl:setopts(Socket, [{nodelay, true}]),
    ok.

%% httpd has not read the body (evatar_web_limit renamed its length): the
%% answer goes out here with `connection: close' and the socket is closed,
%% so the unread body is never parsed as a next request.
too_large(Declared, #mod{socket_type = Type, socket = Socket} = Mod) ->
    Max = max_body(),
    case string:to_integer(string:trim(Declared)) of
        {N, []} when is_integer(N), N > Max ->
            Body = evatar_web_json:encode(body_too_large(Max)),
            Size = byte_size(Body),
            Head = ["HTTP/1.1 413 Request Entity Too Large\r\n",
                    "content-type: application/json\r\n",
                    "cache-control: no-store\r\n",
                    "x-content-type-options: nosniff\r\n",
                    "connection: close\r\n",
                    "content-length: ", integer_to_list(Size), "\r\n\r\n"],
            _ = httpd_socket:deliver(Type, Socket, [Head, Body]),
            _ = httpd_socket:close(Type, Socket),
            {proceed, [{response, {already_sent, 413, Size}}]};
        _ ->
            %% Sent by the client itself, not renamed: it means nothing.
            route(Mod)
    end.

body_too_large(Max) ->
    #{error => <<"body_too_large">>, field => null,
      message => iolist_to_binary(io_lib:format("the request body is larger than the limit ~b bytes "
                                                "(http.max_body, docs/api.md)", [Max]))}.

route(#mod{method = Method, request_uri = Uri} = Mod) ->
    {Path, Query} = split_uri(Uri),
    M = list_to_binary(Method),
    Reply = case match(M, Path, routes()) of
                {ok, Module, Function, Bindings} ->
                    handle(M, Path, Query, Bindings, Module, Function, Mod);
                {error, method_not_allowed, Allowed} ->
                    {error, 405, <<"method_not_allowed">>, null,
                     iolist_to_binary(["allowed: ", lists:join(", ", Allowed)])};
                {error, not_found} when M =:= <<"GET">>, not (Path =:= <<"/api">>) ->
                    case binary:match(Path, <<"/api/">>) of
                        {0, _} -> not_found(Path);
                        %% The page's files hold no data: open, even where
                        %% reads of the API need the token.
                        _ -> static(Path)
                    end;
                {error, not_found} ->
                    not_found(Path)
            end,
    respond(Reply).

handle(Method, Path, Query, Bindings, Module, Function, Mod) ->
    Kind = case Method of
               <<"GET">> -> read;
               _ -> change
           end,
    with_auth(Kind, Mod,
              fun() ->
                      Body = iolist_to_binary(Mod#mod.entity_body),
                      Max = max_body(),
                      case byte_size(Body) > Max of
                          true ->
                              #{message := Message} = body_too_large(Max),
                              {error, 413, <<"body_too_large">>, null, Message};
                          false ->
                              call(Module, Function,
                                   #{method => Method, path => Path, bindings => Bindings,
                                     query => Query, body => Body,
                                     headers => Mod#mod.parsed_header, mod => Mod})
                      end
              end).

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

with_auth(Kind, #mod{parsed_header = Headers}, Fun) ->
    case evatar_web_auth:check(Kind, header("authorization", Headers), header("host", Headers)) of
        ok -> Fun();
        {error, Status, Code, Message} -> {error, Status, Code, null, Message}
    end.

header(Name, Headers) ->
    case lists:keyfind(Name, 1, Headers) of
        {_, V} -> V;
        false -> undefined
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

split_uri(Uri) ->
    {Path, Q} = case string:split(Uri, "?") of
                    [P] -> {P, ""};
                    [P, Rest] -> {P, Rest}
                end,
    Query = case uri_string:dissect_query(Q) of
                L when is_list(L) -> [{unicode:characters_to_binary(K), value(V)} || {K, V} <- L];
                {error, _, _} -> []
            end,
    {unicode:characters_to_binary(Path), Query}.

value(true) -> true;
value(V) -> unicode:characters_to_binary(V).

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

respond({proceed, Data}) ->
    {proceed, Data};
respond({raw, Status, Headers, Body}) ->
    B = iolist_to_binary(Body),
    Head = [{code, Status}, {content_length, integer_to_list(byte_size(B))},
            {"x-content-type-options", "nosniff"}, {"referrer-policy", "no-referrer"}
            | [{K, V} || {K, V} <- Headers, K =/= "content-type"]]
        ++ [{content_type, V} || {"content-type", V} <- Headers],
    {proceed, [{response, {response, Head, [B]}}]};
respond({error, Status, Code, Field, Message}) ->
    json(Status, #{error => Code, field => Field, message => Message},
         case Status of
             401 -> [{"www-authenticate", "Bearer realm=\"evatar\""}];
             _ -> []
         end);
respond({Status, Term}) when is_integer(Status) ->
    json(Status, Term, []).

json(Status, Term, Extra) ->
    respond({raw, Status, [{"content-type", "application/json"}, {"cache-control", "no-store"} | Extra],
             evatar_web_json:encode(Term)}).

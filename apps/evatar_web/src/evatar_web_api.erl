%% @doc Internal. The handlers of the /api/... routes (evatar_web_router's
%% table): each turns a request into a call of evatar_ops and its answer
%% into a status and JSON. Request and response shapes: docs/api.md.
-module(evatar_web_api).

-export([cluster/1, openapi/1, pairings/1, create/1, pairing/1, change/1, delete/1, bindings/1,
         rotate/1, mqtt_avatars/1, mqtt_avatar/1, problems/1, override_description/1,
         wot_avatars/1, wot_problems/1]).

-type request() :: evatar_web_router:request().
-type reply() :: evatar_web_router:reply().

%% @doc GET /api/cluster
-spec cluster(request()) -> reply().
cluster(_Req) ->
    {200, evatar_ops:cluster()}.

%% @doc GET /api/openapi.json: the API's description (OpenAPI 3.0).
-spec openapi(request()) -> reply().
openapi(_Req) ->
    {ok, Bin} = file:read_file(filename:join(code:priv_dir(evatar_web), "openapi.json")),
    {raw, 200, [{"content-type", "application/json"}], Bin}.

%% @doc GET /api/pairings
-spec pairings(request()) -> reply().
pairings(_Req) ->
    {200, evatar_ops:pairings()}.

%% @doc POST /api/pairings {"id": ..., options}
-spec create(request()) -> reply().
create(Req) ->
    with_body(Req, fun(#{<<"id">> := Id} = Body) -> reply(201, evatar_ops:create(Id, Body));
                      (Body) when is_map(Body) ->
                           {error, 400, <<"bad_request">>, <<"id">>, <<"id is required">>};
                      (_) ->
                           {error, 400, <<"bad_request">>, null, <<"the body must be a JSON object">>}
                   end).

%% @doc GET /api/pairings/:id
-spec pairing(request()) -> reply().
pairing(Req) ->
    reply(200, evatar_ops:pairing(id(Req))).

%% @doc PUT /api/pairings/:id {options}
-spec change(request()) -> reply().
change(Req) ->
    with_body(Req, fun(Body) -> reply(200, evatar_ops:change(id(Req), Body)) end).

%% @doc DELETE /api/pairings/:id
-spec delete(request()) -> reply().
delete(Req) ->
    case evatar_ops:delete(id(Req)) of
        ok -> {200, #{id => id(Req), deleted => true}};
        Error -> reply(200, Error)
    end.

%% @doc GET /api/pairings/:id/bindings
-spec bindings(request()) -> reply().
bindings(Req) ->
    reply(200, evatar_ops:bindings(id(Req))).

%% @doc POST /api/pairings/:id/rotate {"role": ...} | {"entity": ...}
-spec rotate(request()) -> reply().
rotate(Req) ->
    with_body(Req, fun(Body) -> reply(200, evatar_ops:rotate(id(Req), Body)) end).

%% @doc GET /api/mqtt_avatars
-spec mqtt_avatars(request()) -> reply().
mqtt_avatars(_Req) ->
    {200, evatar_ops:mqtt_avatars()}.

%% @doc GET /api/mqtt_avatars/:id
-spec mqtt_avatar(request()) -> reply().
mqtt_avatar(Req) ->
    reply(200, evatar_ops:mqtt_avatar(id(Req))).

%% @doc GET /api/mqtt_avatars/:id/problems
-spec problems(request()) -> reply().
problems(Req) ->
    reply(200, evatar_ops:problems(id(Req))).

%% @doc PUT /api/mqtt_avatars/:id/description {"xml": ...} | {"overrides": ...}
-spec override_description(request()) -> reply().
override_description(Req) ->
    with_body(Req, fun(Body) -> reply(200, evatar_ops:override_description(id(Req), Body)) end).

%% @doc GET /api/wot_avatars
-spec wot_avatars(request()) -> reply().
wot_avatars(_Req) ->
    {200, evatar_ops:wot_avatars()}.

%% @doc GET /api/wot_avatars/:id/problems
-spec wot_problems(request()) -> reply().
wot_problems(Req) ->
    reply(200, evatar_ops:wot_problems(id(Req))).

id(#{bindings := #{<<"id">> := Id}}) -> Id.

reply(Status, {ok, Value}) -> {Status, Value};
reply(_, {error, #{status := S, error := C, field := F, message := M}}) -> {error, S, C, F, M}.

with_body(#{body := Body}, Fun) ->
    %% The router bounded the body (max_body); the depth limit stays.
    case evatar_json:decode(Body, #{max_size => max(byte_size(Body), 1)}) of
        {ok, Term} -> Fun(Term);
        {error, R} -> {error, 400, <<"bad_json">>, null, <<"the body: ", (evatar_json:format_error(R))/binary>>}
    end.

%% @doc Internal. The handlers of the /api/... routes (evatar_web_router's
%% table): each turns a request into a call of evatar_ops and its answer
%% into a status and JSON. Request and response shapes: docs/api.md.
-module(evatar_web_api).

-export([cluster/1]).

%% @doc GET /api/cluster
-spec cluster(evatar_web_router:request()) -> evatar_web_router:reply().
cluster(_Req) ->
    {200, evatar_ops:cluster()}.

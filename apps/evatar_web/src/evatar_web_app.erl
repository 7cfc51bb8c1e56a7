%% @doc Internal. The evatar_web application: starts evatar_web_sup, which
%% runs the HTTP server unless the environment's `enabled' is false.
-module(evatar_web_app).
-behaviour(application).

-export([start/2, stop/1]).

%% @private
-spec start(application:start_type(), term()) -> {ok, pid()} | {error, term()}.
start(_Type, _Args) ->
    evatar_web_sup:start_link().

%% @private
-spec stop(term()) -> ok.
stop(_State) ->
    ok.

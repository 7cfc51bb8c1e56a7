%% @doc Internal. Application callback: starts the supervisor under which
%% {@link wot_avatar:start/1} and {@link wot_avatar:keep/1} run WoT Avatars.
-module(wot_avatar_app).
-behaviour(application).

-export([start/2, stop/1]).

-spec start(application:start_type(), term()) -> {ok, pid()} | {error, term()}.
start(_Type, _Args) ->
    wot_avatar_sup:start_link().

-spec stop(term()) -> ok.
stop(_State) ->
    ok.

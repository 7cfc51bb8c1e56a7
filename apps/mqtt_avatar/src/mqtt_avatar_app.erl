%% @doc Internal. Application callback: starts the supervisor under which
%% {@link mqtt_avatar:start/1} runs MQTT Avatars.
-module(mqtt_avatar_app).
-behaviour(application).

-export([start/2, stop/1]).

-spec start(application:start_type(), term()) -> {ok, pid()} | {error, term()}.
start(_Type, _Args) ->
    mqtt_avatar_sup:start_link().

-spec stop(term()) -> ok.
stop(_State) ->
    ok.

%% @doc Internal. Application callback of avatar_sim: starts the top
%% supervisor; Avatars and clocks are started at run time through
%% `avatar_sim'.
-module(avatar_sim_app).
-behaviour(application).

-export([start/2, stop/1]).

-spec start(application:start_type(), term()) -> {ok, pid()}.
start(_Type, _Args) -> avatar_sim_sup:start_link().

-spec stop(term()) -> ok.
stop(_State) -> ok.

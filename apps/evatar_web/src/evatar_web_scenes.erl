%% @doc Internal. `GET /api/scenes': the simulated worlds and agents' views
%% running on this node, for the dashboard's floor plan and arena
%% (docs/dashboard.md). Any loaded application may name a function returning
%% a list of JSON-ready scenes under its environment key `dashboard_scenes'
%% (`{Module, Function, Args}'); avatar_sim and evatar_demo do. So
%% evatar_web depends on neither, and neither on evatar_web.
-module(evatar_web_scenes).

-include_lib("kernel/include/logger.hrl").

-export([scenes/1, all/0]).

%% @doc The route's handler (evatar_web_router).
-spec scenes(evatar_web_router:request()) -> evatar_web_router:reply().
scenes(_Req) ->
    {200, #{scenes => all()}}.

%% @doc Every scene of every application that names a source, in the
%% order of the applications' names.
-spec all() -> [map()].
all() ->
    Sources = lists:sort([{App, MFA} || {App, _, _} <- application:loaded_applications(),
                                        {ok, {_, _, _} = MFA} <- [application:get_env(App, dashboard_scenes)]]),
    lists:append([call(App, MFA) || {App, MFA} <- Sources]).

%% A source whose application is loaded and not running (its processes
%% absent) gives nothing; one that fails is logged and skipped.
call(App, {M, F, A}) when is_atom(M), is_atom(F), is_list(A) ->
    try apply(M, F, A) of
        Scenes when is_list(Scenes) -> [S#{source => atom_to_binary(App)} || S <- Scenes, is_map(S)];
        _ -> []
    catch
        exit:{noproc, _} ->
            [];
        Class:Reason ->
            ?LOG_NOTICE(#{what => dashboard_scene_failed, app => App, class => Class,
                          reason => Reason}),
            []
    end;
call(_App, _Bad) ->
    [].

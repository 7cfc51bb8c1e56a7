%% @doc Internal. The evatar application: starts the supervision tree, then
%% makes sure the cluster has the pairings listed in the application
%% environment (created when absent: `evatar:ensure_pairing/2')
%% (`{evatar, [{pairings, [#{id => <<"home">>, agent_credential => ...,
%% avatar_credential => ...}]}]}').
%% An existing pairing is left as it is; a malformed entry stops the
%% application's start (`{bad_pairing_config, Id, Reason}'), so mistakes
%% show at boot. The node configuration file (node_config) fills this list.
-module(evatar_app).
-behaviour(application).

-export([start/2, stop/1]).

%% @private
-spec start(application:start_type(), term()) -> {ok, pid()} | {error, term()}.
start(_Type, _Args) ->
    ok = evatar_metrics:init_counters(),
    case evatar_sup:start_link() of
        {ok, Sup} ->
            case start_configured(application:get_env(evatar, pairings, [])) of
                ok -> {ok, Sup};
                {error, _} = Error -> Error
            end;
        {error, _} = Error ->
            Error
    end.

%% @private
-spec stop(term()) -> ok.
stop(_State) ->
    ok.

%% A bad entry stops the application from starting: configuration mistakes
%% are found when the node boots, not when the first client is refused.
start_configured([#{id := Id} = Spec | Rest]) ->
    Opts = maps:remove(id, Spec),
    case evatar:ensure_pairing(Id, Opts) of
        %% Created when absent (exists: the catalogue or an alive node has it).
        {ok, _} -> start_configured(Rest);
        {error, Reason} -> {error, {bad_pairing_config, Id, Reason}}
    end;
start_configured([Other | _]) ->
    {error, {bad_pairing_config, Other, missing_id}};
start_configured([]) ->
    ok;
start_configured(Other) ->
    {error, {bad_pairing_config, Other, not_a_list}}.

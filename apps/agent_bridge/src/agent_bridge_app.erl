%% @doc Internal. Starts the bridge's supervision tree.
-module(agent_bridge_app).
-behaviour(application).

-export([start/2, stop/1]).

-spec start(application:start_type(), term()) -> {ok, pid()} | {error, term()}.
start(_Type, _Args) ->
    %% The connections held now, as a gauge of evatar's /metrics.
    ok = evatar_metrics:add_collector({agent_bridge, metrics}),
    agent_bridge_sup:start_link().

-spec stop(term()) -> ok.
stop(_State) ->
    ok.

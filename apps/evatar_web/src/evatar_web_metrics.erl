%% @doc Internal. `GET /metrics': the node's counters in the Prometheus text
%% format (evatar_metrics, docs/metrics.md). A read like the API's: open on
%% a loopback listener, the operator token otherwise.
-module(evatar_web_metrics).

-export([scrape/1]).

%% @doc The exposition, version 0.0.4.
-spec scrape(evatar_web_router:request()) -> evatar_web_router:reply().
scrape(_Request) ->
    {raw, 200, [{"content-type", "text/plain; version=0.0.4; charset=utf-8"}],
     evatar_metrics:render()}.

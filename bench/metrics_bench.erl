%% @doc The cost of counting one routed signal (evatar_metrics:pairing_step/3
%% with the effects of a routed sensor reading): with the pairing's own
%% counters and the node's, with the node's only, and an empty loop for
%% comparison; three rounds of 5,000,000 calls. Not part of the product;
%% bench/EVATAR_BENCH.md, "Metrics", gives the figures.
-module(metrics_bench).

-export([main/0]).

-define(N, 5000000).

%% @doc Prints ns per call, three rounds.
-spec main() -> ok.
main() ->
    {ok, _} = evatar_metrics:start_link(),
    {Node, _} = Both = evatar_metrics:pairing(<<"bench">>),
    NodeOnly = {Node, undefined},
    Signal = #{context => sensor_data, id => <<"s1">>, sender => <<"Thermo01">>,
               receiver => <<"ThermoEmulator01">>},
    Effects = [{deliver, <<"va">>, Signal}, {accepted, <<"av">>, <<"s1">>}],
    Event = {signal, <<"av">>, Signal},
    lists:foreach(
      fun(Round) ->
              Empty = ns(fun() -> ok end),
              Full = ns(fun() -> evatar_metrics:pairing_step(Both, Event, Effects) end),
              Totals = ns(fun() -> evatar_metrics:pairing_step(NodeOnly, Event, Effects) end),
              io:format("round ~b: node + pairing ~.1f ns, node only ~.1f ns, empty loop ~.1f ns "
                        "per call; load average ~s~n",
                        [Round, Full, Totals, Empty, load()])
      end, [1, 2, 3]).

ns(F) ->
    {T, ok} = timer:tc(fun() -> loop(?N, F) end),
    T * 1000 / ?N.

loop(0, _F) -> ok;
loop(N, F) -> _ = F(), loop(N - 1, F).

load() ->
    case file:read_file("/proc/loadavg") of
        {ok, B} -> hd(string:split(string:trim(B), " "));
        {error, _} -> "?"
    end.

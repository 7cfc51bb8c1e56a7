#!/usr/bin/env bash
# Runs the failover benchmark (bench/failover_bench.erl): failover time after
# kill -9 and after a silent stall (SIGSTOP) of the active's node, p50 and
# p99 over 50 trials each, and the cost of TLS distribution. It starts its
# own nodes (real OS processes named fo*@127.0.0.1, fb*@127.0.0.1) on
# loopback ports chosen at run time, and stops them at the end.
# Usage: scripts/bench-failover.sh [ERLANG_OPTION_LIST]
#   scripts/bench-failover.sh                       # everything (about 5 minutes)
#   scripts/bench-failover.sh '[quick]'             # smoke run (5 trials)
#   scripts/bench-failover.sh '[{trials, 100}, kill]'
# Honours REBAR (default rebar3) and REBAR_BASE_DIR (default _build).
set -euo pipefail
cd "$(dirname "$0")/.."

REBAR=${REBAR:-rebar3}
BASE=${REBAR_BASE_DIR:-_build}
OPTS=${1:-[]}

"$REBAR" as bench compile

# The benchmark drives the cluster with the multi-node test support of
# test/ (ha_cluster and friends); the nodes load it from the same place.
OUT="$BASE/bench/extras/failover"
mkdir -p "$OUT"
erlc -o "$OUT" test/ha_cluster.erl test/ha_proxy.erl test/ha_epmd.erl \
  test/ha_traffic.erl test/ha_pairing.erl test/ha_checker.erl bench/failover_bench.erl

exec erl -noshell -pa "$BASE"/bench/lib/*/ebin -pa "$OUT" \
  -eval "try failover_bench:main($OPTS) of
           ok -> halt(0)
         catch C:R:S ->
           io:format(standard_error, \"failover_bench failed: ~p:~p~n~p~n\", [C, R, S]),
           halt(1)
         end."

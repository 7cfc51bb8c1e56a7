#!/usr/bin/env bash
# Runs the failover storm benchmark (bench/storm_bench.erl): kill -9 of the
# node holding the actives of N pairings with traffic, on three real
# OS-process nodes (st*@127.0.0.1) on loopback ports chosen at run time;
# per pairing the time until a round trip is served by its new active,
# the time until every pairing has a synced standby again, and the
# checker's lost and duplicated counts. Stops its nodes at the end.
# Usage: scripts/bench-storm.sh [ERLANG_OPTION_LIST]
#   scripts/bench-storm.sh                          # N = 1000
#   scripts/bench-storm.sh '[quick]'                # smoke run (N = 50)
#   scripts/bench-storm.sh '[{pairings, [1000, 5000]}]'
# Honours REBAR (default rebar3) and REBAR_BASE_DIR (default _build).
set -euo pipefail
# shellcheck source=scripts/bench-lib.sh
source "$(dirname "$0")/bench-lib.sh"
OPTS=${1:-[]}
bench_compile
# 2N clients and their nodes' connections: more ports than the default.
ulimit -n 65536 2>/dev/null || true
run_bench storm_bench "$OPTS" +Q 262144

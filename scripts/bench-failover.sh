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
# shellcheck source=scripts/bench-lib.sh
source "$(dirname "$0")/bench-lib.sh"
OPTS=${1:-[]}

# The cluster harness (evatar_test_cluster and its helpers) is the test
# kit's, built with the bench profile; the nodes load it from there.
bench_compile
run_bench failover_bench "$OPTS"

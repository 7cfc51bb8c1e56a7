#!/usr/bin/env bash
# Runs the isolation benchmark (bench/flood_bench.erl; how to read it:
# bench/README.md, "Isolation"). One node, real loopback TCP through
# agent_bridge: 1,000 pairings in an open loop, in rounds without and
# with a flooded pairing of each kind.
# Usage: scripts/bench-flood.sh [ERLANG_OPTION_LIST]
#   scripts/bench-flood.sh                       # the full run (about 4 minutes)
#   scripts/bench-flood.sh '[quick]'             # smoke run
#   scripts/bench-flood.sh '[{rounds, 5}, {rate, 4000}]'
# Honours REBAR (default rebar3) and REBAR_BASE_DIR (default _build).
set -euo pipefail
# shellcheck source=scripts/bench-lib.sh
source "$(dirname "$0")/bench-lib.sh"
OPTS=${1:-[]}

bench_compile

# Both ends of 1,000 pairings in this node: 4,000 sockets.
if [ "$(ulimit -n)" != unlimited ] && [ "$(ulimit -n)" -lt 8192 ]; then
  ulimit -n "$(ulimit -Hn)" 2>/dev/null || true
fi
# The scheduler flags of config/vm.args, as bench-evatar.
SCHED=${EVATAR_BENCH_SCHED_FLAGS-+sbwt none +sbwtdcpu none +sbwtdio none}
# shellcheck disable=SC2086
run_bench flood_bench "$OPTS" +P 2000000 +Q 1000000 $SCHED

#!/usr/bin/env bash
# Runs the mediator benchmark (bench/evatar_bench.erl; how to read it:
# bench/README.md). One node, real loopback TCP through agent_bridge.
# Usage: scripts/bench-evatar.sh [ERLANG_OPTION_LIST]
#   scripts/bench-evatar.sh                      # the full run (about 11 minutes)
#   scripts/bench-evatar.sh '[quick]'            # smoke run
#   scripts/bench-evatar.sh '[{sizes, [1000]}, {modes, [raw]}, no_idle]'
# Honours REBAR (default rebar3) and REBAR_BASE_DIR (default _build).
set -euo pipefail
# shellcheck source=scripts/bench-lib.sh
source "$(dirname "$0")/bench-lib.sh"
OPTS=${1:-[]}

# 10,000 idle pairings with both ends in this node hold 40,000 sockets.
# Raise the open-file limit if the hard limit allows; otherwise the
# benchmark binds as many as fit and says so in its output.
WANT=100000
if ! ulimit -n "$WANT" 2>/dev/null; then
  hard=$(ulimit -Hn)
  if [ "$hard" != unlimited ] && [ "$hard" -gt "$(ulimit -n)" ]; then
    ulimit -n "$hard"
  fi
  echo "NOTE: cannot raise the open-file limit to $WANT (hard limit: $hard); running with" \
       "ulimit -n $(ulimit -n). The idle measurement will bind fewer than 10,000 pairings" \
       "and say how many." >&2
fi

bench_compile

# +P and +Q: room for 10,000 pairings (six processes and four sockets
# each, both ends in this node).
# The scheduler flags of config/vm.args (the release's); override with
# EVATAR_BENCH_SCHED_FLAGS (e.g. "" for the VM's defaults) to compare.
SCHED=${EVATAR_BENCH_SCHED_FLAGS-+sbwt none +sbwtdcpu none +sbwtdio none}
# shellcheck disable=SC2086
run_bench evatar_bench "$OPTS" +P 2000000 +Q 1000000 $SCHED

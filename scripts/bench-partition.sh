#!/usr/bin/env bash
# Runs the partition benchmark (bench/partition_bench.erl): the longest time
# a majority-side pairing goes without a round trip, for a node cut from the
# other nodes, a node cut from everything and one link cut, each after a
# first partition that left a stale promise behind (docs/ha-design.md
# section 5), on this build and on the build before the fix of that
# freeze, side by side. Every node is an OS process in a network namespace
# of its own (test/evatar_test_netns.erl): needs root and iproute2's `ip'.
# Usage: scripts/bench-partition.sh [ERLANG_OPTION_LIST]
#   scripts/bench-partition.sh                  # three kinds, 8 s partitions (about 5 minutes)
#   scripts/bench-partition.sh '[quick]'        # one kind, 3 s partitions
#   scripts/bench-partition.sh '[{trials, 3}]'
# EVATAR_BEFORE: the git revision to compare with (default: the parent of the
# commit that made an active re-elect itself above a stale promise); `none'
# runs this build only. Honours REBAR (default rebar3) and REBAR_BASE_DIR
# (default _build); the earlier build is kept in $REBAR_BASE_DIR/partition-before/.
set -euo pipefail
# shellcheck source=scripts/bench-lib.sh
source "$(dirname "$0")/bench-lib.sh"
OPTS=${1:-[]}

bench_compile

BEFORE=none
REV=${EVATAR_BEFORE:-}
if [ -z "$REV" ]; then
  FIX=$(git log -1 --format=%H --fixed-strings --grep='re-elects itself above a stale promise' 2>/dev/null || true)
  [ -n "$FIX" ] && REV="$FIX^"
fi
if [ -n "$REV" ] && [ "$REV" != none ]; then
  SHORT=$(git rev-parse --short "$REV")
  BEFORE="$(pwd)/$BASE/partition-before/$SHORT"
  if [ ! -d "$BEFORE/_build/default/lib/evatar/ebin" ]; then
    echo "building $REV ($SHORT) in $BEFORE"
    rm -rf "$BEFORE"; mkdir -p "$BEFORE"
    git archive "$REV" | tar -x -C "$BEFORE"
    (cd "$BEFORE" && env -u REBAR_BASE_DIR "$REBAR" compile > build.log 2>&1) \
      || { echo "the earlier build failed: $BEFORE/build.log"; exit 1; }
  fi
fi

if [ "$BEFORE" = none ]; then ARGS="$OPTS"; else ARGS="[{before, \"$BEFORE\"} | $OPTS]"; fi
run_bench partition_bench "$ARGS"

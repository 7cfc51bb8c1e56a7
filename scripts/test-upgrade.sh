#!/usr/bin/env bash
# Tests a rolling upgrade from the previous release and the replacement of a
# dead machine (bench/upgrade_bench.erl, docs/ha.md section 8) on real
# release nodes started by scripts/cluster.sh (names upg1..3@127.0.0.1,
# ports chosen at random from 17600 up). Builds the previous release from
# git (EVATAR_PREV_REF, default 1900927: the last commit before the TLS
# listener, node_config and data-directory changes of 2026-12-02) in a
# worktree under _build/upgrade/prev, once, and the current tree's release.
# Takes about 2 minutes plus the first build (about 1 minute).
# Usage: scripts/test-upgrade.sh        (or make test-upgrade)
# Honours REBAR (default rebar3), REBAR_BASE_DIR (default _build),
# EVATAR_PREV_REL (an already built old release: no build).
set -euo pipefail
# shellcheck source=scripts/bench-lib.sh
source "$(dirname "$0")/bench-lib.sh"
PREV=${EVATAR_PREV_REF:-1900927}
WORK=$(realpath -m "$BASE/upgrade")
OLD=${EVATAR_PREV_REL:-$WORK/prev/_build/default/rel/evatar}
if [ ! -x "$OLD/bin/evatar" ]; then
  echo "test-upgrade: building the previous release ($PREV) in $WORK/prev"
  rm -rf "$WORK/prev"
  git worktree prune
  git worktree add --detach "$WORK/prev" "$PREV" >/dev/null
  mkdir -p "$WORK/prev/_build/default"
  cp -a "$BASE/default/lib" "$WORK/prev/_build/default/" 2>/dev/null || true
  (cd "$WORK/prev" && "$REBAR" release >/dev/null)
fi
echo "test-upgrade: building the current release"
"$REBAR" release >/dev/null
NEW=$(realpath "$BASE/default/rel/evatar")
bench_compile >/dev/null
run_bench upgrade_bench "[{old, \"$OLD\"}, {new, \"$NEW\"}, {dir, \"$WORK/cluster\"}]"

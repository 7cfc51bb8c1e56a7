#!/usr/bin/env bash
# Runs the promises benchmark (bench/promises_bench.erl): what writing a
# voter's promise to disc (write + fdatasync) costs per vote and per
# takeover storm, on the disc of the directory given (default /tmp).
# Usage: scripts/bench-promises.sh [ERLANG_OPTION_LIST]
#   scripts/bench-promises.sh '[{dir, "/var/lib/evatar/bench"}, {storm, 300}]'
# Honours REBAR (default rebar3) and REBAR_BASE_DIR (default _build).
set -euo pipefail
# shellcheck source=scripts/bench-lib.sh
source "$(dirname "$0")/bench-lib.sh"
OPTS=${1:-[]}

bench_compile
run_bench promises_bench "$OPTS"

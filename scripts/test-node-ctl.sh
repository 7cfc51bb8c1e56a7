#!/usr/bin/env bash
# A test node driven by commands on stdin (port connectors, avatar_sim's
# smart home on a simulated clock) for the tests of clients in other
# languages; see scripts/test-node-ctl.escript for the arguments and the
# commands. Like scripts/test-node.sh it prints EVATAR_PORT=<port> once it
# accepts connections and halts when its stdin closes. Honours
# REBAR_BASE_DIR (default _build); the code must be compiled.
set -euo pipefail
cd "$(dirname "$0")/.."
BASE=${REBAR_BASE_DIR:-_build}
# _deps/: the HTTP server's libraries (scripts/ensure-deps.sh).
if [ "${1:-}" = --send ]; then
  # The control socket's client is a script of its own: every sim-node.sh
  # command then compiles some 60 lines at its start, not the node's 500.
  shift
  exec escript scripts/test-node-ctl-send.escript "$@"
fi
ERL_LIBS="$BASE/default/lib:$PWD/_deps" exec escript scripts/test-node-ctl.escript "$@"

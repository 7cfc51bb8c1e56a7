#!/usr/bin/env bash
# `make demo`: runs the demonstration on one embedded Erlang node, then exits.
# Arguments are passed to reference_agents_demo:main/1 (see docs/scenarios.md).
set -euo pipefail
cd "$(dirname "$0")/.."
# printf with no arguments still prints its format once: build the list
# only from arguments that were given.
args="[]"
if [ "$#" -gt 0 ]; then args=$(printf '"%s",' "$@"); args="[${args%,}]"; fi
exec erl -noshell -sname "evatar_demo_$$" -kernel logger_level notice \
  -pa _build/default/lib/*/ebin \
  -config config/sys.config \
  -eval "ok = reference_agents_demo:main($args), init:stop()."

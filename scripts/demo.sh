#!/usr/bin/env bash
# `make demo`: runs the demonstration on one embedded Erlang node, then exits.
# Arguments are passed to evatar_demo:main/1.
set -euo pipefail
cd "$(dirname "$0")/.."
args=$(printf '"%s",' "$@"); args="[${args%,}]"
exec erl -noshell -sname "evatar_demo_$$" -kernel logger_level notice \
  -pa _build/default/lib/*/ebin \
  -config config/sys.config \
  -eval "ok = evatar_demo:main($args), init:stop()."

#!/usr/bin/env bash
# One EVATAR node for the Java SDK's tests: like scripts/test-node.sh (prints
# EVATAR_PORT=<port>, halts when stdin closes), and it also takes commands on
# stdin to start avatar_sim's smart home, run its clock, report its state and
# start port connectors (see java_sdk_node.erl).
#
# Usage: clients/java/scripts/java-node.sh PAIRING:AGENT_CREDENTIAL:AVATAR_CREDENTIAL...
# Honours REBAR_BASE_DIR (default _build); the code must be compiled.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
cd "$here/../../.."
BASE=${REBAR_BASE_DIR:-_build}
case "$BASE" in /*) ;; *) BASE="$PWD/$BASE" ;; esac
ebin=$(mktemp -d "${TMPDIR:-/tmp}/java-sdk-node.XXXXXX")
trap 'rm -rf "$ebin"' EXIT
erlc -o "$ebin" "$here/java_sdk_node.erl"
erl -noshell -kernel logger_level warning \
  -pa "$BASE"/default/lib/*/ebin -pa "$ebin" -config config/test.config \
  -run java_sdk_node main "$@"

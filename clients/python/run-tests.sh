#!/usr/bin/env bash
# Runs the Python SDK's tests (clients/python/tests) against real EVATAR nodes
# started from the compiled umbrella. The Erlang code must already be compiled
# (`rebar3 compile`; REBAR_BASE_DIR is honoured, default _build).
#
# Creates (or reuses) a virtual environment, EVATAR_PY_VENV or
# clients/python/.venv, installs this package, pytest, agentspeak and SPADE
# from PyPI into it, runs pytest, and prints as its last line
#   N passed, N failed
# exiting non-zero when a test failed or could not run.
# Needs python3 (3.8 or later) with the venv module (Debian: python3-venv).
set -uo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
ROOT=$(cd "$HERE/../.." && pwd)
VENV=${EVATAR_PY_VENV:-$HERE/.venv}
export REBAR_BASE_DIR=${REBAR_BASE_DIR:-$ROOT/_build}
case "$REBAR_BASE_DIR" in /*) ;; *) REBAR_BASE_DIR="$ROOT/$REBAR_BASE_DIR" ;; esac

fail() { echo "clients/python: $*" >&2; echo "0 passed, 1 failed"; exit 1; }

command -v python3 >/dev/null || fail "python3 is not installed"
if [ ! -x "$VENV/bin/python" ]; then
  python3 -m venv "$VENV" >&2 || fail "cannot create a venv in $VENV (install python3-venv)"
fi
PY="$VENV/bin/python"
"$PY" -m pip install --quiet --disable-pip-version-check pytest agentspeak >&2 \
  || fail "cannot install pytest and agentspeak from PyPI"
# SPADE for tests/test_spade.py (evatar.spade), pinned to versions known to work.
"$PY" -m pip install --quiet --disable-pip-version-check -r "$HERE/spade-requirements.txt" >&2 \
  || fail "cannot install SPADE ($HERE/spade-requirements.txt) from PyPI"
"$PY" -m pip install --quiet --disable-pip-version-check --force-reinstall --no-deps "$HERE" >&2 \
  || fail "cannot install the evatar package"
ls "$REBAR_BASE_DIR"/default/lib/agent_bridge/ebin/*.beam >/dev/null 2>&1 \
  || fail "the Erlang code is not compiled in $REBAR_BASE_DIR (run rebar3 compile)"

REPORT=$(mktemp /tmp/evatar-py-junit.XXXXXX)
trap 'rm -f "$REPORT"' EXIT
# Run from tests/ so the installed package, not src/, is what is tested.
(cd "$HERE/tests" && "$PY" -m pytest -q -p no:cacheprovider --junitxml="$REPORT" "$@" .) >&2
STATUS=$?
COUNTS=$("$PY" - "$REPORT" <<'PYEOF'
import sys
import xml.etree.ElementTree as ET
try:
    root = ET.parse(sys.argv[1]).getroot()
except Exception:
    print("0 1"); sys.exit()
suites = [root] if root.tag == "testsuite" else list(root)
t = sum(int(s.get("tests", 0)) for s in suites)
f = sum(int(s.get("failures", 0)) + int(s.get("errors", 0)) for s in suites)
k = sum(int(s.get("skipped", 0)) for s in suites)
print(t - f - k, f)
PYEOF
)
read -r PASSED FAILED <<<"$COUNTS"
if [ "$STATUS" -ne 0 ] && [ "$FAILED" -eq 0 ]; then FAILED=1; fi
echo "$PASSED passed, $FAILED failed"
[ "$STATUS" -eq 0 ] && [ "$FAILED" -eq 0 ]

#!/usr/bin/env bash
# Runs the Python SDK's tests (clients/python/tests) against real EVATAR nodes
# started from the compiled umbrella. The Erlang code must already be compiled
# (`rebar3 compile`; REBAR_BASE_DIR is honoured, default _build).
#
# Creates (or reuses) a virtual environment, EVATAR_PY_VENV or
# clients/python/.venv, installs into it from PyPI what it lacks of pytest,
# pytest-xdist, agentspeak and SPADE (pinned: spade-requirements.txt),
# installs this package again when its source changed, runs pytest, and
# prints as its last line
#   N passed, N failed
# exiting non-zero when a test failed or could not run.
# The test files run three at a time (pytest-xdist: -n 3 --dist loadfile, so
# a file's tests and its module fixtures stay in one process, each process
# with its own session node): most of the suite's time is spent waiting on
# simulated clocks and timeouts, not on the CPU. Arguments go to pytest after
# those: `-n 0` runs the files one after another.
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
# Each pip step below costs seconds and a trip to PyPI even when it has
# nothing to do, so it runs only when the venv lacks what it installs.
# have REQUIREMENT...: every NAME is installed, at VERSION for NAME==VERSION.
# A line it cannot read counts as missing: the check may only cause an
# install, never skip one that was needed.
have() {
  "$PY" - "$@" <<'PYEOF'
import re
import sys
from importlib import metadata
for req in sys.argv[1:]:
    m = re.fullmatch(r"([A-Za-z0-9._-]+)(?:==([A-Za-z0-9.+!-]+))?", req)
    if m is None:
        sys.exit(1)
    try:
        got = metadata.version(m.group(1))
    except metadata.PackageNotFoundError:
        sys.exit(1)
    if m.group(2) is not None and got != m.group(2):
        sys.exit(1)
PYEOF
}
TEST_REQS="pytest pytest-xdist==3.8.0 agentspeak"
# shellcheck disable=SC2086 # one requirement a word
have $TEST_REQS \
  || "$PY" -m pip install --quiet --disable-pip-version-check $TEST_REQS >&2 \
  || fail "cannot install $TEST_REQS from PyPI"
# SPADE for tests/test_spade.py (evatar.spade), pinned to versions known to work.
SPADE_REQS=$(sed -e 's/#.*//' -e 's/[[:space:]]//g' -e '/^$/d' "$HERE/spade-requirements.txt")
# shellcheck disable=SC2086 # one requirement a word
have $SPADE_REQS \
  || "$PY" -m pip install --quiet --disable-pip-version-check -r "$HERE/spade-requirements.txt" >&2 \
  || fail "cannot install SPADE ($HERE/spade-requirements.txt) from PyPI"
# This package, again whenever its source differs from what was installed
# last (the digest of pyproject.toml, README.md and src/evatar, kept in the venv).
SRC_DIGEST=$(cd "$HERE" && find pyproject.toml README.md src/evatar -type f ! -name '*.pyc' -print0 \
  | LC_ALL=C sort -z | xargs -0 sha256sum | sha256sum | cut -d' ' -f1)
if ! have evatar || [ "$(cat "$VENV/evatar-src.sha256" 2>/dev/null)" != "$SRC_DIGEST" ]; then
  "$PY" -m pip install --quiet --disable-pip-version-check --force-reinstall --no-deps "$HERE" >&2 \
    || fail "cannot install the evatar package"
  echo "$SRC_DIGEST" > "$VENV/evatar-src.sha256"
fi
ls "$REBAR_BASE_DIR"/default/lib/agent_bridge/ebin/*.beam >/dev/null 2>&1 \
  || fail "the Erlang code is not compiled in $REBAR_BASE_DIR (run rebar3 compile)"

REPORT=$(mktemp /tmp/evatar-py-junit.XXXXXX)
trap 'rm -f "$REPORT"' EXIT
# Run from tests/ so the installed package, not src/, is what is tested.
(cd "$HERE/tests" && "$PY" -m pytest -q -p no:cacheprovider --junitxml="$REPORT" \
  -n 3 --dist loadfile "$@" .) >&2
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

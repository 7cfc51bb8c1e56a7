#!/usr/bin/env bash
# `make demo DEMO_ARGS=spade`: the holiday story told with a SPADE agent as
# the house VA (clients/python/examples/holiday/demo_spade.py says what runs).
# Makes or reuses the Python suite's venv (EVATAR_PY_VENV or
# clients/python/.venv) with the SDK and SPADE pinned
# (clients/python/spade-requirements.txt) from PyPI. The Erlang code must be
# compiled (make demo does it).
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${EVATAR_PY_VENV:-clients/python/.venv}
if [ ! -x "$VENV/bin/python" ]; then
  python3 -m venv "$VENV" || { echo "demo-spade.sh: cannot create a venv in $VENV (install python3-venv)" >&2; exit 1; }
fi
"$VENV/bin/python" -m pip install --quiet --disable-pip-version-check agentspeak \
  -r clients/python/spade-requirements.txt
"$VENV/bin/python" -m pip install --quiet --disable-pip-version-check --force-reinstall --no-deps \
  ./clients/python
exec "$VENV/bin/python" clients/python/examples/holiday/demo_spade.py

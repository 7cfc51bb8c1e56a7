#!/usr/bin/env bash
# `make demo`: runs the demonstration on one embedded Erlang node, then exits;
# it prints the address of the node's dashboard first (port 0: a free one).
# Arguments are passed to evatar_demo:main/1 (see docs/scenarios.md).
#
# Stopping it (a kept node, --keep, too): Ctrl-C, or SIGTERM/SIGINT/SIGHUP to
# this script or to the `make demo' that runs it, or evatar_demo:stop().
# from a remote shell. A signal asks the node to stop (init:stop/0) and kills
# it if it has not stopped within 10 s.
set -euo pipefail
cd "$(dirname "$0")/.."
case "${1:-}" in
  spade)
    # The SPADE agent's holiday runs in Python, on a node of its own.
    [ "$#" -eq 1 ] || { echo "demo.sh: spade takes no other option" >&2; exit 2; }
    exec bash scripts/demo-spade.sh;;
  -h|--help)
    cat <<'USAGE'
usage: make demo [DEMO_ARGS="[home|mqtt|robots|rooms|bil] [--keep]" | DEMO_ARGS=spade]
       scripts/demo.sh [home|mqtt|robots|rooms|bil] [--keep] | spade
  --keep   keep the node running afterwards, for a remote shell; the home's
           house VA then leaves its pairing to a VA of your own (docs/clients.md)
  spade    the holiday told with a SPADE agent (Python; installs SPADE in
           clients/python/.venv from PyPI; scripts/demo-spade.sh)
Stop it (kept or not) with Ctrl-C, with `kill PID' (SIGTERM) of this script or
of `make demo', or with evatar_demo:stop(). from a remote shell: the
node gets 10 s to stop cleanly, then it is killed.
USAGE
    exit 0;;
esac
# printf with no arguments still prints its format once: build the list
# only from arguments that were given.
args="[]"
if [ "$#" -gt 0 ]; then args=$(printf '"%s",' "$@"); args="[${args%,}]"; fi
# Distributed only for --keep's remote shell: on loopback only (epmd too,
# when this starts it), with the cookie of $HOME/.erlang.cookie, which
# Erlang makes random (mode 0400) when there is none.
export ERL_EPMD_ADDRESS=${ERL_EPMD_ADDRESS:-127.0.0.1}
# The HTTP server's libraries (cowboy, ranch, cowlib), which
# scripts/ensure-deps.sh copies into _deps/.
export ERL_LIBS="$PWD/_deps${ERL_LIBS:+:$ERL_LIBS}"
erl -noshell -name "evatar_demo_$$@127.0.0.1" -kernel inet_dist_use_interface '{127,0,0,1}' \
  -kernel logger_level notice \
  -pa _build/default/lib/*/ebin \
  -config config/sys.config \
  -evatar_web port 0 \
  -eval "case {application:ensure_all_started(evatar_web), evatar_web:url()} of
           {{ok, _}, Url} when is_list(Url) ->
             io:format(\"~nDashboard: ~ts  (the page of this node; docs/dashboard.md)~n\", [Url]);
           Other ->
             io:format(\"~nNo dashboard: ~tp~n\", [Other])
         end,
         ok = evatar_demo:main($args), init:stop()." &
node=$!
# The node is a child, not exec'd, so a signal to this script (or make's
# death) always reaches it: a kept node otherwise outlived a SIGTERM.
stop_node() {
  kill -TERM "$node" 2>/dev/null || return 0
  for _ in $(seq 1 20); do
    kill -0 "$node" 2>/dev/null || return 0
    sleep 0.5
  done
  echo "demo.sh: the node did not stop within 10 s; killing it" >&2
  kill -KILL "$node" 2>/dev/null || true
}
trap 'stop_node; exit 143' TERM
trap 'stop_node; exit 130' INT
trap 'stop_node; exit 129' HUP
parent=$PPID
while kill -0 "$node" 2>/dev/null; do
  # `make demo' killed: its child would otherwise run on, orphaned.
  if ! kill -0 "$parent" 2>/dev/null; then stop_node; break; fi
  sleep 1 & wait $! || true
done
set +e
wait "$node"
exit $?

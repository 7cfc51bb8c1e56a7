#!/usr/bin/env bash
# `make demo`: runs the demonstration on one embedded Erlang node, then exits;
# it prints the address of the node's dashboard first (port 0: a free one).
# Arguments are passed to reference_agents_demo:main/1 (see docs/scenarios.md).
set -euo pipefail
cd "$(dirname "$0")/.."
# printf with no arguments still prints its format once: build the list
# only from arguments that were given.
args="[]"
if [ "$#" -gt 0 ]; then args=$(printf '"%s",' "$@"); args="[${args%,}]"; fi
# Distributed only for --keep's remote shell: on loopback only (epmd too,
# when this starts it), with the cookie of $HOME/.erlang.cookie, which
# Erlang makes random (mode 0400) when there is none.
export ERL_EPMD_ADDRESS=${ERL_EPMD_ADDRESS:-127.0.0.1}
exec erl -noshell -name "evatar_demo_$$@127.0.0.1" -kernel inet_dist_use_interface '{127,0,0,1}' \
  -kernel logger_level notice \
  -pa _build/default/lib/*/ebin \
  -config config/sys.config \
  -evatar_web port 0 \
  -eval "case {application:ensure_all_started(evatar_web), evatar_web:url()} of
           {{ok, _}, Url} when is_binary(Url) ->
             io:format(\"~nDashboard: ~ts  (the page of this node; docs/dashboard.md)~n\", [Url]);
           Other ->
             io:format(\"~nNo dashboard: ~tp~n\", [Other])
         end,
         ok = reference_agents_demo:main($args), init:stop()."

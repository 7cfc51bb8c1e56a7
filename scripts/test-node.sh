#!/usr/bin/env bash
# Starts one EVATAR node for the tests of clients written in other languages
# (clients/python, clients/java). It listens on 127.0.0.1, on EVATAR_PORT
# or a free port, creates the pairings named on the command line, prints
#   EVATAR_PORT=<port>
# on stdout once it accepts connections, and halts when its stdin closes, so
# a test fixture that dies takes the node with it.
#
# Usage: scripts/test-node.sh PAIRING:AGENT_CREDENTIAL:AVATAR_CREDENTIAL[:FEEDBACK_TIMEOUT_MS]...
#   e.g. scripts/test-node.sh home:va-secret:avatar-secret
# A pairing without FEEDBACK_TIMEOUT_MS has the default feedback timeout (5 s).
# Honours REBAR_BASE_DIR (default _build); the code must be compiled
# (`rebar3 compile`).
# With EVATAR_TLS_DIR set to a directory made by scripts/gen-bridge-certs.sh
# it also opens two TLS listeners on free ports of 127.0.0.1 and prints,
# before EVATAR_PORT, EVATAR_TLS_PORT=<port> (server certificate only) and
# EVATAR_MTLS_PORT=<port> (client certificates signed by ca.pem required).
# EVATAR_HANDSHAKE_RATE=N|infinity sets the plain listener's handshake rate
# per address (docs/protocol.md section 7.1; default 20/s after a burst of
# 100), for tests that open many connections in a tight loop.
# EVATAR_TEST_NO_GUARD=1 also refuses a wrong credential at once and never
# locks an address out (and implies rate infinity), for tests of many
# refused handshakes from 127.0.0.1 in seconds.
set -euo pipefail
cd "$(dirname "$0")/.."
BASE=${REBAR_BASE_DIR:-_build}
# The HTTP server's libraries (cowboy, ranch, cowlib), which
# scripts/ensure-deps.sh copies into _deps/.
export ERL_LIBS="$PWD/_deps${ERL_LIBS:+:$ERL_LIBS}"
PORT=${EVATAR_PORT:-0}
specs=""
for arg in "$@"; do
  IFS=: read -r id agent avatar fto <<<"$arg"
  if [ -z "${id:-}" ] || [ -z "${agent:-}" ] || [ -z "${avatar:-}" ] \
     || ! [[ "${fto:-}" =~ ^([1-9][0-9]*)?$ ]]; then
    echo "test-node.sh: bad pairing '$arg', want PAIRING:AGENT_CREDENTIAL:AVATAR_CREDENTIAL[:FEEDBACK_TIMEOUT_MS]" >&2
    exit 2
  fi
  extra=${fto:+", feedback_timeout => $fto"}
  specs="$specs{<<\"$id\">>, #{agent_credential => <<\"$agent\">>, avatar_credential => <<\"$avatar\">>$extra}},"
done
specs="[${specs%,}]"
TLS_DIR=${EVATAR_TLS_DIR:-}
RATE=${EVATAR_HANDSHAKE_RATE:-}
NO_GUARD=${EVATAR_TEST_NO_GUARD:-}
if ! [[ "$RATE" =~ ^([1-9][0-9]*|infinity)?$ ]]; then
  echo "test-node.sh: EVATAR_HANDSHAKE_RATE is a positive integer or infinity" >&2
  exit 2
fi
exec erl -noshell -kernel logger_level warning \
  -pa "$BASE"/default/lib/*/ebin -config config/test.config \
  -eval "
    {ok, _} = application:ensure_all_started(evatar),
    {ok, _} = application:ensure_all_started(agent_bridge),
    [{ok, _} = evatar:create_pairing(Id, Opts) || {Id, Opts} <- $specs],
    %% Heartbeat 500 (not the default): the value in the shared vectors'
    %% Welcome, which the SDKs' transcript tests replay against this node.
    Hb500 = #{heartbeat => 500},
    %% The TLS listeners give the TLS handshake and the Hello 30 s, not the
    %% default 5 s: the RSA work of a handshake with client certificates can
    %% take seconds on a loaded test machine (make test runs these suites
    %% beside dialyzer and EUnit), and no SDK test checks that deadline.
    Tls30 = Hb500#{handshake_timeout => 30000},
    case \"$TLS_DIR\" of
      \"\" -> ok;
      Dir ->
        F = fun(Name) -> filename:join(Dir, Name) end,
        Server = #{certfile => F(\"server.pem\"), keyfile => F(\"server.key\")},
        {ok, _} = agent_bridge:start_listener(test_tls, #{ip => {127,0,0,1}, port => 0,
                                                          tls => Server, conn => Tls30}),
        {ok, _} = agent_bridge:start_listener(test_mtls, #{ip => {127,0,0,1}, port => 0,
                                                           tls => Server#{cacertfile => F(\"ca.pem\")},
                                                           conn => Tls30}),
        [begin {ok, {_, TP}} = agent_bridge:address(L), io:format(\"~s=~b~n\", [Var, TP]) end
         || {L, Var} <- [{test_tls, \"EVATAR_TLS_PORT\"}, {test_mtls, \"EVATAR_MTLS_PORT\"}]]
    end,
    Handshake = case {\"$NO_GUARD\", \"$RATE\"} of
                  {[_ | _], _} -> #{handshake => #{rate => infinity, failure_delay => 0,
                                                   max_failures => 1000000}};
                  {_, \"\"} -> #{};
                  {_, \"infinity\"} -> #{handshake => #{rate => infinity}};
                  {_, R} -> #{handshake => #{rate => list_to_integer(R)}}
                end,
    {ok, _} = agent_bridge:start_listener(test_node, Handshake#{ip => {127,0,0,1}, port => $PORT,
                                                                conn => Hb500}),
    {ok, {_, P}} = agent_bridge:address(test_node),
    io:format(\"EVATAR_PORT=~b~n\", [P]),
    WaitEof = fun Loop() -> case io:get_line('') of eof -> ok; {error, _} -> ok; _ -> Loop() end end,
    WaitEof(),
    halt(0)."

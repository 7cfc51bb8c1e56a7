#!/usr/bin/env bash
# Runs the Java SDK's tests (clients/java: the client, the Jason environment)
# against real EVATAR nodes started from the compiled umbrella, and prints as
# its last line "N passed, N failed" summed from the surefire reports. Exits
# non-zero when a test failed or Maven did.
#
# Needs Java 17+ and Maven 3.8+; dependencies come from Maven Central once and
# are cached in ~/.m2 (set MAVEN_OFFLINE=1 to forbid the network). The Erlang
# code must be compiled (rebar3 compile); REBAR_BASE_DIR is honoured
# (default _build at the repository root).
set -uo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
repo="$(cd "$here/../.." && pwd)"
base="${REBAR_BASE_DIR:-_build}"
case "$base" in /*) ;; *) base="$repo/$base" ;; esac
export REBAR_BASE_DIR="$base"

if ! ls "$base"/default/lib/agent_bridge/ebin/agent_bridge.beam >/dev/null 2>&1; then
  echo "clients/java: the Erlang code is not compiled in $base (run rebar3 compile)" >&2
  echo "0 passed, 1 failed"
  exit 1
fi
for tool in java mvn erl erlc; do
  if ! command -v "$tool" >/dev/null 2>&1; then
    echo "clients/java: $tool not found" >&2
    echo "0 passed, 1 failed"
    exit 1
  fi
done

cd "$here"
rm -rf client/target/surefire-reports jason/target/surefire-reports
offline=()
if [ -n "${MAVEN_OFFLINE:-}" ]; then offline=(-o); fi
# Maven writes colour resets even with -q -B: strip them, so that the summary
# below is a line of its own.
mvn -q -B -Dstyle.color=never "${offline[@]}" -Devatar.repo="$repo" test 2>&1 |
  awk '{ gsub(/\033\[[0-9;]*m/, ""); if (length($0)) print; fflush() }'
rc=${PIPESTATUS[0]}

read -r passed failed < <(
  cat client/target/surefire-reports/TEST-*.xml jason/target/surefire-reports/TEST-*.xml 2>/dev/null |
  grep -o '<testsuite [^>]*>' |
  awk '{
    t = f = e = s = 0
    if (match($0, / tests="[0-9]+"/))    t = substr($0, RSTART + 8, RLENGTH - 9)
    if (match($0, / failures="[0-9]+"/)) f = substr($0, RSTART + 11, RLENGTH - 12)
    if (match($0, / errors="[0-9]+"/))   e = substr($0, RSTART + 9, RLENGTH - 10)
    if (match($0, / skipped="[0-9]+"/))  s = substr($0, RSTART + 10, RLENGTH - 11)
    P += t - f - e - s; F += f + e
  } END { print P + 0, F + 0 }')
if [ "$rc" -ne 0 ] && [ "$failed" -eq 0 ]; then
  echo "clients/java: mvn failed (exit $rc) without a failed test: see above" >&2
  failed=1
fi
echo "$passed passed, $failed failed"
[ "$rc" -eq 0 ] && [ "$failed" -eq 0 ]

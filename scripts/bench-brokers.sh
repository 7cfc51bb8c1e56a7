#!/usr/bin/env bash
# EVATAR against mosquitto, RabbitMQ's MQTT plugin and nats-server, side by
# side in one run (bench/broker_bench.erl; how to read it: bench/README.md,
# section d). Installs the brokers (Debian packages) when missing, only
# those the run names when the options say `{systems, [...]}'; the benchmark
# starts each system as its own OS process on 127.0.0.1 (a fresh one per N)
# and stops it; this script kills whatever a crashed run left behind.
# Usage: scripts/bench-brokers.sh [ERLANG_OPTION_LIST | quick]
#        scripts/bench-brokers.sh profile-rt [ERLANG_OPTION_LIST]
#   (where a round trip's server CPU goes: bench/broker_bench_profile.erl)
#   scripts/bench-brokers.sh                           # the full run (about 15 minutes)
#   scripts/bench-brokers.sh quick                     # smoke run (N = 1, 100; 2 s windows)
#   scripts/bench-brokers.sh '[{sizes, [1000]}, {systems, [evatar, mosquitto]}]'
#   scripts/bench-brokers.sh '[{transport, tls}]'      # EVATAR and mosquitto over TLS
# Honours REBAR (default rebar3) and REBAR_BASE_DIR (default _build).
set -euo pipefail
# shellcheck source=scripts/bench-lib.sh
source "$(dirname "$0")/bench-lib.sh"
MODULE=broker_bench
if [ "${1:-}" = profile-rt ]; then
  MODULE=broker_bench_profile
  shift
  command -v perf >/dev/null 2>&1 || { echo "bench-brokers: profile-rt needs perf (linux-perf)" >&2; exit 1; }
fi
OPTS=${1:-[]}
[ "$OPTS" = quick ] && OPTS='[quick]'

# --- the brokers ------------------------------------------------------------
# The systems the run measures: every broker unless the options name them
# ({transport, tls} measures EVATAR and mosquitto only, profile-rt all but
# RabbitMQ).
wants() {
  case "$OPTS" in
    *'{systems,'*) [[ "$OPTS" =~ \{systems,[^]]*$1 ]] ;;
    *'{transport, tls}'*|*'{transport,tls}'*) [ "$1" = mosquitto ] ;;
    *) [ "$MODULE" = broker_bench ] || [ "$1" != rabbitmq ] ;;
  esac
}
missing=()
if wants mosquitto && [ ! -x /usr/sbin/mosquitto ]; then missing+=(mosquitto); fi
if wants rabbitmq && [ ! -x /usr/lib/rabbitmq/bin/rabbitmq-server ]; then missing+=(rabbitmq-server); fi
if wants nats && [ ! -x /usr/sbin/nats-server ]; then missing+=(nats-server); fi
if [ ${#missing[@]} -gt 0 ]; then
  SUDO=""
  if [ "$(id -u)" -ne 0 ]; then
    command -v sudo >/dev/null 2>&1 || { echo "bench-brokers: need root or sudo to install ${missing[*]}" >&2; exit 1; }
    SUDO=sudo
  fi
  echo "bench-brokers: installing ${missing[*]} with apt-get"
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
  # The packages may start their system services: the benchmark runs its own
  # instances on other ports, so stop and disable what this install started
  # (their CPU would be counted as other load).
  if [ -d /run/systemd/system ]; then
    for unit in "${missing[@]}"; do
      $SUDO systemctl disable --now "$unit" >/dev/null 2>&1 || true
    done
  fi
fi
for svc in rabbitmq-server mosquitto nats-server; do
  if pgrep -x -f ".*/usr/sbin/$svc.*" >/dev/null 2>&1 || \
     { [ "$svc" = rabbitmq-server ] && pgrep -f 'beam.*-s rabbit boot' -u rabbitmq >/dev/null 2>&1; }; then
    echo "bench-brokers: NOTE: a system $svc is running; it does not collide (other ports," \
         "other node name) but its CPU counts as other load" >&2
  fi
done

# --- descriptors: N = 1000 is 2000 connections in the generator and 2000 in
# the system under test, each its own process with this limit --------------
WANT=65536
if ! ulimit -n "$WANT" 2>/dev/null; then
  hard=$(ulimit -Hn)
  if [ "$hard" != unlimited ] && [ "$hard" -gt "$(ulimit -n)" ]; then
    ulimit -n "$hard"
  fi
  echo "bench-brokers: NOTE: open-file limit $(ulimit -n) (hard limit $hard)" >&2
fi
if [ "$(ulimit -n)" != unlimited ] && [ "$(ulimit -n)" -lt 4200 ]; then
  echo "bench-brokers: ulimit -n is $(ulimit -n); N = 1000 needs more than 4,200 descriptors" \
       "per process. Raise the hard limit or pass {sizes, [1, 100]}." >&2
  exit 1
fi

bench_compile

# --- leftovers ---------------------------------------------------------------
RUN_DIR=$(mktemp -d /tmp/broker_bench.XXXXXX)
export BROKER_BENCH_RUN_DIR="$RUN_DIR"
cleanup() {
  for f in "$RUN_DIR"/*.pid; do
    [ -e "$f" ] || continue
    pid=$(cat "$f")
    # Only a process this run started: its command line names the run
    # directory (brokers) or the benchmark's peer node (EVATAR).
    if [ -r "/proc/$pid/cmdline" ] && tr '\0' ' ' <"/proc/$pid/cmdline" | \
         grep -q -e "$RUN_DIR" -e broker_bench_evatar; then
      echo "bench-brokers: stopping leftover $(basename "$f" .pid) (pid $pid)" >&2
      kill -TERM "$pid" 2>/dev/null || true
      sleep 2
      kill -KILL "$pid" 2>/dev/null || true
    fi
  done
  rm -rf "$RUN_DIR"
}
trap cleanup EXIT

# No busy-waiting schedulers in the generator: on a small machine their
# spinning would take CPU from the system under test.
run_bench "$MODULE" "$OPTS" +sbwt none +sbwtdcpu none +sbwtdio none +P 2000000 +Q 1000000

#!/usr/bin/env bash
# Runs an EVATAR cluster of N nodes on this machine from one release, each
# node a separate OS process with its own name, bridge port, distribution
# port, configuration and logs (docs/ha.md).
#
# Usage: scripts/cluster.sh start N      start nodes 1..N (those not running)
#        scripts/cluster.sh stop [N]     stop nodes 1..N (default: as started)
#        scripts/cluster.sh status [N]   one line per node: name, ports, pid
#        scripts/cluster.sh env I [N]    the environment of node I, as exports
#        scripts/cluster.sh console I    remote console on node I (Ctrl-G q)
#        scripts/cluster.sh kill I       kill -9 node I (a crash, for trying
#                                        failover; `start N` brings it back)
#
# Node I is ${EVATAR_NAME:-evatar}I@${EVATAR_HOST:-127.0.0.1}, its bridge
# listens on EVATAR_BASE_PORT+I (default 7400+I) and its distribution on the
# single port EVATAR_DIST_BASE+I (default 9100+I), its HTTP API on
# EVATAR_HTTP_BASE+I (default 7480+I). Also honoured:
#   EVATAR_REL          the release directory (default: the one `rebar3
#                       release` builds under REBAR_BASE_DIR or _build;
#                       built when missing)
#   EVATAR_CLUSTER_DIR  configuration and logs (default _build/cluster)
#   EVATAR_DIST         inet_tcp (default) or inet_tls; with inet_tls the
#                       certificates are made once in the cluster directory
#                       by scripts/gen-dist-certs.sh
#   EVATAR_DIST_IP      distribution's and epmd's address (default: HOST
#                       when it is an IPv4 address, else 127,0,0,1)
# The nodes share one cookie, $HOME/.erlang.cookie: bin/evatar makes it
# (random, mode 0400) when the first node starts (docs/ha.md section 1).
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd -P)
cd "$ROOT"

REBAR=${REBAR:-rebar3}
BASE=${REBAR_BASE_DIR:-_build}
REL=${EVATAR_REL:-$BASE/default/rel/evatar}
DIR=${EVATAR_CLUSTER_DIR:-$BASE/cluster}
NAME=${EVATAR_NAME:-evatar}
HOST=${EVATAR_HOST:-127.0.0.1}
BASE_PORT=${EVATAR_BASE_PORT:-7400}
DIST_BASE=${EVATAR_DIST_BASE:-9100}
HTTP_BASE=${EVATAR_HTTP_BASE:-7480}
DIST=${EVATAR_DIST:-inet_tcp}
if [ -z "${EVATAR_DIST_IP:-}" ]; then
  if [[ $HOST =~ ^[0-9]+\.[0-9]+\.[0-9]+\.[0-9]+$ ]]; then DIST_IP=${HOST//./,}; else DIST_IP=127,0,0,1; fi
else
  DIST_IP=$EVATAR_DIST_IP
fi

usage() {
  sed -n '2,/^set -euo/p' "$0" | sed -e '/^set -euo/d' -e 's/^# \{0,1\}//' >&2
  exit 2
}

# The number of nodes of the running cluster, from the last `start`.
started_n() {
  if [ -f "$DIR/nodes" ]; then cat "$DIR/nodes"; else echo 0; fi
}

peers() {
  local n=$1 i list=""
  for i in $(seq 1 "$n"); do list="${list:+$list,}$NAME$i@$HOST"; done
  echo "$list"
}

# Prints the environment of node I of an N-node cluster.
node_env() {
  local i=$1 n=$2 nd="$DIR/$NAME$1"
  echo "export EVATAR_NODE=$NAME$i@$HOST"
  echo "export EVATAR_PEERS=$(peers "$n")"
  echo "export EVATAR_PORT=$((BASE_PORT + i))"
  echo "export EVATAR_HTTP_PORT=$((HTTP_BASE + i))"
  echo "export EVATAR_DIST_PORT_MIN=$((DIST_BASE + i))"
  echo "export EVATAR_DIST_PORT_MAX=$((DIST_BASE + i))"
  echo "export EVATAR_DIST=$DIST"
  echo "export EVATAR_DIST_IP=$DIST_IP"
  # Each node writes its own vm.args and sys.config (made from the .src
  # files) and its logs in its own directory, not in the shared release.
  echo "export RELX_OUT_FILE_PATH=$nd"
  echo "export RUNNER_LOG_DIR=$nd/log"
  echo "export EVATAR_DATA_DIR=$(realpath -m "$nd/data")"
  if [ "$DIST" = inet_tls ]; then
    echo "export USE_NODETOOL=1"
    echo "export ERL_FLAGS=\"-ssl_dist_optfile $DIR/certs/ssl_dist.conf\""
  fi
}

# Runs bin/evatar for node I of N with that node's environment.
rel() {
  local i=$1 n=$2; shift 2
  mkdir -p "$DIR/$NAME$i/log"
  ( eval "$(node_env "$i" "$n")"; exec "$REL/bin/evatar" "$@" )
}

ensure_release() {
  if [ ! -x "$REL/bin/evatar" ]; then
    echo "cluster: no release in $REL; building it with '$REBAR release'"
    "$REBAR" release
  fi
  if [ ! -f "$REL/releases/"*/vm.args.src ]; then
    echo "cluster: $REL was not built from config/vm.args.src (see docs/ha.md)" >&2
    exit 1
  fi
}

ensure_certs() {
  if [ "$DIST" = inet_tls ] && [ ! -f "$DIR/certs/ssl_dist.conf" ]; then
    bash scripts/gen-dist-certs.sh "$DIR/certs" "$HOST" localhost
  fi
}

running() {
  rel "$1" "$2" ping >/dev/null 2>&1
}

start() {
  local n=$1 i
  ensure_release
  ensure_certs
  mkdir -p "$DIR"
  echo "$n" > "$DIR/nodes"
  for i in $(seq 1 "$n"); do
    if running "$i" "$n"; then
      echo "cluster: $NAME$i@$HOST already running"
    else
      echo "cluster: starting $NAME$i@$HOST (bridge port $((BASE_PORT + i)), distribution port $((DIST_BASE + i)))"
      rel "$i" "$n" daemon
    fi
  done
  status "$n"
}

stop() {
  local n=$1 i
  for i in $(seq 1 "$n"); do
    if running "$i" "$n"; then
      echo "cluster: stopping $NAME$i@$HOST"
      rel "$i" "$n" stop >/dev/null
    fi
  done
  rm -f "$DIR/nodes"
}

status() {
  local n=$1 i pid
  for i in $(seq 1 "$n"); do
    if pid=$(rel "$i" "$n" pid 2>/dev/null); then
      printf '%-24s bridge %-5s dist %-5s running (pid %s)\n' "$NAME$i@$HOST" \
        $((BASE_PORT + i)) $((DIST_BASE + i)) "$pid"
    else
      printf '%-24s bridge %-5s dist %-5s not running\n' "$NAME$i@$HOST" \
        $((BASE_PORT + i)) $((DIST_BASE + i))
    fi
  done
}

kill_node() {
  local i=$1 n pid
  n=$(started_n)
  pid=$(rel "$i" "$n" pid)
  echo "cluster: kill -9 $NAME$i@$HOST (pid $pid)"
  kill -9 "$pid"
}

cmd=${1:-}
case "$cmd" in
  start)   [ $# -eq 2 ] || usage; start "$2" ;;
  stop)    stop "${2:-$(started_n)}" ;;
  status)  status "${2:-$(started_n)}" ;;
  env)     [ $# -ge 2 ] || usage; node_env "$2" "${3:-$(started_n)}" ;;
  console) [ $# -eq 2 ] || usage; rel "$2" "$(started_n)" remote_console ;;
  kill)    [ $# -eq 2 ] || usage; kill_node "$2" ;;
  *)       usage ;;
esac

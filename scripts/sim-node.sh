#!/usr/bin/env bash
# An EVATAR node with a simulated Avatar (apps/avatar_sim, docs/avatars.md)
# for people who write their VA in Python, Java or anything but Erlang:
# start it, then drive the simulation and its failure hooks from a shell.
#
#   scripts/sim-node.sh start home   [options]   the smart home (one gateway, every device)
#   scripts/sim-node.sh start robots [options]   the LEGO arena with two robots
#   scripts/sim-node.sh COMMAND [ARG...]         a command to the running node
#
# `start' runs the node in the foreground (stop it with Ctrl-C or
# `sim-node.sh stop'). It listens for clients on 127.0.0.1 only and prints,
# one per line, EVATAR_PAIRING=<id> (robots: one line per robot),
# EVATAR_SPOOL=<dir> (home), EVATAR_VA_CREDENTIAL=<secret>,
# EVATAR_CONTROL=<socket> and, once it accepts connections,
# EVATAR_PORT=<port>; then the node's warnings (docs/avatars.md 1.1). Options:
#   --port P                 the port on 127.0.0.1 (default 7400; 0: a free one)
#   --pairing ID             home: the pairing (default home); robots: the
#                            prefix of the two pairings ID1 and ID2 (default robot)
#   --va-credential SECRET   the VA's credential (default: a random one, printed)
#   --script holiday|none|FILE
#                            home: the people's script (docs/avatars.md 4.3);
#                            default holiday (an intruder at 21:40)
#   --start YYYY-MM-DDTHH:MM the simulated start, UTC = London's local time
#                            (default 2024-11-15T17:55: already after sunset)
#   --paused                 start the clock paused: no simulated time passes
#                            (no reading, no script step) until `resume'
#   --speed N                simulated ms per real ms (default 1)
#   --feedback-timeout MS    the pairings' feedback timeout (default 5000)
#   --spool DIR              home: where e-mails, SMS and photos go (default DIR/spool)
#   --stop-on-eof            also stop when stdin closes (for a program that
#                            starts the node and may die)
#
# Commands (they print the node's answer, or a short confirmation such as
# `ok muted C' when it has none; exit 0 on success, 1 when the node refused
# the command, 3 when no node runs):
#   mute COMPONENT | unmute COMPONENT     the device swallows requests / answers again
#   disconnect ENTITY [MS] | reconnect ENTITY
#                                         the gateway or robot drops its connection
#                                         (and comes back after MS real ms) / comes back
#   detach COMPONENT | attach COMPONENT   the device leaves / comes back (a rebinding)
#   links                                 LINK ENTITY PAIRING STATE routes=N muted=.. detached=..
#   entities PAIRING                      the EntityIDs registered in the pairing
#   pause | resume | speed N              the simulated clock (speed N also pauses it)
#   run_until HH:MM                       run the clock to that time, then pause
#   time                                  TIME YYYY-MM-DD HH:MM:SS running|paused speed=N
#   outcome                               home: LIGHT, EMAIL, PHOTO, PLAYED lines
#                                         robots: BALL COLOUR X Y ZONE HELD_BY, ROBOT lines
#   stop                                  stop the node
#
# Global option, before the command: --dir DIR (or EVATAR_SIM_DIR), the
# private directory (mode 0700) holding the node's control socket, default
# ${XDG_RUNTIME_DIR:-/tmp}/evatar-sim-<uid>. The commands reach the node
# through that Unix domain socket only: no network listener, no cookie, and
# only the directory's owner can open it. One node per directory.
#
# Needs the Erlang code compiled (`rebar3 compile`; REBAR_BASE_DIR honoured).
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
CTL="$HERE/test-node-ctl.sh"
DIR=${EVATAR_SIM_DIR:-${XDG_RUNTIME_DIR:-/tmp}/evatar-sim-$(id -u)}

usage() { sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'; }
die() { echo "sim-node.sh: $*" >&2; exit 2; }
random_secret() { head -c 18 /dev/urandom | base64 | tr '+/' '-_'; }

# The control directory: created private, and refused when someone else
# could reach the socket in it.
private_dir() {
  mkdir -p -m 700 "$DIR"
  local owner mode
  read -r owner mode < <(stat -c '%u %a' "$DIR")
  [ "$owner" = "$(id -u)" ] || die "$DIR belongs to another user"
  [ "$mode" = 700 ] || die "$DIR is mode $mode, not 700: others could drive the node; give --dir a private directory (one this script creates is)"
}

if [ "${1:-}" = "--dir" ]; then
  [ $# -ge 2 ] || die "--dir needs a directory"
  DIR=$2
  shift 2
fi
SOCK="$DIR/node.sock"

start() {
  local kind=${1:-}
  [ "$kind" = home ] || [ "$kind" = robots ] || die "start home or start robots"
  shift
  local port=7400 pairing="" va="" script="" when="2024-11-15T17:55" speed=1 fto=5000
  local spool="" stdin=--no-stdin paused=()
  while [ $# -gt 0 ]; do
    case "$1" in
      --port) port=${2:?--port needs a value}; shift 2 ;;
      --pairing) pairing=${2:?--pairing needs a value}; shift 2 ;;
      --va-credential) va=${2:?--va-credential needs a value}; shift 2 ;;
      --script) script=${2:?--script needs a value}; shift 2 ;;
      --start) when=${2:?--start needs a value}; shift 2 ;;
      --speed) speed=${2:?--speed needs a value}; shift 2 ;;
      --feedback-timeout) fto=${2:?--feedback-timeout needs a value}; shift 2 ;;
      --spool) spool=${2:?--spool needs a value}; shift 2 ;;
      --stop-on-eof) stdin=""; shift ;;
      --paused) paused=(--paused); shift ;;
      *) die "unknown option $1 (see sim-node.sh --help)" ;;
    esac
  done
  [[ "$port" =~ ^[0-9]+$ ]] || die "--port is a number"
  [[ "$speed" =~ ^[1-9][0-9]*$ ]] || die "--speed is a positive integer"
  [[ "$fto" =~ ^[1-9][0-9]*$ ]] || die "--feedback-timeout is a positive integer (ms)"
  [[ "$when" =~ ^[0-9]{4}-[0-9]{2}-[0-9]{2}T[0-9]{2}:[0-9]{2}$ ]] || die "--start is YYYY-MM-DDTHH:MM"
  [[ -z "$pairing" || "$pairing" =~ ^[A-Za-z0-9_.-]+$ ]] \
    || die "--pairing: letters, digits, '_', '.', '-'"
  [[ "$va" != *:* && "$va" != *,* && "$va" != *" "* ]] \
    || die "--va-credential: no ':', ',' or space"
  [ -n "$va" ] || va=$(random_secret)
  private_dir
  local args=()
  if [ "$kind" = home ]; then
    pairing=${pairing:-home}
    spool=${spool:-$DIR/spool}
    script=${script:-holiday}
    if [ "$script" != holiday ] && [ "$script" != none ]; then
      [ -r "$script" ] || die "cannot read the script file $script"
      script=$(cd "$(dirname "$script")" && pwd)/$(basename "$script")
    fi
    local home_secret; home_secret=$(random_secret)
    args=("$pairing:$va:$home_secret:$fto" --home "$pairing:$home_secret:$spool" --script "$script")
    echo "EVATAR_PAIRING=$pairing"
    echo "EVATAR_SPOOL=$spool"
  else
    [ -z "$script" ] || die "--script is for the home (the robots have no people)"
    pairing=${pairing:-robot}
    local robots=""
    for n in 1 2; do
      local secret; secret=$(random_secret)
      args+=("$pairing$n:$va:$secret:$fto")
      robots="$robots${robots:+,}$pairing$n:$secret"
      echo "EVATAR_PAIRING=$pairing$n"
    done
    args+=(--robots "$robots")
  fi
  echo "EVATAR_VA_CREDENTIAL=$va"
  echo "EVATAR_CONTROL=$SOCK"
  # +B: Ctrl-C stops the node (no break menu).
  EVATAR_PORT=$port ERL_FLAGS="+B ${ERL_FLAGS:-}" exec "$CTL" "${args[@]}" --home-start "$when" --speed "$speed" \
    "${paused[@]}" --control "$SOCK" $stdin
}

case "${1:-}" in
  start) shift; start "$@" ;;
  mute|unmute|detach|attach|reconnect|entities|speed|run_until)
    [ $# -eq 2 ] || die "$1 takes one argument"
    [[ "$2" =~ ^[A-Za-z0-9_.:-]+$ ]] || die "bad argument '$2'"
    exec "$CTL" --send "$SOCK" "$@" ;;
  disconnect)
    [ $# -eq 2 ] || [ $# -eq 3 ] || die "disconnect ENTITY [MS]"
    [[ "$2" =~ ^[A-Za-z0-9_.-]+$ ]] || die "bad entity '$2'"
    [ $# -eq 2 ] || [[ "$3" =~ ^[0-9]+$ ]] || die "MS is a number"
    exec "$CTL" --send "$SOCK" "$@" ;;
  links|outcome|pause|resume|time|stop)
    [ $# -eq 1 ] || die "$1 takes no argument"
    exec "$CTL" --send "$SOCK" "$1" ;;
  -h|--help|help) usage ;;
  "") usage >&2; exit 2 ;;
  *) die "unknown command $1 (see sim-node.sh --help)" ;;
esac

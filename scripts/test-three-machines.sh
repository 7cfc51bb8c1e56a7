#!/usr/bin/env bash
# Runs docs/ha.md section 4 ("Three machines") as written, on three
# machines made of network namespaces: laptop (192.168.1.10), desktop
# (192.168.1.11) and tablet (192.168.1.12) on a bridge of their own, each
# resolving the three names through its own /etc/hosts
# (/etc/netns/NS/hosts, which `ip netns exec' mounts over /etc/hosts). Each
# machine has its own /etc/evatar (/etc/netns/NS/evatar, mounted the same
# way), /opt/evatar and /var/lib/evatar (directories of WORK mounted over
# them in the machine's mount namespace). What the machines share: the
# user `evatar' (made by useradd once, and removed at the end if this
# script made it) and /tmp.
#
# The steps are the section's: make the tarball (or take TARBALL), the
# distribution's and the bridge's certificates and the cookie on the
# laptop, copy them to the others, install them with the section's
# commands, write /etc/evatar/env, and start each node as the systemd unit
# would (as the user evatar, with that environment file, `bin/evatar
# foreground'); then, with the section's command for commands by hand,
# each node answers `ping', and `cluster' on the laptop sees the three
# nodes up with a quorum, connected over TLS. Two departures: root runs
# the steps the section prefixes with sudo, and systemd is played by a
# background process.
#
# Usage: scripts/test-three-machines.sh WORK [TARBALL]
# Exit status 0 when it all worked, 1 when a step failed (the step and its
# output are printed), 77 when network namespaces cannot be made here
# (not root, no `ip', no runuser): the first line says why.
# test/three_machines_SUITE.erl runs it in `make test'.
set -euo pipefail

ROOT=$(cd "$(dirname "$0")/.." && pwd)
WORK=${1:?usage: $0 WORK [TARBALL]}
TARBALL=${2:-}
MACHINES="laptop desktop tablet"
declare -A ADDR=([laptop]=192.168.1.10 [desktop]=192.168.1.11 [tablet]=192.168.1.12)
PREFIX="evatar-$$-hm"
HUB="$PREFIX-hub"
PATH_CLEAN=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin

skip() { echo "SKIP: $*"; exit 77; }
fail() { echo "FAILED: $*"; exit 1; }
say() { echo "== $*"; }

[ "$(id -u)" = 0 ] || skip "network namespaces need root; running as uid $(id -u)"
command -v ip >/dev/null || skip "no \`ip' (iproute2) on the PATH"
command -v runuser >/dev/null || skip "no runuser (util-linux) to run the nodes as the user evatar"
ip netns add "$PREFIX-probe" 2>/dev/null || skip "cannot make a network namespace"
ip netns del "$PREFIX-probe"

ns() { echo "$PREFIX-$1"; }

MADE_DIRS=""
MADE_USER=""
cleanup() {
    set +e
    for m in $MACHINES; do
        pids=$(ip netns pids "$(ns "$m")" 2>/dev/null)
        [ -n "$pids" ] && kill -9 $pids 2>/dev/null
        ip netns del "$(ns "$m")" 2>/dev/null
        rm -rf "/etc/netns/$(ns "$m")"
    done
    ip netns del "$HUB" 2>/dev/null
    [ -n "$MADE_USER" ] && userdel evatar 2>/dev/null
    for d in $MADE_DIRS; do rm -rf "$d"; done
}
trap cleanup EXIT

# The mount points of each machine's own directories.
for d in /etc/evatar /opt/evatar /var/lib/evatar; do
    if [ ! -e "$d" ]; then mkdir -p "$d"; MADE_DIRS="$MADE_DIRS $d"; fi
done

# The home network: a bridge in a hub namespace, one veth to each machine.
mkdir -p "$WORK"
WORK=$(cd "$WORK" && pwd -P)
ip netns add "$HUB"
ip -n "$HUB" link add br0 type bridge
ip -n "$HUB" link set br0 up
for m in $MACHINES; do
    n=$(ns "$m")
    ip netns add "$n"
    ip -n "$HUB" link add "v-$m" type veth peer name eth0 netns "$n"
    ip -n "$HUB" link set "v-$m" master br0 up
    ip -n "$n" link set lo up
    ip -n "$n" addr add "${ADDR[$m]}/24" dev eth0
    ip -n "$n" link set eth0 up
    mkdir -p "/etc/netns/$n/evatar" "$WORK/$m/opt" "$WORK/$m/home" "$WORK/$m/incoming"
    {
        echo "127.0.0.1 localhost"
        for o in $MACHINES; do echo "${ADDR[$o]} $o"; done
    } > "/etc/netns/$n/hosts"
done

# on MACHINE CMD...: CMD as root on MACHINE, in its network and with its
# own /etc/hosts, /etc/evatar, /opt/evatar and /var/lib/evatar.
on() {
    local m=$1; shift
    ip netns exec "$(ns "$m")" sh -c 'mount --bind "$1/opt" /opt/evatar && mount --bind "$1/home" /var/lib/evatar && shift && exec "$@"' on "$WORK/$m" "$@"
}
# by_hand MACHINE COMMAND: the section's way of running a command by hand,
# `sudo -u evatar sh -c 'set -a; . /etc/evatar/env; HOME=/var/lib/evatar; COMMAND''.
by_hand() {
    on "$1" env -i PATH="$PATH_CLEAN" runuser -u evatar -- sh -c "set -a; . /etc/evatar/env; HOME=/var/lib/evatar; $2"
}

say "the tarball"
if [ -z "$TARBALL" ]; then
    (cd "$ROOT" && make tar) > "$WORK/make-tar.log" 2>&1 || { cat "$WORK/make-tar.log"; fail "make tar"; }
    TARBALL=$ROOT/_build/prod/rel/evatar/evatar-0.1.0.tar.gz
fi
[ -f "$TARBALL" ] || fail "no tarball $TARBALL"

say "certificates and cookie, on the laptop"
on laptop sh -c "cd '$WORK/laptop/incoming' &&
  '$ROOT/scripts/gen-dist-certs.sh' /etc/evatar/tls laptop desktop tablet &&
  EVATAR_SERVER_HOSTS='laptop desktop tablet 192.168.1.10 192.168.1.11 192.168.1.12' \
    '$ROOT/scripts/gen-bridge-certs.sh' /etc/evatar/bridge va lamp &&
  head -c 24 /dev/urandom | od -An -tx1 | tr -d ' \n' > cookie" > "$WORK/certs.log" 2>&1 \
    || { cat "$WORK/certs.log"; fail "certificates"; }

say "copied to every machine"
for m in $MACHINES; do
    in=$WORK/$m/incoming
    mkdir -p "$in/tls" "$in/bridge"
    cp "$TARBALL" "$in/evatar-0.1.0.tar.gz"
    cp "$WORK/laptop/incoming/cookie" "$in/cookie" 2>/dev/null || true
    for f in ca.pem node.pem node.key ssl_dist.conf; do cp "/etc/netns/$(ns laptop)/evatar/tls/$f" "$in/tls/"; done
    for f in ca.pem server.pem server.key; do cp "/etc/netns/$(ns laptop)/evatar/bridge/$f" "$in/bridge/"; done
done

say "the user evatar"
if ! id evatar >/dev/null 2>&1; then
    useradd --system --home-dir /var/lib/evatar --create-home evatar
    MADE_USER=yes
fi
for m in $MACHINES; do
    chown evatar:evatar "$WORK/$m/home"
    chmod 0700 "$WORK/$m/home"
done

say "installed on every machine"
for m in $MACHINES; do
    on "$m" sh -c "cd '$WORK/$m/incoming' && set -e
mkdir -p /opt/evatar && tar xzf evatar-0.1.0.tar.gz -C /opt/evatar
install -d -m 0750 -o evatar -g evatar /var/lib/evatar/data
install -m 0400 -o evatar -g evatar cookie /var/lib/evatar/.erlang.cookie
install -d -m 0750 -o root -g evatar /etc/evatar/tls /etc/evatar/bridge
install -m 0644 tls/ca.pem tls/node.pem tls/ssl_dist.conf /etc/evatar/tls/
install -m 0440 -o root -g evatar tls/node.key /etc/evatar/tls/
install -m 0644 bridge/ca.pem bridge/server.pem /etc/evatar/bridge/
install -m 0440 -o root -g evatar bridge/server.key /etc/evatar/bridge/" > "$WORK/$m/install.log" 2>&1 \
        || { cat "$WORK/$m/install.log"; fail "install on $m"; }
    ip=${ADDR[$m]}
    cat > "/etc/netns/$(ns "$m")/evatar/env" <<ENV
EVATAR_NODE=evatar@$m
EVATAR_PEERS=evatar@laptop,evatar@desktop,evatar@tablet
EVATAR_DIST_IP=${ip//./,}
EVATAR_DIST=inet_tls
ERL_FLAGS="-ssl_dist_optfile /etc/evatar/tls/ssl_dist.conf"
USE_NODETOOL=1
EVATAR_DIST_PORT_MIN=9100
EVATAR_DIST_PORT_MAX=9100
EVATAR_TLS=true
EVATAR_TLS_IP=0,0,0,0
EVATAR_TLS_PORT=7401
EVATAR_TLS_CERTFILE=/etc/evatar/bridge/server.pem
EVATAR_TLS_KEYFILE=/etc/evatar/bridge/server.key
EVATAR_DATA_DIR=/var/lib/evatar/data
RELX_OUT_FILE_PATH=/var/lib/evatar
ENV
done

say "started as the systemd unit would"
declare -A NODE_PID
for m in $MACHINES; do
    by_hand "$m" "exec /opt/evatar/bin/evatar foreground" > "$WORK/$m/journal" 2>&1 &
    NODE_PID[$m]=$!
done

# until MACHINE WHAT CMD: runs CMD (by hand, on MACHINE) until it succeeds;
# fails at once when that machine's node has exited, or after 120 s.
until_ok() {
    local m=$1 what=$2 cmd=$3 deadline=$((SECONDS + 120))
    while :; do
        if out=$(by_hand "$m" "$cmd" 2>&1); then echo "$out"; return 0; fi
        for o in $MACHINES; do
            kill -0 "${NODE_PID[$o]}" 2>/dev/null || { echo "the node of $o exited; its journal:"; cat "$WORK/$o/journal"; fail "$what"; }
        done
        [ $SECONDS -lt $deadline ] || { echo "$out"; fail "$what: still failing after 120 s"; }
        sleep 1
    done
}

for m in $MACHINES; do
    say "ping on $m"
    until_ok "$m" "ping on $m" "/opt/evatar/bin/evatar ping"
done
say "the cluster, from the laptop"
until_ok laptop "three nodes up with a quorum" \
    "/opt/evatar/bin/evatar cluster --json | tr -d ' \n' | grep -q '\"quorum\":true' && [ \$(/opt/evatar/bin/evatar cluster --json | tr -d ' \n' | grep -o '\"up\":true' | wc -l) = 3 ]"
by_hand laptop "/opt/evatar/bin/evatar cluster"
say "over TLS"
# {the peers connected, those of them over TLS}
info=$(by_hand laptop "/opt/evatar/bin/evatar eval '{length(nodes()), length([N || {N, I} <- element(2, net_kernel:nodes_info()), lists:member(N, nodes()), element(4, proplists:get_value(address, I)) =:= tls])}.'")
[ "$(echo "$info" | tr -d ' \n')" = "{2,2}" ] || fail "peers connected, over TLS: $info ({2,2} expected)"
echo "the laptop's 2 peers connected over TLS"
for m in $MACHINES; do
    by_hand "$m" "/opt/evatar/bin/evatar stop" >/dev/null 2>&1 || true
done
echo "PASSED: docs/ha.md section 4 on three machines"

#!/usr/bin/env bash
# Generates what TLS distribution (inet_tls_dist) needs for an EVATAR
# cluster: a private certificate authority, one node certificate signed by
# it whose names cover every given host, and the options file the release
# reads (EVATAR_DIST=inet_tls, ERL_FLAGS="-ssl_dist_optfile DIR/ssl_dist.conf").
# Every node presents the certificate and accepts only peers whose
# certificate the same CA signed (verify_peer both ways), so the cookie is
# no longer the only secret and the traffic is encrypted. See docs/ha.md.
#
# Usage: scripts/gen-dist-certs.sh DIR [HOST...]
#   DIR   where to write ca.pem, ca.key, node.pem, node.key, ssl_dist.conf
#         (created; an existing CA in DIR is reused, so a new node
#         certificate can be issued for more hosts later)
#   HOST  names or addresses the nodes' names use after the @ (default:
#         127.0.0.1, localhost and this machine's host name)
# Copy DIR to every machine of the cluster at the same path (or edit the
# paths in ssl_dist.conf); ca.key need not leave the machine that made it.
set -euo pipefail

if [ $# -lt 1 ]; then
  echo "usage: $0 DIR [HOST...]" >&2
  exit 2
fi
if ! command -v openssl >/dev/null 2>&1; then
  echo "gen-dist-certs: openssl is missing (scripts/ensure-deps.sh installs it)" >&2
  exit 1
fi

DIR=$1; shift
mkdir -p "$DIR"
DIR=$(cd "$DIR" && pwd -P)
if [ $# -eq 0 ]; then
  set -- 127.0.0.1 localhost "$(hostname)"
fi

DAYS=${EVATAR_CERT_DAYS:-3650}
umask 077

if [ ! -f "$DIR/ca.pem" ] || [ ! -f "$DIR/ca.key" ]; then
  echo "gen-dist-certs: new CA in $DIR/ca.pem"
  openssl req -x509 -newkey rsa:2048 -nodes -sha256 -days "$DAYS" \
    -subj "/CN=EVATAR cluster CA" \
    -keyout "$DIR/ca.key" -out "$DIR/ca.pem" 2>/dev/null
fi

# Subject alternative names: DNS entries for names; an address gets both
# an IP and a DNS entry, because inet_tls_dist checks the host part of a
# node name (evatar1@192.168.1.10) as a server name, whatever it looks like.
san=""
for h in "$@"; do
  if [[ $h =~ ^[0-9.]+$ || $h == *:* ]]; then entry="IP:$h,DNS:$h"; else entry="DNS:$h"; fi
  san="${san:+$san,}$entry"
done

ext=$(mktemp)
trap 'rm -f "$ext" "$DIR/node.csr"' EXIT
cat > "$ext" <<EXT
basicConstraints = CA:FALSE
keyUsage = digitalSignature, keyEncipherment
extendedKeyUsage = serverAuth, clientAuth
subjectAltName = $san
EXT

openssl req -newkey rsa:2048 -nodes -sha256 -subj "/CN=EVATAR node" \
  -keyout "$DIR/node.key" -out "$DIR/node.csr" 2>/dev/null
openssl x509 -req -in "$DIR/node.csr" -CA "$DIR/ca.pem" -CAkey "$DIR/ca.key" \
  -CAcreateserial -days "$DAYS" -sha256 -extfile "$ext" -out "$DIR/node.pem" 2>/dev/null

cat > "$DIR/ssl_dist.conf" <<CONF
%% TLS options of EVATAR's distribution (inet_tls_dist), written by
%% scripts/gen-dist-certs.sh. Both sides present a certificate signed by
%% the cluster's CA and verify the other's.
[{server, [{certfile, "$DIR/node.pem"},
           {keyfile, "$DIR/node.key"},
           {cacertfile, "$DIR/ca.pem"},
           {verify, verify_peer},
           {fail_if_no_peer_cert, true},
           {secure_renegotiate, true},
           {versions, ['tlsv1.3', 'tlsv1.2']}]},
 {client, [{certfile, "$DIR/node.pem"},
           {keyfile, "$DIR/node.key"},
           {cacertfile, "$DIR/ca.pem"},
           {verify, verify_peer},
           {secure_renegotiate, true},
           {versions, ['tlsv1.3', 'tlsv1.2']}]}].
CONF
chmod 600 "$DIR/node.key" "$DIR/ca.key"
chmod 644 "$DIR/ca.pem" "$DIR/node.pem" "$DIR/ssl_dist.conf"
echo "gen-dist-certs: node certificate for $san in $DIR/node.pem"
echo "gen-dist-certs: run the release with:"
echo "  EVATAR_DIST=inet_tls USE_NODETOOL=1 ERL_FLAGS=\"-ssl_dist_optfile $DIR/ssl_dist.conf\""

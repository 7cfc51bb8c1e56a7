#!/usr/bin/env bash
# Generates the certificates of a TLS bridge listener (docs/protocol.md,
# "TLS"): a private certificate authority, a server certificate signed by
# it, and one client certificate per device name, also signed by it. The
# tests of the three client libraries use it for their TLS cases, and it is
# a starting point for a home network.
#
# Usage: scripts/gen-bridge-certs.sh DIR [CLIENT...]
#        scripts/gen-bridge-certs.sh --server DIR
#   DIR     where to write (created): ca.pem, ca.key, server.pem, server.key,
#           server.sha256 (the server certificate's SHA-256 fingerprint, the
#           value a client pins), and client-NAME.pem, client-NAME.key,
#           client-NAME.sha256 for each CLIENT. An existing CA in DIR is
#           reused, so more clients can be added later.
#   CLIENT  device names, each becoming a certificate's subject CN
#           (default: device-1). Letters, digits, '.', '_' and '-' only.
#   --server  renews the server certificate and key only, with DIR's CA
#           (which must exist): clients that trust ca.pem need nothing new;
#           clients that pin server.sha256 need the new fingerprint.
# Environment:
#   EVATAR_SERVER_HOSTS  names and addresses the server certificate is valid
#                        for (default: "localhost 127.0.0.1 ::1" and this
#                        machine's host name)
#   EVATAR_SERVER_DAYS   the server certificate's validity in days (default
#                        397; at most 398, what browsers accept)
#   EVATAR_CERT_DAYS     the CA's and the client certificates' validity in
#                        days (default 3650)
# The CA certificate is a CA (basicConstraints CA:TRUE, pathlen 0, keyUsage
# keyCertSign and cRLSign) and signs nothing but the leaf certificates,
# which are not CAs: keyUsage digitalSignature, extendedKeyUsage serverAuth
# (with the host names as subjectAltName) or clientAuth. Keys are ECDSA
# P-256 (fast handshakes on small boards); private keys are written mode
# 0600. ca.key need not leave the machine that made it.
set -euo pipefail

if [ $# -lt 1 ]; then
  echo "usage: $0 DIR [CLIENT...]" >&2
  exit 2
fi
if ! command -v openssl >/dev/null 2>&1; then
  echo "gen-bridge-certs: openssl is missing (scripts/ensure-deps.sh installs it)" >&2
  exit 1
fi

SERVER_ONLY=false
if [ "$1" = "--server" ]; then
  SERVER_ONLY=true; shift
  if [ $# -ne 1 ]; then
    echo "usage: $0 --server DIR" >&2
    exit 2
  fi
fi
DIR=$1; shift
if $SERVER_ONLY && { [ ! -f "$DIR/ca.pem" ] || [ ! -f "$DIR/ca.key" ]; }; then
  echo "gen-bridge-certs: --server renews with the CA in $DIR, and $DIR/ca.pem or ca.key is missing" >&2
  exit 1
fi
mkdir -p "$DIR"
DIR=$(cd "$DIR" && pwd -P)
if [ $# -eq 0 ] && ! $SERVER_ONLY; then
  set -- device-1
fi
HOSTS=${EVATAR_SERVER_HOSTS:-"localhost 127.0.0.1 ::1 $(hostname)"}
DAYS=${EVATAR_CERT_DAYS:-3650}
SERVER_DAYS=${EVATAR_SERVER_DAYS:-397}
if ! [[ $SERVER_DAYS =~ ^[0-9]+$ ]] || [ "$SERVER_DAYS" -lt 1 ] || [ "$SERVER_DAYS" -gt 398 ]; then
  echo "gen-bridge-certs: EVATAR_SERVER_DAYS must be 1 to 398 (browsers refuse longer server certificates), not '$SERVER_DAYS'" >&2
  exit 2
fi
umask 077

for name in "$@"; do
  if [[ ! $name =~ ^[A-Za-z0-9._-]+$ ]]; then
    echo "gen-bridge-certs: bad client name '$name' (letters, digits, . _ - only)" >&2
    exit 2
  fi
done

tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

newkey() { openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$1" 2>/dev/null; }
fingerprint() {
  openssl x509 -in "$1" -outform DER | openssl dgst -sha256 -r | cut -d' ' -f1 > "$2"
}

if [ ! -f "$DIR/ca.pem" ] || [ ! -f "$DIR/ca.key" ]; then
  newkey "$DIR/ca.key"
  openssl req -x509 -new -key "$DIR/ca.key" -sha256 -days "$DAYS" \
    -subj "/CN=EVATAR bridge CA" \
    -addext "basicConstraints=critical,CA:TRUE,pathlen:0" \
    -addext "keyUsage=critical,keyCertSign,cRLSign" \
    -addext "subjectKeyIdentifier=hash" \
    -out "$DIR/ca.pem" 2>/dev/null
  echo "gen-bridge-certs: new CA in $DIR/ca.pem"
fi

# sign NAME CN EKU DAYS [SAN]: NAME.key, NAME.pem and NAME.sha256 signed by the CA.
sign() {
  local name=$1 cn=$2 eku=$3 days=$4 san=${5:-}
  newkey "$DIR/$name.key"
  openssl req -new -key "$DIR/$name.key" -sha256 -subj "/CN=$cn" -out "$tmp/$name.csr" 2>/dev/null
  {
    echo "basicConstraints = critical, CA:FALSE"
    echo "keyUsage = critical, digitalSignature"
    echo "extendedKeyUsage = $eku"
    echo "subjectKeyIdentifier = hash"
    echo "authorityKeyIdentifier = keyid:always"
    if [ -n "$san" ]; then echo "subjectAltName = $san"; fi
  } > "$tmp/$name.ext"
  openssl x509 -req -in "$tmp/$name.csr" -CA "$DIR/ca.pem" -CAkey "$DIR/ca.key" \
    -CAcreateserial -CAserial "$DIR/ca.srl" -days "$days" -sha256 \
    -extfile "$tmp/$name.ext" -out "$DIR/$name.pem" 2>/dev/null
  fingerprint "$DIR/$name.pem" "$DIR/$name.sha256"
  chmod 600 "$DIR/$name.key"
  chmod 644 "$DIR/$name.pem" "$DIR/$name.sha256"
}

san=""
for h in $HOSTS; do
  if [[ $h =~ ^[0-9.]+$ || $h == *:* ]]; then entry="IP:$h"; else entry="DNS:$h"; fi
  san="${san:+$san,}$entry"
done
sign server "EVATAR bridge" serverAuth "$SERVER_DAYS" "$san"
echo "gen-bridge-certs: server certificate for $san, SHA-256 $(cat "$DIR/server.sha256")"
for name in "$@"; do
  sign "client-$name" "$name" clientAuth "$DAYS"
  echo "gen-bridge-certs: client certificate CN=$name in $DIR/client-$name.pem"
done
chmod 644 "$DIR/ca.pem"

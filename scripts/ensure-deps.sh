#!/usr/bin/env bash
# Installs what EVATAR needs on a Debian machine, only what is missing, and
# says what it is doing. Used by `make demo`, `make test` and .ci/run.
# Then the HTTP server's libraries (cowboy, ranch, cowlib) into _deps/, below.
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)

PKGS=(erlang-nox erlang-dev erlang-xmerl erlang-common-test erlang-proper
      erlang-proper-dev erlang-dialyzer erlang-jiffy rebar3 mosquitto libxml2-utils python3 openssl make git
      python3-venv python3-pip openjdk-17-jdk-headless maven
      python3-prometheus-client strace
      # scripts/test-under-load.sh: make test while every core is busy.
      stress-ng
      # The dashboard's browser test (evatar_web_dash_SUITE): Debian's
      # chromium, driven by playwright-core from npm.
      chromium nodejs)

missing=()
for p in "${PKGS[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'install ok installed'; then
    missing+=("$p")
  fi
done

# Debian's nodejs comes without npm; nodejs from elsewhere has its own.
if ! command -v npm >/dev/null 2>&1; then
  missing+=(npm)
fi

# The HTTP API runs on cowboy 2.8.0, ranch 2.1.0 and cowlib 2.9.1. Hex
# cannot be reached, so they come as Debian built them for this OTP, inside
# its rabbitmq-server package: the package is downloaded (pinned), not
# installed (no broker runs), and only those three applications' directories
# are copied into _deps/ (gitignored). rebar.config.script puts _deps/ on
# rebar3's code path and in ERL_LIBS; the scripts that start nodes export
# ERL_LIBS too; a release copies the three into its lib/.
RMQ_VERSION=3.10.8-1.1+deb12u1
RMQ_PLUGINS=usr/lib/rabbitmq/lib/rabbitmq_server-3.10.8/plugins
HTTP_APPS=(cowboy-2.8.0 ranch-2.1.0 cowlib-2.9.1)
DEPS_DIR="$ROOT/_deps"

http_apps_present() {
  local app
  for app in "${HTTP_APPS[@]}"; do
    [ -f "$DEPS_DIR/$app/ebin/${app%-*}.app" ] || return 1
  done
}

ensure_http_apps() {
  if http_apps_present; then
    return 0
  fi
  if ! command -v apt-get >/dev/null 2>&1 || ! command -v dpkg >/dev/null 2>&1; then
    echo "ensure-deps: need apt-get and dpkg to fetch ${HTTP_APPS[*]} (Debian's rabbitmq-server $RMQ_VERSION)" >&2
    exit 1
  fi
  local tmp deb app
  tmp=$(mktemp -d)
  chmod 0755 "$tmp"   # apt-get downloads as the _apt user
  echo "ensure-deps: downloading rabbitmq-server=$RMQ_VERSION (not installing it) for ${HTTP_APPS[*]}"
  if ! (cd "$tmp" && apt-get download -qq "rabbitmq-server=$RMQ_VERSION" >/dev/null); then
    # The package lists may not know the version yet (a fresh machine).
    echo "ensure-deps: apt-get update, then downloading again"
    $SUDO apt-get update -qq
    (cd "$tmp" && apt-get download -qq "rabbitmq-server=$RMQ_VERSION" >/dev/null)
  fi
  deb=$(ls "$tmp"/rabbitmq-server_*.deb)
  echo "ensure-deps: unpacking $(basename "$deb") into a temporary directory; copying ${HTTP_APPS[*]} to _deps/"
  dpkg -x "$deb" "$tmp/x"
  mkdir -p "$DEPS_DIR"
  for app in "${HTTP_APPS[@]}"; do
    rm -rf "${DEPS_DIR:?}/$app"
    cp -r "$tmp/x/$RMQ_PLUGINS/$app" "$DEPS_DIR/$app"
  done
  rm -rf "$tmp"
  if ! http_apps_present; then
    echo "ensure-deps: rabbitmq-server $RMQ_VERSION did not hold ${HTTP_APPS[*]}" >&2
    exit 1
  fi
}

SUDO=""
if [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1; then
  SUDO="sudo"
fi

if [ ${#missing[@]} -eq 0 ]; then
  ensure_http_apps
  echo "ensure-deps: all prerequisites present (${PKGS[*]}; ${HTTP_APPS[*]} in _deps/)"
  exit 0
fi

if ! command -v apt-get >/dev/null 2>&1; then
  echo "ensure-deps: missing ${missing[*]} and apt-get is not available." >&2
  echo "ensure-deps: install Erlang/OTP 25+, rebar3, PropEr and mosquitto by hand." >&2
  exit 1
fi

SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1; then
    SUDO="sudo"
  else
    echo "ensure-deps: need root (or sudo) to install: ${missing[*]}" >&2
    exit 1
  fi
fi

echo "ensure-deps: installing ${missing[*]} with apt-get"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
ensure_http_apps
echo "ensure-deps: done"

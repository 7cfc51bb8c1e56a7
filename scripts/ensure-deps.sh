#!/usr/bin/env bash
# Installs what EVATAR needs on a Debian machine, only what is missing, and
# says what it is doing. Used by `make demo`, `make test` and .ci/run.
set -euo pipefail

PKGS=(erlang-nox erlang-dev erlang-xmerl erlang-common-test erlang-proper
      erlang-proper-dev erlang-dialyzer erlang-jiffy rebar3 mosquitto libxml2-utils python3 openssl make git
      python3-venv python3-pip openjdk-17-jdk-headless maven
      python3-prometheus-client strace
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

if [ ${#missing[@]} -eq 0 ]; then
  echo "ensure-deps: all prerequisites present (${PKGS[*]})"
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
echo "ensure-deps: done"

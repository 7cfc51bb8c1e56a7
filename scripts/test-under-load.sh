#!/usr/bin/env bash
# The README's test command from clean clones, several times in a row, while
# stress-ng keeps more workers busy than the machine has cores: the check
# that no test depends on an idle machine.
#
#   bash scripts/test-under-load.sh [RUNS] [COMMIT] [WORKERS]
#
# RUNS (default 3) clean clones of COMMIT (default HEAD of this repository)
# each run `bash .ci/run` in turn under `stress-ng --cpu WORKERS` (default
# twice the cores). Each run's output goes to DIR/run-K.log, DIR printed at
# the start (EVATAR_LOAD_DIR to choose it); the load average is sampled
# every 30 s into DIR/load.log. At the end one line per run: its
# `N passed, N failed` line, its wall time and the failed cases; the exit
# status is non-zero when any run failed.
set -u
ROOT=$(cd "$(dirname "$0")/.." && pwd)
RUNS=${1:-3}
COMMIT=${2:-HEAD}
WORKERS=${3:-$(( 2 * $(nproc) ))}
SHA=$(git -C "$ROOT" rev-parse --verify "$COMMIT^{commit}") || exit 2
DIR=${EVATAR_LOAD_DIR:-$(mktemp -d /tmp/evatar-load.XXXX)}
mkdir -p "$DIR"

bash "$ROOT/scripts/ensure-deps.sh" >/dev/null || exit 1
echo "test-under-load: $RUNS runs of ${SHA:0:12} under stress-ng --cpu $WORKERS; logs in $DIR"

setsid stress-ng --cpu "$WORKERS" --quiet > "$DIR/stress.log" 2>&1 &
STRESS=$!
( while sleep 30; do echo "$(date +%T) $(cut -d' ' -f1-3 /proc/loadavg)"; done ) > "$DIR/load.log" &
SAMPLER=$!
trap 'kill -- -$STRESS 2>/dev/null; kill $SAMPLER 2>/dev/null' EXIT

results=()
failed=0
for k in $(seq 1 "$RUNS"); do
  clone="$DIR/clone-$k"
  rm -rf "$clone"
  git clone -q "$ROOT" "$clone" && git -C "$clone" checkout -q "$SHA" || exit 1
  # A clean clone has no _deps/ yet: .ci/run's ensure-deps fetches them.
  t0=$SECONDS
  (cd "$clone" && bash .ci/run) > "$DIR/run-$k.log" 2>&1
  rc=$?
  [ "$rc" -eq 0 ] || failed=$((failed + 1))
  count=$(grep -E '^[0-9]+ passed, [0-9]+ failed$' "$DIR/run-$k.log" | tail -1)
  # Common Test's and EUnit's names of what failed, as the run printed them.
  cases=$(sed -E 's/\x1b\[[0-9;]*m//g' "$DIR/run-$k.log" \
            | grep -oE '%%% [A-Za-z0-9_]+ ==> [A-Za-z0-9_.]+: FAILED|== [a-z-]+: FAILED' \
            | sort -u | tr '\n' ';')
  results+=("run $k: rc=$rc, ${count:-no count line}, $((SECONDS - t0)) s${cases:+, failed: $cases}")
  echo "test-under-load: ${results[-1]}"
done

echo "test-under-load: load average (1, 5, 15 min) over the runs: $(awk '{print $2}' "$DIR/load.log" | sort -n | sed -n '1p;$p' | tr '\n' ' ')(min max of 1-min)"
printf '%s\n' "${results[@]}"
[ "$failed" -eq 0 ]

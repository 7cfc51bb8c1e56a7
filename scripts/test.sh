#!/usr/bin/env bash
# The two tiers of tests, one script so that both count the same way.
#
#   scripts/test.sh         `make test`: everything. xref, dialyzer, EUnit,
#                           the client suites in other languages (clients/*),
#                           every Common Test suite (apps/*/test and the
#                           multi-node root test/; the PropEr properties run
#                           inside them), with cover.
#   scripts/test.sh check   `make check`: the quick tier. xref, dialyzer,
#                           EUnit and the Common Test suites of apps/*/test
#                           that run on one node (the pure properties among
#                           them, each at a quarter of its count unless
#                           EVATAR_PROPER_FACTOR says otherwise); no root
#                           test/, no app suite that starts a cluster, no
#                           client suites, no cover.
#
# Each check's own output goes to the terminal and to _build/test-report/;
# the last line is the plain count `N passed, N failed` over every test case
# (xref and dialyzer count as one case each), and the exit status is
# non-zero when anything failed.
set -u
cd "$(dirname "$0")/.."

tier=${1:-all}
case "$tier" in
  all|check) ;;
  *) echo "usage: $0 [check]" >&2; exit 2 ;;
esac

REPORT=_build/test-report
mkdir -p "$REPORT"
passed=0
failed=0
summary=()

note() { summary+=("$1"); echo "== $1"; }

# step NAME CMD...: runs one rebar3 step, tee'd to a log.
step() {
  local name=$1; shift
  echo
  echo "== $name: $*"
  # To a file, not through a pipe: a stray child process that inherited the
  # pipe would otherwise keep the whole run waiting after the tool is done.
  local rc=0 t0=$SECONDS
  "$@" > "$REPORT/$name.log" 2>&1 < /dev/null || rc=$?
  cat "$REPORT/$name.log"
  echo "== $name took $((SECONDS - t0)) s"
  return "$rc"
}

# A whole-tool check (xref, dialyzer): one case, passed or failed.
check() {
  local name=$1; shift
  if step "$name" "$@"; then
    passed=$((passed + 1)); note "$name: passed"
  else
    failed=$((failed + 1)); note "$name: FAILED (see $REPORT/$name.log)"
  fi
}

# Counts EUnit's or Common Test's own summary lines (rebar3's formats:
# EUnit "7 tests, 1 failures, 2 cancelled"; Common Test "All 5 tests passed."
# or "Failed 1 tests. Skipped 2 (0, 2) tests. Passed 1 tests."). A run that
# died before it could count (a compile error) is a failure, and so are
# cancelled cases and cases skipped because their init failed.
count_cases() {
  local name=$1 rc=$2 log="$REPORT/$1.log"
  local p=0 f=0 s=0 auto=0 line clean
  clean=$(sed -E 's/\x1b\[[0-9;]*m//g' "$log")
  if line=$(echo "$clean" | grep -E '^\s*[0-9]+ tests, [0-9]+ failures' | tail -1); [ -n "$line" ]; then
    local total fails canc skip
    total=$(echo "$line" | sed -E 's/^\s*([0-9]+) tests.*/\1/')
    fails=$(echo "$line" | sed -E 's/.* ([0-9]+) failures.*/\1/')
    canc=$(echo "$line" | grep -oE '[0-9]+ cancelled' | grep -oE '[0-9]+'); canc=${canc:-0}
    skip=$(echo "$line" | grep -oE '[0-9]+ skipped' | grep -oE '[0-9]+'); skip=${skip:-0}
    f=$((fails + canc)); s=$skip; p=$((total - fails - canc - skip))
  fi
  if line=$(echo "$clean" | grep -E '^\s*All [0-9]+ tests passed\.' | tail -1); [ -n "$line" ]; then
    p=$(echo "$line" | grep -oE '[0-9]+' | head -1)
  fi
  if line=$(echo "$clean" | grep -E '^(Failed [0-9]+ tests?\.|Skipped [0-9]+ \(|Passed [0-9]+ tests?\.)' | tail -1); [ -n "$line" ]; then
    f=$(echo "$line" | grep -oE 'Failed [0-9]+' | grep -oE '[0-9]+'); f=${f:-0}
    p=$(echo "$line" | grep -oE 'Passed [0-9]+' | grep -oE '[0-9]+'); p=${p:-0}
    s=$(echo "$line" | grep -oE 'Skipped [0-9]+ \([0-9]+, [0-9]+\)' | sed -E 's/Skipped [0-9]+ \(([0-9]+),.*/\1/'); s=${s:-0}
    auto=$(echo "$line" | grep -oE 'Skipped [0-9]+ \([0-9]+, [0-9]+\)' | sed -E 's/.*, ([0-9]+)\)/\1/'); auto=${auto:-0}
    f=$((f + auto))
  fi
  if [ "$rc" -ne 0 ] && [ "$f" -eq 0 ]; then f=1; fi
  if [ "$p" -eq 0 ] && [ "$f" -eq 0 ]; then f=1; fi   # nothing ran at all
  passed=$((passed + p)); failed=$((failed + f))
  if [ "$s" -gt 0 ]; then note "$name: $p passed, $f failed, $s skipped"
  else note "$name: $p passed, $f failed"; fi
}

# The clients in other languages (clients/*, docs/clients.md) run their own
# suites against real nodes started from the default profile's build, which
# xref has just compiled. Each script ends with the same `N passed, N
# failed' line, which is added in. They run one after the other once
# dialyzer and EUnit are done, with nothing else beside them, so that no
# check loads the machine under another's timeouts.
clients_run() {
  local script name
  for script in clients/*/run-tests.sh; do
    name="clients-$(basename "$(dirname "$script")")"
    # Not step(): its output would interleave with dialyzer's and EUnit's.
    local rc=0 t0=$SECONDS
    bash "$script" > "$REPORT/$name.log" 2>&1 < /dev/null || rc=$?
    echo "$rc $((SECONDS - t0))" > "$REPORT/$name.status"
  done
}

clients_count() {
  local script name rc took line p f
  for script in clients/*/run-tests.sh; do
    name="clients-$(basename "$(dirname "$script")")"
    echo
    echo "== $name: bash $script"
    cat "$REPORT/$name.log" 2>/dev/null
    read -r rc took < "$REPORT/$name.status" 2>/dev/null || { rc=1; took=?; }
    echo "== $name took $took s"
    line=$(sed -E 's/\x1b\[[0-9;]*m//g' "$REPORT/$name.log" 2>/dev/null | grep -E '^[0-9]+ passed, [0-9]+ failed$' | tail -1)
    if [ -n "$line" ]; then
      p=$(echo "$line" | cut -d' ' -f1); f=$(echo "$line" | cut -d' ' -f3)
    else
      p=0; f=0
    fi
    if [ "$rc" -ne 0 ] && [ "$f" -eq 0 ]; then f=1; fi
    if [ "$p" -eq 0 ] && [ "$f" -eq 0 ]; then f=1; fi
    passed=$((passed + p)); failed=$((failed + f))
    note "$name: $p passed, $f failed"
  done
}

# The names of the cases that failed, so that the last lines of a run (all a
# CI page may keep) say which ones: Common Test's "%%% SUITE ==> case: FAILED"
# (and cases skipped because an init failed), EUnit's numbered failures, and
# pytest's "FAILED file::test" and Maven's "[ERROR]   Class.method" lines.
failed_cases() {
  local log
  for log in "$REPORT/ct.log" "$REPORT/eunit.log" "$REPORT"/clients-*.log; do
    [ -f "$log" ] || continue
    sed -E 's/\x1b\[[0-9;]*m//g' "$log" | grep -E \
      -e '^%%% .* ==> .*: (FAILED|auto_skipped)' -e '^%%% [^ ]+ ==> [^ ]' \
      -e '^  [0-9]+\) [a-z_0-9]+:' \
      -e '^(FAILED|ERROR) [^ ]+::' \
      -e '^\[ERROR\]   [A-Z][A-Za-z0-9_]*\.[a-z]' \
      -e '^clients/.*: .* failed' \
      | cut -c1-240 | sed -E "s|^|   $(basename "$log" .log): |" | head -20
  done
}

# The summary and the last line; the exit status.
summarize() {
  echo
  echo "== summary (${SECONDS} s in all)"
  for line in "${summary[@]}"; do echo "   $line"; done
  if [ "$failed" -ne 0 ]; then
    echo "   failed cases:"
    failed_cases
  fi
  echo "$passed passed, $failed failed"
  [ "$failed" -eq 0 ]; exit $?
}

# The release (evatar_test_release), built once here for every root suite
# that drives it (dist, release_commands, disk_full, node_config) and named
# in EVATAR_REL; a suite run alone builds it itself, and so does a suite
# that finds no EVATAR_REL because the build here failed (it then fails
# saying why: the failure is not counted here). A given EVATAR_REL is used
# as it is. The tarball has one suite (three_machines, as root only), which
# builds it when it runs.
build_once() {
  local name=$1 var=$2 path=$3; shift 3
  if [ -n "${!var:-}" ]; then
    note "$name: $var=${!var} (given)"
  elif step "$name" "$@" && [ -e "$path" ]; then
    export "$var=$PWD/$path"
  else
    note "$name: not built (see $REPORT/$name.log); the suites build it themselves"
  fi
}

check xref rebar3 xref

if [ "$tier" = check ]; then
  # The quick tier runs every PropEr property a quarter as many times
  # (evatar_test_proper:numtests/1); `make test' runs the full counts.
  export EVATAR_PROPER_FACTOR=${EVATAR_PROPER_FACTOR:-0.25}
  note "PropEr counts scaled by EVATAR_PROPER_FACTOR=$EVATAR_PROPER_FACTOR"
  # Dialyzer (the default profile, which xref compiled) beside EUnit (the
  # test profile): neither writes what the other reads.
  t0=$SECONDS
  rebar3 dialyzer > "$REPORT/dialyzer.log" 2>&1 < /dev/null &
  pid_dialyzer=$!
  step eunit rebar3 eunit; count_cases eunit $?
  rc=0; wait "$pid_dialyzer" || rc=$?
  echo
  echo "== dialyzer (beside eunit): rebar3 dialyzer"
  cat "$REPORT/dialyzer.log"
  echo "== dialyzer took $((SECONDS - t0)) s or less"
  if [ "$rc" -eq 0 ]; then
    passed=$((passed + 1)); note "dialyzer: passed"
  else
    failed=$((failed + 1)); note "dialyzer: FAILED (see $REPORT/dialyzer.log)"
  fi
  # The apps' suites that run on one node: not root test/ (the multi-node
  # and release suites) and not an app's suite that starts a cluster of
  # its own (evatar_test_cluster:start).
  # They run in two halves, each its own `rebar3 ct' beside the other: these
  # suites wait on sockets, browsers and brokers more than they compute, so
  # two at once on two cores take little more than the longer half. The
  # halves are split by app, about even by their cases' time (about 130 s
  # and 115 s on an idle machine): evatar_demo, evatar_web and mqtt_avatar
  # in one, the rest in the other. The
  # suites are compiled first, once, so that the two never compile into one
  # directory at once; each half logs under its own logdir.
  one_node=$(grep -L 'evatar_test_cluster:start' apps/*/test/*_SUITE.erl)
  half_b=$(echo "$one_node" | grep -E '^apps/(evatar_demo|evatar_web|mqtt_avatar)/' | paste -sd, -)
  half_a=$(echo "$one_node" | grep -vE '^apps/(evatar_demo|evatar_web|mqtt_avatar)/' | paste -sd, -)
  if step ct-compile rebar3 ct --compile_only; then
    t0=$SECONDS
    echo
    echo "== ct-a and ct-b, beside each other: rebar3 ct --suite ... --logdir _build/test/logs/check-{a,b}"
    mkdir -p _build/test/logs/check-a _build/test/logs/check-b
    rebar3 ct --suite "$half_a" --logdir _build/test/logs/check-a > "$REPORT/ct-a.log" 2>&1 < /dev/null &
    pid_a=$!
    rebar3 ct --suite "$half_b" --logdir _build/test/logs/check-b > "$REPORT/ct-b.log" 2>&1 < /dev/null &
    pid_b=$!
    rc_a=0; wait "$pid_a" || rc_a=$?
    rc_b=0; wait "$pid_b" || rc_b=$?
    cat "$REPORT/ct-a.log" "$REPORT/ct-b.log" > "$REPORT/ct.log"
    cat "$REPORT/ct.log"
    echo "== ct-a and ct-b took $((SECONDS - t0)) s"
    count_cases ct-a $rc_a
    count_cases ct-b $rc_b
  else
    failed=$((failed + 1)); note "ct-compile: FAILED (see $REPORT/ct-compile.log)"
  fi
  summarize
fi

# The release first: it compiles the default profile, which the client
# suites' nodes start from.
build_once release EVATAR_REL _build/default/rel/evatar rebar3 release

check dialyzer rebar3 dialyzer

step eunit rebar3 eunit --cover; count_cases eunit $?

if ls clients/*/run-tests.sh >/dev/null 2>&1; then
  rm -f "$REPORT"/clients-*.status
  if step compile rebar3 compile; then
    clients_run
    clients_count
  else
    failed=$((failed + 1)); note "compile for the client suites: FAILED (see $REPORT/compile.log)"
  fi
fi

step ct rebar3 ct --cover; count_cases ct $?

if step cover rebar3 cover --verbose; then
  note "cover: report in _build/test/cover/index.html"
else
  note "cover: could not build the report (see $REPORT/cover.log)"
fi

summarize

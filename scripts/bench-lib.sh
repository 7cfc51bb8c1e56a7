# Shared by the scripts/bench-*.sh scripts (sourced, not run): the source
# root, REBAR (default rebar3), BASE (REBAR_BASE_DIR, default _build), the
# bench profile's build (every app, the test kit and bench/), and
# run_bench, which runs one benchmark module's main/1 and exits 1, with the
# error on standard error, when it fails.
cd "$(dirname "${BASH_SOURCE[0]}")/.."
REBAR=${REBAR:-rebar3}
BASE=${REBAR_BASE_DIR:-_build}
# The HTTP server's libraries (cowboy, ranch, cowlib), which
# scripts/ensure-deps.sh copies into _deps/.
export ERL_LIBS="$PWD/_deps${ERL_LIBS:+:$ERL_LIBS}"

bench_compile() {
  "$REBAR" as bench compile
}

# run_bench MODULE ARGS [ERL_FLAG...]: erl with the flags, the bench
# profile's code, and MODULE:main(ARGS).
run_bench() {
  local mod=$1 args=$2
  shift 2
  erl "$@" -noshell -pa "$BASE"/bench/lib/*/ebin -pa "$BASE"/bench/extras/bench \
    -eval "try $mod:main($args) of
             ok -> halt(0)
           catch C:R:S ->
             io:format(standard_error, \"$mod failed: ~p:~p~n~p~n\", [C, R, S]),
             halt(1)
           end."
}

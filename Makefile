# EVATAR: the two commands a person needs are `make demo` and `make test`.
# Both install missing prerequisites first (Debian packages; sudo when not root).
.PHONY: all deps compile demo test check bench bench-bil release tar shell clean

REBAR ?= rebar3
BENCH_PA = -pa _build/bench/lib/*/ebin -pa _build/bench/extras/bench

all: compile

deps:
	@bash scripts/ensure-deps.sh

compile: deps
	$(REBAR) compile

## Runs the demonstration on one embedded node, then exits.
demo: compile
	@bash scripts/demo.sh $(DEMO_ARGS)

## Runs every check: xref, dialyzer, EUnit, Common Test with PropEr, cover.
## The last line is `N passed, N failed`.
test: deps
	@bash scripts/test.sh

check: test

## BIL codec and binding benchmarks (figures printed side by side with xmerl).
bench-bil: deps
	$(REBAR) as bench compile
	erl -noshell $(BENCH_PA) -eval 'bil_bench:main(), halt().'

bench: bench-bil

release: deps
	$(REBAR) release

tar: deps
	$(REBAR) as prod tar

shell: compile
	$(REBAR) shell

clean:
	rm -rf _build

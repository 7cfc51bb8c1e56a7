# EVATAR: the two commands a person needs are `make demo` and `make test`.
# Both install missing prerequisites first (Debian packages; sudo when not root).
.PHONY: all deps compile demo test test-upgrade test-ha soak check bench bench-bil bench-evatar bench-brokers bench-failover bench-promises bench-storm bench-flood bench-scale bench-partition bench-complexity bench-mqtt bench-json release tar shell clean vectors

REBAR ?= rebar3
# The HTTP server's libraries (cowboy, ranch, cowlib), copied into _deps/
# by scripts/ensure-deps.sh, for every erl started here (rebar3 finds them
# through rebar.config.script).
export ERL_LIBS := $(CURDIR)/_deps$(if $(ERL_LIBS),:$(ERL_LIBS))
BENCH_PA = -pa _build/bench/lib/*/ebin -pa _build/bench/extras/bench

all: compile

deps:
	@bash scripts/ensure-deps.sh

compile: deps
	$(REBAR) compile

## Runs the demonstration on one embedded node, then exits; prints the address of
## its dashboard first. DEMO_ARGS=--keep leaves the node and the page up.
demo: compile
	@bash scripts/demo.sh $(DEMO_ARGS)

## Runs everything: xref, dialyzer, EUnit, the client suites in other languages
## (clients/*), and every Common Test suite (apps/*/test and the multi-node and
## release suites of test/; the PropEr properties run inside them), with cover.
## The last line is `N passed, N failed`. `.ci/run` runs this.
test: deps
	@bash scripts/test.sh

## The quick tier, for every change: xref, dialyzer, EUnit and the Common Test
## suites of apps/*/test that run on one node (all but those starting a cluster;
## the pure properties among them, each at a quarter of its count:
## EVATAR_PROPER_FACTOR=1 for the full one), without cover. Not the multi-node and
## release suites of test/, nor the client suites. The same last line.
check: deps
	@bash scripts/test.sh check

## Only the multi-node high-availability suites (real OS-process nodes, kill -9,
## SIGSTOP, partitions through proxies, a nemesis of 16 faults); `make test` runs them too.
test-ha: deps
	$(REBAR) ct --dir test

## Randomized faults while traffic flows, for EVATAR_SOAK_SECONDS (default 600).
soak: deps
	EVATAR_SOAK_SECONDS=$${EVATAR_SOAK_SECONDS:-600} $(REBAR) ct --suite test/nemesis_SUITE --group nemesis

## Rolling upgrade from the previous release and replacing a dead machine,
## on real release nodes (docs/ha.md section 8; about 3 minutes).
test-upgrade: deps
	@bash scripts/test-upgrade.sh

## BIL codec and binding benchmarks (figures printed side by side with xmerl).
bench-bil: deps
	$(REBAR) as bench compile
	erl -noshell $(BENCH_PA) -eval 'bil_bench:main(), halt().'

## The mediator: N pairings over loopback TCP, round trips/s, latency, memory.
bench-evatar: deps
	@bash scripts/bench-evatar.sh $(BENCH_ARGS)

## EVATAR against mosquitto and RabbitMQ's MQTT plugin, side by side
## (installs the brokers if missing). BENCH_ARGS=quick for a smoke run.
bench-brokers: deps
	@bash scripts/bench-brokers.sh $(BENCH_ARGS)

## Failover times (kill -9, silent stall: p50/p99 over 50 trials) and TLS distribution's cost.
bench-failover: deps
	@bash scripts/bench-failover.sh $(BENCH_ARGS)

bench-promises: deps
	@bash scripts/bench-promises.sh $(BENCH_ARGS)

## Failover storm: kill -9 of the node holding N actives with traffic (3 nodes);
## per pairing the time until its new active serves a round trip, the time until
## every standby is synced again, lost and duplicated signals. BENCH_ARGS='[quick]'.
bench-storm: deps
	@bash scripts/bench-storm.sh $(BENCH_ARGS)

## Isolation on one node: 1,000 pairings in an open loop, rounds without and with
## a flooded pairing (a VA that never reads; an Avatar that never answers), the
## others' p50/p99/p99.9 side by side and the flood's cost. BENCH_ARGS='[quick]'.
bench-flood: deps
	@bash scripts/bench-flood.sh $(BENCH_ARGS)

## How far one cluster goes, in simulation (docs/scale.md): the pure HA core's takeover
## storm and the placement planner at 50 nodes and 1,000,000 pairings, with this
## machine's cost of a distribution message. BENCH_ARGS='[quick]' for a smoke run.
bench-scale: deps
	$(REBAR) as bench compile
	erl -noshell $(BENCH_PA) -eval 'scale_sim:main($(or $(BENCH_ARGS),[])), halt().'

## Partitions of a real network (each node in a network namespace; root): the longest
## unserved time of a majority-side pairing per kind of partition, this build beside the
## build before the stale-promise fix. BENCH_ARGS='[quick]' for a smoke run.
bench-partition: deps
	@bash scripts/bench-partition.sh $(BENCH_ARGS)

## Growth of a pairing's large operations (voiding, binding, re-binding, resuming) at
## three sizes, with the old algorithms, and other pairings' round trips meanwhile.
## BENCH_ARGS='[quick]' for a smoke run (sizes 10 times smaller).
bench-complexity: deps
	$(REBAR) as bench compile
	erl -noshell $(BENCH_PA) -eval 'complexity_bench:main($(or $(BENCH_ARGS),[])), halt().'

## An MQTT Avatar's description for a zigbee2mqtt home of 300, 3,000 and 30,000 devices:
## ms per device, with the old generator. BENCH_ARGS='[quick]' for sizes 10 times smaller.
bench-mqtt: deps
	$(REBAR) as bench compile
	erl -noshell $(BENCH_PA) -eval 'mqtt_gen_bench:main($(or $(BENCH_ARGS),[])), halt().'

## CPU ms of the device side's JSON (evatar_json, Debian's jiffy): state payloads,
## commands, a device list.
bench-json: deps
	$(REBAR) as bench compile
	erl -noshell $(BENCH_PA) -eval 'json_bench:main($(or $(BENCH_ARGS),[])), halt().'

bench: bench-bil bench-evatar

## Regenerates the shared protocol test vectors (test/vectors/README.md).
## Only after a deliberate protocol change: tests check the committed files.
vectors: compile
	escript test/vectors/generate.escript

release: deps
	$(REBAR) release

tar: deps
	$(REBAR) as prod tar

shell: compile
	$(REBAR) shell

clean:
	rm -rf _build

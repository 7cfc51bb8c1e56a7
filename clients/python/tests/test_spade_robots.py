"""The LEGO robots' coordination with SPADE agents
(examples/robots_spade): a coordinator in a Python process of its own and
two robot VAs embodied through EVATAR in robot1 and robot2 of
``scripts/sim-node.sh start robots``, talking in FIPA-ACL messages over
SPADE's embedded XMPP server (conftest's ``xmpp``). Judged as
evatar_demo_lego_scenario_SUITE judges the Erlang agents: by the arena's
truth (every ball in its colour's zone, none held) and the lexicon all
three hold; and by what the agents' XMPP clients received: every message
a behaviour handled came through the server (the coordinator is in
another process, so SPADE's container cannot carry them)."""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
from pathlib import Path
from typing import Dict, Iterator

import pytest

pytest.importorskip("spade")

from conftest import REPO, XmppServer, run  # noqa: E402
from test_sim_node import start  # noqa: E402

sys.path.insert(0, str(REPO / "clients" / "python" / "examples" / "robots_spade"))
import robots_spade  # noqa: E402

#: A hang guard: the story takes some 20 s of real time at speed 40.
GUARD = 120


@pytest.fixture(scope="module")
def story(tmp_path_factory: pytest.TempPathFactory, xmpp: XmppServer) -> Iterator[Dict[str, object]]:
    node, _control = start(tmp_path_factory.mktemp("robots-spade"), "robots", "--speed", "40")
    coordinator = subprocess.Popen([sys.executable, robots_spade.__file__, "coordinator",
                                    str(xmpp.port)], stdin=subprocess.DEVNULL,
                                   stdout=subprocess.PIPE, text=True)
    assert coordinator.stdout is not None

    async def main() -> Dict[str, object]:
        loop = asyncio.get_running_loop()
        line = await loop.run_in_executor(None, coordinator.stdout.readline)
        assert line.strip() == "COORDINATOR_READY", line
        robots = await asyncio.wait_for(robots_spade.start_robots(node.port, xmpp.port, "va-sim"),
                                        GUARD)
        try:
            await asyncio.wait_for(asyncio.gather(*(r.finished for r in robots)), GUARD)
        finally:
            for r in robots:
                await r.stop()
        done = await loop.run_in_executor(None, coordinator.stdout.readline)
        assert done.startswith("DONE "), done
        return {"coordinator": json.loads(done[len("DONE "):]),
                "robots": {str(r.jid.bare): {"lexicon": r.lexicon, "anchors": r.anchors.describe(),
                                             "handled": dict(r.handled),
                                             "xmpp": dict(r.__dict__.get("xmpp_received", {}))}
                           for r in robots}}
    try:
        result = run(main())
        result["arena"] = node.ask("outcome")
        yield result
    finally:
        if coordinator.poll() is None:
            coordinator.kill()
        coordinator.wait()
        node.stop()


def test_every_ball_at_its_target(story) -> None:  # type: ignore[no-untyped-def]
    """The arena's truth: every ball lies in its colour's zone, no robot
    holds one, and the coordinator gave up on none."""
    balls = [l.split() for l in story["arena"] if l.startswith("BALL ")]
    assert sorted((b[1], b[4], b[5]) for b in balls) == sorted(
        (c, z, "none") for c, z in robots_spade.TARGETS.items()), story["arena"]
    assert story["coordinator"]["given_up"] == []
    assert sorted(story["coordinator"]["placed"]) == ["blue-ball", "green-ball", "red-ball"]


def test_lexicon_agreed_by_all_three(story) -> None:  # type: ignore[no-untyped-def]
    """The coordinator and both robot VAs hold the same lexicon, a word
    for each ball; every anchor a robot made is named in it by its colour."""
    lexicon = story["coordinator"]["lexicon"]
    assert [e["word"] for e in lexicon] == ["blue-ball", "green-ball", "red-ball"]
    for jid, robot in story["robots"].items():
        assert robot["lexicon"] == lexicon, jid
        for a in robot["anchors"]:
            words = [e["word"] for e in lexicon if e["names"].get(jid) == a["symbol"]]
            assert words == ["%s-ball" % a["colour"]], (jid, a, lexicon)


def test_the_agents_talked_over_xmpp(story) -> None:  # type: ignore[no-untyped-def]
    """Every ACL message the agents' behaviours handled reached them
    through their XMPP clients, and the conversation was all there: two
    ready, two explore orders a round agreed and answered, the lexicon told
    and adopted twice, each pick-and-place order agreed and done."""
    c = story["coordinator"]
    assert c["xmpp_received"] == c["handled"], c
    failed = c["handled"].get("failure", 0)
    assert c["orders"] == 3 + failed, c
    assert c["handled"]["agree"] == 2 * c["rounds"] + c["orders"], c
    assert c["handled"]["inform"] == 2 + 2 * c["rounds"] + 2 + 3, c
    got: Dict[str, int] = {}
    for jid, robot in story["robots"].items():
        assert robot["xmpp"] == robot["handled"], (jid, robot)
        for k, v in robot["handled"].items():
            got[k] = got.get(k, 0) + v
    # request: explore per round per robot, and the orders; inform: lexicon and done, each twice.
    assert got == {"request": 2 * c["rounds"] + c["orders"], "inform": 4}, got

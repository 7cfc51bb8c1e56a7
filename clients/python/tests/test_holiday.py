"""The AgentSpeak holiday VA (examples/holiday) against avatar_sim's
simulated home joined to a real node (scripts/test-node-ctl.sh --home):
the same outcome as the Erlang reference VA, checked as
evatar_demo_home_SUITE checks it (evening_light_schedule,
intrusion_email_with_photos, and the sounds of intrusion_narrated)."""

from __future__ import annotations

import asyncio
import os
import sys
from pathlib import Path
from typing import Awaitable, Callable, Dict, List, Optional, Sequence, Tuple

import pytest

from conftest import REPO, Node, run

pytest.importorskip("agentspeak")

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples" / "holiday"))
import holiday_va  # noqa: E402

BODY = str(REPO / "apps" / "bil" / "priv" / "examples" / "smart_home_va.xml")
SPEED = 1000


def complete(lines: List[str]) -> bool:
    """The evening's outcome is all there: six light changes, the e-mail,
    the alarm and the spoken message."""
    loud = [l for l in lines if l.startswith("PLAYED ") and l.split("\t")[1] != "0"]
    return (len([l for l in lines if l.startswith("LIGHT ")]) >= 6
            and any(l.startswith("EMAIL ") for l in lines) and len(loud) >= 2)


#: Starts a holiday VA bound to the node's port; returns its log (a list the
#: agent appends to) and a coroutine function that stops it.
Embody = Callable[[Node], Awaitable[Tuple[List[str], Callable[[], Awaitable[None]]]]]


async def agentspeak_va(node: Node) -> Tuple[List[str], Callable[[], Awaitable[None]]]:
    va = await holiday_va.embody("127.0.0.1", node.port, "home", "home-va-secret", BODY)
    stop = asyncio.Event()
    runner = asyncio.ensure_future(va.run(stop))
    await va.client.wait_binding(lambda b: holiday_va.all_bound(va), timeout=30)

    async def stopped() -> None:
        stop.set()
        await runner
        await va.client.close()
    return va.log, stopped


def evening(spool: Path, until: str = "22:05", start: Optional[str] = None,
            done: Optional[Callable[[List[str]], bool]] = None,
            embody: Embody = agentspeak_va, node_args: Sequence[str] = (),
            fault: Optional[Tuple[str, Callable[[Node], Awaitable[None]]]] = None,
            after: Optional[Callable[[Node], Awaitable[None]]] = None) -> Dict[str, object]:
    """Runs the house and the VA ``embody`` starts (by default the
    AgentSpeak one) from 17:55 (or ``start``) until ``until`` on the
    simulated clock; returns the house's outcome lines and the agent's log.
    With ``done``, the outcome is read again until done says it is all
    there (at most 30 s): the agent acts in real time on a clock a thousand
    times faster, so on a loaded machine it may act on the last reading
    after the clock has stopped. With ``fault`` = (HH:MM, f), the clock
    stops at HH:MM for ``await f(node)``, then goes on; ``await
    after(node)`` runs once the VA has stopped, before the node does."""
    extra = ["--home-start", start] if start else []
    node = Node("test-node-ctl.sh", ["home:home-va-secret:home-gateway-secret",
                                     "--home", "home:home-gateway-secret:%s" % spool]
                + extra + list(node_args))

    async def main() -> Tuple[List[str], List[str]]:
        loop = asyncio.get_running_loop()
        log, stop = await embody(node)
        await loop.run_in_executor(None, node.ask, "speed %d" % SPEED)
        if fault is not None:
            await loop.run_in_executor(None, node.ask, "run_until " + fault[0])
            await fault[1](node)
        await loop.run_in_executor(None, node.ask, "run_until " + until)
        await asyncio.sleep(0.2)  # the last answers reach the house
        lines = await loop.run_in_executor(None, node.ask, "outcome")
        deadline = loop.time() + 30
        while done is not None and not done(lines) and loop.time() < deadline:
            await asyncio.sleep(0.2)
            lines = await loop.run_in_executor(None, node.ask, "outcome")
        await stop()
        if after is not None:
            await after(node)
        return lines, log

    try:
        lines, log = run(main())
    finally:
        node.stop()
    return {"lines": lines, "log": log, "spool": str(spool)}


@pytest.fixture(scope="module")
def outcome(tmp_path_factory: pytest.TempPathFactory) -> Dict[str, object]:
    return evening(tmp_path_factory.mktemp("holiday-spool"), done=complete)


def test_evening_light_schedule(outcome) -> None:  # type: ignore[no-untyped-def]
    got = [tuple(l.split(" ")[1:]) for l in outcome["lines"] if l.startswith("LIGHT ")]
    want = [("18:00", "living", "on"), ("19:10", "kitchen", "on"), ("19:40", "kitchen", "off"),
            ("20:30", "bedroom", "on"), ("20:30", "living", "off"), ("22:00", "bedroom", "off")]
    assert sorted((r, s) for _, r, s in got) == sorted((r, s) for _, r, s in want), got

    def next_time(at: str) -> str:
        later = [a for a, _, _ in want if a > at]
        return later[0] if later else "23:59"
    for at, room, state in want:
        [minute] = [m for m, r, s in got if r == room and s == state]
        assert at <= minute < next_time(at), (at, room, state, minute)


def test_intrusion_email_with_photos(outcome) -> None:  # type: ignore[no-untyped-def]
    lines = outcome["lines"]
    emails = [l[6:].split("\t") for l in lines if l.startswith("EMAIL ")]
    assert len(emails) == 1, emails
    file, subject, attached = emails[0]
    attached_ids = attached.split(",")
    assert subject == "INTRUSION" and len(attached_ids) == 3
    assert os.path.dirname(file) == outcome["spool"]
    eml = Path(file).read_bytes()
    assert b"Subject: INTRUSION" in eml
    assert eml.count(b"Content-Type: image/png") == 3
    photos = {i: (room, f) for i, room, f in
              (l[6:].split("\t") for l in lines if l.startswith("PHOTO "))}
    for pid in attached_ids:
        room, f = photos[pid]
        assert room == "hall"
        assert Path(f).read_bytes()[:4] == b"\x89PNG"


def test_alarm_then_warning(outcome) -> None:  # type: ignore[no-untyped-def]
    played = [l[7:].split("\t") for l in outcome["lines"] if l.startswith("PLAYED ")]
    loud = [(k, int(v), w) for k, v, w in played if int(v) > 0]
    assert len(loud) == 2, loud
    assert loud[0] == ("sound", 100, "alarm")
    assert loud[1][0] == "voice" and loud[1][2].startswith("You are being recorded.")


def test_the_agent_recognised_the_intruder(outcome) -> None:  # type: ignore[no-untyped-def]
    log = outcome["log"]
    expected = ["activity failed_authorisation in hall", "complex activity intruder in hall",
                "policy holiday on intruder do photos 3", "camera: photos ", "e-mail written to "]
    i = 0
    for line in log:
        if i < len(expected) and line.startswith(expected[i]):
            i += 1
    assert i == len(expected), log


def test_no_lights_in_daylight(tmp_path: Path) -> None:
    """In June the sun sets after 21:00 in London: the 18:00 rule, which asks
    for darkness, does nothing."""
    june = evening(tmp_path, until="18:10", start="2024-06-15T17:55")
    assert [l for l in june["lines"] if l.startswith("LIGHT ")] == []
    assert not [l for l in june["log"] if l.startswith("policy")]

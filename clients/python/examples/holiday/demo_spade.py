"""``make demo DEMO_ARGS=spade`` (scripts/demo-spade.sh): the holiday
evening of the plain ``make demo`` told with a SPADE agent as the house VA.

It starts SPADE's embedded XMPP server on loopback (xmpp_server.py), the
simulated home on a node of its own (scripts/sim-node.sh, clock paused),
and the spade-bdi agent of holiday_spade.asl embodied through EVATAR
(evatar.spade); once the agent's body is bound the clock runs from 17:55
to 22:05 a thousand times faster than real time. Each line the agent logs
starts with the house's time as the agent last perceived it; at the end
comes what the house did (lights, e-mail, photos, sounds).
"""

from __future__ import annotations

import asyncio
import datetime
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any, List

import holiday_spade
from evatar import Signal
from evatar.spade import EmbodiedBDIAgent

REPO = Path(__file__).resolve().parents[4]
SIM = str(REPO / "scripts" / "sim-node.sh")
BODY = str(REPO / "apps" / "bil" / "priv" / "examples" / "smart_home_va.xml")
CREDENTIAL = "holiday-spade-va"


def started(cmd: List[str], marker: str, **kw: Any) -> "tuple[subprocess.Popen[str], str]":
    """Starts ``cmd`` and returns it with the value of its ``marker=`` line."""
    p = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, **kw)
    assert p.stdout is not None
    for line in p.stdout:
        if line.startswith(marker + "="):
            return p, line.strip().split("=", 1)[1]
    raise SystemExit("%s did not start" % cmd[0])


class NarratedVA(EmbodiedBDIAgent):
    """Prints each line the agent logs with the house's time it last saw."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.seen = 0
        super().__init__(*args, **kwargs)
        agent = self

        class Log(list):  # type: ignore[type-arg]
            def append(self, text: Any) -> None:
                print("[%s] holiday-va  %s" % (agent.clock(), text), flush=True)
                super().append(text)
        self.log = Log()

    def clock(self) -> str:
        if not self.seen:
            return "--:--:--"
        return datetime.datetime.fromtimestamp(self.seen / 1000, datetime.timezone.utc) \
                       .strftime("%H:%M:%S")

    async def on_percept(self, event: Any) -> None:
        if isinstance(event, Signal) and event.timestamp:
            self.seen = max(self.seen, event.timestamp)
        await super().on_percept(event)


def sim(control: str, *words: str) -> List[str]:
    out = subprocess.run([SIM, "--dir", control] + list(words), check=True,
                         capture_output=True, text=True)
    return out.stdout.splitlines()


async def story(xmpp_port: int, evatar_port: int, control: str) -> None:
    agent = await holiday_spade.embody(xmpp_port, [("127.0.0.1", evatar_port)], "home",
                                       CREDENTIAL, BODY, cls=NarratedVA)
    await agent.body.wait_bound(timeout=30)
    print("[17:55:00] holiday-va  embodied: %d components bound; the clock starts"
          % len(agent.body.bound()), flush=True)
    loop = asyncio.get_running_loop()
    await loop.run_in_executor(None, sim, control, "speed", "1000")
    await loop.run_in_executor(None, sim, control, "run_until", "22:05")
    await asyncio.sleep(1)  # the agent's last answers reach the house (real time, the clock is paused)
    await agent.stop()
    lines = await loop.run_in_executor(None, sim, control, "outcome")
    print("\nWhat the house did\n------------------")
    for l in lines:
        kind, _, rest = l.partition(" ")
        if kind == "LIGHT":
            print("  light  " + rest)
        elif kind == "EMAIL":
            f, subject, photos = rest.split("\t")
            print("  e-mail %r to %s, photos %s" % (subject, f, photos))
        elif kind == "PHOTO":
            pid, room, f = rest.split("\t")
            print("  photo  %s of the %s: %s" % (pid, room, f))
        elif kind == "PLAYED" and rest.split("\t")[1] != "0":
            what, volume, text = rest.split("\t")
            print("  played %s %s (volume %s)" % (what, text, volume))


def main() -> None:
    print("The easy smart home on holiday, with a SPADE agent (paper, section 3.2)\n"
          "======================================================================\n"
          "The house VA is a spade-bdi agent (clients/python/examples/holiday/holiday_spade.asl),\n"
          "an XMPP client of SPADE's embedded server, embodied in the simulated smart home\n"
          "through EVATAR by evatar.spade. Nobody is home: the lights follow an evening\n"
          "schedule when it is dark, and at 21:40 somebody who does not know the code tries\n"
          "the door. Simulated time runs 1000 times faster than real time.\n", flush=True)
    here = Path(__file__).resolve().parent
    xmpp, port = started([sys.executable, str(here.parent / "spade" / "xmpp_server.py")],
                         "XMPP_PORT")
    control = tempfile.mkdtemp(prefix="evatar-spade-demo-")
    spool = os.path.abspath("spool")
    node, evatar = started([SIM, "--dir", control, "start", "home", "--port", "0", "--paused",
                            "--va-credential", CREDENTIAL, "--spool", spool, "--stop-on-eof"],
                           "EVATAR_PORT", cwd=str(REPO))
    try:
        asyncio.run(story(int(port), int(evatar), control))
    finally:
        for p in (node, xmpp):
            assert p.stdin is not None
            p.stdin.close()
            p.wait(20)


if __name__ == "__main__":
    main()

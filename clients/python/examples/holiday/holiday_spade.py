"""The holiday VA as a SPADE agent: a spade-bdi agent (holiday_spade.asl)
embodied through EVATAR (evatar.spade) with the body of the reference
house VA (smart_home_va.xml), on the XMPP server at 127.0.0.1:XMPP_PORT
(SPADE's embedded one: xmpp_server.py beside it, or ``spade run``).

    python holiday_spade.py XMPP_PORT EVATAR_HOST:PORT[,HOST:PORT...] PAIRING CREDENTIAL BODY.xml

starts the agent, prints READY once every emulator of its body is bound,
then runs until stdin closes and prints what the agent logged (LOG lines).
"""

from __future__ import annotations

import asyncio
import os
import sys
from typing import List, Sequence, Tuple, Type

from evatar.spade import Body, EmbodiedBDIAgent

HERE = os.path.dirname(os.path.abspath(__file__))
ASL = os.path.join(HERE, "holiday_spade.asl")


def endpoints(text: str) -> List[Tuple[str, int]]:
    out = []
    for e in text.split(","):
        host, _, port = e.rpartition(":")
        out.append((host, int(port)))
    return out


async def embody(xmpp_port: int, evatar: Sequence[Tuple[str, int]], pairing: str,
                 credential: str, body_file: str, entity_id: str = "house-va",
                 jid: str = "holiday@127.0.0.1", cls: Type[EmbodiedBDIAgent] = EmbodiedBDIAgent,
                 **options: object) -> EmbodiedBDIAgent:
    """Starts the agent (of class ``cls``); returns once its body has
    joined (not yet bound)."""
    agent = cls(jid, "holiday-xmpp", ASL, port=xmpp_port)
    agent.embody(Body(body_file, evatar, pairing=pairing, credential=credential,
                      entity_id=entity_id, **options))
    await agent.start()
    return agent


async def main(argv: List[str]) -> None:
    agent = await embody(int(argv[1]), endpoints(argv[2]), argv[3], argv[4], argv[5])
    await agent.body.wait_bound(timeout=30)
    print("READY", flush=True)
    await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)
    await agent.stop()
    for line in agent.log:
        print("LOG", line, flush=True)


if __name__ == "__main__":
    asyncio.run(main(sys.argv))

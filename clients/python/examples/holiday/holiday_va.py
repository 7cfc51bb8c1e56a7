"""The holiday VA: an AgentSpeak agent (holiday.asl) embodied through
EVATAR with the body of the reference house VA (smart_home_va.xml).

    python holiday_va.py HOST PORT PAIRING CREDENTIAL BODY.xml

connects, describes itself, runs the agent and prints READY once every
emulator of its body is bound (so a test can start the clock), then runs
until the session ends or stdin closes.
"""

from __future__ import annotations

import asyncio
import os
import sys
from typing import Optional

from evatar import Client, parse_frame
from evatar.bdi import AgentSpeakVA
from evatar.bil import Description

HERE = os.path.dirname(os.path.abspath(__file__))
ASL = os.path.join(HERE, "holiday.asl")


def body(path: str, entity_id: str) -> Description:
    with open(path, "rb") as f:
        d = parse_frame(f.read())
    assert isinstance(d, Description)
    d.entity_id = entity_id
    return d


async def embody(host: str, port: int, pairing: str, credential: str, body_file: str,
                 entity_id: str = "house-va") -> AgentSpeakVA:
    client = Client([(host, port)], pairing=pairing, role="agent", entity_id=entity_id,
                    credential=credential)
    await client.connect()
    va = AgentSpeakVA(client, body(body_file, entity_id), ASL)
    await va.start()
    return va


def all_bound(va: AgentSpeakVA) -> bool:
    b = va.client.binding
    if b is None:
        return False
    consumers = {r.consumer_component for r in b.bound if r.consumer_entity == va.client.entity_id}
    return all(c.id in consumers for c in va.description.components if c.consumes)


async def main(argv: list) -> None:
    host, port, pairing, credential, body_file = argv[1], int(argv[2]), argv[3], argv[4], argv[5]
    va = await embody(host, port, pairing, credential, body_file)
    stop = asyncio.Event()
    runner = asyncio.ensure_future(va.run(stop))
    await va.client.wait_binding(lambda b: all_bound(va), timeout=30)
    print("READY", flush=True)
    loop = asyncio.get_running_loop()
    await loop.run_in_executor(None, sys.stdin.read)
    stop.set()
    await runner
    for line in va.log:
        print("LOG", line)
    await va.client.close()


if __name__ == "__main__":
    asyncio.run(main(sys.argv))

"""A VA that EVATAR starts and supervises (agent_bridge's port connector):
it speaks the wire protocol on its stdin/stdout.

    agent_bridge:start_port(porch, #{command => "python3",
        args => ["port_agent.py", "PAIRING", "CREDENTIAL", "ENTITY_ID"]})

When the porch motion sensor reports motion it turns the porch light on,
then tells the light what the feedback said (a Request carrying
``Confirmed``). A reading with ``Exit=yes`` makes it exit (EVATAR starts it
again). When EVATAR closes its stdin the session ends and it exits.
With a fourth argument it writes its process id to that file.
"""

from __future__ import annotations

import asyncio
import os
import sys
from typing import Optional

from evatar import (STDIO, ActuatorEmulator, Client, ClosedError, Entry, SensorEmulator,
                    describe)


async def main(pairing: str, credential: str, entity_id: str,
               pid_file: Optional[str] = None) -> None:
    if pid_file:
        with open(pid_file, "w") as f:
            f.write(str(os.getpid()))
    client = Client([STDIO], pairing=pairing, role="agent", entity_id=entity_id,
                    credential=credential)
    light = ActuatorEmulator(client, "PorchLightEmulator",
                             [Entry("ACTUATOR", "TurnLightOn", {"Light": "yes"})])
    motion = SensorEmulator(client, "PorchMotionEmulator", "MotionDetected")
    await client.connect()
    await describe(client, [light, motion], "PORCH VA")
    print("porch VA joined", pairing, flush=True)  # goes to stderr, logged by EVATAR
    while True:
        try:
            reading = await motion.reading()
        except ClosedError as e:
            print("porch VA: session ended:", e.reason, flush=True)
            return
        if reading.param("Exit") == "yes":
            await client.close()
            return
        if reading.param("Motion") == "yes":
            fb = await light.act("TurnLightOn", {"Light": "yes", "N": reading.param("N") or ""})
            await client.send(sender=light.id, receiver=fb.sender, category="ACTUATOR",
                              type="TurnLightOn",
                              parameters={"Confirmed": fb.param("Done") or "?",
                                          "N": reading.param("N") or ""})


if __name__ == "__main__":
    asyncio.run(main(*sys.argv[1:5]))

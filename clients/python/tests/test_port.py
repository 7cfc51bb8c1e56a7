"""A Python VA started by a real node as a port program (frames on its
stdin/stdout, agent_bridge_port): it joins, works with an Avatar connected
over TCP, and is started again by EVATAR when it exits."""

from __future__ import annotations

import asyncio
import os
import sys
from pathlib import Path
from typing import Iterator, List

import pytest

from evatar import Actuator, Client, Entry, Sensor, Signal, describe

from conftest import Node, run

PROGRAM = str(Path(__file__).resolve().parents[1] / "examples" / "port_agent.py")


@pytest.fixture(scope="module")
def ctl() -> Iterator[Node]:
    n = Node("test-node-ctl.sh", ["porch:porch-va:porch-avatar"])
    yield n
    n.stop()



def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def test_port_program_is_an_agent(ctl: Node, tmp_path: Path) -> None:
    requests: List[Signal] = []

    async def main() -> None:
        confirmations: "asyncio.Queue[Signal]" = asyncio.Queue()

        def turn_on(req: Signal):  # type: ignore[no-untyped-def]
            if req.param("Confirmed") is not None:
                confirmations.put_nowait(req)
            else:
                requests.append(req)
            return {"Done": "yes"}

        loop = asyncio.get_running_loop()
        pid_file = tmp_path / "porch-va.pid"
        av = Client([("127.0.0.1", ctl.port)], pairing="porch", role="avatar",
                    entity_id="porch-house", credential="porch-avatar")
        lamp = Actuator(av, "PorchLight", [Entry("ACTUATOR", "TurnLightOn", {"Light": "yes"})],
                        turn_on)
        sensor = Sensor(av, "PorchMotion", "MotionDetected")
        await av.connect()
        await describe(av, [lamp, sensor])
        await loop.run_in_executor(None, ctl.ask,
                                   "port porch-va %s %s porch porch-va porch-va-1 %s"
                                   % (sys.executable, PROGRAM, pid_file))

        async def bound_to_port_va() -> None:
            await av.wait_binding(lambda b: "porch-va-1" in b.entities and any(
                r.consumer_component == "PorchMotion" for r in b.bound), timeout=20)

        for run_no in (1, 2):
            await bound_to_port_va()
            await sensor.emit({"Motion": "yes", "N": str(run_no)})
            confirm = await asyncio.wait_for(confirmations.get(), 10)
            assert confirm.param("Confirmed") == "yes" and confirm.param("N") == str(run_no)
            assert confirm.context == "Request" and confirm.sender == "PorchLightEmulator"
            assert requests[-1].param("N") == str(run_no)
            assert requests[-1].context == "RequestAwaitingFeedback"
            if run_no == 1:
                # The program exits; EVATAR unbinds it, then starts it again.
                await sensor.emit({"Exit": "yes"})
                await av.wait_binding(lambda b: "porch-va-1" not in b.entities, timeout=10)
        [runs] = await loop.run_in_executor(None, ctl.ask, "runs porch-va")
        assert runs == "RUNS 2"
        pid = int(pid_file.read_text())
        assert alive(pid)
        # Stopped by EVATAR: the program sees end-of-file on stdin and exits.
        await loop.run_in_executor(None, ctl.ask, "stop_port porch-va")
        await av.wait_binding(lambda b: "porch-va-1" not in b.entities, timeout=10)
        for _ in range(100):
            if not alive(pid):
                break
            await asyncio.sleep(0.05)
        assert not alive(pid)
        await av.close()
    run(main())

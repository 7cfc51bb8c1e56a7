"""SPADE agents embodied through EVATAR (evatar.spade), on SPADE's embedded
XMPP server (conftest's ``xmpp``, loopback): the holiday policy as a
spade-bdi agent (examples/holiday/holiday_spade.asl) against the simulated
home on a two-node cluster whose node 1 is killed under it, judged by the
house's outcome as test_holiday judges the python-agentspeak agent; a
wrong credential and an unbound action give the agent errors, never a
hang; docs/clients.md's SPADE agent runs; each emulator of a VA's
description is a spade-artifact artifact its agent focuses on and acts
through."""

from __future__ import annotations

import asyncio
import re
import subprocess
import sys
from pathlib import Path
from typing import Awaitable, Callable, Dict, List, Optional, Tuple

import pytest

pytest.importorskip("spade")
pytest.importorskip("spade_bdi")

from evatar import (Actuator, Binding, Client, Component, Description, Entry,  # noqa: E402
                    NotBoundError, RefusedError, Sensor, describe)
from evatar.spade import Body, EmbodiedAgent, EmbodiedBDIAgent  # noqa: E402

from conftest import REPO, Node, XmppServer, run  # noqa: E402
from test_holiday import (BODY, complete, evening, test_alarm_then_warning,  # noqa: E402,F401
                          test_evening_light_schedule, test_intrusion_email_with_photos,
                          test_the_agent_recognised_the_intruder)

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples" / "holiday"))
import holiday_spade  # noqa: E402

DOCS_AGENT = REPO / "clients" / "python" / "examples" / "spade" / "light_agent.py"


def endpoints(node: Node) -> List[Tuple[str, int]]:
    """Every node's endpoint (a cluster's EVATAR_PORTS), else the one."""
    ports = [l.split("=", 1)[1] for l in node.lines if l.startswith("EVATAR_PORTS=")]
    return [("127.0.0.1", int(p)) for p in (ports[0].split(",") if ports else [node.port])]


def spade_va(xmpp: XmppServer, agents: Optional[List[EmbodiedBDIAgent]] = None
             ) -> Callable[[Node], Awaitable[Tuple[List[str], Callable[[], Awaitable[None]]]]]:
    async def embody(node: Node) -> Tuple[List[str], Callable[[], Awaitable[None]]]:
        agent = await holiday_spade.embody(xmpp.port, endpoints(node), "home",
                                           "home-va-secret", BODY,
                                           handshake_timeout=1.0, reconnect_backoff=(0.02, 0.3))
        await agent.body.wait_bound(timeout=30)
        if agents is not None:
            agents.append(agent)
        return agent.log, agent.stop
    return embody


@pytest.fixture(scope="module")
def outcome(tmp_path_factory: pytest.TempPathFactory, xmpp: XmppServer) -> Dict[str, object]:
    """The evening on two nodes, the agent's body and the house knowing
    both. At 19:00 (the clock stopped) node 1 is killed: the body resumes
    its session on node 2 and the house joins it again; test_holiday's
    checks, imported above, then judge the evening as they judge one
    without the failure."""
    agents: List[EmbodiedBDIAgent] = []
    resumed: List[object] = []

    async def kill_node_1(node: Node) -> None:
        body = agents[0].body
        client = body.client
        assert client is not None
        want = {c.id for c in body.description.components if c.consumes}
        await asyncio.get_running_loop().run_in_executor(None, node.ask, "kill 1")
        await client.wait_binding(lambda b: client.epoch >= 2 and set(body.bound()) >= want,
                                  timeout=60)
        resumed.extend([client.epoch, client.endpoint == endpoints(node)[1],
                        client.session_id == session[0]])

    session: List[Optional[str]] = []

    def embody(node: Node) -> Awaitable[Tuple[List[str], Callable[[], Awaitable[None]]]]:
        async def started() -> Tuple[List[str], Callable[[], Awaitable[None]]]:
            r = await spade_va(xmpp, agents)(node)
            session.append(agents[0].body.client.session_id if agents[0].body.client else None)
            return r
        return started()

    docs_agent: List[object] = []

    async def run_docs_agent(node: Node) -> None:
        """docs/clients.md's SPADE agent, once the holiday VA has left the
        pairing, against node 2 (node 1 is dead)."""
        loop = asyncio.get_running_loop()
        port = endpoints(node)[1][1]
        out = await loop.run_in_executor(None, lambda: subprocess.run(
            [sys.executable, str(DOCS_AGENT), str(port), str(xmpp.port)],
            capture_output=True, text=True, timeout=60))
        lights = await loop.run_in_executor(None, node.ask, "outcome")
        docs_agent.extend([out, [l for l in lights if l.startswith("LIGHT ")][-1]])

    result = evening(tmp_path_factory.mktemp("spade-holiday-spool"), done=complete,
                     embody=embody, node_args=["--cluster", "2"], fault=("19:00", kill_node_1),
                     after=run_docs_agent)
    result["resumed"] = resumed
    result["docs_agent"] = docs_agent
    return result


def test_clients_md_spade_agent_runs(outcome) -> None:  # type: ignore[no-untyped-def]
    """docs/clients.md's SPADE agent is examples/spade/light_agent.py, and
    run after the evening it turns the living-room light on."""
    text = (REPO / "docs" / "clients.md").read_text()
    block = re.search(r"```python\n(.*?)```", text[text.index("### SPADE agents"):], re.S)
    assert block is not None and block.group(1) == DOCS_AGENT.read_text()
    out, last_light = outcome["docs_agent"]
    assert out.returncode == 0, out.stderr[-2000:]
    assert "the living-room light is on" in out.stdout, out.stdout
    assert last_light.split()[2:] == ["living", "on"], last_light


def test_the_body_resumed_on_node_2(outcome) -> None:  # type: ignore[no-untyped-def]
    """The failover was a resume: node 2, epoch 2 or later, the same session."""
    epoch, on_node_2, same_session = outcome["resumed"]
    assert epoch >= 2 and on_node_2 and same_session, outcome["resumed"]


LIGHT = Description(entity_id="spade-va", entity_type="Agent", components=[
    Component("LightEmulator01", [Entry("ACTUATOR", "ACTION FEEDBACK", {"Feedback": "yes"})],
              [Entry("ACTUATOR", "TurnLightOn", {"Light": "yes"})])])
#: A hang guard: none of these waits should come near it.
GUARD = 20


class Plain(EmbodiedAgent):
    """A plain SPADE agent: keeps its percepts."""

    async def setup(self) -> None:
        self.percepts: "asyncio.Queue[object]" = asyncio.Queue()

    async def on_percept(self, event: object) -> None:
        self.percepts.put_nowait(event)


def test_wrong_credential(xmpp: XmppServer, node: Node) -> None:
    """start() raises EVATAR's refusal and leaves the agent stopped."""
    async def main() -> None:
        agent = Plain("wrong@127.0.0.1", "xmpp-secret", port=xmpp.port)
        agent.embody(Body(LIGHT, [("127.0.0.1", node.port)], pairing="kitchen",
                          credential="not-the-secret"))
        with pytest.raises(RefusedError) as refused:
            await asyncio.wait_for(agent.start(), GUARD)
        assert refused.value.code in ("BadCredential", "Unauthorized", "AuthFailed"), refused.value
        assert not agent.is_alive()
        with pytest.raises(RefusedError):
            await asyncio.wait_for(agent.body.act("LightEmulator01", "TurnLightOn"), GUARD)
    run(main())


def test_unbound_action_plain(xmpp: XmppServer, node: Node) -> None:
    """Nothing provides the light: act raises NotBoundError at once; the
    Binding report that says so is a percept; stop() leaves the pairing."""
    async def main() -> None:
        agent = Plain("plain@127.0.0.1", "xmpp-secret", port=xmpp.port)
        body = agent.embody(Body(LIGHT, [("127.0.0.1", node.port)], pairing="kitchen",
                                 credential="va-secret"))
        await asyncio.wait_for(agent.start(), GUARD)
        report = await asyncio.wait_for(agent.percepts.get(), GUARD)
        assert isinstance(report, Binding)
        assert [u.reason for u in report.unbound_for("spade-va")] == ["NoProvider"]
        with pytest.raises(NotBoundError) as e:
            await asyncio.wait_for(body.act("LightEmulator01", "TurnLightOn"), GUARD)
        assert e.value.reason == "NoProvider"
        await agent.stop()
        assert body.client is not None and body.client.closed is not None
        assert body.client.closed.confirmed
    run(main())


UNBOUND_ASL = """
!go.
+!go <- .act("LightEmulator01", "TurnLightOn", [p("Light", "yes")], F); .log("feedback ", F).
+failed(C, S, R) <- .log("failed ", C, " ", S, " ", R).
+unbound(C, S, R) <- .log("unbound ", C, " ", S, " ", R).
"""


def test_unbound_action_bdi(xmpp: XmppServer, node: Node, tmp_path: Path) -> None:
    """A spade-bdi agent's .act with nothing bound fails: the plan stops
    and the agent perceives failed(Component, Service, "NotBound"); the
    Binding report is the belief unbound(Component, Service, Reason)."""
    asl = tmp_path / "unbound.asl"
    asl.write_text(UNBOUND_ASL)

    async def main() -> None:
        agent = EmbodiedBDIAgent("bdi@127.0.0.1", "xmpp-secret", str(asl), port=xmpp.port)
        agent.embody(Body(LIGHT, [("127.0.0.1", node.port)], pairing="kitchen",
                          credential="va-secret"))
        await asyncio.wait_for(agent.start(), GUARD)
        await asyncio.wait_for(agent.body.wait_bound([], timeout=GUARD), GUARD)
        loop = asyncio.get_running_loop()
        deadline = loop.time() + GUARD
        want = {"failed LightEmulator01 TurnLightOn NotBound",
                "unbound LightEmulator01 TurnLightOn NoProvider"}
        while not want <= set(agent.log) and loop.time() < deadline:
            await asyncio.sleep(0.05)  # polls the agent's log; the guard bounds it
        await agent.stop()
        assert want <= set(agent.log), agent.log
        assert not [l for l in agent.log if l.startswith("feedback")]
    run(main())


def test_bdi_agents_still_talk(xmpp: XmppServer, tmp_path: Path) -> None:
    """spade-bdi's .send reaches an EmbodiedBDIAgent whose reasoning
    cycle sleeps while idle: a message wakes it."""
    (tmp_path / "teller.asl").write_text('!go.\n+!go <- .send("listener@127.0.0.1", tell, hello(1)).\n')
    (tmp_path / "listener.asl").write_text('+hello(N)[source(S)] <- .log("hello ", N).\n')

    async def main() -> None:
        listener = EmbodiedBDIAgent("listener@127.0.0.1", "xmpp-secret",
                                    str(tmp_path / "listener.asl"), port=xmpp.port)
        await asyncio.wait_for(listener.start(), GUARD)
        teller = EmbodiedBDIAgent("teller@127.0.0.1", "xmpp-secret",
                                  str(tmp_path / "teller.asl"), port=xmpp.port)
        await asyncio.wait_for(teller.start(), GUARD)
        loop = asyncio.get_running_loop()
        deadline = loop.time() + GUARD
        while not listener.log and loop.time() < deadline:
            await asyncio.sleep(0.05)  # polls the agent's log; the guard bounds it
        await teller.stop()
        await listener.stop()
        assert listener.log == ["hello 1"]
    run(main())


LIGHT_AND_LUX = Description(entity_id="art-va", entity_type="Agent", components=[
    Component("LightEmulator01", [Entry("ACTUATOR", "ACTION FEEDBACK", {"Feedback": "yes"})],
              [Entry("ACTUATOR", "TurnLightOn", {"Light": "yes"})]),
    Component("LuxEmulator01", [Entry("SENSOR", "Luminosity", {"Room": "living"})])])


def test_emulators_as_artifacts(xmpp: XmppServer, node: Node) -> None:
    """Each emulator of the VA's description is an artifact (spade-artifact)
    the agent focuses on: once the house joins, each artifact publishes its
    emulator's binding, the luminosity emulator's artifact the house's
    reading; through the light emulator's artifact the agent turns the
    house's lamp on and gets its Feedback, and a service the emulator does
    not consume fails with NotConsumed."""
    pytest.importorskip("spade_artifact")
    from evatar.spade import ArtifactError, UsesEmulators, emulator_artifacts

    class VA(UsesEmulators, EmbodiedAgent):  # type: ignore[misc,valid-type]
        async def setup(self) -> None:
            self.emulator_percepts: "asyncio.Queue[Tuple[str, dict]]" = asyncio.Queue()

        def on_emulator_percept(self, artifact: str, percept: dict) -> None:
            self.emulator_percepts.put_nowait((artifact, percept))

    async def main() -> None:
        ep = ("127.0.0.1", node.port)
        house = Client([ep], pairing="artifacts", role="avatar", entity_id="art-house",
                       credential="art-avatar")
        asked: List[Optional[str]] = []

        def turn_on(request: object) -> Dict[str, str]:
            asked.append(request.param("Light"))  # type: ignore[attr-defined]
            return {"Light": "on"}
        lamp = Actuator(house, "LivingLamp", [Entry("ACTUATOR", "TurnLightOn", {"Light": "yes"})],
                        turn_on)
        lux = Sensor(house, "LivingLux", "Luminosity", {"Room": "living"})
        await house.connect()
        agent = VA("art-va@127.0.0.1", "xmpp-secret", port=xmpp.port)
        body = agent.embody(Body(LIGHT_AND_LUX, [ep], pairing="artifacts", credential="art-va"))
        await asyncio.wait_for(agent.start(), GUARD)
        light, lux_artifact = artifacts = emulator_artifacts(body, "127.0.0.1", "artifact-secret",
                                                             port=xmpp.port)
        assert [a.component for a in artifacts] == ["LightEmulator01", "LuxEmulator01"]
        names = [str(a.jid.bare) for a in artifacts]
        assert names == ["art-va.lightemulator01@127.0.0.1", "art-va.luxemulator01@127.0.0.1"]
        try:
            for a in artifacts:
                await asyncio.wait_for(a.start(), GUARD)
                await asyncio.wait_for(agent.focus(str(a.jid)), GUARD)

            async def perceived(artifact: str, kind: str) -> dict:
                while True:
                    got, p = await asyncio.wait_for(agent.emulator_percepts.get(), GUARD)
                    if got == artifact and p["percept"] == kind and p.get("bound", True):
                        return p

            await describe(house, [lamp, lux])
            for name, component in zip(names, ["LightEmulator01", "LuxEmulator01"]):
                p = await perceived(name, "binding")
                assert (p["component"], p["bound"], p["unbound"]) == (component, True, [])
            await house.wait_binding(lambda b: b.is_bound("LivingLux"), GUARD)
            await lux.emit({"Lux": "12", "Room": "living"})
            reading = await perceived(names[1], "reading")
            assert (reading["component"], reading["context"], reading["type"], reading["sender"],
                    reading["parameters"]) == ("LuxEmulator01", "SensorData", "Luminosity",
                                               "LivingLux", {"Lux": "12", "Room": "living"})
            assert lux_artifact.get("Luminosity") == reading
            feedback = await asyncio.wait_for(
                agent.use(names[0], "TurnLightOn", {"Light": "yes"}), GUARD)
            assert feedback == {"Light": "on"} and asked == ["yes"]
            with pytest.raises(ArtifactError) as refused:
                await asyncio.wait_for(agent.use(names[0], "OpenDoor"), GUARD)
            assert refused.value.code == "NotConsumed", refused.value
        finally:
            for a in artifacts:
                await a.stop()
            await agent.stop()
            await house.close()
        assert not any(a.is_alive() for a in artifacts)
    run(main())

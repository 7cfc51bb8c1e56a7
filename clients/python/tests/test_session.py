"""The SDK against a real EVATAR node (scripts/test-node.sh): joining as a
VA and as an Avatar, binding, requests and feedback, timeouts, sensor
streams, refusals, multiple endpoints and resume after a dropped
connection."""

from __future__ import annotations

import asyncio
import socket
from typing import List, Tuple

import pytest

from evatar import (Actuator, ActuatorEmulator, Binding, Client, Closed, ClosedError,
                    ConnectError, Entry, FeedbackTimeout, Reconnected, RefusedError, Sensor,
                    SensorEmulator, Signal, SignalError, SyncClient, describe)

from conftest import run


def light_va(ep, pairing: str, cred: str, entity: str = "va-1", **kw):  # type: ignore[no-untyped-def]
    va = Client([ep], pairing=pairing, role="agent", entity_id=entity, credential=cred, **kw)
    light = ActuatorEmulator(va, "LightEmulator01",
                             [Entry("ACTUATOR", "TurnLightOn", {"Light": "yes"})])
    return va, light


def light_avatar(ep, pairing: str, cred: str, action, entity: str = "7008", **kw):  # type: ignore[no-untyped-def]
    av = Client([ep], pairing=pairing, role="avatar", entity_id=entity, credential=cred, **kw)
    act = Actuator(av, "HomeLightActuator01",
                   [Entry("ACTUATOR", "TurnLightOn", {"Light": "yes"})], action)
    return av, act


def bound(b: Binding, consumer: str, provider: str) -> bool:
    return any(r.consumer_component == consumer and r.provider_component == provider
               for r in b.bound)


def test_join_as_va_and_avatar_and_binding(endpoint) -> None:  # type: ignore[no-untyped-def]
    async def main() -> None:
        va, light = light_va(endpoint, "kitchen", "va-secret")
        av, _ = light_avatar(endpoint, "kitchen", "avatar-secret", lambda s: {"Done": "yes"})
        w = await va.connect()
        assert (w.pairing, w.entity_id, len(w.session_id)) == ("kitchen", "va-1", 32)
        assert w.max_frame == 1048576 and not w.ha
        await av.connect()
        await describe(va, [light], "LIGHT VA", "EmulatorDescription")
        await describe(av, [_], "LIGHT ACTUATOR", "ActuatorDescription")
        for c in (va, av):
            b = await c.wait_binding(lambda b: bound(b, "LightEmulator01", "HomeLightActuator01"))
            assert sorted(b.entities) == ["7008", "va-1"]
            row = next(r for r in b.bound if r.consumer_component == "LightEmulator01")
            assert (row.provider_entity, row.category, row.type) == ("7008", "ACTUATOR",
                                                                      "TurnLightOn")
        # The Avatar's ACTION FEEDBACK is bound back to the VA's emulator.
        assert bound(va.binding, "HomeLightActuator01", "LightEmulator01")  # type: ignore[arg-type]
        # The report also came as an event.
        ev = await va.next_event(1)
        assert isinstance(ev, Binding)
        await va.close()
        await av.close()
    run(main())


def test_get_binding(endpoint) -> None:  # type: ignore[no-untyped-def]
    """GetBinding (docs/protocol.md section 2): the current report comes again as an event."""
    async def main() -> None:
        va, light = light_va(endpoint, "kitchen", "va-secret", entity="va-gb")
        await va.connect()
        await describe(va, [light], "LIGHT VA", "EmulatorDescription")
        first = await va.next_event(5)
        assert isinstance(first, Binding) and first.entities == ["va-gb"]
        await va.get_binding()
        again = await va.next_event(5)
        assert again == first
        await va.close()
    run(main())


def test_request_feedback_round_trip(endpoint) -> None:  # type: ignore[no-untyped-def]
    seen: List[Signal] = []

    def turn_on(req: Signal):  # type: ignore[no-untyped-def]
        seen.append(req)
        return {"Done": "yes", "Room": req.param("Room") or ""}

    async def main() -> None:
        va, light = light_va(endpoint, "lab", "lab-va")
        av, act = light_avatar(endpoint, "lab", "lab-avatar", turn_on)
        await va.connect()
        await av.connect()
        await describe(va, [light])
        await describe(av, [act])
        await va.wait_binding(lambda b: bound(b, "LightEmulator01", "HomeLightActuator01"))
        await av.wait_binding(lambda b: bound(b, "HomeLightActuator01", "LightEmulator01"))
        for room in ["kitchen", "hall", "x & <y>"]:
            fb = await light.act("TurnLightOn", {"Light": "yes", "Room": room}, timeout=5)
            assert fb.context == "Feedback"
            assert fb.sender == "HomeLightActuator01" and fb.receiver == "LightEmulator01"
            assert fb.param("Done") == "yes" and fb.param("Room") == room
            assert fb.in_reply_to == seen[-1].id
            assert seen[-1].context == "RequestAwaitingFeedback"
        assert act.handled == 3
        # A signal to a component that does not exist is refused with an
        # error signal, and the connection stays.
        await va.send(sender="LightEmulator01", receiver="NoSuchComponent",
                      category="ACTUATOR", type="TurnLightOn")
        err = await va.next_signal(5, lambda s: s.context == "Error")
        assert err.type == "UnknownReceiver" and err.sender == "EVATAR"
        # An error answering a request raises SignalError.
        with pytest.raises(SignalError) as e:
            await va.request(sender="NotMine", receiver="HomeLightActuator01",
                             category="ACTUATOR", type="TurnLightOn", timeout=5)
        assert e.value.code == "BadSender"
        fb = await light.act("TurnLightOn", {"Light": "yes"}, timeout=5)
        assert fb.param("Done") == "yes"
        await va.close()
        await av.close()
    run(main())


def test_actuator_emulator_passes_device_events(endpoint) -> None:  # type: ignore[no-untyped-def]
    """A device's availability events addressed to an ActuatorEmulator come
    back on next_event(); the answers to act() do not."""
    async def main() -> None:
        va, light = light_va(endpoint, "kitchen", "va-secret", entity="va-dev")
        av, act = light_avatar(endpoint, "kitchen", "avatar-secret", lambda s: {"Done": "yes"},
                               entity="7009")
        try:
            await va.connect()
            await av.connect()
            await describe(va, [light])
            await describe(av, [act])
            await va.wait_binding(lambda b: bound(b, "LightEmulator01", "HomeLightActuator01"))
            await av.wait_binding(lambda b: bound(b, "HomeLightActuator01", "LightEmulator01"))
            fb = await light.act("TurnLightOn", {"Light": "yes"}, timeout=10)
            assert fb.param("Done") == "yes"
            for type, extra in [("DeviceDisconnected", {"Availability": "offline"}),
                                ("DeviceReconnected", {"Availability": "online",
                                                       "OfflineSeconds": "2"})]:
                await av.send(sender="HomeLightActuator01", receiver="LightEmulator01",
                              context="Event", category="EVENT", type=type,
                              parameters={"Component": "HomeLightActuator01", **extra})
            got = [await va.next_signal(10) for _ in range(2)]
            assert [(s.context, s.type, s.receiver) for s in got] == [
                ("Event", "DeviceDisconnected", "LightEmulator01"),
                ("Event", "DeviceReconnected", "LightEmulator01")]
            assert got[1].param("OfflineSeconds") == "2"
            # act() still gets its own answer, which is no event.
            fb = await light.act("TurnLightOn", {"Light": "yes"}, timeout=10)
            assert fb.param("Done") == "yes"
        finally:
            await va.close()
            await av.close()
        rest = []
        while True:
            ev = await va.next_event(10)
            if isinstance(ev, Closed):
                break
            rest.append(ev)
        assert not [e for e in rest if isinstance(e, Signal)], rest
    run(main())


def test_closed_event_is_confirmed_and_last(endpoint) -> None:  # type: ignore[no-untyped-def]
    """After close(), the Closed event an event loop reads says
    confirmed=True (EVATAR's Bye came), and is the last: next_event() then
    raises ClosedError instead of returning Closed again."""
    async def main() -> None:
        va, light = light_va(endpoint, "kitchen", "va-secret", entity="va-closed")
        try:
            await va.connect()
            await describe(va, [light])
            await va.wait_binding()
        except BaseException:
            await va.close()
            raise
        seen: List[Tuple[object, bool]] = []

        async def event_loop() -> None:
            while True:
                ev = await va.next_event(30)
                seen.append((ev, getattr(ev, "confirmed", False)))
                if isinstance(ev, Closed):
                    return

        reader = asyncio.ensure_future(event_loop())
        await asyncio.sleep(0)
        await va.close()
        await asyncio.wait_for(reader, 30)
        closed, confirmed_when_read = seen[-1]
        assert isinstance(closed, Closed) and closed is va.closed
        assert closed.reason == "normal" and confirmed_when_read and closed.confirmed
        with pytest.raises(ClosedError):
            await va.next_event(5)
        with pytest.raises(ClosedError):
            await va.next_event()
        assert (await va.wait_closed()) is closed
    run(main())


def test_feedback_timeouts(endpoint) -> None:  # type: ignore[no-untyped-def]
    async def main() -> None:
        never = asyncio.Event()

        async def silent(req: Signal) -> None:
            await never.wait()  # never answers

        va, light = light_va(endpoint, "timeouts", "t-va")
        av, act = light_avatar(endpoint, "timeouts", "t-avatar", silent)
        await va.connect()
        await av.connect()
        await describe(va, [light])
        await describe(av, [act])
        await va.wait_binding(lambda b: bound(b, "LightEmulator01", "HomeLightActuator01"))
        # The client's own deadline.
        with pytest.raises(FeedbackTimeout):
            await light.act("TurnLightOn", {"Light": "yes"}, timeout=0.3)
        # EVATAR's: the pairing's feedback timeout (2 s, conftest's PAIRINGS) answers for the device.
        fb = await light.act("TurnLightOn", {"Light": "yes"}, timeout=10)
        assert fb.is_evatar_timeout and fb.param("Message")
        never.set()
        await va.close()
        await av.close()
    run(main())


def test_sensor_stream(endpoint) -> None:  # type: ignore[no-untyped-def]
    async def main() -> None:
        va = Client([endpoint], pairing="sensing", role="agent", entity_id="va-s",
                    credential="s-va")
        motion = SensorEmulator(va, "MotionEmulator01", "MotionDetected", {"Room": "hall"})
        av = Client([endpoint], pairing="sensing", role="avatar", entity_id="cam-1",
                    credential="s-avatar")
        sensor = Sensor(av, "HallMotionSensor", "MotionDetected", {"Room": "hall"})
        await va.connect()
        await av.connect()
        await describe(va, [motion])
        await describe(av, [sensor])
        await av.wait_binding(lambda b: bound(b, "HallMotionSensor", "MotionEmulator01"))
        for i in range(50):
            await sensor.emit({"Motion": "yes" if i % 2 else "no", "N": str(i)})
        got = [await motion.reading(5) for _ in range(50)]
        assert [s.param("N") for s in got] == [str(i) for i in range(50)]
        assert all(s.context == "SensorData" and s.sender == "HallMotionSensor" for s in got)
        assert motion.latest is got[-1]
        seqs = [s.sequence for s in got]
        assert all(isinstance(q, int) for q in seqs) and seqs == sorted(seqs)
        await va.close()
        await av.close()
    run(main())


def test_refusals(endpoint) -> None:  # type: ignore[no-untyped-def]
    async def main() -> None:
        with pytest.raises(RefusedError) as e:
            await Client([endpoint], pairing="kitchen", role="agent", entity_id="va-x",
                         credential="wrong").connect()
        assert e.value.code == "BadCredential"
        with pytest.raises(RefusedError) as e:
            await Client([endpoint], pairing="nowhere", role="agent", entity_id="va-x",
                         credential="x").connect()
        assert e.value.code == "UnknownPairing"
        va = Client([endpoint], pairing="kitchen", role="agent", entity_id="va-a",
                    credential="va-secret")
        await va.connect()
        with pytest.raises(RefusedError) as e:
            await Client([endpoint], pairing="kitchen", role="agent", entity_id="va-b",
                         credential="va-secret").connect()
        assert e.value.code == "Occupied"
        await va.close()
        with pytest.raises(ClosedError):
            await va.send(sender="a", receiver="b", category="c", type="d")
    run(main())


def free_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def test_endpoints_in_order(endpoint) -> None:  # type: ignore[no-untyped-def]
    async def main() -> None:
        dead = ("127.0.0.1", free_port())
        with pytest.raises(ConnectError) as e:
            await Client([dead], pairing="lab", role="agent", entity_id="va-1",
                         credential="lab-va", connect_timeout=1).connect()
        assert e.value.failures[0][0] == dead
        c = Client([dead, endpoint], pairing="lab", role="agent", entity_id="va-1",
                   credential="lab-va")
        await c.connect()
        assert c.endpoint == endpoint
        await c.close()
    run(main())


def test_resume_after_dropped_connection(endpoint) -> None:  # type: ignore[no-untyped-def]
    """Protocol version 2 on one node: the VA's connection is cut while the
    Avatar streams readings and the VA sends requests; the VA reconnects,
    resumes its session and gets every reading exactly once, in order, and
    every request it made is answered."""
    answered: List[str] = []

    def turn_on(req: Signal):  # type: ignore[no-untyped-def]
        answered.append(req.param("N") or "")
        return {"Done": "yes"}

    async def main() -> None:
        va = Client([endpoint], pairing="ha", role="agent", entity_id="va-ha",
                    credential="ha-va", ha=True, handshake_timeout=1)
        light = ActuatorEmulator(va, "LightEmulator01",
                                 [Entry("ACTUATOR", "TurnLightOn", {"Light": "yes"})])
        motion = SensorEmulator(va, "MotionEmulator01", "MotionDetected")
        av = Client([endpoint], pairing="ha", role="avatar", entity_id="house",
                    credential="ha-avatar", ha=True)
        act = Actuator(av, "HomeLightActuator01",
                       [Entry("ACTUATOR", "TurnLightOn", {"Light": "yes"})], turn_on)
        sensor = Sensor(av, "MotionSensor", "MotionDetected")
        w = await va.connect()
        assert w.ha and w.resumed is False and w.epoch is not None and w.epoch >= 1
        await av.connect()
        await describe(va, [light, motion])
        await describe(av, [act, sensor])
        await av.wait_binding(lambda b: bound(b, "MotionSensor", "MotionEmulator01"))
        await va.wait_binding(lambda b: bound(b, "LightEmulator01", "HomeLightActuator01"))
        session = va.session_id
        for i in range(10):
            await sensor.emit({"N": str(i)})
        first = [await motion.reading(5) for _ in range(10)]
        va.drop_connection()
        # While the VA is away (or coming back), readings go on.
        for i in range(10, 40):
            await sensor.emit({"N": str(i)})
        ev = await va.next_event(10)
        while not isinstance(ev, Reconnected):
            ev = await va.next_event(10)
        assert ev.resumed and ev.session_id == session and va.session_id == session
        rest = [await motion.reading(5) for _ in range(30)]
        got = [s.param("N") for s in first + rest]
        assert got == [str(i) for i in range(40)]
        with pytest.raises(asyncio.TimeoutError):
            await motion.reading(0.3)  # nothing twice
        # Requests sent around a second drop are answered once each.
        tasks = [asyncio.ensure_future(light.act("TurnLightOn", {"N": str(i)}, timeout=10))
                 for i in range(5)]
        await asyncio.sleep(0)
        va.drop_connection()
        fbs = await asyncio.gather(*tasks)
        assert all(f.param("Done") == "yes" for f in fbs)
        assert sorted(answered) == [str(i) for i in range(5)]
        await va.await_acks(5)
        assert va.unacked == 0 and va.reconnects == 2
        await va.close()
        await av.close()
    run(main())


def test_sync_wrapper(endpoint) -> None:  # type: ignore[no-untyped-def]
    with SyncClient([endpoint], pairing="sync", role="avatar", entity_id="dev",
                    credential="y-avatar") as av, \
         SyncClient([endpoint], pairing="sync", role="agent", entity_id="va",
                    credential="y-va") as va:
        from evatar import Component, Description
        av.describe(Description("dev", "Avatar", [Component(
            "Dev01", [Entry("ACTUATOR", "Beep", {"Sound": "yes"})],
            [Entry("ACTUATOR", "ACTION FEEDBACK", {"Feedback": "yes"})])]))
        va.describe(Description("va", "Agent", [Component(
            "BeepEmulator", [Entry("ACTUATOR", "ACTION FEEDBACK", {"Feedback": "yes"})],
            [Entry("ACTUATOR", "Beep", {"Sound": "yes"})])]))
        va.wait_binding(lambda b: bound(b, "BeepEmulator", "Dev01"))
        av.wait_binding(lambda b: bound(b, "Dev01", "BeepEmulator"))
        va.send(sender="BeepEmulator", receiver="Dev01", category="ACTUATOR", type="Beep",
                context="RequestAwaitingFeedback", parameters={"Sound": "yes"})
        req = av.next_signal(5)
        assert req.type == "Beep" and req.context == "RequestAwaitingFeedback"
        av.reply(req, parameters={"Done": "yes"})
        fb = va.next_signal(5)
        assert fb.in_reply_to == req.id and fb.param("Done") == "yes"

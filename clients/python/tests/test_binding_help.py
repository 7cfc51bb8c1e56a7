"""The Binding report's helpers (is_bound, bound_for, unbound_for) and what
NotBoundError tells, on reports built here: which rows count for a
component, which are the entity's own, and that the error names the
reason and where to look. (test_sim_node.py checks the same against the
simulated home.)"""

from __future__ import annotations

import asyncio

import pytest

from evatar import (ActuatorEmulator, Binding, Bound, Client, Closed, Entry, NotBoundError,
                    Reconnected, SensorEmulator, Signal, Unbound)

from conftest import run

REPORT = Binding(
    entities=["easy-home-01", "night-watch-va"],
    bound=[Bound("easy-home-01", "BedroomMotionSensor01", "night-watch-va", "MotionEmulator",
                 "SENSOR", "MotionDetected", 1, 1),
           Bound("night-watch-va", "LampEmulator", "easy-home-01", "BedroomSocketSwitch01",
                 "ACTUATOR", "SwitchSocketOn", 2, 1),
           Bound("night-watch-va", "HalfEmulator", "easy-home-01", "BedroomSocketSwitch01",
                 "ACTUATOR", "SwitchSocketOn", 2, 1)],
    unbound=[Unbound("easy-home-01", "BedroomSocketSwitch01", "ACTUATOR", "ACTION FEEDBACK",
                     "ParametersMismatch"),
             Unbound("easy-home-01", "TimeSensor01", "SENSOR", "Sunset", "NoProvider"),
             Unbound("night-watch-va", "HalfEmulator", "ACTUATOR", "SwitchSocketOff",
                     "ParametersMismatch"),
             Unbound("night-watch-va", "KitchenEmulator", "ACTUATOR", "TurnLightOn",
                     "NoProvider")])


def test_is_bound_counts_a_component_as_consumer_or_provider() -> None:
    assert REPORT.is_bound("LampEmulator")          # its one action is bound
    assert REPORT.is_bound("MotionEmulator")        # a sensor is bound to it
    # One action bound and one not: not bound as a whole, bound for that type.
    assert not REPORT.is_bound("HalfEmulator")
    assert REPORT.is_bound("HalfEmulator", "SwitchSocketOn")
    assert not REPORT.is_bound("HalfEmulator", "SwitchSocketOff")
    assert not REPORT.is_bound("KitchenEmulator")   # only unbound rows
    assert not REPORT.is_bound("NoSuchEmulator")    # in no row at all
    # The pairing's own unbound entries are not the VA's.
    assert "easy-home-01" in REPORT.entities and not REPORT.is_bound("KitchenEmulator")


def test_unbound_for_and_bound_for_keep_one_entity() -> None:
    mine = REPORT.unbound_for("night-watch-va")
    assert [(u.consumer_component, u.type) for u in mine] == [
        ("HalfEmulator", "SwitchSocketOff"), ("KitchenEmulator", "TurnLightOn")]
    assert [u.type for u in REPORT.unbound_for("night-watch-va", "KitchenEmulator")] == [
        "TurnLightOn"]
    assert len(REPORT.unbound_for("easy-home-01")) == 2
    assert len(REPORT.bound_for("night-watch-va")) == 3
    assert REPORT.bound_for("someone-else") == []


def test_not_bound_error_says_why_and_where_to_look() -> None:
    async def main() -> None:
        va = Client([("127.0.0.1", 1)], pairing="home", role="agent",
                    entity_id="night-watch-va", credential="x")
        half = ActuatorEmulator(va, "HalfEmulator",
                                [Entry("ACTUATOR", "SwitchSocketOn", {"Room": "bedroom"}),
                                 Entry("ACTUATOR", "SwitchSocketOff", {"Room": "attic"})])
        kitchen = ActuatorEmulator(va, "KitchenEmulator",
                                   [Entry("ACTUATOR", "TurnLightOn", {"Light": "yes"})])
        # No report yet: the error says so.
        with pytest.raises(NotBoundError) as e:
            await kitchen.act("TurnLightOn")
        assert e.value.reason is None and "no Binding report has arrived yet" in str(e.value)
        va.binding = REPORT
        with pytest.raises(NotBoundError) as e:
            await half.act("SwitchSocketOff")
        assert (e.value.component, e.value.service, e.value.reason) == (
            "HalfEmulator", "SwitchSocketOff", "ParametersMismatch")
        assert "not with the parameters" in str(e.value)
        assert "client.binding.unbound" in str(e.value)
        with pytest.raises(NotBoundError) as e:
            await kitchen.act("TurnLightOn")
        assert e.value.reason == "NoProvider" and "NoProvider" in str(e.value)
        assert half.provider_of("SwitchSocketOn") == "BedroomSocketSwitch01"
    run(main())


def test_sensor_emulator_category_and_top_level_exports() -> None:
    async def main() -> None:
        va = Client([("127.0.0.1", 1)], pairing="p", role="agent", entity_id="v", credential="x")
        touch = SensorEmulator(va, "TouchEmulator", "Touch", {"Pressed": "yes"})
        beh = SensorEmulator(va, "BehEmulator", "Finished", {"Behaviour": "Forward"},
                             category="BEHAVIOUR")
        assert [(e.category, e.type) for e in touch.component().services] == [("SENSOR", "Touch")]
        assert [(e.category, e.type) for e in beh.component().services] == [
            ("BEHAVIOUR", "Finished")]
        fwd = ActuatorEmulator(va, "ForwardEmulator",
                               [Entry("BEHAVIOUR", "Forward", {"Distance": "yes"})],
                               feedback={"Feedback": "yes", "Behaviour": "Forward"},
                               feedback_category="BEHAVIOUR")
        lamp = ActuatorEmulator(va, "LampEmulator", [Entry("ACTUATOR", "TurnLightOn")])
        assert [(e.category, e.type, e.param("Behaviour")) for e in fwd.component().services] == [
            ("BEHAVIOUR", "ACTION FEEDBACK", "Forward")]
        assert [(e.category, e.type, e.param("Feedback")) for e in lamp.component().services] == [
            ("ACTUATOR", "ACTION FEEDBACK", "yes")]
    run(main())
    # What next_event() returns is importable from the package itself.
    import evatar
    for cls in (Signal, Binding, Bound, Unbound, Reconnected, Closed):
        assert getattr(evatar, cls.__name__) is cls and cls.__name__ in evatar.__all__
    assert asyncio.iscoroutinefunction(Client.next_event)

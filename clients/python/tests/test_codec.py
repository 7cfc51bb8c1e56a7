"""The codec alone: what a client parses is refused when it could grow or
is not BIL, and what it writes parses back to the same thing."""

from __future__ import annotations

import pytest

from evatar import (Ack, Binding, Bound, Bye, Component, Description, Entry, Hello, Refused,
                    Resume, Signal, Unbound, Welcome, encode, encode_frame, parse_frame)
from evatar.frame import FrameDecoder, FrameError
from evatar.xml import BilError

SIGNAL = Signal(id="va-1-1", context="RequestAwaitingFeedback", sender="LightEmulator01",
                receiver="HomeLightActuator01", timestamp=1763800000000,
                body=Entry("ACTUATOR", "TurnLightOn", [("Light", "yes"), ("Note", "a & <b> \r\n é")]))


def refused(data: bytes) -> str:
    with pytest.raises(BilError) as e:
        parse_frame(data)
    return e.value.code


def test_doctype_and_entities_are_refused() -> None:
    laughs = (b'<?xml version="1.0"?><!DOCTYPE lolz [<!ENTITY lol "lol">'
              b'<!ENTITY lol2 "&lol;&lol;&lol;&lol;">]>'
              b'<bil:Bye xmlns:bil="urn:evatar:bil:1"><Reason>&lol2;</Reason></bil:Bye>')
    assert refused(laughs) == "doctype_refused"
    assert refused(b'<!-- c --><!DOCTYPE x SYSTEM "file:///etc/passwd"><x/>') == "doctype_refused"
    assert refused(b'<bil:Bye xmlns:bil="urn:evatar:bil:1"><Reason>&xxe;</Reason></bil:Bye>') \
        == "entity_refused"


def test_what_is_not_bil_is_refused() -> None:
    assert refused(b"GET / HTTP/1.1\r\n") == "malformed"
    assert refused(b'<bil:Bye xmlns:bil="urn:evatar:bil:1"><Reason>x</Reason>') == "truncated"
    assert refused(b"<Bye/>") == "wrong_namespace"
    assert refused(b'<bil:Nope xmlns:bil="urn:evatar:bil:1"/>') == "wrong_root"
    assert refused(b"\xff\xfe<x/>") == "bad_encoding"
    deep = b'<bil:Bye xmlns:bil="urn:evatar:bil:1">' + b"<a>" * 40 + b"</a>" * 40 + b"</bil:Bye>"
    assert refused(deep) == "too_deep"
    bad_ctx = SIGNAL.encode().replace(b"RequestAwaitingFeedback", b"Shout")
    assert refused(bad_ctx) == "bad_value"
    assert refused(SIGNAL.encode().replace(b"<Timestamp>", b"<Timestamp>x")) == "bad_value"


def test_round_trips() -> None:
    docs = [SIGNAL,
            Hello("p", "agent", "va-1", "", 1),
            Resume("p", "avatar", "7008", "s", 2, "AB" * 16, 41, 2),
            Welcome("p", "va-1", "AB" * 16, 5000, 1048576),
            Welcome("p", "va-1", "AB" * 16, 5000, 1048576, 2, True, "va-1-42", 1024, 500),
            Ack(accepted="va-1-42"), Ack(received=17), Ack(), Refused("BadCredential", "no"),
            Bye(), Bye("leaving"),
            Binding(["va-1", "7008"],
                    [Bound("va-1", "L", "7008", "H", "ACTUATOR", "TurnLightOn", 1, 1)],
                    [Unbound("7008", "H", "ACTUATOR", "ACTION FEEDBACK", "NoProvider")]),
            Description("7008", "Avatar", [Component("H", [Entry("ACTUATOR", "On", {"L": "yes"})],
                                                     [Entry("ACTUATOR", "ACTION FEEDBACK")])],
                        "LIGHT", "ctx")]
    for d in docs:
        assert parse_frame(encode(d)) == d


def test_bad_parameter_names_are_not_written() -> None:
    with pytest.raises(ValueError):
        Signal(id="x", context="Request", sender="a", receiver="b",
               body=Entry("c", "t", {"a b": "1"})).encode()


def test_frames() -> None:
    dec = FrameDecoder(65536)
    wire = encode_frame(b"<a/>") + encode_frame(b"<bb/>")
    assert dec.feed(wire[:3]) == []
    assert dec.feed(wire[3:9]) == [b"<a/>"]
    assert dec.feed(wire[9:]) == [b"<bb/>"]
    with pytest.raises(FrameError) as e:
        FrameDecoder(65536).feed(b"GET / HTTP/1.1")
    assert e.value.code == "FrameTooLarge"
    with pytest.raises(FrameError) as e:
        FrameDecoder().feed(b"\0\0\0\0")
    assert e.value.code == "Malformed"


def test_sensor_emulator_ignores_evatar_events() -> None:
    """A RequestClosed Event from EVATAR (docs/protocol.md 4.3) is not a reading."""
    import asyncio
    from evatar import Client, SensorEmulator
    from evatar.bil import Signal as Sig

    async def main() -> None:
        c = Client([("127.0.0.1", 1)], pairing="p", role="agent", entity_id="va", credential="")
        em = SensorEmulator(c, "MotionEmulator01", "MotionDetected")
        closed = Sig("evatar-1", "Event", "EVATAR", "MotionEmulator01",
                     Entry("EVATAR", "RequestClosed", {"Reason": "Timeout"}), origin="EVATAR")
        await em._on_signal(closed)
        assert em.latest is None
        reading = Sig("s-1", "Event", "HallSensor", "MotionEmulator01",
                      Entry("SENSOR", "MotionDetected", {}))
        await em._on_signal(reading)
        assert em.latest is reading
    asyncio.run(main())

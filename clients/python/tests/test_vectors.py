"""The shared protocol and BIL vectors (test/vectors, README there) checked
with the Python implementation: frames byte for byte, documents by meaning
and, when canonical, byte for byte, refusals of invalid input, recorded
transcripts, and the error answers of a real node."""

from __future__ import annotations

import json
import socket
import time
from pathlib import Path
from typing import Any, Dict, List, Optional

import pytest

from evatar import bil
from evatar.bil import (Ack, Binding, Bound, Bye, Component, Description, Entry, GetBinding,
                        Hello, Refused, Resume, Signal, Unbound, Welcome, encode, parse_frame)
from evatar.frame import HANDSHAKE_MAX_FRAME, FrameDecoder, FrameError, encode_frame
from evatar.xml import BilError

from conftest import REPO

VECTORS = REPO / "test" / "vectors"
if not (VECTORS / "vectors.json").exists():
    pytest.skip("test/vectors is not here", allow_module_level=True)
ALL: List[Dict[str, Any]] = json.loads((VECTORS / "vectors.json").read_text("utf-8"))["vectors"]


def of_kind(*kinds: str) -> List[Any]:
    return [pytest.param(v, id=v["name"]) for v in ALL if v["kind"] in kinds]


def read(path: str) -> bytes:
    return (VECTORS / path).read_bytes()


# --------------------------------------------------------------------------
# Meaning <-> documents (README section 2)
# --------------------------------------------------------------------------


def params_meaning(ps: List[Any]) -> List[Dict[str, str]]:
    return [{"name": n, "value": v} for n, v in ps]


def params_of(ps: List[Dict[str, str]]) -> List[Any]:
    return [(p["name"], p["value"]) for p in ps]


def entry_meaning(e: Entry) -> Dict[str, Any]:
    return {"category": e.category, "type": e.type, "parameters": params_meaning(e.parameters)}


def meaning(doc: bil.Document) -> Dict[str, Any]:
    if isinstance(doc, Signal):
        return {"context": doc.context, "id": doc.id, "sender": doc.sender,
                "receiver": doc.receiver, "in_reply_to": doc.in_reply_to,
                "timestamp": doc.timestamp, "sequence": doc.sequence, "epoch": doc.epoch,
                "origin": doc.origin,
                "service": {"category": doc.body.category, "type": doc.body.type},
                "parameters": params_meaning(doc.body.parameters)}
    if isinstance(doc, Description):
        return {"entity_id": doc.entity_id, "api_name": doc.api_name,
                "entity_type": doc.entity_type, "context": doc.context,
                "components": [{"id": c.id, "services": [entry_meaning(e) for e in c.services],
                                "consumes": [entry_meaning(e) for e in c.consumes]}
                               for c in doc.components]}
    if isinstance(doc, (Hello, Resume)):
        m: Dict[str, Any] = {"control": type(doc).__name__, "pairing": doc.pairing,
                             "role": doc.role, "entity_id": doc.entity_id,
                             "credential": doc.credential,
                             "protocol_version": doc.protocol_version}
        if isinstance(doc, Resume):
            m.update(session_id=doc.session_id, received=doc.received, epoch=doc.epoch)
        return m
    if isinstance(doc, Welcome):
        return {"control": "Welcome", "pairing": doc.pairing, "entity_id": doc.entity_id,
                "session_id": doc.session_id, "join_timeout": doc.join_timeout,
                "max_frame": doc.max_frame, "epoch": doc.epoch, "resumed": doc.resumed,
                "last_accepted": doc.last_accepted, "dedup_window": doc.dedup_window,
                "heartbeat": doc.heartbeat}
    if isinstance(doc, Ack):
        return {"control": "Ack", "accepted": doc.accepted, "received": doc.received}
    if isinstance(doc, Refused):
        return {"control": "Refused", "code": doc.code, "message": doc.message}
    if isinstance(doc, Bye):
        return {"control": "Bye", "reason": doc.reason}
    if isinstance(doc, GetBinding):
        return {"control": "GetBinding"}
    if isinstance(doc, Binding):
        return {"control": "Binding", "entities": list(doc.entities),
                "bound": [{"consumer_entity": b.consumer_entity,
                           "consumer_component": b.consumer_component,
                           "provider_entity": b.provider_entity,
                           "provider_component": b.provider_component,
                           "service_category": b.category, "service_type": b.type,
                           "score": b.score, "candidates": b.candidates} for b in doc.bound],
                "unbound": [{"consumer_entity": u.consumer_entity,
                             "consumer_component": u.consumer_component,
                             "service_category": u.category, "service_type": u.type,
                             "reason": u.reason} for u in doc.unbound]}
    raise AssertionError(doc)


def document(m: Dict[str, Any]) -> bil.Document:
    if "service" in m:
        return Signal(id=m["id"], context=m["context"], sender=m["sender"],
                      receiver=m["receiver"], in_reply_to=m["in_reply_to"],
                      timestamp=m["timestamp"], sequence=m["sequence"], epoch=m["epoch"],
                      origin=m["origin"],
                      body=Entry(m["service"]["category"], m["service"]["type"],
                                 params_of(m["parameters"])))
    if "components" in m:
        return Description(
            entity_id=m["entity_id"], api_name=m["api_name"], entity_type=m["entity_type"],
            context=m["context"],
            components=[Component(c["id"],
                                  [Entry(e["category"], e["type"], params_of(e["parameters"]))
                                   for e in c["services"]],
                                  [Entry(e["category"], e["type"], params_of(e["parameters"]))
                                   for e in c["consumes"]]) for c in m["components"]])
    c = m["control"]
    f = {k: v for k, v in m.items() if k != "control"}
    if c == "Binding":
        return Binding(f["entities"],
                       [Bound(b["consumer_entity"], b["consumer_component"], b["provider_entity"],
                              b["provider_component"], b["service_category"], b["service_type"],
                              b["score"], b["candidates"]) for b in f["bound"]],
                       [Unbound(u["consumer_entity"], u["consumer_component"],
                                u["service_category"], u["service_type"], u["reason"])
                        for u in f["unbound"]])
    cls = {"Hello": Hello, "Resume": Resume, "Welcome": Welcome, "Ack": Ack,
           "Refused": Refused, "Bye": Bye, "GetBinding": GetBinding}[c]
    return cls(**f)  # type: ignore[no-any-return]


KIND = {"signal": Signal, "description": Description}


def kind_of(doc: bil.Document) -> str:
    if isinstance(doc, Signal):
        return "signal"
    if isinstance(doc, Description):
        return "description"
    return "control"


# --------------------------------------------------------------------------
# The checks (README section 5)
# --------------------------------------------------------------------------


@pytest.mark.parametrize("v", of_kind("frame"))
def test_frame(v: Dict[str, Any]) -> None:
    raw = read(v["file"])
    doc = read(v["expect"]["document"])
    dec = FrameDecoder(HANDSHAKE_MAX_FRAME)
    frames = dec.feed(raw)
    dec.close()
    assert frames == [doc] and len(doc) == v["expect"]["length"]
    assert encode_frame(doc) == raw
    assert encode(parse_frame(doc)) == doc


@pytest.mark.parametrize("v", of_kind("signal", "control", "description"))
def test_document(v: Dict[str, Any]) -> None:
    data = read(v["file"])
    doc = parse_frame(data)
    assert kind_of(doc) == v["kind"]
    assert meaning(doc) == v["expect"]
    again = encode(document(v["expect"]))
    assert meaning(parse_frame(again)) == v["expect"]
    if v["canonical"]:
        assert again == data


#: The classes the frame decoder reports, as FrameError codes.
FRAME_CLASSES = {"empty_frame": "Malformed", "frame_too_large": "FrameTooLarge",
                 "truncated_frame": "truncated"}


@pytest.mark.parametrize("v", of_kind("invalid"))
def test_invalid(v: Dict[str, Any]) -> None:
    data = read(v["file"])
    cls = v["expect"]["error"]
    if cls in FRAME_CLASSES:
        dec = FrameDecoder(HANDSHAKE_MAX_FRAME)
        with pytest.raises(FrameError) as fe:
            dec.feed(data)
            dec.close()
        assert fe.value.code == FRAME_CLASSES[cls]
    else:
        with pytest.raises(BilError) as be:
            parse_frame(data)
        assert be.value.code == cls


@pytest.mark.parametrize("v", of_kind("transcript"))
def test_transcript_offline(v: Dict[str, Any]) -> None:
    assert v["steps"]
    for step in v["steps"]:
        raw = read(step["file"])
        frames = FrameDecoder().feed(raw)
        assert len(frames) == 1 and encode_frame(frames[0]) == raw
        assert meaning(parse_frame(frames[0])) == step["expect"], step["file"]
        assert encode(document(step["expect"])) == frames[0], step["file"]


# --------------------------------------------------------------------------
# Against the node (README sections 3 and 5.6)
# --------------------------------------------------------------------------


class Wire:
    """A raw TCP connection speaking frames, to replay bytes."""

    def __init__(self, port: int) -> None:
        # Longer than the test node's feedback timeout (5 s): transcript_requests waits for it.
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=15)
        self.dec = FrameDecoder()
        self.frames: List[bytes] = []

    def send(self, data: bytes) -> None:
        self.sock.sendall(data)

    def frame(self) -> Optional[bytes]:
        while not self.frames:
            try:
                data = self.sock.recv(65536)
            except ConnectionResetError:
                data = b""
            if not data:
                return None
            self.frames.extend(self.dec.feed(data))
        return self.frames.pop(0)

    def doc(self) -> Optional[bil.Document]:
        f = self.frame()
        return None if f is None else parse_frame(f)

    def closes(self, within: float = 5.0) -> bool:
        end = time.monotonic() + within
        while time.monotonic() < end:
            if self.frame() is None:
                return True
        return False

    def close(self) -> None:
        self.sock.close()


def setup_connection(port: int, setup: Optional[str]) -> Optional[Wire]:
    if setup is None:
        return None
    role, entity, cred = {"agent_connected": ("agent", "va-1", "va-secret"),
                          "avatar_connected": ("avatar", "7008", "avatar-secret")}[setup]
    w = Wire(port)
    w.send(encode_frame(encode(Hello("vectors", role, entity, cred, 1))))
    assert isinstance(w.doc(), Welcome)
    return w


def bye(w: Wire) -> None:
    w.send(encode_frame(encode(Bye())))
    while True:
        d = w.doc()
        if d is None or isinstance(d, Bye):
            break
    w.close()


@pytest.mark.parametrize("v", of_kind("error"))
def test_error_answer(v: Dict[str, Any], node) -> None:  # type: ignore[no-untyped-def]
    other = setup_connection(node.port, v.get("setup"))
    w = Wire(node.port)
    try:
        w.send(read(v["file"]))
        answer = w.doc()
        while isinstance(answer, Welcome):
            answer = w.doc()
        code, close = v["expect"]["error"], v["expect"]["close"]
        if close:
            assert isinstance(answer, Refused), answer
            assert answer.code == code
            assert w.closes()
        else:
            assert isinstance(answer, Signal) and answer.context == "Error", answer
            assert (answer.type, answer.category, answer.sender) == (code, "ERROR", "EVATAR")
            assert answer.param("Message")
            bye(w)
    finally:
        w.close()
        if other is not None:
            bye(other)


@pytest.mark.parametrize("v", of_kind("transcript"))
def test_transcript_replay(v: Dict[str, Any], node) -> None:  # type: ignore[no-untyped-def]
    """README section 5.5: the recorded session replayed against a node."""
    wires: Dict[str, Wire] = {}
    sessions: Dict[str, str] = {}  # entity id -> the live SessionID
    try:
        for n, step in enumerate(v["steps"]):
            name, expect = step["connection"], step["expect"]
            if name not in wires:
                wires[name] = Wire(node.port)
            w = wires[name]
            if step["from"] == "client":
                data = read(step["file"])
                if expect.get("control") == "Resume":
                    live = dict(expect, session_id=sessions[expect["entity_id"]])
                    data = encode_frame(encode(document(live)))
                w.send(data)
                continue
            empty_ack = {"control": "Ack", "accepted": None, "received": None}
            while True:
                got = w.doc()
                assert got is not None, "step %d: %s closed" % (n, name)
                m = meaning(got)
                if m == empty_ack and expect != empty_ack:
                    continue
                break
            if isinstance(got, Welcome):
                sessions[got.entity_id] = got.session_id
                assert len(got.session_id) == 32
                m["session_id"] = expect["session_id"]
            if isinstance(got, Signal) and got.from_evatar and expect.get("sender") == "EVATAR":
                # EVATAR's own signals: id and clock differ from run to run (README 5.5).
                m["id"], m["timestamp"] = expect["id"], expect["timestamp"]
            assert m == expect, "step %d on %s" % (n, name)
    finally:
        for w in wires.values():
            w.close()

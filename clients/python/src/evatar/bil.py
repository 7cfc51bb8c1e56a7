"""BIL documents (docs/bil.md) and the control documents of the wire
protocol (docs/protocol.md section 2): data classes, encoders and parsers.

``parse_frame(data)`` turns one frame's document into a :class:`Signal`, a
:class:`Description` or one of the control classes, or raises
:class:`~evatar.xml.BilError`. Every ``encode`` returns UTF-8 bytes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, List, Mapping, Optional, Sequence, Tuple, Union

from .xml import BilError, Element, escape_text, parse, valid_name

__all__ = [
    "NS", "CONTEXTS", "Entry", "Component", "Description", "Signal", "Hello", "Resume",
    "Welcome", "Ack", "Refused", "Bye", "GetBinding", "Bound", "Unbound", "Binding", "Document",
    "parse_frame", "parse_signal", "parse_description", "encode", "BilError",
]

NS = "urn:evatar:bil:1"
SIGNAL_MAX = 65536
DESCRIPTION_MAX = 1048576
CONTROL_MAX = 1048576
#: Wire names of signal contexts (docs/bil.md section 3).
CONTEXTS = ("RequestAwaitingFeedback", "Request", "Feedback", "Progress", "SensorData",
            "Event", "Error")

Parameters = List[Tuple[str, str]]
#: What an API taking parameters accepts: pairs in order, or a mapping.
ParamsLike = Union[Sequence[Tuple[str, str]], Mapping[str, str], None]


def _params(p: ParamsLike) -> Parameters:
    if p is None:
        return []
    if isinstance(p, Mapping):
        return [(str(k), str(v)) for k, v in p.items()]
    return [(str(k), str(v)) for k, v in p]


class Entry:
    """A service entry (``Service``/``Consumes``) or a signal body.
    ``parameters`` may be given as pairs or as a mapping; they are kept as
    a list of ``(name, value)`` pairs, in order."""

    __slots__ = ("category", "type", "parameters")

    def __init__(self, category: str, type: str, parameters: ParamsLike = None) -> None:
        self.category = category
        self.type = type
        self.parameters: Parameters = _params(parameters)

    def __eq__(self, other: object) -> bool:
        return (isinstance(other, Entry) and self.category == other.category
                and self.type == other.type and self.parameters == other.parameters)

    def __repr__(self) -> str:
        return "Entry(%r, %r, %r)" % (self.category, self.type, self.parameters)

    def param(self, name: str, default: Optional[str] = None) -> Optional[str]:
        """The value of the first parameter called ``name``."""
        for k, v in self.parameters:
            if k == name:
                return v
        return default


@dataclass
class Component:
    id: str
    services: List[Entry] = field(default_factory=list)
    consumes: List[Entry] = field(default_factory=list)


@dataclass
class Description:
    """A BIL description; ``entity_type`` is ``"Agent"`` or ``"Avatar"``."""

    entity_id: str
    entity_type: str
    components: List[Component] = field(default_factory=list)
    api_name: str = ""
    context: str = ""

    def encode(self) -> bytes:
        out = ['<?xml version="1.0" encoding="UTF-8"?>\n<bil:description xmlns:bil="%s">\n'
               "  <bil:context>\n    <EntityID>%s</EntityID>\n    <APIName>%s</APIName>\n"
               "    <EntityType>%s</EntityType>\n    <Context>%s</Context>\n  </bil:context>\n"
               % (NS, escape_text(self.entity_id), escape_text(self.api_name),
                  self.entity_type, escape_text(self.context))]
        if not self.components:
            out.append("  <bil:types/>\n")
        else:
            out.append("  <bil:types>\n")
            for c in self.components:
                out.append("    <bil:Component>\n      <ComponentID>%s</ComponentID>\n"
                           % escape_text(c.id))
                for tag, entries in (("Service", c.services), ("Consumes", c.consumes)):
                    for e in entries:
                        out.append("      <%s>\n        <ServiceCategory>%s</ServiceCategory>\n"
                                   "        <ServiceType>%s</ServiceType>\n"
                                   % (tag, escape_text(e.category), escape_text(e.type)))
                        if e.parameters:
                            out.append("        <ServiceParameters>\n")
                            for n, v in e.parameters:
                                out.append("          <%s>%s</%s>\n"
                                           % (_check_name(n), escape_text(v), n))
                            out.append("        </ServiceParameters>\n")
                        else:
                            out.append("        <ServiceParameters/>\n")
                        out.append("      </%s>\n" % tag)
                out.append("    </bil:Component>\n")
            out.append("  </bil:types>\n")
        out.append("</bil:description>\n")
        return "".join(out).encode("utf-8")


@dataclass
class Signal:
    """A BIL signal (``Envelope``). ``context`` is the wire name
    (``RequestAwaitingFeedback``, ``Feedback``, ``SensorData``, ...)."""

    id: str
    context: str
    sender: str
    receiver: str
    body: Entry
    timestamp: int = 0
    in_reply_to: Optional[str] = None
    sequence: Optional[int] = None
    epoch: Optional[int] = None
    #: ``"EVATAR"`` on a signal EVATAR made itself (its Timeout and
    #: ProviderGone feedback, its errors), ``None`` on an entity's: the
    #: header's ``Origin``, which EVATAR refuses from entities.
    origin: Optional[str] = None

    @property
    def from_evatar(self) -> bool:
        """True for a signal EVATAR made itself (``Origin`` ``EVATAR``), not an
        entity's, whatever its ``Sender`` says."""
        return self.origin == "EVATAR"

    @property
    def category(self) -> str:
        return self.body.category

    @property
    def type(self) -> str:
        return self.body.type

    def param(self, name: str, default: Optional[str] = None) -> Optional[str]:
        return self.body.param(name, default)

    @property
    def is_error(self) -> bool:
        return self.context == "Error"

    @property
    def is_evatar_timeout(self) -> bool:
        """EVATAR's own feedback for a request that got no answer in time."""
        return (self.context == "Feedback" and self.from_evatar and self.sender == "EVATAR"
                and self.body.category == "EVATAR" and self.body.type == "Timeout")

    def encode(self) -> bytes:
        if self.context not in CONTEXTS:
            raise ValueError("unknown signal context %r" % self.context)
        h = ["<SignalID>%s</SignalID><Context>%s</Context><Sender>%s</Sender>"
             "<Receiver>%s</Receiver>" % (escape_text(self.id), self.context,
                                          escape_text(self.sender), escape_text(self.receiver))]
        if self.in_reply_to is not None:
            h.append("<InReplyTo>%s</InReplyTo>" % escape_text(self.in_reply_to))
        h.append("<Timestamp>%d</Timestamp>" % _nonneg(self.timestamp))
        if self.sequence is not None:
            h.append("<Sequence>%d</Sequence>" % _nonneg(self.sequence))
        if self.epoch is not None:
            h.append("<Epoch>%d</Epoch>" % _nonneg(self.epoch))
        if self.origin is not None:
            if self.origin != "EVATAR":
                raise ValueError("Origin can only be EVATAR, not %r" % self.origin)
            h.append("<Origin>EVATAR</Origin>")
        return ('<?xml version="1.0" encoding="UTF-8"?><bil:Envelope xmlns:bil="%s">'
                "<bil:Header>%s</bil:Header><bil:Body>%s</bil:Body></bil:Envelope>"
                % (NS, "".join(h), _body(self.body))).encode("utf-8")


def _nonneg(n: int) -> int:
    if not isinstance(n, int) or n < 0:
        raise ValueError("numbers must be non-negative integers, not %r" % (n,))
    return n


def _check_name(n: str) -> str:
    if not valid_name(n):
        raise ValueError("bad parameter name %r: not an XML name without a colon" % n)
    return n


def _body(e: Entry) -> str:
    ps = "".join("<%s>%s</%s>" % (_check_name(n), escape_text(v), n) for n, v in e.parameters)
    return ("<ServiceCategory>%s</ServiceCategory><ServiceType>%s</ServiceType>%s"
            % (escape_text(e.category), escape_text(e.type),
               "<ServiceParameters>%s</ServiceParameters>" % ps if ps else "<ServiceParameters/>"))


# --------------------------------------------------------------------------
# Control documents
# --------------------------------------------------------------------------


@dataclass
class Hello:
    pairing: str
    role: str
    entity_id: str
    credential: str
    protocol_version: int = 1


@dataclass
class Resume:
    pairing: str
    role: str
    entity_id: str
    credential: str
    protocol_version: int
    session_id: str
    received: int
    epoch: int


@dataclass
class Welcome:
    pairing: str
    entity_id: str
    session_id: str
    join_timeout: int
    max_frame: int
    #: Version 2 fields; None in a version 1 Welcome.
    epoch: Optional[int] = None
    resumed: Optional[bool] = None
    last_accepted: Optional[str] = None
    dedup_window: Optional[int] = None
    heartbeat: Optional[int] = None

    @property
    def ha(self) -> bool:
        return self.epoch is not None


@dataclass
class Ack:
    accepted: Optional[str] = None
    received: Optional[int] = None


@dataclass
class Refused:
    code: str
    message: str


@dataclass
class Bye:
    reason: str = ""


@dataclass
class GetBinding:
    """Asks EVATAR for the current Binding report (docs/protocol.md section 2, revision 3)."""


@dataclass
class Bound:
    """One row of the Body Mapping Registry: the ``Consumes`` entry
    (``category``/``type``, as the consumer wrote them) of
    ``consumer_component`` of ``consumer_entity`` is bound to the ``Service``
    of ``provider_component`` of ``provider_entity``. ``score`` is how many
    parameter names the two entries share with equal values, ``candidates``
    how many compatible services there were (docs/bil.md section 4). Signals
    pass between the two components in either direction."""

    consumer_entity: str
    consumer_component: str
    provider_entity: str
    provider_component: str
    category: str
    type: str
    score: int
    candidates: int


@dataclass
class Unbound:
    """A ``Consumes`` entry nothing was bound to: ``reason`` is
    ``NoProvider`` (no component of the other entity type provides that
    category and type) or ``ParametersMismatch`` (some do, none with
    compatible parameters; which parameter differs is not in the report:
    compare the two descriptions, docs/clients.md "When something is
    unbound")."""

    consumer_entity: str
    consumer_component: str
    category: str
    type: str
    reason: str


@dataclass
class Binding:
    """The Body Mapping Registry report EVATAR sends after each binding:
    ``entities`` the EntityIDs described in the pairing, ``bound`` and
    ``unbound`` the rows of the whole pairing (every entity's, not only
    yours)."""

    entities: List[str]
    bound: List[Bound] = field(default_factory=list)
    unbound: List[Unbound] = field(default_factory=list)

    def is_bound(self, component: str, type: Optional[str] = None) -> bool:
        """True when ``component`` (a ComponentID, unique in the pairing) is
        in a ``bound`` row, as consumer or as provider, and none of its own
        ``Consumes`` entries is ``unbound``; with ``type``, only the rows of
        that ServiceType count. For a VA's actuator emulator: every action it
        consumes has a device; for a sensor emulator: a device's sensor is
        bound to it, so its readings reach it."""
        rows = [r for r in self.bound
                if component in (r.consumer_component, r.provider_component)
                and (type is None or r.type == type)]
        return bool(rows) and not any(
            u.consumer_component == component and (type is None or u.type == type)
            for u in self.unbound)

    def bound_for(self, entity: str) -> List[Bound]:
        """The ``bound`` rows in which ``entity`` is the consumer or the provider."""
        return [r for r in self.bound if entity in (r.consumer_entity, r.provider_entity)]

    def unbound_for(self, entity: str, component: Optional[str] = None) -> List[Unbound]:
        """The ``unbound`` rows of ``entity``'s own ``Consumes`` entries (of
        ``component`` only, if given): what it asked for and got nothing."""
        return [u for u in self.unbound if u.consumer_entity == entity
                and (component is None or u.consumer_component == component)]


Control = Union[Hello, Resume, Welcome, Ack, Refused, Bye, GetBinding, Binding]
Document = Union[Signal, Description, Hello, Resume, Welcome, Ack, Refused, Bye, GetBinding,
                 Binding]


def _f(name: str, value: str) -> str:
    return "<%s>%s</%s>" % (name, escape_text(value), name)


def _doc(name: str, fields: Sequence[str]) -> bytes:
    return ('<bil:%s xmlns:bil="%s">%s</bil:%s>' % (name, NS, "".join(fields), name)).encode(
        "utf-8")


def encode(doc: Document) -> bytes:
    """Encodes any document exactly as the Erlang encoders do."""
    if isinstance(doc, (Signal, Description)):
        return doc.encode()
    if isinstance(doc, (Hello, Resume)):
        fs = [_f("Pairing", doc.pairing), _f("Role", doc.role), _f("EntityID", doc.entity_id),
              _f("Credential", doc.credential),
              _f("ProtocolVersion", str(_nonneg(doc.protocol_version)))]
        if isinstance(doc, Resume):
            fs += [_f("SessionID", doc.session_id), _f("Received", str(_nonneg(doc.received))),
                   _f("Epoch", str(_nonneg(doc.epoch)))]
            return _doc("Resume", fs)
        return _doc("Hello", fs)
    if isinstance(doc, Welcome):
        fs = [_f("Pairing", doc.pairing), _f("EntityID", doc.entity_id),
              _f("SessionID", doc.session_id), _f("JoinTimeout", str(doc.join_timeout)),
              _f("MaxFrame", str(doc.max_frame))]
        if doc.ha:
            fs += [_f("Epoch", str(doc.epoch)), _f("Resumed", "true" if doc.resumed else "false"),
                   _f("LastAccepted", doc.last_accepted or ""),
                   _f("DedupWindow", str(doc.dedup_window)), _f("Heartbeat", str(doc.heartbeat))]
        return _doc("Welcome", fs)
    if isinstance(doc, Ack):
        fs = []
        if doc.accepted is not None:
            fs.append(_f("Accepted", doc.accepted))
        if doc.received is not None:
            fs.append(_f("Received", str(_nonneg(doc.received))))
        return _doc("Ack", fs)
    if isinstance(doc, Refused):
        return _doc("Refused", [_f("Code", doc.code), _f("Message", doc.message)])
    if isinstance(doc, Bye):
        return _doc("Bye", [_f("Reason", doc.reason)] if doc.reason else [])
    if isinstance(doc, GetBinding):
        return _doc("GetBinding", [])
    if isinstance(doc, Binding):
        fs = ["<Entities>" + "".join(_f("EntityID", e) for e in doc.entities) + "</Entities>"]
        for b in doc.bound:
            fs.append("<Bound>%s</Bound>" % "".join([
                _f("ConsumerEntity", b.consumer_entity), _f("ConsumerComponent", b.consumer_component),
                _f("ProviderEntity", b.provider_entity), _f("ProviderComponent", b.provider_component),
                _f("ServiceCategory", b.category), _f("ServiceType", b.type),
                _f("Score", str(b.score)), _f("Candidates", str(b.candidates))]))
        for u in doc.unbound:
            fs.append("<Unbound>%s</Unbound>" % "".join([
                _f("ConsumerEntity", u.consumer_entity), _f("ConsumerComponent", u.consumer_component),
                _f("ServiceCategory", u.category), _f("ServiceType", u.type),
                _f("Reason", u.reason)]))
        return _doc("Binding", fs)
    raise TypeError("not a BIL document: %r" % (doc,))


# --------------------------------------------------------------------------
# Parsing
# --------------------------------------------------------------------------


def _err(code: str, message: str, path: str) -> BilError:
    return BilError(code, "at %s: %s" % (path, message))


def _leaf(el: Element, path: str) -> str:
    if el.ns:
        raise _err("wrong_namespace", "field elements are in no namespace", path)
    t = el.text()
    if t is None:
        raise _err("unexpected_element", "a field holds text only", path)
    return t


def _check_text_free(el: Element, path: str) -> None:
    for c in el.children:
        if isinstance(c, str):
            raise _err("unexpected_element", "text is not allowed here", path)


def _typed(kind: str, text: str, path: str) -> object:
    if kind == "any":
        return text
    if kind == "text":
        if text == "":
            raise _err("bad_value", "must not be empty", path)
        return text
    if kind in ("int", "pos"):
        if not (1 <= len(text) <= 20 and text.isascii() and text.isdigit()):
            raise _err("bad_value", "expected 1 to 20 decimal digits", path)
        n = int(text)
        if kind == "pos" and n == 0:
            raise _err("bad_value", "must be at least 1", path)
        return n
    if kind == "role":
        if text not in ("agent", "avatar"):
            raise _err("bad_value", "Role is agent or avatar", path)
        return text
    if kind == "bool":
        if text not in ("true", "false"):
            raise _err("bad_value", "expected true or false", path)
        return text == "true"
    if kind == "reason":
        if text not in ("NoProvider", "ParametersMismatch"):
            raise _err("bad_value", "Reason is NoProvider or ParametersMismatch", path)
        return text
    raise AssertionError(kind)


def _fields(children: Sequence[Union[Element, str]], spec: Sequence[Tuple[str, str]],
            path: str) -> Tuple[List[object], Sequence[Union[Element, str]]]:
    """Reads the fields of ``spec`` in order; returns their values and what follows."""
    values: List[object] = []
    i = 0
    for name, kind in spec:
        if i >= len(children):
            raise _err("missing_element", "%s is missing" % name, "%s/%s" % (path, name))
        c = children[i]
        if isinstance(c, str):
            raise _err("unexpected_element", "text is not allowed here", path)
        if c.name != name:
            raise _err("unexpected_element", "expected %s, found %s" % (name, c.name),
                       "%s/%s" % (path, c.name))
        values.append(_typed(kind, _leaf(c, "%s/%s" % (path, name)), "%s/%s" % (path, name)))
        i += 1
    return values, children[i:]


_HELLO = [("Pairing", "text"), ("Role", "role"), ("EntityID", "text"), ("Credential", "any"),
          ("ProtocolVersion", "int")]
_WELCOME = [("Pairing", "text"), ("EntityID", "text"), ("SessionID", "text"),
            ("JoinTimeout", "int"), ("MaxFrame", "int")]
_WELCOME_HA = [("Epoch", "int"), ("Resumed", "bool"), ("LastAccepted", "any"),
               ("DedupWindow", "int"), ("Heartbeat", "int")]
_BOUND = [("ConsumerEntity", "text"), ("ConsumerComponent", "text"), ("ProviderEntity", "text"),
          ("ProviderComponent", "text"), ("ServiceCategory", "text"), ("ServiceType", "text"),
          ("Score", "int"), ("Candidates", "pos")]
_UNBOUND = [("ConsumerEntity", "text"), ("ConsumerComponent", "text"),
            ("ServiceCategory", "text"), ("ServiceType", "text"), ("Reason", "reason")]


def _optional(children: Sequence[Union[Element, str]], name: str, kind: str,
              path: str) -> Tuple[object, Sequence[Union[Element, str]]]:
    if children and isinstance(children[0], str):
        raise _err("unexpected_element", "text is not allowed here", path)
    if children and isinstance(children[0], Element) and children[0].name == name:
        (v,), rest = _fields(children, [(name, kind)], path)
        return v, rest
    return None, children


def _control(root: Element) -> Document:
    name, ch, path = root.name, root.children, "/" + root.name
    if name == "Hello":
        v, _ = _fields(ch, _HELLO, path)
        return Hello(*v)  # type: ignore[arg-type]
    if name == "Resume":
        v, _ = _fields(ch, _HELLO + [("SessionID", "text"), ("Received", "int"),
                                     ("Epoch", "int")], path)
        return Resume(*v)  # type: ignore[arg-type]
    if name == "Welcome":
        v, rest = _fields(ch, _WELCOME, path)
        w = Welcome(*v)  # type: ignore[arg-type]
        if rest and isinstance(rest[0], Element) and rest[0].name == "Epoch":
            h, _ = _fields(rest, _WELCOME_HA, path)
            w.epoch, w.resumed, w.last_accepted, w.dedup_window, w.heartbeat = h  # type: ignore
        return w
    if name == "Ack":
        acc, rest = _optional(ch, "Accepted", "text", path)
        rec, _ = _optional(rest, "Received", "int", path)
        return Ack(acc, rec)  # type: ignore[arg-type]
    if name == "Refused":
        v, _ = _fields(ch, [("Code", "text"), ("Message", "any")], path)
        return Refused(*v)  # type: ignore[arg-type]
    if name == "Bye":
        if not ch:
            return Bye("")
        v, _ = _fields(ch, [("Reason", "any")], path)
        return Bye(*v)  # type: ignore[arg-type]
    if name == "GetBinding":
        return GetBinding()
    if name == "Binding":
        if not ch or isinstance(ch[0], str) or ch[0].name != "Entities":
            raise _err("missing_element", "Entities must come first", path + "/Entities")
        ents = ch[0]
        if ents.ns:
            raise _err("wrong_namespace", "field elements are in no namespace", path + "/Entities")
        ids = []
        for e in ents.children:
            if isinstance(e, str) or e.name != "EntityID":
                raise _err("unexpected_element", "Entities holds EntityID elements only",
                           path + "/Entities")
            ids.append(_typed("text", _leaf(e, path + "/Entities/EntityID"),
                              path + "/Entities/EntityID"))
        b = Binding([str(i) for i in ids])
        for row in ch[1:]:
            if isinstance(row, str):
                raise _err("unexpected_element", "text is not allowed here", path)
            if row.name == "Bound" and not b.unbound:
                if row.ns:
                    raise _err("wrong_namespace", "field elements are in no namespace", path)
                v, _ = _fields(row.children, _BOUND, path + "/Bound")
                b.bound.append(Bound(*v))  # type: ignore[arg-type]
            elif row.name == "Unbound":
                if row.ns:
                    raise _err("wrong_namespace", "field elements are in no namespace", path)
                v, _ = _fields(row.children, _UNBOUND, path + "/Unbound")
                b.unbound.append(Unbound(*v))  # type: ignore[arg-type]
            else:
                break
        return b
    raise _err("wrong_root", "expected Hello, Resume, Welcome, Refused, Binding, GetBinding, "
               "Ack, Bye, Envelope or description", path)


def _structural(el: Element, name: str, path: str) -> None:
    if el.name != name:
        raise _err("unexpected_element", "expected %s, found %s" % (name, el.name), path)
    if el.ns != NS:
        raise _err("wrong_namespace", "%s must be in the BIL namespace" % name, path)
    _check_text_free(el, path)


def _entry(el: Element, path: str) -> Entry:
    _check_text_free(el, path)
    kids = el.elements()
    v, rest = _fields(kids, [("ServiceCategory", "text"), ("ServiceType", "text")], path)
    params: Parameters = []
    if rest:
        sp = rest[0]
        assert isinstance(sp, Element)
        if sp.name != "ServiceParameters":
            raise _err("unexpected_element", "unexpected element %s" % sp.name,
                       "%s/%s" % (path, sp.name))
        ppath = path + "/ServiceParameters"
        if sp.ns:
            raise _err("wrong_namespace", "field elements are in no namespace", ppath)
        _check_text_free(sp, ppath)
        seen = set()
        for p in sp.elements():
            val = _leaf(p, "%s/%s" % (ppath, p.name))
            if p.name in seen:
                raise _err("duplicate_element", "parameter %s given twice" % p.name, ppath)
            seen.add(p.name)
            params.append((p.name, val))
        if len(rest) > 1:
            extra = rest[1]
            assert isinstance(extra, Element)
            raise _err("unexpected_element", "unexpected element %s" % extra.name,
                       "%s/%s" % (path, extra.name))
    return Entry(str(v[0]), str(v[1]), params)


def _signal(root: Element) -> Signal:
    path = "/Envelope"
    _check_text_free(root, path)
    kids = root.elements()
    if not kids:
        raise _err("missing_element", "Header is missing", path + "/Header")
    _structural(kids[0], "Header", path + "/Header")
    if len(kids) < 2:
        raise _err("missing_element", "Body is missing", path + "/Body")
    _structural(kids[1], "Body", path + "/Body")
    if len(kids) > 2:
        raise _err("unexpected_element", "unexpected element %s" % kids[2].name,
                   "%s/%s" % (path, kids[2].name))
    hpath = path + "/Header"
    h = kids[0].elements()
    v, rest = _fields(h, [("SignalID", "text"), ("Context", "text"), ("Sender", "text"),
                          ("Receiver", "text")], hpath)
    if v[1] not in CONTEXTS:
        raise _err("bad_value", "unknown signal context %s" % v[1], hpath + "/Context")
    irt, rest = _optional(rest, "InReplyTo", "text", hpath)
    (ts,), rest = _fields(rest, [("Timestamp", "int")], hpath)
    seq, rest = _optional(rest, "Sequence", "int", hpath)
    ep, rest = _optional(rest, "Epoch", "int", hpath)
    origin, rest = _optional(rest, "Origin", "text", hpath)
    if origin is not None and origin != "EVATAR":
        raise _err("bad_value", "Origin must be EVATAR; found %s" % origin, hpath + "/Origin")
    if rest:
        extra = rest[0]
        assert isinstance(extra, Element)
        raise _err("unexpected_element", "unexpected element %s" % extra.name,
                   "%s/%s" % (hpath, extra.name))
    body = _entry(kids[1], path + "/Body")
    return Signal(id=str(v[0]), context=str(v[1]), sender=str(v[2]), receiver=str(v[3]),
                  body=body, timestamp=int(ts),  # type: ignore[call-overload]
                  in_reply_to=irt, sequence=seq, epoch=ep,  # type: ignore[arg-type]
                  origin=origin)  # type: ignore[arg-type]


def _description(root: Element) -> Description:
    path = "/description"
    _check_text_free(root, path)
    kids = root.elements()
    if not kids:
        raise _err("missing_element", "context is missing", path + "/context")
    _structural(kids[0], "context", path + "/context")
    if len(kids) < 2:
        raise _err("missing_element", "types is missing", path + "/types")
    _structural(kids[1], "types", path + "/types")
    if len(kids) > 2:
        raise _err("unexpected_element", "unexpected element %s" % kids[2].name, path)
    v, rest = _fields(kids[0].elements(), [("EntityID", "text"), ("APIName", "any"),
                                           ("EntityType", "any"), ("Context", "any")],
                      path + "/context")
    if rest:
        raise _err("unexpected_element", "unexpected element in context", path + "/context")
    if v[2] not in ("Agent", "Avatar"):
        raise _err("bad_value", "EntityType is Agent or Avatar", path + "/context/EntityType")
    comps: List[Component] = []
    seen = set()
    for c in kids[1].elements():
        cpath = path + "/types/Component"
        _structural(c, "Component", cpath)
        ck = c.elements()
        (cid,), rest = _fields(ck, [("ComponentID", "text")], cpath)
        if cid in seen:
            raise _err("duplicate_component", "component %s given twice" % cid, cpath)
        seen.add(cid)
        comp = Component(str(cid))
        for e in rest:
            assert isinstance(e, Element)
            if e.ns:
                raise _err("wrong_namespace", "field elements are in no namespace", cpath)
            if e.name == "Service" and not comp.consumes:
                comp.services.append(_entry(e, cpath + "/Service"))
            elif e.name == "Consumes" and comp.services:
                comp.consumes.append(_entry(e, cpath + "/Consumes"))
            else:
                raise _err("unexpected_element", "unexpected element %s" % e.name, cpath)
        if not comp.services:
            raise _err("missing_element", "a component needs a Service", cpath + "/Service")
        comps.append(comp)
    return Description(entity_id=str(v[0]), api_name=str(v[1]), entity_type=str(v[2]),
                       context=str(v[3]), components=comps)


def _parse(data: bytes, max_size: int) -> Document:
    root = parse(data, max_size=max_size)
    if root.ns != NS:
        raise _err("wrong_namespace", "the root element is not in the BIL namespace",
                   "/" + root.name)
    if root.name == "Envelope":
        return _signal(root)
    if root.name == "description":
        return _description(root)
    return _control(root)


def parse_frame(data: bytes) -> Document:
    """Parses one frame's document (signal, description or control)."""
    doc = _parse(data, CONTROL_MAX)
    if isinstance(doc, Signal) and len(data) > SIGNAL_MAX:
        raise BilError("too_large", "signal of %d bytes is over the limit of %d"
                       % (len(data), SIGNAL_MAX))
    return doc


def parse_signal(data: bytes) -> Signal:
    doc = _parse(data, SIGNAL_MAX)
    if not isinstance(doc, Signal):
        raise BilError("wrong_root", "expected bil:Envelope")
    return doc


def parse_description(data: bytes) -> Description:
    doc = _parse(data, DESCRIPTION_MAX)
    if not isinstance(doc, Description):
        raise BilError("wrong_root", "expected bil:description")
    return doc


ParseFn = Callable[[bytes], Document]

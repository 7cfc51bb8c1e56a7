"""Embodying an AgentSpeak agent (python-agentspeak, PyPI ``agentspeak``)
through EVATAR: the agent's actions become BIL requests, BIL sensor
signals and feedback become its percepts.

Install the interpreter with ``pip install agentspeak`` (or the package's
``agentspeak`` extra); this module imports it only when used.

What the agent perceives (beliefs; each addition is a ``+...`` event):

``reading(Component, Type, Params, Time)``
    the latest sensor signal (``SensorData`` or ``Event``) to the VA's
    ``Component`` of service type ``Type``; it replaces the previous one of
    the same component and type. ``Params`` is a list of ``p(Name, Value)``
    (strings); ``Time`` the signal's ``Timestamp`` (ms since 1970 on the
    sender's clock, which for a simulated Avatar is simulated time).
``feedback(Tag, Service, Params)``
    the Feedback answering the request made with ``Tag``.
``progress(Tag, Service, Params)``
    a Progress answering it.
``failure(Tag, Service, Code)``
    an Error signal, EVATAR's Timeout (``Code`` ``"Timeout"``) or a request
    that could not be sent (``"NotBound"``, ``"Closed"``).
``bound(Component)``
    one per VA component bound to a provider, after each Binding report.

What it can do (internal actions):

``.request(Component, Service, Params, Tag)``
    sends ``Service`` from the VA's ``Component`` to the provider bound to
    it, awaiting feedback; returns at once, the answer comes as a percept
    tagged ``Tag``. ``Params``: a list of ``p(Name, Value)``.
``.send(Component, Service, Params)``
    the same, expecting no answer.
``.minute("HH:MM", M)``
    unifies M with the minute of the day (0..1439).
``.log(Term, ...)``
    appends the terms, as text, to :attr:`AgentSpeakVA.log` (and the Python logger).
"""

from __future__ import annotations

import asyncio
import importlib
import logging
from typing import Any, Iterator, List, Optional, Set, Tuple

from .bil import Binding, Description, Signal
from .client import Client, ClosedError, FeedbackTimeout, SignalError

__all__ = ["AgentSpeakVA", "params_of", "plist", "perceive", "minute_of"]

LOG = logging.getLogger("evatar.bdi")


def _import_agentspeak() -> Any:
    try:
        agentspeak = importlib.import_module("agentspeak")
        importlib.import_module("agentspeak.runtime")
        importlib.import_module("agentspeak.stdlib")
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError("evatar.bdi needs python-agentspeak: pip install agentspeak") from e
    return agentspeak


def _text(value: Any) -> str:
    if isinstance(value, float) and value.is_integer():
        return str(int(value))
    if isinstance(value, bool):
        return "yes" if value else "no"
    return str(value)


def params_of(as_: Any, term: Any) -> List[Tuple[str, str]]:
    """BIL parameters from an AgentSpeak list of ``p(Name, Value)``."""
    out = []
    for p in term or ():
        if isinstance(p, as_.Literal) and len(p.args) == 2:
            out.append((_text(p.args[0]), _text(p.args[1])))
        elif isinstance(p, tuple) and len(p) == 2:
            out.append((_text(p[0]), _text(p[1])))
        else:
            raise ValueError("a parameter is p(Name, Value), not %s" % (p,))
    return out


def plist(as_: Any, params: List[Tuple[str, str]]) -> Tuple[Any, ...]:
    """BIL parameters as an AgentSpeak list of ``p(Name, Value)`` (strings)."""
    return tuple(as_.Literal("p", (n, v)) for n, v in params)


def perceive(as_: Any, agent: Any, functor: str, args: Tuple[Any, ...], replace: int = 0,
             annots: Any = None) -> None:
    """Adds the belief ``functor(args)`` to a python-agentspeak agent, with
    its ``+`` event; with ``replace`` = N it first drops (without an event)
    the beliefs of the same functor whose first N arguments match."""
    if replace:
        group = agent.beliefs[(functor, len(args))]
        for b in [b for b in group if tuple(b.args[:replace]) == args[:replace]]:
            group.discard(b)
    term = as_.Literal(functor, args) if annots is None else as_.Literal(functor, args, annots)
    agent.call(as_.Trigger.addition, as_.GoalType.belief, term, as_.runtime.Intention())


def minute_of(text: str) -> Optional[int]:
    """The minute of the day (0..1439) of ``"HH:MM"``, or None."""
    try:
        h, m = text.split(":")[:2]
        return int(h) * 60 + int(m)
    except ValueError:
        return None


class AgentSpeakVA:
    """Runs one AgentSpeak agent as the mind of a VA connected by ``client``
    whose body is ``description`` (sent by :meth:`start`).

    :param source: the .asl file.
    :param request_timeout: seconds a request may wait for its feedback
        before the agent perceives ``failure(Tag, Service, "Timeout")``
        (EVATAR's own feedback timeout usually comes first).
    """

    def __init__(self, client: Client, description: Description, source: str,
                 request_timeout: float = 30.0) -> None:
        self.as_ = _import_agentspeak()
        self.client = client
        self.description = description
        self.request_timeout = request_timeout
        self.log: List[str] = []
        self.requests: List[Tuple[str, str, List[Tuple[str, str]]]] = []
        self._tasks: "set[asyncio.Future[None]]" = set()
        self._wake = asyncio.Event()
        self._bound: Set[str] = set()
        self.env = self.as_.runtime.Environment()
        actions = self._actions()
        with open(source) as f:
            self.agent = self.env.build_agent(f, actions)
        for c in description.components:
            client.on(c.id, self._on_signal)

    # -------------------------------------------------------------- actions

    def _actions(self) -> Any:
        as_ = self.as_
        actions = as_.Actions(as_.stdlib.actions)
        va = self

        def _request(agent: Any, term: Any, intention: Any) -> Iterator[None]:
            comp, service, params, tag = (as_.grounded(a, intention.scope) for a in term.args)
            va._spawn(va._request(str(comp), str(service), va._params(params), tag, True))
            yield

        def _send(agent: Any, term: Any, intention: Any) -> Iterator[None]:
            comp, service, params = (as_.grounded(a, intention.scope) for a in term.args)
            va._spawn(va._request(str(comp), str(service), va._params(params), None, False))
            yield

        def _minute(agent: Any, term: Any, intention: Any) -> Iterator[None]:
            minute = minute_of(str(as_.grounded(term.args[0], intention.scope)))
            if minute is None:
                return
            if as_.unify(term.args[1], minute, intention.scope, intention.stack):
                yield

        def _log(agent: Any, term: Any, intention: Any) -> Iterator[None]:
            text = "".join(_text(v) if isinstance(v, (str, int, float)) else as_.asl_str(v)
                           for v in (as_.grounded(a, intention.scope) for a in term.args))
            va.log.append(text)
            LOG.info("%s", text)
            yield

        actions.add(".request", 4)(_request)
        actions.add(".send", 3)(_send)
        actions.add(".minute", 2)(_minute)
        actions.add(".log")(_log)
        return actions

    def _params(self, term: Any) -> List[Tuple[str, str]]:
        return params_of(self.as_, term)

    def _plist(self, params: List[Tuple[str, str]]) -> Tuple[Any, ...]:
        return plist(self.as_, params)

    # -------------------------------------------------------------- percepts

    def _perceive(self, functor: str, args: Tuple[Any, ...], replace: int = 0) -> None:
        """Adds a belief; with ``replace`` = N, first drops (without an
        event) the belief of the same functor whose first N arguments match."""
        perceive(self.as_, self.agent, functor, args, replace)
        self._wake.set()

    def _on_signal(self, s: Signal) -> None:
        if s.context in ("SensorData", "Event"):
            self._perceive("reading", (s.receiver, s.type, self._plist(s.body.parameters),
                                       s.timestamp), replace=2)

    def _on_binding(self, b: Binding) -> None:
        now = {r.consumer_component for r in b.bound if r.consumer_entity == self.client.entity_id}
        for c in sorted(now - self._bound):
            self._perceive("bound", (c,))
        for c in sorted(self._bound - now):
            self.agent.beliefs[("bound", 1)].discard(self.as_.Literal("bound", (c,)))
        self._bound = now

    async def _request(self, comp: str, service: str, params: List[Tuple[str, str]],
                       tag: Any, feedback: bool) -> None:
        provider = None
        if self.client.binding is not None:
            for r in self.client.binding.bound:
                if (r.consumer_entity == self.client.entity_id and r.consumer_component == comp
                        and r.type == service):
                    provider = r
        if provider is None:
            if feedback:
                self._perceive("failure", (tag, service, "NotBound"))
            return
        self.requests.append((comp, service, params))
        try:
            if not feedback:
                await self.client.send(sender=comp, receiver=provider.provider_component,
                                       category=provider.category, type=service,
                                       parameters=params)
                return
            fb = await self.client.request(sender=comp, receiver=provider.provider_component,
                                           category=provider.category, type=service,
                                           parameters=params, timeout=self.request_timeout)
        except SignalError as e:
            self._perceive("failure", (tag, service, e.code))
            return
        except FeedbackTimeout:
            self._perceive("failure", (tag, service, "Timeout"))
            return
        except ClosedError:
            if feedback:
                self._perceive("failure", (tag, service, "Closed"))
            return
        if fb.is_evatar_timeout:
            self._perceive("failure", (tag, service, "Timeout"))
        else:
            self._perceive("feedback", (tag, service, self._plist(fb.body.parameters)))

    def _spawn(self, coro: Any) -> None:
        t = asyncio.ensure_future(coro)
        self._tasks.add(t)
        t.add_done_callback(self._tasks.discard)

    # ------------------------------------------------------------------ run

    async def start(self) -> None:
        """Describes the body; the agent's initial goals run at :meth:`run`."""
        await self.client.describe(self.description)

    async def run(self, until: Optional[asyncio.Event] = None) -> None:
        """Runs the reasoning cycle whenever something is perceived, until
        ``until`` is set or the session closes."""
        stop = until or asyncio.Event()
        events = asyncio.ensure_future(self._pump_events(stop))
        try:
            while not stop.is_set():
                while self.agent.step():
                    await asyncio.sleep(0)
                self._wake.clear()
                waiter = asyncio.ensure_future(self._wake.wait())
                stopper = asyncio.ensure_future(stop.wait())
                await asyncio.wait([waiter, stopper], return_when=asyncio.FIRST_COMPLETED)
                waiter.cancel()
                stopper.cancel()
        finally:
            events.cancel()
            for t in list(self._tasks):
                t.cancel()

    async def _pump_events(self, stop: asyncio.Event) -> None:
        from .client import Closed
        while True:
            ev = await self.client.next_event()
            if isinstance(ev, Binding):
                self._on_binding(ev)
            elif isinstance(ev, Closed):
                stop.set()
                return
            elif isinstance(ev, Signal) and ev.is_error:
                LOG.warning("error signal %s: %s", ev.type, ev.param("Message"))

    def beliefs(self, functor: str, arity: int) -> List[Tuple[Any, ...]]:
        """The current beliefs ``functor/arity``, as argument tuples."""
        return [tuple(b.args) for b in self.agent.beliefs[(functor, arity)]]

"""SPADE agents embodied through EVATAR (``pip install evatar[spade]``:
``spade``, ``spade-bdi``, ``spade-artifact``).

A SPADE agent is an XMPP client: it reasons and talks to other agents
there. EVATAR gives it a body: add a :class:`Body` (a SPADE behaviour) with
the body's BIL description, the pairing's endpoints and credential, and
the agent becomes a VA of that pairing. The body speaks protocol version 2
(``ha=True``): given every node's endpoint, a node's failure costs the
agent a delay, nothing else.

- :class:`Embodied` (a mixin, before SPADE's class) makes ``start()`` and
  ``stop()`` join and leave the pairing: ``start()`` raises what refused
  the join (:class:`~evatar.RefusedError` for a wrong credential,
  :class:`~evatar.ConnectError`), ``stop()`` says Bye. Without it a body
  joins when its behaviour starts and leaves when it is killed; closing
  it (:meth:`Body.close`) closes its connection.
- What EVATAR sends becomes percepts. For a plain agent (:class:`EmbodiedAgent`)
  each event is a call of ``on_percept(event)`` (the body's ``handler``,
  else the agent's method): a :class:`~evatar.Signal` (``SensorData``,
  ``Event``, an answer that came late), a :class:`~evatar.Binding` report,
  a :class:`~evatar.Reconnected`, the last :class:`~evatar.Closed`.
- Actions are requests: ``await body.act(component, service, params)``
  returns the Feedback, or raises :class:`~evatar.SignalError` (an Error
  answered), :class:`~evatar.FeedbackTimeout` (nobody answered: EVATAR's
  Timeout or the body's ``request_timeout``), :class:`~evatar.NotBoundError`
  (nothing provides it), :class:`~evatar.NotConsumedError` (the component
  does not consume it), :class:`~evatar.ClosedError`. :func:`reason` names
  each as a short code.

For spade-bdi agents (:class:`EmbodiedBDIAgent`) the percepts are beliefs
(annotated ``source(percept)``), the actions internal actions:

``reading(Component, Type, Params, Time)``
    the latest ``SensorData``/``Event`` to the VA's ``Component`` of
    service type ``Type`` (it replaces the previous one of that component
    and type); ``Params`` a list of ``p(Name, Value)`` (strings), ``Time``
    the signal's ``Timestamp`` (ms since 1970, simulated time for a
    simulated Avatar).
``bound(Component)``, ``unbound(Component, Service, Reason)``
    after each Binding report: the VA's components bound to a provider,
    and its ``Consumes`` entries left unbound (``NoProvider``,
    ``ParametersMismatch``).
``failed(Component, Service, Reason)``
    an ``.act`` failed: the intention that ran it stops there (python-
    agentspeak has no failure plans), and this event says why: an Error
    signal's type, ``Timeout``, ``NotBound``, ``NotConsumed``, ``Closed``.
``.act(Component, Service, Params, Feedback)``, ``.act(Component, Service, Params)``
    requests ``Service`` of the provider bound to ``Component`` and
    suspends the intention until the answer: Feedback unifies with the
    feedback's parameters and the plan goes on, or the action fails.
``.minute("HH:MM", M)``, ``.log(Term, ...)``
    as in :mod:`evatar.bdi`. spade-bdi's own ``.send`` sends XMPP messages.

The reasoning cycle of :class:`EmbodiedBDIAgent` sleeps while the agent
has nothing to do (spade-bdi's own polls without pause).

Emulators as artifacts (spade-artifact): :func:`emulator_artifacts` makes
an :class:`EmulatorArtifact` for each component of the body's description,
as the paper's sensor and actuator emulators are objects of the VA's
environment. Each is an XMPP entity of its own with a PubSub node; it
publishes its emulator's percepts as JSON (:func:`emulator_percept`:
``reading`` for a device's ``SensorData``/``Event``, ``binding`` for the
component's state in each Binding report, ``closed``) and takes requests
(ontology :data:`ONTOLOGY`), which it acts on through the body. An agent
class with the :class:`UsesEmulators` mixin (``class VA(UsesEmulators,
EmbodiedAgent)``; spade-artifact's ArtifactMixin) ``focus()``es on an
artifact, perceives its percepts as calls of ``on_emulator_percept(artifact,
percept)``, and ``use()``s it: the Feedback's parameters, or
:class:`ArtifactError` whose ``code`` is :func:`reason`'s. Any agent may
focus on and use an artifact, not only the body's own. A percept published
before an agent focused is not delivered to it (the PubSub service keeps
no last item for new subscribers); the artifact's latest readings are its
``get(type)``.

Not covered: emulator artifacts for spade-bdi agents (no ``.focus`` or
``.use`` internal action, and spade-bdi's cycle would take the artifacts'
answers as its messages), spade-artifact's ``link`` between artifacts and
its readers (CSV, SQL, MongoDB, HTTP), SPADE's presence and web interface,
an agent with several bodies in one pairing. With ``ha`` and no node
reachable, ``start()`` goes on trying for the client's ``reconnect_limit``
(600 s unless given).
"""

from __future__ import annotations

import asyncio
import inspect
import json
import logging
import uuid
from typing import Any, Callable, Dict, List, Optional, Sequence, Set, Tuple, Union

from spade.agent import Agent  # type: ignore[import-untyped]
from spade.behaviour import CyclicBehaviour  # type: ignore[import-untyped]
from spade.message import Message  # type: ignore[import-untyped]

from .bdi import minute_of, params_of, perceive, plist
from .bil import Binding, Description, ParamsLike, Signal, parse_frame
from .client import (Client, Closed, ClosedError, Endpoint, EvatarError, FeedbackTimeout,
                     SignalError)
from .emulators import ActuatorEmulator, NotBoundError, NotConsumedError

__all__ = ["Body", "Embodied", "EmbodiedAgent", "EmbodiedBDIAgent", "reason"]

LOG = logging.getLogger("evatar.spade")

Percept = Union[Signal, Binding, Any]
Handler = Callable[[Percept], Any]


def reason(error: BaseException) -> str:
    """The short code an agent acts on for a failed :meth:`Body.act`."""
    if isinstance(error, (SignalError, ArtifactError)):
        return error.code
    if isinstance(error, FeedbackTimeout):
        return "Timeout"
    if isinstance(error, NotBoundError):
        return "NotBound"
    if isinstance(error, NotConsumedError):
        return "NotConsumed"
    if isinstance(error, ClosedError):
        return "Closed"
    return type(error).__name__


class _Part(ActuatorEmulator):
    """A component of the body that consumes services: the SDK's actuator
    emulator, whose every other signal (Progress too) is a percept."""

    async def _on_signal(self, signal: Signal) -> None:
        self.client._event(signal)


class Body(CyclicBehaviour):  # type: ignore[misc]
    """The behaviour that embodies its agent as a VA described by
    ``description`` (a :class:`~evatar.Description`, its XML, or the path
    of a file) in ``pairing``. ``entity_id`` replaces the description's.
    ``handler(event)`` (a function or coroutine function) receives the
    percepts; by default the agent's ``on_percept``. Other keywords go to
    :class:`~evatar.Client` (``tls``, ``reconnect_limit``, ...)."""

    def __init__(self, description: Union[Description, bytes, str],
                 endpoints: Sequence[Endpoint], *, pairing: str, credential: str,
                 entity_id: Optional[str] = None, handler: Optional[Handler] = None,
                 ha: bool = True, request_timeout: float = 30.0, **client_options: Any) -> None:
        super().__init__()
        if isinstance(description, str):
            with open(description, "rb") as f:
                description = f.read()
        if isinstance(description, bytes):
            parsed = parse_frame(description)
            if not isinstance(parsed, Description):
                raise ValueError("not a BIL description: %s" % type(parsed).__name__)
            description = parsed
        if entity_id is not None:
            description.entity_id = entity_id
        self.description = description
        self.endpoints = list(endpoints)
        self.pairing, self.credential = pairing, credential
        self.handler = handler
        self.ha = ha
        self.request_timeout = request_timeout
        self.client_options = client_options
        self.client: Optional[Client] = None
        self._parts: Dict[str, _Part] = {}
        self._joined: "Optional[asyncio.Future[None]]" = None
        #: Component -> its EmulatorArtifacts' watchers (told before the handler).
        self._watchers: Dict[str, List[Callable[[Percept], None]]] = {}

    # ------------------------------------------------------------ lifecycle

    def _joined_future(self) -> "asyncio.Future[None]":
        if self._joined is None:
            self._joined = asyncio.get_running_loop().create_future()
        return self._joined

    async def on_start(self) -> None:
        joined = self._joined_future()
        d = self.description
        try:
            self.client = Client(self.endpoints, pairing=self.pairing, role="agent",
                                 entity_id=d.entity_id, credential=self.credential, ha=self.ha,
                                 **self.client_options)
            self._parts = {c.id: _Part(self.client, c.id, c.consumes)
                           for c in d.components if c.consumes}
            await self.client.connect()
            await self.client.describe(d)
        except (EvatarError, OSError) as e:
            LOG.warning("%s could not join %s: %s", d.entity_id, self.pairing, e)
            if not joined.done():
                joined.set_exception(e)
                joined.exception()  # retrieved: a plain agent may never ask
            self.kill(exit_code=e)
            return
        if not joined.done():
            joined.set_result(None)

    async def joined(self) -> None:
        """Returns once the body has joined and described itself; raises
        what prevented it."""
        await asyncio.shield(self._joined_future())

    async def run(self) -> None:
        if self.client is None or self.client.closed is not None and self._drained():
            self.kill()
            return
        try:
            ev = await self.client.next_event()
        except ClosedError:
            self.kill()
            return
        await self._perceive(ev)
        if isinstance(ev, Closed):
            self.kill()

    def match(self, message: Any) -> bool:
        """The body reads EVATAR, never an XMPP message: none waits in its mailbox."""
        return False

    def kill(self, exit_code: Optional[Any] = None) -> None:
        """Stops the behaviour; a body still joined leaves the pairing (so
        a plain ``Agent.stop()``, which kills its behaviours, leaves too)."""
        super().kill(exit_code)
        c = self.client
        if c is not None and c.closed is None:
            asyncio.ensure_future(c.close())

    def _drained(self) -> bool:
        return self.client is not None and self.client._closed_delivered

    async def on_end(self) -> None:
        await self.close()

    async def close(self) -> None:
        """Leaves the pairing (Bye) and closes the connection; afterwards
        actions raise :class:`~evatar.ClosedError`. Any number of times."""
        joined = self._joined_future()
        if not joined.done():
            joined.set_exception(ClosedError("the body was closed before it joined"))
            joined.exception()  # retrieved: nobody may be waiting
        if self.client is not None:
            await self.client.close()
        if not self.is_killed():
            self.kill()

    # ------------------------------------------------------------- percepts

    def _watch(self, component: str, watcher: Callable[[Percept], None]) -> None:
        """Tells ``watcher`` every signal addressed to ``component`` and
        every Binding, Reconnected and Closed event, before the handler."""
        self._watchers.setdefault(component, []).append(watcher)

    def _unwatch(self, component: str, watcher: Callable[[Percept], None]) -> None:
        ws = self._watchers.get(component, [])
        if watcher in ws:
            ws.remove(watcher)

    async def _perceive(self, ev: Percept) -> None:
        if isinstance(ev, Signal):
            watchers = list(self._watchers.get(ev.receiver, ()))
        else:
            watchers = [w for ws in self._watchers.values() for w in ws]
        for w in watchers:
            w(ev)
        handler = self.handler or getattr(self.agent, "on_percept", None)
        if handler is None:
            return
        try:
            r = handler(ev)
            if inspect.isawaitable(r):
                await r
        except Exception:  # the agent's bug must not cost it its body
            LOG.exception("the percept handler of %s failed on %r", self.description.entity_id, ev)

    # -------------------------------------------------------------- actions

    def _part(self, component: str, service: str) -> _Part:
        if self.client is None or self.client.closed is not None:
            raise ClosedError(self.client.closed.reason if self.client and self.client.closed
                              else "the body has not joined")
        part = self._parts.get(component)
        if part is None:
            raise NotConsumedError(component, service, [])
        return part

    async def act(self, component: str, service: str, parameters: ParamsLike = None,
                  timeout: Optional[float] = None) -> Signal:
        """Requests ``service`` from the provider bound to the VA's
        ``component`` and returns its Feedback (errors: see the module).
        Before the body has joined it waits for the join."""
        await self.joined()
        fb = await self._part(component, service).act(
            service, parameters, self.request_timeout if timeout is None else timeout)
        if fb.is_evatar_timeout:
            raise FeedbackTimeout("%s: the device did not answer %s in time (EVATAR's Timeout)"
                                  % (component, service))
        return fb

    async def tell(self, component: str, service: str, parameters: ParamsLike = None) -> Signal:
        """Sends ``service`` as a Request expecting no answer; returns it as sent."""
        await self.joined()
        part = self._part(component, service)
        entry = next((e for e in part.consumes if e.type == service), None)
        if entry is None:
            raise NotConsumedError(component, service, [e.type for e in part.consumes])
        assert self.client is not None
        return await self.client.send(sender=component, receiver=part.provider_of(service),
                                      category=entry.category, type=service,
                                      parameters=parameters)

    @property
    def binding(self) -> Optional[Binding]:
        """The latest Binding report, or None."""
        return self.client.binding if self.client is not None else None

    def bound(self) -> List[str]:
        """The VA's components bound to a provider now."""
        b = self.binding
        me = self.description.entity_id
        return sorted({r.consumer_component for r in b.bound if r.consumer_entity == me}
                      if b is not None else set())

    async def wait_bound(self, components: Optional[Sequence[str]] = None,
                         timeout: float = 30.0) -> Binding:
        """Waits until every component named (default: every one that
        consumes a service) is bound."""
        await self.joined()
        assert self.client is not None
        want = list(components) if components is not None else list(self._parts)
        return await self.client.wait_binding(lambda b: all(c in self.bound() for c in want),
                                              timeout)


class Embodied:
    """Mixin for a SPADE agent class (``class A(Embodied, Agent)``):
    :meth:`embody` adds a body; ``start()`` returns once every body joined
    (or raises what refused it, after stopping the agent), ``stop()``
    leaves the pairings first."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        # SPADE's first agent makes its container, which installs uvloop's
        # event loop policy for the whole process; an agent made inside a
        # running loop keeps that loop, and later loops stay the program's.
        policy = asyncio.get_event_loop_policy()
        super().__init__(*args, **kwargs)
        asyncio.set_event_loop_policy(policy)

    def embody(self, body: Body) -> Body:
        bodies = self.__dict__.setdefault("_bodies", [])
        bodies.append(body)
        self.add_behaviour(body)  # type: ignore[attr-defined]
        return body

    @property
    def bodies(self) -> List[Body]:
        return list(self.__dict__.get("_bodies", []))

    @property
    def body(self) -> Body:
        """The first body."""
        return self.bodies[0]

    async def start(self, auto_register: bool = True) -> None:
        await super().start(auto_register=auto_register)  # type: ignore[misc]
        try:
            for b in self.bodies:
                await b.joined()
        except BaseException:
            await self.stop()
            raise

    async def stop(self) -> None:
        for b in self.bodies:
            await b.close()
        await super().stop()  # type: ignore[misc]


class EmbodiedAgent(Embodied, Agent):  # type: ignore[misc]
    """A plain SPADE agent with a body: override ``on_percept(event)``."""

    async def on_percept(self, event: Percept) -> None:
        pass


def _bdi_classes() -> Any:
    import agentspeak as asp  # type: ignore[import-untyped]
    from spade_bdi.bdi import PERCEPT_TAG, BDIAgent  # type: ignore[import-untyped]
    from spade_bdi.bdi_behaviour import BDIBehaviour  # type: ignore[import-untyped]
    return asp, PERCEPT_TAG, BDIAgent, BDIBehaviour


try:
    _asp, _PERCEPT, _BDIAgent, _BDIBehaviour = _bdi_classes()
except ImportError:  # pragma: no cover - spade-bdi is optional for plain agents
    _BDIAgent = None


if _BDIAgent is not None:

    class _Suspended(_asp.runtime.Waiter):  # type: ignore[misc,name-defined]
        """Holds an intention until its request is answered; the answer's
        callback releases it (never the timer of ``.wait``)."""

        def poll(self, env: Any) -> bool:
            return False

    class _Cycle(_BDIBehaviour):  # type: ignore[misc,valid-type]
        """spade-bdi's reasoning cycle, asleep while nothing can run: woken
        by a message, a percept, an answer, or the next ``.wait`` deadline."""

        def __init__(self) -> None:
            super().__init__()
            self._wake: Optional[asyncio.Event] = None

        def wake(self) -> None:
            if self._wake is not None:
                self._wake.set()

        async def enqueue(self, message: Any) -> None:
            await self.queue.put(message)
            self.wake()

        def _idle(self) -> bool:
            a = self.agent
            if self.mailbox_size() or a.bdi_intention_buffer or not a.bdi_enabled:
                return False
            env = a.bdi_agent.env
            return not any(s and (s[-1].waiter is None or s[-1].waiter.poll(env))
                           for s in a.bdi_agent.intentions)

        async def run(self) -> None:
            if self._wake is None:
                self._wake = asyncio.Event()
            await super().run()
            if not self._idle():
                return
            self._wake.clear()
            deadline = self.agent.bdi_agent.shortest_deadline()
            timeout = None if deadline is None else max(
                0.0, deadline - self.agent.bdi_agent.env.time())
            try:
                await asyncio.wait_for(self._wake.wait(), timeout)
            except asyncio.TimeoutError:
                pass

    class EmbodiedBDIAgent(Embodied, _BDIAgent):  # type: ignore[misc,valid-type]
        """A spade-bdi agent with a body: its percepts are beliefs, its
        requests the internal action ``.act`` (see the module).
        ``log`` keeps what ``.log`` wrote."""

        def __init__(self, jid: str, password: str, asl: str, *args: Any, **kwargs: Any) -> None:
            self.log: List[str] = []
            self._bound: Set[str] = set()
            self._unbound: Set[Tuple[str, str, str]] = set()
            super().__init__(jid, password, asl, *args, **kwargs)

        def add_behaviour(self, behaviour: Any, template: Any = None) -> None:
            if type(behaviour) is _BDIBehaviour:
                behaviour = _Cycle()
            super().add_behaviour(behaviour, template)

        def _wake(self) -> None:
            if isinstance(self.bdi, _Cycle):
                self.bdi.wake()

        def believe(self, functor: str, args: Tuple[Any, ...], replace: int = 0) -> None:
            """Adds a percept belief (with its ``+`` event) and wakes the cycle."""
            perceive(_asp, self.bdi_agent, functor, args, replace, _PERCEPT)
            self._wake()

        def forget(self, functor: str, args: Tuple[Any, ...]) -> None:
            self.bdi_agent.beliefs[(functor, len(args))].discard(
                _asp.Literal(functor, args, _PERCEPT))

        async def on_percept(self, event: Percept) -> None:
            if isinstance(event, Signal):
                if event.context in ("SensorData", "Event") and not event.from_evatar:
                    self.believe("reading", (event.receiver, event.type,
                                             plist(_asp, event.body.parameters),
                                             event.timestamp), replace=2)
            elif isinstance(event, Binding):
                self._on_binding(event)

        def _on_binding(self, b: Binding) -> None:
            me = {body.description.entity_id for body in self.bodies}
            now = {r.consumer_component for r in b.bound if r.consumer_entity in me}
            for c in sorted(now - self._bound):
                self.believe("bound", (c,))
            for c in sorted(self._bound - now):
                self.forget("bound", (c,))
            self._bound = now
            unbound = {(u.consumer_component, u.type, u.reason) for u in b.unbound
                       if u.consumer_entity in me}
            for row in sorted(self._unbound - unbound):
                self.forget("unbound", row)
            for row in sorted(unbound - self._unbound):
                self.believe("unbound", row)
            self._unbound = unbound

        def add_custom_actions(self, actions: Any) -> None:
            agent = self

            def _act(asp_agent: Any, term: Any, intention: Any) -> Any:
                comp, service, params = (str(_asp.grounded(a, intention.scope))
                                         if i < 2 else _asp.grounded(a, intention.scope)
                                         for i, a in enumerate(term.args[:3]))
                wanted = term.args[3] if len(term.args) > 3 else None
                intention.waiter = _Suspended()
                task = asyncio.ensure_future(agent.body.act(comp, service,
                                                            params_of(_asp, params)))
                task.add_done_callback(
                    lambda t: agent._answered(t, asp_agent, intention, comp, service, wanted))
                yield

            def _minute(asp_agent: Any, term: Any, intention: Any) -> Any:
                minute = minute_of(str(_asp.grounded(term.args[0], intention.scope)))
                if minute is not None and _asp.unify(term.args[1], minute, intention.scope,
                                                     intention.stack):
                    yield

            def _log(asp_agent: Any, term: Any, intention: Any) -> Any:
                text = "".join(str(v) if isinstance(v, str) else _asp.asl_str(v)
                               for v in (_asp.grounded(a, intention.scope) for a in term.args))
                agent.log.append(text)
                LOG.info("%s: %s", agent.jid, text)
                yield

            actions.add(".act", 4)(_act)
            actions.add(".act", 3)(_act)
            actions.add(".minute", 2)(_minute)
            actions.add(".log")(_log)

        def _answered(self, task: "asyncio.Future[Signal]", asp_agent: Any, intention: Any,
                      comp: str, service: str, wanted: Any) -> None:
            why: Optional[str] = None
            if task.cancelled():
                why = "Closed"
            elif task.exception() is not None:
                e = task.exception()
                assert e is not None
                why = reason(e)
                LOG.info("%s: %s %s failed: %s", self.jid, comp, service, e)
            elif wanted is not None and not _asp.unify(
                    wanted, plist(_asp, task.result().body.parameters), intention.scope,
                    intention.stack):
                why = "FeedbackMismatch"
            if why is None:
                intention.waiter = None
            else:
                # python-agentspeak has no failure plans: the intention
                # ends here, as one without a handler does in Jason.
                for stack in [s for s in asp_agent.intentions if s and s[-1] is intention]:
                    asp_agent.intentions.remove(stack)
                self.believe("failed", (comp, service, why), replace=2)
            self._wake()


# ---------------------------------------------------------------- artifacts

#: The ``ontology`` of the requests an :class:`EmulatorArtifact` takes and
#: of its answers.
ONTOLOGY = "evatar-emulator"


class ArtifactError(EvatarError):
    """An :class:`EmulatorArtifact` answered ``failure``: ``code`` is what
    :func:`reason` would have named on the artifact's side (``NotBound``,
    ``Timeout``, an Error signal's type, ...), the message its text."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__("%s: %s" % (code, message))
        self.code = code


def emulator_percept(component: str, ev: Percept) -> Optional[Dict[str, Any]]:
    """What the artifact of ``component`` publishes for a body's event, or
    None: a reading for a ``SensorData``/``Event`` from a device, the
    component's binding state for a Binding report, ``closed`` at the end."""
    if isinstance(ev, Signal):
        if ev.context not in ("SensorData", "Event") or ev.from_evatar:
            return None
        return {"percept": "reading", "component": component, "context": ev.context,
                "type": ev.type, "sender": ev.sender, "parameters": dict(ev.body.parameters),
                "timestamp": ev.timestamp}
    if isinstance(ev, Binding):
        return {"percept": "binding", "component": component, "bound": ev.is_bound(component),
                "unbound": [{"type": u.type, "reason": u.reason} for u in ev.unbound
                            if u.consumer_component == component]}
    if isinstance(ev, Closed):
        return {"percept": "closed", "component": component}
    return None


try:
    from spade_artifact import Artifact as _Artifact  # type: ignore[import-untyped]
    from spade_artifact import ArtifactMixin as _ArtifactMixin  # type: ignore[import-untyped]
    from slixmpp import JID as _JID  # type: ignore[import-untyped]
except ImportError:  # pragma: no cover - spade-artifact is optional
    _Artifact = None


if _Artifact is not None:

    class EmulatorArtifact(_Artifact):  # type: ignore[misc,valid-type]
        """The emulator ``component`` of ``body``'s description as a
        spade-artifact artifact (an XMPP entity ``jid`` with a PubSub node
        named by its bare JID). Once started it publishes, as JSON text,
        every percept of its emulator (:func:`emulator_percept`: readings,
        its binding state, ``closed``) and takes requests: a message with
        ``ontology`` :data:`ONTOLOGY`, performative ``request`` and body
        ``{"service": S, "parameters": {...}}`` is acted on through the
        body (:meth:`Body.act`), answered ``inform`` with the Feedback's
        parameters or ``failure`` with ``{"reason": code, "error": text}``,
        in the request's thread. :meth:`UsesEmulators.use` sends one."""

        def __init__(self, jid: str, password: str, body: Body, component: str, *,
                     port: int = 5222, pubsub_server: Optional[str] = None,
                     verify_security: bool = False) -> None:
            if not any(c.id == component for c in body.description.components):
                raise ValueError("%s is not a component of %s" % (
                    component, body.description.entity_id))
            policy = asyncio.get_event_loop_policy()  # as Embodied: keep the program's loops
            super().__init__(jid, password, pubsub_server=pubsub_server, port=port,
                             verify_security=verify_security)
            asyncio.set_event_loop_policy(policy)
            self.body = body
            self.component = component
            self._outbox: "asyncio.Queue[Optional[Dict[str, Any]]]" = asyncio.Queue()
            self._tasks: Set["asyncio.Task[None]"] = set()

        async def start(self, auto_register: bool = True) -> None:
            # spade-artifact runs run() on the loop of SPADE's container,
            # the first agent's: in a later loop it would never run.
            self.container.register(self)  # again after a stop()
            self.loop = asyncio.get_running_loop()
            await super().start(auto_register=auto_register)

        async def setup(self) -> None:
            self.body._watch(self.component, self._observe)
            if self.body.binding is not None:
                self._observe(self.body.binding)
            self._spawn(self._publisher())

        def _spawn(self, coro: Any) -> None:
            task = asyncio.ensure_future(coro)
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)

        def _observe(self, ev: Percept) -> None:
            p = emulator_percept(self.component, ev)
            if p is not None:
                if p["percept"] == "reading":
                    self.set(p["type"], p)
                self._outbox.put_nowait(p)

        async def _publisher(self) -> None:
            while True:
                p = await self._outbox.get()
                if p is None:
                    return
                await self.publish(json.dumps(p))

        def dispatch(self, msg: Any) -> List[Any]:
            """SPADE's container hands a message from an agent of this
            process here, not over XMPP."""
            self.queue.put_nowait(msg)
            return []

        async def run(self) -> None:
            while True:
                msg = await self.queue.get()
                if msg is None:
                    return
                if (msg.get_metadata("ontology") == ONTOLOGY
                        and msg.get_metadata("performative") == "request"):
                    self._spawn(self._act(msg))

        async def _act(self, msg: Any) -> None:
            reply = msg.make_reply()
            reply.set_metadata("ontology", ONTOLOGY)
            try:
                req = json.loads(msg.body or "")
                fb = await self.body.act(self.component, str(req["service"]),
                                         req.get("parameters") or None)
            except (EvatarError, OSError) as e:  # NotConsumedError is a ValueError too
                reply.set_metadata("performative", "failure")
                reply.body = json.dumps({"reason": reason(e), "error": str(e)})
            except (ValueError, KeyError, TypeError) as e:
                reply.set_metadata("performative", "not-understood")
                reply.body = json.dumps({"reason": "BadRequest", "error": str(e)})
            else:
                reply.set_metadata("performative", "inform")
                reply.body = json.dumps({"feedback": dict(fb.body.parameters)})
            await self.send(reply)

        async def stop(self) -> None:
            """Stops publishing and taking requests, leaves XMPP."""
            self.body._unwatch(self.component, self._observe)
            self._outbox.put_nowait(None)
            self.queue.put_nowait(None)
            for task in list(self._tasks):
                task.cancel()
            await asyncio.gather(*self._tasks, return_exceptions=True)
            self.container.unregister(str(self.jid))
            if self.presence:
                self.presence.set_unavailable()
            # spade-artifact's stop() clears the alive flag before it looks
            # at it, and so never disconnects.
            if self.client is not None and self.is_alive():
                await self.client.disconnect()
            self.kill()

    def emulator_artifacts(body: Body, host: str, password: str, *, port: int = 5222,
                           jid: Optional[Callable[[str], str]] = None,
                           **options: Any) -> List[EmulatorArtifact]:
        """An :class:`EmulatorArtifact` for each component (emulator) of
        ``body``'s description, not started; the JID of component C is
        ``jid(C)``, by default ``<entity>.<C>@host`` in lower case."""
        me = body.description.entity_id
        name = jid or (lambda c: ("%s.%s@%s" % (me, c, host)).lower())
        return [EmulatorArtifact(name(c.id), password, body, c.id, port=port, **options)
                for c in body.description.components]

    class _Answers(CyclicBehaviour):  # type: ignore[misc]
        """Takes the artifacts' answers to this agent's requests, by thread."""

        def __init__(self) -> None:
            super().__init__()
            self.pending: "Dict[str, asyncio.Future[Any]]" = {}
            self._stopped = asyncio.Event()

        def match(self, message: Any) -> bool:
            return (message.get_metadata("ontology") == ONTOLOGY
                    and message.thread in self.pending)

        async def enqueue(self, message: Any) -> None:
            f = self.pending.pop(message.thread, None)
            if f is not None and not f.done():
                f.set_result(message)

        async def run(self) -> None:
            await self._stopped.wait()

        def kill(self, exit_code: Optional[Any] = None) -> None:
            super().kill(exit_code)
            self._stopped.set()
            for f in self.pending.values():
                if not f.done():
                    f.set_exception(ClosedError("the agent stopped"))
            self.pending.clear()

    class UsesEmulators(_ArtifactMixin):  # type: ignore[misc,valid-type]
        """Mixin for a SPADE agent class (``class A(UsesEmulators,
        EmbodiedAgent)``): :meth:`focus` on an :class:`EmulatorArtifact`
        makes its percepts calls of ``on_emulator_percept(artifact,
        percept)`` (a dict, :func:`emulator_percept`), :meth:`use` acts
        through it."""

        async def _hook_plugin_after_connection(self, *args: Any, **kwargs: Any) -> None:
            await super()._hook_plugin_after_connection(*args, **kwargs)
            answers = self.__dict__.get("_answers")
            if answers is None or answers.is_killed():
                answers = self.__dict__["_answers"] = _Answers()
                self.add_behaviour(answers)  # type: ignore[attr-defined]

        def _message_received(self, msg: Any) -> Any:
            # A PubSub notification is the artifact's percept, taken by
            # spade-artifact's handler; no behaviour is to read it.
            if msg.xml.find("{http://jabber.org/protocol/pubsub#event}event") is not None:
                return []
            return super()._message_received(msg)  # type: ignore[misc]

        async def focus(self, artifact: str, handler: Optional[Callable[[str, Dict[str, Any]], Any]]
                        = None) -> None:
            """Subscribes to the artifact ``artifact`` (its JID); each of its
            percepts is then a call of ``handler(artifact, percept)``
            (function or coroutine function), by default
            ``on_emulator_percept``. Raises :class:`ArtifactError`
            (``NotFocused``) when the PubSub service refuses."""
            node = str(_bare(artifact))
            call = handler or self.on_emulator_percept

            def received(_publisher: Any, text: str) -> None:
                try:
                    r = call(node, json.loads(text))
                    if inspect.isawaitable(r):
                        asyncio.ensure_future(r)
                except Exception:  # the agent's bug must not cost it its artifacts
                    LOG.exception("the percept handler of %s failed on %r", self.jid, text)
            # spade-artifact's own focus() says nothing when the PubSub
            # service refuses: the agent would wait for percepts that never come.
            self.artifacts.focus_callbacks[node] = received  # type: ignore[attr-defined]
            if await self.pubsub.subscribe(self.pubsub_server, node) is None:  # type: ignore[attr-defined]
                del self.artifacts.focus_callbacks[node]  # type: ignore[attr-defined]
                raise ArtifactError("NotFocused", "%s: the PubSub service %s refused the "
                                    "subscription (is the artifact started?)"
                                    % (node, self.pubsub_server))  # type: ignore[attr-defined]

        async def ignore(self, artifact: str) -> None:
            """Unsubscribes from the artifact."""
            await self.artifacts.ignore(str(_bare(artifact)))  # type: ignore[attr-defined]

        def on_emulator_percept(self, artifact: str, percept: Dict[str, Any]) -> Any:
            pass

        async def use(self, artifact: str, service: str, parameters: Optional[Dict[str, str]]
                      = None, timeout: float = 30.0) -> Dict[str, str]:
            """Asks the artifact to request ``service`` of its emulator's
            provider; returns the Feedback's parameters, or raises
            :class:`ArtifactError` (``code``: ``NotBound``, ``Timeout``,
            ``NotConsumed``, an Error's type, ``BadRequest``),
            :class:`~evatar.FeedbackTimeout` when no answer comes within
            ``timeout`` seconds, :class:`~evatar.ClosedError` once the
            agent stopped."""
            answers = self.__dict__.get("_answers")
            if answers is None or answers.is_killed():
                raise ClosedError("the agent is not started")
            msg = Message(to=str(_bare(artifact)), thread=uuid.uuid4().hex,
                           body=json.dumps({"service": service,
                                            "parameters": dict(parameters or {})}),
                           metadata={"performative": "request", "ontology": ONTOLOGY})
            answer = answers.pending[msg.thread] = asyncio.get_running_loop().create_future()
            try:
                await answers.send(msg)
                reply = await asyncio.wait_for(answer, timeout)
            except asyncio.TimeoutError:
                raise FeedbackTimeout("%s did not answer %s within %s s"
                                      % (artifact, service, timeout)) from None
            finally:
                answers.pending.pop(msg.thread, None)
            body = json.loads(reply.body or "{}")
            if reply.get_metadata("performative") != "inform":
                raise ArtifactError(body.get("reason", "Failure"), body.get("error", ""))
            return dict(body.get("feedback", {}))

    def _bare(jid: str) -> Any:
        return _JID(jid).bare

    __all__ += ["ONTOLOGY", "ArtifactError", "EmulatorArtifact", "UsesEmulators",
                "emulator_artifacts", "emulator_percept"]

"""SPADE agents embodied through EVATAR (``pip install evatar[spade]``:
``spade``, ``spade-bdi``).

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

Not covered: spade-artifact (an emulator as an artifact), SPADE's
presence and web interface, an agent with several bodies in one pairing.
With ``ha`` and no node reachable, ``start()`` goes on trying for the
client's ``reconnect_limit`` (600 s unless given).
"""

from __future__ import annotations

import asyncio
import inspect
import logging
from typing import Any, Callable, Dict, List, Optional, Sequence, Set, Tuple, Union

from spade.agent import Agent  # type: ignore[import-untyped]
from spade.behaviour import CyclicBehaviour  # type: ignore[import-untyped]

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
    if isinstance(error, SignalError):
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

    async def _perceive(self, ev: Percept) -> None:
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

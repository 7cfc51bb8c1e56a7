"""Sensor and actuator emulators (paper, section 2.2) and their Avatar-side
counterparts.

In a VA, an **actuator emulator** is the object the agent's virtual actuator
talks to: it consumes the Avatar's actuator service (it sends the requests)
and provides the ``ACTION FEEDBACK`` service the device answers through. A
**sensor emulator** provides the ``SENSOR`` service a physical sensor feeds
and passes the readings to the agent.

In an Avatar, an :class:`Actuator` provides actuator services and answers
requests with Feedback; a :class:`Sensor` consumes a VA's sensor service and
sends it ``SensorData``.

Each object knows its own BIL component (:meth:`Emulator.component`), so a
body is described with :func:`describe`. Receivers are found in the latest
Binding report, so a program never names the other side's components.
"""

from __future__ import annotations

import asyncio
import inspect
from typing import Any, Awaitable, Callable, List, Optional, Sequence, Union

from .bil import Component, Description, Entry, ParamsLike, Signal
from .client import Client, ClosedError, EvatarError

__all__ = ["Emulator", "ActuatorEmulator", "SensorEmulator", "Actuator", "Sensor", "describe",
           "NotBoundError", "NotConsumedError"]


class NotBoundError(EvatarError):
    """The component has no provider bound for that service (yet).
    ``component`` is the emulator, ``service`` the ServiceType, ``reason``
    the Binding report's reason for it: ``NoProvider``,
    ``ParametersMismatch``, or ``None`` when no report has arrived yet or
    the report has no row for it. The message says what to check;
    ``client.binding.unbound_for(client.entity_id)`` lists every entry of
    yours that stayed unbound."""

    def __init__(self, component: str, service: str, reason: Optional[str],
                 has_report: bool = True) -> None:
        if not has_report:
            why = ("no Binding report has arrived yet: describe the body, then wait for one "
                   "(client.wait_binding)")
        elif reason == "ParametersMismatch":
            why = ("ParametersMismatch: a component provides %s, but not with the parameters "
                   "this Consumes entry asks for (docs/bil.md section 4: each of your values "
                   "must be no, yes where the service has yes, or the service's value); "
                   "compare them with the device's Service entry (docs/avatars.md section 7)"
                   % service)
        elif reason == "NoProvider":
            why = ("NoProvider: no component of the other side provides this category and "
                   "type (is it joined and described? is the ServiceType spelt as the "
                   "device's?)")
        else:
            why = ("the latest Binding report has no row for it (the provider left, or the "
                   "description changed): wait for the next report")
        super().__init__("%s has no provider for %s: %s; see client.binding.unbound"
                         % (component, service, why))
        self.component = component
        self.service = service
        self.reason = reason


class NotConsumedError(EvatarError, ValueError):
    """:meth:`ActuatorEmulator.act` was asked for a service the emulator
    does not consume (its description has no such ``Consumes`` entry, so
    EVATAR could never bind it). ``component`` is the emulator,
    ``service`` the ServiceType asked for, ``consumed`` the ServiceTypes
    it does consume. Nothing was sent."""

    def __init__(self, component: str, service: str, consumed: List[str]) -> None:
        super().__init__("%s does not consume %s; it consumes %s" % (
            component, service, ", ".join(consumed) if consumed else "nothing"))
        self.component = component
        self.service = service
        self.consumed = consumed


class Emulator:
    """A component of this entity's body bound to a client."""

    def __init__(self, client: Client, component_id: str, services: Sequence[Entry],
                 consumes: Sequence[Entry] = ()) -> None:
        self.client = client
        self.id = component_id
        self.services = list(services)
        self.consumes = list(consumes)
        client.on(component_id, self._on_signal)

    def component(self) -> Component:
        return Component(self.id, list(self.services), list(self.consumes))

    def provider_of(self, type: str, category: Optional[str] = None) -> str:
        """The component bound to provide what this one consumes as ``type``."""
        b = self.client.binding
        if b is not None:
            for row in b.bound:
                if (row.consumer_entity == self.client.entity_id and row.consumer_component == self.id
                        and row.type == type and (category is None or row.category == category)):
                    return row.provider_component
            reason = next((u.reason for u in b.unbound_for(self.client.entity_id, self.id)
                           if u.type == type and (category is None or u.category == category)),
                          None)
            raise NotBoundError(self.id, type, reason)
        raise NotBoundError(self.id, type, None, has_report=False)

    def is_bound(self, type: str) -> bool:
        try:
            self.provider_of(type)
            return True
        except NotBoundError:
            return False

    async def _on_signal(self, signal: Signal) -> None:
        pass


class ActuatorEmulator(Emulator):
    """A VA's actuator emulator. ``actions`` are the Avatar services it
    consumes (e.g. ``Entry("ACTUATOR", "TurnLightOn", {"Light": "yes",
    "Room": "kitchen"})``); ``feedback`` the parameters of the ``ACTION
    FEEDBACK`` service it provides (default ``{"Feedback": "yes"}``).

    The answers to :meth:`act` (Feedback, Progress, Error) reach the
    emulator through the row binding its action to the device, whatever
    ``feedback`` says. Give ``feedback`` the parameters of the device's
    ``ACTION FEEDBACK`` Consumes entry (docs/avatars.md section 7, e.g.
    ``{"Feedback": "yes", "Device": "SocketSwitch", "Room": "bedroom"}``)
    so that entry is bound too: it then leaves the Binding report's
    ``unbound`` rows, and signals the device sends on its own to its
    feedback consumer reach this emulator. ``feedback_category`` is that
    service's category: ``BEHAVIOUR`` for the LEGO robots' behaviours.

    The emulator keeps the Progress signals of its requests (the queue
    ``progress``); every other signal addressed to it that does not answer
    a pending :meth:`act` comes back on :meth:`Client.next_event`: a
    device's ``DeviceDisconnected``/``DeviceReconnected`` events (an
    MQTT Avatar sends them when a device's availability changes), other
    Events the device sends, an answer arriving after :meth:`act` gave
    up."""

    def __init__(self, client: Client, component_id: str, actions: Sequence[Entry],
                 feedback: ParamsLike = None, feedback_category: str = "ACTUATOR") -> None:
        params = feedback if feedback is not None else {"Feedback": "yes"}
        super().__init__(client, component_id,
                         [Entry(feedback_category, "ACTION FEEDBACK", params)], actions)
        self.progress: "asyncio.Queue[Signal]" = asyncio.Queue()

    async def act(self, type: str, parameters: ParamsLike = None,
                  timeout: float = 10.0) -> Signal:
        """Requests the action ``type`` of the bound Avatar actuator and
        returns its feedback (see :meth:`Client.request`). Raises
        :class:`NotConsumedError` for a ``type`` this emulator does not
        consume and :class:`NotBoundError` while nothing provides it."""
        entry = next((e for e in self.consumes if e.type == type), None)
        if entry is None:
            raise NotConsumedError(self.id, type, [e.type for e in self.consumes])
        return await self.client.request(sender=self.id, receiver=self.provider_of(type),
                                         category=entry.category, type=type,
                                         parameters=parameters, timeout=timeout)

    async def _on_signal(self, signal: Signal) -> None:
        if signal.context == "Progress":
            self.progress.put_nowait(signal)
        else:
            self.client._event(signal)


Listener = Callable[[Signal], Union[None, Awaitable[None]]]


class SensorEmulator(Emulator):
    """A VA's sensor emulator: provides ``category``/``type`` (``SENSOR``
    unless ``category`` says otherwise; with ``parameters``, e.g. the room)
    and keeps what the bound sensor sends
    (``SensorData`` and ``Event`` signals): each reading goes to
    ``listener`` if one is given, else to the queue read by :meth:`reading`.
    ``reads`` are the Avatar services it consumes, if any. A reading is a
    :class:`~evatar.bil.Signal`: ``param(name)``, ``sender`` (the device's
    ComponentID), ``timestamp`` (the device's time, ms since 1970 UTC:
    simulated time for avatar_sim), ``context`` (``SensorData`` or
    ``Event``), ``type``."""

    def __init__(self, client: Client, component_id: str, type: str,
                 parameters: ParamsLike = None,
                 reads: Sequence[Entry] = (), listener: Optional[Listener] = None,
                 category: str = "SENSOR") -> None:
        super().__init__(client, component_id, [Entry(category, type, parameters or [])], reads)
        self.readings: "asyncio.Queue[Signal]" = asyncio.Queue()
        self.latest: Optional[Signal] = None
        self.listener = listener

    async def reading(self, timeout: Optional[float] = None) -> Signal:
        """The next reading. Raises asyncio.TimeoutError after ``timeout``
        seconds, and :class:`~evatar.ClosedError` once the session has ended
        and every reading has been taken."""
        get = asyncio.ensure_future(self.readings.get())
        closed = asyncio.ensure_future(self.client.wait_closed())
        try:
            await asyncio.wait([get, closed], timeout=timeout,
                               return_when=asyncio.FIRST_COMPLETED)
        except BaseException:
            get.cancel()
            raise
        finally:
            closed.cancel()
        if get.done() and not get.cancelled():
            return get.result()
        get.cancel()
        if self.client.closed is not None:
            if not self.readings.empty():
                return self.readings.get_nowait()
            raise ClosedError(self.client.closed.reason if self.client.closed else "closed")
        raise asyncio.TimeoutError("no reading within %s s" % timeout)

    async def _on_signal(self, signal: Signal) -> None:
        # EVATAR's own events (RequestClosed, docs/protocol.md 4.3) are not readings.
        if signal.context not in ("SensorData", "Event") or signal.from_evatar:
            return
        self.latest = signal
        if self.listener is not None:
            r = self.listener(signal)
            if inspect.isawaitable(r):
                await r
        else:
            self.readings.put_nowait(signal)


Action = Callable[[Signal], Union[ParamsLike, Awaitable[ParamsLike]]]


class Actuator(Emulator):
    """An Avatar actuator: provides ``services`` and answers each request
    with Feedback carrying what ``action(request)`` returns (parameters). If
    ``action`` raises, the Feedback carries ``Done=no`` and ``Message``."""

    def __init__(self, client: Client, component_id: str, services: Sequence[Entry],
                 action: Action, feedback: ParamsLike = None) -> None:
        super().__init__(client, component_id, services,
                         [Entry("ACTUATOR", "ACTION FEEDBACK",
                                feedback if feedback is not None else {"Feedback": "yes"})])
        self.action = action
        self.handled = 0

    async def _on_signal(self, signal: Signal) -> None:
        if signal.context not in ("RequestAwaitingFeedback", "Request"):
            return
        try:
            r: Any = self.action(signal)
            if inspect.isawaitable(r):
                r = await r
            params = r if r is not None else {"Done": "yes"}
        except Exception as e:  # reported to the requester, not raised here
            params = {"Done": "no", "Message": str(e)}
        self.handled += 1
        if signal.context == "RequestAwaitingFeedback":
            await self.client.reply(signal, parameters=params)


class Sensor(Emulator):
    """An Avatar sensor: consumes the VA's ``SENSOR``/``type`` service
    (``parameters`` say which, e.g. the room) and sends it readings."""

    def __init__(self, client: Client, component_id: str, type: str,
                 parameters: ParamsLike = None,
                 services: Sequence[Entry] = ()) -> None:
        provided = list(services) or [Entry("SENSOR", "Read" + type, {"Value": "yes"})]
        super().__init__(client, component_id, provided,
                         [Entry("SENSOR", type, parameters or [])])
        self.type = type

    async def emit(self, parameters: ParamsLike = None) -> Signal:
        """Sends one reading to the bound sensor emulator."""
        return await self.client.send(sender=self.id, receiver=self.provider_of(self.type, "SENSOR"),
                                      context="SensorData", category="SENSOR", type=self.type,
                                      parameters=parameters)


async def describe(client: Client, emulators: Sequence[Emulator], api_name: str = "",
                   context: str = "") -> Description:
    """Describes the client's body made of ``emulators`` and sends it."""
    d = Description(entity_id=client.entity_id,
                    entity_type="Agent" if client.role == "agent" else "Avatar",
                    components=[e.component() for e in emulators],
                    api_name=api_name, context=context)
    await client.describe(d)
    return d


def components(emulators: List[Emulator]) -> List[Component]:
    return [e.component() for e in emulators]

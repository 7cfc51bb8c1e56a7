"""The asyncio client of the EVATAR wire protocol (docs/protocol.md).

A :class:`Client` joins one pairing as a VA (``role="agent"``) or as an
Avatar (``role="avatar"``) over TCP, over TLS (``tls=Tls(...)``, see
:mod:`evatar.tls`), or over its own stdin/stdout when EVATAR's port
connector started the program (endpoint ``"stdio"``).

With ``ha=True`` it speaks protocol version 2 (section 11): it keeps every
signal until EVATAR acknowledges it, acknowledges what it receives, and when
the connection goes (closed, a Refused meaning "try elsewhere", a silent
server) it reconnects through its endpoints, starting with the next one,
resumes the session, sends again what was not acknowledged and passes
nothing twice to the application.

What EVATAR sends arrives as events on :meth:`Client.next_event`:
:class:`~evatar.bil.Signal`, :class:`~evatar.bil.Binding`,
:class:`Reconnected` and, last, :class:`Closed` (once: afterwards
:meth:`Client.next_event` raises :class:`ClosedError`). Signals addressed to
a component that has a handler (:meth:`Client.on`, used by the emulators) go
to the handler instead, except Error signals, which are always events
(unless they answer a :meth:`Client.request`). An
:class:`~evatar.ActuatorEmulator` keeps only the Progress signals of its
requests: what else reaches it (a device's ``DeviceDisconnected`` and
``DeviceReconnected`` events, an answer that came after ``act`` gave up)
comes back as events.
"""

from __future__ import annotations

import asyncio
import inspect
import logging
import os
import secrets
import sys
import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import (Any, Awaitable, Callable, Dict, List, Optional, Sequence, Tuple, Union)

from . import bil
from .bil import (Ack, Binding, Bye, Description, Entry, GetBinding, Hello, Refused, Resume,
                  Signal, Welcome, encode, parse_frame)
from .frame import MAX_FRAME, FrameError, check_length, encode_frame
from .tls import Tls
from .xml import BilError

__all__ = ["Client", "Endpoint", "Closed", "Reconnected", "EvatarError", "ConnectError",
           "RefusedError", "ClosedError", "FeedbackTimeout", "SignalError", "AlreadyConnectedError",
           "AckTimeout", "STDIO", "CLOSE_TIMEOUT"]

#: The endpoint naming the program's own stdin/stdout (port connector).
STDIO = "stdio"
Endpoint = Union[Tuple[str, int], str]
Handler = Callable[[Signal], Union[None, Awaitable[None]]]
Event = Union[Signal, Binding, "Reconnected", "Closed"]

#: Refusals after which a version 2 client tries the next endpoint (section 11.3).
RETRY_CODES = frozenset(["NotActive", "Fenced", "StaleEpoch", "PairingDown", "UnknownPairing",
                         "HandshakeTimeout", "SilentLink", "SessionResumed", "Busy",
                         "TooManyConnections", "RateLimited"])
LOG = logging.getLogger("evatar.client")
ACK_DELAY = 0.005
ACK_EVERY = 32
#: Seconds :meth:`Client.close` waits for EVATAR's Bye by default.
CLOSE_TIMEOUT = 5.0
#: How many accepted SignalIDs :meth:`Client.accepted` remembers.
ACCEPTED_MEMORY = 4096


class EvatarError(Exception):
    """Base of the errors this package raises."""


class ConnectError(EvatarError):
    """No endpoint could be joined; ``failures`` says what happened at each."""

    def __init__(self, failures: List[Tuple[Endpoint, str]]) -> None:
        super().__init__("unreachable: " + "; ".join("%s: %s" % (e, w) for e, w in failures))
        self.failures = failures


class RefusedError(EvatarError):
    """EVATAR refused the handshake (docs/protocol.md section 6)."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__("%s: %s" % (code, message))
        self.code = code
        self.message = message


class ClosedError(EvatarError):
    """The client is closed; ``reason`` says why."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


class FeedbackTimeout(EvatarError):
    """No answer to a request within the caller's timeout."""


class AlreadyConnectedError(EvatarError):
    """:meth:`Client.connect` was called on a client that is connected or
    connecting; a client holds one session. Make another client for a
    second one."""


class AckTimeout(EvatarError):
    """EVATAR did not accept a signal within the caller's timeout (it may
    still accept it later; with ``ha`` the client keeps sending it)."""


class SignalError(EvatarError):
    """An Error signal answered a request; ``signal`` is it."""

    def __init__(self, signal: Signal) -> None:
        super().__init__("%s: %s" % (signal.type, signal.param("Message", "")))
        self.signal = signal
        self.code = signal.type


@dataclass
class Reconnected:
    """The connection was replaced (version 2)."""

    endpoint: Endpoint
    resumed: bool
    epoch: int
    session_id: str
    reason: str


@dataclass
class Closed:
    """The last event: the session is over (delivered once; then
    :meth:`Client.next_event` raises :class:`ClosedError`). After
    :meth:`Client.close`, ``confirmed`` says whether EVATAR's Bye came
    (EVATAR had unregistered the entity) before the close returned: the
    event is delivered, and :meth:`Client.wait_closed` returns, only once
    that is known."""

    reason: str
    refused: Optional[Refused] = None
    confirmed: bool = False


class _Link:
    """One connection: a reader of frames and a writer."""

    def __init__(self, endpoint: Endpoint, reader: asyncio.StreamReader,
                 writer: asyncio.StreamWriter) -> None:
        self.endpoint = endpoint
        self.reader = reader
        self.writer = writer
        self.max_in = MAX_FRAME
        self.silent = False

    async def read(self) -> bytes:
        head = await self.reader.readexactly(4)
        n = int.from_bytes(head, "big")
        check_length(n, self.max_in)
        return await self.reader.readexactly(n)

    def write(self, document: bytes) -> None:
        if not self.writer.is_closing():
            self.writer.write(encode_frame(document))

    def abort(self) -> None:
        transport = self.writer.transport
        if isinstance(transport, asyncio.Transport) or hasattr(transport, "abort"):
            try:
                transport.abort()
                return
            except Exception:
                pass
        self.writer.close()


_stdio_used = False


async def _open_stdio() -> Tuple[asyncio.StreamReader, asyncio.StreamWriter]:
    """Frames on the program's stdin/stdout. Whatever the program prints
    afterwards goes to stderr, so it cannot corrupt the frames."""
    global _stdio_used
    if _stdio_used:
        raise OSError("stdin/stdout can carry only one session")
    _stdio_used = True
    loop = asyncio.get_running_loop()
    out_fd = os.dup(1)
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    reader = asyncio.StreamReader(limit=2 ** 22)
    await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader),
                                 os.fdopen(os.dup(0), "rb", buffering=0))
    transport, protocol = await loop.connect_write_pipe(
        lambda: asyncio.streams.FlowControlMixin(), os.fdopen(out_fd, "wb", buffering=0))
    writer = asyncio.StreamWriter(transport, protocol, None, loop)
    return reader, writer


class Client:
    """A client of EVATAR. Create it inside a coroutine (it makes asyncio
    queues and events, which Python before 3.10 binds to the current loop),
    then ``await client.connect()``. Events accumulate until read: a program
    that uses only emulators and handlers may leave Binding events unread,
    but should read them now and then in a long run.

    :param endpoints: ``[("127.0.0.1", 7400), ...]`` (one per node for high
        availability) or ``["stdio"]`` when started by the port connector.
    :param pairing: the pairing id; ``role`` ``"agent"`` or ``"avatar"``;
        ``entity_id`` this entity's id; ``credential`` the pairing's secret.
    :param ha: speak protocol version 2 (reconnect, resume, nothing lost).
    :param tls: connect with TLS (:class:`evatar.tls.Tls`); default plain TCP.
    :param reconnect_backoff: seconds, (min, max) pause after a full round.
    :param reconnect_limit: seconds without a session before giving up
        (default 600: longer than a machine's reboot).
    """

    def __init__(self, endpoints: Sequence[Endpoint], *, pairing: str, role: str,
                 entity_id: str, credential: str = "", ha: bool = False,
                 connect_timeout: float = 5.0, handshake_timeout: float = 5.0,
                 reconnect_backoff: Tuple[float, float] = (0.02, 0.5),
                 reconnect_limit: float = 600.0, max_frame: int = MAX_FRAME,
                 tls: Optional[Tls] = None) -> None:
        if role not in ("agent", "avatar"):
            raise ValueError("role is 'agent' or 'avatar'")
        if not endpoints:
            raise ValueError("at least one endpoint")
        self.endpoints: List[Endpoint] = list(endpoints)
        self.pairing, self.role, self.entity_id = pairing, role, entity_id
        self.credential = credential
        self.tls = tls
        self._ssl_context = tls.context() if tls is not None else None
        self.ha = ha
        self.connect_timeout = connect_timeout
        self.handshake_timeout = handshake_timeout
        self.reconnect_backoff = reconnect_backoff
        self.reconnect_limit = reconnect_limit
        self.max_frame = max_frame
        self.welcome: Optional[Welcome] = None
        self.binding: Optional[Binding] = None
        self._events: "asyncio.Queue[Event]" = asyncio.Queue()
        self._handlers: Dict[str, Handler] = {}
        self._link: Optional[_Link] = None
        self._reader_task: Optional["asyncio.Task[None]"] = None
        self._nonce = secrets.token_hex(4).upper()
        self._counter = 0
        self._pending: Dict[str, "asyncio.Future[Signal]"] = {}
        self._closed: Optional[Closed] = None
        self._description: Optional[bytes] = None
        self._binding_changed = asyncio.Event()
        self._closed_event = asyncio.Event()
        self._closed_delivered = False
        # Protocol version 2.
        self.session_id: Optional[str] = None
        self.epoch = 0
        self.last_seq = 0
        self._acked_seq = 0
        self._ack_handle: Optional[asyncio.TimerHandle] = None
        self._unacked: "OrderedDict[str, bytes]" = OrderedDict()
        # After a new session on a reconnect (the server lost the old one,
        # e.g. every node restarted), signals wait until a Binding report
        # shows another entity registered, instead of being refused as
        # UnknownReceiver while the other side is not back yet.
        self._held = False
        self._window = 1024
        self._room = asyncio.Condition()
        self._heartbeat = 0.0
        self._last_rx = 0.0
        self._next = 0
        self._connected = asyncio.Event()
        self.reconnects = 0
        self._connecting = False
        # The last accepted SignalIDs, so accepted() answers at once for a
        # signal accepted before it was called.
        self._accepted_ids: "OrderedDict[str, None]" = OrderedDict()
        # Acceptance (version 2): futures by SignalID and listeners.
        self._ack_waiters: Dict[str, "asyncio.Future[None]"] = {}
        self._ack_listeners: List[Callable[[str], None]] = []

    # ------------------------------------------------------------------ API

    async def connect(self) -> Welcome:
        """Joins the pairing. Without ``ha``: tries each endpoint in order and
        raises :class:`RefusedError` at the first refusal or
        :class:`ConnectError` when none answers. With ``ha``: goes round the
        endpoints with back-off until ``reconnect_limit``.

        A client holds one session: calling it again while connected or
        connecting raises :class:`AlreadyConnectedError`, and after
        :meth:`close` :class:`ClosedError` (make a new client instead)."""
        if self._closed is not None:
            raise ClosedError("this client is closed (%s): make a new Client to connect again"
                              % self._closed.reason)
        if self._connecting or self.welcome is not None:
            raise AlreadyConnectedError(
                "this client is already %s (entity %s in pairing %s): close it, or make "
                "another Client, for a second session"
                % ("connected" if self.welcome is not None else "connecting",
                   self.entity_id, self.pairing))
        self._connecting = True
        try:
            await self._connect()
        except BaseException:
            self._connecting = False
            raise
        self._connecting = False
        assert self.welcome is not None
        return self.welcome

    async def _connect(self) -> None:
        if self.ha:
            await self._attempt_ring("connect")
        else:
            failures: List[Tuple[Endpoint, str]] = []
            for e in self.endpoints:
                try:
                    await self._try_endpoint(e)
                    break
                except (RefusedError, ClosedError):
                    raise
                except (OSError, asyncio.TimeoutError, asyncio.IncompleteReadError,
                        FrameError, BilError, EvatarError) as why:
                    failures.append((e, _describe(why)))
            else:
                raise ConnectError(failures)

    def on(self, component_id: str, handler: Handler) -> None:
        """Passes signals addressed to ``component_id`` to ``handler``
        (a function or a coroutine function) instead of the event queue."""
        self._handlers[component_id] = handler

    async def describe(self, description: Union[Description, bytes]) -> None:
        """Sends this entity's description (with ``ha``: sent again after a
        reconnect that did not resume the session)."""
        self._check_open()
        doc = description.encode() if isinstance(description, Description) else description
        self._description = doc
        if self._link is not None:
            self._link.write(doc)
            await self._drain()

    async def get_binding(self) -> None:
        """Asks EVATAR for the pairing's current Binding report (GetBinding,
        docs/protocol.md section 2); it arrives as a :class:`~evatar.bil.Binding`
        event. With ``ha`` while reconnecting it does nothing: a resumed
        session is sent the report anyway."""
        self._check_open()
        if self._link is not None:
            self._link.write(encode(GetBinding()))
            await self._drain()

    async def send(self, signal: Optional[Signal] = None, **fields: Any) -> Signal:
        """Sends a signal; what is left out is filled in (id, timestamp).
        Either a :class:`Signal` or the keywords ``sender``, ``receiver``,
        ``category``, ``type``, ``parameters``, ``context`` (default
        ``Request``), ``in_reply_to``. Returns the signal as sent. With
        ``ha`` it returns once the signal is queued (sent now if connected,
        again after a reconnect until acknowledged); it waits while the
        window of unacknowledged signals is full.

        Returning means sent, not accepted: to learn that EVATAR accepted
        it (``ha`` only), ``await client.accepted(s)`` or register
        :meth:`on_ack`."""
        s = self._complete(signal, fields, "Request")
        await self._emit(s)
        return s

    def on_ack(self, listener: Callable[[str], None]) -> None:
        """Calls ``listener(signal_id)`` for each signal EVATAR accepts
        (``ha`` only), in the order they were sent, once each; like the
        Erlang client's ``notify_acks``. It runs on the client's loop and
        must not block."""
        if not self.ha:
            raise EvatarError("acceptance is reported only with ha=True (protocol version 2)")
        self._ack_listeners.append(listener)

    async def accepted(self, signal: Union[Signal, str], timeout: Optional[float] = 10.0) -> None:
        """Returns once EVATAR has accepted ``signal`` (a signal returned by
        :meth:`send`, or its id): it holds it and will not lose it even if
        this connection or the node goes. ``ha`` only. Raises
        :class:`AckTimeout` after ``timeout`` seconds (the client keeps
        sending it), :class:`ClosedError` when the session ends before, and
        :class:`EvatarError` for a signal this client did not send or a
        client without ``ha`` (protocol version 1 has no acknowledgements)."""
        if not self.ha:
            raise EvatarError("acceptance is reported only with ha=True (protocol version 2)")
        sid = signal.id if isinstance(signal, Signal) else signal
        if sid not in self._unacked:
            if sid in self._accepted_ids:
                return
            if self._closed is not None:
                raise ClosedError(self._closed.reason)
            raise EvatarError("%s is not a signal this client sent" % sid)
        fut = self._ack_waiters.get(sid)
        if fut is None:
            fut = asyncio.get_running_loop().create_future()
            self._ack_waiters[sid] = fut
        try:
            await asyncio.wait_for(asyncio.shield(fut), timeout)
        except asyncio.TimeoutError:
            raise AckTimeout("EVATAR did not accept %s within %s s" % (sid, timeout)) from None

    async def request(self, signal: Optional[Signal] = None, *, timeout: float = 10.0,
                      **fields: Any) -> Signal:
        """Sends a request awaiting feedback and returns the feedback, which
        may be EVATAR's own (``signal.is_evatar_timeout``). Raises
        :class:`SignalError` for an error answering it and
        :class:`FeedbackTimeout` after ``timeout`` seconds without an answer.
        With ``ha`` the wait goes on across reconnects."""
        s = self._complete(signal, fields, "RequestAwaitingFeedback")
        fut: "asyncio.Future[Signal]" = asyncio.get_running_loop().create_future()
        self._pending[s.id] = fut
        try:
            await self._emit(s)
            return await asyncio.wait_for(asyncio.shield(fut), timeout)
        except asyncio.TimeoutError:
            raise FeedbackTimeout("no answer to %s within %.3f s" % (s.id, timeout)) from None
        finally:
            self._pending.pop(s.id, None)

    async def reply(self, request: Signal, *, parameters: Any = None,
                    category: Optional[str] = None, type: Optional[str] = None,
                    progress: bool = False) -> Signal:
        """Answers a request received by one of this entity's components
        with Feedback (or Progress). The body names ``category``/``type``
        (by default ``ACTUATOR``/``ACTION FEEDBACK``, the convention of
        docs/bil.md)."""
        return await self.send(Signal(
            id="", context="Progress" if progress else "Feedback", sender=request.receiver,
            receiver=request.sender, in_reply_to=request.id,
            body=Entry(category or "ACTUATOR", type or "ACTION FEEDBACK",
                       parameters or [])))

    async def next_event(self, timeout: Optional[float] = None) -> Event:
        """The next event; raises asyncio.TimeoutError after ``timeout`` s.
        :class:`Closed` is the last event and comes once: once it has been
        returned, ``next_event`` raises :class:`ClosedError` (as
        :meth:`next_signal` and ``SensorEmulator.reading`` do), so a loop
        that does not stop at Closed ends instead of spinning."""
        if self._closed_delivered and self._events.empty():
            raise ClosedError(self._closed.reason if self._closed else "closed")
        ev = await asyncio.wait_for(self._events.get(), timeout)
        if isinstance(ev, Closed):
            self._closed_delivered = True
        return ev

    def _event(self, ev: Event) -> None:
        """Queues an event for :meth:`next_event` (the emulators pass on
        what they do not keep)."""
        self._events.put_nowait(ev)

    async def next_signal(self, timeout: Optional[float] = None,
                          match: Optional[Callable[[Signal], bool]] = None) -> Signal:
        """The next signal event (matching ``match``), skipping other events.
        Raises :class:`ClosedError` if the session ends first."""
        loop = asyncio.get_running_loop()
        deadline = None if timeout is None else loop.time() + timeout
        while True:
            left = None if deadline is None else max(0.0, deadline - loop.time())
            ev = await self.next_event(left)
            if isinstance(ev, Closed):
                raise ClosedError(ev.reason)
            if isinstance(ev, Signal) and (match is None or match(ev)):
                return ev

    async def wait_binding(self, match: Optional[Callable[[Binding], bool]] = None,
                           timeout: float = 10.0) -> Binding:
        """Waits until the latest Binding report satisfies ``match`` (by
        default: one exists). Reports also arrive as events."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while True:
            b = self.binding
            if b is not None and (match is None or match(b)):
                return b
            if self._closed is not None:
                raise ClosedError(self._closed.reason)
            self._binding_changed.clear()
            left = deadline - loop.time()
            if left <= 0:
                raise asyncio.TimeoutError("no matching Binding within %.3f s" % timeout)
            try:
                await asyncio.wait_for(self._binding_changed.wait(), left)
            except asyncio.TimeoutError:
                pass

    async def await_acks(self, timeout: float = 5.0) -> None:
        """Waits until every signal sent so far is acknowledged (``ha``)."""
        async def wait() -> None:
            async with self._room:
                await self._room.wait_for(lambda: not self._unacked or self._closed is not None)
        await asyncio.wait_for(wait(), timeout)
        if self._unacked:
            raise ClosedError(self._closed.reason if self._closed else "closed")

    @property
    def closed(self) -> Optional[Closed]:
        """Why the session ended, or None while it goes on."""
        return self._closed

    async def wait_closed(self) -> Closed:
        """Returns when the session ends (EVATAR closed it, a final
        refusal, :meth:`close`, or end-of-file on stdin for a port program)."""
        await self._closed_event.wait()
        assert self._closed is not None
        return self._closed

    @property
    def unacked(self) -> int:
        return len(self._unacked)

    @property
    def connected(self) -> bool:
        return self._link is not None

    @property
    def endpoint(self) -> Optional[Endpoint]:
        return self._link.endpoint if self._link else None

    async def close(self, timeout: float = CLOSE_TIMEOUT) -> None:
        """Says Bye and waits, at most ``timeout`` seconds (default
        :data:`CLOSE_TIMEOUT`, 5 s), for EVATAR's Bye, which EVATAR sends
        once it has unregistered this entity: after ``close()`` returns, a
        new client with the same EntityID is not refused ``EntityExists``
        (unless the wait timed out, when the connection is cut instead).
        Calling it again, or on a client never connected, does nothing."""
        if self._closed is not None:
            return
        link = self._link
        # The Closed event waits for EVATAR's Bye, so that its ``confirmed``
        # is final when the application reads it.
        self._finish("normal", announce=False)
        reader = self._reader_task
        try:
            if link is not None:
                try:
                    link.write(encode(Bye()))
                    await asyncio.wait_for(link.writer.drain(), timeout)
                except (OSError, asyncio.TimeoutError, ConnectionError):
                    link.abort()
                if reader is not None and reader is not asyncio.current_task():
                    # The reader ends at EVATAR's Bye or at the end of the stream.
                    await asyncio.wait([reader], timeout=timeout)
                link.abort()
            if reader is not None and reader is not asyncio.current_task() and not reader.done():
                reader.cancel()
        finally:
            self._announce_closed()

    def drop_connection(self) -> None:
        """Breaks the current connection as a network failure would (for
        tests and demonstrations of resume)."""
        if self._link is not None:
            self._link.abort()

    async def __aenter__(self) -> "Client":
        await self.connect()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    # ----------------------------------------------------------- connecting

    async def _open(self, e: Endpoint) -> _Link:
        if isinstance(e, str):
            if e != STDIO:
                raise ValueError("an endpoint is (host, port) or %r" % STDIO)
            reader, writer = await _open_stdio()
        else:
            host, port = e
            if self.tls is None:
                reader, writer = await asyncio.wait_for(
                    asyncio.open_connection(host, port), self.connect_timeout)
            else:
                reader, writer = await asyncio.wait_for(
                    asyncio.open_connection(
                        host, port, ssl=self._ssl_context,
                        server_hostname=self.tls.server_hostname or host,
                        ssl_handshake_timeout=self.connect_timeout),
                    self.connect_timeout)
                try:
                    self.tls.check(writer.get_extra_info("ssl_object"))
                except BaseException:
                    writer.transport.abort()
                    raise
        link = _Link(e, reader, writer)
        link.max_in = self.max_frame
        return link

    async def _try_endpoint(self, e: Endpoint) -> None:
        link = await self._open(e)
        try:
            link.write(encode(self._hello()))
            try:
                await link.writer.drain()
            except ConnectionResetError:
                # With TLS 1.3 a server refuses a client certificate after
                # the client's handshake is done: the reason (the TLS
                # alert) waits in the reader.
                if self.tls is None:
                    raise
            doc = parse_frame(await asyncio.wait_for(link.read(), self.handshake_timeout))
        except BaseException:
            link.abort()
            raise
        if isinstance(doc, Refused):
            link.abort()
            raise RefusedError(doc.code, doc.message)
        if not isinstance(doc, Welcome):
            link.abort()
            raise RefusedError("BadHandshake", "expected Welcome, got %s" % type(doc).__name__)
        if self.ha and not doc.ha:
            link.abort()
            raise RefusedError("BadHandshake", "the server does not speak ProtocolVersion 2")
        if self._closed is not None:
            # close() was called while the handshake went on: leave as
            # close() does, waiting for EVATAR's Bye (bounded).
            link.write(encode(Bye()))
            try:
                await asyncio.wait_for(self._await_bye(link), self.handshake_timeout)
            except (OSError, asyncio.TimeoutError, asyncio.IncompleteReadError, FrameError):
                pass
            link.abort()
            raise ClosedError(self._closed.reason)
        self._welcomed(doc, link)

    @staticmethod
    async def _await_bye(link: _Link) -> None:
        await link.writer.drain()
        while True:
            try:
                if isinstance(parse_frame(await link.read()), Bye):
                    return
            except BilError:
                pass

    def _hello(self) -> Union[Hello, Resume]:
        v = 2 if self.ha else 1
        if self.ha and self.session_id is not None:
            return Resume(self.pairing, self.role, self.entity_id, self.credential, v,
                          self.session_id, self.last_seq, self.epoch)
        return Hello(self.pairing, self.role, self.entity_id, self.credential, v)

    def _welcomed(self, w: Welcome, link: _Link) -> None:
        again = self.welcome is not None
        reason = getattr(self, "_lost_reason", "")
        self.welcome = w
        self._link = link
        if self.ha:
            assert w.epoch is not None and w.heartbeat is not None
            if w.resumed:
                self.epoch = max(self.epoch, w.epoch)
                if w.last_accepted:
                    self._acknowledged(w.last_accepted)
            else:
                self.session_id = w.session_id
                self.epoch = w.epoch
                self.last_seq = 0
                self._acked_seq = 0
            self._window = max(1, w.dedup_window or 1)
            self._heartbeat = w.heartbeat / 1000.0
            self._last_rx = time.monotonic()
            description = None if w.resumed else self._description
            described = description is not None
            if description is not None:
                link.write(description)
            # A resumed session stays held if it was (section 11.3 rule 6):
            # resuming elsewhere says nothing of the other side; the Binding
            # report that follows the Welcome does.
            if not w.resumed:
                self._held = again and described
            if not self._held:
                for doc in self._unacked.values():
                    link.write(doc)
            if again:
                self.reconnects += 1
                self._events.put_nowait(Reconnected(link.endpoint, bool(w.resumed), self.epoch,
                                                    w.session_id, reason))
        self._connected.set()
        self._reader_task = asyncio.ensure_future(self._read_loop(link))

    async def _attempt_ring(self, why: str) -> None:
        """Version 2: one endpoint per attempt round the ring, starting at
        ``self._next``; a doubling pause after every full round."""
        loop = asyncio.get_running_loop()
        started = loop.time()
        lo, hi = self.reconnect_backoff
        pause = 0.0
        tried = 0
        failures: List[Tuple[Endpoint, str]] = []
        last = why
        while True:
            if self._closed is not None:
                raise ClosedError(self._closed.reason)
            if tried > 0 and loop.time() - started > self.reconnect_limit:
                if self.welcome is None:
                    raise ConnectError(failures)
                raise ClosedError("gave_up: %s" % last)
            e = self.endpoints[self._next % len(self.endpoints)]
            self._next += 1
            tried += 1
            try:
                await self._try_endpoint(e)
                return
            except RefusedError as r:
                if r.code not in RETRY_CODES:
                    raise
                failures.append((e, str(r)))
                last = str(r)
            except (OSError, asyncio.TimeoutError, asyncio.IncompleteReadError,
                    FrameError, BilError) as w:
                failures.append((e, _describe(w)))
                last = _describe(w)
            if tried % len(self.endpoints) == 0:
                pause = min(hi, max(lo, pause * 2))
                await asyncio.sleep(pause)

    # -------------------------------------------------------------- traffic

    async def _read_loop(self, link: _Link) -> None:
        reason = "closed"
        refused: Optional[Refused] = None
        watchdog = None
        if self.ha and self._heartbeat > 0:
            watchdog = asyncio.ensure_future(self._watch_silence(link))
        try:
            while True:
                data = await link.read()
                self._last_rx = time.monotonic()
                try:
                    doc = parse_frame(data)
                except BilError as e:
                    reason = "malformed: %s" % e
                    refused = Refused("Malformed", str(e))
                    break
                if isinstance(doc, Refused):
                    reason, refused = "refused: %s: %s" % (doc.code, doc.message), doc
                    break
                if isinstance(doc, Bye):
                    reason = "bye" + (": " + doc.reason if doc.reason else "")
                    if self._closed is not None:
                        self._closed.confirmed = True
                    break
                await self._incoming(doc)
        except asyncio.IncompleteReadError:
            reason = "closed"
        except FrameError as e:
            reason, refused = "malformed: %s" % e, Refused("Malformed", str(e))
        except (OSError, ConnectionError) as e:
            reason = "socket_error: %s" % e
        except asyncio.CancelledError:
            if watchdog:
                watchdog.cancel()
            return
        finally:
            if watchdog:
                watchdog.cancel()
        link.abort()
        if link.silent:
            reason = "server_silent"
        if self._link is link:
            self._link = None
        if self._closed is not None:
            return
        self._connected.clear()
        retry = self.ha and link.endpoint != STDIO and (
            refused is None or (refused.code in RETRY_CODES and not reason.startswith("malformed")))
        if not retry:
            self._finish(reason, refused)
            return
        self._lost_reason = reason
        self._cancel_ack_timer()
        self._next = self.endpoints.index(link.endpoint) + 1 if link.endpoint in self.endpoints else 0
        try:
            await self._attempt_ring(reason)
        except ClosedError:
            pass
        except RefusedError as r:
            self._finish("refused: %s: %s" % (r.code, r.message), Refused(r.code, r.message))
        except (ConnectError, EvatarError) as e:
            self._finish("gave_up: %s" % e)

    async def _watch_silence(self, link: _Link) -> None:
        hb = self._heartbeat
        while True:
            await asyncio.sleep(hb)
            if time.monotonic() - self._last_rx > 3 * hb:
                link.silent = True
                link.abort()
                return

    async def _incoming(self, doc: bil.Document) -> None:
        if isinstance(doc, Signal):
            if self.ha:
                if doc.sequence is not None and doc.sequence <= self.last_seq:
                    return
                if doc.epoch is not None and doc.epoch < self.epoch:
                    return
                if doc.sequence is not None:
                    self.last_seq = doc.sequence
                if doc.epoch is not None and doc.epoch > self.epoch:
                    self.epoch = doc.epoch
                self._schedule_ack()
            fut = self._pending.get(doc.in_reply_to or "")
            if fut is not None and doc.context in ("Feedback", "Error"):
                if not fut.done():
                    if doc.context == "Feedback":
                        fut.set_result(doc)
                    else:
                        fut.set_exception(SignalError(doc))
                return
            handler = self._handlers.get(doc.receiver) if doc.context != "Error" else None
            if handler is not None:
                try:
                    r = handler(doc)
                    if inspect.isawaitable(r):
                        asyncio.ensure_future(r).add_done_callback(_log_failure)
                except Exception:
                    LOG.exception("the handler of %s failed on signal %s", doc.receiver, doc.id)
                return
            self._events.put_nowait(doc)
        elif isinstance(doc, Binding):
            self.binding = doc
            if self._held and any(e != self.entity_id for e in doc.entities):
                self._held = False
                if self._link is not None:
                    for queued in self._unacked.values():
                        self._link.write(queued)
            self._binding_changed.set()
            self._events.put_nowait(doc)
        elif isinstance(doc, Ack):
            if doc.accepted is not None:
                self._acknowledged(doc.accepted)
        # Other documents (a Welcome again, a description) are ignored.

    def _schedule_ack(self) -> None:
        if self.last_seq - self._acked_seq >= ACK_EVERY:
            self._send_ack()
        elif self._ack_handle is None:
            self._ack_handle = asyncio.get_running_loop().call_later(ACK_DELAY, self._send_ack)

    def _cancel_ack_timer(self) -> None:
        if self._ack_handle is not None:
            self._ack_handle.cancel()
            self._ack_handle = None

    def _send_ack(self) -> None:
        self._cancel_ack_timer()
        if self.last_seq != self._acked_seq and self._link is not None:
            self._link.write(encode(Ack(received=self.last_seq)))
            self._acked_seq = self.last_seq

    def _acknowledged(self, signal_id: str) -> None:
        if signal_id not in self._unacked:
            return
        while self._unacked:
            k, _ = self._unacked.popitem(last=False)
            self._accepted_ids[k] = None
            if len(self._accepted_ids) > ACCEPTED_MEMORY:
                self._accepted_ids.popitem(last=False)
            fut = self._ack_waiters.pop(k, None)
            if fut is not None and not fut.done():
                fut.set_result(None)
            for listener in self._ack_listeners:
                try:
                    listener(k)
                except Exception:
                    LOG.exception("an on_ack listener failed on %s", k)
            if k == signal_id:
                break
        asyncio.ensure_future(self._notify_room())

    async def _notify_room(self) -> None:
        async with self._room:
            self._room.notify_all()

    def _complete(self, signal: Optional[Signal], fields: Dict[str, Any],
                  default_context: str) -> Signal:
        self._check_open()
        if signal is None:
            try:
                signal = Signal(id=fields.get("id", ""),
                                context=fields.get("context", default_context),
                                sender=fields["sender"], receiver=fields["receiver"],
                                body=Entry(fields["category"], fields["type"],
                                           fields.get("parameters") or []),
                                in_reply_to=fields.get("in_reply_to"))
            except KeyError as k:
                raise TypeError("missing signal field %s" % k) from None
        elif fields:
            raise TypeError("give a Signal or keywords, not both")
        if default_context == "RequestAwaitingFeedback":
            signal.context = default_context
        if not signal.id:
            self._counter += 1
            signal.id = "%s-%s-%d" % (self.entity_id, self._nonce, self._counter)
        if not signal.timestamp:
            signal.timestamp = int(time.time() * 1000)
        signal.sequence = None
        signal.epoch = None
        return signal

    async def _emit(self, s: Signal) -> None:
        doc = s.encode()
        if self.ha:
            async with self._room:
                await self._room.wait_for(
                    lambda: len(self._unacked) < self._window or self._closed is not None)
            self._check_open()
            self._unacked[s.id] = doc
            if self._link is not None and not self._held:
                self._link.write(doc)
                await self._drain()
        else:
            if self._link is None:
                raise ClosedError("not connected")
            self._link.write(doc)
            await self._drain()

    async def _drain(self) -> None:
        link = self._link
        if link is not None:
            try:
                await link.writer.drain()
            except (OSError, ConnectionError):
                pass  # the reader sees the loss and acts on it

    def _check_open(self) -> None:
        if self._closed is not None:
            raise ClosedError(self._closed.reason)

    def _finish(self, reason: str, refused: Optional[Refused] = None,
                announce: bool = True) -> None:
        if self._closed is not None:
            return
        self._closed = Closed(reason, refused)
        self._cancel_ack_timer()
        self._connected.clear()
        for fut in list(self._pending.values()) + list(self._ack_waiters.values()):
            if not fut.done():
                fut.set_exception(ClosedError(reason))
        self._ack_waiters.clear()
        if announce:
            self._announce_closed()
        self._binding_changed.set()
        asyncio.ensure_future(self._notify_room())
        if self._link is not None and reason != "normal":
            self._link.abort()
            self._link = None

    def _announce_closed(self) -> None:
        if self._closed is None or self._closed_event.is_set():
            return
        self._closed_event.set()
        self._events.put_nowait(self._closed)


def _log_failure(task: "asyncio.Future[Any]") -> None:
    if not task.cancelled() and task.exception() is not None:
        LOG.error("a signal handler failed", exc_info=task.exception())


def _describe(e: BaseException) -> str:
    if isinstance(e, asyncio.TimeoutError):
        return "timeout"
    if isinstance(e, asyncio.IncompleteReadError):
        return "closed"
    return "%s: %s" % (type(e).__name__, e)

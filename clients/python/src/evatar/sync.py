"""A synchronous wrapper: the asyncio client runs on an event loop in a
background thread; each method blocks until its coroutine is done.

    with SyncClient([("127.0.0.1", 7400)], pairing="home", role="agent",
                    entity_id="va-1", credential="secret") as c:
        c.describe(description)
        c.wait_binding()
        feedback = c.request(sender=..., receiver=..., category=..., type=...)

:class:`SyncClient` has every public method and property of
:class:`evatar.Client`, with the same parameters, blocking (the SDK's tests
compare the two), plus :meth:`SyncClient.call`. Handlers given to
:meth:`SyncClient.on` and listeners given to :meth:`SyncClient.on_ack` run
on the background thread.

The thread and its loop live from the constructor to :meth:`close`, which
may be called any number of times; a ``with`` block whose connect is refused
closes them before the exception leaves the block, so nothing is left
behind (thread, loop, socket).
"""

from __future__ import annotations

import asyncio
import threading
from typing import Any, Callable, Coroutine, List, Optional, TypeVar, Union

from .bil import Binding, Description, Signal, Welcome
from .client import CLOSE_TIMEOUT, Client, Closed, Endpoint, Event, Handler

__all__ = ["SyncClient"]

T = TypeVar("T")


class SyncClient:
    """Blocking facade of :class:`evatar.Client` (same arguments)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="evatar-client",
                                        daemon=True)
        self._thread.start()
        self._lock = threading.Lock()
        self._stopped = False

        async def make() -> Client:
            return Client(*args, **kwargs)
        try:
            self.client: Client = self._run(make())
        except BaseException:
            self._stop_loop()
            raise

    def _run(self, coro: Coroutine[Any, Any, T], timeout: Optional[float] = None) -> T:
        if self._stopped:
            coro.close()
            raise RuntimeError("this SyncClient is closed")
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result(timeout)

    def _get(self, fn: Callable[[], T]) -> T:
        """Reads client state on the loop's thread."""
        async def read() -> T:
            return fn()
        return self._run(read())

    # The methods of Client, in its order.

    def connect(self) -> Welcome:
        return self._run(self.client.connect())

    def on(self, component_id: str, handler: Handler) -> None:
        self._get(lambda: self.client.on(component_id, handler))

    def describe(self, description: Union[Description, bytes]) -> None:
        self._run(self.client.describe(description))

    def get_binding(self) -> None:
        self._run(self.client.get_binding())

    def send(self, signal: Optional[Signal] = None, **fields: Any) -> Signal:
        return self._run(self.client.send(signal, **fields))

    def on_ack(self, listener: Callable[[str], None]) -> None:
        self._get(lambda: self.client.on_ack(listener))

    def accepted(self, signal: Union[Signal, str], timeout: Optional[float] = 10.0) -> None:
        self._run(self.client.accepted(signal, timeout))

    def request(self, signal: Optional[Signal] = None, *, timeout: float = 10.0,
                **fields: Any) -> Signal:
        return self._run(self.client.request(signal, timeout=timeout, **fields))

    def reply(self, request: Signal, *, parameters: Any = None, category: Optional[str] = None,
              type: Optional[str] = None, progress: bool = False) -> Signal:
        return self._run(self.client.reply(request, parameters=parameters, category=category,
                                           type=type, progress=progress))

    def next_event(self, timeout: Optional[float] = None) -> Event:
        return self._run(self.client.next_event(timeout))

    def next_signal(self, timeout: Optional[float] = None,
                    match: Optional[Callable[[Signal], bool]] = None) -> Signal:
        return self._run(self.client.next_signal(timeout, match))

    def wait_binding(self, match: Optional[Callable[[Binding], bool]] = None,
                     timeout: float = 10.0) -> Binding:
        return self._run(self.client.wait_binding(match, timeout))

    def await_acks(self, timeout: float = 5.0) -> None:
        self._run(self.client.await_acks(timeout))

    @property
    def closed(self) -> Optional[Closed]:
        return self.client.closed

    def wait_closed(self) -> Closed:
        return self._run(self.client.wait_closed())

    @property
    def unacked(self) -> int:
        return self.client.unacked

    @property
    def connected(self) -> bool:
        return self.client.connected

    @property
    def endpoint(self) -> Optional[Endpoint]:
        return self.client.endpoint

    def drop_connection(self) -> None:
        self._get(self.client.drop_connection)

    # Attributes of Client a program reads.

    @property
    def welcome(self) -> Optional[Welcome]:
        return self.client.welcome

    @property
    def binding(self) -> Optional[Binding]:
        return self.client.binding

    @property
    def session_id(self) -> Optional[str]:
        return self.client.session_id

    @property
    def reconnects(self) -> int:
        return self.client.reconnects

    def call(self, fn: Callable[[Client], Coroutine[Any, Any, T]]) -> T:
        """Runs ``fn(client)`` (a coroutine function) on the client's loop."""
        return self._run(fn(self.client))

    def close(self, timeout: float = CLOSE_TIMEOUT) -> None:
        """Closes the session as :meth:`Client.close` does (waiting at most
        ``timeout`` s for EVATAR's Bye), then stops the background thread
        and closes its loop. Calling it again does nothing."""
        with self._lock:
            if self._stopped:
                return
            try:
                self._run(self.client.close(timeout), timeout + 5.0)
            finally:
                self._stop_loop()

    def _stop_loop(self) -> None:
        self._stopped = True

        async def cancel_rest() -> None:
            rest: List["asyncio.Task[Any]"] = [
                t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
            for t in rest:
                t.cancel()
            if rest:
                await asyncio.wait(rest, timeout=5.0)
        try:
            asyncio.run_coroutine_threadsafe(cancel_rest(), self._loop).result(10.0)
        finally:
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(10.0)
            if not self._thread.is_alive():
                self._loop.close()

    def __enter__(self) -> "SyncClient":
        try:
            self.connect()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

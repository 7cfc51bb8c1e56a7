"""A small synchronous wrapper: the asyncio client runs on an event loop in
a background thread; each method blocks until its coroutine is done.

    with SyncClient([("127.0.0.1", 7400)], pairing="home", role="agent",
                    entity_id="va-1", credential="secret") as c:
        c.describe(description)
        c.wait_binding()
        feedback = c.request(sender=..., receiver=..., category=..., type=...)
"""

from __future__ import annotations

import asyncio
import threading
from typing import Any, Callable, Coroutine, Optional, TypeVar

from .bil import Binding, Description, Signal, Welcome
from .client import Client, Event

__all__ = ["SyncClient"]

T = TypeVar("T")


class SyncClient:
    """Blocking facade of :class:`evatar.Client` (same arguments)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="evatar-client",
                                        daemon=True)
        self._thread.start()

        async def make() -> Client:
            return Client(*args, **kwargs)
        self.client: Client = self._run(make())

    def _run(self, coro: Coroutine[Any, Any, T], timeout: Optional[float] = None) -> T:
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result(timeout)

    def connect(self) -> Welcome:
        return self._run(self.client.connect())

    def describe(self, description: Description) -> None:
        self._run(self.client.describe(description))

    def send(self, signal: Optional[Signal] = None, **fields: Any) -> Signal:
        return self._run(self.client.send(signal, **fields))

    def request(self, signal: Optional[Signal] = None, *, timeout: float = 10.0,
                **fields: Any) -> Signal:
        return self._run(self.client.request(signal, timeout=timeout, **fields))

    def reply(self, request: Signal, **kw: Any) -> Signal:
        return self._run(self.client.reply(request, **kw))

    def next_event(self, timeout: Optional[float] = None) -> Event:
        return self._run(self.client.next_event(timeout))

    def next_signal(self, timeout: Optional[float] = None,
                    match: Optional[Callable[[Signal], bool]] = None) -> Signal:
        return self._run(self.client.next_signal(timeout, match))

    def wait_binding(self, match: Optional[Callable[[Binding], bool]] = None,
                     timeout: float = 10.0) -> Binding:
        return self._run(self.client.wait_binding(match, timeout))

    def call(self, fn: Callable[[Client], Coroutine[Any, Any, T]]) -> T:
        """Runs ``fn(client)`` (a coroutine function) on the client's loop."""
        return self._run(fn(self.client))

    def close(self) -> None:
        try:
            self._run(self.client.close(), 5.0)
        finally:
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(5.0)
            self._loop.close()

    def __enter__(self) -> "SyncClient":
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

"""A client's life against a real node (scripts/test-node.sh): closing waits
for EVATAR's Bye, so the same EntityID joins again at once; closing twice;
refused connects leave no thread, loop or socket; a second connect fails
locally; act() on a service not consumed; SyncClient has Client's methods;
and learning which signals EVATAR accepted."""

from __future__ import annotations

import asyncio
import inspect
import os
import socket
import threading
import time
from typing import Iterator, List

import pytest

from evatar import (AckTimeout, Actuator, ActuatorEmulator, AlreadyConnectedError, Client,
                    ClosedError, ConnectError, Entry, EvatarError, NotConsumedError,
                    RefusedError, Signal, SyncClient, describe)

from conftest import Node, run


@pytest.fixture(scope="module")
def endpoint() -> Iterator[tuple]:
    """A node of this module's own, whose listener does not limit the
    handshake rate (the tests open a few hundred connections in tight
    loops, as the agents they stand for do; the shared node keeps its
    limit for the other tests)."""
    n = Node("test-node.sh", ["cycle:c-va:c-avatar", "twice:w-va:w-avatar",
                              "acks:k-va:k-avatar"],
             env={"EVATAR_HANDSHAKE_RATE": "infinity"})
    yield ("127.0.0.1", n.port)
    n.stop()


def open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def assert_nothing_left(threads: int, fds: int) -> None:
    """Threads and descriptors come back to at most their counts before:
    fewer is not a leak (a socket the collector closed), and a count still
    falling is waited for rather than compared once."""
    deadline = time.monotonic() + 10
    while (threading.active_count() > threads or open_fds() > fds) and time.monotonic() < deadline:
        time.sleep(0.02)
    now = (threading.active_count(), open_fds())
    assert now[0] <= threads and now[1] <= fds, f"threads, fds: {(threads, fds)} before, {now} after"


def dead_endpoint() -> tuple:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return ("127.0.0.1", port)


def test_close_waits_for_bye_reconnect_same_id(endpoint) -> None:  # type: ignore[no-untyped-def]
    """50 close/reconnect cycles with the same EntityID, at once: none is
    refused EntityExists (before the fix 5 of 20 were), for protocol
    version 1, version 2 and the SyncClient."""
    refused: List[str] = []

    async def cycles(ha: bool, n: int) -> None:
        for i in range(n):
            c = Client([endpoint], pairing="cycle", role="agent", entity_id="va-cycle",
                       credential="c-va", ha=ha, reconnect_limit=0)
            try:
                await c.connect()
            except (RefusedError, ConnectError) as e:
                refused.append("%s cycle %d: %s" % ("v2" if ha else "v1", i, e))
                continue
            await c.close()
            # close() returned after EVATAR's Bye, which EVATAR sends once
            # it has unregistered the entity.
            assert c.closed is not None and c.closed.reason == "normal"
            assert c.closed.confirmed
    run(cycles(False, 50))
    run(cycles(True, 50))
    for i in range(20):
        try:
            with SyncClient([endpoint], pairing="cycle", role="agent", entity_id="va-cycle",
                            credential="c-va") as s:
                pass
            assert s.closed is not None and s.closed.confirmed
        except RefusedError as e:
            refused.append("sync cycle %d: %s" % (i, e.code))
    assert refused == []


def test_close_twice_and_before_connect(endpoint) -> None:  # type: ignore[no-untyped-def]
    with SyncClient([endpoint], pairing="twice", role="agent", entity_id="va-2",
                    credential="w-va") as c:
        c.close()
        c.close()
    c.close()
    SyncClient([endpoint], pairing="twice", role="agent", entity_id="va-2",
               credential="w-va").close()

    async def main() -> None:
        a = Client([endpoint], pairing="twice", role="agent", entity_id="va-2",
                   credential="w-va")
        await a.close()          # never connected
        await a.close()
        b = Client([endpoint], pairing="twice", role="agent", entity_id="va-2",
                   credential="w-va")
        await b.connect()
        await asyncio.gather(b.close(), b.close())
        await b.close()
        with pytest.raises(ClosedError):
            await b.connect()
    run(main())


def test_close_during_connect(endpoint) -> None:  # type: ignore[no-untyped-def]
    """close() while connect() goes on: connect raises ClosedError (or had
    just finished, and the session is closed); a session the handshake made
    meanwhile is left with a Bye, so the same EntityID joins at once; no
    socket is left open."""
    dead = dead_endpoint()

    async def main() -> None:
        fds = open_fds()
        # Version 2 going round endpoints that do not answer.
        c = Client([dead], pairing="twice", role="agent", entity_id="va-d", credential="w-va",
                   ha=True, reconnect_backoff=(0.05, 0.1))
        task = asyncio.ensure_future(c.connect())
        await asyncio.sleep(0.3)
        await c.close()
        with pytest.raises(ClosedError):
            await asyncio.wait_for(task, 10)
        # A handshake under way with a live node, closed at each step of it.
        for delay in (0, 0.001, 0.005, 0.02):
            c = Client([endpoint], pairing="twice", role="agent", entity_id="va-d",
                       credential="w-va")
            task = asyncio.ensure_future(c.connect())
            await asyncio.sleep(delay)
            await c.close()
            try:
                await task
            except ClosedError:
                pass
            assert c.closed is not None and not c.connected
            again = Client([endpoint], pairing="twice", role="agent", entity_id="va-d",
                           credential="w-va")
            await again.connect()  # not refused EntityExists
            assert again.connected
            await again.close()
        assert_nothing_left(threading.active_count(), fds)
    run(main())


def test_refused_connects_leave_nothing(endpoint) -> None:  # type: ignore[no-untyped-def]
    """Refused and unreachable connects in a loop, with and without
    ``with``: afterwards as many threads and open file descriptors as
    before (the loop's selector and self-pipe, the socket: all closed)."""
    dead = dead_endpoint()

    def refused_once() -> None:
        with pytest.raises(RefusedError):
            with SyncClient([endpoint], pairing="nowhere", role="agent", entity_id="va-r",
                            credential="x"):
                pass
        with pytest.raises(ConnectError):
            with SyncClient([dead], pairing="twice", role="agent", entity_id="va-r",
                            credential="w-va", connect_timeout=2):
                pass
        with pytest.raises(ValueError):
            SyncClient([endpoint], pairing="twice", role="nobody", entity_id="va-r")

        async def plain() -> None:
            with pytest.raises(RefusedError):
                await Client([endpoint], pairing="nowhere", role="agent", entity_id="va-r",
                             credential="x").connect()
        run(plain())

    refused_once()  # lazy imports and caches open what they open once
    threads, fds = threading.active_count(), open_fds()
    for _ in range(20):
        refused_once()
    assert_nothing_left(threads, fds)


def test_connect_twice_fails_locally(endpoint) -> None:  # type: ignore[no-untyped-def]
    async def main() -> None:
        c = Client([endpoint], pairing="twice", role="agent", entity_id="va-t",
                   credential="w-va")
        await c.connect()
        fds = open_fds()
        with pytest.raises(AlreadyConnectedError) as e:
            await c.connect()
        assert "already connected" in str(e.value)
        assert open_fds() <= fds and c.connected
        await c.close()
        # Two connects at once: one session, the other fails locally.
        d = Client([endpoint], pairing="twice", role="agent", entity_id="va-t",
                   credential="w-va")
        results = await asyncio.gather(d.connect(), d.connect(), return_exceptions=True)
        assert sorted(type(r).__name__ for r in results) == ["AlreadyConnectedError", "Welcome"]
        # The session works: EVATAR answers a signal to nobody.
        await d.send(sender="X", receiver="Y", category="ACTUATOR", type="T")
        err = await d.next_signal(5, lambda s: s.context == "Error")
        assert err.from_evatar
        await d.close()
    run(main())


def test_act_on_a_service_not_consumed(endpoint) -> None:  # type: ignore[no-untyped-def]
    async def main() -> None:
        va = Client([endpoint], pairing="twice", role="agent", entity_id="va-n",
                    credential="w-va")
        light = ActuatorEmulator(va, "LightEmulator01",
                                 [Entry("ACTUATOR", "TurnLightOn", {"Light": "yes"}),
                                  Entry("ACTUATOR", "TurnLightOff", {"Light": "yes"})])
        with pytest.raises(NotConsumedError) as e:
            await light.act("OpenDoor")
        assert (e.value.component, e.value.service, e.value.consumed) == (
            "LightEmulator01", "OpenDoor", ["TurnLightOn", "TurnLightOff"])
        assert str(e.value) == ("LightEmulator01 does not consume OpenDoor; "
                                "it consumes TurnLightOn, TurnLightOff")
        assert isinstance(e.value, EvatarError) and isinstance(e.value, ValueError)
    run(main())


def public(cls: type) -> dict:
    return {n: getattr(cls, n) for n in dir(cls) if not n.startswith("_")}


def test_sync_client_has_the_methods_of_client() -> None:
    """Every public method and property of Client is on SyncClient, with
    the same parameters; SyncClient adds only what its docstring names."""
    a, s = public(Client), public(SyncClient)
    missing = sorted(set(a) - set(s))
    assert missing == []
    assert sorted(set(s) - set(a)) == sorted(["call", "welcome", "binding", "session_id",
                                              "reconnects"])
    for name, member in a.items():
        if isinstance(member, property):
            assert isinstance(s[name], property), name
            continue
        want = [(p.name, p.kind, p.default) for p in inspect.signature(member).parameters.values()]
        got = [(p.name, p.kind, p.default) for p in inspect.signature(s[name]).parameters.values()]
        assert got == want, name


def test_accepted_signals(endpoint) -> None:  # type: ignore[no-untyped-def]
    """With ha, send() then accepted() returns once EVATAR holds the
    signal; on_ack sees every accepted SignalID once, in order; without ha
    both say that version 1 has no acknowledgements."""
    handled: List[str] = []

    async def main() -> None:
        va = Client([endpoint], pairing="acks", role="agent", entity_id="va-k",
                    credential="k-va", ha=True)
        light = ActuatorEmulator(va, "LightEmulator01",
                                 [Entry("ACTUATOR", "TurnLightOn", {"Light": "yes"})])
        av = Client([endpoint], pairing="acks", role="avatar", entity_id="lamp",
                    credential="k-avatar")
        lamp = Actuator(av, "Lamp", [Entry("ACTUATOR", "TurnLightOn", {"Light": "yes"})],
                        lambda s: handled.append(s.param("N") or "") or {"Done": "yes"})
        seen: List[str] = []
        va.on_ack(seen.append)
        await va.connect()
        await av.connect()
        await describe(va, [light])
        await describe(av, [lamp])
        await va.wait_binding(lambda b: light.is_bound("TurnLightOn"))
        sent: List[Signal] = []
        for i in range(40):
            sent.append(await va.send(sender="LightEmulator01", receiver="Lamp",
                                      category="ACTUATOR", type="TurnLightOn",
                                      parameters={"N": str(i)}))
        for s in sent:
            await va.accepted(s, timeout=10)
        await va.accepted(sent[0].id)  # already accepted: returns at once
        assert seen == [s.id for s in sent]
        assert va.unacked == 0
        with pytest.raises(EvatarError):
            await va.accepted("never-sent")
        # Accepted means EVATAR holds it: the lamp gets every one.
        deadline = asyncio.get_running_loop().time() + 10
        while len(handled) < 40 and asyncio.get_running_loop().time() < deadline:
            await asyncio.sleep(0.05)
        assert handled == [str(i) for i in range(40)]
        # A signal sent while the connection is down is accepted after the
        # reconnect: accepted() waits across it.
        va.drop_connection()
        late = await va.send(sender="LightEmulator01", receiver="Lamp", category="ACTUATOR",
                             type="TurnLightOn", parameters={"N": "late"})
        await va.accepted(late, timeout=30)
        assert seen[-1] == late.id
        await va.close()
        await av.close()
        v1 = Client([endpoint], pairing="acks", role="agent", entity_id="va-k1",
                    credential="k-va")
        with pytest.raises(EvatarError, match="ha=True"):
            v1.on_ack(print)
        with pytest.raises(EvatarError, match="ha=True"):
            await v1.accepted("x")
    run(main())
    assert AckTimeout.__mro__[1] is EvatarError

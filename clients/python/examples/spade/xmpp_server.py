"""SPADE's embedded XMPP server (pyjabber, what ``spade run`` starts) on
loopback only, for the tests and the demo:

    python xmpp_server.py [PORT]

listens on 127.0.0.1:PORT (default 0: a free port) for clients, with an
in-memory database, no admin web page, no server-to-server listener on a
public address, and PubSub mended for spade-artifact (below); prints
``XMPP_PORT=<port>`` once it listens, and stops when its stdin closes.
Agents' JIDs are ``name@127.0.0.1``; SPADE registers them on their first
start.
"""

from __future__ import annotations

import asyncio
import os
import sys

import uvloop
from loguru import logger
from pyjabber.plugins.xep_0060.xep_0060 import PubSub
from pyjabber.plugins.xep_0363.xep_0363 import HTTPFieldUpload
from pyjabber.server import Server
from pyjabber.server_parameters import Parameters

HOST = "127.0.0.1"


class _Reload:
    """PubSub's memory reload, run only when awaited."""

    def __init__(self, load, pubsub) -> None:
        self.load, self.pubsub = load, pubsub

    def __await__(self):
        return self.load(self.pubsub).__await__()


def reload_pubsub_after_changes() -> None:
    """pyjabber 0.4.5's PubSub calls update_memory_from_database() without
    awaiting it after creating, deleting, subscribing or unsubscribing, so
    it never sees a new node or subscriber: a publish to a node just made
    answers item-not-found, a subscriber gets nothing. Made here to reload
    before the answer is sent (before PubSub() takes its operations)."""
    load = PubSub.update_memory_from_database
    if getattr(load, "evatar_patched", False):
        return

    def update(self):
        return _Reload(load, self)
    update.evatar_patched = True
    PubSub.update_memory_from_database = update

    def reloading(op):
        async def changed(self, element, jid):
            try:
                return await op(self, element, jid)
            finally:
                await self.update_memory_from_database()
        return changed
    for name in ("create_node", "delete_node", "subscribe", "unsubscribe"):
        setattr(PubSub, name, reloading(getattr(PubSub, name)))


async def main(port: int) -> None:
    logger.remove()
    logger.add(sys.stderr, level=os.environ.get("XMPP_LOG", "WARNING"))
    plugins = [p for p in Parameters().plugins if p != "urn:xmpp:http:upload:0"]
    server = Server(Parameters(host=HOST, client_port=port, server_port=0,
                               database_in_memory=True, plugins=plugins,
                               message_persistence=False))
    server._public_ip = None  # loopback only: pyjabber also listens on the public address
    # Without the upload plugin pyjabber never makes its HTTPFieldUpload
    # singleton, yet every session's stanza handler asks for it: the session
    # then dies after binding, silently, and routes no message or presence.
    # Made here with no HTTP server; no client is told the service exists.
    HTTPFieldUpload(None)
    reload_pubsub_after_changes()
    task = asyncio.ensure_future(server.run_server())
    ready = asyncio.ensure_future(server.ready.wait())
    await asyncio.wait([task, ready], return_when=asyncio.FIRST_COMPLETED)
    if not ready.done():
        raise SystemExit("the XMPP server did not start")
    bound = server._client_listener.sockets[0].getsockname()[1]
    print("XMPP_PORT=%d" % bound, flush=True)
    # Not sys.stdin.read in a thread: pyjabber forks worker processes
    # (password hashing), and a child forked while a thread holds stdin's
    # lock hangs when multiprocessing closes stdin in it.
    loop = asyncio.get_running_loop()
    eof = loop.create_future()

    def readable() -> None:
        if not os.read(0, 4096) and not eof.done():
            eof.set_result(None)
    loop.add_reader(0, readable)
    await eof
    loop.remove_reader(0)
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)


if __name__ == "__main__":
    # uvloop, as `spade run` has it: on asyncio's own loop pyjabber loses
    # the stream restarted right after STARTTLS now and then.
    uvloop.install()
    asyncio.run(main(int(sys.argv[1]) if len(sys.argv) > 1 else 0))

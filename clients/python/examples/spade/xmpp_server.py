"""SPADE's embedded XMPP server (pyjabber, what ``spade run`` starts) on
loopback only, for the tests and the demo:

    python xmpp_server.py [PORT]

listens on 127.0.0.1:PORT (default 0: a free port) for clients, with an
in-memory database, no admin web page and no server-to-server listener on
a public address; prints ``XMPP_PORT=<port>`` once it listens, and stops
when its stdin closes. Agents' JIDs are ``name@127.0.0.1``; SPADE
registers them on their first start.
"""

from __future__ import annotations

import asyncio
import os
import sys

import uvloop
from loguru import logger
from pyjabber.plugins.xep_0363.xep_0363 import HTTPFieldUpload
from pyjabber.server import Server
from pyjabber.server_parameters import Parameters

HOST = "127.0.0.1"


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

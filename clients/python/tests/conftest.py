"""Fixtures: a real EVATAR node started by scripts/test-node.sh from the
compiled umbrella (honours REBAR_BASE_DIR), on a free port of 127.0.0.1."""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys
from pathlib import Path
from typing import Dict, Iterator, List, Optional

import pytest

REPO = Path(__file__).resolve().parents[3]

#: ``timeouts`` answers for a silent device after 2 s, not the default 5 s:
#: test_feedback_timeouts waits for that answer.
PAIRINGS = ["kitchen:va-secret:avatar-secret", "lab:lab-va:lab-avatar",
            "ha:ha-va:ha-avatar", "sensing:s-va:s-avatar", "timeouts:t-va:t-avatar:2000",
            "dropped:d-va:d-avatar", "sync:y-va:y-avatar", "vectors:va-secret:avatar-secret",
            "artifacts:art-va:art-avatar", "porch:va-secret:avatar-secret"]


class Node:
    """An EVATAR node in an OS process; stops when its stdin closes."""

    def __init__(self, script: str, args: List[str],
                 env: Optional[Dict[str, str]] = None) -> None:
        self.proc = subprocess.Popen([str(REPO / "scripts" / script)] + args,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=sys.stderr, cwd=str(REPO), text=True, bufsize=1,
                                     errors="replace",
                                     env=None if env is None else {**os.environ, **env})
        self.port: Optional[int] = None
        self.lines: List[str] = []
        #: Every ``EVATAR_*=<port>`` line before EVATAR_PORT (the TLS ports).
        self.ports: Dict[str, int] = {}
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            line = line.strip()
            self.lines.append(line)
            name, eq, value = line.partition("=")
            if eq and name.startswith("EVATAR_") and value.isdigit():
                self.ports[name] = int(value)
            if line.startswith("EVATAR_PORT="):
                self.port = int(line.split("=", 1)[1])
                break
        if self.port is None:
            self.stop()
            raise RuntimeError("the node did not start: %s" % self.lines)

    def readline(self) -> str:
        assert self.proc.stdout is not None
        return self.proc.stdout.readline()

    def command(self, text: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(text + "\n")
        self.proc.stdin.flush()

    def ask(self, text: str) -> List[str]:
        """Sends a command to a test-node-ctl node and returns the lines it
        answers before its ``OK``; raises on ``ERROR`` or end of output."""
        self.command(text)
        lines = []
        while True:
            raw = self.readline()
            if raw == "":
                raise RuntimeError("node: %s: the node's output ended" % text)
            line = raw.rstrip("\n")
            if line == "OK":
                return lines
            if line.startswith("ERROR"):
                raise RuntimeError("node: %s: %s" % (text, line))
            lines.append(line)

    def stop(self) -> None:
        if self.proc.poll() is None:
            try:
                assert self.proc.stdin is not None
                self.proc.stdin.close()
                self.proc.wait(10)
            except (subprocess.TimeoutExpired, BrokenPipeError):
                self.proc.kill()
                self.proc.wait()


@pytest.fixture(scope="session")
def node() -> Iterator[Node]:
    n = Node("test-node.sh", PAIRINGS)
    yield n
    n.stop()


@pytest.fixture
def endpoint(node: Node) -> tuple:
    return ("127.0.0.1", node.port)


def run(coro):  # type: ignore[no-untyped-def]
    """Runs a coroutine to completion on a new event loop."""
    return asyncio.run(coro)


class XmppServer:
    """SPADE's embedded XMPP server (examples/spade/xmpp_server.py) on
    127.0.0.1; stops when its stdin closes."""

    def __init__(self) -> None:
        script = REPO / "clients" / "python" / "examples" / "spade" / "xmpp_server.py"
        self.proc = subprocess.Popen([sys.executable, str(script)], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=sys.stderr, text=True)
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline().strip()
        if not line.startswith("XMPP_PORT="):
            self.stop()
            raise RuntimeError("the XMPP server did not start: %r" % line)
        self.port = int(line.split("=", 1)[1])

    def stop(self) -> None:
        if self.proc.poll() is None:
            assert self.proc.stdin is not None
            self.proc.stdin.close()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


@pytest.fixture(scope="session")
def xmpp() -> Iterator[XmppServer]:
    pytest.importorskip("spade")
    s = XmppServer()
    yield s
    s.stop()

"""The quickstart of docs/clients.md, as written: the VA and the Avatar
programs run as OS processes against a real node."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from conftest import Node

HERE = Path(__file__).resolve().parents[1] / "examples" / "quickstart"


def test_quickstart_va_and_avatar() -> None:
    node = Node("test-node.sh", ["porch:va-secret:avatar-secret"])
    va = subprocess.Popen([sys.executable, str(HERE / "va.py"), str(node.port)],
                          stdout=subprocess.PIPE, text=True)
    try:
        assert va.stdout is not None
        assert va.stdout.readline().startswith("VA: joined")
        av = subprocess.run([sys.executable, str(HERE / "avatar.py"), str(node.port)],
                            capture_output=True, text=True, timeout=60)
        assert av.returncode == 0, av.stderr
        assert "lamp handled 3 requests; lamp on: True" in av.stdout
        lines = [va.stdout.readline().strip() for _ in range(3)]
        assert lines == ["VA: motion %d -> light says on" % n for n in (1, 2, 3)]
    finally:
        va.kill()
        va.wait()
        node.stop()

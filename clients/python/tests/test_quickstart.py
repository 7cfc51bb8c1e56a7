"""The quickstart of docs/clients.md, as written: the two example files are
the code blocks of the document, and that code runs as OS processes
against a real node (on a free port instead of 7400) and prints what the
document says."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path
from typing import List

from conftest import REPO, Node

HERE = REPO / "clients" / "python" / "examples" / "quickstart"


def doc_blocks() -> List[str]:
    text = (REPO / "docs" / "clients.md").read_text()
    python = text[text.index("## Python"):text.index("## Java")]
    return re.findall(r"```python\n(.*?)```", python, re.S)


def test_examples_are_the_documented_code() -> None:
    blocks = doc_blocks()
    assert (HERE / "va.py").read_text() == blocks[0]
    assert (HERE / "avatar.py").read_text() == blocks[1]


def test_quickstart_va_and_avatar(node: Node, tmp_path: Path) -> None:
    """On the session's node, whose ``porch`` pairing no other test uses."""
    port = str(node.port)
    for name in ("va.py", "avatar.py"):
        code = (HERE / name).read_text()
        assert code.count('("127.0.0.1", 7400)') == 1
        (tmp_path / name).write_text(code.replace('("127.0.0.1", 7400)',
                                                  '("127.0.0.1", %s)' % port))
    va = subprocess.Popen([sys.executable, str(tmp_path / "va.py")],
                          stdout=subprocess.PIPE, text=True)
    try:
        assert va.stdout is not None
        assert va.stdout.readline().strip() == "VA: joined, waiting for motion"
        av = subprocess.run([sys.executable, str(tmp_path / "avatar.py")],
                            capture_output=True, text=True, timeout=60)
        assert av.returncode == 0, av.stderr
        assert av.stdout.strip() == "Avatar: lamp handled 3 requests"
        lines = [va.stdout.readline().strip() for _ in range(3)]
        assert lines == ["VA: motion %d -> light says on" % n for n in (1, 2, 3)]
    finally:
        va.kill()
        va.wait()

"""Framing (docs/protocol.md section 1): a 4-byte big-endian length, then
one UTF-8 BIL document."""

from __future__ import annotations

import struct
from typing import List

__all__ = ["FrameError", "encode_frame", "FrameDecoder", "HANDSHAKE_MAX_FRAME", "MAX_FRAME"]

HANDSHAKE_MAX_FRAME = 65536
MAX_FRAME = 1048576


class FrameError(Exception):
    """A stream that is not made of acceptable frames; ``code`` is
    ``Malformed`` (length 0), ``FrameTooLarge`` or ``truncated``."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__("%s: %s" % (code, message))
        self.code = code
        self.message = message


def encode_frame(document: bytes) -> bytes:
    """One frame holding ``document``."""
    if not document:
        raise ValueError("a frame cannot be empty")
    if len(document) > 0xFFFFFFFF:
        raise ValueError("document too large for a frame")
    return struct.pack(">I", len(document)) + document


def check_length(n: int, max_frame: int) -> None:
    if n == 0:
        raise FrameError("Malformed", "a frame of length 0")
    if n > max_frame:
        raise FrameError("FrameTooLarge", "a frame of %d bytes is over the limit of %d"
                         % (n, max_frame))


class FrameDecoder:
    """Incremental decoder: ``feed(bytes)`` returns the complete documents.
    The length is checked from its 4 bytes alone, before the body arrives."""

    def __init__(self, max_frame: int = MAX_FRAME) -> None:
        self.max_frame = max_frame
        self._buf = bytearray()

    def feed(self, data: bytes) -> List[bytes]:
        self._buf += data
        out: List[bytes] = []
        while len(self._buf) >= 4:
            (n,) = struct.unpack(">I", bytes(self._buf[:4]))
            check_length(n, self.max_frame)
            if len(self._buf) < 4 + n:
                break
            out.append(bytes(self._buf[4:4 + n]))
            del self._buf[:4 + n]
        return out

    def close(self) -> None:
        """Raises ``truncated`` if the stream ended inside a frame."""
        if self._buf:
            raise FrameError("truncated", "the stream ended inside a frame (%d bytes left)"
                             % len(self._buf))

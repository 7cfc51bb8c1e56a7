"""TLS for the client (docs/clients.md, "TLS").

    tls = Tls(cafile="certs/ca.pem",                    # trust this CA ...
              certfile="certs/client-lamp.pem",         # ... and present this
              keyfile="certs/client-lamp.key")          #     client certificate
    Client([("evatar.local", 7401)], ..., tls=tls)

The server is checked against ``cafile`` (with its host name), or against
``pin_sha256``, the SHA-256 fingerprint of its certificate (hex; colons and
case do not matter), or both. With neither, the system's CAs are used.
Nothing of the protocol is sent before the server passed every check.
"""

from __future__ import annotations

import hashlib
import ssl
from dataclasses import dataclass
from typing import Optional

__all__ = ["Tls", "TlsError", "PinMismatch", "fingerprint"]


class TlsError(ssl.SSLError):
    """The server's certificate failed a check of this package."""


class PinMismatch(TlsError):
    """The server's certificate is not the pinned one."""

    def __init__(self, expected: str, got: str) -> None:
        super().__init__("the server's certificate SHA-256 is %s, the pinned one %s"
                         % (got, expected))
        self.expected, self.got = expected, got


def fingerprint(der: bytes) -> str:
    """The SHA-256 fingerprint of a DER certificate, lowercase hex."""
    return hashlib.sha256(der).hexdigest()


@dataclass
class Tls:
    """How to connect with TLS.

    :param cafile: the CA (PEM) the server's certificate must chain to.
    :param pin_sha256: the server certificate's SHA-256 fingerprint; alone,
        it replaces the CA check.
    :param certfile: a client certificate (PEM) to present, with
        ``keyfile`` (and ``password`` when the key is encrypted).
    :param server_hostname: the name the server's certificate must carry
        (default: the host connected to).
    """

    cafile: Optional[str] = None
    pin_sha256: Optional[str] = None
    certfile: Optional[str] = None
    keyfile: Optional[str] = None
    password: Optional[str] = None
    server_hostname: Optional[str] = None

    def context(self) -> ssl.SSLContext:
        """The SSL context for these settings."""
        if self.cafile is None and self.pin_sha256 is not None:
            # The pin, checked after the handshake, is the trust.
            ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
            ctx.check_hostname = False
            ctx.verify_mode = ssl.CERT_NONE
        else:
            ctx = ssl.create_default_context(cafile=self.cafile)
        ctx.minimum_version = ssl.TLSVersion.TLSv1_2
        if self.certfile is not None:
            ctx.load_cert_chain(self.certfile, self.keyfile, self.password)
        return ctx

    def check(self, ssl_object: Optional[ssl.SSLObject]) -> None:
        """Raises :class:`PinMismatch` unless the server's certificate is
        the pinned one (nothing to check without a pin)."""
        if self.pin_sha256 is None:
            return
        expected = self.pin_sha256.replace(":", "").lower()
        der = ssl_object.getpeercert(binary_form=True) if ssl_object is not None else None
        got = fingerprint(der) if der else "none"
        if got != expected:
            raise PinMismatch(expected, got)

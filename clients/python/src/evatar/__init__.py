"""EVATAR client SDK: embody a Python agent (a VA) in an Avatar, or write an
Avatar, through EVATAR's wire protocol (docs/protocol.md).

The core is asyncio (:class:`Client`); :class:`SyncClient` wraps it for
blocking code. :mod:`evatar.emulators` has the sensor and actuator
emulators, :mod:`evatar.bil` the documents, :mod:`evatar.frame` the framing.
"""

from .bil import (Ack, Binding, Bound, Bye, Component, Description, Entry, Hello, Refused,
                  Resume, Signal, Unbound, Welcome, encode, parse_frame)
from .client import (CLOSE_TIMEOUT, STDIO, AckTimeout, AlreadyConnectedError, Client, Closed,
                     ClosedError, ConnectError, EvatarError, FeedbackTimeout, Reconnected,
                     RefusedError, SignalError)
from .emulators import (Actuator, ActuatorEmulator, NotBoundError, NotConsumedError, Sensor,
                        SensorEmulator, describe)
from .frame import FrameDecoder, FrameError, encode_frame
from .sync import SyncClient
from .tls import PinMismatch, Tls, TlsError
from .xml import BilError

__version__ = "0.1.0"

__all__ = [
    "Ack", "Binding", "Bound", "Bye", "Component", "Description", "Entry", "Hello", "Refused",
    "Resume", "Signal", "Unbound", "Welcome", "encode", "parse_frame", "STDIO", "Client",
    "Closed", "ClosedError", "ConnectError", "EvatarError", "FeedbackTimeout", "Reconnected",
    "RefusedError", "SignalError", "Actuator", "ActuatorEmulator", "NotBoundError", "Sensor",
    "SensorEmulator", "describe", "FrameDecoder", "FrameError", "encode_frame", "SyncClient",
    "BilError", "Tls", "TlsError", "PinMismatch", "AlreadyConnectedError", "AckTimeout",
    "NotConsumedError", "CLOSE_TIMEOUT",
]

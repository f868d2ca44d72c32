"""The wire protocol between sensor clients, control peers and the server (no I/O here).

- :mod:`~kinefuse.protocol.messages`: one frozen dataclass per message, ``PROTOCOL_VERSION``;
- :mod:`~kinefuse.protocol.codec`: length-prefixed msgpack framing (``encode``, ``Decoder``);
- :mod:`~kinefuse.protocol.auth`: HMAC-SHA256 challenge-response;
- :mod:`~kinefuse.protocol.handshake`: the handshake's one state machine, driven by both ends;
- :mod:`~kinefuse.protocol.errors`: the exception tree (each error has a wire ``code``).

docs/protocol.md is the specification.

May import: errors, io (base), skeleton, geometry, camera, frames (sans-I/O: no sockets).
"""

from kinefuse.protocol.codec import MAX_FRAME_BYTES, Decoder, check_version, encode
from kinefuse.protocol.errors import (
    AuthError,
    EmptyFrame,
    FieldError,
    FrameTooLarge,
    FramingError,
    LimitExceeded,
    MalformedMessage,
    OutOfOrder,
    RemoteError,
    TruncatedFrame,
    UnknownMessageType,
    VersionError,
    WireError,
)
from kinefuse.protocol.fields import printable
from kinefuse.protocol.messages import (
    BODIES_VERSION,
    MAX_BODIES,
    MESSAGE_TYPES,
    PROTOCOL_VERSION,
    AuthReply,
    BodyFrameMessage,
    CalibrationResult,
    CalibrationStart,
    CalibrationStop,
    Challenge,
    ClockProbe,
    ClockReply,
    Error,
    FloorPlaneMessage,
    Goodbye,
    Heartbeat,
    Hello,
    Message,
    OtherBody,
    SensorInfo,
    Shutdown,
    Status,
    StatusRequest,
    WandSighting,
    Welcome,
)

__all__ = [
    "BODIES_VERSION",
    "MAX_BODIES",
    "MAX_FRAME_BYTES",
    "MESSAGE_TYPES",
    "PROTOCOL_VERSION",
    "AuthError",
    "AuthReply",
    "BodyFrameMessage",
    "CalibrationResult",
    "CalibrationStart",
    "CalibrationStop",
    "Challenge",
    "ClockProbe",
    "ClockReply",
    "Decoder",
    "EmptyFrame",
    "Error",
    "FieldError",
    "FloorPlaneMessage",
    "FrameTooLarge",
    "FramingError",
    "Goodbye",
    "Heartbeat",
    "Hello",
    "LimitExceeded",
    "MalformedMessage",
    "Message",
    "OtherBody",
    "OutOfOrder",
    "RemoteError",
    "SensorInfo",
    "Shutdown",
    "Status",
    "StatusRequest",
    "TruncatedFrame",
    "UnknownMessageType",
    "VersionError",
    "WandSighting",
    "Welcome",
    "WireError",
    "check_version",
    "encode",
    "printable",
]

"""The protocol's exception tree (all derive from :class:`kinefuse.errors.ProtocolError`).

Every error carries a short machine-readable :attr:`~WireError.code`, the ``code`` an
:class:`~kinefuse.live.protocol.messages.Error` message sends to the peer before closing::

    ProtocolError (kinefuse.errors)
    └── WireError                    code
        ├── FramingError             the byte stream is broken; the decoder is dead after it
        │   ├── FrameTooLarge        "oversize"   length prefix above the maximum frame size
        │   ├── EmptyFrame           "malformed"  length prefix 0
        │   └── TruncatedFrame       "truncated"  the stream ended inside a frame
        ├── MalformedMessage         "malformed"  not msgpack, not a map, no string "type"
        ├── UnknownMessageType       "unknown_type"  a type this version does not know
        ├── FieldError               "field"      a field missing, of the wrong type, shape,
        │                                         dtype or out of its range
        ├── VersionError             "version"    the peer speaks another major version
        ├── AuthError                "auth"       a wrong or missing HMAC
        ├── OutOfOrder               "order"      a message not allowed in this state/role
        ├── LimitExceeded            "limit"      too many messages a second, too many unknown
        │                                         ones in a row, requests too often
        └── RemoteError              (the peer's)  the peer sent an Error message

After a :class:`FramingError` the stream cannot be resynchronized and the connection must be
closed. After the others the offending frame was consumed whole, so the decoder can go on (the
connection layer decides: see ``docs/protocol.md``, "What closes a connection").
"""

from __future__ import annotations

from typing import Any

from kinefuse.errors import ProtocolError


class WireError(ProtocolError):
    """Base of the protocol's errors; :attr:`code` is what an ``Error`` message carries.

    :attr:`decoded`: when raised by ``Decoder.feed``, the messages decoded before the bad frame
    in that call (handle them, then close). :attr:`reply`: when raised by a peer's
    :class:`~kinefuse.live.protocol.handshake.Handshake`, the message to send before closing.
    """

    code = "protocol"
    decoded: list[Any] = []  # noqa: RUF012 (replaced per instance, never mutated)
    reply: Any = None


class FramingError(WireError):
    """The length-prefixed framing is broken (the stream cannot be resynchronized)."""

    code = "malformed"


class FrameTooLarge(FramingError):
    """A length prefix announced more than the maximum frame size (checked before buffering)."""

    code = "oversize"

    def __init__(self, length: int, limit: int) -> None:
        super().__init__(
            f"frame of {length} bytes announced, the limit is {limit} bytes; "
            "send smaller messages (a depth image never crosses the wire, only sightings)"
        )
        self.length = length
        self.limit = limit


class EmptyFrame(FramingError):
    """A length prefix of 0 (every frame holds a msgpack map)."""

    code = "malformed"


class TruncatedFrame(FramingError):
    """The stream ended inside a frame (``Decoder.close`` with bytes still buffered)."""

    code = "truncated"


class MalformedMessage(WireError):
    """A frame's body is not a msgpack map with a string ``type``."""

    code = "malformed"


class UnknownMessageType(WireError):
    """A frame of a ``type`` this protocol version does not define."""

    code = "unknown_type"

    def __init__(self, type_name: str) -> None:
        super().__init__(
            f"unknown message type {type_name!r}; this peer speaks protocol "
            "version 1 (see docs/protocol.md for the types it knows)"
        )
        self.type_name = type_name


class FieldError(WireError):
    """A field of a known message is missing, mistyped, of the wrong shape or out of range."""

    code = "field"

    def __init__(self, message_type: str, field: str, reason: str) -> None:
        super().__init__(f"{message_type}.{field}: {reason}")
        self.message_type = message_type
        self.field = field
        self.reason = reason


class VersionError(WireError):
    """The peer speaks a protocol major version this one cannot talk to."""

    code = "version"


class AuthError(WireError):
    """Authentication failed (wrong token, missing reply, or a token needed but none given)."""

    code = "auth"


class OutOfOrder(WireError):
    """A valid message that is not allowed from this sender or in this connection state."""

    code = "order"


class LimitExceeded(WireError):
    """The peer exceeded a rate or count limit (a flood: see docs/protocol.md, "Limits")."""

    code = "limit"


class RemoteError(WireError):
    """The peer sent an ``Error`` message; :attr:`code` is the peer's code."""

    def __init__(self, code: str, reason: str) -> None:
        super().__init__(f"the peer refused: {reason} (code {code!r})")
        self.code = code
        self.reason = reason


#: every ``code`` an Error message may carry, and what it means (docs/protocol.md lists them)
ERROR_CODES: dict[str, str] = {
    "oversize": "a frame's length prefix is above the maximum frame size",
    "truncated": "the stream ended inside a frame",
    "malformed": "a frame is empty, not msgpack, not a map, or has no string type",
    "unknown_type": "a message type this version does not know (from a peer of our version)",
    "field": "a field is missing, of the wrong type, shape or dtype, or out of range",
    "version": "the peer speaks another major protocol version",
    "auth": "authentication failed, or a token is needed and the peer gave none",
    "order": "a message not allowed from this role or in this connection state",
    "duplicate_id": "a sensor with this id is already connected",
    "timeout": "nothing heard for the agreed timeout (or no Hello in time)",
    "limit": "the peer sent too much: messages too fast, unknown ones in a row, requests too often",
    "busy": "the server accepts no more peers",
    "internal": "the sender failed (a bug); the connection closes, the process goes on",
}

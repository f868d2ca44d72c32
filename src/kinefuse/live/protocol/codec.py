"""Sans-I/O codec: messages in, bytes out; bytes in, messages out. No sockets, no clocks.

A frame is a 4-byte big-endian unsigned length ``n`` followed by ``n`` bytes of one msgpack
map: ``{"type": <wire type>, <field>: <value>, ...}`` (see docs/protocol.md). ::

    data = encode(Hello(role="sensor", sensor_id="k0", intrinsics=Intrinsics()))
    dec = Decoder()
    for msg in dec.feed(data):   # any chunking: bytes are buffered until a frame is whole
        ...

Limits a hostile peer cannot get around: a frame's length is checked against
``max_frame_bytes`` from its 4-byte prefix, before its body is buffered
(:class:`~kinefuse.live.protocol.wire_errors.FrameTooLarge`); msgpack is decoded with bounded
string, binary, list and map sizes and no extension types; every field is checked by its kind
(:mod:`kinefuse.live.protocol.fields`). The buffer never holds more than one frame plus one fed
chunk.
"""

from __future__ import annotations

import struct
from collections import Counter
from typing import Any

import msgpack

from kinefuse.live.protocol.fields import Version
from kinefuse.live.protocol.messages import (
    MESSAGE_TYPES,
    PROTOCOL_VERSION,
    Hello,
    Message,
    Welcome,
    message_fields,
)
from kinefuse.live.protocol.wire_errors import (
    EmptyFrame,
    FieldError,
    FrameTooLarge,
    FramingError,
    LimitExceeded,
    MalformedMessage,
    TruncatedFrame,
    UnknownMessageType,
    VersionError,
    WireError,
)

#: the largest frame body either side sends or accepts, bytes (1 MiB)
MAX_FRAME_BYTES = 1 << 20
#: the length prefix: 4-byte big-endian unsigned
HEADER = struct.Struct(">I")

_MAX_CONTAINER = 4096  # msgpack list/map entries in one container
#: distinct unknown type names :attr:`Decoder.ignored` keeps by name
MAX_IGNORED_NAMES = 32


def _no_ext(code: int, data: bytes) -> Any:
    raise MalformedMessage(f"msgpack extension type {code} is not used by this protocol")


def to_wire(msg: Message) -> dict[str, Any]:
    """The msgpack map of ``msg`` (``type`` plus every field, encoded by its kind)."""
    out: dict[str, Any] = {"type": msg.TYPE}
    for name, kind in message_fields(type(msg)):
        out[name] = kind.encode(getattr(msg, name))
    return out


def encode(msg: Message, *, max_frame_bytes: int = MAX_FRAME_BYTES) -> bytes:
    """One frame (length prefix + msgpack body) for ``msg``.

    Raises
    ------
    FrameTooLarge
        If the body exceeds ``max_frame_bytes`` (the peer would refuse it).
    ValueError
        If an array field has the wrong shape.
    """
    body = msgpack.packb(to_wire(msg), use_bin_type=True)
    if len(body) > max_frame_bytes:
        raise FrameTooLarge(len(body), max_frame_bytes)
    return HEADER.pack(len(body)) + body


def check_version(peer: tuple[int, int], *, ours: tuple[int, int] = PROTOCOL_VERSION) -> None:
    """Raise :class:`VersionError` unless ``peer`` has our major version (any minor)."""
    if peer[0] != ours[0]:
        raise VersionError(
            f"the peer speaks protocol {peer[0]}.{peer[1]}, this side {ours[0]}.{ours[1]}; "
            "major versions must match: upgrade the older side"
        )


def from_wire(raw: Any, *, peer_version: tuple[int, int] | None = None) -> Message | None:
    """The message of one decoded msgpack value, checked field by field.

    Returns None for an unknown ``type`` when ``peer_version`` is a newer minor version of ours
    (its new messages are skipped); raises :class:`UnknownMessageType` otherwise. Unknown fields
    are ignored (a newer minor version may add optional fields). A Hello or Welcome of another
    major version raises :class:`VersionError` before its other fields are looked at.
    """
    if not isinstance(raw, dict):
        raise MalformedMessage(f"a frame must hold a msgpack map, got {type(raw).__name__}")
    type_name = raw.get("type")
    if not isinstance(type_name, str):
        raise MalformedMessage("a frame's map has no string 'type' field")
    cls = MESSAGE_TYPES.get(type_name)
    if cls is None:
        if (
            peer_version is not None
            and peer_version[0] == PROTOCOL_VERSION[0]
            and peer_version[1] > PROTOCOL_VERSION[1]
        ):
            return None
        raise UnknownMessageType(type_name[:64])
    if cls in (Hello, Welcome) and "protocol_version" in raw:
        check_version(Version().decode(raw["protocol_version"], type_name, "protocol_version"))
    values = {}
    for name, kind in message_fields(cls):
        if name in raw:
            values[name] = kind.decode(raw[name], type_name, name)
    try:
        msg = cls(**values)
    except TypeError:
        missing = [n for n, _ in message_fields(cls) if n not in values]
        raise FieldError(type_name, missing[0] if missing else "?", "missing") from None
    msg.check()
    return msg


def decode_body(body: bytes, *, peer_version: tuple[int, int] | None = None) -> Message | None:
    """The message of one frame body (without its length prefix); see :func:`from_wire`."""
    try:
        raw = msgpack.unpackb(
            body,
            raw=False,
            strict_map_key=True,
            use_list=True,
            ext_hook=_no_ext,
            max_str_len=len(body),
            max_bin_len=len(body),
            max_array_len=_MAX_CONTAINER,
            max_map_len=_MAX_CONTAINER,
            max_ext_len=len(body),
        )
    except WireError:
        raise
    except Exception as e:  # msgpack raises several unrelated types for garbage
        raise MalformedMessage(
            f"frame body is not valid msgpack ({type(e).__name__}: {e})"[:300]
        ) from None
    return from_wire(raw, peer_version=peer_version)


class Decoder:
    """Turns a byte stream (fed in any chunks) into messages.

    Parameters
    ----------
    max_frame_bytes : int
        Frames announcing a larger body raise :class:`FrameTooLarge` (from the prefix alone).
        An attribute: a server lowers it until a peer is authenticated.
    max_ignored_run : int
        Unknown message types skipped in a row (no known message between them) above which
        :class:`LimitExceeded` is raised: a newer peer's new messages come among the ones we
        know, a stream of nothing but unknown ones is a flood.

    Attributes
    ----------
    peer_version : (int, int) or None
        The version the peer announced in its Hello or Welcome (recorded when decoded; or set
        it). Unknown message types from a newer minor version are skipped and counted.
    ignored : collections.Counter
        Skipped unknown message types by name (at most ``MAX_IGNORED_NAMES`` names; the
        others are counted under ``"..."``).
    """

    def __init__(
        self, *, max_frame_bytes: int = MAX_FRAME_BYTES, max_ignored_run: int = 256
    ) -> None:
        if max_frame_bytes < 1:
            raise ValueError(f"max_frame_bytes must be >= 1, got {max_frame_bytes}")
        self.max_frame_bytes = max_frame_bytes
        self.peer_version: tuple[int, int] | None = None
        self.ignored: Counter[str] = Counter()
        self.max_ignored_run = max_ignored_run
        self._ignored_run = 0
        self._buf = bytearray()
        self._broken: FramingError | None = None
        self.n_frames = 0

    @property
    def buffered(self) -> int:
        """Bytes held waiting for the rest of a frame."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[Message]:
        """Buffer ``data`` and return every message completed by it, in order.

        Raises
        ------
        FramingError
            The stream is broken (oversized or empty frame); the decoder refuses any more data.
        MalformedMessage, UnknownMessageType, FieldError, VersionError
            One frame was bad; it was consumed, later bytes stay buffered (call ``feed(b"")``
            to go on). Messages decoded before it in this call are in the exception's
            ``decoded`` attribute.
        """
        if self._broken is not None:
            raise self._broken
        self._buf += data
        out: list[Message] = []
        while True:
            try:
                msg, more = self._next()
            except WireError as e:
                e.decoded = out
                if isinstance(e, FramingError):
                    self._broken = e
                    self._buf.clear()
                raise
            if not more:
                return out
            if msg is not None:
                out.append(msg)

    def _next(self) -> tuple[Message | None, bool]:
        buf = self._buf
        if len(buf) < HEADER.size:
            return None, False
        (n,) = HEADER.unpack_from(buf)
        if n > self.max_frame_bytes:
            raise FrameTooLarge(n, self.max_frame_bytes)
        if n == 0:
            raise EmptyFrame("a frame of length 0; every frame holds a msgpack map")
        end = HEADER.size + n
        if len(buf) < end:
            return None, False
        body = bytes(buf[HEADER.size : end])
        del buf[:end]
        self.n_frames += 1
        msg = decode_body(body, peer_version=self.peer_version)
        if msg is None:
            name = _peek_type(body)
            if name not in self.ignored and len(self.ignored) >= MAX_IGNORED_NAMES:
                name = "..."
            self.ignored[name] += 1
            self._ignored_run += 1
            if self._ignored_run > self.max_ignored_run:
                raise LimitExceeded(
                    f"{self._ignored_run} unknown messages in a row (at most "
                    f"{self.max_ignored_run}): a flood, not a newer peer"
                )
            return msg, True
        self._ignored_run = 0
        if isinstance(msg, Hello | Welcome):
            self.peer_version = msg.protocol_version
        return msg, True

    def close(self) -> None:
        """The stream ended: raise :class:`TruncatedFrame` if a partial frame is buffered."""
        if self._buf and self._broken is None:
            n = len(self._buf)
            self._buf.clear()
            raise TruncatedFrame(f"the stream ended {n} bytes into an unfinished frame")


def _peek_type(body: bytes) -> str:
    try:
        t = msgpack.unpackb(body, raw=False).get("type", "?")
    except Exception:
        return "?"
    return str(t)[:64]

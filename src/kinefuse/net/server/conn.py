"""One TCP connection of the server: bytes to messages and back, with arrival stamps.

Only moves bytes: the sans-I/O :class:`~kinefuse.protocol.codec.Decoder` turns them into
messages, :func:`~kinefuse.protocol.codec.encode` back. Sending never awaits (the transport
buffers), so a broadcast or the fusion loop never waits for a slow peer; a peer that lets more
than ``max_buffer_bytes`` pile up unread is cut off (it cannot stall the server or grow its
memory without bound).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections import deque
from collections.abc import Callable

from kinefuse.protocol import Decoder, Error, Message, WireError, encode
from kinefuse.protocol.errors import OutOfOrder

log = logging.getLogger("kinefuse.serve")


class ConnectionClosed(Exception):
    """The peer closed the connection (``reason`` says how)."""


class PeerTimeout(WireError):
    """Nothing heard from the peer for the agreed timeout."""

    code = "timeout"


class TooSlow(WireError):
    """The peer does not read what the server sends (or the server is full)."""

    code = "busy"


class DuplicateSensor(WireError):
    """A second connection claims a sensor id that is connected."""

    code = "duplicate_id"


class Connection:
    """Message I/O on one accepted stream.

    Parameters
    ----------
    reader, writer : asyncio streams
    clock : callable
        The server clock (s); every message is stamped with the time its bytes were read.
    max_frame_bytes : int
    max_buffer_bytes : int
        Unsent bytes above which the peer is cut off as not reading.
    """

    def __init__(
        self,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        clock: Callable[[], float],
        *,
        max_frame_bytes: int,
        max_buffer_bytes: int = 4 << 20,
    ) -> None:
        self.reader = reader
        self.writer = writer
        self.clock = clock
        self.decoder = Decoder(max_frame_bytes=max_frame_bytes)
        self.max_buffer_bytes = max_buffer_bytes
        peer = writer.get_extra_info("peername")
        self.peer = f"{peer[0]}:{peer[1]}" if isinstance(peer, tuple) else str(peer)
        self.role = "?"
        self.name = self.peer
        self.closed = False
        self.last_sent = clock()
        self.last_heard = clock()
        self.sent = 0
        self._inbox: deque[tuple[Message, float]] = deque()
        self._cut: WireError | None = None
        self._error: WireError | None = None

    def send(self, msg: Message) -> None:
        """Queue ``msg`` for sending (never blocks); cut a peer that does not read."""
        if self.closed:
            return
        transport = self.writer.transport
        if transport.is_closing():
            return
        if transport.get_write_buffer_size() > self.max_buffer_bytes:
            self._cut = TooSlow(
                f"{self.name} does not read what the server sends "
                f"({transport.get_write_buffer_size()} bytes unsent); closing its connection"
            )
            transport.abort()
            return
        self.writer.write(encode(msg))
        self.sent += 1
        self.last_sent = self.clock()

    async def recv(self, timeout_s: float) -> tuple[Message, float]:
        """The next message and the server time its bytes arrived.

        Raises
        ------
        WireError
            A bad frame (the decoder's error), or :class:`PeerTimeout`.
        ConnectionClosed
            The peer closed (or reset) the connection.
        """
        while not self._inbox:
            if self._cut is not None:
                raise self._cut
            if self._error is not None:
                raise self._error
            try:
                data = await asyncio.wait_for(self.reader.read(65536), timeout_s)
            except TimeoutError:
                raise PeerTimeout(f"nothing heard from {self.name} for {timeout_s:g} s") from None
            except (ConnectionError, OSError) as e:
                raise ConnectionClosed(f"connection lost ({type(e).__name__}: {e})") from None
            t = self.clock()
            if not data:
                self.decoder.close()  # raises TruncatedFrame inside a frame
                raise ConnectionClosed("the peer closed the connection")
            self.last_heard = t
            try:
                msgs = self.decoder.feed(data)
            except WireError as e:  # deliver what came before the bad frame, then the error
                self._inbox.extend((m, t) for m in getattr(e, "decoded", []))
                self._error = e
                continue
            self._inbox.extend((m, t) for m in msgs)
        return self._inbox.popleft()

    def check_sender(self, msg: Message) -> None:
        """Raise ``OutOfOrder`` for a message this peer's role may not send."""
        if self.role not in msg.SENDERS:
            raise OutOfOrder(f"a {self.role} peer may not send {msg.TYPE}")

    def refuse(self, code: str, reason: str) -> None:
        """Send ``Error(code, reason)`` (best effort) and close."""
        if not self.closed:
            with contextlib.suppress(Exception):
                self.send(Error(code=code[:32], reason=reason[:1024]))
        self.close()

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        with contextlib.suppress(Exception):
            self.writer.close()

    async def wait_closed(self) -> None:
        with contextlib.suppress(TimeoutError, ConnectionError, OSError):
            await asyncio.wait_for(self.writer.wait_closed(), 2.0)

"""One TCP connection of the server: bytes to messages and back, with arrival stamps.

Only moves bytes: the sans-I/O :class:`~kinefuse.live.protocol.codec.Decoder` turns them into
messages, :func:`~kinefuse.live.protocol.codec.encode` back. Sending never awaits (the transport
buffers), so a broadcast or the fusion loop never waits for a slow peer.

What a hostile peer cannot do here (issue 23):

- keep a connection open by dribbling bytes: :meth:`Connection.recv` waits for a whole
  *message* until its deadline, and bytes that complete none do not move the deadline (a byte a
  second, or a 1 MiB frame sent slowly, is closed with ``timeout`` like silence);
- flood: every frame (including unknown types that are skipped) takes a token from the peer's
  bucket (``msg_rate`` a second, ``msg_burst`` at once); a peer above it is closed with
  ``limit``. Bytes are decoded in slices of ``SLICE_BYTES`` with a yield to the event loop
  between them, so one 64 KiB read of tiny frames cannot hold the loop for long;
- stop reading: a peer whose unsent bytes stay above ``stall_bytes`` for ``stall_s`` (or ever
  exceed ``max_buffer_bytes``) is cut off; it cannot stall the server or grow its memory.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections import deque
from collections.abc import Callable

from kinefuse.live.protocol import Decoder, Error, Message, WireError, encode
from kinefuse.live.protocol.handshake import Handshake
from kinefuse.live.protocol.wire_errors import LimitExceeded, OutOfOrder
from kinefuse.live.server.peer_limits import TokenBucket

#: bytes decoded at a time before the event loop gets a turn
SLICE_BYTES = 4096

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
        The decoder's limit (the server lowers it until the handshake is done, then raises it:
        :attr:`Decoder.max_frame_bytes`).
    max_buffer_bytes : int
        Unsent bytes above which the peer is cut off as not reading.
    stall_bytes, stall_s : int, float
        A peer whose unsent bytes stay above ``stall_bytes`` for ``stall_s`` is cut off too.
    msg_rate, msg_burst : float
        Frames the peer may send per second on average, and at once.
    token : str or None
        The server's token: its :attr:`handshake` (the sans-I/O
        :class:`~kinefuse.live.protocol.handshake.Handshake`, server side) challenges with it.
    """

    def __init__(
        self,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        clock: Callable[[], float],
        *,
        max_frame_bytes: int,
        max_buffer_bytes: int = 1 << 20,
        stall_bytes: int = 64 << 10,
        stall_s: float = 5.0,
        msg_rate: float = 600.0,
        msg_burst: float = 1200.0,
        token: str | None = None,
    ) -> None:
        self.reader = reader
        self.writer = writer
        self.clock = clock
        self.decoder = Decoder(max_frame_bytes=max_frame_bytes)
        self.handshake = Handshake("server", token)
        self.max_buffer_bytes = max_buffer_bytes
        self.stall_bytes = stall_bytes
        self.stall_s = stall_s
        self._stalled_since: float | None = None
        self.bucket = TokenBucket(msg_rate, msg_burst, clock())
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
        unsent = transport.get_write_buffer_size()
        now = self.clock()
        if unsent <= self.stall_bytes:
            self._stalled_since = None
        elif self._stalled_since is None:
            self._stalled_since = now
        if unsent > self.max_buffer_bytes or (
            self._stalled_since is not None and now - self._stalled_since > self.stall_s
        ):
            self._cut = TooSlow(
                f"{self.name} does not read what the server sends ({unsent} bytes unsent"
                f"{'' if unsent > self.max_buffer_bytes else f' for {self.stall_s:g} s'}); "
                "closing its connection"
            )
            transport.abort()
            return
        self.writer.write(encode(msg))
        self.sent += 1
        self.last_sent = now

    async def recv(
        self, timeout_s: float, *, deadline: float | None = None
    ) -> tuple[Message, float]:
        """The next message and the server time its bytes arrived.

        ``timeout_s`` bounds the wait for a whole message (bytes that complete none do not
        extend it); ``deadline`` (server time), when given, bounds it further (a handshake's).

        Raises
        ------
        WireError
            A bad frame (the decoder's error), :class:`PeerTimeout`, or :class:`LimitExceeded`.
        ConnectionClosed
            The peer closed (or reset) the connection.
        """
        end = self.clock() + timeout_s
        if deadline is not None and deadline < end:
            end, timeout_s = deadline, max(deadline - self.clock(), 0.0)
        while not self._inbox:
            if self._cut is not None:
                raise self._cut
            if self._error is not None:
                raise self._error
            left = end - self.clock()
            if left <= 0:
                part = self.decoder.buffered
                raise PeerTimeout(
                    f"no whole message from {self.name} for {timeout_s:g} s"
                    + (f" ({part} bytes of a frame)" if part else "")
                )
            try:
                # asyncio.timeout, not wait_for: no task per read (a read per frame, 720 a
                # second with 24 sensors)
                async with asyncio.timeout(left):
                    data = await self.reader.read(65536)
            except TimeoutError:
                continue  # raises PeerTimeout above
            except (ConnectionError, OSError) as e:
                raise ConnectionClosed(f"connection lost ({type(e).__name__}: {e})") from None
            t = self.clock()
            if not data:
                self.decoder.close()  # raises TruncatedFrame inside a frame
                raise ConnectionClosed("the peer closed the connection")
            self.last_heard = t
            await self._feed(data, t)
        return self._inbox.popleft()

    async def _feed(self, data: bytes, t: float) -> None:
        """Decode ``data`` a slice at a time (the loop gets a turn between slices), every frame
        taking a token from the peer's bucket."""
        for i in range(0, len(data), SLICE_BYTES):
            if i:
                await asyncio.sleep(0)
            n0 = self.decoder.n_frames
            try:
                msgs = self.decoder.feed(data[i : i + SLICE_BYTES])
            except WireError as e:  # deliver what came before the bad frame, then the error
                self._inbox.extend((m, t) for m in getattr(e, "decoded", []))
                self._error = e
                return
            self._inbox.extend((m, t) for m in msgs)
            n = self.decoder.n_frames - n0
            if n and not self.bucket.take(t, n):
                self._error = LimitExceeded(
                    f"{self.name} sends more than {self.bucket.rate:g} messages a second "
                    f"(bursts of {self.bucket.burst:g})"
                )
                return

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

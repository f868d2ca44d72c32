"""What a peer on the viewer/API port can cost the server, and which names it is served under
(``docs/security.md``).

Anyone who reaches the port may connect; no credential is needed to send HTTP headers. So:

- **Connections are counted** in total and per peer address (:class:`PortLimits`); one above
  either cap is reset as it is accepted, before a byte is read (no buffer, no task, no log line
  of its own). The total cap comes from the descriptor limit, less a reserve for the sensor
  port, the recording and the process itself (:func:`capacity`): the viewer can never take the
  descriptors a (re)connecting sensor needs.
- **A request's headers have a deadline** (:attr:`PortLimits.header_timeout_s`) from the
  accept, or from the end of the previous response on a kept-alive connection, to the whole
  request line and headers, whatever trickles in meanwhile; the WebSocket upgrade is such a
  request. A connection past it is closed. Until its first request head is whole, a
  connection's bytes are only held (at most :data:`MAX_HEAD_BYTES`): the HTTP machinery
  (parser, task) is made for a connection that has sent one.
- **Refusals and failed accepts are logged once per interval** with their count
  (:class:`RateLog`), never a line (or a traceback) per event: the port accepts its
  connections itself (:class:`Admission`), so a refusal costs an accept and a close, no
  transport.
- **The ``Host`` header must be a name the server answers to** (:class:`HostNames`): its bind
  address, the loopback names and the names it was given, so that a web page on another site
  whose name was re-pointed at this machine (DNS rebinding) is refused; and a browser's
  ``Origin`` on a WebSocket must be this server, compared by scheme, host and port.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import ipaddress
import logging
import re
import resource
import socket
import struct
import time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any
from urllib.parse import urlsplit

log = logging.getLogger("kinefuse.live.viewer")

#: the names every server answers to (this machine's own loopback)
LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1")
#: bind addresses that mean "every interface": any IP literal is then a name of the server
WILDCARD_HOSTS = ("", "0.0.0.0", "::")
#: a request head (request line and headers) longer than this is refused (aiohttp's own limits
#: are lower: this only bounds what a connection holds before the HTTP parser sees it)
MAX_HEAD_BYTES = 64 * 1024
#: the listen backlog, which is also how many connections are accepted in one turn of the
#: loop: a flood of connections is taken in small bites between the fusion's own callbacks
ACCEPT_BATCH = 16

_NAME = re.compile(r"[a-z0-9_]([a-z0-9_-]*[a-z0-9_])?(\.[a-z0-9_]([a-z0-9_-]*[a-z0-9_])?)*")


@dataclass(frozen=True)
class PortLimits:
    """The limits of the viewer/API port.

    Parameters
    ----------
    header_timeout_s : float
        A request line and its headers must be complete this long after the accept (or after
        the previous response on a kept-alive connection); the connection is closed otherwise.
    max_connections : int
        Connections at most, in total (lowered to what the descriptor limit leaves, see
        :func:`capacity`).
    max_per_address : int
        Connections at most from one peer address.
    fd_reserve : int
        Descriptors kept for everything but the viewer: the sensor port (its sensors, handshakes
        and control peers), the recording, the process's own files (at most half the limit).
    log_every_s : float
        Refusals and failed accepts are logged at most once per this interval, with a count.
    """

    header_timeout_s: float = 5.0
    max_connections: int = 512
    max_per_address: int = 64
    fd_reserve: int = 256
    log_every_s: float = 10.0


def raise_descriptor_limit() -> int:
    """Raise this process's soft ``RLIMIT_NOFILE`` to its hard limit; the soft limit now."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard != soft:
        target = hard if hard != resource.RLIM_INFINITY else max(soft, 1 << 20)
        with contextlib.suppress(ValueError, OSError):  # (a kernel cap below the hard limit)
            resource.setrlimit(resource.RLIMIT_NOFILE, (target, hard))
        soft = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
    return soft if soft != resource.RLIM_INFINITY else 1 << 20


def capacity(limits: PortLimits, nofile: int) -> int:
    """Connections the viewer may hold under a descriptor limit of ``nofile``: at most
    ``limits.max_connections``, and never the ``limits.fd_reserve`` descriptors (at most half
    of the limit) kept for the rest of the server."""
    reserve = min(limits.fd_reserve, nofile // 2)
    return max(1, min(limits.max_connections, nofile - reserve))


class RateLog:
    """Counts events and logs them at most once per ``every_s`` with their count: the first at
    once, the others summed into one line when the interval is over."""

    def __init__(self, what: str, every_s: float) -> None:
        self.what = what
        self.every_s = every_s
        #: events counted since this object was made
        self.total = 0
        self._unlogged = 0
        self._next_s = -float("inf")
        self._flush: asyncio.TimerHandle | None = None

    def add(self) -> None:
        self.total += 1
        self._unlogged += 1
        now = time.monotonic()
        if now >= self._next_s:
            self.flush()
        elif self._flush is None:
            with contextlib.suppress(RuntimeError):  # (no running loop: the next add logs)
                loop = asyncio.get_running_loop()
                self._flush = loop.call_later(self._next_s - now, self.flush)

    def flush(self) -> None:
        """Log what is counted and not yet logged (nothing if nothing is)."""
        if self._flush is not None:
            self._flush.cancel()
            self._flush = None
        if self._unlogged:
            log.warning("%s: %d in the last %g s", self.what, self._unlogged, self.every_s)
            self._unlogged = 0
            self._next_s = time.monotonic() + self.every_s


def reset(transport: Any, sock: Any = None) -> None:
    """Drop the connection now with a TCP reset: what is queued for it is discarded (a plain
    close would leave the kernel trying to deliver it to a peer that never reads)."""
    if sock is None and transport is not None:
        sock = transport.get_extra_info("socket")
    if sock is not None:
        with contextlib.suppress(OSError, ValueError):
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    if transport is not None:
        transport.abort()


class Admission:
    """The listening sockets of one port and what they accept: each connection counted in total
    and per address as it is accepted, and reset there, before asyncio makes a transport for
    it, when it is above a cap; an admitted one gets its header deadline, until
    :meth:`Guarded.disarm` (the app's middleware, once a request has come). Failed accepts (no
    descriptor left) are counted, and the socket rests a second before it accepts again."""

    def __init__(
        self, limits: PortLimits, capacity: int, make_inner: Callable[[], asyncio.Protocol]
    ) -> None:
        self.limits = limits
        self.capacity = capacity
        self.make_inner = make_inner
        self.total = 0
        self.by_address: Counter[str] = Counter()
        self.sockets: list[socket.socket] = []
        #: the admitted connections that are open
        self.connections: set[Guarded] = set()
        self.refused = RateLog(
            f"viewer port: connections refused at accept (caps: {capacity} in total, "
            f"{limits.max_per_address} per address)",
            limits.log_every_s,
        )
        self.expired = RateLog(
            f"viewer port: connections closed without a whole request head within "
            f"{limits.header_timeout_s:g} s (or over {MAX_HEAD_BYTES // 1024} KiB)",
            limits.log_every_s,
        )
        self.failed = RateLog(
            "viewer port: accepts failed for want of descriptors (the port rests 1 s each time)",
            limits.log_every_s,
        )
        self._tasks: set[asyncio.Task[Any]] = set()

    async def listen(self, host: str, port: int) -> int:
        """Bind ``host:port`` (every address it resolves to), listen, and accept on the running
        loop; the bound port (OSError if nothing could be bound)."""
        loop = asyncio.get_running_loop()
        infos = await loop.getaddrinfo(
            host or None, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
        )
        error: OSError | None = None
        for family, kind, proto, _name, address in dict.fromkeys(infos):
            sock = socket.socket(family, kind, proto)
            try:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                if family == socket.AF_INET6:
                    sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
                sock.bind(address)
                sock.listen(ACCEPT_BATCH)
                sock.setblocking(False)
            except OSError as e:
                sock.close()
                error = e
                continue
            self.sockets.append(sock)
            loop.add_reader(sock.fileno(), self._accept, sock)
        if not self.sockets:
            raise error or OSError(f"{host!r} resolves to no address")
        return int(self.sockets[0].getsockname()[1])

    def _accept(self, sock: socket.socket) -> None:
        loop = asyncio.get_running_loop()
        for _ in range(ACCEPT_BATCH):
            try:
                conn, peer = sock.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as e:
                if e.errno not in (errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM):
                    continue  # (the peer gave up before the accept: ECONNABORTED and the like)
                self.failed.add()
                loop.remove_reader(sock.fileno())
                loop.call_later(1.0, self._resume, sock)
                return
            address = str(peer[0]) if isinstance(peer, tuple) and peer else ""
            if (
                self.total >= self.capacity
                or self.by_address[address] >= self.limits.max_per_address
            ):
                self.refused.add()
                with contextlib.suppress(OSError):  # a reset: nothing lingers
                    conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
                conn.close()
                continue
            self.total += 1
            self.by_address[address] += 1
            conn.setblocking(False)
            task = loop.create_task(self._connect(conn, Guarded(self, address)))
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)

    async def _connect(self, conn: socket.socket, guarded: Guarded) -> None:
        loop = asyncio.get_running_loop()
        try:
            await loop.connect_accepted_socket(lambda: guarded, conn)
        except OSError:
            conn.close()
            guarded.connection_lost(None)  # (its count released, once)

    def _resume(self, sock: socket.socket) -> None:
        if sock in self.sockets:
            asyncio.get_running_loop().add_reader(sock.fileno(), self._accept, sock)

    def release(self, address: str) -> None:
        """A connection from ``address`` is gone."""
        self.total -= 1
        self.by_address[address] -= 1
        if self.by_address[address] <= 0:
            del self.by_address[address]

    def close(self) -> None:
        """Stop listening, close the connections the HTTP server does not know yet (those that
        have not sent a whole request head), and log what is counted."""
        loop = asyncio.get_running_loop()
        for sock in self.sockets:
            loop.remove_reader(sock.fileno())
            sock.close()
        self.sockets = []
        for task in list(self._tasks):
            task.cancel()
        for conn in list(self.connections):
            if conn.inner is None and conn.transport is not None:
                conn.transport.abort()
        self.refused.flush()
        self.expired.flush()
        self.failed.flush()


class Guarded(asyncio.Protocol):
    """One admitted connection: its bytes are held until they hold a whole request head (the
    request line and headers, up to :data:`MAX_HEAD_BYTES`), and only then handed to the HTTP
    protocol (``admission.make_inner``): a connection that never completes one costs the server
    this object and its deadline, not an HTTP parser and a task."""

    def __init__(self, admission: Admission, address: str) -> None:
        self.inner: asyncio.Protocol | None = None
        self.admission = admission
        self.address: str | None = address  # None once the connection is gone
        self.transport: asyncio.Transport | None = None
        self._head = bytearray()
        self._deadline: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]
        self.admission.connections.add(self)
        self.arm()

    def arm(self) -> None:
        """Start the header deadline (again: the next request on a kept-alive connection)."""
        self.disarm()
        if self.address is not None:
            loop = asyncio.get_running_loop()
            self._deadline = loop.call_later(self.admission.limits.header_timeout_s, self._expire)

    def disarm(self) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None

    def _expire(self) -> None:
        self._deadline = None
        if self.transport is not None and not self.transport.is_closing():
            self.admission.expired.add()
            self.transport.abort()

    def data_received(self, data: bytes) -> None:
        if self.inner is not None:
            self.inner.data_received(data)
            return
        if self.address is None or self.transport is None:
            return
        seen = max(0, len(self._head) - 3)
        self._head += data
        if self._head.find(b"\n\n", seen) >= 0 or self._head.find(b"\n\r\n", seen) >= 0:
            self.inner = self.admission.make_inner()
            self.inner.connection_made(self.transport)
            head, self._head = bytes(self._head), bytearray()
            self.inner.data_received(head)
        elif len(self._head) > MAX_HEAD_BYTES:
            self.admission.expired.add()
            reset(self.transport)

    def eof_received(self) -> bool | None:
        return self.inner.eof_received() if self.inner is not None else None

    def pause_writing(self) -> None:
        if self.inner is not None:
            self.inner.pause_writing()

    def resume_writing(self) -> None:
        if self.inner is not None:
            self.inner.resume_writing()

    def connection_lost(self, exc: Exception | None) -> None:
        address = self.address
        if address is None:
            return
        self.disarm()
        self.address = None
        self.admission.connections.discard(self)
        self.admission.release(address)
        if self.inner is not None:
            self.inner.connection_lost(exc)


def host_name(text: str) -> str:
    """``text`` as a host name the server compares with: lower case, no brackets around an IPv6
    address, no trailing dot. ValueError when it is neither a DNS name nor an IP address."""
    name = text.strip().lower().rstrip(".")
    if name.startswith("[") and name.endswith("]"):
        name = name[1:-1]
    with contextlib.suppress(ValueError):
        return str(ipaddress.ip_address(name))
    if len(name) > 253 or not _NAME.fullmatch(name):
        raise ValueError(f"{text!r} is not a host name or an IP address")
    return name


def _host_port(value: str, default_port: int | None = None) -> tuple[str, int | None] | None:
    """``(name, port)`` of a ``Host`` value (``name[:port]``, ``[v6][:port]``); None if bad."""
    try:
        parts = urlsplit("//" + value)
        port = parts.port
        name = host_name(parts.hostname or "")
    except ValueError:
        return None
    if parts.path or parts.query or parts.fragment or parts.username is not None:
        return None
    return name, port if port is not None else default_port


@dataclass(frozen=True)
class HostNames:
    """The names the server answers to: its bind address, the loopback names, the names it was
    given; with a wildcard bind (``0.0.0.0``, ``::``) every IP address too (an address typed in
    a browser cannot be re-pointed; a DNS name can)."""

    names: frozenset[str]
    any_ip: bool

    @classmethod
    def of(cls, bind_host: str, extra: Iterable[str] = ()) -> HostNames:
        """The names of a server bound to ``bind_host``, with ``extra`` names (ValueError if
        one is not a host name)."""
        names = {host_name(n) for n in (*LOOPBACK_NAMES, *extra)}
        wildcard = bind_host.strip() in WILDCARD_HOSTS
        if not wildcard:
            names.add(host_name(bind_host))
        return cls(frozenset(names), wildcard)

    def answers_to(self, name: str) -> bool:
        if name in self.names:
            return True
        if not self.any_ip:
            return False
        try:
            ipaddress.ip_address(name)
        except ValueError:
            return False
        return True

    def host_error(self, host: str | None) -> str | None:
        """Why a request with this ``Host`` header is refused; None when it is served (a
        request without one, from a program, is: browsers always send it)."""
        if host is None:
            return None
        hp = _host_port(host)
        if hp is None:
            return f"refused: the Host header {host[:80]!r} is not a host name"
        if not self.answers_to(hp[0]):
            return (
                f"refused: this server does not answer to the name {hp[0][:80]!r} (Host header); "
                "if it should, start it with --allow-host NAME"
            )
        return None

    @staticmethod
    def origin_error(origin: str | None, host: str | None) -> str | None:
        """Why a WebSocket with this ``Origin`` is refused (None: served): a browser's page must
        come from this very server, ``http://`` + the ``Host`` it connects to (port included;
        an ``https://`` page is another origin, this server speaks plain http). Programs that
        send no ``Origin`` pass."""
        if origin is None:
            return None
        try:
            parts = urlsplit(origin)
            port = parts.port
        except ValueError:
            parts, port = urlsplit(""), None
        if parts.scheme != "http" or not parts.hostname:
            return (
                f"cross-origin WebSocket refused: Origin {origin[:80]!r} is not an http:// page "
                "of this server (it speaks plain http)"
            )
        mine = _host_port(host or "", 80)
        try:
            theirs = (host_name(parts.hostname), port if port is not None else 80)
        except ValueError:
            theirs = None
        if mine is None or theirs != mine:
            return (
                f"cross-origin WebSocket refused: Origin {origin[:80]!r} is not this server "
                f"(http://{(host or '')[:80]})"
            )
        return None

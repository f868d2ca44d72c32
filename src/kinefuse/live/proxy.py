"""A fault-injecting TCP proxy: delay, asymmetric jitter, bandwidth limits and cut connections.

The live demo puts one between each sensor client and the server (``--net-jitter-ms``), and the
reliability tests use it to cut connections at a chosen byte or instant. It listens on
``127.0.0.1`` (port 0 by default: a free port), and for every accepted connection opens one to the
target and forwards bytes both ways:

- **up** is client -> target (a sensor's frames and clock replies), **down** target -> client
  (clock probes, calibration start/stop); each direction has its own :class:`LinkProfile`, so the
  two can differ (asymmetric delays are what biases an NTP-style clock estimate);
- each chunk read is released after ``delay_s`` plus a random jitter drawn from the profile's
  distribution (seeded: the same seed gives the same draws), and after the link had time to send
  it at ``bandwidth_Bps``;
- **order is kept**: a TCP stream cannot reorder, so a chunk is never released before the one
  read before it (a large jitter draw delays the chunks behind it, as a queue does);
- **cuts**: after ``cut_after_bytes`` forwarded in a direction, or ``cut_after_s`` after the
  connection was accepted, or when :meth:`FaultProxy.cut` is called, both sides of the connection
  are closed (reset by default, as a pulled cable or a crashed peer; or a clean FIN).

The timing rule is pure (:class:`LinkSchedule`: arrival times and sizes in, release times out) and
tested without sockets; :class:`FaultProxy` only moves bytes (asyncio, one task group per
connection). :class:`ProxyThread` runs proxies on an event loop of their own, for callers that are
not async (the demo).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import threading
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np

from kinefuse.errors import InputError

__all__ = [
    "JITTER_KINDS",
    "ConnectionStats",
    "FaultProxy",
    "LinkProfile",
    "LinkSchedule",
    "ProxyThread",
]

#: Jitter distributions: ``exponential`` (queueing delay, mean ``jitter_s``), ``uniform`` (on
#: ``[0, 2 jitter_s]``, mean ``jitter_s``), ``halfnormal`` (``|N(0, s)|`` scaled to mean
#: ``jitter_s``), ``none``.
JITTER_KINDS = ("exponential", "uniform", "halfnormal", "none")

#: Bytes read from a socket at a time.
CHUNK_BYTES = 65536

#: Delay samples kept per direction and connection (the oldest are dropped beyond it).
MAX_SAMPLES = 100_000


@dataclass(frozen=True)
class LinkProfile:
    """How one direction of a proxied connection behaves.

    Attributes
    ----------
    delay_s : float
        Fixed one-way delay added to every chunk, seconds (>= 0).
    jitter_s : float
        Mean of the random extra delay, seconds (>= 0).
    jitter : str
        Distribution of the extra delay, one of :data:`JITTER_KINDS`.
    bandwidth_Bps : float or None
        Link rate, bytes per second (None: unlimited).
    cut_after_bytes : int or None
        Close the connection (both sides) once this many bytes were forwarded in this direction;
        the bytes up to that count are delivered first. None: never.
    """

    delay_s: float = 0.0
    jitter_s: float = 0.0
    jitter: str = "exponential"
    bandwidth_Bps: float | None = None
    cut_after_bytes: int | None = None

    def __post_init__(self) -> None:
        for name in ("delay_s", "jitter_s"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
                raise InputError(f"LinkProfile.{name} must be a finite number >= 0, got {v!r}")
        if self.jitter not in JITTER_KINDS:
            raise InputError(
                f"LinkProfile.jitter must be one of {', '.join(JITTER_KINDS)}, got {self.jitter!r}"
            )
        b = self.bandwidth_Bps
        if b is not None and not (math.isfinite(b) and b > 0):
            raise InputError(f"LinkProfile.bandwidth_Bps must be > 0 or None, got {b!r}")
        c = self.cut_after_bytes
        if c is not None and not (isinstance(c, int) and c >= 0):
            raise InputError(f"LinkProfile.cut_after_bytes must be an int >= 0 or None, got {c!r}")

    @property
    def passthrough(self) -> bool:
        """True when chunks need no scheduling (no delay, no jitter, no bandwidth limit)."""
        return (
            self.delay_s == 0
            and (self.jitter_s == 0 or self.jitter == "none")
            and self.bandwidth_Bps is None
        )

    def draw_jitter(self, rng: np.random.Generator) -> float:
        """One extra delay, seconds."""
        s = self.jitter_s
        if s == 0 or self.jitter == "none":
            return 0.0
        if self.jitter == "exponential":
            return float(rng.exponential(s))
        if self.jitter == "uniform":
            return float(rng.uniform(0.0, 2.0 * s))
        return float(abs(rng.normal(0.0, s * math.sqrt(math.pi / 2))))  # halfnormal, mean s


class LinkSchedule:
    """When each chunk of one direction is released (pure: no I/O, no clock of its own).

    ``release = max(sent + delay_s + jitter, previous release)``, where ``sent`` is when the
    link finished sending the chunk at ``bandwidth_Bps`` (it starts when the chunk arrives or
    when the previous chunk is sent, whichever is later).

    Parameters
    ----------
    profile : LinkProfile
    rng : numpy.random.Generator
        Source of the jitter draws.
    """

    def __init__(self, profile: LinkProfile, rng: np.random.Generator) -> None:
        self.profile = profile
        self._rng = rng
        self._link_free = -math.inf
        self._last_release = -math.inf

    def release(self, arrival_s: float, n_bytes: int) -> float:
        """Release time of a chunk of ``n_bytes`` that arrived at ``arrival_s`` (seconds)."""
        p = self.profile
        sent = arrival_s
        if p.bandwidth_Bps is not None:
            sent = max(arrival_s, self._link_free) + n_bytes / p.bandwidth_Bps
            self._link_free = sent
        t = max(sent + p.delay_s + p.draw_jitter(self._rng), self._last_release)
        self._last_release = t
        return t


@dataclass
class ConnectionStats:
    """What one proxied connection did (read by tests and the demo after the fact).

    Attributes
    ----------
    index : int
        0 for the first connection the proxy accepted, then 1, 2, ...
    bytes_up, bytes_down : int
        Bytes forwarded client -> target and target -> client.
    delays_up_s, delays_down_s : deque of float
        Per chunk: time from its arrival at the proxy to its write to the other side, seconds.
    cut : str or None
        Why the proxy cut the connection (None: it ended by itself or is open).
    closed : bool
        Both sides are closed.
    """

    index: int
    bytes_up: int = 0
    bytes_down: int = 0
    delays_up_s: deque[float] = field(default_factory=lambda: deque(maxlen=MAX_SAMPLES))
    delays_down_s: deque[float] = field(default_factory=lambda: deque(maxlen=MAX_SAMPLES))
    cut: str | None = None
    closed: bool = False


class _Cut(Exception):
    """Raised inside a connection's task group to close both sides at once."""


_Chunk = tuple[bytes, float, float]  # data, arrival time, release time
_CUT = "cut"  # queue sentinel: deliver what came before, then cut


class FaultProxy:
    """An asyncio TCP proxy with a :class:`LinkProfile` per direction.

    Parameters
    ----------
    target_host, target_port : str, int
        Where every accepted connection is forwarded.
    up, down : LinkProfile
        Client -> target and target -> client behaviour.
    cut_after_s : float or None
        Cut each connection this many seconds after it was accepted.
    max_cuts : int or None
        Cut at most this many connections by ``cut_after_*`` (e.g. 1: the first connection is
        cut, a reconnect then goes through); :meth:`cut` is not limited. None: every one.
    reset : bool
        Cut by resetting both sides (RST, as a crashed peer) rather than closing them (FIN).
    seed : int
        Seed of the jitter draws (each connection and direction has its own stream from it).
    host, port : str, int
        Where to listen (default ``127.0.0.1``, a free port).

    Use ``async with FaultProxy(...) as proxy:``; :attr:`port` is the bound port.
    """

    def __init__(
        self,
        target_host: str,
        target_port: int,
        *,
        up: LinkProfile | None = None,
        down: LinkProfile | None = None,
        cut_after_s: float | None = None,
        max_cuts: int | None = None,
        reset: bool = True,
        seed: int = 0,
        host: str = "127.0.0.1",
        port: int = 0,
    ) -> None:
        if not (isinstance(target_port, int) and 0 < target_port < 65536):
            raise InputError(f"target port must be in 1..65535, got {target_port!r}")
        if cut_after_s is not None and not (math.isfinite(cut_after_s) and cut_after_s >= 0):
            raise InputError(f"cut_after_s must be a number >= 0 or None, got {cut_after_s!r}")
        self.target = (target_host, target_port)
        self.up = up or LinkProfile()
        self.down = down or LinkProfile()
        self.cut_after_s = cut_after_s
        self.max_cuts = max_cuts
        self.reset = reset
        self.seed = int(seed)
        self._listen = (host, port)
        self._server: asyncio.Server | None = None
        self._tasks: set[asyncio.Task[None]] = set()
        self._cut_events: dict[int, asyncio.Event] = {}
        self._auto_cuts = 0
        self.connections: list[ConnectionStats] = []

    @property
    def port(self) -> int:
        """The port the proxy listens on."""
        if self._server is None:
            raise RuntimeError("the proxy is not started; use `async with FaultProxy(...)`")
        return int(self._server.sockets[0].getsockname()[1])

    async def start(self) -> FaultProxy:
        self._server = await asyncio.start_server(self._accept, *self._listen)
        return self

    async def close(self) -> None:
        """Stop listening and cut every open connection (reset); waits for them to end."""
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()
        for ev in self._cut_events.values():
            ev.set()
        if self._tasks:
            await asyncio.gather(*self._tasks, return_exceptions=True)

    async def __aenter__(self) -> FaultProxy:
        return await self.start()

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    def cut(self, index: int | None = None) -> None:
        """Cut one connection (by :attr:`ConnectionStats.index`) or, with None, every open one."""
        for i, ev in list(self._cut_events.items()):
            if index is None or i == index:
                ev.set()

    def _accept(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.get_running_loop().create_task(self._serve(reader, writer))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def _may_cut(self) -> bool:
        return self.max_cuts is None or self._auto_cuts < self.max_cuts

    async def _serve(self, c_reader: asyncio.StreamReader, c_writer: asyncio.StreamWriter) -> None:
        stats = ConnectionStats(index=len(self.connections))
        self.connections.append(stats)
        try:
            t_reader, t_writer = await asyncio.open_connection(*self.target)
        except OSError as e:
            stats.cut = f"target {self.target[0]}:{self.target[1]} refused: {e}"
            _abort(c_writer)
            stats.closed = True
            return
        cut_ev = asyncio.Event()
        self._cut_events[stats.index] = cut_ev
        seeds = np.random.SeedSequence([self.seed, stats.index]).spawn(2)
        auto = self._may_cut()
        up = LinkSchedule(self.up, np.random.default_rng(seeds[0]))
        down = LinkSchedule(self.down, np.random.default_rng(seeds[1]))
        try:
            async with asyncio.TaskGroup() as tg:
                watcher = tg.create_task(self._watch_cut(cut_ev, stats, auto))
                async with asyncio.TaskGroup() as pipes:
                    pipes.create_task(self._direction(c_reader, t_writer, up, stats, "up", auto))
                    pipes.create_task(
                        self._direction(t_reader, c_writer, down, stats, "down", auto)
                    )
                watcher.cancel()  # both directions ended by themselves
        except* _Cut:
            pass
        finally:
            self._cut_events.pop(stats.index, None)
            for w in (c_writer, t_writer):
                if stats.cut is not None and self.reset:
                    _abort(w)
                else:
                    w.close()
            for w in (c_writer, t_writer):
                with contextlib.suppress(OSError, ConnectionError):
                    await w.wait_closed()
            stats.closed = True

    async def _watch_cut(self, ev: asyncio.Event, stats: ConnectionStats, auto: bool) -> None:
        timeout = self.cut_after_s if auto else None
        try:
            await asyncio.wait_for(ev.wait(), timeout)
            reason = "cut on request"
        except TimeoutError:
            reason = f"cut {self.cut_after_s:g} s after it was accepted"
            self._auto_cuts += 1
        if stats.cut is None:
            stats.cut = reason
        raise _Cut

    async def _direction(
        self,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        schedule: LinkSchedule,
        stats: ConnectionStats,
        name: str,
        auto: bool,
    ) -> None:
        """Read chunks, queue them with their release times, write them when due, in order."""
        loop = asyncio.get_running_loop()
        queue: asyncio.Queue[_Chunk | str | None] = asyncio.Queue()
        limit = schedule.profile.cut_after_bytes if auto else None
        delays = stats.delays_up_s if name == "up" else stats.delays_down_s

        async def read() -> None:
            n = 0
            while True:
                try:
                    chunk = await reader.read(CHUNK_BYTES)
                except (ConnectionError, OSError):  # a reset passes on as a reset
                    stats.cut = stats.cut or f"the {name} sender reset the connection"
                    raise _Cut from None
                if not chunk:
                    await queue.put(None)
                    return
                now = loop.time()
                if limit is not None and n + len(chunk) >= limit:
                    chunk = chunk[: limit - n]
                    if chunk:
                        await queue.put((chunk, now, schedule.release(now, len(chunk))))
                    await queue.put(_CUT)
                    return
                n += len(chunk)
                await queue.put((chunk, now, schedule.release(now, len(chunk))))

        async def write() -> None:
            while True:
                item = await queue.get()
                if item is None:  # the sender closed its side: pass the EOF on
                    with contextlib.suppress(OSError, ConnectionError, RuntimeError):
                        if writer.can_write_eof():
                            writer.write_eof()
                    return
                if isinstance(item, str):
                    self._auto_cuts += 1
                    stats.cut = f"cut after {limit} bytes {name}"
                    raise _Cut
                chunk, arrived, due = item
                wait = due - loop.time()
                if wait > 0:
                    await asyncio.sleep(wait)
                try:
                    writer.write(chunk)
                    await writer.drain()
                except (ConnectionError, OSError):
                    stats.cut = stats.cut or f"the {name} receiver went away"
                    raise _Cut from None
                delays.append(loop.time() - arrived)
                if name == "up":
                    stats.bytes_up += len(chunk)
                else:
                    stats.bytes_down += len(chunk)

        async with asyncio.TaskGroup() as tg:
            tg.create_task(read())
            tg.create_task(write())


def _abort(writer: asyncio.StreamWriter) -> None:
    with contextlib.suppress(OSError, RuntimeError):
        writer.transport.abort()


class ProxyThread:
    """Run :class:`FaultProxy` instances on an event loop in a background thread.

    For callers that are not async (the demo runs processes and waits on them). Use as a context
    manager; :meth:`add` starts a proxy and returns it (its :attr:`FaultProxy.port` is bound);
    leaving the context closes every proxy and stops the thread.
    """

    def __init__(self) -> None:
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._run, name="kinefuse-proxy", daemon=True)
        self.proxies: list[FaultProxy] = []

    def _run(self) -> None:
        asyncio.set_event_loop(self._loop)
        self._loop.run_forever()

    def __enter__(self) -> ProxyThread:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def call(self, fn: Callable[[], object]) -> None:
        """Run ``fn`` on the proxies' loop (e.g. ``lambda: proxy.cut()``) and wait for it."""

        async def run() -> None:
            fn()

        asyncio.run_coroutine_threadsafe(run(), self._loop).result(timeout=10)

    def add(self, target_host: str, target_port: int, **kwargs: object) -> FaultProxy:
        """Start a proxy to ``target_host:target_port`` (keyword arguments of FaultProxy)."""
        proxy = FaultProxy(target_host, target_port, **kwargs)  # type: ignore[arg-type]
        asyncio.run_coroutine_threadsafe(proxy.start(), self._loop).result(timeout=10)
        self.proxies.append(proxy)
        return proxy

    def close(self) -> None:
        if not self._thread.is_alive():
            return

        async def stop() -> None:
            for p in self.proxies:
                await p.close()

        with contextlib.suppress(Exception):
            asyncio.run_coroutine_threadsafe(stop(), self._loop).result(timeout=10)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(timeout=10)
        self._loop.close()

    def stats(self) -> Iterator[ConnectionStats]:
        """Every connection of every proxy (read after the traffic stopped)."""
        for p in self.proxies:
            yield from p.connections


def jitter_profiles(jitter_ms: float) -> tuple[LinkProfile, LinkProfile]:
    """The demo's network for ``--net-jitter-ms MS``: up (client -> server) 0.2 ms plus an
    exponential queueing delay of mean MS, down 0.2 ms plus one of mean MS / 2 (asymmetric, as a
    client's uplink carrying its frames is busier than the downlink)."""
    if not (math.isfinite(jitter_ms) and jitter_ms >= 0):
        raise InputError(f"--net-jitter-ms must be a number >= 0, got {jitter_ms!r}")
    s = jitter_ms * 1e-3
    return (
        LinkProfile(delay_s=2e-4, jitter_s=s, jitter="exponential"),
        LinkProfile(delay_s=2e-4, jitter_s=s / 2, jitter="exponential"),
    )


def serve_proxy(
    target_host: str,
    target_port: int,
    *,
    host: str = "127.0.0.1",
    port: int = 0,
    up: LinkProfile | None = None,
    down: LinkProfile | None = None,
    cut_after_s: float | None = None,
    max_cuts: int | None = None,
    seed: int = 0,
    say: Callable[[str], None] | None = None,
) -> int:
    """``kinefuse proxy``: run one proxy until SIGINT/SIGTERM; print where it listens first
    (``kinefuse proxy: listening on HOST:PORT``) and a line per connection when it ends."""
    import signal

    def _print(m: str) -> None:
        print(m, flush=True)

    out = say or _print

    async def main() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        proxy = FaultProxy(
            target_host, target_port, up=up, down=down, cut_after_s=cut_after_s,
            max_cuts=max_cuts, seed=seed, host=host, port=port,
        )  # fmt: skip
        try:
            await proxy.start()
        except OSError as e:
            raise InputError(f"cannot listen on {host}:{port}: {e.strerror or e}") from None
        out(f"kinefuse proxy: listening on {host}:{proxy.port} -> {target_host}:{target_port}")
        try:
            await stop.wait()
        finally:
            await proxy.close()
        for c in proxy.connections:
            out(f"connection {c.index}: {c.bytes_up} bytes up, {c.bytes_down} bytes down"
                + (f", {c.cut}" if c.cut else ""))  # fmt: skip

    asyncio.run(main())
    return 0

"""The sensor client: plays one sensor's frames to the server in real time, as the sensor would.

One client per sensor (paper A's client PC). It connects, says Hello, answers the challenge if
the server has a token (after checking the server's own proof that it knows the token: a client
with a token refuses a server that cannot prove it, or that asks for no token at all), and
after the Welcome:

- plays its :class:`~kinefuse.live.client.playback.Timeline`: each frame is handed over when its
  time comes on the monotonic clock (``m0 + t_play / speed``), stamped ``t_host_s`` with the host
  clock (:mod:`kinefuse.live.client.clocks`) and ``t_device_s`` with the source's device stamp;
- answers every ClockProbe at once from the protocol callback (``t2`` stamped when the bytes
  arrived, ``t3`` just before the reply is written), never queued behind data;
- runs the paper's client-side parts: the 2-D bone-crossing occlusion test on every body frame
  (:func:`kinefuse.capture.occlusion.detect_occlusion`), and while the server runs a calibration the
  wand detector on its depth frames (robust by default, ``detector="paper"``) plus one floor
  plane fit; it sends only the results (depth images never leave the client);
- keeps bounded send queues: the newest body frames win (older ones are dropped and counted),
  wand detection runs on one worker thread and skips depth frames that arrive while it is busy
  (the sighting's ``stride`` says how many frames its detection covers), so the client never
  falls behind and never queues without bound;
- sends a Heartbeat when idle (with a body tracker, at least every ``heartbeat_s``: it carries
  the tracker's rate and drops), and reconnects with capped exponential backoff and jitter when
  the connection breaks, keeping its sensor id and its stream (the play clock goes on).

It stops on :meth:`SensorClient.stop` (SIGINT/SIGTERM in ``kinefuse sensor``; it sends
Goodbye), on the server's Goodbye, or at the end of the source (or ``max_seconds``).

Threads: the asyncio loop does the networking; one worker thread reads the source and runs
occlusion ahead of the frames' times; one runs wand detection, one the floor fit. The client
owns them and joins them when :meth:`SensorClient.run` returns.

Why about 630 lines: :class:`SensorClient` is one state machine (connect, sync, stream, rejoin)
whose states share the connection and the threads; its connection, depth and helper parts
live in ``client_parts`` and ``client_depth``.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import logging
import math
import random
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from kinefuse.core.frames.observations import DepthFrame
from kinefuse.errors import KinefuseError
from kinefuse.live.client.clocks import HostClock, Monotonic
from kinefuse.live.client.depth_sightings import DepthWork
from kinefuse.live.client.parts import Occlusion, Prefetch, Prepared, ServerLink, wait_event
from kinefuse.live.client.playback import Timed, Timeline
from kinefuse.live.protocol import auth, printable
from kinefuse.live.protocol.handshake import Handshake, State, TokenRequired
from kinefuse.live.protocol.messages import (
    BODIES_VERSION,
    MAX_BODIES,
    PROTOCOL_VERSION,
    BodyFrameMessage,
    CalibrationStart,
    CalibrationStop,
    Challenge,
    ClockProbe,
    Error,
    Goodbye,
    Heartbeat,
    Hello,
    Message,
    OtherBody,
    Welcome,
)
from kinefuse.live.protocol.wire_errors import (
    AuthError,
    OutOfOrder,
    RemoteError,
    VersionError,
    WireError,
)

log = logging.getLogger("kinefuse.sensor")

#: exit codes of ``kinefuse sensor``
EXIT_OK = 0
EXIT_REFUSED = 3


class ClientRefused(KinefuseError):
    """The server refused this client for good (wrong or missing token, version, duplicate id).

    ``code`` is the server's error code (``auth``, ``version``, ``duplicate_id``, ...).
    """

    def __init__(self, code: str, message: str) -> None:
        super().__init__(printable(message, 2000))  # it quotes the server: printed, escaped
        self.code = code


@dataclass(frozen=True)
class ClientOptions:
    """How a :class:`SensorClient` runs (every default lives here).

    ``server``: (host, port). ``token``: the shared secret or None. ``detector``: "robust" or
    "paper". ``detect_every``: consider every k-th depth frame for detection (1 = all; the
    worker skips more when busy). ``occlusion_rule``: "crossing" (the paper's) or "coverage".
    ``speed``: source seconds per real second. ``max_seconds``: stop after this much source
    time (None = the whole source). ``body_queue``/``sighting_queue``: bounded send queues
    (messages). ``backoff_initial_s``/``backoff_max_s``: reconnect delays (doubling, capped,
    times a random factor in [0.5, 1]). ``connect_timeout_s``: for the TCP connect and each
    handshake step. ``duplicate_wait_s``: how long to keep retrying while the server says the
    sensor id is connected (its stale connection may linger until the server's timeout).
    ``floor_frames``: depth frames whose per-pixel median gives the floor plane.
    """

    server: tuple[str, int]
    token: str | None = None
    detector: str = "robust"
    detect_every: int = 1
    occlusion_rule: str = "crossing"
    speed: float = 1.0
    max_seconds: float | None = None
    serial: str = ""
    software: str = ""
    body_queue: int = 30
    sighting_queue: int = 30
    backoff_initial_s: float = 0.2
    backoff_max_s: float = 5.0
    connect_timeout_s: float = 5.0
    duplicate_wait_s: float = 15.0
    floor_frames: int = 15

    def __post_init__(self) -> None:
        if self.detector not in ("robust", "paper"):
            raise ValueError(f"detector must be 'robust' or 'paper', got {self.detector!r}")
        if self.occlusion_rule not in ("crossing", "coverage"):
            raise ValueError(f"occlusion_rule must be crossing or coverage: {self.occlusion_rule}")
        if not self.speed > 0:
            raise ValueError(f"speed must be positive, got {self.speed}")
        if self.detect_every < 1 or self.body_queue < 1 or self.sighting_queue < 1:
            raise ValueError("detect_every and the queue sizes must be >= 1")
        if self.token is not None:
            auth.check_token(self.token)


@dataclass
class ClientStats:
    """Counters of one client run (all connections)."""

    connections: int = 0
    body_sent: int = 0
    body_dropped: int = 0
    sightings_sent: int = 0
    sightings_dropped: int = 0
    depth_frames: int = 0
    depth_detected: int = 0
    depth_skipped_busy: int = 0
    probes_answered: int = 0
    late_frames: int = 0
    max_late_s: float = 0.0
    skipped_at_start: int = 0


class _Outcome(Exception):
    """How one connection ended (internal control flow)."""

    def __init__(self, kind: str, detail: str = "") -> None:
        super().__init__(printable(detail or kind, 2000))  # it quotes the server: logged, escaped
        self.kind = kind


def backoff_delay(attempt: int, initial_s: float, max_s: float, rng: random.Random) -> float:
    """The wait before reconnect attempt ``attempt`` (0, 1, ...): ``initial_s * 2**attempt``
    capped at ``max_s``, times a random factor in [0.5, 1) (clients that lost the server
    together do not come back in step)."""
    return min(max_s, initial_s * 2.0 ** min(attempt, 64)) * (0.5 + 0.5 * rng.random())


class SensorClient:
    """Plays ``timeline`` to a server (see the module notes).

    Parameters
    ----------
    timeline : Timeline
        The sensor's frames (:func:`kinefuse.live.client.playback.open_timeline`); the client closes
        it.
    options : ClientOptions
    host_clock : HostClock or callable
        The host clock, or ``make(m0) -> HostClock`` called at the play start with the
        monotonic instant that plays timeline time 0 (an emulated clock depends on it).
    epoch_monotonic : float, optional
        Play timeline time ``T`` at monotonic ``epoch + T / speed`` (several clients in step;
        frames already past at the start are skipped). Default: the first frame plays at once.
    monotonic : callable
        The monotonic clock (tests inject one).
    on_play_start : callable, optional
        Called once with ``(m0, play_start_monotonic, play_start_source_s)`` when playing
        starts (the sensor app writes its truth sidecar then).
    """

    def __init__(
        self,
        timeline: Timeline,
        options: ClientOptions,
        *,
        host_clock: HostClock | Callable[[float], HostClock],
        epoch_monotonic: float | None = None,
        monotonic: Monotonic = time.monotonic,
        on_play_start: Any = None,
        rng: random.Random | None = None,
    ) -> None:
        self.timeline = timeline
        self.options = options
        self.monotonic = monotonic
        self._host_spec: Callable[[float], HostClock] = (
            (lambda _m0: host_clock) if isinstance(host_clock, HostClock) else host_clock
        )
        self.host_clock: HostClock | None = (
            host_clock if isinstance(host_clock, HostClock) else None
        )
        self.epoch = epoch_monotonic
        self.on_play_start = on_play_start
        self.rng = rng or random.Random()
        self.stats = ClientStats()
        self.m0: float | None = None
        self._stop = asyncio.Event()
        self._stop_reason = ""
        self._body: deque[BodyFrameMessage] = deque()
        self._sightings: deque[Message] = deque()
        self._urgent: deque[Message] = deque()  # floor planes: tiny, once per calibration
        self._wake = asyncio.Event()
        self._welcomed = asyncio.Event()
        #: the protocol the server welcomed this client with (a 1.2 server takes one body)
        self._server_version: tuple[int, int] = PROTOCOL_VERSION
        self._every_body = True
        self._said_first_body = False
        self._conn: ServerLink | None = None
        self._source_done = False
        self._held_probes: list[tuple[ServerLink, ClockProbe, float]] = []
        self._delivered = 0
        self._io = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="kinefuse-source")
        self.depth = DepthWork(
            timeline,
            detector=options.detector,
            detect_every=options.detect_every,
            floor_frames=options.floor_frames,
            stats=self.stats,
            send_sighting=self._enqueue_sighting,
            send_floor=self._enqueue_urgent,
            report_floor_error=self._report_floor_error,
        )

    # -- public ----------------------------------------------------------------------------

    def stop(self, reason: str = "stopped") -> None:
        """Ask the client to stop (it says Goodbye and :meth:`run` returns 0)."""
        self._stop_reason = self._stop_reason or reason
        self._stop.set()
        self._wake.set()

    async def run(self) -> int:
        """Connect, play, reconnect as needed; return the exit code (0 on a clean stop).

        Raises
        ------
        ClientRefused
            The server refused for good (auth, version, or a duplicate id for too long).
        """
        try:
            async with asyncio.TaskGroup() as tg:
                tg.create_task(self._connections())
                tg.create_task(self._play())
        except* ClientRefused as eg:
            raise eg.exceptions[0] from None
        except* KinefuseError as eg:
            raise eg.exceptions[0] from None  # bad input (a source that cannot be read)
        finally:
            self._io.shutdown(wait=True, cancel_futures=True)
            self.depth.shutdown()
            with contextlib.suppress(Exception):
                self.timeline.close()
        return EXIT_OK

    # -- connections -----------------------------------------------------------------------

    async def _connections(self) -> None:
        attempt = 0
        duplicate_since: float | None = None
        while not self._stop.is_set():
            try:
                await self._one_connection()
                return
            except _Outcome as out:
                if out.kind == "goodbye":
                    log.info("the server said goodbye (%s): stopping", out)
                    self.stop("server said goodbye")
                    return
                if out.kind == "stop":
                    return
                if out.kind == "duplicate_id":
                    now = self.monotonic()
                    duplicate_since = duplicate_since or now
                    if now - duplicate_since > self.options.duplicate_wait_s:
                        raise ClientRefused(
                            "duplicate_id",
                            f"the server keeps refusing sensor id {self.timeline.sensor_id!r} "
                            f"as already connected ({out}); is another client playing it?",
                        ) from None
                else:
                    duplicate_since = None
                if out.kind == "welcomed":
                    attempt = 0
                log.warning("connection to %s:%d: %s", *self.options.server, out)
            opt = self.options
            delay = backoff_delay(attempt, opt.backoff_initial_s, opt.backoff_max_s, self.rng)
            attempt += 1
            await wait_event(self._stop, delay)

    async def _one_connection(self) -> None:
        loop = asyncio.get_running_loop()
        host, port = self.options.server
        t = self.options.connect_timeout_s
        try:
            async with asyncio.timeout(t):
                _tr, conn = await loop.create_connection(lambda: ServerLink(self), host, port)
        except (OSError, TimeoutError) as e:
            raise _Outcome("connect", f"cannot connect ({e or 'timed out'})") from None
        self._conn = conn
        try:
            hs = await self._handshake(conn)
            welcome = hs.welcome
            assert welcome is not None
            self.stats.connections += 1
            log.info(
                "sensor %s connected to %s:%d (session %r)",
                self.timeline.sensor_id, host, port, welcome.session,
            )  # fmt: skip
            if welcome.calibrating:
                self.depth.start(welcome.calibration_id)
            self._server_version = welcome.protocol_version
            self._every_body = hs.sends_every_body
            self._welcomed.set()
            await self._session(conn, welcome)
        finally:
            self._conn = None
            conn.close()

    async def _next(self, conn: ServerLink, timeout: float) -> Message:
        """The next message from the server; what is queued comes before a close or a stop
        (a refusal and the close after it can arrive together: the refusal must be seen)."""
        if conn.inbox.empty():
            get = asyncio.ensure_future(conn.inbox.get())
            stop = asyncio.ensure_future(self._stop.wait())
            try:
                done, _ = await asyncio.wait(
                    {get, stop, conn.closed}, timeout=timeout, return_when=asyncio.FIRST_COMPLETED
                )
            finally:
                for f in (get, stop):
                    if not f.done():
                        f.cancel()  # a cancelled get leaves its item in the queue
            if get in done:
                item = get.result()
            elif not conn.inbox.empty():
                item = conn.inbox.get_nowait()
            elif stop in done:
                raise _Outcome("stop")
            elif conn.closed in done:
                raise _Outcome("lost", "the server closed the connection")
            else:
                raise _Outcome("timeout", f"nothing from the server for {timeout:g} s")
        else:
            item = conn.inbox.get_nowait()
        if isinstance(item, VersionError):
            raise ClientRefused("version", f"the server speaks another version: {item}")
        if isinstance(item, WireError):
            conn.send(Error(item.code, str(item)[:1000]))
            raise _Outcome("protocol", f"the server broke the protocol: {item}")
        return item

    async def _handshake(self, conn: ServerLink) -> Handshake:
        """Drive the sans-I/O :class:`~kinefuse.live.protocol.handshake.Handshake` until the
        Welcome: with a token, the server must prove it knows it too (over this connection's fresh
        nonce) before this client answers or sends anything else (docs/protocol.md,
        Authentication)."""
        tl, opt = self.timeline, self.options
        hs = Handshake("peer", opt.token)
        hello = Hello(
            role="sensor",
            sensor_id=tl.sensor_id,
            serial=opt.serial,
            intrinsics=tl.intrinsics,
            capabilities=("wand", "floor", "occlusion"),
            software=opt.software,
        )
        conn.send(hs.send(hello))
        while not hs.done:
            msg = await self._next(conn, opt.connect_timeout_s)
            try:
                answer = hs.receive(msg)
            except RemoteError as e:
                if e.code == "auth":
                    raise ClientRefused(
                        "auth",
                        f"the server refused the token ({e.reason}); give the server's token "
                        "with --token-file FILE",
                    ) from None
                if e.code == "version":
                    raise ClientRefused(
                        "version", f"the server speaks another version: {e.reason}"
                    ) from None
                raise _Outcome(e.code, f"refused: {e.reason} ({e.code})") from None
            except TokenRequired:
                conn.send(Goodbye("no token"))
                raise ClientRefused(
                    "auth",
                    "the server requires a token: start the sensor with --token-file FILE "
                    "(the server's token; or KINEFUSE_TOKEN)",
                ) from None
            except AuthError as e:
                conn.send(e.reply)
                raise ClientRefused("auth", f"refusing the server: {e}") from None
            except VersionError as e:
                raise ClientRefused("version", str(e)) from None
            except OutOfOrder as e:
                conn.send(e.reply)
                raise _Outcome("protocol", f"the server sent {msg.TYPE} instead of welcome") from e
            if hs.state is State.CLOSED:  # the server said goodbye
                assert isinstance(msg, Goodbye)
                raise _Outcome("goodbye", msg.reason)
            if answer is not None:
                conn.send(answer)
        return hs

    async def _session(self, conn: ServerLink, welcome: Welcome) -> None:
        writer = asyncio.ensure_future(self._writer(conn, welcome.heartbeat_s))
        try:
            while True:
                idle = self.monotonic() - conn.last_rx
                wait = max(0.05, welcome.timeout_s - idle)
                try:
                    msg = await self._next(conn, wait)
                except _Outcome as out:
                    if (
                        out.kind == "timeout"
                        and self.monotonic() - conn.last_rx < welcome.timeout_s
                    ):
                        continue  # probes (answered inline) arrived meanwhile
                    if out.kind == "timeout":
                        conn.send(Error("timeout", f"nothing heard for {welcome.timeout_s:g} s"))
                    if out.kind == "stop":
                        await self._flush(conn)
                        conn.send(Goodbye(self._stop_reason or "stopped"))
                    raise
                self._handle(conn, msg)
                if writer.done():
                    writer.result()
        finally:
            writer.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await writer

    def _handle(self, conn: ServerLink, msg: Message) -> None:
        if isinstance(msg, CalibrationStart):
            self.depth.start(msg.calibration_id)
        elif isinstance(msg, CalibrationStop):
            self.depth.stop(msg.calibration_id)
        elif isinstance(msg, Goodbye):
            raise _Outcome("goodbye", msg.reason)
        elif isinstance(msg, Error):
            raise _Outcome(msg.code, f"the server reported {msg.code}: {msg.reason}")
        elif isinstance(msg, Heartbeat):
            pass
        elif "server" not in type(msg).SENDERS or isinstance(msg, Challenge | Welcome):
            conn.send(Error("order", f"a server does not send {msg.TYPE} now"))
            raise _Outcome("protocol", f"the server sent {msg.TYPE} out of order")
        # other server messages (status, calibration_result) are not for a sensor: ignored

    async def _writer(self, conn: ServerLink, heartbeat_s: float) -> None:
        last_beat = self.monotonic()
        while True:
            await conn.writable.wait()
            self._send_pending(conn)
            now = self.monotonic()
            idle = now - conn.last_tx
            # a tracker's status goes out every heartbeat_s even while data flows
            due = idle if self.timeline.tracker_status() is None else now - last_beat
            if due >= heartbeat_s:
                conn.send(self._heartbeat())
                last_beat, due = now, 0.0
            self._wake.clear()
            await wait_event(self._wake, max(0.01, heartbeat_s - due))

    def _send_pending(self, conn: ServerLink) -> None:
        # a closing connection takes nothing: what is queued waits for the next connection
        while (
            conn.is_open
            and conn.writable.is_set()
            and (self._urgent or self._sightings or self._body)
        ):
            if self._urgent:
                conn.send(self._urgent.popleft())
            elif self._sightings:
                conn.send(self._sightings.popleft())
                self.stats.sightings_sent += 1
            else:
                conn.send(self._body.popleft())
                self.stats.body_sent += 1

    async def _flush(self, conn: ServerLink, timeout: float = 2.0) -> None:
        end = self.monotonic() + timeout
        while (self._urgent or self._sightings or self._body) and self.monotonic() < end:
            if conn.closed.done():
                return
            self._send_pending(conn)
            await asyncio.sleep(0.01)

    def _heartbeat(self) -> Heartbeat:
        return Heartbeat(
            self._host_now(),
            self._n_sent(),
            self._n_dropped(),
            self.depth.floor_error,
            tracker[:1024] if (tracker := self.timeline.tracker_status()) else tracker,
        )

    def _report_floor_error(self, text: str) -> None:
        """The floor fit failed: tell the server now (a heartbeat carries it)."""
        self._enqueue_urgent(self._heartbeat())

    def _n_sent(self) -> int:
        return self.stats.body_sent + self.stats.sightings_sent

    def _n_dropped(self) -> int:
        return self.stats.body_dropped + self.stats.sightings_dropped

    def _host_now(self) -> float:
        return self.host_clock.now() if self.host_clock is not None else self.monotonic()

    # -- queues ----------------------------------------------------------------------------

    def _enqueue_body(self, msg: BodyFrameMessage) -> None:
        if len(self._body) >= self.options.body_queue:
            self._body.popleft()  # the newest wins
            self.stats.body_dropped += 1
        self._body.append(msg)
        self._wake.set()

    def _enqueue_urgent(self, msg: Message) -> None:
        self._urgent.append(msg)
        self._wake.set()

    def _enqueue_sighting(self, msg: Message) -> None:
        if len(self._sightings) >= self.options.sighting_queue:
            self._sightings.popleft()
            self.stats.sightings_dropped += 1
        self._sightings.append(msg)
        self._wake.set()

    # -- playing ---------------------------------------------------------------------------

    async def _play(self) -> None:
        await self._wait_welcome_or_stop()
        if self._stop.is_set():
            return
        loop = asyncio.get_running_loop()
        epoch, speed = self.epoch, self.options.speed

        def past(timed: Timed) -> bool:
            # joining a common epoch late: what is past before the first delivery is skipped
            return (
                epoch is not None
                and self._delivered == 0
                and epoch + timed.t_play_s / speed < self.monotonic()
            )

        skip = past if epoch is not None and not self.timeline.live else None
        prepared = Prepared(self.timeline, self.options.occlusion_rule, skip)
        ahead = Prefetch(loop, prepared)
        producer = loop.run_in_executor(self._io, ahead.run)
        try:
            await self._play_frames(ahead)
        finally:
            ahead.halt()
            await producer
            self.stats.skipped_at_start += prepared.skipped
        self._source_done = True
        if not self._stop.is_set():
            log.info("sensor %s: the source ended", self.timeline.sensor_id)
            self.stop("source ended")

    async def _play_frames(self, ahead: Prefetch) -> None:
        first = True
        speed = self.options.speed
        t_first: float | None = None
        while not self._stop.is_set():
            item = await ahead.get()
            if item is None:
                return
            timed, occ = item
            if first:
                self._start_play(timed)
                first = False
            if t_first is None:
                t_first = timed.t_play_s
            if (
                self.options.max_seconds is not None
                and math.isfinite(timed.t_play_s)
                and timed.t_play_s - t_first > self.options.max_seconds
            ):
                return
            assert self.m0 is not None
            if not self.timeline.live:
                due = self.m0 + timed.t_play_s / speed
                now = self.monotonic()
                if due < now and self.epoch is not None and self._delivered == 0:
                    self.stats.skipped_at_start += 1
                    continue  # the common epoch is past (a late start): join at the present
                if due > now:
                    await wait_event(self._stop, due - now)
                    if self._stop.is_set():
                        return
                late = self.monotonic() - due
                if late > 0.05:
                    self.stats.late_frames += 1
                self.stats.max_late_s = max(self.stats.max_late_s, late)
            self._deliver(timed, occ)

    async def _wait_welcome_or_stop(self) -> None:
        w = asyncio.ensure_future(self._welcomed.wait())
        s = asyncio.ensure_future(self._stop.wait())
        try:
            await asyncio.wait({w, s}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            w.cancel()
            s.cancel()

    def _start_play(self, first: Timed) -> None:
        now = self.monotonic()
        speed = self.options.speed
        if self.timeline.live:
            self.m0 = now
            start_mono, start_src = now, math.nan
        elif self.epoch is not None:
            self.m0 = self.epoch
            start_mono = max(now, self.epoch + first.t_play_s / speed)
            start_src = (start_mono - self.epoch) * speed
        else:
            self.m0 = now - first.t_play_s / speed
            start_mono, start_src = now, first.t_play_s
        if self.host_clock is None:
            self.host_clock = self._host_spec(self.m0)
        held, self._held_probes = self._held_probes, []
        for conn, probe, t_arrival in held:
            conn._answer(probe, t_arrival)
        if self.on_play_start is not None:
            self.on_play_start(self.m0, start_mono, start_src)

    def _deliver(self, timed: Timed, occ: Occlusion | None) -> None:
        self._delivered += 1
        f = timed.frame
        assert self.host_clock is not None
        if self.timeline.live and math.isfinite(f.t_host_s):
            t_host = f.t_host_s  # a driver stamps on the PC clock itself
        else:
            t_host = self.host_clock.now()
        if isinstance(f, DepthFrame):
            self.depth.on_depth(f, t_host)
            return
        bodies = f.bodies()[:MAX_BODIES]
        if len(bodies) > 1 and not self._every_body:
            if not self._said_first_body:
                self._said_first_body = True
                log.warning(
                    "sensor %s: the server speaks protocol %d.%d, older than %d.%d: it is sent "
                    "the first body of each frame only (upgrade the server to keep every body)",
                    self.timeline.sensor_id, *self._server_version, *BODIES_VERSION,
                )  # fmt: skip
            bodies = bodies[:1]
        occs = occ if occ is not None else ((None, None),) * len(bodies)
        others = tuple(
            OtherBody(b.body_id, b.joints_m, b.states, o[0], o[1])
            for b, o in zip(bodies[1:], occs[1:], strict=False)
        )
        self._enqueue_body(
            BodyFrameMessage(
                seq=f.seq,
                t_device_s=f.t_device_s,
                t_host_s=t_host,
                joints_m=f.joints_m,
                states=f.states,
                occluded=occs[0][0],
                n_crossings=occs[0][1],
                dropped=self.stats.body_dropped,
                body_id=f.body_id,
                others=others,
            )
        )

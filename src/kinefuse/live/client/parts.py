"""The sensor client's parts that are not its control flow: the connection protocol (probe
replies stamped in the socket callback), the read-ahead of the source, and the work the client
does on its frames off the event loop (occlusion, wand detection, the floor fit).

Split from :mod:`kinefuse.live.client.client` to keep each module readable; nothing here is public.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any

import numpy as np

from kinefuse.core.frames.observations import DepthFrame
from kinefuse.live.client.playback import Timed, Timeline
from kinefuse.live.protocol.codec import Decoder, encode
from kinefuse.live.protocol.messages import ClockProbe, ClockReply, Message
from kinefuse.live.protocol.wire_errors import WireError

if TYPE_CHECKING:
    from kinefuse.live.client.client import SensorClient


#: the occlusion test's result per body of a frame (the first body first): flags, crossings
Occlusion = tuple[tuple[np.ndarray, int], ...]


class ServerLink(asyncio.Protocol):
    """One TCP connection: decodes, answers probes inline, queues everything else."""

    def __init__(self, client: SensorClient) -> None:
        self.client = client
        self.decoder = Decoder()
        self.inbox: asyncio.Queue[Message | WireError] = asyncio.Queue()
        self.closed = asyncio.get_running_loop().create_future()
        self.transport: asyncio.Transport | None = None
        self.writable = asyncio.Event()
        self.writable.set()
        self.last_rx = client.monotonic()
        self.last_tx = client.monotonic()

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport

    def data_received(self, data: bytes) -> None:
        t_arrival = self.client.monotonic()  # first: t2 is the moment the bytes arrived
        self.last_rx = t_arrival
        try:
            msgs = self.decoder.feed(data)
            error: WireError | None = None
        except WireError as e:
            msgs, error = e.decoded, e
        for m in msgs:
            if isinstance(m, ClockProbe):
                self._answer(m, t_arrival)
            else:
                self.inbox.put_nowait(m)
        if error is not None:
            self.inbox.put_nowait(error)

    def _answer(self, probe: ClockProbe, t_arrival: float) -> None:
        host = self.client.host_clock
        if self.transport is None or self.transport.is_closing():
            return
        if host is None:
            # the emulated clock starts with the play; the arrival instant is kept, so the
            # reply is exact when it goes (only its turnaround t3 - t2 is longer)
            self.client._held_probes.append((self, probe, t_arrival))
            return
        t2 = host.affine.forward(t_arrival)
        t3 = max(t2, host.now())
        self.transport.write(encode(ClockReply(probe.probe_id, probe.t1, t2, t3)))
        self.last_tx = self.client.monotonic()
        self.client.stats.probes_answered += 1

    @property
    def is_open(self) -> bool:
        return self.transport is not None and not self.transport.is_closing()

    def send(self, msg: Message) -> None:
        if self.is_open:
            assert self.transport is not None
            self.transport.write(encode(msg))
            self.last_tx = self.client.monotonic()

    def pause_writing(self) -> None:
        self.writable.clear()

    def resume_writing(self) -> None:
        self.writable.set()

    def connection_lost(self, exc: Exception | None) -> None:
        self.writable.set()
        if not self.closed.done():
            self.closed.set_result(exc)

    def close(self) -> None:
        if self.transport is not None:
            self.transport.close()


async def wait_event(event: asyncio.Event, timeout: float) -> bool:
    """Wait for ``event`` at most ``timeout`` seconds; True if it is set.

    (Not ``asyncio.wait_for``: on Python 3.11 it can swallow a cancellation that arrives as
    the wait ends, and a cancelled task would then run on.)
    """
    try:
        async with asyncio.timeout(timeout):
            await event.wait()
    except TimeoutError:
        return event.is_set()
    return True


class Prefetch:
    """Runs the source ahead of the play clock on the source thread (``ahead`` frames at most).

    Reading a store decodes depth frames in batches; without a lead, a frame would wait for a
    whole batch to be decoded after its time had come.
    """

    def __init__(
        self, loop: asyncio.AbstractEventLoop, prepared: Prepared, ahead: int = 45
    ) -> None:
        self.loop = loop
        self.prepared = prepared
        self.queue: asyncio.Queue[Any] = asyncio.Queue()
        self.slots = threading.Semaphore(ahead)
        self.halted = threading.Event()

    def run(self) -> None:
        """The producer (on the source thread): until the source ends or :meth:`halt`."""
        try:
            while not self.halted.is_set():
                if not self.slots.acquire(timeout=0.1):
                    continue
                item = self.prepared.next()
                self.loop.call_soon_threadsafe(self.queue.put_nowait, item)
                if item is None:
                    return
        except BaseException as e:
            if not self.halted.is_set():
                self.loop.call_soon_threadsafe(self.queue.put_nowait, e)
        finally:
            self.prepared.close()  # a store closes in its own thread

    def halt(self) -> None:
        self.halted.set()

    async def get(self) -> tuple[Timed, Occlusion | None] | None:
        item = await self.queue.get()
        self.slots.release()
        if isinstance(item, BaseException):
            raise item
        return item


class Prepared:
    """The timeline's frames with the occlusion test done (runs on the source thread).

    ``skip(timed) -> bool``, if given, drops frames before any work is done on them (a client
    joining a common epoch late skips what is already past: reading them costs little, their
    occlusion test would cost the time it is trying to catch up); :attr:`skipped` counts them.
    """

    def __init__(
        self, timeline: Timeline, rule: str, skip: Callable[[Timed], bool] | None = None
    ) -> None:
        self.timeline = timeline
        self.rule = rule
        self.skip = skip
        self.skipped = 0
        self._it: Iterator[Timed] | None = None

    def close(self) -> None:
        """End the iteration (on the source thread: a store closes in its own thread)."""
        it, self._it = self._it, None
        close = getattr(it, "close", None)
        if close is not None:
            close()

    def next(self) -> tuple[Timed, Occlusion | None] | None:
        # imported here, on the source thread, while the loop thread connects
        from kinefuse.capture.occlusion.segments import detect_occlusion

        if self._it is None:
            self._it = iter(self.timeline.frames())
        timed = next(self._it, None)
        while timed is not None and self.skip is not None and self.skip(timed):
            self.skipped += 1
            timed = next(self._it, None)
        if timed is None:
            return None
        f = timed.frame
        if isinstance(f, DepthFrame):
            return timed, None
        bodies = f.bodies()  # each body's own test, in one call (a body per row)
        joints = np.stack([b.joints_m for b in bodies])
        r = detect_occlusion(joints, self.timeline.intrinsics, rule=self.rule)  # type: ignore[arg-type]
        return timed, tuple((r.occluded[k], int(r.n_intersections[k])) for k in range(len(bodies)))


def warm_up() -> None:
    import kinefuse.capture.calibration.floor
    import kinefuse.capture.calibration.wand_paper
    import kinefuse.capture.calibration.wand_robust  # noqa: F401


def detect(depth_mm: np.ndarray, timeline: Timeline, detector: str) -> Any:
    if detector == "paper":
        from kinefuse.capture.calibration.wand_paper import detect_wand_paper

        return detect_wand_paper(depth_mm, timeline.intrinsics, timeline.wand)
    from kinefuse.capture.calibration.wand_robust import detect_wand

    return detect_wand(depth_mm, timeline.intrinsics, timeline.wand)


def fit_floor(stack: list[np.ndarray], timeline: Timeline, t_device_s: float) -> Any:
    """The floor of the per-pixel median of ``stack`` (as calibration.session.gather does)."""
    import warnings

    from kinefuse.capture.calibration.floor import fit_floor_plane
    from kinefuse.errors import CalibrationError

    a = np.stack(stack).astype(np.float32)
    a[a == 0] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(a, axis=0)
    med = np.where(np.isfinite(med), med, 0).astype(np.uint16)
    try:
        return fit_floor_plane(med, timeline.intrinsics, name=timeline.sensor_id), t_device_s
    except CalibrationError:
        return None

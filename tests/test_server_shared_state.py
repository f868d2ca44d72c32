"""The live server's state shared between its event loop and its worker threads.

The fusion's warm-up, a slow frame's fusion and a calibration's solve run in worker threads
(``asyncio.to_thread``) while the event loop goes on serving sensors. Each test drives the one
interleaving that matters deterministically: the worker is paused at the point it works on the
shared state, the loop does what a peer makes it do meanwhile (a sensor joins, a floor plane
arrives), then the worker goes on. Real sockets on 127.0.0.1 where a peer is involved; every
test bounded in time.
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from kinefuse.camera.intrinsics import Intrinsics
from kinefuse.net.publish import FusedFrame
from kinefuse.net.server import Server, ServerOptions
from kinefuse.protocol import (
    BodyFrame,
    ClockProbe,
    ClockReply,
    Decoder,
    Hello,
    Welcome,
    encode,
)
from kinefuse.skeleton import N_JOINTS, standing_pose

LIMIT_S = 30.0


class Peer:
    """A sensor peer on a real socket."""

    def __init__(self, r: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
        self.r, self.w, self.dec, self.inbox = r, w, Decoder(), []

    @classmethod
    async def open(cls, port: int) -> Peer:
        return cls(*await asyncio.open_connection("127.0.0.1", port))

    def send(self, msg: Any) -> None:
        self.w.write(encode(msg))

    async def recv(self, timeout: float = 5.0) -> Any:
        while not self.inbox:
            data = await asyncio.wait_for(self.r.read(65536), timeout)
            if not data:
                raise ConnectionError("closed by the server")
            self.inbox.extend(self.dec.feed(data))
        return self.inbox.pop(0)

    async def hello(self, sensor_id: str) -> Any:
        self.send(Hello(role="sensor", sensor_id=sensor_id, intrinsics=Intrinsics()))
        return await self.recv()


def pose_front(distance_m: float = 2.5) -> np.ndarray:
    """A sensor at (0, -d, 1) looking along +y (sensor z), image-down = world -z."""
    p = np.eye(4)
    p[:3, :3] = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])
    p[:3, 3] = [0.0, -distance_m, 1.0]
    return p


async def stream(port: int, sensor_id: str, stop: asyncio.Event) -> None:
    """A standing skeleton at 30 Hz from ``sensor_id``, answering every clock probe."""
    p = await Peer.open(port)
    assert isinstance(await p.hello(sensor_id), Welcome)
    pose = pose_front()
    joints = (standing_pose() - pose[:3, 3]) @ pose[:3, :3]  # world -> sensor frame
    h0 = 50.0  # the host clock: monotonic + 50 s

    async def answer() -> None:
        while True:
            m = await p.recv(30.0)
            if isinstance(m, ClockProbe):
                t = time.monotonic() + h0
                p.send(ClockReply(probe_id=m.probe_id, t1=m.t1, t2=t, t3=t))

    answering = asyncio.ensure_future(answer())
    seq = 0
    try:
        while not stop.is_set():
            t = time.monotonic() + h0
            p.send(
                BodyFrame(
                    seq=seq,
                    t_device_s=t - h0 - 0.06,
                    t_host_s=t,
                    joints_m=joints,
                    states=np.full(N_JOINTS, 2, np.int8),
                )
            )
            seq += 1
            await asyncio.sleep(1 / 30)
            if answering.done():
                answering.result()
    finally:
        answering.cancel()
        p.w.close()


async def until(cond: Callable[[], bool], timeout: float, what: str) -> None:
    t_end = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > t_end:
            raise TimeoutError(f"timed out waiting for {what}")
        await asyncio.sleep(0.02)


class PauseInWorker:
    """Called from the code under test: the first call from a worker thread tells the loop
    (``reached``) and waits until the test has done its part on the loop (:meth:`resume`)."""

    def __init__(self) -> None:
        self.loop = asyncio.get_running_loop()
        self.loop_thread = threading.get_ident()
        self.reached = asyncio.Event()
        self._go = threading.Event()
        self.where: str | None = None

    def __call__(self, where: str) -> None:
        if threading.get_ident() == self.loop_thread or self.where is not None:
            return
        self.where = where
        self.loop.call_soon_threadsafe(self.reached.set)
        self._go.wait(10.0)

    def resume(self) -> None:
        self._go.set()


def test_a_sensor_joining_while_the_fusion_warms_up_in_a_thread_does_not_stop_the_server():
    """The first calibration's poses make the fusion loop warm up in a worker thread. A sensor
    that joins meanwhile is inserted into the server's table of sensors on the loop: the worker
    must not be iterating that table (it crashed the task group: "dictionary changed size during
    iteration"). The worker is paused at its first touch of a sensor's queue or of the fusion,
    sensor "b" connects and is welcomed, then the worker goes on; fused frames follow."""

    async def main() -> None:
        srv = Server(ServerOptions(port=0, timeout_s=5.0))
        task = asyncio.ensure_future(srv.run())
        await until(lambda: srv.port is not None, 5, "the server")
        assert srv.port is not None
        stop = asyncio.Event()
        streaming = asyncio.ensure_future(stream(srv.port, "a", stop))
        # observations with known capture times buffered for the warm-up
        await until(lambda: len(srv.loop._pending.get("a", ())) >= 15, 10, "a's observations")
        pause = PauseInWorker()
        a = srv.clients["a"]
        drain, fuse = a.drain, srv.fusion.fuse

        def paused_drain() -> Any:
            pause("a sensor's queue")
            return drain()

        def paused_fuse(t: float) -> Any:
            pause("the fusion")
            return fuse(t)

        a.drain = paused_drain  # type: ignore[method-assign]
        srv.fusion.fuse = paused_fuse  # type: ignore[method-assign]
        frames: list[FusedFrame] = []
        sub = srv.publisher.subscribe(None)

        async def collect() -> None:
            async for it in sub:
                if isinstance(it, FusedFrame) and np.isfinite(it.positions_m).all():
                    frames.append(it)

        collecting = asyncio.ensure_future(collect())
        srv.loop.set_poses({"a": pose_front()})  # as a finished calibration does
        b = None
        try:
            await asyncio.wait_for(pause.reached.wait(), 10)
            # the worker is paused in the middle of its work: sensor "b" joins now
            b = await Peer.open(srv.port)
            assert isinstance(await b.hello("b"), Welcome)
            assert "b" in srv.clients
        finally:
            pause.resume()
        n = len(frames)
        await until(lambda: len(frames) >= n + 10 or task.done(), 10, "fused frames")
        assert not task.done(), f"the server stopped: {task.exception()!r}"
        np.testing.assert_allclose(frames[-1].positions_m, standing_pose(), atol=0.02)
        stop.set()
        await streaming
        b.w.close()
        srv.request_stop("done")
        await asyncio.wait_for(task, 10)
        collecting.cancel()

    asyncio.run(asyncio.wait_for(main(), LIMIT_S))

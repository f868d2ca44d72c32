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

import test_server_safety as safety
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.skeleton import standing_pose
from kinefuse.live.bus import FusedFrame
from kinefuse.live.protocol import (
    Welcome,
)
from kinefuse.live.server.server import Server, ServerOptions

LIMIT_S = 30.0


async def stream(port: int, sensor_id: str, stop: asyncio.Event) -> None:
    """A standing skeleton at 30 Hz from ``sensor_id``, answering every clock probe."""
    p = await safety.Peer.open(port)
    assert isinstance(await p.hello(sensor_id), Welcome)
    pose = safety.pose_front()
    joints = (standing_pose() - pose[:3, 3]) @ pose[:3, :3]  # world -> sensor frame
    await safety.stream_standing(p, joints, stop, h0=50.0)  # host clock: monotonic + 50 s


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
        srv.loop.set_poses({"a": safety.pose_front()})  # as a finished calibration does
        b = None
        try:
            await asyncio.wait_for(pause.reached.wait(), 10)
            # the worker is paused in the middle of its work: sensor "b" joins now
            b = await safety.Peer.open(srv.port)
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


class PausingId(str):
    """A sensor id whose hashing (a dict lookup with it as the key looked up) pauses a worker
    thread: the hook that lets the loop act while the worker is inside a loop over a dict."""

    pause: PauseInWorker | None = None

    def __hash__(self) -> int:
        if PausingId.pause is not None:
            PausingId.pause("the floors")
        return str.__hash__(self)


def test_a_floor_arriving_while_the_calibration_is_solved_in_a_thread():
    """The calibration is solved in a worker thread while sensors go on sending: sensor "d"
    joins and sends its floor plane, which the loop keeps (``add_floor``). The worker must not
    be reading the floors the loop adds to (it iterated them: the task group stopped the
    server), the floor is kept for the next calibration, and the state machine is the
    calibration's own: "solving" until the loop applies the outcome, reported as "collecting"."""
    from kinefuse.capture.calibration.floor import FloorPlane
    from kinefuse.capture.calibration.synthetic import make_rig, simulate_sightings, wand_waving
    from kinefuse.live.protocol import FloorPlaneMessage as FloorMsg

    ids = ("a", "b", "c")
    rng = np.random.default_rng(7)
    truth = dict(zip(ids, make_rig(3, rng), strict=True))
    t, p = wand_waving(12.0, rng)
    sights = simulate_sightings(list(truth.values()), Intrinsics(), t, p, rng, sensor_ids=ids)

    def floor(pose: np.ndarray) -> FloorPlane:  # the floor z = 0 seen from the sensor
        return FloorPlane(pose[:3, :3].T @ np.array([0.0, 0.0, 1.0]), float(pose[2, 3]), 1000)

    async def main() -> None:
        srv = Server(ServerOptions(port=0, timeout_s=30.0))
        task = asyncio.ensure_future(srv.run())
        await until(lambda: srv.port is not None, 5, "the server")
        assert srv.port is not None
        peers = []
        for sid in ids:
            peers.append(await safety.Peer.open(srv.port))
            assert isinstance(await peers[-1].hello(sid), Welcome)
        cal = srv.calibration
        srv._start_calibration(method="", sensor_ids=ids)
        for sid in ids:
            key = PausingId(sid) if sid == "a" else sid
            cal.add_floor(key, floor(truth[sid]))
            s = sights[sid]
            for tt, c, q in zip(s.t_server_s, s.centre_sensor_m, s.quality, strict=True):
                cal.add_sighting(sid, float(tt), c, float(q))
        pause = PausingId.pause = PauseInWorker()
        d = None
        try:
            srv._finish_calibration(abort=False, why="the test's wand phase is over")
            assert cal.state == "solving"
            await asyncio.wait_for(pause.reached.wait(), 10)
            # the worker is inside its loop over the floors: sensor "d" joins, sends its floor
            assert srv.status().calibration_state == "collecting"
            d = await safety.Peer.open(srv.port)
            assert isinstance(await d.hello("d"), Welcome)
            d.send(FloorMsg(normal=np.array([0.0, -1.0, 0.0]), offset_m=1.1, n_inliers=500))
            await until(lambda: "d" in cal.floors or task.done(), 5, "d's floor")
            assert cal.state == "solving"  # until the loop applies the outcome
        finally:
            pause.resume()
            PausingId.pause = None
        await until(lambda: srv.last_outcome is not None or task.done(), 20, "the outcome")
        assert not task.done(), f"the server stopped: {task.exception()!r}"
        out = srv.last_outcome
        assert out is not None and out.ok, out.message
        assert cal.state == "calibrated" and set(cal.poses) == set(ids)
        assert set(cal.floors) == {"a", "b", "c", "d"}  # d's floor is kept for later
        assert srv.status().calibration_state == "calibrated"
        for x in (*peers, d):
            x.w.close()
        srv.request_stop("done")
        await asyncio.wait_for(task, 10)

    asyncio.run(asyncio.wait_for(main(), LIMIT_S))


def test_the_calibration_owns_its_state_machine():
    """Solving is a state of LiveCalibration's own (not a string the server writes into it):
    begin_solve (on the loop) enters it, the outcome computed from the snapshot alone changes
    nothing, apply (on the loop) leaves it; the status strings stay the protocol's."""
    from kinefuse.capture.calibration.floor import FloorPlane
    from kinefuse.errors import CalibrationError
    from kinefuse.live.server.live_calibration import (
        CalibrationState,
        LiveCalibration,
        solve_calibration,
    )

    cal = LiveCalibration()
    assert cal.state is CalibrationState.NONE and cal.state == "none"
    cal.start(0.0, ["a"])
    job = cal.begin_solve({"a": Intrinsics()}, {})
    assert cal.state is CalibrationState.SOLVING and cal.state.reported == "collecting"
    try:
        cal.start(1.0, ["a"])
    except CalibrationError as e:
        assert "being solved" in str(e)
    else:
        raise AssertionError("a calibration started while one was being solved")
    cal.add_floor("a", FloorPlane(np.array([0.0, -1.0, 0.0]), 1.0))  # the loop goes on
    out = solve_calibration(job)  # nothing sighted: failed
    assert not out.ok and cal.state is CalibrationState.SOLVING and "a" not in job.floors
    cal.apply(out)
    assert cal.state is CalibrationState.FAILED and cal.state.reported == "failed"

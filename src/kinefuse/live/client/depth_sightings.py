"""The sensor client's calibration side: wand sightings and the floor plane from its own depth
frames, while the server runs a calibration (docs/live.md, "Wand detection rate").

Detection runs on one worker thread, one frame at a time: a depth frame that arrives while the
detector is busy is not detected (counted), and each sighting's ``stride`` says how many depth
frames its detection covers. The floor fit (a per-pixel median of the first ``floor_frames``
frames after a start, then :func:`~kinefuse.capture.calibration.floor.fit_floor_plane`) runs on a
second thread, so its ~0.3 s hold up no detection. Results come back on the event loop. A fit
that fails (an exception in its thread, not "no floor found") is logged and reported: the
client tells the server at once (a Heartbeat's ``floor_error``), which shows it in the sensor's
status.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
from collections.abc import Callable
from typing import Any

import numpy as np

from kinefuse.core.frames.observations import DepthFrame
from kinefuse.live.client.parts import detect, fit_floor, warm_up
from kinefuse.live.client.playback import Timeline
from kinefuse.live.protocol.messages import FloorPlaneMessage, Message, WandSighting

log = logging.getLogger("kinefuse.sensor")


class DepthWork:
    """What a client does with its depth frames (nothing while no calibration runs).

    Parameters
    ----------
    timeline : Timeline
        The sensor (its intrinsics and the wand it sees).
    detector : {"robust", "paper"}
    detect_every : int
        Consider every k-th depth frame only.
    floor_frames : int
        Depth frames whose per-pixel median gives the floor plane.
    stats : ClientStats
        Counters (``depth_frames``, ``depth_detected``, ``depth_skipped_busy``).
    send_sighting, send_floor : callable
        Called on the event loop with each WandSighting / the FloorPlaneMessage.
    report_floor_error : callable, optional
        Called on the event loop with the text of a failed floor fit (also kept in
        :attr:`floor_error` until the next calibration starts).
    """

    def __init__(
        self,
        timeline: Timeline,
        *,
        detector: str,
        detect_every: int,
        floor_frames: int,
        stats: Any,
        send_sighting: Callable[[Message], None],
        send_floor: Callable[[Message], None],
        report_floor_error: Callable[[str], None] | None = None,
    ) -> None:
        self.timeline = timeline
        self.detector = detector
        self.detect_every = detect_every
        self.floor_frames = floor_frames
        self.stats = stats
        self.send_sighting = send_sighting
        self.send_floor = send_floor
        self.report_floor_error = report_floor_error
        #: why this calibration's floor fit failed (None: it did not, or not yet)
        self.floor_error: str | None = None
        self.calibrating = False
        self.calibration_id = 0
        self._floor: list[np.ndarray] | None = None
        self._busy = False
        self._since = 0
        self._count = 0
        self._det = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="kinefuse-detect")
        self._warm = False
        self._flo = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="kinefuse-floor")

    def start(self, calibration_id: int) -> None:
        """A calibration started: detect from the next depth frame on, fit the floor anew."""
        log.info("calibration %d started: sending wand sightings", calibration_id)
        if not self._warm:
            # import the detectors (scipy: ~1 s here) on the detection thread now, and only
            # when a calibration needs them: a client that joins after the calibration never
            # competes with its own catching up for the interpreter
            self._warm = True
            self._det.submit(warm_up)
        self.calibrating = True
        self.calibration_id = calibration_id
        self.floor_error = None
        self._floor = []
        self._since = 0

    def stop(self, calibration_id: int) -> None:
        """The calibration ended: no more sightings (results still on their way are dropped)."""
        if self.calibrating:
            log.info("calibration %d stopped", calibration_id)
        self.calibrating = False
        self._floor = None

    def shutdown(self) -> None:
        """Join the worker threads (pending work is cancelled)."""
        self._det.shutdown(wait=True, cancel_futures=True)
        self._flo.shutdown(wait=True, cancel_futures=True)

    def on_depth(self, f: DepthFrame, t_host: float) -> None:
        """A depth frame reached the client at host time ``t_host`` (on the event loop)."""
        self.stats.depth_frames += 1
        if not self.calibrating:
            return
        loop = asyncio.get_running_loop()
        cal_id = self.calibration_id
        if self._floor is not None:
            self._floor.append(f.depth_mm)
            if len(self._floor) >= self.floor_frames:
                stack, self._floor = self._floor, None
                fut = loop.run_in_executor(self._flo, fit_floor, stack, self.timeline, f.t_device_s)
                fut.add_done_callback(lambda r: self._floor_done(r, cal_id, len(stack)))
        self._count += 1
        self._since += 1
        if (self._count - 1) % self.detect_every:
            return
        if self._busy:
            self.stats.depth_skipped_busy += 1
            return
        self._busy = True
        stride, self._since = self._since, 0
        fut = loop.run_in_executor(self._det, detect, f.depth_mm, self.timeline, self.detector)
        fut.add_done_callback(lambda r: self._detected(r, f, t_host, stride, cal_id))

    def _detected(
        self, fut: asyncio.Future[Any], f: DepthFrame, t_host: float, stride: int, cal_id: int
    ) -> None:
        self._busy = False
        if fut.cancelled():
            return
        if fut.exception() is not None:
            log.warning("wand detection failed on frame %d: %s", f.seq, fut.exception())
            return
        det = fut.result()
        self.stats.depth_detected += 1
        if not det.found or not self.calibrating or cal_id != self.calibration_id:
            return
        self.send_sighting(
            WandSighting(
                seq=f.seq,
                t_device_s=f.t_device_s,
                t_host_s=t_host,
                centre_m=det.centre_sensor_m,
                score=float(np.clip(det.score, 0.0, 1.0)),
                n_points=int(det.n_points),
                residual_m=float(det.residual_m),
                pixel_uv=det.pixel_uv,
                detector=self.detector,
                stride=stride,
                calibration_id=cal_id,
            )
        )

    def _floor_done(self, fut: asyncio.Future[Any], cal_id: int, n: int) -> None:
        if fut.cancelled():
            return
        exc = fut.exception()
        if exc is not None:
            why = f"{type(exc).__name__}: {exc}"
            log.warning(
                "calibration %d: the floor fit on the first %d depth frames failed: %s",
                cal_id,
                n,
                why,
            )
            if cal_id == self.calibration_id:
                self.floor_error = f"floor fit failed: {why}"[:1024]
                if self.report_floor_error is not None:
                    self.report_floor_error(self.floor_error)
            return
        res = fut.result()
        if res is None or cal_id != self.calibration_id:
            log.info("no floor plane found in the first %d depth frames", n)
            return
        plane, t_dev = res
        self.send_floor(
            FloorPlaneMessage(
                normal=plane.normal,
                offset_m=float(plane.offset_m),
                n_inliers=int(plane.n_inliers),
                residual_m=float(plane.residual_m),
                n_frames=n,
                t_device_s=t_dev,
                calibration_id=cal_id,
            )
        )

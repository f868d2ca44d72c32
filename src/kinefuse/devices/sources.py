"""Cameras as sensor sources: a camera (live or a recording) plus an optional body tracker
becomes the :class:`~kinefuse.core.frames.source.FrameSource` a sensor client plays.

A *camera* is what a device module opens (:class:`Camera`: its calibration, serial, whether it
is live, and its captures). Camera kinds are entry points of the group ``kinefuse.cameras``
(``mkv``, ``k4a``, ``realsense``, ``realsense-file``, ``kinect2`` in kinefuse's own
``pyproject.toml``; a package of a user's can add one), each a factory
``open(arg: str, options: dict[str, str]) -> Camera`` raising :class:`InputError` with one line
when its library, runtime or device is missing. :data:`KNOWN_SOURCES` says, for the listing,
which library each kind needs and the command that installs it.

:class:`CameraFrameSource` turns each capture into a :class:`DepthFrame` (the wand is found in
it) and, with a tracker, a :class:`BodyFrame` of the nearest body the tracker kept (empty when
it kept none): for every capture when the tracker runs inline (``kinefuse track``), for the
captures it kept up with when it runs on its own thread (``kinefuse sensor``). The tracker is
handed the pinhole depth and IR (:meth:`CameraFrameSource.for_tracker`). A camera that delivers
bodies itself (the Kinect v2's SDK) gives them as ``Capture``-side results through its own
tracker (:attr:`Camera.tracker`).
"""

from __future__ import annotations

import importlib.util
import math
import sys
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from importlib.metadata import entry_points
from typing import Protocol, runtime_checkable
from urllib.parse import parse_qsl

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.frames.observations import MAX_BODIES, BodyFrame, DepthFrame, Frame
from kinefuse.core.skeleton import N_JOINTS, TrackingState
from kinefuse.devices.capture import CameraCalibration, Capture
from kinefuse.devices.trackers import (
    TrackedBody,
    Tracker,
    TrackerResult,
    available_trackers,
    load_tracker,
)
from kinefuse.devices.undistort import DepthUndistorter
from kinefuse.devices.worker import TrackerWorker
from kinefuse.errors import InputError

__all__ = [
    "CAMERA_GROUP",
    "KNOWN_SOURCES",
    "KNOWN_TRACKERS",
    "Camera",
    "CameraFrameSource",
    "SourceInfo",
    "body_frame",
    "camera_kinds",
    "frame_bodies",
    "list_sources",
    "nearest_body",
    "open_camera",
    "open_camera_source",
    "parse_spec",
]

#: the entry-point group a camera kind is registered under
CAMERA_GROUP = "kinefuse.cameras"


@runtime_checkable
class Camera(Protocol):
    """An RGB-D camera or its recording, as a device module opens it.

    ``live`` is True for a device (captures come in real time, stamped on arrival with this
    PC's monotonic clock in ``t_host_s``), False for a recording (played on its device times).
    ``tracker`` is the camera's own body tracker (the Kinect v2's SDK), or None.
    """

    calibration: CameraCalibration
    serial: str
    live: bool
    rate_hz: float

    def captures(self) -> Iterator[Capture]: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class SourceInfo:
    """One line of ``kinefuse sensor --list-sources``: a source or tracker kind."""

    name: str
    form: str
    what: str
    module: str  #: the library it imports ("" = none beyond kinefuse's own)
    install: str  #: the command that installs it
    platform: str = ""  #: ``sys.platform`` prefix it runs on ("" = any)


#: built-in and device kinds: the library each imports and the command that installs it
KNOWN_SOURCES: tuple[SourceInfo, ...] = (
    SourceInfo("sim", "sim:SESSION.sqlite#SENSOR_ID", "a simulated session's sensor", "", ""),
    SourceInfo("simlive", "simlive:CLIP#SENSOR_ID?...", "a simulated sensor, generated", "", ""),
    SourceInfo("multitrack", "multitrack:FILE.csv#KINECT_ID", "a KinectMultiTrack log", "", ""),
    SourceInfo("kinect2json", "kinect2json:FILE.json", "a kinect2-tracking JSON", "", ""),
    SourceInfo("driver", "driver:MODULE:FACTORY[?K=V]", "a FrameSource of your own", "", ""),
    SourceInfo(
        "mkv",
        "mkv:FILE.mkv[#ID]",
        "an Azure Kinect / Femto recording (k4arecorder)",
        "av",
        "pip install 'kinefuse[mkv]'",
    ),
    SourceInfo(
        "k4a",
        "k4a:[INDEX|SERIAL][?depth_mode=NFOV_UNBINNED&fps=30&color=720P]",
        "a live Azure Kinect DK or Orbbec Femto",
        "pyk4a",
        "pip install 'kinefuse[k4a]'",
    ),
    SourceInfo(
        "realsense",
        "realsense:[SERIAL][?width=640&height=480&fps=30]",
        "a live Intel RealSense D4xx",
        "pyrealsense2",
        "pip install 'kinefuse[realsense]'",
    ),
    SourceInfo(
        "realsense-file",
        "realsense-file:FILE.bag|FILE.db3",
        "a RealSense recording",
        "pyrealsense2",
        "pip install 'kinefuse[realsense]'",
    ),
    SourceInfo(
        "kinect2",
        "kinect2[:INDEX]",
        "a Kinect v2 (64-bit Windows, Kinect for Windows SDK 2.0 runtime)",
        "kinect_next",
        "pip install 'kinefuse[kinect2]' on 64-bit Windows with the Kinect for Windows SDK 2.0 "
        "runtime",
        "win32",
    ),
)

#: trackers kinefuse knows of (an installed entry point is listed whether known or not)
KNOWN_TRACKERS: tuple[SourceInfo, ...] = (
    SourceInfo(
        "k4abt",
        "--tracker k4abt",
        "Microsoft's Azure Kinect Body Tracking SDK",
        "pykinect_azure",
        "pip install pykinect-azure, and install Microsoft's Azure Kinect Body Tracking SDK "
        "(not on PyPI)",
    ),
    SourceInfo(
        "pose",
        "--tracker pose",
        "kinefuse's own tracker (any RGB-D camera)",
        "mediapipe",
        "pip install 'kinefuse[tracker]'",
    ),
)


def _module_found(name: str) -> bool:
    if not name:
        return True
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):
        return False


def list_sources() -> list[tuple[str, str, str, str]]:
    """Rows ``(kind, form, status, what)`` for every source and tracker kind, known or
    registered: status ``installed``, or ``missing: <command that installs it>``, or
    ``needs: <what it needs>`` (another platform)."""
    rows: list[tuple[str, str, str, str]] = []

    def status(info: SourceInfo) -> str:
        if info.platform and not sys.platform.startswith(info.platform):
            return f"needs: {info.install}"
        if _module_found(info.module):
            return "installed"
        return f"missing: {info.install}"

    cams = {ep.name: ep.value for ep in entry_points(group=CAMERA_GROUP)}
    for info in KNOWN_SOURCES:
        rows.append((info.name, info.form, status(info), info.what))
    known = {i.name for i in KNOWN_SOURCES}
    for name in sorted(set(cams) - known):
        rows.append((name, f"{name}:ARG", "installed", f"camera entry point {cams[name]}"))
    trackers = available_trackers()
    for info in KNOWN_TRACKERS:
        st = status(info) if info.name in trackers else f"missing: {info.install}"
        rows.append(("tracker " + info.name, info.form, st, info.what))
    for name in sorted(set(trackers) - {i.name for i in KNOWN_TRACKERS}):
        rows.append(("tracker " + name, f"--tracker {name}", "installed", trackers[name]))
    return rows


def open_camera(kind: str, arg: str, options: Mapping[str, str] | None = None) -> Camera:
    """Open a camera of a registered kind; :class:`InputError` naming the kinds if unknown."""
    eps = {ep.name: ep for ep in entry_points(group=CAMERA_GROUP)}
    if kind not in eps:
        raise InputError(
            f"no camera source {kind!r}; installed ({CAMERA_GROUP} entry points): "
            f"{', '.join(sorted(eps)) or 'none'} (kinefuse sensor --list-sources)"
        )
    cam = eps[kind].load()(arg, dict(options or {}))
    if not isinstance(cam, Camera):
        raise InputError(
            f"camera source {kind!r} gave a {type(cam).__name__}, not a kinefuse Camera "
            "(calibration, serial, live, rate_hz, captures(), close())"
        )
    return cam


def camera_kinds() -> set[str]:
    """The registered camera kinds."""
    return {ep.name for ep in entry_points(group=CAMERA_GROUP)}


def nearest_body(result: TrackerResult) -> TrackedBody | None:
    """The body nearest the camera (smallest median depth of its present joints), or None."""
    best, best_z = None, math.inf
    for b in result.bodies:
        z = np.asarray(b.joints_m, dtype=np.float64)[:, 2]
        ok = np.isfinite(z) & (np.asarray(b.states) != TrackingState.NOT_TRACKED)
        if not ok.any():
            continue
        zm = float(np.median(z[ok]))
        if zm < best_z:
            best, best_z = b, zm
    return best


def frame_bodies(result: TrackerResult) -> tuple[TrackedBody, ...]:
    """Every body of a tracker result that has a present joint: the nearest first (the body
    kinefuse has always taken, :func:`nearest_body`), then the others in the tracker's order;
    at most :data:`~kinefuse.core.frames.observations.MAX_BODIES`."""
    first = nearest_body(result)
    if first is None:
        return ()
    rest = [
        b
        for b in result.bodies
        if b is not first
        and (
            np.isfinite(np.asarray(b.joints_m, dtype=np.float64)).all(-1)
            & (np.asarray(b.states) != TrackingState.NOT_TRACKED)
        ).any()
    ]
    return (first, *rest)[:MAX_BODIES]


def body_frame(
    sensor_id: str,
    capture: Capture,
    body: TrackedBody | None,
    t_host_s: float,
    others: Sequence[TrackedBody] = (),
) -> BodyFrame:
    """The client's body frame of one capture: the body's joints (already in the depth camera's
    frame, x right, y down, z forward, metres) with NaN exactly where NOT_TRACKED, its tracker id
    as ``body_id``, and ``others`` as the frame's other bodies; an empty frame (every joint
    NOT_TRACKED, body 0) when there is no body."""
    joints = np.full((N_JOINTS, 3), np.nan)
    states = np.zeros(N_JOINTS, dtype=np.int8)
    body_id = 0
    if body is not None:
        j = np.asarray(body.joints_m, dtype=np.float64).reshape(N_JOINTS, 3)
        st = np.asarray(body.states, dtype=np.int8).reshape(N_JOINTS)
        ok = (st != TrackingState.NOT_TRACKED) & np.isfinite(j).all(axis=1)
        joints[ok] = j[ok]
        states[ok] = st[ok]
        body_id = int(body.body_id) % (1 << 63)  # a Kinect v2 id is a uint64
    more = tuple(body_frame(sensor_id, capture, o, t_host_s) for o in others)
    return BodyFrame(
        sensor_id, capture.seq, capture.t_device_s, t_host_s, joints, states,
        body_id=body_id, others=more,
    )  # fmt: skip


class CameraFrameSource:
    """A camera and an optional tracker as the frame source of one sensor.

    Parameters
    ----------
    camera : Camera
    sensor_id : str
    tracker : Tracker, optional
        Runs on every capture; None (and the camera has none of its own): depth only.
    depth : bool
        Deliver the depth frames (default True; the wand is found in them).
    threaded : bool
        Run the tracker on its own thread (:class:`~kinefuse.devices.worker.TrackerWorker`), as
        a sensor client does: depth frames flow at the camera's rate, body frames follow as
        the tracker finishes them, and the oldest waiting capture is dropped when it falls
        behind (at most ``max_pending`` wait). False (``kinefuse track``): every capture is
        tracked, in turn.
    speed : float
        With ``threaded``, a recording's captures are handed over at ``speed`` times its
        device clock (a live camera gives them at its own rate).

    After a pass, :attr:`captures`, :attr:`with_person` and :attr:`refused` count what it saw.
    """

    def __init__(
        self,
        camera: Camera,
        sensor_id: str,
        tracker: Tracker | None = None,
        *,
        depth: bool = True,
        threaded: bool = False,
        speed: float = 1.0,
        max_pending: int = 2,
    ) -> None:
        if not speed > 0:
            raise InputError(f"speed must be positive, got {speed}")
        self.camera = camera
        self.threaded, self.speed, self.max_pending = threaded, float(speed), int(max_pending)
        #: the running tracker worker (``threaded`` only), for its status
        self.worker: TrackerWorker | None = None
        self._id = sensor_id
        self.tracker = tracker if tracker is not None else getattr(camera, "tracker", None)
        self.depth = depth
        self.live = bool(camera.live)
        self.serial = camera.serial
        self.captures = 0
        self.with_person = 0
        self.refused: list[str] = []
        cal = camera.calibration
        #: resamples the device's depth to the pinhole camera kinefuse works with (None: the
        #: device gives undistorted images)
        self._pinhole = DepthUndistorter(cal) if any(cal.distortion_depth) else None
        self._tracker_calibration = replace(cal, distortion_depth=())

    def depth_of(self, capture: Capture) -> NDArray[np.uint16] | None:
        """A capture's depth image in the pinhole camera :meth:`intrinsics` describes."""
        d = capture.depth_mm
        if d is None or self._pinhole is None:
            return d
        return self._pinhole(d)

    def for_tracker(self, capture: Capture) -> tuple[Capture, CameraCalibration]:
        """What the tracker gets (the :class:`~kinefuse.devices.trackers.Tracker` contract):
        the depth and IR images in the pinhole camera, with the calibration that says so (no
        depth distortion); the device's own images and calibration for a tracker that sets
        ``device_images`` (Microsoft's, which undistorts itself from the device's JSON)."""
        cal = self.camera.calibration
        if self._pinhole is None or getattr(self.tracker, "device_images", False):
            return capture, cal
        ir = capture.ir
        pinhole_ir = None if ir is None else self._pinhole(ir)
        return (
            replace(capture, depth_mm=self.depth_of(capture), ir=pinhole_ir),
            self._tracker_calibration,
        )

    @property
    def sensor_ids(self) -> tuple[str, ...]:
        return (self._id,)

    def intrinsics(self, sensor_id: str) -> Intrinsics:
        """The depth camera as a pinhole (the device's focal lengths and principal point; its
        distortion is taken out of the depth frames, :meth:`depth_of`)."""
        return self.camera.calibration.depth

    def __iter__(self) -> Iterator[Frame]:
        if self.threaded and self.tracker is not None:
            yield from self._threaded()
            return
        for cap in self.camera.captures():
            self.captures += 1
            yield from self._depth_frame(cap)
            if self.tracker is None:
                continue
            yield self._body_frame(cap, self.tracker.track(*self.for_tracker(cap)))

    def _depth_frame(self, cap: Capture, pinhole: Capture | None = None) -> Iterator[DepthFrame]:
        """The depth frame of ``cap`` (``pinhole``: the tracker's copy, its depth already
        resampled)."""
        if self.depth and cap.depth_mm is not None:
            depth = pinhole.depth_mm if pinhole is not None else self.depth_of(cap)
            assert depth is not None
            yield DepthFrame(self._id, cap.seq, cap.t_device_s, cap.t_host_s, depth)

    def _body_frame(self, cap: Capture, result: TrackerResult) -> BodyFrame:
        self.refused.extend(result.refused)
        bodies = frame_bodies(result)  # the nearest first: the one kinefuse always took
        self.with_person += bool(bodies)
        first = bodies[0] if bodies else None
        return body_frame(self._id, cap, first, cap.t_host_s, bodies[1:])

    def _threaded(self) -> Iterator[Frame]:
        """Depth frames at the camera's rate; body frames as the worker finishes them, stamped
        with their capture's times (a recording is paced on its device clock at ``speed``)."""
        assert self.tracker is not None
        raw = self._pinhole is None or getattr(self.tracker, "device_images", False)
        cal = self.camera.calibration if raw else self._tracker_calibration
        worker = TrackerWorker(self.tracker, cal, max_pending=self.max_pending)
        self.worker = worker.start()
        t0: tuple[float, float] | None = None
        try:
            for cap in self.camera.captures():
                if not self.live:
                    now = time.monotonic()
                    t0 = t0 or (now, cap.t_device_s)
                    due = t0[0] + (cap.t_device_s - t0[1]) / self.speed
                    if due > now:
                        time.sleep(due - now)
                self.captures += 1
                tcap = self.for_tracker(cap)[0]
                yield from self._depth_frame(cap, None if raw else tcap)
                worker.submit(tcap)
                while (done := worker.get(0)) is not None:
                    yield self._body_frame(*done)
            worker.drain()
            while (done := worker.get(0)) is not None:
                yield self._body_frame(*done)
        finally:
            worker.stop()

    def tracker_status(self) -> str | None:
        """The tracker worker's one-line status (rate, drops, last refusal); None without one."""
        return None if self.worker is None else self.worker.status().line()

    def close(self) -> None:
        """Close the camera and the tracker (its worker stopped first: never closed mid-call)."""
        if self.worker is not None:
            self.worker.stop()
        try:
            self.camera.close()
        finally:
            if self.tracker is not None:
                self.tracker.close()


def parse_spec(spec: str) -> tuple[str, str, dict[str, str], str]:
    """``KIND:ARG[?K=V&...][#ID]`` -> ``(kind, arg, options, sensor_id)``."""
    kind, _, rest = spec.partition(":")
    rest, _, sensor = rest.partition("#")
    arg, _, query = rest.partition("?")
    try:
        options = dict(parse_qsl(query, keep_blank_values=True, strict_parsing=bool(query)))
    except ValueError:
        raise InputError(f"source {spec!r}: options go as ?KEY=VALUE&KEY=VALUE") from None
    return kind, arg, options, sensor


def open_camera_source(
    spec: str,
    tracker: str | None = None,
    *,
    depth: bool = True,
    threaded: bool = False,
    speed: float = 1.0,
) -> CameraFrameSource:
    """The frame source of a camera spec ``KIND:ARG[?K=V&...][#SENSOR_ID]`` with the tracker
    named ``tracker`` (:func:`~kinefuse.devices.trackers.load_tracker`), or none;
    ``threaded`` and ``speed`` as :class:`CameraFrameSource`'s."""
    kind, arg, options, sensor = parse_spec(spec)
    trk = load_tracker(tracker) if tracker else None
    try:
        cam = open_camera(kind, arg, options)
    except BaseException:
        if trk is not None:
            trk.close()
        raise
    sid = sensor or str(getattr(cam, "default_id", "") or f"{kind}-{cam.serial or 0}")
    return CameraFrameSource(cam, sid, trk, depth=depth, threaded=threaded, speed=speed)

"""Intel RealSense D4xx cameras and their recordings with pyrealsense2.

- ``realsense:[SERIAL][?width=640&height=480&fps=30&color=1]``: a live camera (the first one,
  or the one with that serial number): depth (z16) and, unless ``color=0``, colour (rgb8);
- ``realsense-file:FILE``: a recording made by the RealSense Viewer, ``rs-record`` or
  pyrealsense2's recorder (``.bag``, ROS 1, from older librealsense; ``.db3``, ROS 2, which
  librealsense 2.56 and later write), read as fast as it decodes (the client plays it on its
  timestamps).

The calibration is the device's (or the file's): the depth stream's intrinsics, the colour
stream's, and the depth-to-colour extrinsics (pyrealsense2 gives the rotation column-major).
Depth is converted to millimetres with the device's depth scale. Device timestamps are the
frames' own (``get_timestamp``, milliseconds).
"""

from __future__ import annotations

import contextlib
import queue
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.devices.capture import CameraCalibration, Capture
from kinefuse.errors import InputError

__all__ = [
    "RealSenseCamera",
    "RealSenseRecording",
    "import_pyrealsense2",
    "open_realsense",
    "open_realsense_file",
]

#: the D4xx depth range a capture is trusted over (Intel's D400 datasheet: from about 0.2-0.3 m
#: at 640x480 to an error past 2 % beyond a few metres); readings outside it still pass
MIN_RANGE_M = 0.2
MAX_RANGE_M = 6.0


def import_pyrealsense2() -> Any:
    """pyrealsense2, or one line saying what to install."""
    try:
        import pyrealsense2
    except ImportError:
        raise InputError(
            "the realsense sources need pyrealsense2: pip install 'kinefuse[realsense]' "
            "(docs/devices.md, RealSense)"
        ) from None
    return pyrealsense2


def _intrinsics(rs_intr: Any, lo: float, hi: float) -> tuple[Intrinsics, tuple[float, ...]]:
    intr = Intrinsics(
        width=int(rs_intr.width),
        height=int(rs_intr.height),
        fx=float(rs_intr.fx),
        fy=float(rs_intr.fy),
        cx=float(rs_intr.ppx),
        cy=float(rs_intr.ppy),
        min_range_m=lo,
        max_range_m=hi,
    )
    coeffs = tuple(float(c) for c in rs_intr.coeffs)
    return intr, coeffs if any(coeffs) else ()


def _device_calibration(
    rs: Any, dev: Any, depth_prof: Any, color_prof: Any
) -> tuple[CameraCalibration, str, float]:
    """``(calibration, serial, mm per depth unit)`` of a device (or a recording's) streams."""
    info = rs.camera_info
    serial = dev.get_info(info.serial_number) if dev.supports(info.serial_number) else ""
    name = dev.get_info(info.name) if dev.supports(info.name) else "RealSense"
    scale = 0.001
    for sensor in dev.query_sensors():
        if sensor.is_depth_sensor():
            scale = float(sensor.as_depth_sensor().get_depth_scale())
    depth, dist_d = _intrinsics(depth_prof.get_intrinsics(), MIN_RANGE_M, MAX_RANGE_M)
    color = None
    dist_c: tuple[float, ...] = ()
    color_from_depth = None
    if color_prof is not None:
        color, dist_c = _intrinsics(color_prof.get_intrinsics(), 0.1, 100.0)
        ex = depth_prof.get_extrinsics_to(color_prof)
        color_from_depth = np.eye(4)
        # pyrealsense2's rotation is column-major
        color_from_depth[:3, :3] = np.asarray(ex.rotation, dtype=np.float64).reshape(3, 3).T
        color_from_depth[:3, 3] = np.asarray(ex.translation, dtype=np.float64)
    cal = CameraCalibration(
        depth=depth,
        color=color,
        color_from_depth=color_from_depth,
        distortion_depth=dist_d,
        distortion_color=dist_c,
        device=f"{name} {serial}".strip(),
    )
    return cal, str(serial), 1000.0 * scale


def _to_mm(z: Any, scale_mm: float) -> NDArray[np.uint16]:
    if abs(scale_mm - 1.0) < 1e-6:  # the D4xx default: units of 1 mm
        return np.array(z, dtype=np.uint16)
    return np.rint(np.asarray(z) * scale_mm).clip(0, 65535).astype(np.uint16)


class RealSenseCamera:
    """A live RealSense through a pyrealsense2 pipeline (see the module notes)."""

    live = True

    def __init__(self, rs: Any, config: Any, what: str) -> None:
        self._what = what
        self._pipe = rs.pipeline()
        try:
            profile = self._pipe.start(config)
        except RuntimeError as e:
            raise InputError(f"{what}: does not start ({e})") from None
        streams = {sp.stream_type(): sp.as_video_stream_profile() for sp in profile.get_streams()}
        depth_prof = streams[rs.stream.depth]
        self.calibration, self.serial, self._scale_mm = _device_calibration(
            rs, profile.get_device(), depth_prof, streams.get(rs.stream.color)
        )
        #: the sensor id unless told
        self.default_id = f"rs-{self.serial}"
        self.rate_hz = float(depth_prof.fps())

    def captures(self) -> Iterator[Capture]:
        """Framesets as the camera delivers them, stamped on arrival with this PC's clock."""
        seq = 0
        while True:
            ok, frames = self._pipe.try_wait_for_frames(5000)
            if not ok:
                raise InputError(f"{self._what}: no frames for 5 s (unplugged?)")
            t_host = time.monotonic()
            depth = frames.get_depth_frame()
            if not depth:
                continue
            color = frames.get_color_frame()
            yield Capture(
                seq=seq,
                t_device_s=depth.get_timestamp() * 1e-3,
                t_host_s=t_host,
                depth_mm=_to_mm(np.asanyarray(depth.get_data()), self._scale_mm),
                color=np.array(np.asanyarray(color.get_data()), dtype=np.uint8) if color else None,
            )
            seq += 1

    def close(self) -> None:
        with contextlib.suppress(RuntimeError):
            self._pipe.stop()


_END = object()


class RealSenseRecording:
    """A RealSense recording read frame by frame (playback not in real time: nothing dropped).

    The playback device hands each frame to a callback, which blocks on a small queue until the
    reader takes it; each depth frame becomes a capture with the latest colour frame."""

    live = False

    def __init__(self, rs: Any, path: Path) -> None:
        self._rs = rs
        self.path = path
        try:
            dev = rs.context().load_device(str(path))
        except RuntimeError as e:
            raise InputError(f"{path}: not a readable RealSense recording ({e})") from None
        profiles: dict[Any, Any] = {}
        for sensor in dev.query_sensors():
            for sp in sensor.get_stream_profiles():
                if sp.is_video_stream_profile():
                    profiles.setdefault(sp.stream_type(), sp.as_video_stream_profile())
        if rs.stream.depth not in profiles:
            raise InputError(f"{path}: the recording has no depth stream")
        depth_prof = profiles[rs.stream.depth]
        self.calibration, self.serial, self._scale_mm = _device_calibration(
            rs, dev, depth_prof, profiles.get(rs.stream.color)
        )
        self.default_id = path.stem
        self.rate_hz = float(depth_prof.fps())

    def captures(self) -> Iterator[Capture]:
        """The recording's depth frames in order, each with the latest colour frame."""
        rs = self._rs
        dev = rs.context().load_device(str(self.path))
        playback = dev.as_playback()
        playback.set_real_time(False)
        q: queue.Queue[Any] = queue.Queue(maxsize=8)

        def on_status(status: Any) -> None:
            if status == rs.playback_status.stopped:
                q.put(_END)

        def on_frame(f: Any) -> None:
            kind = f.get_profile().stream_type()
            if kind in (rs.stream.depth, rs.stream.color):
                data = np.array(np.asanyarray(f.as_video_frame().get_data()))
                q.put((kind, f.get_timestamp() * 1e-3, data))

        playback.set_status_changed_callback(on_status)
        started = []
        try:
            for sensor in dev.query_sensors():
                sensor.open(sensor.get_stream_profiles())
                sensor.start(on_frame)
                started.append(sensor)
            seq = 0
            color = None
            while True:
                try:
                    item = q.get(timeout=10)
                except queue.Empty:
                    raise InputError(f"{self.path}: the playback stalled (damaged file?)") from None
                if item is _END:
                    return
                kind, t, data = item
                if kind == rs.stream.color:
                    color = np.asarray(data, dtype=np.uint8)
                    continue
                yield Capture(seq=seq, t_device_s=t, depth_mm=_to_mm(data, self._scale_mm),
                              color=color)  # fmt: skip
                seq += 1
        finally:
            playback.pause()
            while not q.empty():  # unblock a callback waiting on a full queue
                q.get_nowait()
            for sensor in started:
                with contextlib.suppress(RuntimeError):
                    sensor.stop()
                    sensor.close()

    def close(self) -> None:
        """Nothing held between passes (each :meth:`captures` opens the file)."""


def _size_options(options: dict[str, str], what: str) -> tuple[int, int, int, bool]:
    known = {"width", "height", "fps", "color"}
    bad = sorted(set(options) - known)
    if bad:
        raise InputError(f"{what}: unknown option(s) {', '.join(bad)}; it takes {sorted(known)}")
    try:
        w = int(options.get("width", "640"))
        h = int(options.get("height", "480"))
        fps = int(options.get("fps", "30"))
        color = options.get("color", "1") not in ("0", "no", "off", "false")
    except ValueError:
        raise InputError(f"{what}: width, height and fps are whole numbers") from None
    return w, h, fps, color


def open_realsense(arg: str, options: dict[str, str]) -> RealSenseCamera:
    """The ``realsense`` camera kind: a live D4xx."""
    w, h, fps, color = _size_options(options, "realsense")
    rs = import_pyrealsense2()
    devices = rs.context().query_devices()
    serials = [d.get_info(rs.camera_info.serial_number) for d in devices]
    if not serials:
        raise InputError(
            "realsense: no RealSense camera is connected (check the USB 3 cable; "
            "`rs-enumerate-devices` should list it)"
        )
    if arg and arg not in serials:
        raise InputError(f"realsense: no camera with serial {arg!r}; connected: {serials}")
    cfg = rs.config()
    cfg.enable_device(arg or serials[0])
    cfg.enable_stream(rs.stream.depth, w, h, rs.format.z16, fps)
    if color:
        cfg.enable_stream(rs.stream.color, w, h, rs.format.rgb8, fps)
    return RealSenseCamera(rs, cfg, f"realsense {arg or serials[0]}")


def open_realsense_file(arg: str, options: dict[str, str]) -> RealSenseRecording:
    """The ``realsense-file`` camera kind: a ``.bag`` recording."""
    if options:
        raise InputError(f"realsense-file:{arg}: takes no options")
    p = Path(arg)
    if not p.is_file():
        raise InputError(f"realsense-file: {p}: no such file (a RealSense recording, .bag or .db3)")
    with p.open("rb") as f:
        head = f.read(16)
    if not (head.startswith(b"#ROSBAG V2.0") or head == b"SQLite format 3\x00"):
        raise InputError(
            f"{p}: not a RealSense recording (a ROS bag .bag, or the ROS 2 .db3 that "
            "librealsense 2.56 and later record)"
        )
    rs = import_pyrealsense2()
    return RealSenseRecording(rs, p)

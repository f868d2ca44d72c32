"""A Kinect v2 through kinect-next (``kinect2[:INDEX]``): 64-bit Windows with the Kinect for
Windows SDK 2.0 runtime only (the SDK is a Windows COM library).

The camera delivers depth (512 x 424, millimetres), infrared and the SDK's own body frames; its
bodies are the camera's tracker (:attr:`Kinect2Camera.tracker`), so no ``--tracker`` is needed.
The SDK's camera space is x to the sensor's left, y up, z forward (metres); kinefuse's sensor
frame is x right, y down, z forward: x and y change sign (:data:`KINECT_CAMERA_TO_SENSOR`). Its
joint order and tracking states are kinefuse's (both are the SDK's ``JointType`` and
``TrackingState``).
"""

from __future__ import annotations

import platform
import sys
import time
from collections.abc import Iterable, Iterator
from typing import Any

import numpy as np

from kinefuse.core.camera.intrinsics import (
    KINECT_V2_DEPTH_HEIGHT,
    KINECT_V2_DEPTH_WIDTH,
    KINECT_V2_MAX_RANGE_M,
    KINECT_V2_MIN_RANGE_M,
    Intrinsics,
)
from kinefuse.core.skeleton import N_JOINTS, TrackingState
from kinefuse.devices.capture import CameraCalibration, Capture
from kinefuse.devices.trackers import TrackedBody, TrackerResult
from kinefuse.errors import InputError

__all__ = ["KINECT_CAMERA_TO_SENSOR", "Kinect2Camera", "bodies_to_result", "open_kinect2"]

#: Kinect camera space (x left, y up, z forward) -> kinefuse sensor axes (x right, y down, z fwd)
KINECT_CAMERA_TO_SENSOR = np.array([-1.0, -1.0, 1.0])

NEEDS = "kinect2: needs 64-bit Windows with the Kinect for Windows SDK 2.0 runtime"


def bodies_to_result(bodies: Iterable[Any]) -> TrackerResult:
    """kinect-next's ``Body`` objects -> the tracked bodies in kinefuse's sensor frame.

    Bodies the SDK does not track are left out; a joint the SDK marks NOT_TRACKED (or that is
    missing, or not finite) is NaN and NOT_TRACKED; the others keep the SDK's state."""
    out = []
    for b in bodies:
        if not getattr(b, "is_tracked", False):
            continue
        joints = np.full((N_JOINTS, 3), np.nan)
        states = np.zeros(N_JOINTS, dtype=np.int8)
        for jt in b.joints:
            i = int(jt.joint_type)
            st = int(jt.tracking_state)
            p = np.array([jt.position.x, jt.position.y, jt.position.z], dtype=np.float64)
            if 0 <= i < N_JOINTS and st != TrackingState.NOT_TRACKED and np.isfinite(p).all():
                joints[i] = KINECT_CAMERA_TO_SENSOR * p
                states[i] = st
        out.append(TrackedBody(int(b.tracking_id), joints, states))
    return TrackerResult(bodies=tuple(out))


class _SdkBodies:
    """The Kinect v2 SDK's own tracker: the bodies of the frameset a capture came from."""

    name = "kinect2"

    def __init__(self) -> None:
        self.latest: dict[int, TrackerResult] = {}

    def track(self, capture: Capture, calibration: CameraCalibration) -> TrackerResult:
        return self.latest.pop(capture.seq, TrackerResult())

    def close(self) -> None:
        self.latest.clear()


class Kinect2Camera:
    """A live Kinect v2 (depth, infrared, the SDK's bodies)."""

    live = True
    rate_hz = 30.0

    def __init__(self, kn: Any) -> None:
        streams = kn.StreamType.DEPTH | kn.StreamType.INFRARED | kn.StreamType.BODY
        try:
            self._sensor = kn.KinectSensor(streams)
            fx, fy, cx, cy = self._sensor.mapper.get_depth_camera_intrinsics()
        except kn.KinectError as e:
            raise InputError(
                f"kinect2: the sensor does not open ({e}); check its power supply and USB 3 "
                "adapter, and that Kinect Studio or another program does not hold it"
            ) from None
        self._kn = kn
        self.serial = ""
        self.default_id = "kinect2"
        depth = Intrinsics(
            KINECT_V2_DEPTH_WIDTH, KINECT_V2_DEPTH_HEIGHT, float(fx), float(fy), float(cx),
            float(cy), KINECT_V2_MIN_RANGE_M, KINECT_V2_MAX_RANGE_M,
        )  # fmt: skip
        self.calibration = CameraCalibration(depth=depth, device="Kinect v2")
        self.tracker = _SdkBodies()

    def captures(self) -> Iterator[Capture]:
        for seq, fs in enumerate(self._sensor.poll_frames()):
            t_host = time.monotonic()
            self.tracker.latest = {seq: bodies_to_result(fs.bodies)}
            ir = fs.infrared
            yield Capture(
                seq=seq,
                t_device_s=fs.relative_time_ns * 1e-9,
                t_host_s=t_host,
                depth_mm=None if fs.depth is None else np.array(fs.depth.data, dtype=np.uint16),
                ir=None if ir is None else np.array(ir.data, dtype=np.uint16),
            )

    def close(self) -> None:
        self._sensor.close()


def open_kinect2(arg: str, options: dict[str, str]) -> Kinect2Camera:
    """The ``kinect2`` camera kind (the one Kinect v2 the SDK allows per PC)."""
    if not (sys.platform == "win32" and sys.maxsize > 2**32):
        raise InputError(f"{NEEDS} (this is {sys.platform}, {platform.machine()})")
    if options or arg not in ("", "0"):
        raise InputError("kinect2: takes no options (the SDK drives one Kinect v2 per PC)")
    try:
        import kinect_next
    except ImportError:
        raise InputError(f"{NEEDS}, and kinect-next: pip install 'kinefuse[kinect2]'") from None
    return Kinect2Camera(kinect_next)

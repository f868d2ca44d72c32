"""``--tracker k4abt``: Microsoft's Azure Kinect Body Tracking SDK through pykinect-azure.

The SDK (libk4abt and its model; on Windows "Azure Kinect Body Tracking SDK" from Microsoft's
site, on Linux the ``libk4abt1.1`` package of Microsoft's repository) is on no Python package
registry: the user installs it, and pykinect-azure binds it with ctypes. It tracks from the depth
and IR images of an Azure Kinect (live or recorded) with the device's calibration (its raw JSON,
:attr:`CameraCalibration.raw`).

Its 32 joints map to kinefuse's 25 (:data:`K4ABT_TO_KINECT_V2`; SpineShoulder is the SDK's
SPINE_CHEST, the nearest joint it has); its confidence levels give the states
(:func:`state_of_confidence`): NONE (out of range) -> NOT_TRACKED, LOW (predicted, occluded) ->
INFERRED, MEDIUM and HIGH -> TRACKED. Positions come in millimetres in the depth camera's frame
(x right, y down, z forward): kinefuse's axes, in metres.
"""

from __future__ import annotations

import ctypes
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from kinefuse.core.skeleton import TrackingState
from kinefuse.devices.capture import CameraCalibration, Capture
from kinefuse.devices.k4a_calibration import COLOR_MODES, DEPTH_MODES
from kinefuse.devices.trackers import TrackedBody, TrackerResult, TrackerUnavailable
from kinefuse.errors import InputError

__all__ = ["K4ABT_TO_KINECT_V2", "K4abtTracker", "make", "skeleton_to_body", "state_of_confidence"]

#: for each of kinefuse's 25 joints (Kinect v2 order), the k4abt joint it takes
K4ABT_TO_KINECT_V2: tuple[int, ...] = (
    0,  # SpineBase <- PELVIS
    1,  # SpineMid <- SPINE_NAVEL
    3,  # Neck <- NECK
    26,  # Head <- HEAD
    5, 6, 7, 8,  # ShoulderLeft, ElbowLeft, WristLeft, HandLeft
    12, 13, 14, 15,  # ShoulderRight, ElbowRight, WristRight, HandRight
    18, 19, 20, 21,  # HipLeft, KneeLeft, AnkleLeft, FootLeft
    22, 23, 24, 25,  # HipRight, KneeRight, AnkleRight, FootRight
    2,  # SpineShoulder <- SPINE_CHEST
    9, 10,  # HandTipLeft, ThumbLeft
    16, 17,  # HandTipRight, ThumbRight
)  # fmt: skip

K4ABT_JOINT_COUNT = 32

INSTALL = (
    "pip install pykinect-azure, and Microsoft's Azure Kinect Body Tracking SDK (not on PyPI: "
    "docs/devices.md, Azure Kinect)"
)


def state_of_confidence(level: ArrayLike) -> np.ndarray:
    """k4abt confidence levels (0 none, 1 low, 2 medium, 3 high) -> :class:`TrackingState`."""
    lv = np.asarray(level, dtype=np.int64)
    out = np.full(lv.shape, TrackingState.TRACKED, dtype=np.int8)
    out[lv <= 1] = TrackingState.INFERRED
    out[lv <= 0] = TrackingState.NOT_TRACKED
    return out


def skeleton_to_body(body_id: int, positions_mm: ArrayLike, confidence: ArrayLike) -> TrackedBody:
    """One k4abt skeleton (32 joints in mm, 32 confidence levels) -> a kinefuse body."""
    p = np.asarray(positions_mm, dtype=np.float64).reshape(K4ABT_JOINT_COUNT, 3)
    lv = np.asarray(confidence, dtype=np.int64).reshape(K4ABT_JOINT_COUNT)
    idx = np.asarray(K4ABT_TO_KINECT_V2)
    joints = p[idx] * 1e-3
    states = state_of_confidence(lv[idx])
    gone = (states == TrackingState.NOT_TRACKED) | ~np.isfinite(joints).all(axis=1)
    joints[gone] = np.nan
    states[gone] = TrackingState.NOT_TRACKED
    return TrackedBody(int(body_id), joints, states, confidence=lv[idx] / 3.0)


def _mode_of(cal: CameraCalibration) -> tuple[int, int]:
    """k4a's depth mode and colour resolution enums of a calibration (by image sizes)."""
    size = (cal.depth.width, cal.depth.height)
    name = next((n for n, m in DEPTH_MODES.items() if m.size == size), "NFOV_UNBINNED")
    depth_id = list(DEPTH_MODES).index(name) + 1  # k4a_depth_mode_t: the table's order, from 1
    color_id = 0
    if cal.color is not None:
        for k, (_b, _c, size) in enumerate(COLOR_MODES.values(), start=1):
            if size == (cal.color.width, cal.color.height):
                color_id = k
    return depth_id, color_id


class K4abtTracker:
    """The SDK's tracker on captures of one Azure Kinect (created on the first capture)."""

    name = "k4abt"
    #: the SDK takes the device's own (distorted) depth and IR with the device's calibration
    device_images = True

    def __init__(self, pk: Any, options: Mapping[str, str]) -> None:
        self._pk = pk
        self._tracker: Any = None
        self._cal: Any = None
        self._lite = options.get("model", "") == "lite"

    def _start(self, cal: CameraCalibration) -> None:
        from pykinect_azure.k4a import _k4a
        from pykinect_azure.k4a.calibration import Calibration
        from pykinect_azure.k4abt import _k4abt
        from pykinect_azure.k4abt.tracker import Tracker

        if not cal.raw:
            raise InputError(
                "k4abt tracks Azure Kinect / Femto captures only: the source gave no device "
                "calibration (use --tracker pose for other cameras)"
            )
        depth_mode, color_res = _mode_of(cal)
        raw = cal.raw.encode()
        handle = _k4a.k4a_calibration_t()
        buf = ctypes.create_string_buffer(raw, len(raw) + 1)
        _k4a.VERIFY(
            _k4a.k4a_calibration_get_from_raw(buf, len(raw) + 1, depth_mode, color_res, handle),
            "the device calibration does not load",
        )
        self._cal = Calibration(handle)
        model = _k4abt.K4ABT_LITE_MODEL if self._lite else _k4abt.K4ABT_DEFAULT_MODEL
        self._tracker = Tracker(self._cal, model)

    def _k4a_capture(self, capture: Capture) -> Any:
        from pykinect_azure.k4a import _k4a

        cap = _k4a.k4a_capture_t()
        _k4a.VERIFY(_k4a.k4a_capture_create(cap), "k4a_capture_create failed")
        for img, fmt, setter in (
            (capture.depth_mm, _k4a.K4A_IMAGE_FORMAT_DEPTH16, _k4a.k4a_capture_set_depth_image),
            (capture.ir, _k4a.K4A_IMAGE_FORMAT_IR16, _k4a.k4a_capture_set_ir_image),
        ):
            if img is None:
                continue
            h, w = img.shape
            im = _k4a.k4a_image_t()
            _k4a.VERIFY(_k4a.k4a_image_create(fmt, w, h, w * 2, im), "k4a_image_create failed")
            ctypes.memmove(_k4a.k4a_image_get_buffer(im), np.ascontiguousarray(img).ctypes.data,
                           img.nbytes)  # fmt: skip
            _k4a.k4a_image_set_device_timestamp_usec(im, int(capture.t_device_s * 1e6))
            setter(cap, im)
            _k4a.k4a_image_release(im)
        return cap

    def track(self, capture: Capture, calibration: CameraCalibration) -> TrackerResult:
        from pykinect_azure.k4a import _k4a

        if capture.depth_mm is None or capture.ir is None:
            return TrackerResult(refused=("k4abt needs the depth and IR images",))
        if self._tracker is None:
            self._start(calibration)
        cap = self._k4a_capture(capture)
        try:
            frame = self._tracker.update(_CaptureRef(cap))
        finally:
            _k4a.k4a_capture_release(cap)
        bodies = []
        for i in range(frame.get_num_bodies()):
            sk = frame.get_body_skeleton(i)
            pos = [(j.position.xyz.x, j.position.xyz.y, j.position.xyz.z) for j in sk.joints]
            conf = [j.confidence_level for j in sk.joints]
            bodies.append(skeleton_to_body(frame.get_body_id(i), pos, conf))
        return TrackerResult(bodies=tuple(bodies))

    def close(self) -> None:
        if self._tracker is not None:
            self._tracker.shutdown()
            self._tracker.destroy()
            self._tracker = None


class _CaptureRef:
    """What pykinect-azure's ``Tracker.update`` takes: an object with ``handle()``."""

    def __init__(self, handle: Any) -> None:
        self._handle = handle

    def handle(self) -> Any:
        return self._handle


def make(options: Mapping[str, str]) -> K4abtTracker:
    """The ``k4abt`` entry point of ``kinefuse.trackers`` (option ``model=lite``)."""
    try:
        import pykinect_azure as pk
    except ImportError as e:
        if e.name not in (None, "pykinect_azure"):  # installed, but a dependency of its is not
            raise TrackerUnavailable(
                f"--tracker k4abt: pykinect-azure does not load (no module {e.name!r}); "
                f"install what it needs: pip install pykinect-azure {e.name}"
            ) from None
        raise TrackerUnavailable(f"--tracker k4abt needs {INSTALL}") from None
    try:
        pk.initialize_libraries(track_body=True)
    except (OSError, SystemExit, AttributeError) as e:
        raise TrackerUnavailable(
            f"--tracker k4abt: the Azure Kinect SDK or its Body Tracking SDK is not installed "
            f"({e or 'not found'}); install Microsoft's Azure Kinect Sensor SDK 1.4 and Body "
            "Tracking SDK (docs/devices.md, Azure Kinect)"
        ) from None
    return K4abtTracker(pk, options)

"""The ``pose`` tracker: the 2D model, lifting with depth, the 25 joints, the gates."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.skeleton import JOINT_INDEX, N_JOINTS
from kinefuse.devices.capture import CameraCalibration, Capture
from kinefuse.devices.pose.gates import GateParams, GateResult, check_body
from kinefuse.devices.pose.landmarks import LM, Landmarks2D, with_virtual
from kinefuse.devices.pose.lift import LiftParams, LiftResult, lift_landmarks
from kinefuse.devices.pose.mapping import DIRECT, to_kinect
from kinefuse.devices.trackers import TrackedBody, TrackerResult
from kinefuse.devices.undistort import undistort_pixels
from kinefuse.errors import InputError

__all__ = ["LandmarkModel", "PoseTracker", "Stages", "body_from_landmarks", "ir_to_rgb"]


class LandmarkModel(Protocol):
    """A 2D model: one person's landmarks in an RGB image, or None."""

    def detect(self, rgb: NDArray[np.uint8]) -> Landmarks2D | None: ...

    def close(self) -> None: ...


def ir_to_rgb(ir: NDArray[np.uint16]) -> NDArray[np.uint8]:
    """An IR (active brightness) image as 8-bit grey RGB, its 99th percentile at white."""
    top = float(np.percentile(ir, 99.0)) if ir.size else 0.0
    grey = np.clip(ir.astype(np.float32) * (255.0 / max(top, 1.0)), 0.0, 255.0).astype(np.uint8)
    return np.repeat(grey[:, :, None], 3, axis=2)


@dataclass(frozen=True)
class _View:
    rgb: NDArray[np.uint8]
    intrinsics: Intrinsics
    image_from_depth: NDArray[np.float64] | None
    distortion: tuple[float, ...] = ()  #: the image's lens (the colour camera's)


@dataclass(frozen=True, eq=False)
class Stages:
    """What each stage after the 2D model made of one capture (for scoring and benchmarks)."""

    lifted: LiftResult
    visibility: NDArray[np.float64]
    gate: GateResult
    timings_s: dict[str, float]


def body_from_landmarks(
    landmarks: Landmarks2D,
    depth_mm: NDArray[np.uint16],
    depth_intrinsics: Intrinsics,
    image_intrinsics: Intrinsics,
    image_from_depth: NDArray[np.float64] | None = None,
    lift: LiftParams | None = None,
    gates: GateParams | None = None,
    floor: NDArray[np.float64] | None = None,
) -> Stages:
    """Lift (:func:`.lift.lift_landmarks`), map (:func:`.mapping.to_kinect`) and gate
    (:func:`.gates.check_body`) one person's 2D landmarks, timing each stage."""
    t0 = time.perf_counter()
    uv, vis = with_virtual(landmarks)
    lifted = lift_landmarks(uv, vis, depth_mm, depth_intrinsics, image_intrinsics,
                            image_from_depth, LiftParams() if lift is None else lift)  # fmt: skip
    t1 = time.perf_counter()
    joints, states = to_kinect(lifted)
    t2 = time.perf_counter()
    gate = check_body(joints, states, floor, GateParams() if gates is None else gates)
    t3 = time.perf_counter()
    return Stages(lifted, vis, gate, {"lift": t1 - t0, "map": t2 - t1, "gates": t3 - t2})


class PoseTracker:
    """Bodies from an RGB-D capture: see :mod:`kinefuse.devices.pose`.

    Parameters
    ----------
    model : LandmarkModel
        The 2D model (:class:`~kinefuse.devices.pose.model.BlazePoseModel`).
    lift : LiftParams, optional
    gates : GateParams, optional
    floor : (4,) float or None
        The floor plane in the depth camera's frame (``n @ p + d`` = height, ``n`` up), when
        known; it enables the floor gate.
    """

    name = "pose"

    def __init__(
        self,
        model: LandmarkModel,
        *,
        lift: LiftParams | None = None,
        gates: GateParams | None = None,
        floor: NDArray[np.float64] | None = None,
    ) -> None:
        self.model = model
        self.lift_params = LiftParams() if lift is None else lift
        self.gate_params = GateParams() if gates is None else gates
        self.floor = None if floor is None else np.asarray(floor, dtype=np.float64)
        self._body_id = 0
        self._had_body = False

    def _view(self, capture: Capture, calibration: CameraCalibration) -> _View | None:
        d, kd = np.asarray(capture.depth_mm), calibration.depth
        if d.ndim != 2 or d.dtype != np.uint16 or d.shape != (kd.height, kd.width):
            raise InputError(
                f"the depth image is {d.dtype} {d.shape} but the calibration's depth camera is "
                f"uint16 ({kd.height}, {kd.width}); pass this depth mode's calibration"
            )
        if capture.color is not None and calibration.color is not None:
            if (
                capture.color.ndim != 3
                or capture.color.shape[2] != 3
                or (capture.color.dtype != np.uint8)
            ):
                raise InputError(
                    f"the colour image must be (h, w, 3) uint8 RGB, got {capture.color.dtype} "
                    f"{capture.color.shape}"
                )
            h, w = capture.color.shape[:2]
            c = calibration.color
            if (w, h) != (c.width, c.height):
                raise InputError(
                    f"the colour image is {w}x{h} but the calibration's colour camera is "
                    f"{c.width}x{c.height}; pass the calibration of this colour mode"
                )
            if calibration.color_from_depth is None:
                raise InputError(
                    "the calibration has a colour camera but no color_from_depth: the pose "
                    "tracker cannot register depth to colour without it"
                )
            return _View(capture.color, c, np.asarray(calibration.color_from_depth, float),
                         calibration.distortion_color)  # fmt: skip
        if capture.ir is not None:
            return _View(ir_to_rgb(capture.ir), calibration.depth, None)
        return None

    def track(self, capture: Capture, calibration: CameraCalibration) -> TrackerResult:
        """The body in one capture, or why it was refused."""
        if capture.depth_mm is None:
            return TrackerResult(refused=("no depth in this capture: the pose tracker lifts "
                                          "its landmarks with depth",))  # fmt: skip
        view = self._view(capture, calibration)
        if view is None:
            return TrackerResult(refused=("no colour or IR image in this capture: the pose "
                                          "tracker needs one for its 2D model",))  # fmt: skip
        t0 = time.perf_counter()
        landmarks = self.model.detect(view.rgb)
        t_model = time.perf_counter() - t0
        if landmarks is None:
            self._had_body = False
            return TrackerResult(timings_s={"model": t_model})
        if any(view.distortion):  # the colour image as the device gives it: to its pinhole
            uv = undistort_pixels(landmarks.uv_px, view.intrinsics, view.distortion)
            landmarks = replace(landmarks, uv_px=uv)
        result = self.from_landmarks(
            landmarks, capture.depth_mm, calibration.depth, view.intrinsics, view.image_from_depth
        )
        return TrackerResult(
            bodies=result.bodies,
            refused=result.refused,
            timings_s={"model": t_model, **result.timings_s},
        )

    def from_landmarks(
        self,
        landmarks: Landmarks2D,
        depth_mm: NDArray[np.uint16],
        depth_intrinsics: Intrinsics,
        image_intrinsics: Intrinsics,
        image_from_depth: NDArray[np.float64] | None = None,
    ) -> TrackerResult:
        """Lift, map and gate one set of 2D landmarks (the stages after the 2D model)."""
        stages = body_from_landmarks(landmarks, depth_mm, depth_intrinsics, image_intrinsics,
                                     image_from_depth, self.lift_params, self.gate_params,
                                     self.floor)  # fmt: skip
        gate = stages.gate
        if gate.refused is not None:
            self._had_body = False
            return TrackerResult(refused=(gate.refused,), timings_s=stages.timings_s)
        if not self._had_body:
            self._body_id += 1
        self._had_body = True
        vis = stages.visibility
        conf = np.full(N_JOINTS, float(np.min(vis[[LM["left_shoulder"], LM["right_shoulder"]]])))
        for joint, lm in DIRECT.items():
            conf[JOINT_INDEX[joint]] = vis[LM[lm]]
        body = TrackedBody(self._body_id, gate.joints_m, gate.states, np.clip(conf, 0.0, 1.0))
        return TrackerResult(bodies=(body,), timings_s=stages.timings_s)

    def close(self) -> None:
        self.model.close()

"""The ``pose`` tracker's lifting and mapping scored against the simulator's truth.

A simulated sensor renders the actor's capsule body in the room
(:meth:`kinefuse.sim.lab.SensorSimulation.body_depth_frames`); 2D landmarks are made from the
true joints projected into that depth camera, plus the pixel error of a detector
(:class:`DetectorNoise`); the tracker's stages after its 2D model lift, map and gate them
(:func:`kinefuse.devices.pose.tracker.body_from_landmarks`); each of the 25 joints is compared
with the truth, joints hidden from the camera included (hidden: the rendered surface at its
pixel is well in front of the joint's own).

The 2D model itself is not in this loop (it needs images of people, which a capsule body is
not); its error enters as the detector noise, from the model's published accuracy.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Final

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.skeleton import CAPSULE_RADII_M, JOINT_INDEX, JOINTS, N_JOINTS, TrackingState
from kinefuse.devices.pose.landmarks import LM, N_LANDMARKS, Landmarks2D
from kinefuse.devices.pose.tracker import body_from_landmarks
from kinefuse.errors import InputError
from kinefuse.sim.clock import CaptureTimes
from kinefuse.sim.lab import SensorSimulation
from kinefuse.sim.tracker import TrackerOutput

__all__ = [
    "DetectorNoise",
    "LiftScore",
    "floor_in_sensor",
    "pose_observations",
    "score_lifting",
    "true_landmarks",
]

Array = NDArray[np.float64]

#: landmark <- Kinect joint it is made from (ears: the head's centre +- half a head's width)
_FROM_JOINT: Final = {
    "left_shoulder": "ShoulderLeft", "right_shoulder": "ShoulderRight",
    "left_elbow": "ElbowLeft", "right_elbow": "ElbowRight",
    "left_wrist": "WristLeft", "right_wrist": "WristRight",
    "left_index": "HandTipLeft", "right_index": "HandTipRight",
    "left_pinky": "HandTipLeft", "right_pinky": "HandTipRight",
    "left_thumb": "ThumbLeft", "right_thumb": "ThumbRight",
    "left_hip": "HipLeft", "right_hip": "HipRight", "left_knee": "KneeLeft",
    "right_knee": "KneeRight", "left_ankle": "AnkleLeft", "right_ankle": "AnkleRight",
    "left_heel": "AnkleLeft", "right_heel": "AnkleRight",
    "left_foot_index": "FootLeft", "right_foot_index": "FootRight",
}  # fmt: skip
_EAR_HALF_M: Final = 0.075
_FACE_FORWARD_M: Final = 0.09


@dataclass(frozen=True)
class DetectorNoise:
    """The pixel error of a 2D pose detector, per image axis, Gaussian.

    ``sigma_torso`` is a fraction of the torso's length in the image (shoulders' midpoint to
    hips' midpoint). The default is the Gaussian whose PCK@0.2 (share of keypoints within 0.2
    torso of the truth) equals BlazePose Full's published 84.5 % on its Yoga set (Bazarevsky et
    al. 2020, "BlazePose: On-device Real-time Body Pose tracking", arXiv:2006.10204, table 1;
    84.1 % on its AR set): ``P(r < 0.2 T) = 1 - exp(-(0.2 T)^2 / (2 sigma^2)) = 0.845`` gives
    ``sigma = 0.2 T / sqrt(-2 ln 0.155) = 0.104 T``. A real detector's errors are heavier-tailed
    (most smaller, a few much larger), so this is a like-for-like spread, not its shape.
    """

    sigma_torso: float = field(
        default=0.104,
        metadata={"unit": "torso lengths", "source": "BlazePose Full PCK@0.2 = 84.5 % "
                  "(arXiv:2006.10204), as a Gaussian"},
    )  # fmt: skip


def true_landmarks(
    joints_sensor_m: Array,
    intrinsics: Intrinsics,
    rng: np.random.Generator | None = None,
    noise: DetectorNoise | None = None,
) -> Landmarks2D:
    """The 33 landmarks a detector would give for true joints ``(25, 3)`` (in the camera's
    frame), projected into that camera, with ``noise`` (None: exact). The face is 9 cm in front
    of the head's centre, the ears 7.5 cm to its sides. Visibility is 1 for all: the lifting
    must find hidden joints by itself."""
    j = np.asarray(joints_sensor_m, dtype=np.float64)
    pts = np.full((N_LANDMARKS, 3), np.nan)
    for lm, joint in _FROM_JOINT.items():
        pts[LM[lm]] = j[JOINT_INDEX[joint]]
    head = j[JOINT_INDEX["Head"]]
    lat = j[JOINT_INDEX["ShoulderLeft"]] - j[JOINT_INDEX["ShoulderRight"]]
    lat = lat / max(float(np.linalg.norm(lat)), 1e-9)
    up = head - 0.5 * (j[JOINT_INDEX["HipLeft"]] + j[JOINT_INDEX["HipRight"]])
    fwd = np.cross(lat, up)  # body frame: x forward, y left, z up
    fwd = fwd / max(float(np.linalg.norm(fwd)), 1e-9)
    for k in range(11):  # the face: in front of the head's centre, the ears beside it
        pts[k] = head + _FACE_FORWARD_M * fwd
    pts[LM["left_ear"]] = head + _EAR_HALF_M * lat
    pts[LM["right_ear"]] = head - _EAR_HALF_M * lat
    uv = intrinsics.project(pts)
    if noise is not None and noise.sigma_torso > 0:
        if rng is None:
            raise InputError("detector noise needs an rng (np.random.default_rng(seed))")
        sh = 0.5 * (uv[LM["left_shoulder"]] + uv[LM["right_shoulder"]])
        hp = 0.5 * (uv[LM["left_hip"]] + uv[LM["right_hip"]])
        torso_px = float(np.linalg.norm(sh - hp))
        uv = uv + rng.normal(0.0, noise.sigma_torso * torso_px, uv.shape)
    return Landmarks2D(uv, np.ones(N_LANDMARKS), (intrinsics.width, intrinsics.height))


def floor_in_sensor(sensor2world: Array) -> Array:
    """The floor ``z = 0`` (world, z up) as a plane ``(n, d)`` in the sensor's frame."""
    t = np.asarray(sensor2world, dtype=np.float64)
    return np.concatenate([t[:3, :3].T @ np.array([0.0, 0.0, 1.0]), [t[2, 3]]])


@dataclass(frozen=True, eq=False)
class LiftScore:
    """Per frame and joint: the error against the truth, the state, and whether hidden.

    Attributes
    ----------
    error_m : (N, 25) float
        Distance of the tracker's joint to the true joint, metres; NaN where not tracked.
    states : (N, 25) int8
    hidden : (N, 25) bool
        The joint is hidden from the camera (truth).
    refused : tuple of str
        The gates' reasons for the frames they refused (those frames' errors are NaN).
    """

    error_m: Array
    states: NDArray[np.int8]
    hidden: NDArray[np.bool_]
    refused: tuple[str, ...]

    @classmethod
    def concat(cls, scores: list[LiftScore]) -> LiftScore:
        """Several sensors' (or takes') scores as one."""
        return cls(
            np.concatenate([s.error_m for s in scores]),
            np.concatenate([s.states for s in scores]),
            np.concatenate([s.hidden for s in scores]),
            tuple(r for s in scores for r in s.refused),
        )

    def table(self) -> list[dict[str, object]]:
        """Per joint: median and 95th percentile of the error where visible and where hidden,
        and how often a hidden joint was not tracked as tracked."""
        rows = []
        for k, name in enumerate(JOINTS):
            e, h, s = self.error_m[:, k], self.hidden[:, k], self.states[:, k]
            row: dict[str, object] = {"joint": name}
            for label, sel in (("visible", ~h), ("hidden", h)):
                ok = sel & np.isfinite(e)
                row[f"{label}_n"] = int(ok.sum())
                row[f"{label}_median_m"] = float(np.median(e[ok])) if ok.any() else float("nan")
                row[f"{label}_p95_m"] = (
                    float(np.percentile(e[ok], 95)) if ok.any() else float("nan")
                )
            row["hidden_flagged"] = (
                float(np.mean(s[h] != TrackingState.TRACKED)) if h.any() else float("nan")
            )
            rows.append(row)
        return rows


def _hidden(depth_mm: NDArray[np.uint16], joints: Array, intr: Intrinsics) -> NDArray[np.bool_]:
    radius = np.array([CAPSULE_RADII_M.get(n, 0.10) for n in JOINTS])
    uv = np.rint(intr.project(joints))
    out = np.zeros(N_JOINTS, dtype=bool)
    for k in range(N_JOINTS):
        u, v = uv[k]
        if not (np.isfinite(u) and 0 <= u < intr.width and 0 <= v < intr.height):
            continue
        d = depth_mm[int(v), int(u)] * 1e-3
        out[k] = 0 < d < joints[k, 2] - radius[k] - 0.05
    return out


def score_lifting(
    sim: SensorSimulation,
    *,
    every: int = 1,
    seed: int = 0,
    noise: DetectorNoise | None = None,
    depth_noise: bool = True,
    max_frames: int | None = None,
) -> LiftScore:
    """Score the tracker's stages after the 2D model on one simulated sensor's body depth.

    Parameters
    ----------
    sim : SensorSimulation
        The simulated sensor (its motion phase is rendered).
    every : int
        Every ``every``-th capture.
    seed : int
        The detector noise's seed.
    noise : DetectorNoise or None
        None: exact landmarks (the lifting's own error alone).
    depth_noise : bool
        The depth camera's error model on (False: exact depth).
    max_frames : int or None
        Stop after this many frames.
    """
    rng = np.random.default_rng(seed)
    floor = floor_in_sensor(sim.spec.sensor2world)
    errs, states, hidden, refused = [], [], [], []
    for n, frame in enumerate(sim.body_depth_frames(every=every, noise=depth_noise)):
        if max_frames is not None and n >= max_frames:
            break
        truth = frame.joints_sensor_m
        lm = true_landmarks(truth, sim.intrinsics, rng, noise)
        stages = body_from_landmarks(lm, frame.depth_mm, sim.intrinsics, sim.intrinsics,
                                     floor=floor)  # fmt: skip
        gate = stages.gate
        hidden.append(_hidden(frame.depth_mm, truth, sim.intrinsics))
        if gate.refused is not None:
            refused.append(gate.refused)
            errs.append(np.full(N_JOINTS, np.nan))
            states.append(np.zeros(N_JOINTS, dtype=np.int8))
            continue
        errs.append(np.linalg.norm(gate.joints_m - truth, axis=1))
        states.append(gate.states)
    if not errs:
        raise InputError("no body depth frames to score: the motion phase is empty")
    return LiftScore(np.array(errs), np.array(states), np.array(hidden), tuple(refused))


def pose_observations(
    noise: DetectorNoise | None = None, seed: int = 0, depth_noise: bool = True
) -> Callable[[SensorSimulation], tuple[CaptureTimes, TrackerOutput, Array]]:
    """An ``observe`` for :func:`kinefuse.sim.lab.simulate_session`: each sensor's body
    observations made by the pose tracker's stages after its 2D model, on the sensor's rendered
    body depth at its frame rate, from landmarks projected from the true joints (with
    ``noise``). A frame the gates refuse is a dropout (no joints)."""

    def observe(sim: SensorSimulation) -> tuple[CaptureTimes, TrackerOutput, Array]:
        rng = np.random.default_rng([seed, zlib.crc32(sim.spec.id.encode())])
        floor = floor_in_sensor(sim.spec.sensor2world)
        frames, joints, states, visible, refused, truth = [], [], [], [], [], []
        for f in sim.body_depth_frames(noise=depth_noise):
            lm = true_landmarks(f.joints_sensor_m, sim.intrinsics, rng, noise)
            gate = body_from_landmarks(lm, f.depth_mm, sim.intrinsics, sim.intrinsics,
                                       floor=floor).gate  # fmt: skip
            frames.append(f)
            truth.append(f.joints_world_m)
            seen = sim.intrinsics.in_view(f.joints_sensor_m)
            visible.append(seen & ~_hidden(f.depth_mm, f.joints_sensor_m, sim.intrinsics))
            refused.append(gate.refused is not None)
            if gate.refused is not None:
                joints.append(np.full((N_JOINTS, 3), np.nan))
                states.append(np.zeros(N_JOINTS, dtype=np.int8))
            else:
                joints.append(gate.joints_m)
                states.append(gate.states)
        if not frames:
            raise InputError(f"{sim.spec.id}: no body depth frames in the motion phase")
        cap = CaptureTimes(
            seq=np.array([f.seq for f in frames], dtype=np.int64),
            t_true_s=np.array([f.t_true_s for f in frames]),
            t_sensor_s=np.array([f.t_device_s for f in frames]),
            t_receive_server_s=np.array([f.t_receive_server_s for f in frames]),
            t_receive_host_s=np.array([f.t_host_s for f in frames]),
        )
        n = len(frames)
        out = TrackerOutput(
            joints_sensor=np.array(joints),
            states=np.array(states, dtype=np.int8),
            visible=np.array(visible),
            swapped=np.zeros(n, dtype=bool),
            dropout=np.array(refused),
            facing_angle_rad=np.full(n, np.nan),
        )
        return cap, out, np.array(truth)

    return observe

"""From the lifted landmarks to the 25 Kinect v2 joints.

Shoulders, elbows, wrists, hips, knees and ankles are the model's own landmarks; the head and
hands are the virtual centres (:mod:`.landmarks`); the foot is the foot-index landmark. What the
model lacks is derived and flagged inferred: the spine's three points and the neck from the
shoulders, hips and head (fractions of the reference body
:func:`kinefuse.skeleton.standing_pose`), the hand tip beyond the hand along the wrist-hand
line, the thumb from the thumb landmark.
"""

from __future__ import annotations

from typing import Final

import numpy as np
from numpy.typing import NDArray

from kinefuse.devices.pose.landmarks import LM
from kinefuse.devices.pose.lift import LiftResult
from kinefuse.skeleton import JOINT_INDEX, N_JOINTS, TrackingState

__all__ = ["DERIVED", "DIRECT", "to_kinect"]

Array = NDArray[np.float64]

#: Kinect joint <- landmark, taken as lifted (position and state)
DIRECT: Final[dict[str, str]] = {
    "Head": "head_centre",
    "ShoulderLeft": "left_shoulder", "ElbowLeft": "left_elbow", "WristLeft": "left_wrist",
    "HandLeft": "left_hand_centre",
    "ShoulderRight": "right_shoulder", "ElbowRight": "right_elbow", "WristRight": "right_wrist",
    "HandRight": "right_hand_centre",
    "HipLeft": "left_hip", "KneeLeft": "left_knee", "AnkleLeft": "left_ankle",
    "FootLeft": "left_foot_index",
    "HipRight": "right_hip", "KneeRight": "right_knee", "AnkleRight": "right_ankle",
    "FootRight": "right_foot_index",
}  # fmt: skip
#: joints the model lacks: always inferred (SpineBase: the hips' state)
DERIVED: Final[tuple[str, ...]] = (
    "SpineBase", "SpineMid", "SpineShoulder", "Neck", "HandTipLeft", "ThumbLeft",
    "HandTipRight", "ThumbRight",
)  # fmt: skip

# fractions of the reference standing body (kinefuse.skeleton.standing_pose): SpineBase 5 cm and
# SpineShoulder 50 cm above the hips' midpoint, whose shoulders' midpoint is 47 cm above it;
# SpineMid 25 of 42 cm from SpineBase to the shoulders; the neck 7 of 20 cm from SpineShoulder
# to the head; the hand tip 7 cm beyond an 8 cm wrist-hand span
_BASE_UP: Final = 0.05 / 0.47
_TOP_UP: Final = 0.03 / 0.47
_MID_UP: Final = 0.25 / 0.42
_NECK_UP: Final = 0.07 / 0.20
_TIP_OUT: Final = 0.07 / 0.08


def to_kinect(lifted: LiftResult) -> tuple[Array, NDArray[np.int8]]:
    """The 25 Kinect v2 joints from lifted landmarks.

    Returns
    -------
    joints_m : (25, 3) float
        Depth camera frame, metres; NaN where not tracked.
    states : (25,) int8
    """
    p, st = lifted.points_m, lifted.states
    joints = np.full((N_JOINTS, 3), np.nan)
    states = np.zeros(N_JOINTS, dtype=np.int8)
    for joint, lm in DIRECT.items():
        joints[JOINT_INDEX[joint]] = p[LM[lm]]
        states[JOINT_INDEX[joint]] = st[LM[lm]]

    def put(joint: str, value: Array, state: int) -> None:
        if np.isfinite(value).all():
            joints[JOINT_INDEX[joint]] = value
            states[JOINT_INDEX[joint]] = state

    def j(name: str) -> Array:
        return joints[JOINT_INDEX[name]]

    inferred = int(TrackingState.INFERRED)
    hips = 0.5 * (j("HipLeft") + j("HipRight"))
    shoulders = 0.5 * (j("ShoulderLeft") + j("ShoulderRight"))
    up = shoulders - hips if np.isfinite(hips).all() else np.zeros(3)  # no hips: no offset
    put("SpineShoulder", shoulders + _TOP_UP * up, inferred)
    hip_state = min(int(states[JOINT_INDEX["HipLeft"]]), int(states[JOINT_INDEX["HipRight"]]))
    put("SpineBase", hips + _BASE_UP * (shoulders - hips), hip_state)
    put("SpineMid", j("SpineBase") + _MID_UP * (shoulders - j("SpineBase")), inferred)
    put("Neck", j("SpineShoulder") + _NECK_UP * (j("Head") - j("SpineShoulder")), inferred)
    for side in ("Left", "Right"):
        hand, wrist = j(f"Hand{side}"), j(f"Wrist{side}")
        put(f"HandTip{side}", hand + _TIP_OUT * (hand - wrist), inferred)
        thumb = p[LM[f"{side.lower()}_thumb"]]
        put(f"Thumb{side}", thumb, inferred)
    states[~np.isfinite(joints).all(axis=1)] = TrackingState.NOT_TRACKED
    joints[states == TrackingState.NOT_TRACKED] = np.nan
    return joints, states

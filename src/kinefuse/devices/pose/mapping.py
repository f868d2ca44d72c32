"""From the lifted landmarks to the 25 Kinect v2 joints.

Shoulders, elbows, wrists, hips, knees and ankles are the model's own landmarks; the head and
hands are the virtual centres (:mod:`.landmarks`); the foot is the foot-index landmark. What the
model lacks is derived and flagged inferred: the spine's points and the neck on the line from
the hips to the shoulders, where a real Kinect v2 puts them; the hand tip beyond the hand along
the wrist-hand line; the thumb from the thumb landmark.
"""

from __future__ import annotations

from typing import Final

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.skeleton import JOINT_INDEX, N_JOINTS, TrackingState
from kinefuse.devices.pose.landmarks import LM
from kinefuse.devices.pose.lift import LiftResult

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

# Where a Kinect v2 puts the joints the model lacks, measured on real Kinect v2 output
# (../shared/data/kinect/kinect2_tracking/walker.json, the 65 frames with every trunk and arm
# joint tracked; medians): along the line from the hips' midpoint (0) to the shoulders'
# midpoint (1), SpineBase at 0.00, SpineMid at 0.655, SpineShoulder at 1.138, Neck at 1.295; the
# hand tip 0.986 wrist-hand spans beyond the hand
_SPINE_MID: Final = 0.655
_SPINE_SHOULDER: Final = 1.138
_NECK: Final = 1.295
_TIP_OUT: Final = 0.986


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
    up = shoulders - hips
    hip_state = min(int(states[JOINT_INDEX["HipLeft"]]), int(states[JOINT_INDEX["HipRight"]]))
    put("SpineBase", hips, hip_state)
    put("SpineMid", hips + _SPINE_MID * up, inferred)
    put("SpineShoulder", hips + _SPINE_SHOULDER * up, inferred)
    put("Neck", hips + _NECK * up, inferred)
    if not np.isfinite(hips).all():  # no hips in view: the neck between shoulders and head
        put("SpineShoulder", shoulders, inferred)
        put("Neck", shoulders + 0.35 * (j("Head") - shoulders), inferred)
    for side in ("Left", "Right"):
        hand, wrist = j(f"Hand{side}"), j(f"Wrist{side}")
        put(f"HandTip{side}", hand + _TIP_OUT * (hand - wrist), inferred)
        thumb = p[LM[f"{side.lower()}_thumb"]]
        put(f"Thumb{side}", thumb, inferred)
    states[~np.isfinite(joints).all(axis=1)] = TrackingState.NOT_TRACKED
    joints[states == TrackingState.NOT_TRACKED] = np.nan
    return joints, states

"""The Kinect v2 body: 25 joints in the SDK's ``JointType`` order, its 24 bones, a capsule body.

Joint order and names are those of the Kinect for Windows SDK 2.0 (``JointType`` enum), so that
index ``j`` here is ``JointType`` value ``j`` there.

The capsule body approximates the person's volume for ray casting (depth images, self-occlusion):
every bone is a capsule (a segment swept by a sphere) whose radius is given for a reference adult
of 1.75 m and scales linearly with the subject's height. Radii are an assumption, chosen from
typical anthropometric girths (e.g. thigh circumference about 0.5 m gives radius 0.08 m); they are
not measured from a particular person.
"""

from __future__ import annotations

import enum
from typing import Final

import numpy as np
from numpy.typing import NDArray

JOINTS: Final[tuple[str, ...]] = (
    "SpineBase",
    "SpineMid",
    "Neck",
    "Head",
    "ShoulderLeft",
    "ElbowLeft",
    "WristLeft",
    "HandLeft",
    "ShoulderRight",
    "ElbowRight",
    "WristRight",
    "HandRight",
    "HipLeft",
    "KneeLeft",
    "AnkleLeft",
    "FootLeft",
    "HipRight",
    "KneeRight",
    "AnkleRight",
    "FootRight",
    "SpineShoulder",
    "HandTipLeft",
    "ThumbLeft",
    "HandTipRight",
    "ThumbRight",
)
N_JOINTS: Final = len(JOINTS)
JOINT_INDEX: Final[dict[str, int]] = {name: i for i, name in enumerate(JOINTS)}

#: Parent of every joint in the tree rooted at SpineBase (-1 for the root), as the SDK's bones.
_PARENT_NAMES: Final[dict[str, str | None]] = {
    "SpineBase": None,
    "SpineMid": "SpineBase",
    "SpineShoulder": "SpineMid",
    "Neck": "SpineShoulder",
    "Head": "Neck",
    "ShoulderLeft": "SpineShoulder",
    "ElbowLeft": "ShoulderLeft",
    "WristLeft": "ElbowLeft",
    "HandLeft": "WristLeft",
    "HandTipLeft": "HandLeft",
    "ThumbLeft": "WristLeft",
    "ShoulderRight": "SpineShoulder",
    "ElbowRight": "ShoulderRight",
    "WristRight": "ElbowRight",
    "HandRight": "WristRight",
    "HandTipRight": "HandRight",
    "ThumbRight": "WristRight",
    "HipLeft": "SpineBase",
    "KneeLeft": "HipLeft",
    "AnkleLeft": "KneeLeft",
    "FootLeft": "AnkleLeft",
    "HipRight": "SpineBase",
    "KneeRight": "HipRight",
    "AnkleRight": "KneeRight",
    "FootRight": "AnkleRight",
}
PARENTS: Final[tuple[int, ...]] = tuple(
    -1 if _PARENT_NAMES[n] is None else JOINT_INDEX[_PARENT_NAMES[n]]  # type: ignore[index]
    for n in JOINTS
)

#: The 24 bones as (parent, child) joint names, in the SDK's usual drawing order.
BONES: Final[tuple[tuple[str, str], ...]] = tuple(
    (JOINTS[p], JOINTS[c]) for c, p in enumerate(PARENTS) if p >= 0
)

#: Capsule radius of the bone ending at each child joint, metres, for a 1.75 m adult (assumption).
#: The trunk: the joints every Kinect tracks best and that left/right swaps of the limbs leave
#: alone (used to register sensors from the body and to measure time lags from its motion).
TRUNK_JOINTS: Final[tuple[str, ...]] = (
    "SpineBase",
    "SpineMid",
    "SpineShoulder",
    "Neck",
    "Head",
    "ShoulderLeft",
    "ShoulderRight",
    "HipLeft",
    "HipRight",
)

CAPSULE_RADII_M: Final[dict[str, float]] = {
    "SpineMid": 0.14,  # lower trunk
    "SpineShoulder": 0.15,  # upper trunk (chest)
    "Neck": 0.06,
    "Head": 0.10,
    "ShoulderLeft": 0.06,
    "ElbowLeft": 0.05,  # upper arm
    "WristLeft": 0.04,  # forearm
    "HandLeft": 0.035,
    "HandTipLeft": 0.025,
    "ThumbLeft": 0.015,
    "ShoulderRight": 0.06,
    "ElbowRight": 0.05,
    "WristRight": 0.04,
    "HandRight": 0.035,
    "HandTipRight": 0.025,
    "ThumbRight": 0.015,
    "HipLeft": 0.09,  # pelvis
    "KneeLeft": 0.075,  # thigh
    "AnkleLeft": 0.05,  # shank
    "FootLeft": 0.04,
    "HipRight": 0.09,
    "KneeRight": 0.075,
    "AnkleRight": 0.05,
    "FootRight": 0.04,
}
REFERENCE_HEIGHT_M: Final = 1.75

_LR_NAMES: Final = (
    ("ShoulderLeft", "ShoulderRight"),
    ("ElbowLeft", "ElbowRight"),
    ("WristLeft", "WristRight"),
    ("HandLeft", "HandRight"),
    ("HipLeft", "HipRight"),
    ("KneeLeft", "KneeRight"),
    ("AnkleLeft", "AnkleRight"),
    ("FootLeft", "FootRight"),
    ("HandTipLeft", "HandTipRight"),
    ("ThumbLeft", "ThumbRight"),
)
#: Index pairs (left, right) of the mirrored joints.
LEFT_RIGHT_PAIRS: Final[tuple[tuple[int, int], ...]] = tuple(
    (JOINT_INDEX[a], JOINT_INDEX[b]) for a, b in _LR_NAMES
)


def _mirror_index() -> tuple[int, ...]:
    m = list(range(N_JOINTS))
    for a, b in LEFT_RIGHT_PAIRS:
        m[a], m[b] = b, a
    return tuple(m)


#: ``joints[..., MIRROR_INDEX, :]`` swaps every left joint with its right twin.
MIRROR_INDEX: Final[tuple[int, ...]] = _mirror_index()


class TrackingState(enum.IntEnum):
    """Per-joint state as the Kinect SDK reports it (``TrackingState`` enum values)."""

    NOT_TRACKED = 0
    INFERRED = 1
    TRACKED = 2


def joint_index(name: str) -> int:
    """Index of a Kinect v2 joint by its SDK name; a clear error for an unknown name."""
    try:
        return JOINT_INDEX[name]
    except KeyError:
        raise KeyError(
            f"unknown Kinect v2 joint {name!r}; the 25 names are: {', '.join(JOINTS)}"
        ) from None


def bone_index_array() -> NDArray[np.intp]:
    """Bones as a ``(24, 2)`` array of (parent, child) joint indices."""
    return np.array([(JOINT_INDEX[a], JOINT_INDEX[b]) for a, b in BONES], dtype=np.intp)


def capsule_radii(height_m: float = REFERENCE_HEIGHT_M) -> NDArray[np.float64]:
    """Capsule radius per bone (same order as :data:`BONES`), metres, scaled to ``height_m``.

    Parameters
    ----------
    height_m : float
        The subject's standing height in metres (0.5 to 2.5).

    Returns
    -------
    radii : (24,) float
    """
    if not 0.5 <= height_m <= 2.5:
        raise ValueError(f"subject height must be 0.5 to 2.5 m, got {height_m!r} m")
    scale = height_m / REFERENCE_HEIGHT_M
    return np.array([CAPSULE_RADII_M[c] * scale for _, c in BONES], dtype=np.float64)


#: A 1.75 m adult standing upright, arms hanging, at the world origin facing +x (z up), metres.
_STANDING_M: Final[dict[str, tuple[float, float, float]]] = {
    "SpineBase": (0.0, 0.0, 1.0), "SpineMid": (0.0, 0.0, 1.25),
    "SpineShoulder": (0.0, 0.0, 1.45), "Neck": (0.0, 0.0, 1.52), "Head": (0.0, 0.0, 1.65),
    "ShoulderLeft": (0.0, 0.18, 1.42), "ElbowLeft": (0.0, 0.2, 1.15),
    "WristLeft": (0.05, 0.2, 0.9), "HandLeft": (0.07, 0.2, 0.82),
    "HandTipLeft": (0.09, 0.2, 0.75), "ThumbLeft": (0.1, 0.17, 0.85),
    "ShoulderRight": (0.0, -0.18, 1.42), "ElbowRight": (0.0, -0.2, 1.15),
    "WristRight": (0.05, -0.2, 0.9), "HandRight": (0.07, -0.2, 0.82),
    "HandTipRight": (0.09, -0.2, 0.75), "ThumbRight": (0.1, -0.17, 0.85),
    "HipLeft": (0.0, 0.09, 0.95), "KneeLeft": (0.02, 0.1, 0.5), "AnkleLeft": (0.0, 0.1, 0.08),
    "FootLeft": (0.12, 0.1, 0.03), "HipRight": (0.0, -0.09, 0.95),
    "KneeRight": (0.02, -0.1, 0.5), "AnkleRight": (0.0, -0.1, 0.08),
    "FootRight": (0.12, -0.1, 0.03),
}  # fmt: skip


def standing_pose(height_m: float = REFERENCE_HEIGHT_M) -> NDArray[np.float64]:
    """A person standing upright with arms hanging, at the world origin facing +x, z up.

    A reference pose for tests, benchmarks and examples (not measured from anyone).

    Returns
    -------
    joints : (25, 3) float
        Metres, in :data:`JOINTS` order, scaled to ``height_m``.
    """
    if not 0.5 <= height_m <= 2.5:
        raise ValueError(f"subject height must be 0.5 to 2.5 m, got {height_m!r} m")
    pose = np.array([_STANDING_M[n] for n in JOINTS], dtype=np.float64)
    return pose * (height_m / REFERENCE_HEIGHT_M)

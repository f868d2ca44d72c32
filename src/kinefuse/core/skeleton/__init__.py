"""Skeleton topology as data: the Kinect v2 body (25 joints, 24 bones) and its capsule body.

Part of :mod:`kinefuse.core`: may import only :mod:`kinefuse.errors` and the rest of the core.
"""

from kinefuse.core.skeleton.kinect_v2 import (
    BONES,
    CAPSULE_RADII_M,
    JOINT_INDEX,
    JOINTS,
    LEFT_RIGHT_PAIRS,
    MIRROR_INDEX,
    N_JOINTS,
    PARENTS,
    TRUNK_JOINTS,
    TrackingState,
    bone_index_array,
    capsule_radii,
    joint_index,
    standing_pose,
)

__all__ = [
    "BONES",
    "CAPSULE_RADII_M",
    "JOINTS",
    "JOINT_INDEX",
    "LEFT_RIGHT_PAIRS",
    "MIRROR_INDEX",
    "N_JOINTS",
    "PARENTS",
    "TRUNK_JOINTS",
    "TrackingState",
    "bone_index_array",
    "capsule_radii",
    "joint_index",
    "standing_pose",
]

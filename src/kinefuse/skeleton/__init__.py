"""Skeleton topology as data: the Kinect v2 body (25 joints, 24 bones) and its capsule body.

May import only errors: the Kinect v2 topology as data.
"""

from kinefuse.skeleton.kinect_v2 import (
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

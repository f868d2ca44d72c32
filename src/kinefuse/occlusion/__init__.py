"""Occlusion detection (client side, 2D bone intersection) and sensor selection (server side).

May import: errors, io (base), skeleton, geometry, camera, frames, protocol, motion, sync.
"""

from kinefuse.occlusion.segments import (
    DEFAULT_NEAR_M,
    OcclusionResult,
    PrecisionRecall,
    crossing_parameters,
    detect_occlusion,
    detect_occlusion_sensors,
    non_adjacent_bone_pairs,
    occlusion_precision_recall,
    segments_intersect,
)
from kinefuse.occlusion.select import select_sensors

__all__ = [
    "DEFAULT_NEAR_M",
    "OcclusionResult",
    "PrecisionRecall",
    "crossing_parameters",
    "detect_occlusion",
    "detect_occlusion_sensors",
    "non_adjacent_bone_pairs",
    "occlusion_precision_recall",
    "segments_intersect",
    "select_sensors",
]

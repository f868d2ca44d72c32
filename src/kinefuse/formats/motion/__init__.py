"""Reading real motion (BVH, ASF/AMC) into Kinect v2 joint sequences.

``load_motion(path)`` reads a file and retargets it onto the 25 Kinect v2 joints in the lab
frame (the retargeting itself is :mod:`kinefuse.biomech.retarget`). See ``docs/motion.md``.

Part of :mod:`kinefuse.formats`: may import the rooms below it.
"""

from kinefuse.biomech.name_maps import BUILTIN_MAPS, NameMap, load_name_map, parse_name_map
from kinefuse.biomech.retarget import (
    CORE_JOINTS,
    SYNTHESIS_RULES,
    UNITS_M,
    estimate_height_m,
    facing_direction,
    place,
    resample,
    resolve_map,
    retarget,
    select_map,
)
from kinefuse.core.frames.motion import Motion
from kinefuse.core.frames.source_motion import SourceMotion
from kinefuse.formats.motion.asf_amc import AsfSkeleton, parse_amc, parse_asf, read_amc, read_asf
from kinefuse.formats.motion.bvh import parse_bvh, read_bvh
from kinefuse.formats.motion.load import find_asf_for, load_motion

__all__ = [
    "BUILTIN_MAPS",
    "CORE_JOINTS",
    "SYNTHESIS_RULES",
    "UNITS_M",
    "AsfSkeleton",
    "Motion",
    "NameMap",
    "SourceMotion",
    "estimate_height_m",
    "facing_direction",
    "find_asf_for",
    "load_motion",
    "load_name_map",
    "parse_amc",
    "parse_asf",
    "parse_bvh",
    "parse_name_map",
    "place",
    "read_amc",
    "read_asf",
    "read_bvh",
    "resample",
    "resolve_map",
    "retarget",
    "select_map",
]

"""The BVH text of a solved pose (:mod:`kinefuse.formats.motion.bvh_pose`), and its recognizer.

Written through :mod:`kinefuse.formats.export` (``.bvh`` in its registry: the safe-write rules
of :mod:`kinefuse.core.outputs`). Layout (``docs/formats.md``, "BVH export"): the hierarchy of
:data:`kinefuse.formats.motion.bvh_pose.BVH_NAMES`, offsets in metres, Y up; the root's channels
``Xposition Yposition Zposition`` then its rotations, every other joint three rotation channels
in its own order (:func:`kinefuse.formats.motion.bvh_pose.channel_order`), degrees; one line per
frame.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kinefuse.core.inputs import LINE_LIMIT
from kinefuse.formats.motion.bvh_pose import BVH_NAMES, BVH_PARENTS, BvhPose, channel_order

_IND = "  "


def _vec(v: np.ndarray) -> str:
    return " ".join(f"{x:.6f}" for x in v)


def bvh_text(pose: BvhPose, frame_time_s: float) -> str:
    """The whole file: HIERARCHY, then MOTION with one line per frame (no NaN: the pose's held
    frames are already filled)."""
    rig = pose.rig
    kids: dict[int, list[int]] = {}
    for j, par in enumerate(BVH_PARENTS):
        kids.setdefault(par, []).append(j)
    lines = ["HIERARCHY"]

    def rot_channels(name: str) -> str:
        return " ".join(f"{a}rotation" for a in channel_order(name))

    def visit(j: int, depth: int) -> None:
        ind = _IND * depth
        name = BVH_NAMES[j]
        if BVH_PARENTS[j] < 0:
            lines.append(f"ROOT {name}")
            channels = f"CHANNELS 6 Xposition Yposition Zposition {rot_channels(name)}"
        else:
            lines.append(f"{ind}JOINT {name}")
            channels = f"CHANNELS 3 {rot_channels(name)}"
        lines.append(ind + "{")
        lines.append(f"{ind}{_IND}OFFSET {_vec(rig.offsets[j])}")
        lines.append(f"{ind}{_IND}{channels}")
        for c in kids.get(j, []):
            visit(c, depth + 1)
        if j in rig.end_sites:
            lines.extend(
                [
                    f"{ind}{_IND}End Site",
                    f"{ind}{_IND}{{",
                    f"{ind}{_IND}{_IND}OFFSET {_vec(rig.end_sites[j])}",
                    f"{ind}{_IND}}}",
                ]
            )
        lines.append(ind + "}")

    visit(kids[-1][0], 0)
    t = pose.root_m.shape[0]
    lines += ["MOTION", f"Frames: {t}", f"Frame Time: {frame_time_s:.9f}"]
    data = np.concatenate([pose.root_m, pose.channels_deg.reshape(t, -1)], axis=1)
    if not np.isfinite(data).all():  # the solver fills every gap; a NaN here is a bug
        raise AssertionError("BVH channels must be finite")
    lines += [" ".join(f"{v:.6f}" for v in row) for row in data]
    return "\n".join(lines) + "\n"


def is_bvh_export(path: Path) -> bool:
    """True for a BVH whose hierarchy is kinefuse's rig (its joint names, in its order)."""
    try:
        with path.open(encoding="utf-8") as f:
            if f.readline(LINE_LIMIT).strip() != "HIERARCHY":
                return False
            names: list[str] = []
            for line in iter(lambda: f.readline(LINE_LIMIT), ""):
                words = line.split()
                if words and words[0] in ("ROOT", "JOINT"):
                    names.append(words[1] if len(words) > 1 else "")
                elif words and words[0] == "MOTION":
                    break
                if len(names) > len(BVH_NAMES):
                    return False
    except (OSError, UnicodeDecodeError):
        return False
    return tuple(names) == BVH_NAMES

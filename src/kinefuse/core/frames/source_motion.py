"""The skeleton sequence a motion file yields before retargeting, and the rotation helpers the
readers share.

A :class:`SourceMotion` holds the positions of the file's own joints (and End Sites) in the
file's own units and axes (y up for BVH and ASF/AMC), frame by frame. The position of a joint is
where its rotation pivots (BVH ``JOINT X``: the point ``X``'s channels rotate about; ASF bone
``X``: the start of the bone). End Sites are named ``"<parent>/End"``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


def read_motion_text(path: str | Path) -> str:
    """The text of a motion file; ``.gz`` files are decompressed on the fly. Its size and first
    bytes are checked before it is read whole (:func:`kinefuse.core.inputs.read_text`).

    Raises
    ------
    MotionFormatError
        The file cannot be read, is too large, is binary or is a corrupt gzip file.
    """
    from kinefuse.core.inputs import read_text
    from kinefuse.errors import MotionFormatError

    p = Path(path)
    return read_text(
        p,
        what=f"{motion_suffix(p).lstrip('.').upper() or 'motion'} file",
        fail=lambda message, line: MotionFormatError(message, path=str(p), line=line),
    )


def motion_suffix(path: str | Path) -> str:
    """The format suffix of a motion file, looking through ``.gz`` (``x.bvh.gz`` -> ``.bvh``)."""
    p = Path(path)
    if p.suffix.lower() == ".gz":
        p = p.with_suffix("")
    return p.suffix.lower()


#: Suffix of End Site names: the End Site under joint ``X`` is called ``"X/End"``.
END_SITE_SUFFIX = "/End"


@dataclass(frozen=True, eq=False)
class SourceMotion:
    """Joint positions of a motion file in its own skeleton, units and axes.

    Attributes
    ----------
    names : tuple of str, length J
        Joint names as in the file; End Sites are ``"<parent>/End"``.
    parents : tuple of int, length J
        Index of each joint's parent (-1 for a root); parents come before their children.
    positions : (T, J, 3) float
        Joint positions in file units and file axes (y up for BVH and ASF/AMC).
    rate_hz : float
        Frame rate.
    path : str
        The file it came from.
    fmt : str
        ``"bvh"`` or ``"asf/amc"``.
    asf_unit_m : float
        Metres per file unit under the ``"asf"`` unit (``0.0254 / length`` of the ASF ``:units``
        section; the CMU value ``0.0254 / 0.45`` for BVH files, which carry no units).
    notes : tuple of str
        What the reader did on the way (frames dropped, ...), for provenance.
    rotations : (T, J, 3, 3) float or None
        Global rotation of every joint's frame (BVH: the frame its channels rotate; ASF: the
        bone's ``axis`` frame, ``G @ C``) to the file's axes, per frame; End Sites carry their
        parent's. Computed during forward kinematics; None when a reader does not provide it.
    """

    names: tuple[str, ...]
    parents: tuple[int, ...]
    positions: Array
    rate_hz: float
    path: str
    fmt: str
    asf_unit_m: float = 0.0254 / 0.45
    notes: tuple[str, ...] = ()
    rotations: Array | None = None

    def __post_init__(self) -> None:
        p = np.asarray(self.positions, dtype=np.float64)
        if p.ndim != 3 or p.shape[1:] != (len(self.names), 3) or p.shape[0] < 1:
            raise ValueError(f"positions must have shape (T, {len(self.names)}, 3), got {p.shape}")
        if len(self.parents) != len(self.names):
            raise ValueError(f"parents has {len(self.parents)} entries for {len(self.names)} names")
        object.__setattr__(self, "positions", p)
        if self.rotations is not None:
            r = np.asarray(self.rotations, dtype=np.float64)
            if r.shape != (*p.shape[:2], 3, 3):
                raise ValueError(f"rotations must have shape {(*p.shape[:2], 3, 3)}, got {r.shape}")
            object.__setattr__(self, "rotations", r)

    @property
    def n_frames(self) -> int:
        return int(self.positions.shape[0])

    def index(self) -> dict[str, int]:
        """Name -> joint index."""
        return {n: i for i, n in enumerate(self.names)}


def leading_outlier_frames(positions: Array, roots: list[int], *, max_frames: int = 10) -> int:
    """Number of leading frames that are an inserted pose (T-pose) rather than the motion.

    A T-pose inserted before a capture shows up as a jump of the body's shape (joint positions
    relative to the root) between the inserted frames and the first real frame, far larger than
    the motion's own frame-to-frame change. The first ``k`` frames (``k <= max_frames``) are
    reported when frames ``0..k-1`` hold one pose, the step from frame ``k-1`` to ``k`` is more
    than 20 times the median step of the rest and more than 3 % of the body's size.

    Parameters
    ----------
    positions : (T, J, 3) float
        Joint positions (any unit).
    roots : list of int
        Root joint indices; shapes are taken relative to the first root.

    Returns
    -------
    k : int
        How many leading frames to drop (0 when none).
    """
    t = positions.shape[0]
    if t < 8:
        return 0
    rel = positions - positions[:, roots[0] : roots[0] + 1, :]
    step = np.sqrt(((rel[1:] - rel[:-1]) ** 2).sum(-1)).mean(-1)  # (T-1,) mean joint move
    extent = rel[1:].reshape(-1, 3)
    size = float(np.ptp(extent, axis=0).max()) if extent.size else 0.0
    if size <= 0:
        return 0
    for k in range(1, min(max_frames, t - 4) + 1):
        before = step[: k - 1]
        if before.size and before.max() > 0.01 * step[k - 1]:
            break  # the frames before k are not one held pose
        rest = step[k:]
        typical = float(np.median(rest)) if rest.size else 0.0
        if step[k - 1] > 20.0 * typical and step[k - 1] > 0.03 * size:
            return k
    return 0

"""The skeleton sequence every analysis takes: joint centres over time, optional limb rotations.

All inputs (fused sessions, BVH and ASF/AMC clips, marker files) are expressed on the Kinect v2
joint topology (:data:`kinefuse.core.skeleton.JOINTS`, :data:`kinefuse.core.skeleton.PARENTS`); a
source may lack some joints (marker data without hand tips), in which case ``joint_names`` is a
subset and every joint's parent is its nearest present Kinect ancestor.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.core.skeleton import JOINT_INDEX, JOINTS, N_JOINTS, PARENTS
from kinefuse.errors import InputError

Array = NDArray[np.float64]


def kinect_parents(joint_names: Sequence[str]) -> tuple[int, ...]:
    """Parents (indices into ``joint_names``) on the Kinect tree restricted to ``joint_names``.

    Each joint's parent is its nearest Kinect ancestor that is in ``joint_names``; ``-1`` when no
    ancestor is present (the root).
    """
    unknown = [n for n in joint_names if n not in JOINT_INDEX]
    if unknown:
        raise InputError(
            f"joint names must be Kinect v2 joints, got unknown {unknown}; "
            f"the 25 names are: {', '.join(JOINTS)}"
        )
    local = {n: i for i, n in enumerate(joint_names)}
    out = []
    for n in joint_names:
        p = PARENTS[JOINT_INDEX[n]]
        while p >= 0 and JOINTS[p] not in local:
            p = PARENTS[p]
        out.append(-1 if p < 0 else local[JOINTS[p]])
    return tuple(out)


@dataclass(frozen=True, eq=False)
class SkeletonSequence:
    """Joint centres over time on the Kinect v2 topology, with optional limb orientations.

    Attributes
    ----------
    positions : (T, J, 3) float
        Joint centres, metres, world frame (z up). NaN where a joint is missing.
    mask : (T, J) bool
        True where the joint is present; ``mask == isfinite(positions).all(-1)`` is enforced
        (a NaN position is always masked out, a masked-out position is set to NaN).
    joint_names : tuple of str, length J
        Kinect v2 joint names (a subset of :data:`kinefuse.core.skeleton.JOINTS` is allowed).
    parents : tuple of int, length J
        Parent index of each joint into ``joint_names``, ``-1`` for the root. A tree: one root,
        no cycles (the order need not put parents first; Kinect's SDK order does not).
    t_s : (T,) float
        Time of each frame, seconds, strictly increasing.
    rate_hz : float
        Nominal frame rate, Hz.
    orientations : (T, L, 3, 3) float or None
        Limb-to-world rotation per frame where the source has one (BVH/ASF-AMC rotations,
        marker clusters); NaN where missing. ``None`` for position-only sources (fused sessions).
    orientation_limbs : tuple of str, length L
        Limb names (:data:`kinefuse.biomech.limbs.LIMB_NAMES`) of the ``L`` orientations.
    source : str
        Provenance (path, method, notes).
    """

    positions: Array
    mask: NDArray[np.bool_]
    joint_names: tuple[str, ...]
    parents: tuple[int, ...]
    t_s: Array
    rate_hz: float
    orientations: Array | None = None
    orientation_limbs: tuple[str, ...] = field(default_factory=tuple)
    source: str = ""

    def __post_init__(self) -> None:
        names = tuple(str(n) for n in self.joint_names)
        j = len(names)
        if j == 0:
            raise InputError("a skeleton sequence needs at least one joint, got joint_names=()")
        if len(set(names)) != j:
            raise InputError(f"joint names must be unique, got {names}")
        p = np.array(self.positions, dtype=np.float64)
        if p.ndim != 3 or p.shape[1:] != (j, 3) or p.shape[0] < 1:
            raise InputError(
                f"positions must have shape (T, {j}, 3) for {j} joints with T >= 1, got {p.shape}"
            )
        t = p.shape[0]
        m = np.array(self.mask, dtype=bool)
        if m.shape != (t, j):
            raise InputError(f"mask must have shape ({t}, {j}) like positions, got {m.shape}")
        finite = np.isfinite(p).all(axis=-1)
        m &= finite
        p[~m] = np.nan
        parents = tuple(int(x) for x in self.parents)
        _check_tree(parents, j)
        ts = np.asarray(self.t_s, dtype=np.float64).reshape(-1)
        if ts.shape != (t,):
            raise InputError(f"t_s must have shape ({t},), one time per frame, got {ts.shape}")
        if not np.isfinite(ts).all() or (t > 1 and not (np.diff(ts) > 0).all()):
            raise InputError("t_s must be finite and strictly increasing; sort or de-duplicate it")
        rate = float(self.rate_hz)
        if not rate > 0 or not np.isfinite(rate):
            raise InputError(f"rate_hz must be a positive number, got {self.rate_hz!r}")
        limbs = tuple(str(x) for x in self.orientation_limbs)
        ori = None
        if self.orientations is not None:
            ori = np.asarray(self.orientations, dtype=np.float64)
            if ori.shape != (t, len(limbs), 3, 3):
                raise InputError(
                    f"orientations must have shape ({t}, {len(limbs)}, 3, 3) for the "
                    f"{len(limbs)} orientation_limbs, got {ori.shape}"
                )
        elif limbs:
            raise InputError("orientation_limbs given without orientations; pass both or neither")
        object.__setattr__(self, "positions", p)
        object.__setattr__(self, "mask", m)
        object.__setattr__(self, "joint_names", names)
        object.__setattr__(self, "parents", parents)
        object.__setattr__(self, "t_s", ts)
        object.__setattr__(self, "rate_hz", rate)
        object.__setattr__(self, "orientations", ori)
        object.__setattr__(self, "orientation_limbs", limbs)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_kinect(
        cls,
        positions: ArrayLike,
        /,
        *,
        t_s: ArrayLike | None = None,
        rate_hz: float | None = None,
        joint_names: Sequence[str] = JOINTS,
        mask: ArrayLike | None = None,
        orientations: ArrayLike | None = None,
        orientation_limbs: Sequence[str] = (),
        source: str = "",
    ) -> SkeletonSequence:
        """A sequence on the Kinect topology from positions ``(T, J, 3)``, metres.

        Either ``t_s`` (seconds, ``(T,)``) or ``rate_hz`` must be given; with only one, the other
        is derived (``t_s = arange(T) / rate_hz``, or ``rate_hz = 1 / median(diff(t_s))``). The mask
        defaults to the finite positions. Parents follow :func:`kinect_parents`.
        """
        p = np.asarray(positions, dtype=np.float64)
        if p.ndim != 3:
            raise InputError(f"positions must have shape (T, J, 3), got {p.shape}")
        t = p.shape[0]
        if t_s is None and rate_hz is None:
            raise InputError("give t_s (seconds per frame) or rate_hz to place frames in time")
        if t_s is not None:
            ts = np.asarray(t_s, dtype=np.float64).reshape(-1)
        else:
            ts = np.arange(t, dtype=np.float64) / float(rate_hz or 1.0)
        if rate_hz is None:
            dt = np.diff(ts)
            rate_hz = float(1.0 / np.median(dt)) if dt.size and np.median(dt) > 0 else 30.0
        names = tuple(joint_names)
        m: NDArray[np.bool_] = np.asarray(
            np.isfinite(p).all(axis=-1) if mask is None else mask, dtype=bool
        )
        return cls(
            positions=p,
            mask=m,
            joint_names=names,
            parents=kinect_parents(names),
            t_s=ts,
            rate_hz=float(rate_hz),
            orientations=None if orientations is None else np.asarray(orientations, float),
            orientation_limbs=tuple(orientation_limbs),
            source=source,
        )

    @classmethod
    def from_motion(cls, motion: object, /, *, source: str | None = None) -> SkeletonSequence:
        """A sequence from a :class:`kinefuse.core.frames.motion.Motion` (25 joints, constant
        rate)."""
        positions = np.asarray(motion.positions)  # type: ignore[attr-defined]
        rate = float(motion.rate_hz)  # type: ignore[attr-defined]
        return cls.from_kinect(
            positions,
            rate_hz=rate,
            source=motion.source if source is None else source,  # type: ignore[attr-defined]
        )

    # ------------------------------------------------------------------ access
    @property
    def n_frames(self) -> int:
        """Number of frames ``T``."""
        return int(self.positions.shape[0])

    @property
    def n_joints(self) -> int:
        """Number of joints ``J``."""
        return len(self.joint_names)

    @property
    def duration_s(self) -> float:
        """Time from the first to the last frame, seconds."""
        return float(self.t_s[-1] - self.t_s[0])

    def index(self, name: str) -> int:
        """Index of joint ``name`` in this sequence; a clear error if the source lacks it."""
        try:
            return self.joint_names.index(name)
        except ValueError:
            raise InputError(
                f"joint {name!r} is not in this sequence ({self.source or 'no source'}); "
                f"it has: {', '.join(self.joint_names)}"
            ) from None

    def has(self, name: str) -> bool:
        """Whether the sequence has joint ``name`` at all (it may still be masked per frame)."""
        return name in self.joint_names

    def kinect_positions(self) -> Array:
        """Positions on all 25 Kinect joints ``(T, 25, 3)``, metres, NaN for absent joints.

        Computed once and returned read-only (copy it to modify).
        """
        cached = self.__dict__.get("_kinect")
        if cached is not None:
            return cached
        if self.joint_names == JOINTS:
            out = self.positions.view()
        else:
            out = np.full((self.n_frames, N_JOINTS, 3), np.nan)
            idx = [JOINT_INDEX[n] for n in self.joint_names]
            out[:, idx] = self.positions
        out.flags.writeable = False
        self.__dict__["_kinect"] = out
        return out

    def orientation(self, limb: str) -> Array | None:
        """Limb-to-world rotations ``(T, 3, 3)`` of ``limb``, or None if the source has none."""
        if self.orientations is None or limb not in self.orientation_limbs:
            return None
        return self.orientations[:, self.orientation_limbs.index(limb)]

    def slice(self, start_s: float | None = None, end_s: float | None = None) -> SkeletonSequence:
        """The frames with ``start_s <= t_s <= end_s`` (seconds; None = open end).

        Raises :class:`kinefuse.errors.InputError` when no frame falls in the interval.
        """
        lo = -np.inf if start_s is None else float(start_s)
        hi = np.inf if end_s is None else float(end_s)
        keep = (self.t_s >= lo) & (self.t_s <= hi)
        if not keep.any():
            raise InputError(
                f"no frame in [{start_s}, {end_s}] s; the sequence spans "
                f"{self.t_s[0]:.3f} to {self.t_s[-1]:.3f} s"
            )
        return self.take(np.flatnonzero(keep))

    def take(self, frames: ArrayLike) -> SkeletonSequence:
        """The sequence restricted to frame indices ``frames`` (increasing)."""
        f = np.asarray(frames, dtype=np.intp)
        return SkeletonSequence(
            positions=self.positions[f],
            mask=self.mask[f],
            joint_names=self.joint_names,
            parents=self.parents,
            t_s=self.t_s[f],
            rate_hz=self.rate_hz,
            orientations=None if self.orientations is None else self.orientations[f],
            orientation_limbs=self.orientation_limbs,
            source=self.source,
        )


def _check_tree(parents: tuple[int, ...], j: int) -> None:
    if len(parents) != j:
        raise InputError(f"parents must have one entry per joint ({j}), got {len(parents)}")
    bad = [p for p in parents if not -1 <= p < j]
    if bad:
        raise InputError(f"parents must be -1 or a joint index below {j}, got {bad}")
    roots = [i for i, p in enumerate(parents) if p < 0]
    if len(roots) != 1:
        raise InputError(f"the skeleton must be one tree with one root, got roots {roots}")
    for i in range(j):
        seen = 0
        k = i
        while k >= 0:
            k = parents[k]
            seen += 1
            if seen > j:
                raise InputError(f"parents contain a cycle through joint {i}")

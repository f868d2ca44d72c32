"""Per-joint status codes of the fusion methods.

Every solver returns, next to its positions, one :class:`FusionStatus` per frame and joint, so that
no number leaves a solver without a word on how it was obtained. The codes are ordered by severity:
when several apply, the highest one is reported (``np.maximum`` combines them).

Position contract: positions are finite for every status except :attr:`FusionStatus.NO_DATA`
(always NaN). Only :attr:`FusionStatus.OK` and :attr:`FusionStatus.PLANAR` are the method's own,
well-posed answer; the others are the best estimate available, flagged.
"""

from __future__ import annotations

import enum

import numpy as np
from numpy.typing import ArrayLike, NDArray


class FusionStatus(enum.IntEnum):
    """How a fused joint position was obtained (stored as ``int8``)."""

    #: Solved by the method; the geometry determines the point.
    OK = 0
    #: The sensors in use are (nearly) coplanar (always so with 3 sensors): the ranges fix the
    #: point up to its mirror image across the sensors' plane, and the side was chosen toward the
    #: reference point (the mean of the sensors' own world-frame measurements).
    PLANAR = 1
    #: The ranges are inconsistent (the spheres do not meet): the nearest point in the sensors'
    #: plane is returned.
    NO_INTERSECTION = 2
    #: The iteration cap was reached before ``|F_k - F_{k-1}| < c_threshold``: the last iterate
    #: (whose cost is the lowest so far) is returned.
    NOT_CONVERGED = 3
    #: The geometry cannot determine the point (collinear sensors, singular ``J^T J``, coplanar
    #: sensors with the plain least-squares rule): the best available estimate is returned (the
    #: last iterate, or the reference point).
    DEGENERATE = 4
    #: Fewer than 3 usable sensors: no trilateration; the reference point (the mean of the
    #: sensors' own world-frame measurements) is returned, NaN if there is none.
    TOO_FEW_SENSORS = 5
    #: (``best-live``) Only one sensor contributed: its measurement, filtered; no cross-check.
    SINGLE_SENSOR = 6
    #: (``best-live``) Every contributing sensor reported the joint INFERRED (guessed by its
    #: body tracker), none TRACKED.
    INFERRED_ONLY = 7
    #: (``best-live``) The fused joint breaks a bone length learned so far by more than the
    #: tolerance before the projection onto it: the body's shape is in doubt there.
    BONE_LENGTH = 8
    #: (``best-live``) No measurement at this frame: the filter's prediction from earlier ones.
    PREDICTED = 9
    #: No sensor observed the joint (or not for too long): NaN.
    NO_DATA = 10

    @property
    def description(self) -> str:
        """One line saying what the code means and what position comes with it."""
        return _DESCRIPTIONS[self]


_DESCRIPTIONS: dict[FusionStatus, str] = {
    FusionStatus.OK: "solved; the sensor geometry determines the point",
    FusionStatus.PLANAR: "coplanar sensors: mirror side chosen toward their own measurements",
    FusionStatus.NO_INTERSECTION: "ranges inconsistent: nearest point in the sensors' plane",
    FusionStatus.NOT_CONVERGED: "iteration cap reached: last (lowest-cost) iterate returned",
    FusionStatus.DEGENERATE: "sensor geometry degenerate: best available estimate returned",
    FusionStatus.TOO_FEW_SENSORS: "fewer than 3 sensors: mean of the sensors' own measurements",
    FusionStatus.SINGLE_SENSOR: "one sensor only: its measurement, filtered, not cross-checked",
    FusionStatus.INFERRED_ONLY: "only INFERRED (guessed) measurements, none tracked",
    FusionStatus.BONE_LENGTH: "breaks a learned bone length: projected back onto it",
    FusionStatus.PREDICTED: "no measurement this frame: the filter's prediction",
    FusionStatus.NO_DATA: "no sensor observed the joint: NaN",
}


def is_solved(status: ArrayLike) -> NDArray[np.bool_]:
    """True where the status is ``OK`` or ``PLANAR`` (the method's own, well-posed answer).

    Parameters
    ----------
    status : (...) int
        Codes of :class:`FusionStatus`.

    Returns
    -------
    solved : (...) bool
    """
    s = np.asarray(status)
    return (s == FusionStatus.OK) | (s == FusionStatus.PLANAR)


def status_counts(status: ArrayLike) -> dict[str, int]:
    """How many entries carry each status, by name (every code listed, zeros included)."""
    s = np.asarray(status).ravel()
    counts = np.bincount(s.astype(np.intp), minlength=len(FusionStatus)) if s.size else None
    return {
        code.name: int(counts[code.value]) if counts is not None else 0 for code in FusionStatus
    }

"""Gaps in angle curves: fill the short ones, never invent the long ones.

A *gap* is a run of consecutive frames where a curve is NaN, with valid frames on both sides.
Its duration is ``t[last missing] - t[first missing] + dt`` (``dt`` the median frame interval:
the time the missing frames cover). Gaps of at most ``max_gap_s`` (default 0.1 s, about one
tenth of a gait cycle) are filled by linear interpolation in time between the two valid frames
around them; longer gaps, and missing frames at the start or end (nothing to interpolate
between), stay NaN. Linear interpolation is chosen because it never overshoots: a filled value
always lies between two measured ones.

Pure numpy; no files.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

__all__ = ["MAX_GAP_S", "fill_short_gaps", "fill_short_gaps_all", "missing_runs"]

#: Longest gap filled by interpolation, seconds.
MAX_GAP_S = 0.1


def missing_runs(valid: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """Runs ``(start, stop)`` (stop exclusive) of False in a (T,) bool array."""
    v = np.asarray(valid, dtype=bool)
    d = np.diff(np.concatenate([[1], v.astype(np.int8), [1]]))
    starts = np.flatnonzero(d == -1)
    stops = np.flatnonzero(d == 1)
    return [(int(a), int(b)) for a, b in zip(starts, stops, strict=True)]


def fill_short_gaps(
    t_s: ArrayLike, values: ArrayLike, *, max_gap_s: float = MAX_GAP_S
) -> tuple[Array, NDArray[np.bool_]]:
    """Fill interior gaps of at most ``max_gap_s`` by linear interpolation (module docstring).

    Parameters
    ----------
    t_s : (T,) float
        Frame times, seconds, increasing.
    values : (T,) float
        The curve, NaN where missing.
    max_gap_s : float
        Longest gap filled, seconds.

    Returns
    -------
    filled : (T,) float
        The curve with short gaps filled; long gaps and edge gaps stay NaN.
    was_filled : (T,) bool
        True on the frames that were filled.
    """
    t = np.asarray(t_s, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64).copy()
    flag = np.zeros(v.shape, dtype=bool)
    ok = np.isfinite(v)
    if ok.all() or not ok.any():
        return v, flag
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    for a, b in missing_runs(ok):
        if a == 0 or b == v.size:
            continue  # an edge: nothing to interpolate towards
        if t[b - 1] - t[a] + dt > max_gap_s + 1e-9:
            continue
        w = (t[a:b] - t[a - 1]) / (t[b] - t[a - 1])
        v[a:b] = v[a - 1] + w * (v[b] - v[a - 1])
        flag[a:b] = True
    return v, flag


def fill_short_gaps_all(
    t_s: ArrayLike, curves: Mapping[str, ArrayLike], *, max_gap_s: float = MAX_GAP_S
) -> tuple[dict[str, Array], dict[str, NDArray[np.bool_]]]:
    """:func:`fill_short_gaps` on every curve of a mapping: (filled curves, filled flags)."""
    out: dict[str, Array] = {}
    flags: dict[str, NDArray[np.bool_]] = {}
    for name, v in curves.items():
        out[name], flags[name] = fill_short_gaps(t_s, v, max_gap_s=max_gap_s)
    return out, flags

"""Server-side occlusion compensation: the paper's sensor selection (METHODS.md A.4).

Per frame and joint, the server uses the sensors that see the joint unoccluded; when every sensor
that observed it has it occluded, it takes the one sensor with the fewest intersection points in
that frame (ties go to the lowest sensor index).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.core.skeleton import N_JOINTS
from kinefuse.errors import InputError

BoolArray = NDArray[np.bool_]


def select_sensors(
    occluded: ArrayLike,
    n_intersections: ArrayLike,
    available: ArrayLike | None = None,
) -> BoolArray:
    """The paper's selection of sensors per frame and joint.

    Parameters
    ----------
    occluded : (T, S, 25) bool
        Occlusion flags each sensor's client sent.
    n_intersections : (T, S) int
        Number of bone intersection points each sensor found in each frame.
    available : (T, S, 25) bool, optional
        Where the sensor has an observation at all (finite, tracked or inferred); default all.
        Unavailable sensors are never selected.

    Returns
    -------
    selected : (T, S, 25) bool
        The sensors that see the joint unoccluded; where there is none but some sensor observed
        the joint, the single available sensor with the fewest intersection points; all False
        where no sensor observed the joint.
    """
    occ = np.asarray(occluded)
    if occ.dtype != np.bool_ or occ.ndim != 3 or occ.shape[2] != N_JOINTS:
        raise InputError(
            f"occluded must be a bool array of shape (T, S, {N_JOINTS}), "
            f"got {occ.dtype} {occ.shape}"
        )
    n_frames, n_sensors, _ = occ.shape
    n_int = np.asarray(n_intersections)
    if n_int.shape != (n_frames, n_sensors) or not np.issubdtype(n_int.dtype, np.integer):
        raise InputError(
            f"n_intersections must be an integer array of shape ({n_frames}, {n_sensors}) "
            f"(frames, sensors), got {n_int.dtype} {n_int.shape}"
        )
    if available is None:
        avail = np.ones(occ.shape, dtype=bool)
    else:
        avail = np.asarray(available)
        if avail.dtype != np.bool_ or avail.shape != occ.shape:
            raise InputError(
                f"available must be a bool array of shape {occ.shape}, got {avail.dtype} "
                f"{avail.shape}"
            )
    selected = avail & ~occ
    none_clear = ~selected.any(axis=1) & avail.any(axis=1)  # (T, 25)
    # fewest intersections among the available sensors; unavailable ones rank last
    big = np.iinfo(np.int64).max
    rank = np.where(avail, n_int.astype(np.int64)[:, :, None], big)  # (T, S, 25)
    best = np.argmin(rank, axis=1)  # (T, 25), first index wins ties
    fi, ji = np.nonzero(none_clear)
    selected[fi, best[fi, ji], ji] = True
    return selected

"""The truth a replay viewer overlays (evaluation code: the one place the viewer's truth is read).

The viewer shows stored fused results, which a session does not tag with the calibration they
were fused with: ``kinefuse fuse --store`` uses the session's calibration (its own world: origin
and heading are the protocol's choice), ``--true-calibration`` the simulator's world. As
``kinefuse evaluate`` does, the truth is moved into the calibration's world (the
yaw-and-translation alignment of :func:`kinefuse.lab.fusion_truth.calibration_alignment`),
unless the unaligned truth is less than half as far from the shown result (then that result was
evidently fused with the true poses); the page says which.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.geometry.transforms import apply_transform
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.lab.fusion_truth import calibration_alignment, truth_at

Array = NDArray[np.float64]


def replay_truth(
    store: SessionStore,
    t_s: Array,
    shown_m: Array | None,
    poses: dict[str, Array] | None,
) -> tuple[Array | None, str]:
    """True joints on the replay's frame times, in the world of the shown result.

    Parameters
    ----------
    store : SessionStore
    t_s : (T,) float
        Frame times (server clock), seconds.
    shown_m : (T, 25, 3) float or None
        The fused result the truth is compared with (picks the world, see the module docstring).
    poses : dict of str to (4, 4) float, or None
        The session's calibration (sensor id -> sensor2world), if it has one.

    Returns
    -------
    truth_m : (T, 25, 3) float or None
        None when the session has no truth (a live recording).
    note : str
        Which world the truth is drawn in, for the page.
    """
    if not store.has_truth():
        return None, "no truth in this session (a live recording)"
    truth = truth_at(store, np.asarray(t_s, dtype=np.float64))
    if not poses:
        return truth, "truth in the simulator's world (the session has no calibration)"
    known = {s.id for s in store.sensors()}
    if set(poses) - known:
        return truth, "truth in the simulator's world"
    truth2world, _ = calibration_alignment(store, poses)
    aligned = apply_transform(truth2world, truth)
    if shown_m is None:
        return aligned, "truth aligned to the session's calibration"
    with np.errstate(invalid="ignore"):
        e_raw = np.nanmean(np.linalg.norm(shown_m - truth, axis=-1))
        e_cal = np.nanmean(np.linalg.norm(shown_m - aligned, axis=-1))
    if np.isfinite(e_raw) and (not np.isfinite(e_cal) or e_raw < 0.5 * e_cal):
        return truth, "truth in the simulator's world (the result was fused with the true poses)"
    return aligned, "truth aligned to the session's calibration (yaw + translation)"

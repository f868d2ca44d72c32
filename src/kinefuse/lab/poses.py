"""Sensor poses for fusion: a calibration file, the calibration stored in a session, or (for
simulated sessions, on request) the true poses, which is why this lives with the truth readers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from kinefuse.errors import InputError, StoreError
from kinefuse.formats.store.session_store import SessionStore

Array = NDArray[np.float64]


def resolve_poses(
    store: SessionStore, calibration: Path | None, true_calibration: bool
) -> tuple[dict[str, Array], str]:
    """Sensor poses for fusion: a calibration file, the truth (evaluation only), or the
    calibration stored in the session (``kinefuse calibrate``'s full preferred over paper, then the
    live server's calibration from the person, ``body``)."""
    from kinefuse.capture.calibration.calib_file import loads_calibration, read_calibration

    if calibration is not None and true_calibration:
        raise InputError("give either --calibration or --true-calibration, not both")
    if true_calibration:
        if not store.has_truth():
            raise InputError(
                f"{store.path} has no ground truth (a recording): --true-calibration is only "
                "for simulated sessions; leave it out to use the session's stored calibration, or "
                "pass --calibration CALIB.toml"
            )
        truth = store.truth()
        poses = {}
        for s in store.sensors():
            try:
                poses[s.id] = truth.sensor(s.id)[0]
            except StoreError:  # a sensor added to the recording, not simulated: no true pose
                continue
        return poses, "true poses (simulator)"
    if calibration is not None:
        return read_calibration(calibration).sensor2world, str(calibration)
    for name in ("full", "paper", "body"):
        text = store.calibration(name)
        if text is not None:
            return loads_calibration(text, source=f"{store.path} [{name}]").sensor2world, (
                f"session calibration ({name})"
            )
    import shlex

    raise InputError(
        f"{store.path} has no calibration: run `kinefuse calibrate {shlex.quote(str(store.path))} "
        "--method full --store` first (it stores the calibration in the session), or pass "
        "--calibration CALIB.toml (or --true-calibration for a simulated session)"
    )

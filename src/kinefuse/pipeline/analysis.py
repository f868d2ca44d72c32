"""The analysis chain (paper B) as the commands run it: one input as a skeleton sequence, and
the chain on it (normalization, movement axes by every method, joint angles), timed."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.analysis.kinematics import joint_angles
from kinefuse.analysis.normalize import normalize
from kinefuse.analysis.parameterize import METHODS as AXIS_METHODS
from kinefuse.analysis.parameterize import learn_axes
from kinefuse.analysis.sequence import SkeletonSequence

Array = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class AnalysisInput:
    """One input of ``kinefuse analyze`` as a skeleton sequence."""

    path: Path
    kind: str  # "session", "motion" or "markers"
    seq: SkeletonSequence
    stored_phase_s: tuple[float, float] | None = None  # a session's ROM phase (metadata)
    fusion: dict[str, Any] | None = None  # method, calibration, frames (sessions)
    sensor_poses: dict[str, Array] | None = None  # sensor2world used by the fusion (sessions)
    anatomical: dict[str, Array] | None = None  # ISB anatomical angles, degrees (static trial)
    anatomical_status: dict[str, str] | None = None  # segment -> "ok" or why it was skipped
    static_source: str | None = None  # the static trial used


def analyse_sequence(seq: SkeletonSequence, phase: tuple[float, float]) -> dict[str, Any]:
    """The chain on one sequence: normalization, axes by every method, angles (DJ), timing."""
    t0 = time.perf_counter()
    norm = normalize(seq)
    t1 = time.perf_counter()
    models = {m: learn_axes(seq, norm, phase, method=m) for m in AXIS_METHODS}
    t2 = time.perf_counter()
    angles = joint_angles(seq, norm, models["dj"])
    named = angles.anatomical()
    t3 = time.perf_counter()
    return {
        "seq": seq,
        "norm": norm,
        "models": models,
        "angles": angles,
        "named": named,
        "seconds": {"normalize": t1 - t0, "learn_axes": t2 - t1, "angles": t3 - t2},
    }

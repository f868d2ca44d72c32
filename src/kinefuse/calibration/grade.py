"""Grade a calibration from its own evidence: good, doubtful or failed, and why.

No truth is used: only what the calibration itself saw. The evidence per sensor is the RMS
residual of its wand sightings against the jointly estimated wand positions, the number of
sightings the pose rests on, and (for the paper's level-sensor method) the sensor's tilt
measured from the floor plane in its own depth image.

Thresholds (documented in ``docs/calibration.md``) come from the wand detector's noise: on
simulated sessions a well calibrated sensor shows 1-2 mm RMS residual over about 100 sightings
(``kinefuse calibrate`` on the rigs in ``rigs/``); ten times that is doubtful, thirty times is
a failed registration. A sensor tilted by more than a few degrees breaks the paper's
assumption of level sensors whatever its residual, because that method has no way to see tilt
in its two wand holds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kinefuse.calibration.floor import FloorPlane
from kinefuse.calibration.register import Registration

#: Per-sensor RMS residual above which a calibration is doubtful / failed, metres.
RESIDUAL_DOUBTFUL_M = 0.010
RESIDUAL_FAILED_M = 0.030
#: Sightings below which the full registration of a sensor is doubtful / failed.
SIGHTINGS_DOUBTFUL = 30
SIGHTINGS_FAILED = 6
#: Tilt from level above which the paper's method (level sensors) is doubtful / failed, degrees.
TILT_DOUBTFUL_DEG = 1.5
TILT_FAILED_DEG = 4.0

GRADES = ("good", "doubtful", "failed")


@dataclass(frozen=True)
class Grade:
    """``grade`` in :data:`GRADES` and the ``reasons`` for anything worse than good."""

    grade: str
    reasons: tuple[str, ...]

    def to_dict(self) -> dict[str, object]:
        return {"grade": self.grade, "reasons": list(self.reasons)}


def sensor_tilt_deg(floor: FloorPlane) -> float:
    """How far a sensor is pitched and rolled away from level, degrees: the angle between the
    floor's up normal (in the sensor frame) and the sensor's image-up axis ``-y``."""
    up = np.asarray(floor.normal, dtype=np.float64)
    return float(np.degrees(np.arccos(np.clip(-up[1], -1.0, 1.0))))


def grade_calibration(reg: Registration, floors: dict[str, FloorPlane] | None = None) -> Grade:
    """Grade a registration from its residuals, sightings and (paper's method) sensor tilts."""
    worst = 0
    reasons: list[str] = []

    def flag(level: int, text: str) -> None:
        nonlocal worst
        worst = max(worst, level)
        reasons.append(f"{GRADES[level]}: {text}")

    for k, sid in enumerate(reg.sensor_ids):
        res = float(reg.residual_m[k])
        n = int(reg.n_sightings[k])
        if not np.isfinite(res):
            flag(2, f"sensor {sid} has no residual (its pose rests on nothing)")
        elif res > RESIDUAL_FAILED_M:
            flag(2, f"sensor {sid}: wand residual {1e3 * res:.0f} mm (over "
                 f"{1e3 * RESIDUAL_FAILED_M:.0f} mm): its sightings fit no rigid pose")  # fmt: skip
        elif res > RESIDUAL_DOUBTFUL_M:
            flag(1, f"sensor {sid}: wand residual {1e3 * res:.1f} mm (over "
                 f"{1e3 * RESIDUAL_DOUBTFUL_M:.0f} mm)")  # fmt: skip
        if reg.method == "full":
            if n < SIGHTINGS_FAILED:
                flag(2, f"sensor {sid}: only {n} wand sightings (fewer than {SIGHTINGS_FAILED})")
            elif n < SIGHTINGS_DOUBTFUL:
                flag(1, f"sensor {sid}: only {n} wand sightings (fewer than {SIGHTINGS_DOUBTFUL})")
    if reg.method == "paper":
        for sid in reg.sensor_ids:
            floor = (floors or {}).get(sid)
            if floor is None:
                flag(1, f"sensor {sid} sees no floor, so whether it is level (as the paper's "
                     "method assumes) cannot be checked")  # fmt: skip
                continue
            tilt = sensor_tilt_deg(floor)
            if tilt > TILT_FAILED_DEG:
                flag(2, f"sensor {sid} is tilted {tilt:.1f} deg from level (its floor plane); the "
                     "paper's method assumes level sensors: use --method full")  # fmt: skip
            elif tilt > TILT_DOUBTFUL_DEG:
                flag(1, f"sensor {sid} is tilted {tilt:.1f} deg from level (its floor plane); the "
                     "paper's method assumes level sensors")  # fmt: skip
    return Grade(GRADES[worst], tuple(reasons))

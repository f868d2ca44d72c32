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

Residuals alone cannot say how well the poses are determined: a calibration from few or
sparse sightings (a client too busy to detect the wand in most depth frames), or from sightings
whose times are off (a busy machine), can fit its own sightings well and still be millimetres
off. The **split-half check** measures that from the calibration's own sightings: the same
registration on two halves of them (alternate 1 s blocks of the wand phase,
:func:`split_halves`), each sensor's pose compared between the halves after the rigid
alignment that best maps one world onto the other (:func:`kinefuse.capture.calibration.compare.
pose_errors`). Each half has half the sightings, so the whole calibration's random error is
about half their disagreement; a disagreement above ``HALVES_DOUBTFUL_M`` (3 mm: the whole is
then uncertain by about 1.5 mm, where a good live calibration is 1.2-1.4 mm off the true rig)
is doubtful, above ``HALVES_FAILED_M`` failed; halves that cannot be registered at all
(too few shared sightings in one of them) leave the calibration unchecked: doubtful.
Thresholds from simulated sightings with fewer sightings, timing noise and late clocks
(``tests/test_calibration_grade.py``) and live runs beside a CPU hog
(``benchmarks/bench_live.py --load``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kinefuse.capture.calibration.floor import FloorPlane
from kinefuse.capture.calibration.register import Registration, Sightings

#: Per-sensor RMS residual above which a calibration is doubtful / failed, metres.
RESIDUAL_DOUBTFUL_M = 0.010
RESIDUAL_FAILED_M = 0.030
#: Sightings below which the full registration of a sensor is doubtful / failed.
SIGHTINGS_DOUBTFUL = 30
SIGHTINGS_FAILED = 6
#: Split-half disagreement of a sensor's pose above which a calibration is doubtful / failed, m.
HALVES_DOUBTFUL_M = 0.003
HALVES_FAILED_M = 0.020
#: Length of the alternating time blocks the split-half check deals sightings into, seconds.
HALVES_BLOCK_S = 1.0
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


@dataclass(frozen=True)
class HalvesCheck:
    """The split-half check's outcome: per sensor, how far its pose moved between the two
    halves (m, after aligning their worlds), or why the halves could not be registered."""

    disagreement_m: dict[str, float]
    unchecked: str | None = None

    def to_dict(self) -> dict[str, object]:
        return {
            "disagreement_m": {k: float(v) for k, v in self.disagreement_m.items()},
            "unchecked": self.unchecked,
        }


def split_halves(
    sightings: Sightings, t0_s: float, block_s: float = HALVES_BLOCK_S
) -> tuple[Sightings, Sightings]:
    """A sensor's sightings dealt into two halves by alternate ``block_s`` blocks from ``t0_s``
    (server clock), so that each half spans the whole wand phase."""
    k = np.floor((sightings.t_server_s - t0_s) / block_s).astype(np.int64) % 2 == 0
    q = sightings.quality if len(sightings.quality) else np.ones(len(sightings))
    return (
        Sightings(sightings.t_server_s[k], sightings.centre_sensor_m[k], q[k]),
        Sightings(sightings.t_server_s[~k], sightings.centre_sensor_m[~k], q[~k]),
    )


def halves_disagreement(
    a: Registration, b: Registration, *, align_worlds: bool
) -> dict[str, float]:
    """Each sensor's position difference between two registrations of the same sensors (m):
    after the rigid alignment of ``b``'s world onto ``a``'s (``align_worlds``; the worlds of two
    free registrations differ by where their wand origin fell), or as they are (both registered
    against the same fixed sensors)."""
    from kinefuse.capture.calibration.compare import pose_errors

    ids = [s for s in a.sensor_ids if s in b.sensor_ids]
    pa = np.stack([a.sensor2world[a.sensor_ids.index(s)] for s in ids])
    pb = np.stack([b.sensor2world[b.sensor_ids.index(s)] for s in ids])
    pe = pose_errors(pb, pa, align="rigid" if align_worlds else "none")
    return {s: float(pe.position_error_m[k]) for k, s in enumerate(ids)}


def grade_calibration(
    reg: Registration,
    floors: dict[str, FloorPlane] | None = None,
    halves: HalvesCheck | None = None,
) -> Grade:
    """Grade a registration from its residuals, sightings, (paper's method) sensor tilts and,
    when given, the split-half check of its sightings (:class:`HalvesCheck`)."""
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
    if halves is not None:
        if halves.unchecked is not None:
            flag(1, f"the poses could not be checked on two halves of the sightings "
                 f"({halves.unchecked}): too few sightings to trust")  # fmt: skip
        for sid, d in halves.disagreement_m.items():
            if not np.isfinite(d) or d > HALVES_FAILED_M:
                flag(2, f"sensor {sid}: its pose moves {1e3 * d:.0f} mm between two halves of "
                     f"its sightings (over {1e3 * HALVES_FAILED_M:.0f} mm): the sightings do not "
                     "determine it (too few, or their times are off: a busy machine?)")  # fmt: skip
            elif d > HALVES_DOUBTFUL_M:
                flag(1, f"sensor {sid}: its pose moves {1e3 * d:.1f} mm between two halves of "
                     f"its sightings (over {1e3 * HALVES_DOUBTFUL_M:.0f} mm): worse than its "
                     "residual says (too few sightings, or their times are off: a busy "
                     "machine?)")  # fmt: skip
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

"""Implausible poses (the paper's third application): flags from what the calibration taught.

A limb's pose in a frame is flagged when

- an angle about a learned axis leaves the range seen in the calibration phase by more than
  ``margin_deg`` (the calibration moves every joint through its range, so a pose far beyond it
  is more likely a tracking error than a movement),
- the limb leaves the plane(s) of its learned axes: its off-axis angle (see
  :func:`kinefuse.biomech.parameterize.swing_angles`) is more than ``off_axis_sd`` robust
  standard deviations from the calibration's, and more than ``off_axis_min_deg``,
- its length differs from the model's by more than ``length_tolerance`` (a fused skeleton whose
  bone stretches is wrong, whatever the angles say).

The thresholds are defaults of ours, not fitted to any data.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.biomech.kinematics import Angles
from kinefuse.biomech.limbs import LIMB_INDEX, LIMB_NAMES, LIMBS
from kinefuse.biomech.parameterize import AxisModel
from kinefuse.core.skeleton import N_JOINTS

#: Reason bits of :attr:`Plausibility.reasons`.
RANGE, OFF_AXIS, LENGTH = 1, 2, 4


@dataclass(frozen=True, eq=False)
class Plausibility:
    """Per frame and limb: ``flags (T, L) bool`` and ``reasons (T, L) uint8`` (bits
    :data:`RANGE`, :data:`OFF_AXIS`, :data:`LENGTH`), limbs in :data:`LIMB_NAMES` order."""

    flags: NDArray[np.bool_]
    reasons: NDArray[np.uint8]

    def joint_flags(self) -> NDArray[np.bool_]:
        """Flags ``(T, 25)`` on the Kinect joints: a limb's flag marks its distal joint."""
        out = np.zeros((self.flags.shape[0], N_JOINTS), dtype=bool)
        for i, lb in enumerate(LIMBS):
            out[:, lb.distal_index] |= self.flags[:, i]
        return out

    def summary(self) -> dict[str, float]:
        """Fraction of flagged frames per limb."""
        return {n: float(self.flags[:, i].mean()) for i, n in enumerate(LIMB_NAMES)}


def plausibility(
    angles: Angles,
    model: AxisModel,
    /,
    *,
    margin_deg: float = 15.0,
    off_axis_sd: float = 4.0,
    off_axis_min_deg: float = 10.0,
    length_tolerance: float = 0.15,
) -> Plausibility:
    """Flag implausible frames per limb (see the module docstring for the three tests)."""
    t = angles.t_s.shape[0]
    reasons = np.zeros((t, len(LIMBS)), dtype=np.uint8)
    margin = np.radians(margin_deg)
    for name, lm in model.limbs.items():
        i = LIMB_INDEX[name]
        if not lm.usable or name not in angles.angles:
            continue
        a = angles.angles[name]
        lo, hi = lm.ranges_rad[:, 0] - margin, lm.ranges_rad[:, 1] + margin
        with np.errstate(invalid="ignore"):
            out = ((a < lo) | (a > hi)).any(axis=1)
            off = np.abs(angles.off_axis[name])
            thr = max(off_axis_sd * lm.off_axis_sd_rad, np.radians(off_axis_min_deg))
            off_bad = off > thr
            length = angles.length_m[name]
            len_bad = np.abs(length - lm.length_m) > length_tolerance * lm.length_m
        reasons[:, i] |= np.where(out, RANGE, 0).astype(np.uint8)
        reasons[:, i] |= np.where(off_bad, OFF_AXIS, 0).astype(np.uint8)
        reasons[:, i] |= np.where(len_bad, LENGTH, 0).astype(np.uint8)
    return Plausibility(flags=reasons > 0, reasons=reasons)


# ------------------------------------------------------------------ angle status

#: Physiological range of each anatomical angle, degrees (ISB signs of
#: :data:`kinefuse.biomech.anatomical.ANATOMICAL_ANGLES`), from the normal active ranges of
#: motion of the American Academy of Orthopaedic Surgeons (Greene & Heckman 1994, *The Clinical
#: Measurement of Joint Motion*; the trunk's from its thoracolumbar values; pronation from full
#: supination, ISB's zero), each widened by :data:`RANGE_MARGIN_DEG` when checked (soft
#: tissue, marker placement). Not from those tables, and ours: knee flexion to 150 (AAOS's 135
#: is active flexion; a deep squat goes further), knee adduction ±20 and elbow adduction
#: -30..20 (a joint's varus-valgus play is a few degrees, the elbow's carrying angle 10-15 deg
#: of valgus; beyond these it is an axis misread). Angles relative to the lab (the pelvis's,
#: the thorax's of a capture without a pelvis) have no physiological range.
ANGLE_RANGES_DEG: dict[str, tuple[float, float]] = {
    "trunk_extension": (-80.0, 30.0),
    "trunk_lateral_bend": (-35.0, 35.0),
    "trunk_rotation": (-45.0, 45.0),
    "hip_flexion": (-30.0, 120.0),
    "hip_adduction": (-45.0, 30.0),
    "hip_internal_rotation": (-45.0, 45.0),
    "knee_flexion": (-10.0, 150.0),
    "knee_adduction": (-20.0, 20.0),
    "knee_internal_rotation": (-45.0, 45.0),
    "ankle_dorsiflexion": (-50.0, 20.0),
    "ankle_inversion": (-20.0, 35.0),
    "shoulder_flexion": (-60.0, 180.0),
    "shoulder_adduction": (-180.0, 45.0),
    "shoulder_internal_rotation": (-90.0, 70.0),
    "shoulder_elevation": (0.0, 180.0),
    "shoulder_axial_rotation": (-90.0, 70.0),
    "elbow_flexion": (-10.0, 150.0),
    "elbow_adduction": (-30.0, 20.0),
    "forearm_pronation": (-20.0, 180.0),
}
#: Degrees an angle may exceed its range by before a frame counts as outside it.
RANGE_MARGIN_DEG = 10.0
#: An angle outside its range on more than this fraction of its frames is implausible.
MAX_OUT_OF_RANGE_FRACTION = 0.05
#: Fastest a joint turns, degrees per second: elbow extension in baseball pitching reaches about
#: 2300 deg/s and shoulder internal rotation about 7000 deg/s (Fleisig et al. 1995, Am J Sports
#: Med 23(2)); rotations about a long axis get the second, every other angle the first, both
#: rounded up.
MAX_SPEED_DEG_S = 2500.0
MAX_AXIAL_SPEED_DEG_S = 7500.0


def _range_of(name: str) -> tuple[float, float] | None:
    base = name.removesuffix("_left").removesuffix("_right")
    return ANGLE_RANGES_DEG.get(base)


def angle_status(name: str, t_s: NDArray[np.float64], deg: NDArray[np.float64]) -> list[str]:
    """Why an angle curve is implausible (an empty list: plausible).

    Three tests, on the frames where the angle is present: it wraps (two consecutive frames
    differ by more than 180 deg: the curve went through ±180, which no joint does); it jumps
    faster than a body moves (:data:`MAX_SPEED_DEG_S`, :data:`MAX_AXIAL_SPEED_DEG_S` for
    rotations about a long axis); it is outside :data:`ANGLE_RANGES_DEG` (plus
    :data:`RANGE_MARGIN_DEG`) on more than :data:`MAX_OUT_OF_RANGE_FRACTION` of its frames.
    Angles relative to the lab (``pelvis_*``, ``thorax_*``) and the shoulder's plane of
    elevation (undefined with the arm down) are only tested for jumps.
    """
    v = np.asarray(deg, dtype=np.float64)
    t = np.asarray(t_s, dtype=np.float64)
    ok = np.isfinite(v)
    reasons: list[str] = []
    if ok.sum() < 2:
        return reasons
    k = np.flatnonzero(ok)
    step = np.abs(np.diff(v[k]))
    dt = np.diff(t[k])
    free = name.startswith(("pelvis_", "thorax_")) or "_plane" in name
    consecutive = np.diff(k) == 1
    wraps = (step > 180.0) & consecutive
    if wraps.any() and not free:
        reasons.append(f"wraps through ±180 deg on {int(wraps.sum())} frame(s)")
    axial = "rotation" in name
    limit = MAX_AXIAL_SPEED_DEG_S if axial else MAX_SPEED_DEG_S
    with np.errstate(divide="ignore", invalid="ignore"):
        speed = np.where(dt > 0, step / dt, np.inf)
    jumps = (speed > limit) & consecutive & ~wraps
    if jumps.any():
        reasons.append(
            f"jumps faster than a body moves on {int(jumps.sum())} frame(s) (up to "
            f"{float(np.max(speed[jumps])):.0f} deg/s; at most {limit:.0f} deg/s)"
        )
    rng = None if free else _range_of(name)
    if rng is not None:
        lo, hi = rng
        out = (v[k] < lo - RANGE_MARGIN_DEG) | (v[k] > hi + RANGE_MARGIN_DEG)
        if out.mean() > MAX_OUT_OF_RANGE_FRACTION:
            reasons.append(
                f"outside its range {lo:g}..{hi:g} deg on {100 * out.mean():.0f} % of the frames "
                f"(it runs {float(np.min(v[k])):.0f}..{float(np.max(v[k])):.0f} deg)"
            )
    return reasons


def angle_statuses(
    t_s: NDArray[np.float64], angles_deg: dict[str, NDArray[np.float64]]
) -> dict[str, dict[str, Any]]:
    """:func:`angle_status` of every angle: ``{"status": "ok" | "implausible", "reasons":
    [...]}`` (``"no data"`` for an angle without a value)."""
    out: dict[str, dict[str, Any]] = {}
    for name, v in angles_deg.items():
        if not np.isfinite(v).any():
            out[name] = {"status": "no data", "reasons": []}
            continue
        why = angle_status(name, t_s, v)
        out[name] = {"status": "implausible" if why else "ok", "reasons": why}
    return out

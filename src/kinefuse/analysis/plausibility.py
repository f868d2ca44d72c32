"""Implausible poses (the paper's third application): flags from what the calibration taught.

A limb's pose in a frame is flagged when

- an angle about a learned axis leaves the range seen in the calibration phase by more than
  ``margin_deg`` (the calibration moves every joint through its range, so a pose far beyond it
  is more likely a tracking error than a movement),
- the limb leaves the plane(s) of its learned axes: its off-axis angle (see
  :func:`kinefuse.analysis.parameterize.swing_angles`) is more than ``off_axis_sd`` robust
  standard deviations from the calibration's, and more than ``off_axis_min_deg``,
- its length differs from the model's by more than ``length_tolerance`` (a fused skeleton whose
  bone stretches is wrong, whatever the angles say).

The thresholds are defaults of ours, not fitted to any data.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from kinefuse.analysis.kinematics import Angles
from kinefuse.analysis.limbs import LIMB_INDEX, LIMB_NAMES, LIMBS
from kinefuse.analysis.parameterize import AxisModel
from kinefuse.skeleton import N_JOINTS

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

"""Switches and tuning of the fusion (:class:`BestOptions`), shared by ``best`` and ``best-live``.

The measurement noise and process noise per joint are prior knowledge of the device (see the
comments), not fitted to any truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.skeleton import JOINT_INDEX, N_JOINTS

Array = NDArray[np.float64]

#: Base measurement noise of a tracked joint, metres: lateral (across the ray) and axial (along
#: it). Extremities are noisier (Wang et al. 2015, Otte et al. 2016: hands, wrists, ankles and feet
#: have the largest errors). These are prior knowledge of the device, not fitted to any truth.
_LATERAL_M = np.full(N_JOINTS, 0.015)
_AXIAL_M = np.full(N_JOINTS, 0.025)
for _name, _f in {
    "WristLeft": 1.6,
    "WristRight": 1.6,
    "HandLeft": 1.8,
    "HandRight": 1.8,
    "HandTipLeft": 2.2,
    "HandTipRight": 2.2,
    "ThumbLeft": 2.2,
    "ThumbRight": 2.2,
    "AnkleLeft": 1.8,
    "AnkleRight": 1.8,
    "FootLeft": 2.0,
    "FootRight": 2.0,
    "ElbowLeft": 1.3,
    "ElbowRight": 1.3,
    "KneeLeft": 1.3,
    "KneeRight": 1.3,
    "Head": 1.2,
}.items():
    _LATERAL_M[JOINT_INDEX[_name]] *= _f
    _AXIAL_M[JOINT_INDEX[_name]] *= _f

#: Process noise (white acceleration spectral density, m^2/s^3) of the constant-velocity model:
#: limbs accelerate harder than the trunk.
_ACCEL_PSD = np.full(N_JOINTS, 4.0)
for _name, _q in {
    "WristLeft": 40.0,
    "WristRight": 40.0,
    "HandLeft": 60.0,
    "HandRight": 60.0,
    "HandTipLeft": 80.0,
    "HandTipRight": 80.0,
    "ThumbLeft": 80.0,
    "ThumbRight": 80.0,
    "ElbowLeft": 15.0,
    "ElbowRight": 15.0,
    "AnkleLeft": 40.0,
    "AnkleRight": 40.0,
    "FootLeft": 60.0,
    "FootRight": 60.0,
    "KneeLeft": 15.0,
    "KneeRight": 15.0,
}.items():
    _ACCEL_PSD[JOINT_INDEX[_name]] = _q


@dataclass(frozen=True)
class BestOptions:
    """Switches and tuning of the fusion (see the module docstring)."""

    timestamp: bool = True
    covariance: bool = True
    robust: bool = True
    lr_swap: bool = True
    temporal: str | None = "smoother"
    bones: bool = True
    inferred_inflation: float = 4.0
    occluded_inflation: float = 2.0
    gate_chi2: float = 11.34  # chi-square, 3 dof, 99 %
    #: correlation of one sensor's errors at two neighbouring joints of a limb (rho^k for k
    #: bones apart; :data:`kinefuse.capture.fusion.model.LIMBS`), 0: joints combined one by one
    #: (docs/fusion.md section 13)
    limb_correlation: float = 0.5
    max_interp_gap_s: float = 0.1
    max_predict_s: float = 0.5
    #: per joint (25 values): lateral and axial measurement noise (m), process noise (m^2/s^3);
    #: tuples, so that options compare and hash (they key caches and the ablation table)
    lateral_m: tuple[float, ...] = tuple(_LATERAL_M.tolist())
    axial_m: tuple[float, ...] = tuple(_AXIAL_M.tolist())
    accel_psd: tuple[float, ...] = tuple(_ACCEL_PSD.tolist())
    #: view-dependent measurement noise (:mod:`kinefuse.capture.fusion.view_noise`): standard
    #: deviation (m) added to the trunk, head, shoulders and hips of a sensor that sees the body
    #: deviation (#: straight from
    #: the side, growing as ``|sin view|^view_exponent`` (1); and (m) added to a limb joint on
    #: the far side of the body seen from the side, growing as ``far^far_exponent`` (1). 0 m:
    #: off. Chosen on one simulated take (docs/fusion.md section 9)
    view_sigma_m: float = 0.1
    view_exponent: float = 4.0
    far_sigma_m: float = 0.05
    far_exponent: float = 4.0

    def __post_init__(self) -> None:
        if self.temporal not in (None, "smoother", "filter"):
            raise ValueError(
                f"temporal must be None, 'smoother' or 'filter', got {self.temporal!r}"
            )
        for name in ("lateral_m", "axial_m", "accel_psd"):
            v = tuple(float(x) for x in np.asarray(getattr(self, name), dtype=float).ravel())
            if len(v) != N_JOINTS or not all(x > 0 for x in v):
                raise ValueError(f"{name} must be {N_JOINTS} positive numbers, one per joint")
            object.__setattr__(self, name, v)
        if not (self.view_sigma_m >= 0 and self.far_sigma_m >= 0):
            raise ValueError("view_sigma_m and far_sigma_m must be >= 0 m (0: off)")
        if not 0.0 <= self.limb_correlation < 1.0:
            raise ValueError(f"limb_correlation must be in [0, 1), got {self.limb_correlation}")
        if not (self.view_exponent > 0 and self.far_exponent > 0):
            raise ValueError("view_exponent and far_exponent must be > 0")

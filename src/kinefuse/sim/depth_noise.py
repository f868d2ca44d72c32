"""The Kinect v2 time-of-flight error model of the simulated depth camera
(:class:`DepthNoiseParams`, every value with its unit, source and kind), and its axial noise
and systematic offset.

Split out of :mod:`kinefuse.sim.depth` (which re-exports it): the parameters, not the
renderer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.errors import InputError

Array = NDArray[np.float64]


_MEAS = "measurement"
_ASSUME = "assumption"
_FANKHAUSER = (
    "Fankhauser, Bloesch, Rodriguez, Kaestner, Hutter, Siegwart: Kinect v2 for mobile robot "
    "navigation: evaluation and modeling, ICAR 2015, axial noise model"
)


def _meta(unit: str, kind: str, source: str) -> dict[str, str]:
    return {"unit": unit, "kind": kind, "source": source}


@dataclass(frozen=True)
class DepthNoiseParams:
    """Every parameter of the Kinect v2 depth error model, with its unit and source.

    Each field's ``metadata`` holds ``unit``, ``kind`` (``"measurement"``: a published figure;
    ``"assumption"``: our choice, with what informed it) and ``source``.
    ``docs/error_model_depth.md`` discusses them one by one. Setting a magnitude to 0 switches
    that error off.
    """

    # axial noise sigma_z(z, theta) = c0 + c1 z + c2 z^2 + ca z^1.5 theta^2 / (pi/2 - theta)^2
    axial_c0_mm: float = field(default=1.5, metadata=_meta("mm", _MEAS, _FANKHAUSER))
    axial_c1_mm_per_m: float = field(default=-0.5, metadata=_meta("mm/m", _MEAS, _FANKHAUSER))
    axial_c2_mm_per_m2: float = field(default=0.3, metadata=_meta("mm/m^2", _MEAS, _FANKHAUSER))
    # incidence-angle term of the same model
    axial_angle_mm_per_m1_5: float = field(
        default=0.1, metadata=_meta("mm/m^1.5", _MEAS, _FANKHAUSER)
    )
    # lateral noise: Gaussian sub-pixel jitter of each pixel's ray (clipped at 3 sigma)
    lateral_sigma_px: float = field(
        default=0.5,
        metadata=_meta(
            "px",
            _ASSUME,
            "Fankhauser et al. 2015 model the Kinect v2 noise in axial and lateral directions; "
            "their lateral figure is not reproduced here. Nguyen, Izadi, Lovell (3DIMPVT 2012) "
            "give 0.8 px for the structured-light Kinect v1; 0.5 px (sub-pixel) is our choice",
        ),
    )
    # systematic range offset: b0 + b1 (r - 1 m) + A sin(2 pi r / P + phi)   (measured - true)
    offset_at_1m_mm: float = field(
        default=2.0,
        metadata=_meta(
            "mm",
            _ASSUME,
            "Lachat et al. 2015 (Remote Sens. 7:13070) and Corti et al. 2016 (Robot. Auton. "
            "Syst.) measure a distance-dependent systematic error of the Kinect v2; its form "
            "(trend plus wiggling) follows them, the magnitudes (mm) are chosen, not read off "
            "their figures",
        ),
    )
    offset_slope_mm_per_m: float = field(
        default=2.5,
        metadata=_meta(
            "mm/m", _ASSUME, "as offset_at_1m_mm: the error grows with distance; slope chosen"
        ),
    )
    wiggle_amplitude_mm: float = field(
        default=2.0,
        metadata=_meta(
            "mm",
            _ASSUME,
            "Corti et al. 2016: the Kinect v2 systematic error follows a harmonic trend "
            "('wiggling'); amplitude of a few mm chosen",
        ),
    )
    wiggle_period_m: float = field(
        default=0.47,
        metadata=_meta(
            "m",
            _ASSUME,
            "a quarter of the 1.87 m unambiguous range of the 80 MHz modulation (4-phase "
            "sampling aliases odd harmonics into an error with 4 periods per ambiguity range)",
        ),
    )
    wiggle_phase_rad: float = field(default=0.0, metadata=_meta("rad", _ASSUME, "arbitrary"))
    # flying pixels at depth discontinuities
    flying_jump_m: float = field(
        default=0.10,
        metadata=_meta(
            "m",
            _ASSUME,
            "a jump between 4-neighbours larger than this is a silhouette (larger than the "
            "step between neighbours on a floor seen up to about 75 deg)",
        ),
    )
    flying_prob: float = field(
        default=0.5,
        metadata=_meta(
            "1",
            _ASSUME,
            "Wasenmueller & Stricker 2016 (ACCV workshops) and Sarbolandi et al. 2015 (CVIU) "
            "show Kinect v2 flying pixels at depth edges; the fraction is chosen",
        ),
    )
    flying_max_fraction: float = field(
        default=0.5,
        metadata=_meta(
            "1",
            _ASSUME,
            "a pixel whose centre lies on one side covers at least half of its own side "
            "(straight edge): it moves a uniform fraction in [0, this] toward the other depth",
        ),
    )
    edge_invalid_prob: float = field(
        default=0.2,
        metadata=_meta(
            "1",
            _ASSUME,
            "fraction of silhouette pixels with no reading (the SDK filters part of the "
            "flying pixels out)",
        ),
    )
    # multipath in concave floor-wall corners: extra range max * (1 - d / extent)
    multipath_max_mm: float = field(
        default=10.0,
        metadata=_meta(
            "mm",
            _ASSUME,
            "Corti et al. 2016: multiple reflections distort concave geometry; Wasenmueller & "
            "Stricker 2016 and Sarbolandi et al. 2015 show multipath interference; a concave "
            "corner reads too far (extra light path); magnitude chosen",
        ),
    )
    multipath_extent_m: float = field(
        default=0.30,
        metadata=_meta("m", _ASSUME, "distance from the corner over which multipath fades"),
    )
    # invalid pixels at grazing incidence: dropout rises linearly from soft to max
    grazing_soft_deg: float = field(
        default=70.0,
        metadata=_meta(
            "deg",
            _ASSUME,
            "a diffuse surface returns power proportional to cos(incidence), so readings thin "
            "out toward grazing incidence; onset chosen",
        ),
    )
    grazing_max_deg: float = field(
        default=82.0,
        metadata=_meta(
            "deg",
            _ASSUME,
            "above this incidence angle no reading (also where the axial model above diverges)",
        ),
    )

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                raise InputError(f"DepthNoiseParams.{f.name} must be a finite number, got {v!r}")
        nonneg = (
            "lateral_sigma_px",
            "wiggle_amplitude_mm",
            "flying_jump_m",
            "multipath_max_mm",
            "axial_angle_mm_per_m1_5",
        )
        for name in nonneg:
            if getattr(self, name) < 0:
                raise InputError(
                    f"DepthNoiseParams.{name} must be >= 0, got {getattr(self, name)!r}"
                )
        for name in ("flying_prob", "flying_max_fraction", "edge_invalid_prob"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise InputError(f"DepthNoiseParams.{name} is a probability in [0, 1], got {v!r}")
        if self.flying_prob + self.edge_invalid_prob > 1.0:
            raise InputError(
                "DepthNoiseParams: flying_prob + edge_invalid_prob must not exceed 1, got "
                f"{self.flying_prob} + {self.edge_invalid_prob}"
            )
        if self.wiggle_period_m <= 0 or self.multipath_extent_m <= 0:
            raise InputError(
                "DepthNoiseParams: wiggle_period_m and multipath_extent_m must be > 0, got "
                f"{self.wiggle_period_m} and {self.multipath_extent_m}"
            )
        if not 0.0 < self.grazing_soft_deg <= self.grazing_max_deg < 90.0:
            raise InputError(
                "DepthNoiseParams: need 0 < grazing_soft_deg <= grazing_max_deg < 90, got "
                f"{self.grazing_soft_deg} and {self.grazing_max_deg}"
            )
        if self.lateral_sigma_px > 5.0:
            raise InputError(
                f"DepthNoiseParams.lateral_sigma_px must be at most 5 px, got "
                f"{self.lateral_sigma_px}; the lateral noise is a sub-pixel jitter"
            )
        z = np.linspace(0.0, 10.0, 101)
        if np.any(
            self.axial_c0_mm + self.axial_c1_mm_per_m * z + self.axial_c2_mm_per_m2 * z**2 < 0
        ):
            raise InputError(
                "DepthNoiseParams: the axial noise c0 + c1 z + c2 z^2 must be >= 0 for z in "
                f"0..10 m, got c0={self.axial_c0_mm}, c1={self.axial_c1_mm_per_m}, "
                f"c2={self.axial_c2_mm_per_m2}"
            )


#: The default error model (an immutable instance, safe as a default argument).
DEFAULT_DEPTH_NOISE = DepthNoiseParams()


def axial_sigma_m(
    z_m: ArrayLike, theta_rad: ArrayLike, params: DepthNoiseParams = DEFAULT_DEPTH_NOISE
) -> Array:
    """Standard deviation of the axial noise (Fankhauser et al. 2015), metres.

    ``sigma_z = c0 + c1 z + c2 z^2 + ca z^1.5 theta^2 / (pi/2 - theta)^2`` in mm with ``z`` in m.

    Parameters
    ----------
    z_m : (...) float
        Depth, metres.
    theta_rad : (...) float
        Incidence angle between the ray and the surface normal, radians, in ``[0, pi/2)``.
    params : DepthNoiseParams

    Returns
    -------
    sigma_m : (...) float
        Standard deviation, metres (inf at ``theta = pi/2``).
    """
    z = np.asarray(z_m, dtype=np.float64)
    th = np.asarray(theta_rad, dtype=np.float64)
    p = params
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = th / (0.5 * np.pi - th)
    s_mm = p.axial_c0_mm + z * (p.axial_c1_mm_per_m + p.axial_c2_mm_per_m2 * z)
    if p.axial_angle_mm_per_m1_5 != 0.0:
        s_mm = s_mm + p.axial_angle_mm_per_m1_5 * (z * np.sqrt(np.maximum(z, 0.0))) * (
            ratio * ratio
        )
    return np.asarray(s_mm * 1e-3, dtype=np.float64)


def systematic_offset_m(
    range_m: ArrayLike, params: DepthNoiseParams = DEFAULT_DEPTH_NOISE
) -> Array:
    """Systematic range error (measured minus true) at a true range, metres.

    ``b0 + b1 (r - 1 m) + A sin(2 pi r / P + phi)`` with the values of ``params`` (in mm).

    Parameters
    ----------
    range_m : (...) float
        True distance along the ray, metres.

    Returns
    -------
    offset_m : (...) float
    """
    r = np.asarray(range_m, dtype=np.float64)
    p = params
    mm = p.offset_at_1m_mm + p.offset_slope_mm_per_m * (r - 1.0)
    if p.wiggle_amplitude_mm != 0.0:
        # single-precision sine: rounding the argument (< 4e-6 rad at 5 m) moves it < 0.01 um
        arg = (r * (2.0 * np.pi / p.wiggle_period_m) + p.wiggle_phase_rad).astype(np.float32)
        mm = mm + p.wiggle_amplitude_mm * np.sin(arg).astype(np.float64)
    return np.asarray(mm * 1e-3, dtype=np.float64)

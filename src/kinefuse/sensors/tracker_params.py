"""The parameters of the Kinect v2 body-tracker error model (:mod:`kinefuse.sensors.tracker`).

Every number of the model lives in :class:`TrackerParams` with its unit, kind and source;
``docs/error_model_tracker.md`` explains them and ``docs/realism.md`` says what was fitted to
which real take.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any, Final

import numpy as np

from kinefuse.errors import InputError
from kinefuse.skeleton import JOINT_INDEX, JOINTS, N_JOINTS

#: Joint groups used to write the per-joint parameters compactly.
JOINT_GROUPS: Final[dict[str, tuple[str, ...]]] = {
    "trunk": ("SpineBase", "SpineMid", "SpineShoulder", "Neck"),
    "head": ("Head",),
    "shoulder": ("ShoulderLeft", "ShoulderRight"),
    "elbow": ("ElbowLeft", "ElbowRight"),
    "wrist": ("WristLeft", "WristRight"),
    "hand": ("HandLeft", "HandRight"),
    "handtip": ("HandTipLeft", "HandTipRight"),
    "thumb": ("ThumbLeft", "ThumbRight"),
    "hip": ("HipLeft", "HipRight"),
    "knee": ("KneeLeft", "KneeRight"),
    "ankle": ("AnkleLeft", "AnkleRight"),
    "foot": ("FootLeft", "FootRight"),
}


def per_joint(values: Mapping[str, float]) -> tuple[float, ...]:
    """A 25-tuple in ``JOINTS`` order from values per group of :data:`JOINT_GROUPS`.

    Keys may also be joint names, which override their group's value.
    """
    out: dict[str, float] = {}
    for key in values:
        if key not in JOINT_GROUPS and key not in JOINT_INDEX:
            raise InputError(
                f"unknown joint group or joint {key!r}; groups are {', '.join(JOINT_GROUPS)} "
                "(or use a Kinect v2 joint name)"
            )
    for group, names in JOINT_GROUPS.items():
        if group in values:
            for n in names:
                out[n] = float(values[group])
    for key, v in values.items():
        if key in JOINT_INDEX:
            out[key] = float(v)
    missing = [n for n in JOINTS if n not in out]
    if missing:
        raise InputError(f"per-joint values lack {', '.join(missing)}; give every group")
    return tuple(out[n] for n in JOINTS)


def _bias_mean() -> tuple[tuple[float, float, float], ...]:
    # (right, forward, up) in metres, in the body frame; left joints mirror the right ones.
    right = {
        "Hip": (0.03, 0.0, 0.05),  # hip centres higher and wider than the mocap's
        "Shoulder": (-0.01, 0.0, -0.02),
        "Ankle": (0.0, 0.01, 0.03),  # ankle placed higher, on the front of the joint
        "Foot": (0.0, -0.02, 0.02),
    }
    centre = {"SpineBase": (0.0, 0.0, 0.04), "Head": (0.0, 0.0, 0.02)}
    out = []
    for n in JOINTS:
        v = (0.0, 0.0, 0.0)
        if n in centre:
            v = centre[n]
        for stem, (x, y, z) in right.items():
            if n == stem + "Right":
                v = (x, y, z)
            elif n == stem + "Left":
                v = (-x, y, z)
        out.append(v)
    return tuple(out)


def _meta(unit: str, kind: str, source: str) -> dict[str, str]:
    return {"unit": unit, "kind": kind, "source": source}


_WANG = "Wang et al. 2015 (Kinect v2 vs optical mocap: most joints 5-10 cm, feet/ankles worst)"
_KMT = "KinectMultiTrack real two-Kinect recording (../shared/data/kinect/kinect_multitrack)"
_WALKER = "kinect2-tracking walker.json (real Kinect v2 walk with tracking states)"


@dataclass(frozen=True)
class TrackerParams:
    """Every parameter of the Kinect v2 body-tracker error model.

    Each field's ``metadata`` has ``unit``, ``kind`` (``literature``: a published figure;
    ``measurement``: measured by us on real recordings shipped in ``../shared/data``;
    ``tuned``: fitted so the simulated two-sensor disagreement matches the real one, see
    ``docs/realism.md``; ``assumption``: a stated guess) and ``source``. Per-joint values are
    25-tuples in :data:`kinefuse.skeleton.JOINTS` order (build them with :func:`per_joint`).
    """

    # (a) subject-level bias ---------------------------------------------------------------
    subject_bias_mean_m: tuple[tuple[float, float, float], ...] = field(
        default_factory=_bias_mean,
        metadata=_meta(
            "m (body frame: right, forward, up)",
            "assumption",
            "direction of the known definition differences (hips higher and wider, spine base "
            "higher, ankles higher) after " + _WANG + " and Xu & McGorry 2015; sizes assumed",
        ),
    )
    subject_bias_sigma_m: tuple[float, ...] = field(
        default_factory=lambda: per_joint(
            {
                "trunk": 0.022,
                "head": 0.025,
                "shoulder": 0.025,
                "elbow": 0.027,
                "wrist": 0.03,
                "hand": 0.035,
                "handtip": 0.04,
                "thumb": 0.04,
                "hip": 0.022,
                "knee": 0.027,
                "ankle": 0.04,
                "foot": 0.05,
            }
        ),
        metadata=_meta(
            "m per axis",
            "literature",
            "spread of the per-subject joint offsets, per axis, chosen so that single-sensor "
            "errors are 3-8 cm for trunk and arms and worst for feet/ankles, as in " + _WANG,
        ),
    )
    # (a) view-dependent bias --------------------------------------------------------------
    surface_pushback_m: float = field(
        default=0.039,
        metadata=_meta(
            "m",
            "literature",
            "Shotton et al. 2011 (CVPR), Sec. 3.3: body-part modes lie on the surface and are "
            "pushed back into the scene by a learned offset zeta = 0.039 m",
        ),
    )
    surface_depth_gain: float = field(
        default=0.55,
        metadata=_meta(
            "1",
            "tuned",
            "share of the joint's depth below the visible surface (ray cast against the capsule "
            "body) that the tracker leaves in its estimate before the push-back; chosen so the "
            "simulated 45-degree layout disagrees more than the parallel one as the real logs "
            "do (median ratio 1.35 real, 1.32 simulated), " + _KMT,
        ),
    )
    pose_bias_sigma_m: tuple[float, ...] = field(
        default_factory=lambda: per_joint(
            {
                "trunk": 0.006,
                "head": 0.009,
                "shoulder": 0.008,
                "elbow": 0.009,
                "wrist": 0.008,
                "hand": 0.007,
                "handtip": 0.008,
                "thumb": 0.03,
                "hip": 0.008,
                "knee": 0.012,
                "ankle": 0.008,
                "foot": 0.012,
            }
        ),
        metadata=_meta(
            "m per axis",
            "measurement",
            "per-sensor slowly varying offset: two co-located real sensors watching a person "
            "stand still disagree by 1-4 cm per joint (thumbs 9 cm), " + _KMT + " scenario 1",
        ),
    )
    pose_bias_tau_s: float = field(
        default=2.0,
        metadata=_meta(
            "s",
            "assumption",
            "correlation time of the pose-dependent offset (constant over a 1.5 s still stand "
            "in " + _KMT + ")",
        ),
    )
    # (b) jitter ---------------------------------------------------------------------------
    jitter_sigma_m: tuple[float, ...] = field(
        default_factory=lambda: per_joint(
            {
                "trunk": 0.0015,
                "head": 0.002,
                "shoulder": 0.002,
                "elbow": 0.002,
                "wrist": 0.002,
                "hand": 0.003,
                "handtip": 0.004,
                "thumb": 0.006,
                "hip": 0.0015,
                "knee": 0.002,
                "ankle": 0.002,
                "foot": 0.003,
            }
        ),
        metadata=_meta(
            "m per axis (lateral)",
            "measurement",
            "standard deviation of a still person's joints, 1-3 mm (4-8 mm hand tips and "
            "thumbs), " + _KMT + " scenario 1",
        ),
    )
    jitter_tau_s: float = field(
        default=0.15,
        metadata=_meta(
            "s",
            "measurement",
            "lag-1 autocorrelation 0.74-0.89 at 30 Hz of a still person's joints, " + _KMT,
        ),
    )
    depth_axis_factor: float = field(
        default=2.0,
        metadata=_meta(
            "1",
            "measurement",
            "jitter along the optical axis over lateral jitter, 2.2-3.2 for the front sensors "
            "of " + _KMT + " scenario 1",
        ),
    )
    motion_noise_gain_s: tuple[float, ...] = field(
        default_factory=lambda: per_joint(
            {
                "trunk": 0.01,
                "head": 0.015,
                "shoulder": 0.015,
                "elbow": 0.015,
                "wrist": 0.015,
                "hand": 0.015,
                "handtip": 0.02,
                "thumb": 0.025,
                "hip": 0.01,
                "knee": 0.015,
                "ankle": 0.012,
                "foot": 0.015,
            }
        ),
        metadata=_meta(
            "s (m of noise per m/s of the joint's speed relative to the pelvis, per axis)",
            "tuned",
            "noise grows with the joint's speed (the two real sensors disagree 1-6 cm per axis "
            "while walking, 1-3 mm standing, " + _KMT + "); chosen with pose_bias_sigma_m so "
            "the simulated parallel layout's median is within 15 % of the real one",
        ),
    )
    motion_noise_tau_s: float = field(
        default=0.1,
        metadata=_meta("s", "assumption", "correlation time of the speed-dependent noise"),
    )
    noise_reference_range_m: float = field(
        default=2.5,
        metadata=_meta("m", "assumption", "distance at which the noise sigmas hold"),
    )
    noise_range_exponent: float = field(
        default=1.0,
        metadata=_meta(
            "1",
            "assumption",
            "noise scales as (range / reference)^exponent; Kinect v2 depth noise grows with "
            "distance (Fankhauser et al. 2015), the skeleton inherits part of it",
        ),
    )
    # (c) states ---------------------------------------------------------------------------
    occlusion_margin_m: float = field(
        default=0.02,
        metadata=_meta(
            "m",
            "assumption",
            "a capsule hides a joint only if the ray meets it this far in front of the joint",
        ),
    )
    occlusion_sample_radius: float = field(
        default=1.0,
        metadata=_meta(
            "body radii",
            "assumption",
            "visibility is sampled by five rays, to the joint and to four points this many body "
            "radii around it. Checked against " + _WALKER + ": a simulated walk seen at the "
            "same angle (58 deg) infers arm joints 34 % of the time (real 29 %) but leg joints "
            "only 3 % (real 25 %): the real tracker also infers visible but ambiguous legs",
        ),
    )
    min_visible_fraction: float = field(
        default=0.6,
        metadata=_meta(
            "1",
            "assumption",
            "a joint is TRACKED when at least this share of its five rays reaches it",
        ),
    )
    never_inferred: tuple[str, ...] = field(
        default=("SpineBase", "SpineMid", "SpineShoulder", "Neck", "Head", "HipLeft", "HipRight"),
        metadata=_meta(
            "joint names",
            "measurement",
            "trunk, head and hips were TRACKED in 100 % of 330 frames of a real walk while limb "
            "joints were INFERRED 20-33 % of the time, " + _WALKER,
        ),
    )
    inferred_blend: float = field(
        default=0.7,
        metadata=_meta(
            "1",
            "assumption",
            "weight of the guessed pose (last pose seen, held in the body frame; else the "
            "mirrored twin as last seen; else a standing pose) in the position of an occluded "
            "INFERRED joint in view (one out of view is the guess alone)",
        ),
    )
    inferred_sigma_m: float = field(
        default=0.05,
        metadata=_meta(
            "m per axis",
            "assumption",
            "extra error of INFERRED joints; makes them at least twice as wrong as tracked "
            "ones (the tracker guesses occluded joints, paper A Sec. A.4)",
        ),
    )
    inferred_tau_s: float = field(
        default=0.5, metadata=_meta("s", "assumption", "correlation time of that extra error")
    )
    view_correlation_deg: float = field(
        default=30.0,
        metadata=_meta(
            "deg",
            "assumption",
            "the inferred-joint error and the swap decision are smooth random functions of time "
            "and of the viewing direction in the body frame, shared by every sensor of a "
            "session: sensors that see the body from directions this far apart make correlated "
            "mistakes (two co-located real sensors are mirrored together: the two real sensors "
            "of " + _KMT + " disagree on left/right in only 1-2 % of frames)",
        ),
    )
    min_joints_in_view: int = field(
        default=8,
        metadata=_meta(
            "joints",
            "assumption",
            "with fewer joints inside the view and range the body is lost (all NOT_TRACKED)",
        ),
    )
    out_of_view_inferred: bool = field(
        default=True,
        metadata=_meta(
            "flag",
            "literature",
            "joints of a tracked body outside the image or the depth range are reported INFERRED "
            'at a position guessed from the rest of the body alone, not dropped: "a tracked '
            "joint that cannot be seen by the camera is inferred, that is, the joint position "
            'is calculated from surrounding joint data rather than captured by the camera" '
            "(Kinect for Windows SDK 2.0, TrackingState enumeration); False drops them "
            "(NOT_TRACKED)",
        ),
    )
    # (d) left/right swaps -----------------------------------------------------------------
    swap_prob_max: float = field(
        default=0.9,
        metadata=_meta(
            "1",
            "assumption",
            "swap probability of a person seen from straight behind (the tracker assumes a "
            "frontal view, so a back view is mirrored most of the time)",
        ),
    )
    swap_angle_mid_deg: float = field(
        default=125.0,
        metadata=_meta(
            "deg",
            "assumption",
            "facing angle (body forward vs direction to the sensor) of half the maximum",
        ),
    )
    swap_angle_width_deg: float = field(
        default=12.0,
        metadata=_meta("deg", "assumption", "width of the logistic rise of the swap probability"),
    )
    swap_tau_s: float = field(
        default=1.0,
        metadata=_meta(
            "s",
            "assumption",
            "correlation time of the latent swap process: swaps persist over runs of frames",
        ),
    )
    # (e) dropouts -------------------------------------------------------------------------
    dropout_rate_hz: float = field(
        default=0.01,
        metadata=_meta("1/s", "assumption", "rate of whole-body tracking losses"),
    )
    dropout_mean_s: float = field(
        default=0.4,
        metadata=_meta("s", "assumption", "mean duration of a whole-body loss (exponential)"),
    )

    def __post_init__(self) -> None:
        for name in (
            "subject_bias_sigma_m",
            "pose_bias_sigma_m",
            "jitter_sigma_m",
            "motion_noise_gain_s",
        ):
            v = np.asarray(getattr(self, name), dtype=np.float64)
            if v.shape != (N_JOINTS,) or not np.all(np.isfinite(v)) or np.any(v < 0):
                raise InputError(
                    f"TrackerParams.{name} must be {N_JOINTS} non-negative numbers in JOINTS "
                    f"order, got shape {v.shape}; build it with per_joint({{group: value}})"
                )
        m = np.asarray(self.subject_bias_mean_m, dtype=np.float64)
        if m.shape != (N_JOINTS, 3) or not np.all(np.isfinite(m)):
            raise InputError(
                f"TrackerParams.subject_bias_mean_m must be {N_JOINTS} (right, forward, up) "
                f"triples in metres, got shape {m.shape}"
            )
        for name in ("swap_prob_max", "inferred_blend", "min_visible_fraction"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise InputError(f"TrackerParams.{name} must be in [0, 1], got {v}")
        for name in (
            "pose_bias_tau_s",
            "jitter_tau_s",
            "motion_noise_tau_s",
            "inferred_tau_s",
            "swap_tau_s",
            "dropout_mean_s",
            "noise_reference_range_m",
            "swap_angle_width_deg",
            "view_correlation_deg",
        ):
            v = getattr(self, name)
            if not v > 0:
                raise InputError(f"TrackerParams.{name} must be positive, got {v}")
        for name in (
            "surface_pushback_m",
            "surface_depth_gain",
            "depth_axis_factor",
            "inferred_sigma_m",
            "occlusion_margin_m",
            "occlusion_sample_radius",
            "dropout_rate_hz",
            "noise_range_exponent",
        ):
            v = getattr(self, name)
            if not v >= 0:
                raise InputError(f"TrackerParams.{name} must be non-negative, got {v}")
        unknown = [n for n in self.never_inferred if n not in JOINT_INDEX]
        if unknown:
            raise InputError(
                f"TrackerParams.never_inferred has unknown joints {unknown}; use Kinect v2 names"
            )
        if not 1 <= self.min_joints_in_view <= N_JOINTS:
            raise InputError(
                f"TrackerParams.min_joints_in_view must be 1..{N_JOINTS}, "
                f"got {self.min_joints_in_view}"
            )


def describe_params(params: TrackerParams | None = None) -> list[dict[str, Any]]:
    """Every parameter as ``{"name", "value", "unit", "kind", "source"}`` (for docs, reports)."""
    p = TrackerParams() if params is None else params
    return [{"name": f.name, "value": getattr(p, f.name), **dict(f.metadata)} for f in fields(p)]

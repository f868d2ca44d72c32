"""The Kinect v2 body-tracker error model: what the tracker reports for each joint, given the truth.

A real Kinect v2 does not see joints: it classifies depth pixels of the body surface and regresses
25 joint positions from them, frame by frame, with its own idea of where a joint is. Against
optical motion capture its joints are off by 5-10 cm for most joints, with ankles and feet the
worst (Wang et al. 2015; Otte et al. 2016; Xu & McGorry 2015). This module turns true joint
positions into what such a tracker reports, with these components (every number lives in
:class:`TrackerParams`, with its unit and source; ``docs/error_model_tracker.md`` explains them):

(a) **Systematic bias**, in two parts.
    *Subject-level* (:class:`SubjectBias`, drawn once per session by :func:`draw_subject_bias`,
    common to every sensor): the tracker's joint definitions differ from the mocap's (hip centres
    higher and wider, ankles higher ...). It is expressed in a body frame (right, forward, up), so
    it moves with the body. *View-dependent*: the tracker sees the body surface and pushes its
    estimate a fixed distance behind it (Shotton et al. 2011), so a joint deep inside a thick body
    part ends up pulled toward the sensor along the viewing ray, a thin part pushed away; the
    depth below the surface is ray-cast against the capsule body. A slowly varying per-sensor
    *pose-dependent* offset adds what two co-located real sensors still disagree on.
(b) **Temporally correlated jitter**: Ornstein-Uhlenbeck noise per joint and axis, larger along
    the depth axis, growing with the joint's speed and with distance.
(c) **States**: joints hidden by the body from the sensor (rays cast from the optical centre to
    the joint and around it against the capsules, ignoring the capsules the joint lies inside)
    are ``INFERRED``, with a much larger, biased error (pulled toward the last pose seen, held in
    the body frame, else the mirrored twin as last seen, else a standing pose); joints outside
    the depth camera's view or range are ``INFERRED`` too, at the guess alone (the SDK documents
    that joints it cannot see are inferred from the rest of the body).
(d) **Left/right swaps**: a tracker assumes the person faces it; the probability that it labels
    the body mirrored rises with the facing angle and persists over runs of frames.
(e) **Dropouts**: occasional runs of frames where the body is lost (all joints ``NOT_TRACKED``).

The inferred-joint errors and the swap decisions are smooth random functions of time and of the
viewing direction in the body frame (:class:`SessionLatent`), drawn once per session with the
subject bias: sensors that look from nearby directions make the same mistakes, as two real
co-located Kinects do. Everything is vectorized over frames and joints; the AR(1) recursions run
in :func:`scipy.signal.lfilter`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any, Final

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.signal import lfilter
from scipy.special import ndtr

from kinefuse.errors import InputError
from kinefuse.geometry.raycast import ray_capsules_batched
from kinefuse.sensors.intrinsics import Intrinsics
from kinefuse.skeleton import (
    JOINT_INDEX,
    JOINTS,
    MIRROR_INDEX,
    N_JOINTS,
    TrackingState,
    bone_index_array,
    standing_pose,
)

Array = NDArray[np.float64]

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


@dataclass(frozen=True, eq=False)
class SessionLatent:
    """Smooth random fields of time and viewing direction, shared by every sensor of a session.

    ``F`` independent fields with unit variance, each a sum of ``K`` random Fourier features
    ``sqrt(2/K) * a * cos(omega * t + kappa * phi + psi)``: Gaussian correlation in time with
    length ``tau_s`` and a periodic correlation in the view angle ``phi`` (the sensor's azimuth
    in the body frame) of width ``width_rad``. Two sensors evaluating it at the same time from
    nearby viewpoints get nearly the same values: they make the same mistakes.

    Attributes
    ----------
    omega_rad_s : (K,) float
    kappa : (K,) float
        Integer angular frequencies (periodic in the view angle).
    phase_rad, amplitude : (F, K) float
    """

    omega_rad_s: Array
    kappa: Array
    phase_rad: Array
    amplitude: Array

    @classmethod
    def draw(
        cls,
        rng: np.random.Generator,
        n_fields: int,
        tau_s: float,
        width_rad: float,
        n_features: int = 32,
    ) -> SessionLatent:
        return cls(
            omega_rad_s=rng.normal(0.0, 1.0 / tau_s, n_features),
            kappa=np.round(rng.normal(0.0, 1.0 / width_rad, n_features)),
            phase_rad=rng.uniform(0.0, 2 * np.pi, (n_fields, n_features)),
            amplitude=rng.normal(size=(n_fields, n_features)),
        )

    @property
    def n_fields(self) -> int:
        return int(self.amplitude.shape[0])

    def __call__(self, t_s: ArrayLike, view_rad: ArrayLike) -> Array:
        """Field values ``(T, F)`` at times ``t_s`` (T,) and view angles ``view_rad`` (T,)."""
        arg = np.outer(np.asarray(t_s, dtype=np.float64), self.omega_rad_s) + np.outer(
            np.asarray(view_rad, dtype=np.float64), self.kappa
        )
        k = self.omega_rad_s.size
        ca = self.amplitude * np.cos(self.phase_rad)
        sa = self.amplitude * np.sin(self.phase_rad)
        return np.asarray(
            np.sqrt(2.0 / k) * (np.cos(arg) @ ca.T - np.sin(arg) @ sa.T), dtype=np.float64
        )


@dataclass(frozen=True, eq=False)
class SubjectBias:
    """What is common to every sensor of a session: the subject-level joint offsets, and the
    shared latent processes behind inferred-joint errors and left/right swaps.

    Attributes
    ----------
    offsets_body_m : (25, 3) float
        Offset of each joint in the body frame (right, forward, up), metres.
    swap_latent : SessionLatent or None
        One field; a frame is mirrored where its normal CDF is below the swap probability.
    inferred_latent : SessionLatent or None
        75 fields: the inferred-joint error per joint and body axis, in units of
        ``TrackerParams.inferred_sigma_m``.
        ``None`` latents are drawn per sensor inside :func:`simulate_tracker` (independent
        sensors).
    """

    offsets_body_m: Array
    swap_latent: SessionLatent | None = None
    inferred_latent: SessionLatent | None = None

    def __post_init__(self) -> None:
        a = np.asarray(self.offsets_body_m, dtype=np.float64)
        if a.shape != (N_JOINTS, 3) or not np.all(np.isfinite(a)):
            raise InputError(
                f"SubjectBias.offsets_body_m must be a finite ({N_JOINTS}, 3) array, got {a.shape}"
            )
        object.__setattr__(self, "offsets_body_m", a)
        if self.swap_latent is not None and self.swap_latent.n_fields != 1:
            raise InputError("SubjectBias.swap_latent must have exactly 1 field")
        if self.inferred_latent is not None and self.inferred_latent.n_fields != 3 * N_JOINTS:
            raise InputError(f"SubjectBias.inferred_latent must have {3 * N_JOINTS} fields")

    @classmethod
    def zero(cls) -> SubjectBias:
        """No subject-level bias (the tracker's joint definitions equal the truth's); the
        latent processes are then drawn independently per sensor."""
        return cls(np.zeros((N_JOINTS, 3)))


def draw_subject_bias(rng: np.random.Generator, params: TrackerParams | None = None) -> SubjectBias:
    """Draw the subject-level bias once per session (share it between all sensors).

    The random part is mirror-symmetric in expectation only: left and right joints get their own
    draws, as a real tracker's errors on one person's two knees differ.
    """
    p = TrackerParams() if params is None else params
    if not isinstance(rng, np.random.Generator):
        raise InputError(
            f"rng must be a numpy Generator (np.random.default_rng(seed)), got {type(rng)}"
        )
    mean = np.asarray(p.subject_bias_mean_m, dtype=np.float64)
    sigma = np.asarray(p.subject_bias_sigma_m, dtype=np.float64)
    offsets = mean + rng.normal(size=(N_JOINTS, 3)) * sigma[:, None]
    swap, inferred = _draw_latents(rng, p)
    return SubjectBias(offsets, swap_latent=swap, inferred_latent=inferred)


def _draw_latents(
    rng: np.random.Generator, p: TrackerParams
) -> tuple[SessionLatent, SessionLatent]:
    width = np.radians(p.view_correlation_deg)
    return (
        SessionLatent.draw(rng, 1, p.swap_tau_s, width),
        SessionLatent.draw(rng, 3 * N_JOINTS, p.inferred_tau_s, width),
    )


@dataclass(frozen=True, eq=False)
class TrackerOutput:
    """What one sensor's body tracker reported, plus truth-side extras for evaluation only.

    Attributes
    ----------
    joints_sensor : (T, 25, 3) float
        Reported joints in the sensor frame (x right, y down, z forward), metres, in the labels
        the tracker gave them (mirrored in swapped frames); NaN where ``NOT_TRACKED``.
    states : (T, 25) int8
        :class:`kinefuse.skeleton.TrackingState` per reported joint.
    visible : (T, 25) bool
        Evaluation only: the true joint (true label) is inside the view and range and not hidden
        by the body from this sensor (ray cast against the capsules).
    swapped : (T,) bool
        Evaluation only: the tracker labelled the body left/right mirrored in this frame.
    dropout : (T,) bool
        Evaluation only: the body was lost in this frame (dropout, or too little in view).
    facing_angle_rad : (T,) float
        Evaluation only: angle between the body's forward direction and the direction to the
        sensor, horizontal, 0 = facing the sensor, pi = back to it.
    """

    joints_sensor: Array
    states: NDArray[np.int8]
    visible: NDArray[np.bool_]
    swapped: NDArray[np.bool_]
    dropout: NDArray[np.bool_]
    facing_angle_rad: Array


# ------------------------------------------------------------------------------------------
# helpers


def _ar1(rng: np.random.Generator, shape: tuple[int, ...], phi: float) -> Array:
    """Stationary unit-variance AR(1) sequences along axis 0: ``x_t = phi x_{t-1} + ...``."""
    e = rng.standard_normal(shape)
    if shape[0] == 0:
        return e
    x_prev = rng.standard_normal(shape[1:])
    b = np.array([np.sqrt(max(1.0 - phi * phi, 0.0))])
    a = np.array([1.0, -phi])
    zi = (phi * x_prev)[None, ...]
    y, _ = lfilter(b, a, e, axis=0, zi=zi)
    return np.asarray(y, dtype=np.float64)


def _phi(dt_s: float, tau_s: float) -> float:
    return float(np.exp(-dt_s / tau_s))


def _body_axes(p: Array, up: Array) -> Array:
    """Body frame ``(T, 3, 3)`` with columns (right, forward, up) from joints ``(T, 25, 3)``.

    ``up`` (3,) is the world's up direction in the frame of ``p``.
    """
    j = JOINT_INDEX
    lateral = (p[:, j["HipRight"]] - p[:, j["HipLeft"]]) + (
        p[:, j["ShoulderRight"]] - p[:, j["ShoulderLeft"]]
    )
    lateral = lateral - (lateral @ up)[:, None] * up[None, :]
    n = np.linalg.norm(lateral, axis=1, keepdims=True)
    right = np.where(n > 1e-9, lateral / np.maximum(n, 1e-12), np.array([1.0, 0.0, 0.0]))
    up_t = np.broadcast_to(up, right.shape)
    forward = np.cross(up_t, right)
    return np.stack([right, forward, up_t], axis=-1)


def _default_local(tb: Array, origin: Array) -> Array:
    """A standing pose in body coordinates (right, forward, up) from the spine base ``(T, 25,
    3)``, scaled to the believed body's spine-base-to-head length."""
    std = standing_pose()  # facing +x, z up: right is -y
    std_local = np.stack([-std[:, 1], std[:, 0], std[:, 2]], axis=-1)
    base, head = JOINT_INDEX["SpineBase"], JOINT_INDEX["Head"]
    std_local = std_local - std_local[base]
    trunk = np.linalg.norm(tb[:, head] - origin, axis=-1)
    scale = trunk / np.linalg.norm(std_local[head])
    return std_local[None] * np.nan_to_num(scale, nan=1.0)[:, None, None]


def _point_segment_distance(p: Array, a: Array, b: Array) -> Array:
    """Distance ``(T, P, C)`` from points ``(T, P, 3)`` to segments ``(T, C, 3)``."""
    ab = b - a  # (T, C, 3)
    abab = np.maximum(np.einsum("tci,tci->tc", ab, ab), 1e-18)[:, None, :]
    pab = p @ ab.transpose(0, 2, 1)  # (T, P, C)
    aab = np.einsum("tci,tci->tc", a, ab)[:, None, :]
    s = np.clip((pab - aab) / abab, 0.0, 1.0)
    pp = np.einsum("tpi,tpi->tp", p, p)[:, :, None]
    pa = p @ a.transpose(0, 2, 1)
    aa = np.einsum("tci,tci->tc", a, a)[:, None, :]
    ap2 = pp - 2.0 * pa + aa  # |p - a|^2
    d2 = ap2 - 2.0 * s * (pab - aab) + s * s * abab
    return np.asarray(np.sqrt(np.maximum(d2, 0.0)), dtype=np.float64)


def joint_radii(radii: ArrayLike) -> Array:
    """Radius of the body around each joint ``(25,)``: the mean radius of its bones' capsules."""
    r = np.asarray(radii, dtype=np.float64)
    bones = bone_index_array()
    total = np.zeros(N_JOINTS)
    count = np.zeros(N_JOINTS)
    for col in (0, 1):
        np.add.at(total, bones[:, col], r)
        np.add.at(count, bones[:, col], 1.0)
    return total / np.maximum(count, 1.0)


#: Sample directions around a joint (centre and four points on a circle facing the sensor).
_SAMPLES: Final = np.array([[0.0, 0.0], [1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])


def body_visibility(
    joints_sensor: ArrayLike,
    radii: ArrayLike,
    *,
    margin_m: float = 0.02,
    sample_radius_factor: float = 1.0,
    chunk: int = 128,
) -> tuple[Array, Array]:
    """How much of each joint the sensor sees past the body, and how deep below the surface it is.

    Rays from the sensor's optical centre (the origin) go to every joint and to four points
    around it (on a circle of ``sample_radius_factor`` times the body radius at the joint,
    perpendicular to the ray), and are cast against the capsule body of the same frame. Capsules
    the joint (or the sample point) lies inside are not occluders (the joint is inside its own
    limbs); the first of the joint's capsules along the central ray is the surface the sensor
    sees in front of the joint.

    Parameters
    ----------
    joints_sensor : (T, 25, 3) float
        True joints in the sensor frame, metres.
    radii : (24,) float
        Capsule radius per bone, in :data:`kinefuse.skeleton.BONES` order, metres.
    margin_m : float
        A capsule hides a point only if the ray meets it at least this far in front of it.
    sample_radius_factor : float
        Radius of the sample circle around each joint, in body radii at the joint.
    chunk : int
        Frames per batch (bounds memory).

    Returns
    -------
    visible_fraction : (T, 25) float
        Share of the five rays no other body part blocks (1: fully visible, 0: hidden).
    depth_below_surface_m : (T, 25) float
        Distance along the central ray from the visible surface of the joint's own body parts to
        the joint, metres (0 when the ray does not enter them before the joint).
    """
    p = np.asarray(joints_sensor, dtype=np.float64)
    r = np.asarray(radii, dtype=np.float64)
    bones = bone_index_array()
    if p.ndim != 3 or p.shape[1:] != (N_JOINTS, 3):
        raise InputError(f"joints_sensor must have shape (T, {N_JOINTS}, 3), got {p.shape}")
    if r.shape != (len(bones),) or not np.all(r > 0):
        raise InputError(
            f"radii must be {len(bones)} positive capsule radii in metres (BONES order), "
            f"got shape {r.shape}; use kinefuse.skeleton.capsule_radii(height_m)"
        )
    n_t = p.shape[0]
    n_s = _SAMPLES.shape[0]
    rj = joint_radii(r) * sample_radius_factor  # (J,)
    frac = np.ones((n_t, N_JOINTS))
    depth = np.zeros((n_t, N_JOINTS))
    for s in range(0, n_t, max(int(chunk), 1)):  # chunks bound memory; work is vectorized
        q = p[s : s + chunk]
        nt = q.shape[0]
        a = q[:, bones[:, 0]]
        b = q[:, bones[:, 1]]
        dist = np.linalg.norm(q, axis=-1)  # (t, J)
        u = q / np.maximum(dist, 1e-12)[..., None]
        # two unit vectors perpendicular to each ray (e1 horizontal-ish in the image)
        e1 = np.cross(u, np.array([0.0, 1.0, 0.0]))
        e1 /= np.maximum(np.linalg.norm(e1, axis=-1, keepdims=True), 1e-12)
        e2 = np.cross(u, e1)
        pts = q[:, :, None, :] + rj[None, :, None, None] * (
            _SAMPLES[None, None, :, 0, None] * e1[:, :, None, :]
            + _SAMPLES[None, None, :, 1, None] * e2[:, :, None, :]
        )  # (t, J, S, 3)
        d_pts = np.linalg.norm(pts, axis=-1)
        dirs = (pts / d_pts[..., None]).reshape(nt, N_JOINTS * n_s, 3)
        t_hit = ray_capsules_batched(np.zeros(3), dirs, a, b, r).reshape(
            nt, N_JOINTS, n_s, -1
        )  # (t, J, S, C)
        inside = _point_segment_distance(q, a, b) < r[None, None, :]  # (t, J, C)
        # a capsule the joint or the sample point lies in is part of what is looked at
        inside_pts = _point_segment_distance(pts.reshape(nt, -1, 3), a, b) < r[None, None, :]
        own = inside[:, :, None, :] | inside_pts.reshape(nt, N_JOINTS, n_s, -1)
        blocking = ~own & (t_hit < d_pts[..., None] - margin_m)
        frac[s : s + chunk] = 1.0 - blocking.any(axis=-1).mean(axis=-1)
        t0 = t_hit[:, :, 0, :]
        entry = np.where(inside & (t0 < dist[..., None]), t0, np.inf).min(axis=-1)
        depth[s : s + chunk] = np.where(np.isfinite(entry), dist - entry, 0.0)
    return frac, depth


def _check_rigid(sensor2world: ArrayLike) -> Array:
    t = np.asarray(sensor2world, dtype=np.float64)
    if t.shape != (4, 4) or not np.all(np.isfinite(t)):
        raise InputError(f"sensor2world must be one finite (4, 4) transform, got shape {t.shape}")
    r = t[:3, :3]
    if not np.allclose(r.T @ r, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
        raise InputError(
            "sensor2world's rotation part is not a proper rotation (R^T R = I, det R = +1); "
            "build it with kinefuse.geometry.transforms.look_at or make_transform"
        )
    if not np.allclose(t[3], [0.0, 0.0, 0.0, 1.0]):
        raise InputError(f"sensor2world's last row must be [0, 0, 0, 1], got {t[3]}")
    return t


def _dropout_mask(
    rng: np.random.Generator, n_t: int, dt_s: float, params: TrackerParams
) -> NDArray[np.bool_]:
    n_events = int(rng.poisson(params.dropout_rate_hz * n_t * dt_s)) if n_t else 0
    starts = rng.integers(0, max(n_t, 1), n_events)
    lengths = np.maximum(np.round(rng.exponential(params.dropout_mean_s / dt_s, n_events)), 1)
    ends = np.minimum(starts + lengths.astype(np.int64), n_t)
    marks = np.zeros(n_t + 1, dtype=np.int64)
    np.add.at(marks, starts, 1)
    np.add.at(marks, ends, -1)
    return np.asarray(np.cumsum(marks)[:n_t] > 0)


# ------------------------------------------------------------------------------------------
# the model


def simulate_tracker(
    truth_world: ArrayLike,
    sensor2world: ArrayLike,
    intrinsics: Intrinsics,
    radii: ArrayLike,
    rng: np.random.Generator,
    params: TrackerParams | None = None,
    *,
    dt_s: float = 1.0 / 30.0,
    subject: SubjectBias | None = None,
    t_s: ArrayLike | None = None,
) -> TrackerOutput:
    """What a Kinect v2 body tracker reports, frame by frame, for one sensor.

    Parameters
    ----------
    truth_world : (T, 25, 3) float
        True joint positions at this sensor's capture instants, world frame, metres.
    sensor2world : (4, 4) float
        The sensor's pose.
    intrinsics : Intrinsics
        Its depth camera (joints outside its view and range are guessed, ``INFERRED``).
    radii : (24,) float
        Capsule radius per bone (:func:`kinefuse.skeleton.capsule_radii`), metres.
    rng : numpy.random.Generator
        Source of all randomness (seed it for reproducible sessions).
    params : TrackerParams, optional
        The error model; defaults to ``TrackerParams()``.
    dt_s : float
        Nominal time between frames, seconds (sets the correlation of the noise processes).
    subject : SubjectBias, optional
        The session's subject-level bias, drawn once with :func:`draw_subject_bias` and shared by
        all sensors; ``None`` draws a fresh one from ``rng`` (a one-sensor session).
    t_s : (T,) float, optional
        True capture times, seconds (the clock the session's shared latent processes run on;
        pass them so sensors of one session make correlated mistakes at the same instants).
        Default ``arange(T) * dt_s``.

    Returns
    -------
    TrackerOutput
        ``joints_sensor`` (T, 25, 3) in the sensor frame with NaN where ``NOT_TRACKED``,
        ``states`` (T, 25) int8, and the truth-side extras ``visible``, ``swapped``, ``dropout``,
        ``facing_angle_rad``.
    """
    p = TrackerParams() if params is None else params
    if not isinstance(rng, np.random.Generator):
        raise InputError(
            f"rng must be a numpy Generator (np.random.default_rng(seed)), got {type(rng)}"
        )
    if not isinstance(intrinsics, Intrinsics):
        raise InputError(f"intrinsics must be a kinefuse Intrinsics, got {type(intrinsics)}")
    if not (isinstance(dt_s, float | int) and dt_s > 0 and np.isfinite(dt_s)):
        raise InputError(f"dt_s must be a positive number of seconds, got {dt_s!r}")
    truth = np.asarray(truth_world, dtype=np.float64)
    if truth.ndim != 3 or truth.shape[1:] != (N_JOINTS, 3):
        raise InputError(
            f"truth_world must have shape (T, {N_JOINTS}, 3) in JOINTS order, got {truth.shape}"
        )
    if not np.all(np.isfinite(truth)):
        raise InputError("truth_world must be finite: the truth has no gaps (interpolate first)")
    s2w = _check_rigid(sensor2world)
    subj = draw_subject_bias(rng, p) if subject is None else subject
    if not isinstance(subj, SubjectBias):
        raise InputError(f"subject must be a SubjectBias, got {type(subj)}")
    dt = float(dt_s)
    n_t = truth.shape[0]
    if t_s is None:
        times = np.arange(n_t) * dt
    else:
        times = np.asarray(t_s, dtype=np.float64).reshape(-1)
        if times.shape != (n_t,) or not np.all(np.isfinite(times)):
            raise InputError(
                f"t_s must hold {n_t} finite capture times (one per truth frame), "
                f"got shape {times.shape}"
            )
    if subj.swap_latent is None or subj.inferred_latent is None:
        own_swap, own_inferred = _draw_latents(rng, p)
    swap_latent = subj.swap_latent if subj.swap_latent is not None else own_swap
    inferred_latent = subj.inferred_latent if subj.inferred_latent is not None else own_inferred
    rot = s2w[:3, :3]
    ones = np.arange(N_JOINTS)

    # truth in the sensor frame: p_sensor = R^T (p_world - c)
    p_true = (truth - s2w[:3, 3]) @ rot
    up = rot.T @ np.array([0.0, 0.0, 1.0])  # world up, in sensor coordinates

    # (c) visibility of the true joints
    vis_frac, depth_below = body_visibility(
        p_true,
        radii,
        margin_m=p.occlusion_margin_m,
        sample_radius_factor=p.occlusion_sample_radius,
    )
    in_view = intrinsics.in_view(p_true)
    visible = (vis_frac >= p.min_visible_fraction) & in_view

    # facing angle, horizontal: body forward vs direction from the body to the sensor
    axes_true = _body_axes(p_true, up)
    fwd = axes_true[:, :, 1]
    to_sensor = -p_true[:, JOINT_INDEX["SpineBase"]]
    to_sensor = to_sensor - (to_sensor @ up)[:, None] * up[None, :]
    to_sensor /= np.maximum(np.linalg.norm(to_sensor, axis=1, keepdims=True), 1e-12)
    cos_f = np.einsum("ti,ti->t", fwd, to_sensor)
    sin_f = np.einsum("ti,ti->t", axes_true[:, :, 0], to_sensor)
    view = np.arctan2(sin_f, cos_f)  # the sensor's azimuth in the body frame
    facing = np.abs(view)

    # (e) body lost: dropouts, or too little of it in view
    lost = _dropout_mask(rng, n_t, dt, p) | (in_view.sum(axis=1) < p.min_joints_in_view)

    # (d) swaps: a persistent latent process thresholded at the facing-dependent probability
    z = swap_latent(times, view)[:, 0]
    x = (np.degrees(facing) - p.swap_angle_mid_deg) / p.swap_angle_width_deg
    prob = p.swap_prob_max / (1.0 + np.exp(-x))
    swapped = (ndtr(z) < prob) & ~lost

    # what the tracker believes: the labels mirrored in swapped frames
    perm = np.where(swapped[:, None], np.asarray(MIRROR_INDEX)[None, :], ones[None, :])
    tb = np.take_along_axis(p_true, perm[..., None], axis=1)
    vis_b = np.take_along_axis(visible, perm, axis=1)
    in_view_b = np.take_along_axis(in_view, perm, axis=1)
    depth_b = np.take_along_axis(depth_below, perm, axis=1)
    never = np.isin(ones, [JOINT_INDEX[n] for n in p.never_inferred])
    vis_b = vis_b | (never[None, :] & in_view_b)

    axes_b = _body_axes(tb, up)  # (T, 3, 3) believed body frame
    origin = tb[:, JOINT_INDEX["SpineBase"]]

    # (a) subject bias in the body frame, and the view-dependent pull along the viewing ray
    bias = np.einsum("tik,jk->tji", axes_b, subj.offsets_body_m)
    rng_dist = np.linalg.norm(tb, axis=-1)
    u = tb / np.maximum(rng_dist, 1e-12)[..., None]
    pull = p.surface_depth_gain * depth_b - p.surface_pushback_m
    tracked_pos = tb + bias - u * pull[..., None]

    # per-sensor pose-dependent offset (slow) and jitter (fast, speed- and range-dependent)
    pose_sigma = np.asarray(p.pose_bias_sigma_m)
    tracked_pos += (
        _ar1(rng, (n_t, N_JOINTS, 3), _phi(dt, p.pose_bias_tau_s)) * pose_sigma[None, :, None]
    )
    if n_t > 1:  # speed relative to the pelvis: limbs moving within the body
        vel = np.gradient(p_true, dt, axis=0)
        rel = vel - vel[:, JOINT_INDEX["SpineBase"]][:, None, :]
        speed_true = np.linalg.norm(rel, axis=-1)
    else:
        speed_true = np.zeros((n_t, N_JOINTS))
    speed = np.take_along_axis(speed_true, perm, axis=1)
    range_factor = (rng_dist / p.noise_reference_range_m) ** p.noise_range_exponent
    axis_factor = np.array([1.0, 1.0, p.depth_axis_factor])
    static = np.asarray(p.jitter_sigma_m)[None, :]
    moving = np.asarray(p.motion_noise_gain_s)[None, :] * speed
    jitter = _ar1(rng, (n_t, N_JOINTS, 3), _phi(dt, p.jitter_tau_s)) * static[..., None]
    jitter += _ar1(rng, (n_t, N_JOINTS, 3), _phi(dt, p.motion_noise_tau_s)) * moving[..., None]
    tracked_pos += jitter * range_factor[..., None] * axis_factor

    # (c) INFERRED joints: pulled toward a guessed pose
    local = np.einsum("tik,tji->tjk", axes_b, tb - origin[:, None, :])  # body-frame coords
    seen = vis_b & ~lost[:, None]
    last = np.where(seen, np.arange(n_t)[:, None], -1)
    last = np.maximum.accumulate(last, axis=0)
    held = local[np.maximum(last, 0), ones[None, :]]
    # never seen yet: the mirrored twin as last seen, else a default pose of the body's size
    twin = list(MIRROR_INDEX)
    mirrored = held[:, twin] * np.array([-1.0, 1.0, 1.0])
    guess_local = np.where(
        (last >= 0)[..., None],
        held,
        np.where((last[:, twin] >= 0)[..., None], mirrored, _default_local(tb, origin)),
    )
    guess = origin[:, None, :] + np.einsum("tik,tjk->tji", axes_b, guess_local) + bias
    infer_body = inferred_latent(times, view).reshape(n_t, N_JOINTS, 3) * p.inferred_sigma_m
    infer_noise = np.einsum("tik,tjk->tji", axes_b, infer_body)
    inferred_pos = (1.0 - p.inferred_blend) * tracked_pos + p.inferred_blend * guess + infer_noise

    states = np.full((n_t, N_JOINTS), TrackingState.INFERRED, dtype=np.int8)
    states[vis_b] = TrackingState.TRACKED
    out = np.where(vis_b[..., None], tracked_pos, inferred_pos)
    if p.out_of_view_inferred:
        # the camera saw nothing of a joint out of view: its position is the guess alone
        out = np.where(in_view_b[..., None], out, guess + infer_noise)
        not_tracked = np.broadcast_to(lost[:, None], (n_t, N_JOINTS))
    else:
        not_tracked = ~in_view_b | lost[:, None]
    # nothing reported TRACKED outside the view, even after the noise
    states[(states == TrackingState.TRACKED) & ~intrinsics.in_view(out)] = TrackingState.INFERRED
    states[not_tracked] = TrackingState.NOT_TRACKED
    out[not_tracked] = np.nan
    return TrackerOutput(
        joints_sensor=out,
        states=states,
        visible=visible,
        swapped=swapped,
        dropout=lost,
        facing_angle_rad=facing,
    )

"""The parameters of the Kinect v2 body-tracker error model (:mod:`kinefuse.sim.tracker`).

Every number of the model lives in :class:`TrackerParams` with its unit, kind and source;
``docs/error_model_tracker.md`` explains them and ``docs/realism.md`` says what was fitted to
which real take.

Longer than the project's ~600-line guide on purpose: it is one declarative table (one
dataclass, every field with its unit, kind and source text, and its validation); splitting it
would scatter the table that ``docs/error_model.md`` is generated from.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Any, Final

import numpy as np

from kinefuse.core.skeleton import JOINT_INDEX, JOINTS, N_JOINTS
from kinefuse.errors import InputError

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
_POP = (
    "KinectMultiTrack population, participants 0-9, 25 main takes at 0/45/90 deg "
    "(../shared/data/kinect/kinect_multitrack_population), fitted by studies/fit_tracker_tails.py"
)
_WALKER = "kinect2-tracking walker.json (real Kinect v2 walk with tracking states)"


@dataclass(frozen=True)
class TrackerParams:
    """Every parameter of the Kinect v2 body-tracker error model.

    Each field's ``metadata`` has ``unit``, ``kind`` (``literature``: a published figure;
    ``measurement``: measured by us on real recordings shipped in ``../shared/data``;
    ``tuned``: fitted so the simulated two-sensor disagreement matches the real one, see
    ``docs/realism.md``; ``assumption``: a stated guess) and ``source``. Per-joint values are
    25-tuples in :data:`kinefuse.core.skeleton.JOINTS` order (build them with :func:`per_joint`).
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
                "trunk": 0.018,
                "head": 0.02,
                "shoulder": 0.02,
                "elbow": 0.022,
                "wrist": 0.024,
                "hand": 0.028,
                "handtip": 0.032,
                "thumb": 0.032,
                "hip": 0.018,
                "knee": 0.022,
                "ankle": 0.032,
                "foot": 0.04,
            }
        ),
        metadata=_meta(
            "m per axis",
            "literature",
            "spread of the per-subject joint offsets, per axis, chosen so that single-sensor "
            "errors against the truth (with the view-dependent offset of view_bias_sigma_m on "
            "top) are 3-10 cm, worst for feet/ankles, as in " + _WANG + "; 0.8 times the "
            "values used before the view-dependent offset was added. Drawn coherently along "
            "the skeleton (limb_coherence), so a limb's joints are off together",
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
        default=0.3,
        metadata=_meta(
            "1",
            "tuned",
            "share of the joint's depth below the visible surface (ray cast against the capsule "
            "body) that the tracker leaves in its estimate before the push-back; fitted with "
            "view_bias_sigma_m so the 45-degree take Study_4_Kinect_1 disagrees more than the "
            "parallel one while its wrists, hands, ankles and feet do not (real 2.2 cm in "
            "both), " + _KMT,
        ),
    )
    pose_bias_sigma_m: tuple[float, ...] = field(
        default_factory=lambda: per_joint(
            {
                "trunk": 0.005,
                "SpineBase": 0.011,
                "SpineMid": 0.007,
                "head": 0.012,
                "shoulder": 0.0085,
                "elbow": 0.0105,
                "wrist": 0.0065,
                "hand": 0.005,
                "handtip": 0.005,
                "thumb": 0.025,
                "hip": 0.0075,
                "knee": 0.016,
                "ankle": 0.0055,
                "foot": 0.01,
            }
        ),
        metadata=_meta(
            "m per axis",
            "measurement",
            "per-sensor slowly varying offset: the median disagreement per joint of the two "
            "side-by-side real sensors while the person stands (Study_4_Kinect_0 scenario 1: "
            "0.7-3.8 cm, thumbs 2-9 cm) divided by 2.2, the median distance between two "
            "independent offsets of this sigma per axis, " + _KMT,
        ),
    )
    pose_bias_tau_s: float = field(
        default=2.0,
        metadata=_meta(
            "s",
            "assumption",
            "correlation time of the pose-dependent offset, on its pose clock (constant over a "
            "1.5 s still stand in " + _KMT + ")",
        ),
    )
    pose_clock_speed_m_s: float = field(
        default=0.5,
        metadata=_meta(
            "m/s",
            "assumption",
            "the pose-dependent offset evolves on a clock that runs at real time when the "
            "joints move at this mean speed (a slow walk), faster or slower with the motion: "
            "it is a function of the pose, so it stays put while the person holds still (the "
            "real limb bone lengths vary by only 0.2-0.7 % in a stand, " + _KMT + " scenario 1)",
        ),
    )
    pose_clock_floor: float = field(
        default=0.05,
        metadata=_meta(
            "1",
            "assumption",
            "rate of that clock (in seconds per second) while the body is perfectly still",
        ),
    )
    limb_coherence: float = field(
        default=0.9,
        metadata=_meta(
            "1",
            "tuned",
            "correlation of neighbouring joints' per-sensor errors (pose-dependent offset, "
            "jitter, speed-dependent noise, view-dependent and far-limb errors, INFERRED "
            "error), so that a limb's joints are off together: the real sensors' knee and "
            "elbow angles agree 2-3x better than independent errors of the same size allow. "
            "Fitted to the two sensors' knee and elbow angle disagreement per layout over "
            + _POP.replace("fitted by studies/fit_tracker_tails.py", "")
            + "by studies/fit_limb_coherence.py: flat from 0.8 to 0.95 (0.8 best on participants "
            "0-4, 0.95 on 5-9 and on all ten); 0.9, the middle, keeps the position medians in "
            "band on both halves (0.95: x0.78 at 90 deg on participants 0-4). The subject-level "
            "offsets (subject_bias_sigma_m) are drawn with the same correlation: a real front "
            "sensor reads a standing person's straight knees 5 deg bent in the median over the "
            "ten participants, independent offsets 12 deg, coherent ones 5 deg "
            "(not fitted: tests/test_realism_takes.py)",
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
        default=0.3,
        metadata=_meta(
            "s",
            "tuned",
            "time constant of each of the two low-pass stages of the smoothed jitter (the SDK "
            "smooths its output): fitted with hf_jitter_sigma_m to the still-pose step of the "
            "spine in the three takes (median 0.35-0.6 mm a frame), " + _KMT,
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
        default=1.0,
        metadata=_meta(
            "1",
            "tuned",
            "weight of the guessed pose (last pose seen, held in the body frame and moved with "
            "it; else the mirrored twin as last seen; else a standing pose) in the position of "
            "an occluded INFERRED joint in view, within inferred_max_offset_m of where a "
            "visible one would be (one out of view is the guess alone); with inferred_sigma_m, "
            "keeps INFERRED joints at least twice as wrong as TRACKED ones against the truth",
        ),
    )
    inferred_max_offset_m: float = field(
        default=0.35,
        metadata=_meta(
            "m",
            "assumption",
            "an occluded joint in view is pulled toward the guess by at most this far from "
            "where the tracker would put a visible one (its silhouette around the joint keeps "
            "it on the body; the real two-sensor disagreement of a still stand has a p95 of "
            "4-14 cm, " + _KMT + " scenario 1)",
        ),
    )
    inferred_sigma_m: float = field(
        default=0.06,
        metadata=_meta(
            "m per axis",
            "tuned",
            "extra error of INFERRED joints (a smooth function of time and view shared by the "
            "session): keeps them at least twice as wrong as tracked ones against the truth "
            "(the tracker guesses occluded joints, paper A Sec. A.4) while the extremities of "
            "the 45-degree take Study_4_Kinect_1, often occluded from its side sensor, disagree "
            "little more than the parallel take's, as the real ones do, " + _KMT,
        ),
    )
    inferred_tau_s: float = field(
        default=0.5, metadata=_meta("s", "assumption", "correlation time of that extra error")
    )
    view_correlation_deg: float = field(
        default=60.0,
        metadata=_meta(
            "deg",
            "tuned",
            "the inferred-joint error and the swap decision are smooth random functions of time "
            "and of the viewing direction in the body frame, shared by every sensor of a "
            "session: sensors that see the body from directions this far apart make correlated "
            "mistakes (two co-located real sensors are mirrored together: the two real sensors "
            "of " + _KMT + " disagree on left/right in only 1-2 % of frames at 0 and 45 deg); "
            "fitted with inferred_sigma_m to the extremities of the 45-degree take",
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

    # (f) seen from the side, and a smoothed skeleton --------------------------------------
    view_bias_sigma_m: tuple[float, ...] = field(
        default_factory=lambda: per_joint(
            {
                "trunk": 0.04,
                "head": 0.07,
                "shoulder": 0.045,
                "elbow": 0.01,
                "wrist": 0.01,
                "hand": 0.01,
                "handtip": 0.01,
                "thumb": 0.01,
                "hip": 0.05,
                "knee": 0.035,
                "ankle": 0.01,
                "foot": 0.01,
            }
        ),
        metadata=_meta(
            "m per body axis, seen from the side",
            "tuned",
            "view-dependent offset of the tracker's joints (a smooth function of the view angle, "
            "shared by the session, scaled by |sin(view)|^view_bias_exponent): fitted to the "
            "per-joint disagreement of the 90-degree take Study_1 (head 9.5 cm, hips 7.3-7.5 "
            "cm, spine base 7.8 cm), " + _KMT,
        ),
    )
    view_bias_exponent: float = field(
        default=2.0,
        metadata=_meta(
            "1",
            "tuned",
            "growth of the view-dependent offset with the side view, |sin(view)|^k: 2 so the "
            "population's 45-degree takes keep their median (real 3.6-5.3 cm on eight of nine "
            "participants; docs/realism.md section 6) while the 90-degree ones keep theirs; 4 "
            "(fitted to the one shared 45-degree take, Study_4_Kinect_1, the best-tracked "
            "participant at 45 degrees) in the light model, " + _POP,
        ),
    )
    view_bias_width_deg: float = field(
        default=40.0,
        metadata=_meta(
            "deg",
            "assumption",
            "correlation width of the view-dependent offset over the view angle",
        ),
    )
    side_inferred_onset_deg: float = field(
        default=60.0,
        metadata=_meta(
            "deg",
            "measurement",
            "below this view angle the trunk, head and hips are never INFERRED: TRACKED in all "
            "330 frames of " + _WALKER + ", seen at 58 deg",
        ),
    )
    side_inferred_max: float = field(
        default=0.3,
        metadata=_meta(
            "1",
            "assumption",
            "share of frames in which the trunk, head and hips are INFERRED seen straight from "
            "the side (growing as ((|sin view| - sin onset) / (1 - sin onset))^2 above the onset)",
        ),
    )
    side_inferred_tau_s: float = field(
        default=1.0,
        metadata=_meta("s", "assumption", "correlation time of those INFERRED runs"),
    )
    far_limb_sigma_m: tuple[float, ...] = field(
        default_factory=lambda: per_joint(
            {
                "trunk": 0.0,
                "head": 0.0,
                "shoulder": 0.06,
                "elbow": 0.07,
                "wrist": 0.05,
                "hand": 0.03,
                "handtip": 0.03,
                "thumb": 0.03,
                "hip": 0.03,
                "knee": 0.05,
                "ankle": 0.02,
                "foot": 0.02,
            }
        ),
        metadata=_meta(
            "m per body axis, far side seen straight from the side",
            "tuned",
            "extra slow error of a limb joint on the far side of the body (self-occluded by the "
            "trunk, seen around it), scaled by (far-ness)^far_limb_exponent; fitted to the "
            "far arm of the 90-degree take Study_1 (shoulder/elbow/wrist 10.3/11.0/8.0 cm "
            "against 7.6/5.3/3.6 cm near), " + _KMT,
        ),
    )
    far_limb_exponent: float = field(
        default=4.0,
        metadata=_meta(
            "1",
            "tuned",
            "far-ness is -side * sin(view) in [0, 1]; the error grows as its power, so the far "
            "arm at 45 degrees (far-ness 0.7, a quarter of the error) stays close to the near "
            "one as in "
            "Study_4_Kinect_1, " + _KMT,
        ),
    )
    far_limb_tau_s: float = field(
        default=0.5,
        metadata=_meta("s", "assumption", "correlation time of the far-limb error"),
    )
    hf_jitter_sigma_m: float = field(
        default=0.0001,
        metadata=_meta(
            "m per axis (lateral)",
            "tuned",
            "white frame-to-frame jitter on top of the smoothed errors: fitted to the still-pose "
            "jitter of the spine in the three takes (median step 0.35-0.6 mm a frame), " + _KMT,
        ),
    )
    bone_hold_tracked: float = field(
        default=0.3,
        metadata=_meta(
            "1",
            "tuned",
            "the SDK fits a skeleton: each reported bone is pulled this far toward the body's "
            "own length (guessed joints fully); fitted to the limb bone-length coefficient of "
            "variation of the three takes (0.05-0.07), " + _KMT,
        ),
    )
    bone_hold_inferred: float = field(
        default=1.0,
        metadata=_meta(
            "1",
            "assumption",
            "the same pull for INFERRED joints: a guessed joint keeps the body's bone length, "
            "attached to its parent (the SDK reports a whole skeleton, not loose points)",
        ),
    )
    swap_min_facing_deg: float = field(
        default=90.0,
        metadata=_meta(
            "deg",
            "measurement",
            "no left/right swaps up to this facing angle: the real side sensor at 88 deg of "
            "Study_1 agrees with the front one on left and right in every standing frame (0 %), "
            + _KMT,
        ),
    )

    # (g) gross failures and the person level (kinefuse.sim.tracker_failures) ---------------
    gross_limb_rate_hz: float = field(
        default=1.98,
        metadata=_meta(
            "1/s of motion per sensor",
            "measurement",
            "rate of thrown limbs (an arm or a leg placed 20-50 cm off for a few frames), arms "
            "and legs together, per second of motion: fitted at 0 degrees (the layout where the "
            "model's view-dependent errors make no such runs) so that the simulated runs of an "
            "arm and of a leg more than 20 cm off in the two-sensor disagreement come as often "
            "as the real ones (arms 0.34-0.35/s, legs 0.60-0.77/s on participants 0-4 / 5-9): "
            "the mean of the fits on the two halves (1.77 / 2.19; studies/fit_tracker_tails.py "
            "--participants, one fixed-point step each; 0.98 before the arms and legs were told "
            "apart); 0 in the light model. " + _POP,
        ),
    )
    gross_moving_above_m_s: float = field(
        default=0.03,
        metadata=_meta(
            "m/s",
            "measurement",
            "failures start only while the true pelvis moves faster than this: of the real "
            "runs at 0 degrees none starts in a frame where the reported pelvis moves slower "
            "(the still-frame definition of docs/realism.md), " + _POP,
        ),
    )
    gross_leg_share: float = field(
        default=0.847,
        metadata=_meta(
            "1",
            "measurement",
            "share of thrown limbs that are legs (the rest arms), from the fitted arm and leg "
            "rates (legs are 62-67 % of the real runs above 20 cm, but thrown arms last longer), "
            "mean of the fits on participants 0-4 / 5-9 (0.825 / 0.869), " + _POP,
        ),
    )
    gross_duration_median_s: float = field(
        default=0.075,
        metadata=_meta(
            "s",
            "measurement",
            "median length of a thrown leg and of a whole-body jump (log-normal): fitted so the "
            "simulated leg runs above 20 cm at 0 degrees have the real median length "
            "(0.07-0.08 s): mean of the fits on participants 0-4 / 5-9 (0.066 / 0.084), " + _POP,
        ),
    )
    gross_duration_log_sigma: float = field(
        default=1.36,
        metadata=_meta(
            "1 (natural log)",
            "measurement",
            "log-spread of that length, from the real runs' 50th and 90th percentiles, " + _POP,
        ),
    )
    gross_size_min_m: float = field(
        default=0.15,
        metadata=_meta(
            "m",
            "assumption",
            "smallest displacement of a failure's distal joints (a gross failure is large by "
            "definition; smaller errors are the continuous processes)",
        ),
    )
    gross_size_scale_m: float = field(
        default=0.097,
        metadata=_meta(
            "m",
            "measurement",
            "mean excess of a thrown leg's (and a whole-body jump's) displacement over "
            "gross_size_min_m (exponential): fitted so the simulated leg runs at 0 degrees peak "
            "as far above 20 cm as the real ones (9-11 cm on average; the real peaks fall off "
            "exponentially): mean of the fits on participants 0-4 / 5-9 (0.081 / 0.113), " + _POP,
        ),
    )
    gross_arm_duration_median_s: float = field(
        default=0.26,
        metadata=_meta(
            "s",
            "measurement",
            "median length of a thrown arm (log-normal, gross_duration_log_sigma): real arm runs "
            "above 20 cm at 0 degrees last longer than leg runs (median 0.13-0.20 s against "
            "0.07-0.08 s on participants 0-4 / 5-9), fitted so the simulated runs have the real "
            "length: mean of the fits on the two halves (0.216 / 0.299), " + _POP,
        ),
    )
    gross_arm_size_scale_m: float = field(
        default=0.195,
        metadata=_meta(
            "m",
            "measurement",
            "gross_size_scale_m for arms: real arm runs at 0 degrees peak 16-17 cm above 20 cm on "
            "average, leg runs 9-11 cm, fitted so the simulated runs have the real peaks: mean "
            "of the fits on participants 0-4 / 5-9 (0.158 / 0.232), " + _POP,
        ),
    )
    gross_ramp_s: float = field(
        default=0.067,
        metadata=_meta(
            "s",
            "measurement",
            "onset and end of a failure, a linear ramp: real runs start with a jump of the "
            "disagreement of several cm in one frame (median 4-7 cm, the largest quarter "
            "11-16 cm), " + _POP,
        ),
    )
    gross_body_rate_hz: float = field(
        default=0.025,
        metadata=_meta(
            "1/s of motion per sensor",
            "measurement",
            "rate of whole-body jumps (every joint moved by one vector): runs in which the "
            "spine and neck are all more than 15 cm off, at 0 degrees, shared between the two "
            "sensors; 0 in the light model. " + _POP,
        ),
    )
    person_log_sigma: float = field(
        default=0.12,
        metadata=_meta(
            "1 (natural log)",
            "measurement",
            "spread of the subject-level tracking quality q (log-normal, median 1) that "
            "multiplies a subject's per-sensor continuous errors: the participants' spread of "
            "per-take median disagreement (log, robust), less the spread the model has without "
            "it; 0.07 fitted, 0.12 chosen (docs/realism.md section 6), 0 in the light model. "
            + _POP,
        ),
    )
    person_rate_exponent: float = field(
        default=0.8,
        metadata=_meta(
            "1",
            "measurement",
            "failure rates scale as q^exponent: slope of the log rate of real runs over 20 cm "
            "on the log per-take median, per layout, " + _POP,
        ),
    )

    def __post_init__(self) -> None:
        for name in (
            "subject_bias_sigma_m",
            "pose_bias_sigma_m",
            "jitter_sigma_m",
            "motion_noise_gain_s",
            "view_bias_sigma_m",
            "far_limb_sigma_m",
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
        for name in (
            "swap_prob_max",
            "inferred_blend",
            "min_visible_fraction",
            "side_inferred_max",
            "bone_hold_tracked",
            "bone_hold_inferred",
            "gross_leg_share",
        ):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise InputError(f"TrackerParams.{name} must be in [0, 1], got {v}")
        if not 0.0 <= self.limb_coherence < 1.0:
            raise InputError(
                f"TrackerParams.limb_coherence must be in [0, 1) (0: every joint's error its "
                f"own), got {self.limb_coherence}"
            )
        for name in (
            "pose_bias_tau_s",
            "jitter_tau_s",
            "motion_noise_tau_s",
            "inferred_tau_s",
            "swap_tau_s",
            "dropout_mean_s",
            "noise_reference_range_m",
            "pose_clock_speed_m_s",
            "swap_angle_width_deg",
            "view_bias_width_deg",
            "side_inferred_tau_s",
            "far_limb_tau_s",
            "view_correlation_deg",
            "gross_duration_median_s",
            "gross_arm_duration_median_s",
        ):
            v = getattr(self, name)
            if not v > 0:
                raise InputError(f"TrackerParams.{name} must be positive, got {v}")
        for name in (
            "surface_pushback_m",
            "surface_depth_gain",
            "depth_axis_factor",
            "inferred_sigma_m",
            "inferred_max_offset_m",
            "occlusion_margin_m",
            "occlusion_sample_radius",
            "dropout_rate_hz",
            "noise_range_exponent",
            "pose_clock_floor",
            "view_bias_exponent",
            "far_limb_exponent",
            "hf_jitter_sigma_m",
            "side_inferred_onset_deg",
            "swap_min_facing_deg",
            "gross_limb_rate_hz",
            "gross_duration_log_sigma",
            "gross_size_min_m",
            "gross_size_scale_m",
            "gross_arm_size_scale_m",
            "gross_ramp_s",
            "gross_body_rate_hz",
            "gross_moving_above_m_s",
            "person_log_sigma",
            "person_rate_exponent",
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


#: The model before issue 21 (``--tracker light``): the gross-failure processes and the person
#: level off (a rate or sigma of 0 draws nothing) and the view-dependent offset growing as
#: |sin(view)|^4 as fitted on the three shared takes; a session simulated with it is bit for bit
#: the one every figure stood on before issue 21. The default model has the processes on and
#: the exponent refitted, on the KinectMultiTrack population (studies/fit_tracker_tails.py,
#: docs/realism.md section 6).
LIGHT: dict[str, float] = {
    "gross_limb_rate_hz": 0.0,
    "gross_body_rate_hz": 0.0,
    "person_log_sigma": 0.0,
    "view_bias_exponent": 4.0,
    "limb_coherence": 0.0,
}


def light_tracker(params: TrackerParams | None = None) -> TrackerParams:
    """``params`` (default: the default model) as :data:`LIGHT`: without the gross failures and
    the person level, the lighter-tailed model of before issue 21 (``--tracker light``; its
    joints' errors independent, as they were then)."""
    base = params if params is not None else TrackerParams()
    return replace(base, **LIGHT)  # type: ignore[arg-type]


#: Parts of the error model that a simulation can switch off (``simulate --errors-off``): each
#: part's fields are set to 0. ``subject``, ``view``, ``inferred`` and ``swap`` are drawn once
#: per session and shared by its sensors (:class:`kinefuse.sim.tracker.SubjectBias`); the
#: others each sensor draws on its own random stream, and ``independent`` names them all. The
#: surface pull, the tracking states, the bone-length hold and the dropouts (whole frames lost,
#: not errors) stay. Every part's random numbers are drawn as with the part on and scaled by its
#: 0, so the same seed simulates the same session without it: the difference is what the part
#: costs.
ERROR_PARTS: Final[dict[str, tuple[str, ...]]] = {
    "subject": ("subject_bias_mean_m", "subject_bias_sigma_m"),
    "view": ("view_bias_sigma_m",),
    "inferred": ("inferred_sigma_m",),
    "swap": ("swap_prob_max",),
    "pose": ("pose_bias_sigma_m",),
    "jitter": ("jitter_sigma_m", "motion_noise_gain_s", "hf_jitter_sigma_m"),
    "far": ("far_limb_sigma_m",),
    "gross": ("gross_limb_rate_hz", "gross_body_rate_hz"),
}
ERROR_PARTS["independent"] = tuple(
    f for part in ("pose", "jitter", "far", "gross") for f in ERROR_PARTS[part]
)


def _zeroed(value: Any) -> Any:
    """``value`` (a number or nested tuples of numbers) with every number 0."""
    return tuple(_zeroed(v) for v in value) if isinstance(value, tuple) else 0.0


def without_parts(params: TrackerParams, parts: Sequence[str]) -> TrackerParams:
    """``params`` with the :data:`ERROR_PARTS` named in ``parts`` switched off."""
    unknown = [p for p in parts if p not in ERROR_PARTS]
    if unknown:
        raise InputError(
            f"unknown error-model part(s) {', '.join(map(repr, unknown))}; choose from "
            f"{', '.join(ERROR_PARTS)}"
        )
    off = {f: _zeroed(getattr(params, f)) for p in parts for f in ERROR_PARTS[p]}
    return replace(params, **off)

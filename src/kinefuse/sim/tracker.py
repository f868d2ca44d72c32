"""The Kinect v2 body-tracker error model: what the tracker reports for each joint, given the truth.

A real Kinect v2 does not see joints: it classifies depth pixels of the body surface and regresses
25 joint positions from them, frame by frame, with its own idea of where a joint is. Against
optical motion capture its joints are off by 5-10 cm for most joints, with ankles and feet the
worst (Wang et al. 2015; Otte et al. 2016; Xu & McGorry 2015). This module turns true joint
positions into what such a tracker reports, with these components (every number lives in
:class:`TrackerParams`, with its unit and source; ``docs/error_model_tracker.md`` explains them):

(a) **Systematic bias**.
    *Subject-level* (:class:`SubjectBias`, drawn once per session by :func:`draw_subject_bias`,
    common to every sensor): the tracker's joint definitions differ from the mocap's (hip centres
    higher and wider, ankles higher ...). It is expressed in a body frame (right, forward, up), so
    it moves with the body. *View-dependent*: an offset that is a smooth function of the view
    angle, nothing from the front or back and the most from the side (where the trunk, head and
    hips are hardest to place); and the surface pull: the tracker sees the body surface and pushes
    its estimate a fixed distance behind it (Shotton et al. 2011), so a joint deep inside a thick
    body part ends up pulled toward the sensor along the viewing ray, a thin part pushed away; the
    depth below the surface is ray-cast against the capsule body. A per-sensor *pose-dependent*
    offset, which changes as the pose changes and holds while the person holds still, adds what
    two co-located real sensors still disagree on.
(b) **Smoothed, correlated jitter** (the SDK filters its output): per joint and axis, white noise
    through two low-pass stages, larger along the depth axis, growing with the joint's speed and
    with distance, and a small high-frequency part on top. Limb joints on the far side of the body
    from the sensor get an extra slow error (self-occlusion by the trunk).
(c) **States**: joints hidden by the body from the sensor (rays cast from the optical centre to
    the joint and around it against the capsules, ignoring the capsules the joint lies inside)
    are ``INFERRED``, with a larger error (pulled, by at most a set distance, toward the last pose
    seen, moved with the body, else the mirrored twin as last seen, else a standing pose); joints
    outside the depth camera's view or range are ``INFERRED`` too, at the guess alone (the SDK
    documents that joints it cannot see are inferred from the rest of the body). Seen from the
    side, the trunk, head and hips are ``INFERRED`` in runs. Every reported bone is pulled toward
    the body's own length (fully for a guessed joint), so the skeleton stays plausible.
(d) **Left/right swaps**: a tracker assumes the person faces it; the probability that it labels
    the body mirrored is zero up to a side view, rises with the facing angle beyond it and
    persists over runs of frames.
(e) **Dropouts**: occasional runs of frames where the body is lost (all joints ``NOT_TRACKED``).
(g) **Gross failures and the person level** (:mod:`kinefuse.sim.tracker_failures`): per sensor,
    thrown limbs and whole-body jumps (Poisson events, log-normal lengths, 15-50 cm); per
    subject, a tracking-quality factor that scales the per-sensor errors and the failure rates.
    Both draw from child random streams, so the other components' draws are as before.

The inferred-joint errors, the side-view offsets and the swap decisions are smooth random
functions of time and of the viewing direction in the body frame (:class:`SessionLatent`), drawn
once per session with the subject bias: sensors that look from nearby directions make the same
mistakes, as two real co-located Kinects do. Everything is vectorized over frames and joints; the
filters run in :func:`scipy.signal.lfilter`. ``docs/realism.md`` says which parameter was fitted
to which real take.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import ndtr

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.geometry.raycast import ray_capsules_batched
from kinefuse.core.skeleton import (
    JOINT_INDEX,
    MIRROR_INDEX,
    N_JOINTS,
    TrackingState,
    bone_index_array,
)
from kinefuse.errors import InputError
from kinefuse.sim.people import MOSTLY_HIDDEN_FRACTION
from kinefuse.sim.tracker_body import (
    _body_axes,
    _check_rigid,
    _default_local,
    _dropout_mask,
    _smooth,
    _smooth_along,
    body_visibility,
    bone_lengths,
    chain_correlate,
    far_side,
    hold_to_body,
    joint_radii,
)
from kinefuse.sim.tracker_failures import draw_quality, gross_failures
from kinefuse.sim.tracker_params import (
    JOINT_GROUPS,
    TrackerParams,
    describe_params,
    per_joint,
)

__all__ = [
    "JOINT_GROUPS",
    "SessionLatent",
    "SubjectBias",
    "TrackerOutput",
    "TrackerParams",
    "body_visibility",
    "describe_params",
    "draw_subject_bias",
    "joint_radii",
    "per_joint",
    "simulate_tracker",
]

Array = NDArray[np.float64]


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
        # tau_s = inf: a field of the view angle only, constant in time
        omega = rng.normal(0.0, 1.0, n_features) / tau_s
        return cls(
            omega_rad_s=np.asarray(omega, dtype=np.float64),
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
    view_latent : SessionLatent or None
        75 fields constant in time: the view-dependent offset per joint and body axis, in units
        of ``TrackerParams.view_bias_sigma_m``, as a function of the view angle.
        ``None`` latents are drawn per sensor inside :func:`simulate_tracker` (independent
        sensors).
    quality : float
        How badly this subject is tracked (1: typical): multiplies the per-sensor continuous
        errors and the gross-failure rates (``TrackerParams.person_log_sigma``).
    """

    offsets_body_m: Array
    swap_latent: SessionLatent | None = None
    inferred_latent: SessionLatent | None = None
    view_latent: SessionLatent | None = None
    quality: float = 1.0

    def __post_init__(self) -> None:
        a = np.asarray(self.offsets_body_m, dtype=np.float64)
        if a.shape != (N_JOINTS, 3) or not np.all(np.isfinite(a)):
            raise InputError(
                f"SubjectBias.offsets_body_m must be a finite ({N_JOINTS}, 3) array, got {a.shape}"
            )
        object.__setattr__(self, "offsets_body_m", a)
        if not (np.isfinite(self.quality) and self.quality > 0):
            raise InputError(f"SubjectBias.quality must be a positive number, got {self.quality}")
        if self.swap_latent is not None and self.swap_latent.n_fields != 1:
            raise InputError("SubjectBias.swap_latent must have exactly 1 field")
        if self.inferred_latent is not None and self.inferred_latent.n_fields != 3 * N_JOINTS:
            raise InputError(f"SubjectBias.inferred_latent must have {3 * N_JOINTS} fields")
        if self.view_latent is not None and self.view_latent.n_fields != 3 * N_JOINTS:
            raise InputError(f"SubjectBias.view_latent must have {3 * N_JOINTS} fields")

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
    # one limb, one error: the definition offsets of a limb's joints are coherent along the
    # chain (as the per-sensor fields are), so a limb is displaced rather than kinked
    unit = chain_correlate(rng.normal(size=(1, N_JOINTS, 3)), p.limb_coherence)[0]
    offsets = mean + unit * sigma[:, None]
    swap, inferred, view = _draw_latents(rng, p)
    # the person level from a child stream: the draws above are those of the model without it
    quality = draw_quality(rng.spawn(1)[0], p)
    return SubjectBias(
        offsets, swap_latent=swap, inferred_latent=inferred, view_latent=view, quality=quality
    )


def _draw_latents(
    rng: np.random.Generator, p: TrackerParams
) -> tuple[SessionLatent, SessionLatent, SessionLatent]:
    width = np.radians(p.view_correlation_deg)
    return (
        SessionLatent.draw(rng, 1, p.swap_tau_s, width),
        SessionLatent.draw(rng, 3 * N_JOINTS, p.inferred_tau_s, width),
        SessionLatent.draw(rng, 3 * N_JOINTS, np.inf, np.radians(p.view_bias_width_deg)),
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
        :class:`kinefuse.core.skeleton.TrackingState` per reported joint.
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
    others: Sequence[tuple[Array, Array]] = (),
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
        Capsule radius per bone (:func:`kinefuse.core.skeleton.capsule_radii`), metres.
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
    others : sequence of ((T, 25, 3) float, (24,) float)
        The other people in the room at the same instants (true joints, world frame, and their
        capsule radii): a joint they hide from the sensor is not visible (as one the body hides
        itself), and a body mostly hidden by them is lost
        (:data:`kinefuse.sim.people.MOSTLY_HIDDEN_FRACTION`). None: the subject alone (no draw
        changes either way).

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
    if subj.swap_latent is None or subj.inferred_latent is None or subj.view_latent is None:
        own = _draw_latents(rng, p)
    swap_latent = subj.swap_latent if subj.swap_latent is not None else own[0]
    inferred_latent = subj.inferred_latent if subj.inferred_latent is not None else own[1]
    view_latent = subj.view_latent if subj.view_latent is not None else own[2]
    rot = s2w[:3, :3]
    ones = np.arange(N_JOINTS)
    q = float(subj.quality)  # how badly this subject is tracked (1: typical)

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
    by_others = hidden_by_others(truth, s2w[:3, 3], others)
    visible &= ~by_others

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
    side_view = np.abs(np.sin(view))  # 0 seen from the front or back, 1 from the side

    # (e) body lost: dropouts, or too little of it in view
    lost = _dropout_mask(rng, n_t, dt, p) | (in_view.sum(axis=1) < p.min_joints_in_view)
    lost |= by_others.sum(axis=1) > MOSTLY_HIDDEN_FRACTION * N_JOINTS

    # (d) swaps: a persistent latent process thresholded at the facing-dependent probability,
    # which is zero up to a side view (a person facing the sensor is never mirrored)
    z = swap_latent(times, view)[:, 0]
    swapped = (ndtr(z) < swap_probability(facing, p)) & ~lost

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

    rho = p.limb_coherence  # per-joint error fields coherent along the chain
    # (a) subject bias in the body frame, and the view-dependent pull along the viewing ray
    bias = np.einsum("tik,jk->tji", axes_b, subj.offsets_body_m)
    rng_dist = np.linalg.norm(tb, axis=-1)
    u = tb / np.maximum(rng_dist, 1e-12)[..., None]
    pull = p.surface_depth_gain * depth_b - p.surface_pushback_m
    tracked_pos = tb + bias - u * pull[..., None]
    # view-dependent offset: a smooth function of the view angle shared by the session,
    # growing from nothing (front or back view) to view_bias_sigma_m (side view)
    vb = chain_correlate(view_latent(np.zeros(n_t), view).reshape(n_t, N_JOINTS, 3), rho)
    vb *= np.asarray(p.view_bias_sigma_m)[None, :, None]
    vb *= (q * side_view**p.view_bias_exponent)[:, None, None]
    tracked_pos += np.einsum("tik,tjk->tji", axes_b, vb)

    # per-sensor errors, smoothed as the SDK's output is: a slow pose-dependent offset, a
    # correlated jitter, speed-dependent noise, the far side of the body seen around the trunk,
    # and a small high-frequency jitter on top
    shape = (n_t, N_JOINTS, 3)
    if n_t > 1:  # speed relative to the pelvis: limbs moving within the body
        vel = np.gradient(p_true, dt, axis=0)
        rel = vel - vel[:, JOINT_INDEX["SpineBase"]][:, None, :]
        speed_true = np.linalg.norm(rel, axis=-1)
        body_speed = np.linalg.norm(vel, axis=-1).mean(axis=1)
        pelvis_speed = np.linalg.norm(vel[:, JOINT_INDEX["SpineBase"]], axis=-1)
    else:
        speed_true = np.zeros((n_t, N_JOINTS))
        body_speed = np.zeros(n_t)
        pelvis_speed = np.zeros(n_t)
    # the pose-dependent offset changes as the depth image changes: it runs on a "pose clock"
    # that ticks with the body's movement (and slowly while the person holds still)
    pose_clock = np.cumsum(dt * (p.pose_clock_floor + body_speed / p.pose_clock_speed_m_s))
    pose_sigma = q * np.asarray(p.pose_bias_sigma_m)
    pose_err = _smooth_along(rng, pose_clock, (N_JOINTS, 3), p.pose_bias_tau_s)
    pose_err = chain_correlate(pose_err, rho)
    tracked_pos += pose_err * pose_sigma[None, :, None]
    speed = np.take_along_axis(speed_true, perm, axis=1)
    range_factor = (rng_dist / p.noise_reference_range_m) ** p.noise_range_exponent
    axis_factor = np.array([1.0, 1.0, p.depth_axis_factor])
    static = np.asarray(p.jitter_sigma_m)[None, :]
    moving = q * np.asarray(p.motion_noise_gain_s)[None, :] * speed
    jitter = chain_correlate(_smooth(rng, shape, dt, p.jitter_tau_s), rho) * static[..., None]
    fast = chain_correlate(_smooth(rng, shape, dt, p.motion_noise_tau_s), rho)
    jitter += fast * moving[..., None]
    jitter += rng.standard_normal(shape) * p.hf_jitter_sigma_m
    tracked_pos += jitter * range_factor[..., None] * axis_factor
    far = far_side(view, perm)  # (T, J) 0 near side or centre, 1 far side seen from the side
    far_sigma = q * np.asarray(p.far_limb_sigma_m)[None, :] * far**p.far_limb_exponent
    far_err = chain_correlate(_smooth(rng, shape, dt, p.far_limb_tau_s), rho) * far_sigma[..., None]
    tracked_pos += np.einsum("tik,tjk->tji", axes_b, far_err)

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
    infer_body = chain_correlate(inferred_latent(times, view).reshape(n_t, N_JOINTS, 3), rho)
    infer_body *= q * p.inferred_sigma_m
    infer_noise = np.einsum("tik,tjk->tji", axes_b, infer_body)
    # the guess pulls the joint, but the body seen around it keeps it near: the pull is at most
    # inferred_max_offset_m from where the tracker would have put it
    pull_to_guess = guess - tracked_pos
    size = np.linalg.norm(pull_to_guess, axis=-1, keepdims=True)
    pull_to_guess *= np.minimum(1.0, p.inferred_max_offset_m / np.maximum(size, 1e-9))
    inferred_pos = tracked_pos + p.inferred_blend * pull_to_guess + infer_noise

    states = np.full((n_t, N_JOINTS), TrackingState.INFERRED, dtype=np.int8)
    states[vis_b] = TrackingState.TRACKED
    # the trunk, head and hips seen from the side: INFERRED in runs, more often the more
    # side-on the view (a per-sensor smooth latent thresholded at the probability)
    z_side = _smooth(rng, (n_t, N_JOINTS), dt, p.side_inferred_tau_s)
    side_inf = never[None, :] & (ndtr(z_side) < side_inferred_probability(side_view, p)[:, None])
    states[side_inf & vis_b] = TrackingState.INFERRED
    out = np.where(vis_b[..., None], tracked_pos, inferred_pos)
    if p.out_of_view_inferred:
        # the camera saw nothing of a joint out of view: its position is the guess alone
        out = np.where(in_view_b[..., None], out, guess + infer_noise)
        not_tracked = np.broadcast_to(lost[:, None], (n_t, N_JOINTS))
    else:
        not_tracked = ~in_view_b | lost[:, None]
    # (g) gross failures of this sensor (thrown limbs, whole-body jumps), from a child stream
    # they start only while the person moves (none of the real runs starts in a still stand)
    moving = pelvis_speed > p.gross_moving_above_m_s
    gross = gross_failures(rng.spawn(1)[0], n_t, dt, p, q, moving)
    out = out + np.einsum("tik,tjk->tji", axes_b, gross)
    # the reported skeleton keeps plausible bone lengths: every bone is pulled toward the
    # body's own length (fully for a guessed joint), its subtree moving with it
    nominal = bone_lengths(tb + bias, seen)  # the body's size, from what was seen
    weight = np.where(vis_b, p.bone_hold_tracked, p.bone_hold_inferred)
    out = hold_to_body(out, nominal, weight)
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


def hidden_by_others(
    truth_world: Array, centre: Array, others: Sequence[tuple[Array, Array]]
) -> NDArray[np.bool_]:
    """``(T, 25)`` True where another person's capsule body lies on the line of sight from the
    sensor's optical centre ``centre`` (3,) to the true joint ``truth_world`` (T, 25, 3)."""
    hidden = np.zeros(truth_world.shape[:2], dtype=bool)
    if not others:
        return hidden
    bones = bone_index_array()
    a = np.concatenate([np.asarray(o)[:, bones[:, 0]] for o, _ in others], axis=1)
    b = np.concatenate([np.asarray(o)[:, bones[:, 1]] for o, _ in others], axis=1)
    radius = np.concatenate([np.asarray(r, dtype=np.float64) for _, r in others])
    to = truth_world - centre
    dist = np.linalg.norm(to, axis=-1)
    hit = ray_capsules_batched(centre, to / np.maximum(dist, 1e-9)[..., None], a, b, radius)
    return np.asarray(hit.min(axis=-1) < dist - _OTHERS_MARGIN_M)


#: a joint within this distance behind another person's surface is not counted hidden by it
#: (the two bodies touch: the tracker still segments the joint's own surface)
_OTHERS_MARGIN_M = 0.05


def swap_probability(facing_rad: ArrayLike, params: TrackerParams | None = None) -> Array:
    """Probability that a frame is labelled left/right mirrored, by facing angle ``(T,)``.

    A logistic rise toward ``swap_prob_max`` around ``swap_angle_mid_deg``, shifted and scaled
    so that it is exactly zero up to ``swap_min_facing_deg`` (a person facing the sensor, or seen
    from the side, is never mirrored).
    """
    p = TrackerParams() if params is None else params
    f = np.degrees(np.asarray(facing_rad, dtype=np.float64))

    def rise(x: Array | float) -> Array:
        return np.asarray(
            1.0 / (1.0 + np.exp(-(x - p.swap_angle_mid_deg) / p.swap_angle_width_deg))
        )

    lo = rise(p.swap_min_facing_deg)
    return np.asarray(p.swap_prob_max * np.clip((rise(f) - lo) / (1.0 - lo), 0.0, 1.0))


def side_inferred_probability(side_view: ArrayLike, params: TrackerParams | None = None) -> Array:
    """Probability that the trunk, head and hips are INFERRED, by ``|sin(view)|`` ``(T,)``."""
    p = TrackerParams() if params is None else params
    s0 = np.sin(np.radians(p.side_inferred_onset_deg))
    x = np.clip((np.asarray(side_view, dtype=np.float64) - s0) / max(1.0 - s0, 1e-9), 0.0, 1.0)
    return np.asarray(p.side_inferred_max * x**2)

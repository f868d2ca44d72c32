"""Parameterization (METHODS.md B.2): learned axes, rest position, angles, twist, kinematics.

For each limb the *samples* are its direction in the parent's normalized frame (the joint
sphere). :func:`learn_axes` filters the calibration phase by speed, extracts the movement axes
(Direction Joining by default; stratified PCA and EM kept for comparison), names and signs them
by anatomy (:mod:`kinefuse.biomech.anatomy`), and picks the rest position. :func:`joint_angles`
computes, for every frame, the angles about those axes (two axes: the circle-plane intersection
with the smooth choice of the two candidates), the off-axis angle of one-axis limbs and the twist
in closed form (swing-twist), vectorized over frames. :func:`reconstruct` runs the forward
kinematics back to positions; :func:`edit_pose` changes a pose by anatomical angle names.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from kinefuse.biomech import anatomy
from kinefuse.biomech._vec import dot, signed_angle, tmm, tmv, wrap
from kinefuse.biomech.axes import (
    DELTA_RAD,
    dj_axes,
    em_axes,
    movement_mask,
    pca_axes,
    plane_fit,
    smooth,
    stratify,
)
from kinefuse.biomech.limbs import LIMB_INDEX, LIMB_PARENTS, LIMBS
from kinefuse.biomech.normalize import Normalization
from kinefuse.biomech.sequence import SkeletonSequence
from kinefuse.core.geometry.rotations import chordal_mean, minimal_rotation, rodrigues, unit
from kinefuse.errors import InputError

Array = NDArray[np.float64]

METHODS = ("dj", "pca", "em")
#: A limb whose samples stay within this angle of their median direction did not move (rad).
NO_MOVEMENT_RAD = np.radians(5.0)
#: Movement samples of which 95 % lie within this angle of one plane through the joint centre
#: show one main direction only (rad): a second axis cannot be learned. The 95 % are of the
#: stratified samples (one per occupied cell of the joint sphere, :func:`~kinefuse.biomech.axes.
#: stratify`): of the *extent* of the movement on the sphere, not of the time spent in it (see
#: :func:`_learn_limb`).
ONE_PLANE_RAD = np.radians(8.0)
#: A two-axis limb whose two learned axes are further than this from perpendicular (rad) has a
#: second axis that cannot be trusted: both axis planes pass through the rest direction and the
#: anatomical axes of a two-axis joint (flexion, ab-/adduction or lateral bend) are perpendicular
#: up to their tilt from the textbook axes (Baker 2003, Wu et al. 2005: about 10° each). A
#: second axis that leans towards the first by more has been fitted to the first direction's
#: samples or to a distorted second movement (issue 24: thighs on the held-out walkway's start
#: mark, 33-57° off perpendicular and 35-78° off the truth; the sweep's trusted second axes are
#: within 20° of perpendicular). See :func:`_learn_limb` for what replaces it.
SECOND_AXIS_SKEW_RAD = np.radians(25.0)
#: A limb is given one axis only where that costs little in position: one angle puts the limb's
#: end on its hinge plane's circle through the rest, so over the phase it loses the off-plane
#: angle times the limb's length. Above this budget (metres, mean over the phase's frames) the
#: limb gets two axes whatever the one-plane test says (ours; issue 24: the sweep's
#: reconstruction mean was one-axis limbs leaving their hinge plane). Below the issue's 1.5 mm.
ONE_AXIS_BUDGET_M = 1.0e-3
#: Samples within this angle of the rest sample are averaged into the rest frame (rad).
REST_RADIUS_RAD = np.radians(3.0)
#: Window of the moving average applied to the calibration samples, seconds.
SMOOTH_S = 0.2
#: A two-axis limb within this angle of its fixed axis is in gimbal lock (see
#: :func:`undefined_angles`): its fixed-axis angle and twist are reported as not defined there
#: (rad; at 20° a direction error is magnified at most 1 / sin 20° = 2.9 times).
GIMBAL_RAD = np.radians(20.0)
#: A two-axis limb changes between the two representations of its direction (see
#: :func:`_branch`) only where the other is nearer to the rest by more than this (summed
#: ``|angle|`` about the two axes, rad).
CHART_MARGIN_RAD = np.radians(25.0)


@dataclass(frozen=True, eq=False)
class LimbModel:
    """What the calibration phase taught about one limb.

    Attributes
    ----------
    name : str
    status : str
        ``"ok"``, or why the limb has fewer or no axes (``"no movement ..."``,
        ``"one axis only ..."``, ``"missing ..."``), or why its second axis is the one
        perpendicular to the first and the rest (``"second axis not trusted ..."``,
        ``"second axis not observed ..."``).
    axes : (k, 3) float
        Unit movement axes in the parent's normalized frame, JCS order (fixed axis first), signed
        so that positive angles are the ISB direction; ``k = 0`` when nothing could be learned.
    axis_names : tuple of str
        Anatomical name of the angle about each axis.
    template_deviation_rad : (k,) float
        Angle between each learned axis and its anatomical template.
    rest : (3,) float
        Unit rest direction in the parent's frame.
    rest_frame : (3, 3) float
        The limb's frame in the parent's frame at rest (its long axis maps to ``rest``).
    length_m : float
        Median limb length, metres.
    offset_m : (3,) float
        The proximal joint relative to the parent limb's proximal joint, in the parent's frame
        (median), metres; used by the forward kinematics when the proximal joint is not the
        parent's distal joint.
    ranges_rad : (k, 2) float
        Smallest and largest angle of the (smoothed) calibration phase.
    off_axis_sd_rad : float
        Robust spread (1.4826 MAD) of the angle off the learned axes in the calibration phase.
    n_movement : int
        Movement samples used for the axes.
    axes_decision : str
        Which test decided the number of axes (the one-plane test, the position budget
        :data:`ONE_AXIS_BUDGET_M`, the anatomy or the caller), with its figures.
    refused : bool
        The limb was not learned because the caller refused it (``learn_axes(refuse=...)``:
        the sensors did not see it in the phase): no angle of it is reported, not even those
        that need no learned axes (the shoulder's elevation and plane).
    """

    name: str
    status: str
    axes: Array
    axis_names: tuple[str, ...] = ()
    template_deviation_rad: Array = field(default_factory=lambda: np.zeros(0))
    rest: Array = field(default_factory=lambda: np.full(3, np.nan))
    rest_frame: Array = field(default_factory=lambda: np.full((3, 3), np.nan))
    length_m: float = float("nan")
    offset_m: Array = field(default_factory=lambda: np.zeros(3))
    ranges_rad: Array = field(default_factory=lambda: np.zeros((0, 2)))
    off_axis_sd_rad: float = float("nan")
    n_movement: int = 0
    axes_decision: str = ""
    refused: bool = False

    @property
    def usable(self) -> bool:
        return self.axes.shape[0] > 0


@dataclass(frozen=True, eq=False)
class AxisModel:
    """Learned axes of all limbs (see :class:`LimbModel`), with the method and phase."""

    limbs: dict[str, LimbModel]
    method: str
    phase_s: tuple[float, float]

    @property
    def status(self) -> dict[str, str]:
        return {k: v.status for k, v in self.limbs.items()}

    def axes_parent(self) -> dict[str, Array]:
        """Axes ``(k, 3)`` per limb in the parent's normalized frame."""
        return {k: v.axes for k, v in self.limbs.items()}


def limb_samples(seq: SkeletonSequence, norm: Normalization, limb: str) -> Array:
    """A limb's vector ``(T, 3)`` (proximal -> distal, metres) in its parent's normalized frame."""
    i = LIMB_INDEX[limb]
    lb = LIMBS[i]
    p = seq.kinect_positions()
    v = p[:, lb.distal_index] - p[:, lb.proximal_index]
    par = LIMB_PARENTS[i]
    if par < 0:
        return v
    return tmv(norm.frames[:, par], v)


#: The fewest frames a calibration phase must hold to learn axes from.
MIN_PHASE_FRAMES = 10


def _phase_frames(seq: SkeletonSequence, phase: tuple[float, float] | None) -> NDArray[np.intp]:
    if phase is None:
        return np.arange(seq.n_frames)
    lo, hi = float(phase[0]), float(phase[1])
    if not hi > lo:
        raise InputError(
            f"the calibration phase must be START_S:END_S with END > START, got {phase}"
        )
    f = np.flatnonzero((seq.t_s >= lo) & (seq.t_s <= hi))
    if f.size < MIN_PHASE_FRAMES:
        raise InputError(
            f"the calibration phase {lo:g}:{hi:g} s holds {f.size} frames; the sequence spans "
            f"{seq.t_s[0]:.2f} to {seq.t_s[-1]:.2f} s: give a phase of a few seconds inside it"
        )
    return f


def learn_axes(
    seq: SkeletonSequence,
    norm: Normalization,
    /,
    phase: tuple[float, float] | None = None,
    *,
    method: str = "dj",
    n_axes: dict[str, int] | None = None,
    delta_deg: float = 15.0,
    refuse: dict[str, str] | None = None,
    seen_frames: NDArray[np.bool_] | None = None,
) -> AxisModel:
    """Learn every limb's movement axes and rest position from a calibration phase.

    Parameters
    ----------
    seq, norm : the sequence and its :func:`~kinefuse.biomech.normalize.normalize` result.
    phase : (start_s, end_s), optional
        The calibration phase, seconds on ``seq.t_s`` (default: the whole sequence).
    method : ``"dj"`` | ``"pca"`` | ``"em"``
        Direction Joining (the paper's), stratified PCA, or EM started from PCA.
    n_axes : dict limb -> int, optional
        Override the anatomical number of axes (1 or 2) of some limbs.
    delta_deg : float
        Direction Joining's threshold delta, degrees.
    refuse : dict limb -> str, optional
        Limbs not to learn (no axes), with the reason that becomes their status (e.g. the
        sensors did not see them during the phase).
    seen_frames : (T, L) bool, optional
        Per frame and limb (:data:`~kinefuse.biomech.limbs.LIMB_INDEX`), whether the limb was
        seen well (a fused session: tracked by two or more sensors). A limb's samples are its
        direction in its parent's frame, so its axes are learned from the movement samples of
        the frames in which it and its parent were both seen; the others (one sensor's view, or
        the fusion's prediction where no sensor tracked it) are left out of the axes (not of
        the rest, where the limb stands).

    Returns
    -------
    AxisModel
        A :class:`LimbModel` per limb (except the root pelvis), each with its status; limbs that
        did not move, or show fewer main directions than asked, say so in ``status``.
    """
    if method not in METHODS:
        raise InputError(f"unknown axis method {method!r}; choose one of {', '.join(METHODS)}")
    n_axes = dict(n_axes or {})
    bad = {k: v for k, v in n_axes.items() if k not in LIMB_INDEX or v not in (1, 2)}
    if bad:
        raise InputError(f"n_axes must map limb names to 1 or 2, got {bad}")
    frames = _phase_frames(seq, phase)
    seen = None if seen_frames is None else np.asarray(seen_frames, dtype=bool)
    if seen is not None and seen.shape != (seq.n_frames, len(LIMBS)):
        raise InputError(
            f"seen_frames must be ({seq.n_frames}, {len(LIMBS)}) bool (frames x limbs), got "
            f"{seen.shape}"
        )
    p_all = seq.kinect_positions()
    out: dict[str, LimbModel] = {}
    delta = np.radians(delta_deg)
    for i, lb in enumerate(LIMBS):
        if LIMB_PARENTS[i] < 0:
            continue
        if refuse and lb.name in refuse:
            out[lb.name] = LimbModel(
                name=lb.name, status=refuse[lb.name], axes=np.zeros((0, 3)), refused=True
            )
            continue
        k = n_axes.get(lb.name, lb.n_axes)
        vec = limb_samples(seq, norm, lb.name)
        # the limb and its parent seen: its movement samples are measured, not guessed
        trusted = None if seen is None else (seen[:, i] & seen[:, LIMB_PARENTS[i]])[frames]
        forced = lb.name in n_axes
        out[lb.name] = _learn_limb(
            seq, norm, lb.name, vec, frames, p_all, k, method, delta, forced=forced,
            trusted=trusted,
        )  # fmt: skip
    span = (float(seq.t_s[frames[0]]), float(seq.t_s[frames[-1]]))
    return AxisModel(limbs=out, method=method, phase_s=span)


def _learn_limb(
    seq: SkeletonSequence,
    norm: Normalization,
    name: str,
    vec: Array,
    frames: NDArray[np.intp],
    p_all: Array,
    k: int,
    method: str,
    delta: float,
    *,
    forced: bool = False,
    trusted: NDArray[np.bool_] | None = None,
) -> LimbModel:
    """One limb's axes and rest from its samples ``vec`` over the phase's ``frames``;
    ``trusted`` (over ``frames``): the movement samples the axes may use (:func:`learn_axes`'s
    ``seen_frames``); the rest is where the limb stands in the whole phase."""
    i = LIMB_INDEX[name]
    lb = LIMBS[i]
    par = LIMB_PARENTS[i]
    lengths = np.linalg.norm(vec, axis=-1)
    length = float(np.nanmedian(lengths)) if np.isfinite(lengths).any() else float("nan")
    pp = LIMBS[par].proximal_index
    off = tmv(norm.frames[:, par], p_all[:, lb.proximal_index] - p_all[:, pp])
    offset = np.nanmedian(off, axis=0) if np.isfinite(off).any() else np.zeros(3)
    # depth-sensor noise: a centred moving average of 0.2 s keeps the great circles (averages of
    # points on one plane through the centre stay on it) and takes the jitter out (ours)
    u = smooth(unit(vec[frames]), round(SMOOTH_S * seq.rate_hz / 2))
    ok: NDArray[np.bool_] = np.asarray(np.isfinite(u).all(axis=-1))
    base = {"name": name, "length_m": length, "offset_m": offset}
    if ok.sum() < 10:
        return LimbModel(
            status=f"missing: {lb.proximal}/{lb.distal} present in {int(ok.sum())} of "
            f"{frames.size} calibration frames (need 10)",
            axes=np.zeros((0, 3)),
            **base,  # type: ignore[arg-type]
        )
    med = unit(np.nanmedian(u[ok], axis=0))
    spread = np.arccos(np.clip(u[ok] @ med, -1.0, 1.0))
    if np.percentile(spread, 99.5) < NO_MOVEMENT_RAD:
        return LimbModel(
            status=f"no movement: the limb stays within {np.degrees(NO_MOVEMENT_RAD):.0f}° of "
            "one direction in the calibration phase; move it along its main directions",
            axes=np.zeros((0, 3)),
            **base,  # type: ignore[arg-type]
        )
    moving, _ = movement_mask(u, seq.rate_hz, smooth_s=0.0)
    moving &= ok
    if moving.sum() < 10:
        moving = np.array(ok, dtype=bool)
    # the axes from the trusted movement samples (if there are enough); where the limb rests
    # (below) from every stationary one: a rest seen by one sensor is still where it rests, and
    # the seen frames of a limb that one sensor sees standing are its movements away from it
    # (a tilted rig's right shank, seen by two sensors in 18 % of its phase: knee flexion 6.6 ->
    # 12.8 deg RMSE with the rest from those frames alone)
    axis_samples = moving
    if trusted is not None and (moving & trusted).sum() >= 10:
        axis_samples = moving & trusted
    seg = np.cumsum(np.concatenate([[True], axis_samples[1:] != axis_samples[:-1]]))
    m_u, m_seg = u[axis_samples], seg[axis_samples]
    status = "ok"
    # one plane or two: judged on the stratified samples (one per cell of the sphere), i.e. on
    # where the limb went, not how long it stayed there. Counted in time, the test was decided
    # by the movement filter: samples near the rest direction (sway, the parent's movements, a
    # second mode of slow speeds that the histogram valley let through; 800-1100 of 1800 phase
    # samples in fused and even in true sessions) lie on *every* plane through the rest, and
    # diluted a 50° ab-/adduction of the thigh below 5 % of the samples (issue 24: "the
    # movement lies on one plane, 95 % of it within 5.8°" while the phase moved it along two)
    strat = stratify(m_u)
    one = plane_fit(strat)
    p95_off = float(np.arcsin(min(np.percentile(np.abs(strat @ one), 95), 1.0)))
    # where the limb rests (the stationary samples' centre of gravity), for the position cost
    # and the rest position below
    still = ok & ~moving
    g = unit((u[still] if still.sum() >= 10 else m_u).mean(axis=0))
    cost = _one_axis_cost_m(one, g, u[ok], length)
    figures = (
        f"95 % of the movement within {np.degrees(p95_off):.1f}° of one plane (one-plane test: "
        f"{np.degrees(ONE_PLANE_RAD):.0f}°); one axis would leave it {1e3 * cost:.2f} mm off "
        f"its plane, mean over the phase (budget {1e3 * ONE_AXIS_BUDGET_M:.1f} mm)"
    )
    cheap = not cost > ONE_AXIS_BUDGET_M  # NaN length: the plane test alone
    if forced:
        decision = f"asked for {k} axis(es) by the caller; {figures}"
    elif k == 2 and p95_off < ONE_PLANE_RAD and cheap:
        decision = f"one axis: the one-plane test and the position budget; {figures}"
    elif k == 2 and p95_off < ONE_PLANE_RAD:
        decision = f"two axes: the position budget overrules the one-plane test; {figures}"
    elif k == 2:
        decision = f"two axes: the one-plane test; {figures}"
    elif cheap:
        decision = f"one axis: anatomy, within the position budget; {figures}"
    else:
        decision = f"two axes: the position budget overrules the anatomy's one axis; {figures}"
    if k == 2 and p95_off < ONE_PLANE_RAD and (cheap or forced):
        status = (
            f"one axis only: asked for 2 axes, but the movement lies on one plane "
            f"(95 % of it within {np.degrees(p95_off):.1f}°); learned 1 axis"
        )
        k = 1
    if k == 1:
        # one main direction: the paper's "straightforward regression", the same for all three
        # methods: the plane through the joint centre fitted to the stratified movement samples
        axes = one[None]
        if not cheap and not forced and lb.n_axes == 1:
            # the hinge, and for what leaves its plane the axis perpendicular to it and to the
            # rest (the off-plane movement's great circle through the rest; ours)
            axes = np.stack([one, unit(np.cross(g, one))])
    elif method == "pca":
        axes = pca_axes(m_u, k)
    elif method == "em":
        axes = em_axes(m_u, k)
    else:
        axes, _ = dj_axes(m_u, m_seg, k, delta=delta)
        if axes.shape[0] < k and k == 2 and not cheap and axes.shape[0] == 1:
            # over the position budget one axis loses the limb's off-plane movement: the second
            # axis is the one perpendicular to the first and the rest, as for a second axis not
            # trusted (ours; a walk without a calibration phase: the thighs' quick swings make
            # one main direction, their ab-/adduction none, and one axis cost 20-24 mm)
            status = (
                "second axis not observed: Direction Joining found one main direction, and one "
                f"axis would leave the limb {1e3 * cost:.1f} mm off its plane (budget "
                f"{1e3 * ONE_AXIS_BUDGET_M:.1f} mm); the second axis is the one perpendicular to "
                "the first and the rest direction"
            )
            decision = f"two axes: the position budget, one main direction found; {figures}"
            axes = np.stack([axes[0], unit(np.cross(g, axes[0]))])
        elif axes.shape[0] < k:
            status = (
                f"one axis only: asked for {k} axes, Direction Joining found "
                f"{axes.shape[0]} main direction(s)"
            )
            decision = f"one axis: Direction Joining found one main direction; {figures}"
            if axes.shape[0] == 0:
                axes = one[None]
    axes, names, dev, _ = anatomy.assign_axes(name, axes)
    if axes.shape[0] == 2 and abs(float(axes[0] @ axes[1])) > np.cos(2 * DELTA_RAD):
        status = "one axis only: the two learned axes are within 30° of each other"
        axes, names, dev = axes[:1], names[:1], dev[:1]
    elif axes.shape[0] == 2:
        axes, dev, status = _trusted_second_axis(name, axes, dev, g, status)
    # rest position. One axis: the point of its circle nearest the centre of gravity of the
    # *stationary* samples (the paper takes all samples, which puts a hinge's zero in the middle
    # of its range: the actor returns to the default pose between movements). Two axes: the
    # stationary samples nearest that centre of gravity, not where the learned axis planes meet
    # the sphere (the paper's): fused movements lie a few degrees beside the standing pose (the
    # sensors' slowly varying offsets differ between moving and standing), so the planes' meeting
    # point is off the pose the limb rests in, and every angle carried that offset as its zero
    # (issue 24: the sweep's worst twist median 6.0 -> 4.5 deg, the same reconstruction)
    target = g if axes.shape[0] == 2 else unit(g - dot(g, axes[0]) * axes[0])
    ang = np.arccos(np.clip(u @ target, -1.0, 1.0))
    ang[~ok] = np.inf
    j = int(np.argmin(ang))
    near = ok & (np.arccos(np.clip(u @ u[j], -1.0, 1.0)) < REST_RADIUS_RAD) & ~moving
    near[j] = True
    rest = unit(u[near].mean(axis=0))
    fr = frames[near]
    q = tmm(norm.frames[fr, par], norm.frames[fr, i])
    q = q[np.isfinite(q).all(axis=(1, 2))]
    a_l = norm.long_axis[i]
    if q.shape[0]:
        q0 = chordal_mean(q)
        rest_frame = minimal_rotation(q0 @ a_l, rest) @ q0
    else:
        rest_frame = np.full((3, 3), np.nan)
    model = LimbModel(
        status=status,
        axes=axes,
        axis_names=names,
        template_deviation_rad=dev,
        rest=rest,
        rest_frame=rest_frame,
        n_movement=int(moving.sum()),
        axes_decision=decision,
        **base,  # type: ignore[arg-type]
    )
    ang_v, off_v = swing_angles(model, u)
    ranges = np.nanpercentile(ang_v, [0, 100], axis=0).T if np.isfinite(ang_v).any() else None
    med_off = np.nanmedian(off_v) if np.isfinite(off_v).any() else 0.0
    sd = 1.4826 * float(np.nanmedian(np.abs(off_v - med_off))) if np.isfinite(off_v).any() else 0.0
    return LimbModel(
        status=status,
        axes=axes,
        axis_names=names,
        template_deviation_rad=dev,
        rest=rest,
        rest_frame=rest_frame,
        ranges_rad=np.zeros((axes.shape[0], 2)) if ranges is None else ranges,
        off_axis_sd_rad=sd,
        n_movement=int(moving.sum()),
        axes_decision=decision,
        **base,  # type: ignore[arg-type]
    )


def _one_axis_cost_m(a: Array, g: Array, u: Array, length: float) -> float:
    """Mean position error (metres) of one angle about ``a`` for directions ``u (n, 3)``: the
    elevation off the axis plane relative to the rest's (``g``) times the limb's length."""
    elev = np.arcsin(np.clip(u @ a, -1.0, 1.0)) - np.arcsin(np.clip(float(g @ a), -1.0, 1.0))
    return float(np.mean(np.abs(elev)) * length) if u.shape[0] else float("nan")


def _trusted_second_axis(
    name: str, axes: Array, dev: Array, g: Array, status: str
) -> tuple[Array, Array, str]:
    """The second axis, or its replacement when it is too far from perpendicular to the first
    (:data:`SECOND_AXIS_SKEW_RAD`): the axis perpendicular to the first axis and to the rest
    direction ``g`` (both axis planes pass through the rest), signed as the learned one; the
    status says so (ours)."""
    skew = np.pi / 2 - float(np.arccos(min(abs(float(axes[0] @ axes[1])), 1.0)))
    if skew <= SECOND_AXIS_SKEW_RAD:
        return axes, dev, status
    a1 = unit(np.cross(g, axes[0]))
    a1 = a1 if float(a1 @ axes[1]) >= 0 else -a1
    tpl = anatomy.templates(name)
    d1 = float(np.arccos(min(abs(float(a1 @ tpl[1][1])), 1.0))) if len(tpl) > 1 else np.nan
    status = (
        f"second axis not trusted: the learned axes are {np.degrees(np.pi / 2 - skew):.0f}° "
        f"apart (a two-axis joint's are near 90°, more than "
        f"{np.degrees(SECOND_AXIS_SKEW_RAD):.0f}° off it here): the phase's second movement was "
        "observed too poorly; replaced by the axis perpendicular to the first and the rest "
        "direction"
    )
    return np.stack([axes[0], a1]), np.array([dev[0], d1]), status


def swing_angles(model: LimbModel, u: Array) -> tuple[Array, Array]:
    """Angles ``(T, k)`` about the learned axes and the off-axis angle ``(T,)`` (rad) for unit
    directions ``u (T, 3)`` in the parent frame.

    One axis ``a``: the rotation about ``a`` from the rest ``r`` to ``u``; the off-axis angle is
    the change of elevation from the axis plane. Two axes (``u = R(a0, t0) R(a1, t1) r``): the
    intermediate ``x`` lies on the circle about ``a1`` through ``r`` and on the circle about
    ``a0`` through ``u``; their planes meet in a line that meets the sphere in two candidates;
    the one on the rest's side of the plane spanned by the axes is taken (the floating angle
    within +-90°), switching to the other only where the trajectory passes over the fixed
    axis (the smooth choice, see :func:`_branch`). The off-axis angle is the remaining angle
    when no candidate exists (``u`` out of reach of the two circles). Near the fixed axis
    ``t0`` is ill-conditioned (:func:`undefined_angles`); it is returned all the same (with the
    twist it gives back the limb's frame), and
    :meth:`~kinefuse.biomech.kinematics.Angles.anatomical` reports it as not defined there.
    """
    ang, off, _ = swing_and_undefined(model, u)
    return ang, off


def swing_and_undefined(model: LimbModel, u: Array) -> tuple[Array, Array, NDArray[np.bool_]]:
    """:func:`swing_angles` and :func:`undefined_angles` in one pass (the candidate choice is
    computed once)."""
    r = model.rest
    a = model.axes
    t = u.shape[0]
    if a.shape[0] == 0:
        return np.full((t, 0), np.nan), np.full(t, np.nan), np.zeros((t, 1), dtype=bool)
    bad = np.zeros((t, a.shape[0] + 1), dtype=bool)
    with np.errstate(invalid="ignore"):
        bad[:, 0] = bad[:, -1] = np.abs(u @ a[0]) > np.cos(GIMBAL_RAD)
    if a.shape[0] == 1:
        a0 = np.broadcast_to(a[0], u.shape)
        th = signed_angle(np.broadcast_to(r, u.shape), u, a0)
        off = np.arcsin(np.clip(u @ a[0], -1, 1)) - np.arcsin(np.clip(r @ a[0], -1, 1))
        return th[:, None], off, bad
    t0, t1, off, ambiguous = _intermediate(a[0], a[1], r, u)
    bad |= ambiguous[:, None]
    return np.stack([t0, t1], axis=-1), off, bad


def _intermediate(
    a0: Array, a1: Array, r: Array, u: Array
) -> tuple[Array, Array, Array, NDArray[np.bool_]]:
    """``t0, t1`` (rad) of the chosen candidate (see :func:`swing_angles`), the off-axis angle
    and the ambiguous frames, all ``(T,)``."""
    c = float(a0 @ a1)
    n = np.cross(a0, a1)
    n /= np.linalg.norm(n)
    h0 = u @ a0  # x . a0 = u . a0 (circle about a0 through u)
    h1 = float(r @ a1)  # x . a1 = r . a1 (circle about a1 through r)
    det = 1.0 - c * c
    al = (h0 - c * h1) / det
    be = (h1 - c * h0) / det
    m = al[:, None] * a0 + be[:, None] * a1
    g2 = 1.0 - dot(m, m)
    g = np.sqrt(np.maximum(g2, 0.0))
    off = np.where(g2 < 0, np.sqrt(np.maximum(-g2, 0.0)), 0.0)
    rest_side = 1.0 if float(r @ n) >= 0 else -1.0
    x_p = unit(m + (rest_side * g)[:, None] * n)  # the principal candidate and the other
    x_o = unit(m - (rest_side * g)[:, None] * n)
    rel, ambiguous, t0, t1 = _branch(u, a0, a1, r, x_p, x_o)
    return np.where(rel > 0, t0[0], t0[1]), np.where(rel > 0, t1[0], t1[1]), off, ambiguous


def undefined_angles(model: LimbModel, u: Array) -> NDArray[np.bool_]:
    """Where the angles of directions ``u (T, 3)`` are not defined: ``(T, k + 1)`` bool, one
    column per learned axis and the last for the twist.

    * Within :data:`GIMBAL_RAD` of the fixed (first) axis, either end (gimbal lock for two
      axes, e.g. the arm abducted 70-110°; a hinge gets there only 70° out of its plane): the
      angle about that axis turns ``u`` about itself and cannot be told apart from the twist
      (only their sum is defined); a direction error ``e`` moves each by
      ``e / sin(angle to the axis)``. Both are not defined there.
    * Two axes, where the two representations of the direction (see :func:`_branch`) are about
      equally near the rest (within :data:`CHART_MARGIN_RAD`; high elevations between the
      pole and overhead): which one a frame gets is decided by its noise, and they differ by
      180° in the fixed angle and the twist. All angles are not defined there.
    """
    return swing_and_undefined(model, u)[2]


def _branch(
    u: Array, a0: Array, a1: Array, r: Array, x_p: Array, x_o: Array
) -> tuple[Array, NDArray[np.bool_], tuple[Array, Array], tuple[Array, Array]]:
    """The candidate per frame ``(T,)``: ``+1`` the principal one ``x_p`` (the floating angle
    within +-90°), ``-1`` the other (``x_o``); the frames ``(T,)`` where the choice is
    ambiguous; and ``t0``, ``t1`` of both candidates (ours).

    The two candidates are two charts of the sphere (``t0' = t0 + 180°``,
    ``t1' ~ 180° - t1``) with their poles at +-``a0`` (gimbal lock); each is continuous but at
    the poles and they agree only there. Hence:

    * away from the poles a frame takes the chart whose angles are nearer to the rest (smaller
      ``|t0| + |t1|``): an arm lifted sideways over 90° reads abduction 120°, flexion 0°, not
      flexion 180°, abduction 60°; an arm forward-up reads flexion 100°, abduction 60°, not
      flexion -80°, abduction 120°. Where the two are nearer than :data:`CHART_MARGIN_RAD`
      the frame is *ambiguous* (a few degrees of noise decide; the angles are reported as not
      defined there, :func:`undefined_angles`);
    * within a run of frames nearer than :data:`GIMBAL_RAD` to a pole (where ``t0`` is
      ill-conditioned and not defined) the chart switches at the frame closest to the pole,
      the only place where the two agree: before it each frame takes the chart whose ``t0``
      is nearer to ``t0`` at the last frame before the run, after it the one nearer to ``t0``
      at the first frame after the run (an arm lifted to 100° and lowered again inside the run
      reads abduction 100°, not 80°).

    The paper's smooth choice was made along the trajectory before (switch where it came
    within 3° of the axes' plane, back to the principal chart within 60° of the rest): under
    1 cm of noise a few degrees decided, and a wrong choice turned flexion and the twist by
    180° for seconds.
    """
    t = u.shape[0]
    a0b, a1b = np.broadcast_to(a0, u.shape), np.broadcast_to(a1, u.shape)
    rb = np.broadcast_to(r, u.shape)
    t0 = {1.0: signed_angle(x_p, u, a0b), -1.0: signed_angle(x_o, u, a0b)}
    t1 = (signed_angle(rb, x_p, a1b), signed_angle(rb, x_o, a1b))
    diff = np.abs(t0[1.0]) + np.abs(t1[0]) - np.abs(t0[-1.0]) - np.abs(t1[1])
    with np.errstate(invalid="ignore"):
        near = np.abs(u @ a0) > np.cos(GIMBAL_RAD)
        rel = np.where(diff > 0, -1.0, 1.0)  # +1 the principal chart, -1 the other
        ambiguous = (np.abs(diff) < CHART_MARGIN_RAD) & ~near
    runs = np.flatnonzero(np.diff(np.concatenate([[0], near.astype(np.int8), [0]])))
    for a, b in zip(runs[::2], runs[1::2], strict=True):  # run [a, b) near a pole
        ref_in = t0[rel[a - 1]][a - 1] if a > 0 else np.nan
        ref_out = t0[rel[b]][b] if b < t else np.nan
        ref_in = ref_out if not np.isfinite(ref_in) else ref_in
        ref_out = ref_in if not np.isfinite(ref_out) else ref_out
        if not np.isfinite(ref_in):
            continue  # nothing to continue from: the principal chart
        closest = np.abs(u[a:b] @ a0)
        split = a + (int(np.nanargmax(closest)) if np.isfinite(closest).any() else 0)
        ref = np.where(np.arange(a, b) < split, ref_in, ref_out)
        d_p = np.abs(wrap(t0[1.0][a:b] - ref))
        d_o = np.abs(wrap(t0[-1.0][a:b] - ref))
        rel[a:b] = np.where(d_o < d_p, -1.0, 1.0)
    return rel, np.asarray(ambiguous, dtype=bool), (t0[1.0], t0[-1.0]), t1


def _swing_matrices(model: LimbModel, ang: Array, off: Array | None, u: Array | None) -> Array:
    """Rotations ``(T, 3, 3)`` in the parent frame taking ``rest`` to the limb direction: the
    learned-axis rotations, then the off-axis part (to ``u`` exactly when given, else by the
    off-axis angle for one-axis limbs, else none)."""
    a = model.axes
    t = ang.shape[0]
    s = np.broadcast_to(np.eye(3), (t, 3, 3)).copy()
    for j in range(a.shape[0] - 1, -1, -1):  # u = R(a0) R(a1) r: apply a1 first
        s = rodrigues(np.broadcast_to(a[j], (t, 3)), np.nan_to_num(ang[:, j])) @ s
    v = s @ model.rest
    if u is not None:
        s = minimal_rotation(v, np.where(np.isfinite(u), u, v)) @ s
    elif off is not None and a.shape[0] == 1:
        ax = unit(np.cross(v, np.broadcast_to(a[0], v.shape)))
        ax = np.where(np.isfinite(ax), ax, 0.0)
        s = rodrigues(ax, np.nan_to_num(off)) @ s
    return s

"""Parameterization (METHODS.md B.2): learned axes, rest position, angles, twist, kinematics.

For each limb the *samples* are its direction in the parent's normalized frame (the joint
sphere). :func:`learn_axes` filters the calibration phase by speed, extracts the movement axes
(Direction Joining by default; stratified PCA and EM kept for comparison), names and signs them
by anatomy (:mod:`kinefuse.analysis.anatomy`), and picks the rest position. :func:`joint_angles`
computes, for every frame, the angles about those axes (two axes: the circle-plane intersection
with the smooth choice of the two candidates), the off-axis angle of one-axis limbs and the twist
in closed form (swing-twist), vectorized over frames. :func:`reconstruct` runs the forward
kinematics back to positions; :func:`edit_pose` changes a pose by anatomical angle names.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from kinefuse.analysis import anatomy
from kinefuse.analysis._vec import (
    chordal_mean,
    dot,
    minimal_rotation,
    rodrigues,
    signed_angle,
    tmm,
    tmv,
    unit,
    wrap,
)
from kinefuse.analysis.axes import (
    DELTA_RAD,
    dj_axes,
    em_axes,
    movement_mask,
    pca_axes,
    plane_fit,
    smooth,
    stratify,
)
from kinefuse.analysis.limbs import LIMB_INDEX, LIMB_PARENTS, LIMBS
from kinefuse.analysis.normalize import Normalization
from kinefuse.analysis.sequence import SkeletonSequence
from kinefuse.errors import InputError

Array = NDArray[np.float64]

METHODS = ("dj", "pca", "em")
#: A limb whose samples stay within this angle of their median direction did not move (rad).
NO_MOVEMENT_RAD = np.radians(5.0)
#: Movement samples of which 95 % lie within this angle of one plane through the joint centre
#: show one main direction only (rad): a second axis cannot be learned.
ONE_PLANE_RAD = np.radians(8.0)
#: Samples within this angle of the rest sample are averaged into the rest frame (rad).
REST_RADIUS_RAD = np.radians(3.0)
#: Window of the moving average applied to the calibration samples, seconds.
SMOOTH_S = 0.2
#: A two-axis limb within this angle of its fixed axis is in gimbal lock (see
#: :func:`gimbal_lock`): its fixed-axis angle and twist are reported as not defined there
#: (rad; at 20° a direction error is magnified at most 1 / sin 20° = 2.9 times).
GIMBAL_RAD = np.radians(20.0)


@dataclass(frozen=True, eq=False)
class LimbModel:
    """What the calibration phase taught about one limb.

    Attributes
    ----------
    name : str
    status : str
        ``"ok"``, or why the limb has fewer or no axes (``"no movement ..."``,
        ``"one axis only ..."``, ``"missing ..."``).
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


def _phase_frames(seq: SkeletonSequence, phase: tuple[float, float] | None) -> NDArray[np.intp]:
    if phase is None:
        return np.arange(seq.n_frames)
    lo, hi = float(phase[0]), float(phase[1])
    if not hi > lo:
        raise InputError(
            f"the calibration phase must be START_S:END_S with END > START, got {phase}"
        )
    f = np.flatnonzero((seq.t_s >= lo) & (seq.t_s <= hi))
    if f.size < 10:
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
) -> AxisModel:
    """Learn every limb's movement axes and rest position from a calibration phase.

    Parameters
    ----------
    seq, norm : the sequence and its :func:`~kinefuse.analysis.normalize.normalize` result.
    phase : (start_s, end_s), optional
        The calibration phase, seconds on ``seq.t_s`` (default: the whole sequence).
    method : ``"dj"`` | ``"pca"`` | ``"em"``
        Direction Joining (the paper's), stratified PCA, or EM started from PCA.
    n_axes : dict limb -> int, optional
        Override the anatomical number of axes (1 or 2) of some limbs.
    delta_deg : float
        Direction Joining's threshold delta, degrees.

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
    p_all = seq.kinect_positions()
    out: dict[str, LimbModel] = {}
    delta = np.radians(delta_deg)
    for i, lb in enumerate(LIMBS):
        if LIMB_PARENTS[i] < 0:
            continue
        k = n_axes.get(lb.name, lb.n_axes)
        vec = limb_samples(seq, norm, lb.name)
        out[lb.name] = _learn_limb(seq, norm, lb.name, vec, frames, p_all, k, method, delta)
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
) -> LimbModel:
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
    seg = np.cumsum(np.concatenate([[True], moving[1:] != moving[:-1]]))
    m_u, m_seg = u[moving], seg[moving]
    status = "ok"
    one = plane_fit(m_u)
    p95_off = float(np.arcsin(min(np.percentile(np.abs(m_u @ one), 95), 1.0)))
    if k == 2 and p95_off < ONE_PLANE_RAD:
        status = (
            f"one axis only: asked for 2 axes, but the movement lies on one plane "
            f"(95 % of it within {np.degrees(p95_off):.1f}°); learned 1 axis"
        )
        k = 1
    if k == 1:
        # one main direction: the paper's "straightforward regression", the same for all three
        # methods: the plane through the joint centre fitted to the stratified movement samples
        axes = plane_fit(stratify(m_u))[None]
    elif method == "pca":
        axes = pca_axes(m_u, k)
    elif method == "em":
        axes = em_axes(m_u, k)
    else:
        axes, _ = dj_axes(m_u, m_seg, k, delta=delta)
        if axes.shape[0] < k:
            status = (
                f"one axis only: asked for {k} axes, Direction Joining found "
                f"{axes.shape[0]} main direction(s)"
            )
            if axes.shape[0] == 0:
                axes = one[None]
    axes, names, dev, _ = anatomy.assign_axes(name, axes)
    if axes.shape[0] == 2 and abs(float(axes[0] @ axes[1])) > np.cos(2 * DELTA_RAD):
        status = "one axis only: the two learned axes are within 30° of each other"
        axes, names, dev = axes[:1], names[:1], dev[:1]
    # rest position: where the axis planes meet the sphere, nearest the centre of gravity of
    # the *stationary* samples (ours; the paper takes all samples, which puts a hinge's zero in
    # the middle of its range: the actor returns to the default pose between movements)
    still = ok & ~moving
    g = unit((u[still] if still.sum() >= 10 else m_u).mean(axis=0))
    if axes.shape[0] == 2:
        c = unit(np.cross(axes[0], axes[1]))
        target = c if dot(c, g) >= 0 else -c
    else:
        target = unit(g - dot(g, axes[0]) * axes[0])
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
        **base,  # type: ignore[arg-type]
    )


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
    (:func:`gimbal_lock`) ``t0`` is ill-conditioned; it is returned all the same (with the twist
    it gives back the limb's frame), and :meth:`~kinefuse.analysis.kinematics.Angles.anatomical`
    reports it as not defined there.
    """
    r = model.rest
    a = model.axes
    t = u.shape[0]
    if a.shape[0] == 0:
        return np.full((t, 0), np.nan), np.full(t, np.nan)
    if a.shape[0] == 1:
        a0 = np.broadcast_to(a[0], u.shape)
        th = signed_angle(np.broadcast_to(r, u.shape), u, a0)
        off = np.arcsin(np.clip(u @ a[0], -1, 1)) - np.arcsin(np.clip(r @ a[0], -1, 1))
        return th[:, None], off
    x, off = _intermediate(a[0], a[1], r, u)
    a0 = np.broadcast_to(a[0], u.shape)
    a1 = np.broadcast_to(a[1], u.shape)
    t1 = signed_angle(np.broadcast_to(r, u.shape), x, a1)
    t0 = signed_angle(x, u, a0)
    return np.stack([t0, t1], axis=-1), off


def _intermediate(a0: Array, a1: Array, r: Array, u: Array) -> tuple[Array, Array]:
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
    sign = _branch(u, a0, r, unit(m + (rest_side * g)[:, None] * n), rest_side)
    x = m + (sign * g)[:, None] * n
    return unit(x), off


def gimbal_lock(model: LimbModel, u: Array) -> NDArray[np.bool_]:
    """Frames ``(T,)`` where the limb's direction ``u (T, 3)`` lies within :data:`GIMBAL_RAD`
    of its fixed (first) axis, either end: there the angle about that axis is not defined (it
    turns ``u`` about itself) and cannot be told apart from the twist (only their sum is
    defined), and a direction error ``e`` moves each of them by ``e / sin(angle to the axis)``.
    A two-axis limb gets there in gimbal lock (the arm abducted 90°), a hinge only when it left
    its plane by 70° or more. All False for limbs without axes."""
    if model.axes.shape[0] == 0:
        return np.zeros(u.shape[0], dtype=bool)
    with np.errstate(invalid="ignore"):
        return np.asarray(np.abs(u @ model.axes[0]) > np.cos(GIMBAL_RAD), dtype=bool)


def _branch(u: Array, a0: Array, r: Array, x_p: Array, rest_side: float) -> Array:
    """The candidate per frame ``(T,)``: ``rest_side`` (the principal one, floating angle within
    +-90°) or its opposite, the smooth choice through the fixed axis' poles.

    The two candidates are two charts of the sphere with their poles at +-``a0`` (gimbal
    lock); in the other chart the fixed-axis angle is the principal one + 180°. The principal
    chart is continuous everywhere but at the poles; a trajectory that passes *over* a pole
    (the arm abducted beyond 90°) continues smoothly in the other chart, one that passes beside
    it stays. Near a pole the fixed-axis angle is ill-conditioned, far from it well; so within
    each run of frames nearer than :data:`GIMBAL_RAD` to a pole, and at the first frame after
    it, the chart is the one whose fixed-axis angle is nearer to that angle at the last frame
    before the run (the fixed-axis angle cannot have turned by more than 90° while the limb
    was near the pole); the chart of the first frame after the run holds until the next run.
    Deciding from the distance to the pole (a switch where the trajectory came within a few
    degrees, as before) made the choice a coin flip under noise, and a wrong choice turned the
    fixed-axis angle and the twist by 180° for seconds. Within 60° of the rest the principal
    chart is taken (the rest is its origin), which also ends any wrong choice.
    """
    t = u.shape[0]
    with np.errstate(invalid="ignore"):
        near = np.abs(u @ a0) > np.cos(GIMBAL_RAD)
        at_rest = u @ r > np.cos(np.radians(60.0))
    t0 = signed_angle(x_p, u, np.broadcast_to(a0, u.shape))
    valid = np.flatnonzero(np.isfinite(t0) & ~near)
    sign = np.full(t, rest_side)
    state = rest_side

    def hold(lo: int, hi: int) -> None:  # frames [lo, hi) away from the poles
        nonlocal state
        sign[lo:hi] = state
        rest = np.flatnonzero(at_rest[lo:hi])
        if rest.size:
            sign[lo + rest[0] : hi] = rest_side
            state = rest_side

    pos = 0
    edges = np.flatnonzero(np.diff(np.concatenate([[0], near.astype(np.int8), [0]])))
    for a, b in zip(edges[::2], edges[1::2], strict=True):  # run [a, b) near a pole
        hold(pos, a)
        k = np.searchsorted(valid, a)
        if k == 0:  # the take starts near a pole: nothing to continue from
            sign[a:b] = state
            pos = b
            continue
        before = valid[k - 1]
        ref = t0[before] + (0.0 if sign[before] == rest_side else np.pi)
        stop = valid[k] + 1 if k < valid.size else b
        keep = np.abs(wrap(t0[a:stop] - ref)) <= 0.5 * np.pi
        sign[a:stop] = np.where(keep | ~np.isfinite(t0[a:stop]), rest_side, -rest_side)
        state = float(sign[stop - 1])
        if at_rest[b:stop].any():
            state = rest_side
        pos = b if stop <= b else stop
    hold(pos, t)
    return sign


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

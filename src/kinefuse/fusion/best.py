"""Our fusion ("best"): timestamp-aware, covariance-weighted, robust, swap-correcting, smoothed.

Each part can be switched off (:class:`BestOptions`) so that its gain can be measured:

``timestamp``
    Every observation is placed at its capture time on the server clock and each sensor's stream
    is interpolated to the common frame times. Off: the paper's frame assembly (each sensor's
    latest observation in the frame window, whatever its age).
``covariance``
    Each sensor's joint is a full 3D measurement weighted by its covariance: depth noise along the
    sensor's ray, lateral noise across it, inflated for ``INFERRED`` joints and joints the client
    flagged as occluded. Off: every measurement gets the same isotropic weight.
``robust``
    Measurements that disagree with the others beyond a chi-square gate are down-weighted
    (iteratively reweighted least squares with Huber weights on the Mahalanobis distance).
    Off: plain weighted mean.
``lr_swap``
    Sensors that see the person from behind report left and right swapped. The body's facing
    direction is agreed across sensors (a sensor whose reported facing points away from it cannot
    be swapped; one whose facing points toward it may be) and each observation that contradicts
    it is mirrored back. Off: observations used as reported.
``temporal``
    ``"smoother"`` (offline, Rauch-Tung-Striebel over a constant-velocity model per joint),
    ``"filter"`` (causal Kalman filter, for live use) or ``None``.
``bones``
    Bone lengths are estimated over the session (median) and every frame is projected onto them,
    moving each end in proportion to its uncertainty. Off: no constraint.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.ndimage import uniform_filter1d

from kinefuse.observations import BodyFrames
from kinefuse.skeleton import JOINT_INDEX, MIRROR_INDEX, N_JOINTS, TrackingState, bone_index_array
from kinefuse.sync.assembly import interp_neighbours, latest_in_window

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
    max_interp_gap_s: float = 0.1
    max_predict_s: float = 0.5
    #: per joint (25 values): lateral and axial measurement noise (m), process noise (m^2/s^3);
    #: tuples, so that options compare and hash (they key caches and the ablation table)
    lateral_m: tuple[float, ...] = tuple(_LATERAL_M.tolist())
    axial_m: tuple[float, ...] = tuple(_AXIAL_M.tolist())
    accel_psd: tuple[float, ...] = tuple(_ACCEL_PSD.tolist())

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


@dataclass(frozen=True)
class FusedSkeleton:
    """Fused joints on the frame grid.

    Attributes
    ----------
    t_server_s : (T,) float
    positions : (T, 25, 3) float
        World frame; NaN where there was nothing to fuse and nothing to predict from.
    variance_m2 : (T, 25) float
        Trace of the position covariance / 3 (a per-axis variance), NaN where positions are NaN.
    n_sensors : (T, 25) int
        Sensors that contributed (after gating).
    swaps : dict
        Per sensor index, the number of observations mirrored back.
    """

    t_server_s: Array
    positions: Array
    variance_m2: Array
    n_sensors: NDArray[np.intp]
    swaps: dict[int, int]


def _facing(p_world: Array) -> Array:
    """Horizontal unit facing direction ``(..., 3)`` of skeletons ``(..., 25, 3)`` (NaN: none)."""
    j = JOINT_INDEX
    lr = (p_world[..., j["HipLeft"], :] - p_world[..., j["HipRight"], :]) + (
        p_world[..., j["ShoulderLeft"], :] - p_world[..., j["ShoulderRight"], :]
    )
    f = np.cross(lr, np.array([0.0, 0.0, 1.0]))
    f[..., 2] = 0.0
    n = np.linalg.norm(f, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 1e-6, f / n, np.nan)


def correct_swaps(
    t_server_s: list[Array], p_world: list[Array], sensor_pos: Array, *, bin_s: float = 1 / 30
) -> list[NDArray[np.bool_]]:
    """Decide per observation whether left and right are swapped.

    Parameters
    ----------
    t_server_s : list of (N_s,) float
    p_world : list of (N_s, 25, 3) float
    sensor_pos : (S, 3) float

    Returns
    -------
    swapped : list of (N_s,) bool
    """
    n_s = len(p_world)
    t_all = np.concatenate(t_server_s)
    if t_all.size == 0 or n_s < 2:
        return [np.zeros(len(t), bool) for t in t_server_s]
    t0 = t_all.min()
    n_bins = int((t_all.max() - t0) / bin_s) + 1
    facing = [_facing(p) for p in p_world]
    # direction from the body to the sensor, horizontal
    toward = []
    for s in range(n_s):
        trunk = p_world[s][:, [JOINT_INDEX["SpineBase"], JOINT_INDEX["SpineShoulder"]]]
        c = np.where(np.isfinite(trunk).all(-1, keepdims=True), trunk, 0.0).sum(1)
        n_ok = np.isfinite(trunk).all(-1).sum(1)
        with np.errstate(invalid="ignore", divide="ignore"):
            c = c / np.where(n_ok > 0, n_ok, np.nan)[:, None]
        u = sensor_pos[s] - c
        u[:, 2] = 0.0
        with np.errstate(invalid="ignore"):
            toward.append(u / np.linalg.norm(u, axis=1, keepdims=True))
    # per bin: the facing consensus. Votes: an unambiguous sensor (reported facing points away
    # from it) votes its facing with weight 1; an ambiguous one votes its facing with weight 0.5
    # and, only as a tie-breaker, nothing for the mirrored one.
    votes = np.zeros((n_bins, 3))
    for s in range(n_s):
        b = ((t_server_s[s] - t0) / bin_s).astype(np.intp)
        f = facing[s]
        ok = np.isfinite(f).all(1) & np.isfinite(toward[s]).all(1)
        amb = np.einsum("ni,ni->n", np.nan_to_num(f), np.nan_to_num(toward[s])) > 0
        w = np.where(amb, 0.5, 1.0) * ok
        np.add.at(votes, b[ok], (np.nan_to_num(f) * w[:, None])[ok])
    # ambiguous sensors: the candidate consensus must respect that ambiguous facings could be
    # mirrored; resolve by the smoothed unambiguous evidence over a 1 s window, then per bin.
    k = max(round(1.0 / bin_s), 1)
    smooth = uniform_filter1d(votes, size=k, axis=0, mode="nearest")
    # bins with no evidence take the nearest bin's direction
    norm = np.linalg.norm(smooth, axis=1)
    have = norm > 1e-9
    if not have.any():
        return [np.zeros(len(t), bool) for t in t_server_s]
    idx = np.where(have, np.arange(n_bins), -1)
    idx = np.maximum.accumulate(idx)
    first = np.argmax(have)
    idx[idx < 0] = first
    consensus = smooth[idx] / norm[idx, None]
    out = []
    for s in range(n_s):
        b = np.clip(((t_server_s[s] - t0) / bin_s).astype(np.intp), 0, n_bins - 1)
        f = facing[s]
        agree = np.einsum("ni,ni->n", np.nan_to_num(f), consensus[b])
        amb = np.einsum("ni,ni->n", np.nan_to_num(f), np.nan_to_num(toward[s])) > 0
        out.append((agree < 0) & amb & np.isfinite(f).all(1))
    return out


def _measurement_cov(
    p_sensor: Array,
    states: NDArray[np.int8],
    occluded: NDArray[np.bool_] | None,
    r_s2w: Array,
    opt: BestOptions,
) -> Array:
    """World covariance ``(N, 25, 3, 3)`` of measurements in one sensor."""
    n = p_sensor.shape[0]
    if not opt.covariance:
        return np.broadcast_to(np.eye(3) * 0.03**2, (n, N_JOINTS, 3, 3)).copy()
    ray = p_sensor / np.linalg.norm(p_sensor, axis=-1, keepdims=True)
    ray = np.nan_to_num(ray)
    inflate = np.ones((n, N_JOINTS))
    inflate = np.where(states == TrackingState.INFERRED, opt.inferred_inflation, inflate)
    if occluded is not None:
        inflate = inflate * np.where(occluded, opt.occluded_inflation, 1.0)
    lat2 = (np.asarray(opt.lateral_m) ** 2)[None, :] * inflate**2
    ax2 = (np.asarray(opt.axial_m) ** 2)[None, :] * inflate**2
    outer = ray[..., :, None] * ray[..., None, :]
    cov_s = lat2[..., None, None] * (np.eye(3) - outer) + ax2[..., None, None] * outer
    return np.einsum("ij,ntjk,lk->ntil", r_s2w, cov_s, r_s2w)


def _interp_stream(
    t_grid: Array, t_obs: Array, p: Array, cov: Array, max_gap_s: float
) -> tuple[Array, Array]:
    """Linear interpolation of one stream ``(N, 25, 3)`` to ``t_grid``; NaN across big gaps.

    A joint missing at either neighbour is missing (unless the weight is 0/1 on the good one);
    its covariance is the larger of the two neighbours'.
    """
    i0, i1, w, ok = interp_neighbours(t_obs, t_grid, max_gap_s=max_gap_s)
    wv = w[:, None, None]
    out = np.where(ok[:, None, None], p[i0] * (1 - wv) + p[i1] * wv, np.nan)
    c = np.maximum(cov[i0], cov[i1]) if cov.size else cov
    c = np.where(np.isfinite(out)[..., None], c, np.nan)
    return out, c


def _latest_stream(
    t_grid: Array, t_obs: Array, p: Array, cov: Array, window_s: float
) -> tuple[Array, Array]:
    """The latest observation of one stream in ``(T - window_s, T]`` at each grid time."""
    rows, _, ok = latest_in_window(t_obs, t_grid, window_s=window_s)
    kk = np.maximum(rows, 0)
    out = np.where(ok[:, None, None], p[kk], np.nan)
    c = np.where(ok[:, None, None, None], cov[kk], np.nan)
    return out, c


def _robust_combine(
    p: Array, cov: Array, opt: BestOptions
) -> tuple[Array, Array, NDArray[np.intp]]:
    """Combine ``(T, S, J, 3)`` measurements with ``(T, S, J, 3, 3)`` covariances."""
    valid = np.asarray(np.isfinite(p).all(-1) & np.isfinite(cov).all((-1, -2)), dtype=bool)
    eye = np.eye(3)
    c = np.where(valid[..., None, None], cov, eye)
    w_mat = _inv3(c)
    w_mat = np.where(valid[..., None, None], w_mat, 0.0)
    z = np.where(valid[..., None], p, 0.0)
    rw: Array = valid.astype(np.float64)
    x = np.full(p.shape[:1] + p.shape[2:], np.nan)
    info = np.zeros(p.shape[:1] + p.shape[2:3] + (3, 3))
    n_iter = 4 if opt.robust else 1
    for it in range(n_iter):
        wm = w_mat * rw[..., None, None]
        info = wm.sum(axis=1)
        rhs = np.einsum("tsjab,tsjb->tja", wm, z)
        has = rw.sum(axis=1) > 0
        info_safe = np.where(has[..., None, None], info, eye)
        x = np.einsum("tjab,tjb->tja", _inv3(info_safe), rhs)
        x = np.where(has[..., None], x, np.nan)
        if not opt.robust or it == n_iter - 1:
            break
        r = z - np.nan_to_num(x)[:, None]
        d2 = (np.einsum("tsjab,tsjb->tsja", w_mat, r) * r).sum(-1)
        # Huber weights on the Mahalanobis distance: full weight inside the gate, falling off
        # as 1/d outside it
        rw = valid * np.minimum(1.0, np.sqrt(opt.gate_chi2 / np.maximum(d2, 1e-12)))
        # a measurement far outside the gate is dropped outright, unless that would drop
        # every measurement of the joint (two sensors that disagree: keep both, down-weighted)
        far = d2 > 4 * opt.gate_chi2
        keep_some = (valid & ~far).any(axis=1, keepdims=True)
        rw = np.where(far & keep_some, 0.0, rw)
    used = (rw > 0.2).sum(axis=1)
    has = rw.sum(axis=1) > 0
    cov_x = _inv3(np.where(has[..., None, None], info, eye))
    cov_x = np.where(has[..., None, None], cov_x, np.nan)
    return x, cov_x, used


def _inv3(m: Array) -> Array:
    """Inverses of ``(..., 3, 3)`` matrices by the adjugate (much faster than LAPACK per call)."""
    a, b, c = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    d, e, f = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    g, h, i = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    co = np.stack(
        [
            e * i - f * h, c * h - b * i, b * f - c * e,
            f * g - d * i, a * i - c * g, c * d - a * f,
            d * h - e * g, b * g - a * h, a * e - b * d,
        ],
        axis=-1,
    ).reshape(m.shape)  # fmt: skip
    det = a * co[..., 0, 0] + b * co[..., 1, 0] + c * co[..., 2, 0]
    return co / det[..., None, None]


def _kalman(
    t: Array, z: Array, r_cov: Array, q_psd: Array, *, smooth: bool, max_predict_s: float
) -> tuple[Array, Array]:
    """Constant-velocity Kalman filter (and RTS smoother) per joint and axis.

    Each axis of each joint is filtered on its own with the measurement's variance along that
    axis (the diagonal of the fused covariance; the cross-axis terms were used where they matter
    most, in the fusion across sensors). That makes every step plain element-wise arithmetic on
    ``(J, 3)`` arrays; the recursion over frames is sequential by nature.

    Parameters
    ----------
    t : (T,) float
        Frame times, seconds.
    z : (T, J, 3) float
        Measurements (NaN = none).
    r_cov : (T, J, 3, 3) float
        Their covariances.
    q_psd : (J,) float
        White-acceleration spectral density per joint.

    Returns
    -------
    positions : (T, J, 3) float
        NaN before a joint's first measurement and more than ``max_predict_s`` after its last.
    variance : (T, J) float
        Position variance per axis (mean over the axes).
    """
    n_t, n_j = z.shape[:2]
    dt = np.diff(t, prepend=t[0])
    r = np.diagonal(r_cov, axis1=-2, axis2=-1)  # (T, J, 3)
    has_all = np.isfinite(z) & np.isfinite(r)
    z0 = np.where(has_all, z, 0.0)
    r0 = np.where(has_all, r, 1.0)
    q = q_psd[:, None]
    shape = (n_j, 3)
    x, v = np.zeros(shape), np.zeros(shape)  # position, velocity
    pxx, pxv, pvv = np.zeros(shape), np.zeros(shape), np.zeros(shape)  # covariance entries
    started = np.zeros(shape, bool)
    last = np.full(shape, -np.inf)
    out_f = np.empty((5, n_t, n_j, 3))  # filtered x, v, pxx, pxv, pvv
    out_p = np.empty((5, n_t, n_j, 3))  # predicted
    alive = np.empty((n_t, n_j, 3), bool)
    for k in range(n_t):
        d = dt[k]
        # predict
        x = x + d * v
        pxx = pxx + 2 * d * pxv + d * d * pvv + q * d**3 / 3
        pxv = pxv + d * pvv + q * d**2 / 2
        pvv = pvv + q * d
        out_p[:, k] = x, v, pxx, pxv, pvv
        has = has_all[k]
        init = has & ~started
        started |= has
        # update (joints without a measurement get a zero gain)
        s = pxx + r0[k]
        kx = np.where(has, pxx / s, 0.0)
        kv = np.where(has, pxv / s, 0.0)
        innov = z0[k] - x
        x = x + kx * innov
        v = v + kv * innov
        pxx, pxv, pvv = (1 - kx) * pxx, (1 - kx) * pxv, pvv - kv * pxv
        # a joint's first measurement starts its filter: position measured, velocity unknown
        x = np.where(init, z0[k], x)
        v = np.where(init, 0.0, v)
        pxx = np.where(init, r0[k], pxx)
        pxv = np.where(init, 0.0, pxv)
        pvv = np.where(init, 1.0, pvv)  # 1 m/s a priori
        last = np.where(has, t[k], last)
        alive[k] = started & (t[k] - last <= max_predict_s)
        out_f[:, k] = x, v, pxx, pxv, pvv
    xf, vf, fxx, fxv, fvv = out_f
    if not smooth:
        return (
            np.where(alive, xf, np.nan),
            np.where(alive.all(-1), fxx.mean(-1), np.nan),
        )
    xp, vp, qxx, qxv, qvv = out_p
    # smoother gain C = P_f F^T P_p^-1 of the 2x2 blocks, for every frame at once
    d = dt[1:, None, None]
    a11, a12 = fxx[:-1] + d * fxv[:-1], fxv[:-1]  # (P_f F^T) rows
    a21, a22 = fxv[:-1] + d * fvv[:-1], fvv[:-1]
    b11, b12, b22 = qxx[1:], qxv[1:], qvv[1:]
    det = b11 * b22 - b12 * b12
    with np.errstate(invalid="ignore", divide="ignore"):
        i11, i12, i22 = b22 / det, -b12 / det, b11 / det
    c11, c12 = a11 * i11 + a12 * i12, a11 * i12 + a12 * i22
    c21, c22 = a21 * i11 + a22 * i12, a21 * i12 + a22 * i22
    xs, vs, sxx = xf.copy(), vf.copy(), fxx.copy()
    sxv, svv = fxv.copy(), fvv.copy()
    for k in range(n_t - 2, -1, -1):
        ok = alive[k] & alive[k + 1]
        dx, dv = xs[k + 1] - xp[k + 1], vs[k + 1] - vp[k + 1]
        xs[k] = np.where(ok, xf[k] + c11[k] * dx + c12[k] * dv, xf[k])
        vs[k] = np.where(ok, vf[k] + c21[k] * dx + c22[k] * dv, vf[k])
        e11, e12 = sxx[k + 1] - qxx[k + 1], sxv[k + 1] - qxv[k + 1]
        e22 = svv[k + 1] - qvv[k + 1]
        # P_s = P_f + C (P_s' - P_p') C^T, 2x2 per axis
        m11 = c11[k] * e11 + c12[k] * e12
        m12 = c11[k] * e12 + c12[k] * e22
        m21 = c21[k] * e11 + c22[k] * e12
        m22 = c21[k] * e12 + c22[k] * e22
        sxx[k] = np.where(ok, fxx[k] + m11 * c11[k] + m12 * c12[k], fxx[k])
        sxv[k] = np.where(ok, fxv[k] + m11 * c21[k] + m12 * c22[k], fxv[k])
        svv[k] = np.where(ok, fvv[k] + m21 * c21[k] + m22 * c22[k], fvv[k])
    return (
        np.where(alive, xs, np.nan),
        np.where(alive.all(-1), sxx.mean(-1), np.nan),
    )


def enforce_bone_lengths(
    positions: Array, variance: Array, *, iterations: int = 3
) -> tuple[Array, Array]:
    """Project every frame onto constant bone lengths (each bone's median over the sequence).

    Each bone's two ends move along the bone in proportion to their variances.

    Returns the adjusted positions ``(T, 25, 3)`` and the lengths ``(24,)``.
    """
    bones = bone_index_array()
    x = positions.copy()
    seg = x[:, bones[:, 1]] - x[:, bones[:, 0]]
    lengths = np.nanmedian(np.linalg.norm(seg, axis=-1), axis=0)
    var = np.where(np.isfinite(variance), variance, np.inf)
    for _ in range(iterations):
        for b, (pa, ch) in enumerate(bones):
            d = x[:, ch] - x[:, pa]
            n = np.linalg.norm(d, axis=-1)
            ok = np.isfinite(n) & (n > 1e-9) & np.isfinite(lengths[b])
            if not ok.any():
                continue
            corr = np.where(ok, (n - lengths[b]) / np.where(ok, n, 1.0), 0.0)[
                :, None
            ] * np.nan_to_num(d)
            vp, vc = var[:, pa], var[:, ch]
            tot = vp + vc
            with np.errstate(invalid="ignore", divide="ignore"):
                wc = np.where(np.isfinite(tot) & (tot > 0), vc / tot, 0.5)
            wc = np.where(np.isinf(vc) & np.isfinite(vp), 1.0, wc)
            wc = np.where(np.isinf(vp) & np.isfinite(vc), 0.0, wc)
            x[:, ch] -= wc[:, None] * corr
            x[:, pa] += (1 - wc)[:, None] * corr
    return x, lengths


def check_streams(streams: Sequence[BodyFrames], sensor2world: ArrayLike, what: str) -> Array:
    """Validate S streams (capture times on the server clock) against their poses
    ``(S, 4, 4)``; returns the poses as a float array."""
    if not streams:
        raise ValueError(f"{what} needs at least one sensor stream")
    poses = np.asarray(sensor2world, dtype=np.float64)
    if poses.shape != (len(streams), 4, 4) or not np.isfinite(poses).all():
        raise ValueError(
            f"{what}: sensor2world must be finite ({len(streams)}, 4, 4), one pose per stream; "
            f"got {poses.shape}"
        )
    for s in streams:
        if not np.isfinite(s.t_server_s).all():
            raise ValueError(
                f"{what}: sensor {s.sensor_id!r} has frames without a capture time on the "
                "server clock; map its clock first (BodyFrames.on_server)"
            )
    return poses


def fuse_best(
    streams: Sequence[BodyFrames],
    sensor2world: ArrayLike,
    t_grid_s: Array,
    options: BestOptions = BestOptions(),
    *,
    chunk: int = 2000,
) -> FusedSkeleton:
    """Fuse S sensor streams into one skeleton at the frame times ``t_grid_s`` ``(T,)``.

    ``streams`` carry their capture times on the server clock (``t_server_s``) and are in the
    frames of their sensors, whose poses are ``sensor2world (S, 4, 4)``."""
    poses = check_streams(streams, sensor2world, "fuse_best")
    t_grid = np.asarray(t_grid_s, dtype=np.float64)
    opt = options
    p_world, covs, t_obs = [], [], []
    for s, pose in zip(streams, poses, strict=True):
        r = pose[:3, :3]
        pw = s.joints_m @ r.T + pose[:3, 3]
        p_world.append(pw)
        covs.append(_measurement_cov(s.joints_m, s.states, s.occluded, r, opt))
        t_obs.append(s.t_server_s)
    swaps: dict[int, int] = {}
    if opt.lr_swap:
        sensor_pos = poses[:, :3, 3]
        flags = correct_swaps(t_obs, p_world, sensor_pos)
        mirror = np.asarray(MIRROR_INDEX)
        for i, fl in enumerate(flags):
            swaps[i] = int(fl.sum())
            if fl.any():
                p_world[i][fl] = p_world[i][fl][:, mirror]
                covs[i][fl] = covs[i][fl][:, mirror]
    n_t, n_s = t_grid.size, len(streams)
    fused = np.full((n_t, N_JOINTS, 3), np.nan)
    fcov = np.full((n_t, N_JOINTS, 3, 3), np.nan)
    used = np.zeros((n_t, N_JOINTS), dtype=np.intp)
    for a in range(0, n_t, chunk):
        tg = t_grid[a : a + chunk]
        zs = np.full((tg.size, n_s, N_JOINTS, 3), np.nan)
        cs = np.full((tg.size, n_s, N_JOINTS, 3, 3), np.nan)
        for i in range(n_s):
            if t_obs[i].size == 0:
                continue
            if opt.timestamp:
                zs[:, i], cs[:, i] = _interp_stream(
                    tg, t_obs[i], p_world[i], covs[i], opt.max_interp_gap_s
                )
            else:
                zs[:, i], cs[:, i] = _latest_stream(tg, t_obs[i], p_world[i], covs[i], 1 / 30)
        x, cx, u = _robust_combine(zs, cs, opt)
        fused[a : a + chunk], fcov[a : a + chunk], used[a : a + chunk] = x, cx, u
    if opt.temporal is not None:
        pos, var = _kalman(
            t_grid,
            fused,
            fcov,
            np.asarray(opt.accel_psd),
            smooth=opt.temporal == "smoother",
            max_predict_s=opt.max_predict_s,
        )
    else:
        pos = fused
        var = np.trace(fcov, axis1=-2, axis2=-1) / 3
    if opt.bones:
        pos, _ = enforce_bone_lengths(pos, var)
    return FusedSkeleton(
        t_server_s=t_grid, positions=pos, variance_m2=var, n_sensors=used, swaps=swaps
    )

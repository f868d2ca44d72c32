"""The fusion's model, shared by the causal ``best-live`` and the offline ``best`` (its replay).

Every function works on a batch of frames at once (the time axis first) with element-wise
arithmetic only (no reductions whose order depends on the batch size), so a frame fused alone
and the same frame fused in a batch give bit-identical numbers: what lets a replay batch the
parts that do not depend on the filter's past while staying identical to frame-by-frame
fusion.

- :func:`sensor_at`: one sensor's joints at frame times from its observations (interpolated
  between the two around the frame time when both have arrived, else the latest if recent);
- :func:`world_measurements`: those joints in the world with their covariances (lateral and
  axial noise per joint, inflated for INFERRED and occluded joints, grown with a held
  observation's age);
- :func:`swap_evidence`: what each sensor's skeleton says about the body's facing;
- :func:`robust_combine`: covariance-weighted, Huber-robust combination across sensors;
- :class:`KalmanState`, :func:`kalman_step`, :func:`rts_smooth`: the constant-velocity filter
  per joint and axis, and the Rauch-Tung-Striebel smoother over its recorded states.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from kinefuse.fusion.view import view_variance
from kinefuse.skeleton import JOINT_INDEX, N_JOINTS, TrackingState

Array = NDArray[np.float64]

_TRUNK = [JOINT_INDEX["SpineBase"], JOINT_INDEX["SpineShoulder"]]
_HIP_L, _HIP_R = JOINT_INDEX["HipLeft"], JOINT_INDEX["HipRight"]
_SH_L, _SH_R = JOINT_INDEX["ShoulderLeft"], JOINT_INDEX["ShoulderRight"]
#: the first observation of a stream stands for a frame time up to half a frame before it
_FIRST_LEAD_S = 0.5 / 30


def sensor_at(
    t: Array,
    available_s: Array,
    times: Array,
    count: NDArray[np.intp],
    joints: Array,
    states: NDArray[np.int8],
    occluded: NDArray[np.bool_] | None,
    *,
    max_gap_s: float,
    max_hold_s: float,
    timestamp: bool = True,
) -> tuple[Array, NDArray[np.int8], NDArray[np.bool_], Array]:
    """S sensors' joints at the frame times ``t (T,)`` from their observations.

    Parameters
    ----------
    t : (T,) float
        Frame times (server clock).
    available_s : (T,) float
        Per frame, the latest capture time that has arrived (a replay's ``t + latency``;
        ``inf`` for a live buffer, which holds only what arrived).
    times : (S, N) float
        Each sensor's observations' capture times, increasing over its first ``count[s]``.
    count : (S,) int
        How many of each row are observations (the rest is padding).
    joints, states, occluded : (S, N, 25, 3), (S, N, 25), (S, N, 25) or None
    max_gap_s : float
        Interpolate only between observations at most this far apart.
    max_hold_s : float
        Otherwise the latest observation stands for the frame if at most this old.
    timestamp : bool
        False: the paper's assembly instead (the latest observation within one frame before
        ``t``, no interpolation, no age).

    Returns
    -------
    joints (T, S, 25, 3), states (T, S, 25), occluded (T, S, 25), age_s (T, S)
        NaN / NOT_TRACKED / False / 0 where a sensor has nothing for the frame.
    """
    n_s, width = times.shape
    n = np.asarray(count)[None, :]  # (1, S)
    tt = t[:, None]
    if width <= 32:  # a live buffer: count the arrived observations up to t (padding excluded)
        valid = np.arange(width)[None, :] < n.T  # (S, N)
        k = ((times[None] <= tt[..., None]) & valid[None]).sum(-1)  # (T, S)
    else:
        k = np.stack([np.searchsorted(times[i, : int(n[0, i])], t, side="right")
                      for i in range(n_s)], axis=1)  # fmt: skip
    si = np.arange(n_s)[None, :]
    ka, kb = np.maximum(k - 1, 0), np.maximum(np.minimum(k, n - 1), 0)
    ta, tb = times[si, ka], times[si, kb]
    t0 = times[:, 0][None, :]
    if timestamp:
        avail = available_s[:, None]
        interp = (k > 0) & (k < n) & (tb <= avail) & (tb - ta <= max_gap_s)
        hold = ~interp & (k > 0) & (tt - ta <= max_hold_s)
        first = ~interp & (k == 0) & (n > 0) & (t0 - tt <= _FIRST_LEAD_S) & (t0 <= avail)
    else:
        interp = np.zeros(k.shape, bool)
        hold = (k > 0) & (tt - ta < 1.0 / 30)
        first = interp
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.where(tb > ta, (tt - ta) / (tb - ta), 0.0)[..., None, None]
    ja, jb = joints[si, ka], joints[si, kb]
    out = np.where(interp[..., None, None], ja * (1.0 - w) + jb * w, ja)
    sa = states[si, ka]
    st = np.where(interp[..., None], np.minimum(sa, states[si, kb]), sa)
    if occluded is None:
        occ = np.zeros(st.shape, bool)
    else:
        oa = occluded[si, ka]
        occ = np.where(interp[..., None], oa | occluded[si, kb], oa)
    age = np.where(interp, 0.0, np.abs(tt - ta)) if timestamp else np.zeros(k.shape)
    none = ~(interp | hold | first)
    if none.any():
        out[none] = np.nan
        st[none] = TrackingState.NOT_TRACKED
        occ[none] = False
        age[none] = 0.0
    return out, st.astype(np.int8, copy=False), occ, age


def world_measurements(
    joints: Array,
    states: NDArray[np.int8],
    occluded: NDArray[np.bool_],
    age_s: Array,
    sensor2world: Array,
    *,
    lateral_m: Array,
    axial_m: Array,
    inferred_inflation: float,
    occluded_inflation: float,
    covariance: bool = True,
    view: tuple[float, float, float, float] = (0.0, 2.0, 0.0, 2.0),
) -> tuple[Array, Array]:
    """Sensors' joints in the world and their covariances.

    Parameters
    ----------
    joints : (T, S, 25, 3) float
        In each sensor's frame, NaN = none.
    states, occluded : (T, S, 25)
    age_s : (T, S) float
        Age of a held observation: the body may have moved meanwhile (1 m/s a priori).
    sensor2world : (S, 4, 4) float
    lateral_m, axial_m : (25,) float
        Noise across and along the sensor's ray of a TRACKED, unoccluded joint.
    view : (view_sigma_m, view_exponent, far_sigma_m, far_exponent)
        The view-dependent variance of :func:`kinefuse.fusion.view.view_variance` (zero
        sigmas: none).

    Returns
    -------
    z : (T, S, 25, 3) float
    cov : (T, S, 25, 3, 3) float
        ``lat^2 I + (ax^2 - lat^2) u u^T`` with ``u`` the world ray (``R`` is a rotation, so
        this is ``R (lat^2 (I - r r^T) + ax^2 r r^T) R^T``), plus ``age^2 I`` and the view term.
    """
    r = sensor2world[:, :3, :3]  # (S, 3, 3)
    o = sensor2world[:, :3, 3]

    def rotate(v: Array) -> Array:
        return (r[:, None, :, 0] * v[..., 0, None] + r[:, None, :, 1] * v[..., 1, None]
                + r[:, None, :, 2] * v[..., 2, None])  # fmt: skip

    z = rotate(joints) + o[:, None, :]
    eye = np.eye(3)
    grow = (age_s * age_s)[..., None, None, None] * eye
    if not covariance:
        return z, np.broadcast_to(eye * 0.03**2, (*joints.shape[:3], 3, 3)) + grow
    with np.errstate(invalid="ignore", divide="ignore"):
        norm = np.sqrt(joints[..., 0] ** 2 + joints[..., 1] ** 2 + joints[..., 2] ** 2)
        ray = np.nan_to_num(joints / norm[..., None])
    u = rotate(ray)
    inflate = np.where(states == TrackingState.INFERRED, inferred_inflation, 1.0)
    inflate = inflate * np.where(occluded, occluded_inflation, 1.0)
    lat2 = lateral_m**2 * inflate**2
    ax2 = axial_m**2 * inflate**2
    if view[0] > 0.0 or view[2] > 0.0:  # isotropic: on both
        extra = view_variance(z, o, *view)
        lat2, ax2 = lat2 + extra, ax2 + extra
    cov = lat2[..., None, None] * eye + (ax2 - lat2)[..., None, None] * (
        u[..., :, None] * u[..., None, :]
    )
    return z, cov + grow


def facing(p: Array) -> Array:
    """Horizontal unit facing direction ``(..., 3)`` of skeletons ``(..., 25, 3)``: the normal to
    the left-right axis of hips and shoulders (NaN: none)."""
    lr = (p[..., _HIP_L, :] - p[..., _HIP_R, :]) + (p[..., _SH_L, :] - p[..., _SH_R, :])
    f = np.stack([lr[..., 1], -lr[..., 0], np.zeros_like(lr[..., 0])], axis=-1)
    n = np.sqrt(f[..., 0] ** 2 + f[..., 1] ** 2)[..., None]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 1e-6, f / n, np.nan)


def swap_evidence(z: Array, sensor_pos: Array) -> tuple[Array, NDArray[np.bool_], Array]:
    """What each sensor's skeleton says about the facing, ``z (T, S, 25, 3)`` world.

    A sensor whose reported facing points away from it cannot be seeing the body swapped
    (unambiguous, weight 1); one whose facing points toward it may be (ambiguous, weight 0.5).

    Returns
    -------
    facing : (T, S, 3) float
        NaN replaced by 0 (a sensor without a facing has weight 0).
    ambiguous : (T, S) bool
    weight : (T, S) float
        The sensor's vote weight (0 when it has no facing or no trunk).
    """
    f = facing(z)
    trunk = z[..., _TRUNK, :]  # (T, S, 2, 3)
    fin = np.asarray(np.isfinite(trunk).all(-1))
    n_ok = fin[..., 0].astype(np.float64) + fin[..., 1]
    with np.errstate(invalid="ignore", divide="ignore"):
        t0 = np.where(fin[..., 0, None], trunk[..., 0, :], 0.0)
        t1 = np.where(fin[..., 1, None], trunk[..., 1, :], 0.0)
        centre = (t0 + t1) / n_ok[..., None]
        toward = sensor_pos - centre
        toward[..., 2] = 0.0
        toward = toward / np.sqrt(toward[..., 0] ** 2 + toward[..., 1] ** 2)[..., None]
    ok = np.isfinite(f).all(-1) & np.isfinite(toward).all(-1)
    f0, u0 = np.nan_to_num(f), np.nan_to_num(toward)
    amb = (f0[..., 0] * u0[..., 0] + f0[..., 1] * u0[..., 1] + f0[..., 2] * u0[..., 2]) > 0
    return f0, amb & ok, np.where(amb, 0.5, 1.0) * ok


def swap_vote(facing_: Array, weight: Array) -> Array:
    """``(T, 3)`` the sensors' facing votes ``(T, S, 3)`` summed with weights ``(T, S)``."""
    return _sum_sensors(facing_ * weight[..., None])


def decide_flips(
    facing_: Array, ambiguous: NDArray[np.bool_], vote: Array, prior: Array | None, w_prior: float
) -> NDArray[np.bool_]:
    """One frame's swap decision: the ambiguous sensors ``(S,)`` whose facing ``(S, 3)``
    contradicts the consensus of ``vote (3,)`` and the fused facing so far (``prior``, weight
    ``w_prior``)."""
    v = vote if prior is None else vote + w_prior * prior
    n = math.sqrt(float(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]))
    if n < 1e-9:
        return np.zeros(ambiguous.shape, bool)
    c = v / n
    return ambiguous & ((facing_[:, 0] * c[0] + facing_[:, 1] * c[1] + facing_[:, 2] * c[2]) < 0)


def inv3(m: Array) -> Array:
    """Inverses of ``(..., 3, 3)`` matrices by the adjugate (much faster than LAPACK per call)."""
    a, b, c = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    d, e, f = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    g, h, i = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    co = np.empty(m.shape)
    co[..., 0, 0] = e * i - f * h
    co[..., 0, 1] = c * h - b * i
    co[..., 0, 2] = b * f - c * e
    co[..., 1, 0] = f * g - d * i
    co[..., 1, 1] = a * i - c * g
    co[..., 1, 2] = c * d - a * f
    co[..., 2, 0] = d * h - e * g
    co[..., 2, 1] = b * g - a * h
    co[..., 2, 2] = a * e - b * d
    det = a * co[..., 0, 0] + b * co[..., 1, 0] + c * co[..., 2, 0]
    co /= det[..., None, None]
    return co


def inv3_sym(m: Array) -> Array:
    """Inverses of symmetric ``(..., 3, 3)`` matrices (covariances, information matrices) by the
    adjugate, from their upper triangle."""
    a, b, c = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    e, f, i = m[..., 1, 1], m[..., 1, 2], m[..., 2, 2]
    c00 = e * i - f * f
    c01 = c * f - b * i
    c02 = b * f - c * e
    inv_det = 1.0 / (a * c00 + b * c01 + c * c02)
    co = np.empty(m.shape)
    co[..., 0, 0] = c00 * inv_det
    co[..., 0, 1] = co[..., 1, 0] = c01 * inv_det
    co[..., 0, 2] = co[..., 2, 0] = c02 * inv_det
    co[..., 1, 1] = (a * i - c * c) * inv_det
    co[..., 1, 2] = co[..., 2, 1] = (c * b - a * f) * inv_det
    co[..., 2, 2] = (a * e - b * b) * inv_det
    return co


def _matvec(m: Array, v: Array) -> Array:
    return m[..., 0] * v[..., 0, None] + m[..., 1] * v[..., 1, None] + m[..., 2] * v[..., 2, None]


def _sum_sensors(a: Array) -> Array:
    """Sum over axis 1 (sensors). Not the innermost axis, so numpy adds the sensors one after
    the other whatever the batch size (no pairwise blocking): a frame sums the same alone and
    in a batch (``tests/test_live_fusion.py`` checks it bit for bit)."""
    return np.add.reduce(a, axis=1)


def robust_combine(
    z: Array, cov: Array, *, robust: bool, gate_chi2: float
) -> tuple[Array, Array, NDArray[np.intp]]:
    """Combine ``(T, S, J, 3)`` measurements with ``(T, S, J, 3, 3)`` covariances.

    Iteratively reweighted least squares with Huber weights on the Mahalanobis distance (full
    weight inside the ``gate_chi2`` gate, falling off as 1/d outside it); a measurement far
    outside (4x the gate) is dropped unless that would drop every measurement of the joint.

    Returns the fused ``(T, J, 3)`` (NaN where nothing), its covariance ``(T, J, 3, 3)`` and the
    number of sensors used (weight above 0.2) ``(T, J)``.
    """
    valid = np.asarray(np.isfinite(z).all(-1) & np.isfinite(cov).all((-1, -2)))
    eye = np.eye(3)
    w_mat = inv3_sym(np.where(valid[..., None, None], cov, eye))
    w_mat[~valid] = 0.0
    zz = np.where(valid[..., None], z, 0.0)
    wz = _matvec(w_mat, zz)
    rw: Array = valid.astype(np.float64)
    n_iter = 4 if robust else 1
    x: Array = np.zeros(0)
    has = np.asarray(valid.any(axis=1))
    cov_x: Array = np.zeros(0)
    for it in range(n_iter):
        info = _sum_sensors(w_mat * rw[..., None, None])
        rhs = _sum_sensors(wz * rw[..., None])
        has = _sum_sensors(rw) > 0
        cov_x = inv3_sym(np.where(has[..., None, None], info, eye))
        x = _matvec(cov_x, rhs)
        if not robust or it == n_iter - 1:
            break
        r = zz - x[:, None]
        wr = _matvec(w_mat, r)
        d2 = r[..., 0] * wr[..., 0] + r[..., 1] * wr[..., 1] + r[..., 2] * wr[..., 2]
        rw = np.asarray(valid * np.minimum(1.0, np.sqrt(gate_chi2 / np.maximum(d2, 1e-12))))
        far = d2 > 4 * gate_chi2
        keep_some = np.asarray((valid & ~far).any(axis=1, keepdims=True))
        rw = np.where(far & keep_some, 0.0, rw)
    used = (rw > 0.2).sum(axis=1).astype(np.intp)
    x = np.where(has[..., None], x, np.nan)
    cov_x = np.where(has[..., None, None], cov_x, np.nan)
    return x, cov_x, used


@dataclass
class KalmanState:
    """The constant-velocity filter per joint and axis: ``m (5, J, 3)`` holds position,
    velocity and the three entries of their covariance (x, v, pxx, pxv, pvv); ``started`` and
    ``last_seen`` per joint and axis."""

    m: Array
    started: NDArray[np.bool_]
    last_seen: Array

    @classmethod
    def empty(cls, n_joints: int = N_JOINTS) -> KalmanState:
        return cls(np.zeros((5, n_joints, 3)), np.zeros((n_joints, 3), bool),
                   np.full((n_joints, 3), -np.inf))  # fmt: skip

    @property
    def x(self) -> Array:
        return self.m[0]

    @property
    def pxx(self) -> Array:
        return self.m[2]

    def moments(self) -> Array:
        """``(5, J, 3)``: x, v, pxx, pxv, pvv (a copy)."""
        return self.m.copy()


def kalman_step(
    s: KalmanState,
    t: float,
    d: float,
    z: Array,
    r: Array,
    q: Array,
    max_predict_s: float,
    *,
    predicted: bool = False,
) -> tuple[Array | None, NDArray[np.bool_]]:
    """Predict ``s`` by ``d`` seconds to ``t`` and update it with measurements ``z (J, 3)`` of
    variances ``r (J, 3)`` (NaN: none), in place; ``q (J, 1)`` white-acceleration densities.

    A joint's first measurement starts its filter (position measured, velocity 0 with 1 m/s a
    priori). Returns the predicted moments ``(5, J, 3)`` if ``predicted`` (for a smoother; else
    None) and which joints and axes are alive (seen within ``max_predict_s``)."""
    # predict: the moments move by one linear map (x += d v, P = F P F^T) plus the process noise
    m = s.m.copy()
    m[0] += d * m[1]
    m[2] += 2 * d * m[3] + d * d * m[4] + q * (d**3 / 3)
    m[3] += d * m[4] + q * (d**2 / 2)
    m[4] += q * d
    pred = m.copy() if predicted else None
    has = np.isfinite(z) & np.isfinite(r)
    z0 = np.where(has, z, 0.0)
    gain = np.where(has, m[2:4] / (m[2] + np.where(has, r, 1.0)), 0.0)  # (2, J, 3): kx, kv
    m[:2] += gain * (z0 - m[0])
    m[4] -= gain[1] * m[3]
    m[2:4] *= 1.0 - gain[0]
    init = has & ~s.started
    if init.any():
        s.started |= has
        m[0] = np.where(init, z0, m[0])
        m[1:5] = np.where(init, np.array([0.0, 0.0, 0.0, 1.0])[:, None, None], m[1:5])
        m[2] = np.where(init, r, m[2])
    s.m = m
    s.last_seen = np.where(has, t, s.last_seen)
    return pred, s.started & (t - s.last_seen <= max_predict_s)


def rts_smooth(
    dt: Array, predicted: Array, filtered: Array, alive: NDArray[np.bool_]
) -> tuple[Array, Array]:
    """Rauch-Tung-Striebel smoother over a filter's recorded states.

    Parameters
    ----------
    dt : (T,) float
        Time step into each frame (``dt[0]`` unused).
    predicted, filtered : (5, T, J, 3) float
        The filter's moments (x, v, pxx, pxv, pvv) before and after each frame's update.
    alive : (T, J, 3) bool
        Where the filter has a state; the smoother does not bridge a joint across frames where
        it was dead.

    Returns
    -------
    positions (T, J, 3), position variance per axis (T, J, 3)
    """
    xf, vf, fxx, fxv, fvv = filtered
    xp, vp, qxx, qxv, qvv = predicted
    n_t = xf.shape[0]
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
    return xs, sxx

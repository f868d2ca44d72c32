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
- :func:`robust_combine`: covariance-weighted, Huber-robust combination across sensors, each
  limb's joints solved together when a sensor's errors along a limb are correlated
  (``limb_correlation``);
- :class:`KalmanState`, :func:`kalman_step`, :func:`rts_smooth`: the constant-velocity filter
  per joint and axis, and the Rauch-Tung-Striebel smoother over its recorded states
  (:func:`rts_smooth_tape`: the same, block by block over a :class:`FilterTape`, in memory
  that does not grow with the session).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from kinefuse.capture.fusion.view_noise import view_variance
from kinefuse.core.skeleton import JOINT_INDEX, N_JOINTS, PARENTS, TrackingState, bone_index_array

Array = NDArray[np.float64]

_TRUNK = [JOINT_INDEX["SpineBase"], JOINT_INDEX["SpineShoulder"]]
_HIP_L, _HIP_R = JOINT_INDEX["HipLeft"], JOINT_INDEX["HipRight"]
_SH_L, _SH_R = JOINT_INDEX["ShoulderLeft"], JOINT_INDEX["ShoulderRight"]
#: the first observation of a stream stands for a frame time up to half a frame before it
_FIRST_LEAD_S = 0.5 / 30
_INFERRED, _NOT_TRACKED = int(TrackingState.INFERRED), int(TrackingState.NOT_TRACKED)
_FLOAT_MAX = float(np.finfo(np.float64).max)
_EYE = np.eye(3)
_EYE.flags.writeable = False


#: the skeleton's bones (parent, child) ``(24, 2)``
BONES = bone_index_array()


def _bone_groups() -> tuple[NDArray[np.intp], list[slice], NDArray[np.intp]]:
    """The bones in groups that share no joint (greedy, from the root out): the bones' order
    group after group, each group's slice of that order; and per joint the indices of its bones
    ``(25, 4)`` padded with ``len(bones)``."""
    groups: list[list[int]] = []
    for b, (pa, ch) in enumerate(BONES.tolist()):
        for g in groups:
            if all(pa not in BONES[o] and ch not in BONES[o] for o in g):
                g.append(b)
                break
        else:
            groups.append([b])
    inc = [[b for b in range(len(BONES)) if j in BONES[b]] for j in range(N_JOINTS)]
    width = max(len(i) for i in inc)
    table = np.array([i + [len(BONES)] * (width - len(i)) for i in inc], dtype=np.intp)
    ends = np.cumsum([len(g) for g in groups]).tolist()
    slices = [slice(e - len(g), e) for g, e in zip(groups, ends, strict=True)]
    return np.array([b for g in groups for b in g], dtype=np.intp), slices, table


#: the bones group after group, each group's slice of that order, and each joint's bones (25, 4)
BONE_ORDER, _GROUP_SLICES, JOINT_BONES = _bone_groups()
#: each group's parent and child joints (in the group order)
_GROUP_JOINTS = [(BONES[BONE_ORDER[g], 0], BONES[BONE_ORDER[g], 1]) for g in _GROUP_SLICES]
#: the bones in the group order as (parent, child) ints, for the sweep over one frame
_SWEEP = [(int(a), int(c)) for a, c in BONES[BONE_ORDER].tolist()]


def project_bones(
    pos: Array, movable: NDArray[np.bool_], target: Array, w_child: Array, w_parent: Array
) -> Array:
    """Frames' joints ``(T, 25, 3)`` projected onto bone lengths by one sweep over the bones, in
    groups that share no joint (so each group moves at once), each end moving by its share.

    ``movable``, ``target`` (m), ``w_child`` and ``w_parent`` (the ends' shares) are ``(T, 24)``,
    the bones in :data:`BONE_ORDER`. A bone that is not movable or is shorter than 1e-9 m does
    not move. One frame (the live case) is swept with plain floats (numpy's per-call cost on 24
    bones is most of the work); the same operations in the same order, so both forms give the
    same bits (``tests/test_live_fusion.py`` checks them against each other).
    """
    if pos.shape[0] == 1:
        return np.array(_sweep_frame(pos[0].tolist(), movable[0].tolist(), target[0].tolist(),
                                     w_child[0].tolist(), w_parent[0].tolist()))[None]  # fmt: skip
    out = pos.copy()
    with np.errstate(invalid="ignore", divide="ignore"):
        for g, (a, c) in zip(_GROUP_SLICES, _GROUP_JOINTS, strict=True):
            oa, oc = out[:, a], out[:, c]
            d = oc - oa
            norm = np.sqrt(np.add.reduce(d * d, axis=-1))
            move = movable[:, g] & (norm > 1e-9)
            corr = np.where(move[..., None], d * (1.0 - target[:, g] / norm)[..., None], 0.0)
            out[:, c] = oc - w_child[:, g, None] * corr
            out[:, a] = oa + w_parent[:, g, None] * corr
    return out


def _sweep_frame(
    out: list[list[float]], movable: list[bool], target: list[float], wc: list[float],
    wa: list[float],
) -> list[list[float]]:  # fmt: skip
    """:func:`project_bones` of one frame, on lists (in place)."""
    for b, (a, c) in enumerate(_SWEEP):
        pa, pc = out[a], out[c]
        dx, dy, dz = pc[0] - pa[0], pc[1] - pa[1], pc[2] - pa[2]
        norm = math.sqrt(dx * dx + dy * dy + dz * dz)
        kx = ky = kz = 0.0
        if movable[b] and norm > 1e-9:
            s = 1.0 - target[b] / norm
            kx, ky, kz = dx * s, dy * s, dz * s
        w1, w2 = wc[b], wa[b]
        out[c] = [pc[0] - w1 * kx, pc[1] - w1 * ky, pc[2] - w1 * kz]
        out[a] = [pa[0] + w2 * kx, pa[1] + w2 * ky, pa[2] + w2 * kz]
    return out


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
        k = np.add.reduce((times[None] <= tt[..., None]) & valid[None], axis=-1)  # (T, S)
    else:
        k = np.stack([np.searchsorted(times[i, : int(n[0, i])], t, side="right")
                      for i in range(n_s)], axis=1)  # fmt: skip
    si = np.arange(n_s)[None, :]
    ka, kb = np.maximum(k - 1, 0), np.maximum(np.minimum(k, n - 1), 0)
    ta, tb = times[si, ka], times[si, kb]
    with np.errstate(invalid="ignore"):  # a sensor without observations: inf - inf
        gap = tb - ta
    since_a = tt - ta
    some = k > 0
    if timestamp:
        t0 = times[:, 0][None, :]
        avail = available_s[:, None]
        interp = some & (k < n) & (tb <= avail) & (gap <= max_gap_s)
        hold = ~interp & some & (since_a <= max_hold_s)
        first = k == 0  # before a stream's first observation (rare: tested only then)
        if np.logical_or.reduce(first, axis=None):
            first = ~interp & first & (n > 0) & (t0 - tt <= _FIRST_LEAD_S) & (t0 <= avail)
    else:
        interp = np.zeros(k.shape, bool)
        hold = some & (since_a < 1.0 / 30)
        first = interp
    w = np.zeros(k.shape)
    np.divide(since_a, gap, out=w, where=tb > ta)
    w = w[..., None, None]
    ja, jb = joints[si, ka], joints[si, kb]
    out = np.where(interp[..., None, None], ja * (1.0 - w) + jb * w, ja)
    sa = states[si, ka]
    st = np.where(interp[..., None], np.minimum(sa, states[si, kb]), sa)
    if occluded is None:
        occ = np.zeros(st.shape, bool)
    else:
        oa = occluded[si, ka]
        occ = np.where(interp[..., None], oa | occluded[si, kb], oa)
    age = np.where(interp, 0.0, np.abs(since_a)) if timestamp else np.zeros(k.shape)
    none = ~(interp | hold | first)
    if none.any():
        out[none] = np.nan
        st[none] = _NOT_TRACKED
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
        The view-dependent variance of :func:`kinefuse.capture.fusion.view_noise.view_variance`
        (zero sigmas: none).

    Returns
    -------
    z : (T, S, 25, 3) float
    cov : (T, S, 25, 3, 3) float
        ``lat^2 I + (ax^2 - lat^2) u u^T`` with ``u`` the world ray (``R`` is a rotation, so
        this is ``R (lat^2 (I - r r^T) + ax^2 r r^T) R^T``), plus ``age^2 I`` and the view term.
    """
    r = sensor2world[:, None, :3, :3]  # (S, 1, 3, 3)
    o = sensor2world[:, :3, 3]

    def rotate(v: Array) -> Array:  # R v per sensor, the columns weighted and added in order
        p = r * v[..., None, :]
        return p[..., 0] + p[..., 1] + p[..., 2]

    z = rotate(joints) + o[:, None, :]
    grow = (age_s * age_s)[..., None, None, None] * _EYE
    if not covariance:
        return z, np.broadcast_to(_EYE * 0.03**2, (*joints.shape[:3], 3, 3)) + grow
    sq = joints * joints
    with np.errstate(invalid="ignore", divide="ignore"):
        ray = _nan_to_num(joints / np.sqrt(sq[..., 0] + sq[..., 1] + sq[..., 2])[..., None])
    u = rotate(ray)
    inflate = np.where(states == _INFERRED, inferred_inflation, 1.0)
    inflate = inflate * np.where(occluded, occluded_inflation, 1.0)
    inflate2 = inflate**2
    lat2 = lateral_m**2 * inflate2
    ax2 = axial_m**2 * inflate2
    if view[0] > 0.0 or view[2] > 0.0:  # isotropic: on both
        extra = view_variance(z, o, *view)
        lat2, ax2 = lat2 + extra, ax2 + extra
    cov = lat2[..., None, None] * _EYE + (ax2 - lat2)[..., None, None] * (
        u[..., :, None] * u[..., None, :]
    )
    return z, cov + grow


def facing(p: Array) -> Array:
    """Horizontal unit facing direction ``(..., 3)`` of skeletons ``(..., 25, 3)``: the normal to
    the left-right axis of hips and shoulders (NaN: none)."""
    lr = (p[..., _HIP_L, :] - p[..., _HIP_R, :]) + (p[..., _SH_L, :] - p[..., _SH_R, :])
    f = np.empty(lr.shape)
    f[..., 0], f[..., 1], f[..., 2] = lr[..., 1], -lr[..., 0], 0.0
    n = np.sqrt(f[..., 0] ** 2 + f[..., 1] ** 2)[..., None]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 1e-6, f / n, np.nan)


#: An ambiguous view's weight in the swap vote (an unambiguous one: 1).
AMBIGUOUS_WEIGHT = 0.5


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
    all_ = np.logical_and.reduce
    f = facing(z)
    trunk = z[..., _TRUNK, :]  # (T, S, 2, 3)
    fin = all_(np.isfinite(trunk), axis=-1)
    n_ok = np.add.reduce(fin, axis=-1, dtype=np.float64)
    t01 = np.where(fin[..., None], trunk, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        centre = (t01[..., 0, :] + t01[..., 1, :]) / n_ok[..., None]
        toward = sensor_pos - centre
        toward[..., 2] = 0.0
        toward = toward / np.sqrt(toward[..., 0] ** 2 + toward[..., 1] ** 2)[..., None]
        ok = all_(np.isfinite(f), axis=-1) & all_(np.isfinite(toward), axis=-1)
        f0 = _nan_to_num(f)
        amb = _dot3(f0, toward) > 0  # (only where ok counts: a NaN direction is not ok)
    return f0, amb & ok, np.where(amb, AMBIGUOUS_WEIGHT, 1.0) * ok


def _nan_to_num(a: Array) -> Array:
    """``np.nan_to_num`` of a float array, in place (NaN -> 0, +-inf -> the largest floats) and
    in three numpy calls instead of its dozen."""
    np.copyto(a, 0.0, where=np.isnan(a))
    np.minimum(a, _FLOAT_MAX, out=a)
    return np.maximum(a, -_FLOAT_MAX, out=a)


def _dot3(a: Array, b: Array) -> Array:
    """``(...)`` dot products of ``(..., 3)`` vectors (added in order)."""
    p = a * b
    return p[..., 0] + p[..., 1] + p[..., 2]


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
    v0, v1, v2 = v.tolist()  # three numbers: plain floats (the same arithmetic, no numpy calls)
    n = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    if n < 1e-9:
        return np.zeros(ambiguous.shape, bool)
    return ambiguous & (_dot3(facing_, np.array([v0 / n, v1 / n, v2 / n])) < 0)


#: 3x3 matrices entries first, ``(9, ...)`` row by row (so that one numpy call does one entry
#: of every matrix of a batch, and a frame of 25 joints costs few calls). A symmetric matrix's
#: six cofactors (00, 01, 02, 11, 12, 22) as ``p q - r s`` of its upper triangle (rows p, q, r,
#: s; entries 0-8), repeated into the nine entries (an inverse comes out in the same layout)
_COFACTORS = np.array([[4, 2, 1, 0, 2, 0], [8, 5, 5, 8, 1, 4], [5, 1, 2, 2, 0, 1],
                       [5, 8, 4, 2, 5, 1]])[:, [0, 1, 2, 1, 3, 4, 2, 4, 5]]  # fmt: skip
_EYE_ENTRIES = np.eye(3).ravel()


def inv3_sym(m: Array) -> Array:
    """Inverses of symmetric 3x3 matrices (covariances, information matrices) entries first
    ``(9, ...)``, by the adjugate from their upper triangle; entries first, exactly symmetric."""
    p, q, r, s = m[_COFACTORS]
    co = p * q - r * s
    t = m[:3] * co[:3]  # a c00, b c01, c c02
    return co * (1.0 / (t[0] + t[1] + t[2]))


def _matvec(m: Array, v: Array) -> Array:
    """``(3, ...)`` products of symmetric matrices ``(3, 3, ...)`` and vectors ``(3, ...)``,
    entries first (the columns weighted and added in order)."""
    p = m * v[:, None]  # row j of a symmetric matrix is its column j
    return p[0] + p[1] + p[2]


def _dot(a: Array, b: Array) -> Array:
    """``(...)`` dot products of vectors ``(3, ...)``, entries first (added in order)."""
    p = a * b
    return p[0] + p[1] + p[2]


def _sum_sensors(a: Array, axis: int = 1) -> Array:
    """Sum over the sensors' axis. Not the innermost axis, so numpy adds the sensors one after
    the other whatever the batch size (no pairwise blocking): a frame sums the same alone and
    in a batch (``tests/test_live_fusion.py`` checks it bit for bit)."""
    return np.add.reduce(a, axis=axis)


#: The chains whose joints a sensor gets wrong together (a Kinect regresses a limb from the same
#: depth pixels): ``robust_combine(limb_correlation=rho)`` correlates one sensor's errors of two
#: joints of a chain by ``rho`` per bone between them.
LIMBS: tuple[tuple[str, ...], ...] = (
    ("SpineBase", "SpineMid", "SpineShoulder", "Neck", "Head"),
    ("ShoulderLeft", "ElbowLeft", "WristLeft", "HandLeft", "HandTipLeft", "ThumbLeft"),
    ("ShoulderRight", "ElbowRight", "WristRight", "HandRight", "HandTipRight", "ThumbRight"),
    ("HipLeft", "KneeLeft", "AnkleLeft", "FootLeft"),
    ("HipRight", "KneeRight", "AnkleRight", "FootRight"),
)


@functools.lru_cache(maxsize=8)
def limb_correlation_matrices(
    rho: float,
) -> tuple[NDArray[np.intp], Array, Array, NDArray[np.intp], NDArray[np.intp]]:
    """The chains of :data:`LIMBS` padded to one length: their joint indices ``(L, n)`` (``-1``
    pads), the correlation ``rho^k`` of one sensor's errors at two joints of a chain ``k``
    bones apart ``(L, n, n)`` (identity on the pads; positive definite for ``0 <= rho < 1``: the
    correlation of noise passed down a tree, each joint ``rho`` times its parent's plus its
    own), its inverse, and the pairs ``j <= k`` of the upper triangle (two ``(n (n + 1) / 2,)``
    index arrays)."""
    n = max(len(c) for c in LIMBS)
    idx = np.full((len(LIMBS), n), -1, dtype=np.intp)
    corr = np.tile(np.eye(n), (len(LIMBS), 1, 1))
    for li, names in enumerate(LIMBS):
        joints = [JOINT_INDEX[c] for c in names]
        idx[li, : len(joints)] = joints
        # each joint's ancestors within the chain, itself first (the chains list parents first)
        line: list[list[int]] = []
        for j in joints:
            up = PARENTS[j]
            line.append([j, *(line[joints.index(up)] if up in joints else [])])
        for a, la in enumerate(line):
            for b, lb in enumerate(line):
                common = len(set(la) & set(lb))
                corr[li, a, b] = rho ** (len(la) + len(lb) - 2 * common)  # bones apart
    inv = np.asarray(np.linalg.inv(corr), dtype=np.float64)
    ju, ku = np.triu_indices(n)
    for arr in (idx, corr, inv, ju, ku):
        arr.flags.writeable = False
    return idx, corr, inv, ju.astype(np.intp), ku.astype(np.intp)


def sqrt3_sym(m: Array) -> Array:
    """Square roots of symmetric positive definite 3x3 matrices entries first ``(9, ...)``, in
    closed form: the eigenvalues ``l`` by the trigonometric method (exact for repeated ones),
    then, from Cayley-Hamilton for ``Y = M^(1/2)``, ``Y = (M + i2 I)^-1 (i1 M + i3 I)`` with
    ``i1, i2, i3`` the elementary symmetric functions of ``sqrt(l)``. Element-wise only."""
    a00, a01, a02, _, a11, a12, _, _, a22 = m
    q = (a00 + a11 + a22) / 3.0
    d0, d1, d2 = a00 - q, a11 - q, a22 - q
    p = np.sqrt((d0 * d0 + d1 * d1 + d2 * d2 + 2.0 * (a01 * a01 + a02 * a02 + a12 * a12)) / 6.0)
    with np.errstate(divide="ignore"):
        ip = np.where(p > 0.0, 1.0 / p, 0.0)  # p = 0: a multiple of I, any phi
    b00, b11, b22, b01, b02, b12 = d0 * ip, d1 * ip, d2 * ip, a01 * ip, a02 * ip, a12 * ip
    det = b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02)
    det = det + b02 * (b01 * b12 - b11 * b02)
    phi = np.arccos(np.clip(0.5 * det, -1.0, 1.0)) / 3.0
    l1 = q + 2.0 * p * np.cos(phi)
    l3 = q + 2.0 * p * np.cos(phi + 2.0 * math.pi / 3.0)
    s1, s3 = np.sqrt(l1), np.sqrt(np.maximum(l3, 0.0))
    s2 = np.sqrt(np.maximum(3.0 * q - l1 - l3, 0.0))
    i1, i2, i3 = s1 + s2 + s3, s1 * s2 + s1 * s3 + s2 * s3, s1 * s2 * s3
    ai = inv3_sym(m + i2 * _EYE_ENTRIES.reshape(9, *([1] * (m.ndim - 1))))
    am = ai.reshape(3, 3, *m.shape[1:])
    prod = am[:, :, None] * m.reshape(3, 3, *m.shape[1:])[None]  # (a, b, c): Ai[a, b] M[b, c]
    return (i1 * (prod[:, 0] + prod[:, 1] + prod[:, 2]).reshape(m.shape)) + i3 * ai


def _limb_solve(z: Array, w_mat: Array, weight: Array, x: Array, cov_x: Array, rho: float) -> None:
    """Each limb of :data:`LIMBS` solved again in one weighted least squares over its joints,
    one sensor's errors of two joints ``k`` bones apart correlated by ``rho^k``; in place on
    ``x (3, T, J)`` and ``cov_x (9, T, J)`` (entries first).

    ``z (T, S, J, 3)``; ``w_mat (9, T, S, J)`` each measurement's information (its covariance's
    inverse, entries first); ``weight (T, S, J)`` the robust weights of the per-joint solution
    (0: not used), each scaling its joint's information as there. A sensor's measurements of a
    limb have the covariance ``C = H (R (x) I3) H`` (``H`` block diagonal: each joint's
    covariance's symmetric square root over the root of its weight; ``R`` the chain's
    correlations over the joints this sensor measured), so its information is ``H^-1 (R^-1 (x)
    I3) H^-1``. With ``rho = 0`` this is the per-joint solution again. Every step is
    element-wise or per matrix (LAPACK), so a frame alone gives the numbers it gives in a batch.
    """
    n_t, n_s = z.shape[:2]
    idx, r, r_inv_all, ju, ku = limb_correlation_matrices(rho)
    n_l, n = idx.shape
    real = idx >= 0
    j = idx[real]  # the limbs' joints, limb after limb
    w = np.where(real, weight[:, :, idx], 0.0)  # (T, S, L, n)
    ok = w > 0
    # R^-1 over the joints a sensor measured (R's inverse itself where it measured them all)
    pair = ok[..., :, None] & ok[..., None, :]
    r_inv = np.broadcast_to(r_inv_all, pair.shape).copy()
    part = ~np.logical_and.reduce(ok | ~real, axis=-1)  # (T, S, L): a joint of the limb missing
    if part.any():
        sub = pair[part]
        r_inv[part] = np.linalg.inv(np.where(sub, r[np.nonzero(part)[2]], np.eye(n))) * sub
    # H^-1 of every joint: weight^(1/2) times the information's square root, entries first
    pos = weight > 0
    half_j = sqrt3_sym(np.where(pos, w_mat, _EYE_ENTRIES[:, None, None, None])) * np.sqrt(weight)
    half = np.zeros((9, n_t, n_s, n_l, n))
    half[..., real] = half_j[..., j]
    # the measurement side, half_j sum_k r_inv[j, k] half_k z_k
    zz = np.where(ok, z[:, :, idx].transpose(4, 0, 1, 2, 3), 0.0)  # (3, T, S, L, n)
    h33 = half.reshape(3, 3, n_t, n_s, n_l, n)
    y = _matvec(h33, zz)
    u = r_inv[..., 0] * y[..., 0, None]
    for k in range(1, n):
        u = u + r_inv[..., k] * y[..., k, None]
    rhs = _sum_sensors(_matvec(h33, u), axis=2)  # (3, T, L, n)
    # the information: blocks half_j r_inv[j, k] half_k over the upper triangle, summed over
    # the sensors
    hj, hk = h33[..., ju], h33[..., ku]  # (3, 3, T, S, L, pairs)
    prod = hj[:, :, None] * hk[None]  # (a, b, c): half_j[a, b] half_k[b, c]
    blocks = (prod[:, 0] + prod[:, 1] + prod[:, 2]) * r_inv[..., ju, ku]  # (3, 3, T, S, L, P)
    upper = _sum_sensors(blocks, axis=3).transpose(2, 3, 4, 0, 1)  # (T, L, pairs, 3, 3)
    full = np.empty((n_t, n_l, n, n, 3, 3))
    full[:, :, ju, ku] = upper
    full[:, :, ku, ju] = upper.swapaxes(-1, -2)
    info = full.swapaxes(-3, -2).reshape(n_t, n_l, 3 * n, 3 * n)
    b = rhs.transpose(1, 2, 3, 0).reshape(n_t, n_l, 3 * n)
    has = np.repeat(np.logical_or.reduce(ok, axis=1), 3, axis=-1)  # (T, L, 3n)
    info = np.where(has[..., :, None] & has[..., None, :], info, np.eye(3 * n))
    p = np.linalg.inv(info)
    p = 0.5 * (p + p.swapaxes(-1, -2))
    sol = (p @ np.where(has, b, 0.0)[..., None])[..., 0].reshape(n_t, n_l, n, 3)
    diag = p.reshape(n_t, n_l, n, 3, n, 3)[:, :, np.arange(n), :, np.arange(n)]  # (n, T, L, 3, 3)
    has_j = has.reshape(n_t, n_l, n, 3)[..., 0][:, real]  # (T, joints)
    x[:, :, j] = np.where(has_j, sol[:, real].transpose(2, 0, 1), np.nan)
    cov_x[:, :, j] = diag.transpose(1, 2, 0, 3, 4)[:, real].reshape(n_t, -1, 9).transpose(2, 0, 1)


def robust_combine(
    z: Array, cov: Array, *, robust: bool, gate_chi2: float, limb_correlation: float = 0.0
) -> tuple[Array, Array, NDArray[np.intp]]:
    """Combine ``(T, S, J, 3)`` measurements with ``(T, S, J, 3, 3)`` covariances.

    Iteratively reweighted least squares with Huber weights on the Mahalanobis distance (full
    weight inside the ``gate_chi2`` gate, falling off as 1/d outside it); a measurement far
    outside (4x the gate) is dropped unless that would drop every measurement of the joint.
    With ``limb_correlation`` ``rho > 0`` each limb's joints are then solved together with the
    final weights, one sensor's errors at joints ``k`` bones apart correlated by ``rho^k``
    (:func:`_limb_solve`): a limb a sensor sees displaced as a whole then moves the fused limb
    as a whole, instead of bending it where the sensors' weights change from joint to joint.

    Returns the fused ``(T, J, 3)`` (NaN where nothing), its covariance ``(T, J, 3, 3)`` and the
    number of sensors used (weight above 0.2) ``(T, J)``.
    """
    n_t, n_s, n_j = z.shape[:3]
    all_ = np.logical_and.reduce
    valid = all_(np.isfinite(z), axis=-1) & all_(np.isfinite(cov), axis=(-1, -2))  # (T, S, J)
    # entries first: vectors (3, T, S, J), matrices (9, T, S, J)
    zz = np.where(valid, z.transpose(3, 0, 1, 2), 0.0)
    entries = cov.reshape(n_t, n_s, n_j, 9).transpose(3, 0, 1, 2)
    w_mat = inv3_sym(np.where(valid, entries, _EYE_ENTRIES[:, None, None, None]))
    w_mat[:, ~valid] = 0.0
    w_rows = w_mat.reshape(3, 3, n_t, n_s, n_j)
    # the terms summed over the sensors, in one array: information (9), its product with the
    # measurement (3) and 1 (the weights' sum)
    terms = np.empty((13, n_t, n_s, n_j))
    terms[:9], terms[9:12], terms[12] = w_mat, _matvec(w_rows, zz), 1.0
    rw: Array = valid.astype(np.float64)
    n_iter = 4 if robust else 1
    x: Array = np.zeros(0)
    cov_x: Array = np.zeros(0)
    has = np.logical_or.reduce(valid, axis=1)
    for it in range(n_iter):
        if it == 0:  # the weights are 1 where valid, and the terms 0 elsewhere
            sums = _sum_sensors(terms[:12], axis=2)
        else:
            sums = _sum_sensors(terms * rw, axis=2)
            has = sums[12] > 0
        cov_x = inv3_sym(np.where(has, sums[:9], _EYE_ENTRIES[:, None, None]))
        x = _matvec(cov_x.reshape(3, 3, n_t, n_j), sums[9:12])
        if not robust or it == n_iter - 1:
            break
        r = zz - x[:, :, None]
        d2 = _dot(r, _matvec(w_rows, r))
        new_rw = valid * np.minimum(1.0, np.sqrt(gate_chi2 / np.maximum(d2, 1e-12)))
        far = d2 > 4 * gate_chi2
        keep_some = np.logical_or.reduce(valid > far, axis=1, keepdims=True)  # valid, not far
        rw, previous = np.where(far & keep_some, 0.0, new_rw), rw
        if not np.logical_or.reduce(rw != previous, axis=None):
            break  # a fixed point: the iterations left would repeat this one, bit for bit
    used = np.add.reduce(rw > 0.2, axis=1, dtype=np.intp)
    if limb_correlation > 0.0:
        _limb_solve(z, w_mat, rw, x, cov_x, limb_correlation)
    x = np.where(has, x, np.nan).transpose(1, 2, 0)
    cov_x = np.where(has, cov_x, np.nan).transpose(1, 2, 0).reshape(n_t, n_j, 3, 3)
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
    priori), and so does its first measurement after more than ``max_predict_s`` without one:
    a joint lost that long is not continued from its old state (a velocity seconds old, and the
    jump to where the joint is found again taken as motion).

    Returns the predicted moments ``(5, J, 3)`` if ``predicted`` (for a smoother; else
    None) and which joints and axes are alive (seen within ``max_predict_s``)."""
    # a joint lost for longer than max_predict_s starts afresh at its next measurement
    lost = s.started & (t - s.last_seen > max_predict_s)
    if np.logical_or.reduce(lost, axis=None):
        s.started = s.started & ~lost
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
    if np.logical_or.reduce(init, axis=None):
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
    sm = _rts_moments(dt, predicted, filtered, alive)
    return sm[0], sm[2]


def _rts_moments(dt: Array, predicted: Array, filtered: Array, alive: NDArray[np.bool_]) -> Array:
    """:func:`rts_smooth`'s recursion; returns all five smoothed moments ``(5, T, J, 3)``. The
    last frame's smoothed moments are its ``filtered`` ones: a block of a longer sequence is
    smoothed exactly when its last frame holds the smoothed moments of that frame
    (:func:`rts_smooth_tape`)."""
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
    sm = np.array(filtered, dtype=np.float64, copy=True)
    xs, vs, sxx, sxv, svv = sm
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
    return sm


@dataclass(frozen=True, eq=False)
class FilterTape:
    """What the smoother needs of a filter's run, kept in memory of the size of the output: each
    frame's time, step and measurement (``z`` and its variances ``r``, ``(T, J, 3)``) and a copy
    of the filter's state before every ``every``-th frame. The filter's moments (ten arrays of
    that size) are recomputed from them a block at a time (:meth:`moments`), bit for bit what
    the run computed: :func:`kalman_step` on the same state and inputs."""

    t: Array
    d: Array
    z: Array
    r: Array
    q: Array
    max_predict_s: float
    every: int
    checkpoints: tuple[KalmanState, ...]

    def moments(self, a: int, b: int) -> tuple[Array, Array]:
        """The predicted and filtered moments ``(5, b - a, J, 3)`` of frames ``a`` to ``b - 1``
        (``a`` a multiple of ``every``)."""
        if a % self.every or not 0 <= a < b <= self.t.size:
            raise ValueError(f"moments({a}, {b}): a must be a multiple of {self.every}, < b")
        c = self.checkpoints[a // self.every]
        s = KalmanState(c.m.copy(), c.started.copy(), c.last_seen.copy())
        n_j = s.m.shape[1]
        pred = np.empty((5, b - a, n_j, 3))
        filt = np.empty((5, b - a, n_j, 3))
        for i, k in enumerate(range(a, b)):
            p, _ = kalman_step(s, float(self.t[k]), float(self.d[k]), self.z[k], self.r[k],
                               self.q, self.max_predict_s, predicted=True)  # fmt: skip
            assert p is not None
            pred[:, i], filt[:, i] = p, s.m
        return pred, filt


def rts_smooth_tape(dt: Array, tape: FilterTape, alive: NDArray[np.bool_]) -> tuple[Array, Array]:
    """:func:`rts_smooth` over a :class:`FilterTape`, backwards a block of ``tape.every`` frames at
    a time (each block's moments recomputed, then smoothed from the next block's first frame):
    the same result bit for bit, in memory that does not grow with the number of frames beyond
    the tape and the output (``positions, variance per axis (T, J, 3)``)."""
    n_t = tape.t.size
    n_j = tape.z.shape[1]
    xs = np.empty((n_t, n_j, 3))
    sxx = np.empty((n_t, n_j, 3))
    carry: Array | None = None  # smoothed moments (5, J, 3) of the first frame after the block
    for a in reversed(range(0, n_t, tape.every)):
        b = min(a + tape.every, n_t)
        end = min(b + 1, n_t)  # one frame into the next block: its predicted moments
        pred, filt = tape.moments(a, end)
        if carry is not None:
            filt[:, -1] = carry
        sm = _rts_moments(dt[a:end], pred, filt, alive[a:end])
        xs[a:b], sxx[a:b] = sm[0, : b - a], sm[2, : b - a]
        carry = sm[:, 0]
    return xs, sxx

"""The low-level trilateration solvers on ``(N, K)`` problems (N problems, K sensors): linear least
squares in the sensors' eigenbasis, the three-sphere intersection, the safeguarded Gauss-Newton.
Re-exported by :mod:`kinefuse.capture.fusion.trilateration`, whose docstring describes the methods.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.capture.fusion.status import FusionStatus
from kinefuse.capture.fusion.trilat_common import (
    _COLLINEAR_REL,
    _COPLANAR_REL,
    _MAX_HALVINGS,
    _MAX_SENSORS,
    DEFAULT_C_THRESHOLD,
    DEFAULT_MAX_ITER,
    MIN_SENSORS,
    PLANAR_SPREAD_M,
    SINGULAR_REL_DET,
    OutOfPlane,
    Solution,
)
from kinefuse.errors import InputError

Array = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
StatusArray = NDArray[np.int8]


# --------------------------------------------------------------------------------------------
# low-level solvers on (N, K) problems


def _check_problem(
    centres: ArrayLike, ranges: ArrayLike, reference: ArrayLike, mask: ArrayLike | None
) -> tuple[Array, Array, Array, BoolArray]:
    c = np.asarray(centres, dtype=np.float64)
    if c.ndim != 2 or c.shape[1] != 3 or not 1 <= c.shape[0] <= _MAX_SENSORS:
        raise InputError(
            f"centres must have shape (K, 3) with 1 <= K <= {_MAX_SENSORS}, got {c.shape}"
        )
    if not np.isfinite(c).all():
        raise InputError("centres must be finite sensor positions (metres)")
    r = np.asarray(ranges, dtype=np.float64)
    if r.ndim != 2 or r.shape[1] != c.shape[0]:
        raise InputError(
            f"ranges must have shape (N, K) with K = {c.shape[0]} sensors, got {r.shape}"
        )
    with np.errstate(invalid="ignore"):
        if (r < 0).any():
            raise InputError("ranges must be distances >= 0 metres (NaN where missing), got < 0")
    ref = np.asarray(reference, dtype=np.float64)
    if ref.shape != (r.shape[0], 3):
        raise InputError(
            f"reference must have shape ({r.shape[0]}, 3) (one plausible world point per problem, "
            f"e.g. the mean of the sensors' own world-frame measurements), got {ref.shape}"
        )
    ok = np.isfinite(r)
    if mask is not None:
        m = np.asarray(mask)
        if m.dtype != np.bool_ or m.shape != r.shape:
            raise InputError(
                f"mask must be a bool array of shape {r.shape}, got {m.dtype} {m.shape}"
            )
        ok &= m
    return c, r, ref, ok


def _check_out_of_plane(out_of_plane: str) -> None:
    if out_of_plane not in ("auto", "lstsq", "ranges"):
        raise InputError(f"out_of_plane must be 'auto', 'lstsq' or 'ranges', got {out_of_plane!r}")


@dataclass(frozen=True)
class _Frame:
    """Eigenframe of one sensor subset's scatter (one mask pattern)."""

    mean: Array  # (3,)
    axes: Array  # (3, 3) columns: normal, minor in-plane, major in-plane
    coef: Array  # (3, K): coordinate k = coef[k] @ (q - r^2)
    q: Array  # (K,) |s_i - mean|^2, 0 for unused sensors
    n: int
    coplanar: bool
    collinear: bool
    spread_m: float  # RMS distance of the sensors from their best-fit plane


def _frame(centres: Array, use: BoolArray) -> _Frame:
    k = len(centres)
    n = int(use.sum())
    zeros = np.zeros((3, k))
    if n < MIN_SENSORS:
        return _Frame(np.zeros(3), np.eye(3), zeros, np.zeros(k), n, True, True, 0.0)
    mean = centres[use].mean(axis=0)
    d = np.where(use[:, None], centres - mean, 0.0)
    lam, vec = np.linalg.eigh(d.T @ d)  # ascending: normal first
    lam = np.maximum(lam, 0.0)
    collinear = bool(lam[1] <= _COLLINEAR_REL * lam[2])
    coplanar = bool(lam[0] <= _COPLANAR_REL * lam[2])
    coords = d @ vec  # (K, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        coef = np.where(lam[:, None] > 0, coords.T / (2.0 * lam[:, None]), 0.0)
    if coplanar:
        coef[0] = 0.0
    q = np.einsum("ki,ki->k", d, d)
    return _Frame(mean, vec, coef, q, n, coplanar, collinear, float(np.sqrt(lam[0] / n)))


def _patterns(use: BoolArray) -> tuple[NDArray[np.int64], NDArray[np.intp]]:
    codes = use.astype(np.int64) @ (np.int64(1) << np.arange(use.shape[1], dtype=np.int64))
    uniq, inverse = np.unique(codes, return_inverse=True)
    return uniq, inverse.reshape(-1)


def _side(reference: Array, mean: Array, normal: Array) -> Array:
    """+1 / -1: which side of the plane (mean, normal) the reference lies on (+1 on the plane)."""
    h = ((reference - mean) * normal) @ np.ones(3)
    return np.where(h < 0, -1.0, 1.0)


def solve_linear(
    centres: ArrayLike,
    ranges: ArrayLike,
    reference: ArrayLike,
    *,
    mask: ArrayLike | None = None,
    out_of_plane: OutOfPlane = "auto",
) -> Solution:
    """Linear least-squares trilateration of ``N`` problems.

    Parameters
    ----------
    centres : (K, 3) float
        Sensor positions, metres.
    ranges : (N, K) float
        Measured distances from each sensor, metres; NaN where missing.
    reference : (N, 3) float
        A plausible point per problem (the mean of the sensors' own world-frame measurements):
        chooses between mirror solutions and is the fallback position.
    mask : (N, K) bool, optional
        Sensors allowed to take part; default all with a finite range.
    out_of_plane : {"auto", "lstsq", "ranges"}
        How the coordinate normal to the sensors' best-fit plane is found: ``"lstsq"`` plain least
        squares (``DEGENERATE`` when the sensors spread less than :data:`PLANAR_SPREAD_M` out of
        their plane; the reference when they are exactly coplanar); ``"ranges"`` from the ranges
        with the mirror side toward ``reference``; ``"auto"`` whichever has the smaller predicted
        error: the ranges when the sensors' RMS spread out of their plane is below
        :data:`PLANAR_SPREAD_M` or the joint is farther from the plane than that spread.

    Returns
    -------
    Solution
    """
    c, r, ref, use = _check_problem(centres, ranges, reference, mask)
    _check_out_of_plane(out_of_plane)
    pos, status, _, _ = _linear(c, r, ref, use, out_of_plane)
    return Solution(pos, status, np.zeros(r.shape[0], dtype=np.int32), use)


def _linear(
    c: Array, r: Array, ref: Array, use: BoolArray, out_of_plane: str
) -> tuple[Array, StatusArray, Array, Array]:
    """:func:`solve_linear` on checked input; also each problem's sensor plane (mean, normal)."""
    n_prob = r.shape[0]
    pos = np.full((n_prob, 3), np.nan)
    status = np.full(n_prob, FusionStatus.NO_DATA, dtype=np.int8)
    plane_mean = np.full((n_prob, 3), np.nan)
    plane_normal = np.full((n_prob, 3), np.nan)
    r2 = np.where(use, r, 0.0) ** 2
    codes, inverse = _patterns(use)
    ones = np.ones(r.shape[1])
    for p_idx in range(len(codes)):
        # one pattern (the usual case: every sensor sees the joint): views, no gathers
        sel: slice | NDArray[np.intp] = (
            slice(None) if len(codes) == 1 else np.flatnonzero(inverse == p_idx)
        )
        r2s, refs = r2[sel], ref[sel]
        n_sel = len(r2s)
        fr = _frame(c, use[0 if isinstance(sel, slice) else int(sel[0])])
        if fr.n == 0:
            continue
        if fr.n >= MIN_SENSORS:
            plane_mean[sel] = fr.mean
            plane_normal[sel] = fr.axes[:, 0]
        if fr.n < MIN_SENSORS or fr.collinear:
            pos[sel] = refs
            status[sel] = (
                FusionStatus.TOO_FEW_SENSORS if fr.n < MIN_SENSORS else FusionStatus.DEGENERATE
            )
            continue
        g = fr.q[None, :] - r2s  # (n, K), 0 for unused sensors
        h_ls, y, x = (g @ fr.coef.T).T
        h2 = (r2s @ ones) / fr.n - x * x - y * y - fr.q.sum() / fr.n
        h_rng = np.sqrt(np.maximum(h2, 0.0)) * _side(refs, fr.mean, fr.axes[:, 0])
        if out_of_plane == "lstsq":
            use_rng = np.zeros(n_sel, dtype=bool)
        elif out_of_plane == "ranges" or fr.coplanar:
            use_rng = np.ones(n_sel, dtype=bool)
        else:
            use_rng = (np.abs(h_rng) > fr.spread_m) | (fr.spread_m < PLANAR_SPREAD_M)
        h = np.where(use_rng, h_rng, h_ls)
        st = np.where(
            use_rng,
            np.where(h2 < 0, FusionStatus.NO_INTERSECTION, FusionStatus.PLANAR),
            FusionStatus.OK,
        )
        p = fr.mean + np.stack([h, y, x], axis=1) @ fr.axes.T
        if out_of_plane == "lstsq" and fr.spread_m < PLANAR_SPREAD_M:
            # the plain least-squares out-of-plane coordinate is noise (or undefined): flag it
            st = np.full(n_sel, FusionStatus.DEGENERATE)
            if fr.coplanar:
                p = refs
        # a NaN reference leaves the mirror side undecided: say so
        st = np.where(use_rng & ~np.isfinite(refs @ np.ones(3)), FusionStatus.DEGENERATE, st)
        p = np.where((use_rng & (st == FusionStatus.DEGENERATE))[:, None], refs, p)
        pos[sel] = p
        status[sel] = st
    return pos, status, plane_mean, plane_normal


def _three_spheres(
    a: Array, b: Array, cc: Array, ra: Array, rb: Array, rc: Array, ref: Array
) -> tuple[Array, NDArray[np.bool_]]:
    """Closed-form intersection of three spheres per problem (``(n, 3)`` centres, ``(n,)`` radii).

    Returns the intersection on the reference's side of the centres' plane and where the spheres
    do not meet (then the nearest point in the plane).
    """
    d_ab = np.linalg.norm(b - a, axis=1)
    ex = (b - a) / d_ab[:, None]
    i = np.einsum("ni,ni->n", ex, cc - a)
    ey = cc - a - i[:, None] * ex
    j = np.linalg.norm(ey, axis=1)
    ey /= j[:, None]
    ez = np.cross(ex, ey)
    x = (ra**2 - rb**2 + d_ab**2) / (2.0 * d_ab)
    y = (ra**2 - rc**2 + i**2 + j**2) / (2.0 * j) - (i / j) * x
    z2 = ra**2 - x**2 - y**2
    base = a + x[:, None] * ex + y[:, None] * ey
    z = np.sqrt(np.maximum(z2, 0.0)) * _side(ref, base, ez)
    return base + z[:, None] * ez, z2 < 0


def solve_geometric(
    centres: ArrayLike,
    ranges: ArrayLike,
    reference: ArrayLike,
    *,
    mask: ArrayLike | None = None,
) -> Solution:
    """Closed-form three-sphere intersection (paper C) of ``N`` problems.

    Paper C's system has exactly three sensors. With more, every non-degenerate triple of the
    available sensors is intersected in closed form and the triple whose point agrees best with
    all the available ranges (least sum of squared range residuals) is kept: the plausible
    solution, chosen by the sensors that did not take part. (A truncated, MSAC-style cost would
    resist one grossly wrong range better, but on simulated Kinect sessions, where every range
    errs by centimetres, it chose worse triples: least squares it is.)

    Parameters
    ----------
    centres : (K, 3) float
        Sensor positions, metres.
    ranges : (N, K) float
        Distances, metres; NaN where missing.
    reference : (N, 3) float
        Chooses the mirror solution (the nearer one is kept); fallback position.
    mask : (N, K) bool, optional
        Sensors allowed to take part.

    Returns
    -------
    Solution
        ``used`` marks the three sensors chosen per problem.
    """
    c, r, ref, use = _check_problem(centres, ranges, reference, mask)
    n_prob, k = r.shape
    pos = np.full((n_prob, 3), np.nan)
    status = np.full(n_prob, FusionStatus.NO_DATA, dtype=np.int8)
    used = np.zeros_like(use)
    n_use = use.sum(axis=1)
    few = (n_use > 0) & (n_use < MIN_SENSORS)
    pos[few] = ref[few]
    status[few] = FusionStatus.TOO_FEW_SENSORS
    used[few] = use[few]
    triples = np.array(list(combinations(range(k), 3)), dtype=np.intp).reshape(-1, 3)
    if len(triples) == 0:
        return Solution(pos, status, np.zeros(n_prob, dtype=np.int32), used)
    p1, p2, p3 = c[triples[:, 0]], c[triples[:, 1]], c[triples[:, 2]]
    side12 = np.linalg.norm(p2 - p1, axis=1)
    area2 = np.linalg.norm(np.cross(p2 - p1, p3 - p1), axis=1)
    longest = np.max(
        [side12, np.linalg.norm(p3 - p1, axis=1), np.linalg.norm(p3 - p2, axis=1)], axis=0
    )
    good_triangle = area2 > 1e-6 * longest**2  # (n_triples,)
    valid = use[:, triples].all(axis=2) & good_triangle[None, :]  # (N, n_triples)
    has = valid.any(axis=1)
    degenerate = (n_use >= MIN_SENSORS) & ~has
    pos[degenerate] = ref[degenerate]
    status[degenerate] = FusionStatus.DEGENERATE
    used[degenerate] = use[degenerate]

    idx = np.flatnonzero(has)
    if idx.size == 0:
        return Solution(pos, status, np.zeros(n_prob, dtype=np.int32), used)
    r_i, use_i, ref_i = r[idx], use[idx], ref[idx]
    best_cost = np.full(idx.size, np.inf)
    best_p = np.full((idx.size, 3), np.nan)
    best_miss = np.zeros(idx.size, dtype=bool)
    best_t = np.zeros(idx.size, dtype=np.intp)
    for t, (ia, ib, ic) in enumerate(triples):
        ok = valid[idx, t]
        if not ok.any():
            continue
        n_ok = int(ok.sum())
        p, miss = _three_spheres(
            np.broadcast_to(c[ia], (n_ok, 3)),
            np.broadcast_to(c[ib], (n_ok, 3)),
            np.broadcast_to(c[ic], (n_ok, 3)),
            r_i[ok, ia],
            r_i[ok, ib],
            r_i[ok, ic],
            ref_i[ok],
        )
        res = np.linalg.norm(p[:, None, :] - c[None], axis=2) - np.where(use_i[ok], r_i[ok], 0)
        cost = np.where(use_i[ok], res * res, 0.0) @ np.ones(k)
        sel = np.flatnonzero(ok)
        better = cost < best_cost[sel]
        upd = sel[better]
        best_cost[upd] = cost[better]
        best_p[upd] = p[better]
        best_miss[upd] = miss[better]
        best_t[upd] = t
    st = np.where(best_miss, FusionStatus.NO_INTERSECTION, FusionStatus.PLANAR).astype(np.int8)
    undecided = ~np.isfinite(ref_i).all(axis=1)
    st[undecided] = FusionStatus.DEGENERATE
    best_p[undecided] = np.nan
    pos[idx] = best_p
    status[idx] = st
    used[idx[:, None], triples[best_t]] = True
    return Solution(pos, status, np.zeros(n_prob, dtype=np.int32), used)


def _cost(qx: Array, qy: Array, qz: Array, c: Array, r0: Array, w: Array) -> Array:
    """``F = sum_i w_i (|q - s_i| - r_i)^2`` per problem; coordinates as separate ``(n,)``."""
    dx = qx[:, None] - c[:, 0]
    dy = qy[:, None] - c[:, 1]
    dz = qz[:, None] - c[:, 2]
    f = w * (np.sqrt(dx * dx + dy * dy + dz * dz) - r0)
    return np.asarray((f * f) @ np.ones(c.shape[0]), dtype=np.float64)


def _gauss_newton_step(p: Array, c: Array, r0: Array, w: Array) -> tuple[Array, BoolArray]:
    """Gauss-Newton steps ``(J^T J)^-1 J^T f`` (adjugate / det) and where ``J^T J`` is singular.

    ``p (n, 3)``; ``r0, w (n, K)``: ranges and 0/1 weights, 0 for sensors not taking part.
    Written out on ``(n, K)`` arrays per coordinate: einsum on tiny trailing axes is slower.
    """
    ones = np.ones(c.shape[0])
    dx = p[:, 0, None] - c[:, 0]
    dy = p[:, 1, None] - c[:, 1]
    dz = p[:, 2, None] - c[:, 2]
    dist = np.sqrt(dx * dx + dy * dy + dz * dz)
    inv = w / np.where(dist > 0, dist, 1.0)
    ux, uy, uz = dx * inv, dy * inv, dz * inv  # Jacobian rows (p - s_i) / |p - s_i|
    f = w * (dist - r0)
    a, b, cc = (ux * ux) @ ones, (ux * uy) @ ones, (ux * uz) @ ones  # J^T J, symmetric
    d, e, ff = (uy * uy) @ ones, (uy * uz) @ ones, (uz * uz) @ ones
    gx, gy, gz = (ux * f) @ ones, (uy * f) @ ones, (uz * f) @ ones  # J^T f
    c00 = d * ff - e * e  # adjugate (cofactors; symmetric)
    c01 = cc * e - b * ff
    c02 = b * e - cc * d
    c11 = a * ff - cc * cc
    c12 = b * cc - a * e
    c22 = a * d - b * b
    det = a * c00 + b * c01 + cc * c02
    scale = (a + d + ff) / 3.0
    singular = ~(det > SINGULAR_REL_DET * scale**3)  # NaN counts as singular
    inv_det = np.where(singular, 0.0, 1.0 / np.where(singular, 1.0, det))
    step = np.stack(
        [
            (c00 * gx + c01 * gy + c02 * gz) * inv_det,
            (c01 * gx + c11 * gy + c12 * gz) * inv_det,
            (c02 * gx + c12 * gy + c22 * gz) * inv_det,
        ],
        axis=1,
    )
    return step, np.asarray(singular, dtype=bool)


def _rejected(
    q: Array, q_cost: Array, cost: Array, side: Array, mean: Array, normal: Array
) -> BoolArray:
    """Candidates that raise the cost or cross to the mirror side of the sensors' plane."""
    crossed = side * (((q - mean) * normal) @ np.ones(3)) < 0
    return np.asarray(~(q_cost <= cost) | crossed, dtype=bool)


def _safeguarded_update(
    p: Array,
    step: Array,
    cost: Array,
    c: Array,
    r0: Array,
    w: Array,
    side: Array,
    mean: Array,
    normal: Array,
) -> tuple[Array, Array]:
    """Take ``p - step``; halve rejected steps up to ``_MAX_HALVINGS`` times, else stay."""
    p_new = p - step
    new_cost = _cost(p_new[:, 0], p_new[:, 1], p_new[:, 2], c, r0, w)
    worse = _rejected(p_new, new_cost, cost, side, mean, normal)
    for _ in range(_MAX_HALVINGS):
        k = np.flatnonzero(worse)
        if k.size == 0:
            break
        step[k] *= 0.5
        p_new[k] = p[k] - step[k]
        new_cost[k] = _cost(p_new[k, 0], p_new[k, 1], p_new[k, 2], c, r0[k], w[k])
        worse[k] = _rejected(p_new[k], new_cost[k], cost[k], side[k], mean[k], normal[k])
    p_new[worse] = p[worse]
    new_cost[worse] = cost[worse]
    return p_new, new_cost


def _gauss_newton(
    p: Array,
    c: Array,
    r0: Array,
    w: Array,
    side: Array,
    mean: Array,
    normal: Array,
    c_threshold: float,
    max_iter: int,
) -> tuple[Array, NDArray[np.int32], BoolArray, BoolArray]:
    """Safeguarded Gauss-Newton on ``n`` problems, all live at the start.

    Works on a working set that is compacted when fewer than half of it is still live
    (gathering every iteration costs more than a few wasted rows).

    Returns
    -------
    p : (n, 3) final iterates
    iterations : (n,) steps taken
    singular : (n,) stopped on a singular ``J^T J``
    not_converged : (n,) still moving at the iteration cap
    """
    n = len(p)
    p = p.copy()
    iterations = np.zeros(n, dtype=np.int32)
    singular = np.zeros(n, dtype=bool)
    ws = np.arange(n)  # working set: indices into the problems above
    wp, wr, ww, ws_side, ws_mean, ws_normal = p, r0, w, side, mean, normal
    wc = _cost(wp[:, 0], wp[:, 1], wp[:, 2], c, wr, ww)
    live = np.ones(n, dtype=bool)
    for _ in range(max_iter):
        n_live = int(np.count_nonzero(live))
        if n_live == 0:
            break
        if n_live < len(ws) // 2:
            p[ws] = wp
            keep = live
            ws, wp, wc, wr, ww = ws[keep], wp[keep], wc[keep], wr[keep], ww[keep]
            ws_side, ws_mean, ws_normal = ws_side[keep], ws_mean[keep], ws_normal[keep]
            live = np.ones(len(ws), dtype=bool)
        step, sing = _gauss_newton_step(wp, c, wr, ww)
        sing &= live
        step[~live] = 0.0
        wp, new_cost = _safeguarded_update(wp, step, wc, c, wr, ww, ws_side, ws_mean, ws_normal)
        moving = live & ~sing
        iterations[ws[moving]] += 1
        singular[ws[sing]] = True
        converged = moving & (np.abs(new_cost - wc) < c_threshold)
        wc = np.where(moving, new_cost, wc)
        live &= ~sing & ~converged
    p[ws] = wp
    not_converged = np.zeros(n, dtype=bool)
    not_converged[ws[live]] = True
    return p, iterations, singular, not_converged


def solve_nonlinear(
    centres: ArrayLike,
    ranges: ArrayLike,
    reference: ArrayLike,
    *,
    mask: ArrayLike | None = None,
    start: ArrayLike | None = None,
    c_threshold: float = DEFAULT_C_THRESHOLD,
    max_iter: int = DEFAULT_MAX_ITER,
    out_of_plane: OutOfPlane = "auto",
) -> Solution:
    """Gauss-Newton trilateration (paper A) of ``N`` problems.

    Parameters
    ----------
    centres : (K, 3) float
        Sensor positions, metres.
    ranges : (N, K) float
        Distances, metres; NaN where missing.
    reference : (N, 3) float
        Plausible point per problem: the mirror side of the linear start and the fallback.
    mask : (N, K) bool, optional
        Sensors allowed to take part.
    start : (N, 3) float, optional
        Starting points; default the :func:`solve_linear` solution (``reference`` where that is
        degenerate or not finite).
    c_threshold : float
        Stop a problem when ``|F_k - F_{k-1}| < c_threshold`` (square metres).
    max_iter : int
        Iteration cap (>= 1); problems still moving then get ``NOT_CONVERGED``.
    out_of_plane : {"auto", "lstsq", "ranges"}
        Passed to :func:`solve_linear` for the start.

    Returns
    -------
    Solution
        ``PLANAR`` where the start's mirror side came from the reference.
    """
    c, r, ref, use = _check_problem(centres, ranges, reference, mask)
    _check_out_of_plane(out_of_plane)
    if not (np.isfinite(c_threshold) and c_threshold > 0):
        raise InputError(
            f"c_threshold must be a positive number of square metres, got {c_threshold!r}"
        )
    if isinstance(max_iter, bool) or not isinstance(max_iter, int | np.integer) or max_iter < 1:
        raise InputError(f"max_iter must be an integer >= 1, got {max_iter!r}")
    n_prob = r.shape[0]
    n_use = use.sum(axis=1)
    solvable = n_use >= MIN_SENSORS
    lin_pos, lin_status, plane_mean, plane_normal = _linear(c, r, ref, use, out_of_plane)
    if start is None:
        p = lin_pos.copy()
        bad_start = ~np.isfinite(p).all(axis=1) | (lin_status == FusionStatus.DEGENERATE)
        p[bad_start] = ref[bad_start]
    else:
        p = np.asarray(start, dtype=np.float64).copy()
        if p.shape != (n_prob, 3):
            raise InputError(f"start must have shape ({n_prob}, 3), got {p.shape}")
    # the mirror side came from the reference (range closure, or the reference as the start)
    planar = np.isin(
        lin_status,
        [FusionStatus.PLANAR, FusionStatus.NO_INTERSECTION, FusionStatus.DEGENERATE],
    )
    status = np.where(
        solvable,
        np.where(planar, FusionStatus.PLANAR, FusionStatus.OK),
        lin_status,  # TOO_FEW_SENSORS / NO_DATA with the reference already in place
    ).astype(np.int8)
    p[~solvable] = lin_pos[~solvable]
    # where the side came from the reference, iterates stay on the reference's side of the
    # sensors' plane: across it lies the mirror solution, whose cost differs only by noise
    with np.errstate(invalid="ignore"):
        keep_side = planar & solvable & np.isfinite(plane_normal).all(axis=1)
        side = np.where(keep_side, _side(ref, plane_mean, plane_normal), 0.0)

    active = solvable & np.isfinite(p @ np.ones(3))
    status[solvable & ~active] = FusionStatus.DEGENERATE
    r0 = np.where(use, r, 0.0)
    w = use.astype(np.float64)
    iterations = np.zeros(n_prob, dtype=np.int32)
    sub = slice(None) if active.all() else np.flatnonzero(active)
    p_sub, iterations[sub], singular, not_converged = _gauss_newton(
        p[sub],
        c,
        r0[sub],
        w[sub],
        side[sub],
        plane_mean[sub],
        plane_normal[sub],
        c_threshold,
        max_iter,
    )
    p[sub] = p_sub
    status_sub = status[sub]
    status_sub[singular] = FusionStatus.DEGENERATE
    status_sub[not_converged] = FusionStatus.NOT_CONVERGED
    status[sub] = status_sub
    # a start in the plane of exactly coplanar sensors (the ranges do not reach out of it) has a
    # singular J^T J: the cause is the inconsistent ranges, say so
    in_plane = (
        (status == FusionStatus.DEGENERATE)
        & (lin_status == FusionStatus.NO_INTERSECTION)
        & (iterations == 0)
    )
    status[in_plane] = FusionStatus.NO_INTERSECTION
    return Solution(p, status, iterations, use)

"""Trilateration of joints from several depth sensors (paper A, METHODS.md A.5) and its baselines.

Sensor ``i`` sits at ``s_i`` (the translation of its ``sensor2world``) and measures a joint at the
range ``r_i = |joint in the sensor frame|``. The methods find the world point ``p`` whose distances
to the sensors match the ranges:

``linear``
    Linear least squares from the squared range equations differenced against their mean. In the
    eigenbasis of the sensors' scatter matrix the normal equations are diagonal: the two in-plane
    coordinates are always well determined (unless the sensors are collinear), the out-of-plane
    one only as well as the sensors spread out of their best-fit plane. When that spread is
    smaller than the joint's distance from the plane (level sensors at one height, or 3 sensors:
    exactly coplanar), the out-of-plane coordinate is taken from the ranges instead
    (``H^2 = mean(r^2) - X^2 - Y^2 - mean(|s_i - s_mean|^2)``, exact for exact ranges), with the
    mirror sign chosen toward the reference point (status ``PLANAR``). ``out_of_plane="lstsq"``
    keeps the plain least-squares answer (the paper's baseline), flagged ``DEGENERATE`` when the
    sensors spread less than :data:`PLANAR_SPREAD_M` out of their plane (with exactly coplanar
    sensors it does not exist: the reference is returned); ``"ranges"`` always uses the ranges.
``geometric``
    Paper C's closed-form intersection of three spheres. With more than 3 sensors the three
    nearest ones (smallest ranges: Kinect v2 noise grows with distance) among those not collinear
    are used. Of the two mirror solutions the one nearer the reference point is kept (``PLANAR``);
    when the spheres do not meet, the point in the sensors' plane where the radical planes cross
    (``NO_INTERSECTION``).
``nonlinear``
    Paper A's Gauss-Newton on ``F(p) = sum_i (|p - s_i| - r_i)^2``: start from the ``linear``
    solution (the reference point when that is degenerate), step ``-(J^T J)^-1 J^T f`` with the
    3x3 inverse as adjugate / determinant, stop a problem when ``|F_k - F_{k-1}| < c_threshold``
    (converged problems stop updating), cap the iterations. Two safeguards the paper does not
    mention: a step that would raise ``F`` is halved until it does not (plain Gauss-Newton
    wanders from starts near the plane of level sensors, where ``J^T J`` is nearly singular), and
    where the mirror side came from the reference a step may not cross the sensors' plane.
    A singular ``J^T J`` stops the problem with ``DEGENERATE``; the cap gives ``NOT_CONVERGED``.
    Either way the last iterate is returned, and its cost is never above the start's.
``paper``
    The whole chain of paper A: client-side occlusion detection, the server's selection of the
    unoccluded sensors, then ``nonlinear`` on those. When fewer than 3 sensors are selected the
    joint cannot be trilaterated and the mean of the selected sensors' own world-frame
    measurements is returned (``TOO_FEW_SENSORS``): with a single sensor, that sensor's joint, as
    in the paper.

The reference point, used to choose between mirror solutions and as the fallback, is the mean of
the participating sensors' own measurements mapped to the world (:func:`to_world`). Level sensors
at one height see every joint at two mirror-image points with equal ranges; only this direct 3D
information tells them apart.

All solvers are batched over problems (frames x joints): Python loops run only over iterations,
sensor-mask patterns and sensor triples, never over frames or joints.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from itertools import combinations
from typing import Literal, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.camera.intrinsics import Intrinsics
from kinefuse.errors import InputError
from kinefuse.fusion.status import FusionStatus
from kinefuse.geometry.transforms import check_rigid
from kinefuse.occlusion.segments import (
    DEFAULT_NEAR_M,
    OcclusionRule,
    detect_occlusion_sensors,
)
from kinefuse.occlusion.select import select_sensors
from kinefuse.skeleton import N_JOINTS, TrackingState

Array = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
StatusArray = NDArray[np.int8]
_G = TypeVar("_G", bound=np.generic)

OutOfPlane = Literal["auto", "lstsq", "ranges"]
#: The trilateration methods, in the order of the paper's comparison.
METHODS: tuple[str, ...] = ("linear", "geometric", "nonlinear", "paper")

#: Minimum number of sensors to trilaterate a joint.
MIN_SENSORS = 3
#: Default stopping threshold on ``|F_k - F_{k-1}|``, square metres.
DEFAULT_C_THRESHOLD = 1e-6
#: Default iteration cap of the Gauss-Newton solver.
DEFAULT_MAX_ITER = 50
#: ``det(J^T J) / (trace / 3)^3`` below this counts as singular.
SINGULAR_REL_DET = 1e-12
_COPLANAR_REL = 1e-12  # smallest / largest scatter eigenvalue below this: exactly coplanar
_COLLINEAR_REL = 1e-10  # middle / largest scatter eigenvalue below this: collinear
_MAX_SENSORS = 62  # mask patterns are packed into int64
_MAX_HALVINGS = 10  # step halvings before a Gauss-Newton step that raises F is given up
#: Below this RMS spread of the sensors out of their best-fit plane (metres), ``out_of_plane=
#: "auto"`` takes the out-of-plane coordinate from the ranges: with range noise sigma at range r,
#: least squares has error ``r sigma / (sqrt(n) spread)`` there, the ranges at most about
#: ``sqrt(2 r sigma / sqrt(n))`` (0.3 m for 3 m and 3 cm), so least squares only wins with a
#: spread of about 0.2 m or more.
PLANAR_SPREAD_M = 0.2


@dataclass(frozen=True, eq=False)
class Solution:
    """Result of a low-level solver on ``N`` independent problems.

    Attributes
    ----------
    positions : (N, 3) float
        World positions, metres; NaN only with ``NO_DATA`` (or a NaN reference, see the status).
    status : (N,) int8
        :class:`~kinefuse.fusion.status.FusionStatus` codes.
    iterations : (N,) int32
        Gauss-Newton iterations run (0 for the closed-form methods).
    used : (N, K) bool
        The sensors that took part in each problem.
    """

    positions: Array
    status: StatusArray
    iterations: NDArray[np.int32]
    used: BoolArray


@dataclass(frozen=True, eq=False)
class FusionResult:
    """Fused joints of a session.

    Attributes
    ----------
    positions : (T, 25, 3) float
        Joint positions in the world frame, metres; finite except where ``status`` is
        ``NO_DATA``.
    status : (T, 25) int8
        :class:`~kinefuse.fusion.status.FusionStatus` codes.
    used : (T, S, 25) bool
        Sensors that took part per frame and joint.
    iterations : (T, 25) int32
        Gauss-Newton iterations (0 for the closed-form methods).
    """

    positions: Array
    status: StatusArray
    used: BoolArray
    iterations: NDArray[np.int32]

    @property
    def n_sensors(self) -> NDArray[np.int64]:
        """Number of sensors used per frame and joint, ``(T, 25)``."""
        return np.asarray(self.used.sum(axis=1), dtype=np.int64)


# --------------------------------------------------------------------------------------------
# helpers on sessions


def sensor_centres(sensor2world: ArrayLike) -> Array:
    """Optical centres of the sensors in the world, ``(S, 3)`` metres, from ``(S, 4, 4)`` poses."""
    return _check_poses(sensor2world)[:, :3, 3].copy()


def to_world(joints_sensor: ArrayLike, sensor2world: ArrayLike) -> Array:
    """Map every sensor's joints from its own frame into the world.

    Parameters
    ----------
    joints_sensor : (T, S, 25, 3) float
        Joints in each sensor's frame (x right, y down, z forward), metres; NaN stays NaN.
    sensor2world : (S, 4, 4) float
        Rigid poses of the sensors.

    Returns
    -------
    joints_world : (T, S, 25, 3) float
    """
    j = _check_joints(joints_sensor)
    return _to_world(j, _check_poses(sensor2world, j.shape[1]))


def _to_world(j: Array, t: Array) -> Array:
    out = np.empty_like(j)
    for s in range(j.shape[1]):  # a few sensors; each a BLAS product over frames and joints
        out[:, s] = j[:, s] @ t[s, :3, :3].T + t[s, :3, 3]
    return out


def sensor_ranges(joints_sensor: ArrayLike) -> Array:
    """Range of every joint from its sensor's optical centre, ``(T, S, 25)`` metres (NaN kept)."""
    return _ranges(_check_joints(joints_sensor))


def _ranges(j: Array) -> Array:
    return np.asarray(np.sqrt((j * j) @ np.ones(3)), dtype=np.float64)


def _check_joints(joints_sensor: ArrayLike) -> Array:
    j = np.asarray(joints_sensor, dtype=np.float64)
    if j.ndim != 4 or j.shape[2:] != (N_JOINTS, 3) or j.shape[1] < 1:
        raise InputError(
            f"joints_sensor must have shape (T, S, {N_JOINTS}, 3): frames, sensors, joints, xyz "
            f"in each sensor's frame (metres), got {j.shape}; add a sensor axis for one sensor"
        )
    return j


def _check_poses(sensor2world: ArrayLike, n_sensors: int | None = None) -> Array:
    t = np.asarray(sensor2world, dtype=np.float64)
    if t.ndim != 3 or t.shape[1:] != (4, 4):
        raise InputError(f"sensor2world must have shape (S, 4, 4), got {t.shape}")
    if n_sensors is not None and t.shape[0] != n_sensors:
        raise InputError(
            f"sensor2world has {t.shape[0]} poses but the observations have {n_sensors} sensors; "
            f"pass one pose per sensor, in the order of the sensor axis"
        )
    return check_rigid(t, "sensor2world")


def _available(ranges: Array, mask: ArrayLike | None, states: ArrayLike | None) -> BoolArray:
    """Observations that may take part: finite, not at the optical centre, masked in, tracked."""
    with np.errstate(invalid="ignore"):
        avail = np.isfinite(ranges) & (ranges > 0)
    shape = ranges.shape
    if mask is not None:
        m = np.asarray(mask)
        if m.dtype != np.bool_ or m.shape != shape:
            raise InputError(f"mask must be a bool array of shape {shape}, got {m.dtype} {m.shape}")
        avail &= m
    if states is not None:
        s = np.asarray(states)
        if s.shape != shape or not np.issubdtype(s.dtype, np.integer):
            raise InputError(
                f"states must be an integer array of shape {shape} (TrackingState codes), "
                f"got {s.dtype} {s.shape}"
            )
        avail &= s != TrackingState.NOT_TRACKED
    return np.asarray(avail, dtype=bool)


def _to_problems(a: NDArray[_G]) -> NDArray[_G]:
    """``(T, S, 25, ...)`` -> ``(T * 25, S, ...)``."""
    a = np.moveaxis(a, 2, 1)
    return a.reshape(a.shape[0] * a.shape[1], *a.shape[2:])


def _reference(world_p: Array, use_p: BoolArray) -> Array:
    """Mean of the used sensors' world measurements per problem, ``(N, 3)``; NaN if none."""
    total = np.zeros((world_p.shape[0], 3))
    for s in range(world_p.shape[1]):  # a few sensors
        total += np.where(use_p[:, s, None], world_p[:, s], 0.0)
    n = use_p.astype(np.float64) @ np.ones(use_p.shape[1])
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n[:, None] > 0, total / n[:, None], np.nan)


def _to_result(sol: Solution, n_frames: int) -> FusionResult:
    n_sensors = sol.used.shape[1]
    used = sol.used.reshape(n_frames, N_JOINTS, n_sensors).transpose(0, 2, 1)
    return FusionResult(
        positions=sol.positions.reshape(n_frames, N_JOINTS, 3),
        status=sol.status.reshape(n_frames, N_JOINTS),
        used=np.ascontiguousarray(used),
        iterations=sol.iterations.reshape(n_frames, N_JOINTS),
    )


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


# --------------------------------------------------------------------------------------------
# methods on sessions


def _prepare(
    joints_sensor: ArrayLike,
    sensor2world: ArrayLike,
    mask: ArrayLike | None,
    states: ArrayLike | None,
) -> tuple[Array, Array, Array, Array, BoolArray]:
    j = _check_joints(joints_sensor)
    t = _check_poses(sensor2world, j.shape[1])
    ranges = _ranges(j)
    avail = _available(ranges, mask, states)
    return j, t, _to_world(j, t), ranges, avail


def fuse_linear(
    joints_sensor: ArrayLike,
    sensor2world: ArrayLike,
    *,
    mask: ArrayLike | None = None,
    states: ArrayLike | None = None,
    out_of_plane: OutOfPlane = "auto",
) -> FusionResult:
    """Linear least-squares trilateration of every frame and joint (see :func:`solve_linear`).

    Parameters
    ----------
    joints_sensor : (T, S, 25, 3) float
        Each sensor's joints in its own frame (x right, y down, z forward), metres; NaN where
        missing.
    sensor2world : (S, 4, 4) float
        Sensor poses.
    mask : (T, S, 25) bool, optional
        Observations allowed to take part (default all finite ones).
    states : (T, S, 25) int, optional
        :class:`~kinefuse.skeleton.TrackingState` per observation; ``NOT_TRACKED`` ones are left
        out.
    out_of_plane : {"auto", "lstsq", "ranges"}
        See :func:`solve_linear`.

    Returns
    -------
    FusionResult
    """
    j, t, world, ranges, avail = _prepare(joints_sensor, sensor2world, mask, states)
    use_p = _to_problems(avail)
    sol = solve_linear(
        t[:, :3, 3],
        _to_problems(ranges),
        _reference(_to_problems(world), use_p),
        mask=use_p,
        out_of_plane=out_of_plane,
    )
    return _to_result(sol, j.shape[0])


def fuse_geometric(
    joints_sensor: ArrayLike,
    sensor2world: ArrayLike,
    *,
    mask: ArrayLike | None = None,
    states: ArrayLike | None = None,
) -> FusionResult:
    """Three-sphere trilateration (paper C) of every frame and joint (see :func:`solve_geometric`).

    Parameters are those of :func:`fuse_linear`; ``used`` marks the three sensors chosen.
    """
    j, t, world, ranges, avail = _prepare(joints_sensor, sensor2world, mask, states)
    use_p = _to_problems(avail)
    sol = solve_geometric(
        t[:, :3, 3], _to_problems(ranges), _reference(_to_problems(world), use_p), mask=use_p
    )
    return _to_result(sol, j.shape[0])


def fuse_nonlinear(
    joints_sensor: ArrayLike,
    sensor2world: ArrayLike,
    *,
    mask: ArrayLike | None = None,
    states: ArrayLike | None = None,
    c_threshold: float = DEFAULT_C_THRESHOLD,
    max_iter: int = DEFAULT_MAX_ITER,
    out_of_plane: OutOfPlane = "auto",
) -> FusionResult:
    """Gauss-Newton trilateration (paper A) of every frame and joint (see :func:`solve_nonlinear`).

    Parameters are those of :func:`fuse_linear`, plus ``c_threshold`` (square metres) and
    ``max_iter``.
    """
    j, t, world, ranges, avail = _prepare(joints_sensor, sensor2world, mask, states)
    use_p = _to_problems(avail)
    sol = solve_nonlinear(
        t[:, :3, 3],
        _to_problems(ranges),
        _reference(_to_problems(world), use_p),
        mask=use_p,
        c_threshold=c_threshold,
        max_iter=max_iter,
        out_of_plane=out_of_plane,
    )
    return _to_result(sol, j.shape[0])


def fuse_paper(
    joints_sensor: ArrayLike,
    sensor2world: ArrayLike,
    intrinsics: Intrinsics | Sequence[Intrinsics] | None = None,
    *,
    occlusion: tuple[ArrayLike, ArrayLike] | None = None,
    mask: ArrayLike | None = None,
    states: ArrayLike | None = None,
    c_threshold: float = DEFAULT_C_THRESHOLD,
    max_iter: int = DEFAULT_MAX_ITER,
    near_m: float = DEFAULT_NEAR_M,
    rule: OcclusionRule = "crossing",
    out_of_plane: OutOfPlane = "auto",
) -> FusionResult:
    """Paper A's chain: occlusion detection, sensor selection, nonlinear trilateration.

    Parameters
    ----------
    joints_sensor, sensor2world, mask, states, c_threshold, max_iter, out_of_plane
        As in :func:`fuse_nonlinear`.
    intrinsics : Intrinsics or sequence of S Intrinsics, optional
        The sensors' depth cameras, to detect occlusion; not needed with ``occlusion``.
    occlusion : (occluded (T, S, 25) bool, n_intersections (T, S) int), optional
        Occlusion flags and intersection counts the clients computed; default: detect them here
        with :func:`kinefuse.occlusion.detect_occlusion_sensors`.
    near_m, rule
        Occlusion detection settings (see :func:`kinefuse.occlusion.detect_occlusion`).

    Returns
    -------
    FusionResult
        ``used`` is the selection. Joints with fewer than 3 selected sensors get the mean of the
        selected sensors' own world-frame measurements and ``TOO_FEW_SENSORS``.
    """
    j, t, _, _, avail = _prepare(joints_sensor, sensor2world, mask, states)
    if occlusion is None:
        if intrinsics is None:
            raise InputError(
                "fuse_paper needs the sensors' intrinsics to detect occlusion, or the clients' "
                "results as occlusion=(occluded, n_intersections)"
            )
        det = detect_occlusion_sensors(
            np.where(avail[..., None], j, np.nan), intrinsics, near_m=near_m, rule=rule
        )
        occluded, n_int = det.occluded, det.n_intersections
    else:
        if len(occlusion) != 2:
            raise InputError(
                "occlusion must be a pair (occluded (T, S, 25), n_intersections (T, S))"
            )
        occluded, n_int = np.asarray(occlusion[0]), np.asarray(occlusion[1])
    selected = select_sensors(occluded, n_int, avail)
    return fuse_nonlinear(
        j,
        t,
        mask=selected,
        states=states,
        c_threshold=c_threshold,
        max_iter=max_iter,
        out_of_plane=out_of_plane,
    )


def trilaterate(
    joints_sensor: ArrayLike,
    sensor2world: ArrayLike,
    method: str = "nonlinear",
    *,
    mask: ArrayLike | None = None,
    states: ArrayLike | None = None,
    intrinsics: Intrinsics | Sequence[Intrinsics] | None = None,
    occlusion: tuple[ArrayLike, ArrayLike] | None = None,
    c_threshold: float = DEFAULT_C_THRESHOLD,
    max_iter: int = DEFAULT_MAX_ITER,
    out_of_plane: OutOfPlane = "auto",
) -> FusionResult:
    """Fuse a session's joints with one of :data:`METHODS` by name.

    Parameters
    ----------
    joints_sensor : (T, S, 25, 3) float
    sensor2world : (S, 4, 4) float
    method : {"linear", "geometric", "nonlinear", "paper"}
    mask, states, intrinsics, occlusion, c_threshold, max_iter, out_of_plane
        Passed to the method that takes them (``intrinsics``/``occlusion`` to ``paper`` only;
        ``c_threshold``/``max_iter`` to ``nonlinear`` and ``paper``).

    Returns
    -------
    FusionResult
    """
    if method == "linear":
        return fuse_linear(
            joints_sensor, sensor2world, mask=mask, states=states, out_of_plane=out_of_plane
        )
    if method == "geometric":
        return fuse_geometric(joints_sensor, sensor2world, mask=mask, states=states)
    if method == "nonlinear":
        return fuse_nonlinear(
            joints_sensor,
            sensor2world,
            mask=mask,
            states=states,
            c_threshold=c_threshold,
            max_iter=max_iter,
            out_of_plane=out_of_plane,
        )
    if method == "paper":
        return fuse_paper(
            joints_sensor,
            sensor2world,
            intrinsics,
            occlusion=occlusion,
            mask=mask,
            states=states,
            c_threshold=c_threshold,
            max_iter=max_iter,
            out_of_plane=out_of_plane,
        )
    raise InputError(f"unknown trilateration method {method!r}; choose one of {', '.join(METHODS)}")

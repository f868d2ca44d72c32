"""Client-side occlusion detection by 2D bone intersection (paper A, METHODS.md A.4).

A sensor's body tracker guesses the joints it cannot see. To find them, the client projects the
bones into its depth image and tests every pair of non-adjacent bones (no shared joint) for a
crossing with the paper's tests: the bounding boxes overlap and each segment's end points straddle
the other segment (2D cross products of opposite signs, ``<= 0``). At a crossing, the depth of
each bone at the crossing point decides which bone is behind: that one is occluded there.

Joint rule (our choice; the paper flags joints without saying how): a joint of the rear bone is
occluded when the crossing point lies within ``near_m`` metres of it, measured in the image at the
joint's depth (``near_m * f / z`` pixels). A crossing far along a long bone (a thigh crossing the
other shin near the knee) says nothing about the hip at the bone's other end, so flagging both end
points of every rear bone would flag joints that are in plain view; the radius keeps the flag where
the front bone actually covers the body. The default 0.10 m is about the radius of the trunk and
twice that of a limb, the width the front body part covers around the crossing.

Beyond the paper, ``rule="coverage"`` flags a joint when its image point lies inside the projected
capsule (:func:`kinefuse.core.skeleton.capsule_radii`) of a non-adjacent bone whose axis is nearer
to the camera, at that point, by more than half the capsule's radius. Bones hide joints without
crossing their bones (a far arm behind the trunk), which the crossing rule cannot see: on the real
Kinect v2 walk in ``../shared/data/kinect/kinect2_tracking/walker.json`` viewed from five
directions, against capsule ray-cast visibility, the crossing rule scores precision 0.67-0.85 and
recall 0.19-0.27, the coverage rule precision 0.89-0.92 and recall 0.88-0.97; against the Kinect's
own ``inferred`` states of that walk, precision 0.35 vs 0.44 and recall 0.14 vs 0.61 (see
``docs/fusion.md``). The intersection counts are always those of the crossing test.

Depth at the crossing is interpolated perspective-correctly: along a projected 3D segment, ``1/z``
(not ``z``) is linear in the image parameter.

Everything is vectorized over frames and bone pairs; frames are processed in chunks to bound
memory.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.capture.occlusion.rules import OCCLUSION_RULES, OcclusionRule
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.skeleton import N_JOINTS, bone_index_array, capsule_radii
from kinefuse.core.skeleton.kinect_v2 import REFERENCE_HEIGHT_M
from kinefuse.errors import InputError

Array = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: Default radius around a joint within which a crossing occludes it, metres.
DEFAULT_NEAR_M = 0.10
#: A covering bone must be nearer than the joint by this fraction of its capsule radius.
COVERAGE_DEPTH_FRACTION = 0.5
_CHUNK_FRAMES = 2048


@dataclass(frozen=True, eq=False)
class OcclusionResult:
    """Occlusion analysis of one or several sensors.

    Attributes
    ----------
    occluded : (T, 25) or (T, S, 25) bool
        Joint flagged as hidden behind another body part.
    n_intersections : (T,) or (T, S) int
        Number of crossing points between non-adjacent bones in the image.
    bone_occluded : (T, 24) or (T, S, 24) bool
        Bone (in :data:`kinefuse.core.skeleton.BONES` order) that is the rear one at some crossing.
    """

    occluded: BoolArray
    n_intersections: NDArray[np.int64]
    bone_occluded: BoolArray


@dataclass(frozen=True)
class PrecisionRecall:
    """Occlusion detection scored against true visibility.

    ``precision = tp / (tp + fp)`` (NaN when nothing was flagged), ``recall = tp / (tp + fn)``
    (NaN when nothing was truly hidden); a positive is an occluded joint.
    """

    precision: float
    recall: float
    tp: int
    fp: int
    fn: int
    tn: int

    @property
    def f1(self) -> float:
        """Harmonic mean of precision and recall (NaN when either is undefined)."""
        p, r = self.precision, self.recall
        if not (np.isfinite(p) and np.isfinite(r)) or p + r == 0:
            return float("nan")
        return 2 * p * r / (p + r)


def _cross(a: Array, b: Array) -> Array:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def segments_intersect(p11: ArrayLike, p12: ArrayLike, p21: ArrayLike, p22: ArrayLike) -> BoolArray:
    """The paper's 2D segment intersection test: bounding boxes, then two cross-product tests.

    Segment 1 runs from ``p11`` to ``p12``, segment 2 from ``p21`` to ``p22``. Touching counts as
    intersecting (the paper's ``<= 0``). Segments with a NaN end point never intersect.

    Parameters
    ----------
    p11, p12, p21, p22 : (..., 2) float
        End points, broadcast against each other (pixels or any 2D unit).

    Returns
    -------
    hit : (...) bool
    """
    a0, a1, b0, b1 = (
        _check_2d(p, n) for p, n in ((p11, "p11"), (p12, "p12"), (p21, "p21"), (p22, "p22"))
    )
    return _intersect(a0, a1, b0, b1)


def _check_2d(p: ArrayLike, name: str) -> Array:
    a = np.asarray(p, dtype=np.float64)
    if a.ndim == 0 or a.shape[-1] != 2:
        raise InputError(f"{name} must be 2D points with shape (..., 2), got shape {a.shape}")
    return a


def _intersect(a0: Array, a1: Array, b0: Array, b1: Array) -> BoolArray:
    xy = (
        a0[..., 0],
        a0[..., 1],
        a1[..., 0],
        a1[..., 1],
        b0[..., 0],
        b0[..., 1],
        b1[..., 0],
        b1[..., 1],
    )
    return np.asarray(_bbox_overlap(*xy) & _straddle(*xy), dtype=bool)


def _bbox_overlap(
    ax0: Array, ay0: Array, ax1: Array, ay1: Array, bx0: Array, by0: Array, bx1: Array, by1: Array
) -> BoolArray:
    """The paper's 4 bounding-box inequalities (False where a coordinate is NaN)."""
    with np.errstate(invalid="ignore"):
        return np.asarray(
            (
                np.maximum(np.minimum(ax0, ax1), np.minimum(bx0, bx1))
                <= np.minimum(np.maximum(ax0, ax1), np.maximum(bx0, bx1))
            )
            & (
                np.maximum(np.minimum(ay0, ay1), np.minimum(by0, by1))
                <= np.minimum(np.maximum(ay0, ay1), np.maximum(by0, by1))
            ),
            dtype=bool,
        )


def _straddle(
    ax0: Array, ay0: Array, ax1: Array, ay1: Array, bx0: Array, by0: Array, bx1: Array, by1: Array
) -> BoolArray:
    """The paper's two cross-product tests: each segment's ends straddle the other (<= 0)."""
    d2x, d2y = bx1 - bx0, by1 - by0
    d1x, d1y = ax1 - ax0, ay1 - ay0
    with np.errstate(invalid="ignore"):
        a_ok = ((ax0 - bx0) * d2y - (ay0 - by0) * d2x) * (
            (ax1 - bx0) * d2y - (ay1 - by0) * d2x
        ) <= 0
        b_ok = ((bx0 - ax0) * d1y - (by0 - ay0) * d1x) * (
            (bx1 - ax0) * d1y - (by1 - ay0) * d1x
        ) <= 0
    return np.asarray(a_ok & b_ok, dtype=bool)


def crossing_parameters(
    p11: ArrayLike, p12: ArrayLike, p21: ArrayLike, p22: ArrayLike
) -> tuple[Array, Array]:
    """Where two 2D lines cross, as parameters along each segment.

    The crossing point is ``p11 + t (p12 - p11) = p21 + u (p22 - p21)``.

    Parameters
    ----------
    p11, p12, p21, p22 : (..., 2) float

    Returns
    -------
    t, u : (...) float
        Line parameters (0 and 1 at the segments' ends); NaN for parallel lines.
    """
    a0, a1, b0, b1 = (
        _check_2d(p, n) for p, n in ((p11, "p11"), (p12, "p12"), (p21, "p21"), (p22, "p22"))
    )
    return _params(a0, a1, b0, b1)


def _params(a0: Array, a1: Array, b0: Array, b1: Array) -> tuple[Array, Array]:
    d1 = a1 - a0
    d2 = b1 - b0
    den = _cross(d1, d2)
    w = b0 - a0
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(den != 0, 1.0 / den, np.nan)
        return _cross(w, d2) * inv, _cross(w, d1) * inv


def non_adjacent_bone_pairs(bones: ArrayLike | None = None) -> NDArray[np.intp]:
    """All pairs of bones that share no joint.

    Parameters
    ----------
    bones : (B, 2) int, optional
        Bones as joint index pairs; default the 24 Kinect v2 bones.

    Returns
    -------
    pairs : (P, 2) int
        Indices into ``bones``, first < second.
    """
    b = bone_index_array() if bones is None else _check_bones(bones)
    i, j = np.triu_indices(len(b), k=1)
    shared = (b[i, :, None] == b[j, None, :]).any(axis=(1, 2))
    return np.stack([i[~shared], j[~shared]], axis=1).astype(np.intp)


def _check_bones(bones: ArrayLike) -> NDArray[np.intp]:
    b = np.asarray(bones)
    if b.ndim != 2 or b.shape[1] != 2 or not np.issubdtype(b.dtype, np.integer):
        raise InputError(
            f"bones must be an integer (B, 2) array of joint index pairs, got {b.dtype} {b.shape}"
        )
    if b.size and (b.min() < 0 or b.max() >= N_JOINTS):
        raise InputError(f"bone joint indices must be 0..{N_JOINTS - 1}, got {b.min()}..{b.max()}")
    return b.astype(np.intp)


def detect_occlusion(
    joints_sensor: ArrayLike,
    intrinsics: Intrinsics,
    *,
    near_m: float = DEFAULT_NEAR_M,
    bones: ArrayLike | None = None,
    rule: OcclusionRule = "crossing",
    height_m: float = REFERENCE_HEIGHT_M,
) -> OcclusionResult:
    """Flag occluded joints of one sensor from its own joint observations.

    Parameters
    ----------
    joints_sensor : (T, 25, 3) float
        Joints in the sensor frame (x right, y down, z forward), metres; NaN where missing.
        Bones with a missing end point, or behind the camera, take no part.
    intrinsics : Intrinsics
        The sensor's depth camera, used to project the joints.
    near_m : float
        A crossing occludes a joint of the rear bone when it lies within this many metres of the
        joint (measured in the image at the joint's depth). Default 0.10 m; see the module notes.
    bones : (B, 2) int, optional
        Bones to test; default the 24 Kinect v2 bones. ``rule="coverage"`` needs the default.
    rule : {"crossing", "coverage"}
        ``"crossing"``: the paper's rule (a crossing within ``near_m`` of the joint, rear bone);
        ``"coverage"``: ours (the joint inside the projected capsule of a nearer bone).
    height_m : float
        The subject's height, scales the capsule radii of ``rule="coverage"``, metres.

    Returns
    -------
    OcclusionResult
        ``occluded (T, 25)``, ``n_intersections (T,)``, ``bone_occluded (T, B)``.
    """
    j = np.asarray(joints_sensor, dtype=np.float64)
    if j.ndim != 3 or j.shape[1:] != (N_JOINTS, 3):
        raise InputError(
            f"joints_sensor must have shape (T, {N_JOINTS}, 3) (one sensor's frames, metres in "
            f"the sensor frame), got {j.shape}; for several sensors use detect_occlusion_sensors"
        )
    _check_intrinsics(intrinsics)
    if not (np.isfinite(near_m) and near_m > 0):
        raise InputError(f"near_m must be a positive distance in metres, got {near_m!r}")
    if rule not in OCCLUSION_RULES:
        raise InputError(f"rule must be 'crossing' (the paper's) or 'coverage', got {rule!r}")
    b, pairs = _default_bones() if bones is None else (_check_bones(bones), None)
    if rule == "coverage" and bones is not None and not np.array_equal(b, bone_index_array()):
        raise InputError(
            "rule='coverage' uses the capsule radii of the 24 Kinect v2 bones; leave bones unset"
        )
    if not (np.isfinite(height_m) and 0.5 <= height_m <= 2.5):
        raise InputError(f"height_m must be the subject's height, 0.5 to 2.5 m, got {height_m!r}")
    radii = capsule_radii(height_m) if rule == "coverage" else None
    if pairs is None:
        pairs = non_adjacent_bone_pairs(b)
    t_frames = j.shape[0]
    occluded = np.zeros((t_frames, N_JOINTS), dtype=bool)
    bone_occ = np.zeros((t_frames, len(b)), dtype=bool)
    counts = np.zeros(t_frames, dtype=np.int64)
    focal = 0.5 * (intrinsics.fx + intrinsics.fy)
    for start in range(0, t_frames, _CHUNK_FRAMES):
        sl = slice(start, min(start + _CHUNK_FRAMES, t_frames))
        occ, bocc, cnt = _detect_chunk(j[sl], intrinsics, focal, near_m, b, pairs)
        if radii is not None:
            occ = _coverage(j[sl], intrinsics, focal, b, radii)
        occluded[sl], bone_occ[sl], counts[sl] = occ, bocc, cnt
    return OcclusionResult(occluded=occluded, n_intersections=counts, bone_occluded=bone_occ)


_DEFAULT_BONES: tuple[NDArray[np.intp], NDArray[np.intp]] | None = None


def _default_bones() -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """The 24 Kinect v2 bones and their non-adjacent pairs, computed once (read-only): a live
    client tests every body frame one at a time, and building the pairs cost it more than the
    test itself (issue 23)."""
    global _DEFAULT_BONES
    if _DEFAULT_BONES is None:
        b = bone_index_array()
        pairs = non_adjacent_bone_pairs(b)
        b.flags.writeable = False
        pairs.flags.writeable = False
        _DEFAULT_BONES = (b, pairs)
    return _DEFAULT_BONES


def _check_intrinsics(intrinsics: object) -> None:
    if not isinstance(intrinsics, Intrinsics):
        raise InputError(
            f"intrinsics must be a kinefuse.core.camera.intrinsics.Intrinsics, got "
            f"{type(intrinsics).__name__}"
        )


def _detect_chunk(
    j: Array,
    intrinsics: Intrinsics,
    focal: float,
    near_m: float,
    bones: NDArray[np.intp],
    pairs: NDArray[np.intp],
) -> tuple[BoolArray, BoolArray, NDArray[np.int64]]:
    n = j.shape[0]
    uv = intrinsics.project(j)  # (n, 25, 2), NaN behind the camera
    # joint-major (25, n) layout: gathers of rows stay contiguous, elementwise ops fast
    u = np.ascontiguousarray(uv[..., 0].T)
    v = np.ascontiguousarray(uv[..., 1].T)
    zt = np.ascontiguousarray(j[..., 2].T)
    ba, bb = pairs[:, 0], pairs[:, 1]
    ja0, ja1 = bones[ba, 0], bones[ba, 1]
    jb0, jb1 = bones[bb, 0], bones[bb, 1]
    # bounding boxes first, on every pair and frame; the rest only on the candidates
    cand = _bbox_overlap(u[ja0], v[ja0], u[ja1], v[ja1], u[jb0], v[jb0], u[jb1], v[jb1])
    pi, fi = np.nonzero(cand)  # (P, n) layout
    a0, a1, b0, b1 = ja0[pi], ja1[pi], jb0[pi], jb1[pi]
    ax0, ay0, ax1, ay1 = u[a0, fi], v[a0, fi], u[a1, fi], v[a1, fi]
    bx0, by0, bx1, by1 = u[b0, fi], v[b0, fi], u[b1, fi], v[b1, fi]
    hit = _straddle(ax0, ay0, ax1, ay1, bx0, by0, bx1, by1)
    d1x, d1y, d2x, d2y = ax1 - ax0, ay1 - ay0, bx1 - bx0, by1 - by0
    den = d1x * d2y - d1y * d2x
    hit &= den != 0  # parallel overlapping segments: no crossing point, no depth order
    keep = np.flatnonzero(hit)
    fi, pi, den = fi[keep], pi[keep], den[keep]
    a0, a1, b0, b1 = a0[keep], a1[keep], b0[keep], b1[keep]
    wx, wy = bx0[keep] - ax0[keep], by0[keep] - ay0[keep]
    t = np.clip((wx * d2y[keep] - wy * d2x[keep]) / den, 0.0, 1.0)
    s = np.clip((wx * d1y[keep] - wy * d1x[keep]) / den, 0.0, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        za = 1.0 / ((1.0 - t) / zt[a0, fi] + t / zt[a1, fi])  # perspective-correct depth
        zb = 1.0 / ((1.0 - s) / zt[b0, fi] + s / zt[b1, fi])
    cx = ax0[keep] + t * d1x[keep]  # crossing point, pixels
    cy = ay0[keep] + t * d1y[keep]

    bone_occ = np.zeros((n, len(bones)), dtype=bool)
    occluded = np.zeros((n, N_JOINTS), dtype=bool)
    for behind, rear_bone, rj0, rj1 in ((za > zb, ba, a0, a1), (zb > za, bb, b0, b1)):
        k = np.flatnonzero(behind)
        bone_occ[fi[k], rear_bone[pi[k]]] = True
        for rj in (rj0[k], rj1[k]):
            f = fi[k]
            dist_px = np.hypot(cx[k] - u[rj, f], cy[k] - v[rj, f])
            close = dist_px <= near_m * focal / zt[rj, f]
            occluded[f[close], rj[close]] = True
    return occluded, bone_occ, np.bincount(fi, minlength=n).astype(np.int64)


def _coverage(
    j: Array, intrinsics: Intrinsics, focal: float, bones: NDArray[np.intp], radii: Array
) -> BoolArray:
    """Joints ``(n, 25)`` inside the projected capsule of a nearer, non-adjacent bone."""
    uv = intrinsics.project(j)  # (n, 25, 2)
    u = np.ascontiguousarray(uv[..., 0].T)  # (25, n)
    v = np.ascontiguousarray(uv[..., 1].T)
    z = np.ascontiguousarray(j[..., 2].T)
    jq, bq = _COVER_PAIRS[:, 0], _COVER_PAIRS[:, 1]  # (Q,) joint, bone
    j0, j1 = bones[bq, 0], bones[bq, 1]
    ax, ay = u[j0], v[j0]  # (Q, n)
    abx, aby = u[j1] - ax, v[j1] - ay
    px, py = u[jq] - ax, v[jq] - ay
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.clip((px * abx + py * aby) / np.maximum(abx * abx + aby * aby, 1e-12), 0.0, 1.0)
        dist_px = np.hypot(px - t * abx, py - t * aby)
        z_bone = 1.0 / ((1.0 - t) / z[j0] + t / z[j1])  # perspective-correct
        r = radii[bq][:, None]
        covered = (dist_px < r * focal / z_bone) & (z_bone < z[jq] - COVERAGE_DEPTH_FRACTION * r)
    # the pairs are grouped by joint, in joint order: reduce each group
    out = np.logical_or.reduceat(covered, _COVER_STARTS, axis=0)  # (25, n)
    return np.ascontiguousarray(out.T)


def _cover_pairs() -> NDArray[np.intp]:
    bones = bone_index_array()
    return np.array(
        [(j, k) for j in range(N_JOINTS) for k, (a, b) in enumerate(bones) if j not in (a, b)],
        dtype=np.intp,
    )


#: (joint, bone) pairs where the bone does not end at the joint: candidates for coverage.
_COVER_PAIRS = _cover_pairs()
_COVER_STARTS = np.searchsorted(_COVER_PAIRS[:, 0], np.arange(N_JOINTS))


def detect_occlusion_sensors(
    joints_sensor: ArrayLike,
    intrinsics: Intrinsics | Sequence[Intrinsics],
    *,
    near_m: float = DEFAULT_NEAR_M,
    bones: ArrayLike | None = None,
    rule: OcclusionRule = "crossing",
    height_m: float = REFERENCE_HEIGHT_M,
) -> OcclusionResult:
    """:func:`detect_occlusion` for every sensor of a session.

    Parameters
    ----------
    joints_sensor : (T, S, 25, 3) float
        Each sensor's joints in its own frame, metres; NaN where missing.
    intrinsics : Intrinsics or sequence of S Intrinsics
        One camera model for all sensors, or one per sensor.
    near_m, bones, rule, height_m
        As in :func:`detect_occlusion`.

    Returns
    -------
    OcclusionResult
        ``occluded (T, S, 25)``, ``n_intersections (T, S)``, ``bone_occluded (T, S, B)``.
    """
    j = np.asarray(joints_sensor, dtype=np.float64)
    if j.ndim != 4 or j.shape[2:] != (N_JOINTS, 3):
        raise InputError(
            f"joints_sensor must have shape (T, S, {N_JOINTS}, 3) (every sensor's joints in its "
            f"own frame, metres), got {j.shape}"
        )
    n_sensors = j.shape[1]
    intr = _intrinsics_list(intrinsics, n_sensors)
    results = [
        detect_occlusion(j[:, s], intr[s], near_m=near_m, bones=bones, rule=rule, height_m=height_m)
        for s in range(n_sensors)
    ]
    return OcclusionResult(
        occluded=np.stack([r.occluded for r in results], axis=1),
        n_intersections=np.stack([r.n_intersections for r in results], axis=1),
        bone_occluded=np.stack([r.bone_occluded for r in results], axis=1),
    )


def _intrinsics_list(
    intrinsics: Intrinsics | Sequence[Intrinsics], n_sensors: int
) -> list[Intrinsics]:
    if isinstance(intrinsics, Intrinsics):
        return [intrinsics] * n_sensors
    intr = list(intrinsics)
    if len(intr) != n_sensors:
        raise InputError(
            f"got {len(intr)} intrinsics for {n_sensors} sensors; pass one Intrinsics for all "
            f"sensors or one per sensor in the order of the sensor axis"
        )
    for i in intr:
        _check_intrinsics(i)
    return intr


def occlusion_precision_recall(
    occluded: ArrayLike, visible_truth: ArrayLike, valid: ArrayLike | None = None
) -> PrecisionRecall:
    """Score occlusion flags against the true visibility (from the simulator's ray casting).

    Parameters
    ----------
    occluded : (...) bool
        Detected occlusion flags, e.g. ``(T, S, 25)``.
    visible_truth : (...) bool
        True where the joint is truly visible from the sensor; same shape.
    valid : (...) bool, optional
        Entries to score (e.g. joints in view and observed); default all.

    Returns
    -------
    PrecisionRecall
    """
    occ = np.asarray(occluded)
    vis = np.asarray(visible_truth)
    if occ.dtype != np.bool_ or vis.dtype != np.bool_:
        raise InputError(
            f"occluded and visible_truth must be bool arrays, got {occ.dtype} and {vis.dtype}"
        )
    if occ.shape != vis.shape:
        raise InputError(
            f"occluded and visible_truth must have the same shape, got {occ.shape} and {vis.shape}"
        )
    if valid is None:
        ok = np.ones(occ.shape, dtype=bool)
    else:
        ok = np.asarray(valid)
        if ok.dtype != np.bool_ or ok.shape != occ.shape:
            raise InputError(
                f"valid must be a bool array of shape {occ.shape}, got {ok.dtype} {ok.shape}"
            )
    hidden = ~vis
    tp = int((occ & hidden & ok).sum())
    fp = int((occ & vis & ok).sum())
    fn = int((~occ & hidden & ok).sum())
    tn = int((~occ & vis & ok).sum())
    precision = tp / (tp + fp) if tp + fp else float("nan")
    recall = tp / (tp + fn) if tp + fn else float("nan")
    return PrecisionRecall(precision=precision, recall=recall, tp=tp, fp=fp, fn=fn, tn=tn)

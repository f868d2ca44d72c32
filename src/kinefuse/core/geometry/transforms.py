"""Rigid transforms (rotations: :mod:`kinefuse.core.geometry.rotations`).

Naming follows ``A2B``: ``sensor2world`` maps a point from the sensor frame into the world frame,
``p_world = sensor2world @ [p_sensor, 1]``. Batched inputs have their batch axes first:
transforms ``(..., 4, 4)``, points ``(..., 3)``.

Sensor frames are OpenCV-style: x right, y down, z forward along the optical axis. The world is
right-handed with z up.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.core.geometry.rotations import rot_z

Array = NDArray[np.float64]


def check_points(p: ArrayLike, name: str = "points") -> Array:
    """Coerce to a float64 array whose last axis has length 3."""
    a = np.asarray(p, dtype=np.float64)
    if a.ndim == 0 or a.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (..., 3), got {a.shape}")
    return a


#: How far from orthonormal (max abs entry of ``R^T R - I``) a rotation block may be.
RIGID_ATOL = 1e-6


def check_transform(t: ArrayLike, name: str = "transform") -> Array:
    """Coerce to a float64 array of shape ``(..., 4, 4)`` (the shape only; see
    :func:`check_rigid` for the rigidity check)."""
    a = np.asarray(t, dtype=np.float64)
    if a.ndim < 2 or a.shape[-2:] != (4, 4):
        raise ValueError(f"{name} must have shape (..., 4, 4), got {a.shape}")
    return a


def check_rigid(t: ArrayLike, name: str = "transform", *, atol: float = RIGID_ATOL) -> Array:
    """Coerce to ``(..., 4, 4)`` float64 and check that every transform is rigid and finite.

    Rigid: the rotation block is orthonormal within ``atol`` with determinant +1 (no
    reflection), and the bottom row is ``[0, 0, 0, 1]``.

    Raises
    ------
    InputError
        Naming ``name``, which transforms (by index) fail and how to build a proper one.
    """
    from kinefuse.errors import InputError

    try:
        a = np.asarray(t, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a numeric (..., 4, 4) array") from None
    if a.ndim < 2 or a.shape[-2:] != (4, 4):
        raise InputError(f"{name} must have shape (..., 4, 4), got {a.shape}")
    flat = a.reshape(-1, 4, 4)
    finite = np.asarray(np.isfinite(flat).all(axis=(1, 2)))
    r = np.where(finite[:, None, None], flat[:, :3, :3], np.eye(3))
    ortho = np.abs(np.einsum("nji,njk->nik", r, r) - np.eye(3)).max(axis=(1, 2)) <= atol
    proper = np.linalg.det(r) > 0
    bottom = np.abs(flat[:, 3] - (0.0, 0.0, 0.0, 1.0)).max(axis=1) <= 1e-9
    ok = finite & ortho & proper & bottom
    if not finite.all():
        bad = np.flatnonzero(~finite)[:5].tolist()
        where = "" if a.ndim == 2 else f" (index {', '.join(map(str, bad))})"
        raise InputError(f"{name}{where} is not finite (NaN or inf): calibrate every sensor first")
    if not ok.all():
        bad = np.flatnonzero(~ok)[:5].tolist()
        where = "" if a.ndim == 2 else f" (index {', '.join(map(str, bad))})"
        raise InputError(
            f"{name}{where} is not a rigid transform: its rotation block must be orthonormal "
            "with det +1 and its last row [0, 0, 0, 1]; build it with "
            "kinefuse.core.geometry.transforms.make_transform or look_at, or calibrate again"
        )
    return a


def make_transform(rotation: ArrayLike, translation: ArrayLike) -> Array:
    """Transforms ``(..., 4, 4)`` from rotations ``(..., 3, 3)`` and translations ``(..., 3)``."""
    r = np.asarray(rotation, dtype=np.float64)
    t = np.asarray(translation, dtype=np.float64)
    out = np.zeros((*r.shape[:-2], 4, 4))
    out[..., :3, :3] = r
    out[..., :3, 3] = t
    out[..., 3, 3] = 1.0
    return out


def invert_transform(a2b: ArrayLike) -> Array:
    """Inverse of rigid transforms ``(..., 4, 4)`` (``a2b`` -> ``b2a``), exact for rigid input."""
    t = check_transform(a2b)
    r = t[..., :3, :3]
    rt = np.swapaxes(r, -1, -2)
    return make_transform(rt, -np.einsum("...ij,...j->...i", rt, t[..., :3, 3]))


def apply_transform(a2b: ArrayLike, p_a: ArrayLike) -> Array:
    """Map points ``(..., 3)`` from frame A to frame B with one ``(4, 4)`` transform.

    NaN points stay NaN.
    """
    t = check_transform(a2b)
    p = check_points(p_a)
    if t.shape != (4, 4):
        raise ValueError(f"apply_transform takes one (4, 4) transform, got {t.shape}")
    return p @ t[:3, :3].T + t[:3, 3]


def look_at(position_m: ArrayLike, target_m: ArrayLike, roll_rad: float = 0.0) -> Array:
    """``sensor2world`` of a camera at ``position_m`` whose optical axis points at ``target_m``.

    The camera's x axis (image right) is kept horizontal, y (image down) points as far down as
    possible; ``roll_rad`` then turns the camera about its optical axis (positive: image turns
    clockwise as seen by the camera, i.e. right-handed about +z of the sensor).

    Returns
    -------
    sensor2world : (4, 4) float
    """
    pos = check_points(position_m, "position_m").reshape(3)
    tgt = check_points(target_m, "target_m").reshape(3)
    z = tgt - pos
    n = np.linalg.norm(z)
    if n < 1e-9:
        raise ValueError("look_at: position and target coincide; the camera has no direction")
    z = z / n
    up = np.array([0.0, 0.0, 1.0])
    x = np.cross(z, up)  # image right: horizontal
    if np.linalg.norm(x) < 1e-6:
        raise ValueError("look_at: the camera looks straight up or down; give a tilted target")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)  # image down
    r = np.stack([x, y, z], axis=1) @ rot_z(roll_rad)
    return make_transform(r, pos)


def rigid_fit(
    src: ArrayLike, dst: ArrayLike, weights: ArrayLike | None = None
) -> tuple[Array, Array]:
    """Least-squares rigid transforms (Kabsch/Umeyama, no scale; Söderkvist & Wedin 1993 for a
    marker cluster), per frame: the package's one rigid fit.

    Parameters
    ----------
    src : (M, 3) or (T, M, 3) float
        The points in the reference pose (one set for every frame, or one per frame); NaN points
        are not used.
    dst : (T, M, 3) float
        The same points over time, NaN where missing.
    weights : (M,) or (T, M) float, optional
        Each pair's weight (non-finite or non-positive: not used); 1 by default.

    Returns
    -------
    rotation : (T, 3, 3) float
    translation : (T, 3) float
        ``dst[t] ≈ rotation[t] @ src + translation[t]``; NaN on frames with fewer than three
        pairs.
    """
    r, p, _ = _rigid_fit(src, dst, weights)
    return r, p


def _rigid_fit(
    src: ArrayLike, dst: ArrayLike, weights: ArrayLike | None
) -> tuple[Array, Array, Array]:
    """:func:`rigid_fit`, with the singular values ``(T, 3)`` of each frame's cross-covariance."""
    b = np.asarray(dst, dtype=np.float64)
    a = np.broadcast_to(np.asarray(src, dtype=np.float64), b.shape)
    w = np.ones(b.shape[:2]) if weights is None else np.asarray(weights, dtype=np.float64)
    w = np.broadcast_to(w, b.shape[:2])
    with np.errstate(invalid="ignore"):
        keep = np.isfinite(a).all(-1) & np.isfinite(b).all(-1) & np.isfinite(w) & (w > 0)
    w = np.where(keep, w, 0.0)  # (T, M)
    a0 = np.where(np.isfinite(a), a, 0.0)
    b0 = np.where(np.isfinite(b), b, 0.0)
    n = (w > 0).sum(1)  # (T,)
    ok = n >= 3
    ws = np.where(ok, w.sum(1), 1.0)[:, None]
    ca = np.einsum("tm,tmc->tc", w, a0) / ws
    cb = np.einsum("tm,tmc->tc", w, b0) / ws
    h = np.einsum("tm,tmi,tmj->tij", w, a0 - ca[:, None], b0 - cb[:, None])
    u, s, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(np.einsum("tji,tkj->tik", vt, u)))
    d = np.where(d == 0, 1.0, d)
    e = np.ones((b.shape[0], 3))
    e[:, 2] = d
    r = np.einsum("tji,tj,tkj->tik", vt, e, u)
    p = cb - np.einsum("tij,tj->ti", r, ca)
    r[~ok] = np.nan
    p[~ok] = np.nan
    return r, p, s


def kabsch(src: ArrayLike, dst: ArrayLike, weights: ArrayLike | None = None) -> Array:
    """Rigid transform ``src2dst`` minimizing the (weighted) squared distances (one frame of
    :func:`rigid_fit`). Rows with NaN in either set are ignored.

    Parameters
    ----------
    src, dst : (N, 3) float
        Corresponding points; at least 3 non-collinear finite pairs.
    weights : (N,) float, optional

    Returns
    -------
    src2dst : (4, 4) float
    """
    a = check_points(src, "src").reshape(-1, 3)
    b = check_points(dst, "dst").reshape(-1, 3)
    if a.shape != b.shape:
        raise ValueError(f"src and dst must have the same shape, got {a.shape} and {b.shape}")
    w = np.ones(len(a)) if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
    ok = np.isfinite(a).all(1) & np.isfinite(b).all(1) & np.isfinite(w) & (w > 0)
    if ok.sum() < 3:
        raise ValueError(f"kabsch needs at least 3 finite point pairs, got {int(ok.sum())}")
    r, t, s = _rigid_fit(a[ok], b[ok][None], (w[ok] / w[ok].sum())[None])
    if s[0, 1] < 1e-12 * max(s[0, 0], 1e-300):
        raise ValueError("kabsch: the points are collinear; the rotation is not determined")
    return make_transform(r[0], t[0])


def fit_plane(
    points: ArrayLike, weights: ArrayLike | None = None, *, through_origin: bool = False
) -> tuple[Array, Array]:
    """Least-squares plane through ``points (N, 3)``: ``(centroid (3,), unit normal (3,))``, the
    package's one plane fit (the smallest principal axis of the weighted scatter matrix).

    ``weights (N,)`` (optional) weigh each point's squared distance. ``through_origin``: the
    plane through the origin instead (the centroid returned is then the origin), as for unit
    directions on the sphere. The normal's sign is arbitrary; orient it where the caller knows
    which side is which.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 3:
        raise ValueError(f"fit_plane needs (N >= 3, 3) points, got {p.shape}")
    w = np.ones(len(p)) if weights is None else np.asarray(weights, dtype=np.float64)
    c = np.zeros(3) if through_origin else (w[:, None] * p).sum(0) / w.sum()
    q = p if through_origin else p - c
    _, vec = np.linalg.eigh((q * w[:, None]).T @ q)
    return c, np.asarray(vec[:, 0])

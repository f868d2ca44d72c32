"""Vectorized ray casting against capsules, spheres and planes.

All functions take ray origins ``(N, 3)`` (or one ``(3,)`` broadcast to all rays) and unit
directions ``(N, 3)``, and return the ray parameter ``t`` (distance along the ray, metres) of the
nearest hit in front of the origin, ``inf`` where there is none.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]


def ray_capsules(
    origins: ArrayLike, dirs: ArrayLike, a: ArrayLike, b: ArrayLike, radius: ArrayLike
) -> Array:
    """Distance along each ray to each capsule.

    A capsule is the set of points within ``radius`` of the segment ``a``–``b``.

    Parameters
    ----------
    origins : (N, 3) or (3,) float
    dirs : (N, 3) float
        Unit directions.
    a, b : (C, 3) float
        Capsule end points.
    radius : (C,) float

    Returns
    -------
    t : (N, C) float
        Nearest hit in front of the origin (t > 0), ``inf`` for a miss. Rays that start inside a
        capsule report the exit point.
    """
    d = np.asarray(dirs, dtype=np.float64)
    o = np.asarray(origins, dtype=np.float64)
    o_b = o.reshape(1, 1, 3) if o.ndim == 1 else np.broadcast_to(o, d.shape)[None]
    a_ = np.asarray(a, dtype=np.float64)
    b_ = np.asarray(b, dtype=np.float64)
    return ray_capsules_batched(o_b, d[None], a_[None], b_[None], radius)[0]


def ray_spheres(origins: ArrayLike, dirs: ArrayLike, centre: ArrayLike, radius: ArrayLike) -> Array:
    """Distance along each ray to each sphere: ``(N, S)``, ``inf`` for a miss."""
    o = np.broadcast_to(np.asarray(origins, dtype=np.float64), np.shape(dirs))
    d = np.asarray(dirs, dtype=np.float64)
    c = np.asarray(centre, dtype=np.float64).reshape(-1, 3)
    r = np.asarray(radius, dtype=np.float64).reshape(-1)
    oc = o[:, None, :] - c[None, :, :]
    bb = np.einsum("nci,ni->nc", oc, d)
    cc = np.einsum("nci,nci->nc", oc, oc) - r * r
    hh = bb * bb - cc
    sq = np.sqrt(np.maximum(hh, 0.0))
    t = -bb - sq
    t = np.where(t > 0, t, -bb + sq)
    return np.where((hh >= 0) & (t > 0), t, np.inf)


def ray_plane(origins: ArrayLike, dirs: ArrayLike, point: ArrayLike, normal: ArrayLike) -> Array:
    """Distance along each ray to one plane through ``point`` with ``normal``: ``(N,)``."""
    o = np.broadcast_to(np.asarray(origins, dtype=np.float64), np.shape(dirs))
    d = np.asarray(dirs, dtype=np.float64)
    n = np.asarray(normal, dtype=np.float64)
    p = np.asarray(point, dtype=np.float64)
    den = d @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ((p - o) @ n) / den
    return np.where(np.isfinite(t) & (t > 0), t, np.inf)


def ray_capsules_batched(
    origins: ArrayLike, dirs: ArrayLike, a: ArrayLike, b: ArrayLike, radius: ArrayLike
) -> Array:
    """Distance along each ray to each capsule, with a different capsule set per batch item.

    The batched twin of :func:`ray_capsules`: batch ``k`` (a frame, say) casts its own rays against
    its own capsules, so ``B`` frames of ``N`` rays and ``C`` capsules cost ``B * N * C`` tests
    instead of ``(B * N) * (B * C)``. A single origin (one camera) is the fast path.

    Parameters
    ----------
    origins : (3,) or (B, 1, 3) or (B, N, 3) float
        Ray origins (broadcast against ``dirs``).
    dirs : (B, N, 3) float
        Unit directions.
    a, b : (B, C, 3) float
        Capsule end points of every batch item.
    radius : (C,) or (B, C) float

    Returns
    -------
    t : (B, N, C) float
        Nearest hit in front of the origin (t > 0), ``inf`` for a miss; rays that start inside a
        capsule report the exit point, as in :func:`ray_capsules`.
    """
    d = np.asarray(dirs, dtype=np.float64)
    if d.ndim != 3 or d.shape[-1] != 3:
        raise ValueError(f"dirs must have shape (B, N, 3), got {d.shape}")
    a_ = np.asarray(a, dtype=np.float64)
    b_ = np.asarray(b, dtype=np.float64)
    if a_.ndim != 3 or a_.shape != b_.shape or a_.shape[0] != d.shape[0] or a_.shape[-1] != 3:
        raise ValueError(
            f"capsule end points must have shape (B, C, 3) with B = {d.shape[0]}, "
            f"got {a_.shape} and {b_.shape}"
        )
    o = np.asarray(origins, dtype=np.float64)
    r = np.broadcast_to(np.asarray(radius, dtype=np.float64), a_.shape[:2])
    r2 = (r * r)[:, None, :]  # (B, 1, C)
    ba = b_ - a_  # (B, C, 3)
    baba = np.einsum("bci,bci->bc", ba, ba)[:, None, :]  # (B, 1, C)
    bard = d @ ba.transpose(0, 2, 1)  # (B, N, C)
    shared = o.ndim == 1 or (o.ndim == 3 and o.shape[1] == 1)
    if shared:  # one origin per batch item: everything but the directions is per capsule
        o3 = np.broadcast_to(o.reshape(-1, 1, 3) if o.ndim == 3 else o, (d.shape[0], 1, 3))
        oa = o3 - a_  # (B, C, 3)
        baoa = np.einsum("bci,bci->bc", oa, ba)[:, None, :]
        rdoa = d @ oa.transpose(0, 2, 1)  # (B, N, C)
        oaoa = np.einsum("bci,bci->bc", oa, oa)[:, None, :]
        ob = oa - ba
        rdob = d @ ob.transpose(0, 2, 1)
        obob = np.einsum("bci,bci->bc", ob, ob)[:, None, :]
    else:
        of = np.broadcast_to(o, d.shape)
        oa4 = of[:, :, None, :] - a_[:, None, :, :]  # (B, N, C, 3)
        baoa = np.einsum("bnci,bci->bnc", oa4, ba)
        rdoa = np.einsum("bnci,bni->bnc", oa4, d)
        oaoa = np.einsum("bnci,bnci->bnc", oa4, oa4)
        ob4 = oa4 - ba[:, None, :, :]
        rdob = np.einsum("bnci,bni->bnc", ob4, d)
        obob = np.einsum("bnci,bnci->bnc", ob4, ob4)
    qa = baba - bard * bard
    qb = baba * rdoa - baoa * bard
    qc = baba * oaoa - baoa * baoa - r2 * baba
    h = qb * qb - qa * qc
    t = np.full(bard.shape, np.inf)
    with np.errstate(invalid="ignore", divide="ignore"):
        sq = np.sqrt(np.maximum(h, 0.0))
        t_cyl = (-qb - sq) / qa
        y = baoa + t_cyl * bard
        body = (h >= 0) & (qa > 1e-12) & (y > 0) & (y < baba) & (t_cyl > 0)
        t = np.where(body, t_cyl, t)
        for bb, oo in ((rdoa, oaoa), (rdob, obob)):  # end caps: spheres at a and b
            hh = bb * bb - (oo - r2)
            root = np.sqrt(np.maximum(hh, 0.0))
            tc = np.where(-bb - root > 0, -bb - root, -bb + root)
            hit = (hh >= 0) & (tc > 0)
            t = np.where(hit & (tc < t), tc, t)
    return t

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
    o = np.asarray(origins, dtype=np.float64)
    d = np.asarray(dirs, dtype=np.float64)
    a_ = np.asarray(a, dtype=np.float64)
    b_ = np.asarray(b, dtype=np.float64)
    r = np.asarray(radius, dtype=np.float64)
    o = np.broadcast_to(o, d.shape)
    ba = b_ - a_  # (C, 3)
    baba = np.einsum("ci,ci->c", ba, ba)  # (C,)
    oa = o[:, None, :] - a_[None, :, :]  # (N, C, 3)
    bard = d @ ba.T  # (N, C)
    baoa = np.einsum("nci,ci->nc", oa, ba)
    rdoa = np.einsum("nci,ni->nc", oa, d)
    oaoa = np.einsum("nci,nci->nc", oa, oa)
    r2 = r * r
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
        # end caps: spheres at a and b
        for oc in (oa, oa - ba[None, :, :]):
            bb = np.einsum("nci,ni->nc", oc, d)
            cc = np.einsum("nci,nci->nc", oc, oc) - r2
            hh = bb * bb - cc
            tc = -bb - np.sqrt(np.maximum(hh, 0.0))
            tc = np.where(tc > 0, tc, -bb + np.sqrt(np.maximum(hh, 0.0)))
            hit = (hh >= 0) & (tc > 0)
            t = np.where(hit & (tc < t), tc, t)
    return t


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

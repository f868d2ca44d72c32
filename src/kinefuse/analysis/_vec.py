"""Small batched vector and rotation helpers of the analysis core (pure numpy, ``(..., 3)``)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]


def unit(v: ArrayLike) -> Array:
    """``v / |v|`` along the last axis; NaN where ``|v|`` is zero or not finite."""
    a = np.asarray(v, dtype=np.float64)
    n = np.sqrt(np.einsum("...i,...i->...", a, a))[..., None]
    with np.errstate(invalid="ignore", divide="ignore"):
        out = a / n
    out[~(n[..., 0] > 1e-12)] = np.nan
    return out


def dot(a: Array, b: Array) -> Array:
    """Dot product along the last axis."""
    return np.einsum("...i,...i->...", a, b)


def rodrigues(axis: ArrayLike, angle: ArrayLike) -> Array:
    """Rotation matrices ``(..., 3, 3)`` about unit ``axis (..., 3)`` by ``angle (...)`` rad."""
    k = np.asarray(axis, dtype=np.float64)
    t = np.asarray(angle, dtype=np.float64)
    k, t = np.broadcast_arrays(k, t[..., None])
    t = t[..., 0]
    c, s = np.cos(t), np.sin(t)
    x, y, z = k[..., 0], k[..., 1], k[..., 2]
    C = 1.0 - c
    r = np.empty((*t.shape, 3, 3))
    r[..., 0, 0] = c + x * x * C
    r[..., 0, 1] = x * y * C - z * s
    r[..., 0, 2] = x * z * C + y * s
    r[..., 1, 0] = y * x * C + z * s
    r[..., 1, 1] = c + y * y * C
    r[..., 1, 2] = y * z * C - x * s
    r[..., 2, 0] = z * x * C - y * s
    r[..., 2, 1] = z * y * C + x * s
    r[..., 2, 2] = c + z * z * C
    return r


def rotate(axis: Array, angle: Array, v: Array) -> Array:
    """Rotate ``v (..., 3)`` about unit ``axis (..., 3)`` by ``angle (...)`` rad (Rodrigues)."""
    c = np.cos(angle)[..., None]
    s = np.sin(angle)[..., None]
    return v * c + np.cross(axis, v) * s + axis * dot(axis, v)[..., None] * (1.0 - c)


def signed_angle(a: Array, b: Array, axis: Array) -> Array:
    """Angle ``(...)`` rad of the rotation about unit ``axis`` taking ``a`` toward ``b``.

    Both vectors are projected on the plane orthogonal to ``axis`` first.
    """
    a_p = a - dot(a, axis)[..., None] * axis
    b_p = b - dot(b, axis)[..., None] * axis
    return np.arctan2(dot(axis, np.cross(a_p, b_p)), dot(a_p, b_p))


def minimal_rotation(a: Array, b: Array) -> Array:
    """The smallest rotations ``(..., 3, 3)`` taking unit ``a`` onto unit ``b``."""
    v = np.cross(a, b)
    c = dot(a, b)
    vx = np.zeros((*v.shape[:-1], 3, 3))
    vx[..., 0, 1], vx[..., 0, 2] = -v[..., 2], v[..., 1]
    vx[..., 1, 0], vx[..., 1, 2] = v[..., 2], -v[..., 0]
    vx[..., 2, 0], vx[..., 2, 1] = -v[..., 1], v[..., 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        f = 1.0 / (1.0 + c)
    r = np.eye(3) + vx + (vx @ vx) * f[..., None, None]
    # anti-parallel: rotate by pi about any axis orthogonal to a
    anti = c < -1.0 + 1e-9
    if np.any(anti):
        aa = a[anti]
        ortho = np.cross(aa, np.array([1.0, 0.0, 0.0]))
        small = np.linalg.norm(ortho, axis=-1) < 1e-6
        ortho[small] = np.cross(aa[small], np.array([0.0, 1.0, 0.0]))
        r[anti] = rodrigues(unit(ortho), np.full(aa.shape[0], np.pi))
    return r


def twist_angle(r: Array, axis: Array) -> Array:
    """Twist ``(...)`` rad of rotations ``r (..., 3, 3)`` about unit ``axis (..., 3)``.

    Closed-form swing-twist decomposition: with the quaternion ``(w, v)`` of ``r``, the twist
    about ``axis`` is ``2 atan2(v . axis, w)``, wrapped to ``(-pi, pi]``.
    """
    w = 0.5 * np.sqrt(np.maximum(1.0 + r[..., 0, 0] + r[..., 1, 1] + r[..., 2, 2], 0.0))
    v = np.stack(
        [r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]],
        axis=-1,
    )
    # 4 w v = (r32 - r23, ...); use the unnormalized form so w -> 0 stays defined
    t = 2.0 * np.arctan2(dot(v, axis), 4.0 * w * w)
    return wrap(t)


def wrap(angle: ArrayLike) -> Array:
    """Angles wrapped to ``(-pi, pi]``."""
    a = np.asarray(angle, dtype=np.float64)
    return np.pi - np.mod(np.pi - a, 2.0 * np.pi)


def frame_from(u: Array, r: Array) -> Array:
    """Orthonormal frames ``(..., 3, 3)`` with columns ``[u, w, u x w]``, ``w`` = ``r`` made
    orthogonal to ``u`` (Gram-Schmidt). NaN where ``r`` is parallel to ``u`` or missing."""
    e0 = unit(u)
    w = unit(r - dot(r, e0)[..., None] * e0)
    return np.stack([e0, w, np.cross(e0, w)], axis=-1)


def chordal_mean(r: Array) -> Array:
    """Mean rotation ``(3, 3)`` of rotations ``r (N, 3, 3)`` (projection of the sum onto SO(3))."""
    s = np.nansum(r, axis=0)
    u, _, vt = np.linalg.svd(s)
    d = np.sign(np.linalg.det(u @ vt))
    return np.asarray(u @ np.diag([1.0, 1.0, d]) @ vt)


def tmv(r: Array, v: Array) -> Array:
    """``R^T v`` for stacks ``r (..., 3, 3)`` and ``v (..., 3)``."""
    return np.matmul(np.swapaxes(r, -1, -2), v[..., None])[..., 0]


def mv(r: Array, v: Array) -> Array:
    """``R v`` for stacks ``r (..., 3, 3)`` and ``v (..., 3)`` (``v`` may be one vector)."""
    return np.matmul(r, np.asarray(v)[..., None])[..., 0]


def tmm(a: Array, b: Array) -> Array:
    """``A^T B`` for stacks of 3x3 matrices."""
    return np.matmul(np.swapaxes(a, -1, -2), b)

"""Small batched vector helpers of the analysis core (pure numpy, ``(..., 3)``); ``unit``, the
frame builder and the rotation helpers are in :mod:`kinefuse.core.geometry.rotations`."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]


def dot(a: Array, b: Array) -> Array:
    """Dot product along the last axis."""
    return np.einsum("...i,...i->...", a, b)


def signed_angle(a: Array, b: Array, axis: Array) -> Array:
    """Angle ``(...)`` rad of the rotation about unit ``axis`` taking ``a`` toward ``b``.

    Both vectors are projected on the plane orthogonal to ``axis`` first.
    """
    a_p = a - dot(a, axis)[..., None] * axis
    b_p = b - dot(b, axis)[..., None] * axis
    return np.arctan2(dot(axis, np.cross(a_p, b_p)), dot(a_p, b_p))


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


def tmv(r: Array, v: Array) -> Array:
    """``R^T v`` for stacks ``r (..., 3, 3)`` and ``v (..., 3)``."""
    return np.matmul(np.swapaxes(r, -1, -2), v[..., None])[..., 0]


def mv(r: Array, v: Array) -> Array:
    """``R v`` for stacks ``r (..., 3, 3)`` and ``v (..., 3)`` (``v`` may be one vector)."""
    return np.matmul(r, np.asarray(v)[..., None])[..., 0]


def tmm(a: Array, b: Array) -> Array:
    """``A^T B`` for stacks of 3x3 matrices."""
    return np.matmul(np.swapaxes(a, -1, -2), b)

"""Rotations: the one home of the package's rotation helpers (pure numpy and scipy).

Matrices act on column vectors (``v' = R v``) and are right-handed; batched inputs have their
batch axes first (matrices ``(..., 3, 3)``, vectors ``(..., 3)``). Where
:class:`scipy.spatial.transform.Rotation` is more accurate or general than a closed form written
out here, it is used: angles and rotation vectors near 0 and 180 degrees (an ``arccos`` of the
trace loses half the digits near 0), the rotation of an axis-angle, the chordal mean, and the
Euler angle sequences of the BVH and ASF/AMC channel orders.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

Array = NDArray[np.float64]

# -- elementary rotations ---------------------------------------------------------------------


def axis_rotations(axis: int, angle_rad: ArrayLike) -> Array:
    """Right-handed rotations about one coordinate axis, batched.

    Parameters
    ----------
    axis : int
        0, 1, 2 for x, y, z.
    angle_rad : (...) float

    Returns
    -------
    r : (..., 3, 3) float
    """
    a = np.asarray(angle_rad, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    r = np.zeros((*a.shape, 3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    r[..., axis, axis] = 1.0
    r[..., i, i] = c
    r[..., j, j] = c
    r[..., i, j] = -s
    r[..., j, i] = s
    return r


def rot_x(angle_rad: float) -> Array:
    """Rotation ``(3, 3)`` about x by ``angle_rad`` (right-handed)."""
    return axis_rotations(0, angle_rad)


def rot_y(angle_rad: float) -> Array:
    """Rotation ``(3, 3)`` about y by ``angle_rad`` (right-handed)."""
    return axis_rotations(1, angle_rad)


def rot_z(angle_rad: float) -> Array:
    """Rotation ``(3, 3)`` about z by ``angle_rad`` (right-handed)."""
    return axis_rotations(2, angle_rad)


def euler_rotations(axes: Sequence[int], angles_rad: Sequence[ArrayLike], n: int) -> Array:
    """Product ``R_axes[0] @ R_axes[1] @ ...`` of elementary rotations, batched over frames.

    The intrinsic Euler sequence of a BVH joint's rotation channels (in file order) or of an
    ASF/AMC bone's dofs (reversed: AMC applies the first one first).

    Parameters
    ----------
    axes : sequence of int
        Rotation axes (0, 1, 2 for x, y, z), leftmost factor first; any number of them (more
        than three, or one axis twice in a row, are multiplied in runs scipy takes).
    angles_rad : sequence of (T,) float
        The angle of each factor.
    n : int
        T, the number of frames (used when ``axes`` is empty).

    Returns
    -------
    r : (T, 3, 3) float
    """
    if len(axes) != len(angles_rad):
        raise ValueError(f"{len(axes)} rotation axes but {len(angles_rad)} angle series")
    r = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    start = 0
    while start < len(axes):
        stop = start + 1  # a run scipy takes: at most 3 axes, no axis twice in a row
        while stop < len(axes) and stop - start < 3 and axes[stop] != axes[stop - 1]:
            stop += 1
        seq = "".join("XYZ"[a] for a in axes[start:stop])  # upper case: intrinsic
        ang = np.stack([np.asarray(a, dtype=np.float64) for a in angles_rad[start:stop]], -1)
        r = r @ Rotation.from_euler(seq, ang.reshape(-1, stop - start)).as_matrix()
        start = stop
    return r


# -- axis-angle, rotation vectors, angles ------------------------------------------------------


def skew(v: Array) -> Array:
    """Cross-product matrices ``(..., 3, 3)`` of vectors ``(..., 3)``: ``skew(v) @ u = v x u``."""
    z = np.zeros(v.shape[:-1])
    return np.stack(
        [
            np.stack([z, -v[..., 2], v[..., 1]], -1),
            np.stack([v[..., 2], z, -v[..., 0]], -1),
            np.stack([-v[..., 1], v[..., 0], z], -1),
        ],
        -2,
    )


def rodrigues(axis: ArrayLike, angle: ArrayLike) -> Array:
    """Rotation matrices ``(..., 3, 3)`` about unit ``axis (..., 3)`` by ``angle (...)`` rad.

    Broadcasts ``axis`` against ``angle``; NaN in either gives a NaN matrix.
    """
    k = np.asarray(axis, dtype=np.float64)
    t = np.asarray(angle, dtype=np.float64)
    k, t = np.broadcast_arrays(k, t[..., None])
    rv = (k * t).reshape(-1, 3)
    out = np.full((rv.shape[0], 3, 3), np.nan)
    ok = np.isfinite(rv).all(axis=1)
    if ok.any():
        out[ok] = Rotation.from_rotvec(rv[ok]).as_matrix()
    return out.reshape(*k.shape[:-1], 3, 3)


def so3_exp_and_left_jacobian(phi: Array) -> tuple[Array, Array]:
    """Rotation matrices and SO(3) left Jacobians ``(..., 3, 3)`` of rotation vectors ``phi``.

    The closed forms (series below 1e-6 rad), for a Gauss-Newton step on SO(3).
    """
    th = np.linalg.norm(phi, axis=-1)[..., None, None]
    k = skew(phi)
    k2 = k @ k
    small = th < 1e-6
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0, np.sin(ths) / ths)
    b = np.where(small, 0.5, (1 - np.cos(ths)) / ths**2)
    c = np.where(small, 1.0 / 6.0, (ths - np.sin(ths)) / ths**3)
    eye = np.eye(3)
    return eye + a * k + b * k2, eye + b * k + c * k2


def minimal_rotation(a: Array, b: Array) -> Array:
    """The smallest rotations ``(..., 3, 3)`` taking unit ``a (..., 3)`` onto unit ``b``."""
    v = np.cross(a, b)
    c = np.einsum("...i,...i->...", a, b)
    vx = skew(v)
    with np.errstate(invalid="ignore", divide="ignore"):  # anti-parallel: replaced below
        f = 1.0 / (1.0 + c)
        r = np.eye(3) + vx + (vx @ vx) * f[..., None, None]
    # anti-parallel: rotate by pi about any axis orthogonal to a
    anti = c < -1.0 + 1e-9
    if np.any(anti):
        aa = a[anti]
        ortho = np.cross(aa, np.array([1.0, 0.0, 0.0]))
        small = np.linalg.norm(ortho, axis=-1) < 1e-6
        ortho[small] = np.cross(aa[small], np.array([0.0, 1.0, 0.0]))
        ortho /= np.linalg.norm(ortho, axis=-1, keepdims=True)
        r[anti] = rodrigues(ortho, np.full(aa.shape[0], np.pi))
    return r


def _rotations(m: Array) -> tuple[Rotation | None, NDArray[np.bool_]]:
    """scipy rotations of the finite matrices among ``m (N, 3, 3)``, and which those are."""
    ok = np.asarray(np.isfinite(m).all(axis=(1, 2)), dtype=bool)
    return (Rotation.from_matrix(m[ok]) if ok.any() else None), ok


def rotation_angle_deg(r_a: ArrayLike, r_b: ArrayLike) -> NDArray[np.float64]:
    """Angle of the rotation ``r_a^T r_b`` in degrees, for ``(..., 3, 3)`` inputs; NaN where
    either is not finite. Accurate near 0 and 180 degrees (from the quaternion)."""
    a = np.asarray(r_a, dtype=np.float64)
    b = np.asarray(r_b, dtype=np.float64)
    rel = np.einsum("...ji,...jk->...ik", a, b)
    flat = rel.reshape(-1, 3, 3)
    out = np.full(flat.shape[0], np.nan)
    rot, ok = _rotations(flat)
    if rot is not None:
        out[ok] = np.degrees(rot.magnitude())
    return out.reshape(rel.shape[:-2])


def rotation_vector_deg(r: ArrayLike) -> Array:
    """Rotation vector ``(3,)`` of one rotation ``(3, 3)``, degrees (axis times angle).

    Accurate near 0 and 180 degrees; at exactly 180 degrees the axis's sign is arbitrary. NaN
    when ``r`` is not finite.
    """
    m = np.asarray(r, dtype=np.float64)
    if m.shape != (3, 3):
        raise ValueError(f"rotation_vector_deg takes one (3, 3) rotation, got {m.shape}")
    if not np.isfinite(m).all():
        return np.full(3, np.nan)
    return np.asarray(Rotation.from_matrix(m).as_rotvec(degrees=True), dtype=np.float64)


def chordal_mean(r: Array) -> Array:
    """Mean rotation ``(3, 3)`` of rotations ``r (N, 3, 3)``: the rotation closest to their sum
    (Frobenius), i.e. the chordal L2 mean; rotations with a NaN entry are left out (none
    left: the identity)."""
    rot, _ok = _rotations(np.asarray(r, dtype=np.float64).reshape(-1, 3, 3))
    if rot is None:  # nothing to average: the identity (the projection of a zero sum)
        return np.eye(3)
    return np.asarray(rot.mean().as_matrix(), dtype=np.float64)


# -- rotations fitted to directions, and Euler channels over time -------------------------------


def unit(v: ArrayLike, zero: float = np.nan) -> Array:
    """``v / |v|`` along the last axis, batched ``(..., 3)``.

    ``zero`` (NaN unless given) where ``|v|`` is at most 1e-12; NaN where ``v`` is not finite.
    """
    a = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(a, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        out: Array = np.where(n <= 1e-12, zero, a / n)
    return out


def frames_from_vectors(primary: ArrayLike, reference: ArrayLike) -> Array:
    """Orthonormal right-handed frames ``(..., 3, 3)`` (columns: ``e1, e2, e3``) with ``e1``
    along ``primary`` and ``e2`` the part of ``reference`` orthogonal to it (Gram-Schmidt),
    batched: the package's one two-vector frame builder.

    NaN where either vector is NaN or (near) zero, or the two are parallel (under 1e-9 of their
    lengths).
    """
    b = np.asarray(reference, dtype=np.float64)
    e1 = unit(primary)
    with np.errstate(invalid="ignore", divide="ignore"):
        b_perp = b - np.einsum("...i,...i->...", b, e1)[..., None] * e1
        n = np.linalg.norm(b_perp, axis=-1, keepdims=True)
        e2 = np.where(n > 1e-9 * np.linalg.norm(b, axis=-1, keepdims=True), b_perp / n, np.nan)
    e3 = np.cross(e1, e2)
    return np.stack([e1, e2, e3], axis=-1)


def rotations_between_frames(rest: Array, actual: Array) -> Array:
    """The rotations ``R = actual @ rest^T`` taking orthonormal frames ``rest`` onto ``actual``
    (both ``(..., 3, 3)``, columns the axes)."""
    return np.einsum("...ij,...kj->...ik", actual, rest)


def slerp_rotations(r_a: Array, r_b: Array, weight: ArrayLike) -> Array:
    """``r_a`` moved toward ``r_b`` by ``weight`` in [0, 1] along the shortest path, batched
    ``(..., 3, 3)``; NaN where either is NaN (scipy's rotation vector: exact near 0 and 180)."""
    a = np.asarray(r_a, dtype=np.float64)
    b = np.asarray(r_b, dtype=np.float64)
    w = np.broadcast_to(np.asarray(weight, dtype=np.float64), a.shape[:-2])
    rel = np.einsum("...ji,...jk->...ik", a, b).reshape(-1, 3, 3)
    out = np.full(rel.shape, np.nan)
    rot, ok = _rotations(rel)
    if rot is not None:
        step = Rotation.from_rotvec(rot.as_rotvec() * w.reshape(-1)[ok][:, None])
        out[ok] = step.as_matrix()
    return np.asarray(a @ out.reshape(a.shape), dtype=np.float64)


def continuous_euler_deg(r: Array, seq: str) -> Array:
    """Euler angles ``(T, ..., 3)`` in degrees of rotations ``r (T, ..., 3, 3)``, continuous
    over the first axis (time).

    ``seq`` is an intrinsic sequence (upper case, e.g. ``"ZXY"``: ``R = Rz Rx Ry``, a BVH joint
    with channels ``Zrotation Xrotation Yrotation``). A Tait-Bryan sequence has two solutions,
    ``(a, b, c)`` and ``(a + 180, 180 - b, c + 180)``; frame by frame the one nearer the previous
    frame is taken and each angle is moved by whole turns to within 180 degrees of the previous
    frame, so no channel jumps by 360 degrees (angles may leave [-180, 180]). Rotations must be
    finite.
    """
    m = np.asarray(r, dtype=np.float64)
    if m.ndim < 3 or m.shape[-2:] != (3, 3):
        raise ValueError(f"continuous_euler_deg takes rotations (T, ..., 3, 3), got {m.shape}")
    shape = m.shape[:-2]
    with warnings.catch_warnings():  # at gimbal lock scipy sets the third angle to 0: one of
        warnings.simplefilter("ignore", UserWarning)  # the solutions, which is all we need
        a = np.asarray(
            Rotation.from_matrix(m.reshape(-1, 3, 3)).as_euler(seq, degrees=True),
            dtype=np.float64,
        ).reshape(*shape, 3)
    b = np.stack([a[..., 0] + 180.0, 180.0 - a[..., 1], a[..., 2] + 180.0], axis=-1)
    out = np.empty_like(a)
    if shape[0] == 0:
        return out
    prev = a[0]
    for k in range(shape[0]):
        ca = a[k] - 360.0 * np.round((a[k] - prev) / 360.0)
        cb = b[k] - 360.0 * np.round((b[k] - prev) / 360.0)
        take_b = np.abs(cb - prev).sum(-1) < np.abs(ca - prev).sum(-1)
        prev = np.where(take_b[..., None], cb, ca)
        out[k] = prev
    return out

"""kinefuse.core.geometry.rotations against the closed forms it replaced, and near 0 and 180
degrees.

The ``old_*`` functions are the package's implementations before the move (biomech/_vec.py,
core/geometry/transforms.py, core/frames/source_motion.py), kept here as the reference.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kinefuse.core.geometry.rotations import (
    axis_rotations,
    chordal_mean,
    euler_rotations,
    minimal_rotation,
    rodrigues,
    rot_x,
    rot_y,
    rot_z,
    rotation_angle_deg,
    rotation_vector_deg,
    so3_exp_and_left_jacobian,
)


def old_rodrigues(axis, angle):
    k, t = np.broadcast_arrays(np.asarray(axis, float), np.asarray(angle, float)[..., None])
    t = t[..., 0]
    c, s = np.cos(t), np.sin(t)
    x, y, z = k[..., 0], k[..., 1], k[..., 2]
    C = 1.0 - c
    r = np.empty((*t.shape, 3, 3))
    r[..., 0, :] = np.stack([c + x * x * C, x * y * C - z * s, x * z * C + y * s], -1)
    r[..., 1, :] = np.stack([y * x * C + z * s, c + y * y * C, y * z * C - x * s], -1)
    r[..., 2, :] = np.stack([z * x * C - y * s, z * y * C + x * s, c + z * z * C], -1)
    return r


def old_rotation_angle_deg(a, b):
    rel = np.einsum("...ji,...jk->...ik", a, b)
    cos = (np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def old_chordal_mean(r):
    u, _, vt = np.linalg.svd(np.nansum(r, axis=0))
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def old_compose(axes, angles, n):
    r = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    for ax, ang in zip(axes, angles, strict=True):
        r = r @ axis_rotations(ax, ang)
    return r


def random_axes(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_elementary_rotations_as_before() -> None:
    for a in (-2.0, 0.0, 0.3, np.pi):
        c, s = np.cos(a), np.sin(a)
        np.testing.assert_array_equal(rot_x(a), [[1, 0, 0], [0, c, -s], [0, s, c]])
        np.testing.assert_array_equal(rot_y(a), [[c, 0, s], [0, 1, 0], [-s, 0, c]])
        np.testing.assert_array_equal(rot_z(a), [[c, -s, 0], [s, c, 0], [0, 0, 1]])


def test_rodrigues_as_before_and_batched(rng) -> None:
    ax, ang = random_axes(rng, 200), rng.uniform(-4.0, 4.0, 200)
    np.testing.assert_allclose(rodrigues(ax, ang), old_rodrigues(ax, ang), atol=1e-14)
    # broadcasting one axis over (T, J) angles, and NaN in, NaN out
    ang2 = rng.uniform(-1, 1, (4, 5))
    np.testing.assert_allclose(
        rodrigues([0.0, 0.0, 1.0], ang2), old_rodrigues([0.0, 0.0, 1.0], ang2), atol=1e-15
    )
    bad = rodrigues(np.array([[np.nan, 0, 0], [1.0, 0, 0]]), np.array([0.1, np.nan]))
    assert np.isnan(bad).all()


def test_rodrigues_near_0_and_180(rng) -> None:
    ax = random_axes(rng, 20)
    for ang in (0.0, 1e-12, 1e-8, np.pi - 1e-9, np.pi, -np.pi):
        r = rodrigues(ax, np.full(20, ang))
        np.testing.assert_allclose(r, old_rodrigues(ax, np.full(20, ang)), atol=1e-14)
        np.testing.assert_allclose(
            r @ np.swapaxes(r, -1, -2), np.broadcast_to(np.eye(3), r.shape), atol=1e-14
        )


def test_rotation_angle_as_before_and_accurate_near_0_and_180(rng) -> None:
    a = Rotation.random(100, random_state=1).as_matrix()
    b = Rotation.random(100, random_state=2).as_matrix()
    np.testing.assert_allclose(rotation_angle_deg(a, b), old_rotation_angle_deg(a, b), atol=1e-9)
    ax = random_axes(rng, 6)
    for ang in (1e-9, 1e-6, 1e-3, np.pi - 1e-6, np.pi):
        r = Rotation.from_rotvec(ax * ang).as_matrix()
        got = rotation_angle_deg(np.eye(3), r)
        np.testing.assert_allclose(got, np.degrees(ang), rtol=1e-9, atol=0)
        # the old arccos form loses half the digits near 0 degrees (error ~1e-6 deg)
        np.testing.assert_allclose(old_rotation_angle_deg(np.eye(3), r), got, atol=2e-6)
    assert rotation_angle_deg(np.eye(3), np.eye(3)) == 0.0
    assert rotation_angle_deg(np.eye(3), rot_z(0.5)).shape == ()
    nan = rotation_angle_deg(np.stack([np.eye(3), np.full((3, 3), np.nan)]), np.eye(3))
    assert nan[0] == 0.0 and np.isnan(nan[1])


def test_rotation_vector_near_0_and_180(rng) -> None:
    for ax in random_axes(rng, 10):
        for ang in (1e-10, 1e-5, 0.7, np.pi - 1e-7):
            rv = rotation_vector_deg(Rotation.from_rotvec(ax * ang).as_matrix())
            np.testing.assert_allclose(rv, np.degrees(ax * ang), rtol=1e-7, atol=1e-14)
        rv = rotation_vector_deg(Rotation.from_rotvec(ax * np.pi).as_matrix())
        assert abs(abs(float(rv @ ax)) - 180.0) < 1e-7  # the axis, either sign
    assert (rotation_vector_deg(np.eye(3)) == 0).all()
    assert np.isnan(rotation_vector_deg(np.full((3, 3), np.nan))).all()


def test_chordal_mean_as_before(rng) -> None:
    centre = Rotation.from_rotvec([0.3, -0.2, 1.0])
    for spread in (0.05, 0.5, 1.5):
        r = (centre * Rotation.from_rotvec(rng.normal(0, spread, (30, 3)))).as_matrix()
        np.testing.assert_allclose(chordal_mean(r), old_chordal_mean(r), atol=1e-12)
    r[3] = np.nan  # a missing rotation is left out, as nansum did
    np.testing.assert_allclose(chordal_mean(r), old_chordal_mean(r), atol=1e-12)
    np.testing.assert_array_equal(chordal_mean(np.full((2, 3, 3), np.nan)), np.eye(3))


def test_minimal_rotation_including_antiparallel(rng) -> None:
    a, b = random_axes(rng, 50), random_axes(rng, 50)
    b[:5] = -a[:5]  # 180 degrees
    b[5:10] = a[5:10]  # 0 degrees
    r = minimal_rotation(a, b)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", r, a), b, atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)
    np.testing.assert_allclose(r[5:10], np.broadcast_to(np.eye(3), (5, 3, 3)), atol=1e-15)


@pytest.mark.parametrize(
    "axes", [[2, 0, 1], [0, 1, 2], [1], [0, 2], [2, 2], [0, 1, 2, 0], [0, 1, 0], []]
)
def test_euler_rotations_as_the_product_of_elementary_ones(rng, axes) -> None:
    n = 40
    angles = [rng.uniform(-np.pi, np.pi, n) for _ in axes]
    np.testing.assert_allclose(
        euler_rotations(axes, angles, n), old_compose(axes, angles, n), atol=1e-14
    )


def test_so3_exp_is_rodrigues(rng) -> None:
    phi = random_axes(rng, 30) * rng.uniform(0, 3, (30, 1))
    phi[0] = 0.0
    phi[1] *= 1e-9
    r, _ = so3_exp_and_left_jacobian(phi)
    np.testing.assert_allclose(r, Rotation.from_rotvec(phi).as_matrix(), atol=1e-14)

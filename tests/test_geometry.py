"""The geometry core: rigid transforms, Kabsch, ray casting against capsules, spheres, planes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kinefuse.core.geometry.raycast import (
    ray_capsules,
    ray_capsules_batched,
    ray_plane,
    ray_spheres,
)
from kinefuse.core.geometry.rotations import rotation_angle_deg, rotation_vector_deg
from kinefuse.core.geometry.transforms import (
    apply_transform,
    invert_transform,
    kabsch,
    look_at,
    make_transform,
)


def random_rotation(rng) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def point_segment_distance(p, a, b):
    ab = b - a
    s = np.clip(((p - a) @ ab) / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(p - (a + s[..., None] * ab), axis=-1)


def test_capsule_hits_match_dense_marching(rng) -> None:
    a = rng.normal(0, 0.5, (6, 3))
    b = a + rng.normal(0, 0.4, (6, 3))
    r = rng.uniform(0.05, 0.25, 6)
    origins = rng.normal(0, 3.0, (300, 3))
    dirs = rng.normal(size=(300, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    t = ray_capsules(origins, dirs, a, b, r)
    steps = np.linspace(0, 8, 16001)  # 0.5 mm
    for c in range(6):
        pts = origins[:, None, :] + steps[None, :, None] * dirs[:, None, :]
        inside = point_segment_distance(pts, a[c], b[c]) <= r[c]
        starts_inside = inside[:, 0]
        first = np.where(inside.any(1), steps[np.argmax(inside, axis=1)], np.inf)
        ok = ~starts_inside & (first < 7.9)
        np.testing.assert_allclose(t[ok, c], first[ok], atol=1e-3)  # 1 mm (the march step)
        miss = ~inside.any(1)
        assert np.isinf(t[miss, c]).all()


def test_one_origin_and_batched_agree(rng) -> None:
    a = rng.normal(0, 0.5, (2, 5, 3))
    b = a + 0.3
    r = np.full(5, 0.1)
    dirs = rng.normal(size=(2, 40, 3))
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    o = np.array([0.0, 0.0, -3.0])
    batched = ray_capsules_batched(o, dirs, a, b, r)
    for k in range(2):
        np.testing.assert_allclose(ray_capsules(o, dirs[k], a[k], b[k], r), batched[k])


def test_spheres_and_planes() -> None:
    d = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    t = ray_spheres(np.zeros(3), d, [[0.0, 0.0, 5.0]], [1.0])
    assert t[0, 0] == pytest.approx(4.0) and np.isinf(t[1, 0])
    tp = ray_plane(np.array([0.0, 0.0, 2.0]), np.array([[0.0, 0.0, -1.0], [1.0, 0, 0]]),
                   [0, 0, 0], [0, 0, 1])  # fmt: skip
    assert tp[0] == pytest.approx(2.0) and np.isinf(tp[1])


def test_transforms_round_trip(rng) -> None:
    for _ in range(20):
        t = make_transform(random_rotation(rng), rng.normal(size=3))
        np.testing.assert_allclose(invert_transform(t) @ t, np.eye(4), atol=1e-12)
        p = rng.normal(size=(7, 3))
        np.testing.assert_allclose(apply_transform(invert_transform(t), apply_transform(t, p)), p,
                                   atol=1e-12)  # fmt: skip


def test_kabsch_recovers_a_rigid_motion_and_ignores_nan(rng) -> None:
    src = rng.normal(size=(30, 3))
    truth = make_transform(random_rotation(rng), rng.normal(size=3))
    dst = apply_transform(truth, src)
    src[3] = np.nan
    est = kabsch(src, dst)
    np.testing.assert_allclose(est, truth, atol=1e-10)
    with pytest.raises(ValueError, match="collinear"):
        kabsch(np.outer(np.arange(5.0), [1, 0, 0]), np.outer(np.arange(5.0), [0, 1, 0]))
    with pytest.raises(ValueError, match="at least 3"):
        kabsch(src[:2], dst[:2])


def test_look_at_points_the_optical_axis_and_keeps_x_level() -> None:
    pose = look_at([3.0, 1.0, 2.0], [0.0, 0.0, 1.0], np.radians(5.0))
    z = np.array([-3.0, -1.0, -1.0]) / np.sqrt(11)
    np.testing.assert_allclose(pose[:3, 2], z, atol=1e-12)
    level = look_at([3.0, 1.0, 2.0], [0.0, 0.0, 1.0])
    assert abs(level[2, 0]) < 1e-12  # image x horizontal without roll
    assert rotation_angle_deg(level[:3, :3], pose[:3, :3]) == pytest.approx(5.0)
    with pytest.raises(ValueError, match="coincide"):
        look_at([1, 1, 1], [1, 1, 1])
    with pytest.raises(ValueError, match="straight up or down"):
        look_at([0, 0, 1], [0, 0, 0])


def test_check_rigid_finds_what_is_not_rigid() -> None:
    from kinefuse.core.geometry.rotations import rot_z
    from kinefuse.core.geometry.transforms import check_rigid, make_transform
    from kinefuse.errors import InputError

    good = make_transform(rot_z(0.3), [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(check_rigid(good), good)
    scaled = good.copy()
    scaled[:3, :3] *= 1.01  # a 1 % scale error
    mirrored = good.copy()
    mirrored[:3, 0] *= -1  # a reflection: orthonormal, det -1
    skewed_row = good.copy()
    skewed_row[3, 0] = 0.1
    for bad in (scaled, mirrored, skewed_row):
        with pytest.raises(InputError, match="pose is not a rigid transform"):
            check_rigid(bad, "pose")
    with pytest.raises(InputError, match=r"poses \(index 1\) is not finite"):
        check_rigid(np.stack([good, np.full((4, 4), np.nan)]), "poses")
    with pytest.raises(InputError, match=r"shape \(\.\.\., 4, 4\)"):
        check_rigid(np.eye(3))


def test_rotation_vector_deg_round_trips_through_scipy(rng) -> None:
    from scipy.spatial.transform import Rotation

    for _ in range(50):
        r = random_rotation(rng)
        rv = rotation_vector_deg(r)
        np.testing.assert_allclose(rv, Rotation.from_matrix(r).as_rotvec(degrees=True), atol=1e-9)
        assert np.linalg.norm(rv) == pytest.approx(rotation_angle_deg(np.eye(3), r), abs=1e-9)
    assert (rotation_vector_deg(np.eye(3)) == 0).all()
    # 180 degrees about an axis: the axis comes from the symmetric part (either sign is right)
    axis = np.array([1.0, 2.0, -2.0]) / 3.0
    half_turn = 2.0 * np.outer(axis, axis) - np.eye(3)
    rv = rotation_vector_deg(half_turn)
    assert np.linalg.norm(rv) == pytest.approx(180.0, abs=1e-9)
    assert abs(rv @ axis) == pytest.approx(180.0, abs=1e-6)
    with pytest.raises(ValueError, match=r"one \(3, 3\) rotation"):
        rotation_vector_deg(np.eye(4))


# -- the one rigid fit, plane fit and unit: real markers ----------------------------------------

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "markers" / "opensim"


def _walk_markers() -> tuple[np.ndarray, np.ndarray]:
    """The Gait2354 walk's right foot markers over time (a near-rigid cluster of four), one of
    them dropped from every 7th frame, and the first frame."""
    from kinefuse.formats.markers import read_trc

    m = read_trc(DATA / "Pipelines_Gait2354_Simbody_subject01_walk1.trc")
    cluster = [m.names.index(n) for n in ("R.Heel", "R.Midfoot.Sup", "R.Midfoot.Lat", "R.Toe.Tip")]
    moving = m.positions[:, cluster].copy()
    moving[::7, 0] = np.nan  # a marker missing now and then
    return moving[0], moving


def test_rigid_fit_is_kabsch_per_frame_on_real_markers() -> None:
    from kinefuse.core.geometry.transforms import rigid_fit

    template, moving = _walk_markers()
    template = moving[1]  # a frame with every marker
    rot, tr = rigid_fit(template, moving)
    assert rot.shape == (len(moving), 3, 3) and np.isfinite(rot).all()
    for t in range(0, len(moving), 10):
        t2 = kabsch(template, moving[t])
        np.testing.assert_allclose(rot[t], t2[:3, :3], atol=1e-12)
        np.testing.assert_allclose(tr[t], t2[:3, 3], atol=1e-9)
    few = moving.copy()
    few[3, 1:] = np.nan  # one marker left: no fit there, the rest unaffected
    r2, p2 = rigid_fit(template, few)
    assert np.isnan(r2[3]).all() and np.isnan(p2[3]).all()
    np.testing.assert_array_equal(r2[4], rot[4])


def test_fit_plane_through_origin_on_real_directions() -> None:
    from kinefuse.core.geometry.rotations import unit
    from kinefuse.core.geometry.transforms import fit_plane

    _, moving = _walk_markers()
    d = unit(moving[:, 2] - moving[:, 1])  # a real segment direction over the walk
    d = d[np.isfinite(d).all(1)]
    c, n = fit_plane(d, through_origin=True)
    assert np.array_equal(c, np.zeros(3)) and abs(np.linalg.norm(n) - 1.0) < 1e-12
    # the normal is the direction the samples vary least along, through the origin
    spread = ((d @ n) ** 2).mean()
    for other in unit(np.random.default_rng(0).normal(size=(200, 3))):
        assert ((d @ other) ** 2).mean() >= spread - 1e-12
    c2, _ = fit_plane(d)  # about the centroid: another plane
    np.testing.assert_allclose(c2, d.mean(0), atol=1e-12)


def test_unit_zero_and_missing() -> None:
    from kinefuse.core.geometry.rotations import unit

    v = np.array([[3.0, 0.0, 4.0], [0.0, 0.0, 0.0], [np.nan, 1.0, 0.0]])
    np.testing.assert_allclose(unit(v)[0], [0.6, 0.0, 0.8])
    assert np.isnan(unit(v)[1:]).all()
    z = unit(v, zero=0.0)
    assert np.array_equal(z[1], np.zeros(3)) and np.isnan(z[2]).all()

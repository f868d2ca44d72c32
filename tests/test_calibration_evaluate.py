"""Evaluation of a calibration against the truth (frame alignment, errors, bins, plot)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kinefuse.capture.calibration.compare import align_worlds, pose_errors
from kinefuse.capture.calibration.register import register_full
from kinefuse.capture.calibration.synthetic import (
    make_rig,
    simulate_sightings,
    true_wand_in_sensor,
    wand_waving,
)
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.geometry.rotations import rot_x, rot_z
from kinefuse.core.geometry.transforms import make_transform
from kinefuse.errors import InputError
from kinefuse.lab.calibration_truth import (
    binned,
    error_vs_sightings,
    mapped_wand_errors,
    plot_calibration_errors,
    wand_errors,
)

INTR = Intrinsics()


def test_alignment_removes_the_choice_of_world_frame() -> None:
    rng = np.random.default_rng(71)
    true = make_rig(4, rng)
    gauge = make_transform(rot_z(0.7), [1.0, -2.0, 0.3])
    est = np.einsum("ij,sjk->sik", gauge, true)
    for align in ("yaw", "rigid"):
        e = pose_errors(est, true, align=align)
        np.testing.assert_allclose(e.position_error_m, 0.0, atol=1e-9)
        np.testing.assert_allclose(e.rotation_error_deg, 0.0, atol=1e-5)
        np.testing.assert_allclose(e.est2true @ gauge, np.eye(4), atol=1e-9)
    # a tilt of the whole world is an error of "up": yaw alignment keeps it, rigid removes it
    tilt = make_transform(rot_x(np.radians(1.0)), [0.0, 0.0, 0.0])
    est = np.einsum("ij,sjk->sik", tilt, true)
    np.testing.assert_allclose(
        pose_errors(est, true, align="yaw").rotation_error_deg, 1.0, atol=1e-3
    )
    np.testing.assert_allclose(
        pose_errors(est, true, align="rigid").rotation_error_deg, 0.0, atol=1e-5
    )
    # no alignment: the raw difference
    shifted = true.copy()
    shifted[:, :3, 3] += [0.0, 0.0, 0.01]
    np.testing.assert_allclose(pose_errors(shifted, true, align="none").position_error_m, 0.01)
    # a world 0.3 % too large: similarity alignment reports the scale and removes it
    big = true.copy()
    big[:, :3, 3] *= 1.003
    e = pose_errors(big, true, align="similarity")
    assert abs(e.scale - 1 / 1.003) < 1e-9
    np.testing.assert_allclose(e.position_error_m, 0.0, atol=1e-9)
    assert pose_errors(big, true).mean_position_error_m > 0.005


def test_alignment_bad_inputs() -> None:
    with pytest.raises(InputError, match="differ in shape"):
        align_worlds(np.tile(np.eye(4), (2, 1, 1)), np.tile(np.eye(4), (3, 1, 1)))
    with pytest.raises(InputError, match="align must be"):
        align_worlds(np.eye(4)[None], np.eye(4)[None], align="best")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="at least 2 sensors"):
        align_worlds(np.eye(4)[None], np.eye(4)[None], align="similarity")
    with pytest.raises(ValueError, match=r"\(\.\.\., 4, 4\)"):
        pose_errors(np.eye(3), np.eye(3))


def test_wand_errors_against_distance_and_angle() -> None:
    true_sensor = np.array([[0.0, 0.0, 2.0], [2.0, 0.0, 2.0], [0.0, -3.0, 0.0]])
    est = true_sensor + np.array([[0.0, 0.0, 0.003], [0.004, 0.0, 0.0], [0.0, 0.0, 0.0]])
    w = wand_errors(est, true_sensor, true_sensor)
    np.testing.assert_allclose(w.error_m, [0.003, 0.004, 0.0])
    np.testing.assert_allclose(w.distance_m, [2.0, np.sqrt(8.0), 3.0])
    np.testing.assert_allclose(w.angle_deg, [0.0, 45.0, 90.0])
    with pytest.raises(InputError, match="shapes differ"):
        wand_errors(est[:2], true_sensor, true_sensor)
    # mapped to the world with a pose
    s2w = make_transform(rot_z(0.3), [1.0, 2.0, 1.0])
    world = true_sensor @ s2w[:3, :3].T + s2w[:3, 3]
    m = mapped_wand_errors(s2w, np.eye(4), true_sensor, world, true_sensor)
    np.testing.assert_allclose(m.error_m, 0.0, atol=1e-12)


def test_binned_statistics() -> None:
    x = np.array([0.1, 0.2, 0.6, 0.7, 0.8, 1.5, np.nan])
    e = np.array([1.0, 3.0, 2.0, 2.0, 5.0, 9.0, 1.0])
    b = binned(x, e, [0.0, 0.5, 1.0, 2.0, 3.0])
    np.testing.assert_allclose(b.centre, [0.25, 0.75, 1.5, 2.5])
    np.testing.assert_array_equal(b.count, [2, 3, 1, 0])
    np.testing.assert_allclose(b.mean[:3], [2.0, 3.0, 9.0])
    np.testing.assert_allclose(b.median[:3], [2.0, 2.0, 9.0])
    np.testing.assert_allclose(b.std[:2], [1.0, np.sqrt(2.0)])
    assert np.isnan(b.mean[3]) and np.isnan(b.median[3])
    with pytest.raises(InputError, match="increasing"):
        binned(x, e, [1.0, 0.0])
    with pytest.raises(InputError, match="differ in length"):
        binned(x[:3], e, [0.0, 1.0])


def test_error_vs_sightings_and_plot(tmp_path: Path) -> None:
    rng = np.random.default_rng(72)
    poses = make_rig(3, rng)
    t, wand = wand_waving(16.0, rng)
    sightings = simulate_sightings(poses, INTR, t, wand, rng)
    curve = error_vs_sightings(
        sightings,
        poses,
        lambda s: register_full(s, origin="sensor"),
        [0.5, 8.0, 16.0],
        align="rigid",
    )
    # 0.5 s of a still wand cannot register anything: that point is left out, not a failure
    assert curve.duration_s.tolist() == [8.0, 16.0]
    assert curve.mean_sightings[1] > curve.mean_sightings[0] > 50
    assert np.all(curve.mean_position_error_m < 0.02)
    assert curve.mean_rotation_error_deg.shape == (2,)
    # per-sighting errors of sensor 0 against distance and angle, and the paper-style figure
    reg = register_full(sightings, origin="sensor")
    pe = pose_errors(reg.sensor2world, poses, align="rigid")
    s0 = sightings["k0"]
    truth_s = true_wand_in_sensor(poses[0], t, wand, s0.t_server_s)
    truth_w = truth_s @ poses[0][:3, :3].T + poses[0][:3, 3]
    werr = mapped_wand_errors(reg.pose("k0"), pe.est2true, s0.centre_sensor_m, truth_w, truth_s)
    assert np.median(werr.error_m) < 0.02
    out = plot_calibration_errors(tmp_path / "calib_errors.png", werr, curve=curve)
    assert out.exists() and out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert out.stat().st_size > 10_000

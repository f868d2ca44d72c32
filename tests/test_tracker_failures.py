"""Gross failures and the person level of the tracker model (issue 21,
kinefuse.sim.tracker_failures), and their measurement on real and simulated streams."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.geometry.transforms import look_at
from kinefuse.core.skeleton import JOINT_INDEX, capsule_radii, standing_pose
from kinefuse.sim.tracker import draw_subject_bias, simulate_tracker
from kinefuse.sim.tracker_failures import LIMB_CHAINS, ROOT_WEIGHT, draw_quality, gross_failures
from kinefuse.sim.tracker_params import LIGHT, TrackerParams, light_tracker

ROOT = Path(__file__).resolve().parents[1]
CACHE = ROOT / "tests" / "data" / "realism_population_real.json"
OFF = dict(gross_limb_rate_hz=0.0, gross_body_rate_hz=0.0, person_log_sigma=0.0)


def _glide(n: int = 900) -> np.ndarray:
    """The standing pose swaying sideways, up to 0.3 m/s (failures start only while moving)."""
    x = 0.3 * np.sin(np.arange(n) / 30.0)
    shift = np.stack([0 * x, x, 0 * x], axis=1)
    return np.repeat(standing_pose(1.71)[None], n, axis=0) + shift[:, None, :]


def test_gross_failures_rates_sizes_and_limbs() -> None:
    p = TrackerParams()
    n, dt = 30 * 600, 1 / 30  # ten minutes of one sensor
    d = gross_failures(
        np.random.default_rng(1), n, dt, dataclasses.replace(p, gross_body_rate_hz=0)
    )
    size = np.linalg.norm(d, axis=-1)
    # trunk and head never move in a limb failure; the distal joints move the most, the middle
    # joint half as much, the root (shoulder, hip) ROOT_WEIGHT of it
    for name in ("SpineBase", "SpineMid", "Neck", "Head"):
        assert size[:, JOINT_INDEX[name]].max() == 0.0
    assert size.max() > p.gross_size_min_m
    hand, elbow = JOINT_INDEX["HandLeft"], JOINT_INDEX["ElbowLeft"]
    both = size[:, hand] > 0
    np.testing.assert_allclose(size[both, elbow], 0.5 * size[both, hand])
    np.testing.assert_allclose(
        size[both, JOINT_INDEX["ShoulderLeft"]], ROOT_WEIGHT * size[both, hand]
    )
    # the share of frames in a failure follows rate x mean length (log-normal, arms longer)
    spread = np.exp(p.gross_duration_log_sigma**2 / 2)
    mean_len = spread * (
        p.gross_leg_share * p.gross_duration_median_s
        + (1 - p.gross_leg_share) * p.gross_arm_duration_median_s
    )
    expected = p.gross_limb_rate_hz * mean_len  # per limb-failure, any limb
    busy = (size.max(axis=1) > 0).mean()
    assert 0.5 * expected < busy < 1.5 * expected
    legs = (size[:, JOINT_INDEX["FootLeft"]] > 0) | (size[:, JOINT_INDEX["FootRight"]] > 0)
    arms = (size[:, JOINT_INDEX["HandLeft"]] > 0) | (size[:, JOINT_INDEX["HandRight"]] > 0)
    # legs fail more often, arms longer and further (real runs at 0 degrees)
    foot = size[:, [JOINT_INDEX["FootLeft"], JOINT_INDEX["FootRight"]]].max(axis=1)
    hands = size[:, [JOINT_INDEX["HandLeft"], JOINT_INDEX["HandRight"]]].max(axis=1)
    assert np.mean(hands[arms]) > np.mean(foot[legs])
    assert p.gross_arm_duration_median_s > p.gross_duration_median_s
    assert p.gross_leg_share > 0.5
    assert set(LIMB_CHAINS) == {"ArmLeft", "ArmRight", "LegLeft", "LegRight"}


def test_whole_body_jumps_move_every_joint_alike() -> None:
    p = dataclasses.replace(TrackerParams(), gross_limb_rate_hz=0.0, gross_body_rate_hz=0.5)
    d = gross_failures(np.random.default_rng(2), 3000, 1 / 30, p)
    moved = np.linalg.norm(d, axis=-1).max(axis=1) > 0
    assert moved.any()
    np.testing.assert_allclose(d[moved], np.repeat(d[moved][:, :1], 25, axis=1))


def test_processes_switch_off_and_keep_the_other_draws() -> None:
    """Rates and sigma 0 give the model without them; the new processes draw from child
    streams, so turning them on leaves every other draw as it was."""
    truth = _glide()
    s2w = look_at([2.4, 0.0, 1.0], [0.0, 0.0, 1.0])
    radii = capsule_radii(1.71)
    off = dataclasses.replace(TrackerParams(), **OFF)  # type: ignore[arg-type]
    a = simulate_tracker(truth, s2w, Intrinsics(), radii, np.random.default_rng(4), off)
    b = simulate_tracker(truth, s2w, Intrinsics(), radii, np.random.default_rng(4), off)
    np.testing.assert_array_equal(a.joints_sensor, b.joints_sensor)  # deterministic
    pop = TrackerParams()
    on = simulate_tracker(truth, s2w, Intrinsics(), radii, np.random.default_rng(4), pop)
    again = simulate_tracker(truth, s2w, Intrinsics(), radii, np.random.default_rng(4), pop)
    np.testing.assert_array_equal(on.joints_sensor, again.joints_sensor)
    diff = np.linalg.norm(on.joints_sensor - a.joints_sensor, axis=-1)
    assert np.nanmax(diff) > 0.15  # a failure happened in 30 s
    still = np.repeat(truth[:1], 900, axis=0)  # no failure starts in a still stand
    s_on = simulate_tracker(still, s2w, Intrinsics(), radii, np.random.default_rng(4), pop)
    s_off = simulate_tracker(
        still, s2w, Intrinsics(), radii, np.random.default_rng(4), dataclasses.replace(off)
    )
    # only the person level's scaling of the small continuous errors differs: millimetres
    assert np.nanmax(np.linalg.norm(s_on.joints_sensor - s_off.joints_sensor, axis=-1)) < 0.05
    # the subject's draws are those of the model without the person level, plus its quality
    sa = draw_subject_bias(np.random.default_rng(9), off)
    sb = draw_subject_bias(np.random.default_rng(9), pop)
    np.testing.assert_array_equal(sa.offsets_body_m, sb.offsets_body_m)
    assert sa.quality == 1.0 and sb.quality != 1.0
    # the default model has them on (every published figure stands on it); the light model has
    # them off and is the model of before issue 21 (its view-dependent exponent too, and its
    # joints' errors independent: no limb coherence)
    assert draw_subject_bias(np.random.default_rng(9)).quality != 1.0
    plain = simulate_tracker(truth, s2w, Intrinsics(), radii, np.random.default_rng(4))
    np.testing.assert_array_equal(plain.joints_sensor, on.joints_sensor)
    light = light_tracker()
    assert light == dataclasses.replace(
        off, view_bias_exponent=LIGHT["view_bias_exponent"], limb_coherence=0.0
    )
    assert draw_subject_bias(np.random.default_rng(9), light).quality == 1.0


def test_quality_is_log_normal_with_the_fitted_spread() -> None:
    p = TrackerParams()
    q = np.array([draw_quality(np.random.default_rng(s), p) for s in range(2000)])
    assert np.median(q) == pytest.approx(1.0, abs=0.03)
    assert np.log(q).std() == pytest.approx(p.person_log_sigma, rel=0.1)


def test_a_subject_seed_keeps_its_quality_across_sessions() -> None:
    from kinefuse.sim.lab import ErrorModel, LabConfig, _seeds

    errors = ErrorModel(tracker=TrackerParams())
    base = LabConfig(seed=3, calibration_s=0.0, subject_seed=11, errors=errors)
    a = _seeds(3, 2, base).subject
    b = _seeds(4, 2, dataclasses.replace(base, seed=4)).subject
    assert a.quality == b.quality
    c = _seeds(4, 2, dataclasses.replace(base, seed=4, subject_seed=12)).subject
    assert c.quality != a.quality


# -------------------------------------------------------------------------------------------
# the real population: cached figures match the data (a subset keeps it fast)


def test_the_cached_real_figures_match_the_data(shared_data: Path) -> None:
    from kinefuse.formats.kinect_multitrack import read_kinect_multitrack
    from kinefuse.lab.realism_takes import pair_figures, real_pair

    folder = shared_data / "kinect" / "kinect_multitrack_population"
    if not folder.is_dir():
        pytest.skip(f"no population in {folder}")
    cache = json.loads(CACHE.read_text())
    assert len(cache["takes"]) == len(list(folder.glob("*.csv"))) == 25
    for entry in cache["takes"][::8]:  # 4 of the 25 takes, one per few participants
        fig = pair_figures(real_pair(read_kinect_multitrack(folder / entry["file"])))
        for k in ("median_m", "p95_m", "still_jitter_m_per_frame", "bone_length_cv"):
            assert fig[k] == pytest.approx(entry[k], rel=1e-9), (entry["file"], k)


def test_real_tails_of_a_take(shared_data: Path) -> None:
    """The measurement on one real take: thrown limbs about once a second, mostly short, one
    sensor alone at the onset more often than not."""
    from kinefuse.formats.kinect_multitrack import read_kinect_multitrack
    from kinefuse.lab.realism_tails import GROSS_M, take_tails
    from kinefuse.lab.realism_takes import real_pair

    path = next((shared_data / "kinect" / "kinect_multitrack").glob("Study_4_Kinect_0_*.csv"))
    t = take_tails(real_pair(read_kinect_multitrack(path)))
    assert 0.5 < t.limb_rate_hz < 2.0
    assert all(r.peak_m > GROSS_M for r in t.runs)
    assert np.median([r.duration_s for r in t.runs]) < 0.2
    assert np.mean([r.one_sensor for r in t.runs]) > 0.4

"""Error metrics against the truth, and the confidence interval of a gain."""

from __future__ import annotations

import numpy as np
import pytest

from kinefuse.report.metrics import gain_ci, position_errors


@pytest.fixture
def truth(rng) -> np.ndarray:
    return rng.normal(0.0, 0.3, (300, 25, 3))


def correlated_noise(rng, shape: tuple[int, ...], sigma: float) -> np.ndarray:
    """Noise correlated over ~10 frames, like a tracker's errors."""
    white = rng.normal(0.0, sigma, shape)
    kernel = np.ones(10) / np.sqrt(10)
    return np.apply_along_axis(lambda x: np.convolve(x, kernel, "same"), 0, white)


def test_a_real_gain_is_significant(rng, truth) -> None:
    better = truth + correlated_noise(rng, truth.shape, 0.03)
    worse = truth + correlated_noise(rng, truth.shape, 0.04)
    gain, low, high = gain_ci(better, worse, truth)
    assert gain == pytest.approx(25.0, abs=3.0)  # MAE about 3/4 of the other's
    assert 0 < low < gain < high


def test_a_difference_made_of_noise_is_not(rng, truth) -> None:
    a = truth + correlated_noise(rng, truth.shape, 0.03)
    b = truth + correlated_noise(rng, truth.shape, 0.03)
    gain, low, high = gain_ci(a, b, truth)
    assert low < 0 < high
    assert low <= gain <= high
    assert gain_ci(a, a, truth) == (0.0, 0.0, 0.0)


def test_only_joints_both_estimate_count_and_empty_is_nan(rng, truth) -> None:
    a = truth + 0.01
    b = truth + 0.02
    b[:, 3] = np.nan  # b lacks a joint: a's error there is left out too
    a[:, 4] += 5.0  # ... while a's own outlier joint counts
    gain, _, _ = gain_ci(a, b, truth)
    ea = np.linalg.norm(a - truth, axis=-1)
    ea[:, 3] = np.nan
    expected = 100 * (1 - np.nanmean(ea) / np.nanmean(np.linalg.norm(b - truth, axis=-1)))
    assert gain == pytest.approx(expected)
    assert np.isnan(gain_ci(a, np.full_like(a, np.nan), truth)).all()


def test_position_errors_leave_missing_out(truth) -> None:
    est = truth + np.array([0.03, 0.04, 0.0])  # 5 cm everywhere
    est[:10] = np.nan
    e = position_errors(est, truth)
    assert e["mae_m"] == pytest.approx(0.05) and e["p95_m"] == pytest.approx(0.05)
    assert e["frames"] == 290 and e["missing_fraction"] == pytest.approx(10 / 300)

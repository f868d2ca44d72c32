"""Error metrics against the truth, and the confidence interval of a gain."""

from __future__ import annotations

import numpy as np
import pytest

from kinefuse.lab.metrics import bias_noise, gain, gain_ci, position_errors, verdict


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


def test_gain_in_cm_and_percent_share_one_definition(truth) -> None:
    # a solves fewer joints; on its own joints it is worse, while its full-set MAE looks better
    a = truth + 0.03
    b = truth + 0.02
    b[:, :5] += 0.5  # b's error is large on joints a does not solve at all
    a[:, :5] = np.nan
    own_a = position_errors(a, truth)["mae_m"]
    own_b = position_errors(b, truth)["mae_m"]
    assert own_a < own_b  # the comparison of own MAEs would call a better
    g = gain(a, b, truth)
    r3 = np.sqrt(3)  # an offset of d on each axis is d * sqrt(3) away
    assert g["gain_m"] == pytest.approx(-0.01 * r3)  # on the joints both solved, a is worse
    assert g["gain_percent"] == pytest.approx(-50.0)
    assert g["verdict"] == "loss" and g["common_fraction"] == pytest.approx(20 / 25)
    assert g["mae_m"] == pytest.approx(0.03 * r3) and g["mae_reference_m"] == pytest.approx(
        0.02 * r3
    )
    low, high = g["gain_ci95_m"]
    assert low <= g["gain_m"] <= high


def test_verdict_needs_an_interval_clear_of_zero() -> None:
    assert verdict(0.5, 2.0) == "gain" and verdict(-2.0, -0.5) == "loss"
    assert verdict(-0.1, 2.0) == "no clear difference"
    assert verdict(0.0, 0.0) == "no clear difference"
    assert verdict(0.001, 0.004) == "no clear difference"  # below what the report can print
    assert verdict(float("nan"), 1.0) == "no clear difference"


def test_bias_and_noise_split_a_fixed_offset_from_the_spread(rng, truth) -> None:
    offset = np.array([0.05, -0.02, 0.03])
    est = truth + offset + rng.normal(0.0, 0.01, truth.shape)
    est[:, 7] = np.nan  # a joint never estimated
    bn = bias_noise(est, truth)
    spine = bn["by_joint"]["SpineBase"]
    np.testing.assert_allclose(spine["bias_m"], offset, atol=0.003)  # 3 mm
    assert spine["bias_vertical_m"] == pytest.approx(0.03, abs=0.003)
    assert spine["noise_m"] == pytest.approx(0.01 * np.sqrt(3), rel=0.15)
    assert bn["by_joint"]["HandLeft"] is None
    assert bn["bias_norm_mean_m"] == pytest.approx(np.linalg.norm(offset), abs=0.003)


def test_block_bootstrap_indices_as_the_inline_code_they_replaced() -> None:
    from kinefuse.lab.metrics import block_bootstrap_indices

    for n, block in [(1, 30), (7, 3), (100, 30), (95, 30), (10, 0)]:
        idx = block_bootstrap_indices(n, block=block, n_boot=50, seed=4)
        b = max(1, min(block, n))  # the code gain() and mae_intervals() each carried
        starts = np.random.default_rng(4).integers(0, n, size=(50, -(-n // b)))
        old = ((starts[..., None] + np.arange(b)) % n).reshape(50, -1)[:, :n]
        np.testing.assert_array_equal(idx, old)
        assert idx.shape == (50, n) and idx.min() >= 0 and idx.max() < n
        # within a block the frames are consecutive, wrapping at the end
        d = np.diff(idx[:, :b], axis=1) % n
        assert (d == 1).all()


def test_block_bootstrap_sums_equal_the_whole_gather_in_any_batch(monkeypatch) -> None:
    """The bootstrap's sums are gathered a few resamples at a time (bounded memory on long
    sessions): the same numbers, bit for bit, as gathering every resample at once, for every
    batch size, for per-frame and per-joint values and for counts."""
    from kinefuse.lab import metrics
    from kinefuse.lab.metrics import block_bootstrap_indices, block_bootstrap_sums

    rng = np.random.default_rng(2)
    for n, shape in [(1, ()), (7, ()), (3000, ()), (95, (25,)), (1200, (25,))]:
        v = rng.normal(size=(n, *shape))
        ok = rng.random((n, *shape)) > 0.2
        idx = block_bootstrap_indices(n, block=30, n_boot=200, seed=5)
        whole = [v[idx].sum(axis=1), ok[idx].sum(axis=1)]
        for batch in (1 << 20, 5000, 1):  # one batch, some rows at a time, one row at a time
            monkeypatch.setattr(metrics, "BOOTSTRAP_BATCH_ELEMENTS", batch)
            got = block_bootstrap_sums([v, ok], block=30, n_boot=200, seed=5)
            for a, b in zip(whole, got, strict=True):
                assert a.dtype == b.dtype and a.shape == b.shape == (200, *shape)
                np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="same number of frames"):
        block_bootstrap_sums([np.zeros(3), np.zeros(4)], block=2, n_boot=3, seed=0)

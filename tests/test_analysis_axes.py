"""The movement filter's speed threshold (kinefuse.analysis.axes.speed_threshold)."""

from __future__ import annotations

import numpy as np

from kinefuse.analysis.axes import speed_threshold


def _fused_like_speeds(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """log10 speeds (rad per frame) of one limb in a calibration phase, shaped like a fused
    thigh's of issue 24: the stationary samples (most of the phase: noise and sway), a thin
    plateau of intermediate speeds (the parent's and the other limbs' movements leaking in,
    slow stroke ends), a slow movement (ab-/adduction near its 70 deg/s peak) and a fast one
    (flexion, 100-170 deg/s) piling up near its peak speed. Returns (all, stationary, slow)."""
    stationary = rng.normal(-2.73, 0.2, 1650)
    plateau = rng.uniform(-2.2, -1.9, 40)
    slow = rng.uniform(-1.9, -1.36, 42)
    fast = np.concatenate([rng.uniform(-1.26, -0.9, 30), rng.normal(-1.0, 0.03, 30)])
    return np.concatenate([stationary, plateau, slow, fast]), stationary, slow


def test_a_slow_second_movement_is_above_the_threshold() -> None:
    # the old rule took the deepest bin between the stationary peak and the most prominent
    # bump of the movement's sparse plateau: the gap between the slow and the fast movement,
    # which filtered out every sample of the slow one (the thigh then had one direction only)
    for seed in range(5):
        v, stationary, slow = _fused_like_speeds(np.random.default_rng(seed))
        thr = speed_threshold(v)
        assert np.mean(slow > thr) > 0.95, (seed, thr)
        assert np.mean(stationary > thr) < 0.05, (seed, thr)


def test_a_clear_valley_is_kept() -> None:
    # stationary and movement samples apart with an empty stretch between them: the threshold
    # stays in that stretch
    rng = np.random.default_rng(1)
    stationary = rng.normal(-3.0, 0.15, 1500)
    moving = rng.normal(-1.2, 0.15, 300)
    thr = speed_threshold(np.concatenate([stationary, moving]))
    assert stationary.max() < thr + 0.15 and thr < moving.min() + 0.1
    assert np.mean(stationary > thr) < 0.01 and np.mean(moving > thr) > 0.99


def test_degenerate_speeds() -> None:
    assert speed_threshold(np.array([1.0, 1.0, 1.0])) == float("inf")
    assert speed_threshold(np.array([np.nan, 0.5])) == float("inf")

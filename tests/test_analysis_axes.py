"""The movement filter (kinefuse.biomech.axes): its speed threshold and its runs."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from kinefuse.biomech.axes import movement_mask, speed_threshold


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


def _limb_with_quick_strokes(seed: int) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """A minute of one limb's directions at 30 Hz, shaped like a fused thigh in a 3-sensor
    session of issue 24: correlated jitter of about 1.6 deg with glitches (a few frames 4 deg
    off), two slow flexion strokes of 70 deg, then two quick ab-duction strokes of 24 deg in
    0.55 s each (peak speed about 130 deg/s). Returns the samples and the quick strokes' frames."""
    rng = np.random.default_rng(seed)
    rate, n = 30.0, 1800
    t = np.arange(n) / rate
    ang = np.zeros((n, 2))
    quick = []
    for t0, dur, amp, k in ((20.0, 1.1, 70.0, 0), (21.2, 1.1, 70.0, 0),
                            (23.0, 0.55, 24.0, 1), (23.6, 0.55, 24.0, 1)):  # fmt: skip
        m = (t >= t0) & (t < t0 + dur)
        ang[m, k] += amp * 0.5 * (1.0 - np.cos(2.0 * np.pi * (t[m] - t0) / dur))
        if k == 1:
            quick.append((int(np.flatnonzero(m)[0]), int(np.flatnonzero(m)[-1]) + 1))
    a = np.exp(-1.0 / (0.15 * rate))
    w = rng.normal(0.0, 1.6 * np.sqrt(1.0 - a * a), (n, 3))
    e = np.zeros((n, 3))
    for i in range(1, n):
        e[i] = a * e[i - 1] + w[i]
    for i in rng.choice(np.arange(10, n - 10), 40, replace=False):
        e[i : i + 3] += rng.normal(0.0, 4.0, 3)
    flex = Rotation.from_rotvec(np.radians(ang[:, :1]) * [0.0, 1.0, 0.0])
    abd = Rotation.from_rotvec(np.radians(ang[:, 1:]) * [1.0, 0.0, 0.0])
    u = (Rotation.from_rotvec(np.radians(e)) * flex * abd).apply([0.0, 0.0, -1.0])
    return u, quick


def test_quick_strokes_are_movement() -> None:
    # the old filter dropped every run above the threshold shorter than 0.2 s as a noise
    # spike: a quick stroke crosses a threshold set high by fused glitches for 3-5 frames a
    # half-stroke, so both ab-duction strokes were dropped whole (seeds 0, 1 and 4: none or 38 %
    # of their frames kept) and the limb was learned with one axis
    for seed in range(5):
        u, quick = _limb_with_quick_strokes(seed)
        moving, _ = movement_mask(u, 30.0, smooth_s=0.0)
        for a, b in quick:
            assert moving[a:b].mean() >= 0.3, (seed, a, moving[a:b].mean())
        still = np.concatenate([moving[:500], moving[1000:]])
        assert still.mean() < 0.15, (seed, still.mean())


def test_short_noise_runs_stay_out() -> None:
    # a glitch that crosses the threshold for a few frames and moves the limb 3 deg and back is
    # not a quick stroke, however long the slower speeds around it last (without the sweep
    # test, 13-25 glitch frames were kept as movement)
    for seed in range(3):
        rng = np.random.default_rng(seed)
        n = 1800
        t = np.arange(n) / 30.0
        ang = np.zeros(n)
        for t0 in (5.0, 9.0, 13.0, 17.0):  # four slow 20-deg strokes
            m = (t >= t0) & (t < t0 + 3.0)
            ang[m] = 10.0 * (1.0 - np.cos(2.0 * np.pi * (t[m] - t0) / 3.0))
        jitter = Rotation.from_rotvec(np.radians(rng.normal(0.0, 0.15, (n, 3))))
        u = (jitter * Rotation.from_rotvec(np.radians(ang)[:, None] * [0.0, 1.0, 0.0])).apply(
            [0.0, 0.0, -1.0]
        )
        for i in range(800, 1750, 45):  # glitches from frame 800 on
            axis = rng.normal(size=3)
            axis /= np.linalg.norm(axis)
            for j, a in enumerate((0.5, 1.0, 3.0, 3.0, 1.0, 0.5)):
                u[i + j] = Rotation.from_rotvec(np.radians(a) * axis).apply(u[i + j])
        moving, _ = movement_mask(u, 30.0, smooth_s=0.0)
        assert moving[150:600].sum() > 250  # the strokes
        assert not moving[790:].any(), (seed, int(moving[790:].sum()))

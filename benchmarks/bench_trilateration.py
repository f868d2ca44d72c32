"""Throughput of the batched Gauss-Newton trilateration against scipy, on the same observations.

Run: ``python benchmarks/bench_trilateration.py [--smoke]`` (one thread; prints numbers, asserts
nothing; ``--smoke``: 40 frames, 100 scipy problems and 10 s instead of 10 minutes, to check that
it runs).

1. batched ``solve_nonlinear`` on all problems at once vs ``scipy.optimize.least_squares`` called
   once per problem (same ranges, same linear start, analytic Jacobian), with the agreement of
   their answers; target ratio >= 100x;
2. the paper's Table I trade-off: c_threshold vs error vs microseconds per solve;
3. wall time of each method (and of occlusion detection) on 10 minutes of 4 sensors.
"""

from __future__ import annotations

import os

os.environ["OMP_NUM_THREADS"] = "1"
os.environ["OPENBLAS_NUM_THREADS"] = "1"
os.environ["MKL_NUM_THREADS"] = "1"

import argparse
import json
import time
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from kinefuse.capture.fusion.trilateration import (
    sensor_centres,
    solve_linear,
    solve_nonlinear,
    trilaterate,
)
from kinefuse.capture.occlusion.segments import detect_occlusion_sensors
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.geometry.transforms import invert_transform, look_at
from kinefuse.core.skeleton import N_JOINTS

RATE_HZ = 30.0
WALKER = (
    Path(__file__).resolve().parents[1].parent
    / "shared"
    / "data"
    / "kinect"
    / "kinect2_tracking"
    / "walker.json"
)


def rig(heights: tuple[float, ...], radius_m: float = 3.0) -> np.ndarray:
    angles = np.linspace(0, 2 * np.pi, len(heights), endpoint=False) + 0.4
    return np.stack(
        [
            look_at([radius_m * np.cos(a), radius_m * np.sin(a), h], [0.0, 0.0, 1.0])
            for a, h in zip(angles, heights, strict=True)
        ]
    )


def session(rng: np.random.Generator, n_frames: int, s2w: np.ndarray, noise_m: float):
    """Joint-like truth ``(T, 25, 3)`` and noisy observations ``(T, S, 25, 3)``."""
    truth = np.empty((n_frames, N_JOINTS, 3))
    truth[..., :2] = rng.uniform(-0.7, 0.7, (n_frames, N_JOINTS, 2))
    truth[..., 2] = rng.uniform(0.05, 1.8, (n_frames, N_JOINTS))
    w2s = invert_transform(s2w)
    obs = np.einsum("sij,tkj->tski", w2s[:, :3, :3], truth) + w2s[None, :, None, :3, 3]
    return truth, obs + rng.normal(0.0, noise_m, obs.shape)


def real_poses(n_frames: int) -> np.ndarray | None:
    """The real Kinect v2 walk (330 frames) as world truth ``(T, 25, 3)``, z up, tiled."""
    if not WALKER.is_file():
        return None
    frames = json.loads(WALKER.read_text())["bodyFrame"]
    cam = np.array(
        [
            [
                [q["cameraX"], q["cameraY"], q["cameraZ"]]
                for q in sorted(
                    next(b for b in f["bodies"] if b.get("tracked"))["joints"],
                    key=lambda q: q["jointType"],
                )
            ]
            for f in frames
        ]
    )
    # Kinect camera space (x left, y up, z forward) -> world (x forward, y left, z up)
    world = np.stack([cam[..., 2], cam[..., 0], cam[..., 1]], axis=-1)
    world[..., :2] -= world[:, 0, :2].mean(axis=0)
    world[..., 2] -= world[..., 2].min() - 0.03
    reps = -(-n_frames // len(world))
    return np.concatenate([world, world[::-1]] * reps)[:n_frames]


def problems(truth: np.ndarray, obs: np.ndarray, s2w: np.ndarray):
    ranges = np.linalg.norm(obs, axis=-1).transpose(0, 2, 1).reshape(-1, obs.shape[1])
    world = np.einsum("sij,tskj->tski", s2w[:, :3, :3], obs) + s2w[None, :, None, :3, 3]
    reference = world.mean(axis=1).reshape(-1, 3)
    return sensor_centres(s2w), ranges, reference, truth.reshape(-1, 3)


def best_of(fn, repeats: int = 3) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def scipy_per_problem(centres, ranges, starts):
    out = np.empty_like(starts)
    for i in range(len(ranges)):
        r = ranges[i]

        def fun(p, r=r):
            return np.linalg.norm(p - centres, axis=1) - r

        def jac(p):
            d = p - centres
            return d / np.linalg.norm(d, axis=1)[:, None]

        out[i] = least_squares(fun, starts[i], jac=jac, method="lm").x
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="tiny inputs (seconds to run)")
    smoke = ap.parse_args().smoke
    rng = np.random.default_rng(2026)
    s2w = rig((0.5, 2.0, 1.0, 2.4))
    n_problem_frames = 40 if smoke else 2000
    truth, obs = session(rng, n_problem_frames, s2w, noise_m=0.02)  # frames x 25 joints
    centres, ranges, reference, truth_p = problems(truth, obs, s2w)
    n_batched = len(ranges)
    n_scipy = 100 if smoke else 1000
    starts = solve_linear(centres, ranges, reference).positions

    print("== batched Gauss-Newton vs scipy.optimize.least_squares per joint (1 thread)")
    t_batch = best_of(lambda: solve_nonlinear(centres, ranges, reference))
    sol = solve_nonlinear(centres, ranges, reference)
    t_scipy = best_of(
        lambda: scipy_per_problem(centres, ranges[:n_scipy], starts[:n_scipy]), repeats=1
    )
    ref_sol = scipy_per_problem(centres, ranges[:n_scipy], starts[:n_scipy])
    per_batch_us = t_batch / n_batched * 1e6
    per_scipy_us = t_scipy / n_scipy * 1e6
    agree = np.linalg.norm(sol.positions[:n_scipy] - ref_sol, axis=1)
    print(f"batched : {n_batched} problems in {t_batch * 1e3:.1f} ms = {per_batch_us:.2f} us/joint")
    print(f"scipy   : {n_scipy} problems in {t_scipy * 1e3:.1f} ms = {per_scipy_us:.1f} us/joint")
    print(f"throughput ratio: {per_scipy_us / per_batch_us:.0f}x (target >= 100x)")
    print(f"agreement: median {np.median(agree) * 1e3:.4f} mm, max {agree.max() * 1e3:.4f} mm")
    print(f"mean iterations: {sol.iterations.mean():.2f}")

    print("\n== Table I style: c_threshold vs error vs time (2 cm noise, 4 sensors)")
    print(f"{'c_threshold_m2':>14} {'mae_mm':>8} {'iters':>6} {'us_per_joint':>12}")
    for c in (1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-8, 1e-10):
        t = best_of(lambda c=c: solve_nonlinear(centres, ranges, reference, c_threshold=c))
        s = solve_nonlinear(centres, ranges, reference, c_threshold=c)
        mae = np.linalg.norm(s.positions - truth_p, axis=1).mean()
        us = t / n_batched * 1e6
        print(f"{c:>14.0e} {mae * 1e3:>8.2f} {s.iterations.mean():>6.2f} {us:>12.3f}")

    minutes = 10 / 60 if smoke else 10
    n_frames = int(60 * minutes * RATE_HZ)
    level = rig((1.0, 1.07, 1.13, 1.2))
    walk = real_poses(n_frames)
    if walk is None:
        print("\n(real walk not found: random points instead; occlusion timing is pessimistic)")
        truth10, obs10 = session(rng, n_frames, level, noise_m=0.02)
    else:
        truth10 = walk
        w2s = invert_transform(level)
        obs10 = np.einsum("sij,tkj->tski", w2s[:, :3, :3], truth10) + w2s[None, :, None, :3, 3]
        obs10 = obs10 + rng.normal(0.0, 0.02, obs10.shape)
    print(
        f"\n== {minutes:.2g} minutes of 4 sensors at 30 Hz (real walk poses, level rig 1.0-1.2 m, "
        "2 cm noise)"
    )
    intr = Intrinsics()
    t_occ = best_of(lambda: detect_occlusion_sensors(obs10, intr), repeats=1)
    occ = detect_occlusion_sensors(obs10, intr)
    print(f"occlusion detection (crossing): {t_occ:.2f} s")
    t_cov = best_of(lambda: detect_occlusion_sensors(obs10, intr, rule="coverage"), repeats=1)
    print(f"occlusion detection (coverage): {t_cov:.2f} s")
    t_method = {}
    for method in ("linear", "geometric", "nonlinear"):
        t = t_method[method] = best_of(lambda m=method: trilaterate(obs10, level, m), repeats=1)
        err = np.linalg.norm(trilaterate(obs10, level, method).positions - truth10, axis=-1)
        print(f"{method:>9}: {t:.2f} s   mae {err.mean() * 1e3:.1f} mm   "
              f"({t / t_method['linear']:.1f} x linear, the baseline)")  # fmt: skip
    occlusion = (occ.occluded, occ.n_intersections)
    t = best_of(lambda: trilaterate(obs10, level, "paper", occlusion=occlusion), repeats=1)
    print(f"    paper: {t:.2f} s (selection + nonlinear; detection above)")


if __name__ == "__main__":
    main()

"""Depth rendering speed: one 512x424 Kinect v2 frame of the full lab (room + person + wand).

Run: ``python benchmarks/bench_depth.py [--smoke]`` (``--smoke``: 3 frames and one naive frame,
to check that it runs; too few to quote). Prints the median ms per frame over 30 frames on one
core for the noisy ``render_depth`` (target: under 50 ms), the noise-free ``render_depth_m``, the
first frame of a new sensor pose (the room is cast once per pose and cached), and a naive
baseline that tests all pixels against all capsules with ``kinefuse.core.geometry.raycast`` in the
same run, with the ratio and the largest depth difference between the two.
"""

from __future__ import annotations

import os

os.environ["OMP_NUM_THREADS"] = "1"
os.environ["OPENBLAS_NUM_THREADS"] = "1"
os.environ["MKL_NUM_THREADS"] = "1"

import argparse
import time

import numpy as np

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.geometry.raycast import ray_capsules, ray_plane
from kinefuse.core.geometry.transforms import look_at
from kinefuse.core.skeleton import JOINT_INDEX, standing_pose
from kinefuse.sim import depth_raycast
from kinefuse.sim.depth import (
    Scene,
    render_depth,
    render_depth_m,
    render_geometry,
)

FRAMES = 30
BASELINE_FRAMES = 3

_RIGHT_HAND_RAISED = {
    "ElbowRight": (0.2, -0.3, 1.3),
    "WristRight": (0.4, -0.3, 1.45),
    "HandRight": (0.48, -0.3, 1.5),
    "HandTipRight": (0.55, -0.3, 1.53),
    "ThumbRight": (0.48, -0.26, 1.52),
}
POSE = standing_pose()  # at the origin facing +x, right hand raised in front (metres)
for _name, _xyz in _RIGHT_HAND_RAISED.items():
    POSE[JOINT_INDEX[_name]] = _xyz


def scene_at(k: int) -> Scene:
    """Frame ``k``: the person sways a little and holds the wand up in the right hand."""
    pose = POSE + np.array([0.02 * np.sin(0.3 * k), 0.02 * np.cos(0.2 * k), 0.0])
    hand = pose[JOINT_INDEX["HandRight"]]
    return Scene.from_pose(
        pose, 1.75, wand_centre=hand + np.array([0.0, 0.0, 0.5]), wand_handle_dir=(0.0, 0.0, -1.0)
    )


def naive_depth(scene: Scene, s2w: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """Every pixel against every capsule and every room plane (chunked to bound memory)."""
    rays_s = intr.pixel_rays().reshape(-1, 3)
    rot, o = s2w[:3, :3], s2w[:3, 3]
    a, b, r, _ = scene.primitives()
    lo, hi = scene.room_min_xy_m, scene.room_max_xy_m
    out = np.empty(len(rays_s))
    for s in range(0, len(rays_s), 8192):
        d_s = rays_s[s : s + 8192]
        d_w = d_s @ rot.T
        t = np.minimum(ray_capsules(o, d_w, a, b, r).min(axis=1), ray_plane(o, d_w, 0, (0, 0, 1)))
        for axis, val in ((0, lo[0]), (0, hi[0]), (1, lo[1]), (1, hi[1])):
            n = np.eye(3)[axis]
            tw = ray_plane(o, d_w, n * val, n)
            t = np.minimum(t, np.where(o[2] + tw * d_w[:, 2] <= scene.wall_height_m, tw, np.inf))
        out[s : s + 8192] = t * d_s[:, 2]
    return out.reshape(intr.height, intr.width)


def median_ms(fn, n: int) -> tuple[float, list[float]]:
    times = []
    for k in range(n):
        t0 = time.perf_counter()
        fn(k)
        times.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(times)), times


def main() -> None:
    global FRAMES, BASELINE_FRAMES
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="3 frames (seconds to run)")
    if ap.parse_args().smoke:
        FRAMES, BASELINE_FRAMES = 3, 1
    intr = Intrinsics()
    s2w = look_at((2.5, 0.4, 1.1), (0.0, 0.0, 1.0))
    rng = np.random.default_rng(0)
    render_depth(scene_at(0), s2w, intr, rng)  # warm-up: imports, caches

    noisy, _ = median_ms(lambda k: render_depth(scene_at(k), s2w, intr, rng), FRAMES)
    clean, _ = median_ms(lambda k: render_depth_m(scene_at(k), s2w, intr), FRAMES)

    def cold(k: int) -> None:
        depth_raycast._room_cached.cache_clear()
        render_depth(scene_at(k), s2w, intr, rng)

    first, _ = median_ms(cold, min(5, FRAMES))
    baseline, _ = median_ms(lambda k: naive_depth(scene_at(k), s2w, intr), BASELINE_FRAMES)

    geo = render_geometry(scene_at(0), s2w, intr)
    ref = naive_depth(scene_at(0), s2w, intr)
    fin = np.isfinite(ref)
    same_hits = bool(np.array_equal(fin, np.isfinite(geo.z_m)))
    max_diff = float(np.abs(ref[fin] - geo.z_m[fin]).max())
    body_px = int((geo.label >= 3).sum())
    scene0 = scene_at(0)
    pairs = depth_raycast._pairs(scene0, s2w[:3, :3], s2w[:3, 3], intr, 1.5)
    tested = 0 if pairs is None else int(pairs.pix.size)
    naive_tests = intr.width * intr.height * len(scene0.primitives()[2])

    print(f"depth frame {intr.width}x{intr.height}, room + person (24 capsules) + wand, 1 core")
    print(f"  body+wand pixels in view: {body_px}")
    print(
        f"  pixel-capsule tests: culled {tested} (with the lateral-noise margin) vs naive "
        f"{naive_tests} ({naive_tests / max(tested, 1):.0f}x fewer)"
    )
    print(f"  render_depth (noisy)       median {noisy:7.1f} ms/frame over {FRAMES} frames")
    print(f"  render_depth_m (clean)     median {clean:7.1f} ms/frame over {FRAMES} frames")
    print(f"  render_depth, new pose     median {first:7.1f} ms/frame (room cast, not cached)")
    print(f"  naive all-pixels x all     median {baseline:7.1f} ms/frame over {BASELINE_FRAMES}")
    print(f"  speed-up noisy vs naive    {baseline / noisy:7.1f}x")
    print(f"  speed-up clean vs naive    {baseline / clean:7.1f}x")
    print(f"  same pixels hit: {same_hits}, largest depth difference {max_diff:.2e} m")
    print(f"  target < 50 ms/frame (steady state, noisy): {'met' if noisy < 50 else 'NOT met'}")
    print(f"  (a new sensor pose adds the room cast once: {first - noisy:+.1f} ms)")


if __name__ == "__main__":
    main()

"""Calibration speed: wand detection per depth frame and the full registration.

Run: ``python benchmarks/bench_calibration.py [--smoke]`` (``--smoke``: 4 frames, 5 s of waving,
one run each, to check that it runs). On one core (BLAS threads 1, CPU affinity 1):

1. wand detection on 40 simulated 512x424 Kinect v2 frames of the calibration phase (the actor
   holding the wand, 4 sensors of the default rig, full depth error model): median and p90 ms
   per frame of the robust detector (target: median under 5 ms), against the paper's detector
   (nearest-object binarization, 5 repeats) on the same frames, with the detection rate and the
   median error of both;
2. ``register_full`` of 8 sensors x 600 sightings each (20 s at 30 Hz): median wall time of 5
   runs (target: under 1 s), with the mean pose errors, against 4 sensors x 600 as a baseline.
"""

from __future__ import annotations

import os

os.environ["OMP_NUM_THREADS"] = "1"
os.environ["OPENBLAS_NUM_THREADS"] = "1"
os.environ["MKL_NUM_THREADS"] = "1"

import argparse
import time
from collections.abc import Callable

import numpy as np

from kinefuse.capture.calibration.common import WandDetection
from kinefuse.capture.calibration.compare import pose_errors
from kinefuse.capture.calibration.floor import FloorPlane
from kinefuse.capture.calibration.register import register_full
from kinefuse.capture.calibration.synthetic import make_rig, simulate_sightings, wand_waving
from kinefuse.capture.calibration.wand_paper import detect_wand_paper
from kinefuse.capture.calibration.wand_robust import detect_wand
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.camera.wand import Wand
from kinefuse.core.geometry.transforms import invert_transform
from kinefuse.core.skeleton import JOINTS
from kinefuse.sim.choreography import holding_poses, make_wand_path
from kinefuse.sim.depth import Scene, render_depth
from kinefuse.sim.rig import default_rig

if hasattr(os, "sched_setaffinity"):
    os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})

INTR = Intrinsics()
WAND = Wand()
FRAMES_PER_SENSOR = 10
WAVING_S = 20.0
RUNS = 5
STANDING = {
    "SpineBase": (0.0, 0.0, 0.95), "SpineMid": (0.0, 0.0, 1.18), "Neck": (0.0, 0.0, 1.50),
    "Head": (0.0, 0.0, 1.63), "ShoulderLeft": (-0.18, 0.0, 1.40), "ElbowLeft": (-0.20, 0.0, 1.12),
    "WristLeft": (-0.21, 0.0, 0.88), "HandLeft": (-0.21, 0.0, 0.80),
    "ShoulderRight": (0.18, 0.0, 1.40), "ElbowRight": (0.20, 0.0, 1.12),
    "WristRight": (0.21, 0.0, 0.88), "HandRight": (0.21, 0.0, 0.80),
    "HipLeft": (-0.09, 0.0, 0.92), "KneeLeft": (-0.10, 0.02, 0.50),
    "AnkleLeft": (-0.10, 0.0, 0.08), "FootLeft": (-0.10, 0.12, 0.03),
    "HipRight": (0.09, 0.0, 0.92), "KneeRight": (0.10, 0.02, 0.50),
    "AnkleRight": (0.10, 0.0, 0.08), "FootRight": (0.10, 0.12, 0.03),
    "SpineShoulder": (0.0, 0.0, 1.42), "HandTipLeft": (-0.21, 0.0, 0.72),
    "ThumbLeft": (-0.19, 0.03, 0.82), "HandTipRight": (0.21, 0.0, 0.72),
    "ThumbRight": (0.19, 0.03, 0.82),
}  # fmt: skip


def _frames(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    rest = np.array([STANDING[n] for n in JOINTS])
    path = make_wand_path(20.0, rng)
    rig = default_rig(4)
    frames, truth = [], []
    for spec in rig.sensors:
        w2s = invert_transform(spec.sensor2world)
        for t in rng.uniform(3.0, 20.0, FRAMES_PER_SENSOR):
            c = path.at(np.array([t]))[0]
            poses, handles = holding_poses(c[None], rest, WAND)
            scene = Scene.from_pose(
                poses[0], 1.75, wand=WAND, wand_centre=c, wand_handle_dir=handles[0]
            )
            frames.append(render_depth(scene, spec.sensor2world, INTR, rng))
            truth.append(w2s[:3, :3] @ c + w2s[:3, 3])
    return np.array(frames), np.array(truth)


def _time_detector(
    detector: Callable[[np.ndarray, Intrinsics, Wand], WandDetection],
    frames: np.ndarray,
    truth: np.ndarray,
    repeat: int = 5,
) -> tuple[np.ndarray, float, float]:
    times, errs = [], []
    for i, f in enumerate(frames):
        for _ in range(repeat):
            t0 = time.perf_counter()
            det = detector(f, INTR, WAND)
            times.append(time.perf_counter() - t0)
        errs.append(np.linalg.norm(det.centre_sensor_m - truth[i]) if det.found else np.nan)
    e = np.array(errs)
    return np.array(times) * 1e3, float(np.isfinite(e).mean()), float(np.nanmedian(e)) * 1e3


def bench_detection() -> None:
    rng = np.random.default_rng(1)
    frames, truth = _frames(rng)
    detect_wand(frames[0], INTR, WAND)  # warm up
    t_rob, rate_rob, err_rob = _time_detector(detect_wand, frames, truth, repeat=RUNS)
    t_pap, rate_pap, err_pap = _time_detector(detect_wand_paper, frames, truth, repeat=min(2, RUNS))
    print(f"wand detection, {len(frames)} simulated 512x424 frames (actor + wand, full noise):")
    print(
        f"  robust: median {np.median(t_rob):.2f} ms, p90 {np.percentile(t_rob, 90):.2f} ms "
        f"per frame (target < 5 ms); found {rate_rob:.0%}, median error {err_rob:.1f} mm"
    )
    print("          (the error is mostly the simulated camera's systematic range offset)")
    print(
        f"  paper : median {np.median(t_pap):.2f} ms per frame; found {rate_pap:.0%}, "
        f"median error {err_pap:.0f} mm (it takes the nearest object: often the floor)"
    )
    print(f"  ratio paper / robust time: {np.median(t_pap) / np.median(t_rob):.1f}")


def _registration(n_sensors: int, seed: int) -> tuple[float, float, float, int]:
    rng = np.random.default_rng(seed)
    poses = make_rig(n_sensors, rng, distance_m=(2.5, 3.5), pitch_deg=20.0, roll_deg=5.0)
    t, wand = wand_waving(WAVING_S, rng)
    sightings = simulate_sightings(poses, INTR, t, wand, rng, dropout=0.0)
    floors = {}
    for i, s2w in enumerate(poses):
        up = invert_transform(s2w)[:3, :3] @ np.array([0.0, 0.0, 1.0])
        floors[f"k{i}"] = FloorPlane(up, float(s2w[2, 3]), n_inliers=1000)
    times = []
    reg = None
    for _ in range(RUNS):
        t0 = time.perf_counter()
        reg = register_full(sightings, floors=floors)
        times.append(time.perf_counter() - t0)
    assert reg is not None
    err = pose_errors(reg.sensor2world, poses)
    n = int(np.mean([len(s) for s in sightings.values()]))
    return float(np.median(times)), err.mean_position_error_m, err.mean_rotation_error_deg, n


def bench_registration() -> None:
    t8, p8, r8, n8 = _registration(8, 2)
    t4, p4, r4, n4 = _registration(4, 3)
    print(f"register_full ({WAVING_S:g} s of waving, 1 % outliers, floors given):")
    print(
        f"  8 sensors x {n8} sightings: median {t8 * 1e3:.0f} ms (target < 1000 ms); "
        f"mean errors {p8 * 1e3:.2f} mm, {r8:.3f} deg"
    )
    print(
        f"  4 sensors x {n4} sightings: median {t4 * 1e3:.0f} ms; "
        f"mean errors {p4 * 1e3:.2f} mm, {r4:.3f} deg"
    )
    print(f"  ratio 8 / 4 sensors: {t8 / t4:.1f}")


def main() -> None:
    global FRAMES_PER_SENSOR, WAVING_S, RUNS
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="tiny inputs (seconds to run)")
    if ap.parse_args().smoke:
        FRAMES_PER_SENSOR, WAVING_S, RUNS = 1, 5.0, 1
    bench_detection()
    bench_registration()


if __name__ == "__main__":
    main()

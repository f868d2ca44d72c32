"""Simulator speed: 60 s of 4 sensors without depth frames (target: under 20 s on one core).

Run: ``python benchmarks/bench_simulate.py [--smoke]`` (``--smoke``: 5 s, to check that it runs).
The motion is the bundled CMU 01_01 clip played
forward then backward until it lasts 60 s. Prints the wall time of ``simulate_session`` (store
writes included) split into its parts, and, as a machine-speed reference measured in the same
run, the time of a fixed numpy workload, so runs on different machines can be compared by ratio.
"""

from __future__ import annotations

import os

os.environ["OMP_NUM_THREADS"] = "1"
os.environ["OPENBLAS_NUM_THREADS"] = "1"
os.environ["MKL_NUM_THREADS"] = "1"

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from kinefuse.app.workflows.simulate import demo_clip_path
from kinefuse.core.frames.motion import Motion
from kinefuse.formats.motion import load_motion
from kinefuse.sim.lab import LabConfig, simulate_session
from kinefuse.sim.rig import default_rig, place_actor

SECONDS = 60.0
TARGET_S = 20.0


def reference_workload() -> float:
    """A fixed numpy workload (elementwise math and a small linear solve), seconds."""
    rng = np.random.default_rng(0)
    a = rng.normal(size=2_000_000)
    t0 = time.perf_counter()
    for _ in range(10):
        np.sqrt(np.abs(a) + 1.0).sum()
        np.linalg.solve(np.eye(200) + 0.01 * rng.normal(size=(200, 200)), np.ones(200))
    return time.perf_counter() - t0


def long_motion(seconds: float) -> Motion:
    m = load_motion(demo_clip_path())
    fwd = m.positions
    frames = [fwd]
    n_needed = int(seconds * m.rate_hz) + 2
    while sum(len(f) for f in frames) < n_needed:
        frames.append(frames[-1][::-1])
    pos = np.concatenate(frames)[:n_needed]
    return Motion(pos, m.rate_hz, m.synthesized, m.source + f" (ping-pong to {seconds:g} s)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="5 s of motion (seconds to run)")
    seconds = 5.0 if ap.parse_args().smoke else SECONDS
    rig = default_rig(4)
    motion = place_actor(long_motion(seconds), rig)
    ref = reference_workload()
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "bench.sqlite"
        cfg = LabConfig(seed=0, calibration_s=0.0, motion_s=seconds)
        t0 = time.perf_counter()
        simulate_session(motion, rig, out, cfg)
        took = time.perf_counter() - t0
        size_mb = out.stat().st_size / 1e6
    target = TARGET_S * seconds / SECONDS
    print(f"simulate {seconds:.0f} s x 4 sensors, no depth frames: {took:.2f} s "
          f"(target < {target:.3g} s: {'met' if took < target else 'NOT met'}); "
          f"store {size_mb:.1f} MB")  # fmt: skip
    print(f"reference numpy workload: {ref:.3f} s; simulate / reference = {took / ref:.1f}")


if __name__ == "__main__":
    main()

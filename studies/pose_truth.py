"""The pose tracker's lifting and mapping against the truth, per joint, on rendered body depth.

Run: ``python studies/pose_truth.py [--smoke] [--every N] [--sensors N]`` (``--smoke``: one
sensor, a few frames, to check that it runs; too few to quote). A real CMU walk
(``../shared/data/motion/cmu/131_01_scaled_metres.bvh``) in the simulated lab's default rig;
each sensor renders the actor's capsule body with the Kinect v2 depth error model
(:meth:`kinefuse.sim.lab.SensorSimulation.body_depth_frames`); 2D landmarks are the true joints
projected into that camera, exact and with a detector's pixel noise
(:class:`kinefuse.lab.pose_lift.DetectorNoise`: BlazePose Full's published PCK@0.2 as a
Gaussian); the tracker's stages after its 2D model lift, map and gate them. Prints, per joint,
the median and 95th percentile error where the joint is visible, where it is hidden (the
rendered surface at its pixel well in front of it), and the share of hidden joints not
reported as tracked; the frames the gates refused, with their reasons.
"""

from __future__ import annotations

import argparse
from collections import Counter
from pathlib import Path

import numpy as np

from kinefuse.formats.motion.load import load_motion
from kinefuse.lab.pose_lift import DetectorNoise, LiftScore, score_lifting
from kinefuse.sim.lab import LabConfig, SensorSimulation
from kinefuse.sim.rig import default_rig, place_actor

ROOT = Path(__file__).resolve().parents[1]
WALK = ROOT.parent / "shared" / "data" / "motion" / "cmu" / "131_01_scaled_metres.bvh"


def cm(v: object) -> str:
    x = float(v)  # type: ignore[arg-type]
    return "  -  " if np.isnan(x) else f"{100 * x:5.1f}"


def report(title: str, score: LiftScore) -> None:
    n = score.error_m.shape[0]
    print(f"\n{title}: {n} frames, {len(score.refused)} refused by the gates")
    for reason, k in Counter(score.refused).most_common(3):
        print(f"  refused {k}x: {reason}")
    print("| joint | visible n | median cm | p95 cm | hidden n | median cm | flagged |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for r in score.table():
        flagged = float(r["hidden_flagged"])  # type: ignore[arg-type]
        print(f"| {r['joint']} | {r['visible_n']} | {cm(r['visible_median_m'])} | "
              f"{cm(r['visible_p95_m'])} | {r['hidden_n']} | {cm(r['hidden_median_m'])} | "
              f"{'-' if np.isnan(flagged) else f'{100 * flagged:.0f} %'} |")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="1 sensor, 4 frames (seconds)")
    ap.add_argument("--every", type=int, default=3, help="every Nth capture (default 3)")
    ap.add_argument("--sensors", type=int, default=4, help="sensors of the default rig")
    ap.add_argument("--seed", type=int, default=0, help="the session's and the noise's seed")
    args = ap.parse_args()
    sensors, every, frames = (1, 30, 4) if args.smoke else (args.sensors, args.every, None)
    motion = load_motion(WALK)
    rig = default_rig(sensors)
    motion = place_actor(motion, rig)
    cfg = LabConfig(seed=args.seed, calibration_s=0.0)
    print(f"{WALK.name}: {motion.duration_s:.1f} s, {sensors} sensors of the default rig, "
          f"every {every}th capture, Kinect v2 depth error model on")  # fmt: skip
    for title, noise in (("exact landmarks", None), ("detector noise", DetectorNoise())):
        scores = []
        for k, spec in enumerate(rig.sensors):
            sim = SensorSimulation(motion, rig, spec.id, cfg)
            scores.append(score_lifting(sim, every=every, seed=args.seed + k, noise=noise,
                                        max_frames=frames))  # fmt: skip
        report(title, LiftScore.concat(scores))


if __name__ == "__main__":
    main()

"""A simulated session tracked by the pose tracker, fused and evaluated, beside the simulated
Kinect tracker's.

Run: ``python studies/pose_session.py [--smoke] [--seconds S] [--seed K]`` (``--smoke``: 1 s
of motion, two sensors, to check that it runs; too short to quote). The same clip (a real CMU
walk, ``../shared/data/motion/cmu/131_01_scaled_metres.bvh``), rig (the default 4 sensors) and
seed, simulated three times: with the simulated Kinect v2 tracker (``kinefuse simulate``'s), and
with the pose tracker's stages after its 2D model on every sensor's rendered body depth at
30 Hz, from landmarks projected from the true joints, exact and with a detector's pixel noise
(:class:`kinefuse.lab.pose_lift.DetectorNoise`). Each session is fused with ``best`` and
scored against the truth (``kinefuse evaluate --true-calibration --methods best``): the MAE over
the joints fused, the coverage, the 95th percentile.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from kinefuse.app.workflows.evaluate import run_evaluate
from kinefuse.formats.motion.load import load_motion
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.lab.pose_lift import DetectorNoise, pose_observations
from kinefuse.sim.lab import LabConfig, simulate_session
from kinefuse.sim.rig import default_rig, place_actor

ROOT = Path(__file__).resolve().parents[1]
WALK = ROOT.parent / "shared" / "data" / "motion" / "cmu" / "131_01_scaled_metres.bvh"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="1 s of motion, 2 sensors (seconds)")
    ap.add_argument("--seconds", type=float, default=None, help="motion seconds (default all)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    sensors, seconds = (2, 1.0) if args.smoke else (4, args.seconds)
    rig = default_rig(sensors)
    motion = place_actor(load_motion(WALK), rig, seconds)
    cfg = LabConfig(seed=args.seed, calibration_s=0.0, motion_s=seconds)
    trackers = {
        "simulated Kinect v2 tracker": None,
        "pose, exact landmarks": pose_observations(None, args.seed),
        "pose, detector noise": pose_observations(DetectorNoise(), args.seed),
    }
    print(f"{WALK.name}, {motion.duration_s if seconds is None else seconds:.1f} s, {sensors} "
          f"sensors of the default rig, seed {args.seed}; best, true calibration")  # fmt: skip
    print(f"{'tracker':<30} {'MAE cm':>7} {'p95 cm':>7} {'coverage':>9} {'frames':>7}")
    with tempfile.TemporaryDirectory(prefix="kinefuse-pose-session-") as tmp:
        for k, (name, observe) in enumerate(trackers.items()):
            path = Path(tmp) / f"s{k}.sqlite"
            simulate_session(motion, rig, path, cfg, observe=observe)
            with SessionStore.open(path, writable=True) as store:
                store.mark_complete()  # as kinefuse simulate does once the session is whole
            report = run_evaluate(session=path, methods=("best",), out_dir=None,
                                  calibration=None, true_calibration=True)  # fmt: skip
            r = report.method("best")
            print(f"{name:<30} {100 * r['mae_m']:7.2f} {100 * r['p95_m']:7.2f} "
                  f"{100 * r['coverage']:8.1f}% {report.report['frames']!s:>7}")  # fmt: skip


if __name__ == "__main__":
    main()

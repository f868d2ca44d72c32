"""The two sensors' knee (or elbow) angle disagreement split by how fast the joint bends.

    python studies/limb_angle_by_speed.py [--joint knee|elbow]
        [--tracker default|light] [--limb-coherence RHO]

For every KinectMultiTrack take of the population, real and simulated (one simulated subject per
take, as ``python studies/realism.py --population``): per paired frame and side, the two sensors'
disagreement on the included angle (left and right matched as they agree best), binned by the
joint's angular speed (the two sensors' mean angle, over +-3 frames), per layout: the median
and 90th percentile. docs/realism.md "One limb, one error". About 1 minute per run.
``--smoke``: participant 2's takes only (CI runs it).
"""

from __future__ import annotations

import argparse
import itertools
from dataclasses import replace
from pathlib import Path

import numpy as np

from kinefuse.app.workflows.simulate import tracker_model
from kinefuse.formats.kinect_multitrack import read_kinect_multitrack
from kinefuse.lab.realism import load_walk
from kinefuse.lab.realism_person import population_seeds
from kinefuse.lab.realism_population import layout_key
from kinefuse.lab.realism_takes import (
    StreamPair,
    layout_angle_deg,
    real_pair,
    simulated_pair,
    take_layout,
)
from kinefuse.pipeline.analysis_chain import hinge_angle_deg

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
POPULATION = DATA / "kinect" / "kinect_multitrack_population"
JOINTS = {"knee": ("Hip", "Knee", "Ankle"), "elbow": ("Shoulder", "Elbow", "Wrist")}
BINS = (0.0, 60.0, 120.0, 240.0, np.inf)  # deg/s


def speed_and_disagreement(pair: StreamPair, joint: str) -> np.ndarray:
    """``(N, 2)``: angular speed (deg/s) and disagreement (deg) per paired frame and side."""
    a, b = pair.joints_a[pair.idx_a], pair.joints_b[pair.idx_b]
    t = pair.t_sensor_a_s[pair.idx_a]
    prox, hinge, dist = JOINTS[joint]
    ang = {(q, side): hinge_angle_deg(x, f"{prox}{side}", f"{hinge}{side}", f"{dist}{side}")
           for q, x in (("a", a), ("b", b)) for side in ("Left", "Right")}  # fmt: skip
    out = []
    for side, other in (("Left", "Right"), ("Right", "Left")):
        own = ang[("a", side)]
        d = np.fmin(np.abs(own - ang[("b", side)]), np.abs(own - ang[("b", other)]))
        m = (own + ang[("b", side)]) / 2
        k = 3
        sp = np.full_like(m, np.nan)
        sp[k:-k] = np.abs(m[2 * k :] - m[: -2 * k]) / np.maximum(t[2 * k :] - t[: -2 * k], 1e-3)
        out.append(np.c_[sp, d])
    return np.concatenate(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--joint", choices=sorted(JOINTS), default="knee")
    ap.add_argument("--tracker", choices=("default", "light"), default="default")
    ap.add_argument("--limb-coherence", type=float, help="override the model's limb_coherence")
    ap.add_argument("--population", type=Path, default=POPULATION)
    ap.add_argument("--smoke", action="store_true", help="participant 2's takes only (seconds)")
    args = ap.parse_args()
    walk = load_walk(DATA / "motion" / "cmu" / "02_walk_a.amc")
    params = tracker_model(args.tracker)
    if args.limb_coherence is not None:
        params = replace(params, limb_coherence=args.limb_coherence)
    acc: dict[str, dict[str, list[np.ndarray]]] = {}
    pattern = "Study_2_*.csv" if args.smoke else "*.csv"
    for path in sorted(args.population.glob(pattern)):
        rec = read_kinect_multitrack(path)
        real = real_pair(rec)
        lay = take_layout(rec, real)
        group = acc.setdefault(layout_key(layout_angle_deg(lay)), {"real": [], "sim": []})
        group["real"].append(speed_and_disagreement(real, args.joint))
        for seed in population_seeds(path.name, 1):
            sim = simulated_pair(rec, walk, seed, lay, params)
            group["sim"].append(speed_and_disagreement(sim, args.joint))
    print(f"{args.joint} angle disagreement (deg), median / p90 [frames], by angular speed:")
    for layout in sorted(acc, key=float):
        for who in ("real", "sim"):
            x = np.concatenate(acc[layout][who])
            x = x[np.isfinite(x).all(axis=1)]
            cells = []
            for lo, hi in itertools.pairwise(BINS):
                v = x[(x[:, 0] >= lo) & (x[:, 0] < hi), 1]
                label = f"{lo:.0f}-{hi:.0f}" if np.isfinite(hi) else f">{lo:.0f}"
                cells.append(f"{label} deg/s {np.median(v):.1f} / {np.percentile(v, 90):.1f} "
                             f"[{v.size}]" if v.size else f"{label}: none")  # fmt: skip
            print(f"  {layout:>2} deg {who:4s}: " + "; ".join(cells))


if __name__ == "__main__":
    main()

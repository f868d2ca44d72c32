"""The fit of the tracker model's ``limb_coherence`` (docs/realism.md, "One limb, one error").

    python studies/fit_limb_coherence.py [--seeds 1] [--participants 0-9]
        [--rho 0 0.5 0.7 0.8 0.9 0.95]

For each candidate ``rho`` this simulates every KinectMultiTrack take of the chosen
participants (each take its own simulated subjects, as ``python studies/realism.py --population``)
and compares, per layout, the median over takes of the two sensors' knee and elbow angle
disagreement (``limb_angle_median_deg`` of :func:`kinefuse.lab.realism_takes.pair_figures`)
with the real one. The chosen value is the candidate with the smallest mean ``|log(sim / real)|``
over the three layouts. The median position disagreement is printed beside it: ``rho`` leaves
each joint's own error unchanged, so it should barely move (the Kabsch fit absorbs a little more
of an error that the joints share). About 30 s per candidate with one seed on the shared machine.
``--smoke``: participant 2's takes, one candidate, one seed (CI runs it).
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

from kinefuse.lab.realism import load_walk
from kinefuse.lab.realism_person import population_seeds
from kinefuse.lab.realism_population import population_summary
from kinefuse.lab.realism_takes import compare_take
from kinefuse.sim.tracker_params import TrackerParams

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
POPULATION = DATA / "kinect" / "kinect_multitrack_population"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--participants", default="0-9", help="A-B: fit on these participants")
    ap.add_argument("--rho", type=float, nargs="+", default=[0.0, 0.5, 0.7, 0.8, 0.9, 0.95])
    ap.add_argument("--population", type=Path, default=POPULATION)
    ap.add_argument("--smoke", action="store_true", help="participant 2, one candidate (seconds)")
    args = ap.parse_args()
    if args.smoke:
        args.participants, args.rho, args.seeds = "2-2", [0.5], 1
    lo, hi = (int(v) for v in args.participants.split("-"))
    takes = [
        t for t in sorted(args.population.glob("*.csv")) if lo <= int(t.name.split("_")[1]) <= hi
    ]
    if not takes:
        raise SystemExit(f"no takes of participants {lo}-{hi} in {args.population}")
    walk = load_walk(DATA / "motion" / "cmu" / "02_walk_a.amc")
    scores = {}
    for rho in args.rho:
        params = replace(TrackerParams(), limb_coherence=rho)
        results = [
            compare_take(t, walk, population_seeds(t.name, args.seeds), params=params)
            for t in takes
        ]
        summary = population_summary(results)
        cells, logs = [], []
        for layout, e in summary.items():
            a, m = e["median_limb_angle"], e["median_of_medians"]
            logs.append(abs(np.log(a["ratio"])))
            cells.append(
                f"{layout} deg: angle {a['real']:.2f} real / {a['simulated']:.2f} sim "
                f"({a['ratio']:.2f}), position median x{m['ratio']:.2f}"
            )
        scores[rho] = float(np.mean(logs))
        print(f"rho {rho:.2f}: " + "; ".join(cells) + f"; mean |log ratio| {scores[rho]:.3f}",
              flush=True)  # fmt: skip
    best = min(scores, key=lambda r: scores[r])
    print(f"\nbest of {args.rho} on participants {lo}-{hi} ({len(takes)} takes): rho {best:.2f}")


if __name__ == "__main__":
    main()

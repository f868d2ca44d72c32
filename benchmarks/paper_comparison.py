"""Paper A's comparison rerun: linear, geometric, nonlinear, paper and best on simulated
sessions of the real walking clips, with true calibration, and the ablation of best.

Run: ``python benchmarks/paper_comparison.py [--seeds 0 1 2]``. Prints Markdown tables and a
summary (the ones in docs/fusion.md). Reads the clips from ``../shared/data`` beside the project.
"""

from __future__ import annotations

import argparse
import tempfile
from itertools import pairwise
from pathlib import Path

from kinefuse.app import run_simulate
from kinefuse.fusion.session import METHODS, load_sensors
from kinefuse.io.store import SessionStore
from kinefuse.report.evaluate import ABLATION, evaluate

ROOT = Path(__file__).resolve().parents[1]
CLIPS = ("02_walk_a.amc", "02_walk_b.amc", "131_01_scaled_metres.bvh")
RIGS = ("level4", "tiered4")
ORDERINGS = {
    "paper < geometric < linear": ("paper", "geometric", "linear"),
    "geometric < linear": ("geometric", "linear"),
    "nonlinear < linear": ("nonlinear", "linear"),
    "nonlinear < geometric": ("nonlinear", "geometric"),
}


def session_report(clip: Path, rig: str, seed: int, folder: Path) -> dict:
    out = folder / f"{clip.name}_{rig}_{seed}.sqlite"
    run_simulate(clip=clip, out=out, rig=ROOT / "rigs" / f"{rig}.toml", seed=seed,
                 calibration_s=0.0)  # fmt: skip
    with SessionStore.open(out) as st:
        poses = {s.id: st.truth().sensor(s.id)[0] for s in st.sensors()}
        report, _, _ = evaluate(st, load_sensors(st, poses), METHODS)
    return report


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    args = ap.parse_args()
    data = ROOT.parent / "shared" / "data" / "motion" / "cmu"
    rows, abl_rows, gains = [], [], []
    counts = dict.fromkeys(ORDERINGS, 0)
    with tempfile.TemporaryDirectory() as d:
        for seed in args.seeds:
            for clip in CLIPS:
                for rig in RIGS:
                    report = session_report(data / clip, rig, seed, Path(d))
                    mae = {m: 100 * report[m]["mae_m"] for m in METHODS}
                    for name, order in ORDERINGS.items():
                        counts[name] += all(mae[a] < mae[b] for a, b in pairwise(order))
                    gains.append(100 * (1 - mae["best"] / mae["paper"]))
                    cells = " | ".join(f"{mae[m]:.1f}" for m in METHODS)
                    held = "yes" if mae["paper"] < mae["geometric"] < mae["linear"] else "no"
                    rows.append(
                        f"| {seed} | {clip} | {rig} | {cells} | {held} | {gains[-1]:.0f} % |"
                    )
                    abl = " | ".join(
                        f"{report['ablation'][p]['gain_percent']:+.1f} %" for p in ABLATION
                    )
                    abl_rows.append(f"| {seed} | {clip} | {rig} | {abl} |")
    n = len(rows)
    print("MAE in cm (true calibration, 4 sensors)\n")
    print("| seed | clip | rig | " + " | ".join(METHODS) + " | paper < geometric < linear "
          "| best vs paper |")  # fmt: skip
    print("|---|---|---|" + "---|" * (len(METHODS) + 2))
    print("\n".join(rows))
    print("\nAblation of best: MAE increase when the part is switched off\n")
    print("| seed | clip | rig | " + " | ".join(ABLATION) + " |")
    print("|---|---|---|" + "---|" * len(ABLATION))
    print("\n".join(abl_rows))
    print(f"\nSummary over {n} sessions:\n")
    for name, k in counts.items():
        print(f"- {name}: {k} of {n}")
    print(f"- best below paper by {min(gains):.0f} to {max(gains):.0f} %")


if __name__ == "__main__":
    main()

"""Paper A's comparison rerun: linear, geometric, nonlinear, paper and best on simulated
sessions of the real walking clips, with true calibration, and the ablation of best.

Run: ``python benchmarks/paper_comparison.py [--seed K]``. Prints Markdown tables (the ones in
docs/fusion.md). Reads the clips from ``../shared/data`` beside the project.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from kinefuse.app import run_simulate
from kinefuse.fusion.session import METHODS, load_sensors
from kinefuse.io.store import SessionStore
from kinefuse.report.evaluate import ABLATION, evaluate

ROOT = Path(__file__).resolve().parents[1]
CLIPS = ("02_walk_a.amc", "02_walk_b.amc", "131_01_scaled_metres.bvh")
RIGS = ("level4", "tiered4")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    data = ROOT.parent / "shared" / "data" / "motion" / "cmu"
    rows, abl_rows = [], []
    with tempfile.TemporaryDirectory() as d:
        for clip in CLIPS:
            for rig in RIGS:
                out = Path(d) / f"{clip}_{rig}.sqlite"
                run_simulate(clip=data / clip, out=out, rig=ROOT / "rigs" / f"{rig}.toml",
                             seed=args.seed, calibration_s=0.0)  # fmt: skip
                with SessionStore.open(out) as st:
                    poses = {s.id: st.truth().sensor(s.id)[0] for s in st.sensors()}
                    report, _, _ = evaluate(st, load_sensors(st, poses), METHODS)
                mae = {m: 100 * report[m]["mae_m"] for m in METHODS}
                order = mae["paper"] < mae["geometric"] < mae["linear"]
                gain = 100 * (1 - mae["best"] / mae["paper"])
                rows.append(
                    f"| {clip} | {rig} | "
                    + " | ".join(f"{mae[m]:.1f}" for m in METHODS)
                    + f" | {'yes' if order else 'no'} | {gain:.0f} % |"
                )
                abl_rows.append(
                    f"| {clip} | {rig} | "
                    + " | ".join(
                        f"{report['ablation'][p]['gain_percent']:+.1f} %" for p in ABLATION
                    )
                    + " |"
                )
    print(f"MAE in cm (seed {args.seed}, true calibration, 4 sensors)\n")
    print(
        "| clip | rig | " + " | ".join(METHODS) + " | paper < geometric < linear | best vs paper |"
    )
    print("|---|---|" + "---|" * (len(METHODS) + 2))
    print("\n".join(rows))
    print("\nAblation of best: MAE increase when the part is switched off\n")
    print("| clip | rig | " + " | ".join(ABLATION) + " |")
    print("|---|---|" + "---|" * len(ABLATION))
    print("\n".join(abl_rows))


if __name__ == "__main__":
    main()

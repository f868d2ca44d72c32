"""Paper A's comparison rerun: linear, geometric, nonlinear, paper and best on simulated
sessions of the real walking clips, with true calibration, and the ablation of best.

Run: ``python studies/paper_comparison.py [--seeds 0 1 2] [--clips ...] [--rigs ...] [--smoke]``
(``--smoke``: one session, to check that it runs). Prints Markdown tables and a summary (the ones
in docs/fusion.md). Reads the clips from ``../shared/data`` beside the project.

Every gain comes with a 95 % interval (paired block bootstrap over frames,
:func:`kinefuse.lab.metrics.gain_ci`): a difference whose interval holds 0 is one the
session cannot tell from chance. Three parts:

1. the methods and the ablation of ``best`` on the sessions as simulated;
2. the ablation of ``best``'s robust step when one sensor was bumped after calibration (its
   pose in the calibration is off by ``BUMP_DEG`` of yaw and ``BUMP_M`` sideways), the fault
   that step is there for;
3. the range-only solvers under the paper's own error model (Table I: the true ranges plus
   uniform errors of a given size, no Kinect at all), to show what the algorithms do by
   themselves.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from kinefuse.app.workflows.simulate import run_simulate
from kinefuse.capture.fusion.best import BestOptions
from kinefuse.capture.fusion.methods import METHODS
from kinefuse.capture.fusion.trilateration import solve_geometric, solve_linear, solve_nonlinear
from kinefuse.core.geometry.rotations import rot_z
from kinefuse.core.geometry.transforms import make_transform
from kinefuse.formats.motion import load_motion
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.lab.fusion_truth import ABLATION, COMPARISONS, evaluate, truth_at
from kinefuse.lab.metrics import gain_ci
from kinefuse.pipeline.store_inputs import frame_grid, load_sensors, run_method
from kinefuse.sim.rig import load_rig, place_actor

ROOT = Path(__file__).resolve().parents[1]
CLIPS = ("02_walk_a.amc", "02_walk_b.amc", "131_01_scaled_metres.bvh")
RIGS = ("level4", "tiered4")
BUMP_DEG, BUMP_M = 5.0, 0.10
NOISE_M = (0.01, 0.03, 0.05)


def _ci(v: dict) -> str:
    low, high = v["gain_ci95_percent"]
    return f"{v['gain_percent']:+.1f} [{low:+.1f}, {high:+.1f}]"


def _verdict(v: dict) -> int:
    """+1 significant gain, -1 significant loss, 0 undecided."""
    low, high = v["gain_ci95_percent"]
    return 1 if low > 0 else (-1 if high < 0 else 0)


def bumped_robust_gain(store: SessionStore) -> dict:
    """The robust step's gain when the first sensor's calibrated pose is off."""
    poses = {s.id: store.truth().sensor(s.id)[0].copy() for s in store.sensors()}
    first = store.sensors()[0].id
    bump = make_transform(rot_z(np.radians(BUMP_DEG)), [BUMP_M, 0.0, 0.0])
    poses[first] = bump @ poses[first]
    sensors = load_sensors(store, poses)
    grid = frame_grid(sensors)
    truth = truth_at(store, grid)
    keep = np.isfinite(truth).all((1, 2))
    grid, truth = grid[keep], truth[keep]
    on = run_method(sensors, grid, "best").positions
    off = run_method(sensors, grid, "best", best_options=BestOptions(robust=False)).positions
    gain, low, high = gain_ci(on, off, truth)
    return {"gain_percent": gain, "gain_ci95_percent": [low, high]}


def sessions(
    seeds: list[int],
    data: Path,
    folder: Path,
    clips: tuple[str, ...] | list[str] = CLIPS,
    rigs: tuple[str, ...] | list[str] = RIGS,
) -> list[tuple[int, str, str, dict, dict]]:
    out = []
    for seed in seeds:
        for clip in clips:
            for rig in rigs:
                path = folder / f"{clip}_{rig}_{seed}.sqlite"
                run_simulate(clip=data / clip, out=path, rig=ROOT / "rigs" / f"{rig}.toml",
                             seed=seed, calibration_s=0.0)  # fmt: skip
                with SessionStore.open(path) as st:
                    poses = {s.id: st.truth().sensor(s.id)[0] for s in st.sensors()}
                    report, _, _ = evaluate(st, load_sensors(st, poses), METHODS)
                    bumped = bumped_robust_gain(st)
                out.append((seed, clip, rig, report, bumped))
    return out


def paper_error_model(data: Path, seed: int = 0) -> list[str]:
    """MAE (cm) of the range-only solvers on the true ranges plus uniform errors."""
    rng = np.random.default_rng(seed)
    rows = []
    for rig_name in ("level4", "tiered4", "tilted4"):
        rig = load_rig(ROOT / "rigs" / f"{rig_name}.toml")
        centres = np.array([s.sensor2world[:3, 3] for s in rig.sensors])
        motion = place_actor(load_motion(data / "02_walk_b.amc"), rig, None)
        truth = motion.positions.reshape(-1, 3)
        true_r = np.linalg.norm(truth[:, None] - centres[None], axis=-1)
        for e in NOISE_M:
            ranges = true_r + rng.uniform(-e, e, true_r.shape)
            hint = truth + rng.normal(0.0, 0.03, truth.shape)  # a 3D hint for the mirror side
            sols = {
                "linear (lstsq, the paper's)": solve_linear(
                    centres, ranges, hint, out_of_plane="lstsq"
                ),
                "linear (shipped)": solve_linear(centres, ranges, hint),
                "geometric": solve_geometric(centres, ranges, hint),
                "nonlinear": solve_nonlinear(centres, ranges, hint),
            }
            cells = [
                f"{100 * np.nanmean(np.linalg.norm(s.positions - truth, axis=1)):.1f}"
                for s in sols.values()
            ]
            rows.append(f"| {rig_name} | +/-{100 * e:.0f} | " + " | ".join(cells) + " |")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--clips", nargs="+", default=list(CLIPS))
    ap.add_argument("--rigs", nargs="+", default=list(RIGS))
    ap.add_argument("--smoke", action="store_true", help="one session (seconds to run)")
    args = ap.parse_args()
    if args.smoke:
        args.seeds, args.clips, args.rigs = [0], [CLIPS[0]], [RIGS[0]]
    data = ROOT.parent / "shared" / "data" / "motion" / "cmu"
    with tempfile.TemporaryDirectory() as d:
        runs = sessions(args.seeds, data, Path(d), args.clips, args.rigs)
    n = len(runs)

    print("MAE in cm (true calibration, 4 sensors)\n")
    print("| seed | clip | rig | " + " | ".join(METHODS) + " | paper < geometric < linear |")
    print("|---|---|---|" + "---|" * (len(METHODS) + 1))
    held = 0
    for seed, clip, rig, rep, _ in runs:
        mae = {m: 100 * rep[m]["mae_m"] for m in METHODS}
        ok = mae["paper"] < mae["geometric"] < mae["linear"]
        held += ok
        cells = " | ".join(f"{mae[m]:.1f}" for m in METHODS)
        print(f"| {seed} | {clip} | {rig} | {cells} | {'yes' if ok else 'no'} |")

    print("\nMAE of a below b, % of b's, with its 95 % interval\n")
    pairs = [f"{a} vs {b}" for a, b in COMPARISONS]
    print("| seed | clip | rig | " + " | ".join(pairs) + " |")
    print("|---|---|---|" + "---|" * len(pairs))
    for seed, clip, rig, rep, _ in runs:
        cells = " | ".join(_ci(rep["comparisons"][p]) for p in pairs)
        print(f"| {seed} | {clip} | {rig} | {cells} |")

    print("\nAblation of best: MAE increase without the part, % of it, with its 95 % interval\n")
    print("| seed | clip | rig | " + " | ".join(ABLATION) + " | robust, sensor bumped |")
    print("|---|---|---|" + "---|" * (len(ABLATION) + 1))
    for seed, clip, rig, rep, bumped in runs:
        cells = " | ".join(_ci(rep["ablation"][p]) for p in ABLATION)
        print(f"| {seed} | {clip} | {rig} | {cells} | {_ci(bumped)} |")

    print(f"\nSummary over {n} sessions (significant: the 95 % interval excludes 0):\n")
    print(f"- paper < geometric < linear (point estimates): {held} of {n}")
    for p in pairs:
        v = [_verdict(rep["comparisons"][p]) for *_, rep, _ in runs]
        g = [rep["comparisons"][p]["gain_percent"] for *_, rep, _ in runs]
        print(
            f"- {p}: lower on {sum(x > 0 for x in g)} of {n} ({min(g):+.0f} to {max(g):+.0f} %);"
            f" significantly lower on {v.count(1)}, significantly higher on {v.count(-1)}"
        )
    for part in ABLATION:
        v = [_verdict(rep["ablation"][part]) for *_, rep, _ in runs]
        g = [rep["ablation"][part]["gain_percent"] for *_, rep, _ in runs]
        print(f"- part {part}: {min(g):+.1f} to {max(g):+.1f} %; significant gain on "
              f"{v.count(1)} of {n}, significant loss on {v.count(-1)}")  # fmt: skip
    v = [_verdict(b) for *_, b in runs]
    g = [b["gain_percent"] for *_, b in runs]
    print(f"- part robust, one sensor's pose off by {BUMP_DEG:g} deg and {100 * BUMP_M:g} cm: "
          f"{min(g):+.1f} to {max(g):+.1f} %; significant gain on {v.count(1)} of {n}, "
          f"significant loss on {v.count(-1)}")  # fmt: skip

    print("\nThe paper's own error model: true ranges + uniform errors, 02_walk_b joints, MAE cm\n")
    print("| rig | range error cm | linear (lstsq, the paper's) | linear (shipped) | geometric | "
          "nonlinear |\n|---|---|---|---|---|---|")  # fmt: skip
    print("\n".join(paper_error_model(data)))


if __name__ == "__main__":
    main()

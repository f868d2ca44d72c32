"""How the fusion's ``limb_correlation`` was chosen: the takes of ``studies/analysis_accuracy.py
accuracy --save DIR`` (one folder per subject) fused again with each value.

    python studies/limb_correlation.py DIR [DIR ...] [--values 0 0.3 0.5 0.7 0.85]
        [--rom-s 120] [--static-s 10] [--wand-s 15]

(each DIR's subject seed is read from its name's trailing digits, ``.../s3`` -> ``--seed 3``, as
the ``accuracy`` run that saved it; the other options are that run's, its defaults here). Per
value, over every take and side and the benchmark's walk frames: the mean joint error against
the floor (the truth plus the subject's joint offsets, what a perfect fusion gives; all joints
and the hips, knees and ankles), and the RMSE of the knee's included angle (180 degrees minus
hip-knee-ankle) and of the hip's (thigh against SpineBase -> SpineMid) against the truth's.
docs/fusion.md section 13. About 2 s per take and value.
``--smoke``: makes one small ``accuracy --save`` folder first and reads it (CI runs it).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from analysis_accuracy import saved_takes_arguments, saved_takes_of
from kinefuse.capture.fusion.options import BestOptions
from kinefuse.core.skeleton import JOINT_INDEX
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.lab.poses import resolve_poses
from kinefuse.pipeline.analysis_chain import hinge_angle_deg
from kinefuse.pipeline.store_inputs import frame_grid, load_sensors, run_method

ROOT = Path(__file__).resolve().parents[1]

LEGS = [JOINT_INDEX[f"{j}{s}"] for j in ("Hip", "Knee", "Ankle") for s in ("Left", "Right")]


def _hip_angle_deg(x: np.ndarray, side: str) -> np.ndarray:
    thigh = x[:, JOINT_INDEX[f"Knee{side}"]] - x[:, JOINT_INDEX[f"Hip{side}"]]
    trunk = x[:, JOINT_INDEX["SpineMid"]] - x[:, JOINT_INDEX["SpineBase"]]
    c = (thigh * trunk).sum(-1) / np.linalg.norm(thigh, axis=-1) / np.linalg.norm(trunk, axis=-1)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def _rmse(e: np.ndarray) -> float:
    return float(np.sqrt(np.nanmean(e**2)))


def take_figures(path: Path, walk: tuple[float, float], values: list[float]) -> list[list[float]]:
    """Per value: joint MAE (all, legs) in cm, then the knee and hip angle RMSE per side."""
    z = np.load(path.with_suffix(".npz"))
    t, truth, floor = z["t_s"], z["truth"], z["floor"]
    frames = (t >= walk[0]) & (t <= walk[1])
    with SessionStore.open(path) as store:
        poses, _ = resolve_poses(store, None, False)
        sensors = load_sensors(store, poses)
    grid = frame_grid(sensors)
    out = []
    for rho in values:
        res = run_method(sensors, grid, "best",
                         best_options=replace(BestOptions(), limb_correlation=rho))  # fmt: skip
        if not np.array_equal(res.t_server_s, t):
            raise SystemExit(f"{path}: the fusion's frames are not the saved ones")
        x = res.positions
        gap = np.linalg.norm(x[frames] - floor[frames], axis=-1)
        row = [100 * float(np.nanmean(gap)), 100 * float(np.nanmean(gap[:, LEGS]))]
        for side in ("Left", "Right"):
            knee = (f"Hip{side}", f"Knee{side}", f"Ankle{side}")
            row.append(_rmse((hinge_angle_deg(x, *knee) - hinge_angle_deg(truth, *knee))[frames]))
            row.append(_rmse((_hip_angle_deg(x, side) - _hip_angle_deg(truth, side))[frames]))
        out.append(row)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    saved_takes_arguments(ap)
    ap.add_argument("--values", type=float, nargs="+", default=[0.0, 0.3, 0.5, 0.7, 0.85])
    args = ap.parse_args()
    rows: list[list[list[float]]] = []
    for path, walk in saved_takes_of(args):
        rows.append(take_figures(path, walk, args.values))
        print(f"{path}: done", file=sys.stderr, flush=True)
    a = np.array(rows)  # (takes, values, 6)
    print(f"{a.shape[0]} takes, walk frames; angles against the truth's, joints against the floor")
    print("| limb_correlation | joint MAE cm (hips, knees, ankles) | knee angle RMSE mean (sides "
          "under 8°) | hip angle RMSE mean |")  # fmt: skip
    print("|---|---|---|---|")
    for i, rho in enumerate(args.values):
        knee, hip = a[:, i, [2, 4]].ravel(), a[:, i, [3, 5]].ravel()
        print(f"| {rho:g} | {a[:, i, 0].mean():.3f} ({a[:, i, 1].mean():.3f}) | {knee.mean():.2f}° "
              f"({int((knee < 8).sum())} of {knee.size}) | {hip.mean():.2f}° |")  # fmt: skip


if __name__ == "__main__":
    main()

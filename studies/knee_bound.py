"""How far the fused knee angle is from what any fixed weighting of the sensors' own knee angles
could reach, on the takes of ``studies/analysis_accuracy.py accuracy --save DIR``.

    python studies/knee_bound.py DIR [--rom-s 120] [--seed 0] [--static-s 10]
        [--wand-s 15]

(the options those of the ``accuracy`` run that saved DIR; its defaults here). Per take and
side, over the benchmark's walk frames: the RMSE against the truth of the knee's included angle
(180° minus hip-knee-ankle, frame-free) of the fused skeleton, of each sensor's own skeleton
(its stream interpolated to the fused frame times, any tracking state, left and right exchanged
where the fusion's swap vote mirrored that sensor back: the sensors as the fusion reads them),
of the mean and the
median of the sensors' angles, and of the best fixed weighting of the sensors' angles (weights
summing to 1, chosen *with the truth*: the minimum-variance combination of the sensors' errors
over the frames every sensor has). That last one is an oracle no fusion has; a fusion that
stays near it is using what the sensors' angles hold. docs/analysis_measured.md, the fused
walk's history.
About 20 s per take (each is fused again for its swap decisions).
``--smoke``: makes one small ``accuracy --save`` folder first and reads it (CI runs it).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from analysis_accuracy import SMOKE_TAKES, calibration_motion, smoke_takes
from kinefuse.capture.sync.assembly import interpolate
from kinefuse.core.skeleton import MIRROR_INDEX
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.lab.poses import resolve_poses
from kinefuse.pipeline.analysis_chain import hinge_angle_deg
from kinefuse.pipeline.store_inputs import frame_grid, load_sensors, run_method

ROOT = Path(__file__).resolve().parents[1]

SIDES = {
    "left": ("HipLeft", "KneeLeft", "AnkleLeft"),
    "right": ("HipRight", "KneeRight", "AnkleRight"),
}


def _rmse(e: np.ndarray) -> float:
    return float(np.sqrt(np.nanmean(e**2)))


def take_bound(folder: Path, k: int, walk: tuple[float, float]) -> list[str]:
    z = np.load(folder / f"take{k}.npz")
    t, fused, truth = z["t_s"], z["fused"], z["truth"]
    err = np.nanmean(np.linalg.norm(fused - truth, axis=-1), 1)
    frames = (t >= walk[0]) & (t <= walk[1]) & (err < 0.2)  # as the benchmark's walk frames
    with SessionStore.open(folder / f"take{k}.sqlite") as store:
        poses, _ = resolve_poses(store, None, False)
        sensors = load_sensors(store, poses)
    res = run_method(sensors, frame_grid(sensors), "best")  # the saved take's fusion, again
    if not np.array_equal(res.t_server_s, t):
        raise SystemExit(f"{folder}/take{k}: the fusion's frames are not the saved ones")
    views = []
    for si, s in enumerate(sensors):
        x = interpolate(s.t_server_s, s.observations.joints_m, t[frames])
        flip = res.mirrored[frames, si]
        x[flip] = x[flip][:, list(MIRROR_INDEX)]
        views.append(x)
    lines = []
    for side, (h, kn, a) in SIDES.items():
        true = hinge_angle_deg(truth, h, kn, a)[frames]
        e_fused = hinge_angle_deg(fused, h, kn, a)[frames] - true
        own = np.array([hinge_angle_deg(x, h, kn, a) - true for x in views])
        with np.errstate(all="ignore"):
            e_mean, e_median = np.nanmean(own, 0), np.nanmedian(own, 0)
        every = np.isfinite(own).all(0)
        c = own[:, every] @ own[:, every].T / max(int(every.sum()), 1)
        w = np.linalg.solve(c, np.ones(len(c)))
        w /= w.sum()
        oracle = float(np.sqrt(w @ c @ w))
        fused_every = _rmse(e_fused[every])
        per = " ".join(f"{_rmse(o):.1f}" for o in own)
        lines.append(
            f"take{k} {side:5s}: fused {_rmse(e_fused):5.2f}° | sensors' own {per} | mean "
            f"{_rmse(e_mean):5.2f} median {_rmse(e_median):5.2f} | frames every sensor has "
            f"({100 * every.mean():.0f} %): fused {fused_every:5.2f}, best fixed weights "
            f"{oracle:5.2f} (w {' '.join(f'{x:+.2f}' for x in w)})"
        )
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    ap.add_argument("folder", type=Path, nargs="?",
                    help="a folder written by analysis_accuracy.py accuracy --save")  # fmt: skip
    ap.add_argument("--smoke", action="store_true", help="make one small folder first and read it")
    ap.add_argument("--rom-s", type=float, default=120.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--static-s", type=float, default=10.0)
    ap.add_argument("--wand-s", type=float, default=15.0)
    args = ap.parse_args()
    if args.smoke:
        (args.folder,) = smoke_takes()
        args.rom_s, args.static_s, args.wand_s = (
            SMOKE_TAKES[k] for k in ("rom_s", "static_s", "wand_s")
        )
    if args.folder is None:
        ap.error("give a folder that `analysis_accuracy.py accuracy --save DIR` wrote, or --smoke")
    takes = sorted(int(p.stem[4:]) for p in args.folder.glob("take*.npz"))
    if not takes:
        raise SystemExit(f"{args.folder}: no take*.npz (run analysis_accuracy.py accuracy --save)")
    _, _, _, _, w, _ = calibration_motion(args.rom_s, args.seed, args.static_s)
    walk = (args.wand_s + w[0], args.wand_s + w[1])
    print("knee included angle RMSE vs the truth over the walk, degrees")
    for k in takes:
        for line in take_bound(args.folder, k, walk):
            print(line, flush=True)


if __name__ == "__main__":
    main()

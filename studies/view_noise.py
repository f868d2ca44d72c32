"""The view-dependent measurement noise (``BestOptions.view_*``, ``far_*``) on one simulated take.

Run: ``python studies/view_noise.py [--rig default4] [--heading 20] [--seed 11] [--variants
"0,4,0,4;0.1,4,0.05,4"] [--smoke]`` (``--smoke``: a 55 s ROM phase after a 6 s wand phase instead of
120 s after 15 s, to check that it runs). Simulates one take like those of ``analysis_accuracy.py
accuracy`` (the same clip, a range-of-motion phase before the walk, the full calibration from the
wand) on the given rig, heading and seed, then fuses it with ``best`` once per variant
(``view_sigma_m,view_exponent,far_sigma_m,far_exponent``; default: off, then the shipped defaults)
and prints the mean joint error (ROM phase and walk) and the walk's hip and knee flexion RMSE
against the truth. The default take (default4 rig, heading 20 deg, seed 11, subject seed 11) is the
one the defaults were chosen on (docs/fusion.md section 9); ``analysis_accuracy.py accuracy`` (seeds
0-2, headings 0, 120, -75) and ``live_vs_offline.py`` validate them.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from analysis_accuracy import CLIP, ROOT, _resample, simulate_take
from kinefuse import biomech as an
from kinefuse.biomech.kinematics import joint_angles
from kinefuse.biomech.parameterize import learn_axes
from kinefuse.biomech.rom import make_rom_motion, prepend_rom
from kinefuse.biomech.side_consistency import angle_rmse_deg
from kinefuse.capture.fusion.best import BestOptions
from kinefuse.core.frames.motion import Motion
from kinefuse.formats.motion import load_motion

_ANGLES = ("hip_flexion_left", "hip_flexion_right", "knee_flexion_left", "knee_flexion_right")


def _take(rig_name: str, heading: float, seed: int, subject_seed: int, path: Path,  # type: ignore[no-untyped-def]
          rom_s: float = 120.0, cal_s: float = 15.0):  # fmt: skip
    from kinefuse.sim.rig import default_rig, load_rig

    clip = load_motion(CLIP)
    d = an.find_default_pose(an.SkeletonSequence.from_motion(clip))
    rom, _ = make_rom_motion(clip.positions[d], rom_s, np.random.default_rng(seed), rate_hz=60.0)
    combined = prepend_rom(rom, clip, blend_s=1.0)
    walk = (rom.duration_s + 1.0, combined.duration_s)
    hold = np.repeat(combined.positions[-1:], int(2.0 * combined.rate_hz), axis=0)
    combined = Motion(np.concatenate([combined.positions, hold]), combined.rate_hz, source="x")
    phase = (cal_s, cal_s + rom.duration_s)
    walk = (cal_s + walk[0], cal_s + walk[1])
    base = (
        default_rig(4) if rig_name == "default4" else load_rig(ROOT / "rigs" / f"{rig_name}.toml")
    )
    rig = replace(base, actor_heading_deg=heading)
    _, true_seq, _, _ = simulate_take(rig, combined, path, seed, cal_s, subject_seed)
    return true_seq, phase, walk


def _fuse(path: Path, options: BestOptions) -> an.SkeletonSequence:
    from kinefuse.formats.store.session_store import SessionStore
    from kinefuse.lab.poses import resolve_poses
    from kinefuse.pipeline.store_inputs import frame_grid, load_sensors, run_method

    with SessionStore.open(path) as store:
        poses, _ = resolve_poses(store, None, False)
        sensors = load_sensors(store, poses)
        res = run_method(sensors, frame_grid(sensors), "best", best_options=options)
    return an.SkeletonSequence.from_kinect(res.positions, t_s=res.t_server_s, source="fused")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rig", default="default4", choices=("default4", "tiered4", "tilted4"))
    ap.add_argument("--heading", type=float, default=20.0, help="actor heading, degrees")
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--subject-seed", type=int, default=11)
    ap.add_argument(
        "--variants",
        default="0,4,0,4;0.1,4,0.05,4",
        help="';'-separated view_sigma_m,view_exponent,far_sigma_m,far_exponent",
    )
    ap.add_argument("--rom-s", type=float, default=120.0, help="range-of-motion phase, s")
    ap.add_argument("--wand-s", type=float, default=15.0, help="wand phase before it, s")
    ap.add_argument("--smoke", action="store_true", help="a short take (seconds to run)")
    args = ap.parse_args()
    if args.smoke:
        args.rom_s, args.wand_s = 55.0, 6.0
    variants = [tuple(float(x) for x in v.split(",")) for v in args.variants.split(";") if v]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "take.sqlite"
        t0 = time.perf_counter()
        true_seq, phase, walk = _take(
            args.rig, args.heading, args.seed, args.subject_seed, path, args.rom_s, args.wand_s
        )
        took = time.perf_counter() - t0
        print(f"take: {CLIP.name}, rig {args.rig}, heading {args.heading:g} deg, seed "
              f"{args.seed}, subject seed {args.subject_seed} ({took:.0f} s)")  # fmt: skip
        print("| view sigma m | view exp | far sigma m | far exp | ROM err cm | walk err cm | "
              "hip flex L/R deg | knee flex L/R deg |")  # fmt: skip
        print("|---|---|---|---|---|---|---|---|")
        ang_t = None
        for vs, vp, fs, fp in variants:
            opt = BestOptions(view_sigma_m=vs, view_exponent=vp, far_sigma_m=fs, far_exponent=fp)
            fused = _fuse(path, opt)
            truth = _resample(true_seq, fused.t_s)
            if ang_t is None:
                norm_t = an.normalize(truth)
                ang_t = joint_angles(truth, norm_t, learn_axes(truth, norm_t, phase, method="dj"))
            e = np.linalg.norm(fused.positions - truth.positions, axis=-1)
            err = np.nanmean(e, 1)
            in_walk = (fused.t_s >= walk[0]) & (fused.t_s <= walk[1])
            wf = np.flatnonzero(in_walk & (err < 0.2))
            rf = np.flatnonzero((fused.t_s >= phase[0]) & (fused.t_s <= phase[1]))
            norm = an.normalize(fused)
            ang = joint_angles(fused, norm, learn_axes(fused, norm, phase, method="dj"))
            rm = angle_rmse_deg(ang.anatomical(), ang_t.anatomical(), frames=wf)
            a = [rm.get(k, np.nan) for k in _ANGLES]
            print(f"| {vs:g} | {vp:g} | {fs:g} | {fp:g} | {100 * np.nanmean(e[rf]):.2f} | "
                  f"{100 * np.nanmean(e[wf]):.2f} | {a[0]:.1f}/{a[1]:.1f} | "
                  f"{a[2]:.1f}/{a[3]:.1f} |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()

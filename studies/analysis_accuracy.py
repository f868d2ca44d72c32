"""Analysis (paper B): speed against a per-frame implementation, and accuracy through the lab.

    python studies/analysis_accuracy.py speed [--frames 24000] [--repeat 3]
    python studies/analysis_accuracy.py accuracy [--rom-s 120] [--seed 0] [--takes 3] [--json F]
        [--no-subject-bias] [--errors-off PART[,PART]] [--save DIR]
    python studies/analysis_accuracy.py floor [--subjects 10] [--segment-fixed] [--json F]
    python studies/analysis_accuracy.py --smoke [MODE]

``--smoke``: every mode (or MODE) on tiny inputs, through the same code, to check that it runs
(seconds; the figures are then not the ones to quote).

``speed``: a full body (13 limbs) normalized and parameterized (angles and twist) for 24,000
frames on one core, against a straightforward per-frame implementation of the same math
(one frame at a time, the way the paper's 1.17 ms/frame loop runs), measured in the same run on
the first frames and extrapolated per frame; both must give the same angles.

``accuracy``: the whole chain. A range-of-motion calibration phase is generated on the default
pose of a real clip (CMU 131_01, start-walk-stop), put before that clip, watched by 4 simulated
Kinect v2 sensors (``kinefuse.sim.lab``), the sensors are calibrated from the wand
(``full``), the skeleton is fused (``best``) and analysed as ``kinefuse analyze`` does (the axes
from each limb's movement where two or more sensors tracked it). Measured: the axis error of
Direction Joining, PCA and EM side by side (against the generator's true axes), the
reconstruction error from the parameters, the twist error and the joint angles of the walk
against the same analysis of the true motion, and the normalization consistency over ``--takes``
takes with different rigs and headings (takes of one subject: one ``subject_seed``). Simulated
sessions go to a temporary folder.

Each take is also analysed from its *floor* input: the truth plus the subject-level tracker bias
alone (the joint-definition offsets every sensor shares, so no fusion can remove them), which is
what a perfect fusion would deliver. ``--no-subject-bias`` simulates a tracker without that bias
instead: what the rest of the error model leaves to the chain. ``--errors-off`` switches parts of
the tracker's error model off as ``kinefuse simulate --errors-off`` does, the same sessions
simulated without them: ``independent`` (every error a sensor makes on its own) leaves what the
sensors share, which no weighting of them removes.

``floor``: no sensors, no fusion: the same calibration phase and walk, the truth plus the
subject-level tracker bias of ``--subjects`` simulated subjects (``subject_seed`` 0, 1, ...,
drawn as the lab draws them), analysed as a fused take is. This is what a perfect fusion would
deliver for each subject: the axis errors of DJ, PCA and EM, the twist error and the walk's
knee and hip flexion RMSE. ``--segment-fixed`` holds each joint's offset in the frame of the
limb it ends instead of the body frame (the lab's model), to see how much the conclusion
depends on that assumption.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")  # one core, as the target says

import argparse  # noqa: E402
import json  # noqa: E402
import re  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from kinefuse import biomech as an  # noqa: E402
from kinefuse.app.cli.args import error_parts  # noqa: E402
from kinefuse.biomech.kinematics import joint_angles, reconstruction_error  # noqa: E402
from kinefuse.biomech.normalize import BODY_JOINTS  # noqa: E402
from kinefuse.biomech.parameterize import learn_axes  # noqa: E402
from kinefuse.biomech.rom import make_rom_motion, prepend_rom  # noqa: E402
from kinefuse.biomech.side_consistency import (  # noqa: E402
    angle_rmse_deg,
    axis_errors_deg,
    normalization_consistency,
    true_axes_in_normalization,
    twist_errors_deg,
)
from kinefuse.core.frames.motion import Motion  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
METHODS = ("dj", "pca", "em")
CLIP = ROOT.parent / "shared" / "data" / "motion" / "cmu" / "131_01_scaled_metres.bvh"


# ----------------------------------------------------------------------------- accuracy
def _kabsch_rot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ca, cb = a - a.mean(0), b - b.mean(0)
    u, _, vt = np.linalg.svd(cb.T @ ca)
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1, 1, d]) @ vt


def simulate_take(rig, combined, out: Path, seed: int, cal_s: float, subject_seed: int,  # type: ignore[no-untyped-def]
                  errors_off: tuple[str, ...] = (), keep: dict | None = None):  # type: ignore[type-arg]  # fmt: skip
    """Simulate, calibrate (full), fuse (best); return the fused and true sequences, the
    placement, and the truth plus the subject-level tracker bias only (what every sensor shares,
    so no fusion can remove it: the floor of a perfect fusion). ``keep``: a dict that gets the
    calibrated sensors and the frame grid (``"sensors"``, ``"grid"``), to fuse them again, and
    the frames in which two or more sensors tracked each limb (``"seen"`` ``(T, L)``, as
    ``kinefuse analyze`` counts them: its axes are learned from those). ``errors_off``: parts
    of the tracker's error model switched off (``kinefuse.sim.tracker_params.ERROR_PARTS``)."""
    from kinefuse.app.workflows.calibrate import run_calibrate
    from kinefuse.formats.store.session_store import SessionStore
    from kinefuse.lab.fusion_truth import calibration_alignment
    from kinefuse.lab.poses import resolve_poses
    from kinefuse.pipeline.analysis_chain import SEEN_MIN_SENSORS, fused_limb_counts
    from kinefuse.pipeline.store_inputs import frame_grid, load_sensors, run_method
    from kinefuse.sim.lab import LabConfig, _seeds, simulate_session
    from kinefuse.sim.rig import place_actor
    from kinefuse.sim.tracker_body import _body_axes
    from kinefuse.sim.tracker_params import without_parts

    placed = place_actor(combined, rig)
    rot = _kabsch_rot(combined.positions[0], placed.positions[0])
    config = LabConfig(seed=seed, calibration_s=cal_s, subject_seed=subject_seed)
    if errors_off:  # "subject": a tracker whose joint definitions are the truth's
        tracker = without_parts(config.errors.tracker, errors_off)
        config = replace(config, errors=replace(config.errors, tracker=tracker))
    simulate_session(placed, rig, out, config, overwrite=True)
    with SessionStore.open(out, writable=True) as store:  # a finished simulation
        store.mark_complete()
    run_calibrate(session=out, method="full", out=None, store_result=True)
    with SessionStore.open(out) as store:
        poses, _ = resolve_poses(store, None, False)
        sensors = load_sensors(store, poses)
        res = run_method(sensors, frame_grid(sensors), "best")
        if keep is not None:
            seen = fused_limb_counts(sensors, res) >= SEEN_MIN_SENSORS
            keep.update(sensors=sensors, grid=res.t_server_s, seen=seen)
        t_true, joints, _ = store.truth().motion()
        truth2world, _ = calibration_alignment(store, poses)
    # the truth in the calibration's world (the calibration sets its own origin and heading)
    joints = joints @ truth2world[:3, :3].T + truth2world[:3, 3]
    offsets = _seeds(seed, len(rig.sensors), config).subject.offsets_body_m
    up = truth2world[:3, :3] @ np.array([0.0, 0.0, 1.0])
    floor = joints + np.einsum("tik,jk->tji", _body_axes(joints, up), offsets)
    fused = an.SkeletonSequence.from_kinect(res.positions, t_s=res.t_server_s, source="fused")
    truth = an.SkeletonSequence.from_kinect(joints, t_s=t_true, source="truth")
    floor_seq = an.SkeletonSequence.from_kinect(floor, t_s=t_true, source="truth + subject bias")
    return fused, truth, floor_seq, truth2world[:3, :3] @ rot


def world_axis_errors(model, norm, true_world, frame):  # type: ignore[no-untyped-def]
    """Learned axes taken into the world by the fused parent frame at ``frame`` (the rest pose
    at the start of the calibration phase) against the true axes there, degrees."""
    from kinefuse.biomech.limbs import LIMB_INDEX, LIMB_PARENTS

    vals = []
    for name, a in true_world.items():
        lm = model.limbs.get(name)
        if lm is None or lm.axes.shape[0] != a.shape[0]:
            continue
        w = (norm.frames[frame, LIMB_PARENTS[LIMB_INDEX[name]]] @ lm.axes.T).T
        vals += np.degrees(np.arccos(np.clip(np.abs((w * a).sum(-1)), 0, 1))).tolist()
    v = np.array(vals)
    return {"median": float(np.median(v)), "mean": float(v.mean())} if v.size else {}


def _resample(seq: an.SkeletonSequence, t_s: np.ndarray) -> an.SkeletonSequence:
    flat = seq.positions.reshape(seq.n_frames, -1)
    out = np.stack([np.interp(t_s, seq.t_s, flat[:, k], np.nan, np.nan) for k in range(75)], -1)
    return an.SkeletonSequence.from_kinect(out.reshape(-1, 25, 3), t_s=t_s, source=seq.source)


def calibration_motion(rom_s: float, seed: int, static_s: float = 0.0):  # type: ignore[no-untyped-def]
    """The clip's default-pose frame, the ROM phase and its truth, the (standing +) ROM + walk +
    2 s hold motion and the walk's span (motion time, seconds). ``static_s``: a standing phase
    (static trial) of that many seconds before the ROM, as ``simulate --static`` makes it."""
    from kinefuse.biomech.rom import stand_before
    from kinefuse.formats.motion import load_motion

    clip = load_motion(CLIP)
    d = an.find_default_pose(an.SkeletonSequence.from_motion(clip))
    rng = np.random.default_rng(seed)
    rom, truth = make_rom_motion(clip.positions[d], rom_s, rng, rate_hz=60.0)
    combined = prepend_rom(rom, clip, blend_s=1.0)
    walk = (rom.duration_s + 1.0, combined.duration_s)
    lead = 0.0
    if static_s > 0:  # standing upright, a blend into the ROM's first pose, as simulate --static
        combined, _, lead = stand_before(combined, rom.positions[0], static_s,
                                         np.random.default_rng(seed + 1))  # fmt: skip
        walk = (walk[0] + lead, walk[1] + lead)
    # hold the last pose 2 s so that the end of the session (where the fused skeleton of the
    # last second goes astray) is not part of the walk
    hold = np.repeat(combined.positions[-1:], int(2.0 * combined.rate_hz), axis=0)
    combined = Motion(np.concatenate([combined.positions, hold]), combined.rate_hz,
                      source=combined.source + " + 2 s hold")  # fmt: skip
    return d, rom, truth, combined, walk, lead


def saved_takes_arguments(ap: argparse.ArgumentParser) -> None:
    """The arguments of a tool that reads ``accuracy --save`` folders (:func:`saved_takes`)."""
    ap.add_argument("folders", type=Path, nargs="*",
                    help="folders written by analysis_accuracy.py accuracy --save")  # fmt: skip
    ap.add_argument("--smoke", action="store_true",
                    help="make one small folder first (smoke_takes) and read it")  # fmt: skip
    ap.add_argument("--rom-s", type=float, default=120.0)
    ap.add_argument("--static-s", type=float, default=10.0)
    ap.add_argument("--wand-s", type=float, default=15.0)


def saved_takes_of(args: argparse.Namespace) -> list[tuple[Path, tuple[float, float]]]:
    """:func:`saved_takes` of a tool's parsed :func:`saved_takes_arguments` (``--smoke``: of
    :func:`smoke_takes`' folder, with its options)."""
    if args.smoke:
        args.rom_s, args.static_s, args.wand_s = (
            SMOKE_TAKES[k] for k in ("rom_s", "static_s", "wand_s")
        )
        return saved_takes(smoke_takes(), args.rom_s, args.static_s, args.wand_s)
    if not args.folders:
        raise SystemExit(
            "give the folders an `analysis_accuracy.py accuracy --save DIR` wrote, or --smoke"
        )
    return saved_takes(args.folders, args.rom_s, args.static_s, args.wand_s)


def saved_takes(
    folders: list[Path], rom_s: float = 120.0, static_s: float = 10.0, wand_s: float = 15.0
) -> list[tuple[Path, tuple[float, float]]]:
    """The sessions ``accuracy --save DIR`` kept (``take*.sqlite``, their arrays beside them),
    each with its walk's span on the session clock, from folders named after the run's
    ``--seed`` (``.../s3`` for seed 3); ``rom_s``, ``static_s``, ``wand_s``: that run's options
    (its defaults here). For the diagnostic scripts beside it."""
    out = []
    for folder in folders:
        seed = re.search(r"(\d+)$", folder.name)
        paths = sorted(folder.glob("take*.sqlite"))
        if seed is None or not paths:
            raise SystemExit(f"{folder}: not a folder of analysis_accuracy.py accuracy --save DIR "
                             "named after its seed (s0, s1, ...)")  # fmt: skip
        _, _, _, _, w, _ = calibration_motion(rom_s, int(seed.group(1)), static_s)
        out += [(p, (wand_s + w[0], wand_s + w[1])) for p in paths]
    return out


def accuracy(args: argparse.Namespace) -> dict[str, object]:
    from kinefuse.pipeline.analysis_chain import skeleton_anatomy
    from kinefuse.sim.rig import default_rig, load_rig

    static_s = args.static_s
    errors_off = tuple(sorted({*args.errors_off, *(["subject"] if args.no_subject_bias else [])}))
    if args.ablation and not static_s > 0:
        raise SystemExit("accuracy --ablation needs a standing phase (--static-s > 0)")
    d, rom, truth, combined, walk, lead = calibration_motion(args.rom_s, args.seed, static_s)
    cal_s = args.wand_s
    static_window = (cal_s, cal_s + static_s)
    cal_s += lead  # the ROM phase follows the standing one and its blend
    phase = (cal_s, cal_s + rom.duration_s)
    walk = (args.wand_s + walk[0], args.wand_s + walk[1])  # motion time includes the standing
    rigs = [
        ("default4", replace(default_rig(4), actor_heading_deg=0.0)),
        ("tiered4", replace(load_rig(ROOT / "rigs" / "tiered4.toml"), actor_heading_deg=120.0)),
        ("tilted4", replace(load_rig(ROOT / "rigs" / "tilted4.toml"), actor_heading_deg=-75.0)),
    ][: args.takes]
    report: dict[str, object] = {
        "clip": CLIP.name,
        "rom_s": rom.duration_s,
        "errors_off": list(errors_off),
        "default_pose_frame_of_clip": d,
    }
    norms: dict[str, list[an.Normalization]] = {"fused": [], "floor": []}
    if args.save is not None:
        args.save.mkdir(parents=True, exist_ok=True)
        taken = [p.name for p in args.save.glob("take*") if p.suffix in (".sqlite", ".npz")]
        if taken:
            raise SystemExit(
                f"analysis_accuracy: --save {args.save} already holds {sorted(taken)}; give an "
                "empty or new folder (the takes are never overwritten)"
            )
    with tempfile.TemporaryDirectory() as tmp:
        # with --save the sessions are kept beside the arrays (for diagnostics)
        folder = Path(tmp) if args.save is None else args.save
        for k, (rig_name, rig) in enumerate(rigs):
            t0 = time.perf_counter()
            kept: dict[str, object] = {}
            fused, true_seq, floor_seq, rot = simulate_take(
                rig,
                combined,
                folder / f"take{k}.sqlite",
                args.seed + k,
                args.wand_s,
                args.seed,
                errors_off,
                keep=kept,
            )
            sim_s = time.perf_counter() - t0
            true_seq = _resample(true_seq, fused.t_s)
            floor_seq = _resample(floor_seq, fused.t_s)
            if args.save is not None:
                part = args.save / f"take{k}.npz.part"  # written whole, then renamed
                with part.open("wb") as fh:
                    np.savez(fh, fused=fused.positions, t_s=fused.t_s, truth=true_seq.positions,
                             floor=floor_seq.positions, rot=rot)  # fmt: skip
                part.replace(args.save / f"take{k}.npz")
            norm_t = an.normalize(true_seq)
            model_t = learn_axes(true_seq, norm_t, phase, method="dj")
            ang_t = joint_angles(true_seq, norm_t, model_t)
            # frames where the fusion lost the person (mean joint error over 20 cm: the last
            # second of this clip) say nothing about the analysis; counted and left out
            err = np.nanmean(np.linalg.norm(fused.positions - true_seq.positions, axis=-1), 1)
            in_walk = (fused.t_s >= walk[0]) & (fused.t_s <= walk[1])
            walk_frames = np.flatnonzero(in_walk & (err < 0.2))
            lost = int((in_walk & ~(err < 0.2)).sum())
            rom_frames = np.flatnonzero((fused.t_s >= phase[0]) & (fused.t_s <= phase[1]))
            # the generator's true limb frames at the fused frames of the ROM, in this world
            gi = np.clip(np.round((fused.t_s[rom_frames] - cal_s) * truth.rate_hz), 0, None)
            gi = np.minimum(gi, truth.frames.shape[0] - 1)
            g = np.einsum("ij,tljk->tlik", rot, truth.frames[gi.astype(int)])
            true_world = {k: (rot @ v.T).T for k, v in truth.axes_world.items()}
            frames = (rom_frames, walk_frames)
            take: dict[str, object] = {"rig": rig_name, "heading_deg": rig.actor_heading_deg,
                                       "simulate_fuse_s": sim_s}  # fmt: skip
            norm_f = an.normalize(fused)
            norms["fused"].append(norm_f)
            take.update(analyse_take(fused, norm_f, ang_t, truth, g, true_world, phase, frames,
                                     seen_frames=kept["seen"]))  # fmt: skip
            if not args.ablation:
                kept.clear()  # the sensors are only fused again by the ablation
            take["walk_frames"] = {"used": int(walk_frames.size), "fusion_lost": lost}
            # what the consistency across takes is made of: the fused joints at the default pose
            # against the floor there (the truth plus the bias all takes of the subject share)
            d_f = norm_f.default_frame
            body = [fused.index(n) for n in BODY_JOINTS]
            gap = fused.positions[d_f, body] - floor_seq.positions[d_f, body]
            take["default_pose_fused_vs_floor_cm"] = 100.0 * float(
                np.nanmean(np.linalg.norm(gap, axis=-1))
            )
            norm_b = an.normalize(floor_seq)
            norms["floor"].append(norm_b)
            floor = analyse_take(floor_seq, norm_b, ang_t, truth, g, true_world, phase, frames,
                                 methods=("dj",))  # fmt: skip
            take["floor_subject_bias"] = {
                k2: floor[k2]
                for k2 in ("axis_error_deg_dj", "twist_error_deg", "angle_rmse_deg_walk")
            }
            refused = None
            after: list[str] = []  # printed below the take's own lines
            if static_s > 0:  # a fused standing phase that is not still is refused, as analyze does
                from kinefuse.errors import InputError

                try:
                    skeleton_anatomy(fused, norm_f, static_window)
                except InputError as e:
                    refused = take["anatomical_refused"] = str(e)
                    after.append(f"  anatomical angles of take {k} refused: {refused}")
            if static_s > 0 and refused is None:  # the anatomical angles, same chain
                for zero in ("standing", "geometry"):
                    sfx = "" if zero == "standing" else "_geometry"
                    anat_t, _ = skeleton_anatomy(true_seq, norm_t, static_window, zero)
                    anat_f, sa_f = skeleton_anatomy(fused, norm_f, static_window, zero)
                    anat_b, _ = skeleton_anatomy(floor_seq, norm_b, static_window, zero)
                    take[f"anatomical_rmse_deg_walk{sfx}"] = angle_rmse_deg(
                        anat_f, anat_t, frames=walk_frames
                    )
                    take[f"anatomical_floor_rmse_deg_walk{sfx}"] = angle_rmse_deg(
                        anat_b, anat_t, frames=walk_frames
                    )
                # the knee's included angle straight from the joints (no frames, no zero):
                # what the fused positions themselves allow
                take["included_knee_angle_rmse_deg"] = {
                    side: {w: _included_knee_rmse(q, true_seq, side, walk_frames)
                           for w, q in (("fused", fused), ("floor", floor_seq))}
                    for side in ("left", "right")
                }  # fmt: skip
                take["anatomical_static_motion_mm"] = {
                    k2: 1e3 * v for k2, v in sa_f.static_motion_m.items()
                }
                after.append(_anatomical_text(take))
                if args.ablation:
                    take["fusion_ablation"] = fusion_ablation(
                        kept, true_seq, floor_seq, static_window, walk_frames
                    )
                    after.append(_ablation_text(take["fusion_ablation"]))
            report[f"take{k}"] = take
            print("\n".join([_take_text(k, take), *after]), flush=True)
    if len(norms["fused"]) >= 2:
        cons = normalization_consistency(norms["fused"])
        report["normalization_consistency_deg"] = cons
        floor_cons = normalization_consistency(norms["floor"])
        report["floor_subject_bias"] = {"normalization_consistency_deg": floor_cons}
        print(f"normalization consistency over {len(norms['fused'])} takes: median "
              f"{cons['median']:.2f}°, mean {cons['mean']:.2f}° (floor, the truth plus the "
              f"subject's bias: median {floor_cons['median']:.2f}°, mean "
              f"{floor_cons['mean']:.2f}°)")  # fmt: skip
    return report


def analyse_take(seq, norm, ang_t, truth, g, true_world, phase, frames, methods=METHODS,  # type: ignore[no-untyped-def]
                 seen_frames=None):  # fmt: skip
    """The analysis of one input of a take (the fused skeleton, or the floor input) against the
    truth: axis errors per method, reconstruction, twist, the walk's and the ROM's angles.
    ``seen_frames``: the fused take's frames the axes are learned from (``learn_axes``)."""
    rom_frames, walk_frames = frames
    true_axes = true_axes_in_normalization(truth.axes, g, norm.frames[rom_frames])
    take: dict[str, object] = {}
    models = {}
    for method in methods:
        models[method] = learn_axes(seq, norm, phase, method=method, seen_frames=seen_frames)
        e = axis_errors_deg(models[method], true_axes)
        two = [x for v in e["by_limb"].values() if len(v) == 2 for x in v]  # type: ignore[attr-defined]
        e["two_axis_median"] = float(np.median(two)) if two else float("nan")
        take[f"axis_error_deg_{method}"] = e
        take[f"axis_error_world_deg_{method}"] = world_axis_errors(
            models[method], norm, true_world, rom_frames[0]
        )
    model = models["dj"]
    ang = joint_angles(seq, norm, model)
    take["reconstruction_error_m"] = {
        "full": reconstruction_error(seq, ang, model),
        "minimal": reconstruction_error(seq, ang, model, off_axis=False),
    }
    take["twist_error_deg"] = twist_errors_deg(
        ang.twist, ang_t.twist, ang.twist_weight, frames=rom_frames
    )
    an_f, an_t = ang.anatomical(), ang_t.anatomical()
    take["angle_rmse_deg_walk"] = angle_rmse_deg(an_f, an_t, frames=walk_frames)
    take["angle_rmse_deg_rom"] = angle_rmse_deg(an_f, an_t, frames=rom_frames)
    take["status"] = {k: v for k, v in model.status.items() if v != "ok"}
    return take


#: The anatomical angles the accuracy table shows (issue 20: knee and hip flexion < 8 deg,
#: hip adduction reported).
ANATOMICAL_ROWS = ("knee_flexion", "hip_flexion", "hip_adduction", "hip_internal_rotation",
                   "knee_adduction", "ankle_dorsiflexion", "pelvis_tilt", "pelvis_obliquity",
                   "shoulder_elevation", "elbow_flexion")  # fmt: skip


def _included_knee(seq, side: str) -> np.ndarray:  # type: ignore[no-untyped-def]
    """The knee's included angle (180 - hip-knee-ankle, degrees) of ``seq`` per frame."""
    from kinefuse.pipeline.analysis_chain import hinge_angle_deg

    s = side.capitalize()
    return hinge_angle_deg(seq.kinect_positions(), f"Hip{s}", f"Knee{s}", f"Ankle{s}")


def _included_knee_rmse(seq, truth, side, frames) -> float:  # type: ignore[no-untyped-def]
    """RMSE (degrees) of the knee's included angle of ``seq`` against ``truth`` over ``frames``."""
    d = (_included_knee(seq, side) - _included_knee(truth, side))[frames]
    return float(np.sqrt(np.nanmean(d**2)))


#: the variants of ``best`` the ablation fuses the same take with (``--ablation``)
ABLATION = {
    "best": {},
    "no bones": {"bones": False},
    "no smoother": {"temporal": None},
    "no robust step": {"robust": False},
    "isotropic weights": {"covariance": False},
    "no view noise": {"view_sigma_m": 0.0, "far_sigma_m": 0.0},
    "joints one by one": {"limb_correlation": 0.0},
    "gate chi2 4": {"gate_chi2": 4.0},
    "process noise x0.25": {"accel_scale": 0.25},
}


def fusion_ablation(kept, true_seq, floor_seq, static_window, walk_frames):  # type: ignore[no-untyped-def]
    """Fuse the take's sensors again with each variant of ``best`` (:data:`ABLATION`): per
    variant, the anatomical knee and hip flexion RMSE (zero at standing) against the truth, the
    knee's included angle (180° minus hip-knee-ankle) against the floor's (RMSE and mean signed
    difference: positive where the fused knee is more bent) and the knee position error against
    the floor, over the walk frames."""
    from kinefuse.capture.fusion.options import BestOptions
    from kinefuse.core.skeleton import JOINT_INDEX
    from kinefuse.errors import InputError
    from kinefuse.pipeline.analysis_chain import skeleton_anatomy
    from kinefuse.pipeline.store_inputs import run_method

    norm_t = an.normalize(true_seq)
    anat_t, _ = skeleton_anatomy(true_seq, norm_t, static_window, "standing")
    base = BestOptions()
    out: dict[str, object] = {}
    for name, change in ABLATION.items():
        change = dict(change)
        scale = change.pop("accel_scale", 1.0)
        opt = replace(base, **change)
        if scale != 1.0:
            opt = replace(opt, accel_psd=tuple(scale * np.asarray(base.accel_psd)))
        res = run_method(kept["sensors"], kept["grid"], "best", best_options=opt)
        seq = an.SkeletonSequence.from_kinect(res.positions, t_s=res.t_server_s, source="fused")
        try:
            anat, _ = skeleton_anatomy(seq, an.normalize(seq), static_window, "standing")
        except InputError as e:  # this variant's standing phase is not still enough
            out[name] = {"refused": str(e)}
            continue
        rmse = angle_rmse_deg(anat, anat_t, frames=walk_frames)
        row: dict[str, object] = {}
        for side in ("left", "right"):
            s = side.capitalize()
            inc_f, inc_b = (_included_knee(q, side)[walk_frames] for q in (seq, floor_seq))
            d = inc_f - inc_b
            knee = JOINT_INDEX[f"Knee{s}"]
            gap = (
                seq.kinect_positions()[walk_frames, knee]
                - floor_seq.kinect_positions()[walk_frames, knee]
            )
            row[side] = {
                "knee_flexion_rmse_deg": rmse.get(f"knee_flexion_{side}", float("nan")),
                "hip_flexion_rmse_deg": rmse.get(f"hip_flexion_{side}", float("nan")),
                "included_vs_floor_rmse_deg": float(np.sqrt(np.nanmean(d**2))),
                "included_vs_floor_mean_deg": float(np.nanmean(d)),
                "knee_vs_floor_rms_cm": 100.0 * float(np.sqrt(np.nanmean((gap**2).sum(-1)))),
            }
        out[name] = row
    return out


def _ablation_text(ab: dict) -> str:  # type: ignore[type-arg]
    lines = ["  fusion ablation, walk, left/right: anatomical knee flexion | hip flexion RMSE vs "
             "the truth; included knee angle vs the floor RMSE (mean signed); knee vs the floor "
             "RMS cm"]  # fmt: skip
    for name, row in ab.items():
        if "refused" in row:
            lines.append(f"    {name:20s} static phase refused: {row['refused'][:90]}")
            continue
        lf, rt = row["left"], row["right"]

        def pair(k: str, lf: dict = lf, rt: dict = rt) -> str:  # type: ignore[type-arg]
            return f"{lf[k]:.1f}/{rt[k]:.1f}"

        lines.append(
            f"    {name:20s} {pair('knee_flexion_rmse_deg'):>10s} | "
            f"{pair('hip_flexion_rmse_deg'):>10s}; {pair('included_vs_floor_rmse_deg'):>10s} "
            f"({pair('included_vs_floor_mean_deg')}); {pair('knee_vs_floor_rms_cm')}"
        )
    return "\n".join(lines)


def _anatomical_text(t: dict) -> str:  # type: ignore[type-arg]
    fun = t["angle_rmse_deg_walk"]
    lines = ["  anatomical (static phase) walk RMSE vs the truth's same angles, left/right: "
             "fused | floor, zero at standing; fused | floor, zero from the joint geometry; "
             "functional fused"]  # fmt: skip
    for row in ANATOMICAL_ROWS:
        pelvis = row.startswith("pelvis")
        sides = [row] if pelvis else [f"{row}_left", f"{row}_right"]

        def pair(d: dict, sides: list = sides) -> str:  # type: ignore[type-arg]
            return "/".join(f"{d.get(k, np.nan):.1f}" for k in sides)

        cells = [pair(t[k]) for k in ("anatomical_rmse_deg_walk", "anatomical_floor_rmse_deg_walk",
                                      "anatomical_rmse_deg_walk_geometry",
                                      "anatomical_floor_rmse_deg_walk_geometry")]  # fmt: skip
        lines.append(f"    {row:<22} " + " | ".join(f"{c:>11}" for c in cells)
                     + f" | {pair(fun):>11}")  # fmt: skip
    inc = t["included_knee_angle_rmse_deg"]
    lines.append("    knee included angle from the joints (fused | floor): "
                 f"{inc['left']['fused']:.1f}/{inc['right']['fused']:.1f} | "
                 f"{inc['left']['floor']:.1f}/{inc['right']['floor']:.1f}")  # fmt: skip
    return "\n".join(lines)


def _take_text(k: int, t: dict) -> str:  # type: ignore[type-arg]
    lines = [f"== take {k}: rig {t['rig']}, heading {t['heading_deg']:g}° "
             f"(simulate+calibrate+fuse {t['simulate_fuse_s']:.0f} s)"]  # fmt: skip
    for m in ("dj", "pca", "em"):
        e = t[f"axis_error_deg_{m}"]
        w = t[f"axis_error_world_deg_{m}"]
        lines.append(
            f"  axis error {m:>3}: median {e['median']:.2f}° (two-axis limbs "
            f"{e['two_axis_median']:.2f}°), mean {e['mean']:.2f}° "
            f"(in the world at rest: median {w.get('median', np.nan):.2f}°, "
            f"mean {w.get('mean', np.nan):.2f}°)"
        )
    r = t["reconstruction_error_m"]
    lines.append(
        f"  reconstruction: full mean {1e3 * r['full']['sphere_mean']:.3f} mm, minimal (learned"
        f" axes only) mean {1e3 * r['minimal']['sphere_mean']:.2f} mm"
    )
    tw = t["twist_error_deg"]
    lines.append(f"  twist error (ROM): median {tw['median']:.2f}°, mean {tw['mean']:.2f}°")
    w = t["angle_rmse_deg_walk"]
    lines.append(f"  walk frames: {t['walk_frames']}")
    lines.append(
        f"  default pose: fused body joints {t['default_pose_fused_vs_floor_cm']:.1f} cm from the "
        "floor (mean; the take-dependent error the consistency across takes sees)"
    )
    lines.append("  walk RMSE: " + ", ".join(f"{k2} {v:.1f}°" for k2, v in sorted(w.items())))
    if t["status"]:
        lines.append(f"  status: {t['status']}")
    f = t["floor_subject_bias"]
    fw = f["angle_rmse_deg_walk"]
    lines.append(
        f"  floor (the truth plus the subject-level bias every sensor shares): axis error dj "
        f"median {f['axis_error_deg_dj']['median']:.2f}°, twist median "
        f"{f['twist_error_deg']['median']:.2f}°, walk RMSE knee "
        f"{fw.get('knee_flexion_left', np.nan):.1f}/{fw.get('knee_flexion_right', np.nan):.1f}°,"
        f" hip {fw.get('hip_flexion_left', np.nan):.1f}/{fw.get('hip_flexion_right', np.nan):.1f}°"
    )
    return "\n".join(lines)


# ----------------------------------------------------------------------------- floor
def _segment_offsets(joints: np.ndarray, norm: an.Normalization, body_offsets: np.ndarray,
                     axes: np.ndarray) -> np.ndarray:  # fmt: skip
    """Offsets ``(T, 25, 3)`` fixed in the frame of the limb each joint ends (the pelvis for
    the spine base and hips, the trunk for the shoulders and neck, the forearm for the hand
    joints), equal to the body-frame offsets at the default pose."""
    from kinefuse.biomech.limbs import LIMBS
    from kinefuse.core.skeleton import JOINT_INDEX, JOINTS

    owner = {lb.distal_index: i for i, lb in reversed(list(enumerate(LIMBS)))}
    for name in ("SpineBase", "HipLeft", "HipRight"):
        owner[JOINT_INDEX[name]] = 0
    for name in ("ShoulderLeft", "ShoulderRight", "Neck", "SpineShoulder"):
        owner[JOINT_INDEX[name]] = 1
    d = norm.default_frame
    out = np.zeros(joints.shape)
    for j, name in enumerate(JOINTS):
        li = owner.get(j, an.LIMB_NAMES.index("forearm_" + ("left" if "Left" in name else "right")))
        local = norm.frames[d, li].T @ (axes[d] @ body_offsets[j])
        out[:, j] = np.einsum("tik,k->ti", np.nan_to_num(norm.frames[:, li]), local)
    return out


def floor(args: argparse.Namespace) -> dict[str, object]:
    from kinefuse.sim.lab import LabConfig, _seeds
    from kinefuse.sim.tracker_body import _body_axes

    _, rom, truth, combined, walk, _ = calibration_motion(args.rom_s, args.seed)
    t_s = np.arange(int(combined.duration_s * 30.0)) / 30.0  # a Kinect's rate
    joints = combined.at(t_s)
    true_seq = an.SkeletonSequence.from_kinect(joints, t_s=t_s, source="truth")
    norm_t = an.normalize(true_seq)
    ang_t = joint_angles(true_seq, norm_t, learn_axes(true_seq, norm_t, (0.0, rom.duration_s)))
    phase = (0.0, rom.duration_s)
    rom_frames = np.flatnonzero(t_s <= rom.duration_s)
    walk_frames = np.flatnonzero((t_s >= walk[0]) & (t_s <= walk[1]))
    g = truth.frames[np.round(t_s[rom_frames] * truth.rate_hz).astype(int)]
    axes = _body_axes(joints, np.array([0.0, 0.0, 1.0]))
    rows = []
    for subject in [None, *range(args.subjects)]:  # None: no bias, the truth itself
        if subject is None:
            offsets = np.zeros((25, 3))
        else:
            offsets = _seeds(0, 4, LabConfig(seed=0, subject_seed=subject)).subject.offsets_body_m
        if args.segment_fixed:
            biased = joints + _segment_offsets(joints, norm_t, offsets, axes)
        else:
            biased = joints + np.einsum("tik,jk->tji", axes, offsets)
        seq = an.SkeletonSequence.from_kinect(biased, t_s=t_s, source=f"subject {subject}")
        norm = an.normalize(seq)
        r = analyse_take(seq, norm, ang_t, truth, g, {}, phase, (rom_frames, walk_frames))
        w = r["angle_rmse_deg_walk"]
        row = {
            "subject_seed": subject,
            **{f"axis_median_deg_{m}": r[f"axis_error_deg_{m}"]["median"] for m in METHODS},
            "axis_mean_deg_dj": r["axis_error_deg_dj"]["mean"],
            "twist_median_deg": r["twist_error_deg"]["median"],
            **{k: w.get(k, float("nan")) for k in FLEXION},
        }
        rows.append(row)
        who = "no bias" if subject is None else f"subject {subject}"
        print(f"{who}: axis median dj {row['axis_median_deg_dj']:.2f}° (pca "
              f"{row['axis_median_deg_pca']:.2f}°, em {row['axis_median_deg_em']:.2f}°), "
              f"twist {row['twist_median_deg']:.2f}°, walk RMSE knee "
              f"{row['knee_flexion_left']:.1f}/{row['knee_flexion_right']:.1f}°, hip "
              f"{row['hip_flexion_left']:.1f}/{row['hip_flexion_right']:.1f}°",
              flush=True)  # fmt: skip
    no_bias, rows = rows[0], rows[1:]
    dj = np.array([r["axis_median_deg_dj"] for r in rows])
    best = np.array([min(r["axis_median_deg_pca"], r["axis_median_deg_em"]) for r in rows])
    flex_ok = [all(r[k] < 5.0 for k in FLEXION) for r in rows]
    summary = {
        "subjects": len(rows),
        "no_bias": no_bias,
        "offsets": "segment-fixed" if args.segment_fixed else "body frame (the lab's model)",
        "axis_median_deg_dj": {
            "min": float(dj.min()),
            "median": float(np.median(dj)),
            "max": float(dj.max()),
        },
        "subjects_dj_under_3_deg": int((dj < 3.0).sum()),
        "subjects_dj_beats_pca_and_em": int((dj < best).sum()),
        "subjects_knee_and_hip_flexion_under_5_deg": int(sum(flex_ok)),
    }
    print(f"{summary['offsets']} offsets, {len(rows)} subjects: DJ axis median "
          f"{dj.min():.2f}-{dj.max():.2f}° (median {np.median(dj):.2f}°); under 3° in "
          f"{summary['subjects_dj_under_3_deg']}; DJ below PCA and EM in "
          f"{summary['subjects_dj_beats_pca_and_em']}; knee and hip flexion both sides under 5° "
          f"in {summary['subjects_knee_and_hip_flexion_under_5_deg']}")  # fmt: skip
    return {"summary": summary, "subjects": rows}


FLEXION = ("knee_flexion_left", "knee_flexion_right", "hip_flexion_left", "hip_flexion_right")


# ----------------------------------------------------------------------------- speed
def _speed_sequence(n_frames: int, seed: int) -> tuple[an.SkeletonSequence, float]:
    """A full body: a ROM phase on the real clip's default pose, then the clip's walk and the
    ROM again, repeated to ``n_frames`` at 30 Hz, with 4 mm of noise per joint."""
    from kinefuse.formats.motion import load_motion

    clip = load_motion(CLIP)
    d = an.find_default_pose(an.SkeletonSequence.from_motion(clip))
    rng = np.random.default_rng(seed)
    rom, _ = make_rom_motion(clip.positions[d], 120.0, rng, rate_hz=30.0)
    body = prepend_rom(rom, clip, blend_s=1.0)
    t = np.arange(int(body.duration_s * 30.0)) / 30.0
    one = body.at(t)
    reps = -(-n_frames // one.shape[0])
    p = np.concatenate([one] * reps)[:n_frames]
    p = p + rng.normal(scale=0.004, size=p.shape)
    return an.SkeletonSequence.from_kinect(p, rate_hz=30.0), rom.duration_s


def speed(args: argparse.Namespace) -> dict[str, object]:
    from kinefuse.biomech.normalize import propagate

    seq, rom_s = _speed_sequence(args.frames, 0)
    from kinefuse.pipeline.analysis_chain import skeleton_anatomy

    # each part timed --repeat times, the fastest kept (the shared machine's other jobs and a
    # first call's imports only ever add time); the anatomical angles from a standing window at
    # the start (the ROM's rest pose)
    best: dict[str, float] = {}
    for _ in range(max(args.repeat, 1)):
        t0 = time.perf_counter()
        norm = an.normalize(seq)
        t1 = time.perf_counter()
        model = learn_axes(seq, norm, (0.0, rom_s))
        t2 = time.perf_counter()
        ang = joint_angles(seq, norm, model)
        t3 = time.perf_counter()
        _frames, _weight = propagate(norm, seq.kinect_positions())
        t4 = time.perf_counter()
        anat, _ = skeleton_anatomy(seq, norm, (0.0, 0.3))
        t5 = time.perf_counter()
        for k, v in (("n", t1 - t0), ("l", t2 - t1), ("a", t3 - t2), ("p", t4 - t3),
                     ("anat", t5 - t4)):  # fmt: skip
            best[k] = min(best.get(k, np.inf), v)
    t0, t1, t2, t3 = 0.0, best["n"], best["n"] + best["l"], best["n"] + best["l"] + best["a"]
    t4, anat_s = t3 + best["p"], best["anat"]
    vec = {"normalize_s": t1 - t0, "learn_axes_s": t2 - t1, "angles_twist_s": t3 - t2,
           "total_s": t3 - t0, "per_frame_reorientation_ms": 1e3 * (t4 - t3) / seq.n_frames,
           "per_frame_angles_ms": 1e3 * (t3 - t2) / seq.n_frames,
           "anatomical_s": anat_s, "anatomical_angles": len(anat),
           "anatomical_added_fraction": anat_s / (t3 - t0)}  # fmt: skip
    # the straightforward way: one frame at a time (the same math, no batching)
    n_b = min(args.baseline_frames, seq.n_frames)
    agree, total = 0, 0
    tb = time.perf_counter()
    for f in range(n_b):
        fr, w = propagate(norm, seq.kinect_positions()[f : f + 1])
        one = seq.take([f])
        n1 = replace(norm, frames=fr, twist_weight=w)
        a1 = joint_angles(one, n1, model)
        for k, v in a1.angles.items():
            dv = np.abs(v[0] - ang.angles[k][f])
            if np.isfinite(dv).all():
                # one frame alone cannot follow a crossing of a two-axis joint's axes plane
                # (the smooth choice needs the neighbours): count agreement, not the worst
                agree += int(dv.max() < 1e-9)
                total += 1
    per_frame_s = (time.perf_counter() - tb) / n_b
    base_total = per_frame_s * seq.n_frames + (t1 - t0) + (t2 - t1)
    out = {
        "frames": seq.n_frames,
        "limbs": len(an.LIMBS),
        "vectorized": vec,
        "per_frame_baseline": {
            "measured_frames": n_b,
            "ms_per_frame": 1e3 * per_frame_s,
            "total_s_extrapolated": base_total,
        },
        "speedup_angles": per_frame_s * seq.n_frames / (t3 - t2 + t4 - t3),
        "speedup_total": base_total / (t3 - t0),
        "limb_frames_agreeing_to_1e-9_rad": agree / max(total, 1),
    }
    print(f"{seq.n_frames} frames, {len(an.LIMBS)} limbs, one core")
    print(
        f"  vectorized: normalize {vec['normalize_s']:.3f} s, learn axes {vec['learn_axes_s']:.3f}"
        f" s, angles+twist {vec['angles_twist_s']:.3f} s: total {vec['total_s']:.3f} s"
    )
    print(f"  anatomical angles ({len(anat)}, from a standing window): {anat_s:.3f} s, "
          f"+{100 * anat_s / (t3 - t0):.1f} % of the total above (same run; each part the "
          f"fastest of {max(args.repeat, 1)})")  # fmt: skip
    print(
        f"  per-frame baseline: {1e3 * per_frame_s:.3f} ms/frame (measured on {n_b} frames), "
        f"{base_total:.1f} s for all frames"
    )
    print(f"  speed-up {out['speedup_total']:.0f}x in total, "
          f"{out['speedup_angles']:.0f}x on the per-frame part; "
          f"{100 * agree / max(total, 1):.2f} % of limb-frames agree to 1e-9 rad")  # fmt: skip
    return out


#: ``--smoke``: each mode's options for a run of seconds (55 s is about the shortest ROM phase
#: the generator accepts; one take, so the consistency across takes is not computed)
SMOKE = {
    "speed": ["--frames", "600", "--baseline-frames", "20"],
    "accuracy": ["--rom-s", "55", "--takes", "1", "--wand-s", "6", "--static-s", "3", "--ablation"],
    "floor": ["--rom-s", "55", "--subjects", "1"],
}


#: the options of :func:`smoke_takes`' run, as the tools that read its folder take them
SMOKE_TAKES = {"rom_s": 55.0, "static_s": 3.0, "wand_s": 6.0}


def smoke_takes() -> list[Path]:
    """One small ``accuracy --save`` folder (seed 0) in a temporary folder, for the ``--smoke``
    mode of the tools that read such folders; its options are :data:`SMOKE_TAKES`."""
    folder = Path(tempfile.mkdtemp(prefix="analysis_accuracy_")) / "s0"
    o = SMOKE_TAKES
    main(["accuracy", "--rom-s", str(o["rom_s"]), "--takes", "1", "--wand-s", str(o["wand_s"]),
          "--static-s", str(o["static_s"]), "--save", str(folder)])  # fmt: skip
    return [folder]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--smoke", action="store_true", help="every mode (or MODE) on tiny inputs")
    sub = ap.add_subparsers(dest="mode")
    sp = sub.add_parser("speed")
    sp.add_argument("--frames", type=int, default=24000)
    sp.add_argument("--repeat", type=int, default=3,
                    help="time each vectorized part this many times, keep the fastest")  # fmt: skip
    sp.add_argument("--baseline-frames", type=int, default=1000)
    ac = sub.add_parser("accuracy")
    ac.add_argument("--rom-s", type=float, default=120.0)
    ac.add_argument("--seed", type=int, default=0)
    ac.add_argument("--takes", type=int, default=3)
    ac.add_argument("--wand-s", type=float, default=15.0, help="wand phase before the ROM, s")
    ac.add_argument("--static-s", type=float, default=10.0,
                    help="standing phase (static trial) before the ROM, s; 0: none, no "
                    "anatomical angles")  # fmt: skip
    ac.add_argument("--save", type=Path, default=None,
                    help="a new folder for the takes' arrays and sessions")  # fmt: skip
    ac.add_argument("--ablation", action="store_true",
                    help="fuse each take again with each variant of best and print the knee "
                    "and hip angle errors per variant (with --static-s > 0)")  # fmt: skip
    ac.add_argument("--no-subject-bias", action="store_true",
                    help="simulate a tracker whose joint definitions are the truth's (no "
                    "subject-level bias): what the rest of the error model leaves")  # fmt: skip
    ac.add_argument("--errors-off", type=error_parts, default=(), metavar="PART[,PART]",
                    help="simulate the same sessions with these parts of the tracker's error "
                    "model off, as simulate --errors-off")  # fmt: skip
    fl = sub.add_parser("floor")
    fl.add_argument("--rom-s", type=float, default=120.0)
    fl.add_argument("--seed", type=int, default=0, help="the ROM phase's seed")
    fl.add_argument("--subjects", type=int, default=10)
    fl.add_argument("--segment-fixed", action="store_true",
                    help="offsets fixed in the limb each joint ends")  # fmt: skip
    for p in (sp, ac, fl):
        p.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    modes = {"speed": speed, "accuracy": accuracy, "floor": floor}
    if args.smoke:
        for mode in [args.mode] if args.mode else list(modes):
            print(f"== {mode} (smoke)", flush=True)
            modes[mode](ap.parse_args([mode, *SMOKE[mode]]))
        return 0
    if args.mode is None:
        ap.error("a mode is required: speed, accuracy or floor (or --smoke)")
    report = modes[args.mode](args)
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

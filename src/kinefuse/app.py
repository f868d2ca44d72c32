"""Application workflows behind the CLI: load, configure, run, report. No argument parsing here."""

from __future__ import annotations

import json
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.errors import InputError
from kinefuse.io.store import SessionStore
from kinefuse.motion.types import Motion
from kinefuse.sensors.rig import Rig
from kinefuse.skeleton import JOINT_INDEX

Array = NDArray[np.float64]

#: The demo's bundled clip: CMU subject 01, trial 01 (forward jumps, turn around), the original
#: Acclaim ASF/AMC from the fairmotion repository (BSD); see ``kinefuse/data/LICENSE_clips.md``.
DEMO_CLIP = "01_01.amc.gz"


def demo_clip_path() -> Path:
    """Path of the bundled demo clip inside the installed package."""
    return Path(str(resources.files("kinefuse") / "data" / DEMO_CLIP))


def place_actor(motion: Motion, rig: Rig, seconds: float | None = None) -> Motion:
    """Put the actor where the rig says: its SpineBase at the rig's actor position at the first
    frame, or, when the rig names none, the path of the part that is simulated (the first
    ``seconds``, default all) centred on the origin; facing the rig's heading at the first
    frame; feet on the floor."""
    from kinefuse.motion import place

    if rig.actor_position_m is not None:
        return place(motion, offset_m=rig.actor_position_m, heading_deg=rig.actor_heading_deg)
    placed = place(motion, offset_m=(0.0, 0.0), heading_deg=rig.actor_heading_deg)
    n = placed.n_frames if seconds is None else int(seconds * placed.rate_hz) + 1
    root = placed.positions[:n, JOINT_INDEX["SpineBase"], :2]
    centre = (root.min(axis=0) + root.max(axis=0)) / 2
    return place(
        motion,
        offset_m=(float(-centre[0]), float(-centre[1])),
        heading_deg=rig.actor_heading_deg,
    )


def run_simulate(
    *,
    clip: Path,
    out: Path,
    skeleton: Path | None = None,
    units: str | None = None,
    name_map: Path | None = None,
    rig: Path | None = None,
    sensors: int = 4,
    seconds: float | None = None,
    seed: int = 0,
    calibration_s: float = 20.0,
    depth_rate_hz: float = 10.0,
    force: bool = False,
    progress: Callable[[str], None] | None = None,
    rom_s: float | None = None,
) -> Path:
    """Load a clip and a rig, place the actor, and simulate a session into ``out`` (replacing an
    existing simulated session only with ``force``). ``rom_s``: a range-of-motion calibration
    phase of that many seconds before the motion (:func:`kinefuse.analysis_app.add_rom_phase`)."""
    from kinefuse.motion import load_motion
    from kinefuse.sensors.lab import LabConfig, simulate_session
    from kinefuse.sensors.rig import default_rig, load_rig

    say = progress or (lambda _m: None)
    the_rig = load_rig(rig) if rig is not None else default_rig(sensors)
    say(f"loading {clip}")
    motion = load_motion(clip, skeleton=skeleton, units=units, name_map=name_map)
    if seconds is not None and seconds > motion.duration_s + 1e-9:
        raise InputError(
            f"--seconds {seconds:g} is longer than the clip ({motion.duration_s:.2f} s); "
            "give at most the clip's length or leave --seconds out"
        )
    motion = place_actor(motion, the_rig, seconds)
    rom = None
    if rom_s is not None:
        from kinefuse.analysis_app import add_rom_phase

        rom = add_rom_phase(motion, rom_s, seed=seed)
        if seconds is not None:
            seconds = min(
                seconds + rom.motion.duration_s - motion.duration_s, rom.motion.duration_s
            )
        motion = rom.motion
    out.parent.mkdir(parents=True, exist_ok=True)
    config = LabConfig(
        seed=seed, calibration_s=calibration_s, depth_rate_hz=depth_rate_hz, motion_s=seconds
    )
    path = simulate_session(motion, the_rig, out, config, overwrite=force, progress=say)
    if rom is not None:
        from kinefuse.analysis_app import record_rom_phase

        record_rom_phase(path, rom, calibration_s)
    return path


def run_demo(*, out_dir: Path, seed: int = 0) -> int:
    """The main job, end to end on the bundled clip: simulate a 4-sensor session (wand phase,
    then the motion), calibrate the sensors from the wand, fuse the skeleton, export it, and
    compare every fusion method against the truth."""
    from kinefuse.fusion.session import METHODS
    from kinefuse.report.inspect import format_inspect, inspect_session

    out_dir.mkdir(parents=True, exist_ok=True)
    session = out_dir / "session.sqlite"
    say = print
    say(f"== 1/4 simulate: 4 Kinect v2 sensors watch CMU 01_01 ({DEMO_CLIP}), after 15 s of "
        "wand waving")  # fmt: skip
    run_simulate(
        clip=demo_clip_path(),
        out=session,
        seed=seed,
        calibration_s=15.0,
        force=True,
        progress=lambda m: say("   " + m),
    )
    with SessionStore.open(session) as st:
        info = inspect_session(st)
    (out_dir / "inspect.json").write_text(json.dumps(info, indent=2) + "\n")
    say(format_inspect(info))

    say("\n== 2/4 calibrate: every sensor's pose from the wand seen in depth")
    cal = run_calibrate(
        session=session, method="full", out=out_dir / "calibration.toml", report_dir=out_dir
    )
    say(format_calibrate(cal))

    say("\n== 3/4 fuse: one skeleton from the four sensors (method best)")
    for ext in (".c3d", ".trc"):
        fused = run_fuse(
            session=session,
            method="best",
            out=out_dir / f"fused{ext}",
            calibration=None,
            true_calibration=False,
        )
    say(f"   {fused['frames']} frames in {fused['seconds']:.2f} s -> fused.c3d, fused.trc")

    say("\n== 4/4 evaluate: the paper's methods and ours against the truth")
    report = run_evaluate(
        session=session,
        methods=METHODS,
        out_dir=out_dir / "evaluation",
        calibration=None,
        true_calibration=False,
    )
    say(format_evaluate(report, METHODS))
    say(f"\noutputs in {out_dir}/: session.sqlite, inspect.json, calibration.toml, "
        "calibration_errors_full.png, fused.c3d, fused.trc, evaluation/ (tables I-III, "
        "trajectories.png, evaluate.json)")  # fmt: skip
    return 0


def resolve_poses(
    store: SessionStore, calibration: Path | None, true_calibration: bool
) -> tuple[dict[str, Array], str]:
    """Sensor poses for fusion: a calibration file, the truth (evaluation only), or the
    calibration stored in the session by ``kinefuse calibrate`` (full preferred over paper)."""
    from kinefuse.calibration.calib_file import loads_calibration, read_calibration

    if calibration is not None and true_calibration:
        raise InputError("give either --calibration or --true-calibration, not both")
    if true_calibration:
        if not store.has_truth():
            raise InputError(
                f"{store.path} has no ground truth (a live recording): --true-calibration is only "
                "for simulated sessions; calibrate it with `kinefuse calibrate`"
            )
        truth = store.truth()
        return {s.id: truth.sensor(s.id)[0] for s in store.sensors()}, "true poses (simulator)"
    if calibration is not None:
        return read_calibration(calibration).sensor2world, str(calibration)
    for name in ("full", "paper"):
        text = store.calibration(name)
        if text is not None:
            return loads_calibration(text, source=f"{store.path} [{name}]").sensor2world, (
                f"session calibration ({name})"
            )
    raise InputError(
        f"{store.path} has no calibration: run `kinefuse calibrate {store.path} --method full` "
        "first, or pass --calibration CALIB.toml (or --true-calibration for a simulated session)"
    )


def run_fuse(
    *,
    session: Path,
    method: str,
    out: Path | None,
    calibration: Path | None,
    true_calibration: bool,
) -> dict[str, object]:
    """Fuse a session with one method; store the result in the session and export it."""
    from kinefuse.fusion.session import frame_grid, load_sensors, run_method
    from kinefuse.fusion.status import status_counts
    from kinefuse.io.export import export_skeleton

    if out is not None:
        from kinefuse.io.export import EXPORTERS

        if out.suffix.lower() not in EXPORTERS:
            raise InputError(
                f"{out}: unknown output format {out.suffix or '(none)'!r}; use one of "
                + ", ".join(sorted(EXPORTERS))
            )
    with SessionStore.open(session, writable=True) as store:
        poses, source = resolve_poses(store, calibration, true_calibration)
        sensors = load_sensors(store, poses)
        grid = frame_grid(sensors)
        res = run_method(sensors, grid, method)
        store.write_fused(method, res.t_server_s, res.positions, res.status)
    if out is not None:
        export_skeleton(out, res.t_server_s, res.positions)
    return {
        "method": method,
        "calibration": source,
        "frames": int(res.t_server_s.size),
        "seconds": res.seconds,
        "status": status_counts(res.status),
        "out": str(out) if out is not None else None,
    }


def run_evaluate(
    *,
    session: Path,
    methods: tuple[str, ...],
    out_dir: Path | None,
    calibration: Path | None,
    true_calibration: bool,
) -> dict[str, object]:
    """Compare fusion methods against the truth of a simulated session."""
    from kinefuse.fusion.session import METHODS, load_sensors
    from kinefuse.report.evaluate import calibration_alignment, evaluate, write_tables

    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise InputError(
            f"unknown method(s) {', '.join(unknown)}; choose from {', '.join(METHODS)}"
        )
    with SessionStore.open(session) as store:
        if not store.has_truth():
            raise InputError(
                f"{session} has no ground truth, so there is nothing to evaluate against; "
                "evaluate simulated sessions (kinefuse simulate)"
            )
        poses, source = resolve_poses(store, calibration, true_calibration)
        sensors = load_sensors(store, poses)
        truth2world = None
        if not true_calibration:
            truth2world, cal_error = calibration_alignment(store, poses)
        report, results, truth = evaluate(store, sensors, methods, truth2world=truth2world)
        from kinefuse.report.plausibility_eval import plausibility_vs_errors

        report["plausibility"] = plausibility_vs_errors(store, results, truth)
    report["calibration"] = source
    if truth2world is not None:
        report["calibration_alignment"] = {
            "note": "truth moved into the calibration's world by a translation and a rotation "
            "about z fitted on the sensor poses",
            "translation_m": [float(v) for v in truth2world[:3, 3]],
            "yaw_deg": float(np.degrees(np.arctan2(truth2world[1, 0], truth2world[0, 0]))),
            "calibration_mean_position_error_m": cal_error,
        }
    if out_dir is not None:
        written = write_tables(out_dir, report, results, sensors, truth, methods)
        (out_dir / "evaluate.json").write_text(json.dumps(report, indent=2) + "\n")
        report["written"] = [str(p) for p in written]
    return report


def format_evaluate(report: dict[str, object], methods: tuple[str, ...]) -> str:
    """A short text table of an evaluation."""
    lines = [f"calibration: {report.get('calibration')}, frames: {report.get('frames')}", ""]
    lines.append(f"{'method':<10} {'MAE cm':>8} {'RMSE cm':>8} {'p95 cm':>8} {'missing':>8}")
    for m in methods:
        r = report[m]
        assert isinstance(r, dict)
        lines.append(
            f"{m:<10} {100 * r['mae_m']:8.2f} {100 * r['rmse_m']:8.2f} {100 * r['p95_m']:8.2f}"
            f" {100 * r['missing_fraction']:7.1f}%"
        )
    occ = report.get("occlusion")
    if isinstance(occ, dict):
        lines.append(
            f"\nocclusion detection vs ray casting: precision {occ['precision']:.2f}, "
            f"recall {occ['recall']:.2f}"
        )
    comp = report.get("comparisons")
    if isinstance(comp, dict) and comp:
        lines.append("\nMAE of a below b (95 % interval, block bootstrap over frames):")
        for pair, v in comp.items():
            lines.append(f"  {pair:<22} {_gain_text(v)}")
    from kinefuse.report.plausibility_eval import format_plausibility

    plaus = format_plausibility(report.get("plausibility"))
    if plaus:
        lines.append(plaus)
    abl = report.get("ablation")
    if isinstance(abl, dict):
        lines.append("\nablation of best (MAE without the part, and its gain):")
        for part, v in abl.items():
            lines.append(
                f"  {part:<11} {100 * v['mae_without_m']:6.2f} cm   gain "
                f"{100 * v['gain_m']:+.2f} cm, {_gain_text(v)}"
            )
    return "\n".join(lines)


def _gain_text(v: dict[str, Any]) -> str:
    low, high = v["gain_ci95_percent"]
    verdict = "gain" if low > 0 else ("loss" if high < 0 else "no clear difference")
    return f"{v['gain_percent']:+6.1f} % [{low:+.1f}, {high:+.1f}] {verdict}"


def run_calibrate(
    *, session: Path, method: str, out: Path | None, report_dir: Path | None = None
) -> dict[str, Any]:
    """Calibrate a session's sensors; write the calibration file and store it in the session.

    The error figures (against the simulator's truth) are computed after the calibration, by
    evaluation code, and only when the session has truth.
    """
    from kinefuse.calibration.calib_file import (
        calibration_from_registration,
        dumps_calibration,
        write_calibration,
    )
    from kinefuse.calibration.session import METHODS, calibrate, gather

    if method not in METHODS:
        raise InputError(f"unknown calibration method {method!r}; choose from {', '.join(METHODS)}")
    with SessionStore.open(session, writable=True) as store:
        infos = {s.id: s for s in store.sensors()}
        cal_in = gather(store)
        reg = calibrate(cal_in, method)
        cal = calibration_from_registration(
            reg,
            {k: v.intrinsics for k, v in infos.items()},
            serials={k: v.serial for k, v in infos.items()},
        )
        store.write_calibration(method, dumps_calibration(cal))
        if out is not None:
            write_calibration(out, cal)
        result: dict[str, Any] = {
            "method": method,
            "world": reg.world,
            "rms_m": reg.rms_m,
            "sensors": [
                {
                    "id": sid,
                    "residual_m": float(reg.residual_m[k]),
                    "sightings": int(reg.n_sightings[k]),
                    "detected": int(cal_in.tracks[sid].found.sum()),
                    "frames": len(cal_in.tracks[sid].found),
                }
                for k, sid in enumerate(reg.sensor_ids)
            ],
            "out": str(out) if out is not None else None,
        }
        if store.has_truth():
            from kinefuse.report.calibration import calibration_errors, write_calibration_report

            errs = calibration_errors(store, reg)
            for s in result["sensors"]:
                s.update(errs["by_sensor"][s["id"]])
            for key in (
                "alignment",
                "mean_position_error_m",
                "mean_rotation_error_deg",
                "unaligned_mean_position_error_m",
                "unaligned_mean_rotation_error_deg",
            ):
                result[key] = errs[key]
            if report_dir is not None:
                written = write_calibration_report(report_dir, store, cal_in, reg, method)
                result["written"] = [str(p) for p in written]
    return result


def format_calibrate(r: dict[str, Any]) -> str:
    lines = [f"calibration ({r['method']}): {r['world']}", ""]
    has_err = "mean_position_error_m" in r
    head = f"{'sensor':<8} {'sightings':>9} {'residual mm':>12}"
    if has_err:
        head += f" {'pos err mm':>11} {'rot err deg':>12}"
    lines.append(head)
    for s in r["sensors"]:
        row = f"{s['id']:<8} {s['sightings']:>9} {1e3 * s['residual_m']:12.2f}"
        if has_err:
            row += f" {1e3 * s['position_error_m']:11.2f} {s['rotation_error_deg']:12.3f}"
        lines.append(row)
    if has_err:
        lines.append(
            f"\nmean error vs truth ({r['alignment']}-aligned): "
            f"{1e3 * r['mean_position_error_m']:.2f} mm, {r['mean_rotation_error_deg']:.3f} deg"
            f" (unaligned: {1e3 * r['unaligned_mean_position_error_m']:.2f} mm)"
        )
    return "\n".join(lines)

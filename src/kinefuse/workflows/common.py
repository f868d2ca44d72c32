"""Application workflows behind the CLI: load, configure, run, report. No argument parsing here."""

from __future__ import annotations

import json
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.errors import CalibrationError, InputError, OutputError
from kinefuse.evaluation.poses import resolve_poses
from kinefuse.io.store.session import SessionStore, is_simulated_session

Array = NDArray[np.float64]

#: The demo's bundled clip: CMU subject 01, trial 01 (forward jumps, turn around), the original
#: Acclaim ASF/AMC from the fairmotion repository (BSD); see ``kinefuse/data/LICENSE_clips.md``.
DEMO_CLIP = "01_01.amc.gz"


def demo_clip_path() -> Path:
    """Path of the bundled demo clip inside the installed package."""
    return Path(str(resources.files("kinefuse") / "data" / DEMO_CLIP))


def check_session_out(out: Path, force: bool) -> None:
    """Refuse an ``--out`` for a new session: a foreign extension, or an existing file that is
    not a simulated session (or is one, without ``--force``)."""
    from kinefuse.io.outputs import (
        FOREIGN_SESSION_SUFFIXES,
        check_output_folder,
        is_kinefuse_session,
    )

    if out.suffix.lower() in FOREIGN_SESSION_SUFFIXES:
        raise OutputError(
            f"--out {out}: a session is a SQLite file, but {out.suffix!r} is the extension of "
            "another format; name it .sqlite"
        )
    check_output_folder(out, "session")
    if out.is_dir():
        raise OutputError(f"--out {out} is a folder; give the path of a .sqlite file")
    if not out.exists():
        return
    if not force:
        raise OutputError(
            f"{out} already exists; choose another --out, or pass --force to replace it (only a "
            "simulated kinefuse session is ever replaced)"
        )
    if not is_kinefuse_session(out):
        raise OutputError(
            f"refusing to replace {out}: it is not a kinefuse session (checked by its content, "
            "not its name); --force only replaces simulated sessions"
        )
    if any(out.with_name(out.name + s).exists() for s in ("-wal", "-journal")):
        raise OutputError(
            f"refusing to replace {out}: it is open by another process or was not closed cleanly "
            f"(a {out.name}-wal or -journal file lies beside it); close that process, or run "
            f"`kinefuse inspect {out}` once to recover it, then try again"
        )
    if not is_simulated_session(out):
        raise OutputError(
            f"refusing to replace {out}: it is a recording without ground truth (a live session); "
            "choose another --out"
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
    room: tuple[float, float, float, float] | None = None,
    force: bool = False,
    progress: Callable[[str], None] | None = None,
    rom_s: float | None = None,
    subject_seed: int | None = None,
) -> dict[str, Any]:
    """Load a clip and a rig, place the actor, and simulate a session into ``out``.

    Everything that can be checked is checked before anything is written; the session is built
    in a temporary file beside ``out``, marked complete, and renamed into place only when it is
    whole, so an interrupted or failed run leaves any old ``out`` byte-identical. ``force``
    replaces an existing simulated session, never another file or a live recording. ``rom_s``:
    a range-of-motion calibration phase of that many seconds before the motion
    (:func:`kinefuse.workflows.analyze.add_rom_phase`).

    Returns
    -------
    dict
        ``out`` (path), ``coverage`` (:func:`kinefuse.evaluation.coverage.tracking_coverage`) and
        ``warnings`` (list of str).
    """
    from kinefuse.evaluation.coverage import coverage_warnings, tracking_coverage
    from kinefuse.io.outputs import atomic_file
    from kinefuse.motion import load_motion
    from kinefuse.sim.lab import LabConfig, simulate_session
    from kinefuse.sim.rig import default_rig, load_rig, place_actor

    say = progress or (lambda _m: None)
    check_session_out(out, force)
    the_rig = load_rig(rig, room=room) if rig is not None else default_rig(sensors, room=room)
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
        from kinefuse.workflows.analyze import add_rom_phase

        rom = add_rom_phase(motion, rom_s, seed=seed)
        if seconds is not None:
            seconds = min(
                seconds + rom.motion.duration_s - motion.duration_s, rom.motion.duration_s
            )
        motion = rom.motion
    config = LabConfig(
        seed=seed,
        calibration_s=calibration_s,
        depth_rate_hz=depth_rate_hz,
        motion_s=seconds,
        subject_seed=subject_seed,
    )
    with atomic_file(
        out, what="session", recognizer=is_simulated_session, suffix=".partial.sqlite"
    ) as tmp:
        tmp.unlink()  # the store creates its own file
        simulate_session(motion, the_rig, tmp, config, progress=say)
        if rom is not None:
            from kinefuse.workflows.analyze import record_rom_phase

            record_rom_phase(tmp, rom, calibration_s)
        with SessionStore.open(tmp, writable=True) as store:
            coverage = tracking_coverage(store)
            store.mark_complete()
    warnings = coverage_warnings(coverage)
    return {"out": out, "coverage": coverage, "warnings": warnings}


def run_demo(*, out_dir: Path, seed: int = 0) -> int:
    """The main job, end to end on the bundled clip: simulate a 4-sensor session (wand phase,
    then the motion), calibrate the sensors from the wand, fuse the skeleton, export it, and
    compare every fusion method against the truth.

    Everything is built in a fresh folder beside ``out_dir`` and swapped in only when the whole
    run succeeded, so an interrupted demo leaves the previous run's outputs as they were.
    """
    from kinefuse.evaluation.inspect import format_inspect, inspect_session
    from kinefuse.fusion.session import METHODS
    from kinefuse.io.outputs import atomic_dir

    say = print
    with atomic_dir(out_dir, what="demo output folder") as tmp:
        session = tmp / "session.sqlite"
        say(f"== 1/4 simulate: 4 Kinect v2 sensors watch CMU 01_01 ({DEMO_CLIP}), after 15 s "
            "of wand waving")  # fmt: skip
        sim = run_simulate(
            clip=demo_clip_path(),
            out=session,
            seed=seed,
            calibration_s=15.0,
            progress=lambda m: say("   " + m),
        )
        for w in sim["warnings"]:
            say(f"   warning: {w}")
        with SessionStore.open(session) as st:
            info = inspect_session(st)
        (tmp / "inspect.json").write_text(json.dumps(info, indent=2) + "\n")
        say(format_inspect(info))

        say("\n== 2/4 calibrate: every sensor's pose from the wand seen in depth")
        from kinefuse.workflows.calibrate import format_calibrate, run_calibrate

        cal = run_calibrate(
            session=session,
            method="full",
            out=tmp / "calibration.toml",
            report_dir=tmp / "calibration",
            store_result=True,
        )
        say(format_calibrate(cal))
        if cal["grade"] == "failed":
            raise CalibrationError("the demo's calibration failed; see the reasons above")

        say("\n== 3/4 fuse: one skeleton from the four sensors (method best)")
        for ext in (".c3d", ".trc", ".csv"):
            fused = run_fuse(
                session=session,
                method="best",
                out=tmp / f"fused{ext}",
                calibration=None,
                true_calibration=False,
            )
        say(f"   {fused['frames']} frames in {fused['seconds']:.2f} s -> fused.c3d, fused.trc, "
            "fused.csv")  # fmt: skip

        say("\n== 4/4 evaluate: the paper's methods and ours against the truth")
        report = run_evaluate(
            session=session,
            methods=METHODS,
            out_dir=tmp / "evaluation",
            calibration=None,
            true_calibration=False,
        )
        say(format_evaluate(report, METHODS))
    say(f"\noutputs in {out_dir}/: session.sqlite, inspect.json, calibration.toml, "
        "calibration/ (error plots), fused.c3d, fused.trc, fused.csv, evaluation/ (report.html, "
        "tables I-III, trajectories.png, evaluate.json)")  # fmt: skip
    return 0


def run_fuse(
    *,
    session: Path,
    method: str,
    out: Path | None,
    calibration: Path | None,
    true_calibration: bool,
    store_result: bool = False,
    allow_incomplete: bool = False,
    trc_axes: str = "y-up",
    start_s: float | None = None,
    end_s: float | None = None,
) -> dict[str, object]:
    """Fuse a session with one method and export the result.

    The session is opened read-only; ``store_result`` stores the fused skeleton in it as well
    (the one case that writes to the session). The export's folder and kind are checked before
    the work starts, so a bad ``out`` fails fast.
    """
    from kinefuse.fusion.status import status_counts
    from kinefuse.io.formats.export import check_export_path, export_skeleton
    from kinefuse.io.outputs import check_output_folder
    from kinefuse.pipeline.session import clip_grid, frame_grid, load_sensors, run_method

    if out is not None:
        check_export_path(out)
        check_output_folder(out, "export")
    with SessionStore.open(session, writable=store_result) as store:
        store.require_complete(allow_incomplete=allow_incomplete)
        poses, source = resolve_poses(store, calibration, true_calibration)
        sensors = load_sensors(store, poses)
        warnings = [
            f"sensor {s.id} has no body frames: the fusion uses the other sensors only"
            for s in sensors
            if not s.observations.has_body.any()
        ]
        grid = clip_grid(frame_grid(sensors), start_s, end_s)
        res = run_method(sensors, grid, method)
        if store_result:
            store.write_fused(method, res.t_server_s, res.positions, res.status)
    if out is not None:
        export_skeleton(
            out, res.t_server_s, res.positions, residual_m=res.residual_m, trc_axes=trc_axes
        )
    return {
        "method": method,
        "calibration": source,
        "frames": int(res.t_server_s.size),
        "seconds": res.seconds,
        "status": status_counts(res.status),
        "out": str(out) if out is not None else None,
        "stored_in_session": store_result,
        "warnings": warnings,
    }


def run_evaluate(
    *,
    session: Path,
    methods: tuple[str, ...],
    out_dir: Path | None,
    calibration: Path | None,
    true_calibration: bool,
    allow_incomplete: bool = False,
    start_s: float | None = None,
    end_s: float | None = None,
) -> dict[str, object]:
    """Compare fusion methods against the truth of a simulated session (opened read-only).

    ``out_dir`` gets the tables, plots and ``evaluate.json``, built in a fresh folder and
    swapped in on success (an existing folder is replaced only if kinefuse made it).
    """
    from kinefuse.evaluation.fusion import calibration_alignment, evaluate, write_tables
    from kinefuse.io.outputs import atomic_dir, check_output_folder
    from kinefuse.pipeline.session import METHODS, load_sensors

    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise InputError(
            f"unknown method(s) {', '.join(unknown)}; choose from {', '.join(METHODS)}"
        )
    if out_dir is not None:
        check_output_folder(out_dir, "evaluation folder")
    with SessionStore.open(session) as store:
        store.require_complete(allow_incomplete=allow_incomplete)
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
        report, results, truth = evaluate(
            store, sensors, methods, truth2world=truth2world, start_s=start_s, end_s=end_s
        )
        from kinefuse.evaluation.plausibility import plausibility_vs_errors

        report["plausibility"] = plausibility_vs_errors(store, results, truth)
        facts = None
        if out_dir is not None:
            from kinefuse.evaluation.report_facts import session_facts

            facts = session_facts(store, sensors, poses, source)
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
        with atomic_dir(out_dir, what="evaluation folder") as tmp:
            written = write_tables(tmp, report, results, sensors, truth, methods)
            if facts is not None:
                from kinefuse.report.html import write_html_report

                written.append(
                    write_html_report(tmp / "report.html", facts, report, results, truth, methods)
                )
            report["written"] = [str(out_dir / p.name) for p in written] + [
                str(out_dir / "evaluate.json")
            ]
            (tmp / "evaluate.json").write_text(json.dumps(report, indent=2) + "\n")
    return report


def format_evaluate(report: dict[str, object], methods: tuple[str, ...]) -> str:
    """A short text table of an evaluation."""
    common = report.get("common")
    frac = common.get("joint_fraction", float("nan")) if isinstance(common, dict) else float("nan")
    lines = [f"calibration: {report.get('calibration')}, frames: {report.get('frames')}", ""]
    lines.append(
        f"{'method':<10} {'MAE cm':>8} {'common':>8} {'RMSE cm':>8} {'p95 cm':>8} "
        f"{'coverage':>9} {'bias cm':>8} {'noise cm':>9}"
    )
    for m in methods:
        r = report[m]
        assert isinstance(r, dict)
        bn = r["bias_noise"]
        lines.append(
            f"{m:<10} {100 * r['mae_m']:8.2f} {100 * r['mae_common_m']:8.2f} "
            f"{100 * r['rmse_m']:8.2f} {100 * r['p95_m']:8.2f} {100 * r['coverage']:8.1f}% "
            f"{100 * bn['bias_norm_mean_m']:8.2f} {100 * bn['noise_mean_m']:9.2f}"
        )
    lines.append(
        f"(MAE over each method's own joints; 'common' over the {100 * frac:.1f} % of frames x "
        "joints every method solved; bias = mean offset per joint, noise = spread around it)"
    )
    for m in methods:
        r = report[m]
        assert isinstance(r, dict)
        if m == "best-live":
            parts = [f"{k.lower()} {100 * v['fraction']:.1f} % ({100 * v['mae_m']:.1f} cm)"
                     for k, v in r["by_status"].items()]  # fmt: skip
            lines.append(f"{m} by joint status: " + ", ".join(parts))
    occ = report.get("occlusion")
    if isinstance(occ, dict):
        lines.append(
            f"\nocclusion detection vs ray casting: precision {occ['precision']:.2f}, "
            f"recall {occ['recall']:.2f}"
        )
    comp = report.get("comparisons")
    if isinstance(comp, dict) and comp:
        lines.append("\ngain of a over b: MAE of b minus MAE of a on joints both solved (95 % "
                     "interval, block bootstrap over frames):")  # fmt: skip
        for pair, v in comp.items():
            lines.append(f"  {pair:<22} {_gain_text(v)}")
    from kinefuse.evaluation.plausibility import format_plausibility

    plaus = format_plausibility(report.get("plausibility"))
    if plaus:
        lines.append(plaus)
    abl = report.get("ablation")
    if isinstance(abl, dict):
        lines.append("\nablation of best (MAE without the part, and what the part gains):")
        for part, v in abl.items():
            lines.append(f"  {part:<11} {100 * v['mae_without_m']:6.2f} cm   {_gain_text(v)}")
    return "\n".join(lines)


def _gain_text(v: dict[str, Any]) -> str:
    low, high = v["gain_ci95_percent"]
    return (
        f"{100 * v['gain_m']:+6.2f} cm, {v['gain_percent']:+6.1f} % [{low:+.1f}, {high:+.1f}] "
        f"{v['verdict']}"
    )

"""``kinefuse analyze``: paper B's limb frames and joint angles of sessions, clips, marker files."""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from kinefuse.app.cli import args as shared
from kinefuse.capture.fusion.methods import METHODS
from kinefuse.errors import InputError


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``kinefuse analyze``."""
    p = sub.add_parser(
        "analyze",
        help="normalized limb frames and joint angles (paper B; docs/analysis.md)",
        description="Limb frames and joint angles of sessions, clips and marker files, or of "
        "every trial of a study folder (STUDY_DIR/: in parallel, resumable, one summary; "
        "docs/tutorials/study.md). Exit 0 done, 2 bad input, 1 a study with failed trials, 3 "
        "nothing analysed.",
    )
    p.add_argument(
        "inputs",
        nargs="+",
        type=Path,
        help="session (.sqlite), clip (.bvh/.amc), markers (.trc/.c3d), or one study folder",
    )
    p.add_argument(
        "--calibration-phase",
        type=shared.phase,
        metavar="START_S:END_S",
        help="the frames to learn the movement axes from (default: a session's stored "
        "range-of-motion phase, else the whole input)",
    )
    p.add_argument(
        "--map", type=Path, help="marker map (TOML) for .trc/.c3d (default: a shipped one)"
    )
    p.add_argument(
        "--method",
        default="best",
        choices=METHODS,
        help="fusion method for sessions (best)",
    )
    p.add_argument(
        "--static",
        type=Path,
        metavar="STATIC.trc|.c3d",
        help="static trial: ISB anatomical frames and joint angles beside the functional ones "
        "(marker files; docs/analysis.md)",
    )
    p.add_argument(
        "--static-window",
        type=_static_window,
        metavar="START_S:END_S|auto",
        help="the still part of the static trial, or of the input itself when --static is not "
        "given (seconds); auto: a session's stored standing phase (simulate --static)",
    )
    p.add_argument(
        "--names",
        default="kinefuse",
        metavar="kinefuse|opensim|opensim:MODEL",
        help="angles.mot columns: kinefuse names (both methods), or the anatomical angles "
        "under an OpenSim model's coordinate names and signs (MODEL: gait2354, gait2392, "
        "hamner, rajagopal; opensim alone: hamner)",
    )
    shared.add_calibration_args(p)
    shared.add_people_args(p, every=False)
    p.add_argument("--out", type=Path, required=True, help="fresh output folder")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots (batch runs)")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    study = p.add_argument_group("a study folder (docs/tutorials/study.md)")
    study.add_argument(
        "--jobs", type=shared.count, metavar="N", help="trials at once (default: one per core)"
    )
    study.add_argument(
        "--scheduler",
        metavar="tcp://HOST:PORT",
        help="run the trials on this Dask cluster instead (pip install 'kinefuse[dask]')",
    )
    study.add_argument(
        "--force", action="store_true", help="analyse again the trials done in an earlier run"
    )
    p.set_defaults(func=run)


def run_study(args: argparse.Namespace) -> int:
    """``kinefuse analyze STUDY_DIR/``: every trial, one summary (docs/tutorials/study.md)."""
    import json

    from kinefuse.app.workflows.progress import TerminalProgress
    from kinefuse.app.workflows.study import run_study as study

    for option in ("static", "static_window", "calibration_phase", "calibration"):
        if getattr(args, option) is not None:
            flag = "--" + option.replace("_", "-")
            raise InputError(
                f"{flag} is per trial: in a study the static trials follow the naming rule, "
                f"or list each trial's options in STUDY_DIR/study.toml (docs/tutorials/study.md)"
            )
    with TerminalProgress("analyze", enabled=not args.json) as bar:
        result = study(
            args.inputs[0],
            out=args.out,
            jobs=args.jobs,
            scheduler=args.scheduler,
            force=args.force,
            marker_map=args.map,
            method=args.method,
            names=args.names,
            plots=not args.no_plots,
            progress=bar if bar.active else lambda m: print(m, file=sys.stderr),
        )
    if args.json:
        print(json.dumps(result.to_json(), indent=2))
    else:
        n, bad = len(result.trials), result.failed
        skipped = sum(t.status == "skipped" for t in result.trials)
        print(f"{n - len(bad)} of {n} trials analysed ({skipped} done in an earlier run)")
        for t in bad:
            print(f"  failed: {t.id}: {t.message}")
        print(f"wrote {result.summary_csv}, {result.cycles_csv}, {result.html}")
    if result.exit_code() == 3:
        print("kinefuse: error: no trial of the study could be analysed", file=sys.stderr)
    return result.exit_code()


def _static_window(text: str) -> tuple[float, float] | str:
    return "auto" if text.strip().lower() == "auto" else shared.phase(text)


def run(args: argparse.Namespace) -> int:
    if len(args.inputs) == 1 and args.inputs[0].is_dir():
        if args.subject is not None:
            raise InputError("--subject picks a person of one session, not of a study folder")
        return run_study(args)
    for option in ("jobs", "scheduler", "force"):
        if getattr(args, option):
            raise InputError(f"--{option} is for a study folder (kinefuse analyze STUDY_DIR/)")
    from kinefuse.app.workflows.analyze import format_analyze, run_analyze

    if not args.no_plots:
        import matplotlib

        matplotlib.use("Agg")  # the command draws to files only
    result = run_analyze(
        args.inputs,
        out=args.out,
        calibration_phase=args.calibration_phase,
        marker_map=args.map,
        method=args.method,
        calibration=args.calibration,
        true_calibration=args.true_calibration,
        plots=not args.no_plots,
        progress=lambda m: print(m, file=sys.stderr),
        static=args.static,
        static_window=args.static_window,
        names=args.names,
        subject=args.subject,
    )
    for name, w in result.warnings:
        print(f"kinefuse: warning: {name}: {w}", file=sys.stderr)
    print(result.to_json() if args.json else format_analyze(result.report))
    empty = [r for r in result.inputs if _nothing_analysed(r)]
    for r in empty:
        print(f"kinefuse: nothing analysed in {r['input']}: {_why_nothing(r)}", file=sys.stderr)
    return 3 if empty else 0


def _nothing_analysed(r: dict[str, object]) -> bool:
    """No angle of any limb (functional or anatomical) was written for this input."""
    anat = r.get("anatomical")
    return not r.get("angle_names") and not (isinstance(anat, dict) and anat.get("angle_names"))


def _why_nothing(r: dict[str, object]) -> str:
    """The limbs' reasons, one per distinct reason (skipped limbs of a partial body last)."""
    status = r.get("limb_status")
    groups: dict[str, list[str]] = {}
    for limb, why in status.items() if isinstance(status, dict) else ():
        if why != "ok":  # "missing: KneeLeft/AnkleLeft present in 1 of 181 ..." -> one reason
            key = re.sub(r"\w+/\w+ present in \d+ of", "its joints present in too few of", str(why))
            groups.setdefault(key, []).append(limb)
    order = sorted(groups.items(), key=lambda g: g[0].startswith("skipped"))
    parts = [f"{', '.join(limbs)}: {why}" for why, limbs in order[:4]]
    more = f"; and {len(order) - 4} more reasons" if len(order) > 4 else ""
    return (
        "every limb was refused, so angles.csv holds its header only. "
        + "; ".join(parts)
        + more
        + f". The report is {r.get('out', 'in the output folder')} (analysis.json); the limbs "
        "need a calibration phase in which they are seen and move."
    )

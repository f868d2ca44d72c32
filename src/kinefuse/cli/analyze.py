"""``kinefuse analyze``: paper B's limb frames and joint angles of sessions, clips, marker files."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from kinefuse.cli import args as shared
from kinefuse.fusion.methods import METHODS


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``kinefuse analyze``."""
    p = sub.add_parser(
        "analyze", help="normalized limb frames and joint angles (paper B; docs/analysis.md)"
    )
    p.add_argument(
        "inputs",
        nargs="+",
        type=Path,
        help="session (.sqlite), clip (.bvh/.amc), markers (.trc/.c3d)",
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
    p.add_argument("--out", type=Path, required=True, help="fresh output folder")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots (batch runs)")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.set_defaults(func=run)


def _static_window(text: str) -> tuple[float, float] | str:
    return "auto" if text.strip().lower() == "auto" else shared.phase(text)


def run(args: argparse.Namespace) -> int:
    from kinefuse.workflows.analyze import format_analyze, json_text, run_analyze

    if not args.no_plots:
        import matplotlib

        matplotlib.use("Agg")  # the command draws to files only
    report = run_analyze(
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
    )
    for r in report.get("inputs", [report]):
        for w in r.get("warnings", []):
            print(f"kinefuse: warning: {r['input']}: {w}", file=sys.stderr)
    print(json_text(report) if args.json else format_analyze(report))
    return 0

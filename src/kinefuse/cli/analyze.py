"""``kinefuse analyze``: paper B's limb frames and joint angles of sessions, clips, marker files."""

from __future__ import annotations

import argparse
import re
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
        choices=["kinefuse", "opensim"],
        default="kinefuse",
        help="angles.mot columns: kinefuse names (both methods), or the anatomical angles "
        "under OpenSim's gait-model coordinate names and signs",
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
    empty = [r for r in report.get("inputs", [report]) if _nothing_analysed(r)]
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

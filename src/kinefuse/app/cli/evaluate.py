"""``kinefuse evaluate``: every fusion method against the simulator's truth, or (a session
without truth) their consistency figures."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from kinefuse.app.cli import args as shared
from kinefuse.capture.fusion.methods import METHODS


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``kinefuse evaluate``."""
    p = sub.add_parser(
        "evaluate",
        help="compare fusion methods against the simulator's truth (without truth: consistency)",
    )
    p.add_argument("session", type=Path, help="session store (.sqlite), simulated or recorded")
    shared.add_calibration_args(p)
    p.add_argument(
        "--methods",
        type=shared.methods,
        default=METHODS,
        help="comma-separated methods (all six)",
    )
    p.add_argument("--out", type=Path, help="folder for the paper-style tables and plots")
    shared.add_span_args(p)
    shared.add_partial_arg(p)
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import sys

    from kinefuse.app.workflows.evaluate import format_evaluate, run_evaluate
    from kinefuse.app.workflows.progress import TerminalProgress
    from kinefuse.lab.no_truth import NothingToEvaluate

    try:
        with TerminalProgress("evaluate", enabled=not args.json) as progress:
            report = run_evaluate(
                session=args.session,
                methods=args.methods,
                out_dir=args.out,
                calibration=args.calibration,
                true_calibration=args.true_calibration,
                allow_incomplete=args.partial,
                start_s=args.start,
                end_s=args.end,
                progress=progress,
            )
    except NothingToEvaluate as e:  # a session with nothing fusable: not a user error, exit 3
        print(f"kinefuse: error: {e}", file=sys.stderr)
        return 3
    if args.json:
        print(json.dumps(report.as_dict(), indent=2))
    else:
        print(format_evaluate(report.report, args.methods))
        for w in report.written:
            print(f"wrote {w}")
    return 0

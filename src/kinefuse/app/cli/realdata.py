"""``kinefuse realdata``: the real two-Kinect logs fused, and their consistency."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``kinefuse realdata``."""
    p = sub.add_parser(
        "realdata",
        help="fuse the real two-Kinect recordings and report their consistency (docs/real_data.md)",
        description="Fuse real two-Kinect KinectMultiTrack logs and report their consistency.",
    )
    p.add_argument("paths", nargs="+", help="KinectMultiTrack CSV logs")
    p.add_argument("--json", action="store_true", help="print JSON instead of text")
    p.add_argument(
        "--registration",
        choices=("refined", "logged"),
        default="refined",
        help="the other sensor re-registered from the trunk joints (refined) or as the log has "
        "it (logged)",
    )
    p.add_argument(
        "--other-offaxis-deg",
        type=float,
        default=0.0,
        help="assumed angle of the body's initial centre off the other sensor's optical axis, "
        "toward its image right, degrees (0)",
    )
    p.add_argument(
        "--no-motion-latency",
        action="store_true",
        help="align by the clock fit alone (no relative latency from the motion)",
    )
    p.add_argument(
        "--out",
        type=Path,
        help="export the fused take, all scenarios (.c3d, .trc, .csv or .bvh, as kinefuse fuse "
        "--out); one log only",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from kinefuse.app.cli.fuse import said_once
    from kinefuse.app.workflows.realdata import (
        export_fused,
        format_report,
        format_summary,
        fuse_multitrack,
    )
    from kinefuse.errors import InputError

    if args.out is not None and len(args.paths) != 1:
        raise InputError(
            f"--out exports one fused take: give one log (got {len(args.paths)}), or run "
            "kinefuse realdata once per log"
        )
    fused: list = []
    results = [
        fuse_multitrack(
            p,
            registration=args.registration,
            other_offaxis_deg=args.other_offaxis_deg,
            motion_latency=not args.no_motion_latency,
            fused=fused,
        )
        for p in args.paths
    ]
    written: list[Path] = []
    if args.out is not None:
        out, notes = export_fused(fused[0], args.out, results[0].file)
        for w in said_once([f"{out.name}: {n}" for n in notes]):
            print(f"kinefuse: warning: {w}", file=sys.stderr)
        written.append(out)
    if args.json:
        reports = [r.as_dict() for r in results]
        print(json.dumps(reports if len(reports) > 1 else reports[0], indent=1))
    else:
        print("\n".join(format_summary(r.report) for r in results))
        print("\n" + "\n\n".join(format_report(r.report) for r in results))
        for f in written:
            print(f"\nwrote {f}")
    return 0

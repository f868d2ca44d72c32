"""``kinefuse track``: recordings of real cameras -> a session store."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from kinefuse.app.cli import args as shared


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``kinefuse track``."""
    p = sub.add_parser(
        "track",
        help="turn camera recordings (one per sensor) into a session (docs/devices.md)",
        description="Read one recording per sensor (Azure Kinect .mkv, RealSense .bag/.db3, or "
        "KIND:FILE), run the body tracker on every capture, and write a session store that "
        "calibrate, fuse, evaluate, analyze and view take. A rerun on the same --out skips the "
        "recordings already in it.",
    )
    p.add_argument("recordings", nargs="+", help="one recording per sensor")
    p.add_argument("--out", type=Path, required=True, help="the session store to write (.sqlite)")
    p.add_argument(
        "--tracker",
        metavar="NAME",
        help="body tracker (k4abt, pose, ...; kinefuse sensor --list-sources); default: none, "
        "depth only",
    )
    p.add_argument(
        "--jobs",
        type=shared.count,
        metavar="N",
        help="worker processes (default: one per core, at most one per recording)",
    )
    p.add_argument(
        "--depth-hz",
        type=shared.positive_float,
        default=10.0,
        metavar="HZ",
        help="depth frames kept for the wand, per second (10)",
    )
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from kinefuse.app.workflows.progress import TerminalProgress
    from kinefuse.app.workflows.track import format_track, track_recordings

    with TerminalProgress("track", enabled=not args.json) as progress:
        d = track_recordings(
            args.recordings,
            args.out,
            tracker=args.tracker,
            jobs=args.jobs,
            depth_hz=args.depth_hz,
            progress=progress,
        )
    print(json.dumps(d.as_dict(), indent=1) if args.json else format_track(d))
    return 0

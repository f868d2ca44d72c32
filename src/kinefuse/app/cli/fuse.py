"""``kinefuse fuse``: one session fused into one skeleton, exported."""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

from kinefuse.app.cli import args as shared
from kinefuse.capture.fusion.methods import METHODS


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``kinefuse fuse``."""
    p = sub.add_parser("fuse", help="fuse a session's joints into one skeleton")
    p.add_argument("session", type=Path, help="session store (.sqlite) to fuse")
    shared.add_calibration_args(p)
    p.add_argument(
        "--method",
        default="best",
        choices=METHODS,
        help="fusion method (best; best-live is the causal fusion a live server runs)",
    )
    p.add_argument("--out", type=Path, help="export the fused skeleton (.c3d, .trc, .csv or .bvh)")
    p.add_argument(
        "--trc-axes",
        choices=["y-up", "z-up"],
        default="y-up",
        help="axes of a .trc export: OpenSim's Y up (default) or the lab's Z up",
    )
    p.add_argument(
        "--store",
        action="store_true",
        help="also store the fused skeleton in the session (otherwise the session is only read)",
    )
    shared.add_people_args(p)
    shared.add_span_args(p)
    shared.add_partial_arg(p)
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from kinefuse.app.workflows.fuse import run_fuse
    from kinefuse.app.workflows.progress import TerminalProgress

    with TerminalProgress("fuse", enabled=not args.json) as progress:
        info = run_fuse(
            session=args.session,
            method=args.method,
            out=args.out,
            calibration=args.calibration,
            true_calibration=args.true_calibration,
            store_result=args.store,
            allow_incomplete=args.partial,
            trc_axes=args.trc_axes,
            start_s=args.start,
            end_s=args.end,
            progress=progress,
            subject=args.subject,
            people=args.people,
        )
    for w in said_once(list(info.warnings)):
        print(f"kinefuse: warning: {w}", file=sys.stderr)
    if args.json:
        print(json.dumps(info.as_dict(), indent=2))
    else:
        status = ", ".join(f"{k} {v}" for k, v in info.status.items() if v)
        print(
            f"fused {info.frames} frames with {info.method} ({info.calibration}) in "
            f"{info.seconds:.2f} s; joint status: {status}"
        )
        if info.stored_in_session:
            print(
                f"stored the fused skeleton in {args.session} (method {info.method}); "
                f"replay it: kinefuse view {shlex.quote(str(args.session))}"
            )
        if len(info.people) > 1:
            print(
                f"people {', '.join(map(str, info.people))}; the subject is person "
                f"{info.subject} ({info.subject_rule})"
            )
        for w in info.written:
            print(f"wrote {w}")
    return 0


def said_once(warnings: list[str]) -> list[str]:
    """Each warning once, in order: repeats of one text with its count, and one text about
    several things (``"out.bvh: Hips: rotation held on 30 of 359 frames"``, one per joint)
    as one line naming them (``"out.bvh: rotation held on 30 of 359 frames (24 times: Hips,
    Spine, ...)"``)."""
    groups: dict[str, list[str]] = {}
    first: dict[str, str] = {}
    for w in warnings:
        parts = w.split(": ", 2)
        if len(parts) == 3 and " " not in parts[1]:  # FILE: THING: text
            key = f"{parts[0]}: {parts[2]}"
            groups.setdefault(key, []).append(parts[1])
        else:
            key = w
            groups.setdefault(key, []).append("")
        first.setdefault(key, w)
    out = []
    for key, things in groups.items():
        named = [t for t in things if t]
        if len(things) == 1:
            out.append(first[key])
        elif named:
            out.append(f"{key} ({len(things)} times: {', '.join(named)})")
        else:
            out.append(f"{key} (said {len(things)} times)")
    return out

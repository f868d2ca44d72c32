"""``kinefuse calibrate``: every sensor's pose from a wand phase (a session, or live)."""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from kinefuse.app.cli import args as shared
from kinefuse.capture.calibration.methods import DETECTORS, METHODS

if TYPE_CHECKING:
    from kinefuse.app.workflows.calibrate import CalibrateResult


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``kinefuse calibrate``."""
    p = sub.add_parser("calibrate", help="find every sensor's pose from the wand phase")
    p.add_argument("session", type=Path, nargs="?", help="session store (or --live HOST:PORT)")
    _add_live_args(p)
    p.add_argument("--method", choices=METHODS, default="full", help="registration (full)")
    p.add_argument(
        "--detector",
        choices=DETECTORS,
        help="wand detector (default: the method's own: paper for paper, robust for full)",
    )
    p.add_argument("--out", type=Path, help="write the calibration file (TOML)")
    p.add_argument(
        "--store",
        action="store_true",
        help="also store the calibration in the session (otherwise the session is only read)",
    )
    p.add_argument(
        "--accept",
        action="store_true",
        help="write a calibration even when it grades as failed (exit code 0)",
    )
    p.add_argument(
        "--report",
        type=Path,
        help="folder for the paper-style error plots (sessions with truth only)",
    )
    shared.add_partial_arg(p)
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run)


def _where_it_went(args: argparse.Namespace, r: CalibrateResult) -> str:
    """Where the calibration went, and the exact command of the next step."""
    session = shlex.quote(str(args.session))
    if r.stored_in_session:
        return (
            f"stored the calibration in {args.session} (as {r.method!r}); next: "
            f"kinefuse fuse {session} --method best --store"
        )
    if r.out:
        return (
            f"the session was only read (not stored in it); fuse with this file: kinefuse fuse "
            f"{session} --calibration {shlex.quote(str(r.out))} --method best --store"
        )
    return (
        "the calibration was not stored anywhere (the session is only read); to keep it in the "
        f"session: kinefuse calibrate {session} --method {args.method} --store"
    )


def _add_live_args(p: argparse.ArgumentParser) -> None:
    """The ``--live`` options of ``kinefuse calibrate``."""

    p.add_argument(
        "--live",
        type=shared.host_port,
        metavar="HOST:PORT",
        help="calibrate through a running `kinefuse serve` instead of a session",
    )
    p.add_argument(
        "--seconds",
        type=shared.positive_float,
        help="(--live) stop the wand phase after this long (default: when the wand is put away)",
    )
    p.add_argument(
        "--token-file",
        type=Path,
        metavar="FILE",
        help="(--live) read the server's token from FILE (default: KINEFUSE_TOKEN)",
    )
    p.add_argument("--token", help="(--live) the token itself (visible in ps: prefer a file)")


def run(args: argparse.Namespace) -> int:
    from kinefuse.app.workflows.calibrate import format_calibrate, run_calibrate
    from kinefuse.errors import CalibrationFailed

    if args.live is not None or args.session is None:
        return _run_live(args)
    try:
        r = run_calibrate(
            session=args.session,
            method=args.method,
            out=args.out,
            report_dir=args.report,
            store_result=args.store,
            accept=args.accept,
            allow_incomplete=args.partial,
            detector=args.detector,
        )
    except CalibrationFailed as e:  # a failed calibration, not a user error: exit 3
        print(f"kinefuse: error: {e}", file=sys.stderr)
        return 3
    if args.json:
        print(json.dumps(r.as_dict(), indent=2))
    else:
        print(format_calibrate(r))
        for w in [r.out, *(r.written or ())]:
            if w:
                print(f"wrote {w}")
        if r.report_note:
            print(r.report_note)
        if r.grade != "failed" or r.accepted:
            print(_where_it_went(args, r))
    if r.grade == "failed" and not r.accepted:
        print(
            f"kinefuse: error: calibration failed ({'; '.join(r.reasons)}); nothing was "
            "written (pass --accept to keep it anyway)",
            file=sys.stderr,
        )
        return 3
    return 0


def _run_live(args: argparse.Namespace) -> int:
    """``kinefuse calibrate --live HOST:PORT``."""
    from kinefuse.app.workflows.serve import format_calibrate_live, run_calibrate_live, token_from
    from kinefuse.errors import KinefuseError

    if args.live is None:
        raise KinefuseError("give a session to calibrate, or --live HOST:PORT of a server")
    if args.session is not None:
        raise KinefuseError("give either a session or --live HOST:PORT, not both")
    r = run_calibrate_live(
        address=args.live,
        method=args.method,
        seconds=args.seconds,
        token=token_from(args.token, args.token_file),
    )
    print(json.dumps(r.as_dict(), indent=2) if args.json else format_calibrate_live(r))
    return 0 if r.accepted else 3

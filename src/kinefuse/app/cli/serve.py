"""``kinefuse serve``: the live server."""

from __future__ import annotations

import argparse
from pathlib import Path

from kinefuse.app.cli import args as shared
from kinefuse.capture.calibration.methods import METHODS as CALIBRATION_METHODS
from kinefuse.capture.fusion.methods import LIVE_METHODS


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``kinefuse serve``."""

    p = sub.add_parser("serve", help="run the live server: sensor clients in, fused frames out")
    p.add_argument("--host", default="127.0.0.1", help="bind address (127.0.0.1: this PC only)")
    p.add_argument("--port", type=int, default=7400, help="TCP port (7400; 0: a free one)")
    p.add_argument(
        "--token-file",
        type=Path,
        metavar="FILE",
        help="read the shared secret clients must prove from FILE (default: KINEFUSE_TOKEN)",
    )
    p.add_argument("--token", help="the shared secret itself (visible in ps: prefer --token-file)")
    p.add_argument(
        "--allow-weak-token",
        action="store_true",
        help="take a token under 128 bits of estimated entropy (it can be guessed offline from "
        "one recorded handshake; make a strong one with kinefuse token new FILE)",
    )
    p.add_argument("--record", type=Path, help="record everything into this NEW session file")
    p.add_argument("--calibration", type=Path, help="start with these poses (calibration TOML)")
    p.add_argument("--method", choices=LIVE_METHODS, default="best-live", help="live fusion")
    p.add_argument(
        "--latency-budget-ms",
        type=shared.nonneg_float,
        default=10.0,
        metavar="MS",
        help="wait this long for late frames before predicting (10 ms)",
    )
    p.add_argument(
        "--auto-calibrate",
        action="store_true",
        help="start the wand calibration as soon as a sensor without a pose joins",
    )
    p.add_argument(
        "--calibration-method", choices=CALIBRATION_METHODS, default="full", help="registration"
    )
    p.add_argument(
        "--wand-axis-m",
        type=shared.positive_float,
        metavar="M",
        help="the wand protocol's move between its two holds (m), to fix the scale",
    )
    p.add_argument(
        "--viewer-port",
        type=int,
        metavar="PORT",
        help="serve the live web viewer on this port (0: a free one; on --host)",
    )
    shared.add_allow_host_arg(p)
    p.add_argument(
        "--lsl",
        nargs="?",
        const="kinefuse",
        metavar="NAME",
        help="publish fused frames as a Lab Streaming Layer stream of type MoCap named NAME "
        "(default kinefuse; needs the extra kinefuse[lsl]; docs/lsl.md)",
    )
    p.add_argument(
        "--lsl-xml",
        type=Path,
        metavar="FILE",
        help="write the LSL stream's full description (XML) to this NEW file, for an inlet "
        "built without discovery",
    )
    shared.add_people_args(p, every=False)
    p.add_argument(
        "--people",
        choices=["subject", "all"],
        default="subject",
        help="with --lsl: the subject's stream only (default), or also one stream per person "
        "named by id (NAME_p0, NAME_p1, ...), created when the person appears",
    )
    p.add_argument("--verbose", action="store_true", help="log debug messages")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """``kinefuse serve``."""
    from kinefuse.app.workflows.serve import run_serve, token_from

    return run_serve(
        host=args.host,
        port=args.port,
        token=token_from(args.token, args.token_file),
        record=args.record,
        calibration=args.calibration,
        method=args.method,
        latency_budget_ms=args.latency_budget_ms,
        auto_calibrate=args.auto_calibrate,
        calibration_method=args.calibration_method,
        wand_axis_m=args.wand_axis_m,
        viewer_port=args.viewer_port,
        allow_hosts=tuple(args.allow_host),
        lsl=args.lsl,
        lsl_xml=args.lsl_xml,
        verbose=args.verbose,
        allow_weak_token=args.allow_weak_token,
        subject=args.subject,
        people=args.people,
    )

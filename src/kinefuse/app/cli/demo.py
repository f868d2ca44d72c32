"""``kinefuse demo``: the live system on this machine, then a report (docs/live.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from kinefuse.app.cli import args as shared


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``kinefuse demo``."""

    p = sub.add_parser(
        "demo",
        help="the live system on this machine: a server and one client process per simulated "
        "sensor, live calibration and capture, then an evaluation",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=Path("kinefuse-demo"),
        help="output folder (kinefuse-demo in the current folder; replaced only if an earlier "
        "demo made it)",
    )
    p.add_argument(
        "--seed",
        type=int,
        default=0,
        help="random seed of the simulation and the network jitter (0)",
    )
    p.add_argument("--sensors", type=int, default=4, help="simulated sensors (4)")
    p.add_argument(
        "--seconds", type=shared.positive_float, help="length of the captured motion (20 s at most)"
    )
    p.add_argument("--clip", type=Path, help="motion clip (default: the bundled CMU 01_01)")
    p.add_argument(
        "--net-jitter-ms",
        type=shared.nonneg_float,
        metavar="MS",
        help="put a proxy with asymmetric network jitter of mean MS between each client and "
        "the server",
    )
    p.add_argument("--json", action="store_true", help="print the figures as JSON")
    p.add_argument(
        "--viewer-port",
        type=int,
        default=0,
        metavar="PORT",
        help="port of the live web viewer the server serves on 127.0.0.1 while the demo runs "
        "(0: a free one; the URL is printed)",
    )
    p.add_argument("--no-viewer", action="store_true", help="run the server without the viewer")
    p.add_argument(
        "--offline",
        action="store_true",
        help="the offline pipeline instead (no processes: simulate, calibrate, fuse, compare "
        "every method; the other options do not apply)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.offline:  # the offline pipeline on a simulated session
        from kinefuse.app.workflows.demo import run_demo

        return run_demo(out_dir=args.out, seed=args.seed)
    from kinefuse.app.workflows.demo import run_live_demo

    return run_live_demo(
        out_dir=args.out,
        sensors=args.sensors,
        seconds=args.seconds,
        clip=args.clip,
        net_jitter_ms=args.net_jitter_ms,
        seed=args.seed,
        as_json=args.json,
        viewer_port=None if args.no_viewer else args.viewer_port,
    )

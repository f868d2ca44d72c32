"""``kinefuse sensor``: one live sensor client."""

from __future__ import annotations

import argparse
from pathlib import Path

from kinefuse.app.cli import args as shared
from kinefuse.capture.calibration.methods import DETECTORS
from kinefuse.capture.occlusion.rules import OCCLUSION_RULES


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``kinefuse sensor``."""
    p = sub.add_parser(
        "sensor",
        help="a sensor client: play one sensor's frames to a kinefuse server in real time",
        description="Play one sensor's frames to `kinefuse serve` as the sensor delivers them "
        "(docs/live.md). Stops cleanly on SIGINT/SIGTERM (exit 0); exit 3 when the server "
        "refuses (token, version, duplicate sensor id), 2 on bad input.",
    )
    p.add_argument(
        "--server",
        type=shared.host_port,
        metavar="HOST:PORT",
        help="address of the `kinefuse serve` to send to (required unless --list-sources)",
    )
    p.add_argument(
        "--source",
        help="sim:SESSION.sqlite#SENSOR_ID, simlive:CLIP#SENSOR_ID[?rig=RIG.toml&seed=N&"
        "calibration=S&seconds=S&sensors=N&depth_rate=HZ&bystander=CLIP2] (a simulated sensor, "
        "generated; bystander repeatable: another person, as simulate --bystander), "
        "multitrack:FILE.csv#KINECT_ID, kinect2json:FILE, "
        "a camera (mkv:FILE.mkv, k4a:[INDEX|SERIAL], realsense:[SERIAL], "
        "realsense-file:FILE.bag, kinect2), "
        "driver:MODULE:FACTORY[?KEY=VALUE&...][#SENSOR_ID] or an installed driver NAME:ARG "
        "(--list-sources lists them; required unless --list-sources)",
    )
    p.add_argument(
        "--tracker",
        metavar="NAME",
        help="the body tracker of a camera source (k4abt, pose, ...; default: none, depth only)",
    )
    p.add_argument(
        "--list-sources",
        action="store_true",
        help="list every source kind and tracker, whether it is installed, and how to install it",
    )
    p.add_argument(
        "--token-file",
        type=Path,
        metavar="FILE",
        help="read the server's shared token from FILE (default: $KINEFUSE_TOKEN); it never "
        "crosses the wire",
    )
    p.add_argument("--token", help="the token itself (visible in ps: prefer --token-file)")
    p.add_argument(
        "--truth-out",
        type=Path,
        help="write the emulation's truth (clock and play start) to this JSON, for evaluation",
    )
    p.add_argument(
        "--clock-offset-ms",
        type=shared.finite_float,
        help="emulated host clock at the play start, ms (default: the simulated sensor's, else 0)",
    )
    p.add_argument(
        "--clock-drift-ppm",
        type=shared.finite_float,
        help="emulated host clock rate error, ppm (default: the simulated sensor's, else 0)",
    )
    p.add_argument(
        "--epoch-monotonic",
        type=shared.finite_float,
        metavar="M",
        help="play source time T at CLOCK_MONOTONIC M + T / speed (clients in step; a late "
        "start skips to the present)",
    )
    p.add_argument(
        "--speed", type=shared.positive_float, default=1.0, help="source s per real s (1)"
    )
    p.add_argument(
        "--max-seconds",
        type=shared.positive_float,
        help="stop after this much source time (default: all)",
    )
    p.add_argument("--detector", choices=DETECTORS, default="robust", help="wand detector")
    p.add_argument(
        "--detect-every",
        type=shared.count,
        default=1,
        metavar="K",
        help="run wand detection on every K-th depth frame (1; busy frames are skipped anyway)",
    )
    p.add_argument(
        "--occlusion",
        choices=OCCLUSION_RULES,
        default="crossing",
        help="occlusion rule: the paper's bone crossing (default) or capsule coverage",
    )
    p.add_argument(
        "--serial", default="", help="the device's serial number for Hello (default: the source's)"
    )
    p.add_argument("-v", "--verbose", action="store_true", help="log every connection event")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from kinefuse.app.workflows.sensor import list_sources, run_sensor
    from kinefuse.app.workflows.serve import token_from
    from kinefuse.errors import InputError

    if args.list_sources:
        print(list_sources())
        return 0
    if args.server is None or not args.source:
        raise InputError(
            "kinefuse sensor needs --server HOST:PORT and --source SOURCE "
            "(kinefuse sensor --list-sources lists the sources)"
        )
    return run_sensor(
        clock_drift_ppm=args.clock_drift_ppm,
        clock_offset_ms=args.clock_offset_ms,
        detect_every=args.detect_every,
        detector=args.detector,
        epoch_monotonic=args.epoch_monotonic,
        max_seconds=args.max_seconds,
        occlusion=args.occlusion,
        serial=args.serial,
        server=args.server,
        source=args.source,
        speed=args.speed,
        token=token_from(args.token, args.token_file),
        tracker=args.tracker,
        truth_out=args.truth_out,
        verbose=args.verbose,
    )

"""``kinefuse simulate``: a session of a real clip seen by simulated sensors."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from kinefuse.app.cli import args as shared


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``kinefuse simulate``."""
    p = sub.add_parser("simulate", help="simulate a capture session of a real motion clip")
    p.add_argument("--clip", type=Path, required=True, help="motion clip (.bvh or .amc)")
    p.add_argument(
        "--bystander",
        type=Path,
        action="append",
        default=[],
        metavar="CLIP",
        help="another person in the room during the motion, driven by this clip, placed to pass "
        "within a metre of the subject, between the subject and a sensor (repeat for more; "
        "docs/error_model.md)",
    )
    _add_simulate_args(p)
    p.add_argument("--out", type=Path, required=True, help="session store to write (.sqlite)")
    p.add_argument(
        "--force",
        action="store_true",
        help="replace --out if it is a simulated kinefuse session (never any other file)",
    )
    p.set_defaults(func=run)


def _add_simulate_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--skeleton", type=Path, help="the ASF of an .amc clip (default: found beside it)"
    )
    p.add_argument(
        "--units",
        choices=["m", "cm", "mm", "in", "asf"],
        help="length unit of the clip (default: chosen so the subject's height is plausible)",
    )
    p.add_argument(
        "--name-map",
        type=Path,
        help="TOML map from the clip's joint names to Kinect joints (docs/motion.md)",
    )
    rig = p.add_mutually_exclusive_group()
    rig.add_argument("--rig", type=Path, help="rig file (TOML) with the sensors' poses")
    rig.add_argument("--sensors", type=int, default=4, help="sensors of the default layout (4)")
    p.add_argument(
        "--seconds", type=shared.positive_float, help="length of the motion (default: all)"
    )
    p.add_argument("--seed", type=int, default=0, help="random seed (0)")
    p.add_argument(
        "--subject-seed",
        type=int,
        help="seed of the subject's own tracker joint offsets: sessions with the same one are "
        "takes of the same person (default: drawn from --seed, a new person every session)",
    )
    p.add_argument(
        "--tracker",
        choices=("default", "light"),
        default="default",
        help="body-tracker model: the default one (with the gross failures and the person level "
        "fitted on the KinectMultiTrack population; every published figure stands on it) or "
        "light (without them, the model before issue 21; docs/realism.md)",
    )
    p.add_argument(
        "--errors-off",
        type=shared.error_parts,
        default=(),
        metavar="PART[,PART]",
        help="switch parts of the tracker's error model off, the rest seeded as without: "
        "subject, view, inferred, swap (shared by the sensors), pose, jitter, far, gross (each "
        "sensor's own), independent (all of each sensor's own); what a part costs "
        "(docs/error_model_tracker.md)",
    )
    p.add_argument(
        "--calibration-seconds",
        type=shared.nonneg_float,
        default=20.0,
        help="length of the wand-waving phase before the motion (20 s; 0 = none)",
    )
    p.add_argument(
        "--depth-rate",
        type=shared.positive_float,
        default=10.0,
        help="rate of the stored calibration depth frames, Hz (10)",
    )
    p.add_argument(
        "--room",
        type=shared.room,
        metavar="XMIN,YMIN,XMAX,YMAX",
        help="the room's floor rectangle XMIN,YMIN,XMAX,YMAX in metres (default: the rig's "
        "[room], else -4,-4,4,4; write --room=-5,-5,5,5); every sensor must stand inside it",
    )
    p.add_argument(
        "--rom",
        type=shared.positive_float,
        metavar="SECONDS",
        help="a range-of-motion calibration phase of SECONDS before the motion (docs/analysis.md)",
    )
    p.add_argument(
        "--static",
        type=shared.positive_float,
        metavar="SECONDS",
        help="a standing phase (static trial) of SECONDS before the range-of-motion phase, for "
        "the anatomical angles: analyze SESSION --static-window auto (docs/analysis.md)",
    )


def run(args: argparse.Namespace) -> int:
    from kinefuse.app.workflows.simulate import run_simulate

    r = run_simulate(
        clip=args.clip,
        skeleton=args.skeleton,
        units=args.units,
        name_map=args.name_map,
        rig=args.rig,
        sensors=args.sensors,
        seconds=args.seconds,
        seed=args.seed,
        calibration_s=args.calibration_seconds,
        depth_rate_hz=args.depth_rate,
        room=args.room,
        out=args.out,
        force=args.force,
        progress=lambda m: print(m, file=sys.stderr),
        rom_s=args.rom,
        subject_seed=args.subject_seed,
        tracker=args.tracker,
        static_s=args.static,
        errors_off=args.errors_off,
        bystanders=tuple(args.bystander),
    )
    for w in r.warnings:
        print(f"kinefuse: warning: {w}", file=sys.stderr)
    print(f"wrote {args.out}")
    return 0

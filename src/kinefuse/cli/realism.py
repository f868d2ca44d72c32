"""``kinefuse realism``: real against simulated Kinect v2 figures, take by take."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``kinefuse realism``."""
    p = sub.add_parser(
        "realism",
        help="simulated vs real Kinect v2 two-sensor disagreement (docs/realism.md)",
        description="Real against simulated Kinect v2 figures for KinectMultiTrack takes "
        "(docs/realism.md).",
    )
    p.add_argument(
        "--data",
        type=Path,
        default=None,
        help="the shared data folder (default: ../shared/data beside the project checkout)",
    )
    p.add_argument(
        "--take",
        type=Path,
        nargs="+",
        default=None,
        metavar="CSV",
        help="KinectMultiTrack take(s) (default: every CSV in DATA/kinect/kinect_multitrack)",
    )
    p.add_argument(
        "--population",
        type=Path,
        nargs="?",
        const=_DEFAULT_POPULATION,
        default=None,
        metavar="DIR",
        help="compare per layout the distribution of per-take figures over real participants "
        "with simulated subjects (default DIR: DATA/kinect/kinect_multitrack_population; with "
        "--take, over those takes)",
    )
    p.add_argument("--seeds", type=int, default=5, help="simulations per take (seeds 0..N-1)")
    p.add_argument("--clip", type=Path, default=None, help="walking clip (default CMU 02_walk_a)")
    p.add_argument("--per-joint", action="store_true", help="also print per-joint medians")
    p.add_argument(
        "--single", action="store_true", help="also check one simulated sensor against the truth"
    )
    p.add_argument("--json", action="store_true", help="print JSON instead of Markdown")
    p.add_argument(
        "--tracker",
        choices=("default", "light"),
        default="default",
        help="the simulated body-tracker model: default (with the gross failures and the person "
        "level, every published figure stands on it) or light (without them; docs/realism.md)",
    )
    p.set_defaults(func=run)


#: stands for DATA/kinect/kinect_multitrack_population (resolved once --data is known)
_DEFAULT_POPULATION = Path("<population>")


def run(args: argparse.Namespace) -> int:
    """Exit 1 on a missed target."""
    from kinefuse.workflows.realism import DEFAULT_DATA, run_realism

    population = args.population
    if population == _DEFAULT_POPULATION:
        data = DEFAULT_DATA if args.data is None else args.data
        population = data / "kinect" / "kinect_multitrack_population"

    return run_realism(
        data=args.data,
        takes=args.take,
        seeds=args.seeds,
        clip=args.clip,
        per_joint=args.per_joint,
        single=args.single,
        as_json=args.json,
        population=population,
        tracker=args.tracker,
    )

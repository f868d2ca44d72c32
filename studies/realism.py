"""Real against simulated Kinect v2 figures for KinectMultiTrack takes (``docs/realism.md``).

Real vs simulated figures for every KinectMultiTrack take (registration-independent procedure),
per layout over a population of participants, and, with ``--single``, single simulated sensors
against the truth::

    python studies/realism.py [--take CSV ...] [--seeds N] [--per-joint] [--single] [--json]
    python studies/realism.py --population [DIR] [--seeds 2]
    python studies/realism.py --smoke     # one take, one seed, --single: checks that it runs

Reads ``../shared/data`` beside the project (``--data`` to read another folder). Exit status 0
when every realism target is met, 1 when one is missed, 2 on bad input; with ``--smoke`` 0
whenever it ran (one seed is too few to hold a target to).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from kinefuse.app.workflows.simulate import tracker_model
from kinefuse.errors import InputError
from kinefuse.lab.realism import (
    DEFAULT_HEADINGS,
    default_walk_path,
    load_walk,
    walking_passes,
)
from kinefuse.lab.realism_person import population_seeds
from kinefuse.lab.realism_population import (
    format_population,
    population_failures,
    population_summary,
)
from kinefuse.lab.realism_single import format_single, single_sensor_realism
from kinefuse.lab.realism_takes import compare_take, format_take, format_take_joints

#: ../shared/data beside the project checkout (where the repository's data lives)
DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def run_realism(
    *,
    data: Path = DATA,
    takes: Sequence[Path] | None = None,
    seeds: int = 5,
    clip: Path | None = None,
    per_joint: bool = False,
    single: bool = False,
    as_json: bool = False,
    population: Path | None = None,
    progress: bool | None = None,
    tracker: str = "default",
) -> int:
    """Print real against simulated figures per take; 0 if every target holds, else 1.

    ``population`` (a folder of takes) compares per layout the distribution of per-take figures
    over its real participants with the same over simulated subjects (``takes`` narrows it to
    the given takes); the exit status is then the population acceptance's. ``progress`` prints
    one line per take on stderr (default: when stdout is a terminal and not ``as_json``).
    """
    if seeds < 1:
        raise InputError(f"--seeds must be at least 1, got {seeds}")
    if takes is None and population is not None:
        takes = sorted(Path(population).glob("*.csv"))
        if not takes:
            raise InputError(f"no KinectMultiTrack takes in {population}; pass --population DIR")
    elif takes is None:
        folder = data / "kinect" / "kinect_multitrack"
        takes = sorted(folder.glob("*.csv"))
        if not takes:
            raise InputError(f"no KinectMultiTrack takes in {folder}; pass --take CSV")
    else:
        takes = list(takes)
        # the takes the user named are checked before anything else is looked for or loaded
        missing = [t for t in takes if not Path(t).is_file()]
        if missing:
            raise InputError(
                f"{missing[0]}: no such file; give the path of a KinectMultiTrack CSV log"
            )
    clip = clip or default_walk_path(data)
    if not Path(clip).is_file():
        raise InputError(f"walking clip not found: {clip}; pass --clip or --data")
    walk = load_walk(clip)
    params = tracker_model(tracker)
    if progress is None:
        progress = sys.stdout.isatty() and not as_json
    results = []
    for i, t in enumerate(takes):
        if progress:
            print(f"[{i + 1}/{len(takes)}] {Path(t).name} ({seeds} seeds)", file=sys.stderr)
        take_seeds = (
            population_seeds(Path(t).name, seeds) if population is not None else range(seeds)
        )
        results.append(compare_take(t, walk, take_seeds, params=params))
    if population is not None:
        summary = population_summary(results)
        if as_json:
            doc = {"takes": [r.to_json() for r in results], "population": summary}
            print(json.dumps(doc, indent=2))
        else:
            print(format_population(summary))
            if per_joint:
                print("\n" + format_take_joints(results))
        return 0 if not population_failures(summary) else 1
    if as_json:
        print(json.dumps({"takes": [r.to_json() for r in results]}, indent=2))
    else:
        for r in results:
            print(format_take(r) + "\n")
        if per_joint:
            print(format_take_joints(results) + "\n")
        if single:
            one = single_sensor_realism(
                walking_passes(walk, DEFAULT_HEADINGS), np.random.default_rng(0)
            )
            print(format_single(one))
    return 0 if all(not r.failures() for r in results) else 1


#: stands for DATA/kinect/kinect_multitrack_population (resolved once --data is known)
_DEFAULT_POPULATION = Path("<population>")


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python studies/realism.py", description=__doc__.splitlines()[0]
    )
    p.add_argument("--smoke", action="store_true", help="one take, one seed, --single (seconds)")
    p.add_argument("--data", type=Path, default=DATA, help="the data folder (../shared/data)")
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
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = parser().parse_args(argv)
    population = args.population
    if population == _DEFAULT_POPULATION:
        population = args.data / "kinect" / "kinect_multitrack_population"
    takes, seeds, single = args.take, args.seeds, args.single
    if args.smoke:
        shortest = min((args.data / "kinect" / "kinect_multitrack").glob("*.csv"), key=_size)
        takes, seeds, single = [shortest], 1, True
    start = time.perf_counter()
    try:
        status = run_realism(
            data=args.data,
            takes=takes,
            seeds=seeds,
            clip=args.clip,
            per_joint=args.per_joint,
            single=single,
            as_json=args.json,
            population=population,
            tracker=args.tracker,
        )
    except InputError as e:
        print(f"realism: error: {e}", file=sys.stderr)
        return 2
    if not args.json:
        print(f"\n(computed in {time.perf_counter() - start:.1f} s)")
    if args.smoke and status == 1:  # 1: a target missed; 2 and others: an error
        print("(smoke: a target missed on one seed is not a failure of the run)")
        return 0
    return status


def _size(path: Path) -> int:
    return path.stat().st_size


if __name__ == "__main__":
    raise SystemExit(main())

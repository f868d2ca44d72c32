"""``kinefuse realism``: real against simulated figures for KinectMultiTrack takes (the logic;
the options are in :mod:`kinefuse.cli.realism`)."""

from __future__ import annotations

import json
import sys
import zlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from kinefuse.errors import InputError
from kinefuse.evaluation.realism import (
    DEFAULT_HEADINGS,
    default_walk_path,
    load_walk,
    walking_passes,
)
from kinefuse.evaluation.realism_person import subject_seed
from kinefuse.evaluation.realism_population import (
    format_population,
    population_failures,
    population_summary,
)
from kinefuse.evaluation.realism_single import format_single, single_sensor_realism
from kinefuse.evaluation.realism_takes import compare_take, format_take, format_take_joints
from kinefuse.workflows.simulate import tracker_model

#: ../shared/data beside the project checkout (where the repository's data lives)
DEFAULT_DATA = Path(__file__).resolve().parents[3].parent / "shared" / "data"


def population_seeds(file_name: str, n: int) -> list[int]:
    """The ``n`` simulated subjects of a take in a population comparison: the participant's own
    (:func:`~kinefuse.evaluation.realism_person.subject_seed`, shared by that participant's takes
    at every layout), or, for a file not named as KinectMultiTrack names its takes, seeds of its
    own from its name. Seeds ``0..n-1`` for every take would give every take of a layout the same
    ``n`` person-level draws, and the simulated spread between people would rest on ``n``."""
    try:
        return [subject_seed(file_name, k) for k in range(n)]
    except InputError:
        base = 1000 * (1000 + zlib.crc32(file_name.encode()) % 1_000_000)
        return [base + k for k in range(n)]


def run_realism(
    *,
    data: Path | None = None,
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
    over its real participants with the same over simulated subjects (``--take`` narrows it to
    the given takes); the exit status is then the population acceptance's. ``progress`` prints
    one line per take on stderr (default: when stdout is a terminal and not ``as_json``).
    """
    data = DEFAULT_DATA if data is None else data
    takes_arg = takes
    clip_arg = clip
    if seeds < 1:
        raise InputError(f"--seeds must be at least 1, got {seeds}")
    if takes_arg is None and population is not None:
        takes = sorted(Path(population).glob("*.csv"))
        if not takes:
            raise InputError(f"no KinectMultiTrack takes in {population}; pass --population DIR")
    elif takes_arg is None:
        folder = data / "kinect" / "kinect_multitrack"
        takes = sorted(folder.glob("*.csv"))
        if not takes:
            raise InputError(f"no KinectMultiTrack takes in {folder}; pass --take CSV")
    else:
        takes = list(takes_arg)
        # the takes the user named are checked before anything else is looked for or loaded
        missing = [t for t in takes if not Path(t).is_file()]
        if missing:
            raise InputError(
                f"{missing[0]}: no such file; give the path of a KinectMultiTrack CSV log"
            )
    clip = clip_arg or default_walk_path(data)
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

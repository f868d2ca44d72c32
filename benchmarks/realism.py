"""Recompute the realism tables of ``docs/realism.md``.

Real vs simulated figures for every KinectMultiTrack take (registration-independent procedure)
and, with ``--single``, single simulated sensors against the truth::

    python benchmarks/realism.py [--take CSV ...] [--seeds N] [--per-joint] [--single] [--json]
    python benchmarks/realism.py --smoke     # one take, one seed, --single: checks that it runs

The same as ``kinefuse realism`` (the options are that command's). Reads ``../shared/data``
beside the project. Exit status 0 when every realism target is met; with ``--smoke`` 0 whenever
it ran (one seed is too few to hold a target to), non-zero on an error.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from kinefuse.cli.main import main

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def run(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], add_help=False)
    ap.add_argument("--smoke", action="store_true", help="one take, one seed (seconds)")
    known, args = ap.parse_known_args(argv)
    smoke = known.smoke
    if "-h" in args or "--help" in args:  # this script's option, then kinefuse realism's
        print(ap.format_help())
    if "--data" not in args:
        args = ["--data", str(DATA), *args]
    if smoke:
        takes = (DATA / "kinect" / "kinect_multitrack").glob("*.csv")
        take = min(takes, key=lambda p: p.stat().st_size)  # the shortest
        args += ["--take", str(take), "--seeds", "1", "--single"]
    start = time.perf_counter()
    status = main(["realism", *args])
    print(f"\n(computed in {time.perf_counter() - start:.1f} s)")
    if smoke and status == 1:  # 1: a target missed; 2 and others: an error
        print("(smoke: a target missed on one seed is not a failure of the run)")
        return 0
    return status


if __name__ == "__main__":
    raise SystemExit(run(sys.argv[1:]))

"""Recompute the realism tables of ``docs/realism.md``.

Real vs simulated figures for every KinectMultiTrack take (registration-independent procedure)
and, with ``--single``, single simulated sensors against the truth::

    python benchmarks/realism.py [--take CSV ...] [--seeds N] [--per-joint] [--single] [--json]

The same as ``kinefuse realism``. Reads ``../shared/data`` beside the project. Exit status 0
when every realism target is met.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from kinefuse.evaluation.realism import main

if __name__ == "__main__":
    data = Path(__file__).resolve().parents[1].parent / "shared" / "data"
    args = sys.argv[1:]
    if "--data" not in args:
        args = ["--data", str(data), *args]
    start = time.perf_counter()
    status = main(args)
    print(f"\n(computed in {time.perf_counter() - start:.1f} s)")
    raise SystemExit(status)

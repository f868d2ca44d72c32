"""Peak memory and time of ``kinefuse evaluate`` on a 10-minute, 4-sensor session (issue 23 B;
target: peak RSS under 500 MB, so that an hour-long recording fits on a laptop).

Run: ``python benchmarks/bench_evaluate_memory.py [--smoke] [--keep PATH]`` (``--smoke``: 20 s
instead of 10 minutes, to check that it runs; ``--keep``: also copy the simulated session to
PATH). Simulates the session (the bundled clip played forward and backward, no depth frames),
then runs ``kinefuse evaluate --true-calibration`` (every method and the ablation) in a child
process and reads the child's peak resident set size from
``resource.getrusage(RUSAGE_CHILDREN).ru_maxrss``; also ``kinefuse fuse`` and the baseline, a
child that only imports kinefuse and numpy (the interpreter's own share of the figure).
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from kinefuse.io.store.session import SessionStore
from kinefuse.sim.lab import LabConfig, simulate_session
from kinefuse.sim.rig import default_rig, place_actor

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_simulate import long_motion

SECONDS = 600.0
TARGET_MB = 500.0


def child_peak_mb(argv: list[str]) -> tuple[float, float]:
    """(peak RSS MB, wall s) of ``python argv`` in a fresh child (one child per call: the
    children's figure is the largest of all children so far, so each runs in its own
    grandchild, measured by a child that reports it)."""
    probe = (
        "import resource, subprocess, sys, time\n"
        "t0 = time.perf_counter()\n"
        "r = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL)\n"
        "took = time.perf_counter() - t0\n"
        "peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss\n"
        "print(r.returncode, peak, took)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", probe, sys.executable, *argv],
        capture_output=True,
        text=True,
        check=True,
        env=os.environ,
    ).stdout.split()
    code, peak_kb, took = int(out[0]), int(out[1]), float(out[2])
    if code != 0:
        raise SystemExit(f"{' '.join(argv)} exited with {code}")
    return peak_kb / 1024, took


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="20 s of 4 sensors (seconds to run)")
    ap.add_argument("--keep", type=Path, help="also keep the simulated session here")
    args = ap.parse_args()
    seconds = 20.0 if args.smoke else SECONDS
    rig = default_rig(4)
    motion = place_actor(long_motion(seconds), rig)
    with tempfile.TemporaryDirectory() as d:
        session = Path(d) / "session.sqlite"
        t0 = time.perf_counter()
        simulate_session(
            motion, rig, session, LabConfig(seed=0, calibration_s=0.0, motion_s=seconds)
        )
        t_sim = time.perf_counter() - t0
        with SessionStore.open(session, writable=True) as st:
            st.mark_complete()  # as `kinefuse simulate` does once the session is whole
        if args.keep is not None:
            shutil.copy(session, args.keep)
        base_mb, _ = child_peak_mb(["-c", "import numpy, kinefuse.cli.main"])
        fuse_mb, fuse_s = child_peak_mb(
            ["-m", "kinefuse", "fuse", str(session), "--true-calibration", "--json"]
        )
        eval_mb, eval_s = child_peak_mb(
            ["-m", "kinefuse", "evaluate", str(session), "--true-calibration", "--json"]
        )
    assert resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss > 0
    print(f"{seconds / 60:.2g} min x 4 sensors (simulated in {t_sim:.0f} s)")
    print(f"  baseline (python + numpy + kinefuse imported): {base_mb:7.0f} MB peak RSS")
    print(f"  kinefuse fuse --method best:                   {fuse_mb:7.0f} MB, {fuse_s:6.1f} s")
    print(f"  kinefuse evaluate (all methods + ablation):    {eval_mb:7.0f} MB, {eval_s:6.1f} s")
    verdict = "meets" if eval_mb < TARGET_MB else "MISSES"
    print(f"  evaluate {verdict} the target of {TARGET_MB:.0f} MB peak")


if __name__ == "__main__":
    main()

"""Peak memory and time of ``kinefuse evaluate`` on a 10-minute, 4-sensor session (issue 23 B;
target: peak RSS under 500 MB, so that an hour-long recording fits on a laptop), and whether the
peak grows with the session's length.

Run: ``python benchmarks/bench_evaluate_memory.py [--smoke] [--keep PATH] [--json FILE]``
(``--smoke``: 10 and 20 s instead of 5 and 10 minutes, to check that it runs; ``--keep``: also
copy the longer simulated session to PATH). Simulates two sessions, one twice as long as the
other (the bundled clip played forward and backward, no depth frames), then runs in child
processes ``kinefuse evaluate --true-calibration`` (every method and the ablation),
``kinefuse fuse --out CSV`` and ``kinefuse analyze --true-calibration --no-plots`` on each and
reads each child's peak resident set size from ``resource.getrusage(RUSAGE_CHILDREN).ru_maxrss``;
also the baseline, a child that only imports kinefuse and numpy (the interpreter's own share of
the figure). Prints per command the peak of both, their ratio (2.0 = the peak grows in proportion
to the session; 1.0 = not at all) and the ratio of the peaks above the baseline. Wall times are
noisy on a shared machine.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from kinefuse.formats.store.session_store import SessionStore
from kinefuse.sim.lab import LabConfig, simulate_session
from kinefuse.sim.rig import default_rig, place_actor

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_simulate import long_motion

SECONDS = (300.0, 600.0)
SMOKE_SECONDS = (10.0, 20.0)
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


def simulate(seconds: float, path: Path) -> float:
    """A ``seconds`` long 4-sensor session at ``path``, complete; returns the time it took."""
    rig = default_rig(4)
    motion = place_actor(long_motion(seconds), rig)
    t0 = time.perf_counter()
    simulate_session(motion, rig, path, LabConfig(seed=0, calibration_s=0.0, motion_s=seconds))
    with SessionStore.open(path, writable=True) as st:
        st.mark_complete()  # as `kinefuse simulate` does once the session is whole
    return time.perf_counter() - t0


def commands(session: Path, work: Path) -> dict[str, list[str]]:
    """The commands measured, as ``python`` arguments."""
    k = ["-m", "kinefuse"]
    return {
        "evaluate": [*k, "evaluate", str(session), "--true-calibration", "--json"],
        "fuse": [*k, "fuse", str(session), "--true-calibration", "--out", str(work / "x.csv")],
        "analyze": [
            *k,
            "analyze",
            str(session),
            "--true-calibration",
            "--no-plots",
            "--out",
            str(work / "analysis"),
            "--json",
        ],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="10 and 20 s of 4 sensors (seconds)")
    ap.add_argument("--keep", type=Path, help="also keep the longer simulated session here")
    ap.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    args = ap.parse_args()
    durations = SMOKE_SECONDS if args.smoke else SECONDS
    base_mb, _ = child_peak_mb(["-c", "import numpy, kinefuse.app.cli.main"])
    peaks: dict[str, list[float]] = {}
    walls: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory() as d:
        for seconds in durations:
            run = Path(d) / f"{seconds:g}s"
            run.mkdir()
            session = run / "session.sqlite"
            t_sim = simulate(seconds, session)
            print(f"{seconds / 60:.2g} min x 4 sensors simulated in {t_sim:.0f} s", flush=True)
            if args.keep is not None and seconds == durations[-1]:
                shutil.copy(session, args.keep)
            for name, argv in commands(session, run).items():
                mb, took = child_peak_mb(argv)
                peaks.setdefault(name, []).append(mb)
                walls.setdefault(name, []).append(took)
    assert resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss > 0
    short, long_ = (f"{s / 60:.2g} min" for s in durations)
    print(f"baseline (python + numpy + kinefuse imported): {base_mb:.0f} MB peak RSS")
    print(f"{'command':<10} {short:>9} {long_:>9} {'ratio':>6} {'above baseline':>15}  wall s")
    for name, (a, b) in peaks.items():
        above = (b - base_mb) / max(a - base_mb, 1e-9)
        wa, wb = walls[name]
        print(f"{name:<10} {a:6.0f} MB {b:6.0f} MB {b / a:6.2f} {above:15.2f}  "
              f"{wa:.1f}, {wb:.1f}")  # fmt: skip
    eval_mb = peaks["evaluate"][-1]
    verdict = "meets" if eval_mb < TARGET_MB else "MISSES"
    print(f"evaluate on {long_}: {eval_mb:.0f} MB, {verdict} the target of {TARGET_MB:.0f} MB peak")
    if args.json is not None:
        doc = {
            "seconds": list(durations),
            "baseline_mb": base_mb,
            "peak_mb": peaks,
            "wall_s": walls,
            "target_mb": TARGET_MB,
        }
        args.json.write_text(json.dumps(doc, indent=2) + "\n")


if __name__ == "__main__":
    main()

"""The live demo's acceptance figures (issue 11): time, clock, latency, accuracy.

Run: ``python benchmarks/bench_live.py [--sensors 4] [--seconds 20] [--jitter 3]``. Runs
``kinefuse demo --sensors N --seconds S --json`` twice as a user would (a separate process, the
same Python), once on plain loopback and once with ``--net-jitter-ms`` through the proxies, and
prints per run: the wall time against the 2-minute budget and against the time the session itself
lasts in real time (wand phase + motion: the floor no live run can beat, measured in the same run),
the clock offset error (p50, max after 5 s), the latency host receive -> fused frame published
(p50, p99; p99 also over the frames published before the first client left, i.e. without the
stop, when the last frames wait for clients that have ended), live MAE against offline ``best`` on
the same frames, and the calibration's error.
Targets (issue 11): under 120 s; with jitter: clock p50 < 0.5 ms, max < 2 ms, latency p99 < 50 ms,
live MAE within 15 % of offline ``best``.

``--load [--hogs N] [--runs K]`` (issue 23): K demo runs (plain loopback) each beside N CPU hogs
(``while True: pass`` processes, default one per CPU); per run the live calibration's mean and
worst sensor error against the true rig, its grade and the server's reasons, and whether every
run more than 3 mm off was graded doubtful or failed (``--load --smoke``: one 2-sensor run
beside one hog).

``--smoke``: the jitter run only, 2 sensors, 3 s of motion (after the demo's wand phase), to check
that it runs; exit 0 whatever the figures. Every run is bounded: a demo still running after its
time limit gets SIGTERM (it then stops its own processes: a clean stop, then a kill), then SIGKILL.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from kinefuse.app.workflows.demo import DEMO_CALIBRATION_S

#: how long the demo gets to stop its processes after SIGTERM before it is killed, seconds (its
#: own clean stop, then kill, of a child takes up to 25 s: STOP_TIMEOUT_S + KILL_TIMEOUT_S)
STOP_GRACE_S = 40.0


def run_demo(
    out: Path, sensors: int, seconds: float, jitter: float | None, timeout_s: float = 600.0
) -> dict[str, Any]:
    cmd = [sys.executable, "-m", "kinefuse", "demo", "--out", str(out), "--sensors", str(sensors),
           "--seconds", f"{seconds:g}", "--json"]  # fmt: skip
    if jitter is not None:
        cmd += ["--net-jitter-ms", f"{jitter:g}"]
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        stdout, stderr = proc.communicate(timeout=timeout_s)
    except BaseException:  # the time limit, or Ctrl-C: the demo stops what it started
        proc.terminate()
        try:
            proc.communicate(timeout=STOP_GRACE_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
        raise
    wall = time.monotonic() - t0
    if proc.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{stderr[-3000:]}")
    r: dict[str, Any] = json.loads(stdout)
    r["wall_s"] = wall
    return r


@contextlib.contextmanager
def cpu_hogs(n: int) -> Iterator[None]:
    """``n`` processes that spin on the CPU (pure Python, nice 0) for as long as the block runs."""
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        yield
    finally:
        for h in hogs:
            h.kill()
        for h in hogs:
            h.wait(10)


def run_loaded(args: argparse.Namespace) -> None:
    """``--load``: the demo beside ``--hogs`` CPU hogs, ``--runs`` times; the calibration's
    error against the true rig and its grade (with the server's reasons) per run."""
    print(f"kinefuse demo --sensors {args.sensors} --seconds {args.seconds:g} --json beside "
          f"{args.hogs} CPU hog(s) (while True: pass), {args.runs} run(s); on "
          f"{os.cpu_count()} CPUs\n")  # fmt: skip
    print("| run | wall s | calibration mm | worst sensor mm | grade | > 3 mm | graded "
          "doubtful/failed | reasons |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    ok = True
    with tempfile.TemporaryDirectory() as d:
        for k in range(args.runs):
            with cpu_hogs(args.hogs):
                r = run_demo(Path(d) / f"demo{k}", args.sensors, args.seconds, None, 900.0)
            c = r["calibration"]
            err = c["mean_position_error_m"]
            worst = max((v["position_error_m"] for v in c["by_sensor"].values()), default=None)
            bad = err is not None and err > 0.003
            flagged = c["grade"] in ("doubtful", "failed")
            ok &= flagged or not bad
            reasons = "; ".join(c.get("reasons") or []) or "-"
            print(f"| {k + 1} | {r['wall_s']:.1f} | {_f(1e3 * err, '.2f')} | "
                  f"{_f(None if worst is None else 1e3 * worst, '.2f')} | {c['grade']} | "
                  f"{'yes' if bad else 'no'} | {'yes' if flagged else 'no'} | {reasons} |",
                  flush=True)  # fmt: skip
    print(f"\ndoubtful or failed whenever the error exceeds 3 mm: {'yes' if ok else 'NO'}")


def _f(v: object, fmt: str = ".3f") -> str:
    return "n/a" if not isinstance(v, int | float) else format(v, fmt)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sensors", type=int, default=4)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--jitter", type=float, default=3.0, help="--net-jitter-ms of the second run")
    ap.add_argument("--smoke", action="store_true", help="one short run of 2 sensors")
    ap.add_argument("--load", action="store_true",
                    help="beside CPU hogs: the calibration error and grade")  # fmt: skip
    ap.add_argument("--hogs", type=int, default=os.cpu_count() or 2,
                    help="CPU hogs with --load (default: one per CPU)")  # fmt: skip
    ap.add_argument("--runs", type=int, default=3, help="demo runs with --load (3)")
    args = ap.parse_args()
    if args.load:
        if args.smoke:
            args.sensors, args.seconds, args.runs, args.hogs = 2, 3.0, 1, 1
        run_loaded(args)
        return
    jitters: tuple[float | None, ...] = (None, args.jitter)
    timeout_s = 600.0
    if args.smoke:
        args.sensors, args.seconds, jitters, timeout_s = 2, 3.0, (args.jitter,), 120.0
    floor_s = DEMO_CALIBRATION_S + args.seconds
    print(f"kinefuse demo --sensors {args.sensors} --seconds {args.seconds:g} --json; the session "
          f"lasts {floor_s:g} s in real time (wand phase + motion)\n")  # fmt: skip
    print("| run | wall s | wall / session | < 120 s | frames | clock p50 ms | clock max ms | "
          "latency p50 ms | latency p99 ms | p99 before the stop ms | MAE live cm | "
          "MAE offline cm | live / offline | calibration mm | grade |")  # fmt: skip
    print("|---|" + "---|" * 14)
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for jitter in jitters:
            r = run_demo(Path(d) / "demo", args.sensors, args.seconds, jitter, timeout_s)
            rows.append((jitter, r))
            m, c, k, lat = r["mae_m"], r["calibration"], r["clock_offset_error_ms"], r["latency_ms"]
            name = "loopback" if jitter is None else f"jitter {jitter:g} ms"
            print(
                f"| {name} | {r['wall_s']:.1f} | {r['wall_s'] / floor_s:.2f} | "
                f"{'yes' if r['wall_s'] < 120 else 'NO'} | {r['frames_fused']} | "
                f"{_f(k['p50'])} | {_f(k['max'])} | {_f(lat['p50'], '.1f')} | "
                f"{_f(lat['p99'], '.1f')} | {_f(lat['before_first_disconnect']['p99'], '.1f')} | "
                f"{_f(100 * m['live'], '.2f')} | "
                f"{_f(100 * m['offline'], '.2f')} | {_f(m['ratio'])} | "
                f"{_f(1e3 * c['mean_position_error_m'], '.1f')} | {c['grade']} |"
            )
    _, r = rows[-1]
    k, lat, m = r["clock_offset_error_ms"], r["latency_ms"], r["mae_m"]
    checks = {
        "clock p50 < 0.5 ms": k["p50"] is not None and k["p50"] < 0.5,
        "clock max < 2 ms": k["max"] is not None and k["max"] < 2.0,
        "latency p99 < 50 ms (every published frame)": lat["p99"] is not None and lat["p99"] < 50.0,
        "latency p99 < 50 ms (frames before the first client left)": (
            lat["before_first_disconnect"]["p99"] or 1e9
        )
        < 50.0,
        "live MAE within 15 % of offline best": m["ratio"] is not None and m["ratio"] <= 1.15,
        "both runs under 2 minutes": all(x["wall_s"] < 120 for _, x in rows),
    }
    print(f"\nwith --net-jitter-ms {args.jitter:g}:")
    for what, ok in checks.items():
        print(f"  {what}: {'yes' if ok else 'NO'}")


if __name__ == "__main__":
    main()

"""What one fused frame costs the live server, against its 33 ms frame period (issue 11).

Run: ``python benchmarks/bench_server_fusion.py [--sensors 4] [--seconds 5] [--smoke]``
(``--smoke``: 2 sensors, 2 s, a shorter wand phase: checks that it runs). Simulates a
session, calibrates it offline (``full``), then feeds every observation to the server's
:class:`kinefuse.live.server.fusion_loop.FrameFusion` as the fusion loop does (observations captured
up to ``T + lead`` before frame ``T``) and times ``fuse`` per frame, for ``best-live`` and the
paper's chain. Prints ms per frame and the share of the frame period: the fusion runs on the
event loop, so this is also how long a clock-probe reply can wait to be stamped; and, as the
baseline measured in the same run, ``best-live``'s time as a ratio of the paper's chain's.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from kinefuse.app.workflows.calibrate import run_calibrate
from kinefuse.app.workflows.simulate import demo_clip_path, run_simulate
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.lab.poses import resolve_poses
from kinefuse.live.server.fusion_loop import FrameFusion
from kinefuse.live.server.sensor_state import Observation
from kinefuse.pipeline.store_inputs import frame_grid, load_sensors


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sensors", type=int, default=4)
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--calibration-s", type=float, default=10.0, help="wand phase, seconds")
    ap.add_argument("--smoke", action="store_true", help="2 sensors, 2 s (seconds to run)")
    a = ap.parse_args()
    if a.smoke:
        a.sensors, a.seconds, a.calibration_s = 2, 2.0, 6.0
    with tempfile.TemporaryDirectory() as d:
        sim = Path(d) / "s.sqlite"
        run_simulate(
            clip=demo_clip_path(),
            out=sim,
            sensors=a.sensors,
            seconds=a.seconds,
            calibration_s=a.calibration_s,
        )
        run_calibrate(session=sim, method="full", out=None, store_result=True)
        with SessionStore.open(sim) as st:
            poses, _ = resolve_poses(st, None, False)
            sensors = load_sensors(st, poses)
    grid = frame_grid(sensors)
    period_ms = 1e3 / 30
    median_ms = {}
    for method in ("best-live", "paper"):
        ff = FrameFusion(method)
        ff.set_poses(poses)
        nxt = {s.id: 0 for s in sensors}
        times = []
        for t in grid:
            for s in sensors:
                o = s.observations
                while nxt[s.id] < o.n_frames and s.t_server_s[nxt[s.id]] <= t + ff.lead_s:
                    k = nxt[s.id]
                    ff.push(
                        s.id,
                        Observation(
                            int(o.seq[k]),
                            float(s.t_server_s[k]),
                            0.0,
                            o.joints_m[k],
                            o.states[k],
                            s.occluded[k],
                            int(s.n_intersections[k]),
                        ),
                    )
                    nxt[s.id] += 1
            t0 = time.perf_counter()
            ff.fuse(float(t))
            times.append(time.perf_counter() - t0)
        ms = 1e3 * np.array(times)
        median_ms[method] = float(np.median(ms))
        print(
            f"{method:<9} {a.sensors} sensors: {np.median(ms):.2f} ms per frame (p95 "
            f"{np.percentile(ms, 95):.2f} ms) = {np.median(ms) / period_ms:.1%} of the "
            f"{period_ms:.1f} ms frame period, {len(ms)} frames"
        )
    print(f"best-live / paper (median per frame, same run): "
          f"{median_ms['best-live'] / median_ms['paper']:.2f}")  # fmt: skip


if __name__ == "__main__":
    main()

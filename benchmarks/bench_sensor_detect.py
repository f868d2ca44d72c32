"""Can a sensor client keep up with its depth frames? Wand detection cost per frame.

Run: ``python benchmarks/bench_sensor_detect.py [--smoke]`` (``--smoke``: a 2 s wand phase, to check
that it runs). Simulates a 2-sensor wand phase (bundled-style CMU clip, 4 s at 30 Hz depth) in a
temporary folder, then times on one core, per depth frame: the robust detector (the client's
default), the paper's detector, the floor-plane fit the client runs once per calibration (median of
15 frames), the 2-D occlusion test of one body frame, and, as the baseline measured in the same run,
decoding one depth frame from the store. It prints each as ms per frame and as a fraction of the
Kinect v2's 33.3 ms frame period, and what four clients on a two-core PC would need of it (the
decision in docs/live.md, "Wand detection rate").
"""

from __future__ import annotations

import os

os.environ["OMP_NUM_THREADS"] = "1"
os.environ["OPENBLAS_NUM_THREADS"] = "1"
os.environ["MKL_NUM_THREADS"] = "1"

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from kinefuse.app.workflows.simulate import run_simulate
from kinefuse.capture.calibration.wand_paper import detect_wand_paper
from kinefuse.capture.calibration.wand_robust import detect_wand
from kinefuse.capture.occlusion.segments import detect_occlusion
from kinefuse.core.camera.wand import Wand
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.live.client.parts import fit_floor
from kinefuse.live.client.playback import SimTimeline

ROOT = Path(__file__).resolve().parents[1]
CLIP = ROOT.parent / "shared" / "data" / "motion" / "cmu" / "02_walk_a.amc"
PERIOD_MS = 1000.0 / 30.0


def _median_ms(fn, items) -> float:  # type: ignore[no-untyped-def]
    times = []
    for x in items:
        t = time.perf_counter()
        fn(x)
        times.append(time.perf_counter() - t)
    return 1e3 * float(np.median(times))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="a 2 s wand phase (seconds to run)")
    wand_s = 2.0 if ap.parse_args().smoke else 4.0
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "s.sqlite"
        run_simulate(
            clip=CLIP, out=path, sensors=2, seconds=1.0, calibration_s=wand_s, depth_rate_hz=30.0
        )
        with SessionStore.open(path) as st:
            sid = st.sensors()[0].id
            intr = st.sensor(sid).intrinsics
            t = time.perf_counter()
            frames = [f for _s, _t, fr in st.iter_depth_frames(sid) for f in fr]
            decode_ms = 1e3 * (time.perf_counter() - t) / len(frames)
            joints = st.observations(sid)
            body = [joints.joints_m[k] for k in range(min(60, joints.n_frames))]
        wand = Wand()
        tl = SimTimeline(str(path), sid)
        rows = [
            ("decode one depth frame (baseline)", decode_ms),
            ("robust wand detector", _median_ms(lambda f: detect_wand(f, intr, wand), frames)),
            ("paper wand detector", _median_ms(lambda f: detect_wand_paper(f, intr, wand), frames)),
            ("occlusion test, one body frame", _median_ms(
                lambda j: detect_occlusion(j[None], intr), body)),
            ("floor fit (once per calibration)", _median_ms(
                lambda k: fit_floor(frames[k : k + 15], tl, 0.0), [0, 15, 30])),
        ]  # fmt: skip
    print(f"{len(frames)} depth frames of 512x424; Kinect v2 frame period {PERIOD_MS:.1f} ms")
    print(f"{'step':38s} {'ms/frame':>9s} {'x period':>9s} {'x decode':>9s} {'4 clients':>10s}")
    for name, ms in rows:
        four = f"{4 * ms / PERIOD_MS / 2:9.0%}" if "once" not in name else "      n/a"
        print(f"{name:38s} {ms:9.2f} {ms / PERIOD_MS:9.3f} {ms / decode_ms:9.2f} {four}")
    print("('4 clients': the share of a two-core PC four clients need at 30 Hz for that step)")


if __name__ == "__main__":
    main()

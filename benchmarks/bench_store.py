"""Session store speed: append and read 10 minutes of 4 sensors at 30 Hz, and depth frames.

Run: ``python benchmarks/bench_store.py [--smoke]`` (``--smoke``: 10 s instead of 10 minutes and
3 depth frames, to check that it runs). Prints wall times and rates; target: reading the
observations of 10 min x 4 sensors x 30 Hz well under 1 s. The baseline, measured in the same
run: the same arrays written to and read from plain ``.npy`` files (no index, no transaction).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.skeleton import N_JOINTS
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.lab.inspect import inspect_session

SENSORS = 4
FRAMES = 10 * 60 * 30  # 10 minutes at 30 Hz
DEPTH_FRAMES = 30


def depth_codec(n_poses: int = 8) -> None:
    """KFD1 against plain zlib of the image, on depth frames rendered with the ToF noise model."""
    import zlib

    from kinefuse.core.geometry.transforms import look_at
    from kinefuse.core.skeleton import standing_pose
    from kinefuse.formats.store.session_store import decode_depth, encode_depth
    from kinefuse.sim.depth import DepthNoiseParams, Scene, render_depth

    rng = np.random.default_rng(1)
    scene = Scene.from_pose(standing_pose(), 1.75)
    poses = [
        look_at([3.0 * np.cos(a), 3.0 * np.sin(a), 1.1], [0, 0, 1.0])
        for a in np.linspace(0, 2 * np.pi, n_poses, endpoint=False)
    ]
    frames = [render_depth(scene, p, Intrinsics(), rng, DepthNoiseParams()) for p in poses]
    t0 = time.perf_counter()
    plain = [zlib.compress(f.tobytes(), 1) for f in frames]
    t_plain = (time.perf_counter() - t0) / len(frames)
    t0 = time.perf_counter()
    ours = [encode_depth(f) for f in frames]
    t_ours = (time.perf_counter() - t0) / len(frames)
    t0 = time.perf_counter()
    for b, f in zip(ours, frames, strict=True):
        assert np.array_equal(decode_depth(b, *f.shape), f)
    t_dec = (time.perf_counter() - t0) / len(frames)
    raw = sum(f.nbytes for f in frames)
    n_plain, n_ours = sum(map(len, plain)), sum(map(len, ours))
    per = raw / len(frames) / 1e3
    print(f"depth codec on {len(frames)} rendered 512x424 frames ({per:.0f} kB raw):")
    print(
        f"  zlib of the image: {n_plain / len(frames) / 1e3:.1f} kB/frame, {1e3 * t_plain:.1f} ms"
    )
    print(f"  KFD1:              {n_ours / len(frames) / 1e3:.1f} kB/frame, {1e3 * t_ours:.1f} ms"
          f" (decode {1e3 * t_dec:.1f} ms); {n_plain / n_ours:.2f}x smaller than zlib")  # fmt: skip


def npy_baseline(folder: Path, data: list[tuple[np.ndarray, ...]]) -> tuple[float, float]:
    """Seconds to write and to read the same observation arrays as plain ``.npy`` files."""
    t0 = time.perf_counter()
    for k, arrays in enumerate(data):
        for i, a in enumerate(arrays):
            np.save(folder / f"k{k}_{i}.npy", a)
    t_write = time.perf_counter() - t0
    t0 = time.perf_counter()
    for k, arrays in enumerate(data):
        for i in range(len(arrays)):
            np.load(folder / f"k{k}_{i}.npy")
    return t_write, time.perf_counter() - t0


def main() -> None:
    global FRAMES, DEPTH_FRAMES
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="10 s, 3 depth frames (seconds to run)")
    smoke = ap.parse_args().smoke
    if smoke:
        FRAMES, DEPTH_FRAMES = 10 * 30, 3
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.sqlite"
        store = SessionStore.create(path)
        data = []
        for k in range(SENSORS):
            store.add_sensor(f"k{k}", f"SIM-{k}", Intrinsics())
            states = rng.integers(0, 3, (FRAMES, N_JOINTS)).astype(np.int8)
            joints = rng.normal([0, 0, 2.5], 0.5, (FRAMES, N_JOINTS, 3))
            joints[states == 0] = np.nan
            seq = np.arange(FRAMES)
            data.append((seq, seq / 30.0, joints, states, seq / 30.0 + 0.05))
        t0 = time.perf_counter()
        for k, (seq, t, j, st, tr) in enumerate(data):
            store.append_observations(f"k{k}", seq, t, j, st, t_receive_server_s=tr)
        t_append = time.perf_counter() - t0
        t0 = time.perf_counter()
        for k, (seq, t, j, _st, _tr) in enumerate(data):
            store.append_truth_observations(
                f"k{k}",
                seq,
                t,
                np.nan_to_num(j),
                np.ones((FRAMES, N_JOINTS), bool),
                np.zeros(FRAMES, bool),
            )
        t_truth = time.perf_counter() - t0
        # per-frame appends, as a live recorder would do them (one transaction each)
        t0 = time.perf_counter()
        n_live = min(300, FRAMES)
        for i in range(n_live):
            store.append_observations(
                "k0", [FRAMES + i], [0.0], data[0][2][i : i + 1], data[0][3][i : i + 1]
            )
        t_live = (time.perf_counter() - t0) / n_live
        wall = (3000 + rng.normal(0, 3, (DEPTH_FRAMES, 424, 512))).round().astype(np.uint16)
        t0 = time.perf_counter()
        store.append_depth_frames("k0", np.arange(DEPTH_FRAMES), np.zeros(DEPTH_FRAMES), wall)
        t_depth_w = (time.perf_counter() - t0) / DEPTH_FRAMES
        store.close()

        with SessionStore.open(path) as s:
            t0 = time.perf_counter()
            obs = [s.observations(f"k{k}") for k in range(SENSORS)]
            t_read = time.perf_counter() - t0
            assert all(o.n_frames >= FRAMES for o in obs)
            t0 = time.perf_counter()
            n = sum(d.shape[0] for _, _, d in s.iter_depth_frames("k0"))
            t_depth_r = (time.perf_counter() - t0) / n
            t0 = time.perf_counter()
            inspect_session(s)
            t_inspect = time.perf_counter() - t0
        size_mb = path.stat().st_size / 1e6
        t_npy_write, t_npy_read = npy_baseline(Path(tmp), data)

    rows = SENSORS * FRAMES
    print(f"observations: {SENSORS} sensors x {FRAMES} frames = {rows} rows, file {size_mb:.1f} MB")
    print(f"  append (one call per sensor): {t_append:.3f} s  ({rows / t_append:,.0f} rows/s; "
          f"{t_append / t_npy_write:.1f} x writing .npy files)")  # fmt: skip
    print(f"  append truth observations:    {t_truth:.3f} s")
    print(f"  append one frame per call:    {1e3 * t_live:.2f} ms per frame (live recording)")
    print(f"  read all:                     {t_read:.3f} s  (target < 1 s: {t_read < 1.0}; "
          f"{t_read / t_npy_read:.1f} x reading .npy files)")  # fmt: skip
    print(f"  inspect_session:              {t_inspect:.3f} s")
    print(
        f"depth frames 512x424: write {1e3 * t_depth_w:.1f} ms/frame, "
        f"read {1e3 * t_depth_r:.1f} ms/frame"
    )
    depth_codec(2 if smoke else 8)


if __name__ == "__main__":
    main()

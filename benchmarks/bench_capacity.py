"""How many sensors one live server carries at 30 Hz (issue 23).

Run: ``python benchmarks/bench_capacity.py`` (N = 4, 8, 12, 16, 24, 15 s each), or
``--sensors N --seconds S --json FILE`` for one N, or ``--smoke`` (4 sensors, 4 s: checks that it
runs). Per N: simulates a session of N sensors without a wand phase (the demo clip; N <= 16 the
default ring, 24 two rings), writes its true poses as a calibration file, starts a real
``kinefuse serve --token-file ... --calibration ... --record ...`` process on 127.0.0.1, and
plays every sensor's recorded body frames at 30 Hz from this process: N real
:class:`~kinefuse.live.client.client.SensorClient` s multiplexed on one event loop
(:mod:`kinefuse.live.client.fleet`), each its own authenticated TCP connection, its own emulated
host clock synchronized by the server's probes, the occlusion test, no depth work.

After ``WARM_S`` seconds (clock sync, first frames) it measures for ``S`` seconds:

- ``fused_rate_hz``: fused frames the server published (from its recording) per second;
- ``frames_dropped``: body frames lost anywhere: dropped from a client's send queue, from the
  server's per-sensor queue, as a late backlog, plus fused frames the loop skipped (these are
  the run's counters: the warm-up is included);
- ``latency_ms``: host receive -> published, p50/p99, of the published frames (the server's own
  figure, ``live_fused.latency_s``);
- ``server_cpu_ms_per_frame``: the server process's CPU time (user + system, /proc) over the
  window divided by the frames published in it;
- ``rss_mb``: the server's peak resident memory in the window.

The machine is shared: the load average (1 min) at the end of each run is printed beside it.
"""

from __future__ import annotations

import argparse
import asyncio
import datetime as _dt
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from kinefuse.app.workflows.simulate import demo_clip_path, run_simulate
from kinefuse.capture.calibration.calib_file import (
    CalibrationFile,
    SensorCalibration,
    write_calibration,
)
from kinefuse.core.outputs import atomic_write_text, json_recognizer
from kinefuse.formats.store.live_tables import live_fused
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.live.client.client import ClientOptions
from kinefuse.live.client.fleet import replay_clients, run_clients, stop_all
from kinefuse.sim.rig import Rig, SensorSpec, default_rig, rig_to_toml

SWEEP = (4, 8, 12, 16, 24)
MARK = {"benchmark": "bench_capacity"}
TOKEN = "a7c9e1b3d5f70a2c4e6b8d0f1a3c5e7b9d2f4a6c8e0b1d3f5a7c9e2b4d6f8a0c"  # serve takes 128+ bits
#: seconds from the first frame before the window opens (clock sync, the fusion's first frames)
WARM_S = 4.0
#: the clients start this long after they are created (connect, handshake, first probes)
START_S = 2.0
#: the demo clip's length (CMU 01_01, 2751 frames at 120 Hz), seconds
CLIP_S = 22.9


def rig(n: int) -> Rig:
    """The default ring for up to 16 sensors; above, two rings (3.0 m low, 3.6 m high)."""
    if n <= 16:
        return default_rig(n)
    inner, outer = default_rig(n // 2, 3.0), default_rig(n - n // 2, 3.6)
    sensors = list(inner.sensors)
    for k, s in enumerate(outer.sensors):
        pose = s.sensor2world.copy()
        a = np.pi / len(outer.sensors)  # the outer ring half a step round
        rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])
        pose[:3, :3] = rz @ pose[:3, :3]
        pose[:3, 3] = rz @ pose[:3, 3] + [0, 0, 0.6]
        sid = f"k{len(inner.sensors) + k}"
        sensors.append(SensorSpec(sid, f"SIM{len(inner.sensors) + k:03d}-{sid}", pose))
    return Rig(
        sensors=tuple(sensors),
        description=f"{n} sensors on two rings",
        room_min_xy_m=outer.room_min_xy_m,
        room_max_xy_m=outer.room_max_xy_m,
    )


def simulate(n: int, seconds: float, d: Path) -> Path:
    rig_path = d / f"rig{n}.toml"
    rig_path.write_text(rig_to_toml(rig(n)), encoding="utf-8")  # in this run's own folder
    out = d / f"s{n}.sqlite"
    need = seconds + WARM_S + 2.0
    run_simulate(
        clip=demo_clip_path(),
        out=out,
        rig=rig_path,
        seconds=min(need, CLIP_S),
        calibration_s=0.0,
        # longer than the clip: a range-of-motion phase first (it takes 55 s at the least)
        rom_s=max(55.0, need - CLIP_S) if need > CLIP_S else None,
    )
    return out


def true_calibration(session: Path, out: Path) -> tuple[Path, list[str]]:
    """The session's true poses as a calibration file (the server fuses without a wand)."""
    with SessionStore.open(session) as st:
        truth = st.truth()
        sensors = [(s.id, s.serial, s.intrinsics) for s in st.sensors()]
        cals = tuple(
            SensorCalibration(sid, serial, truth.sensor(sid)[0], intr, 0.001, 100)
            for sid, serial, intr in sensors
        )
    cal = CalibrationFile("full", _dt.datetime.now(_dt.UTC), cals)
    return write_calibration(out, cal), [s[0] for s in sensors]


def proc_cpu_s(pid: int) -> float:
    f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK")


def proc_rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


async def play(
    port: int, pid: int, session: Path, ids: list[str], seconds: float
) -> dict[str, Any]:
    # as `kinefuse sensor` does: the loop stamps probe replies, the source threads (one per
    # client: its occlusion test) must hand the GIL back quickly
    sys.setswitchinterval(0.001)
    epoch = time.monotonic() + START_S
    clients = replay_clients(
        session,
        ids,
        ClientOptions(server=("127.0.0.1", port), token=TOKEN, max_seconds=WARM_S + seconds),
        epoch_monotonic=epoch,
    )
    runner = asyncio.ensure_future(run_clients(clients))
    try:
        await asyncio.sleep(epoch + WARM_S - time.monotonic())
        t0, cpu0, rss = time.monotonic(), proc_cpu_s(pid), [proc_rss_mb(pid)]
        own0 = proc_cpu_s(os.getpid())
        while time.monotonic() < t0 + seconds:
            await asyncio.sleep(1.0)
            rss.append(proc_rss_mb(pid))
        t1, cpu1, own1 = time.monotonic(), proc_cpu_s(pid), proc_cpu_s(os.getpid())
        await asyncio.wait_for(runner, 30)
    finally:
        stop_all(clients, "benchmark over")
        if not runner.done():
            runner.cancel()
    return {
        "t0": t0,
        "t1": t1,
        "cpu_s": cpu1 - cpu0,
        "clients_cpu_s": own1 - own0,
        "rss_mb": max(rss),
        "client_dropped": sum(c.stats.body_dropped for c in clients),
        "client_sent": sum(c.stats.body_sent for c in clients),
        "client_late": sum(c.stats.late_frames for c in clients),
    }


def run_one(
    n: int,
    seconds: float,
    d: Path,
    profile: Path | None = None,
    server_src: Path | None = None,
) -> dict[str, Any]:
    session = simulate(n, seconds, d)
    cal, ids = true_calibration(session, d / f"cal{n}.toml")
    token_file = d / "token"
    token_file.write_text(TOKEN + "\n")
    rec = d / f"rec{n}.sqlite"
    prof = ["-m", "cProfile", "-o", str(profile)] if profile is not None else []
    cmd = [sys.executable, *prof, "-m", "kinefuse", "serve", "--port", "0", "--record", str(rec),
           "--calibration", str(cal), "--token-file", str(token_file), "--verbose"]  # fmt: skip
    with open(d / f"serve{n}.log", "w") as err:
        env = dict(os.environ)
        if server_src is not None:  # another checkout's server (a baseline in the same run)
            env["PYTHONPATH"] = os.pathsep.join([str(server_src), env.get("PYTHONPATH", "")])
        server = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err, text=True, env=env)
    try:
        assert server.stdout is not None
        line = server.stdout.readline()
        port = int(line.rsplit(":", 1)[1])
        m = asyncio.run(play(port, server.pid, session, ids, seconds))
        server.send_signal(2)
        server.wait(60)
    finally:
        if server.poll() is None:
            server.kill()
            server.wait(10)
    log = (d / f"serve{n}.log").read_text()
    with SessionStore.open(rec) as st:
        t0_server = float(st.meta()["server_t0_monotonic"])  # type: ignore[arg-type]
        stats: dict[str, Any] = st.meta().get("live_run") or {}  # type: ignore[assignment]
        lf = live_fused(st)
    sel = (lf.t_server_s >= m["t0"] - t0_server) & (lf.t_server_s < m["t1"] - t0_server)
    n_frames = int(sel.sum())
    lat = lf.latency_s[sel]
    lat = lat[np.isfinite(lat)] * 1e3
    per = stats.get("sensors", {})
    server_dropped = sum(int(s["queue_dropped"]) + int(s["late_dropped"]) for s in per.values())
    return {
        "sensors": n,
        "fused_rate_hz": n_frames / (m["t1"] - m["t0"]),
        "frames_dropped": int(
            m["client_dropped"] + server_dropped + stats.get("frames_skipped", 0)
        ),
        "latency_ms": {
            "p50": float(np.percentile(lat, 50)) if lat.size else None,
            "p99": float(np.percentile(lat, 99)) if lat.size else None,
        },
        "server_cpu_ms_per_frame": 1e3 * m["cpu_s"] / max(n_frames, 1),
        "rss_mb": m["rss_mb"],
        "detail": {
            "seconds": m["t1"] - m["t0"],
            "frames": n_frames,
            "frames_with_latency": int(lat.size),
            "body_frames_sent": m["client_sent"],
            "client_queue_dropped": m["client_dropped"],
            "client_late_frames": m["client_late"],
            "server_queue_dropped": sum(int(s["queue_dropped"]) for s in per.values()),
            "server_late_dropped": sum(int(s["late_dropped"]) for s in per.values()),
            "fusion_frames_skipped": stats.get("frames_skipped"),
            "fusion_ms_per_frame": stats.get("fusion_ms_per_frame"),
            # this process (the N clients) over the window, per second: a core is 1000
            "clients_cpu_ms_per_s": 1e3 * m["clients_cpu_s"] / (m["t1"] - m["t0"]),
            "server_cpu_ms_per_s": 1e3 * m["cpu_s"] / (m["t1"] - m["t0"]),
            "load_average_1min": os.getloadavg()[0],
            "server_warnings": [ln for ln in log.splitlines() if "WARNING" in ln][:20],
        },
    }


def row(r: dict[str, Any]) -> str:
    lat = r["latency_ms"]
    f = lambda v: "n/a" if v is None else f"{v:.1f}"  # noqa: E731
    return (
        f"| {r['sensors']} | {r['fused_rate_hz']:.1f} | {r['frames_dropped']} | {f(lat['p50'])} | "
        f"{f(lat['p99'])} | {r['server_cpu_ms_per_frame']:.1f} | {r['rss_mb']:.0f} | "
        f"{r['detail']['load_average_1min']:.1f} |"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sensors", type=int, help="one N (default: the sweep 4, 8, 12, 16, 24)")
    ap.add_argument("--seconds", type=float, default=15.0, help="measured seconds per N")
    ap.add_argument("--json", type=Path, help="write the result (one N: one object) here")
    ap.add_argument("--smoke", action="store_true", help="4 sensors, 4 s (seconds to run)")
    ap.add_argument("--keep", type=Path, help="keep sessions, recordings, logs (a new folder)")
    ap.add_argument("--profile", type=Path, help="run the server under cProfile, stats here")
    ap.add_argument(
        "--baseline-src",
        type=Path,
        help="also run each N against the server of this src folder (another checkout's), "
        "alternating with this one's, and print both",
    )
    a = ap.parse_args()
    if a.smoke:
        a.sensors, a.seconds = a.sensors or 4, 4.0
    if a.sensors is not None and not 1 <= a.sensors <= 64:
        ap.error(f"--sensors must be 1 to 64, got {a.sensors}")
    if not 1.0 <= a.seconds <= 120.0:
        ap.error(f"--seconds must be 1 to 120, got {a.seconds:g}")
    ns = (a.sensors,) if a.sensors is not None else SWEEP
    print(f"bench_capacity.py --seconds {a.seconds:g} (after {WARM_S:g} s of warm-up)")
    print("| sensors | fused Hz | frames dropped | latency p50 ms | latency p99 ms | "
          "server CPU ms/frame | server RSS MB | load avg (1 min) |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|", flush=True)
    results = []
    if a.keep is not None:
        a.keep.mkdir(parents=True)  # a new folder: nothing of anyone else's is overwritten
    with tempfile.TemporaryDirectory() as tmp:
        d = a.keep if a.keep is not None else Path(tmp)
        for n in ns:
            if a.baseline_src is not None:
                (d / "baseline").mkdir(exist_ok=True)
                b = run_one(n, a.seconds, d / "baseline", None, a.baseline_src)
                print(row(b) + " baseline", flush=True)
            r = run_one(n, a.seconds, d, a.profile)
            results.append(r)
            print(row(r), flush=True)
    if a.json is not None:
        # one N: its object; a sweep: {"runs": [...]}; either marked as this benchmark's, so
        # that a rerun replaces only a file it wrote
        out = {**MARK, **results[0]} if len(results) == 1 else {**MARK, "runs": results}
        atomic_write_text(
            a.json, json.dumps(out, indent=2) + "\n", what="benchmark result",
            recognizer=json_recognizer("benchmark", MARK["benchmark"]),
        )  # fmt: skip


if __name__ == "__main__":
    main()

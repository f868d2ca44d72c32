"""Soak: a live server with 8 sensors, a viewer, a subscriber and the recorder, for 30 minutes.

Run: ``python benchmarks/soak.py [--minutes 30] [--sensors 8] [--plot soak.png] [--json F]``;
``--smoke`` is the 3-minute version CI runs (issue 23; it checks the same things, over shorter
windows). Three processes, all on 127.0.0.1:

- the **server**: ``Server`` with the options ``kinefuse serve --record REC --calibration CAL
  --viewer-port 0`` gives it (built here rather than by ``kinefuse serve`` only so that a sampler
  inside it can report its queue depths; the server runs the same code), the recorder on, the
  live viewer and the subscription API on its publisher;
- the **sensors**: ``--sensors`` light sensors multiplexed in one process (no depth work: they
  replay the real Kinect v2 walk ``../shared/data/kinect/kinect2_tracking/walker.json`` in a loop
  at 30 Hz, seen from each sensor's pose of a ring rig, each with its own PC clock offset, and
  answer the server's clock probes); the server cannot tell them from ``kinefuse sensor``;
- this process: a **viewer** client on ``/ws`` and a **subscriber** on ``/api/v1/stream``
  (JSON), both reading everything, and the sampler of the server's RSS and open descriptors
  (``/proc``), its queue depths (per-sensor observation queues, each publisher subscription,
  the recorder's pending rows, unsent bytes per connection) and the latency host receive ->
  published (from the subscriber's frames), every ``--interval`` s (10).

At the end the server gets SIGINT (a clean stop) and the recording is opened and checked:
marked complete, every sensor in it, every body frame the sensors sent (within the last
second's frames in flight), every fused frame the server published, fused frame numbers without
gaps. Acceptance (issue 23): RSS growth < 5 % (median of the last window against the first;
windows of 5 minutes, a third of the run if shorter, the first minute left out as warm-up when
the run is 30 minutes), no descriptor growth (most open in the last window <= most in the first),
latency p99 within 20 % between the first and the last window, the recording complete. The plot
(``--plot``, a PNG written through a temporary file and a rename) shows the four series.
Timing figures come from a machine shared with other jobs: read latency as a ratio within one run.
Exit 1 when a check fails (0 with ``--smoke``, which checks that it runs and prints the figures).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import datetime as _dt
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
WALKER = ROOT.parent / "shared" / "data" / "kinect" / "kinect2_tracking" / "walker.json"
RATE_HZ = 30.0


# -- the rig and the replayed walk ---------------------------------------------------------------


def ring_poses(n: int, centre: np.ndarray, radius_m: float = 3.0) -> np.ndarray:
    """``(n, 4, 4)`` sensor-to-world poses on a ring around ``centre``, at 0.8-1.2 m height."""
    from kinefuse.core.geometry.transforms import look_at

    out = []
    for k in range(n):
        a = 2 * np.pi * k / n
        h = 0.8 + 0.4 * (k % 3) / 2
        eye = [centre[0] + radius_m * np.cos(a), centre[1] + radius_m * np.sin(a), h]
        out.append(look_at(eye, [centre[0], centre[1], 1.0]))
    return np.stack(out)


def walk_in_world() -> tuple[np.ndarray, np.ndarray]:
    """The real walk as world joints ``(T, 25, 3)`` (z up, NaN untracked) and states ``(T, 25)``:
    the walker's camera put 1 m high, looking along +y."""
    from kinefuse.pipeline.frame_sources import Kinect2TrackingReplay

    frames = list(Kinect2TrackingReplay(WALKER))
    j = np.stack([f.joints_m for f in frames])  # sensor frame: x right, y down, z forward
    st = np.stack([f.states for f in frames]).astype(np.int8)
    world = np.stack([j[..., 0], j[..., 2], 1.0 - j[..., 1]], axis=-1)
    return world, st


def sensor_view(world: np.ndarray, s2w: np.ndarray) -> np.ndarray:
    """World joints seen in one sensor's frame."""
    r, t = s2w[:3, :3], s2w[:3, 3]
    return (world - t) @ r


# -- the server process (a sampler inside it reports queue depths) ------------------------------


def queue_depths(server: Any) -> dict[str, Any]:
    """What the server holds in its queues now (attributes read defensively: best effort)."""
    obs = {sid: len(getattr(c, "queue", ())) for sid, c in getattr(server, "clients", {}).items()}
    subs = [len(s) for s in getattr(server.publisher, "_subs", [])]
    rec = getattr(server, "recorder", None)
    pending = 0
    if rec is not None and getattr(rec, "_batch", None) is not None:
        b = rec._batch
        pending = sum(len(o.seq) for o in b.obs.values()) + len(b.fused) + len(b.events)
    unsent = []
    for c in list(getattr(server, "_conns", ())):
        with contextlib.suppress(Exception):
            unsent.append(int(c.writer.transport.get_write_buffer_size()))
    import threading

    return {
        "obs_queue_max": max(obs.values(), default=0),
        "obs_queue_sum": sum(obs.values()),
        "subscriptions": subs,
        "subscription_max": max(subs, default=0),
        "recorder_pending": pending,
        "unsent_bytes_max": max(unsent, default=0),
        "connections": len(getattr(server, "_conns", ())),
        "threads": threading.active_count(),
        "frames_fused": int(getattr(server.loop, "frames", 0)),
        "frames_skipped": int(getattr(server.loop, "skipped", 0)),
    }


def serve_child(port_file: Path, record: Path, cal: Path, interval: float) -> int:
    from kinefuse.capture.calibration.calib_file import read_calibration
    from kinefuse.live.server.server import Server, ServerOptions
    from kinefuse.live.viewer import live_viewer

    holder: dict[str, Server] = {}

    @contextlib.asynccontextmanager
    async def sampler(_publisher: Any) -> AsyncIterator[str]:
        async def run() -> None:
            while True:
                line = {"t": time.monotonic(), **queue_depths(holder["s"])}
                sys.stdout.write("Q " + json.dumps(line) + "\n")
                sys.stdout.flush()
                await asyncio.sleep(interval / 2)

        task = asyncio.ensure_future(run())
        try:
            yield "sampler"
        finally:
            task.cancel()

    opts = ServerOptions(host="127.0.0.1", port=0, record=record, method="best-live")
    services = {
        "viewer": lambda pub: live_viewer(pub, host="127.0.0.1", port=0),
        "sampler": sampler,
    }
    server = Server(opts, services=services)  # type: ignore[arg-type]
    holder["s"] = server
    server.load_calibration(read_calibration(cal))

    def ready(h: str, p: int) -> None:
        port_file.write_text(json.dumps({"port": p, "viewer": server.services["viewer"]}))
        print(f"R {p} {server.services['viewer']}", flush=True)

    async def main() -> None:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, server.request_stop, f"signal {sig.name}")
        await server.run(ready)

    asyncio.run(main())
    print("S " + json.dumps(server.run_stats(), default=str), flush=True)
    return 0


# -- the sensors process -------------------------------------------------------------------------


async def one_sensor(
    port: int, sid: str, joints: np.ndarray, states: np.ndarray, h0: float, until: float
) -> int:
    from kinefuse.core.camera.intrinsics import Intrinsics
    from kinefuse.live.protocol import (
        BodyFrameMessage,
        ClockProbe,
        ClockReply,
        Decoder,
        Hello,
        Welcome,
        encode,
    )

    r, w = await asyncio.wait_for(asyncio.open_connection("127.0.0.1", port), 10)
    dec = Decoder()
    w.write(encode(Hello(role="sensor", sensor_id=sid, intrinsics=Intrinsics())))
    inbox: list[Any] = []

    async def recv() -> Any:
        while not inbox:
            data = await asyncio.wait_for(r.read(65536), 30)
            if not data:
                raise ConnectionError(f"{sid}: the server closed the connection")
            inbox.extend(dec.feed(data))
        return inbox.pop(0)

    if not isinstance(m := await recv(), Welcome):
        raise ConnectionError(f"{sid}: expected a welcome, got {m!r}")

    async def answer() -> None:
        while True:
            try:
                m = await recv()
            except (ConnectionError, OSError, TimeoutError):
                return  # the server went away: the sender stops too
            if isinstance(m, ClockProbe):
                t = time.monotonic() + h0
                w.write(encode(ClockReply(probe_id=m.probe_id, t1=m.t1, t2=t, t3=t)))

    task = asyncio.ensure_future(answer())
    seq, t_next = 0, time.monotonic()
    try:
        while time.monotonic() < until and not task.done():
            k = seq % len(joints)
            t = time.monotonic() + h0
            w.write(
                encode(
                    BodyFrameMessage(
                        seq=seq,
                        t_device_s=t - h0 - 0.05,  # the device's own clock, 50 ms exposure
                        t_host_s=t,
                        joints_m=joints[k],
                        states=states[k],
                    )
                )
            )
            seq += 1
            t_next += 1 / RATE_HZ
            await asyncio.sleep(max(0.0, t_next - time.monotonic()))
        with contextlib.suppress(ConnectionError, OSError):
            await w.drain()
    finally:
        task.cancel()
        w.close()
    return seq


def sensors_child(port: int, n: int, seconds: float, cal: Path) -> int:
    from kinefuse.capture.calibration.calib_file import read_calibration

    c = read_calibration(cal)
    world, states = walk_in_world()
    until = time.monotonic() + seconds

    async def main() -> list[int]:
        tasks = []
        for k, s in enumerate(c.sensors):
            joints = sensor_view(world, s.sensor2world)
            h0 = 1000.0 * (k + 1) + 0.37 * k  # each PC clock its own offset
            tasks.append(one_sensor(port, s.id, joints, states, h0, until))
        return list(await asyncio.gather(*tasks))

    sent = asyncio.run(main())
    print(json.dumps({s.id: n_ for s, n_ in zip(c.sensors, sent, strict=True)}), flush=True)
    return 0


# -- this process: viewer, subscriber, sampler ---------------------------------------------------


def proc_figures(pid: int) -> tuple[float, int, float]:
    """(RSS MiB, open descriptors, CPU seconds used so far) of a process."""
    rss = float("nan")
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            rss = int(line.split()[1]) / 1024
    stat = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    cpu = (int(stat[11]) + int(stat[12])) / os.sysconf("SC_CLK_TCK")  # utime + stime
    return rss, len(os.listdir(f"/proc/{pid}/fd")), cpu


async def soak(
    server: subprocess.Popen[str],
    sensors: subprocess.Popen[str],
    viewer_port: int,
    seconds: float,
    interval: float,
) -> dict[str, Any]:
    import aiohttp

    assert server.stdout is not None
    latest_q: dict[str, Any] = {}
    stats: dict[str, Any] = {}
    lat_window: list[float] = []
    counts = {"viewer": 0, "api": 0, "api_status": 0}
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()

    async def read_server() -> None:
        while True:
            line = await loop.run_in_executor(None, server.stdout.readline)  # type: ignore[union-attr]
            if not line:
                return
            if line.startswith("Q "):
                latest_q.update(json.loads(line[2:]))
            elif line.startswith("S "):
                stats.update(json.loads(line[2:]))

    async def viewer(http: aiohttp.ClientSession) -> None:
        async with http.ws_connect(f"http://127.0.0.1:{viewer_port}/ws") as ws:
            async for m in ws:
                if m.type == aiohttp.WSMsgType.BINARY:
                    counts["viewer"] += 1
                if stop.is_set():
                    return

    async def subscriber(http: aiohttp.ClientSession) -> None:
        url = f"http://127.0.0.1:{viewer_port}/api/v1/stream?format=json"
        async with http.ws_connect(url) as ws:
            hello = await ws.receive_json()
            assert hello["auth"] == "none", hello
            welcome = await ws.receive_json()
            assert welcome["type"] == "welcome", welcome
            async for m in ws:
                item = json.loads(m.data)
                if item["type"] == "frame":
                    counts["api"] += 1
                    if item.get("latency_ms") is not None:
                        lat_window.append(float(item["latency_ms"]))
                else:
                    counts["api_status"] += 1
                if stop.is_set():
                    return

    samples: list[dict[str, Any]] = []
    async with aiohttp.ClientSession() as http:
        reader = asyncio.ensure_future(read_server())
        clients = [asyncio.ensure_future(viewer(http)), asyncio.ensure_future(subscriber(http))]
        t0 = time.monotonic()
        last = dict(counts)
        last_cpu = proc_figures(server.pid)[2]
        k = 0
        while time.monotonic() - t0 < seconds:
            k += 1
            await asyncio.sleep(max(0.0, t0 + k * interval - time.monotonic()))
            if sensors.poll() is not None:
                raise RuntimeError(f"the sensors process ended early ({sensors.returncode})")
            for c in clients:
                if c.done():
                    raise RuntimeError(f"a client ended early: {c.exception()!r}")
            rss, fds, cpu = proc_figures(server.pid)
            lat = np.array(lat_window)
            lat_window.clear()
            now = dict(counts)
            s = {
                "t_s": time.monotonic() - t0,
                "rss_mb": rss,
                "fds": fds,
                "latency_ms": lat.tolist(),
                "p50_ms": float(np.percentile(lat, 50)) if lat.size else math.nan,
                "p99_ms": float(np.percentile(lat, 99)) if lat.size else math.nan,
                "api_hz": (now["api"] - last["api"]) / interval,
                "viewer_hz": (now["viewer"] - last["viewer"]) / interval,
                "queues": {k_: v for k_, v in latest_q.items() if k_ != "t"},
                "server_cpu": (cpu - last_cpu) / interval,
                "load1": os.getloadavg()[0],
            }
            last_cpu = cpu
            last = now
            samples.append(s)
            q = s["queues"]
            print(
                f"  {s['t_s']:7.0f} s  RSS {rss:6.1f} MB  fds {fds:3d}  p50/p99 "
                f"{s['p50_ms']:5.1f}/{s['p99_ms']:5.1f} ms  api {s['api_hz']:4.1f} Hz  viewer "
                f"{s['viewer_hz']:4.1f} Hz  queues obs {q.get('obs_queue_max')} subs "
                f"{q.get('subscription_max')} rec {q.get('recorder_pending')} unsent "
                f"{q.get('unsent_bytes_max')}  server CPU {100 * s['server_cpu']:3.0f} %  load "
                f"{s['load1']:.1f}",
                flush=True,
            )
        # the sensors end by themselves (their stream outlasts the sampling), then the server
        # stops cleanly (SIGINT) while the viewer and the subscriber are still connected
        out, _ = await loop.run_in_executor(None, lambda: sensors.communicate(timeout=60))
        server.send_signal(signal.SIGINT)
        await asyncio.wait_for(reader, 120)
        stop.set()
        for c in clients:
            c.cancel()
        await asyncio.gather(*clients, return_exceptions=True)
    return {"samples": samples, "counts": counts, "run_stats": stats, "sent": json.loads(out)}


# -- the checks ----------------------------------------------------------------------------------


def check_recording(
    rec: Path,
    sent: dict[str, int],
    frames_fused: int,
    frames_skipped: int,
    late_dropped: dict[str, int],
) -> dict[str, Any]:
    """Open the recording read-only; is it complete?"""
    from kinefuse.formats.store.live_tables import live_fused
    from kinefuse.formats.store.session_store import SessionStore

    with SessionStore.open(rec) as st:
        complete = bool(st.complete)
        ids = {s.id for s in st.sensors()}
        n_obs = {sid: st.observation_count(sid) for sid in sorted(ids)}
        lf = live_fused(st)
        frames = np.asarray(lf.frame)
    # frame numbers count frame times: the ones the loop skipped (it fell behind) are holes
    holes = int(frames[-1] - frames[0] + 1 - frames.size) if frames.size else 0
    # a sensor's last frames may still be in flight when it stops: 1 s of them at most; the
    # frames the server kept out of the fusion as too late (a stalled sensor's backlog:
    # live_run.sensors.*.late_dropped) are recorded like the others
    missing = {sid: sent[sid] - n_obs.get(sid, 0) for sid in sent}
    ok = (
        complete
        and ids == set(sent)
        and all(0 <= m <= RATE_HZ for m in missing.values())
        and frames.size == frames_fused
        and holes == frames_skipped
    )
    return {
        "complete": complete,
        "sensors": sorted(ids),
        "observations": n_obs,
        "sent": sent,
        "missing": missing,
        "late_dropped": late_dropped,
        "fused_frames": int(frames.size),
        "frames_published": frames_fused,
        "frame_holes": holes,
        "frames_skipped": frames_skipped,
        "ok": bool(ok),
    }


def judge(samples: list[dict[str, Any]], seconds: float) -> dict[str, Any]:
    t = np.array([s["t_s"] for s in samples])
    w = min(300.0, seconds / 3)
    warm = 60.0 if seconds >= 1200 else 0.0
    first = (t > warm) & (t <= warm + w)
    lastw = t > t[-1] - w
    rss = np.array([s["rss_mb"] for s in samples])
    fds = np.array([s["fds"] for s in samples])
    lat_first = np.concatenate([samples[i]["latency_ms"] for i in np.flatnonzero(first)])
    lat_last = np.concatenate([samples[i]["latency_ms"] for i in np.flatnonzero(lastw)])
    p99_first = float(np.percentile(lat_first, 99))
    p99_last = float(np.percentile(lat_last, 99))
    growth = float(np.median(rss[lastw]) / np.median(rss[first]) - 1)
    slope = float(np.polyfit(t[t > warm], rss[t > warm], 1)[0] * 3600) if t.size > 2 else math.nan
    return {
        "window_s": w,
        "warmup_s": warm,
        "rss_first_mb": float(np.median(rss[first])),
        "rss_last_mb": float(np.median(rss[lastw])),
        "rss_growth": growth,
        "rss_slope_mb_per_h": slope,
        "rss_max_mb": float(rss.max()),
        "fds_first_max": int(fds[first].max()),
        "fds_last_max": int(fds[lastw].max()),
        "p99_first_ms": p99_first,
        "p99_last_ms": p99_last,
        "p99_ratio": p99_last / p99_first,
        "p50_first_ms": float(np.percentile(lat_first, 50)),
        "p50_last_ms": float(np.percentile(lat_last, 50)),
    }


def plot(samples: list[dict[str, Any]], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from kinefuse.core.outputs import atomic_file, is_png

    t = np.array([s["t_s"] for s in samples]) / 60
    fig, ax = plt.subplots(4, 1, figsize=(8, 9), sharex=True)
    ax[0].plot(t, [s["rss_mb"] for s in samples])
    ax[0].set_ylabel("server RSS, MB")
    ax[1].plot(t, [s["fds"] for s in samples], drawstyle="steps-post")
    ax[1].set_ylabel("open descriptors")
    for key, label in (
        ("obs_queue_sum", "observations queued (all sensors)"),
        ("subscription_max", "largest subscription queue"),
        ("recorder_pending", "recorder rows pending"),
    ):
        ax[2].plot(t, [s["queues"].get(key, np.nan) for s in samples], label=label)
    ax[2].set_ylabel("queue depth, items")
    ax[2].legend(fontsize=7)
    ax[3].plot(t, [s["p50_ms"] for s in samples], label="p50")
    ax[3].plot(t, [s["p99_ms"] for s in samples], label="p99")
    ax[3].set_ylabel("latency receive -> published, ms")
    ax[3].set_xlabel("minutes")
    ax[3].legend(fontsize=7)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    with atomic_file(path, what="plot", recognizer=is_png, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=80, format="png")
    plt.close(fig)


def write_calibration_file(path: Path, n: int) -> None:
    from kinefuse.capture.calibration.calib_file import (
        CalibrationFile,
        SensorCalibration,
        write_calibration,
    )
    from kinefuse.core.camera.intrinsics import Intrinsics

    world, _ = walk_in_world()
    centre = np.nanmean(world.reshape(-1, 3), axis=0)
    poses = ring_poses(n, centre)
    cal = CalibrationFile(
        "full",
        _dt.datetime.now(_dt.UTC),
        tuple(SensorCalibration(f"k{k}", "", poses[k], Intrinsics(), 0.001, 100) for k in range(n)),
    )
    write_calibration(path, cal)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=30.0, help="how long to soak (30)")
    ap.add_argument("--sensors", type=int, default=8, help="light replaying sensors (8)")
    ap.add_argument("--interval", type=float, default=10.0, help="seconds between samples (10)")
    ap.add_argument("--plot", type=Path, help="write the plot here (PNG)")
    ap.add_argument("--json", type=Path, help="write the samples and figures here")
    ap.add_argument("--smoke", action="store_true", help="the 3-minute version CI runs")
    ap.add_argument("--_serve", nargs=4, help=argparse.SUPPRESS)
    ap.add_argument("--_sensors", nargs=4, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a._serve:
        sys.exit(serve_child(Path(a._serve[0]), Path(a._serve[1]), Path(a._serve[2]),
                             float(a._serve[3])))  # fmt: skip
    if a._sensors:
        p, n, s, c = a._sensors
        sys.exit(sensors_child(int(p), int(n), float(s), Path(c)))
    if a.smoke:
        a.minutes = 3.0
    if not WALKER.is_file():
        sys.exit(f"{WALKER} is missing: the soak replays that real walk (../shared/data)")
    seconds = 60 * a.minutes
    print(f"soak: {a.sensors} sensors, a viewer and a subscriber, recorder on, "
          f"{a.minutes:g} min, a sample every {a.interval:g} s", flush=True)  # fmt: skip
    with tempfile.TemporaryDirectory() as d:
        cal, rec, port_file = Path(d) / "cal.toml", Path(d) / "rec.sqlite", Path(d) / "port"
        write_calibration_file(cal, a.sensors)
        me = [sys.executable, str(Path(__file__).resolve())]
        server = subprocess.Popen(
            [*me, "--_serve", str(port_file), str(rec), str(cal), f"{a.interval:g}"],
            stdout=subprocess.PIPE,
            stderr=open(Path(d) / "server.log", "w"),  # noqa: SIM115
            text=True,
        )
        sensors: subprocess.Popen[str] | None = None
        try:
            assert server.stdout is not None
            line = server.stdout.readline()
            if not line.startswith("R "):
                sys.exit(f"the server did not start:\n{(Path(d) / 'server.log').read_text()}")
            port, viewer_port = (int(x) for x in line.split()[1:])
            # the sensors stream 2 s longer than the sampling so that the last window is full
            sensors = subprocess.Popen(
                [*me, "--_sensors", str(port), str(a.sensors), f"{seconds + 2:g}", str(cal)],
                stdout=subprocess.PIPE,
                text=True,
            )
            time.sleep(2.0)
            run = asyncio.run(soak(server, sensors, viewer_port, seconds, a.interval))
            sent = run["sent"]
            server.wait(timeout=120)
        finally:
            for p in (sensors, server):
                if p is not None and p.poll() is None:
                    p.kill()
                    p.wait(10)
        log_tail = (Path(d) / "server.log").read_text()[-2000:]
        if server.returncode != 0:
            sys.exit(f"the server exited {server.returncode}:\n{log_tail}")
        st = run["run_stats"]
        recording = check_recording(
            rec,
            sent,
            int(st.get("frames_fused", -1)),
            int(st.get("frames_skipped", -1)),
            {k: int(v.get("late_dropped", 0)) for k, v in st.get("sensors", {}).items()},
        )
    figures = judge(run["samples"], seconds)
    checks = {
        "RSS growth < 5 %": figures["rss_growth"] < 0.05,
        "no descriptor growth": figures["fds_last_max"] <= figures["fds_first_max"],
        "latency p99 within 20 % first -> last window": abs(figures["p99_ratio"] - 1) <= 0.20,
        "the recording complete": recording["ok"],
    }
    w = figures["window_s"]
    print(f"\nwindows of {w:g} s (first after {figures['warmup_s']:g} s of warm-up, last):")
    print(f"  RSS {figures['rss_first_mb']:.1f} -> {figures['rss_last_mb']:.1f} MB "
          f"({100 * figures['rss_growth']:+.2f} %; fit {figures['rss_slope_mb_per_h']:+.2f} MB/h, "
          f"max {figures['rss_max_mb']:.1f})")  # fmt: skip
    print(f"  open descriptors (most): {figures['fds_first_max']} -> {figures['fds_last_max']}")
    print(f"  latency p50 {figures['p50_first_ms']:.1f} -> {figures['p50_last_ms']:.1f} ms, "
          f"p99 {figures['p99_first_ms']:.1f} -> {figures['p99_last_ms']:.1f} ms "
          f"(x{figures['p99_ratio']:.3f})")  # fmt: skip
    print(f"  frames: api {run['counts']['api']}, viewer {run['counts']['viewer']}, "
          f"published {recording['frames_published']}, recorded {recording['fused_frames']} "
          f"(frame times skipped by the loop: {recording['frames_skipped']}, holes in the "
          f"recording: {recording['frame_holes']})")  # fmt: skip
    print(f"  recording: complete {recording['complete']}, sensors {len(recording['sensors'])}, "
          f"observations {sum(recording['observations'].values())} of "
          f"{sum(sent.values())} sent; kept out of the fusion as late (recorded all the same): "
          f"{sum(recording['late_dropped'].values())}; missing per sensor "
          f"{recording['missing']}")  # fmt: skip
    for what, ok in checks.items():
        print(f"  {what}: {'yes' if ok else 'NO'}")
    title = (f"soak: {a.sensors} sensors, viewer + subscriber + recorder, {a.minutes:g} min "
             f"(python benchmarks/soak.py --minutes {a.minutes:g})")  # fmt: skip
    if a.plot is not None:
        plot(run["samples"], a.plot, title)
        print(f"plot: {a.plot}")
    if a.json is not None:
        from kinefuse.core.outputs import atomic_write_text

        body = {"figures": figures, "recording": recording, "checks": checks, **run}
        atomic_write_text(
            a.json,
            json.dumps(body, indent=1, default=float),
            what="soak figures",
            recognizer=is_soak_json,
        )
    if not a.smoke and not all(checks.values()):
        sys.exit(1)


def is_soak_json(path: Path) -> bool:
    """A file this benchmark wrote (it may be replaced)."""
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(d, dict) and {"figures", "recording", "checks", "samples"} <= set(d)


if __name__ == "__main__":
    main()

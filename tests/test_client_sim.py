"""The sensor client on a simulated session and as a process: the play timeline, the emulated
host clock, wand sightings and the floor from its own depth frames, the truth sidecar, the
driver interface, signals and exit codes."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from kinefuse.capture.calibration.wand_robust import detect_wand
from kinefuse.core.camera.wand import Wand
from kinefuse.core.frames.observations import DepthFrame
from kinefuse.errors import InputError
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.live.client.client import ClientOptions, SensorClient
from kinefuse.live.client.clocks import HostClock
from kinefuse.live.client.playback import SimTimeline, open_timeline
from kinefuse.live.protocol import (
    BodyFrameMessage,
    CalibrationStop,
    ClockProbe,
    FloorPlaneMessage,
    Goodbye,
    Hello,
    WandSighting,
    Welcome,
    encode,
)
from kinefuse.sim.clock import ClockParams, read_sensor_clocks
from test_client import LIMIT_S, TestServer, run

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def session(shared_data: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """2 sensors, a 3 s wand phase (depth at 10 Hz), then 1 s of walking."""
    from kinefuse.app.workflows.simulate import run_simulate

    out = tmp_path_factory.mktemp("clientsim") / "s.sqlite"
    run_simulate(
        clip=shared_data / "motion" / "cmu" / "02_walk_a.amc",
        out=out,
        rig=ROOT / "rigs" / "level4.toml",
        seconds=1.0,
        calibration_s=3.0,
        depth_rate_hz=10.0,
    )
    return out


def test_host_clock_and_its_inverse():
    c = HostClock(h0=900.0, drift=25e-6, m0=10.0, monotonic=lambda: 12.0)
    assert c.now() == pytest.approx(900.0 + 2.0 * (1 + 25e-6), abs=1e-12)
    assert c.affine.inverse(c.affine.forward(123.456)) == pytest.approx(123.456, abs=1e-9)
    with pytest.raises(InputError, match="ppm is not a clock"):
        HostClock(0.0, 0.05, 0.0)


def test_the_sim_timeline_is_one_clock_depth_first_then_body(session: Path):
    tl = SimTimeline(str(session), "k1")
    items = list(tl.frames())
    t = np.array([x.t_play_s for x in items])
    assert np.all(np.diff(t) >= 0)
    kinds = [isinstance(x.frame, DepthFrame) for x in items]
    n_depth = sum(kinds)
    assert kinds == [True] * n_depth + [False] * (len(kinds) - n_depth)  # wand phase first
    with SessionStore.open(session) as st:
        assert n_depth == st.depth_frame_count("k1")
        assert len(items) - n_depth == st.observation_count("k1")
        truth = read_sensor_clocks(st, "k1")
        _seq, t_true, _j, _v, _s = st.truth().observations("k1")
        wand_t, _ = st.truth().wand()
    # a body frame plays when it reaches the host: its true capture + the capture-to-host latency
    body_t = t[n_depth:]
    lat = body_t - t_true[: len(body_t)]
    p = ClockParams()
    assert lat.min() >= p.latency_min_s - 1e-6 and lat.max() < p.latency_mean_s + 0.05
    # depth frames play in the wand phase (true time), at capture + the unit's mean latency
    assert t[0] >= 0.0 and t[n_depth - 1] <= wand_t[-1] + 0.2
    assert tl.truth == truth and tl.wand == Wand(**{"radius_m": 0.1, "stick_length_m": 0.4,
                                                    "stick_radius_m": 0.01})  # fmt: skip


def test_sightings_and_floor_come_from_the_clients_own_depth_frames(session: Path):
    def welcome_calibrating() -> Welcome:
        return Welcome(session="t", heartbeat_s=0.5, calibrating=True, calibration_id=4)

    async def go() -> TestServer:
        server = TestServer(welcome=welcome_calibrating())
        await server.start()
        tl = open_timeline(f"sim:{session}#k0")
        client = SensorClient(
            tl,
            ClientOptions(server=("127.0.0.1", server.port), speed=2.0),
            host_clock=lambda m0: HostClock(5.0, 0.0, m0),
        )
        assert await client.run() == 0
        return server

    server = run(go())
    msgs = server.peers[0].messages
    sightings = [m for m in msgs if isinstance(m, WandSighting)]
    floors = [m for m in msgs if isinstance(m, FloorPlaneMessage)]
    assert len(sightings) >= 10 and len(floors) == 1
    assert all(s.calibration_id == 4 and s.detector == "robust" for s in sightings)
    assert sum(s.stride for s in sightings) <= 30 and all(s.stride >= 1 for s in sightings)
    # each sighting is the robust detector on that very depth frame, nothing else
    with SessionStore.open(session) as st:
        intr = st.sensor("k0").intrinsics
        frames = {
            int(q): f
            for seq, _t, fr in st.iter_depth_frames("k0")
            for q, f in zip(seq, fr, strict=True)
        }
        sensor2world, _clock = st.truth().sensor("k0")
    for s in sightings[:5]:
        det = detect_wand(frames[s.seq], intr, Wand())
        np.testing.assert_allclose(s.centre_m, det.centre_sensor_m, atol=1e-12)
        assert s.score == pytest.approx(det.score)
    # the floor seen from the sensor: the sensor's true height above z = 0 within 3 cm
    assert floors[0].offset_m == pytest.approx(sensor2world[2, 3], abs=0.03)
    assert floors[0].n_frames == 15 and floors[0].calibration_id == 4
    # depth images never cross the wire; body frames come after the wand phase
    assert [type(m).__name__ for m in msgs].count("BodyFrameMessage") > 0
    assert max(len(encode(m)) for m in msgs) < 2000  # bytes


def test_calibration_stop_ends_the_sightings(session: Path):
    def sightings(server: TestServer) -> list[WandSighting]:
        return [m for m in server.peers[0].messages if isinstance(m, WandSighting)]

    async def go() -> tuple[TestServer, SensorClient, int, int]:
        server = TestServer(welcome=Welcome(session="t", calibrating=True, calibration_id=4))
        await server.start()
        client = SensorClient(
            open_timeline(f"sim:{session}#k0"),
            ClientOptions(server=("127.0.0.1", server.port), speed=1.0, max_seconds=2.5),
            host_clock=lambda m0: HostClock(5.0, 0.0, m0),
        )
        task = asyncio.ensure_future(client.run())
        await server.wait_for(lambda: bool(server.peers) and len(sightings(server)) >= 3)
        writer = server.peers[0].writer
        assert writer is not None
        writer.write(encode(CalibrationStop(4)))
        n_stop, depth_stop = len(sightings(server)), client.stats.depth_frames
        assert await task == 0
        return server, client, n_stop, depth_stop

    server, client, n_stop, depth_stop = run(go())
    # the wand phase went on (10 Hz depth) but the sightings stopped: at most the ones already
    # queued or being detected when the stop came
    assert client.stats.depth_frames >= depth_stop + 5
    assert len(sightings(server)) <= n_stop + 3


# ---- the process ----------------------------------------------------------------------------


def _env(extra_path: Path | None = None) -> dict[str, str]:
    env = dict(os.environ)
    paths = [str(ROOT / "src")] + ([str(extra_path)] if extra_path else [])
    env["PYTHONPATH"] = os.pathsep.join([*paths, env.get("PYTHONPATH", "")])
    return env


def _sensor(port: int, *args: str, extra_path: Path | None = None) -> subprocess.Popen[str]:
    cmd = [sys.executable, "-m", "kinefuse", "sensor", "--server", f"127.0.0.1:{port}", *args]
    return subprocess.Popen(cmd, env=_env(extra_path), stderr=subprocess.PIPE, text=True)


async def _wait_proc(proc: subprocess.Popen[str], timeout: float = 20.0) -> int:
    end = time.monotonic() + timeout
    while proc.poll() is None:
        if time.monotonic() > end:
            proc.kill()
            raise AssertionError("the sensor process did not stop in time")
        await asyncio.sleep(0.05)
    return proc.returncode


def test_sigterm_is_a_clean_stop_and_the_sidecar_holds_the_truth(session: Path, tmp_path: Path):
    side = tmp_path / "k1.json"

    async def go() -> tuple[TestServer, int, str, float]:
        server = TestServer()
        await server.start()
        epoch = time.monotonic() + 1.5
        proc = _sensor(
            server.port, "--source", f"sim:{session}#k1", "--truth-out", str(side),
            "--epoch-monotonic", repr(epoch),
        )  # fmt: skip
        try:
            await server.wait_for(lambda: len(server.bodies()) >= 3, timeout=LIMIT_S - 10)
            proc.send_signal(signal.SIGTERM)
            code = await _wait_proc(proc)
        finally:
            if proc.poll() is None:
                proc.kill()
        assert proc.stderr is not None
        return server, code, proc.stderr.read(), epoch

    server, code, err, epoch = run(go())
    assert code == 0, err
    assert isinstance(server.peers[0].messages[-1], Goodbye)
    assert server.peers[0].messages[-1].reason == "signal SIGTERM"
    d = json.loads(side.read_text())
    with SessionStore.open(session) as st:
        clock = st.truth().sensor("k1")[1]
    assert d["written_by"] == "kinefuse sensor" and d["sensor_id"] == "k1"
    assert d["h0"] == clock["host_offset_s"] and d["drift"] == clock["host_drift_ppm"] * 1e-6
    assert d["m0"] == d["epoch_monotonic"] == epoch and d["speed"] == 1.0
    assert "source_clock" not in d and d["stats"]["body_sent"] >= 3
    # the body frames' host stamps are the emulated clock at their simulated arrival
    host = HostClock(d["h0"], d["drift"], d["m0"])
    with SessionStore.open(session) as st:
        obs = st.observations("k1")
        arrive = dict(zip(obs.seq.tolist(), obs.t_host_s, strict=True))
    for b in server.bodies():
        assert 0 <= b.t_host_s - arrive[b.seq] < 0.1  # s: sent when its time came, not before
    assert host.affine.forward(d["m0"]) == d["h0"]
    # every key the sidecar holds is documented in docs/live.md (D's evaluation reads them)
    doc = (ROOT / "docs" / "live.md").read_text(encoding="utf-8")
    table = doc.split("### The truth sidecar", 1)[1].split("###", 1)[0]
    for key in d:
        assert f"`{key}`" in table, key


def test_every_sensor_option_is_documented():
    from kinefuse.app.cli import build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "command")
    sensor = sub.choices["sensor"]  # type: ignore[attr-defined]
    doc = (ROOT / "docs" / "live.md").read_text(encoding="utf-8")
    section = doc.split("## Sensor client and drivers", 1)[1]
    for action in sensor._actions:
        for opt in action.option_strings:
            if opt.startswith("--") and opt != "--help":
                assert f"`{opt}" in section, opt


def test_a_foreign_sidecar_path_is_never_overwritten(session: Path, tmp_path: Path):
    side = tmp_path / "notes.json"
    side.write_text('{"mine": true}\n')
    proc = _sensor(1, "--source", f"sim:{session}#k1", "--truth-out", str(side))
    _out, err = proc.communicate(timeout=LIMIT_S)
    assert proc.returncode == 2 and "notes.json" in err
    assert side.read_text() == '{"mine": true}\n'


def test_wrong_token_exits_3_with_a_clear_message(session: Path):
    async def go() -> tuple[int, str]:
        server = TestServer(token="right")
        await server.start()
        proc = _sensor(server.port, "--source", f"sim:{session}#k0", "--token", "wrong")
        code = await _wait_proc(proc)
        assert proc.stderr is not None
        return code, proc.stderr.read()

    code, err = run(go())
    assert code == 3
    # (mutual authentication: the server's proof fails first, so the client refuses the server)
    assert "could not prove that it knows the token" in err and "Traceback" not in err


DRIVER = '''
import math, time
import numpy as np
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.frames.observations import BodyFrame

class FakeKinect:
    """A driver: frames when the device delivers them, host stamps on time.monotonic()."""

    def __init__(self, frames="5", serial="X"):
        self.n = int(frames)
        self.serial = serial

    @property
    def sensor_ids(self):
        return ("kinect-1",)

    def intrinsics(self, sensor_id):
        return Intrinsics(fx=364.0, fy=364.0)

    def __iter__(self):
        for k in range(self.n):
            time.sleep(0.02)
            j = np.full((25, 3), 0.1 * k)
            j[:, 2] = 2.0
            yield BodyFrame("kinect-1", k, 10.0 + k / 30, time.monotonic(), j,
                            np.full(25, 2, np.int8))

def not_a_source():
    return 42
'''


def test_a_driver_plugs_in_as_module_factory(tmp_path: Path):
    (tmp_path / "fakedriver.py").write_text(textwrap.dedent(DRIVER))

    async def go() -> tuple[TestServer, int, str]:
        server = TestServer()
        await server.start()
        proc = _sensor(
            server.port,
            "--source",
            "driver:fakedriver:FakeKinect?frames=7&serial=SN42",
            extra_path=tmp_path,
        )
        code = await _wait_proc(proc)
        assert proc.stderr is not None
        return server, code, proc.stderr.read()

    server, code, err = run(go())
    assert code == 0, err
    hello = server.peers[0].messages[0]
    assert isinstance(hello, Hello) and hello.sensor_id == "kinect-1" and hello.serial == "SN42"
    assert hello.intrinsics is not None and hello.intrinsics.fx == 364.0
    bodies = [m for m in server.peers[0].messages if isinstance(m, BodyFrameMessage)]
    assert [b.seq for b in bodies] == list(range(7))
    assert all(abs(b.t_host_s - time.monotonic()) < 60 for b in bodies)  # the PC's own clock


@pytest.mark.parametrize(
    ("spec", "match"),
    [
        ("driver:fakedriver", "expected driver:MODULE:FACTORY"),
        ("driver:no_such_module_x:Cls", "cannot import 'no_such_module_x'"),
        ("driver:fakedriver:Nope", "has no callable 'Nope'"),
        ("driver:fakedriver:not_a_source", "not a FrameSource"),
        ("driver:fakedriver:FakeKinect?colour=red", "unexpected keyword argument 'colour'"),
        ("nosuchkind:x", "unknown kind 'nosuchkind'"),
    ],
)
def test_bad_driver_specs_say_what_is_wrong(tmp_path: Path, monkeypatch, spec, match):
    (tmp_path / "fakedriver.py").write_text(textwrap.dedent(DRIVER))
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(InputError, match=match):
        open_timeline(spec)


def test_a_real_kinect_multitrack_log_goes_through_the_live_path(shared_data: Path):
    log = shared_data / "kinect" / "kinect_multitrack" / "Study_4_Kinect_1_Time_1_22_06_PM.csv"
    from kinefuse.pipeline.frame_sources import open_source

    ref = [f for _, f in zip(range(40), open_source(f"multitrack:{log}"), strict=False)]

    async def go() -> tuple[TestServer, SensorClient]:
        server = TestServer()
        await server.start()
        tl = open_timeline(f"multitrack:{log}")
        assert tl.source_clock == "host" and not tl.live
        client = SensorClient(
            tl,
            ClientOptions(server=("127.0.0.1", server.port), speed=4.0, max_seconds=1.0),
            host_clock=lambda m0: HostClock(0.0, 0.0, m0),
        )
        assert await client.run() == 0
        return server, client

    server, _client = run(go())
    bodies = server.bodies()
    assert server.peers[0].hello is not None
    assert server.peers[0].hello.sensor_id == ref[0].sensor_id  # the log's Kinect_Id
    assert 20 <= len(bodies) <= 40  # 1 s of a ~30 Hz log
    for b in bodies:
        r = ref[b.seq]
        assert b.t_device_s == r.t_device_s  # the log's Skeleton_Time
        np.testing.assert_allclose(b.joints_m, r.joints_m, atol=1e-6, equal_nan=True)
        assert b.n_crossings is not None
    # played on the log's own arrival times, 4 times as fast
    t_host = np.array([b.t_host_s for b in bodies])
    span_log = ref[bodies[-1].seq].t_host_s - ref[bodies[0].seq].t_host_s
    assert abs((t_host[-1] - t_host[0]) - span_log / 4.0) < 0.05  # s


def test_kinect2json_plays_on_its_device_clock(shared_data: Path):
    tl = open_timeline(f"kinect2json:{shared_data / 'kinect' / 'kinect2_tracking' / 'walker.json'}")
    first = [x for _, x in zip(range(3), tl.frames(), strict=False)]
    assert tl.source_clock == "device"
    assert [x.t_play_s for x in first] == pytest.approx([0.0, 1 / 30, 2 / 30])


def test_probes_stay_prompt_while_the_client_detects_the_wand(session: Path):
    def probes(server: TestServer, writer: asyncio.StreamWriter) -> None:
        async def every() -> None:
            i = 0
            while not writer.is_closing():
                # bursts of 4 as the server sends them, one burst every 0.25 s
                for _ in range(4):
                    writer.write(encode(ClockProbe(i, server.clock())))
                    i += 1
                    await asyncio.sleep(0.01)
                await asyncio.sleep(0.2)

        server.task = asyncio.ensure_future(every())  # type: ignore[attr-defined]

    async def go() -> tuple[TestServer, SensorClient]:
        server = TestServer(
            welcome=Welcome(session="t", calibrating=True, calibration_id=1), on_welcome=probes
        )
        await server.start()
        client = SensorClient(
            open_timeline(f"sim:{session}#k0"),
            ClientOptions(server=("127.0.0.1", server.port), max_seconds=2.0),
            host_clock=lambda m0: HostClock(300.0, 40e-6, m0),
        )
        assert await client.run() == 0
        return server, client

    server, client = run(go())
    assert client.stats.depth_detected >= 10  # the detector was busy all along
    host = client.host_clock
    assert host is not None
    replies = server.peers[0].replies
    assert len(replies) >= 20
    delay = np.array([(t4 - r.t1) - (r.t3 - r.t2) for r, t4 in replies])
    mid = np.array([0.5 * (r.t1 + t4) for r, t4 in replies])
    offset = np.array([0.5 * ((r.t2 - r.t1) + (r.t3 - t4)) for r, t4 in replies])
    truth = np.array([host.affine.forward(server.t0 + m) - m for m in mid])
    # the least-delay probe of each burst of 4 (what the server's estimator keeps)
    n = len(replies) // 4 * 4
    best = np.argmin(delay[:n].reshape(-1, 4), axis=1) + np.arange(0, n, 4)
    err = np.abs(offset[best] - truth[best])
    assert np.median(err) < 0.5e-3  # s
    assert np.median(delay[best]) < 2e-3  # s


def test_a_client_joining_a_past_epoch_starts_at_the_present(session: Path):
    async def go() -> tuple[TestServer, SensorClient]:
        server = TestServer(welcome=Welcome(session="t", calibrating=True, calibration_id=1))
        await server.start()
        epoch = time.monotonic() - 3.3  # the wand phase (3 s) is over: the motion has begun
        client = SensorClient(
            open_timeline(f"sim:{session}#k1"),
            ClientOptions(server=("127.0.0.1", server.port)),
            host_clock=lambda m0: HostClock(5.0, 0.0, m0),
            epoch_monotonic=epoch,
        )
        assert await client.run() == 0
        return server, client

    server, client = run(go())
    msgs = server.peers[0].messages
    # no depth was due
    assert not any(isinstance(m, WandSighting | FloorPlaneMessage) for m in msgs)
    bodies = server.bodies()
    assert bodies and client.stats.depth_frames == 0
    with SessionStore.open(session) as st:
        n_depth = st.depth_frame_count("k1")
        n_body = st.observation_count("k1")
    # everything before the present was skipped unprocessed, the rest played
    assert client.stats.skipped_at_start + len(bodies) == n_depth + n_body
    assert client.stats.skipped_at_start >= n_depth + 0.2 * 30
    tl = SimTimeline(str(session), "k1")
    truth = tl.truth
    assert truth is not None
    first_true = truth.host.affine.inverse(
        next(x.frame.t_host_s for x in tl.frames() if x.frame.seq == bodies[0].seq
             and not isinstance(x.frame, DepthFrame))
    )  # fmt: skip
    assert first_true >= 3.3  # s: nothing older than the join instant was sent

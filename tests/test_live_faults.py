"""Process-level faults of the live system: real ``kinefuse serve`` and ``kinefuse sensor``
processes on 127.0.0.1 (port 0), every wait bounded.

- a client killed mid-run: fused frames keep flowing from the others, and the restarted client
  rejoins with the pose it was calibrated with (no new calibration);
- the server SIGKILLed while recording: at most the last 0.5 s is lost and the file opens;
- garbage bytes, an oversized frame, a wrong token and a duplicate sensor id, each sent by a raw
  peer to a running server with a client streaming: each is refused, and the session goes on;
- a real KinectMultiTrack log replayed by two sensor processes gives a recording whose
  consistency figures (as ``kinefuse realdata``) can be computed.

The server's own handling of each fault is tested in-process by ``tests/test_server*.py``; here
the point is that it holds between real processes, through the real command lines.
"""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.workflows.demo import ChildProcesses, parse_listening, sensor_args
from kinefuse.app.workflows.simulate import demo_clip_path, run_simulate
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.live.protocol import codec
from kinefuse.live.protocol.auth import compute_mac
from kinefuse.live.protocol.messages import AuthReply, Challenge, Error, Hello, Message

CAL_S = 6.0  # the wand phase of the test sessions, s
MOTION_S = 9.0  # their motion, s (a restarted client has several seconds left to stream)
TOKEN = "3f1c9a7be2d54f08a6b1c3e5d7f9021b4c6e8a0d2f4b6c8e0a2c4e6f8b0d2f4a"  # 256 bits


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("faults") / "sim.sqlite"
    run_simulate(clip=demo_clip_path(), out=out, sensors=2, seconds=MOTION_S, calibration_s=CAL_S)
    return out


def _serve(procs: ChildProcesses, rec: Path, *extra: str) -> int:
    args = ["serve", "--host", "127.0.0.1", "--port", "0", "--record", str(rec), *extra]
    server = procs.start("server", args, announce=True)
    return parse_listening(procs.wait_first_line(server, 60.0))[1]


def _sensors(
    procs: ChildProcesses, port: int, session: Path, work: Path, *extra: str
) -> tuple[float, dict[str, list[str]]]:
    epoch = time.monotonic() + 4.0
    cmds = {}
    for sid in ("k0", "k1"):
        cmds[sid] = [*sensor_args(port, session, sid, work / f"{sid}.json", epoch), *extra]
        procs.start(f"sensor-{sid}", cmds[sid])
    return epoch, cmds


def _child(procs: ChildProcesses, name: str):
    return next(c for c in reversed(procs.children) if c.name == name)


def _wait_until(t_mono: float) -> None:
    time.sleep(max(0.0, t_mono - time.monotonic()))


def _server_t0(rec: Path) -> float:
    with SessionStore.open(rec) as st:
        return float(st.meta()["server_t0_monotonic"])  # type: ignore[arg-type]


def _events(rec: Path) -> list[tuple[float, str, str | None, dict]]:
    from kinefuse.formats.store.live_tables import events

    with SessionStore.open(rec) as st:
        return events(st)


def test_a_killed_client_rejoins_with_its_pose_and_fusion_goes_on(tmp_path, session) -> None:
    from kinefuse.formats.store.live_tables import live_fused

    rec = tmp_path / "rec.sqlite"
    with ChildProcesses(tmp_path / "logs") as procs:
        port = _serve(procs, rec, "--auto-calibrate")
        epoch, cmds = _sensors(procs, port, session, tmp_path)
        kill_at = epoch + CAL_S + 2.0  # calibrated by then (1.5 s after the last sighting)
        _wait_until(kill_at)
        victim = _child(procs, "sensor-k1")
        victim.popen.send_signal(signal.SIGKILL)
        victim.popen.wait(10)
        time.sleep(1.5)
        t_back = time.monotonic()
        procs.start("sensor-k1", cmds["k1"])  # the same command: it resumes at the present
        for c in procs.children:
            if c.name.startswith("sensor") and c is not victim:
                c.popen.wait(epoch + CAL_S + MOTION_S + 20 - time.monotonic())
                assert c.popen.returncode == 0, c.tail()
        assert procs.stop(_child(procs, "server")) == 0
    t0 = _server_t0(rec)
    ev = _events(rec)
    k1 = [(t, k, d) for t, k, s, d in ev if s == "k1" and k in ("connected", "disconnected")]
    assert [k for _, k, _ in k1] == ["connected", "disconnected", "connected", "disconnected"]
    assert k1[2][2]["has_pose"] is True  # it came back with its calibration
    assert sum(1 for _, k, _, _ in ev if k == "calibration_result") == 1  # none redone
    with SessionStore.open(rec) as st:
        lf = live_fused(st)
        k1_obs = st.observations("k1").t_receive_server_s
    gap = (lf.t_server_s > kill_at - t0 + 0.2) & (lf.t_server_s < t_back - t0)
    assert gap.sum() > 20  # 30 Hz frames went on while k1 was away ...
    body = np.isfinite(lf.positions_m).all(-1).any(-1)
    assert body[gap].mean() > 0.8  # ... fused from k0 alone
    assert (k1_obs > t_back - t0).sum() > 30  # and k1 streams again after its restart


def test_sigkill_of_the_server_loses_at_most_half_a_second(tmp_path, session) -> None:
    from kinefuse.formats.store.live_tables import live_fused

    rec = tmp_path / "rec.sqlite"
    with ChildProcesses(tmp_path / "logs") as procs:
        port = _serve(procs, rec, "--auto-calibrate")
        epoch, _ = _sensors(procs, port, session, tmp_path)
        _wait_until(epoch + CAL_S + 3.0)
        server = _child(procs, "server")
        t_kill = time.monotonic()
        server.popen.send_signal(signal.SIGKILL)
        server.popen.wait(10)
    # the file opens as it was left (a -wal beside it), read-only, and says it is incomplete
    t_kill_server = t_kill - _server_t0(rec)
    with SessionStore.open(rec) as st:
        assert not st.complete
        last_obs = max(float(np.nanmax(st.observations(s.id).t_receive_server_s))
                       for s in st.sensors())  # fmt: skip
        lf = live_fused(st)
    assert t_kill_server - 0.5 <= last_obs <= t_kill_server
    assert t_kill_server - 0.5 <= lf.t_server_s.max() <= t_kill_server
    # and the commands read it (inspect recovers what a crashed writer left)
    done = subprocess.run(
        [sys.executable, "-m", "kinefuse", "inspect", str(rec)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr


def _raw_peer(port: int, send: list[Message] | bytes, *, reply: bool = False) -> list[Message]:
    """Connect, send frames (or raw bytes), answer a challenge with a wrong MAC (``reply``),
    read until the server closes; return what it sent. Raises if it does not close in 10 s."""
    got: list[Message] = []
    dec = codec.Decoder()
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        s.sendall(send if isinstance(send, bytes) else b"".join(codec.encode(m) for m in send))
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            try:
                data = s.recv(65536)
            except ConnectionResetError:
                break
            if not data:
                break
            for m in dec.feed(data):
                got.append(m)
                if reply and isinstance(m, Challenge):
                    s.sendall(codec.encode(AuthReply(mac=bytes(32))))
        else:
            raise AssertionError("the server did not close the connection within 10 s")
    return got


def test_bad_peers_are_refused_and_the_session_goes_on(tmp_path, session) -> None:
    from kinefuse.formats.store.live_tables import live_fused

    rec = tmp_path / "rec.sqlite"
    intr = Intrinsics()
    with ChildProcesses(tmp_path / "logs") as procs:
        port = _serve(procs, rec, "--token", TOKEN, "--auto-calibrate")
        epoch, _ = _sensors(procs, port, session, tmp_path, "--token", TOKEN)
        _wait_until(epoch + CAL_S + 2.5)  # calibrated and fusing (1.5 s after the wand)
        t_bad = time.monotonic()
        # garbage: a frame of a valid length whose body is not msgpack
        _raw_peer(port, codec.HEADER.pack(16) + b"\xc1" * 16)
        # an oversized frame: the length prefix alone is refused
        _raw_peer(port, codec.HEADER.pack(codec.MAX_FRAME_BYTES + 1) + b"x" * 1000)
        # a wrong token
        hello = Hello(role="sensor", sensor_id="intruder", intrinsics=intr)
        got = _raw_peer(port, [hello], reply=True)
        assert isinstance(got[-1], Error) and got[-1].code == "auth"
        # a second client claiming k0, with the right token
        dup = Hello(role="sensor", sensor_id="k0", intrinsics=intr)
        with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
            s.sendall(codec.encode(dup))
            dec, msgs = codec.Decoder(), []
            while not msgs:
                msgs = dec.feed(s.recv(65536))
            assert isinstance(msgs[0], Challenge)
            mac = compute_mac(TOKEN, msgs[0].nonce, role="sensor", sensor_id="k0")
            s.sendall(codec.encode(AuthReply(mac=mac)))
            rest = b""
            while chunk := s.recv(65536):
                rest += chunk
            errs = [m for m in dec.feed(rest) if isinstance(m, Error)]
            assert errs and errs[0].code == "duplicate_id"
        t_done = time.monotonic()
        for c in procs.children:
            if c.name.startswith("sensor"):
                c.popen.wait(epoch + CAL_S + MOTION_S + 20 - time.monotonic())
                assert c.popen.returncode == 0, c.tail()
        assert procs.stop(_child(procs, "server")) == 0
    t0 = _server_t0(rec)
    codes = [d["code"] for _, k, _, d in _events(rec) if k == "refused"]
    assert sorted(codes) == ["auth", "duplicate_id", "malformed", "oversize"]
    with SessionStore.open(rec) as st:
        assert st.complete
        lf = live_fused(st)
        for sid in ("k0", "k1"):
            t = st.observations(sid).t_receive_server_s
            during = t[(t > t_bad - t0 - 1.0) & (t < t_done - t0 + 1.0)]
            assert np.diff(during).max() < 0.3  # the clients streamed on, no gap
    t = lf.t_server_s
    during = t[(t > t_bad - t0 - 1.0) & (t < t_done - t0 + 1.0)]
    assert during.size > 45 and np.diff(during).max() < 0.1  # and fused frames kept coming
    # and what was fused is right, with two sensors (best-live's facing is no tie any more)
    from kinefuse.lab.live_truth import live_vs_offline, write_live_truth

    write_live_truth(rec, session, {sid: tmp_path / f"{sid}.json" for sid in ("k0", "k1")})
    with SessionStore.open(rec) as st:
        mae = live_vs_offline(st)
    assert mae["live"] < 0.10 and mae["ratio"] < 1.5  # 10 cm; mirrored limbs gave 32 cm


def test_a_real_log_replayed_by_two_sensor_processes(tmp_path, shared_data) -> None:
    from kinefuse.formats.kinect_multitrack import read_kinect_multitrack
    from kinefuse.lab.live_consistency import recording_consistency

    logs = sorted((shared_data / "kinect" / "kinect_multitrack").glob("Study_4_Kinect_1_*.csv"))
    if not logs:
        pytest.skip("no KinectMultiTrack log in the shared data")
    ids = [s.sensor_id for s in read_kinect_multitrack(logs[0]).streams]
    rec = tmp_path / "rec.sqlite"
    with ChildProcesses(tmp_path / "logs") as procs:
        port = _serve(procs, rec)
        for k, sid in enumerate(ids):
            src = f"multitrack:{logs[0]}#{sid}"
            args = [
                "sensor",
                "--server",
                f"127.0.0.1:{port}",
                "--source",
                src,
                "--speed",
                "2",
                "--max-seconds",
                "30",
            ]
            procs.start(f"sensor-{k}", args)
        for c in procs.children[1:]:
            c.popen.wait(60)
            assert c.popen.returncode == 0, c.tail()
        assert procs.stop(procs.children[0]) == 0
    r = recording_consistency(rec)
    assert sorted(r["sensors"]) == sorted(ids)
    assert r["registration"]["kind"] == "body"
    med = r["disagreement"][f"{r['sensors'][0]}|{r['sensors'][1]}"]["all"][0]
    assert 0.02 < med < 0.15  # real sensors disagree by a few cm (realdata: 3-5 cm)
    assert r["fused_finite"] > 0.8 * r["frames_with_body"]

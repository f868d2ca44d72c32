"""The sensor port's seams an attacker or a careless operator finds (docs/security.md, "The
sensor port"): a restarted sensor, an offline id taken, a stale frame, the handshake lockout, a
weak token, online guessing, a log flood, control characters and a trailing newline.

Real servers on 127.0.0.1 (port 0) with a token and a calibrated sensor; attackers connect
from other loopback addresses (127.0.0.2, 127.0.0.3: other machines, as on a LAN) where the
address matters. Every wait is bounded.
"""

from __future__ import annotations

import asyncio
import contextlib
import datetime as _dt
import logging
import os
import stat
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest

import test_mutual_auth as mutual
import test_server_safety as safety
from kinefuse.app.cli.main import main
from kinefuse.capture.calibration.calib_file import CalibrationFile, SensorCalibration
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.skeleton import N_JOINTS, standing_pose
from kinefuse.formats.store import live_tables as store_live
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.live.bus import FusedFrame
from kinefuse.live.client.client import ClientRefused
from kinefuse.live.protocol import (
    AuthReply,
    BodyFrameMessage,
    Challenge,
    ClockProbe,
    ClockReply,
    Error,
    Goodbye,
    Heartbeat,
    Hello,
    Status,
    StatusRequest,
    Welcome,
    encode,
)
from kinefuse.live.protocol.auth import compute_mac
from kinefuse.live.server.server import Server, ServerOptions

TOKEN = "6c1e3a5f7b9d0e2c4a6f8b1d3e5a7c9f0b2d4e6a8c1f3b5d7e9a0c2e4f6b8d1a"
Peer = safety.Peer
ROOT = Path(__file__).resolve().parents[1]
LIMIT_S = 40.0

POSE = safety.pose_front()
JOINTS = (standing_pose() - POSE[:3, 3]) @ POSE[:3, :3]  # the standing skeleton, sensor frame


async def open_from(port: int, source: str) -> Peer:
    """A peer connected from the loopback address ``source`` (another machine, for the server)."""
    r, w = await asyncio.open_connection("127.0.0.1", port, local_addr=(source, 0))
    return Peer(r, w)


async def hello(p: Peer, sid: str, role: str = "sensor", token: str | None = TOKEN) -> Any:
    p.send(Hello(role=role, sensor_id=sid, intrinsics=Intrinsics() if role == "sensor" else None))
    m = await p.recv()
    if isinstance(m, Challenge) and token is not None:
        p.send(AuthReply(mac=compute_mac(token, m.nonce, role=role, sensor_id=sid)))
        m = await p.recv()
    return m


def frame(seq: int, h0: float = 50.0) -> BodyFrameMessage:
    """A body frame of the standing skeleton now (host clock ``monotonic + h0``)."""
    t = time.monotonic() + h0
    return BodyFrameMessage(
        seq=seq,
        t_device_s=t - h0 - 0.06,
        t_host_s=t,
        joints_m=JOINTS,
        states=np.full(N_JOINTS, 2, np.int8),
    )


async def until(cond: Callable[[], bool], timeout: float, what: str) -> None:
    t_end = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < t_end, f"timed out waiting for {what}"
        await asyncio.sleep(0.02)


class Lab:
    """A server (token, a calibration of "k0", optionally recording) and what it published."""

    def __init__(self, srv: Server) -> None:
        self.srv = srv
        self.frames: list[tuple[float, FusedFrame]] = []  # (monotonic when published, frame)

    @property
    def port(self) -> int:
        assert self.srv.port is not None
        return self.srv.port

    def fused_since(self, t0: float) -> int:
        """Frames published after monotonic ``t0`` that used an observation."""
        return sum(1 for t, f in self.frames if t >= t0 and np.isfinite(f.latency_s))


def run_lab(body: Callable[[Lab], Any], **options: Any) -> Any:
    async def go() -> Any:
        o = dict(port=0, token=TOKEN, timeout_s=1.5, handshake_timeout_s=1.5)
        o.update(options)
        srv = Server(ServerOptions(**o))
        cal = CalibrationFile(
            "full",
            _dt.datetime.now(_dt.UTC),
            (SensorCalibration("k0", "", POSE, Intrinsics(), 0.001, 100),),
        )
        srv.load_calibration(cal)
        task = asyncio.ensure_future(srv.run())
        await until(lambda: srv.port is not None, 10, "the server to listen")
        lab = Lab(srv)
        sub = srv.publisher.subscribe(None)

        async def collect() -> None:
            async for it in sub:
                if isinstance(it, FusedFrame):
                    lab.frames.append((time.monotonic(), it))

        col = asyncio.ensure_future(collect())
        try:
            return await body(lab)
        finally:
            srv.request_stop("test")
            await asyncio.wait_for(task, 15)
            col.cancel()

    return asyncio.run(asyncio.wait_for(go(), LIMIT_S))


async def stream(p: Peer, seqs: range | list[int], *, h0: float = 50.0) -> None:
    """Send body frames with these seqs at 30 Hz, answering the server's clock probes."""

    async def answer() -> None:
        with contextlib.suppress(ConnectionError, TimeoutError):
            while True:
                m = await p.recv(30.0)
                if isinstance(m, ClockProbe):
                    t = time.monotonic() + h0
                    p.send(ClockReply(probe_id=m.probe_id, t1=m.t1, t2=t, t3=t))

    task = asyncio.ensure_future(answer())
    try:
        for s in seqs:
            p.send(frame(s, h0))
            await asyncio.sleep(1 / 30)
    finally:
        task.cancel()


# -- a restarted sensor, an offline id taken, a stale frame ----------------------------------------


def test_a_restarted_sensor_is_fused_and_recorded_from_its_first_frame(tmp_path) -> None:
    """Its counter starts again at 0 on a new connection: fused at once (it used to be dropped
    as stale, silently, until it passed the old counter), and both streams are recorded."""
    rec = tmp_path / "rec.sqlite"

    async def body(lab: Lab) -> tuple[int, int]:
        first = await Peer.open(lab.port)
        assert isinstance(await hello(first, "k0"), Welcome)
        await stream(first, range(60))
        first.w.transport.abort()  # killed: no goodbye
        await until(lambda: not lab.srv.clients["k0"].connected, 5, "k0 offline")
        again = await Peer.open(lab.port)
        assert isinstance(await hello(again, "k0"), Welcome)
        t_restart = time.monotonic()
        await stream(again, range(45))  # 1.5 s, counting from 0 again
        fused = lab.fused_since(t_restart)
        again.send(Goodbye(reason="done"))
        await asyncio.sleep(0.6)  # the recorder commits every 0.25 s
        return fused, lab.srv.clients["k0"].stale

    fused, stale = run_lab(body, record=rec)
    assert fused >= 30, fused  # 1.5 s at 30 Hz, the first frames of the new stream fused
    assert stale == 0  # nothing of the new stream was taken for stale
    with SessionStore.open(rec) as st:
        o = st.observations("k0")
        assert o.seq.size == 105, o.seq.size  # every frame of both streams
        assert np.all(np.diff(o.seq) > 0) and o.seq[:60].tolist() == list(range(60))
        shifts = [d for _, kind, sid, d in store_live.events(st) if kind == "seq_offset"]
        assert shifts == [{"seq": 0, "offset": 60}]  # the new stream recorded after the old


def test_an_offline_id_taken_with_seq_2_63_minus_1_cannot_silence_the_real_sensor(
    tmp_path,
) -> None:
    """A token holder takes k0 while it is offline and sends the largest seq there is; the real
    k0 comes back and is fused and recorded; while k0 is connected its id cannot be taken."""
    rec = tmp_path / "rec.sqlite"

    async def body(lab: Lab) -> tuple[int, Any]:
        real = await Peer.open(lab.port)
        assert isinstance(await hello(real, "k0"), Welcome)
        await stream(real, range(30))
        real.w.transport.abort()
        await until(lambda: not lab.srv.clients["k0"].connected, 5, "k0 offline")
        thief = await open_from(lab.port, "127.0.0.2")
        assert isinstance(await hello(thief, "k0"), Welcome)
        thief.send(frame(2**63 - 1))
        await asyncio.sleep(0.2)
        thief.w.transport.abort()
        await until(lambda: not lab.srv.clients["k0"].connected, 5, "the thief offline")
        back = await Peer.open(lab.port)
        assert isinstance(await hello(back, "k0"), Welcome)
        t_back = time.monotonic()
        streaming = asyncio.ensure_future(stream(back, range(30, 75)))
        await asyncio.sleep(0.3)
        other = await open_from(lab.port, "127.0.0.2")  # the live id cannot be taken
        dup = await hello(other, "k0")
        await streaming
        fused = lab.fused_since(t_back)
        back.send(Goodbye(reason="done"))
        await asyncio.sleep(0.6)
        return fused, dup

    fused, dup = run_lab(body, record=rec)
    assert fused >= 30, fused
    assert isinstance(dup, Error) and dup.code == "duplicate_id"
    with SessionStore.open(rec) as st:
        seq = st.observations("k0").seq
    assert seq.size == 30 + 1 + 45  # the real sensor's frames, before and after, all recorded
    assert np.all(np.diff(seq) > 0)


def test_a_stale_frame_is_counted_in_the_sensors_status() -> None:
    """A seq that goes back on a connection is refused: the connection closes (order) and the
    sensor's status, as a control peer gets it, counts the stale frame."""

    async def body(lab: Lab) -> tuple[Any, Any]:
        p = await Peer.open(lab.port)
        assert isinstance(await hello(p, "k0"), Welcome)
        p.send(frame(5))
        p.send(frame(3))
        err = await p.error_then_close(timeout=5.0)
        control = await Peer.open(lab.port)
        assert isinstance(await hello(control, "", role="control"), Welcome)
        control.send(StatusRequest(request_id=7))
        status = await control.recv()
        while not isinstance(status, Status):
            status = await control.recv()
        return err, status

    err, status = run_lab(body)
    assert err is not None and err.code == "order" and "seq" in err.reason
    (k0,) = [s for s in status.sensors if s.sensor_id == "k0"]
    assert k0.stale_frames == 1


# -- the handshake lockout, online guessing --------------------------------------------------------


def test_unauthenticated_connections_do_not_lock_a_restarted_sensor_out() -> None:
    """32 connections from another machine, reopened as soon as the server cuts them, while k0
    is killed and restarted: k0 is welcomed at its first attempt, within 2 s (it used to be
    refused as busy for as long as the attack went on)."""

    async def body(lab: Lab) -> tuple[list[Any], float, int]:
        k0 = await Peer.open(lab.port)
        assert isinstance(await hello(k0, "k0"), Welcome)  # 127.0.0.1 is a sensor's address
        stop = asyncio.Event()
        most = [0]

        async def attacker() -> None:
            while not stop.is_set():
                try:
                    p = await open_from(lab.port, "127.0.0.2")
                    await p.error_then_close(timeout=3.0)
                except OSError:
                    await asyncio.sleep(0.01)
                held = sum(1 for c in lab.srv._pending if c.peer.startswith("127.0.0.2:"))
                most[0] = max(most[0], held)

        attackers = [asyncio.ensure_future(attacker()) for _ in range(32)]
        try:
            await asyncio.sleep(2.0)  # the attack is on (the handshake deadline is 1.5 s)
            k0.w.transport.abort()
            await until(lambda: not lab.srv.clients["k0"].connected, 5, "k0 offline")
            t0 = time.monotonic()
            replies = []
            for _ in range(3):
                again = await Peer.open(lab.port)
                replies.append(await hello(again, "k0"))
                if isinstance(replies[-1], Welcome):
                    break
                await asyncio.sleep(0.5)
            took = time.monotonic() - t0
        finally:
            stop.set()
            await asyncio.gather(*attackers, return_exceptions=True)
        return replies, took, most[0]

    replies, took, most = run_lab(body)
    assert len(replies) == 1 and isinstance(replies[0], Welcome), replies
    assert took < 2.0
    assert most <= 8  # no address holds more than 8 handshakes


def test_failed_authentications_are_throttled_per_address() -> None:
    """Guessing the token online: after a burst of 10 failures an address is refused at once
    (limit), at most about one guess a second; a sensor from elsewhere is still welcomed."""

    async def body(lab: Lab) -> tuple[dict[str, int], Any]:
        codes: dict[str, int] = {}
        t_end = time.monotonic() + 1.5
        while time.monotonic() < t_end:
            p = await open_from(lab.port, "127.0.0.3")
            m = await hello(p, "k0", token="kinect2024")
            if not isinstance(m, Error):
                m = await p.error_then_close(timeout=2.0)
            code = m.code if m is not None else "none"
            codes[code] = codes.get(code, 0) + 1
        good = await Peer.open(lab.port)
        return codes, await hello(good, "k0")

    codes, good = run_lab(body)
    assert 10 <= codes.get("auth", 0) <= 13, codes  # the burst, then about 1 a second
    assert codes.get("limit", 0) >= 10, codes
    assert isinstance(good, Welcome)


# -- tokens ----------------------------------------------------------------------------------------


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT / "src") + os.pathsep + env.get("PYTHONPATH", "")
    env.pop("KINEFUSE_TOKEN", None)
    return env


def test_token_new_writes_a_private_256_bit_token_and_never_replaces_a_file(
    tmp_path, capsys
) -> None:
    f = tmp_path / "token"
    assert main(["token", "new", str(f)]) == 0
    out = capsys.readouterr().out
    assert f"--token-file {f}" in out
    text = f.read_text(encoding="utf-8")
    assert text.endswith("\n") and len(text.strip()) == 64
    int(text.strip(), 16)  # 64 hex digits: 256 bits
    assert stat.S_IMODE(f.stat().st_mode) == 0o600
    assert main(["token", "new", str(tmp_path / "other")]) == 0
    assert (tmp_path / "other").read_text() != text  # random, not a constant
    assert main(["token", "new", str(f)]) == 2  # exists: never replaced
    assert "never replaced" in capsys.readouterr().err
    assert f.read_text(encoding="utf-8") == text
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left


def test_serve_refuses_a_weak_token_unless_told_and_warns_of_a_shared_token_file(
    tmp_path,
) -> None:
    weak = tmp_path / "weak"
    weak.write_text("kinect2024\n", encoding="utf-8")
    weak.chmod(0o600)
    p = subprocess.run(
        [sys.executable, "-m", "kinefuse", "serve", "--port", "0", "--token-file", str(weak)],
        capture_output=True,
        text=True,
        env=_env(),
        timeout=30,
    )
    assert p.returncode == 2, p.stderr
    assert "too weak" in p.stderr and "kinefuse token new FILE" in p.stderr
    assert "--allow-weak-token" in p.stderr and "Traceback" not in p.stderr
    # told otherwise, it serves; a token file others can read gets a warning
    weak.chmod(0o644)
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "kinefuse",
            "serve",
            "--port",
            "0",
            "--token-file",
            str(weak),
            "--allow-weak-token",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=_env(),
    )
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline()
        assert "listening on 127.0.0.1:" in first, first
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=20)
    assert "can be read by other users" in err and f"chmod 600 {weak}" in err


def test_the_sensor_warns_of_a_token_file_others_can_read(tmp_path) -> None:
    """``kinefuse sensor`` reads the token file the same way: the warning, then its run (here
    it cannot reach a server: it is stopped once the warning is out)."""
    f = tmp_path / "token"
    f.write_text(TOKEN + "\n", encoding="utf-8")
    f.chmod(0o640)
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "kinefuse",
            "sensor",
            "--server",
            "127.0.0.1:9",
            "--source",
            "sim:missing.sqlite#k0",
            "--token-file",
            str(f),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=_env(),
    )
    try:
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert "can be read by other users" in err and "chmod 600" in err


# -- logs: a flood of events, control characters, a trailing newline -----------------------------


def test_a_floor_error_flood_is_limited_in_the_log_and_the_recording(tmp_path, caplog) -> None:
    rec = tmp_path / "rec.sqlite"

    async def body(lab: Lab) -> Any:
        p = await Peer.open(lab.port)
        assert isinstance(await hello(p, "k0"), Welcome)
        for k in range(400):  # every heartbeat a new floor error (within the message rate)
            p.send(Heartbeat(floor_error=f"floor fit failed #{k}"))
            if k % 100 == 99:
                await asyncio.sleep(0.2)
        await until(
            lambda: lab.srv.clients["k0"].floor_error == "floor fit failed #399", 5, "the last"
        )
        lab.srv.clients["k0"].events._window_start -= 10.0  # the window is over: summarized
        await asyncio.sleep(0.5)
        p.send(Goodbye(reason="done"))
        await asyncio.sleep(0.5)
        return lab.srv.status()

    with caplog.at_level(logging.INFO, logger="kinefuse.serve"):
        status = run_lab(body, record=rec)
    lines = [r.getMessage() for r in caplog.records if "floor fit failed" in r.getMessage()]
    assert 1 <= len(lines) <= 10, len(lines)
    summary = [r.getMessage() for r in caplog.records if "more events" in r.getMessage()]
    assert summary and "floor_error: " in summary[0], summary
    (k0,) = status.sensors
    assert k0.floor_error == "floor fit failed #399"  # the status shows the latest all the same
    with SessionStore.open(rec) as st:
        ev = store_live.events(st)
    assert 1 <= sum(1 for _, kind, _, _ in ev if kind == "floor_error") <= 10
    (summ,) = [d for _, kind, _, d in ev if kind == "events_summary"]
    assert summ["floor_error"] >= 390


def test_control_characters_from_a_peer_reach_the_log_escaped(caplog) -> None:
    forged = "\x1b[2J\rsensor k0 connected from 10.6.6.6\n"

    async def body(lab: Lab) -> None:
        p = await Peer.open(lab.port)
        assert isinstance(await hello(p, "k0"), Welcome)
        p.send(Heartbeat(floor_error="bad\x1b]0;owned\x07 fit"))
        await until(lambda: lab.srv.clients["k0"].floor_error is not None, 5, "the floor error")
        p.send(Goodbye(reason=forged))
        await until(lambda: not lab.srv.clients["k0"].connected, 5, "k0 gone")

    with caplog.at_level(logging.INFO, logger="kinefuse.serve"):
        run_lab(body)
    text = "\n".join(r.getMessage() for r in caplog.records)
    assert "\x1b" not in text and "\r" not in text and "\x07" not in text
    assert "\\x1b[2J\\rsensor k0 connected from 10.6.6.6\\n" in text
    assert "bad\\x1b]0;owned\\x07 fit" in text


def test_a_sensor_id_with_a_trailing_newline_is_refused() -> None:
    """The id pattern is matched whole: ``k0\\n`` is not ``k0`` (it used to be welcomed beside
    it)."""

    async def body(lab: Lab) -> tuple[Any, list[str]]:
        p = await Peer.open(lab.port)
        wire = msgpack.unpackb(
            encode(Hello(role="sensor", sensor_id="k0", intrinsics=Intrinsics()))[4:]
        )
        wire["sensor_id"] = "k0\n"
        raw = msgpack.packb(wire)
        p.w.write(len(raw).to_bytes(4, "big") + raw)
        err = await p.error_then_close(timeout=5.0)
        return err, list(lab.srv.clients)

    err, ids = run_lab(body)
    assert err is not None and err.code == "field" and "sensor_id" in err.reason
    assert "\\n" in err.reason and ids == []


def test_a_sensor_without_a_token_is_told_to_use_a_token_file() -> None:
    """The real client against the real server: the hint names ``--token-file`` (``--token``
    shows the secret to every user in ``ps``)."""

    async def go() -> str:
        srv, task = await mutual.real_server(TOKEN)
        try:
            with pytest.raises(ClientRefused) as e:
                await asyncio.wait_for(mutual.client(srv.port, token=None).run(), 15)
            return str(e.value)
        finally:
            await mutual.stop_server(srv, task)

    text = asyncio.run(go())
    assert "--token-file FILE" in text and "--token TOKEN" not in text

"""Hostile peers are closed within their deadlines and limits, and the session goes on (issue 23).

Each test runs the server of ``test_server_safety`` (a token, a calibrated sensor "good"
streaming at 30 Hz; afterwards it must still be connected, fused and probed) and one kind of
attacker on 127.0.0.1: slowloris bytes, a slow frame, idle connections above the cap, a flood
of unknown messages or of any messages, a control-request flood, refusals by the hundred,
implausible time stamps. Closure and limits are checked, never timings of the fusion (the
benchmark ``benchmarks/bench_hostile.py`` measures those). Every wait is bounded.
"""

from __future__ import annotations

import asyncio
import logging
import struct
import time

import msgpack
import numpy as np

import test_server_safety as safety
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.skeleton import N_JOINTS
from kinefuse.live.protocol import (
    AuthReply,
    BodyFrameMessage,
    Challenge,
    Error,
    Heartbeat,
    Hello,
    StatusRequest,
    Welcome,
    encode,
)
from kinefuse.live.protocol.auth import compute_mac

TOKEN, Peer = safety.TOKEN, safety.Peer
running = safety.running  # the fixture: a server with a token and a sensor streaming


async def _closed_within(p: Peer, seconds: float) -> tuple[Error | None, float]:
    """Read until the server closes (at most ``seconds``); its Error and the time it took."""
    t0 = time.monotonic()
    err = await p.error_then_close(timeout=seconds)
    return err, time.monotonic() - t0


async def _authenticated(port: int, role: str, sensor_id: str = "", version=(1, 0)) -> Peer:
    p = await Peer.open(port)
    intr = Intrinsics() if role == "sensor" else None
    p.send(Hello(role=role, sensor_id=sensor_id, intrinsics=intr, protocol_version=version))
    m = await p.recv()
    assert isinstance(m, Challenge), m
    p.send(AuthReply(mac=compute_mac(TOKEN, m.nonce, role=role, sensor_id=sensor_id)))
    w = await p.recv()
    assert isinstance(w, Welcome), w
    return p


def test_slowloris_handshakes_are_closed_at_the_handshake_deadline(running) -> None:
    """A byte at a time (each well within the timeout) does not keep a handshake open: the
    whole handshake has one deadline (1.5 s here)."""

    async def body(srv, frames):
        hello = encode(Hello(role="sensor", sensor_id="slow", intrinsics=Intrinsics()))
        peers = [await Peer.open(srv.port) for _ in range(5)]

        async def dribble(p: Peer) -> None:
            for b in hello:
                if p.w.is_closing():
                    return
                p.w.write(bytes([b]))
                await asyncio.sleep(0.2)

        tasks = [asyncio.ensure_future(dribble(p)) for p in peers]
        try:
            return await asyncio.gather(*(_closed_within(p, 6.0) for p in peers))
        finally:
            for t in tasks:
                t.cancel()

    for err, took in running(body):
        assert err is not None and err.code == "timeout", err
        assert took < 3.0  # 1.5 s deadline (a byte every 0.2 s used to keep it open forever)


def test_a_slow_frame_of_an_authenticated_sensor_is_closed(running) -> None:
    """After the handshake, bytes that complete no message do not move the deadline either."""

    async def body(srv, frames):
        p = await _authenticated(srv.port, "sensor", "dribbler")
        p.w.write(struct.pack(">I", 100_000))  # a big frame, sent a few bytes at a time

        async def dribble() -> None:
            while not p.w.is_closing():
                p.w.write(b"\x00" * 16)
                await asyncio.sleep(0.1)

        task = asyncio.ensure_future(dribble())
        try:
            return await _closed_within(p, 8.0)
        finally:
            task.cancel()

    err, took = running(body)
    assert err is not None and err.code == "timeout" and "bytes of a frame" in err.reason
    assert took < 4.0  # timeout_s = 1.5 s


def test_idle_connections_above_the_cap_are_refused_at_once(running) -> None:
    async def body(srv, frames):
        peers = [await Peer.open(srv.port) for _ in range(20)]
        await asyncio.sleep(0.3)
        pending = len(srv._pending)
        results = await asyncio.gather(*(_closed_within(p, 5.0) for p in peers))
        return pending, results

    pending, results = running(body, max_pending=8)
    assert pending <= 8
    busy = [took for err, took in results if err is not None and err.code == "busy"]
    timeout = [took for err, took in results if err is not None and err.code == "timeout"]
    assert len(busy) >= 12 and max(busy) < 1.0  # refused as they came
    assert len(busy) + len(timeout) == 20  # and the others at the handshake deadline


def test_a_flood_of_unknown_messages_is_closed(running) -> None:
    """A peer announcing a newer minor version may send unknown types (skipped and counted), but
    not a stream of nothing else: 400,000 used to be skipped one by one."""

    async def body(srv, frames):
        p = await _authenticated(srv.port, "control", version=(1, 99))
        junk = b"".join(
            struct.pack(">I", len(b)) + b
            for i in range(2000)
            for b in [msgpack.packb({"type": f"future_{i}", "x": i})]
        )
        p.w.write(junk)
        conn = next(c for c in srv._conns if c.role == "control")
        err, _ = await _closed_within(p, 5.0)
        return err, conn.decoder.ignored

    err, ignored = running(body)
    assert err is not None and err.code == "limit" and "unknown" in err.reason
    assert len(ignored) <= 33  # the names it keeps are bounded too


def test_a_message_flood_is_closed(running) -> None:
    async def body(srv, frames):
        p = await _authenticated(srv.port, "sensor", "flooder")
        p.w.write(encode(Heartbeat()) * 5000)  # 5000 at once: above any sensor's burst
        return await _closed_within(p, 5.0)

    err, _ = running(body)
    assert err is not None and err.code == "limit" and "messages a second" in err.reason


def test_a_control_request_flood_is_closed_without_being_answered(running) -> None:
    """Status requests cost the loop a snapshot each: a peer gets so many a second."""

    async def body(srv, frames):
        p = await _authenticated(srv.port, "control")
        n0 = srv.loop.frames
        p.w.write(b"".join(encode(StatusRequest(request_id=i + 1)) for i in range(500)))
        err, _ = await _closed_within(p, 5.0)
        answered = sum(1 for m in p.inbox if type(m).__name__ == "Status")
        return err, answered, srv.loop.frames - n0

    err, answered, _ = running(body)
    assert err is not None and err.code == "limit" and "requests a second" in err.reason
    assert answered <= 25  # the burst (20), not 500


def test_refusals_are_bounded_in_the_log_the_recording_and_memory(running, tmp_path, caplog):
    rec = tmp_path / "rec.sqlite"

    async def body(srv, frames):
        for _ in range(150):
            p = await Peer.open(srv.port)
            p.w.write(struct.pack(">I", 12) + b"\xc1not msgpack!")
            await p.error_then_close(timeout=3.0)
        # a peer that only claims to be k0: the log names its address
        p = await Peer.open(srv.port)
        await p.hello("k0", token="wrong")
        await p.error_then_close(timeout=3.0)
        return srv.refusals.total, len(srv.refused)

    with caplog.at_level(logging.WARNING, logger="kinefuse.serve"):
        total, kept = running(body, record=rec)
    assert total == 151 and kept <= 100
    closing = [r.getMessage() for r in caplog.records if r.getMessage().startswith("closing")]
    assert len(closing) <= 10  # one window's worth; the rest are summarized
    from kinefuse.formats.store.live_tables import events
    from kinefuse.formats.store.session_store import SessionStore

    with SessionStore.open(rec) as st:
        ev = events(st)
    refused = [d for _, k, _, d in ev if k == "refused"]
    assert len(refused) <= 10
    assert all("127.0.0.1:" in d["peer"] for d in refused)
    assert all("127.0.0.1:" in line for line in closing)
    summaries = [d for _, k, _, d in ev if k == "refused_summary"]
    assert sum(n for d in summaries for n in d.values()) + len(refused) <= 151


def test_a_failed_authentication_is_logged_with_the_peers_address(running, caplog) -> None:
    async def body(srv, frames):
        p = await Peer.open(srv.port)
        await p.hello("k0", token="wrong")
        await p.error_then_close(timeout=3.0)

    with caplog.at_level(logging.WARNING, logger="kinefuse.serve"):
        running(body)
    lines = [r.getMessage() for r in caplog.records if "authentication failed" in r.getMessage()]
    assert lines and "127.0.0.1:" in lines[0] and "not authenticated" in lines[0], lines


def _frame(seq: int, t_device: float, t_host: float) -> BodyFrameMessage:
    return BodyFrameMessage(
        seq=seq,
        t_device_s=t_device,
        t_host_s=t_host,
        joints_m=np.full((N_JOINTS, 3), 1.0),
        states=np.full(N_JOINTS, 2, np.int8),
    )


def test_time_stamps_outside_a_plausible_window_are_refused_at_the_door(running) -> None:
    """A sensor that never set its clock up stamps +-1e12 s: legal on the wire, refused here."""

    async def body(srv, frames):
        out = []
        now = time.monotonic()
        for sid, (td, th) in {
            "far-host": (now, 1e12),
            "far-device": (-1e12, now),
        }.items():
            p = await _authenticated(srv.port, "sensor", sid)
            p.send(_frame(1, td, th))
            err, _ = await _closed_within(p, 5.0)
            out.append((err, srv.clients[sid].last_seq))
        # and one whose host clock jumps by a minute between two frames
        p = await _authenticated(srv.port, "sensor", "jumpy")
        p.send(_frame(1, now - 0.06, now + 100.0))
        p.send(_frame(2, now - 0.03, now + 160.0))
        out.append(((await _closed_within(p, 5.0))[0], srv.clients["jumpy"].last_seq))
        return out

    (e1, seq1), (e2, seq2), (e3, seq3) = running(body)
    for err in (e1, e2, e3):
        assert err is not None and err.code == "field" and "clock" in err.reason, err
    assert seq1 is None and seq2 is None  # never reached the sensor's state
    assert seq3 == 1  # the first frame was plausible; the jump was not


PAUSE_S = 4.0


def test_a_stalled_sensors_backlog_is_dropped_not_fused_late(tmp_path) -> None:
    """A sensor paused for 4 s (SIGSTOP, within the timeout) hands its backlog over at once when
    it resumes: device stamps from the pause, host stamps of now. Those pairs bent the device
    clock fit, so later frames were mapped to capture times in the future and published late
    (0.2-2.3 s in the issue); they are dropped and counted, and the frames published after
    the resume are as fresh as before it."""
    import datetime as _dt

    from kinefuse.capture.calibration.calib_file import CalibrationFile, SensorCalibration
    from kinefuse.core.skeleton import standing_pose
    from kinefuse.live.bus import FusedFrame
    from kinefuse.live.protocol import ClockProbe, ClockReply
    from kinefuse.live.server.server import Server, ServerOptions

    async def main():
        srv = Server(ServerOptions(port=0, timeout_s=5.0, record=tmp_path / "rec.sqlite"))
        cal = CalibrationFile(
            "full",
            _dt.datetime.now(_dt.UTC),
            (SensorCalibration("s", "", safety.pose_front(), Intrinsics(), 0.001, 100),),
        )
        srv.load_calibration(cal)
        task = asyncio.ensure_future(srv.run())
        while srv.port is None:
            await asyncio.sleep(0.01)
        frames: list[FusedFrame] = []
        sub = srv.publisher.subscribe(None)

        async def collect():
            async for it in sub:
                if isinstance(it, FusedFrame):
                    frames.append(it)

        col = asyncio.ensure_future(collect())
        p = await Peer.open(srv.port)
        p.send(Hello(role="sensor", sensor_id="s", intrinsics=Intrinsics()))
        assert isinstance(await p.recv(), Welcome)
        pose = safety.pose_front()
        joints = (standing_pose() - pose[:3, 3]) @ pose[:3, :3]
        h0 = 50.0
        paused = asyncio.Event()

        async def answer() -> None:
            while True:
                if paused.is_set():
                    await asyncio.sleep(0.01)
                    continue
                m = await p.recv(10.0)
                if isinstance(m, ClockProbe):
                    t = time.monotonic() + h0
                    p.send(ClockReply(probe_id=m.probe_id, t1=m.t1, t2=t, t3=t))

        def frame(seq: int, t_cap: float) -> BodyFrameMessage:
            return BodyFrameMessage(
                seq=seq,
                t_device_s=t_cap,
                t_host_s=time.monotonic() + h0,
                joints_m=joints,
                states=np.full(N_JOINTS, 2, np.int8),
            )

        ans = asyncio.ensure_future(answer())
        seq = 0

        async def stream(seconds: float) -> None:
            nonlocal seq
            t_end = time.monotonic() + seconds
            while time.monotonic() < t_end:
                p.send(frame(seq, time.monotonic() - 0.06))
                seq += 1
                await asyncio.sleep(1 / 30)

        try:
            await stream(3.0)
            paused.set()
            t_pause = time.monotonic()
            await asyncio.sleep(PAUSE_S)
            paused.clear()
            t_resume = time.monotonic()
            n_before = len(frames)
            for t_cap in np.arange(t_pause, t_resume, 1 / 30):  # the backlog, all at once
                p.send(frame(seq, float(t_cap) - 0.06))
                seq += 1
            await stream(3.0)
            after = [f.latency_s for f in frames[n_before:] if np.isfinite(f.latency_s)]
            st = srv.clients["s"]
            td = time.monotonic() - 0.06
            fit_error = st.device.to_host(td) - (td + h0)  # the truth: capture host = td + h0
            return after, getattr(st, "late_dropped", -1), fit_error, seq
        finally:
            ans.cancel()
            p.w.close()
            srv.request_stop("test")
            await asyncio.wait_for(task, 10)
            col.cancel()

    after, dropped, fit_error, sent = asyncio.run(asyncio.wait_for(main(), 40))
    # fused from the sensor again after the resume (the first second or so waits for the clock:
    # the probes of the pause are answered late, as a resumed client does)
    assert len(after) > 20
    # the device clock fit is not bent by the backlog (it was by 0.1-0.3 s: frames fused late);
    # the latencies themselves are the benchmark's to measure (bench_hostile.py), not a test's
    assert abs(fit_error) < 0.02, fit_error
    assert dropped >= 30 * (PAUSE_S - 0.5) - 5  # the backlog older than 0.5 s, counted
    # kept out of the fusion but recorded: no frame that reached the server is lost
    from kinefuse.formats.store.session_store import SessionStore

    with SessionStore.open(tmp_path / "rec.sqlite") as st:
        assert st.observation_count("s") == sent

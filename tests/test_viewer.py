"""The viewer's server without a browser: wire format, live source, replay source, CLI errors."""

from __future__ import annotations

import asyncio
import hashlib
import json
import math
from pathlib import Path

import aiohttp
import numpy as np
import pytest

from kinefuse.app.cli import main
from kinefuse.capture.fusion.status import FusionStatus
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.live.bus import FusedFrame, Publisher, SensorInfo, Status
from kinefuse.live.viewer import live_viewer, serve
from kinefuse.live.viewer.replay import ReplaySource
from kinefuse.live.viewer.session_data import load_session_view
from kinefuse.live.viewer.wire import FUSED, RAW, TRUTH, Layer, decode_frame, encode_frame

TIMEOUT_S = 10.0


@pytest.fixture(scope="module")
def session(tmp_path_factory, shared_data) -> Path:
    """A short simulated walk (no wand phase) with two stored results, fused on the true poses."""
    out = tmp_path_factory.mktemp("viewer") / "walk.sqlite"
    clip = shared_data / "motion" / "cmu" / "02_walk_a.amc"
    assert (
        main(
            [
                "simulate",
                "--clip",
                str(clip),
                "--calibration-seconds",
                "0",
                "--seed",
                "3",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    for m in ("best", "paper"):
        assert main(["fuse", str(out), "--method", m, "--true-calibration", "--store"]) == 0
    return out


def _frame(seq: int, sensors: int = 8, rng: np.random.Generator | None = None) -> FusedFrame:
    rng = rng or np.random.default_rng(seq)
    pos = rng.normal(0, 1, (25, 3))
    pos[3] = np.nan  # a missing joint
    st = np.zeros(25, np.int8)
    st[3] = FusionStatus.NO_DATA
    st[7] = FusionStatus.PREDICTED
    raw = {f"k{i}": rng.normal(0, 1, (25, 3)) for i in range(sensors)}
    return FusedFrame(seq, seq / 30, pos, np.full(25, 1e-4), st, 0.012, raw)


def _status(n: int = 4) -> Status:
    sensors = tuple(
        SensorInfo(
            f"k{i}",
            i != 2,
            1.5,
            0.25 * i,
            0.05,
            math.nan if i == 0 else 30.0,  # fps not known yet
            20.0,
            0.9,
            np.eye(4),
        )
        for i in range(n)
    )
    return Status(
        t_server_s=1.0,
        sensors=sensors,
        calibration_state="calibrated",
        calibration_grade="good",
        fused_fps=30.0,
        method="best-live",
    )


def test_frame_round_trips_and_stays_small(rng) -> None:
    f = _frame(7, sensors=8, rng=rng)
    from kinefuse.live.viewer.wire import fused_frame_bytes

    data = fused_frame_bytes(f, method="best-live")
    assert len(data) < 3000  # a few kB at 30 Hz: 8 sensors + fused, about 2.9 kB
    back = decode_frame(data)
    assert back.seq == 7 and back.t_s == pytest.approx(7 / 30)
    assert back.latency_ms == pytest.approx(12.0, abs=1e-4)
    assert [(la.kind, la.name) for la in back.layers] == [(FUSED, "best-live")] + [
        (RAW, f"k{i}") for i in range(8)
    ]
    fused = back.layers[0]
    np.testing.assert_allclose(fused.positions_m, f.positions_m, atol=1e-6)  # float32: < 1 um
    assert np.isnan(fused.positions_m[3]).all()
    np.testing.assert_array_equal(fused.status, f.status)
    assert back.layers[1].status is None
    np.testing.assert_allclose(back.layers[5].positions_m, f.raw_m["k4"], atol=1e-6)


def test_malformed_frames_are_refused() -> None:
    data = encode_frame(1, 0.5, math.nan, [Layer(TRUTH, "truth", np.zeros((25, 3)))])
    with pytest.raises(ValueError, match="truncated"):
        decode_frame(data[:-4])
    with pytest.raises(ValueError, match="after its last layer"):
        decode_frame(data + b"\0")
    with pytest.raises(ValueError, match="not a version-1 frame"):
        decode_frame(b"\x02" + data[1:])
    with pytest.raises(ValueError, match=r"\(25, 3\)"):
        encode_frame(1, 0.0, 0.0, [Layer(FUSED, "x", np.zeros((24, 3)))])


async def _recv(ws: aiohttp.ClientWebSocketResponse):
    msg = await asyncio.wait_for(ws.receive(), TIMEOUT_S)
    if msg.type == aiohttp.WSMsgType.TEXT:
        return json.loads(msg.data)
    if msg.type == aiohttp.WSMsgType.BINARY:
        return decode_frame(msg.data)
    return msg.type


def test_live_viewer_sends_hello_status_and_frames_then_stops() -> None:
    async def run() -> tuple[list, int]:
        pub = Publisher()
        pub.publish(_status())
        async with live_viewer(pub, port=0) as port, aiohttp.ClientSession() as http:
            page = await (await http.get(f"http://127.0.0.1:{port}/")).text()
            assert "/static/viewer.js" in page
            js = await http.get(f"http://127.0.0.1:{port}/static/viewer.js")
            assert js.status == 200 and "decodeFrame" in await js.text()
            assert (await http.get(f"http://127.0.0.1:{port}/static/../app.py")).status == 404
            ws = await http.ws_connect(f"http://127.0.0.1:{port}/ws")
            got = [await _recv(ws), await _recv(ws)]  # hello, then the last status
            while pub.n_subscribers == 0:
                await asyncio.sleep(0.01)
            for k in range(3):
                pub.publish(_frame(k, sensors=4))
                got.append(await _recv(ws))
        # leaving the context stopped the server: the page's socket is closed, the port free
        closed = await _recv(ws)
        assert closed in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED)
        with pytest.raises(aiohttp.ClientConnectionError):
            async with aiohttp.ClientSession() as http:
                await http.get(f"http://127.0.0.1:{port}/")
        return got, pub.n_subscribers

    got, left = asyncio.run(run())
    assert got[0]["type"] == "hello" and got[0]["mode"] == "live"
    assert len(got[0]["joints"]) == 25 and len(got[0]["bones"]) == 24
    st = got[1]
    assert st["sensors"][0]["fps"] is None  # NaN goes out as null: the page's JSON.parse reads it
    assert st["type"] == "status" and [s["id"] for s in st["sensors"]] == ["k0", "k1", "k2", "k3"]
    assert st["sensors"][2]["connected"] is False and st["calibration_grade"] == "good"
    assert len(st["sensors"][0]["pose"]) == 16
    assert [f.seq for f in got[2:]] == [0, 1, 2]
    assert [la.name for la in got[4].layers] == ["fused", "k0", "k1", "k2", "k3"]
    assert left == 0  # the page's subscription went with it


def test_a_page_that_falls_behind_skips_frames_instead_of_queueing_them() -> None:
    async def run() -> list:
        pub = Publisher()
        async with live_viewer(pub, port=0, maxsize=2) as port, aiohttp.ClientSession() as s:
            ws = await s.ws_connect(f"http://127.0.0.1:{port}/ws")
            assert (await _recv(ws))["type"] == "hello"
            while pub.n_subscribers == 0:
                await asyncio.sleep(0.01)
            for k in range(200):  # a burst the page cannot follow (no await in between)
                pub.publish(_frame(k))
            pub.publish(_status())
            got = [await _recv(ws), await _recv(ws)]
            pub.publish(_frame(1000))  # the next frame comes next: nothing older was queued
            got.append(await _recv(ws))
            return got

    got = asyncio.run(run())
    assert got[0]["type"] == "status"  # the newest status goes first (it came with the frame)
    assert [f.seq for f in got[1:]] == [199, 1000]  # of the burst, only the newest frame


def test_a_page_that_stops_reading_is_cut_off_with_a_reset() -> None:
    """A page that stops reading while frames flow is cut by the API's stall rule (its buffers
    fill, then STALL_LIMIT_S) with a TCP reset, so no orphaned socket keeps queued frames (the
    heartbeat alone closed it gracefully, leaving the kernel holding them for a peer that never
    reads). Watched without reading: reading would make it a live page again."""
    import socket as _socket

    from test_api import _ESTABLISHED, _raw_ws

    async def run() -> tuple[float | None, int]:
        pub = Publisher()
        async with live_viewer(pub, port=0) as port:
            stalled, hello = await asyncio.to_thread(_raw_ws, port, "", "/ws")
            assert json.loads(hello)["type"] == "hello"
            t0 = asyncio.get_running_loop().time()
            cut_after = None
            k = 0
            while (now := asyncio.get_running_loop().time()) - t0 < 40.0:
                for _ in range(5):
                    pub.publish(_frame(k))
                    k += 1
                await asyncio.sleep(1 / 60)
                state = stalled.getsockopt(_socket.IPPROTO_TCP, _socket.TCP_INFO, 8)[0]
                if state != _ESTABLISHED:
                    cut_after = now - t0
                    break
            stalled.settimeout(5.0)
            try:  # what is left to read ends in a reset, not in a close
                while stalled.recv(65536):
                    pass
                ended = 0
            except ConnectionResetError:
                ended = 1
            stalled.close()
            return cut_after, ended

    cut_after, reset = asyncio.run(run())
    assert cut_after is not None, "the page that stopped reading was not cut off within 40 s"
    assert reset == 1


def test_replay_plays_seeks_and_steps_with_the_truth(session) -> None:
    digest = hashlib.sha256(session.read_bytes()).hexdigest()
    with SessionStore.open(session) as st:
        view = load_session_view(st)
    assert list(view.methods) == ["best", "paper"] and view.truth is not None
    # the truth the page compares with: best's MAE on this walk, 2 to 10 cm
    err = np.nanmean(np.linalg.norm(view.methods["best"][0] - view.truth, axis=-1))
    assert 0.02 < err < 0.10, err

    async def run() -> list:
        src = ReplaySource(view, name=session.name)
        async with serve(src, port=0) as port, aiohttp.ClientSession() as s:
            ws = await s.ws_connect(f"http://127.0.0.1:{port}/ws")
            hello, status, player, first = [await _recv(ws) for _ in range(4)]
            out = [hello, status, player, first]
            for cmd in (
                {"cmd": "seek", "frame": 40},
                {"cmd": "step", "delta": -1},
                {"cmd": "seek", "t_s": float(view.t_s[10])},
            ):
                await ws.send_str(json.dumps(cmd))
                out += [await _recv(ws), await _recv(ws)]
            await ws.send_str(json.dumps({"cmd": "speed", "value": 4}))
            await ws.send_str(json.dumps({"cmd": "play"}))
            seen = []
            while len(seen) < 6:
                m = await _recv(ws)
                if not isinstance(m, dict):
                    seen.append(m.seq)
            out.append(seen)
            await ws.send_str("not json")  # ignored
            await ws.send_str(json.dumps({"cmd": "pause"}))
            return out

    hello, status, player, first, *rest = asyncio.run(run())
    assert hello["mode"] == "replay" and hello["replay"]["n_frames"] == view.n_frames
    assert hello["replay"]["methods"] == ["best", "paper"] and hello["replay"]["has_truth"]
    assert status["type"] == "status" and len(status["sensors"]) == 4
    assert player["frame"] == 0 and first.seq == 0
    assert [la.name for la in first.layers][:3] == ["best", "paper", "truth"]
    np.testing.assert_allclose(first.layers[2].positions_m, view.truth[0], atol=1e-6)
    seek, f40, step, f39, tseek, f10, played = rest
    assert seek["frame"] == 40 and f40.seq == 40 and f40.t_s == pytest.approx(view.t_s[40])
    assert step["frame"] == 39 and f39.seq == 39
    assert tseek["frame"] == 10 and f10.seq == 10
    assert played == sorted(played) and played[-1] > 10  # playing moves forward
    assert hashlib.sha256(session.read_bytes()).hexdigest() == digest  # only read


def test_view_command_errors_are_clear(tmp_path, session, capsys) -> None:
    bare = tmp_path / "bare.sqlite"
    # a session without fused results: says how to make one
    import shutil

    shutil.copy(session, bare)
    with SessionStore.open(bare, writable=True) as st:
        st._db.execute("DELETE FROM fused_runs")
        st._db.commit()
    assert main(["view", str(bare)]) == 2
    err = capsys.readouterr().err
    assert "no stored fused result" in err and "kinefuse fuse" in err and "--store" in err
    assert main(["view", str(tmp_path / "missing.sqlite")]) == 2
    assert "missing.sqlite" in capsys.readouterr().err
    assert main(["view", str(session), "--port", "70000"]) == 2
    assert "--port" in capsys.readouterr().err


def test_view_prints_its_url_and_stops_cleanly_on_ctrl_c(session) -> None:
    import os
    import signal
    import subprocess
    import sys
    import urllib.request

    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "kinefuse", "view", str(session), "--port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        lines = [proc.stdout.readline() for _ in range(2)]
        url = lines[1].split()[1]
        assert url.startswith("http://127.0.0.1:") and "2 results" not in lines[0]
        assert "best, paper" in lines[0] and "with truth" in lines[0]
        with urllib.request.urlopen(url, timeout=TIMEOUT_S) as r:
            assert b"viewer.js" in r.read()
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=TIMEOUT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    assert "viewer stopped" in out and "Traceback" not in err


def test_the_status_message_shows_stale_frames_and_floor_errors() -> None:
    """What the operator must act on reaches the page and the API, not only the log."""
    from kinefuse.live.protocol.messages import SensorInfo, Status
    from kinefuse.live.viewer.wire import status_message

    info = SensorInfo("k0", True, 1.0, 0.1, 0.01, 30.0, 5.0, 0.9, None, "no plane", 7)
    msg = status_message(Status(sensors=(info,), recording="/srv/data/take.sqlite"))
    (row,) = msg["sensors"]
    assert row["stale_frames"] == 7 and row["floor_error"] == "no plane"
    assert msg["recording"] == "take.sqlite"

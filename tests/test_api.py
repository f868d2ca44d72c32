"""The live subscription API (docs/api.md) on the REAL system: ``kinefuse serve --token`` with
two ``kinefuse sensor`` processes on 127.0.0.1; docs/api_client.py receives frames; a wrong
token, a malformed request and a cross-origin WebSocket are refused; a subscriber that stops
reading is cut off while the others go on."""

from __future__ import annotations

import asyncio
import base64
import json
import os
import re
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import aiohttp
import pytest

from kinefuse.app.workflows.demo import ChildProcesses, parse_listening, sensor_args
from kinefuse.app.workflows.simulate import demo_clip_path, run_simulate
from kinefuse.live.viewer.subscription_api import API_PATH, api_mac

TOKEN = "9d2e4f6a8b0c1d3e5f7a9b1c3d5e7f9a0b2c4d6e8f0a1b3c5d7e9f1a2b4c6d8e"  # 256 bits
CLIENT = Path(__file__).resolve().parents[1] / "docs" / "api_client.py"
_ESTABLISHED = 1  # tcpi_state of an open TCP connection
_VIEWER = re.compile(r"viewer at http://127\.0\.0\.1:(\d+)/")


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("api") / "sim.sqlite"
    run_simulate(clip=demo_clip_path(), out=out, sensors=2, seconds=22.0, calibration_s=9.0)
    return out


def _raw_ws(
    port: int, query: str = "format=json", path: str = API_PATH
) -> tuple[socket.socket, bytes]:
    """A WebSocket that reads nothing unless asked: the handshake, then the first frame."""
    s = socket.socket()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    s.connect(("127.0.0.1", port))
    key = base64.b64encode(os.urandom(16)).decode()
    request = (
        f"GET {path}?{query} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
        f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n"
    )
    s.sendall(request.encode())
    buf = b""
    while b"\r\n\r\n" not in buf:
        buf += s.recv(1)
    assert b" 101 " in buf.split(b"\r\n")[0], buf
    return s, _raw_frame(s)


def _raw_frame(s: socket.socket) -> bytes:
    def exact(n: int) -> bytes:
        out = b""
        while len(out) < n:
            chunk = s.recv(n - len(out))
            if not chunk:
                raise ConnectionError("closed")
            out += chunk
        return out

    _b0, b1 = exact(2)
    n = b1 & 0x7F
    if n == 126:
        n = struct.unpack(">H", exact(2))[0]
    elif n == 127:
        n = struct.unpack(">Q", exact(8))[0]
    return exact(n)


def _raw_send_text(s: socket.socket, text: str) -> None:
    data = text.encode()
    mask = os.urandom(4)
    head = (
        bytes([0x81, 0x80 | len(data)])
        if len(data) < 126
        else bytes([0x81, 0xFE]) + struct.pack(">H", len(data))
    )
    s.sendall(head + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(data)))


async def _refusals(port: int) -> dict[str, object]:
    url = f"ws://127.0.0.1:{port}{API_PATH}"
    out: dict[str, object] = {}
    async with aiohttp.ClientSession() as http:
        async with http.ws_connect(url) as ws:  # a wrong token
            hello = await ws.receive_json()
            await ws.send_json({"type": "auth", "mac": api_mac("wrong", hello["nonce"])})
            out["wrong"] = await ws.receive_json()
            await ws.receive()
            out["wrong_code"] = ws.close_code
        async with http.ws_connect(url) as ws:  # not an auth message
            await ws.receive_json()
            await ws.send_str("hello?")
            out["malformed"] = await ws.receive_json()
        for query in ("?format=xml", "?format=json&token=" + TOKEN):
            try:
                async with http.ws_connect(url + query):
                    pass
            except aiohttp.WSServerHandshakeError as e:
                out[query] = e.status
        try:
            async with http.ws_connect(url, headers={"Origin": "http://evil.example"}):
                pass
        except aiohttp.WSServerHandshakeError as e:
            out["cross_origin"] = e.status
        try:
            viewer = f"ws://127.0.0.1:{port}/ws"
            async with http.ws_connect(viewer, headers={"Origin": "http://evil.example"}):
                pass
        except aiohttp.WSServerHandshakeError as e:
            out["viewer_cross_origin"] = e.status
        async with http.ws_connect(f"ws://127.0.0.1:{port}/ws") as ws:  # the page asks too
            out["viewer_first"] = await ws.receive_json()
            await ws.send_json({"type": "auth", "token": TOKEN})
            out["viewer_then"] = await ws.receive_json()
    return out


def test_api_clients_receive_frames_and_bad_ones_are_refused(tmp_path, session, monkeypatch):
    monkeypatch.setenv("KINEFUSE_TOKEN", TOKEN)  # the server and its sensors take it from here
    with ChildProcesses(tmp_path / "logs") as procs:
        server = procs.start(
            "server",
            ["serve", "--host", "127.0.0.1", "--port", "0", "--viewer-port", "0",
             "--record", str(tmp_path / "rec.sqlite"), "--auto-calibrate"],
            announce=True,
        )  # fmt: skip
        port = parse_listening(procs.wait_first_line(server, 60.0))[1]
        m = server.wait_line(_VIEWER, 30.0)
        assert m is not None, server.tail()
        api_port = int(m[1])
        epoch = time.monotonic() + 3.0
        for sid in ("k0", "k1"):
            procs.start(
                f"sensor-{sid}", sensor_args(port, session, sid, tmp_path / f"{sid}.json", epoch)
            )
        # a subscriber that authenticates, then stops reading
        stalled, hello = _raw_ws(api_port)
        nonce = json.loads(hello)["nonce"]
        _raw_send_text(stalled, json.dumps({"type": "auth", "mac": api_mac(TOKEN, nonce)}))
        assert json.loads(_raw_frame(stalled))["type"] == "welcome"
        t_stall = time.monotonic()
        # the documented client, against the real server, while that one stalls
        run = subprocess.run(
            [sys.executable, str(CLIENT), f"ws://127.0.0.1:{api_port}{API_PATH}", "--frames",
             "60"], capture_output=True, text=True, timeout=90,
        )  # fmt: skip
        assert run.returncode == 0, run.stderr
        frames = [ln for ln in run.stdout.splitlines() if ln.startswith("frame ")]
        assert len(frames) == 60 and "sensors:" in run.stdout
        seqs = [int(ln.split()[1]) for ln in frames]
        assert seqs == sorted(seqs)
        refused = asyncio.run(_refusals(api_port))
        assert refused["wrong"] == {"type": "error", "error": "unauthorized: wrong token"}
        assert refused["wrong_code"] == 4401
        assert str(refused["malformed"]["error"]).startswith("malformed")  # type: ignore[index]
        assert refused["?format=xml"] == 400
        assert refused["?format=json&token=" + TOKEN] == 400  # never a token in a URL
        assert refused["cross_origin"] == 403 and refused["viewer_cross_origin"] == 403
        assert refused["viewer_first"]["type"] == "auth_required"  # type: ignore[index]
        assert refused["viewer_then"]["type"] == "hello"  # type: ignore[index]
        # the stalled subscriber is cut off (its send buffers full, then STALL_LIMIT_S), with a
        # reset: watched without reading (reading would make it a live subscriber again)
        cut_after = None
        while time.monotonic() - t_stall < 60.0:
            if stalled.getsockopt(socket.IPPROTO_TCP, socket.TCP_INFO, 8)[0] != _ESTABLISHED:
                cut_after = time.monotonic() - t_stall
                break
            time.sleep(0.1)
        assert cut_after is not None, "the stalled subscriber was not cut off within 60 s"
        stalled.settimeout(10.0)
        with pytest.raises((ConnectionError, OSError)):
            while True:
                _raw_frame(stalled)
        stalled.close()
        # and the server is unharmed: another client still gets frames
        again = subprocess.run(
            [sys.executable, str(CLIENT), f"ws://127.0.0.1:{api_port}{API_PATH}", "--frames",
             "10"], capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert again.returncode == 0, again.stderr
        assert server.popen.poll() is None
        assert TOKEN not in server.tail()

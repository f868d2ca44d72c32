"""The subscription API (docs/api.md) in Chromium: a page on the REAL live system (``kinefuse
serve --token`` with two real ``kinefuse sensor`` processes on 127.0.0.1) opens
``/api/v1/stream`` as any web program would, answers the token challenge with the documented
HMAC (``crypto.subtle``), and receives status and fused frames, in JSON and binary; a wrong token
is refused with close code 4401 while the other subscribers go on."""

from __future__ import annotations

import re
import time
from pathlib import Path

import pytest

from kinefuse.app.workflows.demo import ChildProcesses, parse_listening, sensor_args
from kinefuse.app.workflows.simulate import demo_clip_path, run_simulate
from kinefuse.live.viewer.subscription_api import API_PATH

TOKEN = "5b7d9f1a3c5e7a9b2d4f6a8c0e1b3d5f7a9c2e4b6d8f0a1c3e5b7d9f2a4c6e8b"  # 256 bits
_VIEWER = re.compile(r"viewer at (http://\S+)/")

#: the page's program: subscribe, prove the token, collect ``want`` frames (or fail on timeout)
_SUBSCRIBE = """
async ([path, format, token, want]) => {
  const hex = (buf) =>
    [...new Uint8Array(buf)].map((b) => b.toString(16).padStart(2, "0")).join("");
  async function mac(key, nonce) {
    const k = await crypto.subtle.importKey("raw", new TextEncoder().encode(key),
      {name: "HMAC", hash: "SHA-256"}, false, ["sign"]);
    const msg = new TextEncoder().encode("kinefuse-live/1|" + nonce);
    return hex(await crypto.subtle.sign("HMAC", k, msg));
  }
  return await new Promise((resolve) => {
    const out = {messages: [], frames: [], binary: [], status: 0, close: null, error: null};
    const ws = new WebSocket(`ws://${location.host}${path}?format=${format}`);
    ws.binaryType = "arraybuffer";
    const done = () => { ws.close(); resolve(out); };
    const timer = setTimeout(() => { out.error = "timeout"; done(); }, 90000);
    ws.onclose = (e) => { out.close = e.code; clearTimeout(timer); resolve(out); };
    ws.onmessage = async (e) => {
      if (typeof e.data !== "string") {
        out.binary.push(e.data.byteLength);
        if (out.binary.length >= want) { clearTimeout(timer); done(); }
        return;
      }
      const m = JSON.parse(e.data);
      out.messages.push(m.type);
      if (m.type === "hello") {
        ws.send(JSON.stringify({type: "auth", mac: await mac(token, m.nonce)}));
      } else if (m.type === "error") {
        out.error = m.error;
      } else if (m.type === "status") {
        out.status += 1;
      } else if (m.type === "frame") {
        out.frames.push({seq: m.seq, t: m.t_server_s, n: m.positions_m.filter((p) => p).length});
        if (out.frames.length >= want) { clearTimeout(timer); done(); }
      }
    };
  });
}
"""


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("browser_api") / "sim.sqlite"
    # as tests/browser/test_browser_live.py: a 9 s wand phase, so the live calibration succeeds
    run_simulate(clip=demo_clip_path(), out=out, sensors=2, seconds=10.0, calibration_s=9.0)
    return out


def test_page_receives_frames_from_the_api_with_the_token(
    tmp_path, session, page, monkeypatch
) -> None:
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
        epoch = time.monotonic() + 3.0
        for sid in ("k0", "k1"):
            procs.start(
                f"sensor-{sid}", sensor_args(port, session, sid, tmp_path / f"{sid}.json", epoch)
            )
        page.set_default_timeout(120_000)
        page.goto(m[1] + "/")  # the server's own origin (the API refuses cross-origin pages)
        assert page.evaluate("() => window.isSecureContext && !!crypto.subtle")
        wrong = page.evaluate(_SUBSCRIBE, [API_PATH, "json", "not-the-token", 1])
        assert wrong["close"] == 4401 and wrong["error"] == "unauthorized: wrong token"
        assert wrong["frames"] == []
        got = page.evaluate(_SUBSCRIBE, [API_PATH, "json", TOKEN, 60])
        assert got["error"] is None, got
        assert got["messages"][:2] == ["hello", "welcome"] and got["status"] >= 1
        seqs = [f["seq"] for f in got["frames"]]
        assert len(seqs) == 60 and seqs == sorted(set(seqs))
        assert max(f["n"] for f in got["frames"]) == 25  # the person, every joint solved
        binary = page.evaluate(_SUBSCRIBE, [API_PATH, "binary", TOKEN, 30])
        assert binary["error"] is None and len(binary["binary"]) == 30
        assert server.popen.poll() is None  # unharmed by the refused page
        assert TOKEN not in server.tail()

"""The replay source: a recorded session played to each page, with its own timeline per page.

A page sends commands (JSON): ``{"cmd": "play"}``, ``{"cmd": "pause"}``, ``{"cmd": "seek",
"frame": i}`` (or ``"t_s": t``), ``{"cmd": "step", "delta": +1 | -1}``, ``{"cmd": "speed",
"value": x}`` (0.1 to 8). The server answers every command with a ``player`` message (frame,
time, playing, speed) and sends the frame shown; while playing it sends frames at the session's
pace times the speed (skipping frames rather than falling behind).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
from typing import Any

from aiohttp import web

from kinefuse.live.bus import Status
from kinefuse.live.viewer.http_server import read_commands
from kinefuse.live.viewer.session_data import SessionView
from kinefuse.live.viewer.wire import FUSED, RAW, TRUTH, Layer, encode_frame, status_message

SPEEDS = (0.1, 8.0)


class ReplaySource:
    """Plays a :class:`~kinefuse.live.viewer.session_data.SessionView` (see the module
    docstring)."""

    def __init__(self, view: SessionView, *, name: str = "") -> None:
        self.view = view
        self.name = name
        cal = view.calibration
        self._status = Status(
            t_server_s=float(view.t_s[0]) if view.n_frames else 0.0,
            sensors=view.sensors,
            calibration_state="calibrated" if cal else "none",
            calibration_grade=view.calibration_grade,
            fused_fps=self._rate(),
            method=view.primary,
            recording=name or None,
        )

    def _rate(self) -> float:
        t = self.view.t_s
        return float((t.size - 1) / (t[-1] - t[0])) if t.size > 1 and t[-1] > t[0] else 30.0

    def hello(self) -> dict[str, Any]:
        from kinefuse.live.viewer.wire import hello_message

        v = self.view
        return hello_message(
            "replay",
            replay={
                "name": self.name,
                "n_frames": v.n_frames,
                "t0_s": float(v.t_s[0]),
                "t1_s": float(v.t_s[-1]),
                "rate_hz": self._rate(),
                "methods": list(v.methods),
                "sensors": list(v.raw),
                "has_truth": v.truth is not None,
                "truth_note": v.truth_note,
                "calibration": v.calibration,
                "calibration_rms_mm": v.calibration_rms_mm,
            },
        )

    def frame_bytes(self, i: int) -> bytes:
        """The binary frame of frame ``i``: every result, the truth, every raw skeleton."""
        v = self.view
        layers = [Layer(FUSED, m, pos[i], st[i]) for m, (pos, st) in v.methods.items()]
        if v.truth is not None:
            layers.append(Layer(TRUTH, "truth", v.truth[i]))
        layers += [Layer(RAW, sid, raw[i]) for sid, raw in v.raw.items()]
        return encode_frame(i, float(v.t_s[i]), math.nan, layers)

    async def serve(self, ws: web.WebSocketResponse) -> None:
        v = self.view
        loop = asyncio.get_running_loop()
        state: dict[str, Any] = {"frame": 0, "playing": False, "speed": 1.0, "t_play": 0.0}
        state["t_play"] = float(v.t_s[0])
        wake = asyncio.Event()
        dirty = True
        await ws.send_str(json.dumps(status_message(self._status)))

        def player() -> dict[str, Any]:
            i = int(state["frame"])
            return {"type": "player", "frame": i, "t_s": float(v.t_s[i]),
                    "playing": bool(state["playing"]), "speed": state["speed"]}  # fmt: skip

        async def read() -> None:
            nonlocal dirty
            async for cmd in read_commands(ws):
                c = cmd.get("cmd")
                i = int(state["frame"])
                if c == "play":
                    if i >= v.n_frames - 1:
                        i = 0  # play from the start again
                    state["playing"] = True
                elif c == "pause":
                    state["playing"] = False
                elif c == "seek":
                    if isinstance(cmd.get("t_s"), int | float):
                        i = int(abs(v.t_s - float(cmd["t_s"])).argmin())
                    elif isinstance(cmd.get("frame"), int | float):
                        i = int(cmd["frame"])
                elif c == "step":
                    state["playing"] = False
                    d = cmd.get("delta", 1)
                    i += int(d) if isinstance(d, int | float) else 1
                elif c == "speed" and isinstance(cmd.get("value"), int | float):
                    val = float(cmd["value"])
                    if math.isfinite(val):
                        state["speed"] = min(max(val, SPEEDS[0]), SPEEDS[1])
                else:
                    continue
                state["frame"] = min(max(i, 0), v.n_frames - 1)
                state["t_play"] = float(v.t_s[int(state["frame"])])
                dirty = True
                wake.set()
            wake.set()

        async def play() -> None:
            nonlocal dirty
            last = loop.time()
            while not ws.closed:
                now = loop.time()
                if state["playing"]:
                    state["t_play"] = float(state["t_play"]) + (now - last) * float(state["speed"])
                    j = int(v.t_s.searchsorted(float(state["t_play"]), side="right")) - 1
                    j = min(max(j, 0), v.n_frames - 1)
                    if j != state["frame"]:
                        state["frame"] = j
                        dirty = True
                    if j >= v.n_frames - 1:
                        state["playing"] = False
                        dirty = True
                last = now
                if dirty:
                    dirty = False
                    await ws.send_str(json.dumps(player()))
                    await ws.send_bytes(self.frame_bytes(int(state["frame"])))
                    continue
                wake.clear()
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(wake.wait(), timeout=1 / 60)

        async with asyncio.TaskGroup() as tg:
            reader = tg.create_task(read())
            tg.create_task(play())
            await reader

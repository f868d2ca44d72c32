"""Publish a recorded session into a :class:`~kinefuse.live.bus.Publisher` as a live server
would: a :class:`FusedFrame` every frame period, a :class:`Status` every second.

This is how the viewer is exercised without the live server (tests, the README screenshot, the
viewer benchmark): the frames are a stored fused result with each sensor's raw skeleton, the
status figures come from the recording (probe round trips, clock fits, rates, tracked
fractions per frame), the frame counter and times are this loop's own, and ``latency_s`` is
the loop's own lateness (tick due -> published).
"""

from __future__ import annotations

import asyncio
import math
from dataclasses import replace

import numpy as np

from kinefuse.live.bus import FusedFrame, Publisher, Status
from kinefuse.live.viewer.session_data import SessionView


def frame_at(
    view: SessionView, k: int, seq: int, t_server_s: float, latency_s: float
) -> FusedFrame:
    """The :class:`FusedFrame` of frame ``k`` of ``view`` (the primary result)."""
    pos, st = view.methods[view.primary]
    var = np.where(np.isfinite(pos[k]).all(-1), 1e-4, np.nan)
    return FusedFrame(
        seq=seq,
        t_server_s=t_server_s,
        positions_m=pos[k],
        variance_m2=var,
        status=st[k],
        latency_s=latency_s,
        raw_m={sid: raw[k] for sid, raw in view.raw.items()},
    )


def status_at(view: SessionView, k: int, t_server_s: float, fused_fps: float) -> Status:
    """The :class:`Status` at frame ``k``: the recording's per-sensor figures, with the
    tracked fraction of the frame shown."""
    sensors = tuple(
        replace(s, tracked_fraction=float(view.tracked[s.sensor_id][k]))
        if s.sensor_id in view.tracked
        else s
        for s in view.sensors
    )
    return Status(
        t_server_s=t_server_s,
        sensors=sensors,
        calibration_state="calibrated" if view.calibration else "none",
        calibration_grade=view.calibration_grade,
        fused_fps=fused_fps,
        method=view.primary,
    )


async def publish_session(
    publisher: Publisher,
    view: SessionView,
    *,
    rate_hz: float = 30.0,
    frames: int | None = None,
    status_every_s: float = 1.0,
) -> int:
    """Publish ``view`` in a loop at ``rate_hz`` (on the loop's clock) until cancelled or
    ``frames`` frames are out; returns the number published. The session repeats from its start
    when it ends."""
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"rate_hz must be a positive number, got {rate_hz}")
    loop = asyncio.get_running_loop()
    t0 = loop.time()
    period = 1.0 / rate_hz
    seq = 0
    next_status = t0
    while frames is None or seq < frames:
        due = t0 + seq * period
        delay = due - loop.time()
        if delay > 0:
            await asyncio.sleep(delay)
        k = seq % view.n_frames
        now = loop.time()
        if now >= next_status:
            publisher.publish(status_at(view, k, now - t0, rate_hz))
            next_status += status_every_s
        publisher.publish(frame_at(view, k, seq, now - t0, loop.time() - due))
        seq += 1
    return seq

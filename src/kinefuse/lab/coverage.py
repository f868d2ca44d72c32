"""How well the sensors saw the subject: per-sensor tracking and the common capture volume.

Uses only what a real server has (observations and clock probes), never the truth, so it works
on live recordings as well as simulated sessions. ``kinefuse simulate`` warns from it and
``kinefuse inspect`` reports it.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.skeleton import TrackingState
from kinefuse.formats.store.session_store import SessionStore

Array = NDArray[np.float64]

#: Width of the time bins in which "a sensor sees the body" is counted, seconds.
BIN_S = 0.1
#: A sensor that tracks the body in less than this fraction of the motion is warned about.
LOW_TRACKING_FRACTION = 0.5
#: Fewer sensors than this seeing the body means the subject is outside the common volume.
MIN_SENSORS = 2


def _intervals(flag: NDArray[np.bool_], t0: float, step: float) -> list[list[float]]:
    """``[[start_s, end_s], ...]`` of the runs of True in ``flag`` (bins of ``step`` from t0)."""
    out: list[list[float]] = []
    padded = np.concatenate([[False], flag, [False]])
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        out.append([round(t0 + a * step, 3), round(t0 + b * step, 3)])
    return out


def tracking_coverage(store: SessionStore) -> dict[str, Any]:
    """Per-sensor tracking fractions and the intervals the subject leaves the common volume.

    Returns
    -------
    dict
        ``sensors``: ``{id: {"body_fraction", "tracked_joint_fraction"}}`` over the span in
        which any sensor saw a body (``body_fraction``: share of that span's time bins in which
        the sensor reported a body; ``tracked_joint_fraction``: share of TRACKED joints in its
        frames with a body); ``span_server_s``; ``min_sensors``; ``outside_common_volume_s``:
        ``[[start, end], ...]`` server-clock seconds in which fewer than ``min_sensors`` sensors
        saw the body; ``outside_fraction``; ``left_out`` (``{id: why}``: sensors whose time
        stamps are not the recording's, :func:`kinefuse.pipeline.screen.screen_sensors`, counted
        nowhere) and ``notes`` (one line each, with frames dropped). Figures with no data are
        None.
    """
    from kinefuse.pipeline.screen import screen_sensors, server_times

    screen = screen_sensors(store, need_clock=False)
    times: dict[str, Array] = {}
    tracked: dict[str, float | None] = {}
    for sid in screen.usable:
        obs = store.observations(sid)
        body = obs.has_body
        if sid in screen.stray_seq:  # frames stamped outside the recording: not counted
            body = body & ~np.isin(obs.seq, screen.stray_seq[sid])
        if obs.n_frames:
            # device stamps -> the client's clock (from the host receive times) -> server
            t = server_times(
                store.clock_probes(sid),
                obs.t_sensor_s,
                obs.t_receive_host_s,
                obs.t_receive_server_s,
            )
        else:
            t = obs.t_sensor_s
        times[sid] = t[body]
        states = obs.states[body]
        tracked[sid] = float((states == TrackingState.TRACKED).mean()) if body.any() else None
    seen = [t for t in times.values() if t.size]
    result: dict[str, Any] = {
        "sensors": {},
        "span_server_s": None,
        "min_sensors": MIN_SENSORS,
        "outside_common_volume_s": [],
        "outside_fraction": None,
        "left_out": dict(screen.left_out),
        "notes": screen.notes(),
    }
    if not seen:
        for sid in times:
            result["sensors"][sid] = {"body_fraction": 0.0, "tracked_joint_fraction": None}
        return result
    t0 = min(float(t.min()) for t in seen)
    t1 = max(float(t.max()) for t in seen)
    n_bins = max(int(np.ceil((t1 - t0) / BIN_S)), 1)
    count = np.zeros(n_bins, dtype=np.int64)
    for sid, t in times.items():
        has = np.zeros(n_bins, dtype=bool)
        if t.size:
            has[np.clip(((t - t0) / BIN_S).astype(np.intp), 0, n_bins - 1)] = True
        count += has
        result["sensors"][sid] = {
            "body_fraction": float(has.mean()),
            "tracked_joint_fraction": tracked[sid],
        }
    need = min(MIN_SENSORS, len(times))
    outside = count < need
    result["span_server_s"] = [round(t0, 3), round(t1, 3)]
    result["min_sensors"] = need
    result["outside_common_volume_s"] = _intervals(outside, t0, BIN_S)
    result["outside_fraction"] = float(outside.mean())
    return result


def coverage_warnings(cov: dict[str, Any], never_seen: dict[str, str] | None = None) -> list[str]:
    """Plain-language warnings for a :func:`tracking_coverage` result (empty when all is well).

    ``never_seen``: per sensor, what to say of one that never sees the body instead of the
    simulated lab's advice (check its pose in the rig file), e.g. for a recording of real
    sensors (:func:`kinefuse.lab.inspect.never_seen_advice`).
    """
    out = list(cov.get("notes", []))
    for sid, s in cov["sensors"].items():
        frac = s["body_fraction"]
        if frac == 0.0:
            out.append(
                (never_seen or {}).get(sid)
                or f"sensor {sid} never sees the body: check that it looks at the capture area "
                "(its position and look_at_m in the rig file)"
            )
        elif frac < LOW_TRACKING_FRACTION:
            out.append(
                f"sensor {sid} sees the body only {100 * frac:.0f} % of the time: check its pose, "
                "or whether the motion leaves its view"
            )
    gaps = cov["outside_common_volume_s"]
    if gaps:
        total = sum(b - a for a, b in gaps)
        first = ", ".join(f"{a:.1f}-{b:.1f} s" for a, b in gaps[:3])
        more = f" and {len(gaps) - 3} more" if len(gaps) > 3 else ""
        out.append(
            f"the subject is seen by fewer than {cov['min_sensors']} sensors for {total:.1f} s "
            f"({100 * cov['outside_fraction']:.0f} % of the take; server time {first}{more}): it "
            "leaves the common capture volume, and fused joints there are guesses or missing"
        )
    return out

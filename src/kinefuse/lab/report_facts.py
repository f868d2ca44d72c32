"""What the HTML report needs from a session beyond ``evaluate``'s results (evaluation code: reads
the truth for the calibration and clock errors).

:func:`session_facts` is called while the session is open and returns plain data, so the
report is written after the store is closed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.capture.fusion.fusion_run import SensorData
from kinefuse.capture.sync.ntp import probe_offsets
from kinefuse.core.affine_clock import AffineClock
from kinefuse.core.skeleton import TrackingState
from kinefuse.formats.store.session_store import SessionStore

Array = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class ClockTrack:
    """One sensor's clock sync: probe offsets around the fitted line and the fit's true error."""

    sensor_id: str
    t_probe_s: Array  # (N,) server time of each probe
    probe_residual_ms: Array  # (N,) probe offset minus the fitted offset at that time
    rtt_ms: Array  # (N,)
    t_s: Array = field(default_factory=lambda: np.zeros(0))  # (M,) times of the true error
    error_ms: Array | None = None  # (M,) fitted client clock minus the true one (truth only)


@dataclass(frozen=True, eq=False)
class SessionFacts:
    """Plain data for the report (see :func:`session_facts`)."""

    name: str
    clip: str | None
    duration_s: float
    sensors: list[dict[str, Any]]  # id, serial, frames, rate_hz, tracked_fraction
    poses: dict[str, Array]  # the poses the fusion used (sensor2world)
    pose_source: str
    calibration: list[dict[str, Any]] | None  # per sensor: residual_mm, sightings (+ errors)
    calibration_note: str
    clocks: list[ClockTrack]
    latency_ms: Array | None = None  # fused-frame latencies, when the session recorded them
    latency_note: str = ""
    has_truth: bool = False
    #: the range-of-motion phase the session stored (server clock, s): the analysis can run
    rom_phase_s: tuple[float, float] | None = None


def _latencies(store: SessionStore) -> tuple[Array | None, str]:
    """The fused frames' latencies (ms) a live recording holds, and a note on what they are."""
    from kinefuse.formats.store.live_tables import has_live_tables, live_fused

    if has_live_tables(store):
        lat = live_fused(store).latency_s
        lat = 1e3 * lat[np.isfinite(lat)]
        if lat.size:
            return lat, (
                f"{lat.size} fused frames published by the live server: client host receive "
                "(mapped onto the server clock) -> fused frame published, on the server clock"
            )
    return None, (
        "not recorded: this session holds no fused-frame latencies (a simulated session "
        "has no live server; a live recording stores them with its fused frames)"
    )


def _calibration_rows(
    store: SessionStore, poses: dict[str, Array], source: str
) -> tuple[list[dict[str, Any]] | None, str]:
    from pathlib import Path

    from kinefuse.capture.calibration.calib_file import (
        is_calibration_file,
        loads_calibration,
        read_calibration,
    )
    from kinefuse.capture.calibration.compare import pose_errors

    # ``source`` is how kinefuse.lab.poses.resolve_poses named the poses it used
    name = next(
        (n for n in ("full", "paper", "body") if source == f"session calibration ({n})"), None
    )
    text = store.calibration(name) if name else None
    if text is not None:
        cal = loads_calibration(text, source=f"{store.path} [{name}]")
        what = f"stored calibration '{name}'"
    elif Path(source).is_file() and is_calibration_file(Path(source)):
        cal = read_calibration(source)
        what = f"calibration file {Path(source).name}"
    else:
        return None, f"the fusion used {source}: no calibration residuals to show"
    rows = [
        {"id": s.id, "residual_mm": s.residual_m * 1e3, "sightings": s.n_sightings}
        for s in cal.sensors
    ]
    note = f"{what} ({cal.method}); world: {cal.world}"
    if store.has_truth():
        ids = [str(r["id"]) for r in rows]
        true = np.stack([store.truth().sensor(i)[0] for i in ids])
        pe = pose_errors(np.stack([poses[i] for i in ids]), true, align="yaw")
        for r, p, a in zip(rows, pe.position_error_m, pe.rotation_error_deg, strict=True):
            r["position_error_mm"] = float(p) * 1e3
            r["rotation_error_deg"] = float(a)
        note += "; errors against the simulator's poses after a yaw + translation alignment"
    return rows, note


def _clock(store: SessionStore, s: SensorData) -> ClockTrack:
    probes = store.clock_probes(s.id)
    offset, delay, t_mid = probe_offsets(probes)
    fit = s.clock.affine.forward(t_mid) - t_mid
    track = ClockTrack(s.id, t_mid, (offset - fit) * 1e3, 2 * delay * 1e3)
    if not store.has_truth():
        return track
    _, clock = store.truth().sensor(s.id)
    if "host_offset_s" not in clock:
        return track
    t = np.linspace(float(t_mid.min()), float(t_mid.max()), 200)
    host = AffineClock.from_drift_ppm(
        clock.get("host_drift_ppm", 0.0), offset=clock["host_offset_s"]
    )
    true = host.forward(t) - t
    err = (s.clock.affine.forward(t) - t - true) * 1e3
    return ClockTrack(s.id, t_mid, track.probe_residual_ms, track.rtt_ms, t, err)


def session_facts(
    store: SessionStore, sensors: list[SensorData], poses: dict[str, Array], source: str
) -> SessionFacts:
    """Collect what the report shows of ``store`` (open) besides the evaluation."""
    meta = store.meta()
    rows = []
    spans = []
    for s in sensors:
        obs = s.observations
        body = obs.has_body
        span = float(obs.t_sensor_s[-1] - obs.t_sensor_s[0]) if obs.n_frames > 1 else 0.0
        spans.append(span)
        rows.append(
            {
                "id": s.id,
                "serial": store.sensor(s.id).serial,
                "frames": obs.n_frames,
                "rate_hz": (obs.n_frames - 1) / span if span > 0 else float("nan"),
                "tracked_fraction": float((obs.states[body] == TrackingState.TRACKED).mean())
                if body.any()
                else float("nan"),
            }
        )
    cal_rows, cal_note = _calibration_rows(store, poses, source)
    latency, latency_note = _latencies(store)
    clip = meta.get("clip")
    rom = meta.get("rom_phase_server_s")
    rom_phase = (float(rom[0]), float(rom[1])) if isinstance(rom, list) and len(rom) == 2 else None
    return SessionFacts(
        name=store.path.name,
        clip=str(clip) if clip is not None else None,
        duration_s=max(spans) if spans else 0.0,
        sensors=rows,
        poses={k: np.asarray(v, dtype=np.float64) for k, v in poses.items()},
        pose_source=source,
        calibration=cal_rows,
        calibration_note=cal_note,
        clocks=[_clock(store, s) for s in sensors if len(store.clock_probes(s.id))],
        latency_ms=latency,
        latency_note=latency_note,
        has_truth=store.has_truth(),
        rom_phase_s=rom_phase,
    )

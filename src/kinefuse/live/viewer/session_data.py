"""What the viewer shows of a recorded session, read once: results, raw skeletons, sensor status.

Everything here comes from what a real server has (observations, clock probes, the stored
calibration and fused results); the truth, for simulated sessions, comes only through
:func:`kinefuse.lab.replay_truth.replay_truth`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from kinefuse.capture.sync import sensor_timebase
from kinefuse.capture.sync.ntp import probe_offsets
from kinefuse.core.geometry.transforms import apply_transform
from kinefuse.core.skeleton import TrackingState
from kinefuse.errors import InputError
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.live.bus import SensorInfo

Array = NDArray[np.float64]

#: The result shown first when a session has several (the rest are toggles).
PREFERRED = ("best", "best-live", "paper", "nonlinear", "geometric", "linear")


@dataclass(frozen=True, eq=False)
class SessionView:
    """A session on one frame grid.

    Attributes
    ----------
    t_s : (T,) float
        Frame times on the server clock, seconds (the primary result's).
    methods : dict of str to ((T, 25, 3) float, (T, 25) int8)
        Every stored fused result on that grid (nearest frame; NaN and NO_DATA where a result
        has no frame within half a frame period). The first key is the primary one.
    raw : dict of str to (T, 25, 3) float
        Each sensor's latest observation at or before each frame time, world frame (needs a
        calibration; empty without one).
    sensors : tuple of SensorInfo
        Per sensor, from the recording: probe round trip, clock offset, rate, latency,
        tracked fraction and the calibrated pose.
    calibration : str or None
        Name of the stored calibration used for the poses.
    truth : (T, 25, 3) float or None
        The true joints (simulated sessions), in the world of the primary result.
    truth_note : str
    """

    t_s: Array
    methods: dict[str, tuple[Array, NDArray[np.int8]]]
    raw: dict[str, Array]
    sensors: tuple[SensorInfo, ...]
    calibration: str | None
    calibration_rms_mm: float | None = None
    calibration_grade: str | None = None
    truth: Array | None = None
    truth_note: str = ""
    tracked: dict[str, NDArray[np.float64]] = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return int(self.t_s.size)

    @property
    def primary(self) -> str:
        return next(iter(self.methods))


def _poses(
    store: SessionStore,
) -> tuple[dict[str, Array] | None, str | None, float | None, str | None]:
    """Poses, name, RMS residual (mm) and grade of the stored calibration (full first)."""
    from kinefuse.capture.calibration import grade as g
    from kinefuse.capture.calibration.calib_file import loads_calibration

    for name in ("full", "paper", *store.calibration_names()):
        text = store.calibration(name)
        if text is not None:
            cal = loads_calibration(text, source=f"{store.path} [{name}]")
            rms = cal.rms_m * 1e3 if math.isfinite(cal.rms_m) else None
            # the grade's residual and sightings rules (the tilt rule needs the depth frames)
            res = np.array([s.residual_m for s in cal.sensors])
            n = np.array([s.n_sightings for s in cal.sensors])
            grade = "good"
            if (res > g.RESIDUAL_DOUBTFUL_M).any() or (n < g.SIGHTINGS_DOUBTFUL).any():
                grade = "doubtful"
            if (res > g.RESIDUAL_FAILED_M).any() or (n < g.SIGHTINGS_FAILED).any():
                grade = "failed"
            return cal.sensor2world, name, rms, grade
    return None, None, None, None


def _on_grid(t_grid: Array, t: Array, rate_hz: float) -> NDArray[np.intp]:
    """Index into ``t`` of the nearest frame to each grid time, -1 if none within half a frame."""
    if t.size == 0:
        return np.full(t_grid.shape, -1, dtype=np.intp)
    i = np.clip(np.searchsorted(t, t_grid), 1, max(t.size - 1, 1))
    i0 = np.clip(i - 1, 0, t.size - 1)
    i1 = np.clip(i, 0, t.size - 1)
    near = np.where(np.abs(t[i0] - t_grid) <= np.abs(t[i1] - t_grid), i0, i1)
    far = np.abs(t[near] - t_grid) > 0.5 / rate_hz + 1e-9
    return np.where(far, -1, near)


def load_session_view(
    store: SessionStore, *, with_truth: bool = True, rate_hz: float = 30.0
) -> SessionView:
    """Read what the viewer shows of ``store`` (see :class:`SessionView`)."""
    from kinefuse.capture.fusion.status import FusionStatus

    names = store.fused_methods()
    if not names:
        raise InputError(
            f"{store.path} has no stored fused result to show; fuse it first, e.g. "
            f"`kinefuse fuse {store.path} --method best --store`"
        )
    order = [m for m in PREFERRED if m in names] + [m for m in names if m not in PREFERRED]
    stored = {m: store.fused(m) for m in order}
    t_grid = np.asarray(stored[order[0]][0], dtype=np.float64)  # type: ignore[index]
    methods: dict[str, tuple[Array, NDArray[np.int8]]] = {}
    for m, res in stored.items():
        assert res is not None
        t, pos, st = res
        idx = _on_grid(t_grid, t, rate_hz)
        p = np.where((idx >= 0)[:, None, None], pos[np.maximum(idx, 0)], np.nan)
        s = np.where((idx >= 0)[:, None], st[np.maximum(idx, 0)], np.int8(FusionStatus.NO_DATA))
        methods[m] = (p, s.astype(np.int8))

    poses, cal_name, rms_mm, grade = _poses(store)
    raw: dict[str, Array] = {}
    tracked: dict[str, Array] = {}
    statuses = []
    for info in store.sensors():
        obs = store.observations(info.id)
        probes = store.clock_probes(info.id)
        rtt_ms = off_ms = sd_ms = lat_ms = fps = math.nan
        frac = math.nan
        t_server = None
        if len(probes):
            tb = sensor_timebase(probes, obs.t_sensor_s, obs.t_receive_host_s)
            t_server = tb.affine.forward(obs.t_sensor_s)
            _offset, delay, _ = probe_offsets(probes)
            rtt_ms = float(np.median(2 * delay)) * 1e3
            mid = float(np.median(t_grid))
            off_ms = float(tb.host.affine.forward(mid) - mid) * 1e3
            sd_ms = float(tb.host.residual_s) * 1e3
            late = obs.t_receive_server_s - t_server
            if np.isfinite(late).any():
                lat_ms = float(np.nanmedian(late)) * 1e3
        if obs.n_frames > 1:
            span = float(obs.t_sensor_s[-1] - obs.t_sensor_s[0])
            fps = (obs.n_frames - 1) / span if span > 0 else math.nan
        body = obs.has_body
        if body.any():
            frac = float((obs.states[body] == TrackingState.TRACKED).mean())
        pose = poses.get(info.id) if poses else None
        if pose is not None and t_server is not None and obs.n_frames:
            k = np.clip(np.searchsorted(t_server, t_grid, side="right") - 1, 0, obs.n_frames - 1)
            fresh = np.abs(t_server[k] - t_grid) <= 2.0 / max(info.rate_hz, 1.0)
            world = apply_transform(pose, obs.joints_m[k])
            world[~fresh] = np.nan
            raw[info.id] = world
            tracked[info.id] = np.where(
                fresh, (obs.states[k] == TrackingState.TRACKED).mean(axis=1), 0.0
            )
        statuses.append(
            SensorInfo(
                sensor_id=info.id,
                connected=bool(obs.n_frames),
                rtt_ms=rtt_ms,
                clock_offset_ms=off_ms,
                clock_offset_sd_ms=sd_ms,
                fps=fps,
                latency_ms=lat_ms,
                tracked_fraction=frac,
                sensor2world=np.asarray(pose, dtype=float).reshape(4, 4)
                if pose is not None
                else None,
            )
        )
    truth, note = None, ""
    if with_truth:
        from kinefuse.lab.replay_truth import replay_truth

        truth, note = replay_truth(store, t_grid, methods[order[0]][0], poses)
    return SessionView(
        t_s=t_grid,
        methods=methods,
        raw=raw,
        sensors=tuple(statuses),
        calibration=cal_name,
        calibration_rms_mm=rms_mm,
        calibration_grade=grade,
        truth=truth,
        truth_note=note,
        tracked=tracked,
    )

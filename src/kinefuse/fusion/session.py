"""The server's side of fusion on a recorded session: clocks, frames, methods.

Everything here uses only what a real server has: the sensors' observations with their device
timestamps and the client PCs' receive times, the clock probes, the sensors' intrinsics and a
calibration (sensor poses). The truth is never read (``--true-calibration`` hands in true poses
explicitly, for evaluation only).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from kinefuse.camera.intrinsics import Intrinsics
from kinefuse.errors import FusionError
from kinefuse.fusion.best import BestOptions, SensorStream, fuse_best
from kinefuse.fusion.status import FusionStatus
from kinefuse.fusion.trilateration import DEFAULT_C_THRESHOLD, trilaterate
from kinefuse.io.store import Observations, SessionStore
from kinefuse.occlusion.segments import detect_occlusion
from kinefuse.skeleton import N_JOINTS
from kinefuse.sync import ClockEstimate, SensorTimebase, assemble_latest, sensor_timebase

Array = NDArray[np.float64]

#: The methods ``kinefuse fuse`` and ``evaluate`` know, in the paper's order, then ours (offline
#: ``best`` and the causal ``best-live`` a live server runs).
METHODS = ("linear", "geometric", "nonlinear", "paper", "best", "best-live")


@dataclass(frozen=True)
class SensorData:
    """One sensor as the server knows it."""

    id: str
    intrinsics: Intrinsics
    sensor2world: Array
    clock: ClockEstimate  # the client PC's clock against the server's (from the probes)
    observations: Observations
    t_server_s: Array  # capture times on the server clock
    occluded: NDArray[np.bool_]  # (N, 25) the client's occlusion flags
    n_intersections: NDArray[np.int64]  # (N,)
    timebase: SensorTimebase | None = None  # device -> host -> server


@dataclass(frozen=True)
class MethodResult:
    """One method's fused joints on the frame grid."""

    method: str
    t_server_s: Array  # (T,)
    positions: Array  # (T, 25, 3) world, NaN where NO_DATA
    status: NDArray[np.int8]  # (T, 25) FusionStatus
    seconds: float  # wall time the method took (for reports)
    #: (T, 25) a per-joint quality, metres, NaN where none: for ``best`` the RMS 3D position
    #: uncertainty of the filter, for the range methods the RMS range residual of the solution
    residual_m: Array | None = None


def load_sensors(store: SessionStore, poses: dict[str, Array]) -> list[SensorData]:
    """Read every sensor's stream, estimate its clock, run the client-side occlusion test.

    Parameters
    ----------
    poses : dict
        ``sensor id -> sensor2world (4, 4)`` from a calibration.
    """
    out = []
    sensors = store.sensors()
    if not sensors:
        raise FusionError(f"{store.path}: the session has no sensors")
    missing = [s.id for s in sensors if s.id not in poses]
    if missing:
        raise FusionError(
            f"the calibration has no pose for sensor(s) {', '.join(missing)}; calibrate the "
            "session again (kinefuse calibrate) or pass a calibration that covers every sensor"
        )
    for s in sensors:
        obs = store.observations(s.id)
        probes = store.clock_probes(s.id)
        if len(probes) == 0:
            raise FusionError(
                f"sensor {s.id}: no clock probes in the session, so its timestamps cannot be put "
                "on the server clock; record with clock sync enabled"
            )
        # device timestamps -> the client's clock (from each frame's arrival) -> the server's
        timebase = sensor_timebase(probes, obs.t_sensor_s, obs.t_receive_host_s)
        clock = timebase.host
        if obs.occluded is not None and obs.n_crossings is not None:
            occluded, crossings = obs.occluded, obs.n_crossings  # the client's own flags
        elif obs.n_frames:
            # the client sent none (simulated sessions): run its test here, on its data only
            occ = detect_occlusion(obs.joints_m, s.intrinsics)
            occluded, crossings = occ.occluded, occ.n_intersections
        else:
            occluded = np.zeros((0, N_JOINTS), bool)
            crossings = np.zeros(0, dtype=np.int64)
        out.append(
            SensorData(
                id=s.id,
                intrinsics=s.intrinsics,
                sensor2world=np.asarray(poses[s.id], dtype=np.float64),
                clock=clock,
                observations=obs,
                t_server_s=timebase.to_server(obs.t_sensor_s),
                occluded=occluded,
                n_intersections=crossings,
                timebase=timebase,
            )
        )
    return out


def frame_grid(sensors: list[SensorData], rate_hz: float = 30.0) -> Array:
    """Server frame times ``(T,)`` at ``rate_hz`` over the span where any sensor saw a body."""
    spans = []
    for s in sensors:
        body = s.observations.has_body
        if body.any():
            t = s.t_server_s[body]
            spans.append((t.min(), t.max()))
    if not spans:
        raise FusionError("no sensor observed a body in this session: nothing to fuse")
    t0 = min(a for a, _ in spans)
    t1 = max(b for _, b in spans)
    return np.arange(np.ceil(t0 * rate_hz) / rate_hz, t1 + 1e-9, 1.0 / rate_hz)


def clip_grid(grid: Array, start_s: float | None, end_s: float | None) -> Array:
    """The frames of ``grid`` within ``[start_s, end_s]`` (server clock, seconds from the
    session's start; None: open end). Raises :class:`FusionError` when none is left."""
    keep = np.ones(grid.shape, dtype=bool)
    if start_s is not None:
        keep &= grid >= start_s - 1e-9
    if end_s is not None:
        keep &= grid <= end_s + 1e-9
    if not keep.any():
        span = f"{grid[0]:.2f} to {grid[-1]:.2f} s" if grid.size else "nothing"
        raise FusionError(
            f"no frames between --start {start_s} and --end {end_s}: the session's fused frames "
            f"run from {span} (server clock, seconds from the session's start)"
        )
    return grid[keep]


def run_method(
    sensors: list[SensorData],
    grid: Array,
    method: str,
    *,
    best_options: BestOptions | None = None,
    c_threshold: float = DEFAULT_C_THRESHOLD,
    occlusion_compensation: bool = True,
) -> MethodResult:
    """Fuse with one method. The paper's methods use the paper's frame assembly (each sensor's
    latest observation in the frame window); ``best`` interpolates at capture times."""
    import time

    if method not in METHODS:
        raise FusionError(f"unknown fusion method {method!r}; choose from {', '.join(METHODS)}")
    t0 = time.perf_counter()
    if method == "best-live":
        from kinefuse.fusion.live import LiveOptions, replay

        live = LiveOptions() if best_options is None else LiveOptions(best=best_options)
        pos, var, status, _used = replay(
            [s.t_server_s for s in sensors],
            [s.observations.joints_m for s in sensors],
            [s.observations.states for s in sensors],
            np.stack([s.sensor2world for s in sensors]),
            grid,
            live,
            occluded=[s.occluded for s in sensors],
        )
        residual = np.sqrt(3.0 * var)
    elif method == "best":
        streams = [
            SensorStream(
                t_server_s=s.t_server_s,
                joints_sensor=s.observations.joints_m,
                states=s.observations.states,
                sensor2world=s.sensor2world,
                occluded=s.occluded,
            )
            for s in sensors
        ]
        fused = fuse_best(streams, grid, best_options or BestOptions())
        pos = fused.positions
        status = np.where(np.isfinite(pos).all(-1), FusionStatus.OK, FusionStatus.NO_DATA).astype(
            np.int8
        )
        residual = np.sqrt(3.0 * fused.variance_m2)
    else:
        frames = assemble_latest(
            grid,
            [s.t_server_s for s in sensors],
            [s.observations.joints_m for s in sensors],
            [s.observations.states for s in sensors],
        )
        poses = np.stack([s.sensor2world for s in sensors])
        occlusion = None
        if method == "paper":
            occ = np.zeros(frames.states.shape, dtype=bool)
            n_int = np.zeros(frames.index.shape, dtype=np.int64)
            for i, s in enumerate(sensors):
                row = frames.index[:, i]
                ok = row >= 0
                occ[ok, i] = s.occluded[row[ok]]
                n_int[ok, i] = s.n_intersections[row[ok]]
            if not occlusion_compensation:
                occ[:] = False
            occlusion = (occ, n_int)
        res = trilaterate(
            frames.joints,
            poses,
            "nonlinear" if method == "paper" and not occlusion_compensation else method,
            states=frames.states,
            occlusion=occlusion if occlusion_compensation else None,
            c_threshold=c_threshold,
        )
        pos, status = res.positions, res.status
        residual = _range_residual(pos, frames.joints, poses, res.used)
    return MethodResult(
        method=method,
        t_server_s=grid,
        positions=pos,
        status=np.asarray(status, dtype=np.int8),
        seconds=time.perf_counter() - t0,
        residual_m=residual,
    )


def _range_residual(
    positions: Array, joints_sensor: Array, poses: Array, used: NDArray[np.bool_]
) -> Array:
    """RMS over the sensors used of ``|p - s_i| - r_i``, ``(T, 25)`` metres (NaN: none used).

    ``positions (T, 25, 3)`` world, ``joints_sensor (T, S, 25, 3)``, ``poses (S, 4, 4)``,
    ``used (T, S, 25)``.
    """
    centres = poses[:, :3, 3]  # (S, 3)
    ranges = np.linalg.norm(joints_sensor, axis=-1)  # (T, S, 25)
    dist = np.linalg.norm(positions[:, None] - centres[None, :, None, :], axis=-1)
    r2 = np.where(used, (dist - ranges) ** 2, 0.0)
    n = used.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, np.sqrt(r2.sum(axis=1) / n), np.nan)

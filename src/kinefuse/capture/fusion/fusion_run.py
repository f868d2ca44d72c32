"""The server's side of fusion on a recorded session: the frame grid and the methods.

Everything here uses only what a real server has: each sensor's observations with their
capture times on the server clock and the client's occlusion flags, and a calibration (sensor
poses). It reads no store and no clock: :mod:`kinefuse.pipeline.store_inputs` reads a session and
hands the sensors in (:func:`kinefuse.pipeline.store_inputs.load_sensors`) and times the methods.
The truth is never
read (``--true-calibration`` hands in true poses explicitly, for evaluation only).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from itertools import pairwise

import numpy as np
from numpy.typing import NDArray

from kinefuse.capture.fusion.best import BestOptions, fuse_best
from kinefuse.capture.fusion.methods import METHODS
from kinefuse.capture.fusion.people import People, associate
from kinefuse.capture.fusion.status import FusionStatus
from kinefuse.capture.fusion.trilateration import DEFAULT_C_THRESHOLD, trilaterate
from kinefuse.capture.sync import ClockEstimate, SensorTimebase, assemble_latest
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.frames.observations import BodyFrames
from kinefuse.core.skeleton import N_JOINTS
from kinefuse.errors import FusionError

Array = NDArray[np.float64]

#: frames a range method assembles and solves at once (its memory grows with this, not with the
#: session)
RANGE_CHUNK = 1024

#: The methods ``kinefuse fuse`` and ``evaluate`` know, in the paper's order, then ours (offline
#: ``best`` and the causal ``best-live`` a live server runs).


@dataclass(frozen=True, eq=False)
class CalibratedSensor:
    """One sensor as the server knows it.

    Attributes
    ----------
    observations : BodyFrames
        Its stream, with capture times on the server clock (``t_server_s``) and the client's
        occlusion flags and crossing counts (``occluded``, ``n_crossings``) filled in.
    intrinsics : Intrinsics
    sensor2world : (4, 4) float
        Its calibrated pose.
    timebase : SensorTimebase
        Device -> host -> server clock mapping (from the clock probes).
    """

    observations: BodyFrames
    intrinsics: Intrinsics
    sensor2world: Array
    timebase: SensorTimebase

    def __post_init__(self) -> None:
        o = self.observations
        if not np.isfinite(o.t_server_s).all() or o.occluded is None or o.n_crossings is None:
            raise FusionError(
                f"sensor {o.sensor_id!r}: fusion needs every frame's capture time on the server "
                "clock and occlusion flags; build the sensor with "
                "kinefuse.pipeline.store_inputs.load_sensors"
            )

    @property
    def id(self) -> str:
        return self.observations.sensor_id

    @property
    def clock(self) -> ClockEstimate:
        """The client PC's clock against the server's (from the probes)."""
        return self.timebase.host

    @property
    def t_server_s(self) -> Array:
        """``(N,)`` capture times on the server clock, seconds."""
        return self.observations.t_server_s

    @property
    def occluded(self) -> NDArray[np.bool_]:
        """``(N, 25)`` the client's occlusion flags."""
        assert self.observations.occluded is not None  # checked in __post_init__
        return self.observations.occluded

    @property
    def n_intersections(self) -> NDArray[np.int64]:
        """``(N,)`` the client's bone-crossing counts."""
        assert self.observations.n_crossings is not None  # checked in __post_init__
        return self.observations.n_crossings


#: The name branches written before the one observation type (issue 10) import; the same class.
SensorData = CalibratedSensor


@dataclass(frozen=True)
class MethodResult:
    """One method's fused joints on the frame grid."""

    method: str
    t_server_s: Array  # (T,)
    positions: Array  # (T, 25, 3) world, NaN where NO_DATA
    status: NDArray[np.int8]  # (T, 25) FusionStatus
    seconds: float  # wall time the method took (for reports; measured by the pipeline)
    #: (T, 25) a per-joint quality, metres, NaN where none: for ``best`` the RMS 3D position
    #: uncertainty of the filter, for the range methods the RMS range residual of the solution
    residual_m: Array | None = None
    #: (T, S) for ``best`` and ``best-live``: per frame, the sensors (in the order given) whose
    #: left and right labels the swap vote exchanged; None for the paper's methods (no swaps)
    mirrored: NDArray[np.bool_] | None = None


def people_of(
    sensors: Sequence[CalibratedSensor],
    *,
    subject: int | None = None,
    phases_s: Sequence[tuple[float, float]] = (),
    picks: Sequence[tuple[float, Mapping[str, int]]] = (),
) -> tuple[People, dict[int, list[CalibratedSensor]]]:
    """The people of a session (:func:`kinefuse.capture.fusion.people.associate` on the sensors'
    all-bodies streams) and, per person, the sensors with that person's bodies only (one row per
    seq: the input of :func:`run_method`). A one-person session's person 0 gets the sensors
    given, unchanged."""
    streams = {s.id: s.observations for s in sensors}
    people = associate(
        streams, {s.id: s.sensor2world for s in sensors}, subject=subject, phases_s=phases_s,
        picks=picks,
    )  # fmt: skip
    split = people.split(streams)
    per = {
        pid: [s if split[pid][s.id] is s.observations else replace(s, observations=split[pid][s.id])
              for s in sensors]
        for pid in people.ids
    }  # fmt: skip
    return people, per


def frame_grid(sensors: Sequence[CalibratedSensor], rate_hz: float = 30.0) -> Array:
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
    sensors: Sequence[CalibratedSensor],
    grid: Array,
    method: str,
    *,
    best_options: BestOptions | None = None,
    c_threshold: float = DEFAULT_C_THRESHOLD,
    occlusion_compensation: bool = True,
) -> MethodResult:
    """Fuse with one method. The paper's methods use the paper's frame assembly (each sensor's
    latest observation in the frame window); ``best`` interpolates at capture times.

    The result's ``seconds`` is NaN: :func:`kinefuse.pipeline.store_inputs.run_method` times the
    call."""
    if method not in METHODS:
        raise FusionError(f"unknown fusion method {method!r}; choose from {', '.join(METHODS)}")
    mirrored = None
    if method == "best-live":
        from kinefuse.capture.fusion.live import LiveOptions, replay_streams

        live = LiveOptions() if best_options is None else LiveOptions(best=best_options)
        streams = [
            BodyFrames.on_server_clock(s.t_server_s, s.observations.joints_m,
                                       s.observations.states, occluded=s.occluded)
            for s in sensors
        ]  # fmt: skip
        r = replay_streams(streams, np.stack([s.sensor2world for s in sensors]), grid, live)
        pos, status = r["positions"], r["status"].astype(np.int8)
        residual = np.sqrt(3.0 * r["variance_m2"])
        mirrored = np.asarray(r["mirrored"], dtype=bool)
    elif method == "best":
        fused = fuse_best(
            [s.observations for s in sensors],
            np.stack([s.sensor2world for s in sensors]),
            grid,
            best_options or BestOptions(),
        )
        pos = fused.positions
        status = np.where(np.isfinite(pos).all(-1), FusionStatus.OK, FusionStatus.NO_DATA).astype(
            np.int8
        )
        residual = np.sqrt(3.0 * fused.variance_m2)
        mirrored = fused.mirrored
    else:
        pos, status, residual = _run_range(
            sensors, grid, method, c_threshold=c_threshold,
            occlusion_compensation=occlusion_compensation,
        )  # fmt: skip
    return MethodResult(
        method=method,
        t_server_s=grid,
        positions=pos,
        status=np.asarray(status, dtype=np.int8),
        seconds=float("nan"),
        residual_m=residual,
        mirrored=mirrored,
    )


def _run_range(
    sensors: Sequence[CalibratedSensor],
    grid: Array,
    method: str,
    *,
    c_threshold: float,
    occlusion_compensation: bool,
) -> tuple[Array, NDArray[np.int8], Array]:
    """A range method (``linear``, ``geometric``, ``nonlinear``, ``paper``) on the grid in
    chunks of at most :data:`RANGE_CHUNK` frames, of equal size (the assembled ``(T, S, 25, 3)``
    frames and the solvers' temporaries never exist for the whole session, only the output does).

    Each frame is solved on its own, but the solvers batch the problems of a chunk by their
    sensors' pattern, and numpy rounds a batch of a handful of problems differently from a large
    one: a chunk of a few frames can differ from the whole session by ~1e-13 m
    (``tests/test_bounded_memory.py``); chunks of equal size keep the last one from being a
    few frames."""
    n_t = grid.size
    poses = np.stack([s.sensor2world for s in sensors])
    pos = np.full((n_t, N_JOINTS, 3), np.nan)
    status = np.zeros((n_t, N_JOINTS), dtype=np.int8)
    residual = np.full((n_t, N_JOINTS), np.nan)
    n_chunks = max(-(-n_t // RANGE_CHUNK), 1)  # an empty grid: one empty chunk, as before
    bounds = [n_t * k // n_chunks for k in range(n_chunks + 1)]
    for a, b in pairwise(bounds):
        sl = slice(a, b)
        frames = assemble_latest(
            grid[sl],
            [s.t_server_s for s in sensors],
            [s.observations.joints_m for s in sensors],
            [s.observations.states for s in sensors],
        )
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
        pos[sl], status[sl] = res.positions, res.status
        residual[sl] = _range_residual(res.positions, frames.joints, poses, res.used)
    return pos, status, residual


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

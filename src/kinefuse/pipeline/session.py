"""The pipeline layer: reads a session store, hands arrays and frozen inputs to the core.

The numerical core (:mod:`kinefuse.fusion.session`, :mod:`kinefuse.calibration.session`) reads
no store and no clock; this module does both for the commands in :mod:`kinefuse.workflows`:

- :func:`load_sensors`: every sensor's stream, its clock from the probes (capture times on the
  server clock) and the client's occlusion flags (run here, on the sensor's own data, when the
  client sent none), paired with its pose from a calibration;
- :func:`run_method`: one fusion method on those sensors, timed;
- :func:`gather_calibration`: the calibration phase's depth frames, clocks and protocol, read
  from the store for :func:`kinefuse.calibration.session.gather`.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.calibration.floor import FloorPlane
from kinefuse.calibration.session import CalibrationInput, LiveSightings
from kinefuse.errors import CalibrationError, FusionError
from kinefuse.fusion.session import (
    METHODS,
    CalibratedSensor,
    MethodResult,
    clip_grid,
    frame_grid,
)
from kinefuse.fusion.session import run_method as _run_method
from kinefuse.io.store import live as store_live
from kinefuse.io.store.session import SessionStore
from kinefuse.occlusion.segments import detect_occlusion
from kinefuse.skeleton import N_JOINTS
from kinefuse.sync import sensor_timebase

Array = NDArray[np.float64]

__all__ = [
    "METHODS",
    "CalibratedSensor",
    "MethodResult",
    "clip_grid",
    "frame_grid",
    "gather_calibration",
    "load_sensors",
    "run_method",
]


def load_sensors(store: SessionStore, poses: dict[str, Array]) -> list[CalibratedSensor]:
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
        timebase = sensor_timebase(probes, obs.t_device_s, obs.t_host_s)
        if obs.occluded is None or obs.n_crossings is None:
            if obs.n_frames:
                # the client sent none (simulated sessions): run its test here, on its data only
                occ = detect_occlusion(obs.joints_m, s.intrinsics)
                obs = obs.with_occlusion(occ.occluded, occ.n_intersections)
            else:
                obs = obs.with_occlusion(np.zeros((0, N_JOINTS), bool), np.zeros(0, np.int64))
        out.append(
            CalibratedSensor(
                observations=obs.on_server(timebase.to_server(obs.t_device_s)),
                intrinsics=s.intrinsics,
                sensor2world=np.asarray(poses[s.id], dtype=np.float64),
                timebase=timebase,
            )
        )
    return out


def gather_calibration(
    store: SessionStore, *, floor_frames: int = 15, detector: str = "robust"
) -> CalibrationInput:
    """Read a session's calibration phase and run :func:`kinefuse.calibration.session.gather`
    on it: every sensor's depth frames (read chunk by chunk as the detector goes), its clock
    (device timestamps -> server, from the body stream's arrivals and the probes), the wand and
    protocol the operator was given (the session's metadata)."""
    from kinefuse.calibration.session import CalibrationSensor, gather
    from kinefuse.camera.wand import Wand

    meta = store.meta()
    phase = meta.get("calibration_phase_server_s")
    wand_meta = meta.get("wand")
    protocol = meta.get("wand_protocol")
    live_floors = store_live.floors(store)
    sensors = []
    for s in store.sensors():
        # depth frames carry device timestamps: the body stream's arrival times (same device
        # clock) map them to the client's clock, the probes to the server's
        if store.depth_frame_count(s.id) == 0:
            # a live recording: the clients sent their wand sightings and floors, not depth
            live = _live_sightings(store, s.id, live_floors.get(s.id))
            sensors.append(CalibrationSensor(s.id, s.intrinsics, None, (), live))
            continue
        obs = store.observations(s.id)
        clock = sensor_timebase(store.clock_probes(s.id), obs.t_device_s, obs.t_host_s)
        depth = ((t, frames) for _seq, t, frames in store.iter_depth_frames(s.id))
        sensors.append(CalibrationSensor(s.id, s.intrinsics, clock, depth))
    try:
        return gather(
            sensors,
            wand=Wand(**wand_meta) if isinstance(wand_meta, dict) else Wand(),
            protocol=protocol if isinstance(protocol, dict) else {},
            phase_server_s=(float(phase[0]), float(phase[1]))
            if isinstance(phase, list)
            else (0, 0),
            floor_frames=floor_frames,
            detector=detector,
        )
    except CalibrationError as e:
        if "no calibration phase" in str(e):
            raise CalibrationError(f"{store.path}: {e}") from None
        raise


def _live_sightings(
    store: SessionStore, sensor_id: str, floor: FloorPlane | None
) -> LiveSightings | None:
    """A live recording's sightings of one sensor (None: it has none), with their device times
    mapped to the server clock as the body frames' are: device -> host from the arrival times of
    the body frames and the sightings together, host -> server from the probes."""
    from kinefuse.calibration.common import WandTrack

    live = store_live.sightings(store, sensor_id)
    n = len(live.seq)
    if n == 0:
        return None
    obs = store.observations(sensor_id)
    clock = sensor_timebase(
        store.clock_probes(sensor_id),
        np.concatenate([obs.t_device_s, live.t_device_s]),
        np.concatenate([obs.t_host_s, live.t_host_s]),
    )
    t_server = clock.to_server(live.t_device_s)
    track = WandTrack(
        found=np.ones(n, dtype=bool),
        centre_sensor_m=live.centre_sensor_m,
        score=live.score,
        n_points=live.n_points,
        residual_m=np.full(n, np.nan),
        reasons=("",) * n,
    )
    return LiveSightings(track, live.as_sightings(t_server), floor)


def run_method(
    sensors: Sequence[CalibratedSensor], grid: Array, method: str, **options: Any
) -> MethodResult:
    """:func:`kinefuse.fusion.session.run_method` (same keyword options), with the wall time it
    took in ``seconds``."""
    t0 = time.perf_counter()
    res = _run_method(sensors, grid, method, **options)
    return replace(res, seconds=time.perf_counter() - t0)

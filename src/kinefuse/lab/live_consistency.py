"""Consistency figures of a live recording of real sensors (no truth), as ``kinefuse realdata``.

When real sensors, or a real log replayed by ``kinefuse sensor --source multitrack:...``, stream
into ``kinefuse serve``, the recording has no ground truth; what can be measured is how well the
sensors agree with each other and with their fused skeleton (:mod:`kinefuse.lab.consistency`,
the figures ``kinefuse realdata`` reports for the KinectMultiTrack logs). This module computes
them from the recording alone, with what the live system recorded:

1. **Clocks**: each sensor's capture times on the server clock from its own recorded stamps, as
   every offline command does (:func:`kinefuse.pipeline.store_inputs.load_sensors`: device -> host
   from the frames' two stamps, host -> server from the clock probes);
2. **Registration**: the sensors' poses from the recording's calibration when it has one (a wand
   calibration), else the body as the calibration object: the other sensors re-registered rigidly
   onto the first from the trunk joints
   (:func:`kinefuse.capture.calibration.body.refine_registration`, as ``realdata`` does), the
   world's up from the first sensor's standing feet;
3. **Consistency** on a 30 Hz grid: sensor vs sensor before fusion, each sensor vs the fused
   skeleton (``best``), left/right swaps.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.errors import InputError
from kinefuse.formats.store.session_store import SessionStore

Array = NDArray[np.float64]


def recording_consistency(path: Path, *, grid_hz: float = 30.0) -> dict[str, Any]:
    """Consistency figures of a live recording with two or more sensors (opened read-only).

    Returns
    -------
    dict
        JSON-ready: ``file``, ``sensors`` (the first is the reference), ``registration``
        (``"calibration"`` or ``"body"``, with the trunk disagreement before and after the body
        registration), ``clocks`` (per sensor: frames, the device->host and host->server fits),
        ``duration_s``, and the figures of :func:`kinefuse.lab.consistency.consistency`:
        ``disagreement`` (per pair, ``{"all": [median_m, p95_m], "by_joint": ..., "n"}``),
        ``to_fused``, ``to_fused_no_lr``, ``swaps``, ``frames``, ``frames_with_body``,
        ``fused_finite``.
    """
    from kinefuse.capture.calibration.calib_file import loads_calibration
    from kinefuse.lab.consistency import consistency
    from kinefuse.pipeline.store_inputs import load_sensors

    if not (math.isfinite(grid_hz) and grid_hz > 0):
        raise InputError(f"grid_hz must be a positive frame rate in Hz, got {grid_hz!r}")
    with SessionStore.open(path) as store:
        infos = store.sensors()
        with_body = [s.id for s in infos if store.observation_count(s.id) > 0]
        if len(with_body) < 2:
            raise InputError(
                f"{path}: consistency needs two sensors with body frames; it has "
                f"{', '.join(with_body) or 'none'}"
            )
        cal_name = next((n for n in ("full", "paper") if store.calibration(n)), None)
        if cal_name is not None:
            text = store.calibration(cal_name) or ""
            poses = loads_calibration(text, source=f"{path} [{cal_name}]").sensor2world
        else:
            poses = {s.id: np.eye(4) for s in infos}
        loaded = [s for s in load_sensors(store, poses) if s.id in with_body]
    # a frame sent twice (a log that repeats a sensor's latest skeleton) counts once, and
    # frames go in capture order
    sensors = loaded
    streams = {
        s.id: s.observations.take(distinct_frames(s.t_server_s, s.observations.t_device_s))
        for s in sensors
    }
    times = {k: v.t_server_s for k, v in streams.items()}
    joints = {k: v.joints_m for k, v in streams.items()}
    reg_info: dict[str, Any] = {"kind": "calibration" if cal_name else "body"}
    if cal_name is None:
        s2w, body_info = register_from_body(times, joints)
        reg_info.update(body_info)
    else:
        s2w = {s.id: s.sensor2world for s in sensors}
    lo = max(float(t.min()) for t in times.values())
    hi = min(float(t.max()) for t in times.values())
    if not hi > lo:
        raise InputError(f"{path}: the sensors' body frames do not overlap in time")
    grid = lo + np.arange(math.floor((hi - lo) * grid_hz) + 1) / grid_hz
    ids = [s.id for s in sensors]
    c = consistency([streams[i] for i in ids], np.stack([s2w[i] for i in ids]), grid, names=ids)
    out = {k: v for k, v in c.items() if not k.startswith("_")}
    out.update(
        {
            "file": str(path),
            "sensors": [s.id for s in sensors],
            "registration": reg_info,
            "duration_s": hi - lo,
            "clocks": {
                s.id: {
                    "frames_received": s.observations.n_frames,
                    "frames": streams[s.id].n_frames,
                    "device_drift_ppm": s.timebase.device.drift_ppm if s.timebase else None,
                    "device_residual_ms": 1e3 * s.timebase.device.residual_s
                    if s.timebase
                    else None,
                    "host_drift_ppm": s.clock.drift_ppm if s.clock else None,
                }
                for s in sensors
            },
        }
    )
    return out


def register_from_body(
    times: dict[str, Array], joints: dict[str, Array]
) -> tuple[dict[str, Array], dict[str, Any]]:
    """Sensor poses with the body as the calibration object (as ``kinefuse realdata`` does).

    The first sensor of ``times`` is the reference: the world's up from its standing feet, the
    others registered rigidly onto it from the trunk joints
    (:func:`kinefuse.capture.calibration.body.refine_registration`).

    Parameters
    ----------
    times : dict
        ``sensor id -> (T,)`` capture times on one clock, seconds.
    joints : dict
        ``sensor id -> (T, 25, 3)`` joints in that sensor's frame, metres.

    Returns
    -------
    sensor2world : dict
        ``sensor id -> (4, 4)``.
    info : dict
        ``by_sensor`` (per other sensor: ``correction_deg``, ``trunk_median_before_m``,
        ``trunk_median_after_m``) and ``floor_samples``.
    """
    from kinefuse.capture.calibration.body import (
        fit_foot_plane,
        refine_registration,
        world_from_floor,
    )

    ids = list(times)
    ref = ids[0]
    floor = fit_foot_plane(times[ref], joints[ref])
    ref2world = world_from_floor(floor)
    s2w = {ref: ref2world}
    by_sensor = {}
    for sid in ids[1:]:
        reg = refine_registration(times[ref], joints[ref], times[sid], joints[sid])
        s2w[sid] = ref2world @ reg.other2ref
        by_sensor[sid] = {
            "correction_deg": reg.angle_deg,
            "trunk_median_before_m": reg.trunk_median_before_m,
            "trunk_median_after_m": reg.trunk_median_after_m,
        }
    return s2w, {"by_sensor": by_sensor, "floor_samples": floor.n_samples}


def distinct_frames(t_server_s: Array, t_device_s: Array) -> NDArray[np.intp]:
    """Indices of the distinct frames (by device time, first received kept) in capture order."""
    _, first = np.unique(t_device_s, return_index=True)
    return first[np.argsort(t_server_s[first], kind="stable")]

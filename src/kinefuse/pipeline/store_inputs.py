"""The pipeline layer: reads a session store, hands arrays and frozen inputs to the core.

The numerical core (:mod:`kinefuse.capture.fusion.fusion_run`,
:mod:`kinefuse.capture.calibration.calibration_run`) reads no store and no clock; this module does
both for the commands in :mod:`kinefuse.app.workflows`:

- :func:`load_sensors`: every sensor's stream, its clock from the probes (capture times on the
  server clock) and the client's occlusion flags (run here, on the sensor's own data, when the
  client sent none), paired with its pose from a calibration;
- :func:`run_method`: one fusion method on those sensors, timed;
- :func:`gather_calibration`: the calibration phase's depth frames, clocks and protocol, read
  from the store for :func:`kinefuse.capture.calibration.calibration_run.gather`.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import replace
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from kinefuse.capture.calibration.calibration_run import CalibrationInput, LiveSightings
from kinefuse.capture.calibration.floor import FloorPlane
from kinefuse.capture.fusion.fusion_run import (
    CalibratedSensor,
    MethodResult,
    clip_grid,
    frame_grid,
    people_of,
)
from kinefuse.capture.fusion.fusion_run import run_method as _run_method
from kinefuse.capture.fusion.people import People
from kinefuse.capture.occlusion.segments import detect_occlusion
from kinefuse.capture.sync import sensor_timebase
from kinefuse.core.skeleton import N_JOINTS
from kinefuse.errors import CalibrationError, FusionError, StoreError
from kinefuse.formats.store import live_tables as store_live
from kinefuse.formats.store.session_store import SensorInfo, SessionStore
from kinefuse.pipeline.screen import SensorScreen, screen_sensors

Array = NDArray[np.float64]

__all__ = [
    "CalibratedSensor",
    "MethodResult",
    "clip_grid",
    "frame_grid",
    "gather_calibration",
    "gather_usable_calibration",
    "load_sensors",
    "load_usable_sensors",
    "run_method",
    "subject_phases",
    "subject_picks",
]


def load_sensors(
    store: SessionStore, poses: dict[str, Array], *, bodies: Literal["first", "all"] = "first"
) -> list[CalibratedSensor]:
    """Read every sensor's stream, estimate its clock, run the client-side occlusion test.

    Parameters
    ----------
    poses : dict
        ``sensor id -> sensor2world (4, 4)`` from a calibration.
    bodies : {"first", "all"}
        One row per seq (the first body, what every fusion method takes) or every body (the
        all-bodies form, for :func:`kinefuse.capture.fusion.fusion_run.people_of`).
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
        out.append(_load_one(store, s, poses[s.id], bodies=bodies))
    return out


def _load_one(
    store: SessionStore,
    s: SensorInfo,
    pose: Array,
    drop_seq: NDArray[np.int64] | None = None,
    *,
    bodies: Literal["first", "all"] = "first",
) -> CalibratedSensor:
    """One sensor's stream on the server clock, with its occlusion flags and pose (frames whose
    seq is in ``drop_seq`` left out before its clock is fitted); ``bodies`` as in
    :func:`load_sensors` (the clock is fitted on one row per seq either way)."""
    obs = store.observations(s.id, bodies=bodies)
    if drop_seq is not None and len(drop_seq):
        obs = obs.take(np.flatnonzero(~np.isin(obs.seq, drop_seq)))
    probes = store.clock_probes(s.id)
    if len(probes) == 0:
        raise FusionError(
            f"sensor {s.id}: no clock probes in the session, so its timestamps cannot be put "
            "on the server clock; record with clock sync enabled"
        )
    # device timestamps -> the client's clock (from each frame's arrival) -> the server's
    first = obs.first_bodies()
    timebase = sensor_timebase(probes, first.t_device_s, first.t_host_s)
    if obs.occluded is None or obs.n_crossings is None:
        if obs.n_frames:
            # the client sent none (simulated sessions): run its test here, on its data only
            occ = detect_occlusion(obs.joints_m, s.intrinsics)
            obs = obs.with_occlusion(occ.occluded, occ.n_intersections)
        else:
            obs = obs.with_occlusion(np.zeros((0, N_JOINTS), bool), np.zeros(0, np.int64))
    return CalibratedSensor(
        observations=obs.on_server(timebase.affine.forward(obs.t_device_s)),
        intrinsics=s.intrinsics,
        sensor2world=np.asarray(pose, dtype=np.float64),
        timebase=timebase,
    )


def load_usable_sensors(
    store: SessionStore, poses: dict[str, Array], *, bodies: Literal["first", "all"] = "first"
) -> tuple[list[CalibratedSensor], SensorScreen]:
    """:func:`load_sensors` on the sensors that can be used, and the screen that says which were
    left out and why (``left_out``): stamps far outside the recording or no clock
    (:func:`kinefuse.pipeline.screen.screen_sensors`), or no pose in the calibration (a sensor
    that never calibrated). A usable sensor's few frames stamped outside the recording are
    dropped (``stray_seq``). Refuses only when no sensor is left.
    """
    infos = store.sensors()
    if not infos:
        raise FusionError(f"{store.path}: the session has no sensors")
    screen = screen_sensors(store)
    screen = screen.without(
        {
            sid: "the calibration has no pose for it (it never calibrated, or joined later); "
            "calibrate the session again to use it"
            for sid in screen.usable
            if sid not in poses
        }
    )
    if not screen.usable:
        raise FusionError(
            f"{store.path}: no sensor can be used: "
            + "; ".join(f"{sid}: {why}" for sid, why in screen.left_out.items())
        )
    by_id = {s.id: s for s in infos}
    sensors = [
        _load_one(store, by_id[sid], poses[sid], screen.stray_seq.get(sid), bodies=bodies)
        for sid in screen.usable
    ]
    return sensors, screen


def load_people(
    store: SessionStore, poses: dict[str, Array], *, subject: int | None = None
) -> tuple[People, dict[int, list[CalibratedSensor]], SensorScreen]:
    """The people of a stored session and each one's sensors (:func:`load_usable_sensors` with
    every body, then :func:`kinefuse.capture.fusion.fusion_run.people_of` with the session's
    phases and the live server's picks for the subject's rule). ``per_person[people.subject]``
    is what the commands fuse by default; for a one-person session it is
    ``load_usable_sensors(store, poses)``, unchanged."""
    everyone, screen = load_usable_sensors(store, poses, bodies="all")
    people, per_person = people_of(
        everyone, subject=subject, phases_s=subject_phases(store), picks=subject_picks(store)
    )
    return people, per_person, screen


def gather_usable_calibration(
    store: SessionStore, *, floor_frames: int = 15, detector: str = "robust"
) -> tuple[CalibrationInput, SensorScreen]:
    """:func:`gather_calibration` on the sensors that can be calibrated, and the screen that
    says which were left out and why: stamps far outside the recording or no clock
    (:func:`kinefuse.pipeline.screen.screen_sensors`), or no calibration data at all (no depth
    frames and no wand sightings: a sensor that never took part in the wand phase). A session in
    which no sensor has calibration data is refused as before (it has no calibration phase)."""
    screen = screen_sensors(store)
    no_data = {
        sid: "it recorded no calibration data (no depth frames, no wand sightings): it never "
        "took part in the wand phase"
        for sid in screen.usable
        if store.depth_frame_count(sid) == 0 and len(store_live.sightings(store, sid).seq) == 0
    }
    if len(no_data) < len(screen.usable):
        screen = screen.without(no_data)
    if not screen.usable:
        raise CalibrationError(
            f"{store.path}: no sensor can be calibrated: "
            + "; ".join(f"{sid}: {why}" for sid, why in screen.left_out.items())
        )
    cal = gather_calibration(
        store,
        floor_frames=floor_frames,
        detector=detector,
        sensor_ids=screen.usable,
        drop_seq=screen.stray_seq,
    )
    return cal, screen


def gather_calibration(
    store: SessionStore,
    *,
    floor_frames: int = 15,
    detector: str = "robust",
    sensor_ids: Sequence[str] | None = None,
    drop_seq: dict[str, NDArray[np.int64]] | None = None,
) -> CalibrationInput:
    """Read a session's calibration phase and run
    :func:`kinefuse.capture.calibration.calibration_run.gather` on it: every sensor's depth frames
    (read chunk by chunk as the detector goes), its clock (device timestamps -> server, from the
    body stream's arrivals and the probes), the wand and protocol the operator was given (the
    session's metadata).

    ``sensor_ids`` limits it to those sensors (default: all); ``drop_seq`` (id -> seq) names body
    frames whose stamps the clock fit must not use (:func:`gather_usable_calibration`)."""
    from kinefuse.capture.calibration.calibration_run import CalibrationSensor, gather
    from kinefuse.core.camera.wand import Wand

    meta = store.meta()
    phase = meta.get("calibration_phase_server_s")
    wand_meta = meta.get("wand")
    protocol = meta.get("wand_protocol")
    live_floors = store_live.floors(store)
    sensors = []
    drop = drop_seq or {}
    for s in store.sensors():
        if sensor_ids is not None and s.id not in sensor_ids:
            continue
        # depth frames carry device timestamps: the body stream's arrival times (same device
        # clock) map them to the client's clock, the probes to the server's
        if store.depth_frame_count(s.id) == 0:
            # a live recording: the clients sent their wand sightings and floors, not depth
            live = _live_sightings(store, s.id, live_floors.get(s.id), drop.get(s.id))
            sensors.append(CalibrationSensor(s.id, s.intrinsics, None, (), live))
            continue
        t_device, t_host = _body_stamps(store, s.id, drop.get(s.id))
        clock = sensor_timebase(store.clock_probes(s.id), t_device, t_host)
        depth = ((t, frames) for _seq, t, frames in store.iter_depth_frames(s.id))
        sensors.append(CalibrationSensor(s.id, s.intrinsics, clock, depth))
    try:
        wand = Wand(**wand_meta) if isinstance(wand_meta, dict) else Wand()
        if isinstance(phase, list):
            phase = (float(phase[0]), float(phase[1]))
    except (TypeError, ValueError, IndexError) as e:
        raise StoreError(
            f"{store.path}: the stored wand or calibration phase is malformed ({e}); the session "
            "is damaged or was not written by kinefuse: restore it from a copy, or make it again"
        ) from None
    try:
        return gather(
            sensors,
            wand=wand,
            protocol=protocol if isinstance(protocol, dict) else {},
            phase_server_s=phase if isinstance(phase, tuple) else (0, 0),
            floor_frames=floor_frames,
            detector=detector,
        )
    except CalibrationError as e:
        if "no calibration phase" in str(e):
            raise CalibrationError(f"{store.path}: {e}") from None
        raise


def _body_stamps(
    store: SessionStore, sensor_id: str, drop_seq: NDArray[np.int64] | None
) -> tuple[Array, Array]:
    """A sensor's body frames' device and host stamps (the time columns only; frames in
    ``drop_seq`` left out)."""
    seq, t_device, _t_server, t_host = store.observation_times(sensor_id)
    if drop_seq is not None and len(drop_seq):
        keep = ~np.isin(seq, drop_seq)
        t_device, t_host = t_device[keep], t_host[keep]
    return t_device, t_host


def _live_sightings(
    store: SessionStore,
    sensor_id: str,
    floor: FloorPlane | None,
    drop_seq: NDArray[np.int64] | None = None,
) -> LiveSightings | None:
    """A live recording's sightings of one sensor (None: it has none), with their device times
    mapped to the server clock as the body frames' are: device -> host from the arrival times of
    the body frames and the sightings together, host -> server from the probes."""
    from kinefuse.capture.calibration.common import WandTrack

    live = store_live.sightings(store, sensor_id)
    n = len(live.seq)
    if n == 0:
        return None
    t_device, t_host = _body_stamps(store, sensor_id, drop_seq)
    clock = sensor_timebase(
        store.clock_probes(sensor_id),
        np.concatenate([t_device, live.t_device_s]),
        np.concatenate([t_host, live.t_host_s]),
    )
    t_server = clock.affine.forward(live.t_device_s)
    track = WandTrack(
        found=np.ones(n, dtype=bool),
        centre_sensor_m=live.centre_sensor_m,
        score=live.score,
        n_points=live.n_points,
        residual_m=np.full(n, np.nan),
        reasons=("",) * n,
    )
    return LiveSightings(track, live.as_sightings(t_server), floor)


def subject_phases(store: SessionStore) -> list[tuple[float, float]]:
    """The session's calibration walk and range-of-motion phases (server clock, seconds): the
    person seen in them is the subject (:func:`kinefuse.capture.fusion.people.choose_subject`)."""
    meta = store.meta()
    out = []
    for key in ("calibration_phase_server_s", "rom_phase_server_s"):
        v = meta.get(key)
        if isinstance(v, list) and len(v) == 2 and all(isinstance(x, int | float) for x in v):
            out.append((float(v[0]), float(v[1])))
    return out


def subject_picks(store: SessionStore) -> list[tuple[float, dict[str, int]]]:
    """The live server's subject and each change of it, from a live recording's ``subject``
    events: ``(t_server_s, {sensor id: tracking id})`` in order, the tracking ids the sensors
    gave the subject's body when the server chose them (empty for any other session). The
    subject :func:`kinefuse.capture.fusion.people.choose_subject` gives is the last of them."""
    out = []
    for t, kind, _sid, detail in store_live.events(store):
        ids = detail.get("body_ids")
        when = detail.get("t_capture_server_s", t)
        if kind != "subject" or not isinstance(ids, dict) or not isinstance(when, int | float):
            continue
        picked = {str(k): int(v) for k, v in ids.items() if isinstance(v, int)}
        if picked:
            out.append((float(when), picked))
    return out


def run_method(
    sensors: Sequence[CalibratedSensor], grid: Array, method: str, **options: Any
) -> MethodResult:
    """:func:`kinefuse.capture.fusion.fusion_run.run_method` (same keyword options), with the wall
    time it took in ``seconds``."""
    t0 = time.perf_counter()
    res = _run_method(sensors, grid, method, **options)
    return replace(res, seconds=time.perf_counter() - t0)

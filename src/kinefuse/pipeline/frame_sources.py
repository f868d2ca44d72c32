"""Frame sources: what a sensor delivers, one frame at a time, in arrival order.

A :class:`FrameSource` yields :class:`BodyFrame` (the body tracker's 25 joints of one frame)
and, during a calibration phase, :class:`DepthFrame` items, in the order a client would have
received them. Sources here:

- :class:`SessionReplay`: a stored session (simulated or live-recorded), every sensor or one;
- :class:`MultitrackReplay`: a real KinectMultiTrack log (two Kinect v2, one CSV), one sensor;
- :class:`Kinect2TrackingReplay`: the kinect2-tracking JSON (one real Kinect v2 walk);
- :class:`SimulatedSensorSource`: one simulated sensor, its frames generated as they are asked
  for (the same numbers the batch simulator writes for the same seed).

A driver for a physical sensor implements the same protocol (``sensor_id``, ``intrinsics``,
``__iter__``); the live client (issue 11) plays any of them in real time. Times are each
sensor's own: ``t_device_s`` stamps the capture on the device's clock, ``t_host_s`` the arrival
on the client PC's clock (NaN where a log does not say).
"""

from __future__ import annotations

import heapq
import json
from collections.abc import Iterator, Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.frames.observations import MAX_BODIES, BodyFrame, DepthFrame, Frame
from kinefuse.core.frames.source import FrameSource
from kinefuse.core.inputs import read_text
from kinefuse.core.skeleton import N_JOINTS
from kinefuse.devices.kinect2 import KINECT_CAMERA_TO_SENSOR
from kinefuse.errors import InputError
from kinefuse.formats.store.session_store import SessionStore

if TYPE_CHECKING:
    from kinefuse.core.frames.motion import Motion
    from kinefuse.sim.lab import LabConfig
    from kinefuse.sim.rig import Rig

__all__ = [
    "Kinect2TrackingReplay",
    "MultitrackReplay",
    "SessionReplay",
    "SimulatedSensorSource",
    "open_source",
]

Array = NDArray[np.float64]

#: Kinect camera space (x left, y up, z forward) -> kinefuse sensor axes (x right, y down, z fwd).
_KINECT_AXES = KINECT_CAMERA_TO_SENSOR


def _arrival_key(f: Frame) -> float:
    return f.t_host_s if np.isfinite(f.t_host_s) else f.t_device_s


class SessionReplay:
    """The frames of a stored session, as its sensors delivered them.

    Parameters
    ----------
    store : SessionStore
        An open session (kept open while iterating).
    sensor_ids : sequence of str, optional
        The sensors to replay (default: all).
    depth : bool
        Also yield the calibration-phase depth frames (default True).

    Within a sensor, frames come in capture order; across sensors they are merged by arrival
    time on each client's clock (the host receive time where recorded, else the device time),
    which is the order a server would see up to the clock offsets.
    """

    def __init__(
        self, store: SessionStore, sensor_ids: Sequence[str] | None = None, *, depth: bool = True
    ) -> None:
        known = [s.id for s in store.sensors()]
        ids = tuple(known if sensor_ids is None else sensor_ids)
        missing = [s for s in ids if s not in known]
        if missing:
            raise InputError(
                f"{store.path} has no sensor {', '.join(missing)}; its sensors: {', '.join(known)}"
            )
        self._store = store
        self._ids = ids
        self._depth = depth

    @property
    def sensor_ids(self) -> tuple[str, ...]:
        return self._ids

    def intrinsics(self, sensor_id: str) -> Intrinsics:
        return self._store.sensor(sensor_id).intrinsics

    def _body(self, sid: str) -> Iterator[tuple[float, Frame]]:
        for f in self._store.observations(sid, bodies="all"):  # each frame with its bodies
            yield _arrival_key(f), f

    def _depth_frames(self, sid: str) -> Iterator[tuple[float, Frame]]:
        # depth frames carry no host time in the store (it stays NaN), and their device clock can
        # be far from the host clock: they are merged at their device time plus the sensor's
        # typical device -> host arrival offset, taken from its body frames (same device clock)
        obs = self._store.observations(sid)
        lag = obs.t_host_s - obs.t_device_s
        lag = lag[np.isfinite(lag)]
        offset = float(np.median(lag)) if lag.size else 0.0
        for seq, t, frames in self._store.iter_depth_frames(sid):
            for k in range(len(seq)):
                f = DepthFrame(sid, int(seq[k]), float(t[k]), float("nan"), frames[k])
                yield float(t[k]) + offset, f

    def __iter__(self) -> Iterator[Frame]:
        streams: list[Iterator[tuple[float, Frame]]] = []
        for sid in self._ids:
            streams.append(self._body(sid))
            if self._depth:
                streams.append(self._depth_frames(sid))
        for _key, f in heapq.merge(*streams, key=lambda item: item[0]):
            yield f


class MultitrackReplay:
    """One sensor of a real KinectMultiTrack log (``Study_*_Kinect_*.csv``).

    The log's joints are already in the reference sensor's frame (the original tracker's
    transform) and carry no per-joint tracking state: every joint present is TRACKED. Device
    time is the sensor's ``Skeleton_Time``; the host time is the receiving server's
    ``Tracker_Time`` (the only arrival time the log has, with tens of ms of jitter).
    """

    def __init__(self, path: str | Path, kinect_id: str | None = None) -> None:
        from kinefuse.formats.kinect_multitrack import read_kinect_multitrack

        rec = read_kinect_multitrack(path)
        ids = [s.sensor_id for s in rec.streams]
        if kinect_id is None:
            kinect_id = ids[0]
        if kinect_id not in ids:
            raise InputError(f"{path} has no Kinect_Id {kinect_id!r}; it has {', '.join(ids)}")
        self._stream = rec.stream(kinect_id)
        self.path = str(path)

    @property
    def sensor_ids(self) -> tuple[str, ...]:
        return (self._stream.sensor_id,)

    def intrinsics(self, sensor_id: str) -> Intrinsics:
        return Intrinsics()  # the log does not say: Kinect v2 nominal values

    def __iter__(self) -> Iterator[Frame]:
        s = self._stream.frames
        order = np.argsort(s.t_receive_server_s, kind="stable").tolist()

        def body(k: int, seq: int) -> BodyFrame:
            # the server's receive time is the only arrival time the log has
            return BodyFrame(
                sensor_id=s.sensor_id,
                seq=seq,
                t_device_s=float(s.t_device_s[k]),
                t_host_s=float(s.t_receive_server_s[k]),
                joints_m=s.joints_m[k],
                states=s.states[k],
                body_id=int(s.body_id[k]),
            )

        # rows logged one after the other of one capture, of other persons, are one frame's
        # bodies (a one-person log: each row is a frame, as always)
        seq, i = 0, 0
        while i < len(order):
            k, j = order[i], i + 1
            ids = {int(s.body_id[k])}
            while (
                j < len(order)
                and s.t_device_s[order[j]] == s.t_device_s[k]
                and int(s.body_id[order[j]]) not in ids
            ):
                ids.add(int(s.body_id[order[j]]))
                j += 1
            first = body(k, seq)
            others = tuple(body(order[m], seq) for m in range(i + 1, j))
            yield replace(first, others=others) if others else first
            seq, i = seq + 1, j


class Kinect2TrackingReplay:
    """The kinect2-tracking JSON (``walker.json``): every tracked body of each frame (the first
    listed first, each with its ``trackingId``; at most ``MAX_BODIES``).

    The file has no timestamps; frames are placed at the Kinect v2's 30 Hz (``rate_hz``).
    Joints come in Kinect camera space and are turned into the sensor frame (x right, y down).
    """

    def __init__(self, path: str | Path, *, sensor_id: str = "kinect", rate_hz: float = 30.0):
        p = Path(path)
        try:
            data = json.loads(read_text(p, what="kinect2-tracking JSON file"))
            frames = data["bodyFrame"]
        except InputError:
            raise  # too large, or not text: read_text said so
        except (ValueError, KeyError, TypeError, RecursionError) as e:
            raise InputError(
                f"{p}: not a kinect2-tracking JSON file ({e}); expected an object with a "
                "'bodyFrame' list"
            ) from None
        self._frames = frames
        self._id = sensor_id
        self._rate = float(rate_hz)
        self.path = str(p)

    @property
    def sensor_ids(self) -> tuple[str, ...]:
        return (self._id,)

    def intrinsics(self, sensor_id: str) -> Intrinsics:
        return Intrinsics()

    def __iter__(self) -> Iterator[Frame]:
        for k, f in enumerate(self._frames):
            t = k / self._rate
            tracked = [b for b in f.get("bodies", []) if b.get("tracked")][:MAX_BODIES]
            bodies = [self._body(b, k, t) for b in tracked]
            if not bodies:  # no one tracked: a frame without a body, as always
                empty = np.full((N_JOINTS, 3), np.nan)
                yield BodyFrame(self._id, k, t, float("nan"), empty, np.zeros(N_JOINTS, np.int8))
                continue
            yield replace(bodies[0], others=tuple(bodies[1:])) if len(bodies) > 1 else bodies[0]

    def _body(self, body: dict[str, Any], k: int, t: float) -> BodyFrame:
        """One tracked body of frame ``k``, with its ``trackingId`` as its body id (its
        ``bodyIndex`` when it has none)."""
        joints = np.full((N_JOINTS, 3), np.nan)
        states = np.zeros(N_JOINTS, dtype=np.int8)
        for jt in body.get("joints", []):
            i = int(jt["jointType"])
            st = int(jt.get("trackingState", 0))
            if 0 <= i < N_JOINTS and st in (1, 2):
                joints[i] = _KINECT_AXES * [jt["cameraX"], jt["cameraY"], jt["cameraZ"]]
                states[i] = st
        try:
            body_id = int(body.get("trackingId", body.get("bodyIndex", 0))) % (1 << 63)
        except (TypeError, ValueError):
            raise InputError(
                f"{self.path}: frame {k}: trackingId {body.get('trackingId')!r} is not an "
                "integer; the file is not kinect2-tracking output"
            ) from None
        return BodyFrame(self._id, k, t, float("nan"), joints, states, body_id=body_id)


class SimulatedSensorSource:
    """One simulated sensor as a live source: its frames generated as they are asked for.

    The calibration phase's depth frames are rendered one at a time (the costly part, 26 ms a
    frame); the motion phase's body frames are drawn when the first of them is asked for (the
    tracker's error processes are smooth over the whole take), then handed out one by one.
    The numbers are those :func:`kinefuse.sim.lab.simulate_session` writes for the same
    ``motion``, ``rig``, sensor and seed (the same random streams in the same order).

    Parameters
    ----------
    motion : Motion
        Already placed in the lab (:func:`kinefuse.sim.rig.place_actor`).
    rig : Rig
    sensor_id : str
        One of the rig's sensors.
    seed : int
        The session's seed (it replaces ``config.seed``).
    config : LabConfig, optional
        Phases and error model (default ``LabConfig()``).
    depth : bool
        Also deliver the calibration phase's depth frames (default True).
    bystanders : sequence of Motion
        Other people in the room (placed, :func:`kinefuse.sim.people.place_bystander`): each
        frame then carries every body the sensor tracks (``BodyFrame.others``).

    ``probes`` holds the client's clock probes over the session ``(N, 4)`` (server ``t1``,
    client ``t2``, ``t3``, server ``t4``), as the client would answer them.
    """

    def __init__(
        self,
        motion: Motion,
        rig: Rig,
        sensor_id: str,
        seed: int = 0,
        *,
        config: LabConfig | None = None,
        depth: bool = True,
        bystanders: Sequence[Motion] = (),
    ) -> None:
        from dataclasses import replace

        from kinefuse.sim.lab import LabConfig, SensorSimulation

        cfg = replace(LabConfig() if config is None else config, seed=int(seed))
        self._args = (motion, rig, sensor_id, cfg, tuple(bystanders))
        self._depth = depth
        first = SensorSimulation(*self._args)
        self._id = sensor_id
        self._intrinsics = first.intrinsics
        self.probes = first.probes
        self.rate_hz = cfg.errors.clock.frame_rate_hz

    @property
    def sensor_ids(self) -> tuple[str, ...]:
        return (self._id,)

    def intrinsics(self, sensor_id: str) -> Intrinsics:
        return self._intrinsics

    def __iter__(self) -> Iterator[Frame]:
        from kinefuse.sim.lab import SensorSimulation

        sim = SensorSimulation(*self._args)  # fresh random streams: every pass is the same
        if self._depth:
            for seq, t_dev, t_host, frame in sim.depth_frames():
                yield DepthFrame(self._id, seq, t_dev, t_host, frame)
        yield from sim.body_frames()


def _simlive(target: str, sensor: str, query: str, spec: str) -> SimulatedSensorSource:
    """``simlive:CLIP#SENSOR_ID?rig=...&seed=...&calibration=...&seconds=...&sensors=...
    &bystander=CLIP2...``."""
    from urllib.parse import parse_qs

    from kinefuse.formats.motion import load_motion
    from kinefuse.sim.lab import LabConfig
    from kinefuse.sim.people import place_bystander
    from kinefuse.sim.rig import default_rig, load_rig, place_actor

    known = {"rig", "seed", "calibration", "seconds", "sensors", "depth_rate", "bystander"}
    given = parse_qs(query, keep_blank_values=True)
    args = {k: v[-1] for k, v in given.items()}
    bad = sorted(set(args) - known)
    if bad:
        raise InputError(
            f"source {spec!r}: unknown option(s) {', '.join(bad)}; simlive takes "
            + ", ".join(sorted(known))
        )
    try:
        seed = int(args.get("seed", "0"))
        cal = float(args.get("calibration", "20"))
        seconds = float(args["seconds"]) if "seconds" in args else None
        n = int(args.get("sensors", "4"))
        depth_rate = float(args.get("depth_rate", "10"))
    except ValueError as e:
        raise InputError(f"source {spec!r}: {e}; seed and sensors are integers, "
                         "calibration and seconds numbers of seconds") from None  # fmt: skip
    rig = load_rig(args["rig"]) if "rig" in args else default_rig(n)
    if not sensor:
        raise InputError(
            f"source {spec!r}: name the sensor after '#' (one of "
            f"{', '.join(s.id for s in rig.sensors)})"
        )
    motion = place_actor(load_motion(target), rig, seconds)
    span = motion.duration_s if seconds is None else seconds
    # placed as `kinefuse simulate --bystander` places them: the same session, live
    others = [
        place_bystander(place_actor(load_motion(clip), rig), motion, rig, i, span)
        for i, clip in enumerate(given.get("bystander", []))
    ]
    config = LabConfig(seed=seed, calibration_s=cal, motion_s=seconds, depth_rate_hz=depth_rate)
    return SimulatedSensorSource(motion, rig, sensor, seed, config=config, bystanders=others)


def open_source(spec: str) -> FrameSource:
    """A source from its command-line form: ``sim:SESSION.sqlite#SENSOR_ID``,
    ``multitrack:FILE.csv#KINECT_ID``, ``kinect2json:FILE.json`` or
    ``simlive:CLIP#SENSOR_ID?rig=RIG.toml&seed=N&calibration=S&seconds=S&sensors=N&depth_rate=HZ
    &bystander=CLIP2`` (a simulated sensor generating its frames as they are asked for,
    :class:`SimulatedSensorSource`: a clip (.bvh, .amc), a rig file or the default rig of
    ``sensors`` sensors, the session's seed, the calibration phase's and the motion's length,
    the depth frame rate, other people's clips (``bystander``, repeatable: placed and tracked as
    ``kinefuse simulate --bystander`` does); defaults as ``kinefuse simulate``: seed 0, 20 s of
    calibration, the whole clip, 4 sensors, 10 Hz, nobody else).

    A session replay opens its store read-only; it stays open as long as the source lives.
    """
    kind, _, rest = spec.partition(":")
    rest, _, query = rest.partition("?")
    target, _, sensor = rest.partition("#")
    if not target:
        raise InputError(
            f"source {spec!r}: expected sim:SESSION.sqlite#SENSOR_ID, "
            "multitrack:FILE.csv#KINECT_ID, kinect2json:FILE.json or simlive:CLIP#SENSOR_ID"
        )
    if kind == "simlive":
        return _simlive(target, sensor, query, spec)
    if kind == "sim":
        store = SessionStore.open(target)
        return SessionReplay(store, [sensor] if sensor else None)
    if kind == "multitrack":
        return MultitrackReplay(target, sensor or None)
    if kind == "kinect2json":
        return Kinect2TrackingReplay(target)
    raise InputError(
        f"source {spec!r}: unknown kind {kind!r}; use sim, multitrack, kinect2json or simlive"
    )

"""Frame sources: what a sensor delivers, one frame at a time, in arrival order.

A :class:`FrameSource` yields :class:`BodyFrame` (the body tracker's 25 joints of one frame)
and, during a calibration phase, :class:`DepthFrame` items, in the order a client would have
received them. Sources here:

- :class:`SessionReplay`: a stored session (simulated or live-recorded), every sensor or one;
- :class:`MultitrackReplay`: a real KinectMultiTrack log (two Kinect v2, one CSV), one sensor;
- :class:`Kinect2TrackingReplay`: the kinect2-tracking JSON (one real Kinect v2 walk).

A driver for a physical sensor implements the same protocol (``sensor_id``, ``intrinsics``,
``__iter__``); the live client (issue 11) plays any of them in real time. Times are each
sensor's own: ``t_device_s`` stamps the capture on the device's clock, ``t_host_s`` the arrival
on the client PC's clock (NaN where a log does not say).
"""

from __future__ import annotations

import heapq
import json
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from kinefuse.camera.intrinsics import Intrinsics
from kinefuse.errors import InputError
from kinefuse.io.store import SessionStore
from kinefuse.observations import BodyFrame, BodyFrames, DepthFrame, Frame
from kinefuse.skeleton import N_JOINTS

__all__ = [
    "BodyFrame",
    "BodyFrames",
    "DepthFrame",
    "Frame",
    "FrameSource",
    "Kinect2TrackingReplay",
    "MultitrackReplay",
    "SessionReplay",
    "open_source",
]

Array = NDArray[np.float64]

#: Kinect camera space (x left, y up, z forward) -> kinefuse sensor axes (x right, y down, z fwd).
_KINECT_AXES = np.array([-1.0, -1.0, 1.0])


@runtime_checkable
class FrameSource(Protocol):
    """What a sensor client plays: frames in arrival order (a driver implements this too).

    ``sensor_ids`` names the sensors it delivers; ``intrinsics(sensor_id)`` their depth camera;
    iterating yields :data:`Frame` items, each sensor's in increasing ``seq``.
    """

    @property
    def sensor_ids(self) -> tuple[str, ...]: ...

    def intrinsics(self, sensor_id: str) -> Intrinsics: ...

    def __iter__(self) -> Iterator[Frame]: ...


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

    def _body(self, sid: str) -> Iterator[BodyFrame]:
        yield from self._store.observations(sid)

    def _depth_frames(self, sid: str) -> Iterator[DepthFrame]:
        for seq, t, frames in self._store.iter_depth_frames(sid):
            for k in range(len(seq)):
                # depth frames carry no host time in the store: their device time stands in
                yield DepthFrame(sid, int(seq[k]), float(t[k]), float("nan"), frames[k])

    def __iter__(self) -> Iterator[Frame]:
        streams: list[Iterator[Frame]] = []
        for sid in self._ids:
            streams.append(self._body(sid))
            if self._depth:
                streams.append(self._depth_frames(sid))
        yield from heapq.merge(*streams, key=_arrival_key)


class MultitrackReplay:
    """One sensor of a real KinectMultiTrack log (``Study_*_Kinect_*.csv``).

    The log's joints are already in the reference sensor's frame (the original tracker's
    transform) and carry no per-joint tracking state: every joint present is TRACKED. Device
    time is the sensor's ``Skeleton_Time``; the host time is the receiving server's
    ``Tracker_Time`` (the only arrival time the log has, with tens of ms of jitter).
    """

    def __init__(self, path: str | Path, kinect_id: str | None = None) -> None:
        from kinefuse.io.kinect_multitrack import read_kinect_multitrack

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
        order = np.argsort(s.t_receive_server_s, kind="stable")
        for seq, k in enumerate(order.tolist()):
            # the server's receive time is the only arrival time the log has
            yield BodyFrame(
                sensor_id=s.sensor_id,
                seq=seq,
                t_device_s=float(s.t_device_s[k]),
                t_host_s=float(s.t_receive_server_s[k]),
                joints_m=s.joints_m[k],
                states=s.states[k],
            )


class Kinect2TrackingReplay:
    """The kinect2-tracking JSON (``walker.json``): the first tracked body of every frame.

    The file has no timestamps; frames are placed at the Kinect v2's 30 Hz (``rate_hz``).
    Joints come in Kinect camera space and are turned into the sensor frame (x right, y down).
    """

    def __init__(self, path: str | Path, *, sensor_id: str = "kinect", rate_hz: float = 30.0):
        p = Path(path)
        try:
            data = json.loads(p.read_text(encoding="utf-8"))
            frames = data["bodyFrame"]
        except (OSError, ValueError, KeyError, TypeError) as e:
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
            body = next((b for b in f.get("bodies", []) if b.get("tracked")), None)
            joints = np.full((N_JOINTS, 3), np.nan)
            states = np.zeros(N_JOINTS, dtype=np.int8)
            if body is not None:
                for jt in body.get("joints", []):
                    i = int(jt["jointType"])
                    st = int(jt.get("trackingState", 0))
                    if 0 <= i < N_JOINTS and st in (1, 2):
                        joints[i] = _KINECT_AXES * [jt["cameraX"], jt["cameraY"], jt["cameraZ"]]
                        states[i] = st
            t = k / self._rate
            yield BodyFrame(self._id, k, t, float("nan"), joints, states)


def open_source(spec: str) -> FrameSource:
    """A source from its command-line form: ``sim:SESSION.sqlite#SENSOR_ID``,
    ``multitrack:FILE.csv#KINECT_ID`` or ``kinect2json:FILE.json``.

    A session replay opens its store read-only; it stays open as long as the source lives.
    """
    kind, _, rest = spec.partition(":")
    target, _, sensor = rest.partition("#")
    if not target:
        raise InputError(
            f"source {spec!r}: expected sim:SESSION.sqlite#SENSOR_ID, "
            "multitrack:FILE.csv#KINECT_ID or kinect2json:FILE.json"
        )
    if kind == "sim":
        store = SessionStore.open(target)
        return SessionReplay(store, [sensor] if sensor else None)
    if kind == "multitrack":
        return MultitrackReplay(target, sensor or None)
    if kind == "kinect2json":
        return Kinect2TrackingReplay(target)
    raise InputError(f"source {spec!r}: unknown kind {kind!r}; use sim, multitrack or kinect2json")

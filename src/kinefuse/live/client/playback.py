"""What a sensor client plays: one sensor's frames on a play timeline, from a source spec.

A :class:`Timeline` yields :class:`Timed` frames in play order; ``t_play_s`` is when the frame
reaches the client PC, in seconds of the timeline's own clock (``source_clock``):

- ``sim:SESSION.sqlite#SENSOR_ID``: a simulated sensor. The timeline is the simulation's true
  time: a body frame plays at the true instant it reached the host (its recorded host arrival
  through the true host clock), a depth frame at its true capture + the mean capture-to-host
  latency. (:class:`kinefuse.pipeline.frame_sources.SessionReplay` merges body and depth frames by
  keys on two different clocks; a player needs one clock, so it merges them here.)
- ``multitrack:FILE.csv#KINECT_ID``, ``kinect2json:FILE``: recorded real logs through
  :func:`kinefuse.pipeline.frame_sources.open_source`; a frame plays at its host time where the log
  has one, else at its device time (``source_clock`` ``"host"`` or ``"device"``).
- ``KIND:ARG[?KEY=VALUE&...][#SENSOR_ID]`` of a camera kind (entry points of the group
  ``kinefuse.cameras``: ``mkv``, ``k4a``, ``realsense``, ``realsense-file``, ``kinect2``;
  :mod:`kinefuse.devices.sources`), with the body tracker ``tracker`` names: a device is live,
  a recording plays on its device times like a log (in real time, or at ``--speed``).
- ``driver:MODULE:FACTORY[?KEY=VALUE&...]`` or an entry point ``NAME:ARG`` of the group
  ``kinefuse.pipeline.frame_sources``: a physical sensor's driver (docs/live.md, "A driver for a
  physical sensor"). It is *live*: its iterator blocks until the device delivers the next frame,
  which the client sends at once (no schedule).
"""

from __future__ import annotations

import heapq
import importlib
import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from importlib.metadata import entry_points
from typing import Any
from urllib.parse import parse_qsl

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.camera.wand import Wand
from kinefuse.core.frames.observations import BodyFrame, DepthFrame, Frame
from kinefuse.core.frames.source import FrameSource
from kinefuse.devices.sources import camera_kinds, open_camera_source
from kinefuse.errors import InputError
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.pipeline.frame_sources import SessionReplay, open_source
from kinefuse.sim.clock import ClockParams, SensorClocks, read_sensor_clocks

#: the entry-point group a driver package registers its sources under
ENTRY_POINT_GROUP = "kinefuse.pipeline.frame_sources"


@dataclass(frozen=True, eq=False)
class Timed:
    """A frame and the time it reaches the client PC on the timeline's clock (seconds)."""

    t_play_s: float
    frame: Frame


class Timeline(ABC):
    """One sensor's frames in play order.

    Attributes
    ----------
    sensor_id : str
    intrinsics : Intrinsics
    wand : Wand
        The wand the depth frames show (a simulated session says; else the default wand).
    source_clock : str
        ``"true"`` (simulated true time), ``"host"``, ``"device"`` or ``"live"`` (a driver).
    truth : SensorClocks or None
        The simulated sensor's true clocks (sim sources only; the simulator reads them).
    live : bool
        The frames come in real time (a driver): play each as it comes.
    serial : str
        The device's serial number if the source knows it (a session, a driver's ``serial``).
    """

    sensor_id: str
    intrinsics: Intrinsics
    serial: str = ""
    wand: Wand = Wand()
    source_clock: str = "host"
    truth: SensorClocks | None = None
    live: bool = False

    @abstractmethod
    def frames(self) -> Iterator[Timed]:
        """The frames with the instants to send them, in order."""

    def close(self) -> None:  # noqa: B027 (a timeline with nothing to release keeps it)
        """Release the source (a store, a device); nothing by default."""

    def tracker_status(self) -> str | None:
        """The body tracker's one-line status (achieved rate, captures dropped because it was
        behind, its last refusal) for the server's status; None when no tracker runs here."""
        return None


class SimTimeline(Timeline):
    """A simulated sensor of a session, on the simulation's true time (see module notes)."""

    source_clock = "true"

    def __init__(self, path: str, sensor_id: str, *, depth: bool = True) -> None:
        # read what the client needs now, and open the store again in the thread that plays
        # it (an SQLite connection belongs to its thread)
        self.path = path
        store = SessionStore.open(path)
        try:
            ids = [s.id for s in store.sensors()]
            if not sensor_id:
                if len(ids) != 1:
                    raise InputError(
                        f"source sim:{path}: name the sensor to play, sim:{path}#ID, one of "
                        f"{', '.join(ids)}"
                    )
                sensor_id = ids[0]
            if sensor_id not in ids:
                raise InputError(
                    f"source sim:{path}: no sensor {sensor_id!r}; its sensors: {', '.join(ids)}"
                )
            self.truth = read_sensor_clocks(store, sensor_id)
            wand = store.meta().get("wand")
            try:
                self.wand = Wand(**wand) if isinstance(wand, dict) else Wand()
            except (TypeError, ValueError) as e:  # a damaged or forged session
                raise InputError(
                    f"source sim:{path}: the session's stored wand is malformed ({e}); "
                    "simulate the session again"
                ) from None
            info = store.sensor(sensor_id)
            self.intrinsics = info.intrinsics
            self.serial = str(info.serial)
        finally:
            store.close()
        self.sensor_id = sensor_id
        #: False: the body frames only (a light sensor that does no depth work, as the
        #: capacity benchmark plays many in one process)
        self.depth = depth
        self._latency_s = ClockParams().latency_mean_s + self.truth.latency_offset_s

    def _body(self, store: SessionStore) -> Iterator[Timed]:
        truth = self.truth
        assert truth is not None
        for f in SessionReplay(store, [self.sensor_id], depth=False):
            yield Timed(truth.host.affine.inverse(f.t_host_s), f)

    def _depth(self, store: SessionStore) -> Iterator[Timed]:
        truth = self.truth
        assert truth is not None
        for seq, t, frames in store.iter_depth_frames(self.sensor_id):
            for k in range(len(seq)):
                f = DepthFrame(self.sensor_id, int(seq[k]), float(t[k]), math.nan, frames[k])
                yield Timed(truth.device.affine.inverse(f.t_device_s) + self._latency_s, f)

    def frames(self) -> Iterator[Timed]:
        """The frames in play order (the store is open while iterating, in this thread)."""
        with SessionStore.open(self.path) as store:
            if not self.depth:
                yield from self._body(store)
                return
            yield from heapq.merge(self._depth(store), self._body(store), key=lambda x: x.t_play_s)


class SourceTimeline(Timeline):
    """Any :class:`~kinefuse.core.frames.source.FrameSource` of one sensor (a log, or a live
    driver)."""

    def __init__(
        self, source: FrameSource, sensor_id: str | None = None, *, live: bool = False
    ) -> None:
        ids = tuple(source.sensor_ids)
        if sensor_id is None or sensor_id == "":
            if len(ids) != 1:
                raise InputError(
                    f"the source delivers sensors {', '.join(ids)}; a client plays one: add "
                    "#SENSOR_ID to the source"
                )
            sensor_id = ids[0]
        if sensor_id not in ids:
            raise InputError(f"the source has no sensor {sensor_id!r}; it has {', '.join(ids)}")
        self.sensor_id = sensor_id
        self.intrinsics = source.intrinsics(sensor_id)
        if not isinstance(self.intrinsics, Intrinsics):
            raise InputError(
                f"the source's intrinsics({sensor_id!r}) gave a {type(self.intrinsics).__name__}, "
                "expected kinefuse.core.camera.intrinsics.Intrinsics"
            )
        self.live = live
        self.source_clock = "live" if live else "host"
        self.serial = str(getattr(source, "serial", "") or "")
        self._source = source

    def tracker_status(self) -> str | None:
        status = getattr(self._source, "tracker_status", None)
        return status() if callable(status) else None

    def frames(self) -> Iterator[Timed]:
        last = -math.inf
        first = True
        for f in self._source:
            if f.sensor_id != self.sensor_id:
                continue
            if not isinstance(f, BodyFrame | DepthFrame):
                raise InputError(
                    f"the source yielded a {type(f).__name__}; a FrameSource yields "
                    "kinefuse.pipeline.frame_sources.BodyFrame and DepthFrame items"
                )
            if self.live:
                yield Timed(math.nan, f)
                continue
            t = f.t_host_s if math.isfinite(f.t_host_s) else f.t_device_s
            if first:
                self.source_clock = "host" if math.isfinite(f.t_host_s) else "device"
                first = False
            # a log's arrival stamps jitter; never play backwards
            last = max(last, t)
            yield Timed(last, f)

    def close(self) -> None:
        close = getattr(self._source, "close", None)
        if callable(close):
            close()


def _driver_factory(target: str) -> Callable[..., Any]:
    module, sep, attr = target.partition(":")
    if not sep or not module or not attr:
        raise InputError(
            f"driver source {target!r}: expected driver:MODULE:FACTORY (a class or function "
            "returning a FrameSource), e.g. driver:mypkg.kinect:KinectV2Source"
        )
    try:
        mod = importlib.import_module(module)
    except ImportError as e:
        raise InputError(f"driver source: cannot import {module!r} ({e})") from None
    factory = getattr(mod, attr, None)
    if not callable(factory):
        raise InputError(f"driver source: {module} has no callable {attr!r}")
    return factory


def _check_source(src: object, what: str) -> FrameSource:
    if not isinstance(src, FrameSource):
        raise InputError(
            f"{what} gave a {type(src).__name__}, which is not a FrameSource (it needs "
            "sensor_ids, intrinsics(sensor_id) and __iter__; docs/live.md)"
        )
    return src


def open_timeline(spec: str, tracker: str | None = None, *, speed: float = 1.0) -> Timeline:
    """The timeline of a ``--source`` spec (see the module notes for the forms); ``tracker``
    names the body tracker of a camera source (refused for the other sources), which runs on
    its own thread; a camera recording is read at ``speed``."""
    kind, _, rest = spec.partition(":")
    if kind in camera_kinds():
        camera = open_camera_source(spec, tracker, threaded=True, speed=speed)
        return SourceTimeline(camera, None, live=camera.live)
    if tracker:
        raise InputError(
            f"--tracker is for camera sources ({', '.join(sorted(camera_kinds()))}); "
            f"{kind!r} delivers body frames already"
        )
    if kind == "sim":
        target, _, sensor = rest.partition("#")
        if not target:
            raise InputError(f"source {spec!r}: expected sim:SESSION.sqlite#SENSOR_ID")
        return SimTimeline(target, sensor)
    if kind in ("multitrack", "kinect2json", "simlive"):
        # simlive (a simulated sensor generating its frames, where kinefuse.pipeline.frame_sources
        # has it) plays on its own host stamps like a log
        sensor = rest.partition("?")[0].partition("#")[2]
        src = open_source(spec)
        return SourceTimeline(src, sensor or None)
    if kind == "driver":
        body, _, sensor = rest.partition("#")
        target, _, query = body.partition("?")
        factory = _driver_factory(target)
        kwargs = dict(parse_qsl(query, keep_blank_values=True, strict_parsing=bool(query)))
        try:
            src = factory(**kwargs)
        except TypeError as e:
            raise InputError(f"driver source {target}: {e}") from None
        return SourceTimeline(_check_source(src, target), sensor or None, live=True)
    eps = {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}
    if kind in eps:
        factory = eps[kind].load()
        arg, _, sensor = rest.partition("#")
        src = _check_source(factory(arg), f"entry point {kind!r}")
        return SourceTimeline(src, sensor or None, live=True)
    raise InputError(
        f"source {spec!r}: unknown kind {kind!r}; use sim:SESSION.sqlite#ID, "
        "multitrack:FILE.csv#KINECT_ID, kinect2json:FILE, a camera "
        f"({', '.join(sorted(camera_kinds()))}), driver:MODULE:FACTORY or an installed driver "
        f"({ENTRY_POINT_GROUP} entry points: {', '.join(sorted(eps)) or 'none'}); "
        "kinefuse sensor --list-sources lists them"
    )

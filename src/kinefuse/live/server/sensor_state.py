"""What the server keeps per sensor: identity, clocks, the bounded queue of observations, stats.

A :class:`SensorState` lives as long as the server (keyed by sensor id), so a client that
reconnects finds its pose and its statistics again. What its frames say belongs to the
connection (:class:`Connection` in :mod:`kinefuse.live.server.server`): each connection is a new
stream, its sequence numbers and clocks start afresh (a restarted sensor counts from 0 again,
its device clock may have restarted; a peer that took an offline id for a while leaves nothing
behind that could hold the real sensor's frames back).

Times of an observation (all seconds):

- ``t_device_s``: capture on the sensor's device clock (from the client);
- ``t_host_s``: arrival at the client PC on its host clock (from the client);
- ``t_receive_server_s``: arrival at the server, server clock;
- ``t_capture_server_s``: the capture time on the server clock the fusion uses, device -> host
  with a running fit of ``t_host - t_device`` over the latest frames minus the nominal latency
  (:func:`kinefuse.capture.sync.device.estimate_device_clock`, the model the offline path fits over
  the whole recording), host -> server with the client's
  :class:`~kinefuse.capture.sync.online.OnlineClock`.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from kinefuse.capture.sync.device import (
    NOMINAL_LATENCY_S,
    DeviceClockEstimate,
    estimate_device_clock,
)
from kinefuse.capture.sync.online import OnlineClock, OnlineClockParams
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.frames.observations import BodyFrame
from kinefuse.core.skeleton import N_JOINTS, TrackingState
from kinefuse.errors import SyncError
from kinefuse.live.server.peer_limits import EventLimit

Array = NDArray[np.float64]


class DeviceClockTracker:
    """Running device -> host clock of one sensor: the offline fit over the latest ``window``
    frames, refitted every ``refit_every`` frames (and at each of the first ones)."""

    def __init__(self, window: int = 600, refit_every: int = 30) -> None:
        self._td: deque[float] = deque(maxlen=window)
        self._th: deque[float] = deque(maxlen=window)
        self._n = 0
        self._every = refit_every
        self.estimate: DeviceClockEstimate | None = None

    def add(self, t_device_s: float, t_host_s: float) -> None:
        if not (math.isfinite(t_device_s) and math.isfinite(t_host_s)):
            return
        self._td.append(t_device_s)
        self._th.append(t_host_s)
        self._n += 1
        if self.estimate is None or self._n < self._every or self._n % self._every == 0:
            self.estimate = estimate_device_clock(np.array(self._td), np.array(self._th))

    def to_host(self, t_device_s: float) -> float:
        """Capture time on the host clock (NaN before the first frame with a host time)."""
        if self.estimate is None:
            return float("nan")
        return float(self.estimate.affine.forward(t_device_s))


@dataclass(frozen=True, eq=False)
class Observation:
    """One body frame as the fusion takes it (see the module docstring for the times).

    ``joints_m``, ``states``, ``occluded`` and ``n_crossings`` are the first body's (the one
    the tracker listed first: what the fusion uses); ``bodies`` is every body of the frame, the
    first first, each a :class:`~kinefuse.core.frames.observations.BodyFrame` with its tracking id
    (sanitized like the first; its times the client's clocks; no ``others``).
    """

    seq: int
    t_capture_server_s: float
    t_host_server_s: float
    joints_m: Array
    states: NDArray[np.int8]
    occluded: NDArray[np.bool_] | None
    n_crossings: int | None
    bodies: tuple[BodyFrame, ...] = ()


def sanitize_joints(joints_m: Array, states: NDArray[np.int8]) -> tuple[Array, NDArray[np.int8]]:
    """Joints NaN exactly where the state is NOT_TRACKED (the store's and fusion's rule): a
    joint without a position is not tracked, a not-tracked joint has no position."""
    j = np.array(joints_m, dtype=np.float64).reshape(N_JOINTS, 3)
    st = np.array(states, dtype=np.int8).reshape(N_JOINTS)
    missing = ~np.isfinite(j).all(axis=1)
    st[missing] = TrackingState.NOT_TRACKED
    j[st == TrackingState.NOT_TRACKED] = np.nan
    return j, st


class SensorState:
    """One sensor as the server knows it, across its connections.

    Parameters
    ----------
    sensor_id, serial : str
    intrinsics : Intrinsics
    queue_size : int
        Observations kept for the fusion loop; when it falls behind the oldest are dropped
        (newest wins) and counted in :attr:`dropped`.
    clock_params : OnlineClockParams, optional
    """

    def __init__(
        self,
        sensor_id: str,
        serial: str,
        intrinsics: Intrinsics,
        *,
        queue_size: int = 16,
        clock_params: OnlineClockParams | None = None,
    ) -> None:
        self.sensor_id = sensor_id
        self.serial = serial
        self.intrinsics = intrinsics
        self.clock = OnlineClock(clock_params)
        self.device = DeviceClockTracker()
        self.connected = False
        self.connections = 0
        self.queue: deque[Observation] = deque(maxlen=queue_size)
        self.dropped = 0
        #: the latest body frame's seq on the current connection (None: none yet)
        self.last_seq: int | None = None
        #: body frames refused because their seq did not increase on their connection
        self.stale = 0
        #: body frames dropped as too late (a stalled sensor's backlog)
        self.late_dropped = 0
        #: server time the current run of late frames began (None: the last frame was on time)
        self.late_since: float | None = None
        #: a run of late frames arriving for this long means the device clock was reset, s
        self.max_late_run_s = 3.0
        self.rtt_s = float("nan")
        self.latency_s = float("nan")
        #: why the client's floor fit of this calibration failed (its heartbeats say), or None
        self.floor_error: str | None = None
        #: the client's body-tracker status line (its heartbeats say), or None
        self.tracker: str | None = None
        #: what of this sensor is logged and recorded one by one (the rest is summarized)
        self.events = EventLimit(per_window=10, window_s=10.0)
        self._bodies: tuple[BodyFrame, ...] = ()
        self._bodies_t_capture_server_s = float("nan")
        self._arrivals: deque[float] = deque(maxlen=90)
        self._tracked: deque[float] = deque(maxlen=90)

    # -- connection lifecycle ----------------------------------------------------------------

    def connect(self) -> None:
        """A new connection, a new stream: its sequence numbers start afresh, the clocks are
        synchronized from scratch (it may be another route or PC, a restarted device)."""
        self.connected = True
        self.connections += 1
        if self.connections > 1:
            self.clock.reset(f"reconnect #{self.connections - 1}")
            self.device = DeviceClockTracker()
        self.last_seq = None
        self.late_since = None
        self.queue.clear()
        self.keep_bodies((), float("nan"))

    def disconnect(self) -> None:
        self.connected = False

    # -- clock ---------------------------------------------------------------------------------

    def host_to_server(self, t_host_s: float) -> float:
        """Server time of a host-clock time (NaN before the first kept probe)."""
        if not math.isfinite(t_host_s):
            return float("nan")
        try:
            return float(self.clock.affine.inverse(t_host_s))
        except SyncError:
            return float("nan")

    def capture_to_server(self, t_device_s: float) -> float:
        """The capture time on the server clock of a device timestamp (NaN: not yet known)."""
        return self.host_to_server(self.device.to_host(t_device_s))

    # -- observations ----------------------------------------------------------------------------

    def lateness(self, t_device_s: float, t_host_s: float, t_arrival_s: float) -> float:
        """How much later than its clocks say a body frame is here, seconds (-inf: unknown).

        Two delays, the larger counts: its arrival at the server after its host stamp (mapped
        by the online clock: a frame held in a queue or a socket), and its host stamp after its
        capture (device stamp through the device clock fit, plus the nominal latency: a frame
        handed over late, as a stalled sensor's player does with its backlog when it resumes).
        """
        late = -math.inf
        t_host_srv = self.host_to_server(t_host_s)
        if math.isfinite(t_host_srv):
            late = t_arrival_s - t_host_srv
        cap_host = self.device.to_host(t_device_s)
        if math.isfinite(cap_host):
            late = max(late, t_host_s - cap_host - NOMINAL_LATENCY_S)
        return late

    def drop_late(self, t_arrival_s: float) -> None:
        """A body frame dropped as late. A backlog arrives in a burst; late frames that go on
        arriving for ``max_late_run_s`` mean the fit is wrong (the device clock was reset), not
        the frames: the device fit starts anew."""
        self.late_dropped += 1
        if self.late_since is None:
            self.late_since = t_arrival_s
        elif t_arrival_s - self.late_since > self.max_late_run_s:
            self.device = DeviceClockTracker()
            self.late_since = None

    def enqueue(self, obs: Observation, t_receive_server_s: float) -> None:
        self.late_since = None
        if len(self.queue) == self.queue.maxlen:
            self.dropped += 1
        self.queue.append(obs)
        self._arrivals.append(t_receive_server_s)
        self._tracked.append(float((obs.states == TrackingState.TRACKED).mean()))

    def keep_bodies(self, bodies: tuple[BodyFrame, ...], t_capture_server_s: float) -> None:
        """Every body of the sensor's latest body frame (the first listed first), captured at
        ``t_capture_server_s`` on the server clock (NaN: not yet known)."""
        self._bodies = bodies
        self._bodies_t_capture_server_s = t_capture_server_s

    def bodies(self) -> tuple[float, tuple[BodyFrame, ...]]:
        """The latest body frame's capture time on the server clock (s, NaN: unknown) and its
        bodies, each a :class:`~kinefuse.core.frames.observations.BodyFrame` with the sensor's
        tracking id, joints in the sensor frame (the first is the one the fusion uses);
        ``(nan, ())`` before the first frame and after a reconnect."""
        return self._bodies_t_capture_server_s, self._bodies

    def drain(self) -> list[Observation]:
        """Take what is queued (atomically per item: safe against an append meanwhile)."""
        out = []
        q = self.queue
        while q:
            out.append(q.popleft())
        return out

    # -- statistics ------------------------------------------------------------------------------

    def fps(self, t_now_s: float) -> float:
        recent = [t for t in self._arrivals if t > t_now_s - 1.0]
        return float(len(recent))

    def tracked_fraction(self) -> float:
        return float(np.mean(self._tracked)) if self._tracked else float("nan")

    def clock_ms(self, t_now_s: float) -> tuple[float, float]:
        """Offset (client minus server) and its standard error now, ms (NaN: none yet)."""
        try:
            e = self.clock.estimate(t_now_s)
        except SyncError:
            return float("nan"), float("nan")
        return e.offset_s * 1e3, e.offset_se_s * 1e3


def latest_bodies(clients: Mapping[str, SensorState]) -> dict[str, list[BodyFrame]]:
    """Every body of each connected sensor's latest body frame, ``{sensor_id: [first, ...]}``
    (the first is the body the fusion uses; sensors without a frame yet are left out): what a
    people associator takes at each fused instant."""
    out: dict[str, list[BodyFrame]] = {}
    for sid, c in clients.items():
        _t, bodies = c.bodies()
        if c.connected and bodies:
            out[sid] = list(bodies)
    return out

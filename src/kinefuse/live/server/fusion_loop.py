"""The server's fusion loop: one fused frame every 1/30 s on the server clock, published.

Frame ``k`` is the skeleton at server time ``T = k / rate_hz``. Observations captured up to
``T + lead_s`` take part (``best-live``: its
:attr:`~kinefuse.capture.fusion.live.LiveOptions.latency_s`, 1/30 s, the frame time is interpolated
between the two observations around it; ``paper``: 0, the paper's assembly takes each sensor's
latest observation in ``(T - 1/30, T]``). Frame ``T`` is fused as soon as every sensor that is
delivering (connected, calibrated, an observation captured within the last ``stall_s`` = 0.2 s) has
delivered one captured after ``T``: each sensor's frames arrive in capture order, so nothing that
can change frame ``T`` is still to come, and the frame is the one
:func:`kinefuse.capture.fusion.live.replay` gives offline on the recording (with ``latency_s =
lead_s``): the fusion at ``T`` only looks at the observations around ``T``. A sensor whose frame is
late is waited for until the deadline ``T + lead_s + NOMINAL_LATENCY_S + wait_s`` (a frame reaches
its client PC ``NOMINAL_LATENCY_S`` = 60 ms after capture on average,
:mod:`kinefuse.capture.sync.device`; ``wait_s`` is ``kinefuse serve --latency-budget-ms``, default
10 ms); after it the frame is fused without it: the filter holds that sensor's last observation
or predicts (``PREDICTED``); the late observation still helps later frames.

The published :class:`~kinefuse.live.bus.FusedFrame` carries ``latency_s``: the server time
it was published minus the host receive time (mapped onto the server clock) of the newest
observation it used; NaN for a frame that used none (a pure prediction: the newest observation
is older than the fusion holds one, ``max_hold_s`` = 50 ms, or the paper's 1/30 s window).

Cost and the event loop: a ``best-live`` frame takes about 1.3 ms of CPU on an idle machine and
6 ms on this shared 2-core one, the paper's chain (one trilateration call per frame) 18 ms
(``python benchmarks/bench_server_fusion.py``, medians, 4 sensors). While the fusion runs on the
event loop, a clock-probe reply that arrives waits to be stamped, which biases that probe. So the
loop measures its own fusion time (CPU time of the thread that fused, ``time.thread_time``: on
a shared machine the wall time also counts waits for a core, and sent a 1 ms fusion to a
thread under load): while the mean over the last frames stays under
``thread_above_s`` (2 ms) the fusion runs on the loop (a thread hop would cost more than it
saves); above it, each frame's ``fuse`` runs in a worker thread (``asyncio.to_thread``), and the
loop only waits at most the interpreter's GIL switch interval (5 ms) to stamp a reply. The
clock estimator's burst minimum (5 probes 20 ms apart, the least delayed kept) discards the
probes that waited anyway. New poses (a calibration) are applied between frames, never during
one.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from kinefuse.capture.fusion.live import LiveFusion, LiveOptions
from kinefuse.capture.fusion.methods import LIVE_METHODS
from kinefuse.capture.fusion.people import PeopleTracker
from kinefuse.capture.fusion.status import FusionStatus
from kinefuse.capture.sync.device import NOMINAL_LATENCY_S
from kinefuse.core.frames.observations import BodyFrame
from kinefuse.core.skeleton import N_JOINTS
from kinefuse.live.bus import FusedFrame, Publisher
from kinefuse.live.server.sensor_state import Observation, SensorState

log = logging.getLogger("kinefuse.serve")

Array = NDArray[np.float64]

METHODS = LIVE_METHODS


class FrameFusion:
    """Fuse frame by frame from pushed observations with ``best-live`` or the paper's method.

    Sensors are known by id; only sensors with a pose take part (:meth:`set_poses`). Every
    body an observation carries (``obs`` and ``obs.others``) is given to a person by the causal
    :class:`~kinefuse.capture.fusion.people.PeopleTracker`, and each person has a fusion of their
    own:
    :meth:`fuse` returns the subject's frame, :attr:`people` every person's. While no sensor
    has reported two bodies at one instant there is one person, 0, the subject, fused exactly
    as before. The subject is the first person seen (of several seen first at one instant, the
    one nearest the centre of the sensors) until :meth:`set_subject` chooses another (the
    operator, ``serve --subject``).
    """

    def __init__(self, method: str = "best-live", options: LiveOptions | None = None) -> None:
        if method not in METHODS:
            raise ValueError(f"unknown live fusion method {method!r}; choose {', '.join(METHODS)}")
        self.method = method
        self.options = options if options is not None else LiveOptions()
        self.ids: list[str] = []
        self._poses = np.zeros((0, 4, 4))
        self._lives: dict[int, LiveFusion] = {}
        self._latest: dict[str, Observation] = {}
        self._paper_windows: dict[int, dict[str, deque[Observation]]] = {}
        self.tracker = PeopleTracker()
        #: the person the server gives by default, and how they were chosen
        self.subject = 0
        self.subject_rule = "first seen"
        #: every person's last fused frame: ``person id -> (positions, variance, status)``
        self.people: dict[int, tuple[Array, Array, NDArray[np.int8]]] = {}
        self._first_seen = True
        #: called with ``(t_server_s, detail)`` once the subject (first, or each change) is
        #: tracked: ``person``, ``rule``, ``body_ids`` (per sensor, the tracking id of the
        #: subject's body then), ``trunk_m`` (world); the server records it
        self.on_subject: Callable[[float, dict[str, object]], None] | None = None
        self._subject_said = False

    def _subject_first_seen(self, persons: set[int]) -> None:
        """The subject by the live rule: the first person seen; of several seen first at one
        instant, the one whose trunk is nearest the centre of the sensors (on the floor)."""
        centre = self._poses[:, :2, 3].mean(axis=0)

        def far(p: int) -> float:
            at = self.tracker.position(p)
            return math.inf if at is None else float(np.linalg.norm(at[:2] - centre))

        self.subject = min(persons, key=lambda p: (far(p), p))
        if len(persons) > 1:
            self.subject_rule = "first seen, nearest the centre"
        log.info("the subject is person %d (%s)", self.subject, self.subject_rule)

    def _person_live(self, person: int) -> LiveFusion:
        if person not in self._lives:
            self._lives[person] = LiveFusion(self._poses, self.options)
        return self._lives[person]

    def set_subject(self, person: int, rule: str = "chosen", *, known: bool = False) -> bool:
        """Make ``person`` the subject (:meth:`fuse` returns their frame from now on).

        ``known``: only a person fused now (the operator picks among those shown); False when
        refused for that reason."""
        if known and person not in self.people:
            log.warning("subject %d asked for, but no such person is fused now", person)
            return False
        self.subject, self.subject_rule = int(person), rule
        self._subject_said = False
        log.info("the subject is person %d (%s)", person, rule)
        return True

    @property
    def subject_known(self) -> bool:
        """Whether the subject has been seen (since the last change)."""
        return self._subject_said

    def _say_subject(self, t: float) -> None:
        """Tell :attr:`on_subject` who the subject is, once they are tracked."""
        at = self.tracker.position(self.subject)
        if at is None:
            return
        self._subject_said = True
        if self.on_subject is not None:
            detail = {"person": self.subject, "rule": self.subject_rule, "t_capture_server_s": t,
                      "body_ids": self.tracker.body_ids(self.subject),
                      "trunk_m": [float(v) for v in at]}  # fmt: skip
            self.on_subject(t, detail)

    @property
    def lead_s(self) -> float:
        return self.options.latency_s if self.method == "best-live" else 0.0

    @property
    def ready(self) -> bool:
        return bool(self.ids)

    def set_poses(self, poses: Mapping[str, Array]) -> None:
        """Take (new) poses; sensors keep their indices, new ones are appended."""
        old = {sid: self._poses[i] for i, sid in enumerate(self.ids)}
        for sid in poses:
            if sid not in self.ids:
                self.ids.append(sid)
        self._poses = np.stack(
            [np.asarray(poses[s] if s in poses else old[s], dtype=np.float64) for s in self.ids]
        )
        if self.method == "best-live":
            self._person_live(self.subject)
            for live in self._lives.values():
                live.set_poses(self._poses)

    def _pose(self, sid: str) -> Array:
        return self._poses[self.ids.index(sid)]

    def push(self, sensor_id: str, obs: Observation) -> None:
        if sensor_id not in self.ids:
            return
        t = obs.t_capture_server_s
        first = BodyFrame(sensor_id, obs.seq, t, obs.t_host_server_s, obs.joints_m, obs.states,
                          obs.occluded, obs.n_crossings)  # fmt: skip
        bodies = obs.bodies or (first,)
        poses = {sid: self._poses[i] for i, sid in enumerate(self.ids)}
        who = self.tracker.update(t, {sensor_id: list(bodies)}, poses)
        if who and self._first_seen:
            self._first_seen = False
            if self.subject_rule == "first seen":
                self._subject_first_seen(set(who.values()))
        if who and not self._subject_said:
            self._say_subject(t)
        if not self.tracker.multi:
            # one person: every frame is theirs, as it always was (one without a trunk too)
            assign = [(obs, 0)]
        else:
            assign = [
                (self._body(obs, b), who[(sensor_id, b.body_id)])
                for k, b in enumerate(bodies)
                if (sensor_id, b.body_id) in who and all(o.body_id != b.body_id for o in bodies[:k])
            ]
            # a person this sensor does not see now gets an empty frame from it, as the offline
            # split (People.split) gives them
            seen = {p for _, p in assign}
            known = set(self._lives) | set(self._paper_windows) | set(self.tracker.people)
            if known - seen:
                empty = replace(
                    obs,
                    joints_m=np.full((N_JOINTS, 3), np.nan),
                    states=np.zeros(N_JOINTS, dtype=np.int8),
                    occluded=None,
                    n_crossings=None,
                    bodies=(),
                )
                assign += [(empty, p) for p in sorted(known - seen)]
        for o, person in assign:
            if person == self.subject:
                self._latest[sensor_id] = o
            if self.method == "best-live":
                self._person_live(person).push(
                    self.ids.index(sensor_id), t, o.joints_m, o.states, o.occluded
                )
            else:
                window = self._paper_windows.setdefault(person, {})
                window.setdefault(sensor_id, deque(maxlen=8)).append(o)

    @staticmethod
    def _body(obs: Observation, b: BodyFrame) -> Observation:
        """One body of an observation as an observation of its own (the same instant)."""
        return replace(obs, joints_m=b.joints_m, states=b.states, occluded=b.occluded,
                       n_crossings=b.n_crossings, bodies=())  # fmt: skip

    def fuse(self, t_server_s: float) -> tuple[Array, Array, NDArray[np.int8]]:
        """The subject's ``positions (25, 3)`` world, ``variance_m2 (25,)`` and ``status (25,)``
        at ``T``; every person's in :attr:`people`."""
        subject = self.subject  # (the operator may change it meanwhile, on the loop)
        people = {}
        for person in sorted(set(self._lives) | set(self._paper_windows) | {subject}):
            if self.method == "best-live":
                fr = self._person_live(person).fuse(t_server_s)
                people[person] = (fr.positions, fr.variance_m2, fr.status)
            else:
                people[person] = self._fuse_paper(t_server_s, person)
        self.people = people
        return people[subject]

    def _fuse_paper(self, t: float, person: int = 0) -> tuple[Array, Array, NDArray[np.int8]]:
        from kinefuse.capture.fusion.trilateration import trilaterate

        n_s = len(self.ids)
        joints = np.full((1, n_s, N_JOINTS, 3), np.nan)
        states = np.zeros((1, n_s, N_JOINTS), dtype=np.int8)
        occ = np.zeros((1, n_s, N_JOINTS), dtype=bool)
        n_int = np.zeros((1, n_s), dtype=np.int64)
        for i, sid in enumerate(self.ids):
            best = None
            for o in self._paper_windows.get(person, {}).get(sid, ()):
                if t - 1.0 / 30.0 < o.t_capture_server_s <= t:
                    best = o
            if best is not None:
                joints[0, i], states[0, i] = best.joints_m, best.states
                if best.occluded is not None:
                    occ[0, i] = best.occluded
                n_int[0, i] = best.n_crossings or 0
        if not (states > 0).any():
            nan = np.full((N_JOINTS, 3), np.nan)
            return nan, np.full(N_JOINTS, np.nan), np.full(N_JOINTS, FusionStatus.NO_DATA, np.int8)
        res = trilaterate(joints, self._poses, "paper", states=states, occlusion=(occ, n_int))
        return res.positions[0], np.full(N_JOINTS, np.nan), np.asarray(res.status[0], np.int8)

    def raw_world(self) -> dict[str, Array]:
        """Each calibrated sensor's latest skeleton in the world (for the viewer)."""
        out = {}
        for sid, o in self._latest.items():
            p = self._pose(sid)
            out[sid] = o.joints_m @ p[:3, :3].T + p[:3, 3]
        return out


class FusionLoop:
    """Drains the clients' queues and fuses/publishes at ``rate_hz`` (see the module docstring).

    Threads: the table of sensors, their queues and this loop's buffers are read and changed on
    the event loop only. A worker thread (a slow frame's ``fuse``, the warm-up's batches) gets
    the fusion and, for the warm-up, a batch of observations taken on the loop; nothing on the
    loop touches the fusion meanwhile (new poses wait in :meth:`set_poses` for the next frame).

    Parameters
    ----------
    fusion : FrameFusion
        Owned by this loop once it runs: change its poses through :meth:`set_poses`.
    clients : mapping sensor id -> SensorState
        The server's (live) table of sensors (changes on the loop when a sensor joins).
    publisher : Publisher
    clock : callable
        The server clock, seconds.
    wait_s : float
        The latency budget: extra wait for late observations, seconds.
    """

    def __init__(
        self,
        fusion: FrameFusion,
        clients: Mapping[str, SensorState],
        publisher: Publisher,
        clock: Callable[[], float],
        *,
        wait_s: float = 0.010,
        rate_hz: float = 30.0,
        stall_s: float = 0.2,
    ) -> None:
        if not (math.isfinite(wait_s) and wait_s >= 0):
            raise ValueError(f"the latency budget must be >= 0 s, got {wait_s}")
        self.fusion = fusion
        self.clients = clients
        self.publisher = publisher
        self.clock = clock
        self.wait_s = float(wait_s)
        self.rate_hz = float(rate_hz)
        self.stall_s = float(stall_s)
        self._latest_cap: dict[str, float] = {}
        self._wake = asyncio.Event()
        self._pending: dict[str, deque[Observation]] = {}
        # capture time (server clock) and host receive time of the newest observation pushed
        self._newest: tuple[float, float] = (-math.inf, math.nan)
        self.frames = 0
        self.skipped = 0
        self.fuse_seconds = 0.0
        #: mean fusion CPU time per frame above which the fusion runs in a worker thread, s
        self.thread_above_s = 0.002
        #: how far back the first calibration's fusion starts from the buffered observations, s
        self.warm_up_s = 1.0
        self._costs: deque[float] = deque(maxlen=30)
        self._was_threaded = False
        self._new_poses: dict[str, Array] | None = None
        self._published: deque[float] = deque(maxlen=31)

    @property
    def delay_s(self) -> float:
        """How long after its frame time a frame is fused at the latest, seconds."""
        return self.fusion.lead_s + NOMINAL_LATENCY_S + self.wait_s

    def fps(self) -> float:
        p = self._published
        if len(p) < 2 or p[-1] <= p[0]:
            return 0.0
        return (len(p) - 1) / (p[-1] - p[0])

    def _collect(self) -> None:
        for sid, c in self.clients.items():
            obs = c.drain()
            if not obs:
                continue
            q = self._pending.setdefault(sid, deque(maxlen=64))
            for o in obs:
                if math.isfinite(o.t_capture_server_s):
                    q.append(o)
                    if o.t_capture_server_s > self._latest_cap.get(sid, -math.inf):
                        self._latest_cap[sid] = o.t_capture_server_s

    def notify(self) -> None:
        """An observation was queued: check whether the next frame can be fused."""
        self._wake.set()

    def ready(self, k: int) -> bool:
        """Whether every delivering sensor has sent an observation captured after frame ``k``."""
        if not self.fusion.ready:
            return False
        t = k / self.rate_hz
        some = False
        for sid in self.fusion.ids:
            c = self.clients.get(sid)
            last = self._latest_cap.get(sid, -math.inf)
            if c is None or not c.connected or last < t - self.stall_s:
                continue  # not delivering: not waited for
            if last <= t:
                return False
            some = True
        return some

    def set_poses(self, poses: Mapping[str, Array]) -> None:
        """New poses, applied before the next frame (not while one is being fused)."""
        self._new_poses = dict(poses)

    @property
    def threaded(self) -> bool:
        """Whether the fusion currently runs in a worker thread (see the module docstring)."""
        c = self._costs
        return len(c) >= 10 and sum(c) / len(c) > self.thread_above_s

    def _take_upto(self, horizon: float) -> dict[str, list[Observation]]:
        """Take the calibrated sensors' buffered observations captured up to ``horizon``, each
        sensor's in capture order; a sensor without a pose keeps its own (the last ``64``) for
        later. On the loop: it reads the buffers :meth:`_collect` fills."""
        out: dict[str, list[Observation]] = {}
        for sid, q in self._pending.items():
            if sid not in self.fusion.ids:
                continue
            ready = sorted(
                (o for o in q if o.t_capture_server_s <= horizon),
                key=lambda o: o.t_capture_server_s,
            )
            if not ready:
                continue
            rest = [o for o in q if o.t_capture_server_s > horizon]
            q.clear()
            q.extend(rest)
            out[sid] = ready
            for o in ready:
                if o.t_capture_server_s > self._newest[0]:
                    self._newest = (o.t_capture_server_s, o.t_host_server_s)
        return out

    def _push_upto(self, horizon: float) -> None:
        """Push the observations :meth:`_take_upto` takes into the fusion."""
        for sid, obs in self._take_upto(horizon).items():
            for o in obs:
                self.fusion.push(sid, o)

    async def _warm_up(self, k: int) -> int:
        """Fuse, without publishing, the frames from at most ``warm_up_s`` before ``k`` that the
        buffered observations cover, and on until the present: a filter that starts mid-motion
        (the first calibration just finished) gets its state, bone lengths and facing from
        them, and publishing then starts on time. Returns the next frame to publish.

        The frames are fused in a worker thread, a batch at a time; between batches the loop
        collects what arrived meanwhile. The worker gets the batch's observations, taken on the
        loop, and touches nothing but them and the fusion (which nothing on the loop touches
        while this task waits for it): the server's table of sensors and their queues change
        on the loop at any time (a sensor joins) and are read on the loop only."""
        self._collect()
        caps = [o.t_capture_server_s for q in self._pending.values() for o in q]
        kk = k
        if caps:
            kk = max(k - round(self.warm_up_s * self.rate_hz), math.ceil(min(caps) * self.rate_hz))
        n = 0
        while True:
            self._collect()
            due = math.floor((self.clock() - self.delay_s) * self.rate_hz)
            end = max(due, k)
            if kk >= end:
                break
            batch = self._take_upto((end - 1) / self.rate_hz + self.fusion.lead_s)
            await asyncio.to_thread(self._fuse_frames, batch, kk, end)
            n += end - kk
            kk = end
        log.info("fusion starts at frame %d after %d frames of warm-up", kk, n)
        return kk

    def _fuse_frames(self, batch: Mapping[str, list[Observation]], k0: int, k1: int) -> None:
        """Frames ``k0 .. k1 - 1``, each after pushing the batch's observations up to its
        horizon (in a worker thread: only ``batch`` and the fusion are touched)."""
        at = dict.fromkeys(batch, 0)
        for kk in range(k0, k1):
            horizon = kk / self.rate_hz + self.fusion.lead_s
            for sid, obs in batch.items():
                i = at[sid]
                while i < len(obs) and obs[i].t_capture_server_s <= horizon:
                    self.fusion.push(sid, obs[i])
                    i += 1
                at[sid] = i
            self.fusion.fuse(kk / self.rate_hz)

    def _fuse_timed(self, t: float) -> tuple[tuple[Array, Array, NDArray[np.int8]], float]:
        """The frame at ``t`` and the CPU time its fusion took in the thread that ran it: not
        the wall time, which on a busy machine counts the waits for a core and, in a worker
        thread, for the interpreter lock that the loop holds while it reads frames. Judged by
        wall time, a loaded server sent a 1 ms fusion to a thread, where handing it over and
        the lock made it take 12 ms (16 sensors, issue 23)."""
        c0 = time.thread_time()
        out = self.fusion.fuse(t)
        return out, time.thread_time() - c0

    async def step(self, k: int) -> FusedFrame | None:
        """Fuse and publish frame ``k`` now (None when no sensor is calibrated yet)."""
        t = k / self.rate_hz
        self._collect()
        if self._new_poses is not None:
            self.fusion.set_poses(self._new_poses)
            self._new_poses = None
        self._push_upto(t + self.fusion.lead_s)
        if not self.fusion.ready:
            return None
        threaded = self.threaded
        if threaded != self._was_threaded:
            log.info(
                "fusion takes %.1f ms per frame: running it %s",
                1e3 * sum(self._costs) / len(self._costs),
                "in a worker thread" if threaded else "on the event loop",
            )
            self._was_threaded = threaded
        if threaded:
            (pos, var, status), cost = await asyncio.to_thread(self._fuse_timed, t)
        else:
            (pos, var, status), cost = self._fuse_timed(t)
        self._costs.append(cost)
        self.fuse_seconds += cost
        t_pub = self.clock()
        # the newest observation is used if the fusion can still take it for this frame (held
        # up to max_hold_s, or in the paper's window); else the frame is a prediction: no latency
        cap, host = self._newest
        used = cap >= t - max(self.fusion.options.max_hold_s, 1.0 / self.rate_hz)
        latency = t_pub - host if used and math.isfinite(host) else math.nan
        frame = FusedFrame(
            seq=k,
            t_server_s=t,
            positions_m=pos,
            variance_m2=var,
            status=status,
            latency_s=latency,
            raw_m=self.fusion.raw_world(),
            subject=self.fusion.subject,
            people_m={p: f[0] for p, f in self.fusion.people.items()},
            people_status={p: f[2] for p, f in self.fusion.people.items()},
        )
        self.publisher.publish(frame)
        self.frames += 1
        self._published.append(t_pub)
        return frame

    async def run(self, stop: asyncio.Event) -> None:
        """Fuse frames until ``stop`` is set; a loop that fell behind skips to the present."""
        k = math.ceil((self.clock() - self.delay_s) * self.rate_hz)
        while not stop.is_set():
            if self._new_poses is not None and not self.fusion.ready:
                # the first calibration: warm up off the loop, then publish from the present on
                self._collect()
                self.fusion.set_poses(self._new_poses)
                self._new_poses = None
                k = await self._warm_up(k)
            due = k / self.rate_hz + self.delay_s
            now = self.clock()
            if now < due:
                self._collect()
                if not self.ready(k):
                    self._wake.clear()
                    # (asyncio.timeout, not wait_for: no task per wake, and it wakes on
                    # every observation: 720 a second with 24 sensors)
                    with contextlib.suppress(TimeoutError):
                        async with asyncio.timeout(due - now):
                            await self._wake.wait()
                    continue
            else:
                behind = int((now - due) * self.rate_hz)
                if behind > 3:
                    self.skipped += behind
                    log.warning("fusion fell %d frames behind; skipping to the present", behind)
                    k += behind
            await self.step(k)
            k += 1
            await asyncio.sleep(0)

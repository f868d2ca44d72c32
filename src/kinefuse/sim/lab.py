"""The simulated capture lab: real motion watched by virtual Kinect v2 sensors.

A session's timeline, on the true (server) clock::

    [0, calibration_s)                      the actor waves the wand; sensors record depth frames
    [calibration_s, calibration_s + motion)  the actor performs the clip; sensors report bodies

Everything a real session would record goes to the store's ordinary tables (sensors and their
factory intrinsics, depth frames, body observations, clock probes); what only the simulator knows
(true poses, clocks, joint positions, visibility, swaps, the wand's path) goes to the ``truth_*``
tables that only evaluation code reads.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from kinefuse import __version__
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.camera.wand import Wand
from kinefuse.core.frames.motion import Motion
from kinefuse.core.frames.observations import BodyFrame, BodyFrames
from kinefuse.core.geometry.transforms import apply_transform, invert_transform
from kinefuse.core.outputs import atomic_file
from kinefuse.core.skeleton import JOINT_INDEX, N_JOINTS, capsule_radii
from kinefuse.errors import InputError, StoreError
from kinefuse.formats.store.session_store import SessionStore, is_simulated_session
from kinefuse.sim.choreography import WandPath, WandProtocol, holding_poses, make_wand_path
from kinefuse.sim.clock import (
    CaptureTimes,
    ClockParams,
    capture_times,
    clock_probes,
    draw_sensor_clocks,
)
from kinefuse.sim.depth import DepthNoiseParams, Scene, render_depth
from kinefuse.sim.people import tracking_ids
from kinefuse.sim.rig import Rig
from kinefuse.sim.tracker import (
    SubjectBias,
    TrackerOutput,
    TrackerParams,
    draw_subject_bias,
    simulate_tracker,
)

Array = NDArray[np.float64]


@dataclass(frozen=True)
class IntrinsicsParams:
    """Unit-to-unit variation of the Kinect v2 depth camera's factory intrinsics."""

    focal_sigma_rel: float = field(
        default=0.01,
        metadata={
            "unit": "1",
            "source": "about 1 % spread of fx, fy between units (published per-unit Kinect v2 "
            "depth intrinsics cluster around 365 px, e.g. 361-368 px)",
        },
    )
    principal_sigma_px: float = field(
        default=2.5,
        metadata={"unit": "px", "source": "about 1 % of the image width/height between units"},
    )


@dataclass(frozen=True)
class ErrorModel:
    """Every parameter of the simulated sensors, grouped by subsystem, each with its source."""

    tracker: TrackerParams = field(default_factory=TrackerParams)
    depth: DepthNoiseParams = field(default_factory=DepthNoiseParams)
    clock: ClockParams = field(default_factory=ClockParams)
    intrinsics: IntrinsicsParams = field(default_factory=IntrinsicsParams)


@dataclass(frozen=True)
class LabConfig:
    """What to simulate. Times in seconds."""

    seed: int = 0
    calibration_s: float = 20.0
    # the subject's own joint offsets (``SubjectBias.offsets_body_m``, the tracker's joint
    # definitions on this body) are drawn from this seed when given, so that several sessions
    # of one subject share them; None: from ``seed`` (every session a new subject)
    subject_seed: int | None = None
    depth_rate_hz: float = 10.0
    motion_s: float | None = None  # None: the whole clip
    wand: Wand = field(default_factory=Wand)
    protocol: WandProtocol = field(default_factory=WandProtocol)
    errors: ErrorModel = field(default_factory=ErrorModel)


def subject_height(motion: Motion) -> float:
    """Standing height estimate, metres: the head's height above the lowest foot, plus the crown."""
    p = motion.positions
    head = p[:, JOINT_INDEX["Head"], 2]
    feet = np.minimum(p[:, JOINT_INDEX["FootLeft"], 2], p[:, JOINT_INDEX["FootRight"], 2])
    h = float(np.median(head - feet)) + 0.10
    return float(np.clip(h, 0.6, 2.4))


def draw_intrinsics(rng: np.random.Generator, params: IntrinsicsParams) -> Intrinsics:
    base = Intrinsics()
    f = base.fx * (1 + rng.normal(0, params.focal_sigma_rel, 2))
    c = np.array([base.cx, base.cy]) + rng.normal(0, params.principal_sigma_px, 2)
    return replace(base, fx=float(f[0]), fy=float(f[1]), cx=float(c[0]), cy=float(c[1]))


def _to_plain(obj: object) -> object:
    if isinstance(obj, dict):
        return {k: _to_plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_to_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def _check_config(motion: Motion, config: LabConfig) -> float:
    """Refuse an impossible configuration; returns the motion phase's length, seconds."""
    if config.calibration_s < 0:
        raise InputError(f"calibration phase must be >= 0 s, got {config.calibration_s}")
    if config.depth_rate_hz <= 0 or config.depth_rate_hz > config.errors.clock.frame_rate_hz:
        raise InputError(
            f"depth rate must be in (0, {config.errors.clock.frame_rate_hz}] Hz, "
            f"got {config.depth_rate_hz}"
        )
    motion_s = motion.duration_s if config.motion_s is None else float(config.motion_s)
    if not 0 < motion_s <= motion.duration_s + 1e-9:
        raise InputError(
            f"motion length must be in (0, {motion.duration_s:.2f}] s (the clip's length), "
            f"got {motion_s}"
        )
    return motion_s


@dataclass(frozen=True, eq=False)
class _Seeds:
    """The session-wide draws: the subject's bias, the wand's path, one seed per sensor."""

    subject: SubjectBias
    wand_track: WandPath
    sensors: tuple[np.random.SeedSequence, ...]


def _seeds(seed: int, n_sensors: int, config: LabConfig) -> _Seeds:
    root = np.random.SeedSequence(seed)
    seq_subject, seq_wand, *seq_sensors = root.spawn(2 + n_sensors)
    subject = draw_subject_bias(np.random.default_rng(seq_subject), config.errors.tracker)
    if config.subject_seed is not None:
        # the same person in another session: own joint offsets and tracking quality (how well
        # this body is tracked), this session's latents
        own = draw_subject_bias(
            np.random.default_rng(np.random.SeedSequence([int(config.subject_seed), 1])),
            config.errors.tracker,
        )
        subject = replace(subject, offsets_body_m=own.offsets_body_m, quality=own.quality)
    wand = make_wand_path(
        float(config.calibration_s), np.random.default_rng(seq_wand), config.protocol
    )
    return _Seeds(subject, wand, tuple(seq_sensors))


@dataclass(frozen=True, eq=False)
class BodyDepthFrame:
    """One depth frame of the motion phase with the truth it shows.

    Attributes
    ----------
    seq : int
    t_device_s, t_host_s : float
        Device timestamp and arrival on the client PC's clock, seconds.
    t_true_s, t_receive_server_s : float
        True (server) time of the capture, and when a body found in it would reach the server.
    depth_mm : (H, W) uint16
        The sensor's depth image (0: no reading).
    joints_world_m, joints_sensor_m : (25, 3) float
        The true joints in the world frame and in the depth camera's frame, metres.
    """

    seq: int
    t_device_s: float
    t_host_s: float
    t_true_s: float
    t_receive_server_s: float
    depth_mm: NDArray[np.uint16]
    joints_world_m: Array
    joints_sensor_m: Array


class SensorSimulation:
    """One simulated sensor of a session, frame by frame: what :func:`simulate_session` writes
    for it, and what a live simulated sensor
    (:class:`kinefuse.pipeline.frame_sources.SimulatedSensorSource`) delivers. The same ``motion``,
    ``rig``, sensor and ``config`` give the same numbers either
    way (the random streams are the session's: seeded by ``config.seed`` and the sensor's place
    in the rig, consumed in the same order).

    Parameters
    ----------
    motion : Motion
        Already placed in the lab.
    rig : Rig
    sensor_id : str
        One of the rig's sensors.
    config : LabConfig
    bystanders : sequence of Motion
        Other people in the room during the motion phase (already placed,
        :func:`kinefuse.sim.people.place_bystander`), persons 1, 2, ...; their own random
        streams, so the subject's alone are what they were.
    """

    def __init__(
        self,
        motion: Motion,
        rig: Rig,
        sensor_id: str,
        config: LabConfig,
        bystanders: Sequence[Motion] = (),
    ) -> None:
        ids = [s.id for s in rig.sensors]
        if sensor_id not in ids:
            raise InputError(f"the rig has no sensor {sensor_id!r}; its sensors: {', '.join(ids)}")
        motion_s = _check_config(motion, config)
        index = ids.index(sensor_id)
        self.spec = rig.sensors[index]
        self.motion, self.rig, self.config = motion, rig, config
        self.t_cal_s = float(config.calibration_s)
        self.t_end_s = self.t_cal_s + motion_s
        self.height_m = subject_height(motion)
        seeds = _seeds(config.seed, len(ids), config)
        self._subject, self._wand_track = seeds.subject, seeds.wand_track
        errs = config.errors
        rng_clock, rng_intr, self._rng_track, self._rng_depth, rng_probe = (
            np.random.default_rng(s) for s in seeds.sensors[index].spawn(5)
        )
        # a sixth stream, spawned after the others so that they are what they always were
        self._seed_body_depth = seeds.sensors[index].spawn(1)[0]
        # the bystanders' streams come after those (none drawn without bystanders)
        self.bystanders = tuple(bystanders)
        self._index = index
        if self.bystanders:
            self._seed_people = seeds.sensors[index].spawn(1)[0]
        # the device clock stamps frames; the client PC's clock answers the probes
        self.clocks = draw_sensor_clocks(rng_clock, errs.clock)
        self.intrinsics = draw_intrinsics(rng_intr, errs.intrinsics)
        #: (N, 4) the client's clock probes over the session (server t1, client t2, t3, server t4)
        self.probes = clock_probes(self.clocks.host, 0.0, self.t_end_s, rng_probe, errs.clock)

    def depth_frames(self) -> Iterator[tuple[int, float, float, NDArray[np.uint16]]]:
        """The calibration phase's depth frames, rendered one at a time as they are asked for:
        ``(seq, t_device_s, t_host_s, depth_mm (H, W) uint16)``. Call once (it consumes the
        sensor's depth noise stream)."""
        if self.t_cal_s <= 0:
            return
        errs, cfg, intr = self.config.errors, self.config, self.intrinsics
        cap = capture_times(self.clocks.device, 0.0, self.t_cal_s, self._rng_depth, errs.clock,
                            host=self.clocks.host,
                            latency_offset_s=self.clocks.latency_offset_s)  # fmt: skip
        step = max(round(errs.clock.frame_rate_hz / cfg.depth_rate_hz), 1)
        pick = np.flatnonzero((cap.seq % step) == 0)
        t_true = cap.t_true_s[pick]
        centres = self._wand_track.at(t_true)
        # the operator sees where the sensors stand and keeps out of their way
        sensor_positions = np.array([s.sensor2world[:3, 3] for s in self.rig.sensors])
        poses, handles = holding_poses(centres, self.motion.positions[0], cfg.wand,
                                       sensor_positions=sensor_positions,
                                       height_m=self.height_m)  # fmt: skip
        for i, k in enumerate(pick.tolist()):
            scene = Scene.from_pose(poses[i], self.height_m, wand=cfg.wand,
                                    wand_centre=centres[i], wand_handle_dir=handles[i],
                                    room_min_xy_m=self.rig.room_min_xy_m,
                                    room_max_xy_m=self.rig.room_max_xy_m)  # fmt: skip
            frame = render_depth(scene, self.spec.sensor2world, intr, self._rng_depth, errs.depth)
            yield (int(cap.seq[k]), float(cap.t_sensor_s[k]), float(cap.t_receive_host_s[k]),
                   frame)  # fmt: skip

    def body_depth_frames(self, *, every: int = 1, noise: bool = True) -> Iterator[BodyDepthFrame]:
        """The motion phase as a depth camera sees it: the actor's capsule body rendered in the
        room, frame by frame, with the true joints (what a body tracker working on depth is
        scored against). Its own random stream: the session's other outputs do not change.

        Parameters
        ----------
        every : int
            Render every ``every``-th capture (1: all, at the sensor's frame rate).
        noise : bool
            The depth error model (:func:`kinefuse.sim.depth.render_depth`); False: exact.
        """
        if every < 1:
            raise InputError(f"every must be a whole number >= 1, got {every}")
        errs = self.config.errors
        rng = np.random.default_rng(self._seed_body_depth)
        cap = capture_times(self.clocks.device, self.t_cal_s, self.t_end_s, rng, errs.clock,
                            host=self.clocks.host,
                            latency_offset_s=self.clocks.latency_offset_s)  # fmt: skip
        world2sensor = invert_transform(self.spec.sensor2world)
        for k in range(0, cap.seq.size, every):
            truth = self.motion.at(np.array([cap.t_true_s[k] - self.t_cal_s]))[0]
            scene = Scene.from_pose(truth, self.height_m, room_min_xy_m=self.rig.room_min_xy_m,
                                    room_max_xy_m=self.rig.room_max_xy_m)  # fmt: skip
            for other in self.bystanders:  # the other people's capsule bodies, in the room
                pose = other.at(np.array([cap.t_true_s[k] - self.t_cal_s]))[0]
                body = Scene.from_pose(pose, subject_height(other), walls=False, floor=False)
                scene = replace(scene, a=np.concatenate([scene.a, body.a]),
                                b=np.concatenate([scene.b, body.b]),
                                radius=np.concatenate([scene.radius, body.radius]))  # fmt: skip
            depth = render_depth(scene, self.spec.sensor2world, self.intrinsics, rng, errs.depth,
                                 noise=noise)  # fmt: skip
            yield BodyDepthFrame(int(cap.seq[k]), float(cap.t_sensor_s[k]),
                                 float(cap.t_receive_host_s[k]), float(cap.t_true_s[k]),
                                 float(cap.t_receive_server_s[k]), depth, truth,
                                 apply_transform(world2sensor, truth))  # fmt: skip

    def body(self) -> tuple[CaptureTimes, TrackerOutput, Array]:
        """The motion phase: capture times, the body tracker's output, and the true joints at
        the capture instants ``(N, 25, 3)`` world. The tracker's error processes are smooth
        over the whole take (correlated noise, dropouts, held guesses), so the phase is drawn
        at once; call once (it consumes the sensor's tracker stream)."""
        errs = self.config.errors
        cap = capture_times(self.clocks.device, self.t_cal_s, self.t_end_s, self._rng_track,
                            errs.clock, host=self.clocks.host,
                            latency_offset_s=self.clocks.latency_offset_s)  # fmt: skip
        truth_world = self.motion.at(cap.t_true_s - self.t_cal_s)
        out = simulate_tracker(truth_world, self.spec.sensor2world, self.intrinsics,
                               capsule_radii(self.height_m), self._rng_track, errs.tracker,
                               dt_s=1.0 / errs.clock.frame_rate_hz, subject=self._subject,
                               t_s=cap.t_true_s)  # fmt: skip
        return cap, out, truth_world

    def people(self) -> tuple[CaptureTimes, list[TrackerOutput], list[Array]]:
        """The motion phase with every person in the room: capture times, the tracker's output
        for each person (0: the subject, then the bystanders) with the others hiding them, and
        each person's true joints ``(N, 25, 3)`` world. Without bystanders the subject's output
        is :meth:`body`'s. Call once (it consumes the sensor's tracker streams)."""
        errs = self.config.errors
        cap = capture_times(self.clocks.device, self.t_cal_s, self.t_end_s, self._rng_track,
                            errs.clock, host=self.clocks.host,
                            latency_offset_s=self.clocks.latency_offset_s)  # fmt: skip
        actors = (self.motion, *self.bystanders)
        truths = [m.at(cap.t_true_s - self.t_cal_s) for m in actors]
        radii = [capsule_radii(subject_height(m)) for m in actors]
        rngs = [self._rng_track]
        biases = [self._subject]
        if self.bystanders:
            streams = self._seed_people.spawn(len(self.bystanders))
            rngs += [np.random.default_rng(q) for q in streams]
            biases += [bystander_bias(self.config, i + 1) for i in range(len(self.bystanders))]
        outs = []
        for k, truth in enumerate(truths):
            others = [(truths[i], radii[i]) for i in range(len(actors)) if i != k]
            outs.append(simulate_tracker(truth, self.spec.sensor2world, self.intrinsics,
                                         radii[k], rngs[k], errs.tracker,
                                         dt_s=1.0 / errs.clock.frame_rate_hz, subject=biases[k],
                                         t_s=cap.t_true_s, others=others))  # fmt: skip
        return cap, outs, truths

    def all_bodies(
        self,
    ) -> tuple[CaptureTimes, BodyFrames, NDArray[np.int64], list[TrackerOutput], list[Array]]:
        """:meth:`people` as the sensor reports it: capture times, the all-bodies stream (each
        tracked body with its tracking id, in the sensor's listing order; an instant with no
        body one row with nothing tracked, id 0), the person each row truly is (-1: none), and
        :meth:`people`'s outputs and true joints per person. Call once."""
        cap, outs, truths = self.people()
        tracked = np.stack([~o.dropout for o in outs], axis=1)
        rng = np.random.default_rng(self._seed_people.spawn(1)[0]) if self.bystanders else None
        ids, slot = tracking_ids(tracked, self._index, rng or np.random.default_rng(0))
        rows: list[tuple[int, int]] = []  # (frame, person or -1)
        for t in range(tracked.shape[0]):
            order = [int(p) for p in np.argsort(slot[t], kind="stable") if slot[t, p] >= 0]
            rows += [(t, p) for p in order] if order else [(t, -1)]
        frame = np.array([r[0] for r in rows], dtype=np.intp)
        person = np.array([r[1] for r in rows], dtype=np.int64)
        joints = np.full((len(rows), N_JOINTS, 3), np.nan)
        states = np.zeros((len(rows), N_JOINTS), dtype=np.int8)
        for p, o in enumerate(outs):
            sel = person == p
            joints[sel], states[sel] = o.joints_sensor[frame[sel]], o.states[frame[sel]]
        body_id = np.where(person >= 0, ids[frame, np.maximum(person, 0)], 0)
        frames = BodyFrames(sensor_id=self.spec.id, seq=cap.seq[frame],
                            t_device_s=cap.t_sensor_s[frame], t_host_s=cap.t_receive_host_s[frame],
                            joints_m=joints, states=states,
                            t_receive_server_s=cap.t_receive_server_s[frame],
                            body_id=body_id)  # fmt: skip
        return cap, frames, person, outs, truths

    def body_frames(self) -> Iterator[BodyFrame]:
        """The motion phase as a live sensor delivers it: one :class:`BodyFrame` per capture,
        the first-listed body with the others in ``others`` (:meth:`all_bodies`; without
        bystanders, :meth:`body`'s frames, id 0). Call once."""
        if not self.bystanders:
            cap, out, _ = self.body()
            for k in range(cap.seq.size):
                yield BodyFrame(self.spec.id, int(cap.seq[k]), float(cap.t_sensor_s[k]),
                                float(cap.t_receive_host_s[k]), out.joints_sensor[k],
                                out.states[k])  # fmt: skip
            return
        _, frames, _, _, _ = self.all_bodies()
        starts = np.flatnonzero(np.r_[True, frames.seq[1:] != frames.seq[:-1]])
        ends = np.r_[starts[1:], frames.n_frames]
        for a, b in zip(starts.tolist(), ends.tolist(), strict=True):
            first = frames.frame(a)
            yield replace(first, others=tuple(frames.frame(k) for k in range(a + 1, b)))


def bystander_bias(config: LabConfig, person: int) -> SubjectBias:
    """The tracker's person-level draws for bystander ``person`` (>= 1): the same for every
    sensor of the session, from a stream of their own."""
    rng = np.random.default_rng(np.random.SeedSequence([int(config.seed), 46, int(person)]))
    return draw_subject_bias(rng, config.errors.tracker)


#: makes one sensor's body observations (:func:`simulate_session`'s ``observe``)
Observe = Callable[["SensorSimulation"], tuple[CaptureTimes, TrackerOutput, Array]]


def simulate_session(
    motion: Motion,
    rig: Rig,
    out: str | Path,
    config: LabConfig = LabConfig(),
    *,
    overwrite: bool = False,
    progress: Callable[[str], None] | None = None,
    observe: Observe | None = None,
    bystanders: Sequence[Motion] = (),
) -> Path:
    """Simulate a capture session of ``motion`` (already placed in the lab) seen by ``rig``.

    ``observe(sensor)`` makes each sensor's body observations of the motion phase: capture
    times, what the tracker reported, the true joints (world) at those times. Default: the
    simulated Kinect tracker (:meth:`SensorSimulation.body`); another tracker working on the
    sensor's body depth (:meth:`SensorSimulation.body_depth_frames`) is scored this way.

    Writes one SQLite session store at ``out`` and returns its path. The store is built in a
    temporary file beside ``out`` and renamed into place only when it is whole
    (:func:`kinefuse.core.outputs.atomic_file`). An existing file is only replaced with
    ``overwrite=True``, and then only when it is a simulated kinefuse session
    (:func:`kinefuse.formats.store.session_store.is_simulated_session`): never a recording without
    ground truth (a live session cannot be simulated again), nor any other file.
    Deterministic: the same inputs and ``config.seed`` give the same observation rows.

    ``bystanders`` (already placed, :func:`kinefuse.sim.people.place_bystander`) are persons
    1, 2, ... in the room during the motion phase: every sensor reports every body it tracks
    (:meth:`SensorSimulation.all_bodies`), and the truth says who is who. Without them the
    session is what it always was.
    """
    say = progress or (lambda _msg: None)
    motion_s = _check_config(motion, config)
    if bystanders and observe is not None:
        raise InputError("bystanders need the simulated Kinect tracker; leave observe out")
    t_cal = float(config.calibration_s)

    if Path(out).exists():
        if not overwrite:
            raise InputError(
                f"{out} already exists; choose another --out, or pass --force to replace it"
            )
        try:
            with SessionStore.open(out) as old:
                live = not old.has_truth()
        except StoreError:
            live = False  # not a session store: nothing recorded to protect
        if live:
            raise InputError(
                f"{out} is a recording without ground truth (a live session); kinefuse will not "
                "overwrite it with a simulation: choose another --out"
            )
    with atomic_file(
        out, what="session", recognizer=is_simulated_session, suffix=".partial.sqlite"
    ) as tmp:
        tmp.unlink()  # the store creates its own file
        _simulate_into(SessionStore.create(tmp), motion, rig, config, t_cal, motion_s, say,
                       observe or SensorSimulation.body, tuple(bystanders))  # fmt: skip
    return Path(out)


def _simulate_into(
    store: SessionStore,
    motion: Motion,
    rig: Rig,
    config: LabConfig,
    t_cal: float,
    motion_s: float,
    say: Callable[[str], None],
    observe: Observe,
    bystanders: tuple[Motion, ...] = (),
) -> None:
    """Fill a new session store with the simulation (:func:`simulate_session`); closes it."""
    t_end = t_cal + motion_s
    height = subject_height(motion)
    errs = config.errors
    try:
        store.set_meta("generator", f"kinefuse {__version__} simulate")
        store.set_meta("clip", motion.source)
        # what only the simulator knows goes with the truth, where only evaluation reads it
        store.write_truth_info("seed", int(config.seed))
        if config.subject_seed is not None:
            store.write_truth_info("subject_seed", int(config.subject_seed))
        store.write_truth_info("rig", rig.description)
        store.write_truth_info("subject_height_m", height)
        store.set_meta("calibration_phase_server_s", [0.0, t_cal])
        store.set_meta("motion_phase_server_s", [t_cal, t_end])
        store.set_meta("wand", asdict(config.wand))
        store.set_meta("wand_protocol", config.protocol.to_dict())
        store.write_truth_info("error_model", _to_plain(asdict(errs)))

        t_truth = np.arange(0.0, motion_s + 1e-9, 1.0 / motion.rate_hz)
        store.write_truth_motion(t_cal + t_truth, motion.at(t_truth), motion.synthesized)
        if bystanders:
            store.write_truth_info(
                "people",
                [{"person": 0, "role": "subject", "clip": motion.source}]
                + [{"person": i + 1, "role": "bystander", "clip": b.source,
                    "height_m": subject_height(b)} for i, b in enumerate(bystanders)],
            )  # fmt: skip
            for i, b in enumerate(bystanders):
                t_b = np.arange(0.0, motion_s + 1e-9, 1.0 / b.rate_hz)
                store.write_truth_person(i + 1, t_cal + t_b, b.at(t_b))

        # the calibration phase's wand path, on a fine grid (truth)
        wand_track = _seeds(config.seed, len(rig.sensors), config).wand_track
        if t_cal > 0:
            t_w = np.arange(0.0, t_cal, 1.0 / 120.0)
            store.append_truth_wand(t_w, wand_track.at(t_w))

        for spec in rig.sensors:
            sim = SensorSimulation(motion, rig, spec.id, config, bystanders)
            store.add_sensor(spec.id, spec.serial, sim.intrinsics, rate_hz=errs.clock.frame_rate_hz)
            store.write_truth_sensor(spec.id, spec.sensor2world, sim.clocks.to_dict())
            store.append_clock_probes(spec.id, *sim.probes.T)
            if t_cal > 0:
                say(f"{spec.id}: rendering calibration depth frames")
                depth = list(sim.depth_frames())
                if depth:
                    store.append_depth_frames(
                        spec.id,
                        np.array([d[0] for d in depth], dtype=np.int64),
                        np.array([d[1] for d in depth]),
                        np.stack([d[3] for d in depth]),
                    )
            say(f"{spec.id}: simulating the body tracker")
            if bystanders:
                _append_people(store, sim)
                continue
            cap, out_, truth_world = observe(sim)
            store.append_observations(
                spec.id,
                cap.seq,
                cap.t_sensor_s,
                out_.joints_sensor,
                out_.states,
                t_receive_server_s=cap.t_receive_server_s,
                t_receive_host_s=cap.t_receive_host_s,
            )
            truth_sensor = apply_transform(invert_transform(spec.sensor2world), truth_world)
            store.append_truth_observations(
                spec.id, cap.seq, cap.t_true_s, truth_sensor, out_.visible, out_.swapped
            )
    finally:
        store.close()


def _append_people(store: SessionStore, sim: SensorSimulation) -> None:
    """One sensor's every body, and who each truly is, into ``store`` (a session with
    bystanders); the subject's truth per frame as in a one-person session."""
    cap, frames, person, outs, truths = sim.all_bodies()
    store.append_observations(
        frames.sensor_id, frames.seq, frames.t_device_s, frames.joints_m, frames.states,
        t_receive_server_s=frames.t_receive_server_s, t_receive_host_s=frames.t_host_s,
        body_id=frames.body_id,
    )  # fmt: skip
    store.append_truth_bodies(sim.spec.id, frames.seq, frames.body_id, person)
    subject = apply_transform(invert_transform(sim.spec.sensor2world), truths[0])
    store.append_truth_observations(
        sim.spec.id, cap.seq, cap.t_true_s, subject, outs[0].visible, outs[0].swapped
    )


def _fmt_value(v: object) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, tuple | list | np.ndarray):
        try:
            a = np.asarray(v, dtype=np.float64)
        except (TypeError, ValueError):
            return ", ".join(str(x) for x in v)
        if a.size > 6:
            shape = "x".join(str(n) for n in a.shape)
            return f"{shape} values, {a.min():.4g} to {a.max():.4g}"
        return ", ".join(f"{x:.4g}" for x in a.ravel())
    return str(v)


def describe_error_model(model: ErrorModel | None = None) -> str:
    """Markdown tables of every simulator parameter: value, unit, kind and source.

    ``docs/error_model.md`` embeds this text; a test keeps the two the same.
    """
    from dataclasses import fields

    m = ErrorModel() if model is None else model
    out = []
    for group in fields(m):
        params = getattr(m, group.name)
        out += [
            f"### `{group.name}`: {type(params).__name__}",
            "",
            "| parameter | value | unit | kind | source |",
            "|---|---|---|---|---|",
        ]
        for f in fields(params):
            md = dict(f.metadata)
            src = str(md.get("source", "")).replace("|", "/").replace("\n", " ")
            kind = md.get("kind", "assumption" if "assumption" in src.lower() else "")
            out.append(
                f"| `{f.name}` | {_fmt_value(getattr(params, f.name))} | {md.get('unit', '')} "
                f"| {kind} | {src} |"
            )
        out.append("")
    return "\n".join(out)

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

from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from kinefuse import __version__
from kinefuse.camera.intrinsics import Intrinsics
from kinefuse.camera.wand import Wand
from kinefuse.errors import InputError, StoreError
from kinefuse.geometry.transforms import apply_transform, invert_transform
from kinefuse.io.store import SessionStore
from kinefuse.motion.types import Motion
from kinefuse.sensors.choreography import WandProtocol, holding_poses, make_wand_path
from kinefuse.sensors.clock import ClockParams, capture_times, clock_probes, draw_sensor_clocks
from kinefuse.sensors.depth import DepthNoiseParams, Scene, render_depth
from kinefuse.sensors.rig import Rig
from kinefuse.sensors.tracker import TrackerParams, draw_subject_bias, simulate_tracker
from kinefuse.skeleton import JOINT_INDEX, capsule_radii

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


def simulate_session(
    motion: Motion,
    rig: Rig,
    out: str | Path,
    config: LabConfig = LabConfig(),
    *,
    overwrite: bool = False,
    progress: Callable[[str], None] | None = None,
) -> Path:
    """Simulate a capture session of ``motion`` (already placed in the lab) seen by ``rig``.

    Writes one SQLite session store at ``out`` and returns its path. An existing file is only
    replaced with ``overwrite=True``, and never when it is a recording without ground truth
    (a live session cannot be simulated again).
    Deterministic: the same inputs and ``config.seed`` give the same observation rows.
    """
    say = progress or (lambda _msg: None)
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
    t_cal = float(config.calibration_s)
    t_end = t_cal + motion_s
    height = subject_height(motion)
    radii = capsule_radii(height)
    errs = config.errors

    root = np.random.SeedSequence(config.seed)
    seq_subject, seq_wand, *seq_sensors = root.spawn(2 + len(rig.sensors))
    subject = draw_subject_bias(np.random.default_rng(seq_subject), errs.tracker)

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
    store = SessionStore.create(out, overwrite=overwrite)
    try:
        store.set_meta("generator", f"kinefuse {__version__} simulate")
        store.set_meta("clip", motion.source)
        # what only the simulator knows goes with the truth, where only evaluation reads it
        store.write_truth_info("seed", int(config.seed))
        store.write_truth_info("rig", rig.description)
        store.write_truth_info("subject_height_m", height)
        store.set_meta("calibration_phase_server_s", [0.0, t_cal])
        store.set_meta("motion_phase_server_s", [t_cal, t_end])
        store.set_meta("wand", asdict(config.wand))
        store.set_meta("wand_protocol", config.protocol.to_dict())
        store.write_truth_info("error_model", _to_plain(asdict(errs)))

        t_truth = np.arange(0.0, motion_s + 1e-9, 1.0 / motion.rate_hz)
        store.write_truth_motion(t_cal + t_truth, motion.at(t_truth), motion.synthesized)

        # the calibration phase's wand path, on a fine grid (truth)
        wand_track = make_wand_path(t_cal, np.random.default_rng(seq_wand), config.protocol)
        if t_cal > 0:
            t_w = np.arange(0.0, t_cal, 1.0 / 120.0)
            store.append_truth_wand(t_w, wand_track.at(t_w))

        rest_pose = motion.positions[0]
        # the operator sees where the sensors stand and keeps out of their way
        sensor_positions = np.array([s.sensor2world[:3, 3] for s in rig.sensors])
        for spec, ss in zip(rig.sensors, seq_sensors, strict=True):
            rng_clock, rng_intr, rng_track, rng_depth, rng_probe = (
                np.random.default_rng(s) for s in ss.spawn(5)
            )
            # the device clock stamps frames; the client PC's clock answers the probes
            clocks = draw_sensor_clocks(rng_clock, errs.clock)
            clock = clocks.device
            intr = draw_intrinsics(rng_intr, errs.intrinsics)
            store.add_sensor(spec.id, spec.serial, intr, rate_hz=errs.clock.frame_rate_hz)
            store.write_truth_sensor(spec.id, spec.sensor2world, clocks.to_dict())
            probes = clock_probes(clocks.host, 0.0, t_end, rng_probe, errs.clock)
            store.append_clock_probes(spec.id, *probes.T)

            if t_cal > 0:
                say(f"{spec.id}: rendering calibration depth frames")
                cap = capture_times(
                    clock,
                    0.0,
                    t_cal,
                    rng_depth,
                    errs.clock,
                    host=clocks.host,
                    latency_offset_s=clocks.latency_offset_s,
                )
                step = max(round(errs.clock.frame_rate_hz / config.depth_rate_hz), 1)
                pick = (cap.seq % step) == 0
                t_true = cap.t_true_s[pick]
                centres = wand_track.at(t_true)
                poses, handles = holding_poses(
                    centres,
                    rest_pose,
                    config.wand,
                    sensor_positions=sensor_positions,
                    height_m=height,
                )
                frames = np.empty((t_true.size, intr.height, intr.width), dtype=np.uint16)
                for i in range(t_true.size):
                    scene = Scene.from_pose(
                        poses[i],
                        height,
                        wand=config.wand,
                        wand_centre=centres[i],
                        wand_handle_dir=handles[i],
                        room_min_xy_m=rig.room_min_xy_m,
                        room_max_xy_m=rig.room_max_xy_m,
                    )
                    frames[i] = render_depth(scene, spec.sensor2world, intr, rng_depth, errs.depth)
                store.append_depth_frames(spec.id, cap.seq[pick], cap.t_sensor_s[pick], frames)

            say(f"{spec.id}: simulating the body tracker")
            cap = capture_times(
                clock,
                t_cal,
                t_end,
                rng_track,
                errs.clock,
                host=clocks.host,
                latency_offset_s=clocks.latency_offset_s,
            )
            truth_world = motion.at(cap.t_true_s - t_cal)
            out_ = simulate_tracker(
                truth_world,
                spec.sensor2world,
                intr,
                radii,
                rng_track,
                errs.tracker,
                dt_s=1.0 / errs.clock.frame_rate_hz,
                subject=subject,
                t_s=cap.t_true_s,
            )
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
    return Path(out)


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

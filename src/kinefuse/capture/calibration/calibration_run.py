"""The server's side of calibration on a recorded session: sightings, registration, scale.

Uses what a real server has: the calibration-phase depth frames, each sensor's clock (from its
probes), the sensors' intrinsics and the operator's protocol (where and how the wand was to be
shown, stored in the session's metadata as the operator was told it). It reads no store:
:func:`kinefuse.pipeline.store_inputs.gather_calibration` reads a session and hands these in. The
truth is never read.
"""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from kinefuse.capture.calibration.common import WandTrack
from kinefuse.capture.calibration.floor import FloorPlane, fit_floor_plane
from kinefuse.capture.calibration.methods import DETECTORS
from kinefuse.capture.calibration.register import (
    Registration,
    Sightings,
    find_hold_windows,
    paper_positions_from_sightings,
    register_full,
    register_paper,
)
from kinefuse.capture.calibration.wand_paper import detect_wand_paper_sequence
from kinefuse.capture.calibration.wand_robust import detect_wand_sequence
from kinefuse.capture.sync import SensorTimebase
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.camera.wand import Wand
from kinefuse.errors import CalibrationError

Array = NDArray[np.float64]


@dataclass(frozen=True)
class CalibrationInput:
    """What calibration works from, gathered from a session."""

    sightings: dict[str, Sightings]
    tracks: dict[str, WandTrack]
    floors: dict[str, FloorPlane]
    protocol: dict[str, object]
    phase_server_s: tuple[float, float]
    frame_period_s: float  # median interval between a sensor's calibration depth frames


@dataclass(frozen=True, eq=False)
class CalibrationSensor:
    """One sensor's calibration phase, as the pipeline hands it in.

    Attributes
    ----------
    id : str
    intrinsics : Intrinsics
    timebase : SensorTimebase or None
        Device -> host -> server clock mapping (the depth frames carry device timestamps);
        None only for a sensor without depth frames.
    depth : iterable of ((N,) float, (N, H, W) uint16)
        The depth frames in chunks: device timestamps and images, in capture order (read
        lazily, so a long phase need not be in memory at once).
    live : LiveSightings or None
        A live recording's calibration phase: the clients detected the wand and fitted their
        floor themselves and sent the results, not depth frames (``depth`` is then empty).
    """

    id: str
    intrinsics: Intrinsics
    timebase: SensorTimebase | None
    depth: Iterable[tuple[Array, NDArray[np.uint16]]]
    live: LiveSightings | None = None


@dataclass(frozen=True, eq=False)
class LiveSightings:
    """What a live client sent for the calibration: its wand detections (times already on the
    server clock) and its floor plane, if it saw one."""

    track: WandTrack
    sightings: Sightings
    floor: FloorPlane | None = None


def gather(
    sensors: Sequence[CalibrationSensor],
    *,
    wand: Wand,
    protocol: dict[str, object],
    phase_server_s: tuple[float, float],
    floor_frames: int = 15,
    detector: str = "robust",
) -> CalibrationInput:
    """Detect the wand in every sensor's calibration frames and fit each sensor's floor.

    ``detector``: ``"paper"`` (METHODS.md A.3, steps 1-4: iterated binarization of the nearest
    object) or ``"robust"`` (a known-radius sphere fit,
    :mod:`kinefuse.capture.calibration.wand_robust`). ``sensors`` with no depth frames are refused
    by name (a calibration needs every sensor);
    :func:`kinefuse.pipeline.store_inputs.gather_calibration` reads them from a session.
    """
    if detector not in DETECTORS:
        raise CalibrationError(f"unknown wand detector {detector!r}; choose paper or robust")
    sightings: dict[str, Sightings] = {}
    tracks: dict[str, WandTrack] = {}
    floors: dict[str, FloorPlane] = {}
    empty = []
    periods = []
    for s in sensors:
        if s.live is not None:  # a live recording: the client's own detections
            tracks[s.id], sightings[s.id] = s.live.track, s.live.sightings
            t_live = s.live.sightings.t_server_s
            if len(t_live) > 1:
                periods.append(float(np.median(np.diff(np.sort(t_live)))))
            if s.live.floor is not None:
                floors[s.id] = s.live.floor
            continue
        ts: list[Array] = []
        found_tracks: list[WandTrack] = []
        firsts: list[NDArray[np.uint16]] = []
        n_first = 0
        for t_sensor, frames in s.depth:
            if len(t_sensor) == 0:
                continue
            ts.append(t_sensor)
            detect = detect_wand_paper_sequence if detector == "paper" else detect_wand_sequence
            found_tracks.append(detect(frames, s.intrinsics, wand, name=s.id))
            if n_first < floor_frames:
                firsts.append(frames[: floor_frames - n_first])
                n_first += len(firsts[-1])
        if not ts or s.timebase is None:
            empty.append(s.id)
            continue
        track = WandTrack(
            found=np.concatenate([t.found for t in found_tracks]),
            centre_sensor_m=np.concatenate([t.centre_sensor_m for t in found_tracks]),
            score=np.concatenate([t.score for t in found_tracks]),
            n_points=np.concatenate([t.n_points for t in found_tracks]),
            residual_m=np.concatenate([t.residual_m for t in found_tracks]),
            reasons=tuple(r for t in found_tracks for r in t.reasons),
        )
        t_server = s.timebase.affine.forward(np.concatenate(ts))
        if len(t_server) > 1:
            periods.append(float(np.median(np.diff(t_server))))
        f = track.found
        tracks[s.id] = track
        sightings[s.id] = Sightings(t_server[f], track.centre_sensor_m[f], track.score[f])
        # the per-pixel median of the first frames hides the moving actor and wand
        stack = np.concatenate(firsts).astype(np.float64)
        stack[stack == 0] = np.nan
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # pixels never valid stay NaN
            med = np.nanmedian(stack, axis=0)
        med = np.where(np.isfinite(med), med, 0).astype(np.uint16)
        # a sensor that sees no floor gets its gravity from the others
        with contextlib.suppress(CalibrationError):
            floors[s.id] = fit_floor_plane(med, s.intrinsics, name=s.id)
    if empty:
        raise CalibrationError(
            f"sensor(s) {', '.join(empty)} recorded no calibration depth frames; record a "
            "calibration phase (kinefuse simulate --calibration-seconds 20, or wave the wand "
            "while recording) before calibrating"
        )
    if not sightings:
        raise CalibrationError(
            "the session has no calibration phase (no depth frames or wand sightings); record one "
            "(kinefuse simulate --calibration-seconds 20)"
        )
    return CalibrationInput(
        sightings=sightings,
        tracks=tracks,
        floors=floors,
        protocol=protocol,
        phase_server_s=phase_server_s,
        frame_period_s=float(np.median(periods)) if periods else 1 / 30,
    )


#: The largest scale correction :func:`calibrate` applies (a fraction): the range scale error of
#: a time-of-flight sensor is a fraction of a percent, so a larger one means the protocol's holds
#: were not found (e.g. the start of the wand phase was missed) and is not applied.
MAX_SCALE_CORRECTION = 0.03


def _protocol_windows(cal: CalibrationInput) -> tuple[tuple[float, float], tuple[float, float]]:
    """The two still holds of the protocol, found in the sightings themselves (not in the
    simulator's choreography: a real operator's timing is not known to the second)."""
    return find_hold_windows(cal.sightings)


def scale_from_axis(cal: CalibrationInput, reg: Registration) -> float:
    """The world's scale error, from the protocol's known move between the two holds.

    Time-of-flight sensors measure range with a small distance-proportional error that a wand of
    one sphere cannot reveal: a uniformly scaled world fits every sighting equally well. The
    protocol's move along the axis mark has a known length (like the paper's wand move): the
    ratio of the length seen in the registered world to the known one is the scale error.

    Returns
    -------
    factor : float
        Multiply world lengths by this (1.0 when the protocol has no known length).
    """
    length = cal.protocol.get("axis_length_m")
    if not isinstance(length, int | float) or length <= 0:
        return 1.0
    ow, mw = _protocol_windows(cal)
    origin, moved = _holds(cal, ow, mw)
    seen = []
    for k, sid in enumerate(reg.sensor_ids):
        if sid in origin and sid in moved:
            r, t = reg.sensor2world[k, :3, :3], reg.sensor2world[k, :3, 3]
            seen.append(np.linalg.norm((r @ moved[sid] + t) - (r @ origin[sid] + t)))
    if not seen:
        return 1.0
    return float(length) / float(np.median(seen))


def _holds(
    cal: CalibrationInput, ow: tuple[float, float], mw: tuple[float, float]
) -> tuple[dict[str, Array], dict[str, Array]]:
    """Median wand centre per sensor in each hold window (sensors that missed one are left out)."""
    origin, moved = {}, {}
    for sid, s in cal.sightings.items():
        a = (s.t_server_s >= ow[0]) & (s.t_server_s <= ow[1])
        b = (s.t_server_s >= mw[0]) & (s.t_server_s <= mw[1])
        if a.sum() >= 2 and b.sum() >= 2:
            origin[sid] = np.median(s.centre_sensor_m[a], axis=0)
            moved[sid] = np.median(s.centre_sensor_m[b], axis=0)
    return origin, moved


def scale_registration(reg: Registration, factor: float) -> Registration:
    """The registration with every sensor position scaled by ``factor`` about the world origin."""
    if factor == 1.0:
        return reg
    poses = reg.sensor2world.copy()
    poses[:, :3, 3] *= factor
    return replace(
        reg,
        sensor2world=poses,
        world=reg.world + f"; scaled by {factor:.5f} from the protocol's known axis length",
        scale=reg.scale * factor,
    )


def calibrate(cal: CalibrationInput, method: str, *, fix_scale: bool = True) -> Registration:
    """Register the sensors with the paper's method or ours (``full``)."""
    if method == "paper":
        ow, mw = _protocol_windows(cal)
        origin, moved = paper_positions_from_sightings(
            cal.sightings, origin_window_s=ow, moved_window_s=mw
        )
        return register_paper(origin, moved)
    if method == "full":
        # sensors are not synchronized: match sightings across sensors by interpolating each
        # track between consecutive frames, and only where the wand moved slowly (a moving wand
        # between frames 1/10 s apart is not where linear interpolation puts it)
        reg = register_full(
            cal.sightings,
            floors=cal.floors or None,
            max_gap_s=1.6 * cal.frame_period_s,
            max_speed_m_s=min(1.5, 0.05 / cal.frame_period_s),
        )
        if not fix_scale:
            return reg
        try:
            factor = scale_from_axis(cal, reg)
        except CalibrationError as e:  # the scale is a refinement: the poses stand without it
            return replace(reg, world=reg.world + f"; scale NOT corrected: {e}")
        if abs(factor - 1.0) > MAX_SCALE_CORRECTION:
            # a range scale error of time-of-flight sensors is a fraction of a percent: a move
            # this far off its known length means the holds found are not the protocol's (a
            # client that missed the start of the wand phase); correcting would break the world
            return replace(
                reg,
                world=reg.world + f"; scale NOT corrected: the move between the holds found is "
                f"{abs(1 / factor - 1):.1%} off the protocol's known length (holds missed?)",
            )
        return scale_registration(reg, factor)
    raise CalibrationError(f"unknown calibration method {method!r}; choose paper or full")

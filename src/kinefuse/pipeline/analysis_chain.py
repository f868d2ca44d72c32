"""The analysis chain (paper B) as the commands run it: one input as a skeleton sequence, and
the chain on it (normalization, movement axes by every method, joint angles), timed; for a
session, how many sensors tracked each limb at each fused frame (:func:`limb_sensor_counts`),
from which ``analyze`` judges whether the calibration phase was seen (:func:`phase_seen`)."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.biomech.kinematics import joint_angles
from kinefuse.biomech.limbs import LIMB_PARENTS, LIMBS
from kinefuse.biomech.normalize import normalize
from kinefuse.biomech.parameterize import METHODS as AXIS_METHODS
from kinefuse.biomech.parameterize import learn_axes
from kinefuse.biomech.sequence import SkeletonSequence
from kinefuse.core.skeleton import JOINT_INDEX, JOINTS, MIRROR_INDEX, N_JOINTS, TrackingState

Array = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class AnalysisInput:
    """One input of ``kinefuse analyze`` as a skeleton sequence."""

    path: Path
    kind: str  # "session", "motion" or "markers"
    seq: SkeletonSequence
    stored_phase_s: tuple[float, float] | None = None  # a session's ROM phase (metadata)
    fusion: dict[str, Any] | None = None  # method, calibration, frames (sessions)
    sensor_poses: dict[str, Array] | None = None  # sensor2world used by the fusion (sessions)
    anatomical: dict[str, Array] | None = None  # ISB anatomical angles, degrees (static trial)
    anatomical_status: dict[str, str] | None = None  # segment -> "ok" or why it was skipped
    # OpenSim model -> the pelvis_* and trunk_* angles of its own pelvis and torso bodies
    # (anatomical.model_body_offsets), for --names opensim:MODEL
    opensim_body_angles: dict[str, dict[str, Array]] | None = None
    static_source: str | None = None  # the static trial used
    # sessions: (T, L) how many sensors tracked each limb (both its joints TRACKED) at each frame
    limb_sensors: NDArray[np.int64] | None = None
    # partial bodies (marker files): the map's joints the file cannot build -> missing markers
    unbuilt_joints: dict[str, str] | None = None
    # skeletons (sessions): the standing phase the anatomical frames come from, seconds, and the
    # one the session stored (``static_phase_server_s``, simulate --static)
    static_window_s: tuple[float, float] | None = None
    stored_static_s: tuple[float, float] | None = None


#: A limb is *seen* at a frame when at least this many sensors track it (both its joints
#: TRACKED): what a fusion needs to triangulate it rather than take one sensor's guess.
SEEN_MIN_SENSORS = 2
#: Axes are not learned for a limb seen in less than this fraction of the calibration phase's
#: frames: what the fusion delivers there is mostly one sensor's (or no sensor's) guess, and the
#: axes it teaches are off by tens of degrees (issue 24: a walkway that saw the phase 4-15 % of
#: the time gave a 25° axis error). A round number of ours: the sessions of
#: ``studies/analysis_sweep.py`` see every limb in 60 % of the phase or more.
SEEN_MIN_FRACTION = 0.5


def limb_sensor_counts(
    t_s: Array,
    sensors: list[tuple[Array, NDArray[np.int8]]],
    rate_hz: float,
    mirrored: NDArray[np.bool_] | None = None,
) -> NDArray[np.int64]:
    """How many sensors track each limb at each frame time ``t_s (T,)``: ``(T, L)`` int.

    ``sensors``: per sensor, its capture times on the same clock ``(N,)`` and joint tracking
    states ``(N, 25)``. A sensor tracks a limb at a frame when its observation nearest in time
    (within half a frame, ``0.5 / rate_hz``) has both the limb's joints TRACKED (not inferred);
    for the pelvis, the root, also both hips (its frame's tilt and heading come from them,
    :func:`kinefuse.biomech.normalize.root_long_axis`).

    ``mirrored (T, S)``: the fusion's swap decisions at the frames (``MethodResult.mirrored``).
    A sensor the fusion mirrored back at a frame gave its left limbs under the right names and
    the reverse, so its states are read mirrored there: its right shank is what it called the
    left one (one seeing the body from behind tracks the near leg, which it names wrongly).
    """
    t_s = np.asarray(t_s, dtype=np.float64)
    out = np.zeros((t_s.size, len(LIMBS)), dtype=np.int64)
    need = np.zeros((len(LIMBS), N_JOINTS), dtype=np.int64)
    for i, lb in enumerate(LIMBS):
        need[i, [lb.proximal_index, lb.distal_index]] = 1
        if LIMB_PARENTS[i] < 0:
            need[i, [JOINT_INDEX[j] for j in lb.twist_ref]] = 1
    if mirrored is not None and mirrored.shape != (t_s.size, len(sensors)):
        raise ValueError(f"mirrored must be ({t_s.size}, {len(sensors)}), got {mirrored.shape}")
    for si, (t_obs, states) in enumerate(sensors):
        if t_obs.size == 0:
            continue
        order = np.argsort(t_obs)
        t_o, st = t_obs[order], np.asarray(states)[order] == TrackingState.TRACKED
        k = np.clip(np.searchsorted(t_o, t_s), 1, t_o.size - 1) if t_o.size > 1 else None
        if k is None:
            near = np.zeros(t_s.size, dtype=np.intp)
        else:
            near = np.where(np.abs(t_o[k - 1] - t_s) <= np.abs(t_o[k] - t_s), k - 1, k)
        close = np.abs(t_o[near] - t_s) <= 0.5 / rate_hz
        at = st[near]
        if mirrored is not None and mirrored[:, si].any():
            flip = mirrored[:, si]
            at[flip] = at[flip][:, np.asarray(MIRROR_INDEX)]
        # tracked: none of the joints the limb needs is untracked, (T, 25) x (25, L)
        lacking = (~at).astype(np.int64) @ need.T
        out += (close[:, None] & (lacking == 0)).astype(np.int64)
    return out


def fused_limb_counts(sensors: Any, result: Any) -> NDArray[np.int64]:
    """:func:`limb_sensor_counts` at a fusion's frames: ``sensors`` the
    :class:`~kinefuse.pipeline.store_inputs.CalibratedSensor` list it fused, ``result`` its
    :class:`~kinefuse.capture.fusion.fusion_run.MethodResult` (frame times and swap decisions)."""
    t = result.t_server_s
    rate = float(1.0 / np.median(np.diff(t))) if t.size > 1 else 30.0
    streams = [(s.observations.t_server_s, s.observations.states) for s in sensors]
    return limb_sensor_counts(t, streams, rate, result.mirrored)


def phase_seen(counts: NDArray[np.int64], t_s: Array, phase: tuple[float, float]) -> dict[str, Any]:
    """How well the calibration phase was seen: per limb the fraction of the phase's frames in
    which at least :data:`SEEN_MIN_SENSORS` sensors tracked it, and the limbs seen in less than
    :data:`SEEN_MIN_FRACTION` of them (``not_seen``: limb -> the reason, for its status)."""
    inside = (t_s >= phase[0]) & (t_s <= phase[1])
    n = int(inside.sum())
    frac = {
        lb.name: float((counts[inside, i] >= SEEN_MIN_SENSORS).mean()) if n else 0.0
        for i, lb in enumerate(LIMBS)
    }
    advice = (
        "Perform the phase where the sensors see the subject (the centre of the capture volume)"
    )
    not_seen: dict[str, str] = {}
    for i, lb in enumerate(LIMBS):
        if LIMB_PARENTS[i] < 0:
            continue  # the root has no axes of its own; it is its children's parent below
        v = frac[lb.name]
        par = LIMBS[LIMB_PARENTS[i]].name
        if v < SEEN_MIN_FRACTION:
            not_seen[lb.name] = (
                f"not seen: tracked by {SEEN_MIN_SENSORS} or more sensors in {100 * v:.0f} % of "
                f"the calibration phase (need {100 * SEEN_MIN_FRACTION:.0f} %); no axes learned. "
                + advice
            )
        elif par in not_seen or frac[par] < SEEN_MIN_FRACTION:
            # its samples are its direction in the parent's frame: an unseen parent's frame is
            # a guess, and so are they (a foot seen 94 % of a phase whose shank was seen 6 %
            # gave axes 18-61° off)
            not_seen[lb.name] = (
                f"not seen: its parent {par} was tracked by {SEEN_MIN_SENSORS} or more sensors "
                f"in {100 * frac[par]:.0f} % of the calibration phase (need "
                f"{100 * SEEN_MIN_FRACTION:.0f} %; this limb {100 * v:.0f} %), and its "
                "movement is measured in the parent's frame; no axes learned. " + advice
            )
    return {
        "min_sensors": SEEN_MIN_SENSORS,
        "min_fraction": SEEN_MIN_FRACTION,
        "frames": n,
        "fraction_by_limb": frac,
        "fraction_min": min(frac.values()) if frac else 0.0,
        "fraction_median": float(np.median(list(frac.values()))) if frac else 0.0,
        "not_seen": not_seen,
        "axes_learned_from": f"each limb's movement in the phase's frames in which "
        f"{SEEN_MIN_SENSORS} or more sensors tracked it and its parent (its rest: the whole phase)",
    }


def analyse_sequence(
    seq: SkeletonSequence,
    phase: tuple[float, float],
    *,
    not_seen: dict[str, str] | None = None,
    seen_frames: NDArray[np.bool_] | None = None,
) -> dict[str, Any]:
    """The chain on one sequence: normalization, axes by every method, angles (DJ), timing.

    ``not_seen``: limbs whose axes are not learned, with the reason (:func:`phase_seen`);
    ``seen_frames (T, L)``: the frames each limb's axes may be learned from
    (:func:`~kinefuse.biomech.parameterize.learn_axes`; a session's
    ``limb_sensors >= SEEN_MIN_SENSORS``)."""
    t0 = time.perf_counter()
    norm = normalize(seq)
    t1 = time.perf_counter()
    models = {
        m: learn_axes(seq, norm, phase, method=m, refuse=not_seen, seen_frames=seen_frames)
        for m in AXIS_METHODS
    }
    t2 = time.perf_counter()
    angles = joint_angles(seq, norm, models["dj"])
    named = angles.anatomical()
    t3 = time.perf_counter()
    return {
        "seq": seq,
        "norm": norm,
        "models": models,
        "angles": angles,
        "named": named,
        "seconds": {"normalize": t1 - t0, "learn_axes": t2 - t1, "angles": t3 - t2},
    }


def skeleton_anatomy(
    seq: SkeletonSequence, norm: Any, window: tuple[float, float], zero: str = "standing"
) -> tuple[dict[str, Array], Any]:
    """The anatomical (ISB, joint coordinate system) angles of a skeleton from a static window
    of the sequence itself: :func:`kinefuse.biomech.anatomical.skeleton_anatomical_frames` on
    its joint centres, carried by the normalized limb frames ``norm.frames``; the elbow's
    flexion is its hinge angle (:func:`hinge_angle_deg`, less its median over the window with
    ``zero="standing"``). Returns (angles in degrees by name, the
    :class:`~kinefuse.biomech.anatomical.SkeletonAnatomy`)."""
    from kinefuse.biomech.anatomical import anatomical_angles, skeleton_anatomical_frames
    from kinefuse.biomech.limbs import LIMB_NAMES
    from kinefuse.biomech.normalize import carried_frames

    p = seq.kinect_positions()
    sel = (seq.t_s >= window[0]) & (seq.t_s <= window[1])
    limb_frames = {n: norm.frames[:, i] for i, n in enumerate(LIMB_NAMES)}
    # a limb whose twist reference is not fully conditioned while standing (a nearly straight
    # knee or elbow: its bend plane is joint-centre error) holds its static frame in the frame
    # carried from its parent; the reference takes over where the hinge bends
    weak = [n for i, n in enumerate(LIMB_NAMES)
            if sel.any() and np.nanmedian(norm.twist_weight[sel, i]) < 1.0]  # fmt: skip
    static = {n: carried_frames(norm, p, n) for n in weak}
    sa = skeleton_anatomical_frames(p, JOINTS, seq.t_s, limb_frames, window, zero=zero,
                                    static_frames=static)  # fmt: skip
    # the forearm's twist comes from the thumb: no pronation, no carrying angle from it
    forearm = [
        f"{a}_{s}" for a in ("elbow_adduction", "forearm_pronation") for s in ("left", "right")
    ]
    angles = anatomical_angles(sa.frames, sa.lab, forearm)
    for side in ("left", "right"):
        name = f"elbow_flexion_{side}"
        if name in angles:
            hinge = hinge_angle_deg(p, f"Shoulder{side.capitalize()}", f"Elbow{side.capitalize()}",
                                    f"Wrist{side.capitalize()}")  # fmt: skip
            if zero == "standing":
                hinge = hinge - np.nanmedian(hinge[sel])
            angles[name] = np.where(np.isfinite(angles[name]), hinge, np.nan)
    return angles, sa


def hinge_angle_deg(positions: Array, proximal: str, joint: str, distal: str) -> Array:
    """The flexion of the hinge at ``joint`` from three joint centres ``(T, 25, 3)``: 180° minus
    the angle proximal-joint-distal (0 straight), degrees, NaN where a joint is missing.

    A skeleton's elbow flexion is this angle (:func:`skeleton_anatomy`), not the joint
    coordinate system's rotation about the carried humerus axis: from joint centres the
    forearm's frame takes its twist from the thumb, 3 cm beside the hand, and with the
    standing frame level (not along the forearm) that twist, pronation included, read as
    flexion, 13.5 / 14.8° RMS (left / right) off the elbow's own angle on the true walk of
    ``studies/analysis_accuracy.py accuracy`` (docs/analysis.md)."""
    from kinefuse.core.skeleton import JOINT_INDEX

    u = positions[:, JOINT_INDEX[proximal]] - positions[:, JOINT_INDEX[joint]]
    v = positions[:, JOINT_INDEX[distal]] - positions[:, JOINT_INDEX[joint]]
    c = (u * v).sum(-1) / (np.linalg.norm(u, axis=-1) * np.linalg.norm(v, axis=-1))
    return np.asarray(180.0 - np.degrees(np.arccos(np.clip(c, -1.0, 1.0))), dtype=np.float64)

"""Realism of the simulated body tracker, checked against real Kinect v2 sensors.

Two checks (``docs/realism.md`` shows the table and how to recompute it):

1. **Two real sensors against each other, independent of their registration.** A real
   KinectMultiTrack log holds two Kinect v2 sensors watching one person. Pair their frames by
   nearest receive time (within 40 ms), rigidly align one stream onto the other with ONE Kabsch
   fit over all paired joints, and take the per-joint distances (:func:`disagreement`). The same
   procedure runs on a simulated copy of the layout (:func:`simulate_layout_disagreement`): the
   same two viewpoints, a real walking clip, the tracker model of
   :mod:`kinefuse.sim.tracker`, unsynchronized 30 Hz capture with the receiver's jitter.
   The subject-level bias is common to both sensors and invisible here; the view-dependent bias,
   jitter, inferred joints and swaps are what show.
2. **One simulated sensor against the truth**
   (:func:`kinefuse.lab.realism_single.single_sensor_realism`).
3. **Figures per take**, real beside simulated (:mod:`kinefuse.lab.realism_takes`, the
   ``python studies/realism.py`` command).

This is evaluation code: it reads the simulator's truth.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.frames.motion import Motion
from kinefuse.core.geometry.transforms import apply_transform, kabsch, look_at
from kinefuse.core.skeleton import (
    JOINT_INDEX,
    MIRROR_INDEX,
    N_JOINTS,
    capsule_radii,
)
from kinefuse.errors import InputError
from kinefuse.formats.kinect_multitrack import MultitrackRecording, read_kinect_multitrack
from kinefuse.sim.clock import ClockParams, capture_times, draw_clock
from kinefuse.sim.lab import subject_height
from kinefuse.sim.tracker import (
    SubjectBias,
    TrackerParams,
    draw_subject_bias,
    simulate_tracker,
)

Array = NDArray[np.float64]

#: Real figures quoted for the shipped KinectMultiTrack takes (median, p95), metres, by
#: ``Kinect_Config`` (issues 6 and 9).
QUOTED_REAL = {0: (0.021, 0.10), 1: (0.029, 0.14), 2: (0.065, 0.47)}
LAYOUT_NAMES = {0: "parallel", 1: "45 deg", 2: "90 deg"}

_CORE = ("SpineBase", "SpineMid", "SpineShoulder", "ShoulderLeft", "ShoulderRight")
_EXTREMITIES = (
    "WristLeft",
    "WristRight",
    "HandLeft",
    "HandRight",
    "AnkleLeft",
    "AnkleRight",
    "FootLeft",
    "FootRight",
)


# ------------------------------------------------------------------------------------------
# the procedure (the same for real and simulated streams)


def pair_by_receive_time(
    t_a_s: ArrayLike, t_b_s: ArrayLike, *, max_gap_s: float = 0.040
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Pair every frame of stream A with the frame of stream B received nearest in time.

    Parameters
    ----------
    t_a_s, t_b_s : (Na,), (Nb,) float
        Receive times on one clock (the receiving server's), seconds; any order.
    max_gap_s : float
        Pairs further apart than this are dropped.

    Returns
    -------
    idx_a, idx_b : (P,) int
        Indices of the paired frames (a B frame may serve several A frames).
    """
    a = np.asarray(t_a_s, dtype=np.float64).reshape(-1)
    b = np.asarray(t_b_s, dtype=np.float64).reshape(-1)
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise InputError("receive times must be finite seconds")
    if not max_gap_s > 0:
        raise InputError(f"max_gap_s must be positive, got {max_gap_s}")
    if a.size == 0 or b.size == 0:
        return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp)
    order = np.argsort(b, kind="stable")
    bs = b[order]
    k = np.clip(np.searchsorted(bs, a), 1, bs.size - 1) if bs.size > 1 else np.zeros_like(a, int)
    if bs.size > 1:
        left_better = np.abs(bs[k - 1] - a) <= np.abs(bs[k] - a)
        k = np.where(left_better, k - 1, k)
    ok = np.abs(bs[k] - a) <= max_gap_s
    return np.flatnonzero(ok).astype(np.intp), order[k[ok]].astype(np.intp)


@dataclass(frozen=True, eq=False)
class Disagreement:
    """How much two streams of one body disagree after one rigid alignment.

    Attributes
    ----------
    n_pairs : int
        Paired frames.
    distances_m : (P, 25) float
        Per-joint distance of every pair after alignment (NaN where either is missing).
    median_m, p95_m : float
        Over all finite distances.
    per_joint_median_m : (25,) float
    b2a : (4, 4) float
        The rigid transform that maps stream B onto stream A.
    mirrored_fraction : float
        Share of paired frames that fit better after swapping every left joint of stream B with
        its right twin: the two trackers disagree on left and right.
    capture_mismatch_std_s : float
        Spread of the capture-time difference of paired frames, from the sensors' own clocks
        (see :func:`capture_mismatch_std`); NaN when not computed.
    mirrored : (P,) bool
        Per pair: it fits better with stream B's left and right swapped.
    frame_ok : (P,) bool
        Per pair: it has a left/right twin finite in both streams (``mirrored`` is meaningful).
    """

    n_pairs: int
    distances_m: Array
    median_m: float
    p95_m: float
    per_joint_median_m: Array
    b2a: Array
    mirrored_fraction: float
    capture_mismatch_std_s: float = float("nan")
    mirrored: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, dtype=bool))
    frame_ok: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, dtype=bool))


def disagreement(
    joints_a: ArrayLike,
    joints_b: ArrayLike,
    idx_a: ArrayLike,
    idx_b: ArrayLike,
) -> Disagreement:
    """Align stream B onto stream A with one Kabsch fit over all paired joints; distances.

    Parameters
    ----------
    joints_a, joints_b : (Na, 25, 3), (Nb, 25, 3) float
        Joints of each stream in its own frame, metres; NaN for missing joints.
    idx_a, idx_b : (P,) int
        Paired frames (:func:`pair_by_receive_time`).
    """
    a = np.asarray(joints_a, dtype=np.float64)
    b = np.asarray(joints_b, dtype=np.float64)
    for nm, x in (("joints_a", a), ("joints_b", b)):
        if x.ndim != 3 or x.shape[1:] != (N_JOINTS, 3):
            raise InputError(f"{nm} must have shape (N, {N_JOINTS}, 3), got {x.shape}")
    ia = np.asarray(idx_a, dtype=np.intp)
    ib = np.asarray(idx_b, dtype=np.intp)
    if ia.shape != ib.shape or ia.ndim != 1:
        raise InputError(f"idx_a and idx_b must be equal-length 1-D, got {ia.shape}, {ib.shape}")
    pa = a[ia]
    pb = b[ib]
    ok = np.asarray(np.isfinite(pa).all(-1) & np.isfinite(pb).all(-1), dtype=bool)
    if ok.sum() < 3:
        raise InputError(
            f"only {int(ok.sum())} paired joints are finite in both streams; need at least 3 "
            "(do the streams overlap in time?)"
        )
    b2a = kabsch(pb[ok], pa[ok])
    pb_a = apply_transform(b2a, pb)
    d = np.linalg.norm(pb_a - pa, axis=-1)
    d[~ok] = np.nan
    d_mirror = np.linalg.norm(pb_a[:, list(MIRROR_INDEX)] - pa, axis=-1)
    ok_m = ok & ok[:, list(MIRROR_INDEX)]
    frames = ok_m.any(axis=1)
    s0 = np.where(ok_m, d, 0.0).sum(axis=1)
    s1 = np.where(ok_m, d_mirror, 0.0).sum(axis=1)
    mirrored_pairs = frames & (s1 < s0)
    mirrored = float(mirrored_pairs[frames].mean()) if frames.any() else float("nan")
    per_joint = np.full(N_JOINTS, np.nan)
    has = ok.any(axis=0)
    per_joint[has] = np.nanmedian(d[:, has], axis=0)
    return Disagreement(
        n_pairs=int(ia.size),
        distances_m=d,
        median_m=float(np.median(d[ok])),
        p95_m=float(np.percentile(d[ok], 95)),
        per_joint_median_m=per_joint,
        b2a=b2a,
        mirrored_fraction=mirrored,
        mirrored=mirrored_pairs,
        frame_ok=frames,
    )


def capture_mismatch_std(
    t_sensor_a_s: ArrayLike,
    t_sensor_b_s: ArrayLike,
    groups: ArrayLike | None = None,
    *,
    outlier_s: float = 0.100,
) -> float:
    """Spread of the capture-time difference of paired frames, from each sensor's own clock.

    The clocks' offsets are unknown, so per group (a scenario, a pass) the difference
    ``t_a - t_b`` is centred on its median, pairs more than ``outlier_s`` off are dropped, and the
    rest centred on their mean. Returns the standard deviation over all groups, seconds.
    """
    ta = np.asarray(t_sensor_a_s, dtype=np.float64).reshape(-1)
    tb = np.asarray(t_sensor_b_s, dtype=np.float64).reshape(-1)
    if ta.shape != tb.shape:
        raise InputError(f"paired sensor times differ in length: {ta.shape} vs {tb.shape}")
    g = np.zeros(ta.size, dtype=np.int64) if groups is None else np.asarray(groups).reshape(-1)
    if g.shape != ta.shape:
        raise InputError(f"groups must have one label per pair, got {g.shape} for {ta.shape}")
    parts = []
    for label in np.unique(g):
        d = ta[g == label] - tb[g == label]
        d = d - np.median(d)
        d = d[np.abs(d) < outlier_s]
        if d.size:
            parts.append(d - d.mean())
    if not parts:
        return float("nan")
    return float(np.concatenate(parts).std())


def _front_and_side(rec: MultitrackRecording) -> tuple[int, int]:
    if len(rec.streams) != 2:
        raise InputError(
            f"{rec.path}: the comparison needs exactly two sensors, found {len(rec.streams)}"
        )
    ang = [abs(s.init_angle_rad) if np.isfinite(s.init_angle_rad) else 0.0 for s in rec.streams]
    front = int(np.argmin(ang))
    return front, 1 - front


def real_disagreement(
    recording: MultitrackRecording | str | Path, *, max_gap_s: float = 0.040
) -> Disagreement:
    """The two-sensor disagreement of a real KinectMultiTrack log (every scenario in it).

    The front sensor (smallest initial body angle) is stream A; the side sensor is aligned
    onto it.
    """
    rec = (
        recording
        if isinstance(recording, MultitrackRecording)
        else read_kinect_multitrack(recording)
    )
    fa, fb = _front_and_side(rec)
    sa, sb = rec.streams[fa], rec.streams[fb]
    ia, ib = pair_by_receive_time(sa.t_receive_s, sb.t_receive_s, max_gap_s=max_gap_s)
    res = disagreement(sa.joints_m, sb.joints_m, ia, ib)
    spread = capture_mismatch_std(sa.t_sensor_s[ia], sb.t_sensor_s[ib], sa.scenario[ia])
    return replace(res, capture_mismatch_std_s=spread)


# ------------------------------------------------------------------------------------------
# simulated layouts


@dataclass(frozen=True)
class PairLayout:
    """Two sensors watching one person, as in a real two-Kinect recording.

    The person's reference spot is the lab origin, facing +x. Each sensor stands at horizontal
    distance ``dist_m[k]`` from it, at azimuth ``azimuth_rad[k]`` from the person's facing
    direction, ``height_m[k]`` above the floor, looking horizontally at the reference spot.
    """

    name: str
    azimuth_rad: tuple[float, float]
    dist_m: tuple[float, float]
    height_m: tuple[float, float] = (1.0, 1.0)

    def sensor2world(self) -> tuple[Array, Array]:
        out = []
        for az, d, h in zip(self.azimuth_rad, self.dist_m, self.height_m, strict=True):
            pos = np.array([d * np.cos(az), d * np.sin(az), h])
            out.append(look_at(pos, np.array([0.0, 0.0, h])))
        return out[0], out[1]

    @classmethod
    def from_recording(cls, rec: MultitrackRecording) -> PairLayout:
        """The layout a real log describes: each sensor's initial body angle and distance."""
        fa, fb = _front_and_side(rec)
        s = (rec.streams[fa], rec.streams[fb])
        for x in s:
            if not (np.isfinite(x.init_angle_rad) and np.isfinite(x.init_dist_m)):
                raise InputError(
                    f"{rec.path}: sensor {x.sensor_id} lacks Skeleton_Init_Angle/Dist; "
                    "cannot rebuild the layout"
                )
        heights = tuple(x.height_m if np.isfinite(x.height_m) else 1.0 for x in s)
        return cls(
            name=LAYOUT_NAMES.get(rec.kinect_config, f"config {rec.kinect_config}"),
            azimuth_rad=(s[0].init_angle_rad, s[1].init_angle_rad),
            dist_m=(s[0].init_dist_m, s[1].init_dist_m),
            height_m=(float(heights[0]), float(heights[1])),
        )


@dataclass(frozen=True)
class ReceiverParams:
    """How the receiving server of a two-Kinect log stamps frames (for the simulated copy)."""

    latency_sigma_s: float = field(
        default=0.016,
        metadata={
            "unit": "s",
            "kind": "measurement",
            "source": "chosen so the simulated capture-time mismatch of paired frames has the "
            "spread measured in the KinectMultiTrack logs (std 22-26 ms, see docs/realism.md)",
        },
    )
    max_gap_s: float = field(
        default=0.040,
        metadata={"unit": "s", "kind": "procedure", "source": "pairing window of the issue"},
    )


@dataclass(frozen=True)
class MotionProfile:
    """How much a person moves in a recording: the share of still frames and the pelvis speed
    while moving (horizontal and vertical, m/s)."""

    still_fraction: float
    moving_speed_m_s: float


def motion_profile(
    recording: MultitrackRecording, *, still_below_m_s: float = 0.15, half_window: int = 5
) -> MotionProfile:
    """Measure the pelvis speed profile of a real log's front sensor.

    Speeds are central differences over ``2 * half_window`` distinct frames (duplicated rows
    removed) on the sensor's own clock, per scenario.
    """
    fa, _ = _front_and_side(recording)
    s = recording.streams[fa]
    speeds = []
    for sc in np.unique(s.scenario):
        m = s.scenario == sc
        t = s.t_sensor_s[m]
        p = s.joints_m[m][:, JOINT_INDEX["SpineBase"]]
        fresh = np.r_[True, np.diff(t) > 0.005]
        t, p = t[fresh], p[fresh]
        k = half_window
        if t.size > 2 * k:
            dt = t[2 * k :] - t[: -2 * k]
            speeds.append(np.linalg.norm(p[2 * k :] - p[: -2 * k], axis=1) / dt)
    if not speeds:
        raise InputError(f"{recording.path}: too few frames to measure the motion")
    v = np.concatenate(speeds)
    moving = v >= still_below_m_s
    return MotionProfile(
        still_fraction=float(1.0 - moving.mean()),
        moving_speed_m_s=float(np.median(v[moving])) if moving.any() else 0.0,
    )


def clip_speed(motion: Motion) -> float:
    """Median horizontal pelvis speed of a clip, m/s."""
    root = motion.positions[:, JOINT_INDEX["SpineBase"], :2]
    if motion.n_frames < 3:
        raise InputError("a clip of fewer than 3 frames has no speed")
    v = np.linalg.norm(np.gradient(root, axis=0), axis=1) * motion.rate_hz
    return float(np.median(v))


def walking_passes(
    motion: Motion,
    headings_rad: Sequence[float],
    *,
    half_length_m: float = 1.0,
    speed_m_s: float | None = None,
    still_fraction: float = 0.0,
    backward: bool = False,
) -> list[Motion]:
    """Cut the middle of a walking clip and replay it through the lab origin at several headings.

    The clip's travel direction is its pelvis' horizontal displacement; the part whose pelvis is
    within ``half_length_m`` (along the travel) of the path's midpoint is kept, rotated about the
    vertical so it walks along each heading (radians from +x, counter-clockwise), and shifted so
    its midpoint is at the origin.

    ``speed_m_s`` replays the clip slower or faster so its median pelvis speed is that (a real
    recording's walking speed); ``still_fraction`` prepends a still stand (the first pose held)
    so that this share of every pass is standing still (1.0: the pass is a stand only, as long
    as the walk would have been). ``backward`` adds every pass played in reverse too (walking
    backward while facing the heading).
    """
    if not half_length_m > 0:
        raise InputError(f"half_length_m must be positive, got {half_length_m}")
    if not 0.0 <= still_fraction <= 1.0:
        raise InputError(f"still_fraction must be in [0, 1], got {still_fraction}")
    if speed_m_s is not None and not speed_m_s > 0:
        raise InputError(f"speed_m_s must be positive, got {speed_m_s}")
    root = motion.positions[:, JOINT_INDEX["SpineBase"], :2]
    travel = root[-1] - root[0]
    dist = float(np.linalg.norm(travel))
    if dist < 0.5:
        raise InputError(
            f"{motion.source or 'the clip'} travels only {dist:.2f} m; a walking clip is needed "
            "(at least 0.5 m of travel)"
        )
    u = travel / dist
    s = (root - root[0]) @ u
    mid = 0.5 * (s.min() + s.max())
    keep = np.flatnonzero(np.abs(s - mid) <= half_length_m)
    seg = motion.positions[keep[0] : keep[-1] + 1]
    if seg.shape[0] < 4:
        raise InputError("the kept part of the walk has fewer than 4 frames; use a longer clip")
    centre = np.array([*(root[0] + mid * u), 0.0])
    base = np.arctan2(u[1], u[0])
    rate = motion.rate_hz
    if speed_m_s is not None:
        rate = rate * speed_m_s / clip_speed(motion)
    if still_fraction >= 1.0 - 1e-9:  # a take that is all standing: stands only
        seg = np.repeat(seg[:1], seg.shape[0], axis=0)
        n_still = seg.shape[0]
    else:
        n_still = round(still_fraction / (1.0 - still_fraction) * seg.shape[0])
        if n_still:
            seg = np.concatenate([np.repeat(seg[:1], n_still, axis=0), seg])
    out = []
    for h in headings_rad:
        a = float(h) - base
        c, sn = np.cos(a), np.sin(a)
        rz = np.array([[c, -sn, 0.0], [sn, c, 0.0], [0.0, 0.0, 1.0]])
        pos = (seg - centre) @ rz.T
        what = f"{motion.source} pass facing {np.degrees(h):.0f} deg"
        out.append(Motion(pos, rate, motion.synthesized, source=what))
        if backward:
            back = np.concatenate([pos[n_still:][::-1], pos[:n_still]])
            out.append(Motion(back, rate, motion.synthesized, source=what + " backward"))
    return out


@dataclass(frozen=True, eq=False)
class SimulatedPair:
    """Two simulated sensors' streams of several walking passes, pooled."""

    joints_a: Array
    joints_b: Array
    idx_a: NDArray[np.intp]
    idx_b: NDArray[np.intp]
    t_sensor_a_s: Array
    t_sensor_b_s: Array
    group_a: NDArray[np.int64]
    true_mismatch_s: Array
    group_b: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))


def simulate_pair(
    passes: Sequence[Motion],
    layout: PairLayout,
    rng: np.random.Generator,
    params: TrackerParams | None = None,
    *,
    receiver: ReceiverParams | None = None,
    subject: SubjectBias | None = None,
) -> SimulatedPair:
    """Simulate both sensors of ``layout`` over every pass and pair their frames."""
    tp = TrackerParams() if params is None else params
    rcv = ReceiverParams() if receiver is None else receiver
    if not passes:
        raise InputError("no walking passes to simulate")
    clock_params = ClockParams(latency_sigma_s=rcv.latency_sigma_s)
    subj = draw_subject_bias(rng, tp) if subject is None else subject
    radii = capsule_radii(subject_height(passes[0]))
    s2w = layout.sensor2world()
    intr = Intrinsics()
    ja, jb, ia_all, ib_all, ta_all, tb_all, ga, gb, mis = [], [], [], [], [], [], [], [], []
    na = nb = 0
    for k, m in enumerate(passes):
        streams = []
        for s in s2w:
            clock = draw_clock(rng, clock_params)
            cap = capture_times(clock, 0.0, m.duration_s, rng, clock_params)
            truth = m.at(cap.t_true_s)
            out = simulate_tracker(
                truth,
                s,
                intr,
                radii,
                rng,
                tp,
                dt_s=1.0 / clock_params.frame_rate_hz,
                subject=subj,
                t_s=cap.t_true_s + 1000.0 * k,
            )
            streams.append((cap, out))
        (ca, oa), (cb, ob) = streams
        ia, ib = pair_by_receive_time(
            ca.t_receive_server_s, cb.t_receive_server_s, max_gap_s=rcv.max_gap_s
        )
        ja.append(oa.joints_sensor)
        jb.append(ob.joints_sensor)
        ia_all.append(ia + na)
        ib_all.append(ib + nb)
        ta_all.append(ca.t_sensor_s)
        tb_all.append(cb.t_sensor_s)
        ga.append(np.full(ca.t_sensor_s.size, k, dtype=np.int64))
        gb.append(np.full(cb.t_sensor_s.size, k, dtype=np.int64))
        mis.append(ca.t_true_s[ia] - cb.t_true_s[ib])
        na += ca.t_sensor_s.size
        nb += cb.t_sensor_s.size
    return SimulatedPair(
        joints_a=np.concatenate(ja),
        joints_b=np.concatenate(jb),
        idx_a=np.concatenate(ia_all),
        idx_b=np.concatenate(ib_all),
        t_sensor_a_s=np.concatenate(ta_all),
        t_sensor_b_s=np.concatenate(tb_all),
        group_a=np.concatenate(ga),
        true_mismatch_s=np.concatenate(mis),
        group_b=np.concatenate(gb),
    )


def simulate_layout_disagreement(
    passes: Sequence[Motion],
    layout: PairLayout,
    rng: np.random.Generator,
    params: TrackerParams | None = None,
    *,
    receiver: ReceiverParams | None = None,
) -> Disagreement:
    """The real procedure applied to a simulated copy of ``layout`` watching ``passes``."""
    sim = simulate_pair(passes, layout, rng, params, receiver=receiver)
    res = disagreement(sim.joints_a, sim.joints_b, sim.idx_a, sim.idx_b)
    spread = capture_mismatch_std(
        sim.t_sensor_a_s[sim.idx_a], sim.t_sensor_b_s[sim.idx_b], sim.group_a[sim.idx_a]
    )
    return replace(res, capture_mismatch_std_s=spread)


# ------------------------------------------------------------------------------------------
# the comparison table


def default_walk_path(data_dir: str | Path) -> Path:
    """The walking clip of the comparison: CMU 02 ``walk_a`` (ASF/AMC) in ``data_dir``."""
    return Path(data_dir) / "motion" / "cmu" / "02_walk_a.amc"


def load_walk(path: str | Path) -> Motion:
    """Load a walking clip (BVH or ASF/AMC) with :func:`kinefuse.formats.motion.load_motion`."""
    from kinefuse.formats.motion import load_motion

    return load_motion(path)


#: Eight walking directions (radians from +x): toward, away, across and diagonal to a sensor
#: at +x; used for the single-sensor check, where sensors stand all around.
DEFAULT_HEADINGS = tuple(np.radians(np.arange(0.0, 360.0, 45.0)))
#: Facing directions of the two-sensor comparison (radians from the front sensor's direction):
#: the real subject kept facing the front sensor (body yaw within about +/-60 degrees of it in
#: 96 % of frames of both logs) while stepping forward, backward and sideways.
FACING_FRONT = tuple(np.radians([-45.0, 0.0, 45.0]))

"""Real against simulated figures, take by take: ``python studies/realism.py [--take CSV ...]``.

For any KinectMultiTrack take (two real Kinect v2 sensors watching one person) this module
computes the same figures for the real streams and for a simulated copy of the take, with ONE
function (:func:`pair_figures`) for both:

``median_m``, ``p95_m``
    all per-joint distances after pairing by receive time and one Kabsch fit
    (:func:`kinefuse.lab.realism.disagreement`);
``trunk_median_m``, ``extremity_median_m``
    the same distances pooled over the spine and shoulders, and over wrists, hands, ankles, feet;
``lr_disagreement_fraction``
    share of pairs that fit better with one stream's left and right swapped;
``lr_disagreement_still_fraction``, ``still_p95_m``
    the same, and the 95th percentile of the distances, over pairs in which the person stands
    still (see below): where a stale inferred joint would show;
``still_jitter_m_per_frame``
    while the person stands still, the median frame-to-frame step of the spine joints
    (SpineBase, SpineMid, SpineShoulder, Neck), over distinct frames of both streams;
``bone_length_cv``
    coefficient of variation of each limb bone's length (upper arms, forearms, thighs, shanks)
    over the whole stream, median over those bones, mean of the two streams;
``limb_angle_median_deg``
    the two sensors' disagreement on the knees' and elbows' included angles (180 deg minus the
    angle at the joint between its two bones; frame-free, so no fit is involved), median over
    paired frames, both sides and both joints pooled, left and right matched as they fit best:
    how coherently a sensor's errors move the joints of one limb (independent errors at hip,
    knee and ankle bend the knee; an error shared by the three does not).
``still_knee_angle_deg``
    the front sensor's included knee angle while the person stands still, median over those
    frames and both knees (:func:`still_knee_angle_deg`): how bent one sensor reads a straight
    leg, the subject-level joint offsets (shared by the sensors, so invisible to the figures
    above) included.

"Standing still" is read from the stream itself, the same way for real and simulated data: the
reported pelvis moves less than :data:`STILL_BELOW_M_S` over +/-5 distinct frames on the
sensor's own clock.

The simulated copy: the layout from the file (logged distances, the side sensor's azimuth from
the logged initial body angle corrected by the rigid fit of the real streams), the walking clip
replayed at the take's speed profile (:func:`kinefuse.lab.realism.motion_profile`), both
sensors through :func:`kinefuse.lab.realism.simulate_pair`, one simulation per seed; the
simulated figures are the mean over seeds with their range.

This is evaluation code (it reads the simulator's truth through ``simulate_pair``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.core.frames.motion import Motion
from kinefuse.core.skeleton import BONES, JOINT_INDEX, JOINTS, bone_index_array, standing_pose
from kinefuse.errors import InputError
from kinefuse.formats.kinect_multitrack import MultitrackRecording, read_kinect_multitrack
from kinefuse.lab.realism import (
    _CORE,
    _EXTREMITIES,
    FACING_FRONT,
    PairLayout,
    _front_and_side,
    disagreement,
    motion_profile,
    pair_by_receive_time,
    simulate_pair,
    walking_passes,
)
from kinefuse.sim.lab import subject_height
from kinefuse.sim.tracker_params import TrackerParams

Array = NDArray[np.float64]

#: The figures every take reports, real and simulated (the ``--json`` schema).
FIGURE_KEYS = (
    "median_m",
    "p95_m",
    "trunk_median_m",
    "extremity_median_m",
    "lr_disagreement_fraction",
    "still_jitter_m_per_frame",
    "bone_length_cv",
)
#: Figures reported beside them (not part of the acceptance schema).
EXTRA_KEYS = (
    "lr_disagreement_still_fraction",
    "still_p95_m",
    "still_fraction",
    "limb_angle_median_deg",
    "still_knee_angle_deg",
)
#: A pelvis slower than this over +/-5 frames is standing still, m/s.
STILL_BELOW_M_S = 0.03
_HALF_WINDOW = 5
#: A take still in at least this share of its frames is simulated standing only
#: (:func:`take_passes`).
MOSTLY_STILL = 0.95
_SPINE = ("SpineBase", "SpineMid", "SpineShoulder", "Neck")
_LIMB_CHILDREN = ("Elbow", "Wrist", "Knee", "Ankle")
_LIMB_BONES = tuple(
    i for i, (_, child) in enumerate(BONES) if any(child.startswith(k) for k in _LIMB_CHILDREN)
)
#: Acceptance bands of the issue: |sim / real - 1| at most this.
BANDS = {"median_m": 0.25, "p95_m": 0.40, "trunk_median_m": 0.35, "extremity_median_m": 0.35}
#: ... and factors for the still-pose figures: real / f <= sim <= real * f.
FACTORS = {"still_jitter_m_per_frame": 2.0, "bone_length_cv": 1.5}
#: Left/right disagreement while standing facing the sensors stays below this.
STILL_LR_MAX = 0.01


@dataclass(frozen=True, eq=False)
class StreamPair:
    """Two streams of one body as the figures need them (real or simulated).

    Attributes
    ----------
    joints_a, joints_b : (Na, 25, 3), (Nb, 25, 3) float
        Joints in each stream's frame, metres, NaN where missing. A is the front sensor.
    t_sensor_a_s, t_sensor_b_s : (Na,), (Nb,) float
        Each frame's timestamp on its sensor's own clock, seconds.
    group_a, group_b : (Na,), (Nb,) int
        Contiguous parts (a scenario, a simulated pass); time differences are taken inside one.
    idx_a, idx_b : (P,) int
        Paired frames (by receive time).
    """

    joints_a: Array
    joints_b: Array
    t_sensor_a_s: Array
    t_sensor_b_s: Array
    group_a: NDArray[np.int64]
    group_b: NDArray[np.int64]
    idx_a: NDArray[np.intp]
    idx_b: NDArray[np.intp]


def real_pair(rec: MultitrackRecording, *, max_gap_s: float = 0.040) -> StreamPair:
    """The two streams of a real take, front sensor first, paired by ``Tracker_Time``."""
    fa, fb = _front_and_side(rec)
    sa, sb = rec.streams[fa], rec.streams[fb]
    ia, ib = pair_by_receive_time(sa.t_receive_s, sb.t_receive_s, max_gap_s=max_gap_s)
    return StreamPair(
        sa.joints_m, sb.joints_m, sa.t_sensor_s, sb.t_sensor_s,
        np.asarray(sa.scenario, np.int64), np.asarray(sb.scenario, np.int64), ia, ib,
    )  # fmt: skip


def still_frames(
    joints: ArrayLike, t_sensor_s: ArrayLike, group: ArrayLike
) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Which frames are distinct and which are standing still, from the stream alone.

    Returns
    -------
    fresh : (N,) bool
        The frame is new (its sensor time is more than 5 ms after the previous one of its group;
        a log repeats the latest skeleton when nothing new arrived).
    still : (N,) bool
        Fresh, and the pelvis moves less than :data:`STILL_BELOW_M_S` over +/-5 fresh frames.
    """
    p = np.asarray(joints, dtype=np.float64)[:, JOINT_INDEX["SpineBase"]]
    t = np.asarray(t_sensor_s, dtype=np.float64)
    g = np.asarray(group)
    fresh = np.zeros(t.size, dtype=bool)
    still = np.zeros(t.size, dtype=bool)
    k = _HALF_WINDOW
    for label in np.unique(g):
        rows = np.flatnonzero(g == label)
        f = np.r_[True, np.diff(t[rows]) > 0.005]
        rows = rows[f]
        fresh[rows] = True
        if rows.size <= 2 * k:
            continue
        dt = t[rows[2 * k :]] - t[rows[: -2 * k]]
        v = np.linalg.norm(p[rows[2 * k :]] - p[rows[: -2 * k]], axis=1) / np.maximum(dt, 1e-9)
        s = np.zeros(rows.size, dtype=bool)
        s[k:-k] = v < STILL_BELOW_M_S  # NaN (body missing) compares False
        still[rows] = s
    return fresh, still


def _jitter_steps(joints: Array, fresh: NDArray[np.bool_], still: NDArray[np.bool_],
                  group: NDArray[np.int64]) -> Array:  # fmt: skip
    spine = [JOINT_INDEX[n] for n in _SPINE]
    out = []
    for label in np.unique(group):
        rows = np.flatnonzero((group == label) & fresh)
        if rows.size < 2:
            continue
        both = still[rows[1:]] & still[rows[:-1]]
        step = np.linalg.norm(joints[rows[1:]][:, spine] - joints[rows[:-1]][:, spine], axis=-1)
        step = step[both]
        keep = np.isfinite(step).any(axis=1)
        out.append(np.nanmedian(step[keep], axis=1) if keep.any() else np.zeros(0))
    return np.concatenate(out) if out else np.zeros(0)


def _bone_cv(joints: Array, fresh: NDArray[np.bool_]) -> float:
    bones = bone_index_array()[list(_LIMB_BONES)]
    q = joints[fresh]
    length = np.linalg.norm(q[:, bones[:, 1]] - q[:, bones[:, 0]], axis=-1)
    ok = np.isfinite(length)
    cv = []
    for b in range(length.shape[1]):
        v = length[ok[:, b], b]
        if v.size >= 3:
            cv.append(float(v.std() / v.mean()))
    return float(np.median(cv)) if cv else float("nan")


#: The hinge joints of :func:`limb_angle_disagreement_deg`: (proximal, hinge, distal) per side.
_HINGES = (("Hip", "Knee", "Ankle"), ("Shoulder", "Elbow", "Wrist"))


def limb_angle_disagreement_deg(pair: StreamPair) -> Array:
    """Per paired frame and hinge (knees, elbows), the two streams' disagreement on the included
    angle, degrees ``(P, 2)``: the mean over the two sides, with left and right matched as they
    agree best (a mirrored skeleton is not counted as a bent knee). NaN where a side is
    missing."""
    from kinefuse.pipeline.analysis_chain import hinge_angle_deg

    a = pair.joints_a[pair.idx_a]
    b = pair.joints_b[pair.idx_b]
    out = []
    for prox, hinge, dist in _HINGES:
        la, ra, lb, rb = (
            hinge_angle_deg(q, f"{prox}{side}", f"{hinge}{side}", f"{dist}{side}")
            for q in (a, b)
            for side in ("Left", "Right")
        )
        same = np.abs(la - lb) + np.abs(ra - rb)
        crossed = np.abs(la - rb) + np.abs(ra - lb)
        out.append(np.fmin(same, crossed) / 2.0)
    return np.stack(out, axis=1)


def still_knee_angle_deg(joints: ArrayLike) -> float:
    """How bent one sensor reads a standing person's straight knees: the median over frames
    ``(N, 25, 3)`` and both knees of the included angle (180 deg minus hip-knee-ankle), degrees;
    NaN without a knee."""
    from kinefuse.pipeline.analysis_chain import hinge_angle_deg

    p = np.asarray(joints, dtype=np.float64)
    if not len(p):
        return float("nan")
    a = np.concatenate(
        [hinge_angle_deg(p, f"Hip{s}", f"Knee{s}", f"Ankle{s}") for s in ("Left", "Right")]
    )
    a = a[np.isfinite(a)]
    return float(np.median(a)) if a.size else float("nan")


def pair_figures(pair: StreamPair) -> dict[str, float]:
    """Every figure of :data:`FIGURE_KEYS` and :data:`EXTRA_KEYS` for two streams of one body.

    The same function serves real and simulated streams.
    """
    d = disagreement(pair.joints_a, pair.joints_b, pair.idx_a, pair.idx_b)
    dist = d.distances_m
    core = [JOINT_INDEX[n] for n in _CORE]
    ext = [JOINT_INDEX[n] for n in _EXTREMITIES]

    def pooled(cols: list[int]) -> float:
        v = dist[:, cols]
        v = v[np.isfinite(v)]
        return float(np.median(v)) if v.size else float("nan")

    fa, sa = still_frames(pair.joints_a, pair.t_sensor_a_s, pair.group_a)
    fb, sb = still_frames(pair.joints_b, pair.t_sensor_b_s, pair.group_b)
    steps = np.concatenate(
        [
            _jitter_steps(pair.joints_a, fa, sa, pair.group_a),
            _jitter_steps(pair.joints_b, fb, sb, pair.group_b),
        ]
    )
    steps = steps[np.isfinite(steps)]
    still_dist = dist[sa[pair.idx_a]]
    still_dist = still_dist[np.isfinite(still_dist)]
    still_pairs = sa[pair.idx_a] & d.frame_ok
    mirrored_still = float(d.mirrored[still_pairs].mean()) if still_pairs.any() else float("nan")
    cv = [_bone_cv(pair.joints_a, fa), _bone_cv(pair.joints_b, fb)]
    cv = [c for c in cv if np.isfinite(c)]
    ang = limb_angle_disagreement_deg(pair)
    ang = ang[np.isfinite(ang)]
    return {
        "median_m": d.median_m,
        "p95_m": d.p95_m,
        "trunk_median_m": pooled(core),
        "extremity_median_m": pooled(ext),
        "lr_disagreement_fraction": d.mirrored_fraction,
        "still_jitter_m_per_frame": float(np.median(steps)) if steps.size else float("nan"),
        "bone_length_cv": float(np.mean(cv)) if cv else float("nan"),
        "lr_disagreement_still_fraction": mirrored_still,
        "still_p95_m": float(np.percentile(still_dist, 95)) if still_dist.size else float("nan"),
        "still_fraction": float(sa[fa].mean()) if fa.any() else float("nan"),
        "limb_angle_median_deg": float(np.median(ang)) if ang.size else float("nan"),
        "still_knee_angle_deg": still_knee_angle_deg(pair.joints_a[sa]),
        "per_joint_median_m": d.per_joint_median_m,  # type: ignore[dict-item]
    }


# ------------------------------------------------------------------------------------------
# one take, real and simulated


def take_layout(rec: MultitrackRecording, real: StreamPair | None = None) -> PairLayout:
    """The layout of a take: logged distances and heights, and the side sensor's azimuth.

    KinectMultiTrack already mapped the side sensor's joints into the front sensor's frame with
    the logged initial body angles; the rigid fit of the two real streams measures what that
    mapping missed (its rotation about the vertical), and the side sensor's azimuth is the logged
    one corrected by it (the logged angle understates a 90-degree layout as about 67 degrees).
    """
    base = PairLayout.from_recording(rec)
    pair = real_pair(rec) if real is None else real
    d = disagreement(pair.joints_a, pair.joints_b, pair.idx_a, pair.idx_b)
    r = d.b2a[:3, :3]
    yaw = float(np.arctan2(r[0, 2], r[2, 2]))  # about the sensor's vertical (y) axis
    az = (base.azimuth_rad[0], base.azimuth_rad[1] - yaw)
    return PairLayout(name=base.name, azimuth_rad=az, dist_m=base.dist_m, height_m=base.height_m)


def layout_angle_deg(layout: PairLayout) -> float:
    """Angle between the two sensors as seen from the person, degrees (0: side by side)."""
    return float(abs(np.degrees(layout.azimuth_rad[1] - layout.azimuth_rad[0])))


def simulated_pair(
    rec: MultitrackRecording,
    walk: Motion,
    seed: int,
    layout: PairLayout | None = None,
    params: TrackerParams | None = None,
) -> StreamPair:
    """One simulated copy of a take (seeded): its layout, the walk at its speed profile."""
    lay = take_layout(rec) if layout is None else layout
    prof = motion_profile(rec)
    passes = take_passes(walk, prof.still_fraction, prof.moving_speed_m_s)
    rng = np.random.default_rng([seed, 9, rec.kinect_config])
    sim = simulate_pair(passes, lay, rng, params)
    return StreamPair(
        sim.joints_a, sim.joints_b, sim.t_sensor_a_s, sim.t_sensor_b_s,
        sim.group_a, sim.group_b, sim.idx_a, sim.idx_b,
    )  # fmt: skip


def take_passes(walk: Motion, still_fraction: float, moving_speed_m_s: float) -> list[Motion]:
    """The simulated person's motion for a take with this speed profile.

    Walking passes facing the front sensor and 45 degrees to either side, forward and backward,
    at the take's moving speed (:func:`kinefuse.lab.realism.walking_passes`), and a stand
    facing the front sensor (the real subjects stood facing it; feet apart and arms down,
    :func:`kinefuse.core.skeleton.standing_pose` at the walker's height) as long as the take's share
    of still frames asks. A take still in at least :data:`MOSTLY_STILL` of its frames gets the
    stand alone (a few swaying frames are not a walk, and matching their share with walking
    passes would stand the person for hundreds of times the passes' length).
    """
    if not 0.0 <= still_fraction <= 1.0:
        raise InputError(f"still_fraction must be in [0, 1], got {still_fraction}")
    standing = still_fraction >= MOSTLY_STILL or not moving_speed_m_s > 0
    walks = walking_passes(
        walk, FACING_FRONT, speed_m_s=None if standing else moving_speed_m_s, backward=True
    )
    total = sum(m.duration_s for m in walks)
    stand_s = total if standing else still_fraction / (1.0 - still_fraction) * total
    rate = walks[0].rate_hz
    n = max(round(stand_s * rate), 4)
    pose = standing_pose(subject_height(walk))  # feet apart, arms down, facing +x
    stand = Motion(
        np.repeat(pose[None], n, axis=0),
        rate,
        walk.synthesized,
        source=f"standing pose of {walk.source}'s height, facing the front sensor",
    )
    return [stand] if standing else [*walks, stand]


@dataclass(frozen=True)
class TakeResult:
    """Real and simulated figures of one take."""

    file: str
    angle_deg: float
    distance_m: float
    real: dict[str, float]
    simulated: dict[str, float]
    simulated_range: dict[str, tuple[float, float]]
    seeds: tuple[int, ...]
    real_per_joint_m: tuple[float, ...]
    sim_per_joint_m: tuple[float, ...]
    #: every seed's figures (one simulated subject each), for the population comparison
    per_seed: tuple[dict[str, float], ...] = field(default=())

    def failures(self) -> list[str]:
        """The acceptance items this take misses (empty when all hold)."""
        out = []
        for k, band in BANDS.items():
            ratio = self.simulated[k] / self.real[k]
            if not abs(ratio - 1.0) <= band:
                out.append(f"{k}: sim/real {ratio:.2f}, outside +/-{band * 100:.0f} %")
        for k, f in FACTORS.items():
            ratio = self.simulated[k] / self.real[k]
            if not 1.0 / f <= ratio <= f:
                out.append(f"{k}: sim/real {ratio:.2f}, outside a factor {f}")
        lr = self.simulated["lr_disagreement_still_fraction"]
        if np.isfinite(lr) and not lr < STILL_LR_MAX:
            out.append(f"left/right disagreement while standing {lr * 100:.1f} % >= 1 %")
        return out

    def to_json(self) -> dict[str, Any]:
        sim: dict[str, Any] = {k: self.simulated[k] for k in (*FIGURE_KEYS, *EXTRA_KEYS)}
        sim["range"] = {k: list(self.simulated_range[k]) for k in (*FIGURE_KEYS, *EXTRA_KEYS)}
        sim["seeds"] = list(self.seeds)
        return {
            "file": self.file,
            "layout": {"angle_deg": self.angle_deg, "distance_m": self.distance_m},
            "real": {k: self.real[k] for k in (*FIGURE_KEYS, *EXTRA_KEYS)},
            "simulated": sim,
        }


def compare_take(
    path: str | Path,
    walk: Motion,
    seeds: Sequence[int],
    params: TrackerParams | None = None,
) -> TakeResult:
    """Real figures of a take and the simulated ones over ``seeds`` (mean and range)."""
    if not seeds:
        raise InputError("give at least one seed")
    rec = read_kinect_multitrack(path)
    real = real_pair(rec)
    real_f = pair_figures(real)
    lay = take_layout(rec, real)
    sims = [pair_figures(simulated_pair(rec, walk, int(s), lay, params)) for s in seeds]
    keys = (*FIGURE_KEYS, *EXTRA_KEYS)
    mean = {k: float(np.nanmean([f[k] for f in sims])) for k in keys}
    rng_ = {k: (float(np.nanmin([f[k] for f in sims])), float(np.nanmax([f[k] for f in sims])))
            for k in keys}  # fmt: skip
    sim_joint = np.nanmean([np.asarray(f["per_joint_median_m"]) for f in sims], axis=0)
    return TakeResult(
        file=str(path),
        angle_deg=layout_angle_deg(lay),
        distance_m=float(lay.dist_m[0]),
        real={k: float(real_f[k]) for k in keys},
        simulated=mean,
        simulated_range=rng_,
        seeds=tuple(int(s) for s in seeds),
        real_per_joint_m=tuple(float(v) for v in np.asarray(real_f["per_joint_median_m"])),
        sim_per_joint_m=tuple(float(v) for v in sim_joint),
        per_seed=tuple({k: float(f[k]) for k in keys} for f in sims),
    )


# ------------------------------------------------------------------------------------------
# output


_UNITS = {
    "median_m": ("median", 100, "cm"),
    "p95_m": ("p95", 100, "cm"),
    "trunk_median_m": ("trunk (spine, shoulders) median", 100, "cm"),
    "extremity_median_m": ("wrists, hands, ankles, feet median", 100, "cm"),
    "lr_disagreement_fraction": ("left/right disagree", 100, "%"),
    "lr_disagreement_still_fraction": ("left/right disagree, standing", 100, "%"),
    "still_p95_m": ("p95 while standing", 100, "cm"),
    "still_jitter_m_per_frame": ("still spine jitter per frame", 1000, "mm"),
    "bone_length_cv": ("limb bone-length CV", 1, ""),
    "still_fraction": ("still frames", 100, "%"),
    "limb_angle_median_deg": ("knee and elbow angle median", 1, "deg"),
    "still_knee_angle_deg": ("front sensor's knee angle, standing", 1, "deg"),
}


def format_take(res: TakeResult) -> str:
    """One take's figures as a Markdown table (real, simulated mean, range, ratio)."""
    name = Path(res.file).name
    lines = [
        f"**{name}**: side sensor at {res.angle_deg:.0f} deg, {res.distance_m:.2f} m; "
        f"seeds {res.seeds[0]}-{res.seeds[-1]}",
        "",
        "| figure | real | simulated (mean) | simulated range | sim / real |",
        "|---|---|---|---|---|",
    ]
    for k in (*FIGURE_KEYS, *EXTRA_KEYS):
        label, scale, unit = _UNITS[k]
        r, s = res.real[k], res.simulated[k]
        lo, hi = res.simulated_range[k]
        digits = 3 if unit == "" else (2 if unit == "mm" else 1)
        ratio = f"{s / r:.2f}" if r else "-"
        lines.append(
            f"| {label} | {r * scale:.{digits}f} {unit} | {s * scale:.{digits}f} {unit} "
            f"| {lo * scale:.{digits}f}-{hi * scale:.{digits}f} | {ratio} |"
        )
    bad = res.failures()
    lines += ["", "acceptance: " + ("all met" if not bad else "; ".join(bad))]
    return "\n".join(lines)


def format_take_joints(results: Sequence[TakeResult]) -> str:
    """Per-joint median disagreement per take, real / simulated (cm)."""
    head = "| joint | " + " | ".join(f"{r.angle_deg:.0f} deg real / sim" for r in results) + " |"
    lines = [head, "|---" * (len(results) + 1) + "|"]
    for j, n in enumerate(JOINTS):
        cells = [f"{r.real_per_joint_m[j] * 100:.1f} / {r.sim_per_joint_m[j] * 100:.1f}"
                 for r in results]  # fmt: skip
        lines.append(f"| {n} | " + " | ".join(cells) + " |")
    return "\n".join(lines)

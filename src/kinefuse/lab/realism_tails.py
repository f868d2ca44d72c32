"""The heavy tails of two-sensor disagreement: gross failures, measured the same way on real and
simulated streams (:class:`kinefuse.lab.realism_takes.StreamPair`).

After pairing and one rigid fit (:func:`kinefuse.lab.realism.disagreement`), over the
distinct frames of the front sensor:

- a **limb run** is a run of pairs in which a limb (an arm: elbow, wrist, hand; a leg: knee,
  ankle, foot) is more than :data:`GROSS_M` off at some joint, in a pair that is not left/right
  mirrored; each has a length, a peak, the one-frame jump of the distal joint's distance at its
  start and at its end, and whether one stream alone moved at the start (its distal joint's step
  more than 3 times the other's: one sensor failed, not both);
- a **whole-body run**: the spine joints and the neck all more than 15 cm off;
- **frozen joints**: a joint of one stream that stays within 1 mm for 5 distinct frames or more
  while that stream's pelvis moves faster than 0.1 m/s (a held guess);
- the distribution of every joint distance, for the pictures of ``docs/realism.md``.

``studies/fit_tracker_tails.py`` prints these for the population and fits the failure processes of
:mod:`kinefuse.sim.tracker_failures` to them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.geometry.transforms import apply_transform
from kinefuse.core.skeleton import JOINT_INDEX, N_JOINTS
from kinefuse.lab.realism import disagreement
from kinefuse.lab.realism_takes import StreamPair, still_frames

Array = NDArray[np.float64]

#: A limb further off than this is a gross failure, m.
GROSS_M = 0.20
#: The whole body is off when every trunk joint is further off than this, m.
WHOLE_BODY_M = 0.15
LIMBS = {
    "ArmLeft": ("ElbowLeft", "WristLeft", "HandLeft"),
    "ArmRight": ("ElbowRight", "WristRight", "HandRight"),
    "LegLeft": ("KneeLeft", "AnkleLeft", "FootLeft"),
    "LegRight": ("KneeRight", "AnkleRight", "FootRight"),
}
_TRUNK = ("SpineBase", "SpineMid", "SpineShoulder", "Neck")


@dataclass(frozen=True)
class LimbRun:
    """One run of a limb more than :data:`GROSS_M` off."""

    limb: str
    duration_s: float
    peak_m: float
    onset_jump_m: float
    end_jump_m: float
    one_sensor: bool


@dataclass(frozen=True, eq=False)
class Tails:
    """The gross failures of one take (real or simulated)."""

    duration_s: float
    runs: tuple[LimbRun, ...]
    whole_body_runs: int
    whole_body_fraction: float
    mirrored_fraction: float
    frozen_fraction: float
    distances_m: Array  # (P, 25) over distinct frames

    @property
    def limb_rate_hz(self) -> float:
        return len(self.runs) / self.duration_s if self.duration_s > 0 else float("nan")


def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    d = np.diff(np.r_[0, mask.astype(np.int64), 0])
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=True))


def _frozen_fraction(joints: Array, t: Array, group: NDArray[np.int64]) -> float:
    fresh, _ = still_frames(joints, t, group)
    total = frozen = 0
    for label in np.unique(group):
        rows = np.flatnonzero((group == label) & fresh)
        if rows.size < 12:
            continue
        q = joints[rows]
        step = np.linalg.norm(np.diff(q, axis=0), axis=-1)  # (n-1, 25)
        pelvis = q[:, JOINT_INDEX["SpineBase"]]
        dt = np.maximum(np.diff(t[rows]), 1e-3)
        moving = np.linalg.norm(np.diff(pelvis, axis=0), axis=-1) / dt > 0.1
        for j in range(N_JOINTS):
            held = (step[:, j] < 0.001) & moving
            for a, b in _runs(held):
                if b - a >= 4:  # 5 frames within 1 mm
                    frozen += b - a
        total += int(moving.sum()) * N_JOINTS
    return frozen / total if total else float("nan")


def take_tails(pair: StreamPair) -> Tails:
    """Limb runs, whole-body runs, mirrored and frozen shares of one take's two streams."""
    d = disagreement(pair.joints_a, pair.joints_b, pair.idx_a, pair.idx_b)
    fresh_a, _ = still_frames(pair.joints_a, pair.t_sensor_a_s, pair.group_a)
    keep = fresh_a[pair.idx_a]
    dist = d.distances_m[keep]
    ia, ib = pair.idx_a[keep], pair.idx_b[keep]
    t = pair.t_sensor_a_s[ia]
    g = pair.group_a[ia]
    a = pair.joints_a[ia]
    b = apply_transform(d.b2a, pair.joints_b[ib])
    mirrored = d.mirrored[keep]
    duration = float(sum(np.ptp(t[g == k]) for k in np.unique(g)))
    runs: list[LimbRun] = []
    for name, joints in LIMBS.items():
        jj = [JOINT_INDEX[n] for n in joints]
        x = np.nanmax(np.where(np.isfinite(dist[:, jj]), dist[:, jj], 0.0), axis=1)
        for s, e in _runs((x > GROSS_M) & ~mirrored):
            if s == 0 or g[s - 1] != g[s] or g[e - 1] != g[s]:
                continue  # runs cut by a group boundary have no onset
            dj = jj[-1]
            sa = float(np.linalg.norm(a[s, dj] - a[s - 1, dj]))
            sb = float(np.linalg.norm(b[s, dj] - b[s - 1, dj]))
            end = float(dist[e - 1, dj] - dist[e, dj]) if e < len(dist) and g[e] == g[s] else np.nan
            runs.append(
                LimbRun(
                    limb=name,
                    duration_s=float(t[e - 1] - t[s]) + 1.0 / 30.0,
                    peak_m=float(x[s:e].max()),
                    onset_jump_m=float(dist[s, dj] - dist[s - 1, dj]),
                    end_jump_m=end,
                    one_sensor=max(sa, sb) > 3.0 * max(min(sa, sb), 1e-3),
                )
            )
    trunk = [JOINT_INDEX[n] for n in _TRUNK]
    whole = np.nanmin(np.where(np.isfinite(dist[:, trunk]), dist[:, trunk], 0.0), axis=1)
    whole_mask = whole > WHOLE_BODY_M
    frozen = np.nanmean(
        [
            _frozen_fraction(pair.joints_a, pair.t_sensor_a_s, pair.group_a),
            _frozen_fraction(pair.joints_b, pair.t_sensor_b_s, pair.group_b),
        ]
    )
    return Tails(
        duration_s=duration,
        runs=tuple(runs),
        whole_body_runs=len(_runs(whole_mask)),
        whole_body_fraction=float(whole_mask.mean()) if whole_mask.size else float("nan"),
        mirrored_fraction=float(mirrored.mean()) if mirrored.size else float("nan"),
        frozen_fraction=float(frozen),
        distances_m=dist,
    )

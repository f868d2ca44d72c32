"""Foot strikes from joint centres, and angle curves normalised to the gait cycle.

Foot strike after Zeni, Richards and Higginson (2008, *Gait & Posture* 27:710-714, "Two simple
methods for determining gait events during treadmill and overground walking using kinematic
data"): a foot strikes the ground when it is furthest ahead of the pelvis along the direction of
walking. Here the foot is the ankle joint centre (the heel marker's proxy every input has) and
the pelvis is ``SpineBase``; the direction of walking is the pelvis's mean horizontal velocity
over a sliding window of about one stride (a turn changes it); in place (a treadmill) it is the
axis the feet swing along, forward where they swing fast (swing is quicker than stance). A strike
is a local maximum of the foot's lead that stands out by :data:`MIN_PROMINENCE_M` and comes at least
:data:`MIN_STEP_S` after the previous one of the same foot. A *cycle* runs from one strike of a
foot to its next, when that lasts :data:`CYCLE_S`; angles are resampled to 101 points per cycle
(0-100 %).

Between two strikes the foot must swing from behind the pelvis to in front of it by
:data:`MIN_SWING_M`, and the other foot must strike once near the middle
(:data:`OPPOSITE_STRIKE`): a jump with both feet, a static trial or a range-of-motion phase gives
no strike, and none is made up. Steps taken while doing something else (a tennis player's
between serves) are strikes too: the strikes of each trial are in its ``gait.json``.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from kinefuse.biomech.sequence import SkeletonSequence

__all__ = [
    "CYCLE_S",
    "GaitEvents",
    "cycle_curves",
    "foot_strikes",
]

Array = NDArray[np.float64]

#: the pelvis's median horizontal speed above which the input is walking overground (else in
#: place: a treadmill, or no walk at all)
OVERGROUND_SPEED_M_S = 0.3
#: between two strikes the foot swings from behind the pelvis to in front of it by at least this
#: (a walking stride swings it 0.5-1 m; a shuffle or a lean much less)
MIN_SWING_M = 0.3
#: a strike must lead the pelvis by this much more than the lowest lead around it
MIN_PROMINENCE_M = 0.05
#: two strikes of one foot are at least this far apart (a stride is 0.8-1.6 s walking, about
#: 0.6 s running)
MIN_STEP_S = 0.4
#: a cycle (strike to the same foot's next strike) is kept when its length is in this range
CYCLE_S = (0.4, 2.5)
#: the other foot strikes once in this part of a cycle (about half way in walking and running)
OPPOSITE_STRIKE = (0.2, 0.8)
#: points per normalised cycle (0, 1, ..., 100 %)
CYCLE_POINTS = 101

_FEET = {"left": "AnkleLeft", "right": "AnkleRight"}


@dataclass(frozen=True)
class GaitEvents:
    """Foot strikes of one input: times in seconds (the input's time base) per side."""

    strikes_s: dict[str, tuple[float, ...]]
    travel_m: float

    def cycles(self, side: str) -> list[tuple[float, float]]:
        """The side's cycles (strike to next strike), those of a plausible length."""
        t = self.strikes_s.get(side, ())
        return [(a, b) for a, b in itertools.pairwise(t) if CYCLE_S[0] <= b - a <= CYCLE_S[1]]

    def to_json(self) -> dict[str, object]:
        return {
            "method": "Zeni et al. 2008: foot furthest ahead of the pelvis",
            "travel_m": round(self.travel_m, 3),
            "strikes_s": {k: [round(x, 4) for x in v] for k, v in self.strikes_s.items()},
            "cycles": {side: len(self.cycles(side)) for side in self.strikes_s},
        }


def _local_maxima(x: Array, min_gap: int, prominence: float) -> list[int]:
    """Indices of local maxima of ``x`` (NaN-free) at least ``min_gap`` apart, each higher by
    ``prominence`` than the lowest point between it and its neighbouring maxima."""
    from scipy.signal import find_peaks

    peaks, _ = find_peaks(x, distance=max(1, min_gap), prominence=prominence)
    return [int(p) for p in peaks]


def _walking_direction(pelvis: Array, feet: list[Array], rate: float) -> Array:
    """``(T, 2)`` unit horizontal direction of walking per frame (module notes)."""
    half = max(1, round(0.6 * rate))
    kernel = np.ones(2 * half + 1) / (2 * half + 1)
    vel = np.column_stack(
        [np.convolve(np.gradient(pelvis[:, k]), kernel, mode="same") * rate for k in range(2)]
    )
    speed = np.linalg.norm(vel, axis=1)
    if np.median(speed) >= OVERGROUND_SPEED_M_S:  # overground: where the pelvis goes
        return vel / np.where(speed > 0, speed, np.nan)[:, None]
    # in place (a treadmill): the axis the feet swing along, forward where they swing fast
    rel = np.concatenate([f - pelvis for f in feet])
    rel = rel[np.isfinite(rel).all(axis=1)]
    if len(rel) < 3:
        return np.full_like(pelvis, np.nan)
    axis = np.linalg.svd(rel - rel.mean(axis=0), full_matrices=False)[2][0]
    v = np.concatenate([np.gradient(f - pelvis, axis=0) @ axis for f in feet]) * rate
    v = v[np.isfinite(v)]
    forward = v[v > 0].mean() if (v > 0).any() else 0.0
    backward = -v[v < 0].mean() if (v < 0).any() else 0.0
    return np.tile(axis if forward >= backward else -axis, (len(pelvis), 1))


def foot_strikes(seq: SkeletonSequence) -> GaitEvents:
    """The foot strikes of a skeleton sequence (module notes); none where it is not a walk."""
    names = list(seq.joint_names)
    none: dict[str, tuple[float, ...]] = {"left": (), "right": ()}
    if "SpineBase" not in names or not all(j in names for j in _FEET.values()):
        return GaitEvents(none, 0.0)
    t = seq.t_s
    pelvis = seq.positions[:, names.index("SpineBase"), :2]
    ok = np.isfinite(pelvis).all(axis=1)
    if ok.sum() < 3 or t.size < 3:
        return GaitEvents(none, 0.0)
    rate = 1.0 / float(np.median(np.diff(t)))
    idx = np.arange(t.size)
    pelvis = np.column_stack([np.interp(idx, idx[ok], pelvis[ok, k]) for k in range(2)])
    travel = float(np.linalg.norm(pelvis[-1] - pelvis[0]))
    feet = {side: seq.positions[:, names.index(j), :2] for side, j in _FEET.items()}
    direction = _walking_direction(pelvis, list(feet.values()), rate)
    strikes: dict[str, tuple[float, ...]] = {}
    leads: dict[str, Array] = {}
    for side, foot in feet.items():
        lead = np.einsum("ij,ij->i", foot - pelvis, direction)
        good = np.isfinite(lead)
        if good.sum() < 3:
            strikes[side] = ()
            continue
        leads[side] = np.interp(idx, idx[good], lead[good])
        peaks = _local_maxima(leads[side], round(MIN_STEP_S * rate), MIN_PROMINENCE_M)
        strikes[side] = tuple(float(t[p]) for p in peaks if good[p])
    # a stride swings the foot from behind the pelvis to in front of it, and the other foot
    # strikes once in between, near the middle: a shuffle, a pivot, a lean or a jump is not one
    kept: dict[str, set[float]] = {side: set() for side in strikes}
    for side, times in strikes.items():
        other = np.asarray(strikes["right" if side == "left" else "left"])
        for a, b in itertools.pairwise(times):
            inside = (t >= a) & (t <= b)
            between = other[(other > a + OPPOSITE_STRIKE[0] * (b - a))
                            & (other < a + OPPOSITE_STRIKE[1] * (b - a))]  # fmt: skip
            if np.ptp(leads[side][inside]) >= MIN_SWING_M and between.size == 1:
                kept[side] |= {a, b}
    strikes = {side: tuple(sorted(v)) for side, v in kept.items()}
    return GaitEvents(strikes, travel)


def cycle_curves(t_s: Array, values: Array, cycles: list[tuple[float, float]]) -> Array:
    """``(n_cycles, 101)``: ``values`` (one angle over ``t_s``) resampled to 0-100 % of each
    cycle; a cycle with a gap (a NaN inside it) is NaN where the gap is."""
    out = np.full((len(cycles), CYCLE_POINTS), np.nan)
    ok = np.isfinite(values)
    for k, (a, b) in enumerate(cycles):
        inside = (t_s >= a) & (t_s <= b)
        if inside.sum() < 3 or not ok[inside].all():
            continue
        out[k] = np.interp(np.linspace(a, b, CYCLE_POINTS), t_s[inside], values[inside])
    return out

"""Gross tracking failures and the person level of the Kinect v2 tracker model.

Two processes measured on the real KinectMultiTrack population (participants 0-9, every main
take; ``studies/fit_tracker_tails.py`` prints the figures and the fitted values,
``docs/realism.md`` shows them):

**Thrown limbs** (:func:`gross_failures`). Now and then a real Kinect v2 places a whole limb
20-50 cm from where it is for a few frames: an arm (shoulder, elbow, wrist, hand, hand tip, thumb)
or a leg (hip, knee, ankle, foot). Thrown arms are rarer but last longer and go further than
thrown legs (``gross_arm_*``). Per sensor, independently of the other sensors (at 0 degrees the two
real sensors see the same picture yet disagree in such runs; at the onset one stream jumps and
the other does not in about 60 % of the runs), events arrive as a Poisson process; each picks a
limb (legs ``gross_leg_share`` of the time, either side), lasts a log-normal time, and displaces
the limb's distal joints by one vector (the middle joint half as much, the root
:data:`ROOT_WEIGHT`) of size
``gross_size_min_m`` plus an exponential excess, in a random direction of the body frame; it
starts and ends with a linear ramp of ``gross_ramp_s``.

**Whole-body jumps**: the same process with its own rate, moving every joint by one vector
(the real trunk is more than 15 cm off in both sensors' alignment in a few runs per take at
0 degrees).

**Person level** (:func:`draw_quality`): some people are tracked much worse than others (real
per-take medians at 45 degrees 2.9-11.8 cm). A subject-level factor ``q``, log-normal with median
1 and log-sigma ``person_log_sigma``, multiplies the per-sensor continuous errors of that subject
(pose-dependent offset, speed-dependent noise, far-limb error, view-dependent offset, inferred
error) and the failure rates (as ``q ** person_rate_exponent``). It is drawn once per subject
(:func:`kinefuse.sim.tracker.draw_subject_bias`) from a child random stream.

Every process draws from its own child stream (``numpy.random.Generator.spawn``), so the draws
of the components that existed before stay as they were; a rate or sigma of 0 switches a
process off.
"""

from __future__ import annotations

from typing import Final

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.skeleton import JOINT_INDEX, N_JOINTS
from kinefuse.sim.tracker_params import TrackerParams

Array = NDArray[np.float64]

#: Share of a thrown limb's displacement that its root (shoulder, hip) takes: real shoulders are
#: more than 20 cm off in 1.7 % of the moving frames at 0 degrees, a quarter of the arms' 6.3 %,
#: and hips more than 10 cm off in 6.9 % (the model without it: 0 %); docs/realism.md section 6.
ROOT_WEIGHT: Final = 0.3

#: The limbs a thrown-limb event moves: (joint, weight of the displacement).
LIMB_CHAINS: Final[dict[str, tuple[tuple[str, float], ...]]] = {
    "ArmLeft": (
        ("ShoulderLeft", ROOT_WEIGHT),
        ("ElbowLeft", 0.5),
        ("WristLeft", 1.0),
        ("HandLeft", 1.0),
        ("HandTipLeft", 1.0),
        ("ThumbLeft", 1.0),
    ),
    "ArmRight": (
        ("ShoulderRight", ROOT_WEIGHT),
        ("ElbowRight", 0.5),
        ("WristRight", 1.0),
        ("HandRight", 1.0),
        ("HandTipRight", 1.0),
        ("ThumbRight", 1.0),
    ),
    "LegLeft": (("HipLeft", ROOT_WEIGHT), ("KneeLeft", 0.5), ("AnkleLeft", 1.0), ("FootLeft", 1.0)),
    "LegRight": (
        ("HipRight", ROOT_WEIGHT),
        ("KneeRight", 0.5),
        ("AnkleRight", 1.0),
        ("FootRight", 1.0),
    ),
}


def _chain_weights() -> Array:
    w = np.zeros((len(LIMB_CHAINS), N_JOINTS))
    for k, chain in enumerate(LIMB_CHAINS.values()):
        for name, weight in chain:
            w[k, JOINT_INDEX[name]] = weight
    return w


_WEIGHTS: Final = _chain_weights()  # (4, 25): arms left, right, legs left, right


def draw_quality(rng: np.random.Generator, params: TrackerParams) -> float:
    """How badly this subject is tracked: a log-normal factor with median 1 (1.0 when off)."""
    if params.person_log_sigma <= 0:
        return 1.0
    return float(np.exp(rng.normal(0.0, params.person_log_sigma)))


def _ramp(length: int, ramp: int) -> Array:
    """Envelope of one event over its ``length`` frames: linear ramps of ``ramp`` frames."""
    k = np.arange(length)
    up = np.clip((k + 1) / ramp, 0.0, 1.0)
    down = np.clip((length - k) / ramp, 0.0, 1.0)
    return np.asarray(np.minimum(up, down), dtype=np.float64)


def gross_failures(
    rng: np.random.Generator,
    n_t: int,
    dt_s: float,
    params: TrackerParams,
    quality: float = 1.0,
    moving: NDArray[np.bool_] | None = None,
) -> Array:
    """Thrown limbs and whole-body jumps of one sensor: displacements ``(T, 25, 3)`` in the body
    frame (right, forward, up), metres; zeros when the rates are 0.

    Failures start only in ``moving`` frames (T,) (default: all): no real run starts while the
    person stands still. The rates are per second of motion.
    """
    p = params
    out = np.zeros((n_t, N_JOINTS, 3))
    if n_t == 0:
        return out
    frames = np.arange(n_t) if moving is None else np.flatnonzero(moving)
    scale = quality**p.person_rate_exponent
    span_s = frames.size * dt_s
    ramp = max(round(p.gross_ramp_s / dt_s), 1)
    for rate, whole in ((p.gross_limb_rate_hz, False), (p.gross_body_rate_hz, True)):
        n_events = int(rng.poisson(rate * scale * span_s)) if rate > 0 and span_s > 0 else 0
        if n_events == 0:
            continue
        starts = frames[rng.integers(0, max(frames.size, 1), n_events)]
        leg = rng.random(n_events) < p.gross_leg_share
        right = rng.random(n_events) < 0.5
        # thrown arms last longer and go further than thrown legs (real runs at 0 degrees:
        # arms median 0.13-0.20 s and 16-17 cm above 20 cm, legs 0.07-0.08 s and 9-11 cm)
        median_s = np.where(leg | whole, p.gross_duration_median_s, p.gross_arm_duration_median_s)
        scale_m = np.where(leg | whole, p.gross_size_scale_m, p.gross_arm_size_scale_m)
        dur = median_s * np.exp(rng.normal(0.0, p.gross_duration_log_sigma, n_events))
        lengths = np.maximum(np.round(dur / dt_s), 1).astype(np.int64)
        size = p.gross_size_min_m + rng.exponential(1.0, n_events) * scale_m
        direction = rng.normal(size=(n_events, 3))
        direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-12)
        limb = 2 * leg.astype(np.int64) + right.astype(np.int64)
        for e in range(n_events):
            a = int(starts[e])
            b = min(a + int(lengths[e]), n_t)
            env = _ramp(int(lengths[e]), ramp)[: b - a]
            w = np.ones(N_JOINTS) if whole else _WEIGHTS[limb[e]]
            out[a:b] += env[:, None, None] * w[None, :, None] * (size[e] * direction[e])[None, None]
    return out

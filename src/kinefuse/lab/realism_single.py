"""One simulated Kinect v2 sensor against the truth: the single-sensor realism check.

:func:`single_sensor_realism` runs real walking passes past sensors on a ring and compares every
report with the true joints: error level per joint, extremities worse than the trunk, INFERRED
joints at least twice as wrong as TRACKED ones, nothing outside the view reported TRACKED.
``docs/realism.md`` shows the figures. This is evaluation code: it reads the simulator's truth.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.frames.motion import Motion
from kinefuse.core.geometry.transforms import apply_transform, invert_transform, look_at
from kinefuse.core.skeleton import (
    JOINT_INDEX,
    JOINTS,
    MIRROR_INDEX,
    N_JOINTS,
    TrackingState,
    capsule_radii,
)
from kinefuse.errors import InputError
from kinefuse.lab.realism import _CORE, _EXTREMITIES
from kinefuse.sim.lab import subject_height
from kinefuse.sim.tracker import TrackerParams, draw_subject_bias, simulate_tracker

Array = NDArray[np.float64]


@dataclass(frozen=True)
class SingleSensorRealism:
    """Single-sensor error figures of simulated sensors against the truth, metres."""

    median_of_joint_medians_m: float
    overall_median_m: float
    per_joint_median_m: dict[str, float]
    core_median_m: float
    extremity_median_m: float
    tracked_median_m: float
    inferred_median_m: float
    state_fraction: dict[str, float]
    tracked_outside_view: int
    swapped_fraction: float

    def failures(self) -> list[str]:
        """The realism targets this result misses (empty when all are met)."""
        out = []
        for nm in ("median_of_joint_medians_m", "overall_median_m"):
            v = getattr(self, nm)
            if not 0.03 <= v <= 0.10:
                out.append(f"{nm} = {v * 100:.1f} cm, outside 3-10 cm")
        if not self.extremity_median_m > self.core_median_m:
            out.append(
                f"extremities ({self.extremity_median_m * 100:.1f} cm) not worse than spine and "
                f"shoulders ({self.core_median_m * 100:.1f} cm)"
            )
        if not self.inferred_median_m >= 2.0 * self.tracked_median_m:
            out.append(
                f"inferred {self.inferred_median_m * 100:.1f} cm < 2 x tracked "
                f"{self.tracked_median_m * 100:.1f} cm"
            )
        if self.tracked_outside_view:
            out.append(f"{self.tracked_outside_view} joints outside the view reported TRACKED")
        return out


def ring_layout(
    n_sensors: int = 4, *, radii_m: Sequence[float] = (2.0, 2.5, 3.0, 3.5)
) -> list[Array]:
    """``sensor2world`` of ``n_sensors`` on a 2-3.5 m ring, 1.0-1.2 m high, facing the centre."""
    if n_sensors < 1:
        raise InputError(f"n_sensors must be at least 1, got {n_sensors}")
    out = []
    for k in range(n_sensors):
        az = 2 * np.pi * k / n_sensors + np.pi / 8
        r = float(radii_m[k % len(radii_m)])
        h = 1.0 + 0.2 * k / max(n_sensors - 1, 1)
        pos = np.array([r * np.cos(az), r * np.sin(az), h])
        out.append(look_at(pos, np.array([0.0, 0.0, 1.0])))
    return out


def single_sensor_realism(
    passes: Sequence[Motion],
    rng: np.random.Generator,
    params: TrackerParams | None = None,
    *,
    sensors: Sequence[Array] | None = None,
) -> SingleSensorRealism:
    """Every sensor of ``sensors`` (default :func:`ring_layout`) against the truth, pooled.

    The subject is the model's typical person (``person_log_sigma`` 0): the targets are the
    literature's averages over subjects, not one drawn person's (one tracked 20 % worse than the
    typical one is as real, and the population comparison holds the spread).
    """
    tp = replace(TrackerParams() if params is None else params, person_log_sigma=0.0)
    rigs = ring_layout() if sensors is None else list(sensors)
    if not passes:
        raise InputError("no motion to simulate")
    subj = draw_subject_bias(rng, tp)
    radii = capsule_radii(subject_height(passes[0]))
    intr = Intrinsics()
    errs, states, outside, swapped = [], [], 0, []
    t0 = 0.0
    for m in passes:
        t = np.arange(0.0, m.duration_s, 1.0 / 30.0)
        truth = m.at(t)
        for s2w in rigs:
            out = simulate_tracker(truth, s2w, intr, radii, rng, tp, subject=subj, t_s=t0 + t)
            tsens = apply_transform(invert_transform(s2w), truth)
            errs.append(np.linalg.norm(out.joints_sensor - tsens, axis=-1))
            states.append(out.states)
            swapped.append(out.swapped)
            tracked = out.states == TrackingState.TRACKED
            # the point the tracker follows: the mirrored twin in swapped frames
            perm = np.where(out.swapped[:, None], np.asarray(MIRROR_INDEX), np.arange(N_JOINTS))
            followed = np.take_along_axis(tsens, perm[..., None], axis=1)
            outside += int((tracked & ~intr.in_view(out.joints_sensor)).sum())
            outside += int((tracked & ~intr.in_view(followed)).sum())
        t0 += m.duration_s + 10.0  # the passes are separate moments of the session
    e = np.concatenate(errs)
    st = np.concatenate(states)
    per_joint = np.array([np.median(e[np.isfinite(e[:, j]), j]) for j in range(N_JOINTS)])
    core = [JOINT_INDEX[n] for n in _CORE]
    ext = [JOINT_INDEX[n] for n in _EXTREMITIES]
    fin = np.isfinite(e)
    return SingleSensorRealism(
        median_of_joint_medians_m=float(np.median(per_joint)),
        overall_median_m=float(np.median(e[fin])),
        per_joint_median_m={n: float(per_joint[j]) for j, n in enumerate(JOINTS)},
        core_median_m=float(np.median(per_joint[core])),
        extremity_median_m=float(np.median(per_joint[ext])),
        tracked_median_m=float(np.median(e[st == TrackingState.TRACKED])),
        inferred_median_m=float(np.median(e[st == TrackingState.INFERRED])),
        state_fraction={s.name.lower(): float((st == s).mean()) for s in TrackingState},
        tracked_outside_view=outside,
        swapped_fraction=float(np.concatenate(swapped).mean()),
    )


def format_single(res: SingleSensorRealism) -> str:
    """The single-sensor figures as Markdown."""
    fr = res.state_fraction
    lines = [
        "| figure | value | target |",
        "|---|---|---|",
        f"| median over joints of the per-joint median | "
        f"{res.median_of_joint_medians_m * 100:.1f} cm | 3-10 cm |",
        f"| overall median | {res.overall_median_m * 100:.1f} cm | 3-10 cm |",
        f"| wrists, hands, ankles, feet (median of joint medians) | "
        f"{res.extremity_median_m * 100:.1f} cm | > spine and shoulders |",
        f"| spine and shoulders | {res.core_median_m * 100:.1f} cm | |",
        f"| TRACKED joints | {res.tracked_median_m * 100:.1f} cm | |",
        f"| INFERRED joints | {res.inferred_median_m * 100:.1f} cm | >= 2 x TRACKED |",
        f"| TRACKED joints outside the view | {res.tracked_outside_view} | 0 |",
        f"| states tracked / inferred / not tracked | {fr['tracked']:.2f} / "
        f"{fr['inferred']:.2f} / {fr['not_tracked']:.2f} | |",
        f"| frames left/right swapped | {res.swapped_fraction:.2f} | |",
    ]
    return "\n".join(lines)

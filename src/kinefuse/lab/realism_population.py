"""Real against simulated figures as populations: ``python studies/realism.py --population [DIR]``.

One real take is one person at one layout; one simulated copy of a take with one seed is one
simulated subject (its own subject-level draw, :func:`kinefuse.sim.tracker.draw_subject_bias`,
hence its own tracking quality). Per layout (0, 45, 90 degrees) this module compares the
distribution of per-take figures over the real participants with the same over the simulated
subjects (every real take simulated with seeds ``0..N-1``):

``median_of_medians``, ``median_of_p95``
    the median over takes of each take's median and p95 pair disagreement;
``iqr_of_medians``
    the interquartile range over takes of the per-take medians: how differently people are
    tracked;
``median_still_jitter``, ``median_bone_cv``, ``median_lr_disagreement``,
``median_limb_angle``, ``median_still_knee_angle``
    the median over takes of the still spine jitter, the limb bone-length CV, the left/right
    disagreement, the knee and elbow angle disagreement and the front sensor's knee angle while
    standing.

Each comes with a 90 % bootstrap interval (takes resampled, 2000 draws, seed 0). The acceptance
of issue 21 is in :data:`POPULATION_BANDS`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.lab.realism_takes import TakeResult

Array = NDArray[np.float64]

#: Layouts by the angle between the two sensors seen from the person, degrees.
LAYOUT_ANGLES = {"0": 0.0, "45": 45.0, "90": 90.0}


def layout_key(angle_deg: float) -> str:
    """The nearest of the three KinectMultiTrack layouts ("0", "45", "90")."""
    return min(LAYOUT_ANGLES, key=lambda k: abs(LAYOUT_ANGLES[k] - angle_deg))


def _iqr(v: Array) -> float:
    q75, q25 = np.percentile(v, [75, 25])
    return float(q75 - q25)


#: statistic name -> (per-take figure, reducer over takes)
STATISTICS: dict[str, tuple[str, Callable[[Array], float]]] = {
    "median_of_medians": ("median_m", lambda v: float(np.median(v))),
    "median_of_p95": ("p95_m", lambda v: float(np.median(v))),
    "iqr_of_medians": ("median_m", _iqr),
    "median_still_jitter": ("still_jitter_m_per_frame", lambda v: float(np.median(v))),
    "median_bone_cv": ("bone_length_cv", lambda v: float(np.median(v))),
    "median_lr_disagreement": ("lr_disagreement_fraction", lambda v: float(np.median(v))),
    "median_limb_angle": ("limb_angle_median_deg", lambda v: float(np.median(v))),
    "median_still_knee_angle": ("still_knee_angle_deg", lambda v: float(np.median(v))),
}
#: Acceptance of issue 21: simulated / real of each statistic within [low, high].
POPULATION_BANDS: dict[str, tuple[float, float]] = {
    "median_of_medians": (0.8, 1.2),
    "median_of_p95": (0.7, 1.3),
    "iqr_of_medians": (0.5, 2.0),
    "median_still_jitter": (0.5, 2.0),
    "median_bone_cv": (1 / 1.5, 1.5),
}


def _interval(v: Array, reduce: Callable[[Array], float], n_boot: int = 2000) -> list[float]:
    rng = np.random.default_rng(0)
    idx = rng.integers(0, v.size, (n_boot, v.size))
    boots = np.array([reduce(v[i]) for i in idx])
    return [float(np.percentile(boots, 5)), float(np.percentile(boots, 95))]


def population_summary(results: Sequence[TakeResult]) -> dict[str, dict[str, Any]]:
    """Per layout: each statistic of :data:`STATISTICS`, real and simulated, with intervals.

    Returns ``{layout: {"n_real_takes", "n_simulated", "files", stat: {"real", "real_interval",
    "simulated", "simulated_interval", "ratio"}}}``. The simulated population is every seed of
    every take (``TakeResult.per_seed``).
    """
    out: dict[str, dict[str, Any]] = {}
    for key in LAYOUT_ANGLES:
        group = [r for r in results if layout_key(r.angle_deg) == key]
        if not group:
            continue
        entry: dict[str, Any] = {
            "n_real_takes": len(group),
            "n_simulated": sum(len(r.per_seed) for r in group),
            "files": [r.file for r in group],
        }
        for stat, (fig, reduce) in STATISTICS.items():
            real = np.array([r.real[fig] for r in group], dtype=np.float64)
            sim = np.array([f[fig] for r in group for f in r.per_seed], dtype=np.float64)
            real = real[np.isfinite(real)]
            sim = sim[np.isfinite(sim)]
            if not (real.size and sim.size):
                continue
            rv, sv = reduce(real), reduce(sim)
            entry[stat] = {
                "real": rv,
                "real_interval": _interval(real, reduce),
                "simulated": sv,
                "simulated_interval": _interval(sim, reduce),
                "ratio": sv / rv if rv else float("nan"),
            }
        out[key] = entry
    return out


def population_failures(summary: dict[str, dict[str, Any]]) -> list[str]:
    """The acceptance items of :data:`POPULATION_BANDS` that a summary misses."""
    bad = []
    for key, entry in summary.items():
        for stat, (lo, hi) in POPULATION_BANDS.items():
            if stat not in entry:
                continue
            r = entry[stat]["ratio"]
            if not lo <= r <= hi:
                bad.append(f"{key} deg {stat}: sim/real {r:.2f}, outside {lo:.2f}-{hi:.2f}")
    return bad


_SCALE = {
    "median_of_medians": (100, "cm", 1),
    "median_of_p95": (100, "cm", 1),
    "iqr_of_medians": (100, "cm", 2),
    "median_still_jitter": (1000, "mm", 2),
    "median_bone_cv": (1, "", 3),
    "median_lr_disagreement": (100, "%", 1),
    "median_limb_angle": (1, "deg", 1),
    "median_still_knee_angle": (1, "deg", 1),
}


def format_population(summary: dict[str, dict[str, Any]]) -> str:
    """The population comparison as a Markdown table (one block of rows per layout)."""
    lines = [
        "| layout | statistic | real (90 % interval) | simulated (90 % interval) | sim / real "
        "| band |",
        "|---|---|---|---|---|---|",
    ]
    for key, entry in summary.items():
        head = f"{key} deg ({entry['n_real_takes']} takes, {entry['n_simulated']} sim.)"
        for stat in STATISTICS:
            if stat not in entry:
                continue
            e = entry[stat]
            scale, unit, dig = _SCALE[stat]

            def fmt(v: float, iv: list[float], s: float = scale, d: int = dig) -> str:
                return f"{v * s:.{d}f} ({iv[0] * s:.{d}f}-{iv[1] * s:.{d}f})"

            band = POPULATION_BANDS.get(stat)
            band_s = f"{band[0]:.2f}-{band[1]:.2f}" if band else ""
            lines.append(
                f"| {head} | {stat} ({unit or '1'}) | {fmt(e['real'], e['real_interval'])} "
                f"| {fmt(e['simulated'], e['simulated_interval'])} | {e['ratio']:.2f} | {band_s} |"
            )
            head = ""
    bad = population_failures(summary)
    lines += ["", "population acceptance: " + ("all met" if not bad else "; ".join(bad))]
    return "\n".join(lines)

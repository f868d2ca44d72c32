"""The person level of the tracker model, fitted from per-take medians (issue 21).

A real take is one person ``p`` at one layout ``l``. Its log median pair disagreement is modelled
as a random-effects sum ``log m[p, l] = a[l] + u[p] + e[p, l]``: a layout effect, a person effect
(how well this body is tracked, the same at every layout) and take noise. :func:`two_way_fit`
estimates ``a`` and ``u`` by median polish (robust: one badly tracked person moves neither the
layout effects nor the other people's effects).

``TrackerParams.person_log_sigma`` is the spread of ``u`` (:func:`person_log_sigma`), a
random-effects variance split made robust: over every pair of takes, the difference of their
layout-centred logs has variance ``2 sigma_e^2`` when both are one person's (the person
cancels: take noise alone) and ``2 (sigma_u^2 + sigma_e^2)`` when they are two people's, so
``sigma_u^2 = (S_between^2 - S_within^2) / 2``, each ``S`` the robust SD 1.4826 median |d| of
those differences. It ignores up to half the pairs being far out (one badly tracked person
of five makes a sixth of the between pairs), so one badly tracked person moves the estimate little
(the interquartile range of per-take medians that the earlier estimator used breaks at a
quarter: one participant with two or three takes among a dozen). The take noise is the
simulator's own (every simulated take has its own subject, :func:`subject_seed`); how far it is
from the real one is reported as ``s_real`` against ``s_sim`` (the Qn of the layout-centred
logs, real and simulated with the person level off) and ``total_match``
``sqrt(max(s_real^2 - s_sim^2, 0))``, the value that would make the simulated spread of per-take
medians at a layout equal the real one by the person level alone (the earlier estimator's idea).

:func:`person_outliers` reports the people whose effect lies more than ``z`` robust standard
deviations of the person effects away from the others: the sign that the person distribution
has a heavy tail (a few people tracked much worse), which a log-normal ``q`` does not reproduce.
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from math import comb

import numpy as np
from numpy.typing import NDArray

from kinefuse.errors import InputError

Array = NDArray[np.float64]

#: Consistency factor of Qn for the normal distribution (Rousseeuw and Croux 1993).
_QN_NORMAL = 2.2219
#: Their small-sample corrections, n = 2..9; beyond, n / (n + 1.4) (n odd) or n / (n + 3.8).
_QN_SMALL = (0.399, 0.994, 0.512, 0.844, 0.611, 0.857, 0.669, 0.872)


def qn_scale(x: Sequence[float] | Array) -> float:
    """The Qn scale estimator of ``x`` (a robust standard deviation, 50 % breakdown).

    The k-th smallest of the pairwise distances ``|x_i - x_j|``, ``k = C(n // 2 + 1, 2)``, times
    2.2219 and a small-sample factor, so that it estimates the standard deviation of normal data.
    NaNs are dropped; ``nan`` for fewer than two values.
    """
    v = np.asarray(x, dtype=np.float64)
    v = v[np.isfinite(v)]
    n = v.size
    if n < 2:
        return float("nan")
    i, j = np.triu_indices(n, 1)
    d = np.sort(np.abs(v[i] - v[j]))
    k = comb(n // 2 + 1, 2)
    large = n / (n + 1.4) if n % 2 else n / (n + 3.8)
    c = _QN_SMALL[n - 2] if n <= 9 else large
    return float(_QN_NORMAL * c * d[k - 1])


@dataclass(frozen=True)
class TwoWayFit:
    """``log m = overall + layout[l] + person[p] + residual`` (median polish)."""

    overall: float
    layout: dict[str, float]
    person: dict[str, float]
    residual: Array  # per take, in input order

    def layout_centred(self, logs: Array, layouts: Sequence[str]) -> Array:
        """``log m - overall - layout[l]``: person effect plus take noise, per take."""
        return np.asarray(
            [x - self.overall - self.layout[lay] for x, lay in zip(logs, layouts, strict=True)]
        )


def two_way_fit(
    log_medians: Sequence[float], layouts: Sequence[str], persons: Sequence[str], sweeps: int = 20
) -> TwoWayFit:
    """Median polish of the log per-take medians on layout and person (Tukey).

    Alternately removes each person's and each layout's median residual; a person seen at one
    layout only gets the effect its take shows relative to that layout.
    """
    x = np.asarray(log_medians, dtype=np.float64)
    if not (x.size == len(layouts) == len(persons)) or x.size == 0:
        raise InputError("give one layout and one person per log median, at least one take")
    if not np.all(np.isfinite(x)):
        raise InputError("the log medians must be finite")
    lay = np.asarray(layouts)
    per = np.asarray(persons)
    res = x.copy()
    overall = 0.0
    a = {k: 0.0 for k in dict.fromkeys(lay.tolist())}
    u = {k: 0.0 for k in dict.fromkeys(per.tolist())}
    for _ in range(sweeps):
        for eff, key in ((u, per), (a, lay)):
            for k in eff:
                sel = key == k
                m = float(np.median(res[sel]))
                eff[k] += m
                res[sel] -= m
            c = float(np.median(list(eff.values())))
            for k in eff:
                eff[k] -= c
            overall += c
    return TwoWayFit(overall, a, u, res)


@dataclass(frozen=True)
class PersonFit:
    """The person level fitted to real per-take medians (see the module)."""

    person_log_sigma: float  # sigma_u, the person effects' spread less the take noise in them
    s_real: float  # Qn of the real layout-centred logs
    s_sim: float  # the same over the simulated takes (person level off)
    total_match: float  # sqrt(max(s_real^2 - s_sim^2, 0))
    person_sd: float  # Qn of the real person effects
    take_sd: float  # sigma_e: robust SD of differences between two takes of a person / sqrt 2
    n_takes: int
    n_persons: int


def _abs_scale(d: Array) -> float:
    """A robust standard deviation of differences (centred on 0): 1.4826 median |d|."""
    return float(1.4826 * np.median(np.abs(d)))


def layout_spread(log_medians: Sequence[float], layouts: Sequence[str]) -> float:
    """Qn of the logs about their layout's median, pooled over layouts (simulated takes)."""
    x = np.asarray(log_medians, dtype=np.float64)
    lay = np.asarray(layouts)
    centred = np.concatenate([x[lay == k] - np.median(x[lay == k]) for k in dict.fromkeys(lay)])
    return qn_scale(centred)


def person_log_sigma(
    real_log_medians: Sequence[float],
    real_layouts: Sequence[str],
    real_persons: Sequence[str],
    sim_log_medians: Sequence[float],
    sim_layouts: Sequence[str],
) -> PersonFit:
    """The person level (``sigma_u``, see the module) and the take-noise check.

    The real takes are centred by the layout effects of :func:`two_way_fit` (so that who was
    seen at which layout does not shift the centres); the simulated ones by their layout's
    median (every simulated take is its own subject, there is no person to remove).
    """
    fit = two_way_fit(real_log_medians, real_layouts, real_persons)
    x = np.asarray(real_log_medians, dtype=np.float64)
    s_real = qn_scale(fit.layout_centred(x, real_layouts))
    s_sim = layout_spread(sim_log_medians, sim_layouts)
    if not (np.isfinite(s_real) and np.isfinite(s_sim)):
        raise InputError("need at least two real and two simulated takes")
    centred = fit.layout_centred(x, real_layouts)
    per = np.asarray(real_persons)
    # differences of layout-centred logs between two takes: of one person, take noise alone
    # (variance 2 sigma_e^2); of two people, person and take (2 (sigma_u^2 + sigma_e^2))
    i, j = np.triu_indices(x.size, 1)
    same = per[i] == per[j]
    d = centred[i] - centred[j]
    if same.sum() < 2 or (~same).sum() < 2:
        raise InputError("need at least two people with two takes each")
    take_sd = _abs_scale(d[same]) / np.sqrt(2.0)
    total_sd = _abs_scale(d[~same]) / np.sqrt(2.0)
    person_sd = qn_scale(list(fit.person.values()))
    sigma_u2 = total_sd**2 - take_sd**2
    return PersonFit(
        person_log_sigma=float(np.sqrt(max(sigma_u2, 0.0))),
        s_real=s_real,
        s_sim=s_sim,
        total_match=float(np.sqrt(max(s_real**2 - s_sim**2, 0.0))),
        person_sd=person_sd,
        take_sd=float(take_sd),
        n_takes=int(x.size),
        n_persons=len(fit.person),
    )


def person_outliers(fit: TwoWayFit, z: float = 3.0) -> dict[str, float]:
    """People whose effect is more than ``z`` robust SDs (Qn over the other people's effects,
    floored at 0.05) from the median of the others: ``{person: effect}``."""
    out = {}
    for p, v in fit.person.items():
        others = [w for q, w in fit.person.items() if q != p]
        if len(others) < 2:
            continue
        s = max(qn_scale(others), 0.05)
        if abs(v - float(np.median(others))) > z * s:
            out[p] = v
    return out


def subject_seed(file_name: str, k: int) -> int:
    """Seed ``k`` of the simulated subjects of a take, unique per take.

    ``simulated_pair`` seeds its generator with ``[seed, 9, kinect_config]``: with seeds
    ``0..N-1`` for every take, all takes of a layout share the same N simulated subjects (the
    same person-level draw), so a layout's simulated spread of per-take medians rests on N draws.
    This gives take ``Study_P_Kinect_C_...`` the seeds ``1000 * (P + 1) + k``.
    """
    try:
        p = int(file_name.split("_")[1])
    except (IndexError, ValueError) as exc:
        raise InputError(f"not a KinectMultiTrack take name (Study_N_...): {file_name}") from exc
    if k < 0 or k >= 1000:
        raise InputError(f"seed index must be in 0..999, got {k}")
    return 1000 * (p + 1) + k


def iqr_band_pass_rate(
    n_real: int,
    n_sim: int,
    band: tuple[float, float] = (0.5, 2.0),
    draws: int = 20000,
    seed: int = 0,
) -> float:
    """How often a perfect model passes the IQR band: the share of draws in which the IQR of
    ``n_sim`` normal values over that of ``n_real`` from the same distribution lies in ``band``.
    """
    if n_real < 2 or n_sim < 2:
        raise InputError("need at least two real and two simulated takes")
    rng = np.random.default_rng(seed)

    def iqr(n: int) -> Array:
        q75, q25 = np.percentile(rng.normal(size=(draws, n)), [75, 25], axis=1)
        return np.asarray(q75 - q25, dtype=np.float64)

    ratio = iqr(n_sim) / iqr(n_real)
    return float(np.mean((ratio >= band[0]) & (ratio <= band[1])))


def population_seeds(file_name: str, n: int) -> list[int]:
    """The ``n`` simulated subjects of a take in a population comparison: the participant's own
    (:func:`subject_seed`, shared by that participant's takes at every layout), or, for a file not
    named as KinectMultiTrack names its takes, seeds of its own from its name. Seeds ``0..n-1``
    for every take would give every take of a layout the same ``n`` person-level draws, and the
    simulated spread between people would rest on ``n``."""
    try:
        return [subject_seed(file_name, k) for k in range(n)]
    except InputError:
        base = 1000 * (1000 + zlib.crc32(file_name.encode()) % 1_000_000)
        return [base + k for k in range(n)]

"""Error metrics of joint positions against the truth (evaluation code: reads truth)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from kinefuse.skeleton import JOINTS


def position_errors(estimate: ArrayLike, truth: ArrayLike) -> dict[str, Any]:
    """Euclidean joint errors of ``estimate`` against ``truth``, both ``(T, 25, 3)`` metres.

    Frames or joints where the estimate is NaN are left out of the statistics and counted in
    ``missing_fraction``.

    Returns
    -------
    dict
        ``mae_m`` (mean), ``rmse_m``, ``median_m``, ``p95_m``, ``frames`` (frames with at least
        one estimated joint), ``missing_fraction``, ``by_joint`` ``{name: mae_m}``.
    """
    est = np.asarray(estimate, dtype=np.float64)
    tru = np.asarray(truth, dtype=np.float64)
    if est.shape != tru.shape or est.ndim != 3 or est.shape[1:] != (len(JOINTS), 3):
        raise ValueError(
            f"estimate and truth must both be (T, 25, 3), got {est.shape} and {tru.shape}"
        )
    e = np.linalg.norm(est - tru, axis=-1)
    ok = np.isfinite(e)
    if not ok.any():
        nan = float("nan")
        return {
            "mae_m": nan,
            "rmse_m": nan,
            "median_m": nan,
            "p95_m": nan,
            "frames": 0,
            "missing_fraction": 1.0,
            "by_joint": {n: nan for n in JOINTS},
        }
    v = e[ok]
    with np.errstate(invalid="ignore"):
        by_joint = np.nanmean(np.where(ok, e, np.nan), axis=0)
    return {
        "mae_m": float(v.mean()),
        "rmse_m": float(np.sqrt(np.mean(v**2))),
        "median_m": float(np.median(v)),
        "p95_m": float(np.percentile(v, 95)),
        "frames": int(ok.any(axis=1).sum()),
        "missing_fraction": float(1.0 - ok.mean()),
        "by_joint": {n: float(by_joint[j]) for j, n in enumerate(JOINTS)},
    }


def gain_ci(
    estimate: ArrayLike,
    reference: ArrayLike,
    truth: ArrayLike,
    *,
    block: int = 30,
    n_boot: int = 1000,
    seed: int = 0,
) -> tuple[float, float, float]:
    """How much lower ``estimate``'s MAE is than ``reference``'s, in percent of the reference's,
    with a 95 % confidence interval: ``(gain, low, high)``.

    Both are ``(T, 25, 3)`` on the same frames as ``truth``. Errors of neighbouring frames are
    correlated, so the interval comes from a paired circular block bootstrap over frames (blocks
    of ``block`` frames, 1 s at 30 Hz): a gain whose interval excludes 0 is one this session
    can tell apart from chance. Only joints both estimate are compared.
    """
    tru = np.asarray(truth, dtype=np.float64)
    ea = np.linalg.norm(np.asarray(estimate, dtype=np.float64) - tru, axis=-1)
    eb = np.linalg.norm(np.asarray(reference, dtype=np.float64) - tru, axis=-1)
    ok = np.isfinite(ea) & np.isfinite(eb)
    sa = np.where(ok, ea, 0.0).sum(axis=1)  # per-frame sums, (T,)
    sb = np.where(ok, eb, 0.0).sum(axis=1)
    if sb.sum() <= 0:
        nan = float("nan")
        return nan, nan, nan
    gain = 100.0 * (1.0 - sa.sum() / sb.sum())
    n = sa.size
    b = max(1, min(block, n))
    n_blocks = -(-n // b)
    rng = np.random.default_rng(seed)
    starts = rng.integers(0, n, size=(n_boot, n_blocks))  # circular: every frame as likely
    idx = ((starts[..., None] + np.arange(b)) % n).reshape(n_boot, -1)[:, :n]
    boot = 100.0 * (1.0 - sa[idx].sum(axis=1) / np.maximum(sb[idx].sum(axis=1), 1e-300))
    low, high = np.percentile(boot, [2.5, 97.5])
    return float(gain), float(low), float(high)

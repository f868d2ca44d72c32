"""Error metrics of joint positions against the truth (evaluation code: reads truth)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.core.skeleton import JOINTS


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
    n = ok.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        by_joint = np.where(ok, e, 0.0).sum(axis=0) / n  # NaN for a joint never estimated
    return {
        "mae_m": float(v.mean()),
        "rmse_m": float(np.sqrt(np.mean(v**2))),
        "median_m": float(np.median(v)),
        "p95_m": float(np.percentile(v, 95)),
        "frames": int(ok.any(axis=1).sum()),
        "missing_fraction": float(1.0 - ok.mean()),
        "by_joint": {n: float(by_joint[j]) for j, n in enumerate(JOINTS)},
    }


#: A difference whose whole 95 % interval lies within this many percent of zero is reported as
#: "no clear difference": it is below the precision the reports print.
NEGLIGIBLE_PERCENT = 0.05


def verdict(low_percent: float, high_percent: float) -> str:
    """``"gain"``, ``"loss"`` or ``"no clear difference"`` for a 95 % interval of a gain.

    The interval must exclude zero, and by more than :data:`NEGLIGIBLE_PERCENT`, to count.
    """
    if not (np.isfinite(low_percent) and np.isfinite(high_percent)):
        return "no clear difference"
    if low_percent > NEGLIGIBLE_PERCENT:
        return "gain"
    if high_percent < -NEGLIGIBLE_PERCENT:
        return "loss"
    return "no clear difference"


def block_bootstrap_indices(n: int, *, block: int, n_boot: int, seed: int) -> NDArray[np.intp]:
    """Frame indices ``(n_boot, n)`` of circular block-bootstrap resamples of ``n >= 1`` frames.

    Each resample joins ``ceil(n / b)`` blocks of ``b = clip(block, 1, n)`` consecutive frames
    (wrapping past the end, so every frame is as likely) drawn from ``default_rng(seed)``, cut to
    ``n``. Neighbouring frames' errors are correlated; blocks keep that correlation in.
    """
    starts, b = _bootstrap_starts(n, block=block, n_boot=n_boot, seed=seed)
    return _resample_rows(starts, b, n)


#: array elements a bootstrap gathers at once (:func:`block_bootstrap_sums`)
BOOTSTRAP_BATCH_ELEMENTS = 1 << 20


def _bootstrap_starts(
    n: int, *, block: int, n_boot: int, seed: int
) -> tuple[NDArray[np.int64], int]:
    """The resamples' block starts ``(n_boot, ceil(n / b))`` and the block length ``b``."""
    b = max(1, min(block, n))
    rng = np.random.default_rng(seed)
    return rng.integers(0, n, size=(n_boot, -(-n // b))), b


def _resample_rows(starts: NDArray[np.int64], b: int, n: int) -> NDArray[np.intp]:
    """Frame indices ``(len(starts), n)`` of the resamples with these block starts."""
    return ((starts[..., None] + np.arange(b)) % n).reshape(len(starts), -1)[:, :n]


def block_bootstrap_sums(
    values: Sequence[ArrayLike], *, block: int, n_boot: int, seed: int
) -> list[NDArray[Any]]:
    """Each ``v (n, ...)``'s sums over the frames of every resample of
    :func:`block_bootstrap_indices` ``(n, block, n_boot, seed)``: ``v[idx].sum(axis=1)``, shape
    ``(n_boot, ...)``, the same numbers, gathered a few resamples at a time so that neither the
    ``(n_boot, n)`` indices nor the ``(n_boot, n, ...)`` gathers exist whole (at 1000 resamples
    of a 10-minute session they were 144 MB each, and 3.6 GB for per-joint errors)."""
    vs = [np.asarray(v) for v in values]
    n = vs[0].shape[0]
    if any(v.shape[0] != n for v in vs):
        raise ValueError("block_bootstrap_sums: every array needs the same number of frames")
    starts, b = _bootstrap_starts(n, block=block, n_boot=n_boot, seed=seed)
    width = max(max(int(np.prod(v.shape[1:])) for v in vs), 1)
    rows = max(1, BOOTSTRAP_BATCH_ELEMENTS // max(n * width, 1))
    parts: list[list[NDArray[Any]]] = [[] for _ in vs]
    for r in range(0, n_boot, rows):
        idx = _resample_rows(starts[r : r + rows], b, n)
        for p, v in zip(parts, vs, strict=True):
            p.append(v[idx].sum(axis=1))
    return [
        np.concatenate(p) if p else np.zeros((0, *v.shape[1:]))
        for p, v in zip(parts, vs, strict=True)
    ]


def gain(
    estimate: ArrayLike,
    reference: ArrayLike,
    truth: ArrayLike,
    *,
    block: int = 30,
    n_boot: int = 1000,
    seed: int = 0,
) -> dict[str, Any]:
    """How much lower ``estimate``'s MAE is than ``reference``'s, on the joints both estimate.

    One definition in both units: ``gain_m = MAE_ref - MAE_est`` and ``gain_percent = 100 *
    gain_m / MAE_ref``, both over the same frames and joints (those where both are finite), so
    they always have the same sign. Errors of neighbouring frames are correlated, so the 95 %
    intervals come from a paired circular block bootstrap over frames (blocks of ``block``
    frames, 1 s at 30 Hz).

    Returns
    -------
    dict
        ``gain_m``, ``gain_percent``, ``gain_ci95_m`` ``[low, high]``, ``gain_ci95_percent``,
        ``verdict`` (:func:`verdict`), ``mae_m`` and ``mae_reference_m`` on the common joints,
        ``common_fraction`` (share of frames x joints both estimate). NaN where nothing is common.
    """
    tru = np.asarray(truth, dtype=np.float64)
    ea = np.linalg.norm(np.asarray(estimate, dtype=np.float64) - tru, axis=-1)
    eb = np.linalg.norm(np.asarray(reference, dtype=np.float64) - tru, axis=-1)
    ok = np.isfinite(ea) & np.isfinite(eb)
    sa = np.where(ok, ea, 0.0).sum(axis=1)  # per-frame sums, (T,)
    sb = np.where(ok, eb, 0.0).sum(axis=1)
    cnt = ok.sum(axis=1).astype(np.float64)
    nan = float("nan")
    out: dict[str, Any] = {
        "gain_m": nan,
        "gain_percent": nan,
        "gain_ci95_m": [nan, nan],
        "gain_ci95_percent": [nan, nan],
        "verdict": "no clear difference",
        "mae_m": nan,
        "mae_reference_m": nan,
        "common_fraction": float(ok.mean()) if ok.size else 0.0,
    }
    if sb.sum() <= 0 or cnt.sum() == 0:
        return out
    a_, b_, c_ = block_bootstrap_sums([sa, sb, cnt], block=block, n_boot=n_boot, seed=seed)
    c_ = np.maximum(c_, 1.0)
    boot_m = (b_ - a_) / c_
    boot_pct = 100.0 * (1.0 - a_ / np.maximum(b_, 1e-300))
    low_m, high_m = np.percentile(boot_m, [2.5, 97.5])
    low_p, high_p = np.percentile(boot_pct, [2.5, 97.5])
    out.update(
        gain_m=float((sb.sum() - sa.sum()) / cnt.sum()),
        gain_percent=float(100.0 * (1.0 - sa.sum() / sb.sum())),
        gain_ci95_m=[float(low_m), float(high_m)],
        gain_ci95_percent=[float(low_p), float(high_p)],
        verdict=verdict(float(low_p), float(high_p)),
        mae_m=float(sa.sum() / cnt.sum()),
        mae_reference_m=float(sb.sum() / cnt.sum()),
    )
    return out


def gain_ci(
    estimate: ArrayLike,
    reference: ArrayLike,
    truth: ArrayLike,
    *,
    block: int = 30,
    n_boot: int = 1000,
    seed: int = 0,
) -> tuple[float, float, float]:
    """``(gain_percent, low, high)`` of :func:`gain`: the percent gain and its 95 % interval."""
    g = gain(estimate, reference, truth, block=block, n_boot=n_boot, seed=seed)
    low, high = g["gain_ci95_percent"]
    return g["gain_percent"], low, high


def bias_noise(estimate: ArrayLike, truth: ArrayLike) -> dict[str, Any]:
    """Split each joint's error into a fixed offset (bias) and its spread (noise).

    ``bias`` is the mean signed error vector ``mean(estimate - truth)`` of a joint over the
    frames it was estimated (world frame, metres; ``[x, y, z]``, with ``z`` the vertical);
    ``noise`` is the RMS distance of the error vectors from that bias. For a gait study the bias
    is what shifts every angle and step length by the same amount; the noise is what smoothing
    or more sensors can remove.

    Returns
    -------
    dict
        ``by_joint``: ``{name: {"bias_m": [x, y, z], "bias_norm_m", "bias_vertical_m",
        "noise_m"}}`` (None for a joint never estimated); ``bias_norm_mean_m``,
        ``bias_vertical_mean_m`` (mean absolute vertical bias), ``noise_mean_m``: means over the
        joints that were estimated.
    """
    est = np.asarray(estimate, dtype=np.float64)
    tru = np.asarray(truth, dtype=np.float64)
    d = est - tru  # (T, 25, 3)
    ok = np.asarray(np.isfinite(d).all(-1))
    n = ok.sum(axis=0)  # (25,)
    dz = np.where(ok[..., None], d, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        bias = dz.sum(axis=0) / n[:, None]  # (25, 3)
        dev = np.where(ok, np.linalg.norm(d - bias[None], axis=-1), 0.0)
        noise = np.sqrt((dev**2).sum(axis=0) / n)
    by_joint: dict[str, Any] = {}
    for j, name in enumerate(JOINTS):
        if n[j] == 0:
            by_joint[name] = None
            continue
        by_joint[name] = {
            "bias_m": [float(v) for v in bias[j]],
            "bias_norm_m": float(np.linalg.norm(bias[j])),
            "bias_vertical_m": float(bias[j, 2]),
            "noise_m": float(noise[j]),
        }
    have = n > 0
    if not have.any():
        nan = float("nan")
        return {"by_joint": by_joint, "bias_norm_mean_m": nan, "bias_vertical_mean_m": nan,
                "noise_mean_m": nan}  # fmt: skip
    return {
        "by_joint": by_joint,
        "bias_norm_mean_m": float(np.linalg.norm(bias[have], axis=-1).mean()),
        "bias_vertical_mean_m": float(np.abs(bias[have, 2]).mean()),
        "noise_mean_m": float(noise[have].mean()),
    }

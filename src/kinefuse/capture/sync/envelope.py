"""The clock of a log that has no clock probes: fitted from the frames' own stamps. Pure, no I/O.

A receiver logs, for every frame, the sensor's capture stamp (its own clock) and the time the
frame arrived (the receiver's clock). Receive time = capture + latency + non-negative jitter, so
the *lower envelope* of ``t_receive`` against ``t_sensor`` carries the clock relation
``t_receive ~ a + b t_sensor`` (:func:`fit_clock_lower_envelope`). What the stamps cannot show,
a latency that differs between two sensors' pipelines, is measured from the body's trunk motion
(:func:`residual_lag_s`). Used on the real KinectMultiTrack logs (``docs/real_data.md``); the
simulated and live sessions have probes (:mod:`kinefuse.capture.sync.ntp`,
:mod:`kinefuse.capture.sync.online`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.capture.sync.assembly import interpolate
from kinefuse.core.affine_clock import AffineClock
from kinefuse.core.skeleton import JOINT_INDEX, TRUNK_JOINTS
from kinefuse.errors import InputError, SyncError

Array = NDArray[np.float64]

_TRUNK = np.array([JOINT_INDEX[n] for n in TRUNK_JOINTS])


@dataclass(frozen=True)
class ClockFit:
    """A sensor clock mapped onto the receiver's clock, and how well the fit went.

    Attributes
    ----------
    affine : AffineClock
        Sensor time -> receiver time: ``origin`` the sensor clock's first frame, ``offset`` its
        receiver time on the lower envelope (capture + minimum latency), ``rate`` receiver
        seconds per sensor second; all seconds.
    n_frames, n_envelope : int
        Frames fitted, and frames on the lower envelope used for the final fit.
    jitter_median_s, jitter_p95_s : float
        Receive time above the envelope (the jitter that the fit removes), median and p95, s.
    """

    affine: AffineClock
    n_frames: int
    n_envelope: int
    jitter_median_s: float
    jitter_p95_s: float


def fit_clock_lower_envelope(
    t_sensor_s: ArrayLike,
    t_receive_s: ArrayLike,
    *,
    quantile: float = 0.05,
    floor_quantile: float = 0.01,
    max_iter: int = 30,
) -> ClockFit:
    """Fit ``t_receive ~ a + b t_sensor`` on the lower envelope of the receive times.

    Receive time = capture + latency + delay with delay >= 0 (network jitter, and at a busy
    receiver a queue that can grow to hundreds of milliseconds), so the frames that arrived
    fastest carry the clock relation. The start is the line under all points that is highest at
    their mean time (the lower convex hull's edge there; the linear-programming estimate of
    Moon, Skelly & Towsley 1999), which an ordinary least-squares start would not be when the
    delay drifts. Then: keep the frames whose residual is in the lowest ``quantile``, refit by
    least squares on them, and repeat until the kept set no longer changes. The line is finally
    lowered to the ``floor_quantile`` of all residuals (a minimum that tolerates a few
    outliers), so the residuals are the delay above the fastest frames, ``>= 0`` for almost all.

    Parameters
    ----------
    t_sensor_s : (N,) float
        Capture times on the sensor's own clock, seconds (distinct frames, any order).
    t_receive_s : (N,) float
        Receive times of the same frames on the receiver's clock, seconds.
    quantile : float
        Fraction of frames kept on the envelope at each refit, in (0, 1].
    floor_quantile : float
        Residual quantile that the final line passes through, in [0, quantile].
    max_iter : int
        Maximum number of refits.

    Returns
    -------
    ClockFit

    Raises
    ------
    InputError
        Arrays of different shapes, not 1-D, non-finite, fewer than 3 frames, or quantiles out
        of range.
    SyncError
        The sensor times do not span a positive interval, or the envelope collapses to one
        instant (no clock relation can be fitted).
    """
    x = np.asarray(t_sensor_s, dtype=np.float64)
    y = np.asarray(t_receive_s, dtype=np.float64)
    if x.ndim != 1 or y.shape != x.shape:
        raise InputError(
            f"t_sensor_s and t_receive_s must be 1-D arrays of one length, got shapes {x.shape} "
            f"and {y.shape}; give one entry per frame"
        )
    if x.size < 3:
        raise InputError(f"a clock fit needs at least 3 frames, got {x.size}")
    if not (np.isfinite(x).all() and np.isfinite(y).all()):
        raise InputError("t_sensor_s and t_receive_s must be finite; drop frames without times")
    if not 0.0 < quantile <= 1.0:
        raise InputError(f"quantile must be in (0, 1], got {quantile!r}")
    if not 0.0 <= floor_quantile <= quantile:
        raise InputError(
            f"floor_quantile must be in [0, quantile={quantile}], got {floor_quantile!r}"
        )
    x0 = float(x.min())
    xs = x - x0
    span = float(xs.max())
    if span <= 0.0:
        raise SyncError(
            "the sensor times do not advance (all equal); a clock relation needs frames spread "
            "over time"
        )
    u = xs / span  # scaled for conditioning
    a_mat = np.stack([np.ones_like(u), u], axis=1)
    coef = _lower_support_line(u, y)
    keep_prev: NDArray[np.bool_] | None = None
    keep = np.ones(x.size, dtype=bool)
    for _ in range(max_iter):
        r = y - a_mat @ coef
        keep = r <= np.quantile(r, quantile)
        if keep.sum() < 2 or np.ptp(xs[keep]) <= 0.0:
            raise SyncError(
                "the lower envelope of the receive times collapses to one instant; the frames "
                "do not carry a clock relation (check that the times belong together)"
            )
        coef = np.asarray(np.linalg.lstsq(a_mat[keep], y[keep], rcond=None)[0], dtype=np.float64)
        if keep_prev is not None and np.array_equal(keep, keep_prev):
            break
        keep_prev = keep
    r = y - a_mat @ coef
    coef[0] += float(np.quantile(r, floor_quantile))
    jitter = y - a_mat @ coef
    return ClockFit(
        AffineClock(origin=x0, offset=float(coef[0]), rate=float(coef[1] / span)),
        n_frames=int(x.size),
        n_envelope=int(keep.sum()),
        jitter_median_s=float(np.median(jitter)),
        jitter_p95_s=float(np.quantile(jitter, 0.95)),
    )


def _lower_support_line(x: Array, y: Array) -> Array:
    """``[a, b]`` of the line ``a + b x`` under every point, highest at the mean of ``x``.

    The edge of the lower convex hull of the points that spans ``mean(x)`` (monotone chain).
    """
    order = np.lexsort((y, x))
    xs, ys = x[order], y[order]
    hull: list[int] = []
    for i in range(xs.size):
        while len(hull) >= 2:
            i0, i1 = hull[-2], hull[-1]
            cross = (xs[i1] - xs[i0]) * (ys[i] - ys[i0]) - (ys[i1] - ys[i0]) * (xs[i] - xs[i0])
            if cross <= 0:
                hull.pop()
            else:
                break
        hull.append(i)
    hx, hy = xs[hull], ys[hull]
    # drop vertical steps (equal x): keep the lowest point of each x (already first by lexsort)
    k = int(np.clip(np.searchsorted(hx, x.mean(), side="right") - 1, 0, hx.size - 2))
    b = (hy[k + 1] - hy[k]) / (hx[k + 1] - hx[k])
    return np.array([hy[k] - b * hx[k], b])


def residual_lag_s(
    t_ref_s: ArrayLike,
    p_ref: ArrayLike,
    t_other_s: ArrayLike,
    p_other: ArrayLike,
    *,
    max_lag_s: float = 0.3,
    iterations: int = 30,
    tol_s: float = 1e-4,
) -> float:
    """The time lag of the other stream's stamps, from the trunk motion alone.

    If the other sensor's stamps are late by ``tau``, the other stream read at the reference's
    times plus ``lag`` differs from the reference by ``v (lag - tau)`` (``v``: the trunk
    joints' velocity, from the reference) plus a constant offset per joint plus noise. A least
    squares fit of the differences on the velocities (one intercept per joint, residuals beyond
    three median absolute residuals dropped) gives ``lag - tau``; ``lag`` is updated and the
    fit repeated until it moves by less than ``tol_s``. A positive result means the other
    sensor's stamps are late: subtract it from them. 0 means the times already agree.

    Parameters
    ----------
    t_ref_s : (N,) float
    p_ref : (N, 25, 3) float
    t_other_s : (M,) float
    p_other : (M, 25, 3) float
        Both streams in one frame, metres, times on one clock, seconds.
    max_lag_s : float
        The search stays within ``+-max_lag_s``.

    Returns
    -------
    float
        Seconds.

    Raises
    ------
    InputError
        The streams do not overlap in time, or the body does not move (no lag is measurable).
    """
    tr = np.asarray(t_ref_s, dtype=np.float64)
    pr = np.asarray(p_ref, dtype=np.float64)[:, _TRUNK]
    po = np.asarray(p_other, dtype=np.float64)[:, _TRUNK]
    order = np.argsort(tr, kind="stable")
    tr, pr = tr[order], pr[order]
    # velocity over +-2 frames (about 0.13 s), NaN across gaps
    v = np.full_like(pr, np.nan)
    if tr.size >= 5:
        dt = tr[4:] - tr[:-4]
        with np.errstate(invalid="ignore", divide="ignore"):
            vel = (pr[4:] - pr[:-4]) / dt[:, None, None]
        v[2:-2] = np.where((dt > 0)[:, None, None] & (dt <= 0.25)[:, None, None], vel, np.nan)
    lag = 0.0
    for _ in range(iterations):
        q = interpolate(t_other_s, po, tr + lag)
        d = q - pr
        ok: NDArray[np.bool_] = np.asarray(
            np.isfinite(d).all(-1) & np.isfinite(v).all(-1), dtype=bool
        )
        if ok.sum() < 10:
            raise InputError(
                f"the two streams overlap in time on only {int(ok.sum())} joint samples; a lag "
                "needs them to overlap on a moving body"
            )
        dd = np.where(ok[..., None], d, 0.0)
        vv = np.where(ok[..., None], v, 0.0)
        n = np.maximum(ok.sum(axis=0), 1)[:, None]
        dd = np.where(ok[..., None], dd - dd.sum(axis=0) / n, 0.0)
        vv = np.where(ok[..., None], vv - vv.sum(axis=0) / n, 0.0)
        w: Array = ok.astype(np.float64)
        slope = 0.0
        for _ in range(2):
            den = float(np.sum(w[..., None] * vv * vv))
            if den < 1e-6 * max(1.0, float(w.sum())):
                raise InputError("the body does not move; the time lag cannot be measured")
            slope = float(np.sum(w[..., None] * vv * dd)) / den
            res: Array = np.asarray(np.linalg.norm(dd - slope * vv, axis=-1))
            w = (ok & (res <= 3.0 * np.median(res[ok]))).astype(np.float64)
        lag = float(np.clip(lag - slope, -max_lag_s, max_lag_s))
        if abs(slope) < tol_s:
            break
    return lag

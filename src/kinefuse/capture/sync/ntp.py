"""NTP-style clock synchronization between the server and one client (METHODS.md A.2).

One probe: the server sends at ``t1`` (its clock), the client receives at ``t2`` and replies at
``t3`` (its clock), the server receives at ``t4``. With symmetric delays, the client's clock
error and the one-way delay are::

    e = ((t2 - t1) - (t4 - t3)) / 2        d = ((t4 - t1) - (t3 - t2)) / 2

Beyond the paper, as NTP's clock filter and chrony do: probes come in bursts and only the
minimum-delay probe of each burst is kept (queueing delay is what makes delays asymmetric), probes
whose delay is far above the recent minimum are rejected, and the offset is tracked as a linear
function of time (drift) by a robust fit, so a client timestamp maps to server time at any moment.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.core.affine_clock import OffsetDriftClock
from kinefuse.errors import SyncError

Array = NDArray[np.float64]


def probe_offsets(probes: ArrayLike) -> tuple[Array, Array, Array]:
    """Offset ``e`` (client minus server), one-way delay ``d`` and midpoint server time.

    Parameters
    ----------
    probes : (N, 4) float
        ``t1_server_s, t2_client_s, t3_client_s, t4_server_s`` per probe.

    Returns
    -------
    offset_s, delay_s, t_mid_server_s : (N,) float
    """
    p = np.asarray(probes, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 4:
        raise SyncError(f"clock probes must have shape (N, 4) [t1, t2, t3, t4], got {p.shape}")
    t1, t2, t3, t4 = p.T
    offset = ((t2 - t1) - (t4 - t3)) / 2
    delay = ((t4 - t1) - (t3 - t2)) / 2
    return offset, delay, (t1 + t4) / 2


@dataclass(frozen=True)
class ClockEstimate(OffsetDriftClock):
    """A client's clock fitted to its probes: the :class:`OffsetDriftClock` map from server time
    to client time (``offset_s``: client time at server time 0), with ``residual_s`` (RMS of the
    kept probes' offsets around the fit, a quality figure) and ``n_probes`` (probes kept after
    filtering)."""

    residual_s: float
    n_probes: int


def estimate_clock(
    probes: ArrayLike, *, burst_gap_s: float = 0.5, delay_factor: float = 3.0
) -> ClockEstimate:
    """Estimate a client's clock offset and drift from NTP-style probes.

    Parameters
    ----------
    probes : (N, 4) float
        ``t1_server_s, t2_client_s, t3_client_s, t4_server_s``; N >= 1.
    burst_gap_s : float
        Probes closer in time than this belong to one burst; each burst keeps its minimum-delay
        probe.
    delay_factor : float
        Probes whose delay exceeds ``delay_factor`` times the overall low (10th percentile)
        delay plus 1 ms are rejected.

    Returns
    -------
    ClockEstimate
    """
    p = np.asarray(probes, dtype=np.float64)
    offset, delay, t_mid = probe_offsets(p)
    ok = np.isfinite(offset) & np.isfinite(delay) & (delay >= 0)
    if not ok.any():
        raise SyncError(
            "no usable clock probe (all non-finite or with negative delay); check that the client "
            "answers with its own clock's receive and send times"
        )
    offset, delay, t_mid = offset[ok], delay[ok], t_mid[ok]
    order = np.argsort(t_mid)
    offset, delay, t_mid = offset[order], delay[order], t_mid[order]
    # one probe per burst: the one with the least delay
    burst = np.concatenate([[0], np.cumsum(np.diff(t_mid) > burst_gap_s)])
    best = np.full(burst[-1] + 1, -1, dtype=np.intp)
    key = np.lexsort((delay, burst))
    first = np.concatenate([[True], burst[key][1:] != burst[key][:-1]])
    best = key[first]
    offset, delay, t_mid = offset[best], delay[best], t_mid[best]
    low = np.percentile(delay, 10)
    keep = delay <= delay_factor * low + 1e-3
    offset, t_mid = offset[keep], t_mid[keep]
    if offset.size == 1 or np.ptp(t_mid) < 1.0:
        e = float(np.median(offset))
        return ClockEstimate(offset_s=e, drift_ppm=0.0, residual_s=0.0, n_probes=int(offset.size))
    # robust line: offset(t) = a + b t, iteratively reweighted (Huber-like, 3 passes)
    tc = t_mid - t_mid.mean()
    w = np.ones_like(tc)
    for _ in range(4):
        a_mat = np.stack([np.ones_like(tc), tc], axis=1) * np.sqrt(w)[:, None]
        coef, *_ = np.linalg.lstsq(a_mat, offset * np.sqrt(w), rcond=None)
        r = offset - (coef[0] + coef[1] * tc)
        s = 1.4826 * np.median(np.abs(r)) + 1e-7
        w = np.minimum(1.0, 2.0 * s / np.maximum(np.abs(r), 1e-12))
    a, b = float(coef[0] - coef[1] * t_mid.mean()), float(coef[1])
    # offset(t) = t_client - t_server = a + b t  =>  t_client = a + (1 + b) t
    resid = float(np.sqrt(np.mean(r**2)))
    return ClockEstimate(offset_s=a, drift_ppm=b * 1e6, residual_s=resid, n_probes=int(offset.size))

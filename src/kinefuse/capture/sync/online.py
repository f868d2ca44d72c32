"""Online clock estimation: one client's offset and drift, updated probe by probe (METHODS.md A.2).

A live server keeps one :class:`OnlineClock` per client and feeds it each NTP-style exchange
``t1, t2, t3, t4`` as the reply arrives (probe formulas and sign as in
:mod:`kinefuse.capture.sync.ntp`: offset = client minus server time). Pure: no I/O, no wall clock;
time comes with the probes.

1. **Delay filter**: a probe whose one-way delay exceeds ``delay_factor`` times the least delay of
   the last ``window_s`` (over all probes, so a lasting new route is accepted after one window)
   plus ``delay_margin_s`` is rejected.
2. **Burst minimum**: probes sent within ``burst_window_s`` of a burst's first one form a burst;
   its least-delay probe is its sample (queueing makes the two directions unequal, so the least
   queued exchange is the least biased). The open burst's sample enters the fit at once.
3. **Consistency**: a probe's offset error is half the difference of its one-way delays, so at
   most its delay above the network's base delay (its *bound*). A burst sample off the line's
   prediction by more than its bound plus ``jump_sigma`` of the line's standard errors (and more
   than ``jump_min_s``) is a *suspect* and is held out of the fit.
4. **Jump**: a suspect that agrees with the previous burst's suspect (within their bounds) is a
   clock step: the window restarts from the two, keeping the drift (a step does not change the
   rate). One bad burst never resets. :meth:`OnlineClock.reset` is the reconnect.

**A sliding weighted line fit, not a Kalman filter**: within a window the clock is a line
(offset + drift), and a weighted least-squares line over the last ``window_s`` of burst samples is
that model with a memory that is exactly the window, where a Kalman filter's memory is set by a
process noise that is unknown per client and network; it is the offline fit restricted to the
window, so :func:`~kinefuse.capture.sync.ntp.estimate_clock` checks it; and a 2x2 solve is cheap. A
drift prior (``drift_prior_ppm``) defines the line from the first sample on. A sample's variance is
that of an error uniform within its bound, ``noise_floor_s**2 + x**2 / 3``; the base delay is the
least delay minus the spread of the four least (the k-th least lies about sqrt(k) times as far above
the base when the delay density rises linearly from it, as a sum of two queues does), 0 until
four samples. Residuals scale the variances up when the data scatter more (chi-square per degree
of freedom, never below 1); the least-delay sample's whole bound stays in the standard error
(a lasting asymmetry of the queues biases every sample alike; averaging does not remove it).
No NTP-style method sees a constant asymmetry of the base delays: ``D`` biases the offset ``D/2``.
"""

from __future__ import annotations

import heapq
import math
from collections import deque
from dataclasses import dataclass, field, fields
from enum import StrEnum

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.affine_clock import AffineClock
from kinefuse.errors import SyncError

Array = NDArray[np.float64]


@dataclass(frozen=True)
class OnlineClockParams:
    """Settings of :class:`OnlineClock` (defaults for a LAN, a burst of 4-8 probes each second).

    ``burst_window_s``: probes sent within this of a burst's first one belong to it (s).
    ``window_s``: length of the sliding window of burst samples, and of the delay minimum (s).
    ``max_bursts``: at most this many samples in the fit (bounds memory and time).
    ``delay_factor``, ``delay_margin_s``: a probe is rejected when its delay exceeds
    ``delay_factor * recent_min + delay_margin_s`` (as in the offline fit).
    ``noise_floor_s``: offset standard deviation of a probe at the base delay (timestamping, s).
    ``drift_prior_ppm``: drift standard deviation before any data (quartz: within +/-100 ppm).
    ``keep_drift_sigma_ppm``: after a jump the drift stays as prior, at least this uncertain.
    ``jump_sigma``, ``jump_min_s``: a burst sample is a suspect when off the prediction by more
    than its bound plus ``jump_sigma`` standard errors of the line, and by more than ``jump_min_s``.
    ``jump_confirm_s``: the second suspect must come within this of the first (s).
    """

    burst_window_s: float = 0.25
    window_s: float = 30.0
    max_bursts: int = 120
    delay_factor: float = 3.0
    delay_margin_s: float = 1e-3
    noise_floor_s: float = 30e-6
    drift_prior_ppm: float = 100.0
    keep_drift_sigma_ppm: float = 2.0
    jump_sigma: float = 8.0
    jump_min_s: float = 1e-3
    jump_confirm_s: float = 5.0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not (math.isfinite(v) and v > 0):
                raise SyncError(f"OnlineClockParams.{f.name} must be a positive number, got {v!r}")
        if self.max_bursts < 2:
            raise SyncError(f"OnlineClockParams.max_bursts must be >= 2, got {self.max_bursts}")


class ProbeStatus(StrEnum):
    """What :meth:`OnlineClock.add_probe` did with a probe."""

    BEST = "best"  # least delay of its burst so far: the burst's sample in the fit
    KEPT = "kept"  # passed the filters, but its burst has a probe with less delay
    REJECTED_DELAY = "rejected-delay"  # delay far above the recent minimum
    SUSPECT = "suspect"  # its burst's sample so far, off the prediction (a possible jump)
    REJECTED_STALE = "rejected-stale"  # sent in an earlier burst than the open one (reordered)


@dataclass(frozen=True)
class ProbeResult:
    """One probe's outcome: ``status``, its ``offset_s`` (client minus server) and one-way
    ``delay_s``, ``t_server_s`` = ``(t1 + t4) / 2`` (the time the offset refers to), ``reason`` (in
    words, with the numbers), and ``reset``: set when this probe restarted the estimate (a jump)."""

    status: ProbeStatus
    offset_s: float
    delay_s: float
    t_server_s: float
    reason: str
    reset: str | None = None


@dataclass(frozen=True)
class OnlineEstimate:
    """The clock at server time ``at_server_s``: ``t_client = t_server + offset(t_server)``.

    ``offset_s`` (client minus server, s) and its standard error ``offset_se_s`` at that time;
    ``drift_ppm`` = d(offset)/dt and ``drift_se_ppm``; ``n_bursts`` burst samples in the fit;
    ``epoch`` = resets so far (explicit or clock jumps). ``affine``: server time -> client time
    under this line (origin ``at_server_s``, where the client reads ``at_server_s + offset_s``).
    """

    at_server_s: float
    offset_s: float
    drift_ppm: float
    offset_se_s: float
    drift_se_ppm: float
    n_bursts: int
    epoch: int
    affine: AffineClock = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        t, off = self.at_server_s, self.offset_s
        a = AffineClock.from_drift_ppm(self.drift_ppm, offset=t + off, origin=t)
        object.__setattr__(self, "affine", a)


@dataclass(frozen=True)
class _Line:
    """offset(t) = a + b (t - t_ref); covariance of (a, b) already scaled by ``scale2``."""

    t_ref: float
    a: float
    b: float
    p_aa: float
    p_ab: float
    p_bb: float
    scale2: float  # chi-square per degree of freedom (>= 1) the sample variances were scaled by
    n: int
    d_low: float  # least delay among the samples (s)
    sys2: float  # variance that averaging cannot reduce: the least-delay sample's bound (s^2)
    affine: AffineClock = field(init=False, repr=False, compare=False)  # server -> client time

    def __post_init__(self) -> None:
        a = AffineClock.from_drift(self.b, offset=self.t_ref + self.a, origin=self.t_ref)
        object.__setattr__(self, "affine", a)

    def offset(self, t: float) -> float:
        return self.a + self.b * (t - self.t_ref)

    def var(self, t: float) -> float:
        dt = t - self.t_ref
        return max(self.p_aa + 2.0 * self.p_ab * dt + self.p_bb * dt * dt, 0.0) + self.sys2


_Sample = tuple[float, float, float]  # (t_server_s, offset_s, delay_s) of a burst's best probe


class OnlineClock:
    """Offset and drift of one client's clock, updated probe by probe.

    Parameters
    ----------
    params : OnlineClockParams
    """

    _samples: deque[_Sample]  # committed burst samples in the window, oldest first
    _sums: tuple[float, ...]  # their weighted sums about (_t_ref, _y_ref)
    _base: _Line | None  # line through the committed samples (what probes are checked against)
    _line: _Line | None  # the same plus the open burst's best probe (what is reported)
    _burst_t1: float | None  # send time of the open burst's first probe
    _open_best: _Sample | None  # the open burst's least-delay probe
    _open_suspect: bool  # ... and whether it is inconsistent with the committed line
    _suspect: _Sample | None  # the last burst of suspects, waiting for a second one
    _delays: deque[tuple[float, float]]  # (t, delay) with increasing delays: the sliding minimum

    def __init__(self, params: OnlineClockParams | None = None) -> None:
        self.params = params if params is not None else OnlineClockParams()
        self.epoch = 0
        self.last_reset: str | None = None
        self._prior_b, self._prior_var = 0.0, (self.params.drift_prior_ppm * 1e-6) ** 2
        self._clear()

    # -- public API ------------------------------------------------------------------------------

    def add_probe(self, t1: float, t2: float, t3: float, t4: float) -> ProbeResult:
        """Take one exchange: server send ``t1``, client receive ``t2`` and reply ``t3`` (client
        clock), server receive ``t4`` (s). Raises :class:`SyncError` on impossible times."""
        bad = None
        if not all(math.isfinite(v) for v in (t1, t2, t3, t4)):
            bad = f"clock probe times must be finite, got t1={t1}, t2={t2}, t3={t3}, t4={t4}; "
            bad += "drop a lost exchange instead of passing NaN"
        elif t4 < t1:
            bad = f"server receive time t4={t4!r} is before its send time t1={t1!r}; pass the "
            bad += "server's own send and receive times (t1, t4) and the client's (t2, t3)"
        elif t3 < t2:
            bad = f"client reply time t3={t3!r} is before its receive time t2={t2!r}; the client "
            bad += "must stamp the request when it arrives (t2) and the reply when it leaves (t3)"
        elif (t3 - t2) - (t4 - t1) > 2e-6:
            bad = f"client turnaround t3-t2={t3 - t2:.6g} s is longer than the round trip t4-t1="
            bad += f"{t4 - t1:.6g} s; t2 and t3 must be the client's receive and reply times"
        if bad is not None:
            raise SyncError(bad)
        y, d = ((t2 - t1) - (t4 - t3)) / 2, ((t4 - t1) - (t3 - t2)) / 2
        d, t = max(d, 0.0), (t1 + t4) / 2
        p = self.params
        if self._burst_t1 is not None and t1 < self._burst_t1 - p.burst_window_s:
            why = "sent before the open burst (a reply overtaken by later ones)"
            return ProbeResult(ProbeStatus.REJECTED_STALE, y, d, t, why)
        reset = None
        if self._burst_t1 is None or t1 - self._burst_t1 > p.burst_window_s:
            self._close_burst()
            self._burst_t1 = t1
        dmin = self._push_delay(t, d)
        if d > p.delay_factor * dmin + p.delay_margin_s:
            why = f"delay {d * 1e3:.3f} ms > {p.delay_factor:g} x recent minimum {dmin * 1e3:.3f}"
            why += f" ms + {p.delay_margin_s * 1e3:g} ms"
            return ProbeResult(ProbeStatus.REJECTED_DELAY, y, d, t, why)
        best = self._open_best
        if best is not None and d >= best[2]:
            why = f"its burst has a probe with less delay ({best[2] * 1e3:.3f} ms)"
            return ProbeResult(ProbeStatus.KEPT, y, d, t, why)
        # the burst's least-delay probe so far: it alone decides whether the burst is consistent
        self._open_best, self._open_suspect, base = (t, y, d), False, self._base
        if base is not None:
            # the probe's own error is within its bound; the line's, within jump_sigma sd (its
            # samples came with more delay than this probe may be off by up to the difference)
            innov, sd = y - base.offset(t), math.sqrt(base.var(t))
            tol = self._bound(d) + p.jump_sigma * sd + max(base.d_low - dmin, 0.0)
            if abs(innov) > max(tol, p.jump_min_s):
                reset = self._confirm_jump((t, y, d), base)
                if reset is None:
                    self._open_suspect, self._line = True, base
                    why = f"offset {innov * 1e3:+.3f} ms off the prediction (tolerance "
                    return ProbeResult(ProbeStatus.SUSPECT, y, d, t, why + f"{tol * 1e3:.3f} ms)")
                self._open_best = (t, y, d)
        self._line = self._solve(self._open_best)
        return ProbeResult(ProbeStatus.BEST, y, d, t, "least delay of its burst so far", reset)

    def estimate(self, at_server_s: float) -> OnlineEstimate:
        """Offset, drift and their standard errors at server time ``at_server_s`` (s)."""
        line = self._require()
        return OnlineEstimate(
            at_server_s=float(at_server_s),
            offset_s=line.offset(at_server_s),
            drift_ppm=line.b * 1e6,
            offset_se_s=math.sqrt(line.var(at_server_s)),
            drift_se_ppm=math.sqrt(line.p_bb) * 1e6,
            n_bursts=line.n,
            epoch=self.epoch,
        )

    @property
    def affine(self) -> AffineClock:
        """The current line, server time -> client time (``inverse``: the server time of client
        timestamps). Raises SyncError before the first kept probe."""
        return self._require().affine

    def reset(self, reason: str, *, keep_drift: bool = False) -> None:
        """Forget the estimate (a reconnect: the client may be another machine, another route).

        ``keep_drift=True`` keeps the current drift as prior (the same machine came back)."""
        if keep_drift and self._line is not None:
            self._set_drift_prior(self._line)
        else:
            self._prior_b, self._prior_var = 0.0, (self.params.drift_prior_ppm * 1e-6) ** 2
        self.epoch += 1
        self.last_reset = str(reason)
        self._clear()

    @property
    def n_bursts(self) -> int:
        """Burst samples in the current estimate (0 before the first kept probe)."""
        return 0 if self._line is None else self._line.n

    # -- internals -------------------------------------------------------------------------------

    def _clear(self) -> None:
        self._samples = deque()
        self._sums = (0.0,) * 6
        self._t_ref = self._y_ref = 0.0
        self._base = self._line = None
        self._burst_t1 = self._open_best = self._suspect = None
        self._open_suspect = False
        self._delays = deque()
        self._base_d = 0.0  # estimated base (no-queue) delay of the network (s)
        self._d_low = math.inf  # least delay among the committed samples (s)

    def _require(self) -> _Line:
        if self._line is None:
            raise SyncError(
                "no clock estimate yet: no probe has been kept since the start or the last reset "
                f"({self.last_reset or 'none'}); wait for the client's first probe burst"
            )
        return self._line

    def _push_delay(self, t: float, d: float) -> float:
        """Sliding-window minimum of the delays (monotone deque), including this one."""
        q = self._delays
        while q and q[-1][1] >= d:
            q.pop()
        q.append((t, d))
        while q[0][0] < t - self.params.window_s:
            q.popleft()
        return q[0][1]

    def _var(self, d: float) -> float:
        """Variance of an offset measured with delay ``d``: uniform within its bound."""
        x = max(d - self._base_d, 0.0)
        return self.params.noise_floor_s**2 + x * x / 3.0

    def _bound(self, d: float) -> float:
        """Largest offset error of a probe with delay ``d``: half the difference of the one-way
        delays is at most their mean above the base."""
        return max(d - self._base_d, 0.0) + self.params.noise_floor_s

    def _sys2(self, d_low: float) -> float:
        """The least-delay sample's whole bound, squared: a lasting asymmetry of the queues biases
        every sample alike (no queue one way puts all of the bound on one side)."""
        return 3.0 * (self._var(d_low) - self.params.noise_floor_s**2)

    def _set_drift_prior(self, line: _Line) -> None:
        self._prior_b = line.b
        self._prior_var = max(line.p_bb, (self.params.keep_drift_sigma_ppm * 1e-6) ** 2)

    def _close_burst(self) -> None:
        """Commit the open burst's sample, or hold its best suspect for a jump's confirmation."""
        best, sus = self._open_best, self._open_suspect
        self._open_best, self._open_suspect = None, False
        if best is None:
            return
        if sus:
            self._suspect = best
            return
        self._suspect = None
        s = self._samples
        s.append(best)
        while len(s) > self.params.max_bursts or s[0][0] < s[-1][0] - self.params.window_s:
            s.popleft()
        self._resum()
        self._base = self._line = self._solve(None)

    def _confirm_jump(self, new: _Sample, base: _Line) -> str | None:
        """Restart from the held suspect and ``new`` when they agree (a clock step), else None."""
        prev, p = self._suspect, self.params
        if prev is None or new[0] - prev[0] > p.jump_confirm_s:
            return None
        dt = new[0] - prev[0]
        gap = new[1] - (prev[1] + base.b * dt)
        tol = self._bound(prev[2]) + self._bound(new[2]) + p.jump_sigma * math.sqrt(base.p_bb) * dt
        if abs(gap) > max(tol, p.jump_min_s):
            return None
        reason = f"clock jump of {(new[1] - base.offset(new[0])) * 1e3:+.3f} ms confirmed by a "
        reason += "second burst"
        self._set_drift_prior(base)
        self.epoch += 1
        self.last_reset = reason
        self._samples, self._suspect = deque([prev]), None
        self._open_best, self._open_suspect = None, False
        self._resum()
        self._base = self._line = self._solve(None)
        return reason

    def _resum(self) -> None:
        """Weighted sums of the committed samples, about the newest time and the oldest offset."""
        s = self._samples
        t_ref, y_ref = s[-1][0], s[0][1]
        # base delay (see the module's docstring); until 4 samples, the one of before a jump or 0
        low = heapq.nsmallest(4, (d for _, _, d in s))
        self._d_low = low[0]
        if len(low) == 4:
            self._base_d = max(low[0] - (low[3] - low[0]), 0.0)
        else:
            self._base_d = min(self._base_d, low[0])
        s0 = s1 = s2 = y0 = y1 = yy = 0.0
        for t, y, d in s:
            w, dt, dy = 1.0 / self._var(d), t - t_ref, y - y_ref
            s0 += w
            s1 += w * dt
            s2 += w * dt * dt
            y0 += w * dy
            y1 += w * dt * dy
            yy += w * dy * dy
        self._t_ref, self._y_ref, self._sums = t_ref, y_ref, (s0, s1, s2, y0, y1, yy)

    def _solve(self, extra: _Sample | None) -> _Line:
        """Weighted line through the window's samples (+ the open burst's) with a drift prior."""
        s0, s1, s2, y0, y1, yy = self._sums
        n, d_low = len(self._samples), self._d_low
        if extra is not None:
            t, y, d = extra
            if n == 0:
                self._t_ref, self._y_ref = t, y
            w, dt, dy = 1.0 / self._var(d), t - self._t_ref, y - self._y_ref
            s0, s1, s2 = s0 + w, s1 + w * dt, s2 + w * dt * dt
            y0, y1, yy = y0 + w * dy, y1 + w * dt * dy, yy + w * dy * dy
            n, d_low = n + 1, min(d_low, d)
        pb, pw = self._prior_b, 1.0 / self._prior_var
        scale2 = 1.0
        while True:  # at most twice: with the model's variances, then scaled by the residuals
            k = 1.0 / scale2
            m00, m01, m11 = k * s0, k * s1, k * s2 + pw
            r0, r1 = k * y0, k * y1 + pw * pb
            det = m00 * m11 - m01 * m01
            a, b = (m11 * r0 - m01 * r1) / det, (m00 * r1 - m01 * r0) / det
            if scale2 > 1.0 or n <= 2:
                break
            chi2 = yy - 2 * a * y0 - 2 * b * y1 + a * a * s0 + 2 * a * b * s1 + b * b * s2
            scale2 = max(1.0, chi2 / (n - 2))
            if scale2 == 1.0:
                break
        p_aa, p_ab, p_bb = m11 / det, -m01 / det, m00 / det
        sys2 = self._sys2(d_low)
        return _Line(self._t_ref, a + self._y_ref, b, p_aa, p_ab, p_bb, scale2, n, d_low, sys2)

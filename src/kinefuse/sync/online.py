"""Online clock estimation: one client's offset and drift, updated probe by probe (METHODS.md A.2).

A live server keeps one :class:`OnlineClock` per client and feeds it each NTP-style exchange
``t1, t2, t3, t4`` as the reply arrives (same probe formulas and sign as :mod:`kinefuse.sync.ntp`:
the offset is client minus server time). Pure: no I/O, no wall clock; time comes with the probes.

What happens to a probe, in order:

1. **Delay filter.** Probes whose one-way delay exceeds ``delay_factor`` times the minimum delay of
   the last ``window_s`` seconds (all probes, rejected ones included, so a lasting change of route
   is accepted after one window) plus ``delay_margin_s`` are rejected.
2. **Consistency.** Against the current line's prediction, a probe whose offset is off by more
   than ``jump_sigma`` standard deviations (and more than ``jump_min_s``) is a *suspect*.
3. **Burst minimum.** Probes whose send times lie within ``burst_window_s`` of the burst's first
   probe form a burst; its least-delay consistent probe is the burst's sample (queueing delay is
   what makes the two directions unequal, so the least-delayed exchange is the least biased). The
   open burst's best sample enters the fit at once and is replaced when a better one comes.
4. **Jump.** A burst with only suspects is held; a second burst of suspects that agrees with the
   first (same offset after drift) confirms a clock step: the window restarts from the two bursts,
   keeping the drift (a step does not change the rate). One bad burst never resets.

**Why a sliding weighted line fit, not a Kalman filter.** The clock model within a window is a
line (offset + drift), and a least-squares line over the last ``window_s`` seconds of burst
samples is exactly that model: old samples leave the estimate when they leave the window, with no
process-noise figure to tune (a Kalman filter's process noise sets its memory, and it is unknown
per client and network); the same line as the offline fit restricted to the window, so the
offline fit checks it directly; and a 2x2 solve over at most ``max_bursts`` samples is cheap. A
drift prior (``drift_prior_ppm``) keeps the line defined from the first sample on. Each sample's
variance comes from its own exchange: the offset error of a probe is half the difference of the
two one-way delays, bounded by the delay above the network's base, so with ``x`` = delay minus
the recent minimum the sample's variance is ``noise_floor_s**2 + x**2 / 3`` (a uniform error in
``[-x, x]``). The fit's residuals scale these variances up when the data scatter more
(chi-square per degree of freedom, never below 1), so the standard error is honest.

What no NTP-style method can see: a constant asymmetry of the base delays (one direction always
slower by ``D``) biases the offset by ``D / 2``.
"""

from __future__ import annotations

import heapq
import math
from collections import deque
from dataclasses import dataclass, fields
from enum import StrEnum
from typing import overload

import numpy as np
from numpy.typing import NDArray

from kinefuse.errors import SyncError

Array = NDArray[np.float64]


@dataclass(frozen=True)
class OnlineClockParams:
    """Settings of :class:`OnlineClock` (defaults for a LAN, a burst of 4-8 probes each second).

    Attributes
    ----------
    burst_window_s : float
        Probes sent within this time of a burst's first probe belong to that burst (s).
    window_s : float
        Length of the sliding window of burst samples in the fit, and of the delay minimum (s).
    max_bursts : int
        At most this many burst samples in the fit (bounds memory and time per burst).
    delay_factor, delay_margin_s : float
        A probe is rejected when its delay exceeds ``delay_factor * recent_min + delay_margin_s``.
    noise_floor_s : float
        Offset standard deviation of a sample at the minimum delay (s): the recent minimum's own
        queueing and the client's timestamp resolution.
    drift_prior_ppm : float
        Standard deviation of the drift before any data (ppm); quartz clocks are within +/-100.
    keep_drift_sigma_ppm : float
        After a clock jump the old drift is kept as prior with at least this uncertainty (ppm).
    jump_sigma, jump_min_s : float
        A probe is a suspect when its offset is off the prediction by more than ``jump_sigma``
        standard deviations and by more than ``jump_min_s`` seconds.
    jump_confirm_s : float
        The second suspect burst must come within this time of the first to confirm a jump (s).
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
    SUSPECT = "suspect"  # offset inconsistent with the prediction (held as a possible jump)
    REJECTED_STALE = "rejected-stale"  # sent in an earlier burst than the open one (reordered)


@dataclass(frozen=True)
class ProbeResult:
    """The outcome of one probe.

    Attributes
    ----------
    status : ProbeStatus
    offset_s, delay_s : float
        The probe's offset (client minus server) and one-way delay.
    t_server_s : float
        Midpoint ``(t1 + t4) / 2``, the server time the offset refers to.
    reason : str
        Why, in words (the numbers the decision was made on).
    reset : str or None
        Set when handling this probe restarted the estimate (a confirmed clock jump).
    """

    status: ProbeStatus
    offset_s: float
    delay_s: float
    t_server_s: float
    reason: str
    reset: str | None = None


@dataclass(frozen=True)
class OnlineEstimate:
    """The clock at one server time: ``t_client = t_server + offset(t_server)``.

    Attributes
    ----------
    at_server_s : float
    offset_s : float
        Offset (client minus server) at ``at_server_s`` (s).
    drift_ppm : float
        Rate error: d(offset)/dt in ppm.
    offset_se_s : float
        Standard error of ``offset_s`` (s).
    drift_se_ppm : float
    n_bursts : int
        Burst samples in the fit.
    epoch : int
        Number of resets so far (explicit or clock jumps).
    """

    at_server_s: float
    offset_s: float
    drift_ppm: float
    offset_se_s: float
    drift_se_ppm: float
    n_bursts: int
    epoch: int

    def to_server(self, t_client_s: float) -> float:
        """Server time of a client timestamp, under this line."""
        b = self.drift_ppm * 1e-6
        return (t_client_s - self.offset_s + b * self.at_server_s) / (1.0 + b)

    def to_client(self, t_server_s: float) -> float:
        return t_server_s + self.offset_s + self.drift_ppm * 1e-6 * (t_server_s - self.at_server_s)


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
        if not all(math.isfinite(v) for v in (t1, t2, t3, t4)):
            raise SyncError(
                f"clock probe times must be finite, got t1={t1}, t2={t2}, t3={t3}, t4={t4}; "
                "drop a lost exchange instead of passing NaN"
            )
        if t4 < t1:
            raise SyncError(
                f"server receive time t4={t4!r} is before its send time t1={t1!r}; pass the "
                "server's own send and receive times (t1, t4) and the client's (t2, t3)"
            )
        if t3 < t2:
            raise SyncError(
                f"client reply time t3={t3!r} is before its receive time t2={t2!r}; the client "
                "must stamp the request when it arrives (t2) and the reply when it leaves (t3)"
            )
        y = ((t2 - t1) - (t4 - t3)) / 2
        d = ((t4 - t1) - (t3 - t2)) / 2
        if d < -1e-6:
            raise SyncError(
                f"client turnaround t3-t2={t3 - t2:.6g} s is longer than the round trip "
                f"t4-t1={t4 - t1:.6g} s; t2 and t3 must be the client's receive and reply times"
            )
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

    @overload
    def to_server(self, t_client_s: float) -> float: ...
    @overload
    def to_server(self, t_client_s: Array) -> Array: ...
    def to_server(self, t_client_s: float | Array) -> float | Array:
        """Server time of client timestamps (s), under the current line."""
        line = self._require()
        return (t_client_s - line.a + line.b * line.t_ref) / (1.0 + line.b)

    @overload
    def to_client(self, t_server_s: float) -> float: ...
    @overload
    def to_client(self, t_server_s: Array) -> Array: ...
    def to_client(self, t_server_s: float | Array) -> float | Array:
        """Client time of server times (s), under the current line."""
        line = self._require()
        return t_server_s + line.a + line.b * (t_server_s - line.t_ref)

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
        """Variance of an offset measured with delay ``d``: uniform within its excess delay."""
        x = max(d - self._base_d, 0.0)
        return self.params.noise_floor_s**2 + x * x / 3.0

    def _bound(self, d: float) -> float:
        """Largest offset error of a probe with delay ``d``: half the difference of the one-way
        delays is at most their mean above the base."""
        return max(d - self._base_d, 0.0) + self.params.noise_floor_s

    def _sys2(self, d_low: float) -> float:
        """A lasting asymmetry of the queues biases every sample alike, up to its bound (one
        direction without queue puts all of it on one side): the least-delay sample's bound is
        kept as a standard deviation that averaging does not lower."""
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
        if not s:
            self._sums = (0.0,) * 6
            return
        t_ref, y_ref = s[-1][0], s[0][1]
        # base delay: below the least delay by about the spread of the few least delays (m of
        # them: the k-th least lies ~sqrt(k) times as far above the base when the delay density
        # rises linearly from it, as a sum of two queues does); between 0 and the least delay
        # (until 4 samples: the estimate of before a jump, or 0 after a reset)
        low = heapq.nsmallest(4, (d for _, _, d in s))
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
        n = len(self._samples)
        d_low = min((d for _, _, d in self._samples), default=math.inf)
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
        for _ in range(2):
            k = 1.0 / scale2
            m00, m01, m11 = k * s0, k * s1, k * s2 + pw
            r0, r1 = k * y0, k * y1 + pw * pb
            det = m00 * m11 - m01 * m01
            a, b = (m11 * r0 - m01 * r1) / det, (m00 * r1 - m01 * r0) / det
            if n <= 2:
                break
            chi2 = yy - 2 * a * y0 - 2 * b * y1 + a * a * s0 + 2 * a * b * s1 + b * b * s2
            new = max(1.0, chi2 / (n - 2))
            if new == scale2:
                break
            scale2 = new
        p_aa, p_ab, p_bb = m11 / det, -m01 / det, m00 / det
        sys2 = self._sys2(d_low)
        return _Line(self._t_ref, a + self._y_ref, b, p_aa, p_ab, p_bb, scale2, n, d_low, sys2)

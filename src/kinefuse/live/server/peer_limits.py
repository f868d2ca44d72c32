"""What keeps one hostile peer from hurting the server: rate limits, a bounded record of
refusals, and the plausibility window of a sensor's time stamps (issue 23).

No I/O and no clock of their own: each takes the server time it is given.

- :class:`TokenBucket`: ``rate`` per second on average, ``burst`` at once (messages of a peer,
  control requests);
- :class:`EventLimit`: at most ``per_window`` events per ``window_s`` are logged and recorded in
  full, the others counted (a sensor's events: its floor errors, connections, stale frames);
- :class:`RefusalLog`: every refused connection is counted, the last ``keep`` are kept, and at
  most ``per_window`` of them per ``window_s`` are logged and recorded in full (the others are
  summarized once per window), so a peer that reconnects as fast as it can costs the log, the
  recording and the memory a bounded amount;
- :class:`HandshakeSlots`: who may start a handshake (budgets for known addresses and for
  strangers, a limit per address, failed authentications throttled per address);
- :class:`StampGate`: a sensor's host-clock stamps must stay within ``window_s`` of the offset
  its clock probes (or its first stamp) showed on this connection, its device stamps no more
  than ``window_s`` ahead of their newest offset from the host stamps, and no offset may exceed
  ``max_offset_s``; a stamp outside is refused at the door (:class:`FieldError`), before it can
  reach the clock fits, the fusion or the recording.
"""

from __future__ import annotations

import math
from collections import Counter, deque

from kinefuse.live.protocol.wire_errors import FieldError


class TokenBucket:
    """``take()`` is True while the average stays under ``rate`` per second (``burst`` at once)."""

    def __init__(self, rate: float, burst: float, now: float) -> None:
        if not (rate > 0 and burst >= 1):
            raise ValueError(f"a token bucket needs rate > 0 and burst >= 1, got {rate}, {burst}")
        self.rate = float(rate)
        self.burst = float(burst)
        self._tokens = float(burst)
        self._t = now

    def take(self, now: float, n: float = 1.0) -> bool:
        """Take ``n`` tokens at server time ``now``; False (nothing taken) when too few."""
        if now > self._t:
            self._tokens = min(self.burst, self._tokens + (now - self._t) * self.rate)
            self._t = now
        if self._tokens >= n:
            self._tokens -= n
            return True
        self._tokens = max(self._tokens - n, -self.burst)  # a flood stays in debt
        return False

    def level(self, now: float) -> float:
        """The tokens there would be at server time ``now`` (negative: in debt)."""
        return min(self.burst, self._tokens + max(now - self._t, 0.0) * self.rate)


class EventLimit:
    """At most ``per_window`` events per ``window_s`` pass (are logged and recorded in full);
    the others are counted by kind and summarized once their window is over."""

    def __init__(self, *, per_window: int = 10, window_s: float = 10.0) -> None:
        self.per_window = per_window
        self.window_s = window_s
        self._window_start = -math.inf
        self._in_window = 0
        self._suppressed: Counter[str] = Counter()

    def allow(self, now: float, kind: str) -> bool:
        """Whether an event of ``kind`` at server time ``now`` may be logged and recorded."""
        if now - self._window_start >= self.window_s:
            self._window_start = now
            self._in_window = 0
        if self._in_window < self.per_window:
            self._in_window += 1
            return True
        self._suppressed[kind[:32]] += 1
        return False

    def summary(self, now: float) -> dict[str, int] | None:
        """The events not logged one by one, by kind, once their window is over (else None)."""
        if not self._suppressed or now - self._window_start < self.window_s:
            return None
        out = dict(self._suppressed)
        self._suppressed.clear()
        return out


class RefusalLog:
    """Refused connections, bounded (see the module docstring).

    Attributes
    ----------
    recent : deque of (code, reason)
        The last ``keep`` refusals (reasons name the peer's address).
    counts : Counter
        Refusals by code since the start (the codes are the protocol's, a fixed set).
    total : int
    """

    def __init__(self, *, keep: int = 100, per_window: int = 10, window_s: float = 10.0) -> None:
        self.recent: deque[tuple[str, str]] = deque(maxlen=keep)
        self.counts: Counter[str] = Counter()
        self.total = 0
        self.limit = EventLimit(per_window=per_window, window_s=window_s)
        self.window_s = window_s

    def add(self, now: float, code: str, reason: str) -> bool:
        """Count a refusal; True when it may be logged and recorded in full."""
        self.total += 1
        self.counts[code[:32]] += 1
        self.recent.append((code, reason[:300]))
        return self.limit.allow(now, code)

    def summary(self, now: float) -> dict[str, int] | None:
        """The refusals not logged one by one, by code, once their window is over (else None)."""
        return self.limit.summary(now)


class StampGate:
    """The plausibility window of one connection's time stamps (see the module docstring).

    Offsets: ``host - server`` for host-clock stamps (a clock reply gives it to within its
    round trip; before the first reply, the first stamp's offset from its arrival stands in,
    and the reply must then agree with it), ``device - host`` for device stamps.
    """

    def __init__(self, *, window_s: float = 30.0, max_offset_s: float = 1e9) -> None:
        self.window_s = window_s
        self.max_offset_s = max_offset_s
        self.host_offset: float | None = None
        self._from_reply = False
        self.device_offset: float | None = None

    def _check(self, msg: str, name: str, offset: float, anchor: float | None, what: str) -> None:
        if abs(offset) > self.max_offset_s:
            raise FieldError(
                msg,
                name,
                f"{what} is {offset:.6g} s from the {_OTHER[what]}: more than "
                f"{self.max_offset_s:g} s, not a plausible clock (is the sensor's clock set up?)",
            )
        if anchor is not None and abs(offset - anchor) > self.window_s:
            raise FieldError(
                msg,
                name,
                f"{what} jumped by {offset - anchor:.6g} s from this connection's earlier "
                f"stamps (the window is {self.window_s:g} s); a clock that jumps is refused",
            )

    def host(self, msg: str, name: str, t_host_s: float, t_arrival_s: float) -> None:
        """Check a host-clock stamp that arrived at server time ``t_arrival_s``."""
        off = t_host_s - t_arrival_s
        self._check(msg, name, off, self.host_offset, "the host clock")
        if self.host_offset is None:
            self.host_offset = off

    def reply(self, t1: float, t2: float, t3: float, t4: float) -> None:
        """Check a clock reply; the first one anchors the host offset."""
        off = 0.5 * ((t2 - t1) + (t3 - t4))
        self._check("clock_reply", "t2", off, self.host_offset, "the host clock")
        if not self._from_reply:
            self.host_offset, self._from_reply = off, True

    def device(self, msg: str, t_device_s: float, t_host_s: float) -> None:
        """Check a device-clock stamp against the host stamp of the same frame.

        Only a jump *forward* (a device stamp newer, against its host stamp, than this
        connection's newest by more than the window) is refused here: a frame that is older
        against its host stamp was held back somewhere (a stalled sensor's backlog), which the
        server drops as late instead (:meth:`SensorState.lateness`)."""
        off = t_device_s - t_host_s
        self._check(msg, "t_device_s", off, None, "the device clock")
        if self.device_offset is not None and off > self.device_offset + self.window_s:
            raise FieldError(
                msg,
                "t_device_s",
                f"the device clock jumped forward by {off - self.device_offset:.6g} s against "
                f"the host clock (the window is {self.window_s:g} s); a clock that jumps is "
                "refused",
            )
        if self.device_offset is None or off > self.device_offset:
            self.device_offset = off


_OTHER = {"the host clock": "server clock", "the device clock": "host clock"}


class HandshakeSlots:
    """Who may start a handshake: connections not yet welcomed, by budget and by address.

    - Addresses from which a peer was welcomed before (``known``: a sensor PC, the operator's)
      have a budget of their own (``max_pending_known``), so a sensor that restarts never
      waits behind strangers' handshakes, however many there are;
    - strangers share ``max_pending``;
    - no address holds more than ``per_address`` handshakes at once;
    - an address whose peers fail authentication more than ``fail_burst`` times (then
      ``fail_rate`` a second) is refused at once until its bucket refills: guessing the token
      online goes at ``fail_rate`` per address.

    A refusal costs the server an accept and one short write: no task, no buffer. Memory is
    bounded: at most ``max_addresses`` known addresses and throttled ones each (the oldest are
    forgotten).
    """

    def __init__(
        self,
        *,
        max_pending: int = 32,
        max_pending_known: int = 16,
        per_address: int = 8,
        fail_rate: float = 1.0,
        fail_burst: float = 10.0,
        max_addresses: int = 4096,
    ) -> None:
        self.max_pending = max_pending
        self.max_pending_known = max_pending_known
        self.per_address = per_address
        self.fail_rate = fail_rate
        self.fail_burst = fail_burst
        self.max_addresses = max_addresses
        self.pending: Counter[str] = Counter()
        self.n_known = 0
        self.n_strangers = 0
        self._known: dict[str, None] = {}
        self._fails: dict[str, TokenBucket] = {}
        self._last_prune = -math.inf

    def admit(self, addr: str, now: float) -> tuple[bool, tuple[str, str] | None]:
        """Whether ``addr`` is known, and ``(code, reason)`` if it may not start a handshake
        now (else None: it holds a slot until :meth:`release`)."""
        known = addr in self._known
        bucket = self._fails.get(addr)
        if bucket is not None and bucket.level(now) < 1.0:
            return known, (
                "limit",
                f"too many failed authentications from {addr} (at most {self.fail_rate:g} a "
                "second after a burst); wait, and check the token",
            )
        if self.pending[addr] >= self.per_address:
            return known, (
                "busy",
                f"{self.per_address} connections from {addr} are in their handshake already",
            )
        if known and self.n_known >= self.max_pending_known:
            return known, (
                "busy",
                f"{self.max_pending_known} connections from known addresses are in their handshake",
            )
        if not known and self.n_strangers >= self.max_pending:
            return known, ("busy", f"{self.max_pending} connections are in their handshake")
        self.pending[addr] += 1
        if known:
            self.n_known += 1
        else:
            self.n_strangers += 1
        return known, None

    def release(self, addr: str, known: bool) -> None:
        """A connection admitted by :meth:`admit` (as ``known`` or not) left its handshake."""
        self.pending[addr] -= 1
        if self.pending[addr] <= 0:
            del self.pending[addr]
        if known:
            self.n_known -= 1
        else:
            self.n_strangers -= 1

    def welcomed(self, addr: str) -> None:
        """A peer from ``addr`` proved itself (or no proof is asked): the address is known."""
        self._known.pop(addr, None)
        self._known[addr] = None
        while len(self._known) > self.max_addresses:
            del self._known[next(iter(self._known))]

    def auth_failed(self, addr: str, now: float) -> None:
        """A peer from ``addr`` failed authentication."""
        bucket = self._fails.get(addr)
        if bucket is None:
            bucket = self._fails[addr] = TokenBucket(self.fail_rate, self.fail_burst, now)
            while len(self._fails) > self.max_addresses:
                del self._fails[next(iter(self._fails))]
        bucket.take(now)

    def prune(self, now: float) -> None:
        """Forget the throttled addresses whose buckets are full again (once a second)."""
        if now - self._last_prune < 1.0:
            return
        self._last_prune = now
        for addr in [a for a, b in self._fails.items() if b.level(now) >= b.burst]:
            del self._fails[addr]

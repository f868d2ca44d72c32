"""The sensor client's host clock.

A sensor client answers clock probes and stamps frame arrivals with its PC's *host clock*. On a
real client PC that clock is the PC's own (``time.monotonic`` here: :func:`real_host_clock`).
A simulated client on the server's machine must not share the server's clock (the sync would
have nothing to find), so it emulates one on ``CLOCK_MONOTONIC``::

    host(t_mono) = h0 + (1 + drift) * (t_mono - m0)        (an AffineClock)

with ``h0``/``drift`` taken from the simulated session's true host clock of that sensor (the
simulator reads it back: :func:`kinefuse.sim.clock.read_sensor_clocks`; or given by
``--clock-offset-ms`` / ``--clock-drift-ppm``) and ``m0`` the monotonic instant that plays true
time 0. These values are TRUTH (the simulator's); the client writes them only to its
``--truth-out`` sidecar for the evaluation, never to the server.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

from kinefuse.core.affine_clock import AffineClock
from kinefuse.errors import InputError

#: a monotonic clock, seconds (injected so tests can drive time)
Monotonic = Callable[[], float]


@dataclass(frozen=True)
class HostClock:
    """``host(t) = h0 + (1 + drift) * (t - m0)`` of a monotonic time ``t`` (seconds).

    Attributes
    ----------
    h0 : float
        Host time at monotonic ``m0``, seconds.
    drift : float
        Rate error (dimensionless; 1e-6 = 1 ppm): the host clock runs ``1 + drift`` times as
        fast as the monotonic one.
    m0 : float
        The monotonic instant at which the host clock reads ``h0``.
    monotonic : callable
        The monotonic clock read by :meth:`now` (``time.monotonic``).
    affine : AffineClock
        Monotonic time -> host time (derived from ``h0``, ``drift`` and ``m0``).
    """

    h0: float
    drift: float
    m0: float
    monotonic: Monotonic = time.monotonic
    affine: AffineClock = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not abs(self.drift) < 1e-2:
            raise InputError(
                f"host clock drift {self.drift * 1e6:g} ppm is not a clock's; give |drift| "
                "below 10000 ppm"
            )
        a = AffineClock.from_drift(self.drift, offset=self.h0, origin=self.m0)
        object.__setattr__(self, "affine", a)

    def now(self) -> float:
        """The host clock now."""
        return self.affine.forward(self.monotonic())

    def to_dict(self) -> dict[str, float]:
        return {"h0": self.h0, "drift": self.drift, "m0": self.m0}


def real_host_clock(monotonic: Monotonic = time.monotonic) -> HostClock:
    """The PC's own clock (a physical sensor's client): ``host(t) = t``."""
    return HostClock(0.0, 0.0, 0.0, monotonic)

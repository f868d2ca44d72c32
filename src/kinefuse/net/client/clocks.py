"""The sensor client's host clock, and what a simulated sensor's true clocks say.

A sensor client answers clock probes and stamps frame arrivals with its PC's *host clock*. On a
real client PC that clock is the PC's own (``time.monotonic`` here: :func:`real_host_clock`).
A simulated client on the server's machine must not share the server's clock (the sync would
have nothing to find), so it emulates one on ``CLOCK_MONOTONIC``::

    host(t_mono) = h0 + (1 + drift) * (t_mono - m0)        (an AffineClock)

with ``h0``/``drift`` taken from the simulated session's true host clock of that sensor (or
given by ``--clock-offset-ms`` / ``--clock-drift-ppm``) and ``m0`` the monotonic instant that
plays true time 0. These values are TRUTH (the simulator's); the client writes them only to its
``--truth-out`` sidecar for the evaluation, never to the server.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

from kinefuse.errors import InputError
from kinefuse.io.store.session import SessionStore
from kinefuse.sync.affine import AffineClock

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

    def at(self, t_mono: float) -> float:
        """Host time at monotonic time ``t_mono``."""
        return self.affine.forward(t_mono)

    def mono_at(self, t_host: float) -> float:
        """The monotonic time at which the host clock reads ``t_host``."""
        return self.affine.inverse(t_host)

    def now(self) -> float:
        """The host clock now."""
        return self.at(self.monotonic())

    def to_dict(self) -> dict[str, float]:
        return {"h0": self.h0, "drift": self.drift, "m0": self.m0}


def real_host_clock(monotonic: Monotonic = time.monotonic) -> HostClock:
    """The PC's own clock (a physical sensor's client): ``host(t) = t``."""
    return HostClock(0.0, 0.0, 0.0, monotonic)


@dataclass(frozen=True)
class SimClockTruth:
    """A simulated sensor's true clocks (``kinefuse.sim.clock.SensorClocks.to_dict``).

    ``device``: true time -> device time, an :class:`AffineClock` of ``offset_s`` and
    ``drift_ppm``; ``host`` likewise of ``host_offset_s``/``host_drift_ppm``;
    ``latency_offset_s`` is the unit's extra mean capture-to-host latency. True time is the
    simulated server's clock.
    """

    offset_s: float
    drift_ppm: float
    host_offset_s: float
    host_drift_ppm: float
    latency_offset_s: float = 0.0
    device: AffineClock = field(init=False, repr=False, compare=False)
    host: AffineClock = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        dev = AffineClock.from_drift_ppm(self.drift_ppm, offset=self.offset_s)
        host = AffineClock.from_drift_ppm(self.host_drift_ppm, offset=self.host_offset_s)
        object.__setattr__(self, "device", dev)
        object.__setattr__(self, "host", host)

    @classmethod
    def from_store(cls, store: SessionStore, sensor_id: str) -> SimClockTruth:
        """Read it from a simulated session's truth (the emulation's own knowledge)."""
        if not store.has_truth():
            raise InputError(
                f"{store.path} holds no simulator truth (a live recording?): a sim: source must "
                "be a simulated session (kinefuse simulate); replay a recording with "
                "--clock-offset-ms/--clock-drift-ppm given"
            )
        _pose, clock = store.truth().sensor(sensor_id)
        try:
            return cls(
                offset_s=clock["offset_s"],
                drift_ppm=clock["drift_ppm"],
                host_offset_s=clock["host_offset_s"],
                host_drift_ppm=clock["host_drift_ppm"],
                latency_offset_s=clock.get("latency_offset_s", 0.0),
            )
        except KeyError as e:
            raise InputError(
                f"{store.path}: the true clock of sensor {sensor_id!r} has no {e}; simulate the "
                "session again with this kinefuse"
            ) from None

    def device_to_true(self, t_device_s: float) -> float:
        return self.device.inverse(t_device_s)

    def host_to_true(self, t_host_s: float) -> float:
        return self.host.inverse(t_host_s)

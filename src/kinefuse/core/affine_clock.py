"""One affine map between two clocks: the single home of ``offset + rate * (t - origin)``.

Every clock relation in kinefuse is affine over the spans it is used on: a simulated sensor's
device or host clock against true time, a client's clock against the server's (NTP-style probes,
offline or online), a device clock against its host PC's, a log's sensor clock against its
receiver's. The classes that estimate or simulate those relations carry more than the map
(uncertainties, frame phases, jitter figures, the monotonic clock they read) and hold an
:class:`AffineClock` for the map itself. Pure: imports nothing from kinefuse.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, overload

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

#: one part per million, dimensionless
PPM = 1e-6


@dataclass(frozen=True, kw_only=True)
class AffineClock:
    """``forward(t) = offset + rate * (t - origin)``: a *source* clock's time to a *target*'s.

    All times are in seconds. ``forward`` takes a reading ``t`` of the source clock and returns
    the target clock's reading at the same instant; ``inverse`` does the reverse. Which clocks
    are source and target is the holder's to say (e.g. for a client clock estimated from
    probes, source = server, target = client).

    Attributes
    ----------
    origin : float
        The reference instant, on the source clock, s.
    offset : float
        The target clock's reading at ``origin``, s.
    rate : float
        Target seconds per source second (dimensionless, positive): the target clock runs
        ``rate`` times as fast as the source; ``rate = 1 + drift_ppm * 1e-6``.

    The default is the identity map. Values are not checked (a degenerate fit's NaN passes
    through, as the arithmetic would); the holders check what they take in.
    """

    origin: float = 0.0
    offset: float = 0.0
    rate: float = 1.0

    @classmethod
    def from_drift(cls, drift: float, *, offset: float = 0.0, origin: float = 0.0) -> AffineClock:
        """The map whose rate is ``1 + drift`` (``drift`` dimensionless: 1e-6 is 1 ppm)."""
        return cls(origin=origin, offset=offset, rate=1.0 + drift)

    @classmethod
    def from_drift_ppm(
        cls, drift_ppm: float, *, offset: float = 0.0, origin: float = 0.0
    ) -> AffineClock:
        """The map whose rate is ``1 + drift_ppm * 1e-6`` (drift in parts per million)."""
        return cls.from_drift(drift_ppm * PPM, offset=offset, origin=origin)

    @property
    def drift_ppm(self) -> float:
        """``(rate - 1) * 1e6``: how much faster the target runs, parts per million."""
        return (self.rate - 1.0) * 1e6

    @overload
    def forward(self, t: float) -> float: ...
    @overload
    def forward(self, t: NDArray[Any]) -> Array: ...
    def forward(self, t: float | NDArray[Any]) -> float | Array:
        """Target-clock times of source-clock times ``t`` (s); a float for a float."""
        return self.offset + self.rate * (t - self.origin)

    @overload
    def inverse(self, t: float) -> float: ...
    @overload
    def inverse(self, t: NDArray[Any]) -> Array: ...
    def inverse(self, t: float | NDArray[Any]) -> float | Array:
        """Source-clock times of target-clock times ``t`` (s): undoes :meth:`forward`."""
        return (t - self.offset) / self.rate + self.origin

    def inverted(self) -> AffineClock:
        """The map from the target clock back to the source (``forward`` is this ``inverse``)."""
        return AffineClock(origin=self.offset, offset=self.origin, rate=1.0 / self.rate)

    def compose(self, inner: AffineClock) -> AffineClock:
        """``self`` after ``inner``: ``forward(t) = self.forward(inner.forward(t))``.

        ``inner`` maps clock A to B and ``self`` maps B to C; the result maps A to C, with
        ``inner``'s origin.
        """
        return AffineClock(
            origin=inner.origin,
            offset=self.forward(inner.offset),
            rate=self.rate * inner.rate,
        )


@dataclass(frozen=True)
class OffsetDriftClock:
    """Base of the frozen dataclasses whose clock map is an offset and a drift in ppm.

    Subclasses add what they carry beyond the map (a frame phase, a fit's residual); times are
    mapped by the map itself, :attr:`affine` (``forward``: source -> target).

    Attributes
    ----------
    offset_s : float
        The target clock's reading at source time 0, s.
    drift_ppm : float
        Parts per million by which the target clock runs faster than the source.
    affine : AffineClock
        The map, source -> target (derived from the two, origin 0).
    """

    offset_s: float
    drift_ppm: float
    affine: AffineClock = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        a = AffineClock.from_drift_ppm(self.drift_ppm, offset=self.offset_s)
        object.__setattr__(self, "affine", a)

    @property
    def rate(self) -> float:
        """Target seconds per source second."""
        return self.affine.rate

"""The motion sequence every reader produces: Kinect v2 joints over time in the lab frame."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.core.skeleton import N_JOINTS

Array = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class Motion:
    """Positions of the 25 Kinect v2 joints over time (the ground truth of a simulated session).

    Attributes
    ----------
    positions : (T, 25, 3) float
        Joint positions in the world (lab) frame, metres, z up, in ``kinefuse.core.skeleton.JOINTS``
        order. Frame ``k`` is at time ``k / rate_hz`` seconds.
    rate_hz : float
        Frame rate.
    synthesized : (25,) bool
        True for joints the source did not have and that were synthesized (hand tips, thumbs,
        feet...).
    source : str
        Where the motion came from (path and notes), for provenance.
    """

    positions: Array
    rate_hz: float
    synthesized: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(N_JOINTS, dtype=bool))
    source: str = ""

    def __post_init__(self) -> None:
        p = np.asarray(self.positions, dtype=np.float64)
        if p.ndim != 3 or p.shape[1:] != (N_JOINTS, 3) or p.shape[0] < 1:
            raise ValueError(f"positions must have shape (T, {N_JOINTS}, 3), got {p.shape}")
        if not np.isfinite(p).all():
            raise ValueError("positions must be finite (the truth has no gaps)")
        if not self.rate_hz > 0:
            raise ValueError(f"rate_hz must be positive, got {self.rate_hz}")
        s = np.asarray(self.synthesized, dtype=bool)
        if s.shape != (N_JOINTS,):
            raise ValueError(f"synthesized must have shape ({N_JOINTS},), got {s.shape}")
        object.__setattr__(self, "positions", p)
        object.__setattr__(self, "synthesized", s)

    @property
    def n_frames(self) -> int:
        return int(self.positions.shape[0])

    @property
    def duration_s(self) -> float:
        """Time of the last frame, seconds."""
        return (self.n_frames - 1) / self.rate_hz

    @property
    def times_s(self) -> Array:
        return np.arange(self.n_frames) / self.rate_hz

    def at(self, t_s: ArrayLike) -> Array:
        """Joint positions ``(..., 25, 3)`` at times ``t_s`` ``(...)``, linearly interpolated.

        Times outside ``[0, duration_s]`` are clamped to the first or last frame.
        """
        t = np.asarray(t_s, dtype=np.float64)
        f = np.clip(t * self.rate_hz, 0.0, self.n_frames - 1)
        i0 = np.minimum(np.floor(f).astype(np.intp), self.n_frames - 1)
        i1 = np.minimum(i0 + 1, self.n_frames - 1)
        w = (f - i0)[..., None, None]
        return self.positions[i0] * (1.0 - w) + self.positions[i1] * w

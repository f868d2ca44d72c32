"""The calibration wand: a rigid object of known geometry held by the actor.

Default: a sphere of radius 0.10 m (e.g. a painted foam ball) on a thin stick of radius 0.01 m and
length 0.40 m, held at the stick's far end. A sphere looks the same from every sensor, so every
sensor sees the same centre; its radius is known, so the centre can be recovered from the visible
cap of the surface (the paper uses a QR-code plate with a known radius instead, which only the
sensors facing it can see).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Wand:
    """Wand geometry, metres."""

    radius_m: float = 0.10
    stick_length_m: float = 0.40
    stick_radius_m: float = 0.01

    def __post_init__(self) -> None:
        if not 0.02 <= self.radius_m <= 0.5:
            raise ValueError(f"wand radius must be 0.02 to 0.5 m, got {self.radius_m} m")
        if self.stick_length_m < 0 or self.stick_radius_m < 0:
            raise ValueError("wand stick length and radius must be non-negative")

    def stick_segment(self, centre: Array, handle_dir: Array) -> tuple[Array, Array]:
        """End points ``(..., 3)`` of the stick: from the sphere's surface to the handle.

        ``handle_dir`` ``(..., 3)`` is the unit direction from the sphere centre to the hand.
        """
        c = np.asarray(centre, dtype=np.float64)
        d = np.asarray(handle_dir, dtype=np.float64)
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        return c + d * self.radius_m, c + d * (self.radius_m + self.stick_length_m)

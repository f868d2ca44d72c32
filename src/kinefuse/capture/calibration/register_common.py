"""What registration works on and returns: the wand centres a sensor saw (:class:`Sightings`) and
every sensor's pose in one world frame (:class:`Registration`). Re-exported by
:mod:`kinefuse.capture.calibration.register`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from kinefuse.errors import InputError

Array = NDArray[np.float64]


# sensor frame (x right, y down, z forward) -> level frame (x right, y forward, z up)
_SENSOR2LEVEL = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True, eq=False)
class Sightings:
    """The wand centres one sensor reported, on the server clock.

    Attributes
    ----------
    t_server_s : (N,) float
        Capture times mapped to the server clock, seconds.
    centre_sensor_m : (N, 3) float
        Wand centre in the sensor frame, metres; rows with NaN (wand not found) are dropped.
    quality : (N,) float
        Detection quality in (0, 1] (the detector's score), used as a weight. Default 1.

    The rows are sorted by time on construction.
    """

    t_server_s: Array
    centre_sensor_m: Array
    quality: Array = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        t = np.asarray(self.t_server_s, dtype=np.float64).reshape(-1)
        c = np.asarray(self.centre_sensor_m, dtype=np.float64)
        if c.ndim != 2 or c.shape[1] != 3:
            raise InputError(f"centre_sensor_m must have shape (N, 3), got {c.shape}")
        if c.shape[0] != t.shape[0]:
            raise InputError(
                f"t_server_s has {t.shape[0]} times but centre_sensor_m {c.shape[0]} rows"
            )
        q = np.asarray(self.quality, dtype=np.float64).reshape(-1)
        if q.size == 0:
            q = np.ones(t.shape[0])
        if q.shape != t.shape:
            raise InputError(f"quality must have shape ({t.shape[0]},), got {q.shape}")
        if not np.all(np.isfinite(t)):
            raise InputError("t_server_s contains NaN/inf; every sighting needs a time")
        keep = np.isfinite(c).all(axis=1) & np.isfinite(q) & (q > 0)
        order = np.argsort(t[keep], kind="stable")
        object.__setattr__(self, "t_server_s", t[keep][order])
        object.__setattr__(self, "centre_sensor_m", c[keep][order])
        object.__setattr__(self, "quality", np.minimum(q[keep][order], 1.0))

    def __len__(self) -> int:
        return int(self.t_server_s.shape[0])


@dataclass(frozen=True, eq=False)
class Registration:
    """Result of a registration.

    Attributes
    ----------
    method : str
        ``"paper"`` or ``"full"``.
    sensor_ids : tuple of str
    sensor2world : (S, 4, 4) float
        Pose of every sensor, in ``sensor_ids`` order.
    residual_m : (S,) float
        RMS distance between each sensor's wand centres (mapped to the world) and the jointly
        estimated wand positions, metres (inliers of the robust fit).
    n_sightings : (S,) int
        Number of that sensor's sightings the result rests on.
    rms_m : float
        RMS residual over all sensors.
    world : str
        How the world frame was defined (for the calibration file and the logs).
    scale : float
        The factor every sensor position was scaled by about the world origin to correct the
        world's scale (the wand protocol's known move); 1.0: not scaled. The sensors' own
        measurements are not scaled: a sensor registered later against this world is
        registered in the unscaled one and its position scaled by the same factor.
    """

    method: str
    sensor_ids: tuple[str, ...]
    sensor2world: Array
    residual_m: Array
    n_sightings: NDArray[np.int64]
    rms_m: float
    world: str
    scale: float = 1.0

    def pose(self, sensor_id: str) -> Array:
        """``sensor2world`` of one sensor."""
        try:
            return self.sensor2world[self.sensor_ids.index(sensor_id)]
        except ValueError:
            raise KeyError(
                f"unknown sensor {sensor_id!r}; registered: {', '.join(self.sensor_ids)}"
            ) from None

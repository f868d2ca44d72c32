"""Registration: every sensor's pose in one world frame from wand centres (server side, pure).

Two methods:

* :func:`register_paper`: paper A's level-sensor method (METHODS.md A.3 step 5). Every sensor is
  assumed level, so it differs from the world by a rotation about the vertical and a translation.
  The wand is shown at the origin, then moved along the world's y axis; each sensor sees both
  positions. The heading comes from the direction of the move seen by the sensor, with ``atan2``
  (the paper's ``arccos`` loses the sign).
* :func:`register_full`: all six degrees of freedom of every sensor. Wand tracks are matched in
  time across sensors (each sensor's track interpolated to a common 30 Hz grid on the server
  clock, skipping gaps and fast moves, because the sensors are not synchronized); sensors are
  added one by one along a maximum spanning tree of the "saw the wand together" graph, each by a
  robust Kabsch fit to the wand positions the already registered sensors agree on; then one joint
  robust least-squares refinement of all poses and all wand positions
  (``scipy.optimize.least_squares``, sparse analytic Jacobian, ``soft_l1`` loss). Gravity and the
  floor height come from the floor planes the sensors see
  (:mod:`kinefuse.capture.calibration.floor`); the origin and x axis as in the paper (first wand
  position, on the floor, x along its first horizontal move), or pinned to a chosen sensor.

Conventions: sensor frames x right, y down, z forward; world right-handed, z up; poses are
``sensor2world`` ``(4, 4)``; metres and seconds.
"""

from __future__ import annotations

from kinefuse.capture.calibration.register_common import Registration, Sightings
from kinefuse.capture.calibration.register_full import register_full
from kinefuse.capture.calibration.register_paper import (
    find_hold_windows,
    paper_positions_from_sightings,
    register_paper,
)

__all__ = [
    "Registration",
    "Sightings",
    "find_hold_windows",
    "paper_positions_from_sightings",
    "register_full",
    "register_paper",
]

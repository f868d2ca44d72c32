"""Fusion of several sensors' joints: the paper's trilateration chain and its baselines.

``trilaterate(joints_sensor, sensor2world, method)`` runs one of :data:`METHODS` on a session;
the ``solve_*`` functions are the batched solvers underneath, on ``(N, K)`` range problems.

May import: errors, io (base), skeleton, geometry, camera, frames, protocol, motion, sync,
occlusion, calibration (the numerical core: no files, sockets or clocks).
"""

from kinefuse.fusion.status import FusionStatus, is_solved, status_counts
from kinefuse.fusion.trilateration import (
    DEFAULT_C_THRESHOLD,
    DEFAULT_MAX_ITER,
    METHODS,
    MIN_SENSORS,
    FusionResult,
    Solution,
    fuse_geometric,
    fuse_linear,
    fuse_nonlinear,
    fuse_paper,
    sensor_centres,
    sensor_ranges,
    solve_geometric,
    solve_linear,
    solve_nonlinear,
    to_world,
    trilaterate,
)

__all__ = [
    "DEFAULT_C_THRESHOLD",
    "DEFAULT_MAX_ITER",
    "METHODS",
    "MIN_SENSORS",
    "FusionResult",
    "FusionStatus",
    "Solution",
    "fuse_geometric",
    "fuse_linear",
    "fuse_nonlinear",
    "fuse_paper",
    "is_solved",
    "sensor_centres",
    "sensor_ranges",
    "solve_geometric",
    "solve_linear",
    "solve_nonlinear",
    "status_counts",
    "to_world",
    "trilaterate",
]

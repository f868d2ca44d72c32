"""Trilateration's shared pieces: constants, result types (:class:`Solution` per problem,
:class:`FusionResult` per frame and joint) and the helpers that turn sensors' observations into
problems (centres, ranges, availability, the reference point). Re-exported by
:mod:`kinefuse.capture.fusion.trilateration`, whose docstring describes the methods.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.capture.fusion.methods import TRILATERATION_METHODS
from kinefuse.core.geometry.transforms import check_rigid
from kinefuse.core.skeleton import N_JOINTS, TrackingState
from kinefuse.errors import InputError

Array = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
StatusArray = NDArray[np.int8]


_G = TypeVar("_G", bound=np.generic)

OutOfPlane = Literal["auto", "lstsq", "ranges"]
#: The trilateration methods, in the order of the paper's comparison.
METHODS = TRILATERATION_METHODS

#: Minimum number of sensors to trilaterate a joint.
MIN_SENSORS = 3
#: Default stopping threshold on ``|F_k - F_{k-1}|``, square metres.
DEFAULT_C_THRESHOLD = 1e-6
#: Default iteration cap of the Gauss-Newton solver.
DEFAULT_MAX_ITER = 50
#: ``det(J^T J) / (trace / 3)^3`` below this counts as singular.
SINGULAR_REL_DET = 1e-12
_COPLANAR_REL = 1e-12  # smallest / largest scatter eigenvalue below this: exactly coplanar
_COLLINEAR_REL = 1e-10  # middle / largest scatter eigenvalue below this: collinear
_MAX_SENSORS = 62  # mask patterns are packed into int64
_MAX_HALVINGS = 10  # step halvings before a Gauss-Newton step that raises F is given up
#: Below this RMS spread of the sensors out of their best-fit plane (metres), ``out_of_plane=
#: "auto"`` takes the out-of-plane coordinate from the ranges: with range noise sigma at range r,
#: least squares has error ``r sigma / (sqrt(n) spread)`` there, the ranges at most about
#: ``sqrt(2 r sigma / sqrt(n))`` (0.3 m for 3 m and 3 cm), so least squares only wins with a
#: spread of about 0.2 m or more.
PLANAR_SPREAD_M = 0.2


@dataclass(frozen=True, eq=False)
class Solution:
    """Result of a low-level solver on ``N`` independent problems.

    Attributes
    ----------
    positions : (N, 3) float
        World positions, metres; NaN only with ``NO_DATA`` (or a NaN reference, see the status).
    status : (N,) int8
        :class:`~kinefuse.capture.fusion.status.FusionStatus` codes.
    iterations : (N,) int32
        Gauss-Newton iterations run (0 for the closed-form methods).
    used : (N, K) bool
        The sensors that took part in each problem.
    """

    positions: Array
    status: StatusArray
    iterations: NDArray[np.int32]
    used: BoolArray


@dataclass(frozen=True, eq=False)
class FusionResult:
    """Fused joints of a session.

    Attributes
    ----------
    positions : (T, 25, 3) float
        Joint positions in the world frame, metres; finite except where ``status`` is
        ``NO_DATA``.
    status : (T, 25) int8
        :class:`~kinefuse.capture.fusion.status.FusionStatus` codes.
    used : (T, S, 25) bool
        Sensors that took part per frame and joint.
    iterations : (T, 25) int32
        Gauss-Newton iterations (0 for the closed-form methods).
    """

    positions: Array
    status: StatusArray
    used: BoolArray
    iterations: NDArray[np.int32]

    @property
    def n_sensors(self) -> NDArray[np.int64]:
        """Number of sensors used per frame and joint, ``(T, 25)``."""
        return np.asarray(self.used.sum(axis=1), dtype=np.int64)


# --------------------------------------------------------------------------------------------
# helpers on sessions


def sensor_centres(sensor2world: ArrayLike) -> Array:
    """Optical centres of the sensors in the world, ``(S, 3)`` metres, from ``(S, 4, 4)`` poses."""
    return _check_poses(sensor2world)[:, :3, 3].copy()


def to_world(joints_sensor: ArrayLike, sensor2world: ArrayLike) -> Array:
    """Map every sensor's joints from its own frame into the world.

    Parameters
    ----------
    joints_sensor : (T, S, 25, 3) float
        Joints in each sensor's frame (x right, y down, z forward), metres; NaN stays NaN.
    sensor2world : (S, 4, 4) float
        Rigid poses of the sensors.

    Returns
    -------
    joints_world : (T, S, 25, 3) float
    """
    j = _check_joints(joints_sensor)
    return _to_world(j, _check_poses(sensor2world, j.shape[1]))


def _to_world(j: Array, t: Array) -> Array:
    out = np.empty_like(j)
    for s in range(j.shape[1]):  # a few sensors; each a BLAS product over frames and joints
        out[:, s] = j[:, s] @ t[s, :3, :3].T + t[s, :3, 3]
    return out


def sensor_ranges(joints_sensor: ArrayLike) -> Array:
    """Range of every joint from its sensor's optical centre, ``(T, S, 25)`` metres (NaN kept)."""
    return _ranges(_check_joints(joints_sensor))


def _ranges(j: Array) -> Array:
    return np.asarray(np.sqrt((j * j) @ np.ones(3)), dtype=np.float64)


def _check_joints(joints_sensor: ArrayLike) -> Array:
    j = np.asarray(joints_sensor, dtype=np.float64)
    if j.ndim != 4 or j.shape[2:] != (N_JOINTS, 3) or j.shape[1] < 1:
        raise InputError(
            f"joints_sensor must have shape (T, S, {N_JOINTS}, 3): frames, sensors, joints, xyz "
            f"in each sensor's frame (metres), got {j.shape}; add a sensor axis for one sensor"
        )
    return j


def _check_poses(sensor2world: ArrayLike, n_sensors: int | None = None) -> Array:
    t = np.asarray(sensor2world, dtype=np.float64)
    if t.ndim != 3 or t.shape[1:] != (4, 4):
        raise InputError(f"sensor2world must have shape (S, 4, 4), got {t.shape}")
    if n_sensors is not None and t.shape[0] != n_sensors:
        raise InputError(
            f"sensor2world has {t.shape[0]} poses but the observations have {n_sensors} sensors; "
            f"pass one pose per sensor, in the order of the sensor axis"
        )
    return check_rigid(t, "sensor2world")


def _available(ranges: Array, mask: ArrayLike | None, states: ArrayLike | None) -> BoolArray:
    """Observations that may take part: finite, not at the optical centre, masked in, tracked."""
    with np.errstate(invalid="ignore"):
        avail = np.isfinite(ranges) & (ranges > 0)
    shape = ranges.shape
    if mask is not None:
        m = np.asarray(mask)
        if m.dtype != np.bool_ or m.shape != shape:
            raise InputError(f"mask must be a bool array of shape {shape}, got {m.dtype} {m.shape}")
        avail &= m
    if states is not None:
        s = np.asarray(states)
        if s.shape != shape or not np.issubdtype(s.dtype, np.integer):
            raise InputError(
                f"states must be an integer array of shape {shape} (TrackingState codes), "
                f"got {s.dtype} {s.shape}"
            )
        avail &= s != TrackingState.NOT_TRACKED
    return np.asarray(avail, dtype=bool)


def _to_problems(a: NDArray[_G]) -> NDArray[_G]:
    """``(T, S, 25, ...)`` -> ``(T * 25, S, ...)``."""
    a = np.moveaxis(a, 2, 1)
    return a.reshape(a.shape[0] * a.shape[1], *a.shape[2:])


def _reference(world_p: Array, use_p: BoolArray) -> Array:
    """Mean of the used sensors' world measurements per problem, ``(N, 3)``; NaN if none."""
    total = np.zeros((world_p.shape[0], 3))
    for s in range(world_p.shape[1]):  # a few sensors
        total += np.where(use_p[:, s, None], world_p[:, s], 0.0)
    n = use_p.astype(np.float64) @ np.ones(use_p.shape[1])
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n[:, None] > 0, total / n[:, None], np.nan)


def _to_result(sol: Solution, n_frames: int) -> FusionResult:
    n_sensors = sol.used.shape[1]
    used = sol.used.reshape(n_frames, N_JOINTS, n_sensors).transpose(0, 2, 1)
    return FusionResult(
        positions=sol.positions.reshape(n_frames, N_JOINTS, 3),
        status=sol.status.reshape(n_frames, N_JOINTS),
        used=np.ascontiguousarray(used),
        iterations=sol.iterations.reshape(n_frames, N_JOINTS),
    )

"""Trilateration of joints from several depth sensors (paper A, METHODS.md A.5) and its baselines.

Sensor ``i`` sits at ``s_i`` (the translation of its ``sensor2world``) and measures a joint at the
range ``r_i = |joint in the sensor frame|``. The methods find the world point ``p`` whose distances
to the sensors match the ranges:

``linear``
    Linear least squares from the squared range equations differenced against their mean. In the
    eigenbasis of the sensors' scatter matrix the normal equations are diagonal: the two in-plane
    coordinates are always well determined (unless the sensors are collinear), the out-of-plane
    one only as well as the sensors spread out of their best-fit plane. When that spread is
    smaller than the joint's distance from the plane (level sensors at one height, or 3 sensors:
    exactly coplanar), the out-of-plane coordinate is taken from the ranges instead
    (``H^2 = mean(r^2) - X^2 - Y^2 - mean(|s_i - s_mean|^2)``, exact for exact ranges), with the
    mirror sign chosen toward the reference point (status ``PLANAR``). ``out_of_plane="lstsq"``
    keeps the plain least-squares answer (the paper's baseline), flagged ``DEGENERATE`` when the
    sensors spread less than :data:`PLANAR_SPREAD_M` out of their plane (with exactly coplanar
    sensors it does not exist: the reference is returned); ``"ranges"`` always uses the ranges.
``geometric``
    Paper C's closed-form intersection of three spheres. With more than 3 sensors the three
    nearest ones (smallest ranges: Kinect v2 noise grows with distance) among those not collinear
    are used. Of the two mirror solutions the one nearer the reference point is kept (``PLANAR``);
    when the spheres do not meet, the point in the sensors' plane where the radical planes cross
    (``NO_INTERSECTION``).
``nonlinear``
    Paper A's Gauss-Newton on ``F(p) = sum_i (|p - s_i| - r_i)^2``: start from the ``linear``
    solution (the reference point when that is degenerate), step ``-(J^T J)^-1 J^T f`` with the
    3x3 inverse as adjugate / determinant, stop a problem when ``|F_k - F_{k-1}| < c_threshold``
    (converged problems stop updating), cap the iterations. Two safeguards the paper does not
    mention: a step that would raise ``F`` is halved until it does not (plain Gauss-Newton
    wanders from starts near the plane of level sensors, where ``J^T J`` is nearly singular), and
    where the mirror side came from the reference a step may not cross the sensors' plane.
    A singular ``J^T J`` stops the problem with ``DEGENERATE``; the cap gives ``NOT_CONVERGED``.
    Either way the last iterate is returned, and its cost is never above the start's.
``paper``
    The whole chain of paper A: client-side occlusion detection, the server's selection of the
    unoccluded sensors, then ``nonlinear`` on those. When fewer than 3 sensors are selected the
    joint cannot be trilaterated and the mean of the selected sensors' own world-frame
    measurements is returned (``TOO_FEW_SENSORS``): with a single sensor, that sensor's joint, as
    in the paper.

The reference point, used to choose between mirror solutions and as the fallback, is the mean of
the participating sensors' own measurements mapped to the world (:func:`to_world`). Level sensors
at one height see every joint at two mirror-image points with equal ranges; only this direct 3D
information tells them apart.

All solvers are batched over problems (frames x joints): Python loops run only over iterations,
sensor-mask patterns and sensor triples, never over frames or joints.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.capture.fusion.trilat_common import (
    DEFAULT_C_THRESHOLD,
    DEFAULT_MAX_ITER,
    METHODS,
    MIN_SENSORS,
    PLANAR_SPREAD_M,
    SINGULAR_REL_DET,
    FusionResult,
    OutOfPlane,
    Solution,
    _available,
    _check_joints,
    _check_poses,
    _ranges,
    _reference,
    _to_problems,
    _to_result,
    _to_world,
    sensor_centres,
    sensor_ranges,
    to_world,
)
from kinefuse.capture.fusion.trilat_solvers import (
    solve_geometric,
    solve_linear,
    solve_nonlinear,
)
from kinefuse.capture.occlusion.segments import (
    DEFAULT_NEAR_M,
    OcclusionRule,
    detect_occlusion_sensors,
)
from kinefuse.capture.occlusion.select import select_sensors
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.errors import InputError

Array = NDArray[np.float64]

__all__ = [
    "DEFAULT_C_THRESHOLD",
    "DEFAULT_MAX_ITER",
    "METHODS",
    "MIN_SENSORS",
    "PLANAR_SPREAD_M",
    "SINGULAR_REL_DET",
    "FusionResult",
    "OutOfPlane",
    "Solution",
    "fuse_geometric",
    "fuse_linear",
    "fuse_nonlinear",
    "fuse_paper",
    "sensor_centres",
    "sensor_ranges",
    "solve_geometric",
    "solve_linear",
    "solve_nonlinear",
    "to_world",
    "trilaterate",
]
BoolArray = NDArray[np.bool_]
StatusArray = NDArray[np.int8]
# --------------------------------------------------------------------------------------------
# methods on sessions


def _prepare(
    joints_sensor: ArrayLike,
    sensor2world: ArrayLike,
    mask: ArrayLike | None,
    states: ArrayLike | None,
) -> tuple[Array, Array, Array, Array, BoolArray]:
    j = _check_joints(joints_sensor)
    t = _check_poses(sensor2world, j.shape[1])
    ranges = _ranges(j)
    avail = _available(ranges, mask, states)
    return j, t, _to_world(j, t), ranges, avail


def fuse_linear(
    joints_sensor: ArrayLike,
    sensor2world: ArrayLike,
    *,
    mask: ArrayLike | None = None,
    states: ArrayLike | None = None,
    out_of_plane: OutOfPlane = "auto",
) -> FusionResult:
    """Linear least-squares trilateration of every frame and joint (see :func:`solve_linear`).

    Parameters
    ----------
    joints_sensor : (T, S, 25, 3) float
        Each sensor's joints in its own frame (x right, y down, z forward), metres; NaN where
        missing.
    sensor2world : (S, 4, 4) float
        Sensor poses.
    mask : (T, S, 25) bool, optional
        Observations allowed to take part (default all finite ones).
    states : (T, S, 25) int, optional
        :class:`~kinefuse.core.skeleton.TrackingState` per observation; ``NOT_TRACKED`` ones are
        left out.
    out_of_plane : {"auto", "lstsq", "ranges"}
        See :func:`solve_linear`.

    Returns
    -------
    FusionResult
    """
    j, t, world, ranges, avail = _prepare(joints_sensor, sensor2world, mask, states)
    use_p = _to_problems(avail)
    sol = solve_linear(
        t[:, :3, 3],
        _to_problems(ranges),
        _reference(_to_problems(world), use_p),
        mask=use_p,
        out_of_plane=out_of_plane,
    )
    return _to_result(sol, j.shape[0])


def fuse_geometric(
    joints_sensor: ArrayLike,
    sensor2world: ArrayLike,
    *,
    mask: ArrayLike | None = None,
    states: ArrayLike | None = None,
) -> FusionResult:
    """Three-sphere trilateration (paper C) of every frame and joint (see :func:`solve_geometric`).

    Parameters are those of :func:`fuse_linear`; ``used`` marks the three sensors chosen.
    """
    j, t, world, ranges, avail = _prepare(joints_sensor, sensor2world, mask, states)
    use_p = _to_problems(avail)
    sol = solve_geometric(
        t[:, :3, 3], _to_problems(ranges), _reference(_to_problems(world), use_p), mask=use_p
    )
    return _to_result(sol, j.shape[0])


def fuse_nonlinear(
    joints_sensor: ArrayLike,
    sensor2world: ArrayLike,
    *,
    mask: ArrayLike | None = None,
    states: ArrayLike | None = None,
    c_threshold: float = DEFAULT_C_THRESHOLD,
    max_iter: int = DEFAULT_MAX_ITER,
    out_of_plane: OutOfPlane = "auto",
) -> FusionResult:
    """Gauss-Newton trilateration (paper A) of every frame and joint (see :func:`solve_nonlinear`).

    Parameters are those of :func:`fuse_linear`, plus ``c_threshold`` (square metres) and
    ``max_iter``.
    """
    j, t, world, ranges, avail = _prepare(joints_sensor, sensor2world, mask, states)
    use_p = _to_problems(avail)
    sol = solve_nonlinear(
        t[:, :3, 3],
        _to_problems(ranges),
        _reference(_to_problems(world), use_p),
        mask=use_p,
        c_threshold=c_threshold,
        max_iter=max_iter,
        out_of_plane=out_of_plane,
    )
    return _to_result(sol, j.shape[0])


def fuse_paper(
    joints_sensor: ArrayLike,
    sensor2world: ArrayLike,
    intrinsics: Intrinsics | Sequence[Intrinsics] | None = None,
    *,
    occlusion: tuple[ArrayLike, ArrayLike] | None = None,
    mask: ArrayLike | None = None,
    states: ArrayLike | None = None,
    c_threshold: float = DEFAULT_C_THRESHOLD,
    max_iter: int = DEFAULT_MAX_ITER,
    near_m: float = DEFAULT_NEAR_M,
    rule: OcclusionRule = "crossing",
    out_of_plane: OutOfPlane = "auto",
) -> FusionResult:
    """Paper A's chain: occlusion detection, sensor selection, nonlinear trilateration.

    Parameters
    ----------
    joints_sensor, sensor2world, mask, states, c_threshold, max_iter, out_of_plane
        As in :func:`fuse_nonlinear`.
    intrinsics : Intrinsics or sequence of S Intrinsics, optional
        The sensors' depth cameras, to detect occlusion; not needed with ``occlusion``.
    occlusion : (occluded (T, S, 25) bool, n_intersections (T, S) int), optional
        Occlusion flags and intersection counts the clients computed; default: detect them here
        with :func:`kinefuse.capture.occlusion.detect_occlusion_sensors`.
    near_m, rule
        Occlusion detection settings (see :func:`kinefuse.capture.occlusion.detect_occlusion`).

    Returns
    -------
    FusionResult
        ``used`` is the selection. Joints with fewer than 3 selected sensors get the mean of the
        selected sensors' own world-frame measurements and ``TOO_FEW_SENSORS``.
    """
    j, t, _, _, avail = _prepare(joints_sensor, sensor2world, mask, states)
    if occlusion is None:
        if intrinsics is None:
            raise InputError(
                "fuse_paper needs the sensors' intrinsics to detect occlusion, or the clients' "
                "results as occlusion=(occluded, n_intersections)"
            )
        det = detect_occlusion_sensors(
            np.where(avail[..., None], j, np.nan), intrinsics, near_m=near_m, rule=rule
        )
        occluded, n_int = det.occluded, det.n_intersections
    else:
        if len(occlusion) != 2:
            raise InputError(
                "occlusion must be a pair (occluded (T, S, 25), n_intersections (T, S))"
            )
        occluded, n_int = np.asarray(occlusion[0]), np.asarray(occlusion[1])
    selected = select_sensors(occluded, n_int, avail)
    return fuse_nonlinear(
        j,
        t,
        mask=selected,
        states=states,
        c_threshold=c_threshold,
        max_iter=max_iter,
        out_of_plane=out_of_plane,
    )


def trilaterate(
    joints_sensor: ArrayLike,
    sensor2world: ArrayLike,
    method: str = "nonlinear",
    *,
    mask: ArrayLike | None = None,
    states: ArrayLike | None = None,
    intrinsics: Intrinsics | Sequence[Intrinsics] | None = None,
    occlusion: tuple[ArrayLike, ArrayLike] | None = None,
    c_threshold: float = DEFAULT_C_THRESHOLD,
    max_iter: int = DEFAULT_MAX_ITER,
    out_of_plane: OutOfPlane = "auto",
) -> FusionResult:
    """Fuse a session's joints with one of :data:`METHODS` by name.

    Parameters
    ----------
    joints_sensor : (T, S, 25, 3) float
    sensor2world : (S, 4, 4) float
    method : {"linear", "geometric", "nonlinear", "paper"}
    mask, states, intrinsics, occlusion, c_threshold, max_iter, out_of_plane
        Passed to the method that takes them (``intrinsics``/``occlusion`` to ``paper`` only;
        ``c_threshold``/``max_iter`` to ``nonlinear`` and ``paper``).

    Returns
    -------
    FusionResult
    """
    if method == "linear":
        return fuse_linear(
            joints_sensor, sensor2world, mask=mask, states=states, out_of_plane=out_of_plane
        )
    if method == "geometric":
        return fuse_geometric(joints_sensor, sensor2world, mask=mask, states=states)
    if method == "nonlinear":
        return fuse_nonlinear(
            joints_sensor,
            sensor2world,
            mask=mask,
            states=states,
            c_threshold=c_threshold,
            max_iter=max_iter,
            out_of_plane=out_of_plane,
        )
    if method == "paper":
        return fuse_paper(
            joints_sensor,
            sensor2world,
            intrinsics,
            occlusion=occlusion,
            mask=mask,
            states=states,
            c_threshold=c_threshold,
            max_iter=max_iter,
            out_of_plane=out_of_plane,
        )
    raise InputError(f"unknown trilateration method {method!r}; choose one of {', '.join(METHODS)}")

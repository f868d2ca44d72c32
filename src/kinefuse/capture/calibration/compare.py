"""Sensor poses of one calibration compared with another set of poses (no truth read here).

The other set is a second calibration (the split-half check of :mod:`kinefuse.capture.calibration.
grade`) or, in :mod:`kinefuse.lab.calibration_truth`, the true rig. Two worlds agree only up to a
choice of frame (the calibration puts its origin under the wand's first position, the simulator
wherever its rig file says), so the estimated poses are first mapped onto the reference ones by
the best transform of a chosen kind:

* ``"yaw"`` (default): rotation about the vertical plus a translation. Gravity is not
  re-estimated, so an error in the calibrated "up" shows up as rotation error, as it should;
* ``"rigid"``: full rotation and translation (for a world pinned to a sensor without gravity);
* ``"similarity"``: like ``"yaw"`` plus a uniform scale fitted on the sensor centres. A depth
  camera whose range error grows with distance (the Kinect v2's does, by a few mm per metre)
  makes a self-calibrated world slightly larger than the true one: no wand or floor seen in depth
  can tell, since the whole world scaled about itself fits the same measurements. This mode
  separates that scale (reported as ``PoseErrors.scale``) from the rest of the error;
* ``"none"``: the frames are already the same.

The alignment uses four points per sensor: its centre and the tips of its three axes at 1 m, so
it is defined for any number of sensors.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.core.geometry.rotations import rotation_angle_deg
from kinefuse.core.geometry.transforms import check_transform, kabsch, make_transform
from kinefuse.errors import InputError

Array = NDArray[np.float64]
Align = Literal["yaw", "rigid", "similarity", "none"]


@dataclass(frozen=True, eq=False)
class PoseErrors:
    """Per-sensor pose errors after aligning the estimated world onto the true one.

    Attributes
    ----------
    position_error_m : (S,) float
        Distance between estimated and true sensor centres.
    rotation_error_deg : (S,) float
        Angle of the rotation between estimated and true orientations.
    est2true : (4, 4) float
        The aligning transform applied to the estimates (its 3x3 block includes ``scale``).
    scale : float
        Scale of the alignment (1 except for ``align="similarity"``).
    """

    position_error_m: Array
    rotation_error_deg: Array
    est2true: Array
    scale: float = 1.0

    @property
    def mean_position_error_m(self) -> float:
        return float(np.mean(self.position_error_m))

    @property
    def mean_rotation_error_deg(self) -> float:
        return float(np.mean(self.rotation_error_deg))


def _pose_points(poses: Array) -> Array:
    tips = np.concatenate([np.zeros((1, 3)), np.eye(3)])  # centre and axis tips, 1 m
    return np.asarray(np.einsum("sij,kj->ski", poses[:, :3, :3], tips) + poses[:, None, :3, 3])


def align_worlds(
    est_sensor2world: ArrayLike, true_sensor2world: ArrayLike, *, align: Align = "yaw"
) -> Array:
    """The transform ``est2true (4, 4)`` that best maps estimated poses onto true ones.

    Parameters
    ----------
    est_sensor2world, true_sensor2world : (S, 4, 4) float
    align : {"yaw", "rigid", "none"}
        Kind of transform (see the module docstring).
    """
    est = check_transform(est_sensor2world, "est_sensor2world").reshape(-1, 4, 4)
    tru = check_transform(true_sensor2world, "true_sensor2world").reshape(-1, 4, 4)
    if est.shape != tru.shape:
        raise InputError(f"estimated and true poses differ in shape: {est.shape} vs {tru.shape}")
    if align == "none":
        return np.eye(4)
    a = _pose_points(est).reshape(-1, 3)
    b = _pose_points(tru).reshape(-1, 3)
    if align == "rigid":
        return kabsch(a, b)
    if align not in ("yaw", "similarity"):
        raise InputError(f"align must be 'yaw', 'rigid', 'similarity' or 'none', got {align!r}")
    if align == "similarity":
        if len(est) < 2:
            raise InputError("align='similarity' needs at least 2 sensors")
        a, b = est[:, :3, 3], tru[:, :3, 3]  # the scale acts on positions only
    ca, cb = a.mean(0), b.mean(0)
    pa, pb = (a - ca)[:, :2], (b - cb)[:, :2]
    ang = np.arctan2(np.sum(pa[:, 0] * pb[:, 1] - pa[:, 1] * pb[:, 0]), np.sum(pa * pb))
    c, s = np.cos(ang), np.sin(ang)
    rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    scale = 1.0
    if align == "similarity":
        scale = float(np.sum(((a - ca) @ rz.T) * (b - cb)) / np.sum((a - ca) ** 2))
    return make_transform(scale * rz, cb - scale * rz @ ca)


def pose_errors(
    est_sensor2world: ArrayLike, true_sensor2world: ArrayLike, *, align: Align = "yaw"
) -> PoseErrors:
    """Position and rotation error of every sensor after :func:`align_worlds`.

    Returns
    -------
    PoseErrors
        ``position_error_m (S,)``, ``rotation_error_deg (S,)``, the alignment used, and the means.
    """
    est = check_transform(est_sensor2world, "est_sensor2world").reshape(-1, 4, 4)
    tru = check_transform(true_sensor2world, "true_sensor2world").reshape(-1, 4, 4)
    e2t = align_worlds(est, tru, align=align)
    scale = float(np.cbrt(np.linalg.det(e2t[:3, :3])))
    pos_est = est[:, :3, 3] @ e2t[:3, :3].T + e2t[:3, 3]
    rot_est = np.einsum("ij,sjk->sik", e2t[:3, :3] / scale, est[:, :3, :3])
    pos = np.linalg.norm(pos_est - tru[:, :3, 3], axis=1)
    rot = np.atleast_1d(rotation_angle_deg(rot_est, tru[:, :3, :3]))
    return PoseErrors(position_error_m=pos, rotation_error_deg=rot, est2true=e2t, scale=scale)

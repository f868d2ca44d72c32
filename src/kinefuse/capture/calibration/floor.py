"""The floor plane seen by one depth sensor: gravity and height for the calibration.

A depth sensor has no accelerometer (the Kinect v2's is not exposed by the SDK), but most sensors
of a capture rig see the floor. The floor gives the direction of gravity in the sensor frame and
the sensor's height, which fixes the world's z axis and z = 0 after the wand registration.

Method: RANSAC over planes through three points of the lower image half whose normal lies within
``max_tilt_deg`` of the sensor's "up" (``-y`` in the OpenCV sensor frame; sensors are mounted
roughly upright), with the sensor at least ``min_height_m`` above the plane; the plane with the
most inliers wins (walls are too steep, tables and bodies are smaller). It is refitted by
weighted total least squares on its inliers at a finer sampling, twice, with the inlier band
shrinking to 3 sigma of the residuals, and weights ``1 / sigma_z(z)^2`` for the depth noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.capture.calibration.common import check_depth_frame
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.geometry.transforms import fit_plane
from kinefuse.errors import CalibrationError

Array = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class FloorPlane:
    """A plane ``normal . p + offset_m = 0`` in the sensor frame (points ``p`` in metres).

    Attributes
    ----------
    normal : (3,) float
        Unit normal pointing up, away from the floor, towards the sensor's side.
    offset_m : float
        The sensor's height above the floor (distance of the sensor origin to the plane).
    n_inliers : int
        Number of depth samples on the plane (a weight for combining sensors).
    residual_m : float
        RMS distance of the inliers to the plane.
    """

    normal: Array
    offset_m: float
    n_inliers: int = 0
    residual_m: float = float("nan")

    def __post_init__(self) -> None:
        n = np.asarray(self.normal, dtype=np.float64).reshape(-1)
        if n.shape != (3,) or not np.all(np.isfinite(n)) or np.linalg.norm(n) < 1e-9:
            raise CalibrationError(f"a floor normal must be a finite non-zero 3-vector, got {n}")
        object.__setattr__(self, "normal", n / np.linalg.norm(n))
        if not np.isfinite(self.offset_m):
            raise CalibrationError(f"floor offset must be finite, got {self.offset_m}")

    def distance(self, p_sensor: ArrayLike) -> Array:
        """Signed height of points ``(..., 3)`` above the floor, metres."""
        p = np.asarray(p_sensor, dtype=np.float64)
        return np.asarray(p @ self.normal + self.offset_m)


def _points(
    d: NDArray[np.uint16], intr: Intrinsics, step: int, lower_only: bool
) -> tuple[Array, Array]:
    v0 = int(intr.cy) if lower_only else 0
    sub = d[v0::step, ::step].astype(np.float64) * 1e-3
    vv, uu = np.mgrid[v0 : intr.height : step, 0 : intr.width : step]
    ok = (sub >= intr.min_range_m) & (sub <= intr.max_range_m)
    z = sub[ok]
    p = np.stack([(uu[ok] - intr.cx) / intr.fx * z, (vv[ok] - intr.cy) / intr.fy * z, z], -1)
    return p, z


def _plane_svd(p: Array, w: Array) -> tuple[Array, float]:
    c, n = fit_plane(p, w)
    return n, float(-n @ c)


def fit_floor_plane(
    depth_mm: ArrayLike,
    intrinsics: Intrinsics,
    *,
    max_tilt_deg: float = 45.0,
    min_height_m: float = 0.2,
    inlier_m: float = 0.03,
    min_inliers: int = 300,
    n_hypotheses: int = 300,
    seed: int = 0,
    name: str = "depth frame",
) -> FloorPlane:
    """Robust floor plane of one depth frame (RANSAC with an "up" prior, then refit).

    Parameters
    ----------
    depth_mm : (H, W) uint16
        Depth in millimetres, 0 = no reading. Several frames of a still sensor can be combined
        beforehand (e.g. their per-pixel median) to lower the noise.
    intrinsics : Intrinsics
    max_tilt_deg : float
        Largest angle between the floor normal and the sensor's up (-y) axis that is accepted.
    min_height_m : float
        The sensor must be at least this high above the plane.
    inlier_m : float
        RANSAC inlier band (metres).
    min_inliers : int
        Fewer inliers (on the 1-in-4 sample grid) than this: no floor.
    n_hypotheses : int
        RANSAC hypotheses (all evaluated at once, vectorized).
    seed : int
        Seed of the RANSAC sampling (the result is deterministic).
    name : str
        Name of the frame (the sensor) for messages.

    Returns
    -------
    FloorPlane
        Normal (up, unit, sensor frame), sensor height, inlier count and RMS residual.

    Raises
    ------
    CalibrationError
        No plane compatible with a floor is visible.
    InputError
        NaN depth or a frame that does not match the intrinsics.
    """
    d = check_depth_frame(depth_mm, intrinsics, name=name)
    pts, _ = _points(d, intrinsics, 4, lower_only=True)
    allp, _ = _points(d, intrinsics, 4, lower_only=False)
    if len(pts) < min_inliers:
        raise CalibrationError(
            f"{name}: only {len(pts)} valid depth samples in the lower half of the image; "
            "no floor visible. Point the sensor so that it sees some floor, or calibrate "
            "without gravity (origin='sensor')"
        )
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(pts), size=(n_hypotheses, 3))
    a, b, c = pts[idx[:, 0]], pts[idx[:, 1]], pts[idx[:, 2]]
    n = np.cross(b - a, c - a)
    norm = np.linalg.norm(n, axis=1)
    good = norm > 1e-6
    n = n[good] / norm[good, None]
    a = a[good]
    n *= np.where(n[:, 1] > 0, -1.0, 1.0)[:, None]  # point up (-y)
    off = -np.einsum("ij,ij->i", n, a)
    cos_tilt = -n[:, 1]
    ok = (cos_tilt >= np.cos(np.radians(max_tilt_deg))) & (off >= min_height_m)
    if not ok.any():
        raise CalibrationError(
            f"{name}: no plane within {max_tilt_deg} deg of the sensor's up axis and "
            f"{min_height_m} m below it; no floor visible"
        )
    n, off = n[ok], off[ok]
    dist = np.abs(allp @ n.T + off[None, :])
    counts = (dist < inlier_m).sum(axis=0)
    best = int(np.argmax(counts))
    if counts[best] < min_inliers:
        raise CalibrationError(
            f"{name}: the best floor candidate has only {int(counts[best])} supporting samples "
            f"(need {min_inliers}); no floor visible"
        )
    normal, offset = n[best], float(off[best])
    fine, zf = _points(d, intrinsics, 2, lower_only=False)
    band = inlier_m
    resid = np.nan
    inl = np.zeros(len(fine), dtype=bool)
    for _ in range(3):
        r = fine @ normal + offset
        inl = np.abs(r) < band
        if inl.sum() < 3:
            break
        sig = 1.5e-3 - 0.5e-3 * zf[inl] + 0.3e-3 * zf[inl] ** 2
        normal, offset = _plane_svd(fine[inl], 1.0 / sig**2)
        if normal[1] > 0:
            normal, offset = -normal, -offset
        r = fine[inl] @ normal + offset
        resid = float(np.sqrt(np.mean(r * r)))
        band = max(3.0 * resid, 0.005)
    if offset < min_height_m or -normal[1] < np.cos(np.radians(max_tilt_deg)):
        raise CalibrationError(
            f"{name}: the refined floor plane is not below the sensor (height {offset:.2f} m, "
            f"tilt {np.degrees(np.arccos(np.clip(-normal[1], -1, 1))):.1f} deg)"
        )
    return FloorPlane(
        normal=normal, offset_m=offset, n_inliers=int(inl.sum()), residual_m=float(resid)
    )

"""Pinhole intrinsics of a depth camera and the projections between pixels and rays.

Pixel coordinates: ``u`` to the right, ``v`` down, origin at the centre of the top-left pixel.
Points are in the sensor frame (x right, y down, z forward), metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

#: Kinect v2 depth camera nominal values (512x424, about 70.6 x 60 degrees field of view).
KINECT_V2_DEPTH_WIDTH = 512
KINECT_V2_DEPTH_HEIGHT = 424
KINECT_V2_FOCAL_PX = 365.0
KINECT_V2_MIN_RANGE_M = 0.5
KINECT_V2_MAX_RANGE_M = 4.5


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole model of a depth camera (no distortion: the Kinect v2 SDK undistorts).

    Attributes
    ----------
    width, height : int
        Image size in pixels.
    fx, fy : float
        Focal lengths in pixels.
    cx, cy : float
        Principal point in pixels.
    min_range_m, max_range_m : float
        Valid depth range; outside it the camera reports 0 (no reading).
    """

    width: int = KINECT_V2_DEPTH_WIDTH
    height: int = KINECT_V2_DEPTH_HEIGHT
    fx: float = KINECT_V2_FOCAL_PX
    fy: float = KINECT_V2_FOCAL_PX
    cx: float = (KINECT_V2_DEPTH_WIDTH - 1) / 2
    cy: float = (KINECT_V2_DEPTH_HEIGHT - 1) / 2
    min_range_m: float = KINECT_V2_MIN_RANGE_M
    max_range_m: float = KINECT_V2_MAX_RANGE_M

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        if not (self.fx > 0 and self.fy > 0):
            raise ValueError(f"focal lengths must be positive pixels, got {self.fx}, {self.fy}")
        if not 0 < self.min_range_m < self.max_range_m:
            raise ValueError(
                f"range must satisfy 0 < min < max, got {self.min_range_m}..{self.max_range_m} m"
            )

    @property
    def matrix(self) -> Array:
        """The 3x3 camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def to_dict(self) -> dict[str, float | int]:
        return {
            "width": self.width,
            "height": self.height,
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "min_range_m": self.min_range_m,
            "max_range_m": self.max_range_m,
        }

    @classmethod
    def from_dict(cls, d: dict[str, float | int]) -> Intrinsics:
        return cls(
            width=int(d["width"]),
            height=int(d["height"]),
            fx=float(d["fx"]),
            fy=float(d["fy"]),
            cx=float(d["cx"]),
            cy=float(d["cy"]),
            min_range_m=float(d.get("min_range_m", KINECT_V2_MIN_RANGE_M)),
            max_range_m=float(d.get("max_range_m", KINECT_V2_MAX_RANGE_M)),
        )

    def project(self, p_sensor: ArrayLike) -> Array:
        """Pixel coordinates ``(..., 2)`` of points ``(..., 3)``; NaN for points at z <= 0."""
        p = np.asarray(p_sensor, dtype=np.float64)
        z = p[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = np.where(z > 0, 1.0 / z, np.nan)
        return np.stack(
            [self.fx * p[..., 0] * inv + self.cx, self.fy * p[..., 1] * inv + self.cy], -1
        )

    def backproject(self, uv: ArrayLike, depth_m: ArrayLike) -> Array:
        """Points ``(..., 3)`` with z = ``depth_m`` ``(...)`` behind pixels ``uv`` ``(..., 2)``."""
        q = np.asarray(uv, dtype=np.float64)
        z = np.asarray(depth_m, dtype=np.float64)
        x = (q[..., 0] - self.cx) / self.fx * z
        y = (q[..., 1] - self.cy) / self.fy * z
        return np.stack([x, y, z * np.ones_like(x)], -1)

    def in_view(self, p_sensor: ArrayLike, margin_px: float = 0.0) -> NDArray[np.bool_]:
        """True where points ``(..., 3)`` project inside the image and lie within the range."""
        p = np.asarray(p_sensor, dtype=np.float64)
        uv = self.project(p)
        z = p[..., 2]
        with np.errstate(invalid="ignore"):
            return (
                (uv[..., 0] >= -0.5 + margin_px)
                & (uv[..., 0] <= self.width - 0.5 - margin_px)
                & (uv[..., 1] >= -0.5 + margin_px)
                & (uv[..., 1] <= self.height - 0.5 - margin_px)
                & (z >= self.min_range_m)
                & (z <= self.max_range_m)
            )

    def pixel_rays(self) -> Array:
        """Unit ray directions ``(height, width, 3)`` through every pixel centre."""
        u, v = np.meshgrid(np.arange(self.width), np.arange(self.height))
        d = np.stack([(u - self.cx) / self.fx, (v - self.cy) / self.fy, np.ones(u.shape)], axis=-1)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

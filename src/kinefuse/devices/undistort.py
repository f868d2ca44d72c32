"""Depth images resampled to the undistorted pinhole camera kinefuse works with.

kinefuse models a depth camera as a pinhole (:class:`~kinefuse.core.camera.intrinsics.Intrinsics`);
a device whose lens is distorted (the Azure Kinect: its factory calibration's Brown-Conrady
model with rational radial terms) gives images in which a pixel's ray is not the pinhole's.
:class:`DepthUndistorter` builds, once per calibration, for every pixel of the pinhole image
(same size, focal lengths and principal point) the device pixel that sees the same ray, and
resamples each depth image by nearest neighbour: a depth value is the z of the surface on that
ray, so it is moved, never blended across an edge. Pixels whose ray falls outside the device's
image read 0 (no reading).

The projection is libk4a's (``transformation_project_internal``, Brown-Conrady branch): with
``r² = x² + y²``, ``x_d = x (1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶) + 2 p1 x y +
p2 (r² + 2 x²)`` and ``y_d`` likewise with ``p1``, ``p2`` exchanged (the centre of distortion is
the principal point, as in the devices' calibrations).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.devices.capture import CameraCalibration

__all__ = ["DepthUndistorter", "distort_normalized", "undistort_pixels"]


def distort_normalized(
    x: NDArray[np.float64], y: NDArray[np.float64], coeffs: tuple[float, ...]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Distorted normalised image coordinates of undistorted ones (``k1 k2 p1 p2 k3 k4 k5 k6``;
    fewer coefficients are padded with zeros)."""
    k1, k2, p1, p2, k3, k4, k5, k6 = (tuple(coeffs) + (0.0,) * 8)[:8]
    r2 = x * x + y * y
    radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return xd, yd


def undistort_pixels(
    uv_px: NDArray[np.float64], camera: Intrinsics, coeffs: tuple[float, ...], iterations: int = 20
) -> NDArray[np.float64]:
    """The pinhole pixels ``(N, 2)`` of a distorted camera's pixels ``uv_px`` (the inverse of
    :func:`distort_normalized`, by fixed-point iteration; NaN stays NaN)."""
    uv = np.asarray(uv_px, dtype=np.float64)
    xd, yd = (uv[..., 0] - camera.cx) / camera.fx, (uv[..., 1] - camera.cy) / camera.fy
    x, y = xd.copy(), yd.copy()
    for _ in range(iterations):
        ex, ey = distort_normalized(x, y, coeffs)
        x, y = x - (ex - xd), y - (ey - yd)
    return np.stack([x * camera.fx + camera.cx, y * camera.fy + camera.cy], axis=-1)


class DepthUndistorter:
    """Resample a device's depth (or IR) images to its pinhole camera (``calibration.depth``).

    Attributes
    ----------
    source_index : (H, W) intp
        Flat index of the device pixel each pinhole pixel takes; -1 where none.
    """

    def __init__(self, calibration: CameraCalibration) -> None:
        k = calibration.depth
        v, u = np.mgrid[0 : k.height, 0 : k.width].astype(np.float64)
        xd, yd = distort_normalized((u - k.cx) / k.fx, (v - k.cy) / k.fy,
                                    calibration.distortion_depth)  # fmt: skip
        su = np.rint(xd * k.fx + k.cx)
        sv = np.rint(yd * k.fy + k.cy)
        inside = (su >= 0) & (su < k.width) & (sv >= 0) & (sv < k.height)
        index = np.full(u.shape, -1, dtype=np.intp)
        index[inside] = (sv[inside] * k.width + su[inside]).astype(np.intp)
        self.source_index = index
        self._shape = (k.height, k.width)

    def __call__(self, image: NDArray[np.uint16]) -> NDArray[np.uint16]:
        """The pinhole image of a device image (same size and dtype)."""
        if image.shape != self._shape:
            raise ValueError(f"image is {image.shape}, the calibration's {self._shape}")
        idx = self.source_index
        out = image.reshape(-1)[np.maximum(idx, 0)]
        out[idx < 0] = 0
        return out

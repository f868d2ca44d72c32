"""What an RGB-D camera delivers: one capture's images and the camera's calibration.

Frames and units as everywhere in kinefuse: the depth camera's frame is x right, y down,
z forward, metres; pixel ``(u, v)`` has ``u`` to the right, ``v`` down, origin at the centre of
the top-left pixel; times in seconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.camera.intrinsics import Intrinsics

__all__ = ["CameraCalibration", "Capture"]


@dataclass(frozen=True)
class CameraCalibration:
    """A camera's calibration as the device reports it (never nominal constants).

    Attributes
    ----------
    depth : Intrinsics
        The depth camera as a pinhole (the device's focal lengths and principal point);
        ``distortion_depth`` holds the device's lens distortion, which its own images have.
        A tracker is handed the images resampled to this pinhole, with ``distortion_depth``
        empty (:class:`~kinefuse.devices.trackers.Tracker`).
    color : Intrinsics or None
        The colour camera, if the device has one.
    color_from_depth : (4, 4) float or None
        Rigid transform taking a point in the depth camera's frame (metres) to the colour
        camera's frame.
    distortion_depth, distortion_color : tuple of float
        The device's lens distortion coefficients (Brown-Conrady ``k1 k2 p1 p2 k3 k4 k5 k6``
        as the device names them); empty when the device undistorts.
    device : str
        What the calibration came from ("Azure Kinect DK", "RealSense D435", ...).
    raw : str
        The device's own calibration text where it has one (the Azure Kinect's JSON), for a
        library that needs it as the device gave it (Microsoft's body tracker); else "".
    """

    depth: Intrinsics
    color: Intrinsics | None = None
    color_from_depth: NDArray[np.float64] | None = None
    distortion_depth: tuple[float, ...] = ()
    distortion_color: tuple[float, ...] = ()
    device: str = ""
    raw: str = ""


@dataclass(frozen=True, eq=False)
class Capture:
    """One capture of an RGB-D camera: whichever images the device delivered, with times.

    Attributes
    ----------
    seq : int
        The source's capture counter (increasing).
    t_device_s : float
        Capture time on the device's clock, seconds.
    t_host_s : float
        Arrival at the host, on the host's monotonic clock; NaN for a recording.
    depth_mm : (H, W) uint16 or None
        Depth in millimetres along z, 0 = no reading, in the depth camera
        (``CameraCalibration.depth``; with the lens distortion of ``distortion_depth`` when
        the calibration lists one).
    color : (h, w, 3) uint8 or None
        Colour image, RGB order, in the colour camera.
    ir : (H, W) uint16 or None
        Infrared (active brightness), registered to the depth image.
    imu : (N, 7) float or None
        IMU samples since the previous capture: ``t_device_s, ax, ay, az (m/s²), gx, gy, gz
        (rad/s)`` in the device's IMU frame.
    """

    seq: int
    t_device_s: float
    t_host_s: float = float("nan")
    depth_mm: NDArray[np.uint16] | None = None
    color: NDArray[np.uint8] | None = None
    ir: NDArray[np.uint16] | None = None
    imu: NDArray[np.float64] | None = None

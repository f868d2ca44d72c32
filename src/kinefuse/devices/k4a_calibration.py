"""The Azure Kinect's factory calibration (``calibration.json``) as a :class:`CameraCalibration`.

The device stores one JSON text (``k4a_device_get_raw_calibration``; a k4arecorder MKV carries
the same text as its ``calibration.json`` attachment; Orbbec Femto cameras give it through
Orbbec's K4A wrapper). Its intrinsics are *raw*: normalised by the sensor's full image and
0-cornered. The images a capture delivers are a crop or binning of that full image depending on
the depth mode and colour resolution; the conversion below is the one libk4a applies
(``transformation_get_mode_specific_camera_calibration``): scale by the mode's binned full
resolution, subtract its crop offset, then half a pixel to put (0, 0) at the centre of the
top-left pixel. Each camera's ``Rt`` is the transform from the depth camera to that camera
(rotation row-major, translation in metres).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.devices.capture import CameraCalibration
from kinefuse.errors import InputError

__all__ = [
    "COLOR_MODES",
    "DEPTH_MODES",
    "DepthMode",
    "calibration_from_k4a_json",
]


@dataclass(frozen=True)
class DepthMode:
    """One depth mode: the binned full image, the crop offset, the output image, the range."""

    binned: tuple[int, int]
    crop: tuple[int, int]
    size: tuple[int, int]
    min_range_m: float
    max_range_m: float


#: libk4a's mode table; the ranges are the operating ranges of Microsoft's hardware
#: specification (Azure Kinect DK, "Depth camera supported operating modes")
DEPTH_MODES: dict[str, DepthMode] = {
    "NFOV_2X2BINNED": DepthMode((512, 512), (96, 90), (320, 288), 0.5, 5.46),
    "NFOV_UNBINNED": DepthMode((1024, 1024), (192, 180), (640, 576), 0.5, 3.86),
    "WFOV_2X2BINNED": DepthMode((512, 512), (0, 0), (512, 512), 0.25, 2.88),
    "WFOV_UNBINNED": DepthMode((1024, 1024), (0, 0), (1024, 1024), 0.25, 2.21),
    "PASSIVE_IR": DepthMode((1024, 1024), (0, 0), (1024, 1024), 0.25, 2.21),
}

#: colour resolution -> (binned full image of the 4:3 calibration, crop offset, output image)
COLOR_MODES: dict[str, tuple[tuple[int, int], tuple[int, int], tuple[int, int]]] = {
    "720P": ((1280, 960), (0, 120), (1280, 720)),
    "1080P": ((1920, 1440), (0, 180), (1920, 1080)),
    "1440P": ((2560, 1920), (0, 240), (2560, 1440)),
    "1536P": ((2048, 1536), (0, 0), (2048, 1536)),
    "2160P": ((3840, 2880), (0, 360), (3840, 2160)),
    "3072P": ((4096, 3072), (0, 0), (4096, 3072)),
}


def _mode_pinhole(
    params: list[float], binned: tuple[int, int], crop: tuple[int, int]
) -> tuple[float, float, float, float]:
    """``fx, fy, cx, cy`` in pixels of a mode from raw (unitised, 0-cornered) parameters."""
    cx, cy, fx, fy = (float(v) for v in params[:4])
    return (
        fx * binned[0],
        fy * binned[1],
        cx * binned[0] - crop[0] - 0.5,
        cy * binned[1] - crop[1] - 0.5,
    )


def _distortion(params: list[float]) -> tuple[float, ...]:
    # raw order: cx cy fx fy k1 k2 k3 k4 k5 k6 codx cody p2 p1 -> k1 k2 p1 p2 k3 k4 k5 k6
    k1, k2, k3, k4, k5, k6 = (float(v) for v in params[4:10])
    p2, p1 = float(params[12]), float(params[13])
    return (k1, k2, p1, p2, k3, k4, k5, k6)


def _rt(cam: dict[str, Any]) -> np.ndarray:
    r = np.asarray(cam["Rt"]["Rotation"], dtype=np.float64).reshape(3, 3)
    t = np.asarray(cam["Rt"]["Translation"], dtype=np.float64).reshape(3)
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = r, t
    return m


def _camera(cams: list[dict[str, Any]], purpose: str) -> dict[str, Any] | None:
    return next(
        (c for c in cams if c.get("Purpose") == f"CALIBRATION_CameraPurpose{purpose}"), None
    )


def calibration_from_k4a_json(
    text: str | bytes,
    depth_mode: str = "NFOV_UNBINNED",
    color_resolution: str | None = None,
    *,
    what: str = "calibration.json",
    device: str = "Azure Kinect DK",
) -> CameraCalibration:
    """The calibration of one depth mode (and colour resolution) from the device's JSON.

    Parameters
    ----------
    text : str or bytes
        The raw calibration (``CalibrationInformation`` object).
    depth_mode : str
        ``NFOV_UNBINNED``, ``NFOV_2X2BINNED``, ``WFOV_UNBINNED``, ``WFOV_2X2BINNED`` or
        ``PASSIVE_IR`` (the k4a names without ``K4A_DEPTH_MODE_``).
    color_resolution : str, optional
        ``720P`` ... ``3072P``; None: no colour camera in the result.
    what : str
        Where the text came from, for the error message.

    Raises
    ------
    InputError
        Not an Azure Kinect calibration, or an unknown mode.
    """
    if depth_mode not in DEPTH_MODES:
        raise InputError(
            f"{what}: unknown depth mode {depth_mode!r}; one of {', '.join(DEPTH_MODES)}"
        )
    if color_resolution is not None and color_resolution not in COLOR_MODES:
        raise InputError(
            f"{what}: unknown colour resolution {color_resolution!r}; one of "
            f"{', '.join(COLOR_MODES)}"
        )
    try:
        info = json.loads(text)["CalibrationInformation"]
        cams = list(info["Cameras"])
        dcam = _camera(cams, "Depth")
        if dcam is None:
            raise KeyError("no depth camera")
        dparams = [float(v) for v in dcam["Intrinsics"]["ModelParameters"]]
        if len(dparams) < 14 or (dcam["SensorWidth"], dcam["SensorHeight"]) != (1024, 1024):
            raise ValueError("the depth camera is not the 1024x1024 sensor of an Azure Kinect")
        world_to_depth = _rt(dcam)
        ccam = _camera(cams, "PhotoVideo")
        cparams = [float(v) for v in ccam["Intrinsics"]["ModelParameters"]] if ccam else []
        serial = str(info.get("Metadata", {}).get("SerialId", ""))
    except (ValueError, KeyError, TypeError, IndexError, AttributeError) as e:
        raise InputError(
            f"{what}: not an Azure Kinect calibration ({e}); expected the device's "
            "CalibrationInformation JSON"
        ) from None
    mode = DEPTH_MODES[depth_mode]
    fx, fy, cx, cy = _mode_pinhole(dparams, mode.binned, mode.crop)
    depth = Intrinsics(
        width=mode.size[0],
        height=mode.size[1],
        fx=fx,
        fy=fy,
        cx=cx,
        cy=cy,
        min_range_m=mode.min_range_m,
        max_range_m=mode.max_range_m,
    )
    color = None
    color_from_depth = None
    dist_color: tuple[float, ...] = ()
    if color_resolution is not None and ccam is not None and len(cparams) >= 14:
        w, h = int(ccam["SensorWidth"]), int(ccam["SensorHeight"])
        if w * 9 // 16 == h:  # a legacy 16:9 calibration: to the 4:3 full image first
            cparams[1] = (cparams[1] * 2304 + 384) / 3072
            cparams[3] = cparams[3] * 2304 / 3072
        binned, crop, size = COLOR_MODES[color_resolution]
        cfx, cfy, ccx, ccy = _mode_pinhole(cparams, binned, crop)
        # the colour camera sees far beyond the depth range; the range only bounds in_view()
        color = Intrinsics(size[0], size[1], cfx, cfy, ccx, ccy, 0.1, 100.0)
        world_to_color = _rt(ccam)
        color_from_depth = world_to_color @ np.linalg.inv(world_to_depth)
        dist_color = _distortion(cparams)
    if not all(math.isfinite(v) for v in (fx, fy, cx, cy)):
        raise InputError(f"{what}: the depth camera's intrinsics are not finite numbers")
    return CameraCalibration(
        depth=depth,
        color=color,
        color_from_depth=color_from_depth,
        distortion_depth=_distortion(dparams),
        distortion_color=dist_color,
        device=f"{device} {serial}".strip(),
        raw=text.decode() if isinstance(text, bytes) else text,
    )

"""Test and benchmark support: the shared Azure Kinect MKV's first capture and its calibration,
read with PyAV and the JSON beside it (no libk4a). The project's ``mkv:`` source does this for
real; this small reader keeps the pose tracker's tests independent of it.

The calibration's normalized intrinsics refer to the full sensors (depth 1024 x 1024, colour
4096 x 3072); the recording's modes crop and scale them: NFOV unbinned depth is the centre
640 x 576 (offset 192, 180), 720p colour is the 4096 x 3072 image scaled by 1280 / 4096 and
cropped to 720 rows (offset 120). The colour camera's ``Rt`` takes depth-frame points (metres)
to the colour frame. Lens distortion is left out (pinhole), as the tracker assumes.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from kinefuse.camera.intrinsics import Intrinsics
from kinefuse.devices.capture import CameraCalibration, Capture


def _camera(cal: dict, purpose: str) -> dict:
    return next(c for c in cal["CalibrationInformation"]["Cameras"] if c["Purpose"] == purpose)


def k4a_calibration(calib_json: Path) -> CameraCalibration:
    """NFOV-unbinned depth and 720p colour of the recording's device."""
    cal = json.loads(Path(calib_json).read_text())
    d = _camera(cal, "CALIBRATION_CameraPurposeDepth")
    cx, cy, fx, fy = d["Intrinsics"]["ModelParameters"][:4]
    w, h = d["SensorWidth"], d["SensorHeight"]
    depth = Intrinsics(width=640, height=576, fx=fx * w, fy=fy * h, cx=cx * w - 192 - 0.5,
                       cy=cy * h - 180 - 0.5, min_range_m=0.25, max_range_m=5.46)  # fmt: skip
    c = _camera(cal, "CALIBRATION_CameraPurposePhotoVideo")
    cx, cy, fx, fy = c["Intrinsics"]["ModelParameters"][:4]
    s = 1280 / c["SensorWidth"]
    w, h = c["SensorWidth"] * s, c["SensorHeight"] * s
    color = Intrinsics(width=1280, height=720, fx=fx * w, fy=fy * h, cx=cx * w - 0.5,
                       cy=cy * h - (h - 720) / 2 - 0.5, min_range_m=0.25,
                       max_range_m=5.46)  # fmt: skip
    t = np.eye(4)
    t[:3, :3] = np.array(c["Rt"]["Rotation"], dtype=np.float64).reshape(3, 3)
    t[:3, 3] = c["Rt"]["Translation"]
    return CameraCalibration(depth=depth, color=color, color_from_depth=t,
                             device="Azure Kinect DK")  # fmt: skip


def k4a_first_capture(mkv: Path) -> Capture:
    """The recording's first depth, IR and colour frames (RGB)."""
    import av

    images: dict[str, np.ndarray] = {}
    with av.open(str(mkv)) as container:
        for stream in container.streams.video:
            title = stream.metadata.get("title")
            frame = next(container.decode(stream))
            fmt = "rgb24" if title == "COLOR" else None
            images[title] = frame.to_ndarray(format=fmt) if fmt else frame.to_ndarray()
            container.seek(0)
    return Capture(seq=0, t_device_s=0.0, depth_mm=images["DEPTH"], color=images["COLOR"],
                   ir=images["IR"])  # fmt: skip

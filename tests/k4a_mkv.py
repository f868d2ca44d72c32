"""Test support: the shared Azure Kinect MKV's first capture and its calibration as a tracker is
handed them, read by kinefuse's own ``mkv:`` source and calibration reader
(:func:`~kinefuse.devices.k4a_calibration.calibration_from_k4a_json`, tested against libk4a in
``tests/test_devices_mkv.py``): NFOV-unbinned depth and IR resampled to the pinhole depth
camera, 720p colour as recorded (:class:`~kinefuse.devices.trackers.Tracker`).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from kinefuse.devices.capture import CameraCalibration, Capture
from kinefuse.devices.k4a_calibration import calibration_from_k4a_json
from kinefuse.devices.mkv import MkvRecording
from kinefuse.devices.sources import CameraFrameSource


def k4a_calibration(calib_json: Path) -> CameraCalibration:
    """The calibration a tracker gets for the recording's modes (no depth distortion: its
    depth images are the pinhole's)."""
    path = Path(calib_json)
    cal = calibration_from_k4a_json(path.read_text(), "NFOV_UNBINNED", "720P", what=str(path))
    return replace(cal, distortion_depth=())


def k4a_first_capture(mkv: Path) -> Capture:
    """The recording's first capture (depth, IR, RGB colour) as a tracker gets it."""
    rec = MkvRecording(mkv)
    return CameraFrameSource(rec, "k4a").for_tracker(next(rec.captures()))[0]

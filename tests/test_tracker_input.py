"""What a body tracker is handed, on the real Azure Kinect recording in ``../shared/data/depth``.

The contract (:class:`kinefuse.devices.trackers.Tracker`): depth and IR resampled to the pinhole
camera ``calibration.depth``, with a calibration that lists no depth distortion, so a tracker
that treats depth as a pinhole (the ``pose`` tracker) reads the right depth where a 3D point
projects; the device's own images and calibration for a tracker that sets ``device_images``
(Microsoft's). The same whether the tracker runs inline (``kinefuse track``) or on its worker
thread (``kinefuse sensor``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kinefuse.devices.capture import CameraCalibration, Capture
from kinefuse.devices.k4abt import K4abtTracker
from kinefuse.devices.mkv import MkvRecording
from kinefuse.devices.sources import CameraFrameSource
from kinefuse.devices.trackers import TrackerResult
from kinefuse.devices.undistort import distort_normalized

pytest.importorskip("av")

#: a device pixel of the shared recording (on the mug, 285 mm away) and the pinhole pixel
#: libk4a 1.4 unprojects it to (``Calibration.convert_2d_to_3d``, tests/test_devices_mkv.py)
DEVICE_PX, PINHOLE_PX = (100, 500), (72.14, 518.10)


class _Seen:
    """Keeps what it is handed (the adapter is under test, not a tracker)."""

    name = "seen"

    def __init__(self, device_images: bool = False) -> None:
        self.device_images = device_images
        self.got: list[tuple[Capture, CameraCalibration]] = []

    def track(self, capture: Capture, calibration: CameraCalibration) -> TrackerResult:
        self.got.append((capture, calibration))
        return TrackerResult()

    def close(self) -> None:
        pass


@pytest.fixture(scope="module")
def rec(shared_data: Path) -> MkvRecording:
    return MkvRecording(shared_data / "depth" / "pyk4a_recording.mkv")


def test_a_known_point_projects_to_the_depth_the_tracker_reads_there(rec: MkvRecording) -> None:
    raw = next(rec.captures())
    assert raw.depth_mm is not None and raw.ir is not None
    z_mm = int(raw.depth_mm[DEVICE_PX[1], DEVICE_PX[0]])
    assert z_mm == 285
    k = rec.calibration.depth
    p = k.backproject(np.array(PINHOLE_PX), z_mm / 1000.0)  # the surface point that pixel sees
    # projected both ways: the pinhole gives the pinhole pixel, the device's lens the device's
    np.testing.assert_allclose(k.project(p), PINHOLE_PX, atol=1e-6)
    xd, yd = distort_normalized(np.array(p[0] / p[2]), np.array(p[1] / p[2]),
                                rec.calibration.distortion_depth)  # fmt: skip
    np.testing.assert_allclose([xd * k.fx + k.cx, yd * k.fy + k.cy], DEVICE_PX, atol=0.5)
    for threaded in (False, True):  # kinefuse track / kinefuse sensor
        seen = _Seen()
        src = CameraFrameSource(rec, "k1", seen, threaded=threaded, speed=100.0)
        list(src)
        (cap, cal), = seen.got  # fmt: skip
        assert cal.depth == k and cal.distortion_depth == ()  # it says what the images are
        assert cal.distortion_color == rec.calibration.distortion_color
        assert cap.seq == raw.seq and cap.t_device_s == raw.t_device_s
        assert cap.depth_mm is not None and cap.ir is not None
        np.testing.assert_array_equal(cap.depth_mm, src.depth_of(raw))
        np.testing.assert_array_equal(cap.color, raw.color)  # colour as the device gives it
        # where the point projects in the pinhole, the tracker reads the point's depth; the
        # device's own image there sees nothing (a tracker taking it as a pinhole would miss)
        u, v = round(PINHOLE_PX[0]), round(PINHOLE_PX[1])
        assert abs(int(cap.depth_mm[v, u]) - z_mm) <= 10
        assert raw.depth_mm[v, u] == 0
        # the IR image went the same way (registered to the depth, it stays registered)
        assert cap.ir[v, u] == raw.ir[DEVICE_PX[1], DEVICE_PX[0]]


def test_a_tracker_asking_for_the_device_images_gets_them_unchanged(rec: MkvRecording) -> None:
    raw = next(rec.captures())
    assert K4abtTracker.device_images  # Microsoft's tracker undistorts from the device's JSON
    for threaded in (False, True):
        seen = _Seen(device_images=True)
        list(CameraFrameSource(rec, "k1", seen, threaded=threaded, speed=100.0))
        (cap, cal), = seen.got  # fmt: skip
        assert cal is rec.calibration and cal.raw
        np.testing.assert_array_equal(cap.depth_mm, raw.depth_mm)
        np.testing.assert_array_equal(cap.ir, raw.ir)

"""What a body tracker is handed, on the real Azure Kinect recording in ``../shared/data/depth``.

The contract (:class:`kinefuse.devices.trackers.Tracker`): depth and IR resampled to the pinhole
camera ``calibration.depth``, with a calibration that lists no depth distortion, so a tracker
that treats depth as a pinhole (the ``pose`` tracker) reads the right depth where a 3D point
projects; the device's own images and calibration for a tracker that sets ``device_images``
(Microsoft's). The same whether the tracker runs inline (``kinefuse track``) or on its worker
thread (``kinefuse sensor``).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from kinefuse.core.geometry.transforms import apply_transform, invert_transform, look_at
from kinefuse.devices.capture import CameraCalibration, Capture
from kinefuse.devices.k4abt import K4abtTracker
from kinefuse.devices.mkv import MkvRecording
from kinefuse.devices.pose.landmarks import Landmarks2D
from kinefuse.devices.pose.tracker import PoseTracker
from kinefuse.devices.sources import CameraFrameSource
from kinefuse.devices.trackers import TrackerResult
from kinefuse.devices.undistort import distort_normalized, undistort_pixels
from kinefuse.formats.motion.load import load_motion
from kinefuse.lab.pose_lift import true_landmarks
from kinefuse.sim.depth import Scene, render_depth

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


def test_colour_pixels_undistort_back_to_the_pinhole(rec: MkvRecording) -> None:
    cal = rec.calibration
    assert cal.color is not None and any(cal.distortion_color)
    k = cal.color
    v, u = np.mgrid[0 : k.height : 40, 0 : k.width : 40].astype(np.float64)
    x, y = (u - k.cx) / k.fx, (v - k.cy) / k.fy
    xd, yd = distort_normalized(x, y, cal.distortion_color)
    distorted = np.stack([xd * k.fx + k.cx, yd * k.fy + k.cy], axis=-1)
    assert np.abs(distorted - np.stack([u, v], axis=-1)).max() > 10  # a lens worth undoing
    np.testing.assert_allclose(undistort_pixels(distorted, k, cal.distortion_color),
                               np.stack([u, v], axis=-1), atol=0.01)  # fmt: skip


class _Fixed:
    """A 2D model giving set landmarks (the tracker's handling of them is under test)."""

    def __init__(self, landmarks: Landmarks2D) -> None:
        self.landmarks = landmarks

    def detect(self, rgb: np.ndarray) -> Landmarks2D:
        return self.landmarks

    def close(self) -> None:
        pass


def test_the_pose_tracker_takes_the_colour_lens_out_of_its_landmarks(
    rec: MkvRecording, shared_data: Path
) -> None:
    """Landmarks where the device's colour camera sees a rendered body (through its lens) lift
    to the body the pinhole landmarks give."""
    cal = replace(rec.calibration, distortion_depth=())  # as a tracker is handed it
    assert cal.color is not None and cal.color_from_depth is not None
    motion = load_motion(shared_data / "motion" / "cmu" / "131_01_scaled_metres.bvh")
    pose = motion.positions[0].copy()
    pose[:, :2] -= pose[0, :2]
    pose[:, 2] -= pose[:, 2].min()
    s2w = look_at([2.5, 0.0, 1.0], [0.0, 0.0, 1.0])
    depth = render_depth(Scene.from_pose(pose, walls=False), s2w, cal.depth,
                         np.random.default_rng(0))  # fmt: skip
    truth = apply_transform(cal.color_from_depth, apply_transform(invert_transform(s2w), pose))
    pinhole = true_landmarks(truth, cal.color)
    k = cal.color
    x, y = (pinhole.uv_px[:, 0] - k.cx) / k.fx, (pinhole.uv_px[:, 1] - k.cy) / k.fy
    xd, yd = distort_normalized(x, y, cal.distortion_color)
    seen = replace(pinhole, uv_px=np.stack([xd * k.fx + k.cx, yd * k.fy + k.cy], axis=1))
    assert np.nanmax(np.abs(seen.uv_px - pinhole.uv_px)) > 2  # the lens moved them
    color = np.zeros((k.height, k.width, 3), np.uint8)
    cap = Capture(seq=0, t_device_s=0.0, depth_mm=depth, color=color)
    got = PoseTracker(_Fixed(seen)).track(cap, cal)
    want = PoseTracker(_Fixed(pinhole)).from_landmarks(pinhole, depth, cal.depth, k,
                                                       cal.color_from_depth)  # fmt: skip
    assert len(want.bodies) == 1 and len(got.bodies) == 1, (got.refused, want.refused)
    np.testing.assert_allclose(got.bodies[0].joints_m, want.bodies[0].joints_m, atol=0.005)
    np.testing.assert_array_equal(got.bodies[0].states, want.bodies[0].states)

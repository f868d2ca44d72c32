"""Wand detection in depth frames: the robust detector and the paper's, on simulated and real data.

Simulated frames come from the lab's renderer (``kinefuse.sim.depth``) with its full Kinect v2
error model; real frames are the depth images in ``../shared/data/depth`` (no wand in them).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from kinefuse.capture.calibration.common import WandDetection
from kinefuse.capture.calibration.wand_paper import (
    binarize_nearest,
    detect_wand_paper,
    detect_wand_paper_sequence,
    paper_filter,
    standardize_depth_cm,
)
from kinefuse.capture.calibration.wand_robust import (
    RobustDetectorParams,
    detect_wand,
    detect_wand_sequence,
)
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.camera.wand import Wand
from kinefuse.core.geometry.transforms import invert_transform, look_at
from kinefuse.core.skeleton import JOINTS
from kinefuse.errors import InputError
from kinefuse.sim.choreography import holding_poses
from kinefuse.sim.depth import DepthNoiseParams, Scene, render_depth

INTR = Intrinsics()
WAND = Wand()
# the simulator's systematic range offset (a few mm growing with distance) moves the detected
# centre along the ray; it is the camera's error, not the detector's: switch it off to test the
# detector, and check it separately.
NO_OFFSET = DepthNoiseParams(
    offset_at_1m_mm=0.0, offset_slope_mm_per_m=0.0, wiggle_amplitude_mm=0.0
)

_STANDING = {  # a 1.75 m adult, x to the right, y forward, z up (metres)
    "SpineBase": (0.0, 0.0, 0.95),
    "SpineMid": (0.0, 0.0, 1.18),
    "Neck": (0.0, 0.0, 1.50),
    "Head": (0.0, 0.0, 1.63),
    "ShoulderLeft": (-0.18, 0.0, 1.40),
    "ElbowLeft": (-0.20, 0.0, 1.12),
    "WristLeft": (-0.21, 0.0, 0.88),
    "HandLeft": (-0.21, 0.0, 0.80),
    "ShoulderRight": (0.18, 0.0, 1.40),
    "ElbowRight": (0.20, 0.0, 1.12),
    "WristRight": (0.21, 0.0, 0.88),
    "HandRight": (0.21, 0.0, 0.80),
    "HipLeft": (-0.09, 0.0, 0.92),
    "KneeLeft": (-0.10, 0.02, 0.50),
    "AnkleLeft": (-0.10, 0.0, 0.08),
    "FootLeft": (-0.10, 0.12, 0.03),
    "HipRight": (0.09, 0.0, 0.92),
    "KneeRight": (0.10, 0.02, 0.50),
    "AnkleRight": (0.10, 0.0, 0.08),
    "FootRight": (0.10, 0.12, 0.03),
    "SpineShoulder": (0.0, 0.0, 1.42),
    "HandTipLeft": (-0.21, 0.0, 0.72),
    "ThumbLeft": (-0.19, 0.03, 0.82),
    "HandTipRight": (0.21, 0.0, 0.72),
    "ThumbRight": (0.19, 0.03, 0.82),
}
REST = np.array([_STANDING[n] for n in JOINTS])


def _sensor(distance_m: float = 3.0, height_m: float = 1.2, pitch_to: float = 1.1) -> np.ndarray:
    """A sensor on the -y axis looking at the origin area."""
    return look_at([0.0, -distance_m, height_m], [0.0, 0.0, pitch_to])


def _wand_scene(centre: np.ndarray) -> Scene:
    """The actor holding the wand at ``centre`` (world), as in the simulator's calibration."""
    poses, handles = holding_poses(centre[None], REST, WAND)
    return Scene.from_pose(
        poses[0], 1.75, wand=WAND, wand_centre=centre, wand_handle_dir=handles[0]
    )


def _in_sensor(s2w: np.ndarray, p: np.ndarray) -> np.ndarray:
    w2s = invert_transform(s2w)
    return w2s[:3, :3] @ p + w2s[:3, 3]


# --------------------------------------------------------------------------------------------
# robust detector on simulated frames


@pytest.mark.parametrize("distance_m", [1.0, 2.0, 3.0, 4.0])
def test_robust_finds_the_wand_held_by_the_actor(distance_m: float) -> None:
    rng = np.random.default_rng(11)
    s2w = _sensor()
    errs = []
    for x in (-0.4, 0.3):
        centre = np.array([x * distance_m / 2, -3.0 + distance_m, 1.3])
        depth = render_depth(_wand_scene(centre), s2w, INTR, rng, NO_OFFSET)
        det = detect_wand(depth, INTR, WAND)
        assert det.found, det.reason
        assert det.reason == "ok"
        assert 0.5 < det.score <= 1.0
        assert det.n_points > 30
        errs.append(np.linalg.norm(det.centre_sensor_m - _in_sensor(s2w, centre)))
        # the centre projects where the wand is
        uv = INTR.project(_in_sensor(s2w, centre))
        np.testing.assert_allclose(det.pixel_uv, uv, atol=1.0)  # 1 px
    assert max(errs) < 0.004  # 4 mm, noise only (no systematic offset)


def test_robust_error_is_the_cameras_range_offset_with_the_full_error_model() -> None:
    """With the systematic range offset on, the centre moves along the ray by about that offset."""
    rng = np.random.default_rng(12)
    s2w = _sensor()
    centre = np.array([0.2, -0.5, 1.3])
    truth = _in_sensor(s2w, centre)
    depth = render_depth(_wand_scene(centre), s2w, INTR, rng)
    det = detect_wand(depth, INTR, WAND)
    assert det.found, det.reason
    err = det.centre_sensor_m - truth
    ray = truth / np.linalg.norm(truth)
    lateral = np.linalg.norm(err - (err @ ray) * ray)
    assert lateral < 0.003  # 3 mm
    assert 0.0 < err @ ray < 0.012  # pushed back by the offset (2 mm at 1 m + 2.5 mm/m +- 2 mm)


def test_robust_finds_nothing_without_a_wand_person_alone() -> None:
    """The actor without a wand, seen from several distances, heights and headings: the head is
    the size of the wand but continues into the body, so it must not be reported."""
    rng = np.random.default_rng(13)
    for distance_m, height_m, heading in [(1.2, 1.6, 0.0), (2.0, 0.8, 1.5), (3.5, 2.2, 3.1)]:
        c, s = np.cos(heading), np.sin(heading)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        scene = Scene.from_pose(REST @ rot.T, 1.75)
        depth = render_depth(scene, _sensor(distance_m, height_m, 1.3), INTR, rng)
        det = detect_wand(depth, INTR, WAND)
        assert not det.found, (distance_m, height_m, det)
        assert np.isnan(det.centre_sensor_m).all()
        assert det.score == 0.0


def test_robust_rejects_a_head_sized_ball_on_shoulders() -> None:
    """A 0.10 m ball (a head) just above shoulders a few cm behind it: its fit is perfect, its size
    right, and the depth jump to the shoulders separates it as a segment; only the isolation
    check (most of its surroundings must be far behind it) can reject it."""
    rng = np.random.default_rng(14)
    s2w = look_at([0.0, -2.0, 1.6], [0.0, 0.0, 1.6])
    head = np.array([0.0, 0.0, 1.62])
    # shoulders: a horizontal capsule under the ball (top 9 cm below its centre) whose front is
    # 8.5 cm behind the ball's silhouette: a depth jump (a separate segment), yet not "far
    # behind" the ball as the background around a wand is; a torso below them
    a = np.array([[-0.25, 0.145, 1.47], [0.0, 0.235, 1.0]])
    b = np.array([[0.25, 0.145, 1.47], [0.0, 0.235, 1.35]])
    scene = Scene(
        a=np.vstack([a, head[None]]),
        b=np.vstack([b, head[None]]),
        radius=np.array([0.06, 0.15, 0.10]),
    )
    depth = render_depth(scene, s2w, INTR, rng, NO_OFFSET)
    det = detect_wand(depth, INTR, WAND)
    assert not det.found
    assert "not isolated" in det.reason
    # the same ball alone in the room is a wand
    alone = Scene(a=head[None], b=head[None], radius=np.array([0.10]))
    det = detect_wand(render_depth(alone, s2w, INTR, rng, NO_OFFSET), INTR, WAND)
    assert det.found, det.reason
    np.testing.assert_allclose(det.centre_sensor_m, _in_sensor(s2w, head), atol=0.004)  # 4 mm


def test_robust_rejects_balls_of_the_wrong_size() -> None:
    rng = np.random.default_rng(15)
    s2w = look_at([0.0, -2.0, 1.3], [0.0, 0.0, 1.3])
    for radius in (0.05, 0.2):
        centre = np.array([[0.0, 0.0, 1.3]])
        ball = Scene(a=centre, b=centre, radius=np.array([radius]))
        det = detect_wand(render_depth(ball, s2w, INTR, rng), INTR, WAND)
        assert not det.found, radius


def test_robust_ignores_the_floor_and_walls() -> None:
    """An empty room from a low, pitched-down sensor: the floor fragments at grazing angles must
    not become a wand."""
    rng = np.random.default_rng(16)
    for s2w in (look_at([0.0, -3.5, 0.6], [0.0, 0.0, 0.0]), _sensor(3.0, 2.4, 0.0)):
        det = detect_wand(render_depth(Scene(), s2w, INTR, rng), INTR, WAND)
        assert not det.found


def test_detect_wand_sequence_returns_arrays() -> None:
    rng = np.random.default_rng(17)
    s2w = _sensor()
    centre = np.array([0.2, 0.4, 1.3])  # the actor stands behind it, seen from the sensor
    frames = np.stack(
        [
            render_depth(_wand_scene(centre), s2w, INTR, rng, NO_OFFSET),
            render_depth(Scene(), s2w, INTR, rng),
        ]
    )
    track = detect_wand_sequence(frames, INTR, WAND)
    assert track.found.tolist() == [True, False]
    assert track.centre_sensor_m.shape == (2, 3)
    assert np.isnan(track.centre_sensor_m[1]).all()
    np.testing.assert_allclose(track.centre_sensor_m[0], _in_sensor(s2w, centre), atol=0.004)
    assert track.score.shape == track.residual_m.shape == track.n_points.shape == (2,)
    assert track.reasons[0] == "ok" and track.reasons[1] != "ok"


# --------------------------------------------------------------------------------------------
# real depth images: no wand in them, nothing may be found


def _azure_nfov_intrinsics(calib_json: Path) -> Intrinsics:
    """Depth intrinsics of the Azure Kinect's NFOV unbinned mode (640x576) from its calibration:
    the normalized parameters refer to the 1024x1024 sensor, cropped by (192, 180) px."""
    cal = json.loads(calib_json.read_text())
    cam = next(
        c
        for c in cal["CalibrationInformation"]["Cameras"]
        if c["Purpose"] == "CALIBRATION_CameraPurposeDepth"
    )
    cx, cy, fx, fy = cam["Intrinsics"]["ModelParameters"][:4]
    w, h = cam["SensorWidth"], cam["SensorHeight"]
    return Intrinsics(
        width=640,
        height=576,
        fx=fx * w,
        fy=fy * h,
        cx=cx * w - 192 - 0.5,
        cy=cy * h - 180 - 0.5,
        min_range_m=0.25,
        max_range_m=5.46,
    )


def test_real_azure_kinect_mug_scene_has_no_wand(shared_data: Path) -> None:
    av = pytest.importorskip("av", reason="PyAV reads the Azure Kinect MKV (test-only dependency)")
    mkv = shared_data / "depth" / "pyk4a_recording.mkv"
    if not mkv.exists():
        pytest.skip(f"{mkv} not found")
    intr = _azure_nfov_intrinsics(shared_data / "depth" / "pyk4a_calibration.json")
    with av.open(str(mkv)) as container:
        stream = next(s for s in container.streams.video if s.metadata.get("title") == "DEPTH")
        frames = [f.to_ndarray() for f in container.decode(stream)]
    assert frames and frames[0].shape == (576, 640) and frames[0].dtype == np.uint16
    assert 1000 < np.median(frames[0][frames[0] > 0]) < 2000  # mm: a real depth image
    for frame in frames:
        for radius in (0.05, 0.08, 0.10, 0.15):  # no ball of any usual wand size either
            det = detect_wand(frame, intr, Wand(radius_m=radius))
            assert not det.found, (radius, det.reason)


def test_real_person_in_front_of_a_wall_has_no_wand(shared_data: Path) -> None:
    pil = pytest.importorskip("PIL.Image", reason="Pillow reads the 16-bit PNG")
    png = shared_data / "depth" / "open3d_person_depth.png"
    if not png.exists():
        pytest.skip(f"{png} not found")
    depth = np.asarray(pil.open(png))
    assert depth.dtype == np.uint16 and depth.shape == (480, 640)
    # a 640x480 structured-light camera (Open3D's test data): nominal PrimeSense intrinsics
    intr = Intrinsics(
        width=640,
        height=480,
        fx=525.0,
        fy=525.0,
        cx=319.5,
        cy=239.5,
        min_range_m=0.3,
        max_range_m=8.0,
    )
    for radius in (0.05, 0.08, 0.10, 0.15):
        det = detect_wand(depth, intr, Wand(radius_m=radius))
        assert not det.found, (radius, det.reason)


# --------------------------------------------------------------------------------------------
# bad input


def test_nan_depth_is_a_clear_error() -> None:
    depth = np.full((INTR.height, INTR.width), 2000.0)
    depth[10, 20] = np.nan
    with pytest.raises(
        InputError, match=r"depth frame contains 1 NaN.*u=20, v=10.*replace NaN by 0"
    ):
        detect_wand(depth, INTR, WAND)
    with pytest.raises(InputError, match=r"frame of k2 contains 1 NaN"):
        detect_wand_paper(depth, INTR, WAND, name="frame of k2")


def test_wrong_size_frame_is_a_clear_error() -> None:
    depth = np.zeros((480, 640), dtype=np.uint16)
    with pytest.raises(InputError, match=r"shape \(480, 640\).*512x424.*intrinsics of the camera"):
        detect_wand(depth, INTR, WAND)
    frames = np.zeros((3, 424, 512), dtype=np.float64)
    frames[2, 0, 0] = np.nan
    with pytest.raises(InputError, match=r"k1\[2\] contains 1 NaN"):
        detect_wand_sequence(frames, INTR, WAND, name="k1")
    with pytest.raises(InputError, match=r"must have shape \(N, 424, 512\)"):
        detect_wand_sequence(np.zeros((424, 512), dtype=np.uint16), INTR, WAND)


def test_other_bad_inputs() -> None:
    ok = np.zeros((INTR.height, INTR.width), dtype=np.uint16)
    with pytest.raises(InputError, match="intrinsics must be a kinefuse"):
        detect_wand(ok, "kinect", WAND)  # type: ignore[arg-type]
    with pytest.raises(InputError, match=r"outside 0\.\.65535"):
        detect_wand(ok.astype(np.int32) - 5, INTR, WAND)
    with pytest.raises(InputError, match="must hold numbers"):
        detect_wand(ok.astype(str), INTR, WAND)
    with pytest.raises(InputError, match="min_isolation must be in"):
        RobustDetectorParams(min_isolation=1.5)
    with pytest.raises(InputError, match="c_offset must be between 0 and 1"):
        detect_wand_paper(ok, INTR, WAND, c_offset=1.5)
    with pytest.raises(InputError, match="repeats must be >= 1"):
        detect_wand_paper(ok, INTR, WAND, repeats=0)
    # an all-zero frame is valid input with nothing in it
    assert not detect_wand(ok, INTR, WAND).found
    assert not detect_wand_paper(ok, INTR, WAND).found


# --------------------------------------------------------------------------------------------
# the paper's detector


def test_paper_standardization_and_binarization() -> None:
    d = np.array([[0, 400, 1000, 7000, 2000]], dtype=np.uint16)
    np.testing.assert_array_equal(standardize_depth_cm(d), [[850, 850, 100, 650, 200]])
    cm = np.array([[100, 104, 300, 310, 850, 650]], dtype=np.float32)
    np.testing.assert_array_equal(binarize_nearest(cm, 0.1), [[1, 1, 0, 0, 0, 0]])


def test_paper_detector_when_the_wand_is_the_nearest_object() -> None:
    """A level sensor at 1.2 m sees the floor from about 2 m on: a wand at 1-1.5 m is the nearest
    object and the paper's method finds it; farther away it takes the floor for the wand."""
    rng = np.random.default_rng(21)
    # the actor stands beyond the wand (seen from the sensor), as in the simulated protocol
    s2w = look_at([0.0, -0.5, 1.2], [0.0, 3.0, 1.2])
    for dist in (1.0, 1.5):
        centre = np.array([0.1, -0.5 + dist, 1.3])
        depth = render_depth(_wand_scene(centre), s2w, INTR, rng, NO_OFFSET)
        det = detect_wand_paper(depth, INTR, WAND)
        assert det.found
        err = np.linalg.norm(det.centre_sensor_m - _in_sensor(s2w, centre))
        assert err < 0.01  # 1 cm
        assert det.score >= 0.6
    far = np.array([0.1, 2.5, 1.3])
    det = detect_wand_paper(render_depth(_wand_scene(far), s2w, INTR, rng), INTR, WAND)
    assert np.linalg.norm(det.centre_sensor_m - _in_sensor(s2w, far)) > 0.3  # the floor
    track = detect_wand_paper_sequence(np.stack([depth, depth]), INTR, WAND)
    assert track.found.shape == (2,)


def test_paper_filter_drops_outliers() -> None:
    rng = np.random.default_rng(22)
    c = np.array([0.1, -0.2, 2.0]) + rng.normal(0, 0.002, (7, 3))  # 2 mm
    c[2] += [0.3, 0.0, 0.0]
    c[5] = np.nan
    centre, kept = paper_filter(c, reject_m=0.02)
    assert kept.tolist() == [True, True, False, True, True, False, True]
    np.testing.assert_allclose(centre, [0.1, -0.2, 2.0], atol=0.003)  # 3 mm
    centre, kept = paper_filter(np.full((3, 3), np.nan))
    assert np.isnan(centre).all() and not kept.any()
    with pytest.raises(InputError, match=r"shape \(K, 3\)"):
        paper_filter(np.zeros((3, 2)))


def test_not_found_detection_defaults() -> None:
    det = WandDetection.not_found("because")
    assert not det.found and det.reason == "because" and np.isnan(det.pixel_uv).all()

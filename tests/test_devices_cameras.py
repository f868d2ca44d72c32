"""The device sources without a device: a RealSense recording written by pyrealsense2's own
software device and recorder, the Kinect v2 body conversion on kinect-next's own objects where
it is installed (constructed ones otherwise), the k4abt joint map, and the one-line refusal of
every source and tracker whose library, SDK or device is missing."""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from kinefuse.core.frames.observations import DepthFrame
from kinefuse.core.skeleton import JOINTS, N_JOINTS, TrackingState
from kinefuse.devices.k4abt import K4ABT_TO_KINECT_V2, skeleton_to_body, state_of_confidence
from kinefuse.devices.kinect2 import bodies_to_result
from kinefuse.devices.sources import list_sources, open_camera_source
from kinefuse.live.client.playback import open_timeline

ROOT = Path(__file__).resolve().parents[1]


def _kinefuse(*args: str, block: str = "") -> subprocess.CompletedProcess[str]:
    """Run the CLI in a fresh interpreter; ``block`` names a module made unimportable there
    (``sys.modules[name] = None``: what Python does for a package that is not installed)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT / "src") + os.pathsep + env.get("PYTHONPATH", "")
    code = (
        "import sys\n"
        + (f"sys.modules[{block!r}] = None\n" if block else "")
        + "from kinefuse.app.cli import main\nsys.exit(main(sys.argv[1:]))\n"
    )
    return subprocess.run(
        [sys.executable, "-c", code, *args], capture_output=True, text=True, env=env, timeout=60
    )


def _refused(p: subprocess.CompletedProcess[str], *words: str) -> None:
    assert p.returncode == 2, (p.returncode, p.stderr)
    assert "Traceback" not in p.stderr
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, p.stderr
    for w in words:
        assert w in lines[0], lines[0]


# -- RealSense -------------------------------------------------------------------------------


def _write_realsense_recording(path: Path, n: int = 5) -> None:
    """A depth stream of ``n`` frames (64 x 48, pixel (u, v) = 1000 + 10 k + u mm) written by
    pyrealsense2's software device through its recorder: the file format librealsense writes."""
    rs = pytest.importorskip("pyrealsense2")
    dev = rs.software_device()
    sensor = dev.add_sensor("Depth")
    intr = rs.intrinsics()
    intr.width, intr.height = 64, 48
    intr.fx, intr.fy, intr.ppx, intr.ppy = 52.0, 51.0, 31.25, 23.75
    intr.model = rs.distortion.brown_conrady
    intr.coeffs = [0.0] * 5
    vs = rs.video_stream()
    vs.type, vs.index, vs.uid = rs.stream.depth, 0, 0
    vs.width, vs.height, vs.fps, vs.bpp = 64, 48, 30, 2
    vs.fmt, vs.intrinsics = rs.format.z16, intr
    profile = sensor.add_video_stream(vs)
    sensor.add_read_only_option(rs.option.depth_units, 0.001)
    recorder = rs.recorder(str(path), dev)
    queue = rs.frame_queue(n + 1)
    sensor.open(profile)
    sensor.start(queue)
    for k in range(n):
        img = (1000 + 10 * k + np.arange(64, dtype=np.uint16))[None, :].repeat(48, 0)
        f = rs.software_video_frame()
        f.pixels, f.bpp, f.stride = np.ascontiguousarray(img), 2, 64 * 2
        f.timestamp, f.frame_number = 5000.0 + 1000.0 * k / 30, k
        f.domain = rs.timestamp_domain.hardware_clock
        f.profile = profile.as_video_stream_profile()
        sensor.on_video_frame(f)
        queue.wait_for_frame()
    sensor.stop()
    sensor.close()
    del recorder  # closes the file


def test_a_realsense_recording_plays_back_through_the_source(tmp_path: Path) -> None:
    rs = pytest.importorskip("pyrealsense2")
    ext = ".db3" if int(rs.__version__.split(".")[1]) >= 56 else ".bag"
    rec = tmp_path / f"take{ext}"
    _write_realsense_recording(rec)
    src = open_camera_source(f"realsense-file:{rec}")
    try:
        assert src.sensor_ids == ("take",) and not src.live
        d = src.intrinsics("take")
        assert (d.width, d.height, d.fx, d.fy, d.cx, d.cy) == (64, 48, 52.0, 51.0, 31.25, 23.75)
        frames = list(src)
    finally:
        src.close()
    assert len(frames) == 5 and all(isinstance(f, DepthFrame) for f in frames)
    for k, f in enumerate(frames):
        assert isinstance(f, DepthFrame)
        np.testing.assert_array_equal(f.depth_mm[7], 1000 + 10 * k + np.arange(64))
        assert f.t_device_s == pytest.approx(5.0 + k / 30, abs=1e-6)
    # the client's timeline: a recording plays on its device times
    tl = open_timeline(f"realsense-file:{rec}#rs1")
    try:
        assert tl.sensor_id == "rs1" and not tl.live and tl.intrinsics == d
        played = [t.t_play_s for t in tl.frames()]
    finally:
        tl.close()
    assert np.allclose(np.diff(played), 1 / 30, atol=1e-6)


def test_realsense_without_a_camera_or_the_library_is_one_line(tmp_path: Path) -> None:
    pytest.importorskip("pyrealsense2")
    _refused(_kinefuse("sensor", "--server", "127.0.0.1:9", "--source", "realsense:"), "no Real")
    p = _kinefuse(
        "sensor", "--server", "127.0.0.1:9", "--source", "realsense:", block="pyrealsense2"
    )
    _refused(p, "pip install 'kinefuse[realsense]'")
    junk = tmp_path / "x.bag"
    junk.write_text("not a bag\n")
    p = _kinefuse("sensor", "--server", "127.0.0.1:9", "--source", f"realsense-file:{junk}")
    _refused(p, "not a RealSense recording")


# -- Kinect v2 -------------------------------------------------------------------------------


@dataclass
class _V3:
    x: float
    y: float
    z: float


def _kinect_body(tracking_id: int, tracked: bool, rng: np.random.Generator):
    """kinect-next's own Body/Joint classes where it is installed, else objects with the same
    attributes (its API: ``Body.tracking_id``, ``is_tracked``, ``joints`` of ``Joint`` with
    ``joint_type``, ``position`` (x, y, z metres, camera space), ``tracking_state``)."""
    pos = rng.uniform(-1, 1, (N_JOINTS, 3)) + np.array([0, 0, 2.5])
    states = np.full(N_JOINTS, 2)
    states[7], states[21] = 1, 0  # HandLeft inferred, HandTipLeft not tracked
    try:
        import kinect_next as kn
        from kinect_next.models.body import JointCollection
    except ImportError:
        joints = [
            SimpleNamespace(joint_type=i, position=_V3(*pos[i]), tracking_state=int(states[i]))
            for i in range(N_JOINTS)
        ]
        body = SimpleNamespace(tracking_id=tracking_id, is_tracked=tracked, joints=joints)
        return body, pos, states
    jc = JointCollection(
        {
            kn.JointType(i): kn.Joint(
                kn.JointType(i),
                kn.Vector3(*pos[i]),
                kn.TrackingState(int(states[i])),
                kn.Quaternion(0.0, 0.0, 0.0, 1.0),
            )
            for i in range(N_JOINTS)
        }
    )
    body = SimpleNamespace(tracking_id=tracking_id, is_tracked=tracked, joints=jc)
    return body, pos, states


def test_kinect_v2_bodies_become_kinefuse_axes_joints_and_states(rng) -> None:
    b1, pos, states = _kinect_body(72057594037928283, True, rng)
    b0, _, _ = _kinect_body(0, False, rng)
    result = bodies_to_result([b0, b1])
    assert len(result.bodies) == 1  # the untracked body slot is left out
    body = result.bodies[0]
    assert body.body_id == 72057594037928283
    # camera space x left, y up -> sensor frame x right, y down; z unchanged
    ok = states > 0
    np.testing.assert_allclose(body.joints_m[ok], pos[ok] * [-1, -1, 1])
    np.testing.assert_array_equal(body.states, states)
    assert np.isnan(body.joints_m[JOINTS.index("HandTipLeft")]).all()
    assert body.states[JOINTS.index("HandLeft")] == TrackingState.INFERRED


def test_kinect2_off_windows_is_one_line_naming_what_it_needs() -> None:
    if sys.platform == "win32":
        pytest.skip("this test is the refusal off Windows")
    p = _kinefuse("sensor", "--server", "127.0.0.1:9", "--source", "kinect2")
    _refused(p, "64-bit Windows", "Kinect for Windows SDK 2.0 runtime")


# -- Azure Kinect (live) and k4abt -----------------------------------------------------------


def test_k4a_without_pyk4a_or_without_a_device_is_one_line() -> None:
    p = _kinefuse("sensor", "--server", "127.0.0.1:9", "--source", "k4a:", block="pyk4a")
    _refused(p, "pip install 'kinefuse[k4a]'")
    p = _kinefuse("sensor", "--server", "127.0.0.1:9", "--source", "k4a:0?depth_mode=BAD")
    _refused(p, "depth_mode must be one of")
    try:
        import pyk4a  # noqa: F401
    except ImportError:
        return  # not installed here (or the numpy-1 wheel under numpy 2): refused above
    p = _kinefuse("sensor", "--server", "127.0.0.1:9", "--source", "k4a:")
    _refused(p, "no Azure Kinect or Femto is connected")


def test_k4abt_maps_its_32_joints_to_the_25_with_confidence_as_states(rng) -> None:
    assert len(K4ABT_TO_KINECT_V2) == N_JOINTS and len(set(K4ABT_TO_KINECT_V2)) == N_JOINTS
    np.testing.assert_array_equal(state_of_confidence([0, 1, 2, 3]), [0, 1, 2, 2])
    pos_mm = rng.uniform(-800, 800, (32, 3)) + np.array([0, 0, 2500])
    conf = np.full(32, 2)
    conf[26] = 3  # HEAD high
    conf[8] = 1  # HAND_LEFT low: predicted
    conf[22] = 0  # HIP_RIGHT none: out of range
    body = skeleton_to_body(7, pos_mm, conf)
    names = {n: JOINTS.index(n) for n in ("Head", "HandLeft", "HipRight", "SpineBase", "Neck")}
    np.testing.assert_allclose(body.joints_m[names["Head"]], pos_mm[26] / 1000)
    np.testing.assert_allclose(body.joints_m[names["SpineBase"]], pos_mm[0] / 1000)  # PELVIS
    np.testing.assert_allclose(body.joints_m[names["Neck"]], pos_mm[3] / 1000)
    assert body.states[names["Head"]] == TrackingState.TRACKED
    assert body.states[names["HandLeft"]] == TrackingState.INFERRED
    assert body.states[names["HipRight"]] == TrackingState.NOT_TRACKED
    assert np.isnan(body.joints_m[names["HipRight"]]).all()
    assert body.confidence is not None and body.confidence[names["Head"]] == 1.0


def test_k4abt_without_its_library_is_one_line(shared_data: Path) -> None:
    mkv = shared_data / "depth" / "pyk4a_recording.mkv"
    args = ("sensor", "--server", "127.0.0.1:9", "--source", f"mkv:{mkv}", "--tracker", "k4abt")
    p = _kinefuse(*args, block="pykinect_azure")
    _refused(p, "pykinect-azure", "Body Tracking SDK")


def test_a_recording_without_pyav_is_one_line(shared_data: Path) -> None:
    mkv = shared_data / "depth" / "pyk4a_recording.mkv"
    p = _kinefuse("sensor", "--server", "127.0.0.1:9", "--source", f"mkv:{mkv}", block="av")
    _refused(p, "pip install 'kinefuse[mkv]'")


def test_list_sources_shows_every_source_and_tracker_with_how_to_install() -> None:
    rows = {r[0]: r for r in list_sources()}
    for kind in ("sim", "multitrack", "kinect2json", "mkv", "k4a", "realsense", "realsense-file",
                 "kinect2", "tracker k4abt", "tracker pose"):  # fmt: skip
        assert kind in rows, kind
    for _kind, _form, status, _what in rows.values():
        assert status == "installed" or "pip install" in status, status
    p = _kinefuse("sensor", "--list-sources", block="pyrealsense2")
    assert p.returncode == 0, p.stderr
    rs_line = next(ln for ln in p.stdout.splitlines() if ln.startswith("realsense "))
    assert "missing" in rs_line
    assert "install: pip install 'kinefuse[realsense]'" in p.stdout

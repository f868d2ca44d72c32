"""The Azure Kinect recording source (``mkv:``) on the real recording in ``../shared/data/depth``:
every stream, timestamp and IMU sample read back, the calibration as libk4a gives it, bad files
refused in one line, and the recording played by ``kinefuse sensor`` into a real ``serve``."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.cli import main
from kinefuse.core.frames.observations import BodyFrame, DepthFrame
from kinefuse.core.skeleton import N_JOINTS, TrackingState
from kinefuse.devices.capture import CameraCalibration, Capture
from kinefuse.devices.k4a_calibration import calibration_from_k4a_json
from kinefuse.devices.mkv import MkvRecording
from kinefuse.devices.sources import CameraFrameSource, open_camera_source
from kinefuse.devices.trackers import TrackedBody, TrackerResult
from kinefuse.errors import InputError
from kinefuse.formats.store.session_store import SessionStore

ROOT = Path(__file__).resolve().parents[1]

av = pytest.importorskip("av")


@pytest.fixture(scope="module")
def mkv(shared_data: Path) -> Path:
    return shared_data / "depth" / "pyk4a_recording.mkv"


def test_every_stream_timestamp_and_the_imu_sample_read_back(mkv: Path) -> None:
    rec = MkvRecording(mkv)
    assert rec.streams == ("COLOR", "DEPTH", "IR", "IMU")
    assert rec.depth_mode == "NFOV_UNBINNED" and rec.color_mode == "MJPG_720P"
    assert rec.serial == "001514394512"
    assert rec.start_offset_s == pytest.approx(0.336277, abs=1e-12)
    caps = list(rec.captures())
    assert len(caps) == 1
    c = caps[0]
    # the block timestamp (463945 us) + K4A_START_OFFSET_NS: libk4a's depth_timestamp_usec
    assert c.t_device_s == pytest.approx(0.800222, abs=1e-9)
    assert rec.rate_hz == pytest.approx(5.0)  # recorded at 5 fps: blocks of 200 ms
    assert c.depth_mm is not None and c.depth_mm.dtype == np.uint16
    assert c.depth_mm.shape == (576, 640)
    # big-endian on disk: the values are millimetres of a table scene (libk4a reads 1939 here)
    assert int(c.depth_mm[300, 300]) == 1939
    valid = c.depth_mm[c.depth_mm > 0]
    assert 0.5 < valid.size / c.depth_mm.size < 1.0 and 500 < np.median(valid) < 3000
    assert c.ir is not None and c.ir.shape == (576, 640) and c.ir.max() > 0
    assert c.color is not None and c.color.shape == (720, 1280, 3) and c.color.dtype == np.uint8
    assert 30 < c.color.mean() < 230  # a decoded picture, not black or white
    # the one IMU sample: libk4a's acc/gyro timestamp is 336277 us (ns in the block)
    assert c.imu is not None and c.imu.shape == (1, 7)
    np.testing.assert_allclose(
        c.imu[0],
        [0.336277, -2.888193, -0.193805, -9.437137, -0.0010146, -0.0019478, 0.0060235],
        atol=1e-6,
    )
    assert np.linalg.norm(c.imu[0, 1:4]) == pytest.approx(9.81, abs=0.2)  # gravity


def test_intrinsics_equal_the_json_beside_the_recording(mkv: Path) -> None:
    rec = MkvRecording(mkv)
    text = (mkv.parent / "pyk4a_calibration.json").read_text()
    beside = calibration_from_k4a_json(text, "NFOV_UNBINNED", "720P")
    assert rec.calibration.depth == beside.depth and rec.calibration.color == beside.color
    assert rec.calibration.distortion_depth == beside.distortion_depth
    # libk4a's conversion of the raw (unitised, 0-cornered) parameters for NFOV_UNBINNED:
    # x 1024, minus the crop (192, 180), minus half a pixel
    raw = json.loads(text)["CalibrationInformation"]["Cameras"][0]["Intrinsics"]["ModelParameters"]
    d = rec.calibration.depth
    assert (d.width, d.height) == (640, 576)
    assert d.fx == pytest.approx(raw[2] * 1024) and d.fy == pytest.approx(raw[3] * 1024)
    assert d.cx == pytest.approx(raw[0] * 1024 - 192.5)
    assert d.cy == pytest.approx(raw[1] * 1024 - 180.5)
    assert (d.min_range_m, d.max_range_m) == (0.5, 3.86)  # NFOV unbinned's operating range
    # what libk4a itself (pyk4a-bundle 1.5.0's PyK4APlayback.calibration) gives for this file
    np.testing.assert_allclose(
        [d.fx, d.fy, d.cx, d.cy], [504.607635, 504.732513, 332.781067, 348.829712], atol=1e-4
    )
    c = rec.calibration.color
    assert c is not None and (c.width, c.height) == (1280, 720)
    np.testing.assert_allclose(
        [c.fx, c.fy, c.cx, c.cy], [611.795349, 611.927002, 639.304321, 365.852905], atol=1e-3
    )
    m = rec.calibration.color_from_depth
    assert m is not None
    np.testing.assert_allclose(m[:3, 3], [-0.0320834, -0.0022054, 0.0038837], atol=1e-6)
    np.testing.assert_allclose(m[:3, :3] @ m[:3, :3].T, np.eye(3), atol=1e-6)
    np.testing.assert_allclose(
        rec.calibration.distortion_depth[:4],
        [0.5479398, -0.0209714, 2.0557534e-05, -7.2104e-05],
        atol=1e-6,
    )


def test_the_calibration_agrees_with_libk4a_where_pyk4a_loads(mkv: Path) -> None:
    pyk4a = pytest.importorskip("pyk4a", exc_type=ImportError)
    pb = pyk4a.PyK4APlayback(str(mkv))
    pb.open()
    try:
        k = pb.calibration.get_camera_matrix(pyk4a.CalibrationType.DEPTH)
        cap = pb.get_next_capture()
        depth = cap.depth
    finally:
        pb.close()
    rec = MkvRecording(mkv)
    np.testing.assert_allclose(rec.calibration.depth.matrix, k, atol=1e-3)
    np.testing.assert_array_equal(next(rec.captures()).depth_mm, depth)


def _env() -> dict[str, str]:
    """The tests' environment: this checkout, and the test trackers of ``tests/plugins``
    (real ``kinefuse.trackers`` entry points)."""
    env = dict(os.environ)
    paths = [str(ROOT / "src"), str(ROOT / "tests" / "plugins"), env.get("PYTHONPATH", "")]
    env["PYTHONPATH"] = os.pathsep.join(paths)
    return env


def _run(*args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    env = _env()
    return subprocess.run(
        [sys.executable, "-m", "kinefuse", *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=timeout,
    )


def _one_line_refusal(p: subprocess.CompletedProcess[str], *words: str) -> None:
    assert p.returncode == 2, p.stderr
    assert "Traceback" not in p.stderr
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, p.stderr
    for w in words:
        assert w in lines[0], lines[0]


@pytest.mark.parametrize("keep", [100, 300_000, 1_699_000])
def test_a_truncated_recording_is_one_line_and_exit_2(mkv: Path, tmp_path: Path, keep) -> None:
    cut = tmp_path / "cut.mkv"
    cut.write_bytes(mkv.read_bytes()[:keep])
    with pytest.raises(InputError, match="truncated"):
        MkvRecording(cut)
    p = _run("sensor", "--server", "127.0.0.1:9", "--source", f"mkv:{cut}", timeout=30)
    _one_line_refusal(p, "truncated", str(cut))


def test_a_matroska_file_that_is_not_a_k4a_recording_is_refused(tmp_path: Path) -> None:
    other = tmp_path / "other.mkv"
    with av.open(str(other), "w") as out:
        s = out.add_stream("ffv1", rate=5)
        s.width, s.height, s.pix_fmt = 64, 48, "gray16le"
        for k in range(3):
            img = np.full((48, 64), 1000 + k, dtype=np.uint16)
            for pkt in s.encode(av.VideoFrame.from_ndarray(img, format="gray16le")):
                out.mux(pkt)
        for pkt in s.encode():
            out.mux(pkt)
    with pytest.raises(InputError, match="not an Azure Kinect recording"):
        MkvRecording(other)
    text = tmp_path / "text.mkv"
    text.write_text("hello\n")
    p = _run("sensor", "--server", "127.0.0.1:9", "--source", f"mkv:{text}", timeout=30)
    _one_line_refusal(p, "not a Matroska file")
    p = _run("sensor", "--server", "127.0.0.1:9", "--source", f"mkv:{tmp_path / 'no.mkv'}")
    _one_line_refusal(p, "no such file")


class _FixedBodies:
    """A tracker that reports two bodies at set depths (not the part under test: the adapter
    is); its joints lie on a vertical line in front of the camera."""

    name = "fixed"

    def __init__(self) -> None:
        self.closed = False

    def track(self, capture: Capture, calibration: CameraCalibration) -> TrackerResult:
        def body(i: int, z: float) -> TrackedBody:
            j = np.zeros((N_JOINTS, 3))
            j[:, 1] = np.linspace(-0.8, 0.8, N_JOINTS)
            j[:, 2] = z
            st = np.full(N_JOINTS, TrackingState.TRACKED, dtype=np.int8)
            st[3] = TrackingState.NOT_TRACKED
            return TrackedBody(i, j, st)

        return TrackerResult((body(1, 3.0), body(2, 2.0)), ("bones of 4 cm: not a person",))

    def close(self) -> None:
        self.closed = True


def test_the_adapter_gives_depth_and_the_nearest_body(mkv: Path) -> None:
    rec = MkvRecording(mkv)
    tracker = _FixedBodies()
    src = CameraFrameSource(rec, "k1", tracker)
    assert src.sensor_ids == ("k1",) and src.intrinsics("k1") == rec.calibration.depth
    frames = list(src)
    assert [type(f) for f in frames] == [DepthFrame, BodyFrame]
    d, b = frames
    assert isinstance(d, DepthFrame) and isinstance(b, BodyFrame)
    assert d.t_device_s == b.t_device_s == pytest.approx(0.800222)
    assert np.isnan(d.t_host_s)  # a recording: no arrival time
    assert np.all(b.joints_m[b.states > 0, 2] == 2.0)  # the nearer of the two bodies
    assert b.states[3] == TrackingState.NOT_TRACKED and np.isnan(b.joints_m[3]).all()
    assert src.with_person == 1 and src.refused == ["bones of 4 cm: not a person"]
    src.close()
    assert tracker.closed
    # no tracker: depth only
    only = list(open_camera_source(f"mkv:{mkv}#k2"))
    assert len(only) == 1 and isinstance(only[0], DepthFrame) and only[0].sensor_id == "k2"


def test_an_unknown_or_missing_tracker_is_one_line(mkv: Path) -> None:
    p = _run("sensor", "--server", "127.0.0.1:9", "--source", f"mkv:{mkv}", "--tracker", "nope")
    _one_line_refusal(p, "no tracker 'nope'", "--list-sources")
    p = _run("sensor", "--server", "127.0.0.1:9", "--source", "multitrack:x.csv", "--tracker", "x")
    _one_line_refusal(p, "--tracker is for camera sources")


@pytest.mark.slow
def test_kinefuse_sensor_plays_the_recording_into_a_real_server(mkv: Path, tmp_path: Path) -> None:
    env = _env()
    rec = tmp_path / "rec.sqlite"
    srv = subprocess.Popen(
        [sys.executable, "-m", "kinefuse", "serve", "--port", "0", "--record", str(rec)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=tmp_path,
    )
    try:
        assert srv.stdout is not None
        first = srv.stdout.readline().strip()
        assert first.startswith("kinefuse serve: listening on 127.0.0.1:"), first
        port = first.rsplit(":", 1)[1]
        p = _run(
            "sensor", "--server", f"127.0.0.1:{port}", "--source", f"mkv:{mkv}#azure1",
            "--speed", "2", "-v",
        )  # fmt: skip
        assert p.returncode == 0, p.stderr
        assert "sensor azure1 connected" in p.stderr
        assert "1 depth frames" in p.stderr and "the source ended" in p.stderr
        assert "0 body frames sent" in p.stderr  # no tracker: depth only
        # a second sensor from the same recording, with a tracker: its body frame is recorded
        p = _run(
            "sensor", "--server", f"127.0.0.1:{port}", "--source", f"mkv:{mkv}#azure2",
            "--tracker", "standing", "-v",
        )  # fmt: skip
        assert p.returncode == 0, p.stderr
        assert "1 body frames sent" in p.stderr
        srv.send_signal(signal.SIGINT)
        _out, err = srv.communicate(timeout=30)
        assert srv.returncode == 0, err
    finally:
        if srv.poll() is None:
            srv.kill()
            srv.wait(10)
    with SessionStore.open(rec) as st:
        info = st.sensor("azure1")
        assert info.serial == "001514394512"
        assert info.intrinsics == MkvRecording(mkv).calibration.depth
        assert st.observation_count("azure1") == 0
        obs = st.observations("azure2")
        assert obs.n_frames == 1 and obs.has_body.all()
        assert obs.t_sensor_s[0] == pytest.approx(0.800222)
    assert main(["inspect", str(rec)]) == 0


#: device pixels and where libk4a 1.4 (pyk4a-bundle 1.5.0, ``Calibration.convert_2d_to_3d``)
#: unprojects them, projected with the pinhole intrinsics: pixel (u, v) -> pinhole (u', v')
LIBK4A_PINHOLE = (((600, 349), (629.41, 349.01)), ((533, 349), (544.62, 349.01)),
                  ((100, 500), (72.14, 518.10)))  # fmt: skip


def test_depth_frames_are_resampled_to_the_pinhole_camera_as_libk4a_unprojects(mkv) -> None:
    from kinefuse.devices.undistort import DepthUndistorter

    rec = MkvRecording(mkv)
    und = DepthUndistorter(rec.calibration)
    w = rec.calibration.depth.width
    for (u, v), (pu, pv) in LIBK4A_PINHOLE:
        src_v, src_u = divmod(int(und.source_index[round(pv), round(pu)]), w)
        assert abs(src_u - u) <= 1 and abs(src_v - v) <= 1, ((u, v), (src_u, src_v))
    # the principal point sees the same ray in both; the frame the adapter sends is resampled
    k = rec.calibration.depth
    assert und.source_index[round(k.cy), round(k.cx)] == round(k.cy) * w + round(k.cx)
    cap = next(rec.captures())
    (frame,) = list(open_camera_source(f"mkv:{mkv}"))
    assert isinstance(frame, DepthFrame) and cap.depth_mm is not None
    np.testing.assert_array_equal(frame.depth_mm, und(cap.depth_mm))
    assert (frame.depth_mm != cap.depth_mm).mean() > 0.3  # the edges moved


def test_the_resampling_agrees_with_libk4a_everywhere_where_pyk4a_loads(mkv: Path) -> None:
    pyk4a = pytest.importorskip("pyk4a", exc_type=ImportError)
    from kinefuse.devices.undistort import DepthUndistorter

    rec = MkvRecording(mkv)
    k = rec.calibration.depth
    und = DepthUndistorter(rec.calibration)
    pb = pyk4a.PyK4APlayback(str(mkv))
    pb.open()
    errors = []
    try:
        for v in range(0, k.height, 24):
            for u in range(0, k.width, 24):
                try:
                    p = pb.calibration.convert_2d_to_3d((u, v), 1000.0, pyk4a.CalibrationType.DEPTH)
                except ValueError:
                    continue  # no valid ray for libk4a
                pu, pv = k.project(np.asarray(p) / 1000.0)
                iu, iv = round(pu), round(pv)
                if 0 <= iu < k.width and 0 <= iv < k.height:
                    sv, su = divmod(int(und.source_index[iv, iu]), k.width)
                    errors.append(np.hypot(su - u, sv - v))
    finally:
        pb.close()
    assert len(errors) > 300 and max(errors) <= 1.0


def test_the_adapter_keeps_every_body_the_nearest_first(mkv: Path) -> None:
    """The tracker's two bodies both reach the body frame: the nearer (id 2, the body kinefuse
    has always taken) first, the farther (id 1) as the frame's other body, same seq and times."""
    src = CameraFrameSource(MkvRecording(mkv), "k1", _FixedBodies())
    (b,) = [f for f in src if isinstance(f, BodyFrame)]
    src.close()
    assert [x.body_id for x in b.bodies()] == [2, 1]
    (o,) = b.others
    assert (o.seq, o.t_device_s, o.sensor_id) == (b.seq, b.t_device_s, "k1") and o.others == ()
    assert np.all(o.joints_m[o.states > 0, 2] == 3.0)
    assert o.states[3] == TrackingState.NOT_TRACKED and np.isnan(o.joints_m[3]).all()

"""A sensor client whose body tracker is slower than its camera: real ``kinefuse serve`` and
``kinefuse sensor`` processes on 127.0.0.1, the shared Azure Kinect recording played on
(``?repeat=N``) at 30 captures a second, and the test tracker ``slow`` (a real
``kinefuse.trackers`` entry point in ``tests/plugins``, :data:`SLOW_S` per capture).

The depth frames keep the camera's rate, the tracker's queue stays bounded (the oldest waiting
capture is dropped), every body frame carries its own capture's device time, and the tracker's
achieved rate and drops reach the server's status (and the viewer's sensor row).
"""

from __future__ import annotations

import asyncio
import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from kinefuse.core.frames.observations import BodyFrame, DepthFrame
from kinefuse.devices.mkv import MkvRecording
from kinefuse.devices.sources import open_camera_source
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.live.viewer.wire import status_message

pytest.importorskip("av")

ROOT = Path(__file__).resolve().parents[1]
# the test trackers, installed as real entry points (their .dist-info) for this process too
sys.path.insert(0, str(ROOT / "tests" / "plugins"))
sys.path.insert(0, str(ROOT / "tests"))
from kinefuse_test_trackers import SLOW_S  # noqa: E402

from test_client_floor_error import control_status  # noqa: E402
from test_devices_mkv import _env  # noqa: E402  (this checkout and the test trackers)

PASSES = 120  # captures: the recording's one capture played 120 times
SPEED = 6.0  # recorded at 5 Hz: 30 captures a second
LINE = re.compile(r"tracker ([0-9.]+) Hz, (\d+) tracked, (\d+) dropped \(behind\)")


def test_the_recording_plays_on_with_repeat(shared_data: Path) -> None:
    mkv = shared_data / "depth" / "pyk4a_recording.mkv"
    caps = list(MkvRecording(mkv, repeat=3).captures())
    assert [c.seq for c in caps] == [0, 1, 2]
    # one frame (200 ms at 5 Hz) after the other, the IMU's clock going on with them
    np.testing.assert_allclose([c.t_device_s for c in caps], [0.800222, 1.000222, 1.200222])
    assert caps[0].imu is not None and caps[2].imu is not None
    assert caps[2].imu[0, 0] - caps[0].imu[0, 0] == pytest.approx(0.4)
    np.testing.assert_array_equal(caps[0].depth_mm, caps[2].depth_mm)
    p = subprocess.run(
        [sys.executable, "-m", "kinefuse", "sensor", "--server", "127.0.0.1:9",
         "--source", f"mkv:{mkv}?repeat=0"],
        capture_output=True, text=True, env=_env(), timeout=60,
    )  # fmt: skip
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert p.stderr.strip().count("\n") == 0 and "repeat must be" in p.stderr, p.stderr


def test_the_adapters_worker_drops_the_oldest_and_keeps_capture_times(shared_data: Path) -> None:
    """In process: the camera source with the slow tracker on its own thread."""
    mkv = shared_data / "depth" / "pyk4a_recording.mkv"
    src = open_camera_source(f"mkv:{mkv}?repeat=30#k1", "slow", threaded=True, speed=SPEED)
    frames = list(src)
    src.close()
    depth = [f for f in frames if isinstance(f, DepthFrame)]
    body = [f for f in frames if isinstance(f, BodyFrame)]
    assert [f.seq for f in depth] == list(range(30))
    assert src.worker is not None
    st = src.worker.status()
    assert st.submitted == 30 and st.errors == 0
    assert st.tracked + st.dropped == 30 and st.dropped > 0  # drained at the end: none lost
    assert len(body) == st.tracked and body[-1].seq == 29  # the newest is never dropped
    for b in body:  # each with its own capture's device time, not when the tracker finished
        assert b.t_device_s == pytest.approx(0.800222 + 0.2 * b.seq)
    # a body frame comes after the depth frame of its capture
    order = [(type(f).__name__, f.seq) for f in frames]
    for b in body:
        assert order.index(("DepthFrame", b.seq)) < order.index(("BodyFrame", b.seq))


@pytest.mark.slow
def test_a_slow_tracker_in_a_live_sensor_keeps_depth_flowing_and_says_its_rate(
    shared_data: Path, tmp_path: Path
) -> None:
    mkv = shared_data / "depth" / "pyk4a_recording.mkv"
    rec, side = tmp_path / "rec.sqlite", tmp_path / "side.json"
    env = _env()
    srv = subprocess.Popen(
        [sys.executable, "-m", "kinefuse", "serve", "--port", "0", "--record", str(rec)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=tmp_path,
    )  # fmt: skip
    sensor = None
    try:
        assert srv.stdout is not None
        first = srv.stdout.readline().strip()
        assert first.startswith("kinefuse serve: listening on 127.0.0.1:"), first
        port = int(first.rsplit(":", 1)[1])
        sensor = subprocess.Popen(
            [sys.executable, "-m", "kinefuse", "sensor", "--server", f"127.0.0.1:{port}",
             "--source", f"mkv:{mkv}?repeat={PASSES}#azure1", "--tracker", "slow",
             "--speed", str(SPEED), "--truth-out", str(side), "-v"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=tmp_path,
        )  # fmt: skip
        # while it plays, the server's status carries the tracker's line
        line = None
        t_end = time.monotonic() + 60
        while line is None and sensor.poll() is None and time.monotonic() < t_end:
            status = asyncio.run(control_status(port))
            rows = [s for s in status.sensors if s.sensor_id == "azure1"]
            if rows and rows[0].tracker and LINE.match(rows[0].tracker):
                line = rows[0].tracker
                viewer_row = status_message(status)["sensors"][0]
            else:
                time.sleep(0.2)
        _out, err = sensor.communicate(timeout=120)
        assert sensor.returncode == 0, err
        srv.send_signal(signal.SIGINT)
        _out, serr = srv.communicate(timeout=30)
        assert srv.returncode == 0, serr
    finally:
        for p in (sensor, srv):
            if p is not None and p.poll() is None:
                p.kill()
                p.wait(10)
    assert line is not None, "the server's status never showed the sensor's tracker"
    m = LINE.match(line)
    assert m is not None
    rate = float(m.group(1))
    assert 0 < rate <= 1.2 / SLOW_S, line  # the tracker's own rate, not the camera's 30 Hz
    assert viewer_row["tracker"] == line  # what the viewer's sensor row shows
    # the depth frames kept the camera's rate: all of them, none late by more than a frame or
    # so (the tracker inline would have made the last one about 25 s late)
    stats = json.loads(side.read_text())
    assert stats["stats"]["depth_frames"] == PASSES
    assert stats["stats"]["max_late_s"] < 1.0, stats["stats"]
    # the queue stayed bounded: every capture tracked or dropped, the oldest first
    final = LINE.search(stats["tracker"])
    assert final is not None, stats["tracker"]
    tracked, dropped = int(final.group(2)), int(final.group(3))
    assert tracked + dropped == PASSES and dropped > PASSES // 2, stats["tracker"]
    assert f"{tracked} body frames sent" in err, err
    with SessionStore.open(rec) as st:
        obs = st.observations("azure1")
    assert obs.n_frames == tracked and obs.has_body.all()
    # each with its own capture's device time (0.2 s a capture), the newest capture last
    seq = np.asarray(obs.seq)
    assert seq[-1] == PASSES - 1 and (np.diff(seq) >= 1).all()
    np.testing.assert_allclose(obs.t_device_s, 0.800222 + 0.2 * seq, atol=1e-6)


def test_closing_the_source_mid_play_stops_the_worker_before_the_tracker(
    shared_data: Path,
) -> None:
    """A sensor stopped while its tracker works: the worker ends before the tracker closes."""
    mkv = shared_data / "depth" / "pyk4a_recording.mkv"
    src = open_camera_source(f"mkv:{mkv}?repeat=30#k1", "slow", threaded=True, speed=SPEED)
    frames = iter(src)
    for _ in range(5):  # a few depth frames in: the worker is tracking
        next(frames)
    assert src.worker is not None and src.worker._thread.is_alive()
    src.close()  # the generator is still suspended, as when the client stops
    assert not src.worker._thread.is_alive()

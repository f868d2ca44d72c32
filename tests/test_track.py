"""``kinefuse track``: the real Azure Kinect recording into a session that inspect, calibrate and
fuse take; trackers as installed entry points (``tests/plugins``), one worker process per
recording, the clocks, and a rerun that continues an interrupted one."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.workflows.track import track_recordings
from kinefuse.core.skeleton import TrackingState
from kinefuse.devices.mkv import MkvRecording
from kinefuse.devices.undistort import DepthUndistorter
from kinefuse.errors import InputError
from kinefuse.formats.store.session_store import SessionStore

ROOT = Path(__file__).resolve().parents[1]
PLUGINS = ROOT / "tests" / "plugins"

pytest.importorskip("av")


def _kinefuse(*args: str, cwd: Path, plugins: bool = False) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ)
    paths = [str(ROOT / "src"), *([str(PLUGINS)] if plugins else [])]
    env["PYTHONPATH"] = os.pathsep.join([*paths, env.get("PYTHONPATH", "")])
    return subprocess.run(
        [sys.executable, "-m", "kinefuse", *args],
        capture_output=True,
        text=True,
        env=env,
        cwd=cwd,
        timeout=300,
    )


@pytest.fixture(scope="module")
def mkv(shared_data: Path) -> Path:
    return shared_data / "depth" / "pyk4a_recording.mkv"


def test_track_makes_a_session_of_the_recording_that_inspect_shows(mkv, tmp_path) -> None:
    p = _kinefuse("track", str(mkv), "--out", "S.sqlite", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert "pyk4a_recording: 1 captures, 1 depth frames stored; depth only" in p.stdout
    with SessionStore.open(tmp_path / "S.sqlite") as st:
        assert st.complete
        (info,) = st.sensors()
        assert info.id == "pyk4a_recording" and info.serial == "001514394512"
        assert info.intrinsics == MkvRecording(mkv).calibration.depth
        assert info.rate_hz == 5.0
        ((seq, t, frames),) = list(st.iter_depth_frames(info.id))
        assert seq.tolist() == [0] and t[0] == pytest.approx(0.800222)
        rec = MkvRecording(mkv)  # stored in the pinhole camera of the stored intrinsics
        raw = next(rec.captures()).depth_mm
        assert raw is not None
        np.testing.assert_array_equal(frames[0], DepthUndistorter(rec.calibration)(raw))
        obs = st.observations(info.id)
        assert obs.n_frames == 1 and not obs.has_body.any()  # one empty body frame: no tracker
    q = _kinefuse("inspect", "S.sqlite", cwd=tmp_path)
    assert q.returncode == 0, q.stderr
    row = next(ln for ln in q.stdout.splitlines() if ln.startswith("pyk4a_recording"))
    # frames 1, body 0, seen 0 %, rate -, depth 1
    assert row.split()[:7] == ["pyk4a_recording", "1", "0", "0", "%", "-", "1"]
    assert "intrinsics pyk4a_recording: 640x576 px, fx 504.61 fy 504.73 cx 332.78 cy 348.83" in (
        q.stdout
    )
    # calibrate takes it and says in one line why it cannot calibrate one sensor without a wand
    c = _kinefuse("calibrate", "S.sqlite", cwd=tmp_path)
    assert c.returncode in (2, 3) and "Traceback" not in c.stderr
    assert "at least 2 sensors that saw the wand" in c.stderr
    # a rerun skips what is done
    r = _kinefuse("track", str(mkv), "--out", "S.sqlite", cwd=tmp_path)
    assert r.returncode == 0 and "already in the session (skipped)" in r.stdout
    with SessionStore.open(tmp_path / "S.sqlite") as st:
        assert st.observation_count("pyk4a_recording") == 1


def test_a_tracker_that_finds_no_one_says_0_frames_had_a_person(mkv, tmp_path) -> None:
    a, b = tmp_path / "a.mkv", tmp_path / "b.mkv"
    shutil.copy(mkv, a)
    shutil.copy(mkv, b)
    args = ("track", "a.mkv", "b.mkv", "--out", "S.sqlite", "--tracker", "nobody", "--jobs", "2")
    p = _kinefuse(*args, cwd=tmp_path, plugins=True)
    assert p.returncode == 0, p.stderr
    assert "0 of 2 frames had a person" in p.stdout
    assert "refused: bones of 4 cm: not a person (1)" in p.stdout
    with SessionStore.open(tmp_path / "S.sqlite") as st:
        assert [s.id for s in st.sensors()] == ["a", "b"]
        meta = st.meta()
        assert meta["track_recordings"]["b"]["with_person"] == 0
        assert "start times" in meta["track_clock"]  # two standalone devices
    assert not (tmp_path / "S.sqlite.track-parts").exists()


def test_a_tracked_person_is_stored_as_body_frames_on_the_session_clock(mkv, tmp_path) -> None:
    p = _kinefuse("track", str(mkv), "--out", "S.sqlite", "--tracker", "standing",
                  cwd=tmp_path, plugins=True)  # fmt: skip
    assert p.returncode == 0, p.stderr
    assert "1 of 1 frames had a person (standing)" in p.stdout
    with SessionStore.open(tmp_path / "S.sqlite") as st:
        obs = st.observations("pyk4a_recording")
        assert obs.has_body.all() and (obs.states == TrackingState.TRACKED).all()
        assert obs.joints_m[0, 0, 2] == pytest.approx(2.5, abs=0.2)  # SpineBase 2.5 m ahead
        # one recording: the session clock is its device clock from its first capture
        _seq, t_dev, _t_srv, t_host = st.observation_times("pyk4a_recording")
        assert t_dev[0] == pytest.approx(0.800222)
        assert t_host[0] == pytest.approx(0.060)  # + the latency the clock fit takes off


def test_an_interrupted_run_is_continued_by_the_next(mkv, tmp_path) -> None:
    a, b = tmp_path / "a.mkv", tmp_path / "b.mkv"
    shutil.copy(mkv, a)
    shutil.copy(mkv, b)
    out = tmp_path / "S.sqlite"

    def ctrl_c_while_writing_b(message: str) -> None:
        if message.startswith("b: writing"):
            raise KeyboardInterrupt  # Ctrl-C after a was merged, before b

    with pytest.raises(KeyboardInterrupt):
        track_recordings([str(a), str(b)], out, jobs=1, progress=ctrl_c_while_writing_b)
    with SessionStore.open(out) as st:
        assert not st.complete and [s.id for s in st.sensors()] == ["a"]
    # and b's merge itself cut after its first transactions (the sensor and its depth frames)
    part = tmp_path / "S.sqlite.track-parts" / "b.sqlite"
    with SessionStore.open(part) as p, SessionStore.open(out, writable=True) as st:
        info = p.sensor("b")
        st.add_sensor("b", info.serial, info.intrinsics, info.rate_hz)
        for seq, t, frames in p.iter_depth_frames("b"):
            st.append_depth_frames("b", seq, t, frames)
    d = track_recordings([str(a), str(b)], out, jobs=1)
    assert d.skipped == ("a",)
    with SessionStore.open(out) as st:
        assert st.complete and [s.id for s in st.sensors()] == ["a", "b"]
        assert st.depth_frame_count("a") == st.depth_frame_count("b") == 1
        assert st.observation_count("b") == 1 and st.clock_probes("b").shape[0] > 0
    # complete: another recording goes into a new session
    c = tmp_path / "c.mkv"
    shutil.copy(mkv, c)
    with pytest.raises(InputError, match="complete session"):
        track_recordings([str(a), str(b), str(c)], out)


def test_track_refuses_what_it_cannot_read_or_must_not_overwrite(mkv, tmp_path) -> None:
    (tmp_path / "notes.txt").write_text("x\n")
    p = _kinefuse("track", "notes.txt", "--out", "S.sqlite", cwd=tmp_path)
    assert p.returncode == 2 and "not a recording kinefuse knows" in p.stderr
    (tmp_path / "mine.sqlite").write_text("someone's file\n")
    p = _kinefuse("track", str(mkv), "--out", "mine.sqlite", cwd=tmp_path)
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert (tmp_path / "mine.sqlite").read_text() == "someone's file\n"
    p = _kinefuse("track", str(mkv), "--out", "T.sqlite", "--tracker", "k4abt", cwd=tmp_path)
    assert p.returncode == 2 and "k4abt" in p.stderr and not (tmp_path / "T.sqlite").exists()


def test_motion_lag_recovers_a_clock_offset_from_the_trunk_speed_alone() -> None:
    """Real motion (the bundled CMU 01_01 walk) seen by two 'sensors' in different frames, at
    30 Hz with interleaved samples, 1 cm of noise, the second's clock 1.73 s late."""
    from importlib.resources import files

    from scipy.spatial.transform import Rotation

    from kinefuse.app.workflows.track import motion_lag_s
    from kinefuse.formats.motion import load_motion

    m = load_motion(str(files("kinefuse") / "data" / "01_01.amc.gz"))
    rng = np.random.default_rng(11)
    t = np.arange(m.positions.shape[0]) / m.rate_hz
    ra = Rotation.from_euler("z", 40, degrees=True).as_matrix()
    rb = Rotation.from_euler("zx", [-70, 10], degrees=True).as_matrix()
    pa = m.positions[::4] @ ra.T + [1.0, 2.0, 0.0]
    pb = m.positions[2::4] @ rb.T + [-1.0, 0.5, 0.3]
    pa += rng.normal(0, 0.01, pa.shape)
    pb += rng.normal(0, 0.01, pb.shape)
    found = motion_lag_s(t[::4], pa, t[2::4] + 1.73, pb)
    assert found is not None
    lag, r = found
    assert lag == pytest.approx(1.73, abs=0.01) and r > 0.9
    # a person standing still gives no clock
    still = np.repeat(pa[:1], pa.shape[0], axis=0)
    assert motion_lag_s(t[::4], still, t[2::4], pb) is None


def test_two_recordings_of_a_standing_person_keep_their_start_time_clocks(mkv, tmp_path) -> None:
    shutil.copy(mkv, tmp_path / "a.mkv")
    shutil.copy(mkv, tmp_path / "b.mkv")
    p = _kinefuse("track", "a.mkv", "b.mkv", "--out", "S.sqlite", "--tracker", "standing",
                  "--jobs", "1", cwd=tmp_path, plugins=True)  # fmt: skip
    assert p.returncode == 0, p.stderr
    assert "2 of 2 frames had a person" in p.stdout
    with SessionStore.open(tmp_path / "S.sqlite") as st:
        clock = st.meta()["track_clock"]
    assert "start times" in clock and "motion" not in clock  # one still frame each: no lag


def test_an_unreadable_recording_is_refused_before_any_output(mkv, tmp_path) -> None:
    cut = tmp_path / "cut.mkv"
    cut.write_bytes(mkv.read_bytes()[:300_000])
    p = _kinefuse("track", str(mkv), "cut.mkv", "--out", "S.sqlite", cwd=tmp_path)
    assert p.returncode == 2 and "truncated" in p.stderr and "Traceback" not in p.stderr
    assert not (tmp_path / "S.sqlite").exists()

"""Frame sources: a stored session, a real KinectMultiTrack log and the kinect2-tracking JSON,
frame by frame in arrival order (issue 10 item 2)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.cli import main
from kinefuse.core.frames.observations import BodyFrame, DepthFrame
from kinefuse.core.frames.source import FrameSource
from kinefuse.core.skeleton import TrackingState
from kinefuse.errors import InputError
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.pipeline.frame_sources import (
    Kinect2TrackingReplay,
    MultitrackReplay,
    SessionReplay,
    open_source,
)


@pytest.fixture(scope="module")
def session(tmp_path_factory, shared_data) -> Path:
    out = tmp_path_factory.mktemp("src") / "s.sqlite"
    clip = shared_data / "motion" / "cmu" / "02_walk_a.amc"
    assert main(["simulate", "--clip", str(clip), "--seconds", "1", "--calibration-seconds", "1",
                 "--depth-rate", "5", "--out", str(out)]) == 0  # fmt: skip
    return out


def test_a_session_replays_every_frame_in_order(session) -> None:
    with SessionStore.open(session) as st:
        src = SessionReplay(st)
        assert isinstance(src, FrameSource) and src.sensor_ids == ("k0", "k1", "k2", "k3")
        frames = list(src)
        for sid in src.sensor_ids:
            body = [f for f in frames if isinstance(f, BodyFrame) and f.sensor_id == sid]
            depth = [f for f in frames if isinstance(f, DepthFrame) and f.sensor_id == sid]
            o = st.observations(sid)
            assert [f.seq for f in body] == o.seq.tolist()  # capture order within a sensor
            np.testing.assert_array_equal(np.stack([f.joints_m for f in body]), o.joints_m)
            np.testing.assert_array_equal(np.stack([f.states for f in body]), o.states)
            assert len(depth) == st.depth_frame_count(sid) > 0
            assert src.intrinsics(sid) == st.sensor(sid).intrinsics
        # a sensor's depth and body frames in capture order although their stamps are on two
        # clocks (host for body frames, device for depth): each depth frame comes before the
        # body frames captured after it (their device times are on the same clock)
        order = {id(f): k for k, f in enumerate(frames)}
        for d in depth:
            later = [order[id(b)] for b in body if b.t_device_s > d.t_device_s + 0.05]
            assert not later or order[id(d)] < min(later)
    # across sensors: arrival order on the clients' clocks (a depth frame: its device time plus
    # the sensor's device -> host offset seen in its body frames)
    offset = {}
    with SessionStore.open(session) as st:
        for sid in src.sensor_ids:
            o = st.observations(sid)
            offset[sid] = float(np.median(o.t_host_s - o.t_device_s))
    keys = [f.t_host_s if isinstance(f, BodyFrame) else f.t_device_s + offset[f.sensor_id]
            for f in frames]  # fmt: skip
    assert keys == sorted(keys)
    assert max(abs(v) for v in offset.values()) > 1.0  # the two clocks are far apart here


def test_one_sensor_of_a_session_and_bad_names(session) -> None:
    src = open_source(f"sim:{session}#k2")
    assert src.sensor_ids == ("k2",)
    assert {f.sensor_id for f in src} == {"k2"}
    with pytest.raises(InputError, match="no sensor k9"), SessionStore.open(session) as st:
        SessionReplay(st, ["k9"])
    with pytest.raises(InputError, match="unknown kind 'usb'"):
        open_source("usb:/dev/video0")
    with pytest.raises(InputError, match=r"expected sim:SESSION\.sqlite#SENSOR_ID"):
        open_source("sim:")


def test_a_real_multitrack_log_replays_as_one_sensor(shared_data) -> None:
    from kinefuse.formats.kinect_multitrack import read_kinect_multitrack

    path = next((shared_data / "kinect" / "kinect_multitrack").glob("Study_4_Kinect_0_*.csv"))
    rec = read_kinect_multitrack(path)
    second = rec.streams[1]
    src = open_source(f"multitrack:{path}#{second.sensor_id}")
    frames = list(src)
    assert len(frames) == second.n_frames and src.sensor_ids == (second.sensor_id,)
    t_host = np.array([f.t_host_s for f in frames])
    assert (np.diff(t_host) >= 0).all()  # arrival order
    assert sorted(f.t_device_s for f in frames) == sorted(second.t_sensor_s.tolist())
    states = np.stack([f.states for f in frames])
    present = np.isfinite(np.stack([f.joints_m for f in frames])).all(-1)
    assert (states[present] == TrackingState.TRACKED).all()
    assert (states[~present] == TrackingState.NOT_TRACKED).all()
    with pytest.raises(InputError, match="no Kinect_Id"):
        MultitrackReplay(path, "10.0.0.99")


def test_the_kinect2_tracking_walk(shared_data, tmp_path) -> None:
    path = shared_data / "kinect" / "kinect2_tracking" / "walker.json"
    frames = list(Kinect2TrackingReplay(path))
    raw = json.loads(path.read_text())["bodyFrame"]
    assert len(frames) == len(raw) == 330
    # frame 0, by hand: the tracked body's spine base, Kinect camera space -> x right, y down
    body = next(b for b in raw[0]["bodies"] if b["tracked"])
    j0 = next(j for j in body["joints"] if j["jointType"] == 0)
    np.testing.assert_allclose(frames[0].joints_m[0],
                               [-j0["cameraX"], -j0["cameraY"], j0["cameraZ"]])  # fmt: skip
    assert frames[10].t_device_s == pytest.approx(10 / 30)
    inferred = np.stack([f.states for f in frames]) == TrackingState.INFERRED
    assert inferred.any()  # the real walk has inferred joints, kept as such
    bad = tmp_path / "x.json"
    bad.write_text('{"frames": []}')
    with pytest.raises(InputError, match="not a kinect2-tracking JSON"):
        Kinect2TrackingReplay(bad)


def test_a_simulated_sensor_runs_live_with_the_batch_simulators_numbers(
    session, shared_data, monkeypatch
) -> None:
    """``simlive:`` generates one sensor's frames as they are asked for; they are the frames the
    batch simulator stored for the same clip, rig and seed (the fixture's session: seed 0, 1 s
    of calibration at 5 Hz depth, 1 s of motion), bit for bit."""
    from kinefuse.sim.lab import SensorSimulation

    clip = shared_data / "motion" / "cmu" / "02_walk_a.amc"
    spec = f"simlive:{clip}#k1?seed=0&calibration=1&seconds=1&depth_rate=5"
    src = open_source(spec)
    assert isinstance(src, FrameSource) and src.sensor_ids == ("k1",)
    with SessionStore.open(session) as st:
        stored = list(SessionReplay(st, ["k1"]))
        probes = st.clock_probes("k1")
        intr = st.sensor("k1").intrinsics
    np.testing.assert_array_equal(src.probes, probes)
    assert src.intrinsics("k1") == intr
    # lazy: the first depth frame comes before the motion phase is drawn
    calls = []
    real_body = SensorSimulation.body
    monkeypatch.setattr(SensorSimulation, "body", lambda self: calls.append(1) or real_body(self))
    it = iter(src)
    first = next(it)
    assert isinstance(first, DepthFrame) and calls == []
    live = [first, *it]
    assert calls == [1]
    # the store merges a sensor's depth and body frames by arrival; the live sensor delivers
    # its calibration phase first, then its bodies: compare each kind in order
    for kind in (DepthFrame, BodyFrame):
        a = [f for f in stored if isinstance(f, kind)]
        b = [f for f in live if isinstance(f, kind)]
        assert len(a) == len(b) > 0
        for x, y in zip(a, b, strict=True):
            assert (x.seq, x.t_device_s) == (y.seq, y.t_device_s)
            if kind is BodyFrame:
                assert x.t_host_s == y.t_host_s
                np.testing.assert_array_equal(x.joints_m, y.joints_m)
                np.testing.assert_array_equal(x.states, y.states)
            else:
                np.testing.assert_array_equal(x.depth_mm, y.depth_mm)
    with pytest.raises(InputError, match="unknown option"):
        open_source(f"simlive:{clip}#k1?sead=3")
    with pytest.raises(InputError, match="name the sensor"):
        open_source(f"simlive:{clip}")
    with pytest.raises(InputError, match="no sensor 'k9'"):
        open_source(f"simlive:{clip}#k9?seconds=1")

"""Live calibration on the server (pure state): register, add a sensor later, end rules (issue 11).

Synthetic wand sightings with known truth (:mod:`kinefuse.capture.calibration.synthetic`), as the
clients would send them; no sockets here (tests/test_server.py runs the whole flow).
"""

from __future__ import annotations

import numpy as np
import pytest

from kinefuse.capture.calibration.synthetic import make_rig, simulate_sightings, wand_waving
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.geometry.transforms import invert_transform
from kinefuse.errors import CalibrationError
from kinefuse.live.server.live_calibration import LiveCalibration, LiveCalibrationOptions

IDS = ("a", "b", "c", "d")


@pytest.fixture(scope="module")
def wand():
    rng = np.random.default_rng(7)
    poses = make_rig(4, rng)
    t, p = wand_waving(20.0, rng)
    sights = simulate_sightings(poses, Intrinsics(), t, p, rng, sensor_ids=IDS)
    return dict(zip(IDS, poses, strict=True)), sights


def feed(cal: LiveCalibration, sights, ids) -> None:
    for sid in ids:
        s = sights[sid]
        for t, c, q in zip(s.t_server_s, s.centre_sensor_m, s.quality, strict=True):
            cal.add_sighting(sid, float(t), c, float(q))


def relative(poses, i, j):
    return invert_transform(poses[i]) @ poses[j]


def test_register_then_add_a_sensor_without_redoing_the_others(wand) -> None:
    truth, sights = wand
    cal = LiveCalibration(LiveCalibrationOptions())
    intr = {s: Intrinsics() for s in IDS}
    cal.start(0.0, ["a", "b", "c"])
    assert cal.targets == ("a", "b", "c")
    feed(cal, sights, ["a", "b", "c"])
    out = cal.solve(intr, {})
    assert out.ok and out.grade.grade == "good", out.grade.reasons
    first = {s: p.copy() for s, p in cal.poses.items()}
    assert set(first) == {"a", "b", "c"}
    for i, j in (("a", "b"), ("a", "c")):  # no floors: a world pinned to one sensor
        err = relative(first, i, j) - relative(truth, i, j)
        assert np.abs(err[:3, 3]).max() < 0.01  # 1 cm
    # "d" joins later: only it is registered, against the wand track the others see
    cal.start(30.0, ["a", "b", "c", "d"])
    assert cal.targets == ("d",)
    feed(cal, sights, IDS)
    out2 = cal.solve(intr, {})
    assert out2.ok, out2.message
    assert out2.targets == ("d",) and set(cal.poses) == set(IDS)
    for s in ("a", "b", "c"):
        np.testing.assert_array_equal(cal.poses[s], first[s])  # kept as they were
    err = relative(cal.poses, "a", "d") - relative(truth, "a", "d")
    assert np.abs(err[:3, 3]).max() < 0.01  # 1 cm
    assert np.abs(err[:3, :3]).max() < 0.01  # about 0.5 deg
    assert "registered against a, b, c" in out2.calibration.world


def test_a_failed_calibration_keeps_the_poses(wand) -> None:
    _truth, sights = wand
    cal = LiveCalibration()
    intr = {s: Intrinsics() for s in IDS}
    cal.start(0.0, list(IDS))
    feed(cal, sights, IDS)
    assert cal.solve(intr, {}).ok
    before = {s: p.copy() for s, p in cal.poses.items()}
    cal.start(40.0, list(IDS), sensor_ids=["b"])  # redo b, but nothing is waved
    out = cal.solve(intr, {})
    assert not out.ok and out.grade.grade == "failed"
    assert "saw the wand" in out.message or "sightings" in out.message
    assert cal.state == "calibrated"
    for s in IDS:
        np.testing.assert_array_equal(cal.poses[s], before[s])


def test_when_a_calibration_ends(wand) -> None:
    _truth, sights = wand
    cal = LiveCalibration(LiveCalibrationOptions(quiet_s=1.0, min_sightings=30, max_s=60.0))
    assert cal.should_stop(0.0) is None  # not collecting
    cal.start(0.0, ["a", "b"])
    assert cal.should_stop(5.0) is None  # nothing seen yet: wait for the wand
    feed(cal, sights, ["a", "b"])
    t_last = max(float(sights[s].t_server_s[-1]) for s in ("a", "b"))
    assert cal.should_stop(t_last + 0.5) is None
    assert "put away" in (cal.should_stop(t_last + 1.1) or "")
    assert "longest" in (cal.should_stop(61.0) or "")
    cal.start(100.0, ["a"], seconds=2.0)  # asked for 2 s: that rule alone (before max_s)
    assert cal.should_stop(101.0) is None and "2 s" in (cal.should_stop(102.0) or "")
    with pytest.raises(CalibrationError, match="unknown calibration method"):
        cal.start(0.0, ["a"], method="magic")
    cal.abort()
    assert cal.state != "collecting"


def test_the_scale_is_fixed_from_the_protocol_only_when_its_holds_were_seen(wand) -> None:
    from kinefuse.capture.calibration.floor import FloorPlane
    from kinefuse.capture.calibration.register import Sightings

    truth, sights = wand
    floors = {}
    for sid, p in truth.items():  # the floor z = 0 seen from each sensor
        n = p[:3, :3].T @ np.array([0.0, 0.0, 1.0])
        floors[sid] = FloorPlane(n, float(p[2, 3]), 1000, 0.002)

    def run(drop_s: float) -> str:
        cal = LiveCalibration(LiveCalibrationOptions(axis_length_m=1.0))
        for sid, fl in floors.items():
            cal.add_floor(sid, fl)
        cal.start(0.0, list(IDS))
        cut = {
            s: Sightings(
                *(a[v.t_server_s >= drop_s] for a in (v.t_server_s, v.centre_sensor_m, v.quality))
            )
            for s, v in sights.items()
        }
        feed(cal, cut, IDS)
        out = cal.solve({s: Intrinsics() for s in IDS}, {})
        assert out.ok, out.message
        return out.calibration.world

    assert "scaled by" in run(0.0)  # both holds seen: the known 1 m move fixes the scale
    # the start (the first hold) missed: the holds found are others, their move is no 1 m
    assert "scale NOT corrected" in run(3.0)

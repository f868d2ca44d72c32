"""A simulated sensor delivers the depth of the simulated body (its motion phase rendered),
on a random stream of its own: everything the simulator gave before is unchanged."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kinefuse.core.skeleton import CAPSULE_RADII_M, JOINT_INDEX
from kinefuse.formats.motion.load import load_motion
from kinefuse.sim.lab import LabConfig, SensorSimulation
from kinefuse.sim.rig import default_rig, place_actor


@pytest.fixture(scope="module")
def setup(shared_data: Path):  # type: ignore[no-untyped-def]
    motion = load_motion(shared_data / "motion" / "cmu" / "131_01_scaled_metres.bvh")
    rig = default_rig(3)
    return place_actor(motion, rig), rig, LabConfig(seed=5, calibration_s=1.0, motion_s=2.0)


def test_body_depth_shows_the_body_where_the_true_joints_are(setup) -> None:  # type: ignore[no-untyped-def]
    motion, rig, cfg = setup
    sim = SensorSimulation(motion, rig, rig.sensors[0].id, cfg)
    frames = list(sim.body_depth_frames(every=15))
    assert 3 <= len(frames) <= 6  # 2 s at 30 Hz, every 15th
    intr = sim.intrinsics
    for f in frames:
        assert f.depth_mm.shape == (intr.height, intr.width) and f.depth_mm.dtype == np.uint16
        head = f.joints_sensor_m[JOINT_INDEX["Head"]]
        u, v = np.rint(intr.project(head)).astype(int)
        seen = f.depth_mm[v - 1 : v + 2, u - 1 : u + 2].astype(float) * 1e-3
        # the head's front surface: its centre's depth less the head's radius, give or take the
        # time-of-flight error model (noise and a systematic offset of a few cm at 4 m)
        surface = head[2] - CAPSULE_RADII_M["Head"]
        assert np.median(seen[seen > 0]) == pytest.approx(surface, abs=0.05)
    assert [f.seq for f in frames] == sorted(f.seq for f in frames)


def test_the_sessions_other_outputs_do_not_change(setup) -> None:  # type: ignore[no-untyped-def]
    motion, rig, cfg = setup
    plain = SensorSimulation(motion, rig, rig.sensors[1].id, cfg)
    rendered = SensorSimulation(motion, rig, rig.sensors[1].id, cfg)
    next(iter(rendered.body_depth_frames()))  # draw from the new stream first
    for a, b in zip(plain.depth_frames(), rendered.depth_frames(), strict=True):
        assert a[:3] == b[:3] and np.array_equal(a[3], b[3])
    cap_a, out_a, truth_a = plain.body()
    cap_b, out_b, truth_b = rendered.body()
    assert np.array_equal(cap_a.t_sensor_s, cap_b.t_sensor_s)
    assert np.array_equal(truth_a, truth_b)
    np.testing.assert_array_equal(out_a.joints_sensor, out_b.joints_sensor)
    np.testing.assert_array_equal(plain.probes, rendered.probes)

"""The server's fusion loop: which observations a frame uses, when, and what it publishes."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest

from kinefuse.capture.fusion.status import FusionStatus
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.skeleton import N_JOINTS, standing_pose
from kinefuse.live.bus import FusedFrame, Publisher
from kinefuse.live.server.fusion_loop import FrameFusion, FusionLoop
from kinefuse.live.server.sensor_state import Observation, SensorState, sanitize_joints


def rig(n: int = 4) -> dict[str, np.ndarray]:
    """Sensors on a circle of 3 m at heights 0.8-1.6 m, looking at the origin's vertical."""
    out = {}
    for i in range(n):
        a = 2 * np.pi * i / n
        c = np.array([3 * np.cos(a), 3 * np.sin(a), 0.8 + 0.8 * (i % 2)])
        z = -c * np.array([1, 1, 0]) / np.linalg.norm(c[:2])  # optical axis, level
        y = np.array([0.0, 0.0, -1.0])  # image down
        x = np.cross(y, z)
        p = np.eye(4)
        p[:3, :3] = np.stack([x, y, z], axis=1)
        p[:3, 3] = c
        out[f"s{i}"] = p
    return out


def observe(pose: np.ndarray, world: np.ndarray, t: float, seq: int) -> Observation:
    j = (world - pose[:3, 3]) @ pose[:3, :3]
    return Observation(seq, t, t + 0.06, j, np.full(N_JOINTS, 2, np.int8), None, None)


@pytest.mark.parametrize("method", ["best-live", "paper"])
def test_frame_fusion_recovers_a_skeleton_seen_exactly(method) -> None:
    poses = rig()
    world = standing_pose() + np.array([0.2, -0.1, 0.0])
    ff = FrameFusion(method)
    ff.set_poses(poses)
    for k in range(10):
        t = k / 30
        for sid, p in poses.items():
            ff.push(sid, observe(p, world, t - 0.004, k))
        pos, _var, status = ff.fuse(t)
    assert np.isfinite(pos).all() and (status != FusionStatus.NO_DATA).all()
    np.testing.assert_allclose(pos, world, atol=0.01)  # 1 cm
    raw = ff.raw_world()
    np.testing.assert_allclose(raw["s0"], world, atol=1e-9)


def test_the_loop_uses_what_was_captured_up_to_its_horizon_and_publishes() -> None:
    poses = rig(2)
    world = standing_pose()
    now = [0.0]
    clients = {s: SensorState(s, "", Intrinsics()) for s in poses}
    pub = Publisher()
    sub = pub.subscribe(None)
    loop = FusionLoop(FrameFusion("best-live"), clients, pub, lambda: now[0], wait_s=0.01)
    assert loop.delay_s == pytest.approx(1 / 30 + 0.060 + 0.01)
    # before any pose: nothing is fused or published
    assert asyncio.run(loop.step(0)) is None
    loop.set_poses(poses)  # applied at the next frame
    for sid, p in poses.items():
        for k, t in enumerate((0.95, 1.00, 1.05, 1.20)):  # beyond frame 30's horizon: the last 2
            clients[sid].enqueue(observe(p, world, t, k), t + 0.07)
    now[0] = 1.2
    fr = asyncio.run(loop.step(30))  # T = 1.0 s, horizon 1.0 + 1/30
    assert isinstance(fr, FusedFrame) and fr.seq == 30 and fr.t_server_s == pytest.approx(1.0)
    np.testing.assert_allclose(fr.positions_m, world, atol=0.01)
    # the newest observation used (captured 1.00 s) reached its host at 1.06: latency = now - that
    assert fr.latency_s == pytest.approx(1.2 - 1.06, abs=1e-6)
    assert [len(q) for q in loop._pending.values()] == [2, 2]  # 1.05 and 1.20 s wait their frames
    now[0] = 1.4
    assert asyncio.run(loop.step(36)).latency_s == pytest.approx(1.4 - 1.26)  # T = 1.2 s
    now[0] = 2.0
    late = asyncio.run(loop.step(50))  # T = 1.67 s: nothing new for 0.47 s, a prediction
    assert np.isnan(late.latency_s)
    items = []

    async def take() -> None:
        pub.close()
        async for it in sub:
            items.append(it)

    asyncio.run(take())
    assert [it.seq for it in items] == [30, 36, 50]


def test_sanitize_joints_makes_nan_and_not_tracked_agree() -> None:
    j = np.ones((N_JOINTS, 3))
    st = np.full(N_JOINTS, 2, np.int8)
    j[3, 1] = np.nan  # a position without a value: not tracked
    st[5] = 0  # not tracked: no position
    jj, ss = sanitize_joints(j, st)
    assert ss[3] == 0 and np.isnan(jj[3]).all()
    assert np.isnan(jj[5]).all() and ss[5] == 0
    assert (ss[[0, 1, 2, 4]] == 2).all() and np.isfinite(jj[[0, 1, 2, 4]]).all()

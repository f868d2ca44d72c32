"""A hand-made scene of two real people for the people tests: CMU 131_01 as the subject, CMU
02_walk_a as a bystander crossing close in front of them, seen by three sensors of the default
rig, with tracking ids that change as a Kinect's do."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kinefuse.biomech.retarget import place
from kinefuse.core.frames.observations import BodyFrames
from kinefuse.core.skeleton import JOINT_INDEX, TrackingState
from kinefuse.formats.motion.load import load_motion
from kinefuse.sim.rig import default_rig

RATE = 30.0


def _at_rate(positions: np.ndarray, rate_hz: float) -> np.ndarray:
    k = np.round(np.arange(0, positions.shape[0], rate_hz / RATE)).astype(int)
    return positions[k[k < positions.shape[0]]]


def two_people(shared_data: Path) -> dict:
    """The subject standing, walking, stopping near the centre; a bystander crossing their path
    0.35 m in front of them at 2.6 s; every sensor's all-bodies stream and the truth of every row.

    Sensor k0 loses the subject from 4.0 to 4.8 s and finds them under a new tracking id; every
    sensor loses the subject from 6.0 to 7.2 s (out of view) and finds them under new ids. The
    bodies are listed in an order that flips every second (the "first body" changes hands)."""
    cmu = shared_data / "motion" / "cmu"
    subj = place(
        load_motion(cmu / "131_01_scaled_metres.bvh"), offset_m=(0.0, 1.0), heading_deg=-90
    )
    a = _at_rate(subj.positions, subj.rate_hz)[: int(8 * RATE)]
    by = load_motion(cmu / "02_walk_a.amc")
    b0 = _at_rate(place(by, offset_m=(0.0, 0.0), heading_deg=0).positions, by.rate_hz)
    t_cross = int(2.6 * RATE)
    mid = b0.shape[0] // 2
    target = a[t_cross, JOINT_INDEX["SpineBase"], :2] + np.array([0.0, -0.35])
    shift = target - b0[mid, JOINT_INDEX["SpineBase"], :2]
    b = b0.copy()
    b[..., :2] += shift
    start = t_cross - mid  # the bystander's frame 0 on the session's frame axis
    n = a.shape[0]
    rig = default_rig(3, 3.0)
    poses = {s.id: s.sensor2world for s in rig.sensors}
    rng = np.random.default_rng(46)
    streams, truth = {}, {}
    for i, s in enumerate(rig.sensors):
        pose = s.sensor2world
        rows: list[tuple[int, int, np.ndarray, int]] = []  # seq, body id, joints, person
        for k in range(n):
            t = k / RATE
            bodies = []
            lost_all = 6.0 <= t < 7.2
            lost_here = s.id == "k0" and 4.0 <= t < 4.8
            if not (lost_all or lost_here):
                sid = 10 * i + 1 + (1 if t >= 4.8 and s.id == "k0" else 0) + (2 if t >= 7.2 else 0)
                bodies.append((sid, a[k], 0))
            kb = k - start
            if 0 <= kb < b.shape[0]:
                bodies.append((10 * i + 5, b[kb], 1))
            if int(t) % 2:
                bodies.reverse()
            for bid, p, who in bodies:
                j = (p - pose[:3, 3]) @ pose[:3, :3]
                j = j + rng.normal(0.0, 0.01, j.shape)
                rows.append((k, bid, j, who))
        seq = np.array([r[0] for r in rows])
        joints = np.array([r[2] for r in rows])
        streams[s.id] = BodyFrames(
            sensor_id=s.id,
            seq=seq,
            t_device_s=seq / RATE,
            t_host_s=np.full(seq.size, np.nan),
            joints_m=joints,
            states=np.full(joints.shape[:2], TrackingState.TRACKED, dtype=np.int8),
            t_server_s=seq / RATE + 0.004 * i,
            body_id=np.array([r[1] for r in rows]),
        )
        truth[s.id] = np.array([r[3] for r in rows])
    return {"streams": streams, "truth": truth, "poses": poses, "a": a, "b": b, "start": start}


def observation(lab: dict, sid: str, k: int) -> object | None:
    """The server's :class:`~kinefuse.live.server.sensor_state.Observation` of sensor ``sid`` at
    instant ``k`` (every body in ``bodies``, the first listed first), or None when the sensor
    saw nobody then."""
    from kinefuse.live.server.sensor_state import Observation

    s = lab["streams"][sid]
    rows = np.flatnonzero(s.seq == k)
    if rows.size == 0:
        return None
    r0 = rows[0]
    t = float(s.t_server_s[r0])
    return Observation(k, t, t + 0.06, s.joints_m[r0], s.states[r0], None, None,
                       tuple(s.frame(r) for r in rows))  # fmt: skip

"""Consistency figures of a recording of real sensors, from the recording alone (no truth).

The recording here is made by hand from a real two-Kinect KinectMultiTrack log, frame by frame as
a client sends it (every logged row; device stamp = ``Skeleton_Time``, host stamp = the logged
receive time, clock probes of a host clock 40 s ahead of the server's), so the figures can be
held against what ``kinefuse realdata`` finds on the same file. The process-level run (two
``kinefuse sensor`` processes into ``kinefuse serve``) is in ``tests/test_live_faults.py``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.frames.observations import BodyFrame
from kinefuse.errors import InputError
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.lab.live_consistency import recording_consistency
from kinefuse.pipeline.frame_sources import MultitrackReplay

HOST_AHEAD_S = 40.0  # the pretend client PCs' clocks run 40 s ahead of the server's


def _log(shared_data: Path, pattern: str) -> Path:
    files = sorted((shared_data / "kinect" / "kinect_multitrack").glob(pattern))
    if not files:
        pytest.skip(f"no KinectMultiTrack log {pattern} in {shared_data}")
    return files[0]


def _record(path: Path, out: Path) -> list[str]:
    from kinefuse.formats.kinect_multitrack import read_kinect_multitrack

    ids = [s.sensor_id for s in read_kinect_multitrack(path).streams]
    with SessionStore.create(out) as st:
        for sid in ids:
            frames = [f for f in MultitrackReplay(path, sid) if isinstance(f, BodyFrame)]
            st.add_sensor(sid, sid, Intrinsics())
            host = np.array([f.t_host_s for f in frames]) + HOST_AHEAD_S
            st.append_observations(
                sid,
                [f.seq for f in frames],
                [f.t_device_s for f in frames],
                np.stack([f.joints_m for f in frames]),
                np.stack([f.states for f in frames]),
                t_receive_host_s=host,
            )
            t1 = np.arange(0.0, host.max() - HOST_AHEAD_S, 1.0)
            st.append_clock_probes(
                sid, t1, t1 + 1e-3 + HOST_AHEAD_S, t1 + 1.1e-3 + HOST_AHEAD_S, t1 + 2.1e-3
            )
        st.mark_complete()
    return ids


def test_consistency_of_a_recorded_real_log_matches_realdata(shared_data, tmp_path) -> None:
    log = _log(shared_data, "Study_4_Kinect_1_*.csv")  # side sensor at 45 degrees
    rec = tmp_path / "rec.sqlite"
    ids = _record(log, rec)
    r = recording_consistency(rec)
    assert r["registration"]["kind"] == "body"
    other = r["sensors"][1]
    reg = r["registration"]["by_sensor"][other]
    # realdata on this file (docs/real_data.md): a correction of 11.3 deg, trunk median 107 ->
    # 25 mm; the recording's own clocks (a straight line through the stamps, not realdata's
    # lower envelope and motion latency) give nearly the same (2 deg, 15 mm: timing differences)
    assert abs(reg["correction_deg"] - 11.3) < 2.0
    assert reg["trunk_median_after_m"] < 0.040 < reg["trunk_median_before_m"]
    pair = f"{r['sensors'][0]}|{other}"
    med, p95 = r["disagreement"][pair]["all"]
    assert 0.02 < med < 0.12 and med < p95  # a few cm, as real sensors disagree
    for sid in ids:
        assert 0.005 < r["to_fused"][sid]["all"][0] < med  # each closer to the fused skeleton
        assert r["clocks"][sid]["frames"] < r["clocks"][sid]["frames_received"]  # duplicates
    assert r["fused_finite"] > 0.8 * r["frames_with_body"]
    assert r["duration_s"] > 50


def test_consistency_needs_two_sensors_with_body_frames(tmp_path) -> None:
    rec = tmp_path / "one.sqlite"
    with SessionStore.create(rec) as st:
        st.add_sensor("a", "A", Intrinsics())
        st.add_sensor("b", "B", Intrinsics())
        st.mark_complete()
    with pytest.raises(InputError, match="needs two sensors with body frames"):
        recording_consistency(rec)

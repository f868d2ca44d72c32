"""The real-log readers keep every body they are given: a KinectMultiTrack log's persons, the
kinect2-tracking JSON's tracked bodies; the real one-person files read as they always did."""

from __future__ import annotations

import copy
import csv
import json

import numpy as np

from kinefuse.formats.kinect_multitrack import read_kinect_multitrack, unique_frames
from kinefuse.pipeline.frame_sources import Kinect2TrackingReplay, MultitrackReplay


def _multitrack(shared_data):
    return next((shared_data / "kinect" / "kinect_multitrack").glob("Study_4_Kinect_0_*.csv"))


def test_a_one_person_multitrack_log_reads_as_before(shared_data) -> None:
    rec = read_kinect_multitrack(_multitrack(shared_data))
    for s in rec.streams:
        u = unique_frames(s)
        assert u.bodies is None and u.every_body is u.frames and not u.frames.multi
        assert (u.frames.body_id == 0).all()
        # the distinct frames: one per capture time, the first receipt of each, capture order
        ticks = np.round(s.t_sensor_s * 1e7).astype(np.int64)
        assert u.n_frames == np.unique(ticks).size
        assert (np.diff(np.round(u.t_sensor_s * 1e7)) > 0).all()
        assert u.n_duplicates == s.n_rows - u.n_frames


def test_a_second_person_in_a_multitrack_log_is_a_second_body(shared_data, tmp_path) -> None:
    """The real log with a second person (Person_Id 1) beside the first in each of one sensor's
    rows: the reader keeps both, a frame's bodies under one seq; the first body unchanged."""
    path = _multitrack(shared_data)
    with path.open(newline="", encoding="utf-8-sig") as fh:
        rows = list(csv.reader(fh))
    header = [c.strip() for c in rows[0]]
    ip, ik = header.index("Person_Id"), header.index("Kinect_Id")
    ix = [i for i, c in enumerate(header) if c.endswith("_X")]
    sensor = rows[1][ik].strip()
    out = [rows[0]]
    for row in rows[1:]:
        out.append(row)
        if row and row[ik].strip() == sensor:
            twin = list(row)
            twin[ip] = "1"
            for i in ix:
                twin[i] = repr(float(row[i]) + 1.0)  # 1 m to the side
            out.append(twin)
    two = tmp_path / "two.csv"
    with two.open("w", newline="") as fh:
        csv.writer(fh).writerows(out)
    before = unique_frames(read_kinect_multitrack(path).stream(sensor))
    after = unique_frames(read_kinect_multitrack(two).stream(sensor))
    np.testing.assert_array_equal(after.frames.joints_m, before.frames.joints_m)
    np.testing.assert_array_equal(after.frames.t_device_s, before.frames.t_device_s)
    every = after.every_body
    assert every.multi and every.n_frames == 2 * before.n_frames
    assert every.body_id.tolist() == [0, 1] * before.n_frames
    np.testing.assert_array_equal(every.first_bodies().joints_m, before.frames.joints_m)
    second = every.take(every.body_id == 1)
    np.testing.assert_array_equal(second.seq, after.frames.seq)  # its frame's seq
    np.testing.assert_allclose(second.joints_m[..., 0], before.frames.joints_m[..., 0] - 1.0)
    # the replay source makes the two rows of a capture one frame with two bodies
    replay = list(MultitrackReplay(two, sensor))
    assert len(replay) == len(list(MultitrackReplay(path, sensor)))
    assert all([b.body_id for b in f.bodies()] == [0, 1] for f in replay)


def test_every_tracked_body_of_the_kinect2_tracking_json(shared_data, tmp_path) -> None:
    path = shared_data / "kinect" / "kinect2_tracking" / "walker.json"
    one = list(Kinect2TrackingReplay(path))
    assert all(f.others == () for f in one)  # the walk has one person
    data = json.loads(path.read_text())
    ids = {b["trackingId"] for f in data["bodyFrame"] for b in f["bodies"] if b.get("tracked")}
    assert {f.body_id for f in one if f.states.any()} == {int(i) for i in ids}
    # a second tracked body (another slot, its own id), 1 m further away, in every other frame
    for k, f in enumerate(data["bodyFrame"]):
        tracked = next((b for b in f["bodies"] if b.get("tracked")), None)
        if tracked is None or k % 2:
            continue
        other = copy.deepcopy(tracked)
        other["trackingId"], other["bodyIndex"] = "72057594037900001", 5
        for j in other["joints"]:
            j["cameraZ"] += 1.0
        f["bodies"].append(other)
    two = tmp_path / "two.json"
    two.write_text(json.dumps(data))
    frames = list(Kinect2TrackingReplay(two))
    assert len(frames) == len(one)
    for k, (a, b) in enumerate(zip(one, frames, strict=True)):
        np.testing.assert_array_equal(a.joints_m, b.joints_m)  # the first body as before
        np.testing.assert_array_equal(a.states, b.states)
        if a.states.any() and k % 2 == 0:
            (o,) = b.others
            assert o.body_id == 72057594037900001 and o.seq == b.seq
            np.testing.assert_allclose(o.joints_m[..., 2], a.joints_m[..., 2] + 1.0)
        else:
            assert b.others == ()

"""Calibration from the person: the registration and its grade on real two-Kinect logs, and the
live server's person path as a state machine fed the logs' frames (no sockets; the process-level
run is in ``tests/test_live_person.py``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.workflows.realdata import fuse_multitrack
from kinefuse.capture.calibration.body import calibrate_from_body
from kinefuse.capture.calibration.grade import Grade
from kinefuse.capture.sync.envelope import fit_clock_lower_envelope
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.geometry.rotations import rotation_vector_deg
from kinefuse.core.geometry.transforms import invert_transform, make_transform
from kinefuse.formats.kinect_multitrack import read_kinect_multitrack, unique_frames
from kinefuse.live.server.live_calibration import LiveCalibration
from kinefuse.live.server.person import WALK, PersonCalibration, PersonOptions, solve_person

Tracks = dict[str, tuple[np.ndarray, np.ndarray]]


def _log(shared_data: Path, folder: str, pattern: str) -> Path:
    files = sorted((shared_data / "kinect" / folder).glob(pattern))
    if not files:
        pytest.skip(f"no KinectMultiTrack log {pattern} in {shared_data}/kinect/{folder}")
    return files[0]


def _tracks(path: Path) -> Tracks:
    """Each sensor's distinct frames at their capture times on the receiver's clock (the
    lower-envelope clock fit ``kinefuse realdata`` uses), from 0 s."""
    rec = read_kinect_multitrack(path)
    out = {}
    for s in rec.streams:
        f = unique_frames(s)
        t = fit_clock_lower_envelope(f.t_sensor_s, f.t_receive_s).affine.forward(f.t_sensor_s)
        out[s.sensor_id] = (t, f.joints_m)
    t0 = min(float(t[0]) for t, _ in out.values())
    return {k: (t - t0, p) for k, (t, p) in out.items()}


def _upto(tracks: Tracks, t_s: float) -> Tracks:
    return {k: (t[t < t_s], p[t < t_s]) for k, (t, p) in tracks.items()}


@pytest.fixture(scope="module")
def take45(shared_data) -> tuple[Path, Tracks]:
    path = _log(shared_data, "kinect_multitrack", "Study_4_Kinect_1_*.csv")  # side sensor at 45°
    return path, _tracks(path)


def test_a_person_standing_still_does_not_calibrate(take45) -> None:
    """The take's first 12 s: the person stands still. The two sensors' trunks agree, and the
    halves agree too (both halves are the same standing pose), but the rotation between the
    sensors is loose by degrees; only the spread of the path across the floor shows it."""
    _, tracks = take45
    cal = calibrate_from_body(_upto(tracks, 12.0))
    assert cal.grade == "failed", cal.reasons
    assert any("walk through the volume" in r and r.startswith("failed") for r in cal.reasons)
    (fit,) = cal.fits.values()
    assert fit.spread_m < 0.05 and fit.residual_m < 0.04


def test_a_whole_take_calibrates_good_and_as_realdata_registers_it(take45) -> None:
    path, tracks = take45
    cal = calibrate_from_body(tracks)
    assert cal.grade == "good", cal.reasons
    assert cal.floor is not None and cal.floor.n_samples > 100
    (other,) = (s for s in tracks if s != cal.reference)
    fit = cal.fits[other]
    assert fit.spread_m > 0.25 and fit.residual_m < 0.04 and fit.halves_m < 0.03
    # the world: z up from the reference's feet, the reference above the origin
    ref_pose = cal.sensor2world[cal.reference]
    assert np.allclose(ref_pose[:2, 3], 0.0) and 0.5 < ref_pose[2, 3] < 2.5
    # the two sensors' relative pose is realdata's re-registration (which also takes the
    # sensors' relative latency off: 1 deg and 3 cm apart at most)
    rep = fuse_multitrack(path).as_dict()
    corr = make_transform(
        _rotation(rep["registration"]["correction_rotvec_deg"]),
        np.array(rep["registration"]["correction_translation_m"]),
    )
    mine = invert_transform(ref_pose) @ cal.sensor2world[other]
    if rep["sensors"][0] != cal.reference:
        corr = invert_transform(corr)
    diff = invert_transform(corr) @ mine
    assert np.linalg.norm(rotation_vector_deg(diff[:3, :3])) < 1.0
    assert np.linalg.norm(diff[:3, 3]) < 0.03


def _rotation(rotvec_deg: list[float]) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(np.radians(rotvec_deg)).as_matrix()


def test_another_person_in_one_sensor_fails(take45, shared_data) -> None:
    """One sensor's frames replaced by another participant's, at the same times: the trunks
    fit no rigid pose (or not the same one on two halves), and the grade says failed."""
    _, tracks = take45
    other = _tracks(_log(shared_data, "kinect_multitrack", "Study_1_Kinect_2_*.csv"))
    ids = sorted(tracks)
    t, _ = tracks[ids[1]]
    t_o, p_o = next(iter(other.values()))
    n = min(len(t), len(t_o))
    mixed = {ids[0]: tracks[ids[0]], ids[1]: (t[:n], p_o[:n])}
    cal = calibrate_from_body(mixed)
    assert cal.grade == "failed", cal.reasons


def test_a_sensor_is_registered_against_a_fixed_one(take45) -> None:
    """With one sensor's pose known (a wand calibration), the other is registered onto it and
    the known pose stays as it is."""
    _, tracks = take45
    free = calibrate_from_body(tracks)
    ids = sorted(tracks)
    fixed_pose = make_transform(np.eye(3), np.array([1.0, 2.0, 3.0])) @ np.diag([1, -1, -1, 1.0])
    cal = calibrate_from_body(tracks, fixed={ids[0]: fixed_pose})
    assert cal.reference == ids[0] and cal.floor is None
    assert set(cal.sensor2world) == {ids[1]}  # the fixed pose is not re-registered
    rel_free = invert_transform(free.sensor2world[ids[0]]) @ free.sensor2world[ids[1]]
    assert np.allclose(cal.sensor2world[ids[1]], fixed_pose @ rel_free, atol=1e-9)


def test_sensors_that_never_see_the_person_together_are_not_registered(take45) -> None:
    _, tracks = take45
    ids = sorted(tracks)
    t, p = tracks[ids[1]]
    apart = {ids[0]: tracks[ids[0]], ids[1]: (t + 1000.0, p)}  # no common instant
    cal = calibrate_from_body(apart)
    assert cal.grade == "failed"
    assert ids[1] in cal.unregistered or ids[0] in cal.unregistered


# -- the live server's person path, fed the log's frames ----------------------------------------


Rows = list[tuple[float, str, float, np.ndarray]]


def _rows(path: Path) -> Rows:
    """Every logged row of both sensors as a client sends it: ``(receive time, sensor, device
    time, joints)`` in receive order, from 0 s (a row repeats a sensor's latest skeleton when
    the other sensor's frame triggered it, and rows come out of capture order)."""
    from kinefuse.core.frames.observations import BodyFrame
    from kinefuse.pipeline.frame_sources import MultitrackReplay

    rows = []
    for s in read_kinect_multitrack(path).streams:
        for f in MultitrackReplay(path, s.sensor_id):
            if isinstance(f, BodyFrame):
                rows.append((f.t_host_s, s.sensor_id, f.t_device_s, f.joints_m))
    rows.sort(key=lambda r: r[0])
    t0 = rows[0][0]
    return [(t - t0, sid, td, p) for t, sid, td, p in rows]


def _feed(p: PersonCalibration, rows: Rows, t_from: float, t_to: float) -> None:
    for t, sid, td, joints in rows:
        if t_from <= t < t_to:
            p.add_body(sid, td, t, joints)


@pytest.fixture(scope="module")
def rows45(take45) -> Rows:
    return _rows(take45[0])


def test_the_person_path_starts_without_a_wand_and_refines_until_good(take45, rows45) -> None:
    """Fed the log's rows as the clients send them (repeats, rows out of order, the receive
    times' jitter), on the receive clock."""
    _, tracks = take45
    ids = sorted(tracks)
    cal = LiveCalibration()
    p = PersonCalibration(PersonOptions(wand_wait_s=5.0, refine_s=5.0))
    intr = dict.fromkeys(ids, Intrinsics())
    serials = dict.fromkeys(ids, "")
    t = 0.0
    grades = []
    started = both = None
    track_from = None
    while t < 80.0 and p.grade != "good":
        _feed(p, rows45, t, t + 0.5)
        t += 0.5
        if len(p.tracking(t, ids)) < 2:
            both = None  # (the log has a gap between its first two scenarios)
        elif both is None:
            both = t
        p.say(t, ids, cal)
        if p.due(t, ids, cal):
            if started is None:
                started, track_from = t, both
            job = p.begin(t, cal, intr, serials)
            out = solve_person(job)
            p.finish(out, cal)
            grades.append(out.grade.grade)
    # the path starts 5 s after both sensors track the person (their trunks seen)
    assert track_from is not None and started is not None
    assert track_from + 5.0 <= started <= track_from + 5.5
    assert grades[0] == "failed" and grades[-1] == "good", grades  # standing, then walking
    assert cal.calibration is not None and cal.calibration.method == "body"
    assert set(cal.poses) == set(ids) and cal.grade == "good"
    assert p.message == "calibrated from the person: good"
    assert not p.due(t + 10.0, ids, cal)  # good: it stops
    # the rows' repeats and receive-time jitter cost nothing: the same relative pose as from the
    # distinct frames at realdata's capture times up to then
    clean = calibrate_from_body(_upto(tracks, t)).sensor2world

    def rel(poses: dict[str, np.ndarray]) -> np.ndarray:
        return invert_transform(poses[ids[0]]) @ poses[ids[1]]

    d = invert_transform(rel(clean)) @ rel(cal.poses)
    assert np.linalg.norm(rotation_vector_deg(d[:3, :3])) < 0.5 and np.linalg.norm(d[:3, 3]) < 0.02


def test_a_wand_sighting_keeps_the_person_path_from_starting(take45, rows45) -> None:
    _, tracks = take45
    ids = sorted(tracks)
    cal = LiveCalibration()
    p = PersonCalibration()
    _feed(p, rows45, 0.0, 28.0)
    cal.add_sighting(ids[0], 17.0, np.zeros(3), 1.0)  # a wand seen 3 s ago
    assert not p.due(20.0, ids, cal)
    assert p.due(22.5, ids, cal) is False  # 5.5 s since the wand: the wait starts now
    assert p.due(27.6, ids, cal)


def test_no_pose_is_said_every_few_seconds_with_the_reason(take45, rows45) -> None:
    _, tracks = take45
    ids = sorted(tracks)
    cal = LiveCalibration()
    p = PersonCalibration(PersonOptions(say_s=5.0))
    said = [(t, p.say(t, [ids[0]], cal)) for t in np.arange(0.0, 12.0, 0.5)]
    texts = [(t, s) for t, s in said if s is not None]
    assert [t for t, _ in texts] == [0.0, 5.0, 10.0]
    assert all(f"only sensor {ids[0]} is connected" in s for _, s in texts)
    assert p.message is not None and p.message.startswith("no pose yet")
    assert "no sensor is connected" in (p.say(20.0, [], cal) or "")
    _feed(p, rows45, 25.0, 28.0)  # both connected and tracking: waiting for a wand
    assert "calibrating from the person in" in (p.say(28.0, ids, cal) or "")
    assert p.say(28.5, ids, cal) is None  # not again within say_s
    assert WALK.startswith("calibrating from the person")


def test_a_sensor_that_joins_later_is_registered_onto_the_poses_in_force(take45, rows45) -> None:
    """After a good calibration a third sensor joins; the first two keep their poses and the new
    one is registered onto them. It is the second sensor's stream seen from a frame moved by a
    known rigid transform (30 deg, 0.5 m), so its pose must come out as that sensor's pose times
    the inverse."""
    from kinefuse.core.geometry.rotations import rot_z

    _, tracks = take45
    ids = sorted(tracks)
    cal = LiveCalibration()
    p = PersonCalibration()
    intr = dict.fromkeys([*ids, "k2"], Intrinsics())
    serials = dict.fromkeys([*ids, "k2"], "")
    moved = make_transform(rot_z(np.radians(30.0)), np.array([0.5, -0.2, 0.1]))
    t = 0.0
    while p.grade != "good" and t < 80.0:
        _feed(p, rows45, t, t + 0.5)
        t += 0.5
        if p.due(t, ids, cal):
            p.finish(solve_person(p.begin(t, cal, intr, serials)), cal)
    assert p.grade == "good"
    before = {s: cal.poses[s].copy() for s in ids}
    _feed(p, rows45, t, t + 5.0)
    for tr, sid, td, joints in rows45:  # the new sensor's frames, from the start
        if sid == ids[1] and tr < t + 5.0:
            p.add_body("k2", td, tr, joints @ moved[:3, :3].T + moved[:3, 3])
    assert p.due(t + 5.0, [*ids, "k2"], cal)  # a sensor without a pose
    job = p.begin(t + 5.0, cal, intr, serials)
    assert set(job.fixed) == set(ids)
    out = solve_person(job)
    assert p.finish(out, cal)
    for s in ids:
        assert np.array_equal(cal.poses[s], before[s])
    # (within what 5 s more frames change: the second sensor's pose rests on fewer)
    d = invert_transform(before[ids[1]] @ invert_transform(moved)) @ cal.poses["k2"]
    assert np.linalg.norm(rotation_vector_deg(d[:3, :3])) < 0.5 and np.linalg.norm(d[:3, 3]) < 0.01


def test_the_calibration_message_crosses_the_wire_and_reaches_the_viewer() -> None:
    from kinefuse.live.protocol import Status, codec
    from kinefuse.live.viewer.wire import status_message

    st = Status(calibration_message=f"{WALK} (sensors a and b saw the person over 3 cm)")
    (back,) = codec.Decoder().feed(codec.encode(st))
    assert isinstance(back, Status) and back.calibration_message == st.calibration_message
    assert status_message(back)["calibration_message"] == st.calibration_message
    assert status_message(Status())["calibration_message"] is None


def test_a_wand_calibration_without_sightings_gives_way_to_the_person(take45, rows45) -> None:
    """``serve --auto-calibrate`` starts the wand's collection when a sensor joins; with no
    depth no sighting ever comes, and the person path starts anyway (the server then gives the
    wand's collection up); once the wand is seen it does not."""
    _, tracks = take45
    ids = sorted(tracks)
    cal = LiveCalibration()
    cal.start(0.0, ids)
    assert cal.collecting
    p = PersonCalibration()
    _feed(p, rows45, 0.0, 28.0)
    assert not p.due(20.0, ids, cal) and p.due(25.5, ids, cal)  # 5 s after 20 s
    cal.add_sighting(ids[0], 25.6, np.zeros(3), 1.0)
    assert not p.due(31.0, ids, cal)  # the wand path is under way


def test_a_wand_calibration_in_force_stops_the_person_path(take45, rows45) -> None:
    """The person path runs (doubtful), then the operator calibrates with the wand: the person
    path stops refining over it and the status no longer asks to walk."""
    from kinefuse.capture.calibration.calib_file import CalibrationFile, SensorCalibration
    from kinefuse.live.server.live_calibration import CalibrationOutcome

    _, tracks = take45
    ids = sorted(tracks)
    cal = LiveCalibration()
    p = PersonCalibration()
    intr = dict.fromkeys(ids, Intrinsics())
    _feed(p, rows45, 0.0, 30.0)
    assert not p.due(25.0, ids, cal) and p.due(30.0, ids, cal)
    p.finish(solve_person(p.begin(30.0, cal, intr, dict.fromkeys(ids, ""))), cal)
    assert p.active and p.grade == "doubtful" and p.message is not None
    wand = CalibrationFile(
        method="full",
        created=cal.calibration.created,  # type: ignore[union-attr]
        sensors=tuple(SensorCalibration(s, "", np.eye(4), Intrinsics(), 0.001, 100) for s in ids),
        world="the wand's",
        rms_m=0.001,
    )
    cal.adopt(CalibrationOutcome(99, True, "full", Grade("good", ()), "wand", tuple(ids), wand))
    _feed(p, rows45, 30.0, 50.0)
    assert not p.due(50.0, ids, cal)
    assert p.say(50.0, ids, cal) is None and p.message is None and not p.active


def test_a_sensor_with_too_few_person_frames_fails_the_solve_not_the_server() -> None:
    """A sensor with a pose (from a file) and a newcomer that sent three frames of nothing (as a
    fuzzing peer with the token does): the solve fails with a reason; it used to raise (numpy's
    "need at least one array to stack") and end the server."""
    from kinefuse.core.skeleton import standing_pose
    from kinefuse.live.server.person import PersonJob, solve_person

    pose = np.asarray(standing_pose(), dtype=float)
    t = [k / 30 for k in range(60)]
    ahead = pose + np.array([0.0, 0.0, 3.0])
    tracks = {
        "s0": (t, t, [ahead] * 60),
        "fz0": (t[:3], t[:3], [pose * np.nan] * 3),
    }
    out = solve_person(PersonJob(1, tracks, {"s0": np.eye(4)}, None, {}, {}))
    assert not out.ok and out.grade.grade == "failed"
    assert "no sensor could be registered" in out.message


def test_the_person_path_keeps_the_subject_only(shared_data) -> None:
    """Two people in view (the scene of tests/people_scene.py: the subject from the start, a
    bystander crossing in front of them, the subject lost and found under new tracking ids): each
    sensor keeps the subject's trunk frames and none of the bystander's."""
    import numpy as np

    from kinefuse.live.server.person import PersonCalibration
    from people_scene import two_people

    lab = two_people(shared_data)
    pc = PersonCalibration()
    for sid, s in lab["streams"].items():
        for r in range(s.n_frames):
            t = float(s.t_server_s[r])
            pc.add_body(sid, t, t + 0.06, s.joints_m[r], int(s.body_id[r]))
    for sid, s in lab["streams"].items():
        kept = np.array(pc._frames[sid].p)
        subject = s.joints_m[lab["truth"][sid] == 0]
        assert len(kept) == len(subject)
        assert np.allclose(kept, subject)

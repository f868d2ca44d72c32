"""The simulated lab with bystanders: placement, occlusion between people, Kinect-like tracking
ids, the store's every body, the truth of who is who, and evaluate per person and identity."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.cli import main
from kinefuse.core.frames.observations import BodyFrames
from kinefuse.core.skeleton import (
    JOINT_INDEX,
    N_JOINTS,
    TrackingState,
    capsule_radii,
    standing_pose,
)
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.lab.people import (
    all_bodies,
    evaluate_people,
    first_body_assignment,
    identity_share,
    match_people,
    true_assignment,
)
from kinefuse.pipeline.store_inputs import clip_grid, frame_grid, load_usable_sensors
from kinefuse.sim.people import ID_BASE, ID_STRIDE, tracking_ids
from kinefuse.sim.tracker import hidden_by_others, simulate_tracker

SIM = ["--seconds", "5", "--calibration-seconds", "1", "--depth-rate", "5", "--seed", "2"]


@pytest.fixture(scope="module")
def sessions(tmp_path_factory, shared_data) -> tuple[Path, Path]:
    """The same session without and with one walking bystander."""
    d = tmp_path_factory.mktemp("people")
    clip = shared_data / "motion" / "cmu" / "01_01.amc"
    walk = shared_data / "motion" / "cmu" / "02_walk_a.amc"
    alone, crowd = d / "alone.sqlite", d / "crowd.sqlite"
    assert main(["simulate", "--clip", str(clip), *SIM, "--out", str(alone)]) == 0
    assert main(["simulate", "--clip", str(clip), "--bystander", str(walk), *SIM,
                 "--out", str(crowd)]) == 0  # fmt: skip
    return alone, crowd


def _root_xy(store: SessionStore, person: int, t: np.ndarray) -> np.ndarray:
    tt, j = store.truth().person_motion(person)
    return np.stack([np.interp(t, tt, j[:, JOINT_INDEX["SpineBase"], k]) for k in (0, 1)], -1)


def test_one_person_session_keeps_no_other_body(sessions) -> None:
    alone, _ = sessions
    with SessionStore.open(alone) as st:
        assert st.truth().people() == [0] and st.truth().info("people") is None
        for s in st.sensors():
            first, every = st.observations(s.id), st.observations(s.id, bodies="all")
            assert not every.multi and np.array_equal(every.seq, first.seq)
            assert (every.body_id == 0).all()
            assert (st.truth().person_of(s.id, first.seq, first.body_id) == 0).all()
        assert st._db.execute("SELECT count(*) FROM observation_bodies").fetchone()[0] == 0


def test_bystander_passes_near_and_between_but_not_in_the_calibration(sessions) -> None:
    alone, crowd = sessions
    with SessionStore.open(crowd) as st, SessionStore.open(alone) as st0:
        people = st.truth().info("people")
        assert [p["role"] for p in people] == ["subject", "bystander"]  # type: ignore[index]
        t_cal, t_end = st.meta()["motion_phase_server_s"]
        t = np.linspace(t_cal, t_end, 200)
        a, b = _root_xy(st, 0, t), _root_xy(st, 1, t)
        assert 0.45 < np.linalg.norm(a - b, axis=1).min() < 1.0  # close, not through each other
        # at mid-motion the bystander stands on the line from the subject to sensor k0
        mid = np.array([(t_cal + t_end) / 2])
        a, b = _root_xy(st, 0, mid)[0], _root_xy(st, 1, mid)[0]
        k0 = st.truth().sensor("k0")[0][:2, 3]
        u = (k0 - a) / np.linalg.norm(k0 - a)
        assert 0.5 < (b - a) @ u < np.linalg.norm(k0 - a)
        assert abs(u[0] * (b - a)[1] - u[1] * (b - a)[0]) < 0.05
        # nobody else in the room during the wand calibration: the same depth frames
        for s in st.sensors():
            for f, f0 in zip(st.iter_depth_frames(s.id), st0.iter_depth_frames(s.id), strict=True):
                assert np.array_equal(f[-1], f0[-1])


def test_tracking_ids_are_each_sensors_own_and_the_first_body_is_not_always_the_subject(
    sessions,
) -> None:
    _, crowd = sessions
    with SessionStore.open(crowd) as st:
        seen: list[set[int]] = []
        first_is_bystander = 0
        for s in st.sensors():
            every = st.observations(s.id, bodies="all")
            assert every.multi
            first = st.observations(s.id)
            assert np.array_equal(first.seq, np.unique(every.seq))
            assert np.array_equal(first.body_id, every.first_bodies().body_id)
            who = st.truth().person_of(s.id, every.seq, every.body_id)
            assert set(np.unique(who)) <= {-1, 0, 1} and (who == 1).any()
            assert ((who == -1) == ~every.has_body).all()
            ids = set(every.body_id[every.has_body].tolist())
            seen.append(ids)
            # one id per person per run of tracked frames: an id never changes person
            for i in ids:
                assert np.unique(who[every.body_id == i]).size == 1
            first_is_bystander += int((st.truth().person_of(s.id, first.seq, first.body_id)
                                       == 1).sum())  # fmt: skip
        for i, a in enumerate(seen):
            for b in seen[i + 1 :]:
                assert not a & b  # ids are never shared between sensors
        assert first_is_bystander > 0


def test_tracking_ids_new_after_a_loss() -> None:
    tracked = np.array([[1, 1], [1, 1], [0, 1], [1, 1], [1, 0]], dtype=bool)
    ids, slot = tracking_ids(tracked, 2, np.random.default_rng(0))
    base = ID_BASE + 3 * ID_STRIDE
    assert ids[0, 0] != ids[0, 1] and ids[1].tolist() == ids[0].tolist()
    assert ids[2, 0] == 0 and slot[2, 0] == -1
    assert ids[3, 0] not in (ids[0, 0], ids[0, 1]) and ids[3, 1] == ids[0, 1]
    assert (ids[tracked] > base).all() and (ids[tracked] < base + ID_STRIDE).all()
    # person 0 came back into the free slot its loss left, person 1 keeps its own
    assert slot[3, 1] == slot[0, 1] and slot[3, 0] == slot[0, 0]
    other, _ = tracking_ids(tracked, 3, np.random.default_rng(0))
    assert not set(ids[tracked].tolist()) & set(other[tracked].tolist())


def _person(x: float, y: float, n: int = 20) -> np.ndarray:
    pose = standing_pose()  # facing +x
    return np.repeat((pose + np.array([x, y, 0.0]))[None], n, axis=0)


def test_a_person_in_front_hides_and_is_lost_one_beside_changes_nothing() -> None:
    from kinefuse.core.camera.intrinsics import Intrinsics

    s2w = np.eye(4)
    # a sensor at x = 3 m, 1 m high, looking along -x (z forward, y down)
    s2w[:3, :3] = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    s2w[:3, 3] = (3.0, 0.0, 1.0)
    subject, radii = _person(0.0, 0.0), capsule_radii(1.75)
    front, beside = _person(1.2, 0.0), _person(1.2, 2.0)
    hidden = hidden_by_others(subject, s2w[:3, 3], [(front, radii)])
    assert hidden.mean() > 0.8
    assert not hidden_by_others(subject, s2w[:3, 3], [(beside, radii)]).any()

    def track(others):  # the same random draws every time
        return simulate_tracker(subject, s2w, Intrinsics(), radii, np.random.default_rng(5),
                                t_s=np.arange(20) / 30, others=others)  # fmt: skip

    alone, aside, behind = track([]), track([(beside, radii)]), track([(front, radii)])
    assert np.array_equal(alone.states, aside.states)
    assert np.array_equal(alone.joints_sensor, aside.joints_sensor, equal_nan=True)
    assert behind.dropout.all() and (behind.states == TrackingState.NOT_TRACKED).all()
    assert alone.visible.any() and not behind.visible.any()


def test_a_partly_hidden_subject_gets_inferred_joints(sessions) -> None:
    share = []
    for path in sessions:
        with SessionStore.open(path) as st:
            vis = [st.truth().observations(s.id)[3] for s in st.sensors()]
            share.append(float(np.concatenate(vis).mean()))
    assert share[1] < share[0]  # the bystander hides some of the subject's joints


def _streams(path: Path):
    with SessionStore.open(path) as st:
        poses = {s.id: st.truth().sensor(s.id)[0] for s in st.sensors()}
        sensors, _ = load_usable_sensors(st, poses)
        streams = all_bodies(st, sensors)
        true = true_assignment(st, streams)
    return sensors, streams, true


def test_identity_right_and_wrong_assignments(sessions) -> None:
    sensors, streams, true = _streams(sessions[1])
    grid = clip_grid(frame_grid(sensors), None, None)
    assert identity_share(streams, true, true, grid) == 1.0
    # the bystander's bodies given to the subject on one sensor: every frame they are seen wrong
    wrong = dict(true)
    sid = next(s for s, w in true.items() if (w == 1).sum() > 20)
    wrong[sid] = np.where(true[sid] == 1, 0, true[sid])
    share = identity_share(streams, wrong, true, grid)
    assert 0.0 < share < 1.0
    first = identity_share(streams, first_body_assignment(streams), true, grid)
    assert first < 1.0  # the one-body fusion takes the bystander when a sensor lists it first
    # the system numbers people its own way: right bodies under other ids are still right
    renamed = {sid: np.where(w == 0, 7, np.where(w == 1, 3, w)) for sid, w in true.items()}
    assert match_people(renamed, true) == {7: 0, 3: 1}
    assert identity_share(streams, renamed, true, grid) == 1.0
    # the person the system gives as the subject is scored as the subject, whoever it is
    assert match_people(renamed, true, subject=3) == {7: 0, 3: 0}
    assert identity_share(streams, renamed, true, grid, subject=3) < 1.0


def test_evaluate_people_scores_each_person(sessions) -> None:
    path = sessions[1]
    sensors, _, true = _streams(path)
    grid = clip_grid(frame_grid(sensors), None, None)
    with SessionStore.open(path) as st:
        right = evaluate_people(st, sensors, ["best"], grid, true, rule="the truth")
        first = evaluate_people(st, sensors, ["best"], grid, first_body_assignment(
            all_bodies(st, sensors)), rule="first body", subject=0)  # fmt: skip
    assert right["identity"] == 1.0 and first["identity"] < 1.0
    p0, p1 = right["persons"]["0"], right["persons"]["1"]
    assert p0["role"] == "subject" and p1["role"] == "bystander" and p1["rows"] > 0
    assert 0.0 < p0["best"]["mae_m"] < 0.15 and 0.0 < p1["best"]["mae_m"] < 0.25
    # the one-body fusion's subject is whoever each sensor lists first
    assert first["persons"]["0"]["rows"] > 0 and first["persons"]["0"]["best"]["mae_m"] > 0
    assert first["persons"]["1"]["rows"] == 0 and np.isnan(first["persons"]["1"]["best"]["mae_m"])


def test_evaluate_cli_reports_people_only_with_bystanders(sessions, capsys) -> None:
    alone, crowd = sessions
    for path, has in ((alone, False), (crowd, True)):
        code = main(["evaluate", str(path), "--true-calibration", "--methods", "best", "--json"])
        out = capsys.readouterr().out
        assert code == 0
        report = json.loads(out)
        assert ("people" in report) is has
        if has:
            assert set(report["people"]["persons"]) == {"0", "1"}
            # the association keeps each person on their own bodies (the one-body fusion does
            # not: the test above)
            assert report["people"]["identity"] >= 0.99
            assert report["people"]["assignment"].startswith("the association")
            # the main table is the subject's, fused from their own bodies as `fuse` does
            subject = report["people"]["persons"]["0"]["best"]["mae_m"]
            assert report["best"]["mae_m"] == pytest.approx(subject)


def test_a_missing_bystander_clip_is_refused(tmp_path, shared_data, capsys) -> None:
    clip = shared_data / "motion" / "cmu" / "01_01.amc"
    out = tmp_path / "s.sqlite"
    code = main(["simulate", "--clip", str(clip), "--bystander", str(tmp_path / "nope.amc"),
                 *SIM, "--out", str(out)])  # fmt: skip
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if line.startswith("kinefuse: error:")]
    assert code == 2 and len(errors) == 1 and "nope.amc: no such motion file" in errors[0]
    assert "Traceback" not in err
    assert not out.exists()


def test_store_round_trip_of_every_body(tmp_path) -> None:
    from kinefuse.core.camera.intrinsics import Intrinsics

    j = np.ones((5, N_JOINTS, 3))
    st_ = np.full((5, N_JOINTS), TrackingState.TRACKED, dtype=np.int8)
    j[2], st_[2] = np.nan, TrackingState.NOT_TRACKED  # an instant with no body
    t = [0.0, 0.0, 0.1, 0.2, 0.2]
    frames = BodyFrames("k0", seq=[0, 0, 1, 2, 2], t_device_s=t, t_host_s=t,
                        joints_m=j * np.arange(5)[:, None, None], states=st_,
                        body_id=[7, 9, 0, 9, 11])  # fmt: skip
    with SessionStore.create(tmp_path / "s.sqlite") as st:
        st.add_sensor("k0", "SIM", Intrinsics())
        st.append_observations("k0", frames.seq, t, frames.joints_m, frames.states,
                               t_receive_host_s=t, body_id=frames.body_id)  # fmt: skip
        every, first = st.observations("k0", bodies="all"), st.observations("k0")
    assert every.multi and not first.multi
    assert every.body_id.tolist() == [7, 9, 0, 9, 11] and first.body_id.tolist() == [7, 0, 9]
    assert np.array_equal(every.joints_m, frames.joints_m, equal_nan=True)
    assert np.array_equal(first.joints_m, frames.first_bodies().joints_m, equal_nan=True)


@pytest.fixture(scope="module")
def lab(shared_data):  # type: ignore[no-untyped-def]
    from kinefuse.formats.motion.load import load_motion
    from kinefuse.sim.lab import LabConfig
    from kinefuse.sim.people import place_bystander
    from kinefuse.sim.rig import default_rig, place_actor

    rig = default_rig(3)
    subject = place_actor(load_motion(shared_data / "motion" / "cmu" / "131_01_scaled_metres.bvh"),
                          rig)  # fmt: skip
    walk = place_actor(load_motion(shared_data / "motion" / "cmu" / "02_walk_a.amc"), rig)
    other = place_bystander(walk, subject, rig, 0, 2.0)
    return subject, rig, LabConfig(seed=5, calibration_s=1.0, motion_s=2.0), other


def test_body_depth_renders_the_bystander_in_front_of_the_subject(lab) -> None:  # type: ignore[no-untyped-def]
    from kinefuse.sim.lab import SensorSimulation

    subject, rig, config, other = lab
    frames = []
    for people in ((), (other,)):
        sim = SensorSimulation(subject, rig, "k0", config, people)
        frames.append(list(sim.body_depth_frames(every=30, noise=False)))
    mid = len(frames[0]) // 2
    alone, crowd = frames[0][mid], frames[1][mid]
    assert np.array_equal(alone.joints_sensor_m, crowd.joints_sensor_m)
    reach = float(np.linalg.norm(alone.joints_sensor_m[JOINT_INDEX["SpineBase"]])) - 0.3
    near = [int(((f.depth_mm > 0) & (f.depth_mm < 1000 * reach)).sum()) for f in (alone, crowd)]
    assert near[1] > near[0] + 500  # a body nearer the sensor than the subject: the bystander


def test_body_frames_hand_every_body_over(lab) -> None:  # type: ignore[no-untyped-def]
    from kinefuse.sim.lab import SensorSimulation

    subject, rig, config, other = lab
    plain = list(SensorSimulation(subject, rig, "k0", config).body_frames())
    _, body, _ = SensorSimulation(subject, rig, "k0", config).body()
    assert all(f.others == () and f.body_id == 0 for f in plain)
    assert np.array_equal(np.stack([f.joints_m for f in plain]), body.joints_sensor,
                          equal_nan=True)  # fmt: skip
    crowd = list(SensorSimulation(subject, rig, "k0", config, (other,)).body_frames())
    assert [f.seq for f in crowd] == [f.seq for f in plain]
    two = [f for f in crowd if len(f.bodies()) == 2]
    assert two and all(f.others[0].seq == f.seq and f.others[0].body_id != f.body_id for f in two)


def test_a_live_simulated_sensor_delivers_every_body(lab) -> None:  # type: ignore[no-untyped-def]
    from kinefuse.core.frames.observations import BodyFrame
    from kinefuse.pipeline.frame_sources import SimulatedSensorSource

    subject, rig, config, other = lab
    source = SimulatedSensorSource(subject, rig, "k0", 5, config=config, depth=False,
                                   bystanders=(other,))  # fmt: skip
    frames = [f for f in source if isinstance(f, BodyFrame)]
    assert any(len(f.bodies()) == 2 for f in frames)
    ids = {b.body_id for f in frames for b in f.bodies() if b.states.any()}
    assert len(ids) >= 2 and 0 not in ids

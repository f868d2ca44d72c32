"""Per-person fusion and the people of ``kinefuse fuse``: a simulated session of the subject
(the bundled clip) with a bystander walking a real clip (CMU 02_walk_a) across the volume added to
every sensor's stream; each person fused from their own bodies, one export per person."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.cli.main import main
from kinefuse.app.workflows.fuse import person_path
from kinefuse.biomech.retarget import place
from kinefuse.capture.fusion.fusion_run import CalibratedSensor, people_of
from kinefuse.capture.fusion.people import trunk_world
from kinefuse.core.frames.observations import BodyFrames
from kinefuse.core.skeleton import JOINT_INDEX, TrackingState
from kinefuse.formats.export import export_skeleton
from kinefuse.formats.motion.load import load_motion
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.pipeline.store_inputs import frame_grid, load_sensors, run_method


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Path:
    from kinefuse.app.workflows.simulate import demo_clip_path, run_simulate

    d = tmp_path_factory.mktemp("people")
    s = d / "s.sqlite"
    run_simulate(clip=demo_clip_path(), out=s, sensors=3, seconds=6.0, seed=3,
                 calibration_s=0.0, depth_rate_hz=1.0)  # fmt: skip
    return s


def _true_poses(store: SessionStore) -> dict[str, np.ndarray]:
    from kinefuse.lab.poses import resolve_poses

    return resolve_poses(store, None, True)[0]


def with_bystander(sensors: list[CalibratedSensor], walk: np.ndarray, rate_hz: float) -> list:
    """Each sensor's stream in all-bodies form: its body, and at the instants the bystander is
    in the room (``walk (T, 25, 3)`` world, from the session's first capture) the bystander's,
    listed first on odd seconds (so the first body changes hands)."""
    t0 = min(float(s.t_server_s[0]) for s in sensors)
    out = []
    for i, s in enumerate(sensors):
        o = s.observations
        k = np.round((o.t_server_s - t0) * rate_hz).astype(int)
        have = (k >= 0) & (k < walk.shape[0])
        have[have] = np.isfinite(walk[k[have]]).all(axis=(1, 2))  # the bystander is in the room
        pose = s.sensor2world
        by = (walk[k[have]] - pose[:3, 3]) @ pose[:3, :3]
        rows = np.r_[np.arange(o.n_frames), np.flatnonzero(have)]
        first = (np.floor(o.t_server_s[have] - t0) % 2) == 1  # the bystander first
        order = np.r_[np.zeros(o.n_frames), np.where(first, -1.0, 1.0)]
        idx = np.lexsort((order, o.seq[rows]))
        joints = np.concatenate([o.joints_m, by])[idx]
        states = np.concatenate([o.states, np.full(by.shape[:2], TrackingState.TRACKED, np.int8)])[
            idx
        ]
        occ = np.concatenate([s.occluded, np.zeros(by.shape[:2], bool)])[idx]
        cross = np.concatenate([s.n_intersections, np.zeros(by.shape[0], np.int64)])[idx]
        body = np.r_[np.full(o.n_frames, 1), np.full(by.shape[0], 7 + i)][idx]
        obs = BodyFrames(
            sensor_id=o.sensor_id,
            seq=o.seq[rows][idx],
            t_device_s=o.t_device_s[rows][idx],
            t_host_s=o.t_host_s[rows][idx],
            joints_m=joints,
            states=states,
            occluded=occ,
            n_crossings=cross,
            t_server_s=o.t_server_s[rows][idx],
            body_id=body,
        )
        out.append(replace(s, observations=obs))
    return out


@pytest.fixture(scope="module")
def two(session: Path, shared_data: Path) -> dict:
    with SessionStore.open(session) as store:
        sensors = load_sensors(store, _true_poses(store))
    rate = 30.0
    # the bystander walks 4 m across the volume, passing beside the subject
    by = load_motion(shared_data / "motion/cmu/02_walk_a.amc")
    trunk = trunk_world(
        sensors[0].observations.joints_m, sensors[0].observations.states, sensors[0].sensor2world
    )
    mid = np.nanmedian(trunk, axis=0)
    w = place(by, offset_m=(float(mid[0]) - 2.0, float(mid[1]) + 0.6), heading_deg=0)
    k = np.round(np.arange(0, w.n_frames, w.rate_hz / rate)).astype(int)
    walk = np.concatenate([np.full((30, 25, 3), np.nan), w.positions[k[k < w.n_frames]]])
    return {"sensors": sensors, "multi": with_bystander(sensors, walk, rate), "walk": walk}


def test_the_subject_fused_with_a_bystander_is_the_subject_alone(two: dict) -> None:
    sensors, multi = two["sensors"], two["multi"]
    assert all(s.observations.multi for s in multi)
    grid = frame_grid(sensors)
    alone = run_method(sensors, grid, "best").positions
    people, per = people_of(multi)
    assert len(people.ids) == 2 and people.rule == "nearest the centre"
    for method in ("best", "paper"):
        res = run_method(per[people.subject], grid, method).positions
        ref = alone if method == "best" else run_method(sensors, grid, method).positions
        diff = np.linalg.norm(res - ref, axis=-1)
        assert np.nanmedian(diff) < 0.005, method
    # the first bodies alone mix the two people
    firsts = [replace(s, observations=s.observations.first_bodies()) for s in multi]
    mixed = run_method(firsts, grid, "best").positions
    assert np.nanmax(np.linalg.norm(mixed - alone, axis=-1)) > 0.5


def test_every_person_exports_to_a_file_of_their_own(two: dict, tmp_path: Path) -> None:
    import ezc3d

    multi, walk = two["multi"], two["walk"]
    people, per = people_of(multi)
    grid = frame_grid(multi)
    other = next(p for p in people.ids if p != people.subject)
    for pid in people.ids:
        r = run_method(per[pid], grid, "best")
        export_skeleton(person_path(tmp_path / "people.c3d", pid), r.t_server_s, r.positions)
    files = sorted(p.name for p in tmp_path.iterdir())
    assert files == [f"people_p{i}.c3d" for i in sorted(people.ids)]
    c = ezc3d.c3d(str(tmp_path / f"people_p{other}.c3d"))
    pts = c["data"]["points"][:3]  # (3, markers, frames), the file's unit
    unit = c["parameters"]["POINT"]["UNITS"]["value"][0]
    scale = 0.001 if unit == "mm" else 1.0
    sb = JOINT_INDEX["SpineBase"]
    t0 = min(float(s.t_server_s[0]) for s in multi)
    k = np.round((grid - t0) * 30.0).astype(int)
    ok = (k >= 0) & (k < walk.shape[0])
    true = walk[k[ok], sb]
    got = pts[:, sb, ok].T * scale
    err = np.linalg.norm(got - true, axis=1)
    assert np.isfinite(err).sum() > 30 and np.nanmedian(err) < 0.05


def test_fuse_people_all_on_a_one_person_session(session: Path, tmp_path: Path, capsys) -> None:
    one, all_ = tmp_path / "one.csv", tmp_path / "all.csv"
    assert main(["fuse", str(session), "--true-calibration", "--out", str(one)]) == 0
    capsys.readouterr()
    argv = ["fuse", str(session), "--true-calibration", "--people", "all", "--out", str(all_)]
    assert main([*argv, "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert (info["people"], info["subject"], info["subject_rule"]) == ([0], 0, "one person")
    assert info["written"] == [str(all_)]
    assert one.read_bytes() == all_.read_bytes()


def test_fuse_refuses_a_subject_that_is_not_there(session: Path, capsys) -> None:
    code = main(["fuse", str(session), "--true-calibration", "--subject", "1"])
    assert code == 2
    err = capsys.readouterr().err
    assert "--subject 1: this recording has one person, id 0" in err


def test_analyze_analyses_the_subject(session: Path, tmp_path: Path, capsys) -> None:
    from kinefuse.app.workflows.analyze import sequence_from_session

    inp = sequence_from_session(session, true_calibration=True)
    assert inp.fusion is not None
    assert (inp.fusion["people"], inp.fusion["subject"], inp.fusion["subject_rule"]) == (
        [0],
        0,
        "one person",
    )
    argv = ["analyze", str(session), "--true-calibration", "--no-plots", "--subject", "2"]
    assert main([*argv, "--out", str(tmp_path / "a")]) == 2
    assert "--subject 2: this recording has one person, id 0" in capsys.readouterr().err
    assert not (tmp_path / "a").exists()


def test_a_recording_of_two_people_exports_both(
    session: Path, two: dict, tmp_path: Path, capsys
) -> None:
    """A session store holding both people's bodies (the simulated session's sensors, clocks
    and truth; every sensor's stream replaced by its two-person form), fused with
    ``--people all``: one C3D and one TRC per person, each loading in ezc3d and OpenSim, each on
    its own person."""
    import shutil
    import sqlite3

    import ezc3d

    opensim = pytest.importorskip("opensim")
    rec = tmp_path / "two.sqlite"
    shutil.copy(session, rec)
    con = sqlite3.connect(rec)
    with con:  # the recorded streams go; the sensors, clocks, truth and meta stay
        con.execute("DELETE FROM observation_bodies")
        con.execute("DELETE FROM observations")
    con.close()
    with SessionStore.open(rec, writable=True) as st:
        for s in two["multi"]:
            o = s.observations
            st.append_observations(o.sensor_id, o.seq, o.t_device_s, o.joints_m, o.states,
                                   t_receive_host_s=o.t_host_s, body_id=o.body_id)  # fmt: skip
    out = tmp_path / "people.c3d"
    argv = ["fuse", str(rec), "--true-calibration", "--people", "all", "--out", str(out)]
    assert main([*argv, "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["people"] == [0, 1] and info["subject_rule"] == "nearest the centre"
    other = 1 - info["subject"]
    assert info["written"] == [str(tmp_path / f"people_p{p}.c3d") for p in (0, 1)]
    trc = tmp_path / "people.trc"
    assert main(["fuse", str(rec), "--true-calibration", "--people", "all", "--out", str(trc)]) == 0
    sb = JOINT_INDEX["SpineBase"]
    walk = two["walk"]
    t0 = min(float(s.t_server_s[0]) for s in two["sensors"])
    alone = run_method(two["sensors"], frame_grid(two["sensors"]), "best")
    for pid in (0, 1):
        c = ezc3d.c3d(str(tmp_path / f"people_p{pid}.c3d"))
        scale = 0.001 if c["parameters"]["POINT"]["UNITS"]["value"][0] == "mm" else 1.0
        got = c["data"]["points"][:3, sb, :].T * scale  # (frames, 3)
        table = opensim.TimeSeriesTableVec3(str(tmp_path / f"people_p{pid}.trc"))
        assert table.getNumColumns() == 25 and table.getNumRows() == got.shape[0]
        if pid == other:
            k = np.round((alone.t_server_s - t0) * 30.0).astype(int)
            ok = (k >= 0) & (k < walk.shape[0])
            err = np.linalg.norm(got[ok] - walk[k[ok], sb], axis=1)
        else:
            err = np.linalg.norm(got - alone.positions[:, sb], axis=1)
        assert np.isfinite(err).sum() > 30 and np.nanmedian(err) < 0.05, pid

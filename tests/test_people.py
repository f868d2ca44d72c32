"""People matched across sensors and over time (:mod:`kinefuse.capture.fusion.people`), on two real
clips (CMU 131_01 as the subject, CMU 02_walk_a as a bystander crossing close in front of them)
seen by three sensors of the default rig, with tracking ids that change as a Kinect's do."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from kinefuse.capture.fusion.best import fuse_best
from kinefuse.capture.fusion.people import PeopleTracker, associate, trunk_world
from kinefuse.core.skeleton import JOINT_INDEX, TrackingState
from kinefuse.errors import InputError
from kinefuse.sim.rig import default_rig
from people_scene import RATE, two_people


@pytest.fixture(scope="module")
def lab(shared_data: Path) -> dict:
    return two_people(shared_data)


def test_the_bystander_passes_close_and_the_first_body_changes_hands(lab: dict) -> None:
    # the scene is what the tests below claim: a pass within 0.5 m, the first body not always
    # the subject's
    a, b, start = lab["a"], lab["b"], lab["start"]
    sb = JOINT_INDEX["SpineBase"]
    k = np.arange(max(start, 0), min(a.shape[0], start + b.shape[0]))
    gap = np.linalg.norm(a[k, sb, :2] - b[k - start, sb, :2], axis=1)
    assert gap.min() < 0.5
    s = lab["streams"]["k1"]
    assert s.multi
    first = s.first_bodies()
    who = lab["truth"]["k1"][
        np.isin(np.arange(s.n_frames), np.flatnonzero(np.r_[True, np.diff(s.seq) != 0]))
    ]
    assert first.n_frames == np.unique(s.seq).size
    assert set(who.tolist()) == {0, 1}


def test_every_body_goes_to_its_own_person(lab: dict) -> None:
    people = associate(lab["streams"], lab["poses"])
    assert len(people.ids) == 2
    # the tracker's ids against the truth's: one to one, every row right
    pairs = set()
    for sid, p in people.person.items():
        pairs |= set(zip(p.tolist(), lab["truth"][sid].tolist(), strict=True))
    assert len(pairs) == 2 and len({p for p, _ in pairs}) == 2
    # the subject stood at the volume's centre from the start
    assert dict(pairs)[people.subject] == 0
    assert people.rule == "nearest the centre"


def test_a_person_keeps_their_id_through_new_tracking_ids_and_a_return(lab: dict) -> None:
    people = associate(lab["streams"], lab["poses"])
    s0 = lab["streams"]["k0"]
    subj = people.person["k0"][lab["truth"]["k0"] == 0]
    ids = s0.body_id[lab["truth"]["k0"] == 0]
    assert set(ids.tolist()) == {1, 2, 4}  # three tracking ids on k0 for the subject
    assert set(subj.tolist()) == {people.subject}


def test_the_subject_can_be_chosen_and_a_wrong_choice_is_refused(lab: dict) -> None:
    other = associate(lab["streams"], lab["poses"], subject=1)
    assert (other.subject, other.rule) == (1, "chosen")
    with pytest.raises(InputError, match="--subject 7: no such person"):
        associate(lab["streams"], lab["poses"], subject=7)


def test_each_person_fused_from_their_own_bodies(lab: dict) -> None:
    people = associate(lab["streams"], lab["poses"])
    split = people.split(lab["streams"])
    ids = [s.id for s in default_rig(3, 3.0).sensors]
    poses = np.stack([lab["poses"][i] for i in ids])
    grid = np.arange(0.0, 5.9, 1 / RATE)
    mapping = {}
    for sid, p in people.person.items():
        mapping.update(zip(p.tolist(), lab["truth"][sid].tolist(), strict=True))
    for pid, streams in split.items():
        for s in streams.values():
            assert not s.multi
        fused = fuse_best([streams[i] for i in ids], poses, grid)
        if mapping[pid] == 0:
            true = lab["a"][: grid.size]
        else:
            k = np.arange(grid.size) - lab["start"]
            keep = (k >= 0) & (k < lab["b"].shape[0])
            true = np.full_like(lab["a"][: grid.size], np.nan)
            true[keep] = lab["b"][k[keep]]
        err = np.linalg.norm(fused.positions - true, axis=-1)
        ok = np.isfinite(err)
        assert ok.sum() > 50
        # within the sensors' 1 cm noise and interpolation, not two people averaged
        assert np.median(err[ok]) < 0.03


def test_the_first_bodies_alone_mix_the_two_people(lab: dict) -> None:
    # what kinefuse did before: each sensor's first body, fused as one person
    ids = [s.id for s in default_rig(3, 3.0).sensors]
    poses = np.stack([lab["poses"][i] for i in ids])
    grid = np.arange(0.0, 5.9, 1 / RATE)
    fused = fuse_best([lab["streams"][i].first_bodies() for i in ids], poses, grid)
    err = np.linalg.norm(fused.positions - lab["a"][: grid.size], axis=-1)
    assert np.nanmax(err) > 0.3


def test_one_person_streams_are_one_person_unchanged(lab: dict) -> None:
    one = {sid: s.first_bodies() for sid, s in lab["streams"].items()}
    people = associate(one, lab["poses"])
    assert (people.ids, people.subject, people.rule) == ((0,), 0, "one person")
    split = people.split(one)
    assert all(split[0][sid] is one[sid] for sid in one)


def test_the_live_tracker_gives_the_same_people_frame_by_frame(lab: dict) -> None:
    # the causal tracker fed whole instants of all sensors at once, as a live server does
    streams, poses = lab["streams"], lab["poses"]
    tracker = PeopleTracker()
    wrong = total = 0
    mapping: dict[int, int] = {}
    for k in range(lab["a"].shape[0]):
        frames, who = {}, {}
        for sid, s in streams.items():
            rows = np.flatnonzero(s.seq == k)
            frames[sid] = [s.frame(r) for r in rows]
            for r in rows:
                who[(sid, int(s.body_id[r]))] = int(lab["truth"][sid][r])
        got = tracker.update(k / RATE, frames, poses)
        for key, pid in got.items():
            mapping.setdefault(pid, who[key])
            total += 1
            wrong += mapping[pid] != who[key]
    assert total > 600 and wrong == 0
    assert len(mapping) == 2


def test_trunk_needs_a_tracked_trunk_joint(lab: dict) -> None:
    s = lab["streams"]["k0"]
    states = s.states[:2].copy()
    states[1] = TrackingState.NOT_TRACKED
    t = trunk_world(s.joints_m[:2], states, lab["poses"]["k0"])
    assert np.isfinite(t[0]).all() and np.isnan(t[1]).all()


def test_bodies_without_tracking_ids_are_not_merged(lab: dict) -> None:
    # a source that numbers nothing reports every body as 0: the first is kept, a repeat is
    # nobody's rather than the same person twice
    s = lab["streams"]["k1"]
    rows = np.flatnonzero(s.seq == int(2.6 * RATE))
    assert rows.size == 2
    frames = [replace(s.frame(r), body_id=0) for r in rows]
    tracker = PeopleTracker()
    got = tracker.update(2.6, {"k1": frames}, lab["poses"])
    assert list(got) == [("k1", 0)]
    streams = dict(lab["streams"])
    streams["k1"] = replace(s, body_id=np.zeros(s.n_frames, dtype=np.int64))
    people = associate(streams, lab["poses"])
    p = people.person["k1"]
    first = np.r_[True, np.diff(s.seq) != 0]
    assert (p[~first] == -1).all() and (p[first] >= 0).all()
    for per in people.split(streams).values():
        assert not per["k1"].multi

"""The server's per-person live fusion (:class:`kinefuse.live.server.fusion_loop.FrameFusion`):
the hand-made two-person scene of :mod:`people_scene` pushed observation by observation, every
body of an instant in one observation; the subject's fused frames stay on the subject while the
bystander crosses close in front of them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kinefuse.live.server.fusion_loop import FrameFusion
from people_scene import RATE, observation, two_people


def _replay(lab: dict, method: str, *, alone: bool) -> tuple[np.ndarray, list, set]:
    """The subject's frames from 1/30 s to 5.9 s; the bystander's frames (person 1) where
    the bystander is; the persons seen. ``alone``: the bystander's bodies left out."""
    ff = FrameFusion(method)
    ff.set_poses(lab["poses"])
    scene = lab
    if alone:
        streams = {sid: s.take(lab["truth"][sid] == 0) for sid, s in lab["streams"].items()}
        scene = {**lab, "streams": streams}
    subject, bystander, persons = [], [], set()
    for k in range(lab["a"].shape[0]):
        for sid in scene["streams"]:
            o = observation(scene, sid, k)
            if o is not None:
                ff.push(sid, o)
        t = (k - 1) / RATE + 0.009  # every sensor's frame of that instant is in
        if k < 1 or t > 5.9:
            continue
        pos, _var, _status = ff.fuse(t)
        assert ff.subject == 0
        persons |= set(ff.people)
        subject.append(pos)
        kb = k - 1 - lab["start"]
        if 0 <= kb < lab["b"].shape[0] and 1 in ff.people:
            bystander.append((ff.people[1][0], lab["b"][kb]))
    return np.array(subject), bystander, persons


@pytest.mark.parametrize("method", ["best-live", "paper"])
def test_the_subject_stays_the_subject_while_a_bystander_crosses(
    shared_data: Path, method: str
) -> None:
    lab = two_people(shared_data)
    with_, bystander, persons = _replay(lab, method, alone=False)
    alone, _, persons_alone = _replay(lab, method, alone=True)
    assert persons == {0, 1} and persons_alone == {0}
    # the subject's frames are those of the subject alone, the crossing included (the two
    # people averaged would be tens of centimetres off)
    diff = np.linalg.norm(with_ - alone, axis=-1)
    assert np.nanmax(np.nanmedian(diff, axis=1)) < 0.02
    truth = lab["a"][: with_.shape[0]]
    first = np.nanmedian(np.linalg.norm(with_ - truth, axis=-1), axis=1)
    assert np.nanmedian(first) < 0.05
    # and the bystander is fused as themselves
    err = [np.nanmedian(np.linalg.norm(p - t, axis=-1)) for p, t in bystander]
    assert len(err) > 40 and np.nanmedian(err) < 0.06


def test_the_operator_chooses_the_subject(shared_data: Path) -> None:
    lab = two_people(shared_data)
    ff = FrameFusion("best-live")
    ff.set_poses(lab["poses"])
    for k in range(int(3.0 * RATE)):
        for sid in lab["streams"]:
            o = observation(lab, sid, k)
            if o is not None:
                ff.push(sid, o)
    ff.set_subject(1)
    pos, _, _ = ff.fuse(2.9)
    kb = int(2.9 * RATE) - lab["start"]
    assert (ff.subject, ff.subject_rule) == (1, "chosen")
    assert np.nanmedian(np.linalg.norm(pos - lab["b"][kb], axis=-1)) < 0.05


def test_the_operator_can_pick_only_a_person_fused_now(shared_data: Path) -> None:
    lab = two_people(shared_data)
    ff = FrameFusion("best-live")
    ff.set_poses(lab["poses"])
    for sid in lab["streams"]:
        o = observation(lab, sid, 0)
        assert o is not None
        ff.push(sid, o)
    ff.fuse(0.0)
    assert set(ff.people) == {0}  # the bystander has not come in yet
    assert not ff.set_subject(1, "operator", known=True)
    assert (ff.subject, ff.subject_rule) == (0, "first seen")
    assert ff.set_subject(0, "operator", known=True) and ff.subject_rule == "operator"

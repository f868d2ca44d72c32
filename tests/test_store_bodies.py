"""The session store keeps every body a sensor reported: the first body where it always was,
the others beside it; an old store (one body per frame) reads as before, each row body 0."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import numpy as np
import pytest

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.frames.observations import BodyFrames
from kinefuse.core.skeleton import N_JOINTS, TrackingState
from kinefuse.errors import InputError
from kinefuse.formats.store.session_store import SessionStore


def _rows(rng: np.random.Generator, n: int, seq: np.ndarray, occluded: bool):
    st = rng.integers(0, 3, (n, N_JOINTS)).astype(np.int8)
    j = rng.normal([0.0, 0.0, 2.5], 0.5, (n, N_JOINTS, 3))
    j[st == TrackingState.NOT_TRACKED] = np.nan
    t = 10.0 + seq / 30.0
    occ = rng.random((n, N_JOINTS)) < 0.3 if occluded else None
    cr = rng.integers(0, 5, n) if occluded else None
    return t, j, st, occ, cr


@pytest.mark.parametrize("occluded", [True, False])
def test_every_body_is_stored_and_the_first_is_what_it_always_was(tmp_path, rng, occluded):
    # seq 0: one body, seq 1: three bodies, seq 2: two bodies, seq 3: one body
    seq = np.array([0, 1, 1, 1, 2, 2, 3])
    ids = np.array([5, 5, 9, 2, 9, 5, 9])
    t, j, st, occ, cr = _rows(rng, seq.size, seq, occluded)
    path = tmp_path / "s.sqlite"
    with SessionStore.create(path) as s:
        s.add_sensor("k0", "SIM-0", Intrinsics())
        s.append_observations(
            "k0", seq, t, j, st, occluded=occ, n_crossings=cr, body_id=ids,
            t_receive_server_s=t + 0.01,
        )  # fmt: skip
        s.append_observations("k0", [4], [11.0], j[:1], st[:1],
                              occluded=None if occ is None else occ[:1],
                              n_crossings=None if cr is None else cr[:1])  # fmt: skip
    with SessionStore.open(path) as s:
        first = s.observations("k0")
        every = s.observations("k0", bodies="all")
        assert s.observation_count("k0") == 5
        later = s.observations("k0", since_seq=1, bodies="all")
    assert not first.multi and first.seq.tolist() == [0, 1, 2, 3, 4]
    assert first.body_id.tolist() == [5, 5, 9, 9, 0]
    assert every.multi and every.seq.tolist() == [0, 1, 1, 1, 2, 2, 3, 4]
    assert every.body_id.tolist() == [*ids.tolist(), 0]
    np.testing.assert_array_equal(every.joints_m[:7], j)
    np.testing.assert_array_equal(every.states[:7], st)
    np.testing.assert_array_equal(every.t_device_s[:7], t)
    np.testing.assert_array_equal(every.t_receive_server_s[:7], t + 0.01)
    if occluded:
        assert every.occluded is not None and every.n_crossings is not None
        np.testing.assert_array_equal(every.occluded[:7], occ)
        np.testing.assert_array_equal(every.n_crossings[:7], cr)
    else:
        assert every.occluded is None
    # the first-body read is the all-bodies read's first bodies, row for row
    again = every.first_bodies()
    np.testing.assert_array_equal(again.joints_m, first.joints_m)
    np.testing.assert_array_equal(again.seq, first.seq)
    assert later.seq.tolist() == [2, 2, 3, 4] and later.body_id.tolist() == [9, 5, 9, 0]
    # and the frames it iterates into carry their other bodies
    frames = list(every)
    assert [len(f.bodies()) for f in frames] == [1, 3, 2, 1, 1]
    assert [b.body_id for b in frames[1].bodies()] == [5, 9, 2]


def test_bodies_are_checked_before_anything_is_written(tmp_path, rng):
    seq = np.array([0, 0, 1])
    t, j, st, _, _ = _rows(rng, 3, seq, False)
    with SessionStore.create(tmp_path / "s.sqlite") as s:
        s.add_sensor("k0", "SIM-0", Intrinsics())
        with pytest.raises(InputError, match="body_id repeats within one seq"):
            s.append_observations("k0", seq, t, j, st, body_id=[3, 3, 3])
        with pytest.raises(InputError, match=r"seq has duplicate values \[0\]"):
            s.append_observations("k0", [0, 1, 0], t, j, st, body_id=[1, 2, 3])
        with pytest.raises(InputError, match="bodies must be 'first' or 'all'"):
            s.observations("k0", bodies="every")  # type: ignore[arg-type]
        assert s.observation_count("k0") == 0


def _old_store(path: Path, rng) -> tuple[np.ndarray, np.ndarray]:
    """A store as kinefuse wrote it before every body was kept (no body_id, no other bodies)."""
    seq = np.arange(6)
    t, j, st, occ, cr = _rows(rng, 6, seq, True)
    with SessionStore.create(path) as s:
        s.add_sensor("k0", "SIM-0", Intrinsics())
        s.append_observations("k0", seq, t, j, st, occluded=occ, n_crossings=cr)
    conn = sqlite3.connect(path)
    conn.execute("DROP TABLE observation_bodies")
    conn.execute("ALTER TABLE observations DROP COLUMN body_id")
    conn.commit()
    conn.close()
    return j, st


def test_an_old_store_reads_as_before_each_row_body_0(tmp_path, rng):
    path = tmp_path / "old.sqlite"
    j, st = _old_store(path, rng)
    with SessionStore.open(path) as s:
        first = s.observations("k0")
        every = s.observations("k0", bodies="all")
    for o in (first, every):
        assert not o.multi and o.seq.tolist() == list(range(6))
        assert o.body_id.tolist() == [0] * 6
        np.testing.assert_array_equal(o.joints_m, j)
        np.testing.assert_array_equal(o.states, st)
    # one body per frame may still be appended; more are refused with what to do
    with SessionStore.open(path, writable=True) as s:
        s.append_observations("k0", [6], [20.0], j[:1], st[:1])
        with pytest.raises(InputError, match="append to a new session store"):
            s.append_observations("k0", [7, 7], [21.0, 21.0], j[:2], st[:2], body_id=[1, 2])
        assert s.observation_count("k0") == 7


def test_a_stream_in_all_bodies_form_round_trips(tmp_path, rng):
    seq = np.array([3, 3, 4, 5, 5])
    t, j, st, occ, cr = _rows(rng, 5, seq, True)
    stream = BodyFrames(
        "k0", seq, t, np.full(5, np.nan), j, st, occ, cr, body_id=np.array([1, 2, 1, 2, 1])
    )
    with SessionStore.create(tmp_path / "s.sqlite") as s:
        s.add_sensor("k0", "SIM-0", Intrinsics())
        s.append_observations(
            "k0", stream.seq, stream.t_device_s, stream.joints_m, stream.states,
            occluded=stream.occluded, n_crossings=stream.n_crossings, body_id=stream.body_id,
        )  # fmt: skip
        back = s.observations("k0", bodies="all")
    np.testing.assert_array_equal(back.seq, stream.seq)
    np.testing.assert_array_equal(back.body_id, stream.body_id)
    np.testing.assert_array_equal(back.joints_m, stream.joints_m)


def test_a_stored_session_replays_every_body(tmp_path, rng):
    """What a replayed session (``sim:`` and ``session:`` sources) hands its client: each frame
    once, with its other bodies."""
    from kinefuse.pipeline.frame_sources import SessionReplay

    seq = np.array([0, 0, 1, 2, 2, 2])
    t, j, st, _, _ = _rows(rng, 6, seq, False)
    with SessionStore.create(tmp_path / "s.sqlite") as s:
        s.add_sensor("k0", "SIM-0", Intrinsics())
        s.append_observations("k0", seq, t, j, st, body_id=[4, 6, 4, 4, 6, 7])
        frames = list(SessionReplay(s, ["k0"], depth=False))
    assert [f.seq for f in frames] == [0, 1, 2]
    assert [[b.body_id for b in f.bodies()] for f in frames] == [[4, 6], [4], [4, 6, 7]]
    np.testing.assert_array_equal(frames[2].others[1].joints_m, j[5])

"""The one observation type: a frame and its batch form, converted both ways."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from kinefuse.core.frames.observations import BodyFrame, BodyFrames
from kinefuse.core.skeleton import N_JOINTS, TrackingState
from kinefuse.errors import InputError


def _frames(rng, n: int, *, occlusion: bool) -> list[BodyFrame]:
    out = []
    for k in range(n):
        j = rng.normal(0, 1, (N_JOINTS, 3))
        st = rng.integers(0, 3, N_JOINTS).astype(np.int8)
        j[st == TrackingState.NOT_TRACKED] = np.nan
        occ = rng.random(N_JOINTS) < 0.2 if occlusion else None
        out.append(
            BodyFrame(
                "k1",
                10 + k,
                0.1 * k,
                0.1 * k + 0.02,
                j,
                st,
                occ,
                int(rng.integers(0, 4)) if occlusion else None,
            )
        )
    return out


@pytest.mark.parametrize("occlusion", [True, False])
def test_frames_round_trip_through_the_batch_form(rng, occlusion) -> None:
    frames = _frames(rng, 7, occlusion=occlusion)
    batch = BodyFrames.from_frames(frames)
    assert batch.sensor_id == "k1" and len(batch) == 7
    assert batch.joints_m.shape == (7, N_JOINTS, 3) and batch.states.dtype == np.int8
    assert np.isnan(batch.t_server_s).all()  # not mapped to the server clock yet
    np.testing.assert_array_equal(batch.present, np.isfinite(batch.joints_m).all(-1))
    back = list(batch)
    for a, b in zip(frames, back, strict=True):
        assert (a.sensor_id, a.seq, a.t_device_s, a.t_host_s) == (
            b.sensor_id, b.seq, b.t_device_s, b.t_host_s)  # fmt: skip
        np.testing.assert_array_equal(a.joints_m, b.joints_m)
        np.testing.assert_array_equal(a.states, b.states)
        assert (a.occluded is None) == (b.occluded is None) and a.n_crossings == b.n_crossings
        if a.occluded is not None:
            np.testing.assert_array_equal(a.occluded, b.occluded)
    sub = batch.take(np.array([5, 1]))
    assert sub.seq.tolist() == [15, 11]
    np.testing.assert_array_equal(sub.joints_m[0], batch.joints_m[5])


def test_batch_form_refuses_mismatched_shapes_and_mixed_sensors(rng) -> None:
    frames = _frames(rng, 3, occlusion=False)
    with pytest.raises(InputError, match="several sensors"):
        BodyFrames.from_frames([*frames, BodyFrame("k2", 0, 0.0, 0.0, frames[0].joints_m,
                                                   frames[0].states)])  # fmt: skip
    b = BodyFrames.from_frames(frames)
    with pytest.raises(InputError, match=r"joints_m must be \(3, 25, 3\)"):
        BodyFrames("k1", b.seq, b.t_device_s, b.t_host_s, b.joints_m[:2], b.states)
    with pytest.raises(InputError, match="t_server_s must have one value per frame"):
        b.on_server(np.zeros(2))
    empty = BodyFrames.from_frames([], sensor_id="k9")
    assert empty.sensor_id == "k9" and empty.joints_m.shape == (0, N_JOINTS, 3)


def _with_others(frames: list[BodyFrame], rng, n_others: list[int]) -> list[BodyFrame]:
    """The frames with ``n_others[k]`` further bodies each (ids 100 + i), same seq and times."""
    out = []
    for f, n in zip(frames, n_others, strict=True):
        others = tuple(
            replace(o, seq=f.seq, t_device_s=f.t_device_s, t_host_s=f.t_host_s, body_id=100 + i)
            for i, o in enumerate(_frames(rng, n, occlusion=f.occluded is not None))
        )
        out.append(replace(f, body_id=7, others=others))
    return out


@pytest.mark.parametrize("occlusion", [True, False])
def test_every_body_round_trips_through_the_all_bodies_form(rng, occlusion) -> None:
    frames = _with_others(_frames(rng, 4, occlusion=occlusion), rng, [0, 2, 1, 0])
    assert [len(f.bodies()) for f in frames] == [1, 3, 2, 1]
    assert frames[1].bodies()[0] is frames[1] and frames[1].first_body().others == ()
    batch = BodyFrames.from_frames(frames, bodies="all")
    assert batch.multi and len(batch) == 7
    assert batch.seq.tolist() == [10, 11, 11, 11, 12, 12, 13]
    assert batch.body_id.tolist() == [7, 7, 100, 101, 7, 100, 7]
    first = batch.first_bodies()
    assert not first.multi and first.seq.tolist() == [10, 11, 12, 13]
    assert first.body_id.tolist() == [7] * 4
    for a, b in zip(frames, first, strict=True):
        np.testing.assert_array_equal(a.joints_m, b.joints_m)
    back = list(batch)  # one frame per seq, its other bodies attached
    assert [len(f.bodies()) for f in back] == [1, 3, 2, 1]
    for a, b in zip(frames, back, strict=True):
        for x, y in zip(a.bodies(), b.bodies(), strict=True):
            assert (x.seq, x.body_id, x.t_device_s) == (y.seq, y.body_id, y.t_device_s)
            np.testing.assert_array_equal(x.joints_m, y.joints_m)
            np.testing.assert_array_equal(x.states, y.states)
            if x is not a:
                assert y.others == ()
            if x.occluded is not None:
                np.testing.assert_array_equal(x.occluded, y.occluded)
    # the first-body form of the same frames is what kinefuse always built
    plain = BodyFrames.from_frames(frames)
    assert not plain.multi and plain.seq.tolist() == first.seq.tolist()
    np.testing.assert_array_equal(plain.joints_m, first.joints_m)


def test_a_one_body_stream_is_its_own_first_bodies(rng) -> None:
    batch = BodyFrames.from_frames(_frames(rng, 5, occlusion=True))
    assert not batch.multi and batch.first_bodies() is batch
    assert batch.body_id.tolist() == [0] * 5
    assert not BodyFrames.from_frames([], sensor_id="k1").multi
    with pytest.raises(InputError, match="body_id must be"):
        BodyFrames(
            sensor_id="k1",
            seq=batch.seq,
            t_device_s=batch.t_device_s,
            t_host_s=batch.t_host_s,
            joints_m=batch.joints_m,
            states=batch.states,
            body_id=np.zeros(2, dtype=np.int64),
        )
    with pytest.raises(InputError, match="bodies must be"):
        BodyFrames.from_frames(list(batch), bodies="some")  # type: ignore[arg-type]

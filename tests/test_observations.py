"""The one observation type: a frame and its batch form, converted both ways."""

from __future__ import annotations

import numpy as np
import pytest

from kinefuse.errors import InputError
from kinefuse.frames.observations import BodyFrame, BodyFrames
from kinefuse.skeleton import N_JOINTS, TrackingState


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

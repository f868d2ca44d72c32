"""Fusion in bounded memory (issue 23): the chunked paths give the numbers of the whole-session
ones, bit for bit, whatever the chunk size.

The range methods solve the grid a chunk at a time; ``best``'s smoother runs backwards over a
:class:`~kinefuse.capture.fusion.model.FilterTape`, recomputing each block's filter moments from a
checkpoint; the replay prepares its measurements a chunk at a time. Each test runs the same
fusion with chunks of one size and another and compares every array exactly."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from kinefuse.capture.fusion import fusion_run as fusion_session
from kinefuse.capture.fusion import live
from kinefuse.capture.fusion.best import BestOptions, fuse_best
from kinefuse.capture.fusion.live import LiveOptions, replay_streams
from kinefuse.capture.fusion.model import rts_smooth, rts_smooth_tape
from kinefuse.core.frames.observations import BodyFrames
from kinefuse.core.geometry.transforms import apply_transform, invert_transform
from kinefuse.core.skeleton import TrackingState, standing_pose
from kinefuse.sim.rig import default_rig


def _streams(
    rng: np.random.Generator, seconds: float = 12.0
) -> tuple[list[BodyFrames], np.ndarray]:
    """Four sensors at ~30 Hz watching a swaying body, with noise, and a gap of 1.5 s in every
    sensor (the filter predicts, then its joints die and restart) and one sensor's hands
    missing for a while."""
    rig = default_rig(4)
    streams = []
    for i, s in enumerate(rig.sensors):
        t = np.sort(rng.uniform(0.0, seconds, int(30 * seconds)))
        t = t[(t < 5.0) | (t > 6.5)]
        p = np.repeat(standing_pose()[None], t.size, 0)
        p[..., 0] += 0.3 * np.sin(0.8 * t)[:, None]
        p = apply_transform(invert_transform(s.sensor2world), p) + rng.normal(0, 0.02, p.shape)
        st = np.full(p.shape[:2], TrackingState.TRACKED, np.int8)
        if i == 1:
            hands = (t > 2.0) & (t < 3.0)
            p[np.ix_(hands, [7, 11])] = np.nan
            st[np.ix_(hands, [7, 11])] = TrackingState.NOT_TRACKED
        streams.append(BodyFrames.on_server_clock(t, p, st))
    return streams, np.stack([s.sensor2world for s in rig.sensors])


def _arrays(f) -> list[np.ndarray]:
    return [f.positions, f.variance_m2, f.n_sensors]


@pytest.mark.parametrize("options", [BestOptions(), BestOptions(temporal=None),
                                     BestOptions(bones=False, lr_swap=False)])  # fmt: skip
def test_best_is_the_same_for_every_chunk_size(rng, monkeypatch, options) -> None:
    streams, poses = _streams(rng)
    grid = np.arange(0.0, 12.0, 1 / 30)
    monkeypatch.setattr(live, "_CHUNK", 100_000)  # one chunk: the whole session at once
    whole = _arrays(fuse_best(streams, poses, grid, options))
    assert np.isnan(whole[0]).any() and np.isfinite(whole[0]).mean() > 0.8  # gaps, mostly fused
    for chunk in (1, 7, 256):
        monkeypatch.setattr(live, "_CHUNK", chunk)
        got = _arrays(fuse_best(streams, poses, grid, options))
        for a, b in zip(whole, got, strict=True):
            np.testing.assert_array_equal(a, b)


def test_smoother_over_the_tape_equals_the_smoother_over_every_moment(rng, monkeypatch) -> None:
    """Block by block (moments recomputed from checkpoints, each block smoothed from the next
    one's first frame) against the whole recursion over every frame's moments at once."""
    streams, poses = _streams(rng)
    grid = np.arange(0.0, 12.0, 1 / 30)
    opts = LiveOptions(best=BestOptions(bones=False), latency_s=np.inf)
    dt = np.diff(grid, prepend=grid[:1])
    for chunk in (13, 256):
        monkeypatch.setattr(live, "_CHUNK", chunk)
        r = replay_streams(streams, poses, grid, opts, record=True)
        tape = r["tape"]
        assert len(tape.checkpoints) == -(-grid.size // chunk)
        alive3 = np.repeat(np.isfinite(r["positions"]).all(-1)[..., None], 3, axis=-1)
        one = replace(tape, every=grid.size, checkpoints=tape.checkpoints[:1])
        pred, filt = one.moments(0, grid.size)  # every moment of the run at once
        xs, sxx = rts_smooth(dt, pred, filt, alive3)
        bx, bs = rts_smooth_tape(dt, tape, alive3)
        np.testing.assert_array_equal(xs, bx)
        np.testing.assert_array_equal(sxx, bs)
        # the recomputed filter is the run's: its positions where the filter is alive
        alive = alive3[..., 0]
        np.testing.assert_array_equal(filt[0][alive], r["positions"][alive])
    with pytest.raises(ValueError, match="multiple of"):
        tape.moments(1, 5)


@pytest.fixture(scope="module")
def sensors_and_grid(tmp_path_factory):
    """A simulated 12 s 4-sensor session's sensors as the commands load them."""
    from kinefuse.app.workflows.simulate import demo_clip_path
    from kinefuse.formats.motion import load_motion
    from kinefuse.formats.store.session_store import SessionStore
    from kinefuse.pipeline.store_inputs import frame_grid, load_sensors
    from kinefuse.sim.lab import LabConfig, simulate_session
    from kinefuse.sim.rig import place_actor

    rig = default_rig(4)
    motion = place_actor(load_motion(demo_clip_path()), rig)
    out = Path(tmp_path_factory.mktemp("bounded")) / "s.sqlite"
    simulate_session(motion, rig, out, LabConfig(seed=3, calibration_s=0.0, motion_s=12.0))
    with SessionStore.open(out) as st:
        sensors = load_sensors(st, {s.id: st.truth().sensor(s.id)[0] for s in st.sensors()})
    return sensors, frame_grid(sensors)


RANGE_RUNS = [
    ("linear", {}),
    ("geometric", {}),
    ("nonlinear", {}),
    ("paper", {}),
    ("paper", {"occlusion_compensation": False}),
]


@pytest.mark.parametrize("method,kw", RANGE_RUNS)
def test_range_methods_are_the_same_for_every_chunk_size(
    sensors_and_grid, monkeypatch, method, kw
) -> None:
    """Chunks of 1 and 37 frames against the whole session at once: the same statuses, and
    positions and residuals within 1e-9 m (the solvers batch a chunk's problems by sensor
    pattern, and numpy rounds a batch of a handful differently: ~1e-13 m seen)."""
    sensors, grid = sensors_and_grid
    assert grid.size > 300
    monkeypatch.setattr(fusion_session, "RANGE_CHUNK", 100_000)
    whole = fusion_session.run_method(sensors, grid, method, **kw)
    assert np.isfinite(whole.positions).mean() > 0.9
    for chunk in (1, 37):
        monkeypatch.setattr(fusion_session, "RANGE_CHUNK", chunk)
        got = fusion_session.run_method(sensors, grid, method, **kw)
        np.testing.assert_array_equal(whole.status, got.status)
        np.testing.assert_allclose(got.positions, whole.positions, rtol=0, atol=1e-9)
        np.testing.assert_allclose(got.residual_m, whole.residual_m, rtol=0, atol=1e-9)
        assert (np.isnan(got.positions) == np.isnan(whole.positions)).all()

"""Clock estimation from NTP-style probes and the paper's frame assembly."""

from __future__ import annotations

import numpy as np
import pytest

from kinefuse.capture.sync import assemble_latest, estimate_clock, probe_offsets
from kinefuse.capture.sync.assembly import interp_neighbours, interpolate, latest_in_window
from kinefuse.errors import SyncError
from kinefuse.sim.clock import ClockParams, capture_times, clock_probes, draw_clock


def test_probe_formulas_match_the_paper() -> None:
    # client 5 s ahead, 2 ms one-way delay, 1 ms turnaround
    t1, d, e = 100.0, 0.002, 5.0
    t2 = t1 + d + e
    t3 = t2 + 0.001
    t4 = t3 - e + d
    off, delay, _ = probe_offsets([[t1, t2, t3, t4]])
    assert off[0] == pytest.approx(e, abs=1e-12)
    assert delay[0] == pytest.approx(d, abs=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_estimate_recovers_offset_and_drift(seed: int) -> None:
    rng = np.random.default_rng(seed)
    params = ClockParams(drift_sigma_ppm=40.0)
    clock = draw_clock(rng, params)
    est = estimate_clock(clock_probes(clock, 0.0, 120.0, rng, params))
    assert est.drift_ppm == pytest.approx(clock.drift_ppm, abs=1.0)  # 1 ppm
    t = np.linspace(0.0, 120.0, 50)
    err = est.affine.inverse(clock.affine.forward(t)) - t
    assert np.abs(err).max() < 2e-4  # 0.2 ms, far below a 33 ms frame


def test_estimate_rejects_congested_probes(rng) -> None:
    params = ClockParams()
    clock = draw_clock(rng, params)
    p = clock_probes(clock, 0.0, 60.0, rng, params)
    # a tenth of the probes hit a 40 ms one-way queue on the way back only (asymmetric)
    bad = rng.random(len(p)) < 0.1
    p[bad, 3] += 0.040
    est = estimate_clock(p)
    t = np.linspace(0.0, 60.0, 10)
    assert np.abs(est.affine.inverse(clock.affine.forward(t)) - t).max() < 5e-4


def test_bad_probes_are_an_error() -> None:
    with pytest.raises(SyncError, match=r"shape \(N, 4\)"):
        estimate_clock(np.zeros((3, 3)))
    with pytest.raises(SyncError, match="no usable clock probe"):
        estimate_clock(np.full((2, 4), np.nan))


def test_assembly_takes_latest_within_window(rng) -> None:
    params = ClockParams(frame_drop_prob=0.0)
    caps = [capture_times(draw_clock(rng, params), 0.0, 2.0, rng, params) for _ in range(3)]
    joints = [np.repeat(c.t_true_s[:, None, None], 25, 1).repeat(3, 2) for c in caps]
    states = [np.full((c.seq.size, 25), 2, np.int8) for c in caps]
    frames = np.arange(0.1, 1.9, 1 / 30)
    a = assemble_latest(frames, [c.t_true_s for c in caps], joints, states)
    assert (a.index >= 0).all()
    assert np.nanmax(a.age_s) < 1 / 30 and np.nanmin(a.age_s) >= 0
    # the joint value encodes the capture time: it is the latest one not after the frame time
    np.testing.assert_allclose(a.joints[:, :, 0, 0], frames[:, None] - a.age_s, atol=1e-12)
    # a frame time before any capture gets nothing
    b = assemble_latest([-1.0], [c.t_true_s for c in caps], joints, states)
    assert (b.index == -1).all() and np.isnan(b.joints).all()


def test_latest_in_window_returns_rows_of_the_unsorted_stream() -> None:
    t = np.array([0.30, 0.10, 0.20, 0.20, 0.50])  # any order, with a tie
    rows, age, ok = latest_in_window(t, [0.05, 0.10, 0.25, 0.33, 0.45, 0.55], window_s=0.1)
    # 0.05: nothing yet; 0.10: row 1 (age 0); 0.25: the later of the tied rows (3);
    # 0.33: row 0; 0.45: row 0 is 0.15 s old, outside the window; 0.55: row 4
    np.testing.assert_array_equal(rows, [-1, 1, 3, 0, -1, 4])
    np.testing.assert_array_equal(ok, rows >= 0)
    np.testing.assert_allclose(age[ok], [0.0, 0.05, 0.03, 0.05], atol=1e-12)
    assert np.isnan(age[~ok]).all()
    none_rows, none_age, none_ok = latest_in_window([], [0.0, 1.0], window_s=0.1)
    assert (none_rows == -1).all() and np.isnan(none_age).all() and not none_ok.any()


def test_interpolation_stops_at_gaps_and_takes_the_ends_within_half_a_frame() -> None:
    t = np.array([0.2, 0.0, 0.1, 0.6])  # unsorted; a 0.4 s gap between 0.2 and 0.6
    v = 10.0 * t
    q = np.array([-0.01, -0.03, 0.05, 0.15, 0.4, 0.61, 0.63])
    i0, i1, w, ok = interp_neighbours(t, q, max_gap_s=0.1)
    np.testing.assert_array_equal(ok, [True, False, True, True, False, True, False])
    est = v[i0] * (1 - w) + v[i1] * w
    np.testing.assert_allclose(est[ok], [0.0, 0.5, 1.5, 6.0], atol=1e-12)
    p = interpolate(t, np.stack([v, -v], axis=1), q, max_gap_s=0.1)
    assert p.shape == (q.size, 2)
    np.testing.assert_allclose(p[ok, 0], est[ok], atol=1e-12)
    assert np.isnan(p[~ok]).all()
    # a longer gap limit bridges the gap
    np.testing.assert_allclose(interpolate(t, v, [0.4], max_gap_s=0.5), [4.0], atol=1e-12)

"""The truth of a live run onto the server clock, and the clock figures measured against it.

A small simulated session stands for the one the clients played; a recording made by hand stands
for what ``kinefuse serve`` records (its sensors, its clock start, clock probes made from a known
emulated host clock and known network delays), so every expected figure is known exactly.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from kinefuse.app.workflows.simulate import demo_clip_path, run_simulate
from kinefuse.errors import InputError
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.lab.live_truth import clock_errors, playback_truth, write_live_truth

SERVER_T0 = 5000.0  # CLOCK_MONOTONIC instant the (pretend) server started, s
EPOCH = 5003.5  # the clients' common playback epoch, s
HOST = {"k0": (120.0, 31e-6, 4990.0), "k1": (-7.5, -12e-6, 4991.0)}  # h0, drift, m0


@pytest.fixture(scope="module")
def sim(tmp_path_factory: pytest.TempPathFactory):
    out = tmp_path_factory.mktemp("sim") / "sim.sqlite"
    run_simulate(clip=demo_clip_path(), out=out, sensors=2, seconds=2.0, calibration_s=1.0)
    return out


def _recording(tmp_path, sim, probes_delays: tuple[float, float] | None = None):
    rec = tmp_path / "recording.sqlite"
    sides = {}
    with SessionStore.open(sim) as s, SessionStore.create(rec) as r:
        for info in s.sensors():
            r.add_sensor(info.id, info.serial, info.intrinsics, info.rate_hz)
        r.set_meta("server_t0_monotonic", SERVER_T0)
        for sid, (h0, drift, m0) in HOST.items():
            side = {"sensor_id": sid, "h0": h0, "drift": drift, "m0": m0, "epoch_monotonic": EPOCH}
            sides[sid] = tmp_path / f"{sid}.json"
            sides[sid].write_text(json.dumps(side))
            if probes_delays is not None:
                up, down = probes_delays
                t1 = np.arange(0.0, 20.0, 0.25)
                host = h0 + (1 + drift) * (t1 + up + SERVER_T0 - m0)
                r.append_clock_probes(sid, t1, host, host + 1e-4, t1 + up + 1e-4 + down)
        r.mark_complete()
    return rec, sides


def test_truth_is_moved_onto_the_server_clock(tmp_path, sim) -> None:
    rec, sides = _recording(tmp_path, sim)
    info = write_live_truth(rec, sim, sides)
    shift = EPOCH - SERVER_T0  # true time T was played at monotonic EPOCH + T
    assert info["true_to_server_s"] == pytest.approx(shift, abs=1e-9)
    assert info["spread_ms"] == 0.0
    with SessionStore.open(sim) as s, SessionStore.open(rec) as r:
        ts, tr = s.truth(), r.truth()
        t_sim, j_sim, _ = ts.motion()
        t_rec, j_rec, _ = tr.motion()
        np.testing.assert_allclose(t_rec, t_sim + shift, atol=1e-9)
        np.testing.assert_array_equal(j_rec, j_sim)
        np.testing.assert_allclose(tr.wand()[0], ts.wand()[0] + shift, atol=1e-9)
        for sid, (h0, drift, m0) in HOST.items():
            pose_s, clock_s = ts.sensor(sid)
            pose_r, clock_r = tr.sensor(sid)
            np.testing.assert_array_equal(pose_r, pose_s)
            # the emulated host clock in server terms: host(t + t0) - t = offset + drift t
            t = np.array([0.0, 10.0, 100.0])
            host = h0 + (1 + drift) * (t + SERVER_T0 - m0)
            np.testing.assert_allclose(
                clock_r["host_offset_s"] + clock_r["host_drift_ppm"] * 1e-6 * t, host - t, atol=1e-9
            )
            # the device clock: the same device stamp for the same instant on either clock
            seq, t_true, *_ = ts.observations(sid)
            seq_r, t_server, *_ = tr.observations(sid)
            np.testing.assert_array_equal(seq_r, seq)
            dev_sim = clock_s["offset_s"] + (1 + clock_s["drift_ppm"] * 1e-6) * t_true
            dev_rec = clock_r["offset_s"] + (1 + clock_r["drift_ppm"] * 1e-6) * t_server
            np.testing.assert_allclose(dev_rec, dev_sim, atol=1e-9)
    with pytest.raises(InputError, match="already holds truth"):
        write_live_truth(rec, sim, sides)


def test_clock_error_is_zero_for_symmetric_delays_and_half_the_asymmetry_otherwise(
    tmp_path, sim
) -> None:
    for (up, down), expected_ms in (((0.001, 0.001), 0.0), ((0.003, 0.001), 1.0)):
        folder = tmp_path / f"up{up}"
        folder.mkdir()
        rec, sides = _recording(folder, sim, probes_delays=(up, down))
        write_live_truth(rec, sim, sides)
        with SessionStore.open(rec) as r:
            c = clock_errors(r)
        assert c["source"] == "online estimator replayed over the recorded probes"
        # a constant asymmetry biases every NTP-style estimate by half of it (0.01 ms: rounding)
        assert c["p50"] == pytest.approx(expected_ms, abs=0.01)
        assert c["max"] == pytest.approx(expected_ms, abs=0.01)
        for sid in HOST:
            assert c["by_sensor"][sid]["estimates"] == 80


def test_recorded_estimates_are_preferred_and_each_epoch_warms_up(tmp_path, sim) -> None:
    from kinefuse.formats.store.live_tables import append_clock, create_live_tables

    rec, sides = _recording(tmp_path, sim, probes_delays=(0.001, 0.001))
    write_live_truth(rec, sim, sides)
    with SessionStore.open(rec, writable=True) as r:
        create_live_tables(r)
        truth = r.truth()
        for sid in HOST:
            c = truth.sensor(sid)[1]
            t = np.arange(0.0, 20.0, 0.5)
            true_off = c["host_offset_s"] + c["host_drift_ppm"] * 1e-6 * t
            # 0.5 ms off, except a bad start of each epoch (a reconnect at 10 s) that warms up
            err = np.where((t % 10.0) < 5.0, 0.1, 0.0005)
            rows = [(float(a), float(b), 0.0, 1e-4, int(a >= 10.0))
                    for a, b in zip(t, true_off + err, strict=True)]  # fmt: skip
            append_clock(r, sid, rows)
    with SessionStore.open(rec) as r:
        c = clock_errors(r)
    assert c["source"] == "recorded by the server (live_clock)"
    assert c["p50"] == pytest.approx(0.5, abs=1e-6)
    assert c["max"] == pytest.approx(0.5, abs=1e-6)
    assert c["by_sensor"]["k0"]["epochs"] == 2


def test_sidecars_without_an_epoch_and_bad_ones() -> None:
    clock = {"offset_s": 50.0, "drift_ppm": 10.0, "host_offset_s": 300.0, "host_drift_ppm": -20.0}
    side = {
        "sensor_id": "k0",
        "h0": 1.0,
        "drift": 0.0,
        "m0": 0.0,
        "play_start_monotonic": 100.0,
        "play_start_source_s": 305.0,
        "source_clock": "host",
    }
    p = playback_truth(side, clock)
    # host source time s = 300 + (1 - 20e-6) T is played at monotonic 100 + (s - 305)
    t_true = 12.0
    s = 300.0 + (1 - 20e-6) * t_true
    assert p.mono_at_true0 + p.mono_rate * t_true == pytest.approx(100.0 + s - 305.0, abs=1e-9)
    with pytest.raises(InputError, match="source_clock must be one of"):
        playback_truth({**side, "source_clock": "wall"}, clock)
    with pytest.raises(InputError, match="play_start_monotonic must be a number"):
        playback_truth({k: v for k, v in side.items() if k != "play_start_monotonic"}, clock)

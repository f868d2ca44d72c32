"""Device vs host clocks (issue 9): what the simulated sensors stamp, what the sync recovers, old
stores without host times, and fusion/calibration that never read the truth."""

from __future__ import annotations

import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest

from kinefuse.app import run_simulate
from kinefuse.camera.intrinsics import Intrinsics
from kinefuse.errors import InputError, SyncError
from kinefuse.io.store import SessionStore
from kinefuse.sensors.clock import (
    ClockParams,
    capture_times,
    clock_probes,
    draw_sensor_clocks,
)
from kinefuse.sync import (
    DeviceClockEstimate,
    estimate_clock,
    estimate_device_clock,
    sensor_timebase,
)
from kinefuse.sync.device import NOMINAL_LATENCY_S

ROOT = Path(__file__).resolve().parents[1]


def test_the_device_clock_is_not_the_probed_clock(rng: np.random.Generator) -> None:
    params = ClockParams()
    clocks = draw_sensor_clocks(rng, params)
    cap = capture_times(
        clocks.device, 0.0, 60.0, rng, params,
        host=clocks.host, latency_offset_s=clocks.latency_offset_s,
    )  # fmt: skip
    probes = clock_probes(clocks.host, 0.0, 60.0, rng, params)
    # the probes measure the host clock: through them alone, device stamps land far off
    probed = estimate_clock(probes)
    assert np.abs(probed.to_server(cap.t_sensor_s) - cap.t_true_s).min() > 0.5  # s
    # each frame's arrival on the host clock, after a variable latency
    arrival = clocks.host.to_true(cap.t_receive_host_s) - cap.t_true_s
    assert arrival.std() == pytest.approx(params.latency_sigma_s, rel=0.2)
    assert arrival.mean() == pytest.approx(
        params.latency_mean_s + clocks.latency_offset_s, abs=1e-3
    )
    # device -> host from the two stamps, host -> server from the probes
    tb = sensor_timebase(probes, cap.t_sensor_s, cap.t_receive_host_s)
    err = tb.to_server(cap.t_sensor_s) - cap.t_true_s
    # what is left is this unit's own latency offset, which no client can see (1 ms besides)
    np.testing.assert_allclose(err, clocks.latency_offset_s, atol=0.001)
    assert tb.device.residual_s == pytest.approx(params.latency_sigma_s, rel=0.25)
    rel_drift = (clocks.host.rate / clocks.device.rate - 1.0) * 1e6
    # slope of a 60 s fit through 4 ms of latency jitter: about 5 ppm standard error
    assert tb.device.drift_ppm == pytest.approx(rel_drift, abs=20.0)  # ppm


def test_estimate_device_clock_edge_cases() -> None:
    t = np.arange(100) / 30.0 + 500.0
    assert estimate_device_clock(t, np.full(100, np.nan)) == DeviceClockEstimate.identity()
    short = estimate_device_clock(t[:2], t[:2] + 3.07)
    assert short.offset_s == pytest.approx(3.07 - NOMINAL_LATENCY_S)
    assert short.drift_ppm == 0.0
    with pytest.raises(SyncError, match="must pair up frame by frame, got 100 and 3"):
        estimate_device_clock(t, t[:3])
    with pytest.raises(SyncError, match="latency_s must be a non-negative"):
        estimate_device_clock(t, t, latency_s=-1.0)


# -------------------------------------------------------------------------------------------
# old session stores: no host receive times


_OLD_OBSERVATIONS = """
CREATE TABLE observations (
    sensor_key         INTEGER NOT NULL REFERENCES sensors(key),
    seq                INTEGER NOT NULL,
    t_sensor_s         REAL NOT NULL,
    t_receive_server_s REAL,
    joints_m           BLOB NOT NULL CHECK (length(joints_m) = 600),
    states             BLOB NOT NULL CHECK (length(states) = 25),
    PRIMARY KEY (sensor_key, seq)
) WITHOUT ROWID
"""


def _old_store(path: Path) -> Path:
    """A store as kinefuse wrote it before host receive times were recorded."""
    with SessionStore.create(path) as s:
        s.add_sensor("k0", "A", Intrinsics())
    conn = sqlite3.connect(path)
    conn.execute("DROP TABLE observations")
    conn.execute(_OLD_OBSERVATIONS)
    conn.commit()
    conn.close()
    return path


def test_an_old_store_reads_and_appends_without_host_times(tmp_path: Path) -> None:
    path = _old_store(tmp_path / "old.sqlite")
    j = np.zeros((3, 25, 3))
    st = np.full((3, 25), 2, np.int8)
    with SessionStore.open(path, writable=True) as s:
        s.append_observations("k0", [0, 1, 2], [0.0, 0.033, 0.067], j, st)
        with pytest.raises(InputError, match="written by an older kinefuse without host receive"):
            s.append_observations("k0", [3], [0.1], j[:1], st[:1], t_receive_host_s=[0.2])
        digest = s.observations_digest()
    with SessionStore.open(path) as s:
        obs = s.observations("k0")
        assert obs.n_frames == 3 and np.isnan(obs.t_receive_host_s).all()
        assert s.observations_digest() == digest
    # a new store with the same rows and no host times has the same digest (they hash as before)
    with SessionStore.create(tmp_path / "new.sqlite") as s:
        s.add_sensor("k0", "A", Intrinsics())
        s.append_observations("k0", [0, 1, 2], [0.0, 0.033, 0.067], j, st)
        assert s.observations_digest() == digest
        s.append_observations("k0", [3], [0.1], j[:1], st[:1], t_receive_host_s=[0.2])
        assert s.observations("k0").t_receive_host_s[3] == 0.2
    # without host times the device stamps are taken to be on the probed clock
    tb = sensor_timebase([[0.0, 5.0, 5.0, 0.001]], obs.t_sensor_s, obs.t_receive_host_s)
    np.testing.assert_allclose(tb.to_server(obs.t_sensor_s), obs.t_sensor_s - 5.0, atol=1e-3)


# -------------------------------------------------------------------------------------------
# the truth firewall: calibration and fusion read observations, depth and probes only


def _calibrate_and_fuse(path: Path) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    from kinefuse.calibration.session import calibrate, gather
    from kinefuse.fusion.session import frame_grid, load_sensors, run_method

    with SessionStore.open(path) as store:
        reg = calibrate(gather(store), "full")
        poses = dict(zip(reg.sensor_ids, reg.sensor2world, strict=True))
        sensors = load_sensors(store, poses)
        grid = frame_grid(sensors)
        fused = {m: run_method(sensors, grid, m).positions for m in ("paper", "best")}
    return poses, fused


@pytest.mark.slow
def test_calibration_and_fusion_never_read_the_truth(shared_data: Path, tmp_path: Path) -> None:
    session = run_simulate(
        clip=shared_data / "motion" / "cmu" / "02_walk_a.amc",
        out=tmp_path / "s.sqlite",
        rig=ROOT / "rigs" / "level4.toml",
        seconds=1.0,
        calibration_s=12.0,
        depth_rate_hz=5.0,
    )["out"]
    blind = tmp_path / "blind.sqlite"
    shutil.copyfile(session, blind)
    conn = sqlite3.connect(blind)
    tables = [r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")]
    truth_tables = [t for t in tables if t.startswith("truth_")]
    assert len(truth_tables) >= 5
    for t in truth_tables:
        conn.execute(f"DELETE FROM {t}")  # table names from the schema
    conn.commit()
    conn.close()
    with SessionStore.open(blind) as s:
        assert not s.has_truth()  # nothing left to peek at
    poses, fused = _calibrate_and_fuse(session)
    poses_b, fused_b = _calibrate_and_fuse(blind)
    assert poses.keys() == poses_b.keys()
    for k in poses:
        np.testing.assert_array_equal(poses[k], poses_b[k])
    for m in fused:
        assert np.isfinite(fused[m]).any()
        np.testing.assert_array_equal(fused[m], fused_b[m])

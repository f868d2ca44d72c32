"""The session store: round trips of every table, bad inputs, crash safety, real Kinect data."""

from __future__ import annotations

import json
import sqlite3
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.skeleton import N_JOINTS, TrackingState
from kinefuse.errors import InputError, StoreError
from kinefuse.formats.store.session_store import (
    SCHEMA_VERSION,
    Observations,
    SensorInfo,
    SessionStore,
)

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
WALKER = DATA / "kinect" / "kinect2_tracking" / "walker.json"

SMALL = Intrinsics(width=8, height=6, fx=5.0, fy=5.0, cx=3.5, cy=2.5)


def random_observations(rng: np.random.Generator, n: int, seq0: int = 0):
    """Seeded frames with a mix of states; NaN exactly where not tracked."""
    seq = np.arange(seq0, seq0 + n, dtype=np.int64)
    t = 100.0 + seq / 30.0 + rng.normal(0, 1e-4, n)
    states = rng.integers(0, 3, (n, N_JOINTS)).astype(np.int8)
    joints = rng.normal([0.0, 0.0, 2.5], 0.5, (n, N_JOINTS, 3))
    joints[states == TrackingState.NOT_TRACKED] = np.nan
    t_recv = t + 0.05
    t_recv[::3] = np.nan
    return seq, t, joints, states, t_recv


@pytest.fixture
def store(tmp_path: Path):
    s = SessionStore.create(tmp_path / "s.sqlite")
    s.add_sensor("k0", "SIM-000", Intrinsics(fx=366.1, cx=254.0), rate_hz=30.0)
    s.add_sensor("k1", "SIM-001", SMALL, rate_hz=15.0)
    yield s
    s.close()


# ---------------------------------------------------------------------------------------------
# Round trips


def test_create_and_reopen_meta_and_sensors(tmp_path: Path, store: SessionStore) -> None:
    store.set_meta("seed", 7)
    store.set_meta("phases", {"calibration_s": [0.0, 20.0], "motion_s": [20.0, 80.0]})
    store.set_meta("seed", 8)  # replaces
    store.close()
    with SessionStore.open(tmp_path / "s.sqlite") as s:
        meta = s.meta()
        assert meta["schema_version"] == SCHEMA_VERSION
        assert meta["seed"] == 8
        assert meta["phases"] == {"calibration_s": [0.0, 20.0], "motion_s": [20.0, 80.0]}
        assert isinstance(meta["created"], str)
        sensors = s.sensors()
        assert [x.id for x in sensors] == ["k0", "k1"]
        assert sensors[0] == SensorInfo("k0", "SIM-000", Intrinsics(fx=366.1, cx=254.0), 30.0)
        assert sensors[1].intrinsics == SMALL and sensors[1].rate_hz == 15.0
        assert not s.writable
    # a closed store is one self-contained file in rollback-journal mode
    assert not (tmp_path / "s.sqlite-wal").exists()
    mode = sqlite3.connect(tmp_path / "s.sqlite").execute("PRAGMA journal_mode").fetchone()[0]
    assert mode == "delete"


def test_observations_round_trip_in_seq_order(tmp_path: Path, store: SessionStore) -> None:
    rng = np.random.default_rng(1)
    a = random_observations(rng, 50, seq0=40)
    b = random_observations(rng, 40, seq0=0)  # appended later, earlier seq numbers
    store.append_observations("k0", *a[:4], t_receive_server_s=a[4])
    store.append_observations("k0", *b[:4], t_receive_server_s=b[4])
    store.append_observations("k1", *b[:4])  # receive times unknown
    store.close()
    with SessionStore.open(tmp_path / "s.sqlite") as s:
        obs = s.observations("k0")
        assert isinstance(obs, Observations) and obs.n_frames == 90
        want = [np.concatenate([b[i], a[i]]) for i in range(5)]
        np.testing.assert_array_equal(obs.seq, want[0])
        assert obs.seq.dtype == np.int64
        np.testing.assert_array_equal(obs.t_sensor_s, want[1])  # bit-exact float64
        np.testing.assert_array_equal(obs.joints_m, want[2])  # NaN in the same places
        np.testing.assert_array_equal(obs.states, want[3])
        assert obs.states.dtype == np.int8
        np.testing.assert_array_equal(obs.t_receive_server_s, want[4])
        assert obs.joints_m.flags.writeable
        k1 = s.observations("k1")
        assert np.isnan(k1.t_receive_server_s).all()
        np.testing.assert_array_equal(k1.has_body, (b[3] != 0).any(axis=1))
        assert s.observation_count("k0") == 90
    with SessionStore.open(tmp_path / "s.sqlite", writable=True) as s:
        s.add_sensor("k2", "SIM-002", SMALL)
        e = s.observations("k2")
        assert e.n_frames == 0 and e.joints_m.shape == (0, N_JOINTS, 3)
        assert e.states.shape == (0, N_JOINTS)


def test_empty_append_is_a_no_op(store: SessionStore) -> None:
    store.append_observations("k0", [], [], np.zeros((0, N_JOINTS, 3)), np.zeros((0, N_JOINTS)))
    assert store.observation_count("k0") == 0


def test_observations_digest_is_reproducible(tmp_path: Path) -> None:
    def make(path: Path, nudge: float = 0.0) -> str:
        rng = np.random.default_rng(5)
        with SessionStore.create(path) as s:
            s.add_sensor("k0", "A", SMALL)
            seq, t, j, st, tr = random_observations(rng, 30)
            j[st != 0] += nudge
            s.append_observations("k0", seq, t, j, st, t_receive_server_s=tr)
            return s.observations_digest()

    d1, d2 = make(tmp_path / "a.sqlite"), make(tmp_path / "b.sqlite")
    assert d1 == d2
    assert make(tmp_path / "c.sqlite", nudge=1e-12) != d1


def test_depth_frames_round_trip_in_batches(tmp_path: Path, store: SessionStore) -> None:
    rng = np.random.default_rng(2)
    depth = rng.integers(0, 4500, (7, SMALL.height, SMALL.width)).astype(np.uint16)
    depth[:, 0, :] = 0  # invalid pixels
    store.append_depth_frames("k1", np.arange(3, 10), np.linspace(0, 0.2, 7), depth)
    store.append_depth_frames("k1", [0], [-0.1], depth[:1] // 2)
    assert store.depth_frame_count("k1") == 8
    assert store.depth_frame_count("k0") == 0
    batches = list(store.iter_depth_frames("k1", batch=3))
    assert [b[2].shape for b in batches] == [(3, 6, 8), (3, 6, 8), (2, 6, 8)]
    seq = np.concatenate([b[0] for b in batches])
    t = np.concatenate([b[1] for b in batches])
    d = np.concatenate([b[2] for b in batches])
    np.testing.assert_array_equal(seq, [0, 3, 4, 5, 6, 7, 8, 9])
    np.testing.assert_array_equal(t, np.concatenate([[-0.1], np.linspace(0, 0.2, 7)]))
    assert d.dtype == np.uint16
    np.testing.assert_array_equal(d[0], depth[0] // 2)
    np.testing.assert_array_equal(d[1:], depth)
    assert list(store.iter_depth_frames("k0")) == []


def test_depth_frames_full_size_compress(store: SessionStore) -> None:
    # a smooth wall at 3 m with 1 mm noise: zlib must shrink it well below the raw 434 kB
    rng = np.random.default_rng(3)
    wall = (3000 + rng.normal(0, 1, (2, 424, 512))).round().astype(np.uint16)
    store.append_depth_frames("k0", [0, 1], [0.0, 1 / 30], wall)
    (raw_bytes,) = store._db.execute("SELECT sum(length(depth_mm)) FROM depth_frames").fetchone()
    assert raw_bytes < 0.5 * wall.nbytes
    ((_, _, back),) = list(store.iter_depth_frames("k0"))
    np.testing.assert_array_equal(back, wall)


def test_clock_probes_round_trip(store: SessionStore) -> None:
    rng = np.random.default_rng(4)
    t1 = np.cumsum(rng.uniform(0.5, 1.0, 10))
    t2 = t1 + 0.3 + 0.001
    t3 = t2 + 0.0002
    t4 = t3 - 0.3 + 0.001
    store.append_clock_probes("k0", t1[:6], t2[:6], t3[:6], t4[:6])
    store.append_clock_probes("k0", t1[6:], t2[6:], t3[6:], t4[6:])
    p = store.clock_probes("k0")
    assert p.shape == (10, 4)
    np.testing.assert_array_equal(p, np.stack([t1, t2, t3, t4], axis=-1))
    assert store.clock_probes("k1").shape == (0, 4)


def test_calibration_and_fused_round_trip(store: SessionStore) -> None:
    assert store.calibration("paper") is None
    store.write_calibration("paper", "[sensor.k0]\nx = 1\n")
    store.write_calibration("paper", "[sensor.k0]\nx = 2\n")
    store.write_calibration("full6dof", "ä ü ∞")
    assert store.calibration("paper") == "[sensor.k0]\nx = 2\n"
    assert store.calibration("full6dof") == "ä ü ∞"
    assert store.calibration_names() == ["full6dof", "paper"]

    rng = np.random.default_rng(6)
    assert store.fused("trilateration") is None
    t = np.arange(20) / 30.0
    j = rng.normal(size=(20, N_JOINTS, 3))
    j[3, 5] = np.nan
    status = rng.integers(-3, 4, (20, N_JOINTS)).astype(np.int8)
    store.write_fused("trilateration", t, j, status)
    store.write_fused("trilateration", t[:5], j[:5], status[:5])  # replaces
    store.write_fused("robust", t[:0], j[:0], status[:0])  # an empty result is still a result
    got = store.fused("trilateration")
    assert got is not None
    np.testing.assert_array_equal(got[0], t[:5])
    np.testing.assert_array_equal(got[1], j[:5])
    np.testing.assert_array_equal(got[2], status[:5])
    assert got[2].dtype == np.int8
    empty = store.fused("robust")
    assert empty is not None and empty[1].shape == (0, N_JOINTS, 3)
    assert store.fused_methods() == ["robust", "trilateration"]


def rigid(rng: np.random.Generator) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.linalg.det(q))
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = q, rng.normal(size=3)
    return m


def test_truth_round_trip(tmp_path: Path, store: SessionStore) -> None:
    rng = np.random.default_rng(7)
    assert not store.has_truth()
    t = np.arange(40) / 120.0
    joints = rng.normal(size=(40, N_JOINTS, 3))
    syn = np.zeros(N_JOINTS, bool)
    syn[21:] = True
    store.write_truth_motion(t, joints, syn)
    assert store.has_truth()
    m = rigid(rng)
    clock = {"offset_s": 12.5, "drift_ppm": -31.0, "jitter_s": 0.0005, "latency_s": 0.06}
    store.write_truth_sensor("k0", m, clock)
    seq = np.arange(12)
    t_true = seq / 30.0
    js = rng.normal(size=(12, N_JOINTS, 3))
    vis = rng.random((12, N_JOINTS)) < 0.8
    sw = rng.random(12) < 0.3
    store.append_truth_observations("k0", seq[6:], t_true[6:], js[6:], vis[6:], sw[6:])
    store.append_truth_observations("k0", seq[:6], t_true[:6], js[:6], vis[:6], sw[:6])
    wand_t = np.arange(30) / 120.0
    centre = rng.normal(size=(30, 3))
    store.append_truth_wand(wand_t[:10], centre[:10])
    store.append_truth_wand(wand_t[10:], centre[10:])
    store.close()

    with SessionStore.open(tmp_path / "s.sqlite") as s:
        truth = s.truth()
        t2, j2, syn2 = truth.motion()
        np.testing.assert_array_equal(t2, t)
        np.testing.assert_array_equal(j2, joints)
        np.testing.assert_array_equal(syn2, syn)
        m2, clock2 = truth.sensor("k0")
        np.testing.assert_array_equal(m2, m)
        assert clock2 == clock
        o = truth.observations("k0")
        for got, want in zip(o, (seq, t_true, js, vis, sw), strict=True):
            np.testing.assert_array_equal(got, want)
        assert o[3].dtype == bool and o[4].dtype == bool
        assert truth.observations("k1")[2].shape == (0, N_JOINTS, 3)
        wt, wc = truth.wand()
        np.testing.assert_array_equal(wt, wand_t)
        np.testing.assert_array_equal(wc, centre)
        with pytest.raises(StoreError, match="no true pose stored for sensor 'k1'"):
            truth.sensor("k1")


def test_truth_motion_is_replaced(store: SessionStore) -> None:
    rng = np.random.default_rng(8)
    store.write_truth_motion(np.arange(5.0), rng.normal(size=(5, N_JOINTS, 3)), np.ones(25, bool))
    j = rng.normal(size=(3, N_JOINTS, 3))
    store.write_truth_motion(np.arange(3.0), j, np.zeros(25, bool))
    t, j2, syn = store.truth().motion()
    assert t.shape == (3,) and not syn.any()
    np.testing.assert_array_equal(j2, j)


def test_live_recording_has_no_truth(store: SessionStore) -> None:
    assert not store.has_truth()
    with pytest.raises(StoreError, match="holds no ground truth"):
        store.truth()


# ---------------------------------------------------------------------------------------------
# Crash safety


def test_crash_keeps_committed_appends(tmp_path: Path) -> None:
    """A writer killed mid-append (no close(), no commit) loses only that append."""
    path = tmp_path / "crash.sqlite"
    script = textwrap.dedent(
        f"""
        import os, numpy as np
        from kinefuse.formats.store.session_store import SessionStore
        from kinefuse.core.camera.intrinsics import Intrinsics
        s = SessionStore.create({str(path)!r})
        s.add_sensor("k0", "A", Intrinsics())
        st = np.full((20, 25), 2, np.int8)
        j = np.arange(20 * 75, dtype=float).reshape(20, 25, 3)
        s.append_observations("k0", np.arange(10), np.arange(10) / 30, j[:10], st[:10])
        s.set_meta("phase", "motion")
        # the second append dies half-way through its transaction
        conn = s._db
        conn.execute("BEGIN IMMEDIATE")
        conn.execute("INSERT INTO observations (sensor_key, seq, t_sensor_s, "
                     "t_receive_server_s, joints_m, states) VALUES (1, 10, 0.5, NULL, ?, ?)",
                     (j[10].tobytes(), st[10].tobytes()))
        os._exit(3)
        """
    )
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert r.returncode == 3, r.stderr
    assert (tmp_path / "crash.sqlite-wal").exists()  # the writer never checkpointed
    with SessionStore.open(path) as s:
        obs = s.observations("k0")
        np.testing.assert_array_equal(obs.seq, np.arange(10))
        np.testing.assert_array_equal(
            obs.joints_m, np.arange(20 * 75, dtype=float).reshape(20, 25, 3)[:10]
        )
        assert s.meta()["phase"] == "motion"
    with SessionStore.open(path, writable=True) as s:  # and recording can go on
        s.append_observations("k0", [10], [0.5], np.zeros((1, 25, 3)), np.full((1, 25), 2, np.int8))
        assert s.observation_count("k0") == 11


def test_store_dropped_without_close_reads_back(tmp_path: Path) -> None:
    path = tmp_path / "dropped.sqlite"
    s = SessionStore.create(path)
    s.add_sensor("k0", "A", SMALL)
    rng = np.random.default_rng(9)
    seq, t, j, st, _ = random_observations(rng, 15)
    s.append_observations("k0", seq, t, j, st)
    with SessionStore.open(path) as r:  # a second reader while the writer is still open
        np.testing.assert_array_equal(r.observations("k0").joints_m, j)
    del s
    with SessionStore.open(path) as r:
        np.testing.assert_array_equal(r.observations("k0").joints_m, j)


def test_failed_append_writes_nothing(store: SessionStore) -> None:
    rng = np.random.default_rng(10)
    seq, t, j, st, _ = random_observations(rng, 10)
    store.append_observations("k0", seq[:5], t[:5], j[:5], st[:5])
    with pytest.raises(StoreError, match=r"seq \[4\] already stored"):
        store.append_observations("k0", seq[4:], t[4:], j[4:], st[4:])
    assert store.observation_count("k0") == 5


# ---------------------------------------------------------------------------------------------
# Bad inputs


def test_open_missing_file(tmp_path: Path) -> None:
    with pytest.raises(StoreError, match=r"no session store at .*nope\.sqlite: the file does not"):
        SessionStore.open(tmp_path / "nope.sqlite")


def test_open_not_sqlite(tmp_path: Path) -> None:
    p = tmp_path / "notes.sqlite"
    p.write_text("HIERARCHY\nROOT Hips\n")
    with pytest.raises(StoreError, match=r"is not a SQLite file \(it starts with b'HIERARCHY"):
        SessionStore.open(p)


def test_open_folder(tmp_path: Path) -> None:
    with pytest.raises(StoreError, match="is a folder"):
        SessionStore.open(tmp_path)


def test_open_other_sqlite(tmp_path: Path) -> None:
    p = tmp_path / "other.sqlite"
    sqlite3.connect(p).execute("CREATE TABLE x (a)").connection.commit()
    with pytest.raises(StoreError, match="SQLite file but not a kinefuse session store"):
        SessionStore.open(p)


def test_open_wrong_schema_version(tmp_path: Path) -> None:
    p = tmp_path / "v2.sqlite"
    SessionStore.create(p).close()
    c = sqlite3.connect(p)
    c.execute("UPDATE meta SET value = '2' WHERE key = 'schema_version'")
    c.commit()
    c.close()
    with pytest.raises(StoreError, match=r"schema version 2, but this kinefuse reads version 1"):
        SessionStore.open(p)


def test_create_refuses_existing_unless_overwrite(tmp_path: Path) -> None:
    p = tmp_path / "s.sqlite"
    with SessionStore.create(p) as s:
        s.add_sensor("k0", "A", SMALL)
        s.append_truth_wand([0.0], [[0.0, 0.0, 1.0]])  # a simulation: only those are replaced
    with pytest.raises(StoreError, match="already exists; pass overwrite=True"):
        SessionStore.create(p)
    with SessionStore.create(p, overwrite=True) as s:
        assert s.sensors() == []
    with pytest.raises(StoreError, match="does not exist"):
        SessionStore.create(tmp_path / "no" / "such" / "s.sqlite")


def test_read_only_and_closed(tmp_path: Path, store: SessionStore) -> None:
    store.close()
    with pytest.raises(StoreError, match="is closed; open it again"):
        store.sensors()
    store.close()  # idempotent
    with (
        SessionStore.open(tmp_path / "s.sqlite") as s,
        pytest.raises(
            StoreError,
            match=r"is open read-only \(kinefuse commands store results in a session only when",
        ),
    ):
        s.set_meta("x", 1)


def test_bad_sensor_and_meta(store: SessionStore) -> None:
    with pytest.raises(StoreError, match=r"unknown sensor 'k9' .*sensors: 'k0', 'k1'"):
        store.append_observations("k9", [0], [0.0], np.zeros((1, 25, 3)), np.full((1, 25), 2))
    with pytest.raises(StoreError, match="unknown sensor 'k9'"):
        store.observations("k9")
    with pytest.raises(StoreError, match="sensor 'k0' is already registered"):
        store.add_sensor("k0", "B", SMALL)
    with pytest.raises(InputError, match="sensor id must be a non-empty string"):
        store.add_sensor("", "B", SMALL)
    with pytest.raises(InputError, match="intrinsics must be a kinefuse Intrinsics"):
        store.add_sensor("k5", "B", {"fx": 1})  # type: ignore[arg-type]
    with pytest.raises(InputError, match="rate_hz must be a positive number"):
        store.add_sensor("k5", "B", SMALL, rate_hz=0.0)
    with pytest.raises(InputError, match="must be JSON-able"):
        store.set_meta("rig", {"pos": np.zeros(3)})
    with pytest.raises(InputError, match="must be JSON-able"):
        store.set_meta("x", float("nan"))
    with pytest.raises(InputError, match="'schema_version' is managed by the store"):
        store.set_meta("schema_version", 2)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda a: a.update(joints=a["joints"][:, :24]), r"joints_m must have shape \(N, 25, 3\)"),
        (lambda a: a.update(states=a["states"][:, None]), r"states must have shape \(N, 25\)"),
        (lambda a: a.update(seq=a["seq"][:3]), r"same number of rows, got seq=3, t_sensor_s=4"),
        (lambda a: a.update(seq=a["seq"] * 1.0), "seq must be integers, got dtype float64"),
        (lambda a: a.update(seq=np.array([0, 1, 1, 2])), r"seq has duplicate values \[1\]"),
        (lambda a: a["t"].__setitem__(2, np.nan), "t_sensor_s must be finite; 1 row"),
        (lambda a: a["joints"].__setitem__((0, 0, 0), np.inf), "joints_m contains"),
        (lambda a: a["states"].__setitem__((1, 3), 5), r"TrackingState values 0, 1, 2 .*\[5\]"),
        (lambda a: a["joints"].__setitem__((1, 4, 2), np.nan), "frame 1, joint 4 has state 2"),
        (lambda a: a["states"].__setitem__((2, 7), 0), "frame 2, joint 7 has state 0"),
        (lambda a: a.update(recv=np.array([0.0, np.inf, 0.0, 0.0])), "t_receive_server_s con"),
        (lambda a: a.update(recv=np.zeros(5)), r"t_receive_server_s=5"),
    ],
)
def test_append_observations_rejects(store: SessionStore, change, message) -> None:
    a = {
        "seq": np.arange(4),
        "t": np.arange(4) / 30.0,
        "joints": np.ones((4, N_JOINTS, 3)),
        "states": np.full((4, N_JOINTS), 2, np.int8),
        "recv": None,
    }
    change(a)
    with pytest.raises(InputError, match=message) as info:
        store.append_observations(
            "k0", a["seq"], a["t"], a["joints"], a["states"], t_receive_server_s=a["recv"]
        )
    assert "sensor 'k0'" in str(info.value)
    assert store.observation_count("k0") == 0


def test_bad_depth_frames(store: SessionStore) -> None:
    d = np.zeros((2, SMALL.height, SMALL.width), np.uint16)
    with pytest.raises(InputError, match="depth_mm must be uint16 millimetres, got dtype float64"):
        store.append_depth_frames("k1", [0, 1], [0.0, 0.1], d.astype(float))
    with pytest.raises(InputError, match=r"depth_mm must have shape \(N, 6, 8\), got \(2, 8, 6\)"):
        store.append_depth_frames("k1", [0, 1], [0.0, 0.1], d.transpose(0, 2, 1))
    with pytest.raises(InputError, match=r"depth_mm must have shape \(N, 424, 512\)"):
        store.append_depth_frames("k0", [0, 1], [0.0, 0.1], d)
    store.append_depth_frames("k1", [0, 1], [0.0, 0.1], d)
    with pytest.raises(StoreError, match=r"depth_frames of sensor 'k1': seq \[1\] already"):
        store.append_depth_frames("k1", [1], [0.2], d[:1])
    with pytest.raises(InputError, match="batch must be a positive int"):
        next(store.iter_depth_frames("k1", batch=0))


def test_bad_clock_probes(store: SessionStore) -> None:
    with pytest.raises(InputError, match="probe 1 has t4_server_s < t1_server_s"):
        store.append_clock_probes("k0", [0.0, 1.0], [5.0, 6.0], [5.0, 6.0], [0.1, 0.9])
    with pytest.raises(InputError, match="probe 0 has t3_client_s < t2_client_s"):
        store.append_clock_probes("k0", [0.0], [5.0], [4.9], [0.1])
    with pytest.raises(InputError, match="clock probe times must be finite"):
        store.append_clock_probes("k0", [0.0], [np.nan], [5.0], [0.1])
    with pytest.raises(InputError, match="same number of rows"):
        store.append_clock_probes("k0", [0.0, 1.0], [5.0], [5.0], [0.1])
    with pytest.raises(StoreError, match="unknown sensor 'kx'"):
        store.append_clock_probes("kx", [0.0], [5.0], [5.0], [0.1])


def test_bad_results(store: SessionStore) -> None:
    with pytest.raises(InputError, match="text must be a str"):
        store.write_calibration("paper", b"x")  # type: ignore[arg-type]
    with pytest.raises(InputError, match=r"joints_world must have shape \(N, 25, 3\)"):
        store.write_fused("m", [0.0], np.zeros((1, 3)), np.zeros((1, 25), np.int8))
    with pytest.raises(InputError, match="status must fit int8"):
        store.write_fused("m", [0.0], np.zeros((1, 25, 3)), np.full((1, 25), 300))
    with pytest.raises(InputError, match="t_server_s must be finite"):
        store.write_fused("m", [np.nan], np.zeros((1, 25, 3)), np.zeros((1, 25), np.int8))
    assert store.fused("m") is None


def test_bad_truth(store: SessionStore) -> None:
    rng = np.random.default_rng(11)
    j = rng.normal(size=(3, N_JOINTS, 3))
    with pytest.raises(InputError, match=r"t_s must be strictly increasing, but t_s\[2\]"):
        store.write_truth_motion([0.0, 1.0, 1.0], j, np.zeros(25, bool))
    with pytest.raises(InputError, match="synthesized must be bool, got dtype int64"):
        store.write_truth_motion([0.0, 1.0, 2.0], j, np.zeros(25, np.int64))
    j[1, 2, 0] = np.nan
    with pytest.raises(InputError, match="joints_world must be finite; 1 row"):
        store.write_truth_motion([0.0, 1.0, 2.0], j, np.zeros(25, bool))
    bad = np.eye(4)
    bad[0, 0] = 2.0
    with pytest.raises(InputError, match="sensor2world is not a rigid transform"):
        store.write_truth_sensor("k0", bad, {})
    with pytest.raises(InputError, match="clock must be a dict of str to finite numbers"):
        store.write_truth_sensor("k0", np.eye(4), {"offset_s": float("nan")})
    with pytest.raises(InputError, match="visible must be bool"):
        store.append_truth_observations(
            "k0", [0], [0.0], np.zeros((1, 25, 3)), np.ones((1, 25)), np.zeros(1, bool)
        )
    with pytest.raises(StoreError, match="unknown sensor 'k7'"):
        store.append_truth_observations(
            "k7", [0], [0.0], np.zeros((1, 25, 3)), np.ones((1, 25), bool), np.zeros(1, bool)
        )
    store.append_truth_wand([0.0, 0.1], np.zeros((2, 3)))
    with pytest.raises(InputError, match=r"t_s\[0\]=0.05 is not after the last stored time 0\.1"):
        store.append_truth_wand([0.05], np.zeros((1, 3)))
    with pytest.raises(InputError, match=r"centre_world must have shape \(N, 3\)"):
        store.append_truth_wand([0.2], np.zeros((1, 4)))
    assert store.truth().wand()[0].shape == (2,)


# ---------------------------------------------------------------------------------------------
# Real Kinect v2 body-tracker output through the store


def load_walker(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The first tracked body of every frame in the sensor frame (x right, y down), NaN-masked.

    Kinect camera space is x left, y up; the sensor frame flips both.
    """
    frames = json.loads(path.read_text())["bodyFrame"]
    joints = np.full((len(frames), N_JOINTS, 3), np.nan)
    states = np.zeros((len(frames), N_JOINTS), np.int8)
    for f, frame in enumerate(frames):
        body = next((b for b in frame["bodies"] if b.get("tracked")), None)
        if body is None:
            continue
        for jd in body["joints"]:
            k = jd["jointType"]
            states[f, k] = jd["trackingState"]
            if jd["trackingState"] != 0:
                joints[f, k] = (-jd["cameraX"], -jd["cameraY"], jd["cameraZ"])
    return joints, states


@pytest.mark.skipif(not WALKER.exists(), reason=f"real Kinect data not found at {WALKER}")
def test_real_kinect_frames_round_trip(tmp_path: Path) -> None:
    joints, states = load_walker(WALKER)
    n = joints.shape[0]
    assert n == 330
    with SessionStore.create(tmp_path / "walker.sqlite") as s:
        s.add_sensor("kinect", "walker.json", Intrinsics())
        s.set_meta("source", "kinect2-tracking samples/walker.json (MIT)")
        half = n // 2
        t = np.arange(n) / 30.0
        s.append_observations("kinect", np.arange(half), t[:half], joints[:half], states[:half])
        s.append_observations("kinect", np.arange(half, n), t[half:], joints[half:], states[half:])
    with SessionStore.open(tmp_path / "walker.sqlite") as s:
        obs = s.observations("kinect")
    np.testing.assert_array_equal(obs.joints_m, joints)
    np.testing.assert_array_equal(obs.states, states)
    tracked = obs.joints_m[obs.states == TrackingState.TRACKED]
    # a person walking 1-4 m in front of the sensor
    assert 0.5 < np.median(tracked[:, 2]) < 4.5  # metres
    # sensor frame has y down: the head is above (smaller y than) the spine base
    both = (obs.states[:, 3] == 2) & (obs.states[:, 0] == 2)
    assert (obs.joints_m[both, 3, 1] < obs.joints_m[both, 0, 1]).all()


def test_client_occlusion_flags_and_reading_since_a_sequence(tmp_path, rng) -> None:
    from kinefuse.core.skeleton import N_JOINTS

    with SessionStore.create(tmp_path / "s.sqlite") as st:
        st.add_sensor("k0", "S0", Intrinsics())
        n = 10
        joints = rng.normal([0.0, 0.0, 2.5], 0.3, (n, N_JOINTS, 3))
        states = np.full((n, N_JOINTS), 2, dtype=np.int8)
        occ = rng.random((n, N_JOINTS)) < 0.3
        crossings = rng.integers(0, 5, n)
        st.append_observations("k0", np.arange(n), np.arange(n) / 30, joints, states,
                               occluded=occ, n_crossings=crossings)  # fmt: skip
        o = st.observations("k0")
        np.testing.assert_array_equal(o.occluded, occ)
        np.testing.assert_array_equal(o.n_crossings, crossings)
        new = st.observations("k0", since_seq=6)  # a reader following a live recording
        np.testing.assert_array_equal(new.seq, [7, 8, 9])
        np.testing.assert_array_equal(new.occluded, occ[7:])
        # a frame without the client's flags reads as not occluded; none at all reads as None
        st.append_observations("k0", [10], [10 / 30], joints[:1], states[:1])
        mixed = st.observations("k0", since_seq=8).occluded
        assert mixed is not None and not mixed[1].any()
        np.testing.assert_array_equal(mixed[0], occ[9])
        st.add_sensor("k1", "S1", Intrinsics())
        st.append_observations("k1", [0], [0.0], joints[:1], states[:1])
        assert st.observations("k1").occluded is None
        with pytest.raises(InputError, match="together"):
            st.append_observations("k1", [1], [0.1], joints[:1], states[:1], occluded=occ[:1])
        with pytest.raises(InputError, match="occluded must be bool"):
            st.append_observations("k1", [1], [0.1], joints[:1], states[:1],
                                   occluded=occ[:1].astype(int), n_crossings=[0])  # fmt: skip

"""What a live recording holds beyond an ordinary session: the extra tables of ``kinefuse serve``.

A live recording is an ordinary :class:`~kinefuse.formats.store.session_store.SessionStore`
(sensors, body observations with device, host and server times, clock probes, calibrations, fused
results), so every offline command reads it as it reads a simulated session. The server also records
what only a live run has, in tables this module adds (``CREATE TABLE IF NOT EXISTS``: the store's
own tables and schema version are unchanged, and a reader that does not know them ignores them):

``live_sightings``
    Every wand sighting a client sent: ``seq`` (its depth frame), ``t_device_s``, ``t_host_s``,
    ``t_server_s`` (the capture time on the server clock the live calibration used), the centre
    in the sensor frame (m), the detector's ``score``, ``n_points``, ``residual_m``.
``live_floors``
    A floor plane a client reported (sensor frame: unit up normal, height offset, inliers).
``live_obs_times``
    For each body observation the capture time on the server clock the live fusion used (device
    -> host -> server with the running clock estimates), so an evaluation can compare it with
    the offline mapping.
``live_fused``
    Every fused frame as published: time, joints (world, m), status, variance (m^2), the
    system latency (s) and the server time the recorder took it from the publisher.
``live_clock``
    The server's online clock estimate of each client
    (:class:`~kinefuse.capture.sync.online.OnlineClock`) after every probe reply: server time of the
    reply, offset (client minus server, s), drift (ppm), the offset's standard error (s) and the
    estimator's epoch (resets so far).
``live_events``
    Connections, refusals, disconnections, calibration steps, one row each with the server time
    and a JSON detail.

Writing goes through the store's own transactions; these functions are meant to be called
from the recorder's single writer thread (:mod:`kinefuse.live.server.recorder`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.capture.calibration.floor import FloorPlane
from kinefuse.capture.calibration.register import Sightings
from kinefuse.core.skeleton import N_JOINTS
from kinefuse.errors import StoreError
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.formats.store.store_codec import _json_loads, _numbers, _unblob

Array = NDArray[np.float64]

_J = N_JOINTS * 3 * 8

LIVE_SCHEMA = f"""
CREATE TABLE IF NOT EXISTS live_sightings (
    sensor_key  INTEGER NOT NULL REFERENCES sensors(key),
    seq         INTEGER NOT NULL,
    t_device_s  REAL NOT NULL,
    t_host_s    REAL,
    t_server_s  REAL,
    x_m         REAL NOT NULL,
    y_m         REAL NOT NULL,
    z_m         REAL NOT NULL,
    score       REAL NOT NULL,
    n_points    INTEGER NOT NULL,
    residual_m  REAL,
    PRIMARY KEY (sensor_key, seq)
) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS live_floors (
    sensor_key INTEGER PRIMARY KEY REFERENCES sensors(key),
    t_server_s REAL NOT NULL,
    nx REAL NOT NULL, ny REAL NOT NULL, nz REAL NOT NULL,
    offset_m   REAL NOT NULL,
    n_inliers  INTEGER NOT NULL,
    residual_m REAL
);
CREATE TABLE IF NOT EXISTS live_obs_times (
    sensor_key         INTEGER NOT NULL REFERENCES sensors(key),
    seq                INTEGER NOT NULL,
    t_capture_server_s REAL NOT NULL,
    PRIMARY KEY (sensor_key, seq)
) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS live_fused (
    frame         INTEGER PRIMARY KEY,
    t_server_s    REAL NOT NULL,
    joints_m      BLOB NOT NULL CHECK (length(joints_m) = {_J}),
    status        BLOB NOT NULL CHECK (length(status) = {N_JOINTS}),
    variance_m2   BLOB NOT NULL CHECK (length(variance_m2) = {N_JOINTS * 8}),
    latency_s     REAL,
    t_recorded_s REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS live_clock (
    sensor_key  INTEGER NOT NULL REFERENCES sensors(key),
    idx         INTEGER NOT NULL,
    t_server_s  REAL NOT NULL,
    offset_s    REAL NOT NULL,
    drift_ppm   REAL NOT NULL,
    offset_se_s REAL NOT NULL,
    epoch       INTEGER NOT NULL,
    PRIMARY KEY (sensor_key, idx)
) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS live_events (
    idx        INTEGER PRIMARY KEY,
    t_server_s REAL NOT NULL,
    kind       TEXT NOT NULL,
    sensor_id  TEXT,
    detail     TEXT NOT NULL
);
"""

_F8 = np.dtype("<f8")
_I1 = np.dtype("i1")


def _none_if_nan(x: float) -> float | None:
    return None if not math.isfinite(x) else float(x)


def _nan_for_null(x: object) -> object:
    """SQL NULL as NaN, any other value as read (checked by ``_numbers``)."""
    return np.nan if x is None else x


def has_live_tables(store: SessionStore) -> bool:
    """True if the store was recorded by ``kinefuse serve`` (it has the live tables)."""
    row = store._db.execute(
        "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'live_sightings'"
    ).fetchone()
    return row is not None


def create_live_tables(store: SessionStore) -> None:
    """Add the live tables to a writable store (idempotent)."""
    with store._transaction("create the live tables") as conn:
        for stmt in LIVE_SCHEMA.split(";"):
            if stmt.strip():
                conn.execute(stmt)


# -- rows the recorder appends ----------------------------------------------------------------


@dataclass(frozen=True)
class SightingRow:
    """One wand sighting as received (times in s, centre in the sensor frame, m)."""

    sensor_id: str
    seq: int
    t_device_s: float
    t_host_s: float
    t_server_s: float
    centre_m: tuple[float, float, float]
    score: float
    n_points: int
    residual_m: float


def append_sightings(store: SessionStore, rows: Sequence[SightingRow]) -> None:
    """Append sightings (a sighting already stored under the same sensor and seq is kept)."""
    if not rows:
        return
    vals = [
        (
            store._key(r.sensor_id, "append_sightings"),
            int(r.seq),
            float(r.t_device_s),
            _none_if_nan(r.t_host_s),
            _none_if_nan(r.t_server_s),
            *(float(c) for c in r.centre_m),
            float(r.score),
            int(r.n_points),
            _none_if_nan(r.residual_m),
        )
        for r in rows
    ]
    with store._transaction("append_sightings") as conn:
        conn.executemany(
            "INSERT OR IGNORE INTO live_sightings (sensor_key, seq, t_device_s, t_host_s, "
            "t_server_s, x_m, y_m, z_m, score, n_points, residual_m) "
            "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
            vals,
        )


@dataclass(frozen=True, eq=False)
class StoredSightings:
    """One sensor's recorded sightings, in seq order (see :data:`LIVE_SCHEMA`)."""

    seq: NDArray[np.int64]
    t_device_s: Array
    t_host_s: Array
    t_server_s: Array
    centre_sensor_m: Array
    score: Array
    n_points: NDArray[np.int64]

    def as_sightings(self, t_server_s: Array | None = None) -> Sightings:
        """The registration's input, with these times or the given ones (server clock, s)."""
        t = self.t_server_s if t_server_s is None else t_server_s
        ok = np.isfinite(t)
        return Sightings(t[ok], self.centre_sensor_m[ok], np.maximum(self.score[ok], 1e-3))


def sightings(store: SessionStore, sensor_id: str) -> StoredSightings:
    """The sightings recorded for one sensor (empty arrays when none)."""
    key = store._key(sensor_id, "sightings")
    rows = (
        store._db.execute(
            "SELECT seq, t_device_s, t_host_s, t_server_s, x_m, y_m, z_m, score, n_points "
            "FROM live_sightings WHERE sensor_key = ? ORDER BY seq",
            (key,),
        ).fetchall()
        if has_live_tables(store)
        else []
    )
    what = f"the wand sightings of sensor {sensor_id!r}"
    n = len(rows)
    col = _numbers([[_nan_for_null(r[i]) for i in range(9)] for r in rows], np.float64, what,
                   store.path).reshape(n, 9)  # fmt: skip
    return StoredSightings(
        seq=_numbers(col[:, 0], np.int64, what, store.path),
        t_device_s=col[:, 1].copy(),
        t_host_s=col[:, 2].copy(),
        t_server_s=col[:, 3].copy(),
        centre_sensor_m=col[:, 4:7].copy(),
        score=col[:, 7].copy(),
        n_points=_numbers(col[:, 8], np.int64, what, store.path),
    )


def write_floor(store: SessionStore, sensor_id: str, t_server_s: float, floor: FloorPlane) -> None:
    """Store (or replace) the floor plane a sensor reported."""
    key = store._key(sensor_id, "write_floor")
    n = floor.normal
    with store._transaction("write_floor") as conn:
        conn.execute(
            "INSERT OR REPLACE INTO live_floors (sensor_key, t_server_s, nx, ny, nz, offset_m, "
            "n_inliers, residual_m) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
            (
                key,
                float(t_server_s),
                *map(float, n),
                float(floor.offset_m),
                int(floor.n_inliers),
                _none_if_nan(floor.residual_m),
            ),
        )


def floors(store: SessionStore) -> dict[str, FloorPlane]:
    """The floor planes the sensors reported, by sensor id."""
    if not has_live_tables(store):
        return {}
    ids = {v: k for k, v in store._sensor_keys.items()}
    rows = store._db.execute(
        "SELECT sensor_key, nx, ny, nz, offset_m, n_inliers, residual_m FROM live_floors"
    ).fetchall()
    out: dict[str, FloorPlane] = {}
    for r in rows:
        if r[0] not in ids:
            continue
        what = f"the floor of sensor {ids[r[0]]!r}"
        v = _numbers([_nan_for_null(x) for x in r[1:7]], np.float64, what, store.path)
        try:
            out[ids[r[0]]] = FloorPlane(v[:3], float(v[3]), int(v[4]), float(v[5]))
        except (ValueError, OverflowError) as e:
            raise StoreError(f"{store.path}: {what} is malformed ({e})") from None
    return out


def append_obs_times(
    store: SessionStore, sensor_id: str, seq: Sequence[int], t: Sequence[float]
) -> None:
    """Record the capture times (server clock) the live fusion used for observations."""
    if not seq:
        return
    key = store._key(sensor_id, "append_obs_times")
    with store._transaction("append_obs_times") as conn:
        conn.executemany(
            "INSERT OR REPLACE INTO live_obs_times (sensor_key, seq, t_capture_server_s) "
            "VALUES (?, ?, ?)",
            [(key, int(s), float(x)) for s, x in zip(seq, t, strict=True)],
        )


def obs_times(store: SessionStore, sensor_id: str) -> tuple[NDArray[np.int64], Array]:
    """``(seq, t_capture_server_s)`` the live fusion used for a sensor's observations."""
    key = store._key(sensor_id, "obs_times")
    rows = store._db.execute(
        "SELECT seq, t_capture_server_s FROM live_obs_times WHERE sensor_key = ? ORDER BY seq",
        (key,),
    ).fetchall()
    what = f"the live capture times of sensor {sensor_id!r}"
    return (
        _numbers([r[0] for r in rows], np.int64, what, store.path),
        _numbers([r[1] for r in rows], np.float64, what, store.path),
    )


@dataclass(frozen=True, eq=False)
class FusedRow:
    """One published fused frame."""

    frame: int
    t_server_s: float
    positions_m: Array  # (25, 3)
    status: NDArray[np.int8]  # (25,)
    variance_m2: Array  # (25,)
    latency_s: float
    t_recorded_s: float


def append_fused(store: SessionStore, rows: Sequence[FusedRow]) -> None:
    """Append published fused frames (a frame number already stored is replaced)."""
    if not rows:
        return
    vals = [
        (
            int(r.frame),
            float(r.t_server_s),
            np.ascontiguousarray(r.positions_m, dtype=_F8).tobytes(),
            np.ascontiguousarray(r.status, dtype=_I1).tobytes(),
            np.ascontiguousarray(r.variance_m2, dtype=_F8).tobytes(),
            _none_if_nan(r.latency_s),
            float(r.t_recorded_s),
        )
        for r in rows
    ]
    with store._transaction("append_fused") as conn:
        conn.executemany(
            "INSERT OR REPLACE INTO live_fused (frame, t_server_s, joints_m, status, variance_m2, "
            "latency_s, t_recorded_s) VALUES (?, ?, ?, ?, ?, ?, ?)",
            vals,
        )


@dataclass(frozen=True, eq=False)
class LiveFused:
    """All fused frames of a live recording, in frame order.

    ``frame (T,)``, ``t_server_s (T,)``, ``positions_m (T, 25, 3)`` world, ``status (T, 25)``,
    ``variance_m2 (T, 25)``, ``latency_s (T,)`` (NaN: no observation used),
    ``t_recorded_s (T,)``.
    """

    frame: NDArray[np.int64]
    t_server_s: Array
    positions_m: Array
    status: NDArray[np.int8]
    variance_m2: Array
    latency_s: Array
    t_recorded_s: Array


def live_fused(store: SessionStore) -> LiveFused:
    """The fused frames the server published (empty arrays when none)."""
    rows = (
        store._db.execute(
            "SELECT frame, t_server_s, joints_m, status, variance_m2, latency_s, t_recorded_s "
            "FROM live_fused ORDER BY frame"
        ).fetchall()
        if has_live_tables(store)
        else []
    )
    what, path = "the live fused frames", store.path
    return LiveFused(
        frame=_numbers([r[0] for r in rows], np.int64, what, path),
        t_server_s=_numbers([r[1] for r in rows], np.float64, what, path),
        positions_m=_unblob([r[2] for r in rows], _F8, (N_JOINTS, 3), f"{path}: {what}"),
        status=_unblob([r[3] for r in rows], _I1, (N_JOINTS,), f"{path}: {what}"),
        variance_m2=_unblob([r[4] for r in rows], _F8, (N_JOINTS,), f"{path}: {what}"),
        latency_s=_numbers([_nan_for_null(r[5]) for r in rows], np.float64, what, path),
        t_recorded_s=_numbers([r[6] for r in rows], np.float64, what, path),
    )


def append_clock(
    store: SessionStore, sensor_id: str, rows: Sequence[tuple[float, float, float, float, int]]
) -> None:
    """Append clock estimates ``(t_server_s, offset_s, drift_ppm, offset_se_s, epoch)``."""
    if not rows:
        return
    key = store._key(sensor_id, "append_clock")
    with store._transaction("append_clock") as conn:
        row = conn.execute(
            "SELECT coalesce(max(idx) + 1, 0) FROM live_clock WHERE sensor_key = ?", (key,)
        ).fetchone()
        start = int(row[0])
        conn.executemany(
            "INSERT INTO live_clock (sensor_key, idx, t_server_s, offset_s, drift_ppm, "
            "offset_se_s, epoch) VALUES (?, ?, ?, ?, ?, ?, ?)",
            [
                (key, start + i, float(a), float(b), float(c), float(d), int(e))
                for i, (a, b, c, d, e) in enumerate(rows)
            ],
        )


def clock_estimates(store: SessionStore, sensor_id: str) -> Array:
    """``(N, 5)`` the online clock estimates of one client: ``t_server_s, offset_s, drift_ppm,
    offset_se_s, epoch``."""
    if not has_live_tables(store):
        return np.zeros((0, 5))
    key = store._key(sensor_id, "clock_estimates")
    rows = store._db.execute(
        "SELECT t_server_s, offset_s, drift_ppm, offset_se_s, epoch FROM live_clock "
        "WHERE sensor_key = ? ORDER BY idx",
        (key,),
    ).fetchall()
    what = f"the clock estimates of sensor {sensor_id!r}"
    return _numbers(rows, np.float64, what, store.path).reshape(len(rows), 5)


def append_events(
    store: SessionStore, rows: Sequence[tuple[float, str, str | None, dict[str, Any]]]
) -> None:
    """Append events ``(t_server_s, kind, sensor_id or None, detail)``."""
    if not rows:
        return
    with store._transaction("append_events") as conn:
        conn.executemany(
            "INSERT INTO live_events (t_server_s, kind, sensor_id, detail) VALUES (?, ?, ?, ?)",
            [(float(t), k, s, json.dumps(d, default=str)) for t, k, s, d in rows],
        )


def events(store: SessionStore) -> list[tuple[float, str, str | None, dict[str, Any]]]:
    """The recorded events in order."""
    if not has_live_tables(store):
        return []
    rows = store._db.execute(
        "SELECT t_server_s, kind, sensor_id, detail FROM live_events ORDER BY idx"
    ).fetchall()
    times = _numbers([r[0] for r in rows], np.float64, "the recorded events", store.path)
    return [
        (
            float(t),
            str(k),
            s,
            _json_loads(d, f"the detail of recorded event {k!r}", store.path, dict),
        )
        for t, (_, k, s, d) in zip(times, rows, strict=True)
    ]

"""The session store: one SQLite file per capture session, simulated or recorded live.

A session store holds what the sensors reported (sensors, body-tracker observation streams,
calibration-phase depth frames, clock probes), what later stages computed (calibrations, fused
skeletons) and, for simulated sessions, the ground truth in separate ``truth_*`` tables that only
evaluation code reads (through :meth:`SessionStore.truth`). The schema is documented in
``docs/formats.md`` (section "Session store") and versioned by :data:`SCHEMA_VERSION`.

Safety against partial writes: every append is one SQLite transaction; a process that dies in
the middle of an append loses that append only. While a store is open for writing it runs in
WAL mode (fast commits, durable against a crash of the writing process); :meth:`SessionStore.close`
checkpoints and returns the file to the rollback-journal mode, so a closed session is a single
self-contained file.

Parts of the store live beside it, by what they hold: the sensors' streams (observations, depth
frames, clock probes: :mod:`~kinefuse.formats.store.streams`), the truth (:mod:`~kinefuse.core.
store_truth`), the encodings (:mod:`~kinefuse.formats.store.store_codec`) and the live server's
tables (:mod:`~kinefuse.formats.store.live_tables`). This module keeps the schema and the connection
(about 670 lines: the schema is one text and the class that owns the connection reads it
everywhere).

Arrays are stored as little-endian BLOBs, one row per frame: joints ``float64`` (25 x 3), states
``int8`` (25), depth frames ``uint16`` losslessly compressed (:func:`encode_depth`). Every
BLOB's size is checked on read.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import math
import os
import sqlite3
from collections.abc import Iterator
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.frames.observations import BodyFrames
from kinefuse.core.outputs import APPLICATION_ID, PRIVATE_FILE_MODE, is_kinefuse_session
from kinefuse.core.skeleton import N_JOINTS
from kinefuse.errors import IncompleteSessionError, InputError, KinefuseError, StoreError
from kinefuse.formats.store.store_codec import (
    _F8,
    _I1,
    _JOINTS_BYTES,
    _STATES_BYTES,
    DEPTH_CODEC_MAGIC,
    DEPTH_ZLIB_LEVEL,
    ReadConnection,
    _blobs,
    _column,
    _float_array,
    _int_array,
    _json_dumps,
    _json_loads,
    _numbers,
    _require_finite,
    _require_no_inf,
    _require_same_length,
    _unblob,
    decode_depth,
    encode_depth,
)
from kinefuse.formats.store.streams import SensorStreams
from kinefuse.formats.store.truth import Truth, TruthTables

__all__ = [
    "DEPTH_CODEC_MAGIC",
    "DEPTH_ZLIB_LEVEL",
    "SCHEMA_VERSION",
    "Observations",
    "SensorInfo",
    "SessionStore",
    "Truth",
    "decode_depth",
    "encode_depth",
]

#: Version of the table layout written by this module; :meth:`SessionStore.open` reads only it.
SCHEMA_VERSION = 1


_RESERVED_META = frozenset({"schema_version", "complete", "completed"})

_SCHEMA = f"""
CREATE TABLE meta (
    key   TEXT PRIMARY KEY,
    value TEXT NOT NULL
) WITHOUT ROWID;
CREATE TABLE sensors (
    key        INTEGER PRIMARY KEY,
    id         TEXT NOT NULL UNIQUE,
    serial     TEXT NOT NULL,
    intrinsics TEXT NOT NULL,
    rate_hz    REAL NOT NULL
);
CREATE TABLE observations (
    sensor_key         INTEGER NOT NULL REFERENCES sensors(key),
    seq                INTEGER NOT NULL,
    t_sensor_s         REAL NOT NULL,
    t_receive_server_s REAL,
    joints_m           BLOB NOT NULL CHECK (length(joints_m) = {_JOINTS_BYTES}),
    states             BLOB NOT NULL CHECK (length(states) = {_STATES_BYTES}),
    t_receive_host_s   REAL,
    occluded           BLOB CHECK (occluded IS NULL OR length(occluded) = {_STATES_BYTES}),
    n_crossings        INTEGER CHECK (n_crossings IS NULL OR n_crossings >= 0),
    body_id            INTEGER NOT NULL DEFAULT 0,
    PRIMARY KEY (sensor_key, seq)
) WITHOUT ROWID;
CREATE TABLE observation_bodies (
    sensor_key  INTEGER NOT NULL REFERENCES sensors(key),
    seq         INTEGER NOT NULL,
    idx         INTEGER NOT NULL CHECK (idx >= 1),
    body_id     INTEGER NOT NULL,
    joints_m    BLOB NOT NULL CHECK (length(joints_m) = {_JOINTS_BYTES}),
    states      BLOB NOT NULL CHECK (length(states) = {_STATES_BYTES}),
    occluded    BLOB CHECK (occluded IS NULL OR length(occluded) = {_STATES_BYTES}),
    n_crossings INTEGER CHECK (n_crossings IS NULL OR n_crossings >= 0),
    PRIMARY KEY (sensor_key, seq, idx)
) WITHOUT ROWID;
CREATE TABLE depth_frames (
    sensor_key INTEGER NOT NULL REFERENCES sensors(key),
    seq        INTEGER NOT NULL,
    t_sensor_s REAL NOT NULL,
    height     INTEGER NOT NULL,
    width      INTEGER NOT NULL,
    depth_mm   BLOB NOT NULL,
    PRIMARY KEY (sensor_key, seq)
);
CREATE TABLE clock_probes (
    sensor_key  INTEGER NOT NULL REFERENCES sensors(key),
    idx         INTEGER NOT NULL,
    t1_server_s REAL NOT NULL,
    t2_client_s REAL NOT NULL,
    t3_client_s REAL NOT NULL,
    t4_server_s REAL NOT NULL,
    PRIMARY KEY (sensor_key, idx)
) WITHOUT ROWID;
CREATE TABLE calibrations (
    name TEXT PRIMARY KEY,
    text TEXT NOT NULL
) WITHOUT ROWID;
CREATE TABLE fused_runs (
    method TEXT PRIMARY KEY,
    frames INTEGER NOT NULL
) WITHOUT ROWID;
CREATE TABLE fused (
    method      TEXT NOT NULL,
    frame       INTEGER NOT NULL,
    t_server_s  REAL NOT NULL,
    joints_m    BLOB NOT NULL CHECK (length(joints_m) = {_JOINTS_BYTES}),
    status      BLOB NOT NULL CHECK (length(status) = {_STATES_BYTES}),
    PRIMARY KEY (method, frame)
) WITHOUT ROWID;
CREATE TABLE truth_info (
    key   TEXT PRIMARY KEY,
    value TEXT NOT NULL
) WITHOUT ROWID;
CREATE TABLE truth_motion (
    frame    INTEGER PRIMARY KEY,
    t_s      REAL NOT NULL,
    joints_m BLOB NOT NULL CHECK (length(joints_m) = {_JOINTS_BYTES})
);
CREATE TABLE truth_sensors (
    sensor_key   INTEGER PRIMARY KEY REFERENCES sensors(key),
    sensor2world BLOB NOT NULL CHECK (length(sensor2world) = 128),
    clock        TEXT NOT NULL
);
CREATE TABLE truth_observations (
    sensor_key INTEGER NOT NULL REFERENCES sensors(key),
    seq        INTEGER NOT NULL,
    t_true_s   REAL NOT NULL,
    joints_m   BLOB NOT NULL CHECK (length(joints_m) = {_JOINTS_BYTES}),
    visible    BLOB NOT NULL CHECK (length(visible) = {_STATES_BYTES}),
    swapped    INTEGER NOT NULL CHECK (swapped IN (0, 1)),
    PRIMARY KEY (sensor_key, seq)
) WITHOUT ROWID;
CREATE TABLE truth_people (
    person   INTEGER NOT NULL CHECK (person >= 1),
    frame    INTEGER NOT NULL,
    t_s      REAL NOT NULL,
    joints_m BLOB NOT NULL CHECK (length(joints_m) = {_JOINTS_BYTES}),
    PRIMARY KEY (person, frame)
) WITHOUT ROWID;
CREATE TABLE truth_bodies (
    sensor_key INTEGER NOT NULL REFERENCES sensors(key),
    seq        INTEGER NOT NULL,
    body_id    INTEGER NOT NULL,
    person     INTEGER NOT NULL CHECK (person >= -1),
    PRIMARY KEY (sensor_key, seq, body_id)
) WITHOUT ROWID;
CREATE TABLE truth_wand (
    frame INTEGER PRIMARY KEY,
    t_s   REAL NOT NULL,
    x_m   REAL NOT NULL,
    y_m   REAL NOT NULL,
    z_m   REAL NOT NULL
);
"""

Array = NDArray[np.float64]


# --------------------------------------------------------------------------------------------
# Records


@dataclass(frozen=True)
class SensorInfo:
    """A sensor registered in a session.

    Attributes
    ----------
    id : str
        The session-local sensor id (``"k0"``, ``"front"``, ...).
    serial : str
        The device serial number (simulated sensors get a made-up one).
    intrinsics : Intrinsics
        Depth-camera pinhole model.
    rate_hz : float
        Nominal frame rate.
    """

    id: str
    serial: str
    intrinsics: Intrinsics
    rate_hz: float


#: The batch form of a sensor's stream (:class:`kinefuse.core.frames.observations.BodyFrames`) under
#: the name this module first gave it; :meth:`SessionStore.observations` returns it.
Observations = BodyFrames


class SessionStore(SensorStreams, TruthTables):
    """One capture session in one SQLite file.

    Create with :meth:`create`, open an existing one with :meth:`open`; use as a context manager
    or call :meth:`close`. Reading methods return fresh numpy arrays; appending methods validate
    their input and write it in one transaction.

    Examples
    --------
    >>> with SessionStore.create("s.sqlite") as store:  # doctest: +SKIP
    ...     store.add_sensor("k0", "SIM-0", Intrinsics())
    ...     store.append_observations("k0", seq, t, joints, states)
    """

    path: Path

    def __init__(self, conn: sqlite3.Connection, path: Path, *, writable: bool) -> None:
        """Use :meth:`create` or :meth:`open`; this wraps an already checked connection."""
        self._conn: sqlite3.Connection | None = conn
        self.path = path
        self._writable = writable
        self._sensor_keys: dict[str, int] = {}
        self._load_sensor_keys()
        # sessions written before the host receive time was recorded lack its column
        cols = {r[1] for r in conn.execute("PRAGMA table_info(observations)").fetchall()}
        self._has_host_time = "t_receive_host_s" in cols
        self._has_client_occlusion = "occluded" in cols
        # sessions written before every body was recorded hold one body per frame (id 0)
        self._has_bodies = "body_id" in cols
        tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        # sessions written before bystanders were simulated lack the people's truth tables
        self._has_people_truth = "truth_people" in tables

    # -- opening and closing ------------------------------------------------------------------

    @classmethod
    def create(cls, path: str | PathLike[str], *, overwrite: bool = False) -> SessionStore:
        """Create a new, empty session store at ``path``.

        Parameters
        ----------
        path : path-like
            The ``.sqlite`` file to create; its folder must exist.
        overwrite : bool
            Replace an existing simulated session (and its ``-shm`` companion); any other file,
            a live recording or a session open by a writer is refused
            (:func:`kinefuse.formats.store.session_store.is_simulated_session`). The new store is
            built in place; to keep the old one until the new one is whole, build it in
            :func:`kinefuse.core.outputs.atomic_file` as :func:`kinefuse.sim.lab.simulate_session`
            does.

        Raises
        ------
        StoreError
            The file exists and ``overwrite`` is False, or the folder does not exist.
        OutputError
            ``overwrite`` is True and the file is not a simulated kinefuse session.
        """
        p = Path(path)
        if p.is_dir():
            raise StoreError(f"cannot create a session store at {p}: it is a folder")
        if p.exists() and not overwrite:
            raise StoreError(
                f"{p} already exists; pass overwrite=True to replace it, or choose another path"
            )
        if not p.parent.is_dir():
            raise StoreError(
                f"cannot create a session store at {p}: folder {p.parent} does not exist"
            )
        if overwrite:
            from kinefuse.core.outputs import refuse_unless_ours
            from kinefuse.formats.store.session_store import is_simulated_session

            refuse_unless_ours(p, is_simulated_session, "session")
            for q in (p, *(p.with_name(p.name + s) for s in ("-wal", "-shm", "-journal"))):
                q.unlink(missing_ok=True)
        # made private before SQLite opens it (its -wal and -shm companions take its mode)
        try:
            os.close(os.open(p, os.O_WRONLY | os.O_CREAT | os.O_EXCL, PRIVATE_FILE_MODE))
        except FileExistsError:
            raise StoreError(
                f"{p} already exists; pass overwrite=True to replace it, or choose another path"
            ) from None
        except OSError as e:
            raise StoreError(f"cannot create a session store at {p}: {e.strerror or e}") from None
        conn = sqlite3.connect(p, isolation_level=None)
        try:
            cls._configure_writer(conn)
            conn.execute(f"PRAGMA application_id = {APPLICATION_ID}")
            conn.execute("BEGIN IMMEDIATE")
            for stmt in _SCHEMA.split(";"):
                if stmt.strip():
                    conn.execute(stmt)
            created = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
            conn.executemany(
                "INSERT INTO meta (key, value) VALUES (?, ?)",
                [
                    ("schema_version", json.dumps(SCHEMA_VERSION)),
                    ("created", json.dumps(created)),
                    ("complete", json.dumps(False)),
                ],
            )
            conn.execute("COMMIT")
        except BaseException:
            conn.close()
            raise
        return cls(conn, p, writable=True)

    @classmethod
    def open(cls, path: str | PathLike[str], *, writable: bool = False) -> SessionStore:
        """Open an existing session store.

        Parameters
        ----------
        path : path-like
            A file written by :meth:`create`.
        writable : bool
            Allow appends (default: read only; writing methods then raise :class:`StoreError`).

        Raises
        ------
        StoreError
            The file is missing, is not a SQLite file, is not a kinefuse session store, or has
            another schema version.
        """
        p = Path(path)
        if not p.exists():
            raise StoreError(
                f"no session store at {p}: the file does not exist; check the path, or make one "
                f"with `kinefuse simulate ... --out {p.name}`"
            )
        if p.is_dir():
            raise StoreError(f"{p} is a folder, not a session store file (.sqlite)")
        with p.open("rb") as f:
            head = f.read(16)
        if head and head != b"SQLite format 3\x00":
            raise StoreError(
                f"{p} is not a SQLite file (it starts with {head[:16]!r}); a session store is "
                f"the .sqlite file written by `kinefuse simulate` or a recording"
            )
        conn = cls._connect(p, writable)
        try:
            cls._check_schema(conn, p)
            if writable:
                cls._configure_writer(conn)
            else:
                conn.execute("PRAGMA query_only = ON")
        except sqlite3.DatabaseError as e:
            conn.close()
            raise StoreError(f"{p} is not a readable SQLite file: {e}") from None
        except BaseException:
            conn.close()
            raise
        return cls(conn, p, writable=writable)

    @staticmethod
    def _connect(p: Path, writable: bool) -> sqlite3.Connection:
        """Open ``p`` read-write (never create) or strictly read-only.

        A session opened for reading is opened with ``mode=ro``: nothing can be written to it,
        and it works on read-only media. A file left in WAL mode by a writer that died needs
        its ``-shm`` companion, which cannot be made on read-only media; such a file is then
        read as ``immutable`` (no other process can be writing to read-only media).
        """
        base = p.resolve().as_uri()
        if writable:
            if not os.access(p, os.W_OK) or not os.access(p.parent, os.W_OK | os.X_OK):
                raise StoreError(
                    f"cannot write to {p}: the file or its folder is read-only; copy the "
                    "session somewhere writable, or leave out the option that stores results in it"
                )
            uris = [base + "?mode=rw"]
        else:
            uris = [base + "?mode=ro", base + "?mode=ro&immutable=1"]
        err: sqlite3.Error | None = None
        for uri in uris:
            conn: sqlite3.Connection | None = None
            try:
                if writable:
                    conn = sqlite3.connect(uri, uri=True, isolation_level=None)
                else:  # a query that fails names the file (ReadConnection)
                    conn = sqlite3.connect(
                        uri, uri=True, isolation_level=None, factory=ReadConnection
                    )
                    conn.path = str(p)
                conn.execute("SELECT count(*) FROM sqlite_master").fetchone()
                return conn
            except sqlite3.DatabaseError as e:
                if conn is not None:
                    conn.close()
                if "not a database" in str(e) or "malformed" in str(e):
                    raise StoreError(f"{p} is not a readable SQLite file: {e}") from None
                err = e
        raise StoreError(f"cannot open {p} as a SQLite file: {err}") from None

    @staticmethod
    def _configure_writer(conn: sqlite3.Connection) -> None:
        conn.execute("PRAGMA journal_mode = WAL")
        conn.execute("PRAGMA synchronous = NORMAL")
        conn.execute("PRAGMA foreign_keys = ON")

    @staticmethod
    def _check_schema(conn: sqlite3.Connection, p: Path) -> None:
        try:
            has_meta = conn.execute(
                "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'meta'"
            ).fetchone()
        except sqlite3.DatabaseError as e:
            raise StoreError(f"{p} is not a readable SQLite file: {e}") from None
        if not has_meta:
            raise StoreError(
                f"{p} is a SQLite file but not a kinefuse session store (it has no meta table)"
            )
        row = conn.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()
        version: object = None
        if row is not None:
            with contextlib.suppress(StoreError):
                version = _json_loads(row[0], "the schema version", p)
        if version != SCHEMA_VERSION:
            raise StoreError(
                f"{p} has session-store schema version {version!r}, but this kinefuse reads "
                f"version {SCHEMA_VERSION}; use the kinefuse release that wrote it, or make the "
                f"session again"
            )

    def close(self) -> None:
        """Commit nothing new, checkpoint the WAL into the file and close; idempotent."""
        conn = self._conn
        if conn is None:
            return
        self._conn = None
        try:
            if self._writable:
                # Leave a single self-contained file behind. Fails harmlessly (the file stays
                # in WAL mode) when another connection still has the store open.
                with contextlib.suppress(sqlite3.Error):
                    conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
                    conn.execute("PRAGMA journal_mode = DELETE")
        finally:
            conn.close()

    def __enter__(self) -> SessionStore:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._conn is None else ("writable" if self._writable else "read-only")
        return f"SessionStore({str(self.path)!r}, {state})"

    @property
    def writable(self) -> bool:
        return self._writable

    # -- internals -------------------------------------------------------------------------

    @property
    def _db(self) -> sqlite3.Connection:
        if self._conn is None:
            raise StoreError(f"session store {self.path} is closed; open it again")
        return self._conn

    def _writer(self, what: str) -> sqlite3.Connection:
        conn = self._db
        if not self._writable:
            raise StoreError(
                f"{what}: {self.path} is open read-only (kinefuse commands store results in a "
                "session only when given --store)"
            )
        return conn

    @contextlib.contextmanager
    def _transaction(self, what: str) -> Iterator[sqlite3.Connection]:
        conn = self._writer(what)
        conn.execute("BEGIN IMMEDIATE")
        try:
            yield conn
        except BaseException:
            conn.execute("ROLLBACK")
            raise
        conn.execute("COMMIT")

    def _load_sensor_keys(self) -> None:
        rows = self._db.execute("SELECT id, key FROM sensors").fetchall()
        self._sensor_keys = {str(i): int(k) for i, k in rows}

    def _key(self, sensor_id: str, what: str) -> int:
        try:
            return self._sensor_keys[sensor_id]
        except KeyError:
            known = ", ".join(repr(s) for s in self._sensor_keys) or "none yet"
            raise StoreError(
                f"{what}: unknown sensor {sensor_id!r} in {self.path.name} (sensors: {known}); "
                f"register it first with add_sensor()"
            ) from None

    def _existing_seqs(self, table: str, key: int, seq: NDArray[Any]) -> NDArray[np.int64]:
        lo, hi = int(seq.min()), int(seq.max())
        rows = self._db.execute(
            f"SELECT seq FROM {table} WHERE sensor_key = ? AND seq BETWEEN ? AND ?",
            (key, lo, hi),
        ).fetchall()
        have = np.array([r[0] for r in rows], dtype=np.int64)
        return np.intersect1d(have, seq)

    def _insert_frames(
        self,
        table: str,
        key: int,
        sensor_id: str,
        seq: NDArray[Any],
        sql: str,
        rows: Any,
        bodies: list[tuple[Any, ...]] | None = None,
    ) -> None:
        """Insert ``rows`` by ``sql`` (refusing a seq already stored), and ``bodies``, the
        frames' other bodies (``observation_bodies`` rows), in the same transaction."""
        what = f"{table} of sensor {sensor_id!r}"
        with self._transaction(what) as conn:
            dup = self._existing_seqs(table, key, seq)
            if dup.size:
                raise StoreError(
                    f"{what}: seq {dup[:5].tolist()} already stored ({dup.size} duplicate(s)); "
                    f"sequence numbers must be unique per sensor"
                )
            conn.executemany(sql, rows)
            if bodies:
                conn.executemany(
                    "INSERT INTO observation_bodies (sensor_key, seq, idx, body_id, joints_m, "
                    "states, occluded, n_crossings) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                    bodies,
                )

    # -- metadata ------------------------------------------------------------------------------

    def set_meta(self, key: str, value: object) -> None:
        """Set a metadata entry (phases, generator, seed, clip, rig...) to a JSON-able value."""
        what = f"set_meta({key!r})"
        if not isinstance(key, str) or not key:
            raise InputError(f"set_meta: key must be a non-empty string, got {key!r}")
        if key in _RESERVED_META:
            raise InputError(f"{what}: {key!r} is managed by the store and cannot be set")
        text = _json_dumps(value, what)
        with self._transaction(what) as conn:
            conn.execute("INSERT OR REPLACE INTO meta (key, value) VALUES (?, ?)", (key, text))

    def mark_complete(self) -> None:
        """Record that everything the session should hold has been written (a clean end of a
        simulation or a recording). Until then :attr:`complete` is False."""
        done = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
        with self._transaction("mark_complete") as conn:
            conn.executemany(
                "INSERT OR REPLACE INTO meta (key, value) VALUES (?, ?)",
                [("complete", json.dumps(True)), ("completed", json.dumps(done))],
            )

    @property
    def complete(self) -> bool:
        """True once the writer called :meth:`mark_complete`; False for a session that was
        interrupted (or written by a kinefuse that did not record completion)."""
        row = self._db.execute("SELECT value FROM meta WHERE key = 'complete'").fetchone()
        return row is not None and _json_loads(row[0], "meta entry 'complete'", self.path) is True

    def require_complete(self, *, allow_incomplete: bool = False, flag: str = "--partial") -> None:
        """Raise :class:`IncompleteSessionError` for an incomplete session unless allowed."""
        if self.complete or allow_incomplete:
            return
        raise IncompleteSessionError(
            f"{self.path} is incomplete: the simulation or recording that wrote it did not finish "
            f"(interrupted or failed), so some sensors or frames may be missing; run `kinefuse "
            f"inspect {self.path}` to see what it holds, make it again, or pass {flag} to use "
            "what is there"
        )

    def meta(self) -> dict[str, object]:
        """All metadata, including ``schema_version`` and ``created`` (ISO 8601, UTC)."""
        rows = self._db.execute("SELECT key, value FROM meta ORDER BY key").fetchall()
        return {str(k): _json_loads(v, f"meta entry {k!r}", self.path) for k, v in rows}

    # -- sensors ------------------------------------------------------------------------------

    def add_sensor(
        self, sensor_id: str, serial: str, intrinsics: Intrinsics, rate_hz: float = 30.0
    ) -> None:
        """Register a sensor; its id must be new in this session."""
        what = f"add_sensor({sensor_id!r})"
        if not isinstance(sensor_id, str) or not sensor_id.strip():
            raise InputError(f"add_sensor: sensor id must be a non-empty string, got {sensor_id!r}")
        if not isinstance(serial, str):
            raise InputError(f"{what}: serial must be a string, got {type(serial).__name__}")
        if not isinstance(intrinsics, Intrinsics):
            raise InputError(
                f"{what}: intrinsics must be a kinefuse Intrinsics, got {type(intrinsics).__name__}"
            )
        if not (isinstance(rate_hz, int | float) and math.isfinite(rate_hz) and rate_hz > 0):
            raise InputError(f"{what}: rate_hz must be a positive number, got {rate_hz!r}")
        if sensor_id in self._sensor_keys:
            raise StoreError(f"{what}: sensor {sensor_id!r} is already registered")
        text = _json_dumps(intrinsics.to_dict(), what)
        with self._transaction(what) as conn:
            conn.execute(
                "INSERT INTO sensors (id, serial, intrinsics, rate_hz) VALUES (?, ?, ?, ?)",
                (sensor_id, serial, text, float(rate_hz)),
            )
        self._load_sensor_keys()

    def sensors(self) -> list[SensorInfo]:
        """The registered sensors, in the order they were added."""
        rows = self._db.execute(
            "SELECT id, serial, intrinsics, rate_hz FROM sensors ORDER BY key"
        ).fetchall()
        out = []
        for i, s, k, r in rows:
            rate = _numbers(r, np.float64, f"the rate of sensor {i!r}", self.path)
            out.append(SensorInfo(str(i), str(s), self._intrinsics(str(i), k), float(rate)))
        return out

    def _intrinsics(self, sensor_id: str, text: object) -> Intrinsics:
        """The stored intrinsics of one sensor; a :class:`StoreError` naming the session and the
        sensor when they are not what :meth:`add_sensor` writes."""
        what = f"the intrinsics record of sensor {sensor_id!r}"
        d = _json_loads(text, what, self.path, dict)
        try:
            return Intrinsics.from_dict(d)
        except (KeyError, TypeError, ValueError, OverflowError) as e:
            why = f"no {e}" if isinstance(e, KeyError) else str(e)
            raise StoreError(
                f"{self.path}: {what} is malformed ({why}); the session is damaged or was not "
                "written by kinefuse: restore it from a copy, or make it again"
            ) from None

    def sensor(self, sensor_id: str) -> SensorInfo:
        """One registered sensor by id."""
        self._key(sensor_id, "sensor")
        return next(s for s in self.sensors() if s.id == sensor_id)

    # -- results of later stages ---------------------------------------------------------------

    def write_calibration(self, name: str, text: str) -> None:
        """Store (or replace) a calibration result as text (e.g. TOML) under ``name``."""
        if not isinstance(name, str) or not name:
            raise InputError(f"write_calibration: name must be a non-empty string, got {name!r}")
        if not isinstance(text, str):
            raise InputError(
                f"write_calibration({name!r}): text must be a str, got {type(text).__name__}"
            )
        with self._transaction(f"write_calibration({name!r})") as conn:
            conn.execute(
                "INSERT OR REPLACE INTO calibrations (name, text) VALUES (?, ?)", (name, text)
            )

    def calibration(self, name: str) -> str | None:
        """The calibration text stored under ``name``, or None."""
        row = self._db.execute("SELECT text FROM calibrations WHERE name = ?", (name,)).fetchone()
        return None if row is None else str(row[0])

    def calibration_names(self) -> list[str]:
        """Names of the stored calibrations, sorted."""
        rows = self._db.execute("SELECT name FROM calibrations ORDER BY name").fetchall()
        return [str(r[0]) for r in rows]

    def write_fused(
        self, method: str, t_server_s: ArrayLike, joints_world: ArrayLike, status: ArrayLike
    ) -> None:
        """Store the fused skeleton of ``method``, replacing that method's previous result.

        Parameters
        ----------
        method : str
            Name of the fusion method (``"trilateration"``, ``"robust"``, ...).
        t_server_s : (T,) float
            Frame times on the server's clock, seconds, finite.
        joints_world : (T, 25, 3) float
            Fused joints in the world frame, metres; NaN where nothing could be fused.
        status : (T, 25) int8
            Per-joint status code of the fusion method (-128..127).
        """
        what = f"write_fused({method!r})"
        if not isinstance(method, str) or not method:
            raise InputError(f"write_fused: method must be a non-empty string, got {method!r}")
        t = _float_array(t_server_s, "t_server_s", (None,), what)
        j = _float_array(joints_world, "joints_world", (None, N_JOINTS, 3), what)
        st = _int_array(status, "status", (None, N_JOINTS), what)
        n = _require_same_length(what, t_server_s=t, joints_world=j, status=st)
        _require_finite(t, "t_server_s", what)
        _require_no_inf(j, "joints_world", what)
        if st.size and (st.min() < -128 or st.max() > 127):
            raise InputError(f"{what}: status must fit int8 (-128..127)")
        rows = zip([method] * n, range(n), t.tolist(), _blobs(j, _F8), _blobs(st, _I1), strict=True)
        with self._transaction(what) as conn:
            conn.execute("DELETE FROM fused WHERE method = ?", (method,))
            conn.executemany(
                "INSERT INTO fused (method, frame, t_server_s, joints_m, status) "
                "VALUES (?, ?, ?, ?, ?)",
                rows,
            )
            conn.execute(
                "INSERT OR REPLACE INTO fused_runs (method, frames) VALUES (?, ?)", (method, n)
            )

    def fused(self, method: str) -> tuple[Array, Array, NDArray[np.int8]] | None:
        """``(t_server_s (T,), joints_world (T, 25, 3), status (T, 25) int8)`` or None."""
        what = f"fused result {method!r}"
        known = self._db.execute(
            "SELECT frames FROM fused_runs WHERE method = ?", (method,)
        ).fetchone()
        if known is None:
            return None
        rows = self._db.execute(
            "SELECT t_server_s, joints_m, status FROM fused WHERE method = ? ORDER BY frame",
            (method,),
        ).fetchall()
        return (
            _column(rows, 0, what, self.path),
            _unblob([r[1] for r in rows], _F8, (N_JOINTS, 3), what),
            _unblob([r[2] for r in rows], _I1, (N_JOINTS,), what),
        )

    def fused_methods(self) -> list[str]:
        """Methods that have a stored fused result, sorted."""
        rows = self._db.execute("SELECT method FROM fused_runs ORDER BY method").fetchall()
        return [str(r[0]) for r in rows]


def is_simulated_session(path: Path) -> bool:
    """True if ``path`` is a kinefuse session with ground truth (a simulation, which can be made
    again) and no writer has it open; a live recording, or any other file, is never replaced.

    The one recognizer of a replaceable session: ``kinefuse simulate --force``,
    :func:`kinefuse.sim.lab.simulate_session` and ``SessionStore.create(overwrite=True)``
    all use it."""
    if not is_kinefuse_session(path):
        return False
    if any(path.with_name(path.name + s).exists() for s in ("-wal", "-journal")):
        return False  # open by a writer, or a crashed one left its journal: not ours to drop
    try:
        with SessionStore.open(path) as old:
            return old.has_truth()
    except KinefuseError:
        return False

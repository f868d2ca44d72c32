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

Arrays are stored as little-endian BLOBs, one row per frame: joints ``float64`` (25 x 3), states
``int8`` (25), depth frames ``uint16`` losslessly compressed (:func:`encode_depth`). Every
BLOB's size is checked on read.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import hashlib
import json
import math
import os
import sqlite3
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.camera.intrinsics import Intrinsics
from kinefuse.errors import IncompleteSessionError, InputError, StoreError
from kinefuse.geometry.transforms import check_rigid
from kinefuse.observations import BodyFrames
from kinefuse.skeleton import N_JOINTS, TrackingState

__all__ = [
    "SCHEMA_VERSION",
    "Observations",
    "SensorInfo",
    "SessionStore",
    "Truth",
]

#: Version of the table layout written by this module; :meth:`SessionStore.open` reads only it.
SCHEMA_VERSION = 1

#: ``PRAGMA application_id`` of a kinefuse session store ("KNFS"), so ``file(1)`` can tell.
APPLICATION_ID = 0x4B4E4653

#: zlib level for depth frames: 1 is several times faster than the default 6 and compresses
#: noisy time-of-flight depth nearly as well.
DEPTH_ZLIB_LEVEL = 1

#: First bytes of a depth frame in the "KFD1" codec (see :func:`encode_depth`); frames that do
#: not start with it are plain zlib streams of the uint16 image (sessions written before).
DEPTH_CODEC_MAGIC = b"KFD1"

_F8 = np.dtype("<f8")
_I1 = np.dtype("i1")
_U1 = np.dtype("u1")
_U2 = np.dtype("<u2")
_JOINTS_BYTES = N_JOINTS * 3 * 8
_STATES_BYTES = N_JOINTS
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
    PRIMARY KEY (sensor_key, seq)
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


#: The batch form of a sensor's stream (:class:`kinefuse.observations.BodyFrames`) under the
#: name this module first gave it; :meth:`SessionStore.observations` returns it.
Observations = BodyFrames


# --------------------------------------------------------------------------------------------
# Validation helpers (public boundary: clear messages, InputError)


def _float_array(x: ArrayLike, name: str, shape: tuple[int | None, ...], what: str) -> Array:
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise InputError(f"{what}: {name} must be numeric, got {type(x).__name__} ({e})") from None
    _check_shape(a, name, shape, what)
    return a


def _check_shape(a: np.ndarray, name: str, shape: tuple[int | None, ...], what: str) -> None:
    ok = a.ndim == len(shape) and all(
        s is None or s == d for s, d in zip(shape, a.shape, strict=True)
    )
    if not ok:
        want = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
        raise InputError(f"{what}: {name} must have shape {want}, got {a.shape}")


def _int_array(x: ArrayLike, name: str, shape: tuple[int | None, ...], what: str) -> NDArray[Any]:
    a = np.asarray(x)
    if a.size == 0 and a.dtype.kind == "f":
        a = a.astype(np.int64)
    if a.dtype.kind not in "iu":
        raise InputError(f"{what}: {name} must be integers, got dtype {a.dtype}")
    _check_shape(a, name, shape, what)
    return a


def _require_finite(a: np.ndarray, name: str, what: str) -> None:
    if not np.isfinite(a).all():
        bad = np.flatnonzero(~np.isfinite(a.reshape(a.shape[0], -1)).all(axis=1))
        raise InputError(
            f"{what}: {name} must be finite; {bad.size} row(s) are not, first at index {bad[0]}"
        )


def _require_no_inf(a: np.ndarray, name: str, what: str) -> None:
    if np.isinf(a).any():
        raise InputError(f"{what}: {name} contains +-inf; use NaN for missing values")


def _require_same_length(what: str, **arrays: np.ndarray) -> int:
    lengths = {k: int(v.shape[0]) for k, v in arrays.items()}
    if len(set(lengths.values())) > 1:
        listing = ", ".join(f"{k}={n}" for k, n in lengths.items())
        raise InputError(f"{what}: arrays must have the same number of rows, got {listing}")
    return next(iter(lengths.values()))


def _require_unique(seq: NDArray[Any], what: str) -> None:
    s = np.sort(seq)
    dup = s[1:][s[1:] == s[:-1]]
    if dup.size:
        raise InputError(f"{what}: seq has duplicate values {np.unique(dup)[:5].tolist()}")


def _require_increasing(t: Array, name: str, what: str) -> None:
    if t.size > 1 and not (np.diff(t) > 0).all():
        i = int(np.flatnonzero(np.diff(t) <= 0)[0])
        raise InputError(
            f"{what}: {name} must be strictly increasing, but {name}[{i + 1}]={float(t[i + 1])!r} "
            f"follows {float(t[i])!r}"
        )


def _blobs(a: np.ndarray, dtype: np.dtype) -> list[bytes]:
    """One little-endian BLOB per row of ``a``."""
    b = np.ascontiguousarray(a, dtype=dtype)
    flat = b.reshape(b.shape[0], int(np.prod(b.shape[1:])))
    return [r.tobytes() for r in flat]


def _unblob(blobs: list[bytes], dtype: np.dtype, shape: tuple[int, ...], what: str) -> NDArray[Any]:
    """Stack BLOBs into ``(len(blobs), *shape)``; a :class:`StoreError` on a size mismatch."""
    n_bytes = int(np.prod(shape)) * dtype.itemsize
    if blobs and any(len(b) != n_bytes for b in blobs):
        i = next(i for i, b in enumerate(blobs) if len(b) != n_bytes)
        raise StoreError(
            f"{what}: row {i} holds {len(blobs[i])} bytes where {n_bytes} were expected "
            f"(shape {shape}, {dtype}); the store is corrupt"
        )
    buf = b"".join(blobs)
    out = np.frombuffer(buf, dtype=dtype).reshape((len(blobs), *shape))
    return out.astype(dtype.newbyteorder("="), copy=True)


def encode_depth(depth_mm: NDArray[np.uint16]) -> bytes:
    """Lossless "KFD1" coding of one ``(H, W)`` uint16 depth image.

    Layout: the magic ``KFD1``, then one zlib stream of: the bit-packed mask of pixels with a
    reading (``depth > 0``, row-major, ``ceil(H * W / 8)`` bytes), then the valid pixels' values
    in row-major order as differences from the previous valid pixel (modulo 2**16), stored as
    the plane of low bytes followed by the plane of high bytes. Time-of-flight images are
    mostly "no reading" and smooth apart from noise, so this is about 1.2x smaller than zlib of
    the raw image and faster to make; the noise bounds what any lossless coder can do.
    """
    flat = np.ascontiguousarray(depth_mm, dtype=_U2).reshape(-1)
    valid = flat != 0
    v = flat[valid].astype(np.int32)
    dv = (np.diff(v, prepend=0) & 0xFFFF).astype(_U2)
    planes = dv.view(np.uint8).reshape(-1, 2).T
    payload = np.packbits(valid).tobytes() + np.ascontiguousarray(planes).tobytes()
    return DEPTH_CODEC_MAGIC + zlib.compress(payload, DEPTH_ZLIB_LEVEL)


def decode_depth(blob: bytes, height: int, width: int) -> NDArray[np.uint16]:
    """Inverse of :func:`encode_depth` (also reads the older plain-zlib frames).

    Raises
    ------
    zlib.error, ValueError
        The blob is corrupt.
    """
    if not blob.startswith(DEPTH_CODEC_MAGIC):
        raw = zlib.decompress(blob)
        if len(raw) != 2 * height * width:
            raise ValueError(f"{len(raw)} bytes for a {height}x{width} uint16 image")
        return np.frombuffer(raw, dtype=_U2).reshape(height, width).astype(np.uint16)
    payload = zlib.decompress(blob[len(DEPTH_CODEC_MAGIC) :])
    n = height * width
    n_mask = (n + 7) // 8
    if len(payload) < n_mask:
        raise ValueError("truncated pixel mask")
    valid = np.unpackbits(np.frombuffer(payload[:n_mask], np.uint8), count=n).astype(bool)
    k = int(valid.sum())
    if len(payload) != n_mask + 2 * k:
        raise ValueError(f"{len(payload) - n_mask} value bytes for {k} valid pixels")
    planes = np.frombuffer(payload[n_mask:], np.uint8).reshape(2, k)
    dv = np.ascontiguousarray(planes.T).view(_U2).reshape(k).astype(np.int64)
    out = np.zeros(n, dtype=np.uint16)
    out[valid] = (np.cumsum(dv) & 0xFFFF).astype(np.uint16)
    return out.reshape(height, width)


def _column(rows: list[tuple[Any, ...]], i: int) -> Array:
    """Float column ``i`` of ``rows``; SQL NULL becomes NaN."""
    return np.array([r[i] for r in rows], dtype=np.float64).reshape(len(rows))


def _json_dumps(value: object, what: str) -> str:
    try:
        return json.dumps(value, sort_keys=True, allow_nan=False, separators=(",", ":"))
    except (TypeError, ValueError) as e:
        raise InputError(
            f"{what}: value must be JSON-able (dict, list, str, finite numbers, bool, None); {e}"
        ) from None


# --------------------------------------------------------------------------------------------
# The store


class SessionStore:
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

    # -- opening and closing ------------------------------------------------------------------

    @classmethod
    def create(cls, path: str | PathLike[str], *, overwrite: bool = False) -> SessionStore:
        """Create a new, empty session store at ``path``.

        Parameters
        ----------
        path : path-like
            The ``.sqlite`` file to create; its folder must exist.
        overwrite : bool
            Replace an existing file (and its ``-wal``/``-shm``/``-journal`` companions).

        Raises
        ------
        StoreError
            The file exists and ``overwrite`` is False, or the folder does not exist.
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
            for q in (p, *(p.with_name(p.name + s) for s in ("-wal", "-shm", "-journal"))):
                q.unlink(missing_ok=True)
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
                conn = sqlite3.connect(uri, uri=True, isolation_level=None)
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
            with contextlib.suppress(ValueError):
                version = json.loads(row[0])
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
        self, table: str, key: int, sensor_id: str, seq: NDArray[Any], sql: str, rows: Any
    ) -> None:
        what = f"{table} of sensor {sensor_id!r}"
        with self._transaction(what) as conn:
            dup = self._existing_seqs(table, key, seq)
            if dup.size:
                raise StoreError(
                    f"{what}: seq {dup[:5].tolist()} already stored ({dup.size} duplicate(s)); "
                    f"sequence numbers must be unique per sensor"
                )
            conn.executemany(sql, rows)

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
        return row is not None and json.loads(row[0]) is True

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
        return {str(k): json.loads(v) for k, v in rows}

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
        return [
            SensorInfo(str(i), str(s), Intrinsics.from_dict(json.loads(k)), float(r))
            for i, s, k, r in rows
        ]

    def sensor(self, sensor_id: str) -> SensorInfo:
        """One registered sensor by id."""
        self._key(sensor_id, "sensor")
        return next(s for s in self.sensors() if s.id == sensor_id)

    # -- observations -------------------------------------------------------------------------

    def append_observations(
        self,
        sensor_id: str,
        seq: ArrayLike,
        t_sensor_s: ArrayLike,
        joints_m: ArrayLike,
        states: ArrayLike,
        *,
        t_receive_server_s: ArrayLike | None = None,
        t_receive_host_s: ArrayLike | None = None,
        occluded: ArrayLike | None = None,
        n_crossings: ArrayLike | None = None,
    ) -> None:
        """Append body-tracker frames of one sensor (one transaction).

        Parameters
        ----------
        sensor_id : str
            A sensor registered with :meth:`add_sensor`.
        seq : (N,) int
            Sequence numbers, unique per sensor (also against frames stored before).
        t_sensor_s : (N,) float
            Capture times on the sensor's clock, seconds, finite.
        joints_m : (N, 25, 3) float
            Joints in the sensor frame, metres; NaN exactly where the state is ``NOT_TRACKED``.
        states : (N, 25) int
            :class:`~kinefuse.skeleton.TrackingState` values (0, 1, 2).
        t_receive_server_s : (N,) float, optional
            Arrival times on the server's clock, seconds; NaN (or omitted) where unknown.
        t_receive_host_s : (N,) float, optional
            Arrival times at the sensor's client PC, on its clock, seconds; NaN (or omitted)
            where unknown. A store written before this column existed cannot take them.
        occluded : (N, 25) bool, optional
            The client's occlusion flags; given together with ``n_crossings``.
        n_crossings : (N,) int, optional
            The client's number of bone crossings per frame (>= 0).
        """
        what = f"append_observations(sensor {sensor_id!r})"
        key = self._key(sensor_id, what)
        s = _int_array(seq, "seq", (None,), what)
        t = _float_array(t_sensor_s, "t_sensor_s", (None,), what)
        j = _float_array(joints_m, "joints_m", (None, N_JOINTS, 3), what)
        st = _int_array(states, "states", (None, N_JOINTS), what)
        tr = (
            np.full(t.shape, np.nan)
            if t_receive_server_s is None
            else _float_array(t_receive_server_s, "t_receive_server_s", (None,), what)
        )
        th = (
            np.full(t.shape, np.nan)
            if t_receive_host_s is None
            else _float_array(t_receive_host_s, "t_receive_host_s", (None,), what)
        )
        n = _require_same_length(
            what,
            seq=s,
            t_sensor_s=t,
            joints_m=j,
            states=st,
            t_receive_server_s=tr,
            t_receive_host_s=th,
        )
        if n == 0:
            return
        _require_finite(t, "t_sensor_s", what)
        _require_no_inf(tr, "t_receive_server_s", what)
        _require_no_inf(th, "t_receive_host_s", what)
        if not self._has_host_time and not np.isnan(th).all():
            raise InputError(
                f"{what}: {self.path} was written by an older kinefuse without host receive "
                "times; append to a new session store to record them"
            )
        _require_no_inf(j, "joints_m", what)
        if not np.isin(st, (0, 1, 2)).all():
            bad = np.unique(st[~np.isin(st, (0, 1, 2))])[:5].tolist()
            raise InputError(
                f"{what}: states must be TrackingState values 0, 1, 2 (not tracked, inferred, "
                f"tracked), got {bad}"
            )
        nan = np.isnan(j)
        not_tracked = st == TrackingState.NOT_TRACKED
        bad_nan = (nan.any(axis=-1) != not_tracked) | (nan.all(axis=-1) != not_tracked)
        if bad_nan.any():
            f, jj = np.argwhere(bad_nan)[0]
            raise InputError(
                f"{what}: joints_m must be all-NaN exactly where states is NOT_TRACKED (0); "
                f"frame {f}, joint {jj} has state {int(st[f, jj])} and position "
                f"{j[f, jj].tolist()}"
            )
        _require_unique(s, what)
        occ_rows = self._client_occlusion_rows(occluded, n_crossings, n, what)
        cols: tuple[list[Any], ...] = (
            np.full(n, key).tolist(),
            s.astype(np.int64).tolist(),
            t.tolist(),
            [None if math.isnan(x) else x for x in tr.tolist()],
            _blobs(j, _F8),
            _blobs(st, _I1),
        )
        extra_cols, extra_q = "", ""
        if self._has_host_time:
            cols = (*cols, [None if math.isnan(x) else x for x in th.tolist()])
            extra_cols, extra_q = ", t_receive_host_s", ", ?"
        if self._has_client_occlusion:
            cols = (*cols, *occ_rows)
            extra_cols, extra_q = extra_cols + ", occluded, n_crossings", extra_q + ", ?, ?"
        self._insert_frames(
            "observations",
            key,
            sensor_id,
            s,
            "INSERT INTO observations (sensor_key, seq, t_sensor_s, t_receive_server_s, joints_m,"
            f" states{extra_cols}) VALUES (?, ?, ?, ?, ?, ?{extra_q})",
            zip(*cols, strict=True),
        )

    def _client_occlusion_rows(
        self, occluded: ArrayLike | None, n_crossings: ArrayLike | None, n: int, what: str
    ) -> tuple[list[bytes | None], list[int | None]]:
        """The ``occluded`` and ``n_crossings`` column values of ``n`` rows (NULL when absent)."""
        if occluded is None and n_crossings is None:
            return [None] * n, [None] * n
        if occluded is None or n_crossings is None:
            raise InputError(f"{what}: give the client's occluded flags and n_crossings together")
        if not self._has_client_occlusion:
            raise InputError(
                f"{what}: {self.path} was written by an older kinefuse without the clients' "
                "occlusion flags; append to a new session store to record them"
            )
        occ = np.asarray(occluded)
        if occ.dtype != np.bool_:
            raise InputError(f"{what}: occluded must be bool, got dtype {occ.dtype}")
        _check_shape(occ, "occluded", (n, N_JOINTS), what)
        cr = _int_array(n_crossings, "n_crossings", (n,), what)
        if (cr < 0).any():
            raise InputError(f"{what}: n_crossings must be >= 0")
        blobs: list[bytes | None] = list(_blobs(occ, _U1))
        return blobs, [int(c) for c in cr.tolist()]

    def observations(self, sensor_id: str, *, since_seq: int | None = None) -> BodyFrames:
        """Observations of one sensor ordered by sequence number: all of them, or only those
        after ``since_seq`` (a reader following a live recording asks for what is new)."""
        what = f"observations of sensor {sensor_id!r}"
        key = self._key(sensor_id, what)
        host = ", t_receive_host_s" if self._has_host_time else ", NULL"
        occ = ", occluded, n_crossings" if self._has_client_occlusion else ", NULL, NULL"
        after = -(2**63) if since_seq is None else int(since_seq)
        rows = self._db.execute(
            "SELECT seq, t_sensor_s, t_receive_server_s, joints_m, states"
            f"{host}{occ} FROM observations WHERE sensor_key = ? AND seq > ? ORDER BY seq",
            (key, after),
        ).fetchall()
        flags = [r[6] for r in rows]
        have = [f is not None for f in flags]
        occluded = crossings = None
        if rows and all(have):
            occluded = _unblob(flags, _U1, (N_JOINTS,), what).astype(bool)
            crossings = np.array([r[7] for r in rows], dtype=np.int64)
        elif any(have):  # some frames without flags: NULL rows count as not occluded
            blank = bytes(N_JOINTS)
            occluded = _unblob([f or blank for f in flags], _U1, (N_JOINTS,), what).astype(bool)
            crossings = np.array([r[7] or 0 for r in rows], dtype=np.int64)
        return BodyFrames(
            sensor_id=sensor_id,
            seq=np.array([r[0] for r in rows], dtype=np.int64),
            t_device_s=_column(rows, 1),
            joints_m=_unblob([r[3] for r in rows], _F8, (N_JOINTS, 3), what),
            states=_unblob([r[4] for r in rows], _I1, (N_JOINTS,), what),
            t_receive_server_s=_column(rows, 2),
            t_host_s=_column(rows, 5),
            occluded=occluded,
            n_crossings=crossings,
        )

    def observation_count(self, sensor_id: str) -> int:
        """Number of observation frames stored for one sensor."""
        key = self._key(sensor_id, "observation_count")
        row = self._db.execute(
            "SELECT count(*) FROM observations WHERE sensor_key = ?", (key,)
        ).fetchone()
        return int(row[0])

    def observations_digest(self) -> str:
        """SHA-256 (hex) over every sensor's observation rows, for reproducibility checks.

        Two sessions made by the same calls have the same digest, whatever their creation date.
        """
        h = hashlib.sha256()
        for info in self.sensors():
            h.update(info.id.encode() + b"\x00")
            host = ", t_receive_host_s" if self._has_host_time else ", NULL"
            rows = self._db.execute(
                "SELECT seq, t_sensor_s, t_receive_server_s, joints_m, states"
                f"{host} FROM observations WHERE sensor_key = ? ORDER BY seq",
                (self._sensor_keys[info.id],),
            )
            for seq, t, tr, j, st, th in rows:
                h.update(np.array([seq], "<i8").tobytes())
                h.update(np.array([t, np.nan if tr is None else tr], _F8).tobytes())
                h.update(j)
                h.update(st)
                if th is not None:  # rows without a host time hash as before
                    h.update(np.array([th], _F8).tobytes())
        return h.hexdigest()

    # -- depth frames -------------------------------------------------------------------------

    def append_depth_frames(
        self, sensor_id: str, seq: ArrayLike, t_sensor_s: ArrayLike, depth_mm: ArrayLike
    ) -> None:
        """Append calibration-phase depth frames of one sensor (zlib-compressed, one transaction).

        Parameters
        ----------
        sensor_id : str
        seq : (N,) int
            Sequence numbers, unique per sensor.
        t_sensor_s : (N,) float
            Capture times on the sensor's clock, seconds.
        depth_mm : (N, H, W) uint16
            Depth images in millimetres (0 = no reading); ``H, W`` must be the sensor's image size.
        """
        what = f"append_depth_frames(sensor {sensor_id!r})"
        key = self._key(sensor_id, what)
        intr = self.sensor(sensor_id).intrinsics
        s = _int_array(seq, "seq", (None,), what)
        t = _float_array(t_sensor_s, "t_sensor_s", (None,), what)
        d = np.asarray(depth_mm)
        if d.dtype != np.uint16:
            raise InputError(
                f"{what}: depth_mm must be uint16 millimetres, got dtype {d.dtype}; convert "
                f"with np.round(depth_m * 1000).astype(np.uint16)"
            )
        _check_shape(d, "depth_mm", (None, intr.height, intr.width), what)
        n = _require_same_length(what, seq=s, t_sensor_s=t, depth_mm=d)
        if n == 0:
            return
        _require_finite(t, "t_sensor_s", what)
        _require_unique(s, what)
        d = np.ascontiguousarray(d, dtype=_U2)
        blobs = [encode_depth(f) for f in d]
        rows = zip(
            np.full(n, key).tolist(),
            s.astype(np.int64).tolist(),
            t.tolist(),
            [intr.height] * n,
            [intr.width] * n,
            blobs,
            strict=True,
        )
        self._insert_frames(
            "depth_frames",
            key,
            sensor_id,
            s,
            "INSERT INTO depth_frames (sensor_key, seq, t_sensor_s, height, width, depth_mm) "
            "VALUES (?, ?, ?, ?, ?, ?)",
            rows,
        )

    def depth_frame_count(self, sensor_id: str) -> int:
        """Number of depth frames stored for one sensor."""
        key = self._key(sensor_id, "depth_frame_count")
        row = self._db.execute(
            "SELECT count(*) FROM depth_frames WHERE sensor_key = ?", (key,)
        ).fetchone()
        return int(row[0])

    def storage_bytes(self) -> dict[str, int]:
        """Bytes on disk: the whole file (``file``) and the BLOBs of depth frames
        (``depth_frames``, compressed) and body observations (``observations``)."""
        depth = self._db.execute("SELECT coalesce(sum(length(depth_mm)), 0) FROM depth_frames")
        obs = self._db.execute(
            "SELECT coalesce(sum(length(joints_m) + length(states)), 0) FROM observations"
        )
        return {
            "file": self.path.stat().st_size,
            "depth_frames": int(depth.fetchone()[0]),
            "observations": int(obs.fetchone()[0]),
        }

    def iter_depth_frames(
        self, sensor_id: str, *, batch: int = 32
    ) -> Iterator[tuple[NDArray[np.int64], Array, NDArray[np.uint16]]]:
        """Depth frames of one sensor in seq order, ``batch`` at a time.

        Yields
        ------
        seq : (n,) int64
        t_sensor_s : (n,) float
        depth_mm : (n, H, W) uint16
        """
        what = f"depth frames of sensor {sensor_id!r}"
        key = self._key(sensor_id, what)
        if not (isinstance(batch, int) and batch > 0):
            raise InputError(f"iter_depth_frames: batch must be a positive int, got {batch!r}")
        cur = self._db.execute(
            "SELECT seq, t_sensor_s, height, width, depth_mm FROM depth_frames "
            "WHERE sensor_key = ? ORDER BY seq",
            (key,),
        )
        try:
            while rows := cur.fetchmany(batch):
                shapes = {(int(r[2]), int(r[3])) for r in rows}
                if len(shapes) != 1:
                    raise StoreError(f"{what}: frames of different sizes {sorted(shapes)}")
                (h, w) = shapes.pop()
                frames = np.empty((len(rows), h, w), dtype=np.uint16)
                for i, r in enumerate(rows):
                    try:
                        frames[i] = decode_depth(r[4], h, w)
                    except (zlib.error, ValueError) as e:
                        raise StoreError(f"{what}: frame seq {r[0]} is corrupt ({e})") from None
                yield (
                    np.array([r[0] for r in rows], dtype=np.int64),
                    _column(rows, 1),
                    frames,
                )
        finally:
            cur.close()

    # -- clock probes -------------------------------------------------------------------------

    def append_clock_probes(
        self,
        sensor_id: str,
        t1_server_s: ArrayLike,
        t2_client_s: ArrayLike,
        t3_client_s: ArrayLike,
        t4_server_s: ArrayLike,
    ) -> None:
        """Append NTP-style clock probes between the server and one sensor's client.

        Parameters
        ----------
        sensor_id : str
        t1_server_s, t4_server_s : (N,) float
            Request sent and reply received, server clock, seconds (``t4 >= t1``).
        t2_client_s, t3_client_s : (N,) float
            Request received and reply sent, client clock, seconds (``t3 >= t2``).
        """
        what = f"append_clock_probes(sensor {sensor_id!r})"
        key = self._key(sensor_id, what)
        names = ("t1_server_s", "t2_client_s", "t3_client_s", "t4_server_s")
        cols = [
            _float_array(a, nm, (None,), what)
            for a, nm in zip(
                (t1_server_s, t2_client_s, t3_client_s, t4_server_s), names, strict=True
            )
        ]
        n = _require_same_length(what, **dict(zip(names, cols, strict=True)))
        if n == 0:
            return
        t = np.stack(cols, axis=-1)
        _require_finite(t, "clock probe times", what)
        if (t[:, 3] < t[:, 0]).any():
            i = int(np.flatnonzero(t[:, 3] < t[:, 0])[0])
            raise InputError(f"{what}: probe {i} has t4_server_s < t1_server_s (reply before send)")
        if (t[:, 2] < t[:, 1]).any():
            i = int(np.flatnonzero(t[:, 2] < t[:, 1])[0])
            raise InputError(
                f"{what}: probe {i} has t3_client_s < t2_client_s (reply before receipt)"
            )
        with self._transaction(what) as conn:
            row = conn.execute(
                "SELECT coalesce(max(idx) + 1, 0) FROM clock_probes WHERE sensor_key = ?", (key,)
            ).fetchone()
            start = int(row[0])
            conn.executemany(
                "INSERT INTO clock_probes (sensor_key, idx, t1_server_s, t2_client_s, "
                "t3_client_s, t4_server_s) VALUES (?, ?, ?, ?, ?, ?)",
                [(key, start + i, *r) for i, r in enumerate(t.tolist())],
            )

    def clock_probes(self, sensor_id: str) -> Array:
        """``(N, 4)`` clock probes ``t1_server_s, t2_client_s, t3_client_s, t4_server_s``."""
        key = self._key(sensor_id, f"clock probes of sensor {sensor_id!r}")
        rows = self._db.execute(
            "SELECT t1_server_s, t2_client_s, t3_client_s, t4_server_s FROM clock_probes "
            "WHERE sensor_key = ? ORDER BY idx",
            (key,),
        ).fetchall()
        return np.array(rows, dtype=np.float64).reshape(len(rows), 4)

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
            _column(rows, 0),
            _unblob([r[1] for r in rows], _F8, (N_JOINTS, 3), what),
            _unblob([r[2] for r in rows], _I1, (N_JOINTS,), what),
        )

    def fused_methods(self) -> list[str]:
        """Methods that have a stored fused result, sorted."""
        rows = self._db.execute("SELECT method FROM fused_runs ORDER BY method").fetchall()
        return [str(r[0]) for r in rows]

    # -- ground truth (simulator writes; evaluation code reads via truth()) ----------------

    def write_truth_motion(
        self, t_s: ArrayLike, joints_world: ArrayLike, synthesized: ArrayLike
    ) -> None:
        """Store (replace) the true motion.

        Parameters
        ----------
        t_s : (T,) float
            Times on the true (simulation) clock, seconds, strictly increasing.
        joints_world : (T, 25, 3) float
            True joints in the world frame, metres, finite.
        synthesized : (25,) bool
            True for joints the motion source lacked and that were synthesized.
        """
        what = "write_truth_motion"
        t = _float_array(t_s, "t_s", (None,), what)
        j = _float_array(joints_world, "joints_world", (None, N_JOINTS, 3), what)
        syn = np.asarray(synthesized)
        if syn.dtype != np.bool_:
            raise InputError(f"{what}: synthesized must be bool, got dtype {syn.dtype}")
        _check_shape(syn, "synthesized", (N_JOINTS,), what)
        n = _require_same_length(what, t_s=t, joints_world=j)
        if n == 0:
            raise InputError(f"{what}: the motion has no frames")
        _require_finite(t, "t_s", what)
        _require_finite(j, "joints_world", what)
        _require_increasing(t, "t_s", what)
        with self._transaction(what) as conn:
            conn.execute("DELETE FROM truth_motion")
            conn.executemany(
                "INSERT INTO truth_motion (frame, t_s, joints_m) VALUES (?, ?, ?)",
                zip(range(n), t.tolist(), _blobs(j, _F8), strict=True),
            )
            conn.execute(
                "INSERT OR REPLACE INTO truth_info (key, value) VALUES ('synthesized', ?)",
                (json.dumps(syn.tolist()),),
            )

    def write_truth_sensor(
        self, sensor_id: str, sensor2world: ArrayLike, clock: dict[str, float]
    ) -> None:
        """Store (replace) a sensor's true pose and true clock parameters.

        Parameters
        ----------
        sensor_id : str
        sensor2world : (4, 4) float
            Rigid transform from the sensor frame to the world frame.
        clock : dict of str to float
            The true clock (offset, drift, jitter, latency... as the simulator defines them).
        """
        what = f"write_truth_sensor(sensor {sensor_id!r})"
        key = self._key(sensor_id, what)
        m = check_rigid(_float_array(sensor2world, "sensor2world", (4, 4), what),
                        f"{what}: sensor2world")  # fmt: skip
        if not isinstance(clock, dict) or not all(
            isinstance(k, str) and isinstance(v, int | float) and math.isfinite(v)
            for k, v in clock.items()
        ):
            raise InputError(
                f"{what}: clock must be a dict of str to finite numbers, got {clock!r}"
            )
        text = _json_dumps({k: float(v) for k, v in clock.items()}, what)
        with self._transaction(what) as conn:
            conn.execute(
                "INSERT OR REPLACE INTO truth_sensors (sensor_key, sensor2world, clock) "
                "VALUES (?, ?, ?)",
                (key, np.ascontiguousarray(m, _F8).tobytes(), text),
            )

    def append_truth_observations(
        self,
        sensor_id: str,
        seq: ArrayLike,
        t_true_s: ArrayLike,
        joints_sensor: ArrayLike,
        visible: ArrayLike,
        swapped: ArrayLike,
    ) -> None:
        """Append the truth behind a sensor's observation frames (same ``seq`` numbers).

        Parameters
        ----------
        sensor_id : str
        seq : (N,) int
            Sequence numbers of the observation frames described.
        t_true_s : (N,) float
            True capture instants (simulation clock), seconds.
        joints_sensor : (N, 25, 3) float
            True joints in the sensor frame at the capture instant, metres, finite.
        visible : (N, 25) bool
            True where the joint is in view and not hidden by the body.
        swapped : (N,) bool
            True for frames the tracker reported left/right swapped.
        """
        what = f"append_truth_observations(sensor {sensor_id!r})"
        key = self._key(sensor_id, what)
        s = _int_array(seq, "seq", (None,), what)
        t = _float_array(t_true_s, "t_true_s", (None,), what)
        j = _float_array(joints_sensor, "joints_sensor", (None, N_JOINTS, 3), what)
        v = np.asarray(visible)
        w = np.asarray(swapped)
        for a, nm in ((v, "visible"), (w, "swapped")):
            if a.dtype != np.bool_:
                raise InputError(f"{what}: {nm} must be bool, got dtype {a.dtype}")
        _check_shape(v, "visible", (None, N_JOINTS), what)
        _check_shape(w, "swapped", (None,), what)
        n = _require_same_length(what, seq=s, t_true_s=t, joints_sensor=j, visible=v, swapped=w)
        if n == 0:
            return
        _require_finite(t, "t_true_s", what)
        _require_finite(j, "joints_sensor", what)
        _require_unique(s, what)
        rows = zip(
            np.full(n, key).tolist(),
            s.astype(np.int64).tolist(),
            t.tolist(),
            _blobs(j, _F8),
            _blobs(v, _U1),
            w.astype(np.int64).tolist(),
            strict=True,
        )
        self._insert_frames(
            "truth_observations",
            key,
            sensor_id,
            s,
            "INSERT INTO truth_observations (sensor_key, seq, t_true_s, joints_m, visible, "
            "swapped) VALUES (?, ?, ?, ?, ?, ?)",
            rows,
        )

    def append_truth_wand(self, t_s: ArrayLike, centre_world: ArrayLike) -> None:
        """Append the true wand centre over time.

        Parameters
        ----------
        t_s : (T,) float
            Times on the simulation clock, seconds, strictly increasing and after those stored.
        centre_world : (T, 3) float
            Wand (sphere) centre in the world frame, metres, finite.
        """
        what = "append_truth_wand"
        t = _float_array(t_s, "t_s", (None,), what)
        c = _float_array(centre_world, "centre_world", (None, 3), what)
        n = _require_same_length(what, t_s=t, centre_world=c)
        if n == 0:
            return
        _require_finite(t, "t_s", what)
        _require_finite(c, "centre_world", what)
        _require_increasing(t, "t_s", what)
        with self._transaction(what) as conn:
            last = conn.execute("SELECT max(frame), max(t_s) FROM truth_wand").fetchone()
            start = 0 if last[0] is None else int(last[0]) + 1
            if last[1] is not None and t[0] <= last[1]:
                raise InputError(
                    f"{what}: t_s[0]={float(t[0])!r} is not after the last stored time {last[1]!r}"
                )
            conn.executemany(
                "INSERT INTO truth_wand (frame, t_s, x_m, y_m, z_m) VALUES (?, ?, ?, ?, ?)",
                [
                    (start + i, ti, *ci)
                    for i, (ti, ci) in enumerate(zip(t.tolist(), c.tolist(), strict=True))
                ],
            )

    def write_truth_info(self, key: str, value: object) -> None:
        """Store (replace) a JSON-able piece of truth under ``key`` (e.g. the true movement axes
        of a range-of-motion phase); read back only by evaluation code, via :meth:`Truth.info`."""
        what = f"write_truth_info({key!r})"
        if not isinstance(key, str) or not key or key == "synthesized":
            raise InputError(f"{what}: key must be a non-empty string other than 'synthesized'")
        text = _json_dumps(value, what)
        with self._transaction(what) as conn:
            conn.execute(
                "INSERT OR REPLACE INTO truth_info (key, value) VALUES (?, ?)", (key, text)
            )

    def has_truth(self) -> bool:
        """True if the session holds any ground truth (a simulated session)."""
        for table in ("truth_motion", "truth_sensors", "truth_observations", "truth_wand"):
            if self._db.execute(f"SELECT 1 FROM {table} LIMIT 1").fetchone():
                return True
        return False

    def truth(self) -> Truth:
        """Read-only access to the ground truth; for evaluation code only.

        Raises
        ------
        StoreError
            The session has no ground truth (a live recording).
        """
        if not self.has_truth():
            raise StoreError(
                f"{self.path.name} holds no ground truth (a live recording?); only simulated "
                f"sessions can be evaluated against the truth"
            )
        return Truth(self)


class Truth:
    """Read-only accessor to a session's ground truth (the ``truth_*`` tables).

    Only evaluation code uses it; the system under test never reads the truth.
    """

    def __init__(self, store: SessionStore) -> None:
        self._store = store

    def motion(self) -> tuple[Array, Array, NDArray[np.bool_]]:
        """``(t_s (T,), joints_world (T, 25, 3), synthesized (25,) bool)``."""
        db = self._store._db
        rows = db.execute("SELECT t_s, joints_m FROM truth_motion ORDER BY frame").fetchall()
        info = db.execute("SELECT value FROM truth_info WHERE key = 'synthesized'").fetchone()
        if not rows or info is None:
            raise StoreError(f"{self._store.path.name} holds no true motion")
        syn = np.array(json.loads(info[0]), dtype=bool)
        joints = _unblob([r[1] for r in rows], _F8, (N_JOINTS, 3), "truth motion")
        return _column(rows, 0), joints, syn

    def info(self, key: str) -> object | None:
        """The truth stored under ``key`` by :meth:`SessionStore.write_truth_info`, or None."""
        row = self._store._db.execute(
            "SELECT value FROM truth_info WHERE key = ?", (key,)
        ).fetchone()
        return None if row is None else json.loads(row[0])

    def sensor(self, sensor_id: str) -> tuple[Array, dict[str, float]]:
        """``(sensor2world (4, 4), clock dict)`` of one sensor."""
        key = self._store._key(sensor_id, "truth sensor")
        row = self._store._db.execute(
            "SELECT sensor2world, clock FROM truth_sensors WHERE sensor_key = ?", (key,)
        ).fetchone()
        if row is None:
            raise StoreError(f"no true pose stored for sensor {sensor_id!r}")
        m = _unblob([row[0]], _F8, (4, 4), f"true pose of sensor {sensor_id!r}")[0]
        return m, {str(k): float(v) for k, v in json.loads(row[1]).items()}

    def observations(
        self, sensor_id: str
    ) -> tuple[NDArray[np.int64], Array, Array, NDArray[np.bool_], NDArray[np.bool_]]:
        """``(seq (N,), t_true_s (N,), joints_sensor (N, 25, 3), visible (N, 25), swapped (N,))``.

        Ordered by seq; empty arrays if the simulator wrote none for this sensor.
        """
        what = f"truth observations of sensor {sensor_id!r}"
        key = self._store._key(sensor_id, what)
        rows = self._store._db.execute(
            "SELECT seq, t_true_s, joints_m, visible, swapped FROM truth_observations "
            "WHERE sensor_key = ? ORDER BY seq",
            (key,),
        ).fetchall()
        vis = _unblob([r[3] for r in rows], _U1, (N_JOINTS,), what)
        return (
            np.array([r[0] for r in rows], dtype=np.int64),
            _column(rows, 1),
            _unblob([r[2] for r in rows], _F8, (N_JOINTS, 3), what),
            vis.astype(bool),
            np.array([r[4] for r in rows], dtype=bool).reshape(len(rows)),
        )

    def wand(self) -> tuple[Array, Array]:
        """``(t_s (T,), centre_world (T, 3))``; empty arrays if no wand was simulated."""
        rows = self._store._db.execute(
            "SELECT t_s, x_m, y_m, z_m FROM truth_wand ORDER BY frame"
        ).fetchall()
        a = np.array(rows, dtype=np.float64).reshape(len(rows), 4)
        return a[:, 0].copy(), a[:, 1:].copy()

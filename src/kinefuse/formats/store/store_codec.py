"""The session store's encodings: validation of what goes in, BLOBs, and the depth codec.

Arrays are little-endian BLOBs, one row per frame; every BLOB's size is checked on read. Depth
frames use the "KFD1" codec (:func:`encode_depth`). Split from
:mod:`kinefuse.formats.store.session_store`, which keeps the schema and the
:class:`~kinefuse.formats.store.session_store.SessionStore` class.
"""

from __future__ import annotations

import contextlib
import json
import sqlite3
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.core.skeleton import N_JOINTS
from kinefuse.errors import InputError, StoreError

Array = NDArray[np.float64]

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


def _unblob(
    blobs: Sequence[bytes], dtype: np.dtype, shape: tuple[int, ...], what: str, first_row: int = 0
) -> NDArray[Any]:
    """Stack BLOBs into ``(len(blobs), *shape)``; a :class:`StoreError` on a size mismatch
    (naming the row, counted from ``first_row``)."""
    n_bytes = int(np.prod(shape)) * dtype.itemsize
    bad = [i for i, b in enumerate(blobs) if not isinstance(b, bytes) or len(b) != n_bytes]
    if bad:
        i = bad[0]
        held = (
            f"{len(blobs[i])} bytes"
            if isinstance(blobs[i], bytes)
            else f"a {type(blobs[i]).__name__}"
        )
        raise StoreError(
            f"{what}: row {first_row + i} holds {held} where {n_bytes} bytes were "
            f"expected (shape {shape}, {dtype}); the store is corrupt"
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


#: The largest side of a stored depth image, pixels (the Kinect v2's is 512, Azure's 1024): a
#: frame said to be larger is a damaged session, not an image to allocate.
MAX_DEPTH_SIDE = 4096


def _inflate(data: bytes, limit: int) -> bytes:
    """zlib-decompress ``data``, no further than ``limit`` bytes (a forged frame is no bomb)."""
    out = zlib.decompressobj().decompress(data, limit + 1)
    if len(out) > limit:
        raise ValueError(f"it expands past the {limit} bytes its image can hold")
    return out


def decode_depth(blob: bytes, height: int, width: int) -> NDArray[np.uint16]:
    """Inverse of :func:`encode_depth` (also reads the older plain-zlib frames).

    Raises
    ------
    zlib.error, ValueError
        The blob is corrupt.
    """
    n = height * width
    n_mask = (n + 7) // 8
    if not blob.startswith(DEPTH_CODEC_MAGIC):
        raw = _inflate(blob, 2 * n)
        if len(raw) != 2 * n:
            raise ValueError(f"{len(raw)} bytes for a {height}x{width} uint16 image")
        return np.frombuffer(raw, dtype=_U2).reshape(height, width).astype(np.uint16)
    payload = _inflate(blob[len(DEPTH_CODEC_MAGIC) :], n_mask + 2 * n)
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


#: rows a reader converts at once: a whole recording is never held as Python rows (about 1 kB a
#: frame), only as the arrays it is read into
READ_BATCH = 4096


@dataclass(frozen=True)
class Blob:
    """A BLOB column of :func:`read_columns`: ``dtype`` items of ``shape`` per row; ``nullable``:
    NULL rows read as zeros and are marked in the column's mask."""

    dtype: np.dtype
    shape: tuple[int, ...]
    nullable: bool = False


#: a column of :func:`read_columns`: ``"f8"`` (NULL: NaN), ``"i8"`` (NULL: 0) or a :class:`Blob`
Column = str | Blob


def read_columns(
    cursor: sqlite3.Cursor, columns: Sequence[Column], what: str
) -> tuple[list[NDArray[Any]], list[NDArray[np.bool_] | None]]:
    """A query's rows, fetched :data:`READ_BATCH` at a time, as one array per column, and per
    nullable BLOB column the rows that were not NULL (None for the other columns).

    The same arrays as converting ``fetchall()`` at once; without its list of every row."""
    parts: list[list[NDArray[Any]]] = [[] for _ in columns]
    masks: list[list[NDArray[np.bool_]]] = [[] for _ in columns]
    n = 0
    while rows := cursor.fetchmany(READ_BATCH):
        cols = list(zip(*rows, strict=True))
        for i, kind in enumerate(columns):
            c = cols[i]
            if isinstance(kind, Blob):
                if kind.nullable:
                    have = np.array([b is not None for b in c], dtype=bool)
                    blank = bytes(int(np.prod(kind.shape)) * kind.dtype.itemsize)
                    c = tuple(blank if b is None else b for b in c)
                    masks[i].append(have)
                parts[i].append(_unblob(c, kind.dtype, kind.shape, what, first_row=n))
            elif kind == "f8":
                parts[i].append(_numbers(c, np.float64, what, _path_of(cursor)).reshape(len(c)))
            elif kind == "i8":
                ints = _numbers([v or 0 for v in c], np.int64, what, _path_of(cursor))
                parts[i].append(ints.reshape(len(c)))
            else:
                raise ValueError(f"unknown column kind {kind!r}")
        n += len(rows)
    out: list[NDArray[Any]] = []
    for kind, p in zip(columns, parts, strict=True):
        if p:
            out.append(p[0] if len(p) == 1 else np.concatenate(p))
        elif isinstance(kind, Blob):
            out.append(np.zeros((0, *kind.shape), dtype=kind.dtype.newbyteorder("=")))
        else:
            out.append(np.zeros(0, dtype=np.float64 if kind == "f8" else np.int64))
    have_out: list[NDArray[np.bool_] | None] = [
        (np.concatenate(m) if m else np.zeros(0, bool)) if isinstance(k, Blob) and k.nullable
        else None
        for k, m in zip(columns, masks, strict=True)
    ]  # fmt: skip
    return out, have_out


def _path_of(cursor: sqlite3.Cursor) -> str:
    return str(getattr(cursor.connection, "path", "<session>"))


def _column(rows: list[tuple[Any, ...]], i: int, what: str = "", path: Path | str = "") -> Array:
    """Float column ``i`` of ``rows``; SQL NULL becomes NaN."""
    return _numbers([r[i] for r in rows], np.float64, what, path).reshape(len(rows))


def _json_dumps(value: object, what: str) -> str:
    try:
        return json.dumps(value, sort_keys=True, allow_nan=False, separators=(",", ":"))
    except (TypeError, ValueError) as e:
        raise InputError(
            f"{what}: value must be JSON-able (dict, list, str, finite numbers, bool, None); {e}"
        ) from None


def _json_loads(text: object, what: str, path: Path, expect: type | None = None) -> Any:
    """The JSON value stored in a session as ``what`` (its intrinsics, a meta entry, ...).

    Every JSON text read back from a session goes through here: a damaged or forged session
    gives one :class:`StoreError` naming the file and the entry, never a ``JSONDecodeError``.

    Raises
    ------
    StoreError
        ``text`` is not JSON (or nested too deeply to read), or not of type ``expect``.
    """
    try:
        if not isinstance(text, str | bytes):
            raise ValueError(f"a {type(text).__name__} where a JSON text belongs")
        value = json.loads(text)
    except (ValueError, RecursionError) as e:
        why = "nested too deeply" if isinstance(e, RecursionError) else str(e)
        raise StoreError(
            f"{path}: {what} is not valid JSON ({why}); the session is damaged or was not "
            "written by kinefuse: restore it from a copy, or make it again"
        ) from None
    if expect is not None and not isinstance(value, expect):
        names: dict[type, str] = {dict: "an object", list: "an array", str: "a string"}
        raise StoreError(
            f"{path}: {what} is not {names.get(expect, expect.__name__)} but {value!r:.40}; the "
            "session is damaged or was not written by kinefuse: restore it from a copy, or make "
            "it again"
        )
    return value


class DamagedStoreError(StoreError, sqlite3.DatabaseError):
    """A session SQLite opens but cannot be read as kinefuse writes it (a table or a column
    missing, a damaged page): a :class:`StoreError` for the commands (one line, exit 2), and
    still a ``sqlite3.DatabaseError`` for code that handles those."""


class ReadConnection(sqlite3.Connection):
    """The connection of a session opened for reading: an SQLite error of a query becomes a
    :class:`DamagedStoreError` naming the file (``path``, set by the store)."""

    path = "<session>"

    def execute(self, sql: str, parameters: Any = (), /) -> sqlite3.Cursor:
        try:
            return super().execute(sql, parameters)
        except sqlite3.DatabaseError as e:
            raise DamagedStoreError(
                f"{self.path}: the session cannot be read ({e}); it is damaged or was not "
                "written by this kinefuse: restore it from a copy, or make it again"
            ) from None


def _numbers(values: Any, dtype: type, what: str, path: Path | str) -> NDArray[Any]:
    """``np.array(values, dtype)`` of values read from a session; a :class:`StoreError` naming
    the file when one is not a number (SQLite keeps text in a REAL column)."""
    try:
        return np.array(values, dtype=dtype)
    except (TypeError, ValueError) as e:
        raise StoreError(
            f"{path}: {what or 'a stored column'} holds a value that is not a number ({e}); the "
            "session is damaged or was not written by kinefuse: restore it from a copy, or make "
            "it again"
        ) from None


# --------------------------------------------------------------------------------------------
# The store


class StorePart:
    """Base of the parts of :class:`~kinefuse.formats.store.session_store.SessionStore` kept in
    other modules (:mod:`~kinefuse.formats.store.streams`, :mod:`~kinefuse.formats.store.truth`):
    declares, for the type checker, the connection helpers that SessionStore provides."""

    if TYPE_CHECKING:  # provided by SessionStore
        path: Path

        @property
        def _db(self) -> sqlite3.Connection: ...

        def _writer(self, what: str) -> sqlite3.Connection: ...

        def _transaction(
            self, what: str
        ) -> contextlib.AbstractContextManager[sqlite3.Connection]: ...

        def _key(self, sensor_id: str, what: str) -> int: ...

        def _existing_seqs(self, table: str, key: int, seq: NDArray[Any]) -> NDArray[np.int64]: ...

        def _insert_frames(
            self,
            table: str,
            key: int,
            sensor_id: str,
            seq: NDArray[Any],
            sql: str,
            rows: Any,
            bodies: list[tuple[Any, ...]] | None = None,
        ) -> None: ...

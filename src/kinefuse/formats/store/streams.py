"""What the sensors delivered, in the session store: body-tracker observations, calibration
depth frames and clock probes (a part of
:class:`~kinefuse.formats.store.session_store.SessionStore`, which inherits :class:`SensorStreams`;
split from :mod:`kinefuse.formats.store.session_store` by what each part is).
"""

from __future__ import annotations

import contextlib
import hashlib
import math
import sqlite3
import zlib
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.core.frames.observations import BodyFrames
from kinefuse.core.skeleton import N_JOINTS, TrackingState
from kinefuse.errors import InputError, StoreError
from kinefuse.formats.store.store_codec import (
    _F8,
    _I1,
    _U1,
    _U2,
    MAX_DEPTH_SIDE,
    Blob,
    Column,
    StorePart,
    _blobs,
    _check_shape,
    _column,
    _float_array,
    _int_array,
    _numbers,
    _require_finite,
    _require_no_inf,
    _require_same_length,
    _require_unique,
    decode_depth,
    encode_depth,
    read_columns,
)

if TYPE_CHECKING:
    from kinefuse.formats.store.session_store import SensorInfo

Array = NDArray[np.float64]


#: the columns an observation row is read as (:meth:`SensorStreams.observations`)
_OBS_COLUMNS: list[Column] = [
    "i8", "f8", "f8", Blob(_F8, (N_JOINTS, 3)), Blob(_I1, (N_JOINTS,)), "f8",
    Blob(_U1, (N_JOINTS,), nullable=True), "i8", "i8",
]  # fmt: skip


class SensorStreams(StorePart):
    """Observations, depth frames and clock probes of each sensor (a part of SessionStore)."""

    if TYPE_CHECKING:  # provided by SessionStore
        _sensor_keys: dict[str, int]
        _has_host_time: bool
        _has_client_occlusion: bool
        _has_bodies: bool

        def sensors(self) -> list[SensorInfo]: ...

        def sensor(self, sensor_id: str) -> SensorInfo: ...

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
        body_id: ArrayLike | None = None,
    ) -> None:
        """Append body-tracker frames of one sensor (one transaction).

        Given ``body_id``, the rows may be in all-bodies form (see
        :class:`~kinefuse.core.frames.observations.BodyFrames`): several consecutive rows with the
        same ``seq``, one per body the tracker reported, the first listed first, with the same
        times (the first row's are kept).

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
            :class:`~kinefuse.core.skeleton.TrackingState` values (0, 1, 2).
        t_receive_server_s : (N,) float, optional
            Arrival times on the server's clock, seconds; NaN (or omitted) where unknown.
        t_receive_host_s : (N,) float, optional
            Arrival times at the sensor's client PC, on its clock, seconds; NaN (or omitted)
            where unknown. A store written before this column existed cannot take them.
        occluded : (N, 25) bool, optional
            The client's occlusion flags; given together with ``n_crossings``.
        n_crossings : (N,) int, optional
            The client's number of bone crossings per frame (>= 0).
        body_id : (N,) int, optional
            The sensor's tracking id of each row's body (default: 0, one row per seq), unique
            within a seq.
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
        ids = (
            np.zeros(n, np.int64) if body_id is None else _int_array(body_id, "body_id", (n,), what)
        )
        first = np.ones(n, dtype=bool)
        if body_id is not None:  # the all-bodies form: a seq's rows are consecutive
            first[1:] = s[1:] != s[:-1]
        _require_unique(s[first], what)
        occ_rows = self._client_occlusion_rows(occluded, n_crossings, n, what)
        more = self._other_body_rows(key, s, first, ids, j, st, occ_rows, what)
        if not first.all():
            s, st, ids = s[first], st[first], ids[first]
            t, tr, th, j = t[first], tr[first], th[first], j[first]
            occ_rows = (
                [b for b, f in zip(occ_rows[0], first, strict=True) if f],
                [c for c, f in zip(occ_rows[1], first, strict=True) if f],
            )
            n = int(first.sum())
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
        if self._has_bodies:
            cols = (*cols, ids.tolist())
            extra_cols, extra_q = extra_cols + ", body_id", extra_q + ", ?"
        self._insert_frames(
            "observations",
            key,
            sensor_id,
            s,
            "INSERT INTO observations (sensor_key, seq, t_sensor_s, t_receive_server_s, joints_m,"
            f" states{extra_cols}) VALUES (?, ?, ?, ?, ?, ?{extra_q})",
            zip(*cols, strict=True),
            more,
        )

    def _other_body_rows(
        self,
        key: int,
        seq: NDArray[np.int64],
        first: NDArray[np.bool_],
        ids: NDArray[np.int64],
        joints: Array,
        states: NDArray[Any],
        occ_rows: tuple[list[bytes | None], list[int | None]],
        what: str,
    ) -> list[tuple[Any, ...]]:
        """The ``observation_bodies`` rows of an all-bodies batch: each seq's bodies after its
        first, numbered 1, 2, ... in the order given."""
        if first.all():  # one body a frame (seqs unique): nothing beside the first
            if self._has_bodies or not ids.any():
                return []
        elif np.unique(np.stack([seq, ids], axis=1), axis=0).shape[0] != seq.shape[0]:
            raise InputError(f"{what}: a body_id repeats within one seq; each body needs its own")
        if not self._has_bodies:
            raise InputError(
                f"{what}: {self.path} was written by an older kinefuse that keeps one body per "
                "frame; append to a new session store to record every body"
            )
        start = np.maximum.accumulate(np.where(first, np.arange(seq.shape[0]), 0))
        idx = np.arange(seq.shape[0]) - start
        rest = np.flatnonzero(~first)
        jb, sb = _blobs(joints[rest], _F8), _blobs(states[rest], _I1)
        return [
            (key, int(seq[r]), int(idx[r]), int(ids[r]), jb[i], sb[i], occ_rows[0][r],
             occ_rows[1][r])
            for i, r in enumerate(rest.tolist())
        ]  # fmt: skip

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

    def observations(
        self,
        sensor_id: str,
        *,
        since_seq: int | None = None,
        bodies: Literal["first", "all"] = "first",
    ) -> BodyFrames:
        """Observations of one sensor ordered by sequence number: all of them, or only those
        after ``since_seq`` (a reader following a live recording asks for what is new).

        ``bodies="first"`` (the default): one row per seq, the body the tracker listed first;
        ``"all"``: the all-bodies form, a row per body (see
        :class:`~kinefuse.core.frames.observations.BodyFrames`). A store written before every body
        was recorded reads the same both ways, each row body 0.
        """
        what = f"observations of sensor {sensor_id!r}"
        if bodies not in ("first", "all"):
            raise InputError(f"{what}: bodies must be 'first' or 'all', not {bodies!r}")
        key = self._key(sensor_id, what)
        host = ", t_receive_host_s" if self._has_host_time else ", NULL"
        occ = ", occluded, n_crossings" if self._has_client_occlusion else ", NULL, NULL"
        ids = ", body_id" if self._has_bodies else ", 0"
        after = -(2**63) if since_seq is None else int(since_seq)
        cur = self._db.execute(
            "SELECT seq, t_sensor_s, t_receive_server_s, joints_m, states"
            f"{host}{occ}{ids} FROM observations WHERE sensor_key = ? AND seq > ? ORDER BY seq",
            (key, after),
        )
        cols, have = read_columns(cur, _OBS_COLUMNS, what)
        seq, t_device, t_server, joints, states, t_host, flags, n_cross, body_id = cols
        flagged = have[6]
        assert flagged is not None
        if bodies == "all" and self._has_bodies:
            cur = self._db.execute(
                "SELECT seq, 0.0, 0.0, joints_m, states, 0.0, occluded, n_crossings, body_id "
                "FROM observation_bodies WHERE sensor_key = ? AND seq > ? ORDER BY seq, idx",
                (key, after),
            )
            more, more_have = read_columns(cur, _OBS_COLUMNS, what)
            if more[0].size:
                # each seq's other bodies after its first, with the first's times
                at = np.searchsorted(seq, more[0])
                if (at >= seq.size).any() or (seq[np.minimum(at, seq.size - 1)] != more[0]).any():
                    raise StoreError(f"{what}: {self.path} holds bodies of frames it lacks")
                for i in (1, 2, 5):
                    more[i] = cols[i][at]
                mh = more_have[6]
                assert mh is not None
                order = np.argsort(np.concatenate([seq, more[0]]), kind="stable")
                seq, t_device, t_server, joints, states, t_host, flags, n_cross, body_id = (
                    np.concatenate([a, b])[order] for a, b in zip(cols, more, strict=True)
                )
                flagged = np.concatenate([flagged, mh])[order]
        occluded = crossings = None
        if flagged.any():  # frames without flags (NULL rows) count as not occluded
            occluded, crossings = flags.astype(bool), n_cross
        return BodyFrames(
            sensor_id=sensor_id,
            seq=seq,
            t_device_s=t_device,
            joints_m=joints,
            states=states,
            t_receive_server_s=t_server,
            t_host_s=t_host,
            occluded=occluded,
            n_crossings=crossings,
            body_id=body_id,
        )

    def observation_times(self, sensor_id: str) -> tuple[NDArray[np.int64], Array, Array, Array]:
        """``seq, t_sensor_s, t_receive_server_s, t_receive_host_s`` of one sensor's frames, in
        sequence order (NaN where unknown): the time stamps alone, without reading the joints, for
        checks of a whole recording that must not load it all."""
        key = self._key(sensor_id, f"observation times of sensor {sensor_id!r}")
        host = ", t_receive_host_s" if self._has_host_time else ", NULL"
        cur = self._db.execute(
            f"SELECT seq, t_sensor_s, t_receive_server_s{host} FROM observations "
            "WHERE sensor_key = ? ORDER BY seq",
            (key,),
        )
        (seq, t_sensor, t_server, t_host), _ = read_columns(cur, ["i8", "f8", "f8", "f8"], "")
        return seq, t_sensor, t_server, t_host

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
            if self._has_bodies:  # other bodies (none in a one-body session: hashes as before)
                for row in self._db.execute(
                    "SELECT seq, idx, body_id, joints_m, states FROM observation_bodies "
                    "WHERE sensor_key = ? ORDER BY seq, idx",
                    (self._sensor_keys[info.id],),
                ):
                    h.update(np.array(row[:3], "<i8").tobytes() + row[3] + row[4])
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
                    raise StoreError(
                        f"{self.path}: {what}: frames of different sizes {sorted(shapes)}"
                    )
                (h, w) = shapes.pop()
                if not (0 < h <= MAX_DEPTH_SIDE and 0 < w <= MAX_DEPTH_SIDE):
                    raise StoreError(
                        f"{self.path}: {what}: frames of {h}x{w} pixels; a depth image is 1 to "
                        f"{MAX_DEPTH_SIDE} pixels a side: the session is damaged"
                    )
                frames = np.empty((len(rows), h, w), dtype=np.uint16)
                for i, r in enumerate(rows):
                    try:
                        frames[i] = decode_depth(r[4], h, w)
                    except (zlib.error, ValueError) as e:
                        raise StoreError(
                            f"{self.path}: {what}: frame seq {r[0]} is corrupt ({e})"
                        ) from None
                yield (
                    _numbers([r[0] for r in rows], np.int64, what, self.path),
                    _column(rows, 1, what, self.path),
                    frames,
                )
        finally:
            # a generator left unfinished is closed when it is collected, possibly after the
            # store it read from: its cursor is gone with the connection then
            with contextlib.suppress(sqlite3.ProgrammingError):
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
        what = f"clock probes of sensor {sensor_id!r}"
        return _numbers(rows, np.float64, what, self.path).reshape(len(rows), 4)

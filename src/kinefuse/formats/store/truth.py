"""The ground truth of a simulated session: its writers (the simulator's) and the read-only
accessor :class:`Truth` that only evaluation code (``lab/report/``) uses.

The truth lives in the ``truth_*`` tables of the same SQLite file; :class:`TruthTables` adds
their writers to :class:`~kinefuse.formats.store.session_store.SessionStore`, which inherits it. The
system under test never reads them (the truth-firewall test empties them and makes :meth:`truth`
raise).
"""

from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.core.geometry.transforms import check_rigid
from kinefuse.core.skeleton import N_JOINTS
from kinefuse.errors import InputError, StoreError
from kinefuse.formats.store.store_codec import (
    _F8,
    _U1,
    Blob,
    StorePart,
    _blobs,
    _check_shape,
    _float_array,
    _int_array,
    _json_dumps,
    _json_loads,
    _require_finite,
    _require_increasing,
    _require_same_length,
    _require_unique,
    _unblob,
    read_columns,
)

if TYPE_CHECKING:
    from kinefuse.formats.store.session_store import SessionStore

Array = NDArray[np.float64]


class TruthTables(StorePart):
    """The simulator's writers of the ``truth_*`` tables (a part of ``SessionStore``)."""

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

    def write_truth_person(self, person: int, t_s: ArrayLike, joints_world: ArrayLike) -> None:
        """Store (replace) the true motion of a bystander (``person`` >= 1; the subject, person
        0, is :meth:`write_truth_motion`'s).

        Parameters
        ----------
        person : int
            The bystander's person id (1, 2, ... in the order they were added).
        t_s : (T,) float
            Times on the true clock, seconds, strictly increasing.
        joints_world : (T, 25, 3) float
            True joints in the world frame, metres, finite.
        """
        what = f"write_truth_person({person!r})"
        if not isinstance(person, int | np.integer) or int(person) < 1:
            raise InputError(f"{what}: person must be an int >= 1 (0 is the subject's motion)")
        t = _float_array(t_s, "t_s", (None,), what)
        j = _float_array(joints_world, "joints_world", (None, N_JOINTS, 3), what)
        n = _require_same_length(what, t_s=t, joints_world=j)
        if n == 0:
            raise InputError(f"{what}: the motion has no frames")
        _require_finite(t, "t_s", what)
        _require_finite(j, "joints_world", what)
        _require_increasing(t, "t_s", what)
        with self._transaction(what) as conn:
            conn.execute("DELETE FROM truth_people WHERE person = ?", (int(person),))
            conn.executemany(
                "INSERT INTO truth_people (person, frame, t_s, joints_m) VALUES (?, ?, ?, ?)",
                zip([int(person)] * n, range(n), t.tolist(), _blobs(j, _F8), strict=True),
            )

    def append_truth_bodies(
        self, sensor_id: str, seq: ArrayLike, body_id: ArrayLike, person: ArrayLike
    ) -> None:
        """Append who each observation row truly is: ``(N,)`` seq, body id, person (-1: none,
        a row without a body)."""
        what = f"append_truth_bodies(sensor {sensor_id!r})"
        key = self._key(sensor_id, what)
        s = _int_array(seq, "seq", (None,), what)
        b = _int_array(body_id, "body_id", (None,), what)
        p = _int_array(person, "person", (None,), what)
        n = _require_same_length(what, seq=s, body_id=b, person=p)
        if n == 0:
            return
        if (p < -1).any():
            raise InputError(f"{what}: person must be >= -1 (-1: no person)")
        with self._transaction(what) as conn:
            conn.executemany(
                "INSERT INTO truth_bodies (sensor_key, seq, body_id, person) VALUES (?, ?, ?, ?)",
                zip([key] * n, s.tolist(), b.tolist(), p.tolist(), strict=True),
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
        return Truth(cast("SessionStore", self))  # only SessionStore inherits this


class Truth:
    """Read-only accessor to a session's ground truth (the ``truth_*`` tables).

    Only evaluation code uses it; the system under test never reads the truth.
    """

    def __init__(self, store: SessionStore) -> None:
        self._store = store

    def motion(self) -> tuple[Array, Array, NDArray[np.bool_]]:
        """``(t_s (T,), joints_world (T, 25, 3), synthesized (25,) bool)``."""
        db = self._store._db
        cur = db.execute("SELECT t_s, joints_m FROM truth_motion ORDER BY frame")
        (t, joints), _ = read_columns(cur, ["f8", Blob(_F8, (N_JOINTS, 3))], "truth motion")
        info = db.execute("SELECT value FROM truth_info WHERE key = 'synthesized'").fetchone()
        if not t.size or info is None:
            raise StoreError(f"{self._store.path.name} holds no true motion")
        syn = np.array(
            _json_loads(info[0], "the true synthesized joints", self._store.path, list), dtype=bool
        )
        return t, joints, syn

    def info(self, key: str) -> object | None:
        """The truth stored under ``key`` by :meth:`SessionStore.write_truth_info`, or None."""
        row = self._store._db.execute(
            "SELECT value FROM truth_info WHERE key = ?", (key,)
        ).fetchone()
        return (
            None if row is None else _json_loads(row[0], f"truth entry {key!r}", self._store.path)
        )

    def sensor(self, sensor_id: str) -> tuple[Array, dict[str, float]]:
        """``(sensor2world (4, 4), clock dict)`` of one sensor."""
        key = self._store._key(sensor_id, "truth sensor")
        row = self._store._db.execute(
            "SELECT sensor2world, clock FROM truth_sensors WHERE sensor_key = ?", (key,)
        ).fetchone()
        if row is None:
            raise StoreError(f"no true pose stored for sensor {sensor_id!r}")
        m = _unblob([row[0]], _F8, (4, 4), f"true pose of sensor {sensor_id!r}")[0]
        what = f"the true clock of sensor {sensor_id!r}"
        clock = _json_loads(row[1], what, self._store.path, dict)
        try:
            return m, {str(k): float(v) for k, v in clock.items()}
        except (TypeError, ValueError):
            raise StoreError(
                f"{self._store.path}: {what} holds a value that is not a number"
            ) from None

    def observations(
        self, sensor_id: str
    ) -> tuple[NDArray[np.int64], Array, Array, NDArray[np.bool_], NDArray[np.bool_]]:
        """``(seq (N,), t_true_s (N,), joints_sensor (N, 25, 3), visible (N, 25), swapped (N,))``.

        Ordered by seq; empty arrays if the simulator wrote none for this sensor.
        """
        what = f"truth observations of sensor {sensor_id!r}"
        key = self._store._key(sensor_id, what)
        cur = self._store._db.execute(
            "SELECT seq, t_true_s, joints_m, visible, swapped FROM truth_observations "
            "WHERE sensor_key = ? ORDER BY seq",
            (key,),
        )
        (seq, t, joints, vis, swapped), _ = read_columns(
            cur, ["i8", "f8", Blob(_F8, (N_JOINTS, 3)), Blob(_U1, (N_JOINTS,)), "i8"], what
        )
        return seq, t, joints, vis.astype(bool), swapped.astype(bool)

    def people(self) -> list[int]:
        """The person ids of the session's actors: ``[0]`` (the subject alone), or ``[0, 1, ...]``
        with bystanders."""
        if not self._store._has_people_truth:
            return [0]
        rows = self._store._db.execute("SELECT DISTINCT person FROM truth_people ORDER BY person")
        return [0, *(int(r[0]) for r in rows)]

    def person_motion(self, person: int) -> tuple[Array, Array]:
        """``(t_s (T,), joints_world (T, 25, 3))`` of one person (0: the subject)."""
        if person == 0:
            t, joints, _ = self.motion()
            return t, joints
        if person not in self.people():
            raise StoreError(f"{self._store.path.name} holds no person {person}")
        cur = self._store._db.execute(
            "SELECT t_s, joints_m FROM truth_people WHERE person = ? ORDER BY frame", (person,)
        )
        (t, joints), _ = read_columns(cur, ["f8", Blob(_F8, (N_JOINTS, 3))], "truth person")
        return t, joints

    def person_of(self, sensor_id: str, seq: ArrayLike, body_id: ArrayLike) -> NDArray[np.int64]:
        """The person each observation row ``(seq, body_id)`` of a sensor truly is ``(N,)``
        (-1: none). A session without bystanders: every row is the subject's (0)."""
        s = np.asarray(seq, dtype=np.int64).reshape(-1)
        b = np.asarray(body_id, dtype=np.int64).reshape(-1)
        if len(self.people()) == 1:
            return np.zeros(s.shape, dtype=np.int64)
        key = self._store._key(sensor_id, "truth bodies")
        rows = self._store._db.execute(
            "SELECT seq, body_id, person FROM truth_bodies WHERE sensor_key = ?", (key,)
        ).fetchall()
        who = {(int(q), int(i)): int(p) for q, i, p in rows}
        return np.array(
            [who.get((q, i), -1) for q, i in zip(s.tolist(), b.tolist(), strict=True)],
            dtype=np.int64,
        )

    def wand(self) -> tuple[Array, Array]:
        """``(t_s (T,), centre_world (T, 3))``; empty arrays if no wand was simulated."""
        rows = self._store._db.execute(
            "SELECT t_s, x_m, y_m, z_m FROM truth_wand ORDER BY frame"
        ).fetchall()
        a = np.array(rows, dtype=np.float64).reshape(len(rows), 4)
        return a[:, 0].copy(), a[:, 1:].copy()

"""The live recorder: everything the server receives and produces, into a new session store.

The server calls the ``add_*`` methods from the event loop as things happen (they only append
to in-memory lists, never block); fused frames and status snapshots come through a lossless
:class:`~kinefuse.live.bus.Subscription`. Every ``flush_s`` (0.25 s) the pending rows are
handed, as one batch, to a single writer thread that owns the SQLite connection (sqlite3
connections belong to the thread that made them) and commits them, so the event loop never
waits for the disk and a crash of the server loses at most the last ``flush_s`` plus one commit
(the store runs in WAL mode). A write that fails (disk full, file removed) ends :meth:`run` with
the error: the server stops loudly instead of recording nothing.

Safety: the recording is always a NEW file (an existing path is refused, whatever it is: a
recording is data, never replaced), written in place (not through a temporary file, so what was
committed survives a crash), marked complete by a clean :meth:`close`. On a clean close the live
fused frames are also stored as the fused result ``"live"`` (``kinefuse export``-able) and the
run's figures as metadata.

Sequence numbers: the store keys a sensor's observations (and sightings) by ``(sensor, seq)``,
and the server takes each connection as a new stream whose ``seq`` may start again at 0 (a
restarted sensor). So the recorder keeps a sensor's recorded seqs increasing across its streams
(:class:`SeqMap`): a frame is recorded under its own ``seq`` while that is above everything
recorded of the sensor (always, in a run without restarts, so the rows match the sensor's
frames and a simulation's truth), else under the next free number, and a stream is never
allowed a jump above ``MAX_SEQ_GAP`` (so a peer that sent seq 2**63-1 cannot leave the real
sensor no number to record under). Every shift of a body frame's seq is recorded as the event
``seq_offset`` (the wire seq is the recorded one minus ``offset``); recordings made before
read as they did (no new column).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import dataclasses
import logging
import math
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.capture.calibration.floor import FloorPlane
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.frames.observations import BodyFrame
from kinefuse.core.skeleton import N_JOINTS
from kinefuse.errors import OutputError
from kinefuse.formats.store import live_tables as store_live
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.live.bus import FusedFrame, Status, Subscription

log = logging.getLogger("kinefuse.serve")

Array = NDArray[np.float64]

#: the fused result name a clean stop stores the live frames under
LIVE_METHOD = "live"
#: the largest step between two recorded seqs of a sensor (2**32 frames: 4.5 years at 30 Hz)
MAX_SEQ_GAP = 1 << 32


class SeqMap:
    """Recorded seqs of one sensor's frames of one kind, increasing across its streams (see the
    module docstring).

    Attributes
    ----------
    offset : int
        Recorded minus wire seq of the current stream.
    high : int or None
        The highest recorded seq (None: nothing recorded).
    """

    def __init__(self) -> None:
        self.offset = 0
        self.high: int | None = None
        self._fresh = True

    def new_stream(self) -> None:
        """The next seq is the first of a new stream (a new connection)."""
        self._fresh = True

    def record(self, seq: int) -> tuple[int, bool]:
        """The recorded seq of wire ``seq`` (increasing within a stream), and whether the
        offset changed for it."""
        offset = 0 if self._fresh else self.offset
        rec = seq + offset
        floor = -1 if self.high is None else self.high
        if rec <= floor or rec - max(floor, 0) > MAX_SEQ_GAP:
            rec = floor + 1
            offset = rec - seq
        changed = offset != self.offset
        self.offset, self.high, self._fresh = offset, rec, False
        return rec, changed


@dataclass
class _ObsBatch:
    seq: list[int] = field(default_factory=list)
    t_device: list[float] = field(default_factory=list)
    t_host: list[float] = field(default_factory=list)
    t_server: list[float] = field(default_factory=list)
    t_capture: list[float] = field(default_factory=list)
    joints: list[Array] = field(default_factory=list)
    states: list[NDArray[np.int8]] = field(default_factory=list)
    occluded: list[NDArray[np.bool_] | None] = field(default_factory=list)
    crossings: list[int | None] = field(default_factory=list)
    body_id: list[int] = field(default_factory=list)
    #: each frame's other bodies (the first listed first; empty for a one-body frame)
    others: list[tuple[BodyFrame, ...]] = field(default_factory=list)

    def all_bodies(self, occlusion: bool) -> dict[str, NDArray[Any]]:
        """The batch in all-bodies form, as the store takes it: each frame's row, then a row
        per other body with the frame's times (``occluded``/``crossings`` if ``occlusion``;
        another body without flags counts as not occluded)."""
        first: list[BodyFrame | None] = [None]
        rows = [(k, x) for k in range(len(self.seq)) for x in (*first, *self.others[k])]
        k = np.array([r[0] for r in rows], dtype=np.int64)
        blank = np.zeros(N_JOINTS, dtype=bool)
        out: dict[str, NDArray[Any]] = {
            "seq": np.array(self.seq, dtype=np.int64)[k],
            "t_device": np.array(self.t_device)[k],
            "t_host": np.array(self.t_host)[k],
            "t_server": np.array(self.t_server)[k],
            "joints": np.stack([self.joints[i] if x is None else x.joints_m for i, x in rows]),
            "states": np.stack([self.states[i] if x is None else x.states for i, x in rows]),
            "body_id": np.array(
                [self.body_id[i] if x is None else x.body_id for i, x in rows], dtype=np.int64
            ),
        }
        if occlusion:
            flags = [self.occluded[i] if x is None else x.occluded for i, x in rows]
            out["occluded"] = np.stack([blank if f is None else f for f in flags]).astype(bool)
            out["crossings"] = np.array(
                [self.crossings[i] if x is None else (x.n_crossings or 0) for i, x in rows],
                dtype=np.int64,
            )
        return out


@dataclass
class _Batch:
    sensors: list[tuple[str, str, Intrinsics, float]] = field(default_factory=list)
    obs: dict[str, _ObsBatch] = field(default_factory=lambda: defaultdict(_ObsBatch))
    probes: dict[str, list[tuple[float, float, float, float]]] = field(
        default_factory=lambda: defaultdict(list)
    )
    clock: dict[str, list[tuple[float, float, float, float, int]]] = field(
        default_factory=lambda: defaultdict(list)
    )
    sightings: list[store_live.SightingRow] = field(default_factory=list)
    floors: list[tuple[str, float, FloorPlane]] = field(default_factory=list)
    calibrations: list[tuple[str, str]] = field(default_factory=list)
    fused: list[store_live.FusedRow] = field(default_factory=list)
    events: list[tuple[float, str, str | None, dict[str, Any]]] = field(default_factory=list)
    meta: list[tuple[str, object]] = field(default_factory=list)

    def empty(self) -> bool:
        return not (
            self.sensors
            or self.obs
            or self.probes
            or self.clock
            or self.sightings
            or self.floors
            or self.calibrations
            or self.fused
            or self.events
            or self.meta
        )


def check_recording_path(path: Path) -> None:
    """Refuse a recording path that exists, has another format's extension or whose folder is
    missing (before the server starts listening)."""
    from kinefuse.core.outputs import FOREIGN_SESSION_SUFFIXES, check_output_folder

    if path.suffix.lower() in FOREIGN_SESSION_SUFFIXES:
        raise OutputError(
            f"--record {path}: a recording is a SQLite session file, but {path.suffix!r} is the "
            "extension of another format; name it .sqlite"
        )
    check_output_folder(path, "recording")
    companions = [path.with_name(path.name + s) for s in ("-wal", "-shm", "-journal")]
    if path.exists() or any(c.exists() for c in companions):
        raise OutputError(
            f"--record {path} already exists; a recording is never replaced: choose a new file"
        )


class Recorder:
    """Writes a live session (see the module docstring).

    Parameters
    ----------
    path : Path
        The new ``.sqlite`` file.
    meta : dict
        Metadata written at once (server start, method, options...).
    clock : callable
        The server clock (s); stamps when a fused frame reached the recorder.
    flush_s : float
        Commit interval, seconds (at most 0.5 s by the recording's guarantee).
    """

    def __init__(
        self,
        path: Path,
        meta: dict[str, object],
        *,
        clock: Callable[[], float],
        flush_s: float = 0.25,
    ) -> None:
        if not 0 < flush_s <= 0.5:
            raise ValueError(f"flush_s must be in (0, 0.5] s, got {flush_s}")
        self.path = Path(path)
        self.flush_s = flush_s
        self._meta0 = dict(meta)
        self._clock = clock
        self._batch = _Batch()
        self._pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="recorder")
        self._store: SessionStore | None = None
        self._obs_seq: dict[str, SeqMap] = defaultdict(SeqMap)
        self._sighting_seq: dict[str, SeqMap] = defaultdict(SeqMap)
        self._stop = asyncio.Event()
        self.rows_written = 0
        self.flushes = 0
        self._closed = False

    # -- lifecycle -----------------------------------------------------------------------------

    async def open(self) -> None:
        """Create the store (in the writer thread) with its live tables and metadata."""
        check_recording_path(self.path)
        await self._in_thread(self._open_sync)

    def _open_sync(self) -> None:
        store = SessionStore.create(self.path)
        try:
            store_live.create_live_tables(store)
            for k, v in self._meta0.items():
                store.set_meta(k, v)
        except BaseException:
            store.close()
            raise
        self._store = store

    async def _in_thread(self, fn: Any, *args: Any) -> Any:
        loop = asyncio.get_running_loop()
        return await loop.run_in_executor(self._pool, fn, *args)

    async def run(self, sub: Subscription) -> None:
        """Take the published items and commit every ``flush_s`` until :meth:`stop`."""
        async with asyncio.TaskGroup() as tg:
            tg.create_task(self._consume(sub))
            tg.create_task(self._flusher())

    def stop(self) -> None:
        """End :meth:`run` after a last flush (the subscription ends when the publisher closes)."""
        self._stop.set()

    async def _consume(self, sub: Subscription) -> None:
        async for item in sub:
            if isinstance(item, FusedFrame):
                self.add_fused(item, self._clock())
            elif isinstance(item, Status):
                self.add_event(item.t_server_s, "status", None, _status_detail(item))

    async def _flusher(self) -> None:
        while not self._stop.is_set():
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._stop.wait(), self.flush_s)
            await self.flush()

    async def flush(self) -> None:
        """Commit what is pending (in the writer thread)."""
        batch, self._batch = self._batch, _Batch()
        if batch.empty():
            return
        n = await self._in_thread(self._write_sync, batch)
        self.rows_written += n
        self.flushes += 1

    async def close(self, *, clean: bool) -> None:
        """Flush, then (clean) store the live frames as fused result ``live`` and mark the
        recording complete; close the file. Idempotent."""
        if self._closed:
            return
        self._closed = True
        try:
            try:
                await self.flush()
            except Exception:
                if clean:
                    raise
                log.exception("the last rows could not be written to %s", self.path)
            if clean:
                await self._in_thread(self._finish_sync)
        finally:
            await self._in_thread(self._close_sync)
            self._pool.shutdown(wait=True)

    def _finish_sync(self) -> None:
        st = self._require()
        fused = store_live.live_fused(st)
        if fused.frame.size:
            st.write_fused(LIVE_METHOD, fused.t_server_s, fused.positions_m, fused.status)
        st.set_meta("recording_frames_fused", int(fused.frame.size))
        st.mark_complete()

    def _close_sync(self) -> None:
        if self._store is not None:
            self._store.close()
            self._store = None

    def _require(self) -> SessionStore:
        if self._store is None:
            raise OutputError(f"the recording {self.path} is not open")
        return self._store

    # -- what the server hands in (event loop; never blocks) -------------------------------------

    def add_sensor(
        self, sensor_id: str, serial: str, intrinsics: Intrinsics, rate_hz: float = 30.0
    ) -> None:
        self._batch.sensors.append((sensor_id, serial, intrinsics, rate_hz))

    def new_stream(self, sensor_id: str) -> None:
        """A sensor's new connection: its seqs start a new stream (see :class:`SeqMap`)."""
        self._obs_seq[sensor_id].new_stream()
        self._sighting_seq[sensor_id].new_stream()

    def add_observation(
        self,
        sensor_id: str,
        seq: int,
        t_device_s: float,
        t_host_s: float,
        t_receive_server_s: float,
        t_capture_server_s: float,
        joints_m: Array,
        states: NDArray[np.int8],
        occluded: NDArray[np.bool_] | None,
        n_crossings: int | None,
        *,
        bodies: tuple[BodyFrame, ...] = (),
    ) -> None:
        """One body frame (joints NaN exactly where states is 0: the server sanitized it);
        ``seq`` is the wire seq, increasing on the sensor's current stream. ``bodies``: every
        body of the frame, the first (the one given by the other arguments) first; each is
        recorded with its tracking id."""
        rec, changed = self._obs_seq[sensor_id].record(seq)
        if changed:  # a restarted stream (the wire seq is the recorded one minus the offset)
            self.add_event(
                self._clock(), "seq_offset", sensor_id, {"seq": seq, "offset": rec - seq}
            )
        seq = rec
        b = self._batch.obs[sensor_id]
        b.seq.append(seq)
        b.t_device.append(t_device_s)
        b.t_host.append(t_host_s)
        b.t_server.append(t_receive_server_s)
        b.t_capture.append(t_capture_server_s)
        b.joints.append(joints_m)
        b.states.append(states)
        b.occluded.append(occluded)
        b.crossings.append(n_crossings)
        b.body_id.append(bodies[0].body_id if bodies else 0)
        b.others.append(bodies[1:])

    def add_probe(self, sensor_id: str, t1: float, t2: float, t3: float, t4: float) -> None:
        self._batch.probes[sensor_id].append((t1, t2, t3, t4))

    def add_clock(
        self,
        sensor_id: str,
        t_server_s: float,
        offset_s: float,
        drift_ppm: float,
        offset_se_s: float,
        epoch: int,
    ) -> None:
        self._batch.clock[sensor_id].append((t_server_s, offset_s, drift_ppm, offset_se_s, epoch))

    def add_sighting(self, row: store_live.SightingRow) -> None:
        """One wand sighting; ``row.seq`` is the wire seq (kept increasing like a body frame's,
        without an event: a sighting's seq is only its key)."""
        seq, _ = self._sighting_seq[row.sensor_id].record(row.seq)
        self._batch.sightings.append(dataclasses.replace(row, seq=seq))

    def add_floor(self, sensor_id: str, t_server_s: float, floor: FloorPlane) -> None:
        self._batch.floors.append((sensor_id, t_server_s, floor))

    def add_calibration(self, name: str, text: str) -> None:
        self._batch.calibrations.append((name, text))

    def add_fused(self, frame: FusedFrame, t_recorded_s: float) -> None:
        self._batch.fused.append(
            store_live.FusedRow(
                frame=frame.seq,
                t_server_s=frame.t_server_s,
                positions_m=frame.positions_m,
                status=frame.status,
                variance_m2=frame.variance_m2,
                latency_s=frame.latency_s,
                t_recorded_s=t_recorded_s,
            )
        )

    def add_event(
        self, t_server_s: float, kind: str, sensor_id: str | None, detail: dict[str, Any]
    ) -> None:
        self._batch.events.append((t_server_s, kind, sensor_id, detail))

    def add_meta(self, key: str, value: object) -> None:
        self._batch.meta.append((key, value))

    # -- the writer thread ---------------------------------------------------------------------

    def _write_sync(self, b: _Batch) -> int:
        st = self._require()
        n = 0
        known = {s.id for s in st.sensors()}
        for sid, serial, intr, rate in b.sensors:
            if sid not in known:
                st.add_sensor(sid, serial, intr, rate)
                known.add(sid)
                n += 1
        for sid, o in b.obs.items():
            has_occ = all(x is not None for x in o.occluded) and all(
                c is not None for c in o.crossings
            )
            every = o.all_bodies(has_occ)
            st.append_observations(
                sid,
                every["seq"],
                every["t_device"],
                every["joints"],
                every["states"],
                t_receive_server_s=every["t_server"],
                t_receive_host_s=every["t_host"],
                occluded=every.get("occluded"),
                n_crossings=every.get("crossings"),
                body_id=every["body_id"],
            )
            ok = [i for i, t in enumerate(o.t_capture) if math.isfinite(t)]
            store_live.append_obs_times(
                st, sid, [o.seq[i] for i in ok], [o.t_capture[i] for i in ok]
            )
            n += len(o.seq)
        for sid, rows in b.probes.items():
            a = np.array(rows, dtype=np.float64).reshape(-1, 4)
            st.append_clock_probes(sid, a[:, 0], a[:, 1], a[:, 2], a[:, 3])
            n += len(rows)
        for sid, est in b.clock.items():
            store_live.append_clock(st, sid, est)
            n += len(est)
        store_live.append_sightings(st, b.sightings)
        for sid, t, fl in b.floors:
            store_live.write_floor(st, sid, t, fl)
        for name, text in b.calibrations:
            st.write_calibration(name, text)
        store_live.append_fused(st, b.fused)
        store_live.append_events(st, b.events)
        for key, value in b.meta:
            st.set_meta(key, value)
        n += len(b.sightings) + len(b.floors) + len(b.calibrations) + len(b.fused)
        return n + len(b.events) + len(b.meta)


def _status_detail(s: Status) -> dict[str, Any]:
    return {
        "calibration_state": s.calibration_state,
        "calibration_grade": s.calibration_grade,
        "calibration_message": s.calibration_message,
        "fused_fps": s.fused_fps,
        "subject": s.subject,
        "subject_rule": s.subject_rule,
        "sensors": [
            {
                "id": x.sensor_id,
                "connected": x.connected,
                "rtt_ms": x.rtt_ms,
                "clock_offset_ms": x.clock_offset_ms,
                "clock_offset_sd_ms": x.clock_offset_sd_ms,
                "fps": x.fps,
                "latency_ms": x.latency_ms,
                "tracked_fraction": x.tracked_fraction,
                "stale_frames": x.stale_frames,
            }
            for x in s.sensors
        ],
    }

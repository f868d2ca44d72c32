"""``kinefuse track``: recordings of real cameras (one per sensor) -> a session store that
``calibrate``, ``fuse``, ``evaluate``, ``analyze`` and ``view`` take as they take a simulated one.

For each recording (``.mkv`` of k4arecorder, ``.bag``/``.db3`` of RealSense, or any camera spec
``KIND:FILE``), one worker process (up to one per core) reads every capture, runs the tracker,
and writes into a part store of its own beside the output (``OUT.track-parts/``): a body frame
per capture (the nearest body the tracker kept; empty without a tracker, so the device clock
still maps onto the session's), the depth frames at ``depth_hz`` for the wand, and the
recording's intrinsics. The parts are then merged into the session in the order given.

**Clocks.** Each recording has its own device clock. The session clock is chosen from what the
recordings say: Azure Kinects on a sync cable (``MASTER``/``SUBORDINATE``) share one device
clock, used as it is; otherwise each recording starts at its file's start time
(``creation_time``, whole seconds) relative to the earliest, and recordings without one are
assumed to have started together. Each sensor's frames get host arrival times on that session
clock (plus the nominal latency the clock fit takes off) and identity clock probes: the session
clock *is* the host clock. Then, unless the devices share a clock, the recordings in which the
tracker saw a person are aligned on the first of them by the person's motion
(:func:`motion_lag_s`: the trunk's speed, which no change of frame alters, cross-correlated
within 5 s), which corrects start times that are off by up to that much.

**Resumable.** The session is complete only once every recording is merged; a rerun on the same
output skips the recordings already merged (by sensor id) and redoes the others.
"""

from __future__ import annotations

import concurrent.futures
import math
import multiprocessing
import os
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from kinefuse.errors import InputError, StoreError

__all__ = ["TrackResult", "format_track", "motion_lag_s", "recording_spec", "track_recordings"]

#: what the session's metadata says made it (a session without it is not ours to continue)
GENERATOR = "kinefuse track"

_CHUNK = 32


@dataclass(frozen=True)
class TrackResult:
    """What ``kinefuse track`` did (``--json`` prints :meth:`as_dict`).

    Attributes
    ----------
    session : str
        The session written.
    clock : str
        How the recordings' clocks were put on the session's.
    skipped : tuple of str
        Sensors already merged by an earlier run (not redone).
    workers : int
        Worker processes used (0 when everything was merged before).
    sensors : tuple of dict
        Per recording, in the order given: its entry of the session's ``track_recordings``
        metadata (``sensor_id``, ``recording``, ``captures``, ``depth_frames``,
        ``with_person``, ``tracker``, ``refused``), or only ``sensor_id`` if it has none.
    """

    session: str
    clock: str
    skipped: tuple[str, ...]
    workers: int
    sensors: tuple[dict[str, Any], ...]

    def as_dict(self) -> dict[str, Any]:
        """JSON-able, as ``--json`` prints it."""
        return {
            "session": self.session,
            "clock": self.clock,
            "skipped": list(self.skipped),
            "workers": self.workers,
            "sensors": list(self.sensors),
        }


def recording_spec(path: str) -> str:
    """The camera spec of a recording: ``KIND:FILE`` as given, or by the file's suffix."""
    kind, sep, _rest = path.partition(":")
    if sep and len(kind) > 1 and not Path(path).exists():
        return path  # an explicit KIND:FILE (a Windows drive letter is one character)
    suffix = Path(path).suffix.lower()
    if suffix == ".mkv":
        return f"mkv:{path}"
    if suffix in (".bag", ".db3"):
        return f"realsense-file:{path}"
    raise InputError(
        f"{path}: not a recording kinefuse knows by its name (.mkv: Azure Kinect, .bag/.db3: "
        "RealSense); name its kind as KIND:FILE (kinefuse sensor --list-sources)"
    )


@dataclass(frozen=True)
class _Header:
    sensor_id: str
    spec: str
    serial: str
    sync_mode: str
    start_wall_s: float
    first_device_s: float


def _header(spec: str, sensor_id: str) -> _Header:
    from kinefuse.devices.sources import open_camera_source

    src = open_camera_source(spec, None)
    try:
        cam = src.camera
        first = next(iter(cam.captures()), None)
        if first is None:
            raise InputError(f"{spec}: the recording holds no capture")
        return _Header(
            sensor_id,
            spec,
            cam.serial,
            str(getattr(cam, "sync_mode", "STANDALONE")),
            float(getattr(cam, "start_wall_s", math.nan)),
            first.t_device_s,
        )
    finally:
        src.close()


def _offsets(headers: Sequence[_Header]) -> tuple[dict[str, float], str]:
    """Session time = device time + offset, per sensor; and how the clocks were aligned."""
    synced = len(headers) > 1 and all(h.sync_mode in ("MASTER", "SUBORDINATE") for h in headers)
    if synced or len(headers) == 1:
        t0 = min(h.first_device_s for h in headers)
        how = (
            "one recording: its device clock" if len(headers) == 1
            else "wired sync: the devices share one clock"
        )  # fmt: skip
        return {h.sensor_id: -t0 for h in headers}, how
    walls = [h.start_wall_s for h in headers]
    if all(math.isfinite(w) for w in walls):
        w0 = min(walls)
        offs = {h.sensor_id: (h.start_wall_s - w0) - h.first_device_s for h in headers}
        return offs, "by the recordings' start times (whole seconds)"
    return (
        {h.sensor_id: -h.first_device_s for h in headers},
        "assumed started together (no common clock, no start times)",
    )


def _trunk_speed(t: np.ndarray, joints: np.ndarray, hz: float) -> tuple[np.ndarray, np.ndarray]:
    """The trunk centre's speed (m/s) on a grid at ``hz`` from ``t[0]``: a rigid change of frame
    leaves it unchanged, so two sensors' speeds compare before any calibration. NaN where the
    trunk was not seen or across gaps over 0.2 s."""
    from kinefuse.core.skeleton import TRUNK_JOINTS, joint_index

    trunk = joints[:, [joint_index(n) for n in TRUNK_JOINTS], :]
    ok = np.isfinite(trunk).all(axis=2).any(axis=1)
    with np.errstate(invalid="ignore"):
        centre = np.nanmean(np.where(np.isfinite(trunk), trunk, np.nan), axis=1)
    t, centre = t[ok], centre[ok]
    if t.size < 3:
        return np.zeros(0), np.zeros(0)
    grid = t[0] + np.arange(int((t[-1] - t[0]) * hz) + 1) / hz
    p = np.stack([np.interp(grid, t, centre[:, k]) for k in range(3)], axis=1)
    speed = np.full(grid.size, np.nan)
    speed[1:-1] = np.linalg.norm(p[2:] - p[:-2], axis=1) * hz / 2
    gap = np.diff(t) > 0.2
    if gap.any():  # no speed across a gap in the tracking
        for a, b in zip(t[:-1][gap], t[1:][gap], strict=True):
            speed[(grid > a - 1 / hz) & (grid < b + 1 / hz)] = np.nan
    return grid, speed


def motion_lag_s(
    t_ref: np.ndarray,
    joints_ref: np.ndarray,
    t_other: np.ndarray,
    joints_other: np.ndarray,
    *,
    max_lag_s: float = 5.0,
    hz: float = 30.0,
    min_overlap_s: float = 5.0,
) -> tuple[float, float] | None:
    """How much later the same motion appears in ``other``'s times than in ``ref``'s: the
    ``lag`` to subtract from ``other``'s times, from the cross-correlation of the two trunk
    speeds (:func:`_trunk_speed`) over lags within ``max_lag_s``; and the correlation at the
    peak. None when they overlap by less than ``min_overlap_s`` of motion at any lag, or the
    peak is below 0.5 (the person stood still, or one sensor did not see them)."""
    ga, va = _trunk_speed(np.asarray(t_ref), np.asarray(joints_ref), hz)
    gb, vb = _trunk_speed(np.asarray(t_other), np.asarray(joints_other), hz)
    if ga.size < 3 or gb.size < 3:
        return None
    n = round(max_lag_s * hz)
    best = (-np.inf, 0)
    corr = np.full(2 * n + 1, np.nan)
    for i, k in enumerate(range(-n, n + 1)):
        # other's sample at its time g + k/hz against ref's at g: other = ref delayed by k/hz
        vb_at = np.interp(ga + k / hz, gb, vb, left=np.nan, right=np.nan)
        ok = np.isfinite(va) & np.isfinite(vb_at)
        if ok.sum() < min_overlap_s * hz:
            continue
        a, b = va[ok] - va[ok].mean(), vb_at[ok] - vb_at[ok].mean()
        den = float(np.sqrt((a * a).sum() * (b * b).sum()))
        if den <= 0:
            continue
        corr[i] = float((a * b).sum()) / den
        if corr[i] > best[0]:
            best = (corr[i], i)
    peak, i = best
    if not np.isfinite(peak) or peak < 0.5:
        return None
    frac = 0.0
    if 0 < i < 2 * n and np.isfinite(corr[i - 1]) and np.isfinite(corr[i + 1]):
        den = corr[i - 1] - 2 * corr[i] + corr[i + 1]
        frac = 0.5 * (corr[i - 1] - corr[i + 1]) / den if den < 0 else 0.0
    return (i - n + frac) / hz, float(peak)


def _track_one(
    spec: str,
    sensor_id: str,
    part: str,
    tracker: str | None,
    depth_hz: float,
    progress: Any,
) -> dict[str, Any]:
    """One recording into its part store (runs in a worker process)."""
    from kinefuse.devices.sources import body_frame, frame_bodies, open_camera_source
    from kinefuse.formats.store.session_store import SessionStore

    src = open_camera_source(spec, tracker)
    cam, trk = src.camera, src.tracker
    p = Path(part)
    for q in (p, *(p.with_name(p.name + s) for s in ("-wal", "-shm", "-journal"))):
        q.unlink(missing_ok=True)  # a part left by an interrupted run: ours, in our folder
    refused: Counter[str] = Counter()
    n = with_person = depth_kept = 0
    last_depth = -math.inf
    obs: list[Any] = []
    depth: list[tuple[int, float, Any]] = []
    try:
        with SessionStore.create(p) as store:
            store.add_sensor(sensor_id, cam.serial, cam.calibration.depth, cam.rate_hz)

            def flush() -> None:
                if obs:
                    rows = [b for f in obs for b in f.bodies()]  # every body, the first first
                    store.append_observations(
                        sensor_id,
                        [f.seq for f in rows],
                        [f.t_device_s for f in rows],
                        np.stack([f.joints_m for f in rows]),
                        np.stack([f.states for f in rows]),
                        body_id=[f.body_id for f in rows],
                    )
                    obs.clear()
                if depth:
                    store.append_depth_frames(
                        sensor_id, [d[0] for d in depth], [d[1] for d in depth],
                        np.stack([d[2] for d in depth]),
                    )  # fmt: skip
                    depth.clear()

            for cap in cam.captures():
                n += 1
                bodies: tuple[Any, ...] = ()
                if trk is not None:
                    result = trk.track(*src.for_tracker(cap))
                    refused.update(result.refused)
                    bodies = frame_bodies(result)  # the nearest first, as always
                    with_person += bool(bodies)
                first = bodies[0] if bodies else None
                obs.append(body_frame(sensor_id, cap, first, math.nan, bodies[1:]))
                if cap.depth_mm is not None and cap.t_device_s - last_depth >= 1 / depth_hz - 1e-6:
                    depth.append((cap.seq, cap.t_device_s, src.depth_of(cap)))
                    last_depth = cap.t_device_s
                    depth_kept += 1
                if len(obs) >= _CHUNK:
                    flush()
                    if progress is not None:
                        progress.put((sensor_id, n))
            flush()
            store.mark_complete()
    finally:
        src.close()
    if n == 0:
        raise InputError(f"{spec}: the recording holds no capture")
    return {
        "sensor_id": sensor_id,
        "recording": spec.partition(":")[2],
        "captures": n,
        "depth_frames": depth_kept,
        "with_person": with_person if trk is not None else None,
        "tracker": getattr(trk, "name", None),
        "refused": refused.most_common(3),
    }


def _merge(out: Any, part: Path, sensor_id: str, offset_s: float) -> None:
    """A finished part into the session: the sensor, its frames on the session clock, identity
    probes (the session clock is the host clock). Each append is one transaction, so a merge
    that was interrupted is continued where it stopped (what is stored is skipped)."""
    from kinefuse.capture.sync.device import NOMINAL_LATENCY_S
    from kinefuse.formats.store.session_store import SessionStore

    with SessionStore.open(part) as p:
        if not p.complete:
            raise StoreError(f"{part}: the worker did not finish this recording")
        info = p.sensor(sensor_id)
        if sensor_id not in {s.id for s in out.sensors()}:
            out.add_sensor(sensor_id, info.serial, info.intrinsics, info.rate_hz)
        have = out.depth_frame_count(sensor_id)  # appended in this order, chunk by chunk
        for seq, t, frames in p.iter_depth_frames(sensor_id):
            skip = min(have, len(seq))
            have -= skip
            if skip < len(seq):
                out.append_depth_frames(sensor_id, seq[skip:], t[skip:], frames[skip:])
        o = p.observations(sensor_id, bodies="all")
        host = o.t_device_s + offset_s + NOMINAL_LATENCY_S
        if out.observation_count(sensor_id) == 0:
            out.append_observations(
                sensor_id, o.seq, o.t_device_s, o.joints_m, o.states, t_receive_host_s=host,
                body_id=o.body_id,
            )  # fmt: skip
        if out.clock_probes(sensor_id).shape[0] == 0:
            t = (
                np.arange(math.floor(host.min()), math.ceil(host.max()) + 1.0)
                if host.size
                else host
            )
            out.append_clock_probes(sensor_id, t, t, t, t)


def _open_output(out: Path) -> Any:
    from kinefuse.core.outputs import check_output_folder
    from kinefuse.formats.store.session_store import SessionStore

    if not out.exists():
        check_output_folder(out, "session")
        store = SessionStore.create(out)
        store.set_meta("generator", GENERATOR)
        return store
    try:
        store = SessionStore.open(out, writable=True)
    except StoreError:
        raise InputError(
            f"{out} exists and is not a session kinefuse track made; choose another --out"
        ) from None
    if store.meta().get("generator") != GENERATOR:
        store.close()
        raise InputError(
            f"{out} is a session kinefuse track did not make (it is never overwritten); "
            "choose another --out"
        )
    return store


def track_recordings(
    recordings: Sequence[str],
    out: Path,
    *,
    tracker: str | None = None,
    jobs: int | None = None,
    depth_hz: float = 10.0,
    progress: Callable[[str], None] | None = None,
) -> TrackResult:
    """Track recordings into the session ``out`` (see the module notes); return a summary.

    Raises
    ------
    InputError
        A recording cannot be read, the tracker is not installed, ``out`` is not a session
        this command made (never overwritten), or it is complete with other recordings.
    """
    from kinefuse.devices.trackers import load_tracker

    if not recordings:
        raise InputError("kinefuse track: name at least one recording")
    if not (math.isfinite(depth_hz) and depth_hz > 0):
        raise InputError(f"--depth-hz must be a positive rate, got {depth_hz}")
    if tracker:
        load_tracker(tracker).close()  # refuse a missing tracker before any work
    from kinefuse.devices.sources import parse_spec

    specs = [recording_spec(r) for r in recordings]
    ids: list[str] = []
    for spec in specs:
        _kind, arg, _opt, sid = parse_spec(spec)
        base = sid or Path(arg).stem or "sensor"
        sid = base
        k = 2
        while sid in ids:
            sid, k = f"{base}-{k}", k + 1
        ids.append(sid)
    say = progress or (lambda _m: None)
    say("reading the recordings' clocks")  # and refusing an unreadable one before any output
    headers = [_header(spec, sid) for spec, sid in zip(specs, ids, strict=True)]
    store = _open_output(Path(out))
    try:
        return _track(store, Path(out), headers, tracker, jobs, depth_hz, say)
    finally:
        store.close()


def _track(
    store: Any,
    out: Path,
    headers: list[_Header],
    tracker: str | None,
    jobs: int | None,
    depth_hz: float,
    say: Callable[[str], None],
) -> TrackResult:
    specs = [h.spec for h in headers]
    ids = [h.sensor_id for h in headers]
    meta = store.meta()
    done = set(meta.get("track_recordings") or {})  # merged to the end
    registered = {s.id for s in store.sensors()}  # merged, or a merge that was interrupted
    known = dict(meta.get("track_offsets_s") or {})
    if store.complete and set(ids) - done:
        raise InputError(
            f"{out} is a complete session of {', '.join(sorted(done))}; track "
            f"{', '.join(sorted(set(ids) - done))} into a new --out"
        )
    todo = [(spec, sid) for spec, sid in zip(specs, ids, strict=True) if sid not in done]
    if not known or any(sid not in known for _spec, sid in todo):
        offsets, how = _offsets(headers)
        offsets = {**offsets, **known}  # sensors merged before keep their session clock
        store.set_meta("track_offsets_s", offsets)
        store.set_meta("track_clock", how)
    else:
        offsets, how = known, str(meta.get("track_clock", ""))
    parts = out.with_name(out.name + ".track-parts")
    parts.mkdir(exist_ok=True)
    results: dict[str, dict[str, Any]] = {}
    workers = max(1, min(jobs or os.cpu_count() or 1, len(todo) or 1))
    if todo:
        results = _run_workers(todo, parts, tracker, depth_hz, workers, say)
        if "wired sync" not in how and len(ids) > 1:
            say("aligning the recordings by the person's motion")
            moved = _align_by_motion(store, parts, ids, done, registered, offsets)
            if moved:
                offsets = {
                    **offsets,
                    **{sid: offsets[sid] - lag for sid, (lag, _c) in moved.items()},
                }
                how += (
                    "; then by the person's motion ("
                    + ", ".join(
                        f"{sid} {lag * 1000:+.0f} ms, r {c:.2f}" for sid, (lag, c) in moved.items()
                    )
                    + ")"
                )
                store.set_meta("track_offsets_s", offsets)
                store.set_meta("track_clock", how)
        for _spec, sid in todo:  # merged in the order given
            say(f"{sid}: writing into {out.name}")
            _merge(store, parts / f"{sid}.sqlite", sid, float(offsets[sid]))
            prev = dict(store.meta().get("track_recordings") or {})
            prev[sid] = results[sid]
            store.set_meta("track_recordings", prev)
            for q in parts.glob(f"{sid}.sqlite*"):
                q.unlink()
    if not any(parts.iterdir()):
        parts.rmdir()
    if not store.complete:
        t0 = [store.observation_times(s)[3] for s in ids]  # host stamps: the session clock
        lo = min(float(np.nanmin(t)) for t in t0 if t.size)
        hi = max(float(np.nanmax(t)) for t in t0 if t.size)
        store.set_meta("calibration_phase_server_s", [lo, hi])
        store.set_meta("motion_phase_server_s", [lo, hi])
        store.mark_complete()
    recs = store.meta().get("track_recordings") or {}
    return TrackResult(
        session=str(out),
        clock=how,
        skipped=tuple(sid for sid in ids if sid in done),
        workers=workers if todo else 0,
        sensors=tuple(recs.get(sid, {"sensor_id": sid}) for sid in ids),
    )


def _align_by_motion(
    store: Any,
    parts: Path,
    ids: list[str],
    done: set[str],
    registered: set[str],
    offsets: dict[str, float],
) -> dict[str, tuple[float, float]]:
    """Lags of the new sensors against the first sensor that saw a person (on the session clock
    so far), from the trunk's speed; sensors already in the session keep their clock."""
    from kinefuse.formats.store.session_store import SessionStore

    def series(sid: str) -> tuple[np.ndarray, np.ndarray]:
        if sid in done:
            o = store.observations(sid)
        else:
            with SessionStore.open(parts / f"{sid}.sqlite") as p:
                o = p.observations(sid)
        return o.t_device_s + float(offsets[sid]), o.joints_m

    streams = {sid: series(sid) for sid in ids}
    seen = [sid for sid in ids if np.isfinite(streams[sid][1]).any()]
    if len(seen) < 2:
        return {}
    ref = seen[0]
    out = {}
    for sid in seen[1:]:
        if sid in registered:
            continue
        lag = motion_lag_s(*streams[ref], *streams[sid])
        if lag is not None:
            out[sid] = lag
    return out


def _run_workers(
    todo: list[tuple[str, str]],
    parts: Path,
    tracker: str | None,
    depth_hz: float,
    workers: int,
    say: Callable[[str], None],
) -> dict[str, dict[str, Any]]:
    if workers == 1:

        class _Say:
            def put(self, item: tuple[str, int]) -> None:
                say(f"{item[0]}: {item[1]} captures")

        return {
            sid: _track_one(spec, sid, str(parts / f"{sid}.sqlite"), tracker, depth_hz, _Say())
            for spec, sid in todo
        }
    ctx = multiprocessing.get_context("spawn")  # a clean interpreter per worker (no forked locks)
    with ctx.Manager() as manager:
        q = manager.Queue()
        counts = {sid: 0 for _spec, sid in todo}
        with concurrent.futures.ProcessPoolExecutor(workers, mp_context=ctx) as pool:
            futs = {
                pool.submit(_track_one, spec, sid, str(parts / f"{sid}.sqlite"), tracker,
                            depth_hz, q): sid
                for spec, sid in todo
            }  # fmt: skip
            pending = set(futs)
            while pending:
                _done, pending = concurrent.futures.wait(pending, timeout=0.5)
                while not q.empty():
                    sid, n = q.get()
                    counts[sid] = n
                say(", ".join(f"{s}: {n}" for s, n in counts.items()) + " captures")
            return {futs[f]: f.result() for f in futs}


def format_track(d: TrackResult) -> str:
    """The text report of :func:`track_recordings`."""
    lines = [f"kinefuse track: {d.session}: {len(d.sensors)} sensor(s); clocks {d.clock}"]
    for s in d.sensors:
        sid = s["sensor_id"]
        if sid in d.skipped:
            lines.append(f"  {sid}: already in the session (skipped)")
            continue
        if s.get("with_person") is None:
            who = "depth only (no tracker: run with --tracker NAME for skeletons)"
        else:
            who = f"{s['with_person']} of {s['captures']} frames had a person ({s['tracker']})"
            if s["refused"]:
                who += "; refused: " + "; ".join(f"{r} ({n})" for r, n in s["refused"])
        lines.append(
            f"  {sid}: {s['captures']} captures, {s['depth_frames']} depth frames stored; {who}"
        )
    if d.sensors and all(s.get("with_person") is not None for s in d.sensors):
        total = sum(s.get("with_person") or 0 for s in d.sensors)
        n = sum(s.get("captures") or 0 for s in d.sensors)
        lines.append(f"{total} of {n} frames had a person")
    lines.append(f"next: kinefuse inspect {d.session}")
    return "\n".join(lines)

"""Evaluation of a live recording against the simulator's truth, after the run.

A live recording (``kinefuse serve --record``) holds no truth: the server never sees it. When the
clients played a simulated session (``kinefuse sensor --source sim:... --truth-out SIDE.json``),
what only a simulation knows is in two places: the simulated session's ``truth_*`` tables (the
motion, the poses, the device and host clocks, on the simulation's true clock) and each client's
truth sidecar (how it emulated its host clock on CLOCK_MONOTONIC and when it played the source).
CLOCK_MONOTONIC is shared by every process on one machine, and the server records the monotonic
instant its clock started (meta ``server_t0_monotonic``; server time = monotonic - that), so the
simulation's true time maps onto the server clock:

- with a common playback epoch ``M`` (``--epoch-monotonic``): true time ``T`` is played at
  monotonic ``M + T``, so ``t_server = T + M - server_t0``;
- otherwise the client started its own playback: ``T`` was played at ``m0 + T`` (``m0`` = the
  Welcome instant minus the first frame's true time), or, when the sidecar names a
  ``source_clock`` (``true``, ``host`` or ``device``), from its ``play_start_monotonic`` and
  ``play_start_source_s`` (source time on that clock);
- a sidecar's ``speed`` (simulated seconds per real second, default 1) divides those times.

:func:`write_live_truth` writes that truth into the recording's truth tables (the true motion,
wand and observations moved onto the server clock; each sensor's true pose; its clocks in server
terms: the device clock, and the emulated host clock ``host(t) = h0 + (1 + drift)(t - m0)`` of
monotonic ``t``), so ``kinefuse evaluate RECORDING`` works as on a simulated session.
:func:`evaluate_live` then measures what the live system did: the server's online clock estimate
against the emulated clock, the live calibration against the true rig, the system latency of the
published frames, and the live frames' MAE against offline ``best`` on the same recording and the
same frames.

This module reads the truth; nothing in the capture path may import it.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.affine_clock import AffineClock
from kinefuse.errors import InputError
from kinefuse.formats.store.session_store import SessionStore

Array = NDArray[np.float64]

#: Clock errors are measured after this much time from a sensor's first probe, seconds.
CLOCK_WARMUP_S = 5.0

SOURCE_CLOCKS = ("true", "host", "device")


# ------------------------------------------------------------------------------------------
# the truth of one client's playback


@dataclass(frozen=True)
class PlaybackTruth:
    """How one simulated client played its sensor, on CLOCK_MONOTONIC.

    Attributes
    ----------
    sensor_id : str
    h0, drift, m0 : float
        The emulated host clock: ``host(t) = h0 + (1 + drift) (t - m0)`` of monotonic ``t``
        (s, 1, s).
    mono_at_true0 : float
        Monotonic instant at which the simulation's true time 0 was played, seconds.
    mono_rate : float
        Monotonic seconds per simulated true second (1 when played on the true clock).
    host : AffineClock
        Monotonic time -> emulated host time (derived from ``h0``, ``drift``, ``m0``).
    """

    sensor_id: str
    h0: float
    drift: float
    m0: float
    mono_at_true0: float
    mono_rate: float = 1.0
    host: AffineClock = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        a = AffineClock.from_drift(self.drift, offset=self.h0, origin=self.m0)
        object.__setattr__(self, "host", a)

    def true_offset_s(self, t_server_s: Array, server_t0: float) -> Array:
        """True host-clock offset (client minus server) at server times, seconds."""
        t = np.asarray(t_server_s, dtype=np.float64)
        return self.host.forward(t + server_t0) - t


def read_sidecar(path: Path) -> dict[str, Any]:
    """A client's truth sidecar (JSON object); an :class:`InputError` naming what is wrong."""
    try:
        d = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        raise InputError(f"cannot read the truth sidecar {path}: {e}") from None
    if not isinstance(d, dict):
        raise InputError(f"{path}: a truth sidecar is a JSON object, got {type(d).__name__}")
    for key in ("sensor_id", "h0", "drift", "m0"):
        if key not in d:
            raise InputError(f"{path}: the truth sidecar has no {key!r} (keys: {sorted(d)})")
    return d


def playback_truth(side: dict[str, Any], sim_clock: dict[str, float]) -> PlaybackTruth:
    """Read a sidecar against the sensor's true clocks in the simulated session.

    ``sim_clock`` is the sensor's clock dict in the simulated session's truth
    (:meth:`kinefuse.sim.clock.SensorClocks.to_dict`: ``offset_s``, ``drift_ppm``,
    ``host_offset_s``, ``host_drift_ppm``).
    """

    def num(key: str) -> float:
        v = side.get(key)
        if not isinstance(v, int | float) or not math.isfinite(v):
            raise InputError(f"truth sidecar of {side.get('sensor_id')!r}: {key} must be a number")
        return float(v)

    h0, drift, m0 = num("h0"), num("drift"), num("m0")
    speed = num("speed") if side.get("speed") is not None else 1.0
    if not speed > 0:
        raise InputError(f"truth sidecar of {side['sensor_id']!r}: speed must be > 0")
    epoch = side.get("epoch_monotonic")
    if epoch is not None:  # true time T played at monotonic M + T / speed
        a, b = num("epoch_monotonic"), 1.0 / speed
    elif "source_clock" not in side:  # the client's own start: T played at m0 + T / speed
        a, b = m0, 1.0 / speed
    else:
        clock = side.get("source_clock", "true")
        if clock not in SOURCE_CLOCKS:
            raise InputError(
                f"truth sidecar of {side['sensor_id']!r}: source_clock must be one of "
                f"{', '.join(SOURCE_CLOCKS)}, got {clock!r}"
            )
        p0, s0 = num("play_start_monotonic"), num("play_start_source_s")
        # source time s = off + rate T, played at monotonic p0 + (s - s0)
        off, rate = 0.0, 1.0
        if clock == "host":
            off = sim_clock["host_offset_s"]
            rate = AffineClock.from_drift_ppm(sim_clock["host_drift_ppm"]).rate
        elif clock == "device":
            off = sim_clock["offset_s"]
            rate = AffineClock.from_drift_ppm(sim_clock["drift_ppm"]).rate
        a, b = p0 + off - s0, rate
    return PlaybackTruth(str(side["sensor_id"]), h0, drift, m0, a, b)


def _server_t0(store: SessionStore) -> float:
    v = store.meta().get("server_t0_monotonic")
    if not isinstance(v, int | float) or not math.isfinite(v):
        raise InputError(
            f"{store.path} has no meta server_t0_monotonic: it was not recorded by kinefuse serve "
            "(or by one that does not record its clock's start)"
        )
    return float(v)


# ------------------------------------------------------------------------------------------
# writing the truth into the recording


def write_live_truth(recording: Path, simulated: Path, sidecars: dict[str, Path]) -> dict[str, Any]:
    """Write the truth of a live run into its recording's truth tables (see the module doc).

    Parameters
    ----------
    recording : Path
        The live recording (opened for writing; it must hold no truth yet).
    simulated : Path
        The simulated session the clients played (opened read-only).
    sidecars : dict of sensor id -> Path
        Each client's truth sidecar.

    Returns
    -------
    dict
        ``true_to_server_s`` (the offset ``t_server = T + offset`` written), ``spread_ms`` (how
        far the sensors' own offsets are from it: 0 with a common epoch), ``sensors``.
    """
    with SessionStore.open(simulated) as sim, SessionStore.open(recording, writable=True) as rec:
        if rec.has_truth():
            raise InputError(
                f"{recording} already holds truth; it was evaluated before (the truth is written "
                "once, from the run's own sidecars)"
            )
        t0 = _server_t0(rec)
        truth = sim.truth()
        rec_ids = [s.id for s in rec.sensors()]
        plays = {}
        for sid in rec_ids:
            if sid not in sidecars:
                raise InputError(f"no truth sidecar for sensor {sid!r} of {recording}")
            plays[sid] = playback_truth(read_sidecar(sidecars[sid]), truth.sensor(sid)[1])
        rates = {p.mono_rate for p in plays.values()}
        rate = float(np.median(list(rates)))
        shifts = np.array([p.mono_at_true0 - t0 for p in plays.values()])
        shift = float(np.median(shifts))

        def to_server(t: Array) -> Array:
            return shift + rate * np.asarray(t, dtype=np.float64)

        t_m, joints, syn = truth.motion()
        rec.write_truth_motion(to_server(t_m), joints, syn)
        t_w, c_w = truth.wand()
        rec.append_truth_wand(to_server(t_w), c_w)
        for key in ("seed", "rig", "subject_height_m", "error_model"):
            v = truth.info(key)
            if v is not None:
                rec.write_truth_info(key, v)
        rec.write_truth_info(
            "live_playback",
            {
                "simulated_session": simulated.name,
                "true_to_server_s": shift,
                "rate": rate,
                "spread_ms": float(1e3 * np.ptp(shifts)),
            },
        )
        for sid, p in plays.items():
            pose, clock = truth.sensor(sid)
            dev_rate = AffineClock.from_drift_ppm(clock["drift_ppm"]).rate
            # device time = off + rate T and T = (t_server - shift) / rate_play
            dev_off = clock["offset_s"] - dev_rate * shift / rate
            host_at_server0 = float(p.host.forward(t0))
            rec.write_truth_sensor(
                sid,
                pose,
                {
                    "offset_s": dev_off,
                    "drift_ppm": (dev_rate / rate - 1.0) * 1e6,
                    "phase_s": clock.get("phase_s", 0.0),
                    "host_offset_s": host_at_server0,
                    "host_drift_ppm": p.drift * 1e6,
                    "latency_offset_s": clock.get("latency_offset_s", 0.0),
                },
            )
            seq, t_true, j_s, vis, swapped = truth.observations(sid)
            rec.append_truth_observations(sid, seq, to_server(t_true), j_s, vis, swapped)
    return {
        "true_to_server_s": shift,
        "spread_ms": float(1e3 * np.ptp(shifts)),
        "sensors": rec_ids,
    }


# ------------------------------------------------------------------------------------------
# the measurements


def _quantiles_ms(x: Array) -> dict[str, float | None]:
    x = np.asarray(x, dtype=np.float64)
    x = x[np.isfinite(x)]
    if not x.size:
        return {"p50": None, "p99": None, "max": None, "n": 0}
    return {
        "p50": float(1e3 * np.median(x)),
        "p99": float(1e3 * np.quantile(x, 0.99)),
        "max": float(1e3 * x.max()),
        "n": int(x.size),
    }


def _replayed_estimates(probes: Array) -> Array:
    """``(N, 3)`` ``t_server_s, offset_s, epoch``: the online estimator replayed over probes."""
    from kinefuse.capture.sync.online import OnlineClock
    from kinefuse.errors import SyncError

    clock = OnlineClock()
    rows = []
    for t1, t2, t3, t4 in probes.tolist():
        clock.add_probe(t1, t2, t3, t4)
        try:
            e = clock.estimate(t4)
        except SyncError:  # no estimate yet (every probe so far rejected)
            continue
        rows.append((t4, e.offset_s, e.epoch))
    return np.array(rows, dtype=np.float64).reshape(len(rows), 3)


def clock_errors(store: SessionStore, warmup_s: float = CLOCK_WARMUP_S) -> dict[str, Any]:
    """The server's online host-clock estimate against the emulated clock, per sensor and over all.

    The truth is the recording's (:func:`write_live_truth`: ``host_offset_s`` at server time 0,
    ``host_drift_ppm``). The estimate is the one the server recorded after every probe reply
    (``live_clock``, :func:`kinefuse.formats.store.live_tables.clock_estimates`); a recording
    without it gets the online estimator (:class:`kinefuse.capture.sync.online.OnlineClock`, default
    parameters) replayed over its probes. Errors are ``|estimate - truth|`` at the estimate's time,
    from ``warmup_s`` after the first estimate of each estimator epoch (a fresh start, e.g. after a
    reconnect, warms up again).
    """
    from kinefuse.formats.store.live_tables import clock_estimates

    truth = store.truth()
    out: dict[str, Any] = {"by_sensor": {}, "warmup_s": warmup_s}
    every = []
    sources = set()
    for info in store.sensors():
        sid = info.id
        est = clock_estimates(store, sid)
        if est.size:
            t, off, epoch = est[:, 0], est[:, 1], est[:, 4]
            sources.add("recorded by the server (live_clock)")
        else:
            rep = _replayed_estimates(store.clock_probes(sid))
            t, off, epoch = rep[:, 0], rep[:, 1], rep[:, 2]
            sources.add("online estimator replayed over the recorded probes")
        if not t.size:
            out["by_sensor"][sid] = {"estimates": 0, "p50_ms": None, "max_ms": None}
            continue
        true_clock = truth.sensor(sid)[1]
        true_host = AffineClock.from_drift_ppm(
            true_clock["host_drift_ppm"], offset=true_clock["host_offset_s"]
        )
        true_off = true_host.forward(t) - t
        err = np.abs(off - true_off)
        # each epoch's first estimate starts a warm-up (a reset or a reconnect)
        new = np.r_[True, epoch[1:] != epoch[:-1]]
        start = t[new][np.cumsum(new) - 1]
        keep = t >= start + warmup_s
        every.append(err[keep])
        out["by_sensor"][sid] = {
            "estimates": int(t.size),
            "epochs": int(new.sum()),
            "p50_ms": float(1e3 * np.median(err[keep])) if keep.any() else None,
            "max_ms": float(1e3 * err[keep].max()) if keep.any() else None,
        }
    allerr = np.concatenate(every) if every else np.zeros(0)
    out["source"] = ", ".join(sorted(sources))
    out["p50"] = float(1e3 * np.median(allerr)) if allerr.size else None
    out["max"] = float(1e3 * allerr.max()) if allerr.size else None
    return out


def calibration_figures(store: SessionStore) -> dict[str, Any]:
    """The live calibration stored in the recording against the true rig (yaw-aligned, as
    :func:`kinefuse.capture.calibration.compare.pose_errors`), and its grade as the server gave
    it."""
    from kinefuse.capture.calibration.compare import pose_errors
    from kinefuse.lab.poses import resolve_poses

    poses, source = resolve_poses(store, None, False)
    ids = sorted(poses)
    truth = store.truth()
    pe = pose_errors(
        np.stack([poses[i] for i in ids]),
        np.stack([truth.sensor(i)[0] for i in ids]),
        align="yaw",
    )
    live = store.meta().get("live_calibration")
    grade = live.get("grade") if isinstance(live, dict) else None
    reasons = live.get("reasons") if isinstance(live, dict) else None
    return {
        "grade": grade,
        "reasons": list(reasons) if isinstance(reasons, list) else [],
        "source": source,
        "mean_position_error_m": pe.mean_position_error_m,
        "mean_rotation_error_deg": pe.mean_rotation_error_deg,
        "by_sensor": {
            i: {
                "position_error_m": float(pe.position_error_m[k]),
                "rotation_error_deg": float(pe.rotation_error_deg[k]),
            }
            for k, i in enumerate(ids)
        },
    }


def live_vs_offline(store: SessionStore) -> dict[str, Any]:
    """MAE of the frames the server published and of offline ``best`` on the same recording, at
    the same frame times, against the truth (in the calibration's world, as ``evaluate`` does);
    both over the frames x joints that both solved (``common``) and each over its own."""
    from kinefuse.core.geometry.transforms import apply_transform
    from kinefuse.formats.store.live_tables import live_fused
    from kinefuse.lab.fusion_truth import calibration_alignment, truth_at
    from kinefuse.lab.poses import resolve_poses
    from kinefuse.pipeline.store_inputs import load_sensors, run_method

    lf = live_fused(store)
    poses, _ = resolve_poses(store, None, False)
    truth2world, _ = calibration_alignment(store, poses)
    truth = apply_transform(truth2world, truth_at(store, lf.t_server_s))
    in_motion = np.isfinite(truth).all((1, 2))
    t = lf.t_server_s[in_motion]
    truth = truth[in_motion]
    live = lf.positions_m[in_motion]
    sensors = load_sensors(store, poses)
    offline = run_method(sensors, t, "best").positions
    err_live = np.linalg.norm(live - truth, axis=-1)
    err_off = np.linalg.norm(offline - truth, axis=-1)
    both = np.isfinite(err_live) & np.isfinite(err_off)

    def mean(e: Array) -> float | None:
        e = e[np.isfinite(e)]
        return float(e.mean()) if e.size else None

    live_c, off_c = mean(np.where(both, err_live, np.nan)), mean(np.where(both, err_off, np.nan))
    return {
        "frames": int(t.size),
        "live": live_c,
        "offline": off_c,
        "ratio": (live_c / off_c) if live_c is not None and off_c else None,
        "common_fraction": float(both.mean()) if both.size else 0.0,
        "live_own": mean(err_live),
        "offline_own": mean(err_off),
        "live_coverage": float(np.isfinite(err_live).mean()) if err_live.size else 0.0,
        "offline_coverage": float(np.isfinite(err_off).mean()) if err_off.size else 0.0,
    }


def client_connections(store: SessionStore) -> dict[str, dict[str, Any]]:
    """Per sensor: its connections and how long before the playback of the simulated session
    started (true time 0, on the server clock) it first connected, seconds (negative: it joined
    late and missed the start of the wand phase)."""
    from kinefuse.formats.store.live_tables import events

    info = store.truth().info("live_playback")
    start = info.get("true_to_server_s") if isinstance(info, dict) else None
    out: dict[str, dict[str, Any]] = {}
    for t, kind, sid, _ in events(store):
        if sid is None or kind != "connected":
            continue
        c = out.setdefault(sid, {"connections": 0, "connected_before_playback_s": None})
        c["connections"] += 1
        if c["connections"] == 1 and isinstance(start, int | float):
            c["connected_before_playback_s"] = float(start) - t
    return out


def evaluate_live(
    recording: Path, *, offline_report: dict[str, Any] | None = None
) -> dict[str, Any]:
    """Every figure of a live run (the recording must hold its truth: :func:`write_live_truth`).

    Returns
    -------
    dict
        JSON-ready: ``frames_fused``, ``mae_m`` (``live``, ``offline`` on common frames x joints,
        ``ratio``...), ``calibration`` (``grade``, ``mean_position_error_m``...),
        ``clock_offset_error_ms`` (``p50``, ``max`` after the warm-up, per sensor),
        ``latency_ms`` (``p50``, ``p99``, ``max`` of client host receive -> fused frame
        published, server clock), and with ``offline_report`` (``run_evaluate``'s) the offline
        MAE of each method.
    """
    from kinefuse.formats.store.live_tables import live_fused

    with SessionStore.open(recording) as store:
        if not store.has_truth():
            raise InputError(f"{recording} holds no truth yet: write it with write_live_truth")
        lf = live_fused(store)
        with_body = np.isfinite(lf.positions_m).all(-1).any(-1)
        result: dict[str, Any] = {
            "frames_fused": int(lf.t_server_s.size),
            "frames_with_body": int(with_body.sum()),
            "mae_m": live_vs_offline(store),
            "calibration": calibration_figures(store),
            "clock_offset_error_ms": clock_errors(store),
            "latency_ms": _quantiles_ms(lf.latency_s),
        }
        result["latency_ms"]["definition"] = (
            "client host receive (on the server clock) -> fused frame published"
        )
        # the same over the frames published before the first client left (the capture, without
        # the stop, when the last frames wait for clients that have ended)
        from kinefuse.formats.store.live_tables import events

        gone = [t for t, kind, _, _ in events(store) if kind == "disconnected"]
        before = lf.t_recorded_s < min(gone) if gone else np.ones(lf.t_server_s.size, bool)
        result["latency_ms"]["before_first_disconnect"] = _quantiles_ms(lf.latency_s[before])
        result["clients"] = client_connections(store)
    if offline_report is not None:
        result["offline_methods_mae_m"] = {
            m: v["mae_m"] for m, v in offline_report.items() if isinstance(v, dict) and "mae_m" in v
        }
    return result


def format_live(r: dict[str, Any]) -> str:
    """A short text summary of :func:`evaluate_live`'s result."""

    def f(v: object, scale: float = 1.0, fmt: str = ".2f") -> str:
        return "n/a" if not isinstance(v, int | float) else format(scale * v, fmt)

    m, c, k, lat = r["mae_m"], r["calibration"], r["clock_offset_error_ms"], r["latency_ms"]
    lines = [
        f"fused frames published: {r['frames_fused']} ({r['frames_with_body']} with a body)",
        f"MAE on the same {m['frames']} frames (joints both solved, "
        f"{f(m['common_fraction'], 100, '.1f')} %): live {f(m['live'], 100)} cm, offline best "
        f"{f(m['offline'], 100)} cm (live / offline {f(m['ratio'], 1, '.3f')})",
        f"live calibration: grade {c['grade']}, mean error vs the true rig "
        f"{f(c['mean_position_error_m'], 1e3)} mm, {f(c['mean_rotation_error_deg'], 1, '.3f')} deg",
        f"clock offset error after {k['warmup_s']:g} s: p50 {f(k['p50'], 1, '.3f')} ms, max "
        f"{f(k['max'], 1, '.3f')} ms",
        f"latency (host receive -> published): p50 {f(lat['p50'], 1, '.1f')} ms, p99 "
        f"{f(lat['p99'], 1, '.1f')} ms (before the first client left: p99 "
        f"{f(lat.get('before_first_disconnect', {}).get('p99'), 1, '.1f')} ms)",
    ]
    if c["grade"] != "good":
        lines += [f"  why: {why}" for why in c.get("reasons") or []]
    late = [
        f"{sid} ({-c['connected_before_playback_s']:.1f} s)"
        for sid, c in r.get("clients", {}).items()
        if isinstance(c.get("connected_before_playback_s"), float)
        and c["connected_before_playback_s"] < 0
    ]
    if late:
        lines.append("warning: joined after the playback started: " + ", ".join(late))
    return "\n".join(lines)

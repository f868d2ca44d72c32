"""``kinefuse inspect``: what a session store holds and, for simulated sessions, how wrong the
sensors were.

The error figures compare each reported joint (not NaN) with the true joint in the same sensor
frame at the capture instant (``Truth.observations``, matched by sequence number). This is
evaluation code: it is the one place besides the simulator that reads the truth tables.
"""

from __future__ import annotations

import warnings
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.skeleton import JOINTS, N_JOINTS, TrackingState
from kinefuse.errors import InputError
from kinefuse.formats.store.session_store import SessionStore

__all__ = ["format_inspect", "inspect_session"]


def _num(x: float | np.floating[Any] | None) -> float | None:
    """A JSON-safe float: NaN and None become None."""
    if x is None:
        return None
    f = float(x)
    return None if np.isnan(f) else f


def _median(x: NDArray[np.float64]) -> float | None:
    return _num(np.median(x)) if x.size else None


def _sensor_rate_hz(t_sensor_s: NDArray[np.float64]) -> float | None:
    """Frame rate from capture times: 1 / median frame interval (robust to dropped frames)."""
    if t_sensor_s.size < 2:
        return None
    dt = np.diff(np.sort(t_sensor_s))
    dt = dt[dt > 0]
    return _num(1.0 / np.median(dt)) if dt.size else None


#: The bulk of a sensor's time stamps: the central 90 % of them (quantiles 5 % and 95 %).
BULK_QUANTILES = (0.05, 0.95)
#: Stamps further outside the bulk than this share of its length (plus :data:`BULK_PAD_S`) are
#: not counted in a duration: a recording's frames are spread evenly, a forged or corrupt stamp
#: lies far off (a 2-minute take with one frame stamped 2,000 s later is not 35 minutes long).
BULK_REACH = 0.5
BULK_PAD_S = 1.0


def plausible_span(t_s: NDArray[np.float64]) -> tuple[float, int]:
    """``(span_s, ignored)``: the span of the stamps ``t_s`` (seconds) that lie within reach of
    their bulk (:data:`BULK_QUANTILES`, :data:`BULK_REACH`, :data:`BULK_PAD_S`), and how many
    stamps lie beyond it (or are not finite) and were ignored."""
    t = np.asarray(t_s, dtype=np.float64)
    ok = np.isfinite(t)
    if not ok.any():
        return 0.0, int(t.size)
    lo, hi = np.quantile(t[ok], BULK_QUANTILES)
    reach = BULK_REACH * float(hi - lo) + BULK_PAD_S
    ok &= (t >= lo - reach) & (t <= hi + reach)
    kept = t[ok]
    return float(kept.max() - kept.min()), int(t.size - kept.size)


def inspect_session(store: SessionStore | str | PathLike[str]) -> dict[str, Any]:
    """Summarize a session store as a JSON-able dict.

    Parameters
    ----------
    store : SessionStore or path-like
        An open store, or the path of one (opened read-only and closed again).

    Returns
    -------
    dict
        ``schema_version``, ``path``, ``meta``; ``sensors``: a list of per-sensor dicts
        (``id``, ``serial``, ``frames``, ``frames_with_body``, ``rate_hz`` measured from the
        sensor-clock timestamps, ``nominal_rate_hz``, ``duration_s``, ``stamps_ignored``,
        ``depth_frames``, ``clock_probes``, ``observation_error_m`` median or None,
        ``intrinsics`` of its depth camera as stored); ``duration_s`` (longest per-sensor span
        of capture times, seconds, counting only the stamps near the bulk of each sensor's,
        :func:`plausible_span`; ``stamps_ignored`` per sensor and in all: the others);
        ``joints`` (25); ``has_truth``;
        ``tracking_state_fraction`` (``tracked``, ``inferred``, ``not_tracked`` over all
        frames x joints of all sensors); ``observation_error_m`` (``median``, ``p95``,
        ``by_joint`` {name: median}, ``by_state`` {``tracked``, ``inferred``}, ``samples``), or
        None without truth; ``lr_swap_fraction`` (frames the simulator swapped left/right among
        matched frames with a body) or None without truth; ``complete`` (the writer finished);
        ``storage_bytes`` (``file``, ``depth_frames``, ``observations``); ``coverage``
        (:func:`kinefuse.lab.coverage.tracking_coverage`: how much of the time each sensor
        saw the body, when fewer than 2 did; no truth used) and its ``warnings``; ``left_out``
        (``[{id, reason}]``: sensors whose time stamps are not the recording's, left out of the
        coverage and the duration; each sensor's entry has its ``left_out`` reason or None);
        ``calibrations``; ``fused_methods``. Distances in metres; a figure with no data is None.
    """
    if isinstance(store, SessionStore):
        return _inspect(store)
    if isinstance(store, str | PathLike):
        with SessionStore.open(store) as s:
            return _inspect(s)
    raise InputError(
        f"inspect_session: expected a SessionStore or the path of one, got {type(store).__name__}"
    )


def never_seen_advice(store: SessionStore, sensors: list[dict[str, Any]]) -> dict[str, str]:
    """What to say of each sensor of a recording of real sensors that never saw the body.

    A sensor that delivered only depth frames had no body tracker: a session made by
    ``kinefuse track`` gets the command that tracks its recordings again with kinefuse's own
    tracker (into a new file), a live recording the option its client needs. ``sensors``: the
    per-sensor entries of :func:`inspect_session`.
    """
    import shlex

    meta = store.meta()
    tracked = meta.get("track_recordings") if meta.get("generator") == "kinefuse track" else None
    retrack = ""
    if isinstance(tracked, dict) and tracked:
        recs = [str(v.get("recording", "")) for v in tracked.values() if isinstance(v, dict)]
        new = _free_name(store.path.with_name(f"{store.path.stem}-pose.sqlite"))
        retrack = "kinefuse track " + " ".join(
            shlex.quote(r) for r in [*recs, "--out", str(new), "--tracker", "pose"]
        )
    out = {}
    for e in sensors:
        sid = e["id"]
        if e["frames_with_body"]:
            continue
        tracker = tracked.get(sid, {}).get("tracker") if isinstance(tracked, dict) else None
        if tracker:
            out[sid] = (
                f"sensor {sid}: the body tracker ({tracker}) found no person in its "
                f"{e['frames']} frames: check that the person is in the camera's view"
            )
        elif e["depth_frames"] and retrack:
            out[sid] = (
                f"sensor {sid} delivered depth frames only, no body tracker's frames (it was "
                f"tracked without --tracker): track the recordings again with one, `{retrack}` "
                "(`kinefuse sensor --list-sources` lists the trackers installed)"
            )
        elif e["depth_frames"]:
            out[sid] = (
                f"sensor {sid} delivered depth frames only, no body tracker's frames: add "
                "--tracker NAME to its kinefuse sensor command to get skeletons (`kinefuse "
                "sensor --list-sources` lists the trackers installed)"
            )
        elif e["frames"]:
            out[sid] = (
                f"sensor {sid} never saw the body in its {e['frames']} frames: check that it looks "
                "at the capture area and that the person is in its view"
            )
        else:
            out[sid] = (
                f"sensor {sid} sent no frame: check that its client ran and reached the server"
            )
    return out


def _free_name(path: Path) -> Path:
    """``path``, or ``stem-2.suffix``, ``stem-3.suffix``... the first that does not exist."""
    k = 2
    out = path
    while out.exists():
        out = path.with_name(f"{path.stem}-{k}{path.suffix}")
        k += 1
    return out


def _inspect(store: SessionStore) -> dict[str, Any]:
    meta = store.meta()
    has_truth = store.has_truth()
    truth = store.truth() if has_truth else None

    sensors: list[dict[str, Any]] = []
    state_counts = np.zeros(3, dtype=np.int64)
    errors: list[NDArray[np.float64]] = []  # per sensor (M, 25), NaN where not reported
    err_states: list[NDArray[np.int8]] = []
    swapped_frames = 0
    body_frames = 0
    matched_any = False
    spans: list[float] = []

    for info in store.sensors():
        obs = store.observations(info.id)
        n = obs.n_frames
        has_body = obs.has_body
        state_counts += np.bincount(obs.states.ravel().astype(np.intp), minlength=3)[:3]
        span, ignored = plausible_span(obs.t_sensor_s) if n else (0.0, 0)
        spans.append(span)
        entry: dict[str, Any] = {
            "id": info.id,
            "serial": info.serial,
            "frames": n,
            "frames_with_body": int(has_body.sum()),
            "rate_hz": _sensor_rate_hz(obs.t_sensor_s),
            "nominal_rate_hz": info.rate_hz,
            "duration_s": span,
            "stamps_ignored": ignored,
            "depth_frames": store.depth_frame_count(info.id),
            "clock_probes": int(store.clock_probes(info.id).shape[0]),
            "observation_error_m": None,
            "intrinsics": info.intrinsics.to_dict(),
        }
        if truth is not None:
            t_seq, _, t_joints, _, t_swapped = truth.observations(info.id)
            _, i_obs, i_true = np.intersect1d(obs.seq, t_seq, return_indices=True)
            if i_obs.size:
                matched_any = True
                err = np.linalg.norm(obs.joints_m[i_obs] - t_joints[i_true], axis=-1)
                errors.append(err)
                err_states.append(obs.states[i_obs])
                body = has_body[i_obs]
                body_frames += int(body.sum())
                swapped_frames += int((t_swapped[i_true] & body).sum())
                e = err[np.isfinite(err)]
                entry["observation_error_m"] = _median(e)
        sensors.append(entry)

    total = int(state_counts.sum())
    fractions = {
        "tracked": _num(state_counts[TrackingState.TRACKED] / total) if total else None,
        "inferred": _num(state_counts[TrackingState.INFERRED] / total) if total else None,
        "not_tracked": _num(state_counts[TrackingState.NOT_TRACKED] / total) if total else None,
    }

    error_summary: dict[str, Any] | None = None
    swap_fraction: float | None = None
    if matched_any:
        err = np.concatenate(errors, axis=0)  # (M, 25)
        st = np.concatenate(err_states, axis=0)
        ok = np.isfinite(err)
        flat = err[ok]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN joints -> None
            by_joint = np.nanmedian(err, axis=0) if err.shape[0] else np.full(N_JOINTS, np.nan)
        error_summary = {
            "median": _median(flat),
            "p95": _num(np.percentile(flat, 95)) if flat.size else None,
            "by_joint": {name: _num(v) for name, v in zip(JOINTS, by_joint, strict=True)},
            "by_state": {
                "tracked": _median(err[ok & (st == TrackingState.TRACKED)]),
                "inferred": _median(err[ok & (st == TrackingState.INFERRED)]),
            },
            "samples": int(flat.size),
        }
        swap_fraction = _num(swapped_frames / body_frames) if body_frames else None

    from kinefuse.lab.coverage import coverage_warnings, tracking_coverage

    coverage = tracking_coverage(store)
    simulated = has_truth or str(meta.get("generator", "")).endswith(" simulate")
    left_out = coverage["left_out"]
    for entry in sensors:
        entry["left_out"] = left_out.get(entry["id"])
    spans = [sp for sp, e in zip(spans, sensors, strict=True) if e["left_out"] is None]
    return {
        "path": str(store.path),
        "schema_version": meta.get("schema_version"),
        "complete": store.complete,
        "storage_bytes": store.storage_bytes(),
        "coverage": coverage,
        "warnings": coverage_warnings(
            coverage, None if simulated else never_seen_advice(store, sensors)
        ),
        "left_out": [{"id": k, "reason": v} for k, v in left_out.items()],
        "meta": meta,
        "sensors": sensors,
        "duration_s": max(spans) if spans else 0.0,
        "stamps_ignored": sum(e["stamps_ignored"] for e in sensors if e["left_out"] is None),
        "joints": N_JOINTS,
        "has_truth": has_truth,
        "tracking_state_fraction": fractions,
        "observation_error_m": error_summary,
        "lr_swap_fraction": swap_fraction,
        "calibrations": store.calibration_names(),
        "fused_methods": store.fused_methods(),
    }


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100.0 * x:.1f} %"


def _pct0(x: float | None) -> str:
    return "-" if x is None else f"{100.0 * x:.0f} %"


def _cm(x: float | None) -> str:
    return "-" if x is None else f"{100.0 * x:.1f} cm"


def format_inspect(d: dict[str, Any]) -> str:
    """A short human-readable table of :func:`inspect_session`'s result (distances in cm)."""
    lines = [
        f"session {d.get('path', '?')}  (schema {d['schema_version']}, "
        f"created {d.get('meta', {}).get('created', '?')})",
        f"duration {d['duration_s']:.2f} s, {d['joints']} joints, "
        f"ground truth: {'yes' if d['has_truth'] else 'no'}, "
        f"size {d['storage_bytes']['file'] / 1e6:.1f} MB "
        f"(depth frames {d['storage_bytes']['depth_frames'] / 1e6:.1f} MB)",
    ]
    ignored = {
        s["id"]: s["stamps_ignored"]
        for s in d["sensors"]
        if s.get("stamps_ignored") and s.get("left_out") is None
    }
    if ignored:
        lines.append(
            f"duration from the bulk of the time stamps: {sum(ignored.values())} frame(s) stamped "
            "far outside it not counted ("
            + ", ".join(f"{k}: {v}" for k, v in ignored.items())
            + "; a clock jump or forged stamps)"
        )
    if not d["complete"]:
        lines.append(
            "INCOMPLETE: the run that wrote this session did not finish; sensors or frames may "
            "be missing (fuse, calibrate and evaluate refuse it unless given --partial)"
        )
    lines += [
        "",
        f"{'sensor':<12}{'frames':>8}{'body':>8}{'seen':>7}{'rate_hz':>9}{'depth':>7}"
        f"{'probes':>8}{'err_median':>12}",
    ]
    cov = d["coverage"]["sensors"]
    for s in d["sensors"]:
        rate = "-" if s["rate_hz"] is None else f"{s['rate_hz']:.2f}"
        seen = cov.get(s["id"], {}).get("body_fraction")
        lines.append(
            f"{s['id']:<12}{s['frames']:>8}{s['frames_with_body']:>8}{_pct0(seen):>7}{rate:>9}"
            f"{s['depth_frames']:>7}{s['clock_probes']:>8}{_cm(s['observation_error_m']):>12}"
        )
    for s in d["sensors"]:
        k = s.get("intrinsics")
        if k:
            lines.append(
                f"intrinsics {s['id']}: {k['width']}x{k['height']} px, fx {k['fx']:.2f} "
                f"fy {k['fy']:.2f} cx {k['cx']:.2f} cy {k['cy']:.2f}, depth "
                f"{k['min_range_m']:.2f}-{k['max_range_m']:.2f} m"
            )
    f = d["tracking_state_fraction"]
    lines += [
        "",
        f"tracking states: tracked {_pct(f['tracked'])}, inferred {_pct(f['inferred'])}, "
        f"not tracked {_pct(f['not_tracked'])}",
    ]
    e = d.get("observation_error_m")
    if e is not None:
        lines.append(
            f"observation error vs truth: median {_cm(e['median'])}, p95 {_cm(e['p95'])}; "
            f"tracked {_cm(e['by_state']['tracked'])}, inferred {_cm(e['by_state']['inferred'])}"
        )
        lines.append(f"left/right swapped: {_pct(d['lr_swap_fraction'])} of frames with a body")
        lines.append("median error by joint:")
        items = [f"{name:<14}{_cm(v):>9}" for name, v in e["by_joint"].items()]
        for i in range(0, len(items), 3):
            lines.append("  " + "   ".join(items[i : i + 3]))
    for w in d.get("warnings", []):
        lines.append(f"warning: {w}")
    if d.get("calibrations"):
        lines.append(f"calibrations: {', '.join(d['calibrations'])}")
    if d.get("fused_methods"):
        lines.append(f"fused: {', '.join(d['fused_methods'])}")
    return "\n".join(lines)

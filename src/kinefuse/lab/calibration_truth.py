"""Calibration against the simulator's truth (evaluation code: reads the truth).

Sensor poses are compared after aligning the estimated world onto the true one by a translation
and a rotation about the vertical (``align="yaw"``): the world's origin and heading are a choice
of the protocol (the paper's method puts the origin at the wand, 1 m above the floor), while
gravity and scale are measured and so stay in the error. Errors without any alignment are
reported too.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.capture.calibration.calibration_run import CalibrationInput, calibrate
from kinefuse.capture.calibration.compare import Align, pose_errors
from kinefuse.capture.calibration.register import Registration, Sightings
from kinefuse.core.geometry.transforms import apply_transform, check_transform, invert_transform
from kinefuse.core.outputs import atomic_file, atomic_write_text, never_replace
from kinefuse.errors import CalibrationError, InputError
from kinefuse.formats.store.session_store import SessionStore

Array = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class WandErrors:
    """Errors of individual wand sightings, with what the paper plots them against.

    Attributes
    ----------
    error_m : (N,) float
        Distance between the estimated and the true wand centre.
    distance_m : (N,) float
        True distance of the wand from the sensor.
    angle_deg : (N,) float
        True angle between the wand direction and the sensor's optical axis.
    """

    error_m: Array
    distance_m: Array
    angle_deg: Array


def wand_errors(est_m: ArrayLike, true_m: ArrayLike, true_centre_sensor_m: ArrayLike) -> WandErrors:
    """Per-sighting errors against distance and angle from the optical axis.

    Parameters
    ----------
    est_m, true_m : (N, 3) float
        Estimated and true wand centres in the same frame: the sensor frame for the detector's
        error, or the world (estimated pose mapped through ``est2true``) for the calibration's.
    true_centre_sensor_m : (N, 3) float
        True wand centre in the sensor frame (gives distance and angle).
    """
    e = np.asarray(est_m, dtype=np.float64).reshape(-1, 3)
    t = np.asarray(true_m, dtype=np.float64).reshape(-1, 3)
    c = np.asarray(true_centre_sensor_m, dtype=np.float64).reshape(-1, 3)
    if not (e.shape == t.shape == c.shape):
        raise InputError(f"shapes differ: {e.shape}, {t.shape}, {c.shape}")
    dist = np.linalg.norm(c, axis=1)
    ang = np.degrees(np.arccos(np.clip(c[:, 2] / np.maximum(dist, 1e-12), -1.0, 1.0)))
    return WandErrors(np.linalg.norm(e - t, axis=1), dist, ang)


def mapped_wand_errors(
    sensor2world: ArrayLike,
    est2true: ArrayLike,
    centre_sensor_m: ArrayLike,
    true_world_m: ArrayLike,
    true_centre_sensor_m: ArrayLike,
) -> WandErrors:
    """Errors of one sensor's sightings mapped to the world with its estimated pose.

    ``est2true`` is the alignment from :func:`pose_errors`; the error combines detection and
    registration, like the paper's comparison with a laser meter.
    """
    s2w = check_transform(sensor2world).reshape(4, 4)
    e2t = check_transform(est2true).reshape(4, 4)
    t = e2t @ s2w
    c = np.asarray(centre_sensor_m, dtype=np.float64).reshape(-1, 3)
    return wand_errors(c @ t[:3, :3].T + t[:3, 3], true_world_m, true_centre_sensor_m)


@dataclass(frozen=True, eq=False)
class Binned:
    """Statistics of an error in bins of a variable: centres, mean, std, quartiles, count."""

    centre: Array
    mean: Array
    std: Array
    median: Array
    q25: Array
    q75: Array
    count: NDArray[np.int64]


def binned(x: ArrayLike, err: ArrayLike, edges: ArrayLike) -> Binned:
    """Mean, std and median of ``err`` in the bins ``edges`` of ``x`` (NaN for empty bins)."""
    xv = np.asarray(x, dtype=np.float64).reshape(-1)
    ev = np.asarray(err, dtype=np.float64).reshape(-1)
    ed = np.asarray(edges, dtype=np.float64).reshape(-1)
    if xv.shape != ev.shape:
        raise InputError(f"x and err differ in length: {xv.shape} vs {ev.shape}")
    if ed.size < 2 or np.any(np.diff(ed) <= 0):
        raise InputError("edges must be at least 2 increasing values")
    ok = np.isfinite(xv) & np.isfinite(ev)
    idx = np.digitize(xv[ok], ed) - 1
    nb = ed.size - 1
    inside = (idx >= 0) & (idx < nb)
    idx, vals = idx[inside], ev[ok][inside]
    count = np.bincount(idx, minlength=nb).astype(np.int64)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.bincount(idx, weights=vals, minlength=nb) / count
        sq = np.bincount(idx, weights=vals * vals, minlength=nb) / count
    std = np.sqrt(np.maximum(sq - mean * mean, 0.0))
    order = np.argsort(idx, kind="stable")
    splits = np.split(vals[order], np.cumsum(count)[:-1])
    q = np.array([np.percentile(s, [25, 50, 75]) if s.size else [np.nan] * 3 for s in splits])
    q = q.reshape(nb, 3)
    return Binned(0.5 * (ed[1:] + ed[:-1]), mean, std, q[:, 1], q[:, 0], q[:, 2], count)


@dataclass(frozen=True, eq=False)
class SightingsCurve:
    """Mean calibration errors against the number of wand sightings used."""

    duration_s: Array
    mean_sightings: Array
    mean_position_error_m: Array
    mean_rotation_error_deg: Array


def error_vs_sightings(
    sightings: Mapping[str, Sightings],
    true_sensor2world: ArrayLike,
    register: Callable[[Mapping[str, Sightings]], Registration],
    durations_s: Sequence[float],
    *,
    align: Align = "yaw",
) -> SightingsCurve:
    """Calibrate on the first ``d`` seconds of the wand phase for each ``d``; errors vs truth.

    Parameters
    ----------
    sightings : mapping sensor id -> Sightings
    true_sensor2world : (S, 4, 4) float
        True poses in the order of ``sightings``.
    register : callable
        ``sightings -> Registration`` (e.g. ``lambda s: register_full(s, floors=floors)``).
    durations_s : sequence of float
        Lengths of the calibration phase to try.

    Returns
    -------
    SightingsCurve
        Durations where the registration succeeded, with the mean number of sightings per sensor
        and the mean errors.
    """
    true = check_transform(true_sensor2world).reshape(-1, 4, 4)
    ids = list(sightings)
    t0 = min(float(s.t_server_s[0]) for s in sightings.values() if len(s))
    rows = []
    for d in durations_s:
        sub = {
            k: Sightings(
                s.t_server_s[s.t_server_s <= t0 + d],
                s.centre_sensor_m[s.t_server_s <= t0 + d],
                s.quality[s.t_server_s <= t0 + d],
            )
            for k, s in sightings.items()
        }
        try:
            reg = register(sub)
        except CalibrationError:  # too few sightings is a data point, not a failure
            continue
        order = [reg.sensor_ids.index(k) for k in ids]
        pe = pose_errors(reg.sensor2world[order], true, align=align)
        rows.append(
            (
                d,
                float(np.mean([len(v) for v in sub.values()])),
                pe.mean_position_error_m,
                pe.mean_rotation_error_deg,
            )
        )
    arr = np.array(rows, dtype=np.float64).reshape(-1, 4)
    return SightingsCurve(arr[:, 0], arr[:, 1], arr[:, 2], arr[:, 3])


def plot_calibration_errors(
    path: str | Path,
    errors: WandErrors,
    *,
    curve: SightingsCurve | None = None,
    title: str = "Calibration error",
    distance_edges_m: ArrayLike = (0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 4.5),
    angle_edges_deg: ArrayLike = (0, 5, 10, 15, 20, 25, 30, 35, 40),
) -> Path:
    """Write a PNG with error vs wand distance, vs angle from the optical axis, and (optionally)
    vs number of sightings, like the paper's figures. Returns the path written."""
    from matplotlib.figure import Figure  # drawn off-screen; no global backend is changed

    n_panels = 3 if curve is not None else 2
    fig = Figure(figsize=(5 * n_panels, 4), constrained_layout=True)
    axes = fig.subplots(1, n_panels)
    for ax, x, edges, label in (
        (axes[0], errors.distance_m, distance_edges_m, "wand distance from the sensor (m)"),
        (axes[1], errors.angle_deg, angle_edges_deg, "wand angle from the optical axis (deg)"),
    ):
        b = binned(x, errors.error_m, edges)
        mm = errors.error_m * 1e3
        ax.scatter(x, mm, s=2, alpha=0.2, color="0.5", label="sightings")
        ax.errorbar(
            b.centre,
            b.median * 1e3,
            yerr=np.abs(np.stack([b.median - b.q25, b.q75 - b.median])) * 1e3,
            fmt="o-",
            color="C0",
            capsize=3,
            label="median, quartiles",
        )
        ax.plot(b.centre, b.mean * 1e3, "s--", color="C3", ms=4, label="mean")
        fin = mm[np.isfinite(mm)]
        if fin.size:  # gross outliers (shown as the count above the axis) would hide the trend
            top = 1.5 * float(np.percentile(fin, 95))
            n_out = int((fin > top).sum())
            ax.set_ylim(0.0, top)
            if n_out:
                ax.set_title(f"{n_out} sightings above {top:.0f} mm not shown", fontsize=9)
        ax.set_xlabel(label)
        ax.set_ylabel("error (mm)")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper left")
    if curve is not None:
        ax = axes[2]
        ax.plot(
            curve.mean_sightings, curve.mean_position_error_m * 1e3, "o-", label="position (mm)"
        )
        ax2 = ax.twinx()
        ax2.plot(
            curve.mean_sightings,
            curve.mean_rotation_error_deg,
            "s--",
            color="C1",
            label="rotation (deg)",
        )
        ax.set_xlabel("wand sightings per sensor")
        ax.set_ylabel("mean position error (mm)")
        ax2.set_ylabel("mean rotation error (deg)")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right")
        ax2.legend(loc="center right")
    fig.suptitle(title)
    out = Path(path)
    with atomic_file(out, what="plot", recognizer=never_replace, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=100, format="png")

    return out


def calibration_errors(
    store: SessionStore, reg: Registration, *, align: str = "yaw"
) -> dict[str, Any]:
    """Per-sensor position and rotation errors of a registration against the true poses."""
    truth = store.truth()
    true = np.stack([truth.sensor(sid)[0] for sid in reg.sensor_ids])
    pe = pose_errors(reg.sensor2world, true, align=align)  # type: ignore[arg-type]
    raw = pose_errors(reg.sensor2world, true, align="none")
    return {
        "alignment": align,
        "by_sensor": {
            sid: {
                "position_error_m": float(pe.position_error_m[k]),
                "rotation_error_deg": float(pe.rotation_error_deg[k]),
            }
            for k, sid in enumerate(reg.sensor_ids)
        },
        "mean_position_error_m": pe.mean_position_error_m,
        "mean_rotation_error_deg": pe.mean_rotation_error_deg,
        "unaligned_mean_position_error_m": raw.mean_position_error_m,
        "unaligned_mean_rotation_error_deg": raw.mean_rotation_error_deg,
        "est2true": pe.est2true,
    }


def _wand_errors(
    store: SessionStore, cal: CalibrationInput, reg: Registration, est2true: np.ndarray
) -> WandErrors:
    truth = store.truth()
    t_w, c_w = truth.wand()
    errs, dists, angs = [], [], []
    for k, sid in enumerate(reg.sensor_ids):
        s = cal.sightings[sid]
        true_w = np.stack([np.interp(s.t_server_s, t_w, c_w[:, i]) for i in range(3)], axis=1)
        true_s = apply_transform(invert_transform(truth.sensor(sid)[0]), true_w)
        e = mapped_wand_errors(reg.sensor2world[k], est2true, s.centre_sensor_m, true_w, true_s)
        errs.append(e.error_m)
        dists.append(e.distance_m)
        angs.append(e.angle_deg)
    return WandErrors(np.concatenate(errs), np.concatenate(dists), np.concatenate(angs))


def write_calibration_report(
    out_dir: Path, store: SessionStore, cal: CalibrationInput, reg: Registration, method: str
) -> list[Path]:
    """The paper's evaluation: error vs wand distance and angle (PNG), error vs sightings (CSV
    and the PNG's third panel)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    errs = calibration_errors(store, reg)
    wand = _wand_errors(store, cal, reg, errs["est2true"])
    truth = store.truth()
    true = np.stack([truth.sensor(sid)[0] for sid in reg.sensor_ids])
    phase = cal.phase_server_s[1] - cal.phase_server_s[0]
    durations = [d for d in (4, 6, 8, 10, 12, 15, 20, 30, 45, 60) if d <= phase + 1e-9]
    curve = error_vs_sightings(
        {sid: cal.sightings[sid] for sid in reg.sensor_ids},
        true,
        lambda s: calibrate(replace(cal, sightings=dict(s)), method),
        durations,
    )
    png = plot_calibration_errors(
        out_dir / f"calibration_errors_{method}.png",
        wand,
        curve=curve if len(curve.duration_s) else None,
        title=f"Calibration error ({method})",
    )
    csv = out_dir / f"calibration_vs_sightings_{method}.csv"
    rows = ["duration_s,mean_sightings,mean_position_error_mm,mean_rotation_error_deg"]
    for d, n, p, r in zip(curve.duration_s, curve.mean_sightings, curve.mean_position_error_m,
                          curve.mean_rotation_error_deg, strict=True):  # fmt: skip
        rows.append(f"{d:g},{n:.1f},{p * 1e3:.3f},{r:.4f}")
    atomic_write_text(csv, "\n".join(rows) + "\n", what="table", recognizer=never_replace)
    return [Path(png), csv]

"""Calibration against the simulator's truth (evaluation code: reads the truth).

Sensor poses are compared after aligning the estimated world onto the true one by a translation
and a rotation about the vertical (``align="yaw"``): the world's origin and heading are a choice
of the protocol (the paper's method puts the origin at the wand, 1 m above the floor), while
gravity and scale are measured and so stay in the error. Errors without any alignment are
reported too.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from kinefuse.calibration.evaluate import (
    WandErrors,
    error_vs_sightings,
    mapped_wand_errors,
    plot_calibration_errors,
    pose_errors,
)
from kinefuse.calibration.register import Registration
from kinefuse.calibration.session import CalibrationInput, calibrate
from kinefuse.geometry.transforms import apply_transform, invert_transform
from kinefuse.io.outputs import atomic_write_text, never_replace
from kinefuse.io.store.session import SessionStore


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

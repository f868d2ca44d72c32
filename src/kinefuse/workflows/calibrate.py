"""``kinefuse calibrate``: find every sensor's pose from a session's wand phase, grade the
result from its own residuals, write the calibration file."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from kinefuse.errors import CalibrationError, CalibrationFailed, InputError
from kinefuse.io.store.session import SessionStore


def run_calibrate(
    *,
    session: Path,
    method: str,
    out: Path | None,
    report_dir: Path | None = None,
    store_result: bool = False,
    accept: bool = False,
    allow_incomplete: bool = False,
    detector: str | None = None,
) -> dict[str, Any]:
    """Calibrate a session's sensors and grade the result from its own residuals.

    ``detector`` (``paper`` or ``robust``) finds the wand in the depth frames; by default each
    method uses its own: the paper's registration the paper's detector, ``full`` ours.

    The session is opened read-only unless ``store_result`` asks to store the calibration in it.
    A calibration graded ``failed`` is written nowhere unless ``accept``. The error figures
    (against the simulator's truth) are computed afterwards, by evaluation code, and only when
    the session has truth.
    """
    from kinefuse.calibration.calib_file import (
        calibration_from_registration,
        dumps_calibration,
        write_calibration,
    )
    from kinefuse.calibration.grade import grade_calibration
    from kinefuse.calibration.methods import METHODS
    from kinefuse.calibration.session import calibrate
    from kinefuse.io.outputs import atomic_dir, check_output_folder
    from kinefuse.pipeline.session import gather_usable_calibration

    if method not in METHODS:
        raise InputError(f"unknown calibration method {method!r}; choose from {', '.join(METHODS)}")
    for target, what in ((out, "calibration file"), (report_dir, "calibration report")):
        if target is not None:
            check_output_folder(target, what)
    with SessionStore.open(session, writable=store_result) as store:
        store.require_complete(allow_incomplete=allow_incomplete)
        det = detector or ("paper" if method == "paper" else "robust")
        cal_in, screen = gather_usable_calibration(store, detector=det)
        infos = {s.id: s for s in store.sensors() if s.id in screen.usable}
        try:
            reg = calibrate(cal_in, method)
        except CalibrationError as e:
            raise CalibrationFailed(_why_failed(e, det, cal_in.protocol)) from None
        grade = grade_calibration(reg, cal_in.floors)
        cal = calibration_from_registration(
            reg,
            {k: v.intrinsics for k, v in infos.items()},
            serials={k: v.serial for k, v in infos.items()},
        )
        text = dumps_calibration(cal)
        usable = grade.grade != "failed" or accept
        if usable and store_result:
            store.write_calibration(method, text)
        if usable and out is not None:
            write_calibration(out, text)
        result: dict[str, Any] = {
            "method": method,
            "detector": det,
            "world": reg.world,
            "rms_m": reg.rms_m,
            **grade.to_dict(),
            "accepted": usable,
            "stored_in_session": bool(usable and store_result),
            "sensors": [
                {
                    "id": sid,
                    "residual_m": float(reg.residual_m[k]),
                    "sightings": int(reg.n_sightings[k]),
                    "detected": int(cal_in.tracks[sid].found.sum()),
                    "frames": len(cal_in.tracks[sid].found),
                }
                for k, sid in enumerate(reg.sensor_ids)
            ],
            "out": str(out) if out is not None and usable else None,
            "left_out": [{"id": k, "reason": v} for k, v in screen.left_out.items()],
            "notes": screen.notes(),
        }
        if store.has_truth():
            from kinefuse.evaluation.calibration import calibration_errors, write_calibration_report

            errs = calibration_errors(store, reg)
            for s in result["sensors"]:
                s.update(errs["by_sensor"][s["id"]])
            for key in (
                "alignment",
                "mean_position_error_m",
                "mean_rotation_error_deg",
                "unaligned_mean_position_error_m",
                "unaligned_mean_rotation_error_deg",
            ):
                result[key] = errs[key]
            if report_dir is not None:
                with atomic_dir(report_dir, what="calibration report") as tmp:
                    written = write_calibration_report(tmp, store, cal_in, reg, method)
                result["written"] = [str(report_dir / p.name) for p in written]
        elif report_dir is not None:
            result["report_note"] = (
                "no report written: the error plots compare with the truth, and this session has "
                "none (a live recording)"
            )
    return result


def _why_failed(e: CalibrationError, detector: str, protocol: dict[str, object]) -> str:
    """What a registration that could not be computed says, with the likely cause: the paper's
    detector takes the nearest object in view for the wand, and when that object stays put while
    the wand moves the registration sees (almost) no move."""
    text = f"calibration failed: {e}"
    if detector == "paper" and "saw the wand move only" in str(e):
        length = protocol.get("axis_length_m")
        moved = f" (the protocol moves it {length:g} m)" if isinstance(length, int | float) else ""
        text += (
            f"{moved}. The paper's wand detector takes the nearest object in each depth frame for "
            "the wand, and here it found something else, an object that did not move with the "
            "wand; calibrate with --detector robust (a sphere of the wand's size) or --method full"
        )
    return text + "; nothing was written"


def format_calibrate(r: dict[str, Any]) -> str:
    lines = [
        f"calibration ({r['method']}, wand detector {r['detector']}): {r['world']}",
        f"grade: {r['grade']}",
    ]
    lines += [f"  {why}" for why in r["reasons"]]
    lines += [f"note: {n}" for n in r.get("notes", [])]
    if r["grade"] == "failed":
        lines.append(
            "  the calibration was accepted anyway (--accept)"
            if r["accepted"]
            else "  nothing was written; fix the setup, or pass --accept to use it all the same"
        )
    lines.append("")
    has_err = "mean_position_error_m" in r
    head = f"{'sensor':<8} {'sightings':>9} {'residual mm':>12}"
    if has_err:
        head += f" {'pos err mm':>11} {'rot err deg':>12}"
    lines.append(head)
    for s in r["sensors"]:
        row = f"{s['id']:<8} {s['sightings']:>9} {1e3 * s['residual_m']:12.2f}"
        if has_err:
            row += f" {1e3 * s['position_error_m']:11.2f} {s['rotation_error_deg']:12.3f}"
        lines.append(row)
    if has_err:
        lines.append(
            f"\nmean error vs truth ({r['alignment']}-aligned): "
            f"{1e3 * r['mean_position_error_m']:.2f} mm, {r['mean_rotation_error_deg']:.3f} deg"
            f" (unaligned: {1e3 * r['unaligned_mean_position_error_m']:.2f} mm)"
        )
    return "\n".join(lines)

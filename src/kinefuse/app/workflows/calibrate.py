"""``kinefuse calibrate``: find every sensor's pose from a session's wand phase, grade the
result from its own residuals, write the calibration file."""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

from kinefuse.errors import CalibrationError, CalibrationFailed, InputError
from kinefuse.formats.store.session_store import SessionStore


@dataclass(frozen=True)
class TruthErrors:
    """A calibration's error against the simulator's truth (sessions with truth only).

    Attributes
    ----------
    alignment : str
        How the calibration's world was aligned with the truth's before comparing.
    mean_position_error_m, mean_rotation_error_deg : float
        Mean pose error over the sensors after that alignment, metres and degrees.
    unaligned_mean_position_error_m, unaligned_mean_rotation_error_deg : float
        The same without the alignment.
    """

    alignment: str
    mean_position_error_m: float
    mean_rotation_error_deg: float
    unaligned_mean_position_error_m: float
    unaligned_mean_rotation_error_deg: float


@dataclass(frozen=True)
class SensorFit:
    """One sensor's part of a calibration.

    Attributes
    ----------
    id : str
        The sensor.
    residual_m : float
        RMS residual of its wand sightings after the registration, metres.
    sightings : int
        Wand sightings the registration used.
    detected : int
        Depth frames in which the wand was found.
    frames : int
        Depth frames of the wand phase.
    position_error_m, rotation_error_deg : float or None
        Its pose's error against the simulator's truth (None without truth).
    """

    id: str
    residual_m: float
    sightings: int
    detected: int
    frames: int
    position_error_m: float | None = None
    rotation_error_deg: float | None = None

    def as_dict(self) -> dict[str, Any]:
        """JSON-able; the truth's errors only when there are some."""
        d: dict[str, Any] = {
            "id": self.id,
            "residual_m": self.residual_m,
            "sightings": self.sightings,
            "detected": self.detected,
            "frames": self.frames,
        }
        if self.position_error_m is not None:
            d["position_error_m"] = self.position_error_m
            d["rotation_error_deg"] = self.rotation_error_deg
        return d


@dataclass(frozen=True)
class CalibrateResult:
    """What ``kinefuse calibrate`` did (``--json`` prints :meth:`as_dict`).

    Attributes
    ----------
    method, detector : str
        The registration method and the wand detector.
    world : str
        How the world frame was defined.
    rms_m : float
        RMS residual over all sensors, metres.
    grade : str
        ``good``, ``doubtful`` or ``failed`` (from the residuals alone).
    reasons : tuple of str
        Why the grade is worse than good.
    accepted : bool
        Whether the calibration was written (not failed, or ``--accept``).
    stored_in_session : bool
        Whether it was stored in the session.
    sensors : tuple of SensorFit
        Per sensor.
    out : str or None
        The calibration file written, if any.
    left_out : dict of str to str
        Sensors left out, by id, with the reason.
    notes : tuple of str
        What the user should know about the sensors screened.
    truth : TruthErrors or None
        The error against the simulator's truth (None: the session has none).
    written : tuple of str or None
        The error plots written (``report_dir`` with truth).
    report_note : str or None
        Why no report was written (``report_dir`` without truth).
    """

    method: str
    detector: str
    world: str
    rms_m: float
    grade: str
    reasons: tuple[str, ...]
    accepted: bool
    stored_in_session: bool
    sensors: tuple[SensorFit, ...]
    out: str | None
    left_out: dict[str, str]
    notes: tuple[str, ...]
    truth: TruthErrors | None = None
    written: tuple[str, ...] | None = None
    report_note: str | None = None

    def as_dict(self) -> dict[str, Any]:
        """JSON-able, as ``--json`` prints it: the truth's figures, the plots written and the
        report note only when there are some."""
        d: dict[str, Any] = {
            "method": self.method,
            "detector": self.detector,
            "world": self.world,
            "rms_m": self.rms_m,
            "grade": self.grade,
            "reasons": list(self.reasons),
            "accepted": self.accepted,
            "stored_in_session": self.stored_in_session,
            "sensors": [s.as_dict() for s in self.sensors],
            "out": self.out,
            "left_out": [{"id": k, "reason": v} for k, v in self.left_out.items()],
            "notes": list(self.notes),
        }
        if self.truth is not None:
            d.update(asdict(self.truth))
        if self.written is not None:
            d["written"] = list(self.written)
        if self.report_note is not None:
            d["report_note"] = self.report_note
        return d


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
) -> CalibrateResult:
    """Calibrate a session's sensors and grade the result from its own residuals.

    ``detector`` (``paper`` or ``robust``) finds the wand in the depth frames; by default each
    method uses its own: the paper's registration the paper's detector, ``full`` ours.

    The session is opened read-only unless ``store_result`` asks to store the calibration in it.
    A calibration graded ``failed`` is written nowhere unless ``accept``. The error figures
    (against the simulator's truth) are computed afterwards, by evaluation code, and only when
    the session has truth.
    """
    from kinefuse.capture.calibration.calib_file import (
        calibration_from_registration,
        dumps_calibration,
        write_calibration,
    )
    from kinefuse.capture.calibration.calibration_run import calibrate
    from kinefuse.capture.calibration.grade import grade_calibration
    from kinefuse.capture.calibration.methods import METHODS
    from kinefuse.core.outputs import atomic_dir, check_output_folder
    from kinefuse.pipeline.store_inputs import gather_usable_calibration

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
        result = CalibrateResult(
            method=method,
            detector=det,
            world=reg.world,
            rms_m=reg.rms_m,
            grade=grade.grade,
            reasons=grade.reasons,
            accepted=usable,
            stored_in_session=bool(usable and store_result),
            sensors=tuple(
                SensorFit(
                    id=sid,
                    residual_m=float(reg.residual_m[k]),
                    sightings=int(reg.n_sightings[k]),
                    detected=int(cal_in.tracks[sid].found.sum()),
                    frames=len(cal_in.tracks[sid].found),
                )
                for k, sid in enumerate(reg.sensor_ids)
            ),
            out=str(out) if out is not None and usable else None,
            left_out=dict(screen.left_out),
            notes=tuple(screen.notes()),
        )
        if store.has_truth():
            from kinefuse.lab.calibration_truth import calibration_errors, write_calibration_report

            errs = calibration_errors(store, reg)
            result = replace(
                result,
                sensors=tuple(replace(s, **errs["by_sensor"][s.id]) for s in result.sensors),
                truth=TruthErrors(**{f.name: errs[f.name] for f in fields(TruthErrors)}),
            )
            if report_dir is not None:
                with atomic_dir(report_dir, what="calibration report") as tmp:
                    written = write_calibration_report(tmp, store, cal_in, reg, method)
                result = replace(result, written=tuple(str(report_dir / p.name) for p in written))
        elif report_dir is not None:
            result = replace(
                result,
                report_note=(
                    "no report written: the error plots compare with the truth, and this session "
                    "has none (a live recording)"
                ),
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


def format_calibrate(r: CalibrateResult) -> str:
    """A calibration's result as text for the terminal."""
    lines = [
        f"calibration ({r.method}, wand detector {r.detector}): {r.world}",
        f"grade: {r.grade}",
    ]
    lines += [f"  {why}" for why in r.reasons]
    lines += [f"note: {n}" for n in r.notes]
    if r.grade == "failed":
        lines.append(
            "  the calibration was accepted anyway (--accept)"
            if r.accepted
            else "  nothing was written; fix the setup, or pass --accept to use it all the same"
        )
    lines.append("")
    has_err = r.truth is not None
    head = f"{'sensor':<8} {'sightings':>9} {'residual mm':>12}"
    if has_err:
        head += f" {'pos err mm':>11} {'rot err deg':>12}"
    lines.append(head)
    for s in r.sensors:
        row = f"{s.id:<8} {s.sightings:>9} {1e3 * s.residual_m:12.2f}"
        if s.position_error_m is not None and s.rotation_error_deg is not None:
            row += f" {1e3 * s.position_error_m:11.2f} {s.rotation_error_deg:12.3f}"
        lines.append(row)
    if r.truth is not None:
        e = r.truth
        lines.append(
            f"\nmean error vs truth ({e.alignment}-aligned): "
            f"{1e3 * e.mean_position_error_m:.2f} mm, {e.mean_rotation_error_deg:.3f} deg"
            f" (unaligned: {1e3 * e.unaligned_mean_position_error_m:.2f} mm)"
        )
    return "\n".join(lines)

"""``kinefuse fuse``: a session's joints fused into one skeleton, exported or stored."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.errors import InputError
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.lab.poses import resolve_poses

Array = NDArray[np.float64]

#: what ``--people`` takes: the subject only, or every person (one file each)
PEOPLE = ("subject", "all")


def person_path(path: Path, person_id: int) -> Path:
    """The export of one person: ``people.c3d`` -> ``people_p1.c3d``."""
    return path.with_name(f"{path.stem}_p{person_id}{path.suffix}")


@dataclass(frozen=True)
class FuseResult:
    """What ``kinefuse fuse`` did (``kinefuse fuse --json`` prints :meth:`as_dict`).

    Attributes
    ----------
    method : str
        The fusion method.
    calibration : str
        Where the sensors' poses came from (the session's, a file, the truth).
    frames : int
        Frames fused.
    seconds : float
        Wall time of the fusion, seconds.
    status : dict of str to int
        Joint-frames per fusion status.
    out : str or None
        The export, if one was asked for.
    also_out : tuple of str
        The further exports of the same result.
    stored_in_session : bool
        Whether the fused skeleton was stored in the session.
    warnings : tuple of str
        What the user should know (sensors screened out, export notes).
    sensors : tuple of str
        The sensors fused.
    left_out : dict of str to str
        The sensors left out, by id, with the reason.
    people : tuple of int
        The persons found (``(0,)`` for a one-person session).
    subject : int
        The person given by default.
    subject_rule : str
        How the subject was chosen (:data:`kinefuse.capture.fusion.people.SUBJECT_RULES`).
    written : tuple of str
        Every file written (one per person and export with ``people="all"``).
    """

    method: str
    calibration: str
    frames: int
    seconds: float
    status: dict[str, int]
    out: str | None
    also_out: tuple[str, ...]
    stored_in_session: bool
    warnings: tuple[str, ...]
    sensors: tuple[str, ...]
    left_out: dict[str, str]
    people: tuple[int, ...] = (0,)
    subject: int = 0
    subject_rule: str = "one person"
    written: tuple[str, ...] = ()

    def as_dict(self) -> dict[str, Any]:
        """The result as JSON-able data (what ``--json`` prints)."""
        return {
            "method": self.method,
            "calibration": self.calibration,
            "frames": self.frames,
            "seconds": self.seconds,
            "status": dict(self.status),
            "out": self.out,
            "also_out": list(self.also_out),
            "stored_in_session": self.stored_in_session,
            "warnings": list(self.warnings),
            "sensors": list(self.sensors),
            "left_out": [{"id": k, "reason": v} for k, v in self.left_out.items()],
            "people": list(self.people),
            "subject": self.subject,
            "subject_rule": self.subject_rule,
            "written": list(self.written),
        }


def run_fuse(
    *,
    session: Path,
    method: str,
    out: Path | None,
    calibration: Path | None,
    true_calibration: bool,
    store_result: bool = False,
    allow_incomplete: bool = False,
    trc_axes: str = "y-up",
    start_s: float | None = None,
    end_s: float | None = None,
    also_out: tuple[Path, ...] = (),
    progress: Callable[[str], None] | None = None,
    subject: int | None = None,
    people: str = "subject",
) -> FuseResult:
    """Fuse a session with one method and export the result.

    The session's bodies are matched to people
    (:func:`kinefuse.capture.fusion.fusion_run.people_of`) and each person fused from their own
    bodies. ``people="subject"`` (default) fuses and exports the subject (``subject``: the person id
    chosen by hand, else the documented rule); ``"all"`` every person, each export one file per
    person named by id (``out.c3d`` -> ``out_p0.c3d``, ``out_p1.c3d``...). A one-person session has
    one person, 0, and its files are named as given.

    The session is opened read-only; ``store_result`` stores the fused skeleton in it as well
    (the one case that writes to the session). The export's folder and kind are checked before
    the work starts, so a bad ``out`` fails fast. ``also_out``: more exports of the same
    result (the demo writes every format from one fusion). ``progress(message)`` hears of each
    step.
    """
    say = progress or (lambda _msg: None)
    from kinefuse.capture.fusion.status import status_counts
    from kinefuse.core.outputs import check_output_folder
    from kinefuse.formats.export import check_export_path, export_skeleton
    from kinefuse.pipeline.store_inputs import clip_grid, frame_grid, load_people, run_method

    if people not in PEOPLE:
        raise InputError(f"--people {people!r}: choose one of {', '.join(PEOPLE)}")
    outs = ([out] if out is not None else []) + list(also_out)
    for o in outs:
        check_export_path(o)
        check_output_folder(o, "export")
    with SessionStore.open(session, writable=store_result) as store:
        store.require_complete(allow_incomplete=allow_incomplete)
        poses, source = resolve_poses(store, calibration, true_calibration)
        say("reading the sensors' streams and clocks")
        found, per_person, screen = load_people(store, poses, subject=subject)
        everyone = [s for per in per_person.values() for s in per]
        warnings = screen.notes() + [
            f"sensor {sid} has no body frames: the fusion uses the other sensors only"
            for sid in dict.fromkeys(s.id for s in everyone)
            if not any(s.observations.has_body.any() for s in everyone if s.id == sid)
        ]
        grid = clip_grid(frame_grid(everyone), start_s, end_s)
        chosen = list(found.ids) if people == "all" else [found.subject]
        results = {}
        for pid in chosen:
            who = "" if len(found.ids) == 1 else f" (person {pid})"
            say(f"fusing {grid.size} frames with {method}{who}")
            results[pid] = run_method(per_person[pid], grid, method)
        res = results[found.subject] if found.subject in results else results[chosen[0]]
        if store_result:
            store.write_fused(method, res.t_server_s, res.positions, res.status)
            store.set_meta("subject", {"person": found.subject, "rule": found.rule})
    written: list[str] = []
    for o in outs:
        for pid, r in results.items():
            path = o if len(found.ids) == 1 or people == "subject" else person_path(o, pid)
            say(f"writing {path}")
            notes: list[str] = []
            export_skeleton(
                path,
                r.t_server_s,
                r.positions,
                residual_m=r.residual_m,
                trc_axes=trc_axes,
                notes=notes,
            )
            warnings += [f"{path.name}: {n}" for n in notes]
            written.append(str(path))
    return FuseResult(
        method=method,
        calibration=source,
        frames=int(res.t_server_s.size),
        seconds=res.seconds,
        status=status_counts(res.status),
        out=str(out) if out is not None else None,
        also_out=tuple(str(o) for o in also_out),
        stored_in_session=store_result,
        warnings=tuple(warnings),
        sensors=tuple(s.id for s in per_person[found.subject]),
        left_out=dict(screen.left_out),
        people=found.ids,
        subject=found.subject,
        subject_rule=found.rule,
        written=tuple(written),
    )

"""The workflow of ``kinefuse analyze``: inputs -> skeleton sequences -> paper B -> files.

Inputs (the extension decides): a session store (``.sqlite``: fused here with ``--method``,
read-only, nothing is written into it), a BVH or ASF/AMC clip (``.bvh``, ``.amc``, with their
source rotations), a marker file (``.trc``, ``.c3d``, through a marker map).

The calibration phase (the frames the movement axes are learned from) is, in this order:
``--calibration-phase START:END`` (seconds on the input's time base: the server clock of a
session, the clip's time from 0), the range-of-motion phase a session stored in its metadata
(``rom_phase_server_s``, written by ``kinefuse simulate --rom``), or, when there is none, the
whole input; the report's ``calibration_phase.source`` and ``statement`` say which, and what
that means for the figures.

Output folder (fresh: created, or an existing empty folder; never a folder with files in it;
written as a hidden staging folder beside it and renamed into place when everything is done):
one input writes its files straight into it; several inputs write one subfolder each
(``01_<stem>``, ``02_<stem>``, ...) plus the consistency figures in ``analysis.json``. Every
file goes through a temporary file and an atomic rename. Formats in ``docs/analysis.md``.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.biomech.rom import RomPhase
from kinefuse.biomech.sequence import SkeletonSequence
from kinefuse.core.outputs import (
    atomic_dir,
    atomic_write_lines,
    atomic_write_text,
    check_output_folder,
    never_replace,
)
from kinefuse.errors import InputError, OutputError
from kinefuse.pipeline.analysis_chain import AnalysisInput

Array = NDArray[np.float64]

SESSION_EXT = (".sqlite", ".db")
MOTION_EXT = (".bvh", ".amc")
MARKER_EXT = (".trc", ".c3d")


def _kind(path: Path) -> str:
    from kinefuse.core.frames.source_motion import motion_suffix

    ext = motion_suffix(path)
    if ext in SESSION_EXT:
        return "session"
    if ext in MOTION_EXT:
        return "motion"
    if ext in MARKER_EXT:
        return "markers"
    raise InputError(
        f"{path}: cannot analyse {ext or 'a file without extension'!r}; kinefuse analyze reads a "
        "session (.sqlite), a clip (.bvh, .amc) or a marker file (.trc, .c3d)"
    )


def sequence_from_session(
    path: Path,
    *,
    method: str = "best",
    calibration: Path | None = None,
    true_calibration: bool = False,
    subject: int | None = None,
) -> AnalysisInput:
    """Fuse a session (read-only) with one method and return it as a skeleton sequence.

    The fusion is that of ``kinefuse fuse`` (clocks, occlusion test, ``method``, the subject:
    ``subject`` or the documented rule) with the session's stored calibration, a calibration
    file or the true poses; the result is not stored. The session's range-of-motion phase, if it
    has one, comes along as protocol metadata.
    """
    from kinefuse.capture.fusion.methods import METHODS
    from kinefuse.formats.store.session_store import SessionStore
    from kinefuse.lab.poses import resolve_poses
    from kinefuse.pipeline.analysis_chain import fused_limb_counts
    from kinefuse.pipeline.store_inputs import frame_grid, load_people, run_method

    if method not in METHODS:
        raise InputError(f"unknown fusion method {method!r}; choose from {', '.join(METHODS)}")
    with SessionStore.open(path) as store:
        poses, source = resolve_poses(store, calibration, true_calibration)
        people, per_person, screen = load_people(store, poses, subject=subject)
        grid = frame_grid([s for per in per_person.values() for s in per])
        sensors = per_person[people.subject]
        res = run_method(sensors, grid, method)
        meta = store.meta()
    phase = meta.get("rom_phase_server_s")
    stored = None
    if isinstance(phase, list) and len(phase) == 2:
        stored = (float(phase[0]), float(phase[1]))
    st = meta.get("static_phase_server_s")
    stored_static = None
    if isinstance(st, list) and len(st) == 2:
        stored_static = (float(st[0]), float(st[1]))
    t = res.t_server_s
    rate = float(1.0 / np.median(np.diff(t))) if t.size > 1 else 30.0
    counts = fused_limb_counts(sensors, res)
    seq = SkeletonSequence.from_kinect(
        res.positions,
        t_s=t,
        rate_hz=rate,
        source=f"{path} fused with {method} ({source})",
    )
    return AnalysisInput(
        path=path,
        kind="session",
        seq=seq,
        stored_phase_s=stored,
        fusion={
            "method": method,
            "calibration": source,
            "frames": int(grid.size),
            "left_out": dict(screen.left_out),
            "people": list(people.ids),
            "subject": people.subject,
            "subject_rule": people.rule,
        },
        sensor_poses={k: np.asarray(v, dtype=np.float64) for k, v in poses.items()},
        limb_sensors=counts,
        stored_static_s=stored_static,
    )


def load_input(
    path: Path,
    *,
    marker_map: Path | str | None = None,
    method: str = "best",
    calibration: Path | None = None,
    true_calibration: bool = False,
    static: Path | None = None,
    static_window: tuple[float, float] | str | None = None,
    subject: int | None = None,
) -> AnalysisInput:
    """Any input of ``kinefuse analyze`` as an :class:`AnalysisInput` (see the module doc).

    ``static_window``: seconds, or ``"auto"`` for the standing phase a session stored
    (``static_phase_server_s``, written by ``kinefuse simulate --static``)."""
    from kinefuse.formats.sequences import sequence_from_motion_file

    if not path.exists():
        raise InputError(f"{path}: no such file")
    kind = _kind(path)
    if kind != "markers" and marker_map is not None:
        raise InputError(f"{path}: --map is for marker files (.trc, .c3d), not a {kind}")
    if kind != "session" and (calibration is not None or true_calibration):
        raise InputError(f"{path}: --calibration/--true-calibration are for sessions (.sqlite)")
    if kind != "session" and subject is not None:
        raise InputError(f"{path}: --subject picks a person of a session (.sqlite)")
    if kind == "session":
        if static is not None:
            raise InputError(
                f"{path}: a session's static trial is its own standing phase: give "
                "--static-window START:END (seconds on the session's server clock), or "
                "--static-window auto for a session made with kinefuse simulate --static; "
                "--static takes a marker file's static trial"
            )
        inp = sequence_from_session(
            path,
            method=method,
            calibration=calibration,
            true_calibration=true_calibration,
            subject=subject,
        )
        if static_window == "auto":
            if inp.stored_static_s is None:
                raise InputError(
                    f"{path}: --static-window auto needs the standing phase a session made with "
                    "kinefuse simulate --static stores (static_phase_server_s); this session has "
                    "none. Give --static-window START:END of a part where the subject stands "
                    "still (seconds on the session's server clock)"
                )
            return replace(inp, static_window_s=inp.stored_static_s, static_source=(
                f"{path} standing phase {inp.stored_static_s[0]:g}-{inp.stored_static_s[1]:g} s "
                "(static_phase_server_s)"))  # fmt: skip
        if isinstance(static_window, tuple):
            where = f"{path} {static_window[0]:g}-{static_window[1]:g} s (--static-window)"
            return replace(inp, static_window_s=static_window, static_source=where)
        return inp
    if static_window == "auto":
        raise InputError(
            f"{path}: --static-window auto is for sessions made with kinefuse simulate --static; "
            "give START:END (seconds) of the still part"
        )
    if (static is not None or static_window is not None) and kind != "markers":
        raise InputError(
            f"{path}: --static/--static-window are for marker files (.trc, .c3d) so far; a "
            f"{kind} is analysed with paper B's functional axes only"
        )
    if kind == "motion":
        return AnalysisInput(path=path, kind=kind, seq=sequence_from_motion_file(path))
    if static is None and static_window is None:
        from kinefuse.biomech.marker_maps import unbuilt_joints
        from kinefuse.formats.sequences import resolve_marker_input, sequence_from_marker_data

        markers, mmap, notes, _ = resolve_marker_input(path, marker_map=marker_map)
        seq = sequence_from_marker_data(markers, mmap, notes)
        return AnalysisInput(
            path=path, kind=kind, seq=seq, unbuilt_joints=unbuilt_joints(markers, mmap) or None
        )
    assert not isinstance(static_window, str)
    return _markers_with_static(path, marker_map, static or path, static_window)


def _markers_with_static(
    path: Path, marker_map: Path | str | None, static: Path, window: tuple[float, float] | None
) -> AnalysisInput:
    """A marker file with its static trial: the functional sequence and the anatomical angles."""
    from kinefuse.biomech.anatomical import anatomical_angles
    from kinefuse.biomech.marker_maps import unbuilt_joints
    from kinefuse.biomech.static_trial import anatomical_frames, check_static
    from kinefuse.formats.sequences import resolve_marker_input, sequence_from_marker_data

    if not Path(static).exists():
        raise InputError(f"{static}: no such static trial")
    if _kind(Path(static)) != "markers":
        raise InputError(
            f"{static}: a static trial is a marker file (.trc, .c3d) here; sessions as static "
            "trials are not supported yet"
        )
    markers, mmap, notes, st = resolve_marker_input(
        path, marker_map=marker_map, static=static, static_window=window
    )
    assert st is not None  # a static path was given
    check_static(st, markers, mmap)
    seq = sequence_from_marker_data(markers, mmap, notes)
    af = anatomical_frames(markers, st, mmap)
    where = f"{static}" + (f" {window[0]:g}-{window[1]:g} s" if window else "")
    body_angles = {}
    for model, offsets in af.model_offsets.items():
        frames = {**af.frames, **{k: af.frames[k] @ v for k, v in offsets.items()}}
        body_angles[model] = {
            k: v
            for k, v in anatomical_angles(frames, af.lab, af.undefined).items()
            if k.startswith(("pelvis_", "trunk_"))
        }
    return AnalysisInput(
        path=path,
        kind="markers",
        seq=seq,
        anatomical=anatomical_angles(af.frames, af.lab, af.undefined),
        anatomical_status=af.status,
        opensim_body_angles=body_angles or None,
        static_source=where,
        unbuilt_joints=unbuilt_joints(markers, mmap) or None,
    )


def prepare_out(out: Path) -> Path:
    """Create the output folder, or accept an existing empty one; refuse anything else."""
    if out.exists():
        if not out.is_dir():
            raise OutputError(f"{out} exists and is not a folder; choose a fresh output folder")
        if any(out.iterdir()):
            raise OutputError(
                f"{out} already holds files; kinefuse analyze writes into a fresh folder only "
                "(it never overwrites files it did not make): choose a new --out"
            )
        return out
    try:
        out.mkdir(parents=True)
    except OSError as e:
        raise OutputError(
            f"{out}: cannot create the output folder: {e.strerror or e}; choose another --out"
        ) from None
    return out


def write_limb_frames(path: Path, t_s: Array, limbs: Sequence[str], transforms: Array) -> Path:
    """``limb_frames.csv``: per frame and limb, the normalized frame's origin and axes (world).

    Columns ``time_s, limb, origin_x_m, origin_y_m, origin_z_m, x_x, x_y, x_z, y_x, y_y, y_z,
    z_x, z_y, z_z``: the origin (limb midpoint, metres) and the unit axes x (forward), y (left),
    z (up in the default pose) of the limb's normalized frame in world coordinates; empty cells
    where the limb is missing.
    """
    origin = transforms[..., :3, 3]
    axes = np.swapaxes(transforms[..., :3, :3], -1, -2).reshape(*transforms.shape[:2], 9)
    vals = np.concatenate([origin, axes], axis=-1)  # (T, L, 12)

    def lines() -> Iterator[str]:
        yield "time_s,limb,origin_x_m,origin_y_m,origin_z_m,x_x,x_y,x_z,y_x,y_y,y_z,z_x,z_y,z_z\n"
        for k in range(vals.shape[0]):
            tk = f"{t_s[k]:.6f}"
            for i, name in enumerate(limbs):
                row = vals[k, i]
                cells = ",".join("" if not np.isfinite(v) else f"{v:.6f}" for v in row)
                yield f"{tk},{name},{cells}\n"

    return atomic_write_lines(path, lines(), what="limb frames file", recognizer=never_replace)


def _choose_phase(
    given: tuple[float, float] | None, inp: AnalysisInput
) -> tuple[tuple[float, float], str, str]:
    """(phase, source, statement) for an input."""
    seq = inp.seq
    t0, t1 = float(seq.t_s[0]), float(seq.t_s[-1])
    if given is not None:
        lo, hi = given
        if hi <= lo:
            raise InputError(f"--calibration-phase {lo:g}:{hi:g}: the end must be after the start")
        if hi < t0 or lo > t1:
            raise InputError(
                f"--calibration-phase {lo:g}:{hi:g} s lies outside {inp.path} "
                f"({t0:.2f} to {t1:.2f} s on its time base)"
            )
        return (
            (lo, hi),
            "given (--calibration-phase)",
            ("movement axes learned from the given calibration phase; angles over the whole input"),
        )
    if inp.stored_phase_s is not None:
        return (
            inp.stored_phase_s,
            "the session's range-of-motion phase (rom_phase_server_s)",
            (
                "movement axes learned from the session's range-of-motion phase; angles over the "
                "whole input"
            ),
        )
    return (
        (t0, t1),
        "none: the whole input",
        (
            "no calibration phase: normalization, default pose and limb frames are computed as "
            "usual; the movement axes are learned from the input's own motion, so a limb that does "
            "not move along a direction during the take gets fewer axes (its status says so) and "
            "its angles read about the directions it did move in. No axis or twist error against "
            "a truth is computed (there are no true axes without a range-of-motion phase)."
        ),
    )


def json_default(o: object) -> object:
    """JSON encoder fallback: numpy scalars and arrays, NaN -> None."""
    if isinstance(o, np.ndarray):
        return [json_default(v) for v in o.tolist()] if o.ndim else json_default(o.item())
    if isinstance(o, np.generic):
        return json_default(o.item())
    if isinstance(o, float):
        return o if np.isfinite(o) else None
    if isinstance(o, tuple):
        return list(o)
    raise TypeError(f"cannot write {type(o).__name__} to JSON")


def clean_json(value: object) -> object:
    """Replace NaN/inf floats (also nested, also numpy) by None so the JSON is strict."""
    if isinstance(value, dict):
        return {str(k): clean_json(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [clean_json(v) for v in value]
    if isinstance(value, np.ndarray | np.generic):
        return clean_json(value.tolist())
    if isinstance(value, float):
        return value if np.isfinite(value) else None
    return value


def json_text(report: dict[str, Any]) -> str:
    """The report as strict JSON (NaN written as null)."""
    return json.dumps(clean_json(report), indent=2)


@dataclass(frozen=True)
class AnalyzeResult:
    """What ``kinefuse analyze`` made (``--json`` prints the ``analysis.json`` it wrote).

    Attributes
    ----------
    out : Path
        The analysis folder.
    inputs : tuple of dict
        Each input's report, in the order given (one input: the report itself): ``input``,
        ``frames``, ``angle_names``, ``limb_status``, ``warnings``, ... (the per-input part of
        ``analysis.json``, docs/analysis.md).
    report : dict
        The whole report, as ``analysis.json`` holds it (several inputs: ``inputs`` and the
        consistency across them).
    """

    out: Path
    inputs: tuple[dict[str, Any], ...]
    report: dict[str, Any]

    @classmethod
    def of(cls, out: Path, report: dict[str, Any]) -> AnalyzeResult:
        """The result of a report read back from ``analysis.json``."""
        return cls(out=out, inputs=tuple(report.get("inputs", [report])), report=report)

    @property
    def warnings(self) -> tuple[tuple[str, str], ...]:
        """``(input, warning)`` for every input's warnings, in order."""
        return tuple((str(r["input"]), str(w)) for r in self.inputs for w in r.get("warnings", []))

    def as_dict(self) -> dict[str, Any]:
        """JSON-able: the report, as ``analysis.json`` holds it."""
        return self.report

    def to_json(self) -> str:
        """The report as strict JSON text, as ``analysis.json`` holds it (without its final
        newline)."""
        return json_text(self.report)


def run_analyze(
    inputs: Sequence[Path],
    *,
    out: Path,
    calibration_phase: tuple[float, float] | None = None,
    marker_map: Path | str | None = None,
    method: str = "best",
    calibration: Path | None = None,
    true_calibration: bool = False,
    plots: bool = True,
    plot_dpi: int | None = None,
    progress: Callable[[str], None] | None = None,
    static: Path | None = None,
    static_window: tuple[float, float] | str | None = None,
    names: str = "kinefuse",
    subject: int | None = None,
) -> AnalyzeResult:
    """Analyse one or several inputs into a fresh folder ``out``; returns what it made.

    Everything is written into a hidden staging folder beside ``out`` and renamed onto ``out``
    at the end, so a failed run leaves nothing behind (and never touches other files).
    """
    from kinefuse.biomech.anatomical import opensim_model

    say = progress or (lambda _m: None)
    if not inputs:
        raise InputError("give at least one input file")
    opensim_model(names)  # refuse an unknown --names before any work
    kinds = [_kind(Path(p)) for p in inputs]
    if marker_map is not None and "markers" not in kinds:
        raise InputError("--map is for marker files (.trc, .c3d); none of the inputs is one")
    if (calibration is not None or true_calibration) and "session" not in kinds:
        raise InputError("--calibration/--true-calibration are for sessions (.sqlite)")
    if subject is not None and "session" not in kinds:
        raise InputError(
            "--subject picks a person of a session (.sqlite); none of the inputs is one"
        )
    loaded = []
    for p, kind in zip(inputs, kinds, strict=True):
        say(f"loading {p}")
        loaded.append(
            load_input(
                Path(p),
                marker_map=marker_map if kind == "markers" else None,
                method=method,
                calibration=calibration if kind == "session" else None,
                true_calibration=true_calibration and kind == "session",
                static=static,
                static_window=static_window,
                subject=subject if kind == "session" else None,
            )
        )
    check_output_folder(out, "analysis folder")  # fail early, before any work
    # built in a fresh folder beside --out and swapped in when complete: a failed run leaves
    # nothing, and only an empty folder or an earlier kinefuse output is ever replaced
    with atomic_dir(out, what="analysis folder") as stage:
        report = _analyse_all(
            loaded, stage, calibration_phase, plots, true_calibration, say, plot_dpi, names
        )
        report["out"] = str(out)
        text = json_text(report).replace(str(stage), str(out))
        atomic_write_text(stage / "analysis.json", text + "\n", what="analysis report",
                          recognizer=lambda _p: False)  # fmt: skip
    return AnalyzeResult.of(out, dict(json.loads(text)))


def _analyse_all(
    loaded: list[AnalysisInput],
    out: Path,
    calibration_phase: tuple[float, float] | None,
    plots: bool,
    true_calibration: bool,
    say: Callable[[str], None],
    plot_dpi: int | None = None,
    names: str = "kinefuse",
) -> dict[str, Any]:
    from kinefuse.app.workflows.analyze_one import analyse_one, consistency_report

    reports = []
    results = []
    for k, inp in enumerate(loaded):
        folder = out if len(loaded) == 1 else out / f"{k + 1:02d}_{inp.path.stem}"
        if folder != out:
            prepare_out(folder)
        phase, source, statement = _choose_phase(calibration_phase, inp)
        say(f"analysing {inp.path} (calibration phase: {source})")
        t0 = time.perf_counter()
        rep, res = analyse_one(
            inp,
            folder,
            phase=phase,
            phase_source=source,
            statement=statement,
            plots=plots,
            true_calibration=true_calibration,
            plot_dpi=plot_dpi,
            names=names,
        )
        rep["wall_time_s"] = time.perf_counter() - t0
        reports.append(rep)
        results.append(res)
    report: dict[str, Any]
    if len(reports) == 1:
        return reports[0]
    report = {"inputs": reports}
    report.update(consistency_report(results))
    return report


def format_analyze(report: dict[str, Any]) -> str:
    """A short text summary of an analysis report."""
    from kinefuse.app.workflows.analyze_one import format_report

    return format_report(report)


# ------------------------------------------------------------------ simulate --rom


def record_rom_phase(session: Path, phase: RomPhase, start_s: float) -> None:
    """Store a simulated session's standing and ROM phases: their intervals as ordinary protocol
    metadata (``static_phase_server_s``, ``rom_phase_server_s``: what a real lab's protocol
    also knows), the ROM's truth in the truth info (``rom_truth``, read only by ``lab/report/``)."""
    from kinefuse.formats.store.session_store import SessionStore

    with SessionStore.open(session, writable=True) as store:
        if phase.static_s > 0:
            store.set_meta("static_phase_server_s", [start_s, start_s + phase.static_s])
        if phase.rom_s > 0:
            rom_start = start_s + phase.rom_start_s
            store.set_meta("rom_phase_server_s", [rom_start, rom_start + phase.rom_s])
            store.set_meta("rom_blend_s", phase.blend_s)
            truth = dict(phase.truth)
            truth["start_server_s"] = rom_start
            store.write_truth_info("rom_truth", truth)

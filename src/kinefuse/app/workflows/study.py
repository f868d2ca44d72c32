"""``kinefuse analyze STUDY_DIR/ --out RESULTS/``: every trial of a study, one summary.

A *study* is a folder. Its trials are found by a documented naming rule, or listed in a
``study.toml`` at its top (``docs/tutorials/study.md``):

- every ``.trc``, ``.c3d``, ``.bvh``, ``.amc`` and ``.sqlite`` below the folder is a trial
  (hidden folders, and the results folder when it is inside the study, are skipped);
- a file whose name contains ``static`` (any case) is a static trial, not a trial: a trial takes
  the static trial of its own folder (of the nearest folder above that has one); where a folder
  holds several, the one whose name shares the longest beginning with the trial's name, and none
  when that is not one file.

Each trial is analysed as ``kinefuse analyze TRIAL [--static STATIC] --out
RESULTS/trials/ID/`` would (``ID``: its path in the study, separators as ``__``), on the local
cores (one process each) or on an existing Dask cluster (``--scheduler``). A trial whose folder
is complete (it holds ``analysis.json``) is skipped unless ``--force``: an interrupted study
resumes where it stopped. Then ``RESULTS/summary.csv`` (per trial, angle and method: frames,
minimum, maximum, range, mean, peak), ``RESULTS/cycles.csv`` (the mean gait-cycle-normalised
curve of every angle where foot strikes were found) and ``RESULTS/summary.html`` are written
from every trial folder there is.
"""

from __future__ import annotations

import csv
import json
import os
import tomllib
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from kinefuse.core.outputs import atomic_write_lines, atomic_write_text, check_output_folder
from kinefuse.errors import InputError, KinefuseError

__all__ = ["StudyResult", "Trial", "find_trials", "run_study"]

TRIAL_EXT = (".trc", ".c3d", ".bvh", ".amc", ".sqlite")
STATIC_WORD = "static"
STUDY_FILE = "study.toml"
#: the mark of the files this command wrote (gait.json; the page carries it too)
MARK = "kinefuse analyze (study)"


@dataclass(frozen=True)
class Trial:
    """One trial of a study: the file, its static trial, its options."""

    id: str
    path: Path
    static: Path | None = None
    calibration_phase: tuple[float, float] | None = None


@dataclass
class TrialOutcome:
    """What became of one trial (picklable: it comes back from a worker process)."""

    id: str
    status: str  # "done", "skipped" (done before) or "failed"
    message: str = ""
    wall_time_s: float = 0.0


@dataclass
class StudyResult:
    """The result of ``kinefuse analyze STUDY_DIR``."""

    study: str
    out: str
    trials: list[TrialOutcome] = field(default_factory=list)
    summary_csv: str = ""
    cycles_csv: str = ""
    html: str = ""

    @property
    def analysed(self) -> list[TrialOutcome]:
        return [t for t in self.trials if t.status in ("done", "skipped")]

    @property
    def failed(self) -> list[TrialOutcome]:
        return [t for t in self.trials if t.status == "failed"]

    def exit_code(self) -> int:
        """0 every trial analysed, 1 some failed, 3 none analysed."""
        if not self.analysed:
            return 3
        return 1 if self.failed else 0

    def to_json(self) -> dict[str, Any]:
        return {**asdict(self), "exit_code": self.exit_code()}


# ------------------------------------------------------------------------------------------
# finding the trials


def _is_static(path: Path) -> bool:
    return STATIC_WORD in path.stem.lower()


def _common_start(a: str, b: str) -> int:
    n = 0
    for x, y in zip(a.lower(), b.lower(), strict=False):
        if x != y:
            break
        n += 1
    return n


def _static_for(trial: Path, statics: dict[Path, list[Path]], root: Path) -> Path | None:
    folder = trial.parent
    while True:
        here = statics.get(folder, [])
        if len(here) == 1:
            return here[0]
        if len(here) > 1:
            scores = [_common_start(trial.stem, s.stem) for s in here]
            best = max(scores)
            winners = [s for s, k in zip(here, scores, strict=True) if k == best]
            return winners[0] if best > 0 and len(winners) == 1 else None
        if folder == root or root not in folder.parents:
            return None
        folder = folder.parent


def _trial_id(path: Path, root: Path) -> str:
    rel = path.relative_to(root).with_suffix("")
    return "__".join(rel.parts)


def find_trials(study: Path, *, skip: Path | None = None) -> list[Trial]:
    """The trials of ``study`` (module notes), in path order; ``skip``: a folder to leave out."""
    study = study.resolve()
    if not study.is_dir():
        raise InputError(f"{study}: not a folder; give a study folder or trial files")
    spec = study / STUDY_FILE
    if spec.is_file():
        return _trials_from_toml(spec, study)
    files: list[Path] = []
    for dirpath, dirnames, filenames in os.walk(study):
        here = Path(dirpath)
        dirnames[:] = sorted(
            d
            for d in dirnames
            if not d.startswith(".") and (skip is None or (here / d).resolve() != skip.resolve())
        )
        files += [here / f for f in sorted(filenames) if Path(f).suffix.lower() in TRIAL_EXT]
    statics: dict[Path, list[Path]] = {}
    for f in files:
        if _is_static(f):
            statics.setdefault(f.parent, []).append(f)
    trials = [
        Trial(_trial_id(f, study), f, _static_for(f, statics, study))
        for f in files
        if not _is_static(f)
    ]
    if not trials:
        found = f" (only static trials: {', '.join(p.name for p in files)})" if files else ""
        raise InputError(
            f"{study}: no trial found{found}; a study folder holds .trc, .c3d, .bvh, .amc or "
            f".sqlite files, or a {STUDY_FILE} listing them (docs/tutorials/study.md)"
        )
    return trials


def _phase(value: object, where: str) -> tuple[float, float] | None:
    if value is None:
        return None
    if (
        isinstance(value, list)
        and len(value) == 2
        and all(isinstance(v, int | float) for v in value)
        and value[0] < value[1]
    ):
        return float(value[0]), float(value[1])
    raise InputError(f"{where}: calibration_phase must be [START_S, END_S], got {value!r}")


def _trials_from_toml(spec: Path, study: Path) -> list[Trial]:
    try:
        doc = tomllib.loads(spec.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
        raise InputError(f"{spec}: not a readable study file: {e}") from None
    entries = doc.get("trial")
    if not isinstance(entries, list) or not entries:
        raise InputError(f'{spec}: list the trials as [[trial]] tables with file = "PATH"')
    trials: list[Trial] = []
    for k, entry in enumerate(entries, 1):
        where = f"{spec}: trial {k}"
        if not isinstance(entry, dict) or not isinstance(entry.get("file"), str):
            raise InputError(f'{where}: needs file = "PATH" (relative to the study folder)')
        unknown = set(entry) - {"file", "static", "calibration_phase", "id"}
        if unknown:
            raise InputError(f"{where}: unknown keys {sorted(unknown)} (file, static, "
                             "calibration_phase, id)")  # fmt: skip
        path = study / entry["file"]
        if not path.is_file():
            raise InputError(f"{where}: no such file {path}")
        static = entry.get("static")
        if static is not None and not (study / str(static)).is_file():
            raise InputError(f"{where}: no such static trial {study / str(static)}")
        trials.append(
            Trial(
                str(entry.get("id") or _trial_id(path, study)),
                path,
                None if static is None else study / str(static),
                _phase(entry.get("calibration_phase"), where),
            )
        )
    ids = [t.id for t in trials]
    if len(set(ids)) != len(ids):
        raise InputError(f'{spec}: two trials share an id; give each an id = "..."')
    return trials


# ------------------------------------------------------------------------------------------
# one trial (runs in a worker process, or on a Dask worker)


def analyse_trial(trial: Trial, folder: Path, options: dict[str, Any]) -> TrialOutcome:
    """Analyse one trial into ``folder`` (a fresh or kinefuse-made folder); never raises for a
    bad trial: the outcome says what went wrong."""
    import time

    t0 = time.perf_counter()
    try:
        import matplotlib

        matplotlib.use("Agg")
        from kinefuse.app.workflows.analyze import load_input, run_analyze
        from kinefuse.biomech.gait import foot_strikes

        run_analyze(
            [trial.path],
            out=folder,
            calibration_phase=trial.calibration_phase,
            marker_map=options.get("marker_map"),
            method=options.get("method", "best"),
            plots=options.get("plots", True),
            static=trial.static,
            names=options.get("names", "kinefuse"),
        )
        loaded = load_input(
            trial.path,
            marker_map=options.get("marker_map") if trial.path.suffix.lower() in (".trc", ".c3d")
            else None,
            method=options.get("method", "best"),
            static=trial.static,
        )  # fmt: skip
        events = foot_strikes(loaded.seq)
        atomic_write_text(
            folder / "gait.json",
            json.dumps({"written_by": MARK, **events.to_json()}, indent=2) + "\n",
            what="gait events",
            recognizer=lambda _p: True,  # inside the trial folder this command just wrote
        )
    except KinefuseError as e:
        return TrialOutcome(trial.id, "failed", str(e).splitlines()[0][:500],
                            time.perf_counter() - t0)  # fmt: skip
    except Exception as e:  # a defect of ours: the study goes on, the trial says what it was
        return TrialOutcome(trial.id, "failed", f"internal error, please report: "
                            f"{type(e).__name__}: {e}"[:500], time.perf_counter() - t0)  # fmt: skip
    return TrialOutcome(trial.id, "done", "", time.perf_counter() - t0)


def _complete(folder: Path) -> bool:
    return (folder / "analysis.json").is_file() and (folder / "gait.json").is_file()


# ------------------------------------------------------------------------------------------
# the study


def run_study(
    study: Path,
    *,
    out: Path,
    jobs: int | None = None,
    scheduler: str | None = None,
    force: bool = False,
    marker_map: Path | None = None,
    method: str = "best",
    names: str = "kinefuse",
    plots: bool = True,
    progress: Callable[[str], None] | None = None,
) -> StudyResult:
    """Analyse every trial of ``study`` into ``out`` and write the summary (module notes)."""
    say = progress or (lambda _m: None)
    out = out.resolve()
    trials = find_trials(study, skip=out)
    check_output_folder(out, "study results folder")
    if out.exists() and any(out.iterdir()) and not (out / "trials").is_dir():
        raise InputError(
            f"{out} holds files that are not a study's results; give a new or empty folder"
        )
    (out / "trials").mkdir(parents=True, exist_ok=True)
    result = StudyResult(str(study), str(out))
    todo = []
    for trial in trials:
        if not force and _complete(out / "trials" / trial.id):
            result.trials.append(TrialOutcome(trial.id, "skipped", "done in an earlier run"))
        else:
            todo.append(trial)
    options = {
        "marker_map": marker_map,
        "method": method,
        "names": names,
        "plots": plots,
    }
    total = len(trials)
    done = len(result.trials)
    say(f"{done} of {total} trials done before; analysing {len(todo)}")
    for outcome in _run_all(todo, out, options, jobs, scheduler):
        done += 1
        result.trials.append(outcome)
        state = "failed: " + outcome.message if outcome.status == "failed" else "done"
        say(f"[{done}/{total}] {outcome.id}: {state}")
    result.trials.sort(key=lambda t: t.id)
    ids = [t.id for t in result.analysed]
    rows = list(_summary_rows(out, ids))
    cycles = list(_cycle_rows(out, ids))
    summary = _write_csv(out / "summary.csv", SUMMARY_COLUMNS, rows, "study summary")
    result.summary_csv = str(summary)
    result.cycles_csv = str(_write_csv(out / "cycles.csv", CYCLE_COLUMNS, cycles, "cycle curves"))
    from kinefuse.lab.report.study_html import render_study

    html = render_study(result.to_json(), rows, cycles)
    result.html = str(
        atomic_write_text(out / "summary.html", html, what="study page", recognizer=_ours_html)
    )
    return result


def _ours_html(path: Path) -> bool:
    try:
        with path.open(encoding="utf-8") as f:
            return MARK in f.read(4096)
    except (OSError, UnicodeDecodeError):
        return False


def _run_all(
    todo: Sequence[Trial],
    out: Path,
    options: dict[str, Any],
    jobs: int | None,
    scheduler: str | None,
) -> Iterable[TrialOutcome]:
    if not todo:
        return
    folders = [out / "trials" / t.id for t in todo]
    if scheduler is not None:
        yield from _run_dask(todo, folders, options, scheduler)
        return
    workers = max(1, min(jobs or os.cpu_count() or 1, len(todo)))
    if workers == 1:
        for trial, folder in zip(todo, folders, strict=True):
            yield analyse_trial(trial, folder, options)
        return
    import multiprocessing

    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures: dict[Future[TrialOutcome], Trial] = {
            pool.submit(analyse_trial, trial, folder, options): trial
            for trial, folder in zip(todo, folders, strict=True)
        }
        for f in as_completed(futures):
            yield f.result()


def _run_dask(
    todo: Sequence[Trial], folders: Sequence[Path], options: dict[str, Any], scheduler: str
) -> Iterable[TrialOutcome]:
    try:
        from dask.distributed import Client
        from dask.distributed import as_completed as dask_completed
    except ImportError:
        raise InputError(
            "--scheduler needs Dask: pip install 'kinefuse[dask]' (and kinefuse on every worker)"
        ) from None
    try:
        client = Client(scheduler, timeout=10)
    except (OSError, TimeoutError) as e:
        raise InputError(f"cannot reach the Dask scheduler at {scheduler}: {e}") from None
    with client:
        futures = [
            client.submit(analyse_trial, trial, folder, options, pure=False)
            for trial, folder in zip(todo, folders, strict=True)
        ]
        for f in dask_completed(futures):
            yield f.result()


# ------------------------------------------------------------------------------------------
# the summary

SUMMARY_COLUMNS = ("trial", "angle", "joint", "method", "frames", "min_deg", "max_deg",
                   "range_deg", "mean_deg", "peak_deg", "cycles")  # fmt: skip
CYCLE_COLUMNS = ("trial", "angle", "method", "side", "cycles", *(f"p{k}" for k in range(101)))


def _read_angles(path: Path) -> dict[tuple[str, str, str], tuple[np.ndarray, np.ndarray]]:
    """``angles.csv`` as ``(angle, joint, method) -> (t_s, degrees)``."""
    series: dict[tuple[str, str, str], tuple[list[float], list[float]]] = {}
    with path.open(newline="", encoding="utf-8") as f:
        for row in csv.DictReader(f):
            key = (row["angle"], row["joint"], row["method"])
            t, v = series.setdefault(key, ([], []))
            t.append(float(row["time_s"]))
            v.append(float(row["degrees"]) if row["degrees"] not in ("", "nan") else np.nan)
    return {k: (np.asarray(t), np.asarray(v)) for k, (t, v) in series.items()}


def _side(angle: str) -> str:
    return "left" if angle.endswith("_left") or angle.endswith("_l") else "right"


def _events(folder: Path) -> dict[str, list[tuple[float, float]]]:
    from kinefuse.biomech.gait import GaitEvents

    try:
        doc = json.loads((folder / "gait.json").read_text(encoding="utf-8"))
        ev = GaitEvents({k: tuple(v) for k, v in doc["strikes_s"].items()}, doc["travel_m"])
    except (OSError, ValueError, KeyError, TypeError):
        return {}
    return {side: ev.cycles(side) for side in ("left", "right")}


def _summary_rows(out: Path, ids: Sequence[str]) -> Iterable[dict[str, object]]:
    for trial in ids:
        folder = out / "trials" / trial
        cycles = _events(folder)
        for (angle, joint, method), (_t, v) in sorted(_read_angles(folder / "angles.csv").items()):
            ok = v[np.isfinite(v)]
            if ok.size == 0:
                continue
            yield {
                "trial": trial,
                "angle": angle,
                "joint": joint,
                "method": method,
                "frames": ok.size,
                "min_deg": ok.min(),
                "max_deg": ok.max(),
                "range_deg": ok.max() - ok.min(),
                "mean_deg": ok.mean(),
                "peak_deg": ok[np.argmax(np.abs(ok))],
                "cycles": len(cycles.get(_side(angle), [])),
            }


def _cycle_rows(out: Path, ids: Sequence[str]) -> Iterable[dict[str, object]]:
    from kinefuse.biomech.gait import cycle_curves

    for trial in ids:
        folder = out / "trials" / trial
        cycles = _events(folder)
        if not any(cycles.values()):
            continue
        for (angle, _joint, method), (t, v) in sorted(_read_angles(folder / "angles.csv").items()):
            side = _side(angle)
            curves = cycle_curves(t, v, cycles.get(side, []))
            whole = curves[np.isfinite(curves).all(axis=1)]
            if not len(whole):
                continue
            mean = whole.mean(axis=0)
            yield {"trial": trial, "angle": angle, "method": method, "side": side,
                   "cycles": len(whole), **{f"p{k}": mean[k] for k in range(101)}}  # fmt: skip


def _fmt(v: object) -> str:
    if isinstance(v, float | np.floating):
        return f"{float(v):.4f}"
    return str(v)


def _write_csv(
    path: Path, columns: Sequence[str], rows: Sequence[dict[str, object]], what: str
) -> Path:
    header = ",".join(columns) + "\n"

    def lines() -> Iterable[str]:
        yield header
        for r in rows:
            yield ",".join(_fmt(r[c]) for c in columns) + "\n"

    def ours(p: Path) -> bool:
        try:
            with p.open(encoding="utf-8") as f:
                return f.readline() == header
        except (OSError, UnicodeDecodeError):
            return False

    return atomic_write_lines(path, lines(), what=what, recognizer=ours)

"""``kinefuse evaluate``: every fusion method of a simulated session against its truth."""

from __future__ import annotations

import json
import math
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


@dataclass(frozen=True)
class EvaluateResult:
    """What ``kinefuse evaluate`` found (``--json`` prints :meth:`as_dict`, the ``evaluate.json``
    it writes).

    Attributes
    ----------
    truth : bool
        Whether the session had truth (else ``report`` holds the consistency figures).
    calibration : str or None
        Where the sensors' poses came from.
    written : tuple of str
        The files written into the evaluation folder (none without one).
    report : dict
        The whole report as ``evaluate.json`` holds it: per method its figures (``mae_m``,
        ``rmse_m``, ``p95_m``, ``coverage``, ...), ``frames``, ``comparisons``, ``notes``, ...
        (:func:`kinefuse.lab.fusion_truth.evaluate`,
        :func:`kinefuse.lab.no_truth.evaluate_without_truth`).
    """

    truth: bool
    calibration: str | None
    written: tuple[str, ...]
    report: dict[str, Any]

    @classmethod
    def of(cls, report: dict[str, Any]) -> EvaluateResult:
        """The result of a finished report."""
        cal = report.get("calibration")
        return cls(
            truth=report.get("truth") is not False,
            calibration=cal if isinstance(cal, str) else None,
            written=tuple(report.get("written", ())),
            report=report,
        )

    def method(self, name: str) -> dict[str, Any]:
        """One method's figures; :class:`KeyError` naming the methods evaluated otherwise."""
        figures = self.report.get(name)
        if not isinstance(figures, dict):
            raise KeyError(f"method {name!r} was not evaluated")
        return figures

    def as_dict(self) -> dict[str, Any]:
        """JSON-able: the report, as ``evaluate.json`` holds it."""
        return self.report


def run_evaluate(
    *,
    session: Path,
    methods: tuple[str, ...],
    out_dir: Path | None,
    calibration: Path | None,
    true_calibration: bool,
    allow_incomplete: bool = False,
    start_s: float | None = None,
    end_s: float | None = None,
    progress: Callable[[str], None] | None = None,
) -> EvaluateResult:
    """Compare fusion methods against the truth of a simulated session (opened read-only); a
    session without truth gets its consistency figures instead
    (:func:`kinefuse.lab.no_truth.evaluate_without_truth`; its ``truth`` is False).

    ``out_dir`` gets the tables, plots and ``evaluate.json``, built in a fresh folder and
    swapped in on success (an existing folder is replaced only if kinefuse made it).
    ``progress(message)`` hears of each step (:class:`kinefuse.app.workflows.progress.
    TerminalProgress` shows them on a terminal).
    """
    say = progress or (lambda _msg: None)
    from kinefuse.capture.fusion.methods import METHODS
    from kinefuse.core.outputs import atomic_dir, check_output_folder
    from kinefuse.lab.fusion_truth import calibration_alignment, evaluate, write_tables
    from kinefuse.pipeline.store_inputs import load_people

    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise InputError(
            f"unknown method(s) {', '.join(unknown)}; choose from {', '.join(METHODS)}"
        )
    if out_dir is not None:
        check_output_folder(out_dir, "evaluation folder")
    with SessionStore.open(session) as store:
        store.require_complete(allow_incomplete=allow_incomplete)
        if not store.has_truth():
            if true_calibration:  # refused with the reason: there are no true poses
                resolve_poses(store, calibration, true_calibration)
            return EvaluateResult.of(
                _without_truth(store, methods, out_dir, calibration, start_s, end_s, say)
            )
        poses, source = resolve_poses(store, calibration, true_calibration)
        say("reading the sensors' streams and clocks")
        # the subject as the other commands fuse them: their own bodies only (with bystanders
        # in the room, every sensor's first-listed body would mix people)
        people, per_person, screen = load_people(store, poses)
        sensors = per_person[people.subject]
        poses = {s.id: poses[s.id] for s in sensors}
        truth2world = None
        if not true_calibration:
            truth2world, cal_error = calibration_alignment(store, poses)
        report, results, truth = evaluate(
            store,
            sensors,
            methods,
            truth2world=truth2world,
            start_s=start_s,
            end_s=end_s,
            progress=say,
        )
        from kinefuse.lab.people import evaluate_people, several_people

        if several_people(store):
            say("scoring each person and the identity")
            grid = next(iter(results.values())).t_server_s
            report["people"] = evaluate_people(
                store, sensors, methods, grid, truth2world=truth2world, progress=say
            )
        say("scoring plausibility")
        from kinefuse.lab.plausibility_truth import plausibility_vs_errors

        report["plausibility"] = plausibility_vs_errors(store, results, truth)
        facts = None
        if out_dir is not None:
            from kinefuse.lab.report_facts import session_facts

            facts = session_facts(store, sensors, poses, source)
    report["calibration"] = source
    report["left_out"] = [{"id": k, "reason": v} for k, v in screen.left_out.items()]
    report["notes"] = screen.notes()
    if truth2world is not None:
        report["calibration_alignment"] = {
            "note": "truth moved into the calibration's world by a translation and a rotation "
            "about z fitted on the sensor poses",
            "translation_m": [float(v) for v in truth2world[:3, 3]],
            "yaw_deg": float(np.degrees(np.arctan2(truth2world[1, 0], truth2world[0, 0]))),
            "calibration_mean_position_error_m": cal_error,
        }
    if out_dir is not None:
        say(f"writing tables, plots and the report to {out_dir}")
        with atomic_dir(out_dir, what="evaluation folder") as tmp:
            written = write_tables(tmp, report, results, sensors, truth, methods)
            if facts is not None:
                from kinefuse.lab.report.html import write_html_report

                written.append(
                    write_html_report(tmp / "report.html", facts, report, results, truth, methods)
                )
            report["written"] = [str(out_dir / p.name) for p in written] + [
                str(out_dir / "evaluate.json")
            ]
            (tmp / "evaluate.json").write_text(json.dumps(report, indent=2) + "\n")
    return EvaluateResult.of(report)


def _without_truth(
    store: SessionStore,
    methods: tuple[str, ...],
    out_dir: Path | None,
    calibration: Path | None,
    start_s: float | None,
    end_s: float | None,
    say: Callable[[str], None],
) -> dict[str, Any]:
    """:func:`run_evaluate` of a session without truth (``store`` open): the consistency figures,
    ``evaluate.json``, ``consistency_by_joint.csv`` and ``report.html`` in ``out_dir``."""
    from kinefuse.core.outputs import atomic_dir
    from kinefuse.lab.no_truth import evaluate_without_truth, write_consistency_csv

    report, results, sensors, poses, source = evaluate_without_truth(
        store, methods, calibration=calibration, start_s=start_s, end_s=end_s, progress=say
    )
    if out_dir is None:
        return report
    from kinefuse.core.skeleton import JOINT_INDEX
    from kinefuse.lab.report.html import write_consistency_report
    from kinefuse.lab.report_facts import session_facts

    facts = session_facts(store, sensors, poses, source)
    focus = results.get("best") or next(iter(results.values()))
    track = focus.positions[:, JOINT_INDEX["SpineBase"], :2]
    say(f"writing the table and the report to {out_dir}")
    with atomic_dir(out_dir, what="evaluation folder") as tmp:
        written = [
            write_consistency_csv(tmp / "consistency_by_joint.csv", report, methods),
            write_consistency_report(tmp / "report.html", facts, report, methods, track),
        ]
        report["written"] = [str(out_dir / p.name) for p in written] + [
            str(out_dir / "evaluate.json")
        ]
        (tmp / "evaluate.json").write_text(json.dumps(report, indent=2) + "\n")
    return report


def _cm(mae_m: float) -> str:
    """An error in cm, or what it is when there is none (joints with no position: no_data)."""
    return f"{100 * mae_m:.1f} cm" if math.isfinite(mae_m) else "no position to compare"


def format_evaluate(report: dict[str, object], methods: tuple[str, ...]) -> str:
    """A short text table of an evaluation (the consistency figures without truth)."""
    if report.get("truth") is False:
        from kinefuse.lab.no_truth import format_consistency

        return format_consistency(report, methods)
    common = report.get("common")
    frac = common.get("joint_fraction", float("nan")) if isinstance(common, dict) else float("nan")
    lines = [f"calibration: {report.get('calibration')}, frames: {report.get('frames')}"]
    notes = report.get("notes")
    lines += [f"note: {n}" for n in notes] if isinstance(notes, list) else []
    lines.append("")
    lines.append(
        f"{'method':<10} {'MAE cm':>8} {'common':>8} {'RMSE cm':>8} {'p95 cm':>8} "
        f"{'coverage':>9} {'bias cm':>8} {'noise cm':>9}"
    )
    for m in methods:
        r = report[m]
        assert isinstance(r, dict)
        bn = r["bias_noise"]
        lines.append(
            f"{m:<10} {100 * r['mae_m']:8.2f} {100 * r['mae_common_m']:8.2f} "
            f"{100 * r['rmse_m']:8.2f} {100 * r['p95_m']:8.2f} {100 * r['coverage']:8.1f}% "
            f"{100 * bn['bias_norm_mean_m']:8.2f} {100 * bn['noise_mean_m']:9.2f}"
        )
    lines.append(
        f"(MAE over each method's own joints; 'common' over the {100 * frac:.1f} % of frames x "
        "joints every method solved; bias = mean offset per joint, noise = spread around it)"
    )
    for m in methods:
        r = report[m]
        assert isinstance(r, dict)
        if m == "best-live":
            parts = [f"{k.lower()} {100 * v['fraction']:.1f} % ({_cm(v['mae_m'])})"
                     for k, v in r["by_status"].items()]  # fmt: skip
            lines.append(f"{m} by joint status: " + ", ".join(parts))
    occ = report.get("occlusion")
    if isinstance(occ, dict):
        lines.append(
            f"\nocclusion detection vs ray casting: precision {occ['precision']:.2f}, "
            f"recall {occ['recall']:.2f}"
        )
    comp = report.get("comparisons")
    if isinstance(comp, dict) and comp:
        lines.append("\ngain of a over b: MAE of b minus MAE of a on joints both solved (95 % "
                     "interval, block bootstrap over frames):")  # fmt: skip
        for pair, v in comp.items():
            lines.append(f"  {pair:<22} {_gain_text(v)}")
    people = report.get("people")
    if isinstance(people, dict):
        lines.append(f"\npeople (bodies given to each by: {people['assignment']}):")
        for p, v in people["persons"].items():
            maes = ", ".join(f"{m} {_cm(v[m]['mae_m'])}" for m in methods if m in v)
            lines.append(f"  person {p} ({v['role']}, {v['rows']} bodies): {maes}")
        lines.append(
            f"  identity: {100 * people['identity']:.1f} % of frames fuse every person only "
            "from bodies that truly are theirs"
        )
    from kinefuse.lab.plausibility_truth import format_plausibility

    plaus = format_plausibility(report.get("plausibility"))
    if plaus:
        lines.append(plaus)
    abl = report.get("ablation")
    if isinstance(abl, dict):
        lines.append("\nablation of best (MAE without the part, and what the part gains):")
        for part, v in abl.items():
            lines.append(f"  {part:<11} {100 * v['mae_without_m']:6.2f} cm   {_gain_text(v)}")
    return "\n".join(lines)


def _gain_text(v: dict[str, Any]) -> str:
    low, high = v["gain_ci95_percent"]
    return (
        f"{100 * v['gain_m']:+6.2f} cm, {v['gain_percent']:+6.1f} % [{low:+.1f}, {high:+.1f}] "
        f"{v['verdict']}"
    )

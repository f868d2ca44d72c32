"""One input of ``kinefuse analyze`` through paper B, its files, and (sessions) its truth figures.

This module is in ``lab/report/`` because it reads the truth of simulated sessions (the true motion,
the range-of-motion phase's true axes) to measure the analysis; nothing in the analysis itself
sees them: the fused skeleton is analysed first, and the truth is read afterwards to score it.

Figures (all in the report JSON; definitions in ``docs/analysis.md``):

* ``reconstruction_error_m``: the paper's measure, each limb's end on its joint sphere from the
  angles about the learned axes (without the off-axis angle) vs measured
  (:func:`kinefuse.biomech.kinematics.reconstruction_error`), mean and median.
* ``axes_decision``: per limb, which test decided its number of axes (the one-plane test, the
  position budget :data:`kinefuse.biomech.parameterize.ONE_AXIS_BUDGET_M`), with its figures.
* ``timing_ms_per_frame``: wall time of normalization + angles + twist per frame (the axis
  learning on the calibration phase is reported apart).
* with truth: ``axis_error_deg`` (learned vs true axes of the range-of-motion phase, per method),
  ``twist_error_deg`` (twist of the analysed input vs the same twist from the true motion),
  ``angle_rmse_deg`` (each named angle of the input vs the same angle computed by the same chain
  on the true motion, over the frames after the calibration phase when there are any).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.biomech.gaps import fill_short_gaps_all
from kinefuse.biomech.kinematics import reconstruction_error
from kinefuse.biomech.limbs import LIMB_NAMES, LIMBS, limb
from kinefuse.errors import InputError
from kinefuse.formats.angles import plan_mot, write_angles_csv, write_angles_mot
from kinefuse.pipeline.analysis_chain import analyse_sequence

if TYPE_CHECKING:
    from kinefuse.pipeline.analysis_chain import AnalysisInput

Array = NDArray[np.float64]

#: The limb an anatomical angle belongs to, by the name's first word.
_ANGLE_LIMB = {
    "trunk": "trunk",
    "head": "head",
    "shoulder": "upper_arm",
    "elbow": "forearm",
    "forearm": "forearm",
    "hip": "thigh",
    "knee": "shank",
    "ankle": "foot",
}


def angle_joint(name: str) -> str:
    """The Kinect joint an anatomical angle is at (the proximal joint of its limb)."""
    head = name.split("_", 1)[0]
    kind = _ANGLE_LIMB.get(head)
    side = name.rsplit("_", 1)[-1]
    if kind is None:
        return name.split("_axis", 1)[0] if "_axis" in name else "unknown"
    lname = f"{kind}_{side}" if side in ("left", "right") else kind
    try:
        return limb(lname).proximal
    except KeyError:
        return "unknown"


def angle_limb(name: str) -> str | None:
    """The limb an anatomical angle belongs to (``knee_flexion_left`` -> ``shank_left``)."""
    kind = _ANGLE_LIMB.get(name.split("_", 1)[0])
    if kind is None:
        return None
    side = name.rsplit("_", 1)[-1]
    return f"{kind}_{side}" if side in ("left", "right") else kind


def skipped_limbs(unbuilt: dict[str, str] | None, joints: tuple[str, ...]) -> dict[str, str]:
    """Limb -> ``"skipped: ..."`` for the limbs of a partial body: those with a joint the
    marker map names but the file cannot build (``unbuilt``: joint -> its missing markers)."""
    out: dict[str, str] = {}
    for lb in LIMBS:
        # the root's SpineMid may be missing: normalization then uses the hips (lower body)
        ends = (lb.proximal,) if lb.parent is None else (lb.proximal, lb.distal)
        gone = [j for j in ends if j not in joints]
        why = [f"{j} (markers {unbuilt[j]})" for j in gone if unbuilt and j in unbuilt]
        if why:
            out[lb.name] = (
                f"skipped: the input has no {' and no '.join(why)}; this limb is not analysed"
            )
    return out


def _wrap_deg(d: Array) -> Array:
    return (d + 180.0) % 360.0 - 180.0


def _stats(values: Array) -> dict[str, float]:
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"median": float("nan"), "mean": float("nan"), "n": 0}
    return {"median": float(np.median(v)), "mean": float(v.mean()), "n": int(v.size)}


def _axis_angle_deg(a: Array, b: Array) -> float:
    """Angle between two axes as lines (sign-free), degrees."""
    c = abs(float(np.dot(a, b)) / max(float(np.linalg.norm(a) * np.linalg.norm(b)), 1e-12))
    return float(np.degrees(np.arccos(min(c, 1.0))))


def analyse_one(
    inp: AnalysisInput,
    folder: Path,
    *,
    phase: tuple[float, float],
    phase_source: str,
    statement: str,
    plots: bool = True,
    true_calibration: bool = False,
    plot_dpi: int | None = None,
    names: str = "kinefuse",
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Analyse one input into ``folder`` (which exists and is empty); returns (report, result)."""
    from kinefuse.biomech.parameterize import MIN_PHASE_FRAMES
    from kinefuse.pipeline.analysis_chain import SEEN_MIN_SENSORS, phase_seen

    seq = inp.seq
    seen = None if inp.limb_sensors is None else phase_seen(inp.limb_sensors, seq.t_s, phase)
    if seen is not None and seen["frames"] < MIN_PHASE_FRAMES:
        # no sensor saw the subject during the phase, so the fusion has (almost) no frame there:
        # say so, rather than ask for another phase as for a clip (issue 24)
        raise InputError(
            f"{inp.path.name}: the sensors saw the subject in {seen['frames']} fused frame(s) "
            f"of the calibration phase {phase[0]:g}:{phase[1]:g} s (the fused frames span "
            f"{seq.t_s[0]:.2f} to {seq.t_s[-1]:.2f} s): no axes can be learned. Perform the "
            "phase where the sensors see the subject (the centre of the capture volume)"
        )
    # a session's axes are learned from the frames its sensors saw (each limb and its parent
    # tracked by SEEN_MIN_SENSORS or more), not from the fusion's guesses in between
    res = analyse_sequence(
        seq,
        phase,
        not_seen=None if seen is None else seen["not_seen"],
        seen_frames=None if inp.limb_sensors is None else inp.limb_sensors >= SEEN_MIN_SENSORS,
    )
    if inp.static_window_s is not None and inp.anatomical is None:
        # a skeleton's anatomical angles: ISB frames from its standing phase, carried by the
        # normalized limb frames (kinefuse.biomech.anatomical.skeleton_anatomical_frames)
        from dataclasses import replace

        from kinefuse.pipeline.analysis_chain import skeleton_anatomy

        anat, sa = skeleton_anatomy(seq, res["norm"], inp.static_window_s)
        inp = replace(inp, anatomical=anat, anatomical_status=sa.status)
        static_motion_mm = {k: 1e3 * v for k, v in sa.static_motion_m.items()}
    else:
        static_motion_mm = None
    skipped = skipped_limbs(inp.unbuilt_joints, seq.joint_names)
    if skipped:  # a partial body: the angles of the skipped limbs are not written
        res["named"] = {k: v for k, v in res["named"].items() if angle_limb(k) not in skipped}
    norm, models, angles, named = res["norm"], res["models"], res["angles"], res["named"]
    dj = models["dj"]
    n = seq.n_frames
    sec = res["seconds"]
    rec = reconstruction_error(seq, angles, dj, off_axis=False)
    rec_full = reconstruction_error(seq, angles, dj, off_axis=True)
    report: dict[str, Any] = {
        "input": str(inp.path),
        "kind": inp.kind,
        "source": seq.source,
        "frames": n,
        "rate_hz": seq.rate_hz,
        "joints": list(seq.joint_names),
        "calibration_phase": {"start_s": phase[0], "end_s": phase[1], "source": phase_source},
        "statement": statement,
        "warnings": [],
        "default_pose_frame": int(norm.default_frame),
        "default_pose_time_s": float(seq.t_s[norm.default_frame]),
        "normalization_status": dict(norm.status),
        "observable": norm.observable,
        "axes": {k: v.axes for k, v in dj.limbs.items() if v.usable},
        "axis_names": {k: list(v.axis_names) for k, v in dj.limbs.items() if v.usable},
        "limb_status": dj.status,
        # which test decided each limb's number of axes (one-plane test, position budget)
        "axes_decision": {k: v.axes_decision for k, v in dj.limbs.items() if v.axes_decision},
        "methods": {
            m: {
                "axes": {k: v.axes for k, v in mod.limbs.items() if v.usable},
                "status": mod.status,
            }
            for m, mod in models.items()
        },
        "reconstruction_error_m": {"mean": rec["sphere_mean"], "median": rec["sphere_median"]},
        "reconstruction_error_note": "each limb's end on its joint sphere from the angles about "
        "the learned axes alone (the paper's minimal parameters) vs measured; with the off-axis "
        "angle added the reconstruction is exact up to rounding (reconstruction_error_full_m)",
        "reconstruction_error_full_m": {
            "mean": rec_full["sphere_mean"],
            "median": rec_full["sphere_median"],
        },
        "timing_ms_per_frame": 1e3 * (sec["normalize"] + sec["angles"]) / n,
        "timing_ms": {k: 1e3 * v for k, v in sec.items()},
        "angle_names": sorted(named),
    }
    if skipped:
        report["limb_status"] = {**dj.status, **skipped}
        report["skipped_limbs"] = skipped
        report["analysed_limbs"] = [  # the limbs with normalized frames
            lm
            for i, lm in enumerate(LIMB_NAMES)
            if lm not in skipped and np.isfinite(norm.frames[:, i]).any()
        ]
        report["warnings"].append(
            "partial body: "
            + "; ".join(f"{k} {v}" for k, v in skipped.items())
            + f". Analysed: {', '.join(report['analysed_limbs']) or 'nothing'}"
        )
        report["statement"] += (
            f" Partial body: {', '.join(skipped)} skipped (their joints' markers are not in the "
            "input); their angles are not written."
        )
    if inp.fusion is not None:
        report["fusion"] = inp.fusion
        for sid, why in inp.fusion.get("left_out", {}).items():
            report["warnings"].append(f"sensor {sid} left out of the fusion: {why}")
    if seen is not None:
        report["calibration_phase"]["seen"] = seen
        if seen["not_seen"]:
            unseen = sorted(seen["not_seen"])
            report["warnings"].append(
                f"the sensors did not see the calibration phase well: {len(unseen)} limb(s) "
                f"tracked by {seen['min_sensors']} or more sensors in less than "
                f"{100 * seen['min_fraction']:.0f} % of it ({', '.join(unseen)}; least "
                f"{100 * seen['fraction_min']:.0f} %); their axes were not learned and their "
                "angles are missing. Record the phase where the sensors see the subject"
            )
            report["statement"] += (
                f" The calibration phase was not seen for {', '.join(unseen)}: no axes or "
                "angles for them (their limb_status says why)."
            )
    # limbs whose second axis is the one perpendicular to the first and the rest, and why
    for prefix, why in (
        ("second axis not trusted", "the learned axes are far from perpendicular (the phase's "
         "second movement was observed too poorly); replaced by the axis perpendicular to the "
         "first and the rest direction (limb_status: the angles)"),
        ("second axis not observed", "the phase moved them along one main direction only, and "
         "one axis would lose their off-plane movement; their second axis is the one "
         "perpendicular to the first and the rest direction (limb_status). Move each along "
         "both main directions in the calibration phase"),
    ):  # fmt: skip
        replaced = sorted(k for k, v in dj.status.items() if v.startswith(prefix))
        if replaced:
            report["warnings"].append(f"{prefix} for {', '.join(replaced)}: {why}")
    # the generator's two-axis limbs that kept two axes (what a one-plane misjudgement loses)
    two = [k for k, v in dj.limbs.items() if limb(k).n_axes == 2]
    report["two_axis_limbs"] = {
        "asked": len(two),
        "learned_two": sum(1 for k in two if dj.limbs[k].axes.shape[0] == 2),
        "one_or_none": sorted(k for k in two if dj.limbs[k].axes.shape[0] != 2),
    }
    from kinefuse.biomech.angle_plausibility import plausibility

    report["plausibility"] = _flag_summary(plausibility(angles, dj), seq.t_s, phase)
    truth = None
    if inp.kind == "session":
        from kinefuse.lab.analysis_truth import truth_figures

        truth = truth_figures(inp, res, phase, true_calibration=true_calibration)
        if truth is not None:
            report.update(truth["report"])
    if inp.anatomical is not None:
        report["anatomical"] = {
            "static_trial": inp.static_source,
            "segment_status": inp.anatomical_status,
            "skipped": {
                k: v for k, v in (inp.anatomical_status or {}).items() if not v.startswith("ok")
            },
            "angle_names": sorted(inp.anatomical),
            "present_fraction": {
                k: float(np.isfinite(v).mean()) for k, v in sorted(inp.anatomical.items())
            },
        }
        if static_motion_mm is not None:
            report["anatomical"]["static_motion_p90_mm"] = static_motion_mm
    from kinefuse.biomech.angle_plausibility import angle_statuses

    # every angle's plausibility (wraps, jumps, leaves its range): in angles.csv, here and in
    # the text report
    statuses = {
        "functional": angle_statuses(seq.t_s, res["named"]),
        "anatomical": angle_statuses(seq.t_s, inp.anatomical or {}),
    }
    report["angle_status"] = {
        m: {k: v for k, v in sorted(st.items()) if v["status"] != "ok"}
        for m, st in statuses.items()
    }
    # per joint: implausible when one of its angles is, with the angles' reasons
    report["joint_status"] = {m: _joint_status(st) for m, st in statuses.items()}
    report["angle_status_rule"] = (
        "implausible: the angle wraps through ±180 deg, jumps faster than a body moves, or is "
        "outside its physiological range on more than 5 % of its frames "
        "(kinefuse.biomech.angle_plausibility.angle_status); angles not listed are ok"
    )
    if inp.anatomical is not None:
        report["anatomical"]["angle_status"] = {
            k: v["status"] for k, v in sorted(statuses["anatomical"].items())
        }
    written, mot = _write_outputs(folder, inp, res, plots, truth, plot_dpi, names, statuses)
    report["angles_mot"] = mot
    report["written"] = [str(p) for p in written]
    return report, res


def _flag_summary(flags: Any, t_s: Array, phase: tuple[float, float]) -> dict[str, Any]:
    f = np.asarray(flags.flags, dtype=bool)
    after = t_s > phase[1]
    sel = after if after.any() else np.ones_like(after)
    names = list(LIMB_NAMES[: f.shape[1]])
    return {
        "frames_flagged_fraction": float(f[sel].any(axis=1).mean()) if f.size else 0.0,
        "by_limb_fraction": {nm: float(f[sel, i].mean()) for i, nm in enumerate(names)},
        "over": "frames after the calibration phase" if after.any() else "all frames",
    }


def _write_outputs(
    folder: Path,
    inp: AnalysisInput,
    res: dict[str, Any],
    plots: bool,
    truth: dict[str, Any] | None,
    plot_dpi: int | None = None,
    mot_names: str = "kinefuse",
    statuses: dict[str, dict[str, dict[str, Any]]] | None = None,
) -> tuple[list[Path], dict[str, Any]]:
    from kinefuse.app.workflows.analyze import write_limb_frames
    from kinefuse.biomech.anatomical import opensim_angles, opensim_model

    seq, norm, named = res["seq"], res["norm"], res["named"]
    t = seq.t_s
    names = sorted(named)
    filled, flags = fill_short_gaps_all(t, {k: named[k] for k in names})
    anat, aflags = fill_short_gaps_all(t, inp.anatomical or {})
    # angles.csv: both methods under their names; the method column tells them apart
    rows = {f"{k}\tfunctional": v for k, v in filled.items()}
    rows.update({f"{k}\tanatomical": v for k, v in anat.items()})
    csv_flags = {f"{k}\tfunctional": v for k, v in flags.items()}
    csv_flags.update({f"{k}\tanatomical": v for k, v in aflags.items()})
    model = opensim_model(mot_names)
    if model is not None:
        if inp.anatomical is None:
            from kinefuse.errors import InputError

            raise InputError(
                f"{inp.path}: --names {mot_names} writes the anatomical angles, which need a "
                "static trial (--static STATIC.trc or --static-window START:END)"
            )
        # the pelvis and torso as the model's own bodies where its marker template is known
        body, _ = fill_short_gaps_all(t, (inp.opensim_body_angles or {}).get(model.name, {}))
        mot_cols = opensim_angles({**anat, **body}, model)
    else:
        mot_cols = dict(filled)
        mot_cols.update({f"{k}_anatomical": v for k, v in anat.items()})
    plan = plan_mot(t, mot_cols)
    written = [
        write_angles_csv(
            folder / "angles.csv",
            t,
            rows,
            {k: angle_joint(k.split("\t")[0]) for k in rows},
            methods={k: k.split("\t")[1] for k in rows},
            filled=csv_flags,
            labels={k: k.split("\t")[0] for k in rows},
            status={k: _status_of(statuses, k) for k in rows},
        ),
        write_angles_mot(folder / "angles.mot", t, mot_cols, plan=plan),
        write_limb_frames(folder / "limb_frames.csv", t, LIMB_NAMES, norm.transforms()),
    ]
    if plots:
        from kinefuse.lab.report.analysis_plots import plot_angle_curves, plot_joint_spheres

        title = f"{inp.path.name} ({inp.kind})"
        written.append(
            plot_angle_curves(
                folder / "angles.png",
                t,
                named,
                title=title,
                truth_deg=None if truth is None else truth.get("named_true"),
                dpi=plot_dpi or 80,
            )
        )
        dj = res["models"]["dj"]
        ph = dj.phase_s
        inside = (t >= ph[0]) & (t <= ph[1])
        samples = {k: res["angles"].direction[k][inside] for k in dj.limbs}
        written.append(
            plot_joint_spheres(
                folder / "axes_on_spheres.png",
                samples,
                {k: v.axes for k, v in dj.limbs.items()},
                status=dj.status,
                true_axes=None if truth is None else truth.get("true_axes"),
                title=f"{title}, calibration phase {ph[0]:.1f}-{ph[1]:.1f} s",
                dpi=int(1.3 * plot_dpi) if plot_dpi else 70,
            )
        )
    return written, plan.summary()


def _joint_status(statuses: dict[str, dict[str, Any]]) -> dict[str, str]:
    """Joint (``angles.csv``'s joint column; ``pelvis`` for the pelvis's angles) -> ``ok``, or
    ``implausible: ANGLE: reasons | ...`` when one of its angles is."""
    out: dict[str, list[str]] = {}
    for k, v in sorted(statuses.items()):
        if v["status"] == "no data":
            continue
        j = angle_joint(k)
        bad = out.setdefault(k.split("_", 1)[0] if j == "unknown" else j, [])
        if v["status"] == "implausible":
            bad.append(f"{k}: {'; '.join(v['reasons'])}")
    return {j: "implausible: " + " | ".join(b) if b else "ok" for j, b in out.items()}


def _status_of(statuses: dict[str, dict[str, dict[str, Any]]] | None, key: str) -> str:
    """The status of an ``angles.csv`` row key (``name<TAB>method``); "" when not known."""
    name, method = key.split("\t")
    return str((statuses or {}).get(method, {}).get(name, {}).get("status", ""))


def consistency_report(results: list[dict[str, Any]]) -> dict[str, Any]:
    """``normalization_consistency_deg`` across several inputs of one subject."""
    from kinefuse.biomech.side_consistency import normalization_consistency

    c = normalization_consistency([r["norm"] for r in results])
    return {"normalization_consistency_deg": c}


def _num(v: object, scale: float = 1.0, fmt: str = ".2f") -> str:
    """A number for the text report; "n/a" for a missing (None/NaN) one."""
    if isinstance(v, int | float) and np.isfinite(v):
        return format(scale * v, fmt)
    return "n/a"


def format_report(report: dict[str, Any]) -> str:
    """A short text summary (one block per input)."""
    items = report.get("inputs", [report])
    lines: list[str] = []
    for r in items:
        lines.append(f"{r['input']} ({r['kind']}, {r['frames']} frames)")
        ph = r["calibration_phase"]
        lines.append(
            f"  calibration phase {_num(ph['start_s'])}-{_num(ph['end_s'])} s: {ph['source']}"
        )
        seen = ph.get("seen")
        if seen is not None:
            lines.append(
                f"  phase seen by {seen['min_sensors']}+ sensors: median "
                f"{100 * seen['fraction_median']:.0f} % of its frames per limb, least "
                f"{100 * seen['fraction_min']:.0f} %"
            )
        for w in r.get("warnings", []):
            lines.append(f"  warning: {w}")
        two = r.get("two_axis_limbs")
        if two is not None:
            lines.append(f"  two-axis limbs learned with two axes: {two['learned_two']} of "
                         f"{two['asked']}")  # fmt: skip
        lines.append(f"  default pose: frame {r['default_pose_frame']}")
        rec = r["reconstruction_error_m"]
        lines.append(
            f"  reconstruction error: mean {_num(rec['mean'], 1e3)} mm, median "
            f"{_num(rec['median'], 1e3)} mm; "
            f"{_num(r['timing_ms_per_frame'], 1, '.3f')} ms per frame"
        )
        bad = {k: v for k, v in r["limb_status"].items() if v != "ok"}
        if bad:
            lines.append("  limbs not ok: " + "; ".join(f"{k}: {v}" for k, v in bad.items()))
        for m, st in r.get("angle_status", {}).items():
            for k, v in st.items():
                if v["status"] == "implausible":
                    lines.append(f"  implausible {m} {k}: {'; '.join(v['reasons'])}")
        for m, e in r.get("axis_error_by_method_deg", {}).items():
            lines.append(
                f"  axis error {m:>3}: median {_num(e['median'])} deg, mean {_num(e['mean'])} deg"
            )
        if "twist_error_deg" in r:
            tw = r["twist_error_deg"]
            lines.append(
                f"  twist error: median {_num(tw['median'])} deg, mean {_num(tw['mean'])} deg"
            )
        rm = r.get("angle_rmse_deg", {})
        for k in sorted(rm):
            if "knee_flexion" in k or "hip_flexion" in k:
                lines.append(f"  RMSE {k}: {_num(rm[k])} deg")
    if "normalization_consistency_deg" in report:
        c = report["normalization_consistency_deg"]
        lines.append(
            f"normalization consistency: median {_num(c['median'])} deg, mean {_num(c['mean'])} deg"
        )
    lines.append(f"wrote {report.get('out')}")
    return "\n".join(lines)

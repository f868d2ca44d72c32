"""``report.html``: one self-contained page (inline CSS, figures as PNG data URIs, no script, no
network) that ``kinefuse evaluate --out DIR`` and ``kinefuse demo`` write.

The figures come from what :func:`kinefuse.lab.fusion_truth.evaluate` computed (its report, the
methods' results and the truth on the same frames) and from
:class:`~kinefuse.lab.report_facts. SessionFacts`; the one thing computed here is the 95 %
interval of each MAE (a circular block bootstrap over frames, as
:func:`kinefuse.lab.metrics.gain` does for differences).
"""

from __future__ import annotations

import html
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.capture.fusion.fusion_run import MethodResult
from kinefuse.core.skeleton import JOINT_INDEX, JOINTS
from kinefuse.lab.metrics import block_bootstrap_sums
from kinefuse.lab.report import html_plots as hp
from kinefuse.lab.report_facts import SessionFacts

Array = NDArray[np.float64]

#: The methods the per-joint and trajectory figures show (the others are in the tables).
FOCUS = ("paper", "best", "best-live")
GENERATOR = '<meta name="generator" content="kinefuse report">'


def mae_intervals(
    estimate: Array, truth: Array, *, block: int = 30, n_boot: int = 400, seed: int = 0
) -> tuple[tuple[float, float], tuple[Array, Array]]:
    """95 % intervals of the MAE, over all joints and per joint (circular block bootstrap over
    frames, blocks of ``block`` frames: neighbouring frames' errors are correlated).

    Returns
    -------
    overall : (low_m, high_m)
    per_joint : ((25,) low_m, (25,) high_m)
    """
    e = np.linalg.norm(np.asarray(estimate) - np.asarray(truth), axis=-1)  # (T, 25)
    ok = np.isfinite(e)
    s = np.where(ok, e, 0.0)
    n = s.shape[0]
    if n == 0:
        nan = np.full(len(JOINTS), np.nan)
        return (math.nan, math.nan), (nan, nan)
    sums, cnts = block_bootstrap_sums(
        [s, ok], block=block, n_boot=n_boot, seed=seed
    )  # (n_boot, 25)
    cnts = cnts.astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        per = sums / cnts
        tot = sums.sum(axis=1) / cnts.sum(axis=1)
    lo, hi = np.nanpercentile(tot, [2.5, 97.5])
    jl, jh = np.nanpercentile(per, [2.5, 97.5], axis=0)
    return (float(lo), float(hi)), (jl, jh)


#: The angles the report draws when the analysis runs (names of ``Angles.anatomical()``).
ANGLE_WORDS = ("knee", "hip", "elbow")


def joint_angle_curves(
    result: MethodResult, phase_s: tuple[float, float]
) -> tuple[Array, dict[str, Array]]:
    """Paper B's flexion angles (degrees) of a fused result, the movement axes learned on the
    range-of-motion phase ``phase_s`` (Direction Joining, as ``kinefuse analyze``)."""
    from kinefuse import biomech as an
    from kinefuse.biomech.sequence import SkeletonSequence

    t = result.t_server_s
    seq = SkeletonSequence.from_kinect(
        result.positions, t_s=t, rate_hz=30.0, source=f"fused with {result.method}"
    )
    norm = an.normalize(seq)
    model = an.learn_axes(seq, norm, phase=phase_s, method="dj")
    deg = an.joint_angles(seq, norm, model).anatomical()
    keep = {
        k: v
        for k, v in sorted(deg.items())
        if "flexion" in k and any(w in k for w in ANGLE_WORDS) and np.isfinite(v).any()
    }
    return t, keep


def angle_status_table(t_s: Array, angles: dict[str, Array]) -> str:
    """An HTML table: per angle its plausibility status and why
    (:func:`kinefuse.biomech.angle_plausibility.angle_statuses`)."""
    from kinefuse.biomech.angle_plausibility import angle_statuses

    rows = "".join(
        f"<tr><td>{_e(k)}</td><td>{_e(v['status'])}</td><td>{_e('; '.join(v['reasons']))}</td></tr>"
        for k, v in angle_statuses(t_s, angles).items()
    )
    return f"<table><tr><th>angle</th><th>status</th><th>why</th></tr>{rows}</table>"


CSS = """
body { font: 14px/1.5 system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; color: #1f2933;
       max-width: 1080px; margin: 0 auto; padding: 20px 28px 60px; background: #fff; }
h1 { font-size: 24px; margin-bottom: 2px; } h2 { font-size: 18px; margin-top: 34px;
border-bottom: 1px solid #e4e7eb; padding-bottom: 4px; } h3 { font-size: 15px; }
.sub { color: #616e7c; margin-top: 0; } .note { color: #616e7c; font-size: 13px; }
table { border-collapse: collapse; margin: 8px 0 14px; font-variant-numeric: tabular-nums; }
th, td { padding: 3px 10px; border-bottom: 1px solid #e4e7eb; text-align: right; }
th { background: #f5f7fa; font-weight: 600; } th:first-child, td:first-child { text-align: left; }
img { max-width: 100%; display: block; margin: 6px 0; }
.row { display: flex; gap: 18px; flex-wrap: wrap; align-items: flex-start; }
.row > div { flex: 1 1 420px; min-width: 0; }
.kpi { display: flex; gap: 14px; flex-wrap: wrap; margin: 14px 0; }
.kpi div { background: #f5f7fa; border-radius: 6px; padding: 8px 14px; }
.kpi b { display: block; font-size: 20px; } .gain { color: #2f9e44; } .loss { color: #c92a2a; }
nav a { margin-right: 12px; color: #1971c2; text-decoration: none; font-size: 13px; }
"""


def _e(x: object) -> str:
    return html.escape(str(x))


def _n(x: float | None, d: int = 2, scale: float = 1.0) -> str:
    if x is None or not isinstance(x, int | float) or not math.isfinite(x):
        return "–"
    return f"{x * scale:.{d}f}"


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    h = "".join(f"<th>{_e(c)}</th>" for c in header)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><thead><tr>{h}</tr></thead><tbody>{body}</tbody></table>"


def _img(uri: str, alt: str) -> str:
    return f'<img src="{uri}" alt="{_e(alt)}">'


def _gain_cell(g: dict[str, Any]) -> str:
    lo, hi = g["gain_ci95_percent"]
    cls = {"gain": "gain", "loss": "loss"}.get(g["verdict"], "")
    return (
        f'<span class="{cls}">{_n(g["gain_m"], 2, 100)} cm, {_n(g["gain_percent"], 1)} % '
        f"[{_n(lo, 1)}, {_n(hi, 1)}]</span> {_e(g['verdict'])}"
    )


#: the sections every report has, first in its navigation (:func:`_session_sections`)
_SESSION_NAV = (("setup", "setup"), ("calibration", "calibration"), ("clock", "clock sync"),
                ("latency", "latency"))  # fmt: skip


def _nav(*sections: tuple[str, str]) -> str:
    """The report's navigation: the session's sections, then ``sections`` (anchor, title)."""
    links = (f'<a href="#{a}">{t}</a>' for a, t in (*_SESSION_NAV, *sections))
    return "<nav>" + "".join(links) + "</nav>"


def render_report(
    facts: SessionFacts,
    report: dict[str, Any],
    results: dict[str, MethodResult],
    truth: Array,
    methods: Sequence[str],
    *,
    angles: tuple[Array, dict[str, Array]] | None = None,
) -> str:
    """The HTML text of the report (see the module docstring)."""
    methods = [m for m in methods if m in results]
    focus = [m for m in FOCUS if m in methods] or methods[:3]
    ci = {m: mae_intervals(results[m].positions, truth) for m in methods}
    parts: list[str] = []
    add = parts.append
    best = min(methods, key=lambda m: report[m]["mae_m"])
    add(f"<h1>kinefuse evaluation: {_e(facts.name)}</h1>")
    add(
        f'<p class="sub">clip {_e(facts.clip or "–")} · {len(facts.sensors)} sensors · '
        f"{report.get('frames', 0)} fused frames ({facts.duration_s:.1f} s recorded) · poses: "
        f"{_e(facts.pose_source)}</p>"
    )
    add(
        _nav(
            ("accuracy", "accuracy"),
            ("time", "error over time"),
            ("trajectories", "trajectories"),
            ("occlusion", "occlusion"),
            ("angles", "angles"),
        )
    )
    kpi = [(f"{_n(report[m]['mae_m'], 1, 100)} cm", f"MAE {m}") for m in focus]
    occ = report.get("occlusion") or {}
    kpi.append((_n(occ.get("precision"), 2), "occlusion precision"))
    add('<div class="kpi">' + "".join(f"<div><b>{v}</b>{_e(k)}</div>" for v, k in kpi) + "</div>")

    path = None
    if "best" in results:
        path = results["best"].positions[:, JOINT_INDEX["SpineBase"], :2]
    parts += _session_sections(facts, path)

    # accuracy
    add('<h2 id="accuracy">Accuracy</h2>')
    mae = {m: report[m]["mae_m"] for m in methods}
    add(
        '<div class="row"><div>'
        + _img(
            hp.data_uri(hp.accuracy_figure(methods, mae, {m: ci[m][0] for m in methods})),
            "MAE per method",
        )
    )
    add(_img(hp.data_uri(hp.bias_noise_figure(methods, report)), "bias and noise"))
    add("</div><div>")
    cols = ["method", "MAE (cm)", "95 % interval", "RMSE", "p95", "coverage", "bias", "noise"]
    add(
        _table(
            cols,
            [
                [
                    f"<b>{_e(m)}</b>" if m == best else _e(m),
                    _n(report[m]["mae_m"], 2, 100),
                    f"{_n(ci[m][0][0], 2, 100)} – {_n(ci[m][0][1], 2, 100)}",
                    _n(report[m]["rmse_m"], 2, 100),
                    _n(report[m]["p95_m"], 2, 100),
                    f"{_n(report[m]['coverage'], 1, 100)} %",
                    _n(report[m]["bias_noise"]["bias_norm_mean_m"], 2, 100),
                    _n(report[m]["bias_noise"]["noise_mean_m"], 2, 100),
                ]
                for m in methods
            ],
        )
    )
    add(
        '<p class="note">centimetres; intervals: circular block bootstrap over frames (1 s '
        "blocks); bias = each joint's mean offset, noise = the spread around it</p>"
    )
    comp = report.get("comparisons") or {}
    if comp:
        add("<h3>Differences (MAE of b minus MAE of a, same joints)</h3>")
        add(
            _table(
                ["a vs b", "gain of a, 95 % interval"],
                [[_e(k), _gain_cell(v)] for k, v in comp.items()],
            )
        )
    abl = report.get("ablation") or {}
    if abl:
        add("<h3>What each part of best is worth (ablation)</h3>")
        add(
            _table(
                ["part switched off", "MAE without (cm)", "gain of the part"],
                [[_e(k), _n(v["mae_without_m"], 2, 100), _gain_cell(v)] for k, v in abl.items()],
            )
        )
    add("</div></div>")
    add("<h3>Per joint</h3>")
    add(
        _img(
            hp.data_uri(
                hp.per_joint_figure(
                    focus, {m: report[m]["by_joint"] for m in focus}, {m: ci[m][1] for m in focus}
                )
            ),
            "error per joint",
        )
    )

    # error over time, trajectories
    add('<h2 id="time">Error over time</h2>')
    add(_img(hp.data_uri(hp.error_time_figure(results, truth, methods)), "error over time"))
    add('<h2 id="trajectories">Trajectories against the truth</h2>')
    for joint in ("WristRight", "AnkleLeft"):
        add(_img(hp.data_uri(hp.trajectory_figure(results, truth, focus, joint)), joint))

    # occlusion
    add('<h2 id="occlusion">Occlusion detection</h2>')
    if occ:
        add(
            _table(
                ["precision", "recall", "F1"],
                [[_n(occ.get("precision"), 3), _n(occ.get("recall"), 3), _n(occ.get("f1"), 3)]],
            )
        )
        add(
            '<p class="note">the clients\' occlusion flags against ray-cast visibility in the '
            "simulator (joints the tracker reported)</p>"
        )
    # joint angles
    add('<h2 id="angles">Joint angles</h2>')
    method = "best" if "best" in results else methods[-1]
    angle_note = ""
    if angles is None and facts.rom_phase_s is not None:
        from kinefuse.errors import KinefuseError

        try:
            angles = joint_angle_curves(results[method], facts.rom_phase_s)
            lo, hi = facts.rom_phase_s
            angle_note = (
                f"paper B's flexion angles of {method}; movement axes learned on the "
                f"session's range-of-motion phase ({lo:.1f} to {hi:.1f} s)"
            )
        except (KinefuseError, ValueError) as exc:
            angle_note = f"the analysis could not run on {method}: {exc}"
    if angles is not None and angles[1]:
        add(_img(hp.data_uri(hp.angle_figure(*angles, facts.rom_phase_s)), "joint angles"))
        add(angle_status_table(*angles))
        if angle_note:
            add(f'<p class="note">{_e(angle_note)}</p>')
    elif angle_note:
        add(f'<p class="note">{_e(angle_note)}</p>')
    else:
        add(
            '<p class="note">the analysis has not run on this session: '
            "it needs a range-of-motion phase (<code>kinefuse simulate --rom SECONDS</code>); "
            "<code>kinefuse analyze SESSION --out DIR</code> computes paper B's joint angles</p>"
        )
    return _page(facts, parts)


def _page(facts: SessionFacts, parts: Sequence[str]) -> str:
    """The whole HTML document around the sections ``parts``."""
    top = f'<meta charset="utf-8">{GENERATOR}<title>kinefuse report: {_e(facts.name)}</title>'
    return (
        f'<!DOCTYPE html>\n<html lang="en"><head>{top}<style>{CSS}</style></head><body>\n'
        + "\n".join(parts)
        + "\n</body></html>\n"
    )


def _session_sections(facts: SessionFacts, path: Array | None) -> list[str]:
    """The setup, calibration, clock and latency sections (``path``: the body's ground track
    ``(T, 2)`` drawn on the rig figure, or None)."""
    parts: list[str] = []
    add = parts.append
    # setup
    add('<h2 id="setup">Setup</h2><div class="row"><div>')
    add(_img(hp.data_uri(hp.rig_figure(facts, path)), "rig seen from above"))
    add("</div><div>")
    add(
        _table(
            ["sensor", "serial", "frames", "rate (Hz)", "tracked"],
            [
                [
                    _e(s["id"]),
                    _e(s["serial"]),
                    str(s["frames"]),
                    _n(s["rate_hz"], 1),
                    f"{_n(s['tracked_fraction'], 0, 100)} %",
                ]
                for s in facts.sensors
            ],
        )
    )
    add("</div></div>")

    # calibration
    add('<h2 id="calibration">Calibration quality</h2>')
    add(f'<p class="note">{_e(facts.calibration_note)}</p>')
    if facts.calibration:
        rows = facts.calibration
        has_err = "position_error_mm" in rows[0]
        head = ["sensor", "wand residual (mm)", "sightings"]
        head += ["position error (mm)", "rotation error (deg)"] if has_err else []
        body = [
            [_e(r["id"]), _n(r["residual_mm"], 2), str(r["sightings"])]
            + ([_n(r["position_error_mm"], 2), _n(r["rotation_error_deg"], 3)] if has_err else [])
            for r in rows
        ]
        add(
            '<div class="row"><div>'
            + _img(hp.data_uri(hp.calibration_figure(rows)), "calibration residuals")
            + "</div><div>"
            + _table(head, body)
            + "</div></div>"
        )

    # clock
    add('<h2 id="clock">Clock sync over time</h2>')
    if facts.clocks:
        add(_img(hp.data_uri(hp.clock_figure(facts)), "clock sync"))
        clock_rows: list[list[str]] = []
        vs_truth = any(c.error_ms is not None for c in facts.clocks)
        for c in facts.clocks:
            err = c.error_ms
            clock_rows.append(
                [
                    _e(c.sensor_id),
                    str(c.t_probe_s.size),
                    _n(float(np.median(c.rtt_ms)), 2),
                    _n(float(np.std(c.probe_residual_ms)), 3),
                ]
                + (
                    [_n(float(np.max(np.abs(err))), 3) if err is not None else "–"]
                    if vs_truth
                    else []
                )
            )
        add(
            _table(
                ["sensor", "probes", "median RTT (ms)", "probe scatter (ms)"]
                + (["max error vs truth (ms)"] if vs_truth else []),
                clock_rows,
            )
        )
    else:
        add('<p class="note">no clock probes in this session</p>')

    # latency
    add('<h2 id="latency">Latency</h2>')
    if facts.latency_ms is not None and np.isfinite(facts.latency_ms).any():
        add(_img(hp.data_uri(hp.latency_figure(facts.latency_ms)), "latency distribution"))
    else:
        add(f'<p class="note">{_e(facts.latency_note)}</p>')
    return parts


def write_html_report(
    path: Path,
    facts: SessionFacts,
    report: dict[str, Any],
    results: dict[str, MethodResult],
    truth: Array,
    methods: Sequence[str],
    *,
    angles: tuple[Array, dict[str, Array]] | None = None,
) -> Path:
    """Write ``report.html`` at ``path`` through a temporary file and an atomic rename."""
    from kinefuse.core.outputs import atomic_write_text

    text = render_report(facts, report, results, truth, methods, angles=angles)
    return atomic_write_text(path, text, what="HTML report", recognizer=is_kinefuse_report)


def _mm_pair(v: Sequence[float | None] | None) -> str:
    """``[median, p95]`` metres as ``"median / p95"`` millimetres."""
    if not v:
        return "–"
    return f"{_n(v[0], 0, 1e3)} / {_n(v[1], 0, 1e3)}"


def render_consistency_report(
    facts: SessionFacts,
    report: dict[str, Any],
    methods: Sequence[str],
    ground_track: Array | None = None,
) -> str:
    """The HTML text of the report of a session without truth
    (:func:`kinefuse.lab.no_truth.evaluate_without_truth`): the session's sections, then
    the consistency figures; the sections that need the truth are absent and it says why.
    ``ground_track`` ``(T, 2)``: the body's path seen from above, drawn on the rig figure."""
    methods = [m for m in methods if m in report]
    focus = "best" if "best" in methods else methods[0]
    parts: list[str] = []
    add = parts.append
    add(f"<h1>kinefuse evaluation: {_e(facts.name)}</h1>")
    add(
        f'<p class="sub">{len(facts.sensors)} sensors · {report.get("frames", 0)} fused frames '
        f"({facts.duration_s:.1f} s recorded) · poses: {_e(report.get('calibration'))}</p>"
    )
    add(_nav(("consistency", "consistency"), ("joints", "per joint"), ("bones", "bones")))
    agree = report.get("agreement")
    r = report[focus]
    kpi = [(f"{_n(r['placed'], 1, 100)} %", f"joints placed ({focus})")]
    kpi.append((f"{_n(r['bone_sd_median_m'], 0, 1e3)} mm", f"bone-length spread ({focus})"))
    if agree:
        first = next(iter(agree["disagreement_lr"].values()))
        kpi.append((f"{_n(first['all'][0], 0, 1e3)} mm", "sensor vs sensor (median)"))
    add('<div class="kpi">' + "".join(f"<div><b>{v}</b>{_e(k)}</div>" for v, k in kpi) + "</div>")
    add(
        '<p class="note" id="no-truth">No accuracy, error over time, trajectories against the '
        f"truth, occlusion or plausibility sections: {_e(report.get('why_no_truth'))}.</p>"
    )
    parts += _session_sections(facts, ground_track)

    add('<h2 id="consistency">Consistency</h2>')
    if agree:
        add("<h3>Sensor against sensor, before fusion</h3>")
        add(
            _table(
                ["pair", "as reported (mm)", "after left/right correction (mm)", "frames"],
                [
                    [
                        _e(pair),
                        _mm_pair(v["all"]),
                        _mm_pair(agree["disagreement_lr"][pair]["all"]),
                        str(v["n"]),
                    ]
                    for pair, v in agree["disagreement"].items()
                ],
            )
        )
    else:
        add('<p class="note">one sensor saw the body: there is no second view to compare</p>')
    add("<h3>Per method</h3>")
    sensors = list(r["to_sensors"])
    add(
        _table(
            ["method", "placed", "OK", "residual (mm)", "bone spread (mm)"]
            + [f"{sid} to fused (mm)" for sid in sensors],
            [
                [
                    _e(m),
                    f"{_n(report[m]['placed'], 1, 100)} %",
                    f"{_n(report[m]['status']['OK'], 1, 100)} %",
                    _mm_pair(report[m]["residual_m"]),
                    _n(report[m]["bone_sd_median_m"], 1, 1e3),
                ]
                + [_mm_pair(report[m]["to_sensors"][sid]["all"]) for sid in sensors]
                for m in methods
            ],
        )
    )
    add(
        '<p class="note">median / p95; placed: joint-frames with a position; OK: solved by the '
        "method (the other statuses are predicted, held or inferred joints); residual: the "
        "method's own (best: RMS position uncertainty of its filter; range methods: RMS range "
        "residual); bone spread: median over bones of the standard deviation of a bone's length "
        "(a rigid bone keeps its length)</p>"
    )
    add(f'<h2 id="joints">Per joint ({_e(focus)})</h2>')
    statuses = list(next(iter(r["by_joint"].values()))["status"])
    add(
        _table(
            ["joint", "placed", "residual (mm)", *statuses],
            [
                [_e(j), f"{_n(v['placed'], 1, 100)} %", _n(v["residual_median_m"], 1, 1e3)]
                + [f"{_n(v['status'][c], 1, 100)} %" for c in statuses]
                for j, v in r["by_joint"].items()
            ],
        )
    )
    add(f'<h2 id="bones">Bone lengths ({_e(focus)})</h2>')
    add(
        _table(
            ["bone", "median (mm)", "spread (mm)", "frames"],
            [
                [_e(b), _n(v["median_m"], 0, 1e3), _n(v["sd_m"], 1, 1e3), str(v["frames"])]
                for b, v in r["bones"].items()
            ],
        )
    )
    return _page(facts, parts)


def write_consistency_report(
    path: Path,
    facts: SessionFacts,
    report: dict[str, Any],
    methods: Sequence[str],
    ground_track: Array | None = None,
) -> Path:
    """Write :func:`render_consistency_report`'s ``report.html`` at ``path`` atomically."""
    from kinefuse.core.outputs import atomic_write_text

    text = render_consistency_report(facts, report, methods, ground_track)
    return atomic_write_text(path, text, what="HTML report", recognizer=is_kinefuse_report)


def is_kinefuse_report(path: Path) -> bool:
    """True if ``path`` is a report this module wrote (so it may be replaced)."""
    try:
        with Path(path).open(encoding="utf-8") as f:
            return GENERATOR in f.read(400)
    except (OSError, UnicodeDecodeError):
        return False

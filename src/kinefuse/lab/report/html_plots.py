"""The HTML report's figures: matplotlib's object API (no global backend), PNG as data URIs."""

from __future__ import annotations

import base64
import io
from collections.abc import Sequence
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from numpy.typing import NDArray

from kinefuse.capture.fusion.fusion_run import MethodResult
from kinefuse.core.skeleton import JOINT_INDEX, JOINTS
from kinefuse.lab.report_facts import SessionFacts

Array = NDArray[np.float64]

#: One colour per method everywhere in the report; the truth is black.
METHOD_COLOURS = {
    "linear": "#9aa5b1",
    "geometric": "#7b8794",
    "nonlinear": "#52606d",
    "paper": "#e8590c",
    "best": "#1971c2",
    "best-live": "#2f9e44",
}
SENSOR_COLOURS = ("#e8590c", "#9c36b5", "#0c8599", "#c2255c", "#5c940d", "#1864ab", "#d9480f")


def _colour(method: str, k: int = 0) -> str:
    return METHOD_COLOURS.get(method, f"C{k % 10}")


def data_uri(fig: Figure, *, dpi: int = 96) -> str:
    """The figure as a ``data:image/png;base64,...`` URI."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _style(ax: Any) -> None:
    ax.grid(alpha=0.3, lw=0.6)
    for side in ("top", "right"):
        ax.spines[side].set_visible(False)
    ax.tick_params(labelsize=8)


def rig_figure(facts: SessionFacts, path_xy: Array | None) -> Figure:
    """Top view of the rig: each sensor with its field of view, and the actor's path."""
    fig = Figure(figsize=(5.2, 4.6))
    ax = fig.subplots()
    half = np.radians(35.3)  # Kinect v2 depth: 70.6 deg horizontal
    for k, (sid, m) in enumerate(sorted(facts.poses.items())):
        c = m[:3, 3]
        fwd = m[:3, 2][:2]
        fwd = fwd / (np.linalg.norm(fwd) or 1.0)
        col = SENSOR_COLOURS[k % len(SENSOR_COLOURS)]
        for sgn in (-1, 1):
            rot = np.array(
                [
                    [np.cos(sgn * half), -np.sin(sgn * half)],
                    [np.sin(sgn * half), np.cos(sgn * half)],
                ]
            )
            edge = c[:2] + 2.5 * rot @ fwd
            ax.plot([c[0], edge[0]], [c[1], edge[1]], color=col, lw=0.8, alpha=0.6)
        ax.plot(*c[:2], marker="s", ms=8, color=col)
        ax.annotate(
            f"{sid}\n{c[2]:.2f} m",
            (float(c[0]), float(c[1])),
            xytext=(6, 6),
            textcoords="offset points",
            fontsize=8,
            color=col,
        )
    if path_xy is not None and np.isfinite(path_xy).any():
        ax.plot(path_xy[:, 0], path_xy[:, 1], color="black", lw=1.5, label="actor (SpineBase)")
        ax.plot(*path_xy[0], "o", color="black", ms=4)
        ax.legend(fontsize=8, loc="lower right")
    ax.plot(0, 0, "+", color="grey", ms=10)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)", fontsize=9)
    ax.set_ylabel("y (m)", fontsize=9)
    ax.set_title("rig, seen from above (world frame, z up)", fontsize=10)
    _style(ax)
    return fig


def calibration_figure(rows: list[dict[str, Any]]) -> Figure:
    """Per-sensor registration residual and, with truth, position error (mm)."""
    fig = Figure(figsize=(5.2, 2.6))
    ax = fig.subplots()
    ids = [r["id"] for r in rows]
    x = np.arange(len(ids))
    has_err = "position_error_mm" in rows[0]
    w = 0.38 if has_err else 0.6
    ax.bar(
        x - (w / 2 if has_err else 0),
        [r["residual_mm"] for r in rows],
        w,
        label="wand residual (RMS)",
        color="#1971c2",
    )
    if has_err:
        ax.bar(
            x + w / 2,
            [r["position_error_mm"] for r in rows],
            w,
            label="position error vs truth",
            color="#e8590c",
        )
    ax.set_xticks(x, ids)
    ax.set_ylabel("mm", fontsize=9)
    ax.legend(fontsize=8)
    ax.set_title("calibration quality per sensor", fontsize=10)
    _style(ax)
    return fig


def clock_figure(facts: SessionFacts) -> Figure:
    """Clock sync over time: each probe's offset around the fitted line, and the fit's error."""
    with_truth = any(c.error_ms is not None for c in facts.clocks)
    fig = Figure(figsize=(10, 3.0))
    axes = fig.subplots(1, 2 if with_truth else 1, squeeze=False)[0]
    for k, c in enumerate(facts.clocks):
        col = SENSOR_COLOURS[k % len(SENSOR_COLOURS)]
        axes[0].plot(c.t_probe_s, c.probe_residual_ms, ".", ms=2.5, color=col, label=c.sensor_id)
        if with_truth and c.error_ms is not None:
            axes[1].plot(c.t_s, c.error_ms, color=col, lw=1.3, label=c.sensor_id)
    axes[0].set_title("probe offsets around the fitted clock", fontsize=10)
    axes[0].set_ylabel("ms", fontsize=9)
    if with_truth:
        axes[1].axhline(0, color="black", lw=0.6)
        axes[1].set_title("fitted clock minus the true one", fontsize=10)
        axes[1].set_ylabel("ms", fontsize=9)
    for ax in axes:
        ax.set_xlabel("server time (s)", fontsize=9)
        ax.legend(fontsize=7, ncol=4)
        _style(ax)
    fig.tight_layout()
    return fig


def latency_figure(latency_ms: Array) -> Figure:
    fig = Figure(figsize=(5.2, 2.6))
    ax = fig.subplots()
    ax.hist(latency_ms[np.isfinite(latency_ms)], bins=40, color="#1971c2")
    p50, p99 = np.nanpercentile(latency_ms, [50, 99])
    for v, lab in ((p50, "p50"), (p99, "p99")):
        ax.axvline(v, color="black", lw=0.8, ls="--")
        ax.annotate(f"{lab} {v:.1f}", (v, ax.get_ylim()[1] * 0.9), fontsize=8)
    ax.set_xlabel("latency (ms)", fontsize=9)
    _style(ax)
    return fig


def accuracy_figure(
    methods: Sequence[str], mae_m: dict[str, float], ci_m: dict[str, tuple[float, float]]
) -> Figure:
    """MAE per method with its 95 % interval (horizontal bars, best at the bottom)."""
    fig = Figure(figsize=(5.2, 0.45 * len(methods) + 0.9))
    ax = fig.subplots()
    y = np.arange(len(methods))
    vals = np.array([100 * mae_m[m] for m in methods])
    lo = np.array([100 * ci_m[m][0] for m in methods])
    hi = np.array([100 * ci_m[m][1] for m in methods])
    ax.barh(y, vals, color=[_colour(m, k) for k, m in enumerate(methods)], height=0.6)
    ax.errorbar(vals, y, xerr=_xerr(vals, lo, hi), fmt="none", ecolor="black", capsize=3)
    for k, v in enumerate(vals):
        ax.annotate(
            f"{v:.1f}", (hi[k], y[k]), xytext=(4, -3), textcoords="offset points", fontsize=8
        )
    ax.set_yticks(y, list(methods))
    ax.invert_yaxis()
    ax.set_xlabel("mean absolute joint error (cm), 95 % interval", fontsize=9)
    _style(ax)
    return fig


def _xerr(v: Array, lo: Array, hi: Array) -> Array:
    """Error-bar lengths ``(2, n)``: a bootstrap percentile interval need not contain the
    estimate (a skewed error distribution), so a side that would be negative is drawn as 0."""
    return np.nan_to_num(np.clip(np.stack([v - lo, hi - v]), 0.0, None))


def per_joint_figure(
    methods: Sequence[str],
    by_joint: dict[str, dict[str, float]],
    ci: dict[str, tuple[Array, Array]],
) -> Figure:
    """Per-joint MAE (cm) of a few methods, one row per joint, with 95 % intervals."""
    fig = Figure(figsize=(6.2, 7.2))
    ax = fig.subplots()
    y = np.arange(len(JOINTS))
    off = np.linspace(-0.22, 0.22, len(methods)) if len(methods) > 1 else [0.0]
    for k, m in enumerate(methods):
        v = np.array([100 * by_joint[m][n] for n in JOINTS])
        lo, hi = 100 * ci[m][0], 100 * ci[m][1]
        ax.errorbar(
            v,
            y + off[k],
            xerr=_xerr(v, lo, hi),
            fmt="o",
            ms=4,
            capsize=2,
            lw=1,
            color=_colour(m, k),
            label=m,
        )
    ax.set_yticks(y, list(JOINTS), fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("mean absolute error (cm), 95 % interval", fontsize=9)
    ax.legend(fontsize=8, loc="lower right")
    _style(ax)
    return fig


def bias_noise_figure(methods: Sequence[str], report: dict[str, Any]) -> Figure:
    """Each method's error split into a fixed offset (bias) and its spread (noise)."""
    fig = Figure(figsize=(5.2, 0.45 * len(methods) + 0.9))
    ax = fig.subplots()
    y = np.arange(len(methods))
    b = np.array([100 * report[m]["bias_noise"]["bias_norm_mean_m"] for m in methods])
    n = np.array([100 * report[m]["bias_noise"]["noise_mean_m"] for m in methods])
    ax.barh(y - 0.18, b, 0.36, color="#e8590c", label="bias (mean offset per joint)")
    ax.barh(y + 0.18, n, 0.36, color="#1971c2", label="noise (spread around it)")
    ax.set_yticks(y, list(methods))
    ax.invert_yaxis()
    ax.set_xlabel("cm (mean over joints)", fontsize=9)
    ax.legend(fontsize=8)
    _style(ax)
    return fig


def error_time_figure(
    results: dict[str, MethodResult], truth: Array, methods: Sequence[str]
) -> Figure:
    """Mean joint error per frame over time, one line per method (smoothed over 0.5 s)."""

    fig = Figure(figsize=(10, 3.2))
    ax = fig.subplots()
    for k, m in enumerate(methods):
        r = results[m]
        with np.errstate(invalid="ignore"):
            e = np.nanmean(np.linalg.norm(r.positions - truth, axis=-1), axis=1) * 100
        win = 15
        ok = np.isfinite(e)
        ker = np.ones(win)
        num = np.convolve(np.where(ok, e, 0), ker, "same")
        den = np.convolve(ok.astype(float), ker, "same")
        with np.errstate(invalid="ignore", divide="ignore"):
            smooth = num / den
        strong = m in ("paper", "best", "best-live")
        ax.plot(
            r.t_server_s,
            smooth,
            color=_colour(m, k),
            lw=1.8 if strong else 0.9,
            alpha=1.0 if strong else 0.7,
            label=m,
        )
    ax.set_xlabel("server time (s)", fontsize=9)
    ax.set_ylabel("mean joint error (cm)", fontsize=9)
    ax.set_ylim(bottom=0)
    ax.legend(
        fontsize=8, ncol=len(methods), loc="lower center", bbox_to_anchor=(0.5, 1.0), frameon=False
    )
    _style(ax)
    return fig


def trajectory_figure(
    results: dict[str, MethodResult], truth: Array, methods: Sequence[str], joint: str
) -> Figure:
    """One joint's x, y, z over time against the truth (as the paper's trajectory figures)."""
    j = JOINT_INDEX[joint]
    fig = Figure(figsize=(10, 5.4))
    axes = fig.subplots(3, 1, sharex=True)
    t = next(iter(results.values())).t_server_s
    for c, axis in enumerate("xyz"):
        ax = axes[c]
        ax.plot(t, truth[:, j, c], color="black", lw=2.2, label="truth")
        for k, m in enumerate(methods):
            ax.plot(t, results[m].positions[:, j, c], color=_colour(m, k), lw=1.1, label=m)
        ax.set_ylabel(f"{axis} (m)", fontsize=9)
        _style(ax)
    axes[0].legend(fontsize=8, ncol=len(methods) + 1)
    axes[0].set_title(f"{joint}: fused trajectory against the truth", fontsize=10)
    axes[-1].set_xlabel("server time (s)", fontsize=9)
    fig.tight_layout()
    return fig


def angle_figure(
    t_s: Array, angles_deg: dict[str, Array], phase_s: tuple[float, float] | None = None
) -> Figure:
    """Joint-angle curves (degrees) over time, one panel per joint (knee, hip, elbow: left and
    right together), the range-of-motion phase shaded."""
    groups: dict[str, list[str]] = {}
    for name in angles_deg:
        groups.setdefault(name.split("_")[0], []).append(name)
    n = max(len(groups), 1)
    fig = Figure(figsize=(10, 2.4 * n))
    axes = fig.subplots(n, 1, sharex=True, squeeze=False)[:, 0]
    for ax, (joint, names) in zip(axes, sorted(groups.items()), strict=False):
        for k, name in enumerate(sorted(names)):
            ax.plot(t_s, angles_deg[name], lw=1.1, color=("#1971c2", "#e8590c")[k % 2],
                    label=name.replace("_", " "))  # fmt: skip
        if phase_s is not None:
            ax.axvspan(*phase_s, color="0.92", zorder=0)
        ax.set_ylabel(f"{joint} (deg)", fontsize=9)
        ax.legend(fontsize=8, loc="upper left")
        _style(ax)
    axes[-1].set_xlabel("server time (s); shaded: range-of-motion phase", fontsize=9)
    fig.tight_layout()
    return fig

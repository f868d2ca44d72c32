"""Evaluation of the fusion methods against the simulator's truth (issue 4's comparison).

This module reads the truth; nothing in the capture path may import it.
"""

from __future__ import annotations

import csv
import io
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.capture.fusion.best import BestOptions
from kinefuse.capture.fusion.methods import METHODS
from kinefuse.capture.fusion.status import status_counts
from kinefuse.capture.fusion.trilateration import solve_nonlinear
from kinefuse.capture.occlusion.segments import occlusion_precision_recall
from kinefuse.core.geometry.transforms import apply_transform, invert_transform
from kinefuse.core.outputs import atomic_file, atomic_write_text, never_replace, refuse_unless_ours
from kinefuse.core.skeleton import JOINT_INDEX, JOINTS, TrackingState
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.lab.metrics import bias_noise, gain, position_errors
from kinefuse.pipeline.store_inputs import (
    CalibratedSensor,
    MethodResult,
    clip_grid,
    frame_grid,
    run_method,
)

Array = NDArray[np.float64]

#: The parts of ``best`` and the option that switches each one off.
ABLATION: dict[str, BestOptions] = {
    "timestamp": BestOptions(timestamp=False),
    "covariance": BestOptions(covariance=False),
    "robust": BestOptions(robust=False),
    "lr_swap": BestOptions(lr_swap=False),
    "temporal": BestOptions(temporal=None),
    "bones": BestOptions(bones=False),
    "view": BestOptions(view_sigma_m=0.0, far_sigma_m=0.0),
    "limbs": BestOptions(limb_correlation=0.0),
}

#: Method pairs whose MAE the report compares (the paper's ordering, then ours): ``(a, b)``
#: reads "how much lower is a's MAE than b's".
COMPARISONS = (
    ("paper", "geometric"),
    ("geometric", "linear"),
    ("nonlinear", "linear"),
    ("nonlinear", "geometric"),
    ("best", "paper"),
)

ARM_JOINTS = ("ShoulderLeft", "ElbowLeft", "WristLeft", "ShoulderRight", "ElbowRight", "WristRight")
LEG_JOINTS = ("HipLeft", "KneeLeft", "AnkleLeft", "HipRight", "KneeRight", "AnkleRight")


def truth_at(store: SessionStore, t_server_s: Array) -> Array:
    """True joint positions ``(T, 25, 3)`` at server times (linear interpolation; NaN outside)."""
    t, joints, _ = store.truth().motion()
    out = np.empty((t_server_s.size, *joints.shape[1:]))
    flat = joints.reshape(len(t), -1)
    for k in range(flat.shape[1]):
        out.reshape(t_server_s.size, -1)[:, k] = np.interp(
            t_server_s, t, flat[:, k], left=np.nan, right=np.nan
        )
    return out


def _summary(res: MethodResult, truth: Array, common: NDArray[np.bool_]) -> dict[str, Any]:
    e = position_errors(res.positions, truth)
    on_common = np.where(common[..., None], res.positions, np.nan)
    c = position_errors(on_common, truth)
    return {
        "mae_m": e["mae_m"],
        "rmse_m": e["rmse_m"],
        "p95_m": e["p95_m"],
        "median_m": e["median_m"],
        "frames": e["frames"],
        "missing_fraction": e["missing_fraction"],
        "coverage": 1.0 - e["missing_fraction"],
        "mae_common_m": c["mae_m"],
        "seconds": res.seconds,
        "status": status_counts(res.status),
        "by_status": _by_status(res, truth),
        "by_joint": e["by_joint"],
        "bias_noise": bias_noise(res.positions, truth),
    }


def _by_status(res: MethodResult, truth: Array) -> dict[str, dict[str, float]]:
    """MAE and share of the joints per status code: which fused joints can be trusted."""
    from kinefuse.capture.fusion.status import FusionStatus

    err = np.linalg.norm(res.positions - truth, axis=-1)
    out = {}
    for code in np.unique(res.status):
        sel = res.status == code
        e = err[sel & np.isfinite(err)]
        out[FusionStatus(int(code)).name] = {
            "fraction": float(sel.mean()),
            "mae_m": float(e.mean()) if e.size else float("nan"),
        }
    return out


def occlusion_score(store: SessionStore, sensors: list[CalibratedSensor]) -> dict[str, float]:
    """Precision and recall of the clients' occlusion flags against ray-cast visibility."""
    occ, vis, valid = [], [], []
    truth = store.truth()
    for s in sensors:
        seq_t, _, _, visible, _ = truth.observations(s.id)
        obs = s.observations
        if not np.array_equal(seq_t, obs.seq):
            pos = {int(q): i for i, q in enumerate(seq_t)}
            take = np.array([pos[int(q)] for q in obs.seq])
            visible = visible[take]
        occ.append(s.occluded)
        vis.append(visible)
        valid.append(obs.states != TrackingState.NOT_TRACKED)
    pr = occlusion_precision_recall(np.concatenate(occ), np.concatenate(vis), np.concatenate(valid))
    return {"precision": pr.precision, "recall": pr.recall, "f1": pr.f1}


def calibration_alignment(store: SessionStore, poses: dict[str, Array]) -> tuple[Array, float]:
    """``truth2world`` (4, 4) taking the true world into a calibration's world, and the residual.

    A calibration defines its own origin and heading (the paper's puts the origin at the wand, a
    metre above the floor), so fused joints are compared with the truth after a translation and a
    rotation about the vertical fitted on the sensor poses; gravity and scale are not fitted, so
    their errors stay in the comparison.

    Returns
    -------
    truth2world : (4, 4) float
    mean_position_error_m : float
        The calibration's own mean sensor position error after that alignment.
    """
    from kinefuse.capture.calibration.compare import pose_errors

    ids = sorted(poses)
    est = np.stack([poses[i] for i in ids])
    true = np.stack([store.truth().sensor(i)[0] for i in ids])
    pe = pose_errors(est, true, align="yaw")
    return invert_transform(pe.est2true), pe.mean_position_error_m


def evaluate(
    store: SessionStore,
    sensors: list[CalibratedSensor],
    methods: tuple[str, ...] = METHODS,
    *,
    ablation: bool = True,
    truth2world: Array | None = None,
    start_s: float | None = None,
    end_s: float | None = None,
    progress: Callable[[str], None] | None = None,
) -> tuple[dict[str, Any], dict[str, MethodResult], Array]:
    """Run the methods, score them against the truth; returns (report, results, truth).

    ``truth2world`` (4, 4) maps the simulator's world into the world of the calibration in use
    when they differ by the protocol's arbitrary choices (origin, heading); see
    :func:`calibration_alignment`. The truth returned is in the calibration's world.
    ``progress(message)`` hears of each method and ablation run as it starts.
    """
    say = progress or (lambda _msg: None)
    grid = clip_grid(frame_grid(sensors), start_s, end_s)
    truth = truth_at(store, grid)
    if truth2world is not None:
        truth = apply_transform(truth2world, truth)
    keep = np.isfinite(truth).all((1, 2))
    grid, truth = grid[keep], truth[keep]
    n_runs = len(methods) + (len(ABLATION) if ablation and "best" in methods else 0)
    results = {}
    for i, m in enumerate(methods):
        say(f"fusing {grid.size} frames with {m} ({i + 1}/{n_runs})")
        results[m] = run_method(sensors, grid, m)
    # every method is also scored on the frames and joints that all of them solved
    common = np.logical_and.reduce([np.isfinite(r.positions).all(-1) for r in results.values()])
    report: dict[str, Any] = {m: _summary(r, truth, common) for m, r in results.items()}
    report["common"] = {
        "note": "mae_common_m of each method is over the frames x joints every method solved",
        "joint_fraction": float(common.mean()) if common.size else 0.0,
    }
    report["occlusion"] = occlusion_score(store, sensors)
    report["comparisons"] = {
        f"{a} vs {b}": gain(results[a].positions, results[b].positions, truth)
        for a, b in COMPARISONS
        if a in results and b in results
    }
    if ablation and "best" in results:
        abl = {}
        for i, (part, off) in enumerate(ABLATION.items()):
            say(f"ablation of best without {part} ({len(methods) + i + 1}/{n_runs})")
            r = run_method(sensors, grid, "best", best_options=off)
            abl[part] = {
                "mae_without_m": position_errors(r.positions, truth)["mae_m"],
                **gain(results["best"].positions, r.positions, truth),
            }
        report["ablation"] = abl
    report["frames"] = int(grid.size)
    report["sensors"] = [s.id for s in sensors]
    return report, results, truth


# ------------------------------------------------------------------------------------------
# paper-style tables


def _md_table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def _write_table(out_dir: Path, name: str, header: list[str], rows: list[list[str]]) -> None:
    """``name.csv`` and ``name.md``, each new (an existing file is refused), written atomically."""
    buf = io.StringIO(newline="")
    w = csv.writer(buf)
    w.writerow(header)
    w.writerows(rows)
    files = {
        out_dir / f"{name}.csv": buf.getvalue(),
        out_dir / f"{name}.md": _md_table(header, rows),
    }
    for path in files:  # both refused before either is written
        refuse_unless_ours(path, never_replace, "table")
    for path, text in files.items():
        atomic_write_text(path, text, what="table", recognizer=never_replace)


def table_c_threshold(
    sensors: list[CalibratedSensor],
    grid: Array,
    truth: Array,
    thresholds: tuple[float, ...] = (1e-1, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6),
    noise_m: tuple[float, ...] = (0.01, 0.03, 0.05),
    seed: int = 0,
) -> tuple[list[str], list[list[str]]]:
    """Table I: c_threshold vs error vs microseconds per solve, for ranges with uniform errors of
    several sizes (true geometry, true joints: the paper's synthetic setting) and for the
    session's own measurements (``paper``)."""
    rng = np.random.default_rng(seed)
    centres = np.stack([s.sensor2world[:3, 3] for s in sensors])
    pts = truth.reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(1)]
    pts = pts[rng.choice(len(pts), size=min(len(pts), 20000), replace=False)]
    true_r = np.linalg.norm(pts[:, None, :] - centres[None], axis=-1)
    header = ["c_threshold"] + [f"MAE (cm), range error +/-{n * 100:.0f} cm" for n in noise_m]
    header += ["mean iterations", "us per solve", "MAE (cm), session (paper)"]
    rows = []
    for c in thresholds:
        row = [f"{c:g}"]
        its, us = [], []
        for n in noise_m:
            r = true_r + rng.uniform(-n, n, true_r.shape)
            ref = pts + rng.normal(0, 0.05, pts.shape)  # a rough reference for the mirror side
            t0 = time.perf_counter()
            sol = solve_nonlinear(centres, r, ref, c_threshold=c)
            us.append(1e6 * (time.perf_counter() - t0) / len(pts))
            its.append(float(sol.iterations.mean()))
            row.append(f"{100 * np.nanmean(np.linalg.norm(sol.positions - pts, axis=1)):.2f}")
        res = run_method(sensors, grid, "paper", c_threshold=c)
        mae = position_errors(res.positions, truth)["mae_m"]
        row += [f"{np.mean(its):.2f}", f"{np.mean(us):.3f}", f"{100 * float(mae):.2f}"]
        rows.append(row)
    return header, rows


def table_occlusion(
    sensors: list[CalibratedSensor], grid: Array, truth: Array
) -> tuple[list[str], list[list[str]]]:
    """Table II: MAE with and without occlusion compensation, arm and leg joints."""
    on = run_method(sensors, grid, "paper")
    off = run_method(sensors, grid, "paper", occlusion_compensation=False)
    rows = []
    for label, names in (
        ("arm (shoulder, elbow, wrist)", ARM_JOINTS),
        ("leg (hip, knee, ankle)", LEG_JOINTS),
    ):
        idx = [JOINT_INDEX[n] for n in names]
        e_on = np.nanmean(np.linalg.norm(on.positions[:, idx] - truth[:, idx], axis=-1))
        e_off = np.nanmean(np.linalg.norm(off.positions[:, idx] - truth[:, idx], axis=-1))
        rows.append([label, f"{100 * e_on:.2f}", f"{100 * e_off:.2f}"])
    return ["joints", "MAE with compensation (cm)", "MAE without compensation (cm)"], rows


def table_per_joint(
    report: dict[str, Any], methods: tuple[str, ...]
) -> tuple[list[str], list[list[str]]]:
    """Table III: per-joint MAE (cm) of every method."""
    header = ["joint"] + [f"{m} (cm)" for m in methods]
    rows = []
    for name in JOINTS:
        rows.append([name] + [f"{100 * report[m]['by_joint'][name]:.2f}" for m in methods])
    rows.append(["all joints"] + [f"{100 * report[m]['mae_m']:.2f}" for m in methods])
    return header, rows


def plot_trajectories(
    results: dict[str, MethodResult],
    truth: Array,
    path: Path,
    joints: tuple[str, ...] = ("SpineBase", "WristRight", "AnkleLeft"),
) -> None:
    """Trajectories of a few joints, x/y/z over time, every method against the truth (PNG, a new
    file written atomically: an existing one is refused)."""
    from matplotlib.figure import Figure  # drawn off-screen; no global backend is changed

    t = next(iter(results.values())).t_server_s
    fig = Figure(figsize=(14, 3 * len(joints)))
    axes = fig.subplots(len(joints), 3, sharex=True)
    for r, name in enumerate(joints):
        j = JOINT_INDEX[name]
        for c, axis in enumerate("xyz"):
            ax = axes[r, c]
            ax.plot(t, truth[:, j, c], "k", lw=2, label="truth")
            for m, res in results.items():
                ax.plot(t, res.positions[:, j, c], lw=0.8, label=m)
            ax.set_title(f"{name} {axis} (m)")
            if r == len(joints) - 1:
                ax.set_xlabel("server time (s)")
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    with atomic_file(path, what="plot", recognizer=never_replace, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=90, format="png")


def write_tables(
    out_dir: Path,
    report: dict[str, Any],
    results: dict[str, MethodResult],
    sensors: list[CalibratedSensor],
    truth: Array,
    methods: tuple[str, ...],
) -> list[Path]:
    """Tables I-III (CSV and Markdown) and the trajectory plot into ``out_dir``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    grid = next(iter(results.values())).t_server_s
    written = []
    h, rows = table_c_threshold(sensors, grid, truth)
    _write_table(out_dir, "table1_c_threshold", h, rows)
    h, rows = table_occlusion(sensors, grid, truth)
    _write_table(out_dir, "table2_occlusion", h, rows)
    h, rows = table_per_joint(report, methods)
    _write_table(out_dir, "table3_per_joint", h, rows)
    for n in ("table1_c_threshold", "table2_occlusion", "table3_per_joint"):
        written += [out_dir / f"{n}.csv", out_dir / f"{n}.md"]
    plot = out_dir / "trajectories.png"
    plot_trajectories(results, truth, plot)
    written.append(plot)
    return written

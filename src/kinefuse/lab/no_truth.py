"""``kinefuse evaluate`` of a session without ground truth: what can be known without it.

A recording of real sensors (``kinefuse serve --record``, ``kinefuse track``) has no truth, so
no error can be measured. What can be measured is how the fusion behaves and how well the
sensors agree (every figure a *consistency* figure, as ``kinefuse realdata`` reports):

- **agreement** (two or more sensors with body frames): sensor vs sensor before fusion, as
  reported and after the left/right correction, and each sensor vs the fused skeleton
  (:func:`kinefuse.lab.consistency.consistency`);
- per method: the share of joints it placed, its **status** shares and its own **residuals**
  (for ``best`` the RMS position uncertainty of its filter, for the range methods the RMS range
  residual), per joint; how far each sensor is from its skeleton; and **bone-length
  stability** (a rigid bone keeps its length: the spread of each bone's length over the frames).

The sensors' poses: a calibration file, else the session's stored calibration, else the body as
the calibration object (:func:`kinefuse.lab.live_consistency.register_from_body`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.skeleton import BONES, JOINTS, bone_index_array
from kinefuse.errors import FusionError
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.pipeline.store_inputs import CalibratedSensor, MethodResult

Array = NDArray[np.float64]

#: Why the truth-only figures are absent (the text, the JSON and the report say it).
WHY_NO_TRUTH = (
    "the session has no ground truth (a recording of real sensors): accuracy, error over time, "
    "trajectories against the truth, occlusion detection and the plausibility scores need it, "
    "so every figure here is a consistency figure (sensors against each other and against the "
    "fused skeleton, the fusion's own residuals, bone-length stability), not an error"
)


class NothingToEvaluate(FusionError):
    """The session holds nothing to fuse (no sensor delivered a body frame): exit 3."""


def _summary(
    res: MethodResult, world: dict[str, tuple[Array, Array]], max_gap_s: float
) -> dict[str, Any]:
    """One method's consistency figures (see the module docstring)."""
    from kinefuse.capture.fusion.status import FusionStatus
    from kinefuse.capture.sync.assembly import interpolate
    from kinefuse.lab.consistency import distance_stats

    pos, status = res.positions, res.status
    placed: NDArray[np.bool_] = np.asarray(np.isfinite(pos).all(-1), dtype=bool)  # (T, J)
    shares = {c.name: float((status == c.value).mean()) for c in FusionStatus}
    resid = res.residual_m if res.residual_m is not None else np.full(placed.shape, np.nan)
    by_joint = {}
    for j, name in enumerate(JOINTS):
        r = resid[:, j][np.isfinite(resid[:, j])]
        by_joint[name] = {
            "placed": float(placed[:, j].mean()),
            "residual_median_m": float(np.median(r)) if r.size else None,
            "status": {c.name: float((status[:, j] == c.value).mean()) for c in FusionStatus},
        }
    r = resid[np.isfinite(resid)]
    bones_idx = bone_index_array()
    length = np.linalg.norm(pos[:, bones_idx[:, 1]] - pos[:, bones_idx[:, 0]], axis=-1)  # (T, B)
    bones = {}
    for b, (a, c) in enumerate(BONES):
        v = length[np.isfinite(length[:, b]), b]
        bones[f"{a}-{c}"] = (
            {"median_m": float(np.median(v)), "sd_m": float(np.std(v)), "frames": int(v.size)}
            if v.size > 1
            else {"median_m": None, "sd_m": None, "frames": int(v.size)}
        )
    sds = [v["sd_m"] for v in bones.values() if v["sd_m"] is not None]
    return {
        "frames": int(pos.shape[0]),
        "placed": float(placed.mean()) if placed.size else 0.0,
        "status": shares,
        "residual_m": [float(np.median(r)), float(np.quantile(r, 0.95))] if r.size else None,
        "residual_note": "RMS position uncertainty of the filter"
        if res.method.startswith("best")
        else "RMS range residual of the solution",
        "by_joint": by_joint,
        "bones": bones,
        "bone_sd_median_m": float(np.median(sds)) if sds else None,
        "to_sensors": {
            sid: distance_stats(
                np.linalg.norm(
                    interpolate(t, p, res.t_server_s, max_gap_s=max_gap_s) - pos, axis=-1
                )
            )
            for sid, (t, p) in world.items()
        },
        "seconds": res.seconds,
    }


def evaluate_without_truth(
    store: SessionStore,
    methods: Sequence[str],
    *,
    calibration: Path | None,
    start_s: float | None = None,
    end_s: float | None = None,
    progress: Callable[[str], None] | None = None,
    max_gap_s: float = 0.1,
) -> tuple[dict[str, Any], dict[str, MethodResult], list[CalibratedSensor], dict[str, Array], str]:
    """Consistency figures of every method on a session without truth (``store`` open).

    Returns
    -------
    report : dict
        JSON-ready: ``truth`` (False), ``why_no_truth``, ``frames``, ``sensors_with_body``,
        ``registration`` (how the poses were found), ``agreement`` (the figures of
        :func:`kinefuse.lab.consistency.consistency`, or None with one sensor), and per
        method ``{"placed", "status", "residual_m": [median, p95], "by_joint", "bones",
        "bone_sd_median_m", "to_sensors", ...}``; ``left_out`` and ``notes`` of the screen.
    results : dict
        Per method, its :class:`MethodResult`.
    sensors : list of CalibratedSensor
    poses : dict
        ``sensor id -> sensor2world`` in use.
    source : str
        Where the poses came from.

    Raises
    ------
    NothingToEvaluate
        No sensor delivered a body frame.
    """
    from kinefuse.core.geometry.transforms import apply_transform
    from kinefuse.lab.consistency import consistency
    from kinefuse.lab.live_consistency import distinct_frames, register_from_body
    from kinefuse.lab.poses import resolve_poses
    from kinefuse.pipeline.store_inputs import (
        clip_grid,
        frame_grid,
        load_people,
        load_usable_sensors,
        run_method,
    )

    say = progress or (lambda _msg: None)
    infos = store.sensors()
    say("reading the sensors' streams and clocks")
    stored = any(store.calibration(n) for n in ("full", "paper", "body"))
    if calibration is not None or stored:
        poses, source = resolve_poses(store, calibration, False)
        people, per_person, screen = load_people(store, poses)  # the subject's bodies only
        sensors = per_person[people.subject]
    else:
        sensors, screen = load_usable_sensors(store, {s.id: np.eye(4) for s in infos})
    streams = {
        s.id: s.observations.take(distinct_frames(s.t_server_s, s.observations.t_device_s))
        for s in sensors
    }
    streams = {k: v for k, v in streams.items() if v.has_body.any()}
    if not streams:
        raise NothingToEvaluate(
            f"nothing to evaluate in {store.path}: no sensor delivered a body frame (a sensor "
            "with depth frames only needs a body tracker); `kinefuse inspect "
            f"{store.path}` says what each sensor recorded"
        )
    registration: dict[str, Any] = {"kind": "calibration", "source": None}
    if calibration is None and not stored:
        say("registering the sensors on the body (no calibration in the session)")
        ids = list(streams)
        s2w, info = register_from_body(
            {i: streams[i].t_server_s for i in ids}, {i: streams[i].joints_m for i in ids}
        )
        sensors = [replace(s, sensor2world=s2w[s.id]) for s in sensors if s.id in s2w]
        source = "the body as calibration object (no calibration in the session)"
        registration = {"kind": "body", **info}
    registration["source"] = source
    poses = {s.id: s.sensor2world for s in sensors}
    grid = clip_grid(frame_grid(sensors), start_s, end_s)
    world = {
        i: (v.t_server_s, apply_transform(poses[i], v.joints_m))
        for i, v in streams.items()
        if i in poses
    }
    agreement = None
    if len(world) >= 2:
        say(f"comparing {len(world)} sensors before and after fusion")
        ids = list(world)
        c = consistency(
            [streams[i] for i in ids], np.stack([poses[i] for i in ids]), grid, names=ids
        )
        agreement = {k: v for k, v in c.items() if not k.startswith("_")}
    results = {}
    report: dict[str, Any] = {}
    for k, m in enumerate(methods):
        say(f"fusing {grid.size} frames with {m} ({k + 1}/{len(methods)})")
        results[m] = run_method(sensors, grid, m)
        report[m] = _summary(results[m], world, max_gap_s)
    report.update(
        {
            "truth": False,
            "why_no_truth": WHY_NO_TRUTH,
            "calibration": source,
            "frames": int(grid.size),
            "sensors_with_body": sorted(world),
            "registration": registration,
            "agreement": agreement,
            "left_out": [{"id": k, "reason": v} for k, v in screen.left_out.items()],
            "notes": screen.notes(),
        }
    )
    return report, results, sensors, poses, source


def _mm(v: Sequence[float | None] | None) -> str:
    """``[median, p95]`` metres as ``"m / p mm"``, or a dash."""
    if not v or v[0] is None or v[1] is None:
        return "–"
    return f"{1e3 * v[0]:.0f} / {1e3 * v[1]:.0f} mm"


def format_consistency(report: dict[str, Any], methods: Sequence[str]) -> str:
    """A short text of :func:`evaluate_without_truth`'s report."""
    lines = [
        f"calibration: {report['calibration']}, frames: {report['frames']}, sensors with body "
        f"frames: {', '.join(report['sensors_with_body'])}",
        f"no truth: {report['why_no_truth']}",
    ]
    lines += [f"note: {n}" for n in report.get("notes", [])]
    reg = report.get("registration", {})
    for sid, r in reg.get("by_sensor", {}).items():
        lines.append(
            f"registered {sid} on the body: trunk median {1e3 * r['trunk_median_before_m']:.0f} "
            f"-> {1e3 * r['trunk_median_after_m']:.0f} mm"
        )
    agree = report.get("agreement")
    if agree:
        lines.append("\nsensor vs sensor (median / p95), as reported and after left/right swap:")
        for pair, v in agree["disagreement"].items():
            lines.append(
                f"  {pair:<24} {_mm(v['all']):>16} {_mm(agree['disagreement_lr'][pair]['all']):>16}"
            )
    else:
        lines.append("\none sensor saw the body: no second view to compare it with")
    lines.append("")
    lines.append(
        f"{'method':<10} {'placed':>7} {'OK':>6} {'residual med/p95':>18} {'bone sd':>8}  "
        "each sensor, as reported, to fused (median / p95)"
    )
    for m in methods:
        r = report[m]
        to = ", ".join(f"{k} {_mm(v['all'])}" for k, v in r["to_sensors"].items())
        sd = r["bone_sd_median_m"]
        lines.append(
            f"{m:<10} {100 * r['placed']:6.1f}% {100 * r['status']['OK']:5.1f}% "
            f"{_mm(r['residual_m']):>18} {'–' if sd is None else f'{1e3 * sd:.0f} mm':>8}  {to}"
        )
    lines.append(
        "(placed: joint-frames with a position; OK: solved by the method; residual: the method's "
        "own; bone sd: median over bones of the spread of a bone's length)"
    )
    return "\n".join(lines)


def write_consistency_csv(path: Path, report: dict[str, Any], methods: Sequence[str]) -> Path:
    """Per method and joint: share placed, share OK, median residual (written atomically)."""
    import csv
    import io

    from kinefuse.core.outputs import atomic_write_text, never_replace

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["method", "joint", "placed", "ok", "residual_median_m"])
    for m in methods:
        for joint, v in report[m]["by_joint"].items():
            res = v["residual_median_m"]
            w.writerow(
                [
                    m,
                    joint,
                    f"{v['placed']:.4f}",
                    f"{v['status']['OK']:.4f}",
                    "" if res is None else f"{res:.5f}",
                ]
            )
    return atomic_write_text(
        path, buf.getvalue(), what="consistency table", recognizer=never_replace
    )

"""The workflow of ``kinefuse realdata``: fuse a real two-Kinect KinectMultiTrack log and report
how well the sensors agree.

There is no ground truth in these recordings: every figure here is a *consistency* figure (how
far the two sensors are from each other, how far each is from the fused skeleton), not an error.

Pipeline (``docs/real_data.md`` shows the result and how to rerun it):

1. **Frames** (:func:`kinefuse.formats.kinect_multitrack.unique_frames`). Each sensor's rows are
   reduced to its distinct frames (a row repeats a sensor's latest skeleton whenever the other
   sensor triggered the log line; rows are also logged out of capture order). A frame's receive
   time is its first appearance.
2. **Clocks** (:func:`kinefuse.capture.sync.envelope.fit_clock_lower_envelope`). Receive time =
   capture + latency + non-negative jitter, so the *lower envelope* of ``t_receive`` against
   ``t_sensor`` carries the clock relation ``t_receive ~ a + b t_sensor``. Capture times on the
   receiver's clock are then ``a + b t_sensor`` (up to one constant latency). What the clocks cannot
   show, a latency that differs between the two sensors' pipelines, is measured from the trunk
   motion (:func:`kinefuse.capture.sync.envelope.residual_lag_s`) and taken off.
3. **Registration** (:mod:`kinefuse.capture.calibration.body`). KinectMultiTrack mapped every sensor
   into the reference sensor's frame by the body's initial yaw and centre. ``refine_registration``
   re-registers the other sensor rigidly onto the reference from the trunk joints at their
   aligned capture times (the body as the calibration object); the floor (``fit_foot_plane``,
   the plane of the standing feet) gives the world's up. See
   :func:`kinefuse.formats.kinect_multitrack.sensor_poses` for how each sensor's pose is
   reconstructed.
4. **Fusion** with :func:`kinefuse.capture.fusion.best.fuse_best` on a 30 Hz grid, with and without
   the left/right swap correction, and the per-joint consistency figures
   (:func:`kinefuse.lab.consistency.consistency`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.capture.calibration.body import fit_foot_plane, refine_registration, world_from_floor
from kinefuse.capture.fusion.best import BestOptions
from kinefuse.capture.sync.envelope import fit_clock_lower_envelope, residual_lag_s
from kinefuse.core.frames.observations import BodyFrames
from kinefuse.core.geometry.transforms import apply_transform, make_transform
from kinefuse.core.skeleton import JOINTS
from kinefuse.errors import InputError
from kinefuse.formats.kinect_multitrack import (
    LAYOUT_NAMES,
    LAYOUT_NOMINAL_DEG,
    SCENARIO_NAMES,
    kmt_rotation,
    read_kinect_multitrack,
    reference_sensor,
    sensor_poses,
    unique_frames,
)
from kinefuse.lab.consistency import consistency, pair_disagreement, pose_summary

Array = NDArray[np.float64]


def _grid(t_lists: Sequence[Array], hz: float) -> Array:
    lo = min(float(t.min()) for t in t_lists if t.size)
    hi = max(float(t.max()) for t in t_lists if t.size)
    n = math.floor((hi - lo) * hz + 1e-9) + 1
    return lo + np.arange(n) / hz


@dataclass(frozen=True)
class RealdataResult:
    """What ``kinefuse realdata`` made of one KinectMultiTrack log (``--json`` prints
    :meth:`as_dict`).

    Attributes
    ----------
    file : str
        The log.
    layout : str
        The sensors' layout the log names (``parallel``, ``45 degrees``, ...).
    sensors : tuple of str
        The reference sensor and the other.
    report : dict
        Every figure, JSON-ready, as :func:`fuse_multitrack` documents it (what
        :func:`format_report` writes out).
    """

    file: str
    layout: str
    sensors: tuple[str, str]
    report: dict[str, Any]

    def as_dict(self) -> dict[str, Any]:
        """JSON-able: the report."""
        return self.report


def fuse_multitrack(
    path: str | Path,
    *,
    registration: str = "refined",
    grid_hz: float = 30.0,
    other_offaxis_deg: float = 0.0,
    motion_latency: bool = True,
    options: BestOptions | None = None,
    fused: list[tuple[Array, Array]] | None = None,
) -> RealdataResult:
    """Read a two-Kinect KinectMultiTrack log, align its clocks, fuse it, and report.

    Parameters
    ----------
    path : str or Path
        A ``Study_*_Kinect_*.csv`` log with two sensors.
    registration : {"refined", "logged"}
        Fuse with the other sensor re-registered onto the reference from the trunk joints
        (:func:`refine_registration`, default) or with KinectMultiTrack's mapping as logged.
    grid_hz : float
        Rate of the fused frames, Hz.
    other_offaxis_deg : float
        Assumed horizontal angle of the body's initial centre off the non-reference sensor's
        optical axis (toward its image right), degrees; see :func:`sensor_poses`.
    motion_latency : bool
        Also estimate the sensors' relative latency (their capture-to-receive delays differ,
        e.g. by the PC each runs on) from the trunk motion (:func:`residual_lag_s`, alternated
        twice with the registration) and take it off the other sensor's capture times. Off:
        the clock fit alone, one latency for both sensors.
    options : BestOptions, optional
        Fusion options (default: ``BestOptions()``).
    fused : list, optional
        Receives the fused take: ``(t_s (T,), positions (T, 25, 3))``, every scenario on one
        uniform grid at ``grid_hz`` with NaN between them (for :func:`export_fused`).

    Returns
    -------
    RealdataResult
        Its ``report``, JSON-ready: ``file``, ``layout``, ``reference`` (sensor and how it was
        found), ``sensors``, ``clocks`` (per sensor: ``drift_ppm``, ``offset_s``, ``rate``, frames,
        duplicates, out-of-order frames, ``jitter_median_ms``, ``jitter_p95_ms``),
        ``row_pair_skew_ms`` (capture-time difference of the two skeletons the log pairs in one
        row: median, p95), ``relative_latency_ms`` (taken off the other sensor's times),
        ``residual_lag_ms`` (:func:`residual_lag_s` with receive times, with the clock fit alone,
        and after the latency correction), ``registration`` (logged and refined yaw between the
        optical axes, the correction, trunk disagreement before and after, floor tilt between
        the sensors),
        ``floor``, ``poses`` (per sensor, world position, yaw, pitch) and ``scenarios``: per
        scenario id, ``disagreement`` (before fusion, per joint ``[median_m, p95_m]``; variants
        ``receive`` = streams placed at their receive times, ``clock`` = at the clock fit's
        capture times, ``aligned`` = clock fit and relative latency (the fused timing),
        ``logged`` = aligned timing with KinectMultiTrack's mapping as logged, ``aligned_lr`` =
        aligned after the left/right correction; all but ``logged`` with the fused
        registration), ``to_fused`` and ``to_fused_no_lr`` per sensor,
        ``swaps`` per sensor, and frame counts.

    Raises
    ------
    InputError
        The file cannot be read (see :func:`read_kinect_multitrack`), does not hold exactly two
        sensors, or a parameter is out of range.
    """
    if registration not in ("refined", "logged"):
        raise InputError(f"registration must be 'refined' or 'logged', got {registration!r}")
    if not (math.isfinite(grid_hz) and grid_hz > 0):
        raise InputError(f"grid_hz must be a positive frame rate in Hz, got {grid_hz!r}")
    if not (math.isfinite(other_offaxis_deg) and abs(other_offaxis_deg) < 60.0):
        raise InputError(
            f"other_offaxis_deg must be within +-60 degrees (the Kinect's field of view), got "
            f"{other_offaxis_deg!r}"
        )
    rec = read_kinect_multitrack(path)
    if len(rec.streams) != 2:
        raise InputError(
            f"{rec.path}: holds {len(rec.streams)} sensor(s) "
            f"({', '.join(s.sensor_id for s in rec.streams)}); this report fuses exactly two"
        )
    ref_id, how = reference_sensor(path, rec)
    ref_stream = rec.stream(ref_id)
    oth_stream = next(s for s in rec.streams if s.sensor_id != ref_id)
    frames = {s.sensor_id: unique_frames(s) for s in (ref_stream, oth_stream)}
    clocks = {k: fit_clock_lower_envelope(f.t_sensor_s, f.t_receive_s) for k, f in frames.items()}
    t_cap = {k: clocks[k].affine.forward(f.t_sensor_s) for k, f in frames.items()}
    fr, fo = frames[ref_id], frames[oth_stream.sensor_id]
    oth_id = fo.sensor_id

    # registration and the sensors' relative latency, estimated in turn
    t_clock_oth = t_cap[oth_id]
    latency = 0.0
    reg = refine_registration(t_cap[ref_id], fr.joints_m, t_clock_oth, fo.joints_m)
    lag_clock = residual_lag_s(
        t_cap[ref_id], fr.joints_m, t_clock_oth, apply_transform(reg.other2ref, fo.joints_m)
    )
    if motion_latency:
        dl = lag_clock
        for _ in range(2):
            latency += dl
            reg = refine_registration(
                t_cap[ref_id], fr.joints_m, t_clock_oth - latency, fo.joints_m
            )
            dl = residual_lag_s(
                t_cap[ref_id],
                fr.joints_m,
                t_clock_oth - latency,
                apply_transform(reg.other2ref, fo.joints_m),
            )
        t_cap[oth_id] = t_clock_oth - latency
    start = fr.t_receive_s <= fr.t_receive_s.min() + 1.0
    c_ref = np.nanmean(fr.joints_m[start], axis=(0, 1))
    floor = fit_foot_plane(
        t_cap[ref_id],
        fr.joints_m,
        fallback_tilt_deg=ref_stream.tilt_deg if math.isfinite(ref_stream.tilt_deg) else 0.0,
        fallback_height_m=ref_stream.height_m if math.isfinite(ref_stream.height_m) else 1.0,
    )
    ref2world = world_from_floor(floor)
    delta = oth_stream.init_angle_rad - ref_stream.init_angle_rad
    dh = oth_stream.height_m - ref_stream.height_m
    dh = dh if math.isfinite(dh) else 0.0
    if not (math.isfinite(delta) and math.isfinite(oth_stream.init_dist_m)):
        raise InputError(
            f"{rec.path}: Skeleton_Init_Angle/Skeleton_Init_Dist are missing; the sensors' "
            "poses cannot be reconstructed without them"
        )
    common = {
        "c_ref": c_ref,
        "delta_rad": delta,
        "other_init_dist_m": oth_stream.init_dist_m,
        "ref2world": ref2world,
        "other_offaxis_deg": other_offaxis_deg,
        "height_difference_m": dh,
    }
    # one assumption for the other sensor's centre (solved with the registration that is fused);
    # the logged and refined mappings then differ only by the correction
    correction = reg.other2ref if registration == "refined" else np.eye(4)
    oth2ref, o_kmt = sensor_poses(correction=correction, **common)
    m = kmt_rotation(delta)
    oth2ref_logged = make_transform(m, o_kmt)
    oth2ref_refined = reg.other2ref @ oth2ref_logged
    joints_other_sensor = (fo.joints_m - o_kmt) @ m  # = M^T (p - o): the sensor's own frame
    s2w = {ref_id: ref2world, oth_id: ref2world @ oth2ref}
    joints_sensor = {ref_id: fr.joints_m, oth_id: joints_other_sensor}

    # floor of the other sensor's joints (mapped), before and after the correction
    fo_floor = fit_foot_plane(t_cap[oth_id], fo.joints_m)
    up_logged = fo_floor.up
    up_refined = reg.other2ref[:3, :3] @ fo_floor.up

    def tilt_between(u: Array) -> float | None:
        if fo_floor.n_samples == 0 or floor.n_samples == 0:
            return None
        return float(np.degrees(np.arccos(np.clip(u @ floor.up, -1.0, 1.0))))

    def optical_yaw(o2r: Array) -> float:
        z = ref2world[:3, :3] @ o2r[:3, 2]
        return float(math.degrees(math.atan2(z[0], z[1])))

    # logged row pairs: the capture-time skew of the two skeletons that one row pairs
    skew: list[float | None] = [None, None]
    if np.array_equal(ref_stream.t_receive_s, oth_stream.t_receive_s):
        sk = np.abs(
            clocks[ref_id].affine.forward(ref_stream.t_sensor_s)
            - clocks[oth_id].affine.forward(oth_stream.t_sensor_s)
        )
        skew = [float(np.median(sk)) * 1e3, float(np.quantile(sk, 0.95)) * 1e3]

    opt = BestOptions() if options is None else options
    streams_all = {
        k: BodyFrames.on_server_clock(t_cap[k], joints_sensor[k], sensor_id=k)
        for k in (ref_id, oth_id)
    }
    pw = {k: apply_transform(s2w[k], s.joints_m) for k, s in streams_all.items()}
    pw_logged_other = apply_transform(ref2world @ oth2ref_logged, joints_other_sensor)
    pw_refined_other = apply_transform(ref2world @ oth2ref_refined, joints_other_sensor)

    scen_out: dict[str, Any] = {}
    fused_parts: list[tuple[Array, Array]] = []
    for sc in rec.scenarios:
        sel = {k: frames[k].scenario == sc for k in frames}
        if not all(v.any() for v in sel.values()):
            continue
        grid = _grid([t_cap[k][sel[k]] for k in frames], grid_hz)
        sub = [streams_all[k].take(sel[k]) for k in (ref_id, oth_id)]
        poses = np.stack([s2w[ref_id], s2w[oth_id]])
        cons = consistency(sub, poses, grid, names=[ref_id, oth_id], options=opt)
        key = f"{ref_id}|{oth_id}"
        gap = opt.max_interp_gap_s
        dis = {
            "clock": pair_disagreement(
                t_cap[ref_id][sel[ref_id]],
                pw[ref_id][sel[ref_id]],
                t_clock_oth[sel[oth_id]],
                pw_refined_other[sel[oth_id]],
                grid,
                gap,
            ),
            "receive": pair_disagreement(
                fr.t_receive_s[sel[ref_id]],
                pw[ref_id][sel[ref_id]],
                fo.t_receive_s[sel[oth_id]],
                pw_refined_other[sel[oth_id]],
                _grid([fr.t_receive_s[sel[ref_id]], fo.t_receive_s[sel[oth_id]]], grid_hz),
                gap,
            ),
            "logged": pair_disagreement(
                t_cap[ref_id][sel[ref_id]],
                pw[ref_id][sel[ref_id]],
                t_cap[oth_id][sel[oth_id]],
                pw_logged_other[sel[oth_id]],
                grid,
                gap,
            ),
            "aligned": cons["disagreement"][key],
            "aligned_lr": cons["disagreement_lr"][key],
        }
        fused_parts.append((cons["_fused"].t_server_s, cons["_fused"].positions))
        scen_out[str(sc)] = {
            "name": SCENARIO_NAMES.get(int(sc), f"scenario {sc}"),
            "duration_s": float(grid[-1] - grid[0]),
            "frames": cons["frames"],
            "frames_with_body": cons["frames_with_body"],
            "fused_finite": cons["fused_finite"],
            "fused_trunk_finite": cons["fused_trunk_finite"],
            "disagreement": dis,
            "to_fused": cons["to_fused"],
            "to_fused_no_lr": cons["to_fused_no_lr"],
            "swaps": cons["swaps"],
        }

    t_rx = {k: f.t_receive_s for k, f in frames.items()}
    lag_aligned = residual_lag_s(t_cap[ref_id], pw[ref_id], t_cap[oth_id], pw_refined_other)
    lag_receive = residual_lag_s(t_rx[ref_id], pw[ref_id], t_rx[oth_id], pw_refined_other)
    if fused is not None:
        fused.append(_joined(fused_parts, grid_hz))
    layout = LAYOUT_NAMES.get(rec.kinect_config, f"config {rec.kinect_config}")
    report: dict[str, Any] = {
        "file": str(rec.path),
        "layout": layout,
        "kinect_config": rec.kinect_config,
        "reference": {"sensor": ref_id, "found_by": how},
        "sensors": [ref_id, oth_id],
        "fused_with": registration,
        "other_offaxis_deg": other_offaxis_deg,
        "clocks": {
            k: {
                "drift_ppm": clocks[k].affine.drift_ppm,
                "offset_s": clocks[k].affine.offset,
                "rate": clocks[k].affine.rate,
                "rows": frames[k].n_rows,
                "frames": frames[k].t_sensor_s.size,
                "duplicates": frames[k].n_duplicates,
                "out_of_order": frames[k].n_out_of_order,
                "envelope_frames": clocks[k].n_envelope,
                "jitter_median_ms": clocks[k].jitter_median_s * 1e3,
                "jitter_p95_ms": clocks[k].jitter_p95_s * 1e3,
            }
            for k in (ref_id, oth_id)
        },
        "row_pair_skew_ms": skew,
        "relative_latency_ms": latency * 1e3,
        "residual_lag_ms": {
            "receive": lag_receive * 1e3,
            "clock": lag_clock * 1e3,
            "aligned": lag_aligned * 1e3,
        },
        "registration": {
            "logged_yaw_deg": optical_yaw(oth2ref_logged),
            "refined_yaw_deg": optical_yaw(oth2ref_refined),
            "nominal_yaw_deg": LAYOUT_NOMINAL_DEG.get(rec.kinect_config),
            "correction_deg": reg.angle_deg,
            "correction_rotvec_deg": [float(v) for v in reg.rotvec_deg],
            "correction_translation_m": [float(v) for v in reg.other2ref[:3, 3]],
            "trunk_median_before_m": reg.trunk_median_before_m,
            "trunk_median_after_m": reg.trunk_median_after_m,
            "floor_tilt_between_logged_deg": tilt_between(up_logged),
            "floor_tilt_between_refined_deg": tilt_between(up_refined),
            "init_centre_depth_check_m": float(c_ref[2] - ref_stream.init_dist_m),
        },
        "floor": {
            "height_m": floor.height_m,
            "rms_m": floor.rms_m,
            "samples": floor.n_samples,
            "tilt_deg": float(np.degrees(np.arccos(np.clip(-floor.up[1], -1.0, 1.0)))),
        },
        "poses": {
            ref_id: pose_summary(s2w[ref_id], ref2world),
            oth_id: pose_summary(s2w[oth_id], ref2world),
        },
        "scenarios": scen_out,
    }
    return RealdataResult(
        file=str(rec.path), layout=layout, sensors=(ref_id, oth_id), report=report
    )


def _joined(parts: list[tuple[Array, Array]], hz: float) -> tuple[Array, Array]:
    """The scenarios' fused skeletons as one take on one uniform grid at ``hz`` (the exports
    have one frame rate): each frame at its nearest grid time, NaN between the scenarios."""
    if not parts:
        return np.zeros(0), np.zeros((0, len(JOINTS), 3))
    t0 = min(float(p[0][0]) for p in parts)
    t1 = max(float(p[0][-1]) for p in parts)
    n = round((t1 - t0) * hz) + 1
    pos = np.full((n, len(JOINTS), 3), np.nan)
    for t, p in parts:
        pos[np.clip(np.round((t - t0) * hz).astype(int), 0, n - 1)] = p
    return t0 + np.arange(n) / hz, pos


def export_fused(take: tuple[Array, Array], out: Path, source: str) -> tuple[Path, list[str]]:
    """Write a fused take of :func:`fuse_multitrack` (its ``fused``) to ``out`` (``.c3d``,
    ``.trc``, ``.csv`` or ``.bvh``, as ``kinefuse fuse --out``); returns the path and the
    export's notes."""
    from kinefuse.core.outputs import check_output_folder
    from kinefuse.formats.export import check_export_path, export_skeleton

    check_export_path(out)
    check_output_folder(out, "export")
    t, pos = take
    if t.size == 0:
        raise InputError(f"{source}: no scenario was fused, so there is nothing to export")
    notes: list[str] = []
    export_skeleton(out, t - t[0], pos, notes=notes)
    return out, notes


def format_summary(d: dict[str, Any]) -> str:
    """The few lines that say how a log fused: layout, registration, per scenario the fused
    frames and the sensors' median distance to the fused skeleton (mm)."""
    ref, oth = d["sensors"]
    reg = d["registration"]
    lines = [
        f"{Path(d['file']).name}: layout {d['layout']}, sensors {ref} (reference) and {oth}; "
        f"registration corrected by {reg['correction_deg']:.1f} deg, trunk disagreement "
        f"{1e3 * reg['trunk_median_before_m']:.0f} -> {1e3 * reg['trunk_median_after_m']:.0f} mm"
    ]
    for sc, s in d["scenarios"].items():
        to = s["to_fused"]
        med = [to[k]["all"][0] for k in (ref, oth)]
        dist = ", ".join(
            f"{k} {1e3 * m:.0f} mm" if m is not None else f"{k} -"
            for k, m in zip((ref, oth), med, strict=True)
        )
        lines.append(
            f"  scenario {sc} ({s['name']}): {s['duration_s']:.1f} s, fused on "
            f"{s['fused_finite']} of {s['frames_with_body']} frames with a body; sensor to fused "
            f"(median): {dist}"
        )
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# text report
# --------------------------------------------------------------------------------------------


def _mm(v: Sequence[float | None]) -> str:
    if v[0] is None or v[1] is None:
        return "-"
    return f"{1e3 * v[0]:.0f}/{1e3 * v[1]:.0f}"


def format_report(d: dict[str, Any]) -> str:
    """Plain-text report of :func:`fuse_multitrack`'s result (distances as median/p95 in mm)."""
    for k in ("file", "clocks", "registration", "scenarios", "sensors", "poses"):
        if k not in d:
            raise InputError(f"not a fuse_multitrack result: key {k!r} is missing")
    ref, oth = d["sensors"]
    short = {ref: "ref", oth: "oth"}
    reg = d["registration"]
    lines = [
        f"# {Path(d['file']).name}: layout {d['layout']}",
        f"reference sensor (frame of the log): {ref} (found by {d['reference']['found_by']}); "
        f"other: {oth}; fused with the {d['fused_with']} registration",
        "No ground truth: every figure is a consistency figure (sensor vs sensor, sensor vs "
        "fused).",
        "",
        "## Clocks (lower-envelope fit of receive time on sensor time)",
        "sensor            frames  dup  ooo  drift_ppm  jitter_med_ms  jitter_p95_ms",
    ]
    for k in d["sensors"]:
        c = d["clocks"][k]
        lines.append(
            f"{k:<16} {c['frames']:>7} {c['duplicates']:>4} {c['out_of_order']:>4} "
            f"{c['drift_ppm']:>10.1f} {c['jitter_median_ms']:>14.1f} {c['jitter_p95_ms']:>14.1f}"
        )
    sk = d["row_pair_skew_ms"]
    if sk[0] is not None:
        lines.append(
            f"capture-time skew of the two skeletons paired in one logged row: median "
            f"{sk[0]:.1f} ms, p95 {sk[1]:.1f} ms"
        )
    lag = d["residual_lag_ms"]
    lines += [
        f"lag of {oth}'s stamps from the trunk motion (0 = the times agree): receive times "
        f"{lag['receive']:+.1f} ms, clock fit {lag['clock']:+.1f} ms, after the relative "
        f"latency correction of {d['relative_latency_ms']:+.1f} ms: {lag['aligned']:+.1f} ms",
        "",
        "## Registration and poses",
        f"yaw between the optical axes: logged mapping {reg['logged_yaw_deg']:+.1f} deg, "
        f"refined {reg['refined_yaw_deg']:+.1f} deg (layout nominal "
        f"{reg['nominal_yaw_deg']} deg in magnitude)",
        f"correction {reg['correction_deg']:.1f} deg, translation "
        f"{np.round(reg['correction_translation_m'], 3).tolist()} m; trunk disagreement median "
        f"{1e3 * reg['trunk_median_before_m']:.0f} -> {1e3 * reg['trunk_median_after_m']:.0f} mm",
    ]
    if reg["floor_tilt_between_logged_deg"] is not None:
        lines.append(
            f"angle between the two sensors' foot planes: logged "
            f"{reg['floor_tilt_between_logged_deg']:.1f} deg, refined "
            f"{reg['floor_tilt_between_refined_deg']:.1f} deg (feet not used in the fit)"
        )
    lines.append(
        f"body's initial centre depth in the reference (first second) minus the logged "
        f"Skeleton_Init_Dist: {1e3 * reg['init_centre_depth_check_m']:+.0f} mm"
    )
    fl = d["floor"]
    lines.append(
        f"floor (reference's standing feet): {fl['samples']} samples, rms "
        f"{1e3 * fl['rms_m']:.1f} mm, sensor {fl['height_m']:.3f} m above it, tilt "
        f"{fl['tilt_deg']:.1f} deg"
    )
    for k in d["sensors"]:
        p = d["poses"][k]
        lines.append(
            f"pose {k}: position {np.round(p['position_m'], 3).tolist()} m, yaw "
            f"{p['yaw_deg']:+.1f} deg, pitch {p['pitch_deg']:+.1f} deg"
        )
    cols = [
        ("recv", lambda s: s["disagreement"]["receive"]),
        ("clock", lambda s: s["disagreement"]["clock"]),
        ("aligned", lambda s: s["disagreement"]["aligned"]),
        ("logged", lambda s: s["disagreement"]["logged"]),
        ("al+LR", lambda s: s["disagreement"]["aligned_lr"]),
        (f"{short[ref]}>F", lambda s: s["to_fused"][ref]),
        (f"{short[oth]}>F", lambda s: s["to_fused"][oth]),
        (f"{short[ref]}>F-", lambda s: s["to_fused_no_lr"][ref]),
        (f"{short[oth]}>F-", lambda s: s["to_fused_no_lr"][oth]),
    ]
    for sc, s in d["scenarios"].items():
        lines += [
            "",
            f"## Scenario {sc} ({s['name']}): {s['duration_s']:.1f} s, {s['frames']} frames, "
            f"{s['frames_with_body']} with a body, fused finite on {s['fused_finite']} (trunk "
            f"on {s['fused_trunk_finite']}); "
            f"L/R swaps corrected: " + ", ".join(f"{short[k]} {v}" for k, v in s["swaps"].items()),
            "distances in mm as median/p95. Before fusion, sensor vs sensor: recv = placed at "
            "receive times; clock = at the clock fit's capture times; aligned = clock fit and "
            "relative latency (the fused timing); logged = aligned, but KinectMultiTrack's "
            "mapping as logged; al+LR = aligned after the L/R correction. recv, clock, aligned "
            "and al+LR use the fused registration. After fusion: X>F = sensor X to the fused "
            "skeleton with the L/R correction, X>F- = without it.",
            f"{'joint':<14}" + "".join(f"{c:>10}" for c, _ in cols),
        ]
        for name in ("all", *JOINTS):
            row = f"{name:<14}"
            for _, get in cols:
                st = get(s)
                row += f"{_mm(st['all'] if name == 'all' else st['by_joint'][name]):>10}"
            lines.append(row)
    return "\n".join(lines)

"""Scoring the analysis of a simulated session against its truth (reads the truth tables).

The same chain (normalization, axes from the same calibration phase, angles) runs on the true
motion sampled at the fused frame times; the fused input's figures are compared with it:

* ``angle_rmse_deg``: RMSE of each named angle, fused vs true-motion chain, over the frames after
  the calibration phase (all frames when the phase covers the input); for sessions also over
  the frames in which the limb was tracked by a sensor (``angle_rmse_tracked_deg``) and by two
  or more (``angle_rmse_seen_deg``), each with its share of the frames (``_seen_rmse``).
* ``segment_angle_rmse_deg``: the included angle at the knees and elbows straight from the
  joint positions (no axes, no rest), fused vs true: how far the positions alone already are
  from the truth, a floor under ``angle_rmse_deg`` of flexion angles.
* ``twist_error_deg``: absolute twist difference (wrapped to +-180 deg), fused vs true-motion
  chain, over every limb and frame where both are observable, during the calibration phase.
* ``axis_error_deg`` (Direction Joining) and ``axis_error_by_method_deg`` (dj, pca, em side by
  side): the angle between each learned axis and the true axis of
  the range-of-motion generator (stored by ``kinefuse simulate --rom`` in the truth info
  ``rom_truth``), both in the parent limb's normalized frame; the true axes are expressed in the
  true-motion chain's frames, the learned ones in the fused chain's. Without ``rom_truth`` (a
  session without a range-of-motion phase) no axis error is reported.

Angles do not depend on where the calibration put the world's origin and heading, so no
alignment of the truth into the calibration's world is needed.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.biomech.sequence import SkeletonSequence

if TYPE_CHECKING:
    from kinefuse.pipeline.analysis_chain import AnalysisInput

Array = NDArray[np.float64]


def true_sequence(inp: AnalysisInput) -> tuple[SkeletonSequence, object | None] | None:
    """The true motion at the input's frame times, and the stored ROM truth (or None)."""
    from kinefuse.formats.store.session_store import SessionStore
    from kinefuse.lab.fusion_truth import truth_at

    with SessionStore.open(inp.path) as store:
        if not store.has_truth():
            return None
        truth = store.truth()
        p = truth_at(store, inp.seq.t_s)
        rom = truth.info("rom_truth")
    seq = SkeletonSequence.from_kinect(
        p, t_s=inp.seq.t_s, rate_hz=inp.seq.rate_hz, source=f"{inp.path} [truth]"
    )
    return seq, rom


def truth_figures(
    inp: AnalysisInput,
    res: dict[str, Any],
    phase: tuple[float, float],
    *,
    true_calibration: bool = False,
) -> dict[str, Any] | None:
    """Figures of one analysed session against its truth (None for a live recording)."""
    from kinefuse.biomech.side_consistency import angle_rmse_deg, axis_errors_deg, twist_errors_deg
    from kinefuse.pipeline.analysis_chain import analyse_sequence

    got = true_sequence(inp)
    if got is None:
        return None
    tseq, rom = got
    tres = analyse_sequence(tseq, phase)
    named, tnamed = res["named"], tres["named"]
    t = inp.seq.t_s
    after = t > phase[1]
    sel: Any = np.flatnonzero(after if after.any() else np.ones_like(after))
    report: dict[str, Any] = {
        "angle_rmse_deg": angle_rmse_deg(named, tnamed, sel),
        "segment_angle_rmse_deg": _segment_angle_rmse(inp.seq, tseq, sel),
        "angle_rmse_over": "frames after the calibration phase" if after.any() else "all frames",
        "truth_chain": {
            "default_pose_frame": int(tres["norm"].default_frame),
            "limb_status": tres["models"]["dj"].status,
        },
    }
    if inp.limb_sensors is not None:
        from kinefuse.pipeline.analysis_chain import SEEN_MIN_SENSORS

        rm, share = _seen_rmse(inp.limb_sensors, named, tnamed, after, SEEN_MIN_SENSORS)
        report.update({"angle_rmse_seen_deg": rm, "seen_fraction_after_phase": share})
        rm, share = _seen_rmse(inp.limb_sensors, named, tnamed, after, 1)
        report.update({"angle_rmse_tracked_deg": rm, "tracked_fraction_after_phase": share})
    if inp.static_window_s is not None and inp.anatomical is not None:
        # the anatomical angles of the true motion from the same standing phase
        from kinefuse.pipeline.analysis_chain import skeleton_anatomy

        tanat, _ = skeleton_anatomy(tseq, tres["norm"], inp.static_window_s)
        report["anatomical_rmse_deg"] = angle_rmse_deg(inp.anatomical, tanat, sel)
        if inp.limb_sensors is not None:  # over the frames a sensor tracked the segment
            rm, _ = _seen_rmse(inp.limb_sensors, inp.anatomical, tanat, after, 1)
            report["anatomical_rmse_tracked_deg"] = rm
    inside: Any = np.flatnonzero((t >= phase[0]) & (t <= phase[1]))
    ang = res["angles"]
    true_axes = None
    if isinstance(rom, dict) and isinstance(rom.get("axes_parent"), dict):
        true_axes = {
            k: np.asarray(v, dtype=np.float64).reshape(-1, 3) for k, v in rom["axes_parent"].items()
        }
        by_method = {m: axis_errors_deg(model, true_axes) for m, model in res["models"].items()}
        report["axis_error_parent_frame_deg"] = {
            m: {"median": v["median"], "mean": v["mean"]} for m, v in by_method.items()
        }
        world = _axes_in_world(inp, res, rom, phase, true_calibration)
        by_world = {m: axis_errors_deg(_as_model(world[m]), _true_world(rom, inp, true_calibration))
                    for m in world}  # fmt: skip
        report["axis_error_deg"] = by_world["dj"]
        report["axis_error_by_method_deg"] = by_world
        # the generator's true twist, at the fused frame times inside the ROM phase
        t_rom = np.asarray(rom["t_s"], dtype=np.float64) + float(rom["start_server_s"])
        true_twist = {
            k: np.interp(t, t_rom, np.asarray(v, dtype=np.float64), left=np.nan, right=np.nan)
            for k, v in rom["twist_rad"].items()
        }
        report["twist_error_deg"] = twist_errors_deg(
            ang.twist, true_twist, ang.twist_weight, inside
        )
        report["twist_error_against"] = "the generator's true twist, during the ROM phase"
    else:
        report["twist_error_deg"] = twist_errors_deg(
            ang.twist, tres["angles"].twist, ang.twist_weight, inside
        )
        report["twist_error_against"] = (
            "the twist the same chain computes from the true motion (no ROM truth)"
        )
    return {"report": report, "named_true": tnamed, "true_axes": true_axes}


class _WorldModel:
    """An AxisModel look-alike holding world-frame axes (for ``axis_errors_deg``)."""

    def __init__(self, axes: dict[str, Array]) -> None:
        from types import SimpleNamespace

        self.limbs = {k: SimpleNamespace(axes=v, status="ok") for k, v in axes.items()}


def _as_model(axes: dict[str, Array]) -> Any:
    return _WorldModel(axes)


def _axes_in_world(
    inp: AnalysisInput,
    res: dict[str, Any],
    rom: dict[str, Any],
    phase: tuple[float, float],
    true_calibration: bool,
) -> dict[str, dict[str, Array]]:
    """Per method, the learned axes carried into the world by the fused parent frame at the
    start of the phase (mean over its first 0.3 s)."""
    from kinefuse.biomech.limbs import LIMB_INDEX, LIMB_PARENTS
    from kinefuse.core.geometry.rotations import chordal_mean

    t = inp.seq.t_s
    start = float(rom["start_server_s"])
    win = np.flatnonzero((t >= start) & (t <= start + 0.3))
    frames = res["norm"].frames
    out: dict[str, dict[str, Array]] = {}
    for m, model in res["models"].items():
        axes = {}
        for name, lm in model.limbs.items():
            if not lm.usable:
                continue
            par = LIMB_PARENTS[LIMB_INDEX[name]]
            r = frames[win, par]
            r = r[np.isfinite(r).all(axis=(1, 2))]
            if len(r) == 0:
                continue
            axes[name] = (chordal_mean(r) @ lm.axes.T).T
        out[m] = axes
    return out


def _true_world(
    rom: dict[str, Any], inp: AnalysisInput, true_calibration: bool
) -> dict[str, Array]:
    """The generator's world axes, rotated into the calibration's world."""
    rot = np.eye(3)
    if not true_calibration and inp.sensor_poses is not None:
        from kinefuse.formats.store.session_store import SessionStore
        from kinefuse.lab.fusion_truth import calibration_alignment

        with SessionStore.open(inp.path) as store:
            truth2world, _ = calibration_alignment(store, inp.sensor_poses)
        rot = truth2world[:3, :3]
    return {
        k: (rot @ np.asarray(v, dtype=np.float64).reshape(-1, 3).T).T
        for k, v in rom["axes_world"].items()
    }


#: The limb an anatomical angle belongs to, by the name's first word.
_ANGLE_LIMB = {"trunk": "trunk", "head": "head", "shoulder": "upper_arm", "elbow": "forearm",
               "forearm": "forearm", "hip": "thigh", "knee": "shank", "ankle": "foot"}  # fmt: skip


def _angle_limb(name: str) -> str:
    kind = _ANGLE_LIMB.get(name.split("_", 1)[0], "")
    side = name.rsplit("_", 1)[-1]
    return f"{kind}_{side}" if side in ("left", "right") else kind


def _seen_rmse(
    counts: NDArray[np.int64],
    named: dict[str, Array],
    tnamed: dict[str, Array],
    after: NDArray[np.bool_],
    min_sensors: int,
) -> tuple[dict[str, float], dict[str, float]]:
    """Each angle's RMSE over the frames after the phase in which its limb and the limb's
    parent were tracked (both joints ``TRACKED``) by ``min_sensors`` or more sensors, and the
    share of those frames among the frames after the phase (per angle).

    With 1 (``angle_rmse_tracked_deg``, ``tracked_fraction_after_phase``): the frames the fusion
    had a measurement of the limb for; the others are what it guesses where no sensor tracks
    the limb (outside every sensor's view), not the analysis's error. With
    :data:`~kinefuse.pipeline.analysis_chain.SEEN_MIN_SENSORS` (``angle_rmse_seen_deg``,
    ``seen_fraction_after_phase``): inside the common volume. The RMSE over every frame after
    the phase (``angle_rmse_deg``) stays in the report beside them: nothing is hidden."""
    from kinefuse.biomech.limbs import LIMB_INDEX, LIMB_PARENTS
    from kinefuse.biomech.side_consistency import angle_rmse_deg

    rmse: dict[str, float] = {}
    share: dict[str, float] = {}
    n_after = max(int(after.sum()), 1)
    for name in named:
        lname = _angle_limb(name)
        if lname not in LIMB_INDEX or name not in tnamed:
            continue
        i = LIMB_INDEX[lname]
        ok = counts[:, i] >= min_sensors
        if LIMB_PARENTS[i] >= 0:
            ok &= counts[:, LIMB_PARENTS[i]] >= min_sensors
        sel: Any = np.flatnonzero(after & ok)
        share[name] = float(sel.size / n_after)
        rmse.update(angle_rmse_deg({name: named[name]}, {name: tnamed[name]}, sel))
    return rmse, share


def _segment_angle_rmse(
    seq: SkeletonSequence, tseq: SkeletonSequence, frames: Any
) -> dict[str, float]:
    """RMSE (degrees) of the included knee and elbow angles from positions, fused vs truth."""
    from kinefuse.pipeline.analysis_chain import hinge_angle_deg as included

    p, q = seq.kinect_positions(), tseq.kinect_positions()
    out = {}
    for side in ("Left", "Right"):
        for name, (a, b, c) in (
            ("knee", ("Hip", "Knee", "Ankle")),
            ("elbow", ("Shoulder", "Elbow", "Wrist")),
        ):
            d = included(p, a + side, b + side, c + side) - included(
                q, a + side, b + side, c + side
            )
            d = d[frames]
            d = d[np.isfinite(d)]
            out[f"{name}_{side.lower()}"] = (
                float(np.sqrt(np.mean(d**2))) if d.size else float("nan")
            )
    return out

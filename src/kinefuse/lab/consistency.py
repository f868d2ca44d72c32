"""How well sensors agree with each other and with their fused skeleton, where there is no truth.

Every figure here is a *consistency* figure (how far two sensors are from each other, how far
each is from the fused skeleton), not an error: the real recordings (``docs/real_data.md``) have
no ground truth. Distances are summarized per joint and overall as ``[median_m, p95_m]``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.capture.fusion.best import BestOptions, check_streams, correct_swaps, fuse_best
from kinefuse.capture.sync.assembly import interpolate
from kinefuse.core.frames.observations import BodyFrames
from kinefuse.core.geometry.transforms import apply_transform
from kinefuse.core.skeleton import JOINT_INDEX, JOINTS, MIRROR_INDEX, TRUNK_JOINTS
from kinefuse.errors import InputError

Array = NDArray[np.float64]

_TRUNK = np.array([JOINT_INDEX[n] for n in TRUNK_JOINTS])


def distance_stats(d: Array) -> dict[str, Any]:
    """Per-joint and overall median and p95 of distances ``(T, J)`` (NaN ignored)."""
    ok = np.isfinite(d)
    per = []
    for j in range(d.shape[1]):
        v = d[ok[:, j], j]
        per.append([float(np.median(v)), float(np.quantile(v, 0.95))] if v.size else [None, None])
    v = d[ok]
    return {
        "all": [float(np.median(v)), float(np.quantile(v, 0.95))] if v.size else [None, None],
        "by_joint": dict(zip(JOINTS, per, strict=True)),
        "n": int(ok.any(axis=1).sum()),
    }


def consistency(
    streams: Sequence[BodyFrames],
    sensor2world: ArrayLike,
    t_grid_s: ArrayLike,
    *,
    names: Sequence[str] | None = None,
    options: BestOptions | None = None,
    max_gap_s: float = 0.1,
) -> dict[str, Any]:
    """Per-joint consistency of S sensors before and after fusion, on a frame grid.

    Parameters
    ----------
    streams : list of BodyFrames
        Capture times on one clock (``t_server_s``), joints in each sensor's frame.
    sensor2world : (S, 4, 4) float
        The sensors' poses.
    t_grid_s : (T,) float
        Frame times, seconds.
    names : list of str, optional
        Sensor names (default ``"0"``, ``"1"``, ...).
    options : BestOptions, optional
        Fusion options (default ``BestOptions()``); the run without the left/right correction
        uses the same options with ``lr_swap=False``.
    max_gap_s : float
        Interpolation gap limit for the before-fusion comparison, seconds.

    Returns
    -------
    dict
        ``"disagreement"`` and ``"disagreement_lr"``: per sensor pair ``"a|b"``, the distance
        between the two sensors' joints on the grid before fusion, as reported and after the
        left/right correction (``{"all": [median_m, p95_m], "by_joint": {name: [median_m,
        p95_m]}, "n": frames}``); ``"to_fused"`` and ``"to_fused_no_lr"``: per sensor, its
        distance to the fused skeleton with the correction (its observations as corrected) and
        without it (as reported); ``"swaps"``: per sensor, observations mirrored;
        ``"frames"``, ``"frames_with_body"``, ``"fused_finite"`` (frames with a body whose fused
        skeleton is finite for every joint), ``"fused_trunk_finite"`` (the same for the trunk
        joints); and, not JSON, ``"_fused"`` and ``"_fused_no_lr"``,
        the :class:`FusedSkeleton` results.
    """
    if len(streams) < 2:
        raise InputError(f"consistency needs at least 2 sensor streams, got {len(streams)}")
    grid = np.asarray(t_grid_s, dtype=np.float64)
    if grid.ndim != 1 or grid.size == 0 or not np.isfinite(grid).all():
        raise InputError(f"t_grid_s must be a non-empty finite 1-D array, got shape {grid.shape}")
    labels = [str(i) for i in range(len(streams))] if names is None else [str(n) for n in names]
    if len(labels) != len(streams):
        raise InputError(f"{len(labels)} names for {len(streams)} streams; give one per stream")
    opt = BestOptions() if options is None else options
    opt_on, opt_off = replace(opt, lr_swap=True), replace(opt, lr_swap=False)
    poses = check_streams(streams, sensor2world, "consistency")
    t_obs = [s.t_server_s for s in streams]
    p_world = [apply_transform(pose, s.joints_m) for s, pose in zip(streams, poses, strict=True)]
    sensor_pos = poses[:, :3, 3]
    flags = correct_swaps(t_obs, [p.copy() for p in p_world], sensor_pos)
    mirror = np.asarray(MIRROR_INDEX)
    p_corr = []
    for p, fl in zip(p_world, flags, strict=True):
        q = p.copy()
        q[fl] = q[fl][:, mirror]
        p_corr.append(q)
    raw = [
        interpolate(t, p, grid, max_gap_s=max_gap_s) for t, p in zip(t_obs, p_world, strict=True)
    ]
    cor = [interpolate(t, p, grid, max_gap_s=max_gap_s) for t, p in zip(t_obs, p_corr, strict=True)]
    fused_on = fuse_best(streams, poses, grid, opt_on)
    fused_off = fuse_best(streams, poses, grid, opt_off)
    out: dict[str, Any] = {"disagreement": {}, "disagreement_lr": {}}
    for a in range(len(streams)):
        for b in range(a + 1, len(streams)):
            key = f"{labels[a]}|{labels[b]}"
            out["disagreement"][key] = distance_stats(np.linalg.norm(raw[a] - raw[b], axis=-1))
            out["disagreement_lr"][key] = distance_stats(np.linalg.norm(cor[a] - cor[b], axis=-1))
    out["to_fused"] = {
        n: distance_stats(np.linalg.norm(c - fused_on.positions, axis=-1))
        for n, c in zip(labels, cor, strict=True)
    }
    out["to_fused_no_lr"] = {
        n: distance_stats(np.linalg.norm(r - fused_off.positions, axis=-1))
        for n, r in zip(labels, raw, strict=True)
    }
    out["swaps"] = {n: int(fl.sum()) for n, fl in zip(labels, flags, strict=True)}
    body = np.zeros(grid.size, dtype=bool)
    for r in raw:
        body |= np.isfinite(r).all(-1).any(-1)
    finite: NDArray[np.bool_] = np.asarray(np.isfinite(fused_on.positions).all(-1), dtype=bool)
    out["frames"] = int(grid.size)
    out["frames_with_body"] = int(body.sum())
    out["fused_finite"] = int((finite.all(-1) & body).sum())
    out["fused_trunk_finite"] = int((finite[:, _TRUNK].all(-1) & body).sum())
    out["_fused"] = fused_on
    out["_fused_no_lr"] = fused_off
    return out


def pose_summary(s2w: Array, ref2world: Array) -> dict[str, Any]:
    """A sensor pose ``(4, 4)`` for the report: position (m), yaw of its optical axis from the
    reference's, and pitch (degrees, positive = looking up)."""
    z = s2w[:3, 2]
    zr = ref2world[:3, 2]
    yaw = math.degrees(math.atan2(z[0], z[1]) - math.atan2(zr[0], zr[1]))
    return {
        "position_m": [float(v) for v in s2w[:3, 3]],
        "yaw_deg": float(math.degrees(math.remainder(math.radians(yaw), 2 * math.pi))),
        "pitch_deg": float(math.degrees(math.asin(max(-1.0, min(1.0, z[2]))))),
    }


def pair_disagreement(
    t_a: Array, p_a: Array, t_b: Array, p_b: Array, grid: Array, max_gap_s: float
) -> dict[str, Any]:
    """:func:`distance_stats` of two streams' distance ``(T, J)`` on a grid, both interpolated
    (gap limit ``max_gap_s``); streams in one frame, times on one clock."""
    return distance_stats(
        np.linalg.norm(
            interpolate(t_a, p_a, grid, max_gap_s=max_gap_s)
            - interpolate(t_b, p_b, grid, max_gap_s=max_gap_s),
            axis=-1,
        )
    )

"""Our fusion ("best"): timestamp-aware, covariance-weighted, robust, swap-correcting, smoothed.

Each part can be switched off (:class:`BestOptions`) so that its gain can be measured:

``timestamp``
    Every observation is placed at its capture time on the server clock and each sensor's stream
    is interpolated to the common frame times. Off: the paper's frame assembly (each sensor's
    latest observation in the frame window, whatever its age).
``covariance``
    Each sensor's joint is a full 3D measurement weighted by its covariance: depth noise along the
    sensor's ray, lateral noise across it, inflated for ``INFERRED`` joints and joints the client
    flagged as occluded. Off: every measurement gets the same isotropic weight.
``robust``
    Measurements that disagree with the others beyond a chi-square gate are down-weighted
    (iteratively reweighted least squares with Huber weights on the Mahalanobis distance).
    Off: plain weighted mean.
``limb_correlation``
    A sensor gets a limb's joints wrong together (it regresses them from the same depth
    pixels): each limb's joints are solved in one generalised least squares, one sensor's
    errors at joints ``k`` bones apart correlated by ``limb_correlation^k`` (0.5). Otherwise a
    sensor whose knee weighs less than its hip and ankle (``INFERRED``, seen from the far side)
    bends the fused leg by the difference between the sensors' displacements. 0: each joint
    on its own.
``lr_swap``
    Sensors that see the person from behind report left and right swapped. The body's facing
    is agreed frame by frame across sensors (a sensor whose reported facing points away from it
    cannot be swapped; one whose facing points toward it may be), with the fused facing so far
    and, when the views are all ambiguous and split, the walking direction (the causal vote of
    :mod:`kinefuse.capture.fusion.live`); a sensor that contradicts it is mirrored back. Off:
    observations used as reported. (:func:`correct_swaps` is a vote per second without that
    continuity, for comparing raw sensors before fusion.)
``temporal``
    ``"smoother"`` (offline, Rauch-Tung-Striebel over a constant-velocity model per joint),
    ``"filter"`` (causal Kalman filter, for live use) or ``None``.
``bones``
    Bone lengths are estimated over the session (median) and every frame is projected onto them,
    moving each end in proportion to its uncertainty. Off: no constraint.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.ndimage import uniform_filter1d

from kinefuse.capture.fusion.model import facing, rts_smooth_tape
from kinefuse.capture.fusion.options import BestOptions
from kinefuse.core.frames.observations import BodyFrames
from kinefuse.core.skeleton import JOINT_INDEX, bone_index_array

__all__ = [
    "BestOptions",
    "FusedSkeleton",
    "check_streams",
    "correct_swaps",
    "enforce_bone_lengths",
    "fuse_best",
]

Array = NDArray[np.float64]


@dataclass(frozen=True)
class FusedSkeleton:
    """Fused joints on the frame grid.

    Attributes
    ----------
    t_server_s : (T,) float
    positions : (T, 25, 3) float
        World frame; NaN where there was nothing to fuse and nothing to predict from.
    variance_m2 : (T, 25) float
        Trace of the position covariance / 3 (a per-axis variance), NaN where positions are NaN.
    n_sensors : (T, 25) int
        Sensors that contributed (after gating).
    swaps : dict
        Per sensor index, the number of frames whose measurement of that sensor the swap vote
        mirrored back.
    mirrored : (T, S) bool
        Per frame, the sensors whose skeleton the swap vote mirrored back (their left and right
        labels exchanged before the combination).
    """

    t_server_s: Array
    positions: Array
    variance_m2: Array
    n_sensors: NDArray[np.intp]
    swaps: dict[int, int]
    mirrored: NDArray[np.bool_]


def correct_swaps(
    t_server_s: list[Array], p_world: list[Array], sensor_pos: Array, *, bin_s: float = 1 / 30
) -> list[NDArray[np.bool_]]:
    """Decide per observation whether left and right are swapped.

    Parameters
    ----------
    t_server_s : list of (N_s,) float
    p_world : list of (N_s, 25, 3) float
    sensor_pos : (S, 3) float

    Returns
    -------
    swapped : list of (N_s,) bool
    """
    n_s = len(p_world)
    t_all = np.concatenate(t_server_s)
    if t_all.size == 0 or n_s < 2:
        return [np.zeros(len(t), bool) for t in t_server_s]
    t0 = t_all.min()
    n_bins = int((t_all.max() - t0) / bin_s) + 1
    facing_ = [facing(p) for p in p_world]
    # direction from the body to the sensor, horizontal
    toward = []
    for s in range(n_s):
        trunk = p_world[s][:, [JOINT_INDEX["SpineBase"], JOINT_INDEX["SpineShoulder"]]]
        c = np.where(np.isfinite(trunk).all(-1, keepdims=True), trunk, 0.0).sum(1)
        n_ok = np.isfinite(trunk).all(-1).sum(1)
        with np.errstate(invalid="ignore", divide="ignore"):
            c = c / np.where(n_ok > 0, n_ok, np.nan)[:, None]
        u = sensor_pos[s] - c
        u[:, 2] = 0.0
        with np.errstate(invalid="ignore"):
            toward.append(u / np.linalg.norm(u, axis=1, keepdims=True))
    # per bin: the facing consensus. Votes: an unambiguous sensor (reported facing points away
    # from it) votes its facing with weight 1; an ambiguous one votes its facing with weight 0.5
    # and, only as a tie-breaker, nothing for the mirrored one.
    votes = np.zeros((n_bins, 3))
    for s in range(n_s):
        b = ((t_server_s[s] - t0) / bin_s).astype(np.intp)
        f = facing_[s]
        ok = np.isfinite(f).all(1) & np.isfinite(toward[s]).all(1)
        amb = np.einsum("ni,ni->n", np.nan_to_num(f), np.nan_to_num(toward[s])) > 0
        w = np.where(amb, 0.5, 1.0) * ok
        np.add.at(votes, b[ok], (np.nan_to_num(f) * w[:, None])[ok])
    # ambiguous sensors: the candidate consensus must respect that ambiguous facings could be
    # mirrored; resolve by the smoothed unambiguous evidence over a 1 s window, then per bin.
    k = max(round(1.0 / bin_s), 1)
    smooth = uniform_filter1d(votes, size=k, axis=0, mode="nearest")
    # bins with no evidence take the nearest bin's direction
    norm = np.linalg.norm(smooth, axis=1)
    have = norm > 1e-9
    if not have.any():
        return [np.zeros(len(t), bool) for t in t_server_s]
    idx = np.where(have, np.arange(n_bins), -1)
    idx = np.maximum.accumulate(idx)
    first = np.argmax(have)
    idx[idx < 0] = first
    consensus = smooth[idx] / norm[idx, None]
    out = []
    for s in range(n_s):
        b = np.clip(((t_server_s[s] - t0) / bin_s).astype(np.intp), 0, n_bins - 1)
        f = facing_[s]
        agree = np.einsum("ni,ni->n", np.nan_to_num(f), consensus[b])
        amb = np.einsum("ni,ni->n", np.nan_to_num(f), np.nan_to_num(toward[s])) > 0
        out.append((agree < 0) & amb & np.isfinite(f).all(1))
    return out


def enforce_bone_lengths(
    positions: Array, variance: Array, *, iterations: int = 3
) -> tuple[Array, Array]:
    """Project every frame onto constant bone lengths (each bone's median over the sequence).

    Each bone's two ends move along the bone in proportion to their variances.

    Returns the adjusted positions ``(T, 25, 3)`` and the lengths ``(24,)``.
    """
    bones = bone_index_array()
    x = positions.copy()
    seg = x[:, bones[:, 1]] - x[:, bones[:, 0]]
    lengths = np.nanmedian(np.linalg.norm(seg, axis=-1), axis=0)
    var = np.where(np.isfinite(variance), variance, np.inf)
    for _ in range(iterations):
        for b, (pa, ch) in enumerate(bones):
            d = x[:, ch] - x[:, pa]
            n = np.linalg.norm(d, axis=-1)
            ok = np.isfinite(n) & (n > 1e-9) & np.isfinite(lengths[b])
            if not ok.any():
                continue
            corr = np.where(ok, (n - lengths[b]) / np.where(ok, n, 1.0), 0.0)[
                :, None
            ] * np.nan_to_num(d)
            vp, vc = var[:, pa], var[:, ch]
            tot = vp + vc
            with np.errstate(invalid="ignore", divide="ignore"):
                wc = np.where(np.isfinite(tot) & (tot > 0), vc / tot, 0.5)
            wc = np.where(np.isinf(vc) & np.isfinite(vp), 1.0, wc)
            wc = np.where(np.isinf(vp) & np.isfinite(vc), 0.0, wc)
            x[:, ch] -= wc[:, None] * corr
            x[:, pa] += (1 - wc)[:, None] * corr
    return x, lengths


def check_streams(streams: Sequence[BodyFrames], sensor2world: ArrayLike, what: str) -> Array:
    """Validate S streams (capture times on the server clock) against their poses
    ``(S, 4, 4)``; returns the poses as a float array."""
    if not streams:
        raise ValueError(f"{what} needs at least one sensor stream")
    poses = np.asarray(sensor2world, dtype=np.float64)
    if poses.shape != (len(streams), 4, 4) or not np.isfinite(poses).all():
        raise ValueError(
            f"{what}: sensor2world must be finite ({len(streams)}, 4, 4), one pose per stream; "
            f"got {poses.shape}"
        )
    for s in streams:
        if not np.isfinite(s.t_server_s).all():
            raise ValueError(
                f"{what}: sensor {s.sensor_id!r} has frames without a capture time on the "
                "server clock; map its clock first (BodyFrames.on_server)"
            )
    return poses


def fuse_best(
    streams: Sequence[BodyFrames],
    sensor2world: ArrayLike,
    t_grid_s: Array,
    options: BestOptions = BestOptions(),
) -> FusedSkeleton:
    """Fuse S sensor streams into one skeleton at the frame times ``t_grid_s`` ``(T,)``.

    The replay of the causal fusion (:func:`kinefuse.capture.fusion.live.replay_streams`, with every
    observation available: an offline budget of unlimited latency; its swap vote when
    ``lr_swap``) followed by the non-causal refinements the options ask for: the
    Rauch-Tung-Striebel smoother over the filter's recorded states (``temporal="smoother"``;
    ``"filter"``: the causal filter's output; ``None``: the per-frame combination),
    session-wide bone lengths (``bones``).

    ``streams`` carry their capture times on the server clock (``t_server_s``) and are in the
    frames of their sensors, whose poses are ``sensor2world (S, 4, 4)``."""
    from kinefuse.capture.fusion.live import LiveOptions, replay_streams

    poses = check_streams(streams, sensor2world, "fuse_best")
    t_grid = np.asarray(t_grid_s, dtype=np.float64)
    opt = options
    # the swaps are the causal vote's (the facing so far, the walking direction): a consensus
    # of each second's votes alone (correct_swaps) has no continuity, and where every view is
    # ambiguous (four sensors all seeing the body obliquely) it mirrored whole seconds
    live = LiveOptions(best=replace(opt, bones=False), latency_s=np.inf)
    r = replay_streams(list(streams), poses, t_grid, live, record=opt.temporal != "filter")
    swaps = {i: int(n) for i, n in enumerate(r["mirrored"].sum(axis=0))}
    if opt.temporal == "filter":
        pos, var = r["positions"], r["variance_m2"]
    elif opt.temporal == "smoother":
        alive = np.asarray(np.isfinite(r["positions"]).all(-1))
        for k in ("positions", "variance_m2", "status", "measurement_var"):
            del r[k]  # the filter's own output, not needed any more: freed before the smoother
        dt = np.diff(t_grid, prepend=t_grid[:1])
        alive3 = np.repeat(alive[..., None], 3, axis=-1)
        pos, sxx = rts_smooth_tape(dt, r.pop("tape"), alive3)
        pos[~alive] = np.nan  # in place: the smoothed positions are ours
        var = np.where(alive, sxx.mean(-1), np.nan)
        del sxx, r["measurement"]  # (the tape's measurements)
    else:
        pos, var = r["measurement"], r["measurement_var"]
    if opt.bones:
        pos, _ = enforce_bone_lengths(pos, var)
    return FusedSkeleton(
        t_server_s=t_grid,
        positions=pos,
        variance_m2=var,
        n_sensors=r["n_sensors"].astype(np.intp),
        swaps=swaps,
        mirrored=np.asarray(r["mirrored"], dtype=bool),
    )

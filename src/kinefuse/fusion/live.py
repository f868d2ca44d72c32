"""Causal fusion (``best-live``): push observations as they arrive, ask for the skeleton at a time.

The live counterpart of :func:`kinefuse.fusion.best.fuse_best`, with the same measurement model
(covariance along and across each sensor's ray, inflated for INFERRED and occluded joints; Huber-
robust combination across sensors) but nothing that looks ahead:

- **Timestamps**: each sensor's joints at the frame time come from its own observations on the
  server clock: interpolated between the two around the frame time when both have arrived,
  else the latest one if it is recent (its covariance grows with its age).
- **Left/right swaps**: the body's facing is agreed from this frame's unambiguous sensors (a
  sensor whose reported facing points away from it cannot be swapped), the ambiguous ones at half
  weight, and the fused skeleton's facing so far; an ambiguous sensor that contradicts it is
  mirrored back. (Offline ``best`` votes over a centred 1 s window instead.)
- **Kalman filter**: one constant-velocity filter per joint and axis keeps its state between
  calls; a frame without measurements is a prediction; a joint unseen for ``max_predict_s``
  becomes missing.
- **Bone lengths**: a running robust estimate per bone from well-observed frames; once a bone has
  enough samples the output is projected onto it (the filter state is not changed).
- **Status and uncertainty** per joint: :class:`~kinefuse.fusion.status.FusionStatus`
  (``OK``, ``SINGLE_SENSOR``, ``INFERRED_ONLY``, ``BONE_LENGTH``, ``PREDICTED``, ``NO_DATA``)
  and the filter's position variance.

Determinism: the result of :meth:`LiveFusion.fuse` depends only on the calls made before it, so
a replay that pushes every observation captured up to ``T + latency_s`` before fusing frame
``T`` gives bit-identical frames for a session and for any prefix of it (:func:`replay`).
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.errors import FusionError
from kinefuse.fusion.best import BestOptions
from kinefuse.fusion.status import FusionStatus
from kinefuse.skeleton import JOINT_INDEX, MIRROR_INDEX, N_JOINTS, TrackingState, bone_index_array

Array = NDArray[np.float64]

_BONES = bone_index_array()
_MIRROR = np.asarray(MIRROR_INDEX)
_TRUNK = [JOINT_INDEX["SpineBase"], JOINT_INDEX["SpineShoulder"]]
_HIP_L, _HIP_R = JOINT_INDEX["HipLeft"], JOINT_INDEX["HipRight"]
_SH_L, _SH_R = JOINT_INDEX["ShoulderLeft"], JOINT_INDEX["ShoulderRight"]


@dataclass(frozen=True)
class LiveOptions:
    """Tuning of the causal fusion. Times in seconds."""

    #: the measurement model and the parts shared with offline ``best``
    best: BestOptions = field(default_factory=lambda: BestOptions(temporal="filter"))
    #: how long after a frame time its observations may still arrive (the latency budget): a
    #: replay pushes observations captured up to ``T + latency_s`` before fusing frame ``T``
    latency_s: float = 1.0 / 30.0
    #: the latest observation of a sensor stands for the frame time if it is at most this old
    max_hold_s: float = 0.05
    #: observations kept per sensor (enough to interpolate across the latency budget)
    buffer: int = 8
    #: weight of the fused skeleton's facing so far in the swap vote (an unambiguous sensor: 1)
    facing_prior_weight: float = 1.5
    #: samples a bone needs before the output is projected onto its running length
    bone_min_samples: int = 15
    #: relative deviation from a bone's running length beyond which a joint is ``BONE_LENGTH``
    #: (at least 3 cm)
    bone_tolerance: float = 0.2

    def __post_init__(self) -> None:
        if not self.latency_s >= 0 or not self.max_hold_s >= 0:
            raise ValueError("latency_s and max_hold_s must be >= 0")
        if self.buffer < 2:
            raise ValueError(f"buffer must keep at least 2 observations, got {self.buffer}")


@dataclass(frozen=True, eq=False)
class LiveFrame:
    """One fused frame.

    Attributes
    ----------
    t_server_s : float
    positions : (25, 3) float
        World frame, metres; NaN where ``status`` is ``NO_DATA``.
    variance_m2 : (25,) float
        Position variance per axis (mean of the filter's three), NaN with the positions.
    status : (25,) int8
        :class:`FusionStatus` codes.
    n_sensors : (25,) int
        Sensors that contributed after the robust weighting.
    """

    t_server_s: float
    positions: Array
    variance_m2: Array
    status: NDArray[np.int8]
    n_sensors: NDArray[np.intp]


class _Stream:
    """The latest observations of one sensor, in capture order."""

    def __init__(self, n: int) -> None:
        self.obs: deque[tuple[float, Array, NDArray[np.int8], NDArray[np.bool_] | None]] = deque(
            maxlen=n
        )


class LiveFusion:
    """Causal fusion of S sensors' observations (see the module docstring).

    Parameters
    ----------
    sensor2world : (S, 4, 4) float
        Calibrated pose of every sensor; sensor ``i`` is pushed as index ``i``.
    options : LiveOptions
    """

    def __init__(self, sensor2world: ArrayLike, options: LiveOptions = LiveOptions()) -> None:
        poses = np.asarray(sensor2world, dtype=np.float64)
        if poses.ndim != 3 or poses.shape[1:] != (4, 4) or not np.isfinite(poses).all():
            raise FusionError(f"sensor2world must be finite (S, 4, 4), got {poses.shape}")
        self.options = options
        self._streams = [_Stream(options.buffer) for _ in poses]
        self._sensor_pos = poses[:, :3, 3].copy()
        self._r = poses[:, :3, :3].copy()
        shape = (N_JOINTS, 3)
        self._x, self._v = np.zeros(shape), np.zeros(shape)
        self._pxx, self._pxv, self._pvv = np.zeros(shape), np.zeros(shape), np.zeros(shape)
        self._started = np.zeros(shape, bool)
        self._last_seen = np.full(shape, -np.inf)
        self._t: float | None = None
        self._facing: Array | None = None
        n_b = len(_BONES)
        self._bone_n = np.zeros(n_b, dtype=np.int64)
        self._bone_len = np.zeros(n_b)
        self._bone_var = np.zeros(n_b)

    @property
    def n_sensors(self) -> int:
        return len(self._streams)

    def set_poses(self, sensor2world: ArrayLike) -> None:
        """Switch to new sensor poses ``(S', 4, 4)`` (a live calibration finished, a sensor was
        added), keeping the filter, the bone lengths and each kept sensor's observations.

        Sensor ``i`` stays index ``i``; ``S' >= S`` (new sensors get the new indices)."""
        poses = np.asarray(sensor2world, dtype=np.float64)
        if poses.ndim != 3 or poses.shape[1:] != (4, 4) or not np.isfinite(poses).all():
            raise FusionError(f"sensor2world must be finite (S, 4, 4), got {poses.shape}")
        if len(poses) < len(self._streams):
            raise FusionError(
                f"set_poses: {len(poses)} poses for {len(self._streams)} sensors; sensors are "
                "only ever added (keep a removed one's pose)"
            )
        self._streams += [
            _Stream(self.options.buffer) for _ in range(len(poses) - len(self._streams))
        ]
        self._sensor_pos = poses[:, :3, 3].copy()
        self._r = poses[:, :3, :3].copy()

    def push(
        self,
        sensor: int,
        t_server_s: float,
        joints_sensor: ArrayLike,
        states: ArrayLike,
        occluded: ArrayLike | None = None,
    ) -> None:
        """Add one observation of sensor ``sensor``: joints ``(25, 3)`` in its frame (NaN = not
        tracked), tracking states ``(25,)``, the client's occlusion flags ``(25,)`` if any,
        captured at ``t_server_s`` on the server clock. Late observations (older than the
        sensor's latest) are put in order; ones older than the last fused frame still help
        interpolate later frames."""
        if not 0 <= sensor < len(self._streams):
            raise FusionError(f"unknown sensor index {sensor}; there are {len(self._streams)}")
        t = float(t_server_s)
        if not np.isfinite(t):
            raise FusionError(f"sensor {sensor}: capture time must be finite, got {t_server_s!r}")
        j = np.asarray(joints_sensor, dtype=np.float64).reshape(N_JOINTS, 3)
        st = np.asarray(states, dtype=np.int8).reshape(N_JOINTS)
        occ = None if occluded is None else np.asarray(occluded, dtype=bool).reshape(N_JOINTS)
        q = self._streams[sensor].obs
        item = (t, j, st, occ)
        if not q or t >= q[-1][0]:
            q.append(item)
        else:  # a late one: keep the buffer in capture order
            items = sorted([*q, item], key=lambda o: o[0])
            q.clear()
            q.extend(items[-q.maxlen :] if q.maxlen else items)

    # -- one frame -----------------------------------------------------------------------------

    def _measurements(self, t: float) -> tuple[Array, Array, NDArray[np.int8]]:
        """Every sensor's joints at ``t`` in the world, ``(S, 25, 3)``, their covariances
        ``(S, 25, 3, 3)`` and states ``(S, 25)`` (NaN / 0 where a sensor has nothing)."""
        opt = self.options
        n_s = len(self._streams)
        joints = np.full((n_s, N_JOINTS, 3), np.nan)
        states = np.zeros((n_s, N_JOINTS), dtype=np.int8)
        occ = np.zeros((n_s, N_JOINTS), dtype=bool)
        age = np.zeros(n_s)
        for i, s in enumerate(self._streams):
            if not s.obs:
                continue
            times = [o[0] for o in s.obs]
            k = bisect.bisect_right(times, t)  # obs[k-1].t <= t < obs[k].t
            if 0 < k < len(times) and times[k] - times[k - 1] <= opt.best.max_interp_gap_s:
                (ta, ja, sa, oa), (tb, jb, sb, ob) = s.obs[k - 1], s.obs[k]
                w = (t - ta) / (tb - ta) if tb > ta else 0.0
                joints[i] = ja * (1.0 - w) + jb * w
                states[i] = np.minimum(sa, sb)
                if oa is not None and ob is not None:
                    occ[i] = oa | ob
            else:
                if k > 0 and t - times[k - 1] <= opt.max_hold_s:
                    o = s.obs[k - 1]
                elif k == 0 and times[0] - t <= 0.5 / 30:
                    o = s.obs[0]  # the first observation, within half a frame
                else:
                    continue
                joints[i], states[i], age[i] = o[1], o[2], abs(t - o[0])
                if o[3] is not None:
                    occ[i] = o[3]
        cov = self._covariance(joints, states, occ)
        # a held observation: the body moved meanwhile (1 m/s a priori)
        cov += (age**2)[:, None, None, None] * np.eye(3)
        z = np.einsum("sab,sjb->sja", self._r, joints) + self._sensor_pos[:, None, :]
        return z, cov, states

    def _covariance(
        self, joints: Array, states: NDArray[np.int8], occluded: NDArray[np.bool_]
    ) -> Array:
        """World covariances ``(S, 25, 3, 3)`` of all sensors' joints at once (the model of
        :func:`kinefuse.fusion.best._measurement_cov`)."""
        opt = self.options.best
        if not opt.covariance:
            return np.broadcast_to(np.eye(3) * 0.03**2, (*joints.shape[:2], 3, 3)).copy()
        with np.errstate(invalid="ignore", divide="ignore"):
            ray = np.nan_to_num(joints / np.linalg.norm(joints, axis=-1, keepdims=True))
        inflate = np.where(states == TrackingState.INFERRED, opt.inferred_inflation, 1.0)
        inflate = inflate * np.where(occluded, opt.occluded_inflation, 1.0)
        lat2 = np.asarray(opt.lateral_m) ** 2 * inflate**2
        ax2 = np.asarray(opt.axial_m) ** 2 * inflate**2
        outer = ray[..., :, None] * ray[..., None, :]
        cov_s = lat2[..., None, None] * (np.eye(3) - outer) + ax2[..., None, None] * outer
        r = self._r
        return np.einsum("sab,sjbc,sdc->sjad", r, cov_s, r)

    def _correct_swaps(self, z: Array, cov: Array, states: NDArray[np.int8]) -> None:
        """Mirror, in place, the ambiguous sensors that contradict the facing consensus."""
        facing = _facing_fast(z)  # (S, 3)
        trunk = z[:, _TRUNK]
        n_ok = np.isfinite(trunk).all(-1).sum(1)
        with np.errstate(invalid="ignore", divide="ignore"):
            centre = np.where(np.isfinite(trunk), trunk, 0.0).sum(1) / n_ok[:, None]
            toward = self._sensor_pos - centre
            toward[:, 2] = 0.0
            toward /= np.linalg.norm(toward, axis=1, keepdims=True)
        ok = np.isfinite(facing).all(1) & np.isfinite(toward).all(1)
        if not ok.any():
            return
        amb = (np.nan_to_num(facing) * np.nan_to_num(toward)).sum(1) > 0
        w = np.where(amb, 0.5, 1.0) * ok
        vote = (np.nan_to_num(facing) * w[:, None]).sum(0)
        if self._facing is not None:
            vote = vote + self.options.facing_prior_weight * self._facing
        n = np.linalg.norm(vote)
        if n < 1e-9:
            return
        consensus = vote / n
        flip = ok & amb & ((np.nan_to_num(facing) @ consensus) < 0)
        for i in np.flatnonzero(flip):
            z[i] = z[i][_MIRROR]
            cov[i] = cov[i][_MIRROR]
            states[i] = states[i][_MIRROR]

    def _filter(self, t: float, x: Array, cov_x: Array) -> tuple[Array, Array, NDArray[np.bool_]]:
        """Predict the per-joint, per-axis constant-velocity filter to ``t`` and update it with
        the fused measurement ``x (25, 3)``; returns position, variance and which joints are
        alive (seen within ``max_predict_s``)."""
        opt = self.options.best
        d = 0.0 if self._t is None else max(t - self._t, 0.0)
        self._t = t if self._t is None else max(t, self._t)
        q = np.asarray(opt.accel_psd)[:, None]
        x_ = self._x + d * self._v
        pxx = self._pxx + 2 * d * self._pxv + d * d * self._pvv + q * d**3 / 3
        pxv = self._pxv + d * self._pvv + q * d**2 / 2
        pvv = self._pvv + q * d
        r = np.diagonal(cov_x, axis1=-2, axis2=-1)
        has = np.isfinite(x) & np.isfinite(r)
        z0 = np.where(has, x, 0.0)
        r0 = np.where(has, r, 1.0)
        init = has & ~self._started
        self._started |= has
        s = pxx + r0
        kx = np.where(has, pxx / s, 0.0)
        kv = np.where(has, pxv / s, 0.0)
        innov = z0 - x_
        x_ = x_ + kx * innov
        v = self._v + kv * innov
        pxx, pxv, pvv = (1 - kx) * pxx, (1 - kx) * pxv, pvv - kv * pxv
        self._x = np.where(init, z0, x_)
        self._v = np.where(init, 0.0, v)
        self._pxx = np.where(init, r0, pxx)
        self._pxv = np.where(init, 0.0, pxv)
        self._pvv = np.where(init, 1.0, pvv)  # 1 m/s a priori
        self._last_seen = np.where(has, t, self._last_seen)
        alive = self._started & (t - self._last_seen <= opt.max_predict_s)
        return self._x.copy(), self._pxx.mean(-1), np.asarray(alive.all(-1))

    def _bones(self, pos: Array, var: Array, good: NDArray[np.bool_]) -> tuple[Array, Array]:
        """Update the running bone lengths from well-observed joints; project onto them.

        Returns the projected positions and each joint's largest bone deviation before the
        projection, in units of the allowed one (NaN where no bone of the joint is known yet).
        """
        pa, ch = _BONES[:, 0], _BONES[:, 1]
        seg = pos[ch] - pos[pa]
        length = np.linalg.norm(seg, axis=-1)
        ok = good[pa] & good[ch] & np.isfinite(length)
        # robust running mean: innovations clipped at 3 sigma once a bone has a few samples
        n = self._bone_n
        sigma = np.sqrt(self._bone_var / np.maximum(n, 1)) + 0.01
        innov = np.where(n >= 5, np.clip(length - self._bone_len, -3 * sigma, 3 * sigma),
                         length - self._bone_len)  # fmt: skip
        upd = ok & np.isfinite(innov)
        n_new = n + upd
        step = np.where(upd, innov / np.maximum(n_new, 1), 0.0)
        self._bone_len = self._bone_len + step
        self._bone_var = self._bone_var + np.where(upd, innov * (innov - step), 0.0)
        self._bone_n = n_new
        known = self._bone_n >= self.options.bone_min_samples
        # deviation relative to the tolerance: > 1 breaks the bone (short bones, the hands' and
        # feet's, get an absolute floor of 3 cm, about their trackers' noise)
        allowed = np.maximum(self.options.bone_tolerance * self._bone_len, 0.03)
        dev_bone = np.where(known, np.abs(length - self._bone_len) / allowed, np.nan)
        dev = np.full(N_JOINTS, np.nan)
        np.fmax.at(dev, pa, dev_bone)
        np.fmax.at(dev, ch, dev_bone)
        # one Gauss-Seidel sweep over the bones from the root out, each end moving in proportion
        # to its variance; plain floats, as the sweep is sequential and the arrays tiny
        out = pos.tolist()
        vv = np.where(np.isfinite(var), var, np.inf).tolist()
        lengths = self._bone_len.tolist()
        for b in np.flatnonzero(known & np.isfinite(length) & (length > 1e-9)).tolist():
            a, c = int(pa[b]), int(ch[b])
            pa_, pc = out[a], out[c]
            d = [pc[0] - pa_[0], pc[1] - pa_[1], pc[2] - pa_[2]]
            norm = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
            if not norm > 1e-9:
                continue
            k = 1.0 - lengths[b] / norm
            va, vc = vv[a], vv[c]
            tot = va + vc
            if math.isinf(vc) and not math.isinf(va):
                wc = 1.0
            elif math.isinf(va) and not math.isinf(vc):
                wc = 0.0
            else:
                wc = vc / tot if math.isfinite(tot) and tot > 0 else 0.5
            for ax in range(3):
                corr = d[ax] * k
                pc[ax] -= wc * corr
                pa_[ax] += (1.0 - wc) * corr
        return np.array(out), dev

    def fuse(self, t_server_s: float) -> LiveFrame:
        """The skeleton at ``t_server_s`` from everything pushed so far; advances the filter.

        Frame times should not go backwards (an earlier time is fused as a prediction-free
        update at the filter's current time)."""
        t = float(t_server_s)
        z, cov, states = self._measurements(t)
        opt = self.options
        if opt.best.lr_swap and self.n_sensors > 1:
            self._correct_swaps(z, cov, states)
        x, cov_x, used = _combine(z, cov, opt.best)
        pos, var, alive = self._filter(t, x, cov_x)
        measured = np.isfinite(x).all(-1)
        present = np.isfinite(z).all(-1)  # (S, 25)
        tracked = (present & (states == TrackingState.TRACKED)).sum(0)
        status = np.full(N_JOINTS, FusionStatus.OK, dtype=np.int8)
        status[measured & (used <= 1)] = FusionStatus.SINGLE_SENSOR
        status[measured & (tracked == 0)] = FusionStatus.INFERRED_ONLY
        good = alive & measured & (used >= 2) & (tracked >= 1)
        if opt.best.bones:
            pos, dev = self._bones(pos, var, good)
            broken = measured & (dev > 1.0)
            status[broken] = np.maximum(status[broken], FusionStatus.BONE_LENGTH)
        status[~measured] = FusionStatus.PREDICTED
        status[~alive] = FusionStatus.NO_DATA
        pos = np.where(alive[:, None], pos, np.nan)
        var = np.where(alive, var, np.nan)
        f = _facing_fast(pos)
        if np.isfinite(f).all():
            self._facing = f
        return LiveFrame(t, pos, var, status, np.asarray(used, dtype=np.intp))


def _facing_fast(p: Array) -> Array:
    """:func:`kinefuse.fusion.best._facing` for ``(..., 25, 3)`` without ``np.cross``: the
    horizontal unit normal to the left-right axis of hips and shoulders (NaN: none)."""
    lr = (p[..., _HIP_L, :] - p[..., _HIP_R, :]) + (p[..., _SH_L, :] - p[..., _SH_R, :])
    f = np.stack([lr[..., 1], -lr[..., 0], np.zeros_like(lr[..., 0])], axis=-1)
    n = np.sqrt(f[..., 0] ** 2 + f[..., 1] ** 2)[..., None]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 1e-6, f / n, np.nan)


def _combine(z: Array, cov: Array, opt: BestOptions) -> tuple[Array, Array, NDArray[np.intp]]:
    """One frame of :func:`kinefuse.fusion.best._robust_combine`: ``(S, 25, 3)`` measurements
    with ``(S, 25, 3, 3)`` covariances -> fused ``(25, 3)``, its covariance and the sensors
    used; written for small arrays (batched LAPACK inverses, no per-frame batching axis)."""
    valid = np.asarray(np.isfinite(z).all(-1) & np.isfinite(cov).all((-1, -2)))  # (S, 25)
    eye = np.eye(3)
    w_mat = np.linalg.inv(np.where(valid[..., None, None], cov, eye))
    w_mat[~valid] = 0.0
    zz = np.where(valid[..., None], z, 0.0)
    wz = np.einsum("sjab,sjb->sja", w_mat, zz)  # W z per measurement
    rw = valid.astype(np.float64)
    has = np.asarray(valid.any(axis=0))
    n_iter = 4 if opt.robust else 1
    info = np.zeros((N_JOINTS, 3, 3))
    x = np.zeros((N_JOINTS, 3))
    for it in range(n_iter):
        info = np.einsum("s,sjab->jab", np.ones(len(z)), w_mat * rw[..., None, None])
        rhs = (wz * rw[..., None]).sum(axis=0)
        info[~has] = eye
        x = np.asarray(np.linalg.solve(info, rhs[..., None])[..., 0])
        if not opt.robust or it == n_iter - 1:
            break
        r = zz - x[None]
        d2 = np.einsum("sja,sjab,sjb->sj", r, w_mat, r)
        rw = valid * np.minimum(1.0, np.sqrt(opt.gate_chi2 / np.maximum(d2, 1e-12)))
        far = d2 > 4 * opt.gate_chi2
        keep_some = (valid & ~far).any(axis=0)
        rw = np.where(far & keep_some[None], 0.0, rw)
        has = np.asarray(rw.sum(axis=0) > 0)
    used = np.asarray((rw > 0.2).sum(axis=0), dtype=np.intp)
    cov_x = np.asarray(np.linalg.inv(info), dtype=np.float64)
    x[~has] = np.nan
    cov_x[~has] = np.nan
    return x, cov_x, used


def replay(
    t_server_s: list[Array],
    joints_sensor: list[Array],
    states: list[NDArray[np.int8]],
    sensor2world: ArrayLike,
    grid_s: Array,
    options: LiveOptions = LiveOptions(),
    *,
    occluded: list[NDArray[np.bool_] | None] | None = None,
) -> tuple[Array, Array, NDArray[np.int8], NDArray[np.intp]]:
    """Run :class:`LiveFusion` over recorded streams as a live server would have.

    Before frame ``T`` is fused, every observation captured up to ``T + options.latency_s`` is
    pushed, in capture order across sensors; nothing later is seen.

    Parameters
    ----------
    t_server_s, joints_sensor, states, occluded : lists over sensors
        ``(N_s,)`` capture times on the server clock, ``(N_s, 25, 3)``, ``(N_s, 25)``, and
        ``(N_s, 25)`` or None.
    sensor2world : (S, 4, 4) float
    grid_s : (T,) float
        Frame times, increasing.

    Returns
    -------
    positions (T, 25, 3), variance_m2 (T, 25), status (T, 25) int8, n_sensors (T, 25)
    """
    fusion = LiveFusion(sensor2world, options)
    occ = occluded if occluded is not None else [None] * len(t_server_s)
    events = sorted((float(t), i, k) for i, ts in enumerate(t_server_s) for k, t in enumerate(ts))
    n_t = len(grid_s)
    pos = np.full((n_t, N_JOINTS, 3), np.nan)
    var = np.full((n_t, N_JOINTS), np.nan)
    status = np.full((n_t, N_JOINTS), FusionStatus.NO_DATA, dtype=np.int8)
    used = np.zeros((n_t, N_JOINTS), dtype=np.intp)
    e = 0
    for f, t in enumerate(np.asarray(grid_s, dtype=np.float64)):
        while e < len(events) and events[e][0] <= t + options.latency_s:
            _, i, k = events[e]
            o = occ[i]
            fusion.push(i, events[e][0], joints_sensor[i][k], states[i][k],
                        None if o is None else o[k])  # fmt: skip
            e += 1
        fr = fusion.fuse(float(t))
        pos[f], var[f], status[f], used[f] = fr.positions, fr.variance_m2, fr.status, fr.n_sensors
    return pos, var, status, used

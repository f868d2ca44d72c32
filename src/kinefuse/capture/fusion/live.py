"""Causal fusion (``best-live``): push observations as they arrive, ask for the skeleton at a time.

The one fusion: offline :func:`kinefuse.capture.fusion.best.fuse_best` is its replay
(:func:`replay_streams`) plus non-causal refinements. The measurement model
(:mod:`kinefuse.capture.fusion.model`: covariance along and across each sensor's ray, inflated for
INFERRED and occluded joints; Huber-robust combination across sensors), and nothing that looks
ahead:

- **Timestamps**: each sensor's joints at the frame time come from its own observations on the
  server clock: interpolated between the two around the frame time when both have arrived,
  else the latest one if it is recent (its covariance grows with its age).
- **Left/right swaps**: the body's facing is agreed from this frame's unambiguous sensors (a
  sensor whose reported facing points away from it cannot be swapped), the ambiguous ones at half
  weight, and the filter's facing so far; an ambiguous sensor that contradicts it is mirrored
  back. When every view is ambiguous and the views do not agree (two sensors, one seeing the
  back: a tie the facing so far would freeze; a sensor that sees no trunk has no view) the
  pelvis's walking direction joins the vote (``walk_weight``, ``walk_tie``); against the facing
  so far only once the body has walked against it for ``walk_against_s`` (a turn on the spot
  moves the pelvis backwards for a moment). Agreeing ambiguous views are not overruled by it
  (two sensors in front of a person who walks backwards, in a real recording). Offline
  ``best`` replays this vote.
- **Kalman filter**: one constant-velocity filter per joint and axis keeps its state between
  calls; a frame without measurements is a prediction; a joint unseen for ``max_predict_s``
  becomes missing.
- **Bone lengths**: a running robust estimate per bone from well-observed frames; once a bone has
  enough samples the output is projected onto it (the filter state is not changed).
- **Status and uncertainty** per joint: :class:`~kinefuse.capture.fusion.status.FusionStatus`
  (``OK``, ``SINGLE_SENSOR``, ``INFERRED_ONLY``, ``BONE_LENGTH``, ``PREDICTED``, ``NO_DATA``)
  and the filter's position variance.

Determinism: the result of :meth:`LiveFusion.fuse` depends only on the calls made before it, so
a replay that pushes every observation captured up to ``T + latency_s`` before fusing frame
``T`` gives bit-identical frames for a session and for any prefix of it (:func:`replay`); the
replay prepares the measurements of many frames at once and equals pushing and fusing frame by
frame, bit for bit.

Why one module of about 680 lines: the state object and its batch replay are two drivers of the
same steps, and that bit-for-bit identity is this module's contract; the math they share lives
in :mod:`kinefuse.capture.fusion.model`, what is left here is the two drivers and their bookkeeping.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.capture.fusion.model import (
    AMBIGUOUS_WEIGHT,
    BONE_ORDER,
    BONES,
    JOINT_BONES,
    FilterTape,
    KalmanState,
    decide_flips,
    kalman_step,
    project_bones,
    robust_combine,
    sensor_at,
    swap_evidence,
    swap_vote,
    world_measurements,
)
from kinefuse.capture.fusion.options import BestOptions
from kinefuse.capture.fusion.status import FusionStatus
from kinefuse.core.frames.observations import BodyFrames
from kinefuse.core.skeleton import JOINT_INDEX, MIRROR_INDEX, N_JOINTS, TrackingState
from kinefuse.errors import FusionError

Array = NDArray[np.float64]

_MIRROR = np.asarray(MIRROR_INDEX)
#: frames whose measurements a replay prepares at once (bounds its memory)
_CHUNK = 256
#: hips and shoulders (left, right, left, right): the body's facing
_FACING_JOINTS = np.array([JOINT_INDEX[n] for n in ("HipLeft", "HipRight", "ShoulderLeft",
                                                     "ShoulderRight")])  # fmt: skip
_PELVIS = JOINT_INDEX["SpineBase"]
#: the bones' parent and child joints in the group order of the projection
_PARENTS, _CHILDREN = BONES[BONE_ORDER, 0], BONES[BONE_ORDER, 1]
_TRACKED = int(TrackingState.TRACKED)
#: the statuses as plain ints (numpy converts an enum member slowly)
_S_OK, _S_SINGLE, _S_INFERRED, _S_BONE, _S_PREDICTED, _S_NO_DATA = (
    int(v) for v in (FusionStatus.OK, FusionStatus.SINGLE_SENSOR, FusionStatus.INFERRED_ONLY,
                     FusionStatus.BONE_LENGTH, FusionStatus.PREDICTED, FusionStatus.NO_DATA)
)  # fmt: skip


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
    #: its weight while no decided vote has confirmed it: a facing taken from a tie (one
    #: ambiguous view alone, as when the body comes back into view) must not outvote two
    #: agreeing ambiguous views that arrive after it (below one ambiguous view's 0.5, so it
    #: still breaks an even tie); the facing so far is forgotten when the body is lost
    #: (hips and shoulders unseen for ``best.max_predict_s``): it says nothing of a body found
    #: again seconds later (docs/fusion.md section 11)
    unconfirmed_prior_weight: float = 0.25
    #: when every sensor's view is ambiguous, the pelvis's walking direction joins the swap vote
    #: with this weight (above the facing so far, so a wrong facing is re-decided while walking)
    #: once it moves faster than ``walk_speed_m_s`` (m/s)
    walk_weight: float = 2.0
    walk_speed_m_s: float = 0.5
    #: a walking direction against the facing so far joins the vote only once the body has
    #: walked against it this long in all (s; pauses do not count, walking with it resets): a
    #: frozen wrong facing lasts the whole walk, a body turning round on the spot moves against
    #: its facing for less than a step (0.4 s in CMU 131_01, mirrored for 0.5 s without this)
    walk_against_s: float = 0.6
    #: the walking direction joins only a tie: one ambiguous view alone, or the ambiguous
    #: sensors' vote shorter than this fraction of its largest possible length (every facing
    #: the same way)
    walk_tie: float = 0.5
    #: the most the ambiguous views together weigh in the vote (an unambiguous view: 1). Each
    #: Kinect reports a body facing it whether it sees the front or the back, so ambiguous views
    #: that agree say on which side the sensors stand, not which way the body faces: three of
    #: them behind a walking body (0.5 each) outvoted its confirmed facing (1.5) and mirrored
    #: the legs for 1.5 s (CMU 131_01 on a 5-sensor ring). Capped, they decide only against an
    #: unconfirmed facing; a confirmed one changes with side views and the walking direction.
    #: ``inf``: no cap
    ambiguous_vote_cap: float = 1.0
    #: samples a bone needs before the output is projected onto its running length
    bone_min_samples: int = 15
    #: relative deviation from a bone's running length beyond which a joint is ``BONE_LENGTH``
    #: (at least 3 cm)
    bone_tolerance: float = 0.2

    def __post_init__(self) -> None:
        if not self.latency_s >= 0 or not self.max_hold_s >= 0:
            raise ValueError("latency_s and max_hold_s must be >= 0")
        if not self.ambiguous_vote_cap > 0:
            raise ValueError(f"ambiguous_vote_cap must be > 0, got {self.ambiguous_vote_cap}")
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


class _Buffers:
    """The latest observations of every sensor, in capture order (at most ``n`` each), as
    arrays ``(S, n, ...)``; a row's unused tail holds ``inf`` times."""

    def __init__(self, n_sensors: int, n: int) -> None:
        self.t = np.full((n_sensors, n), np.inf)
        self.joints = np.full((n_sensors, n, N_JOINTS, 3), np.nan)
        self.states = np.zeros((n_sensors, n, N_JOINTS), np.int8)
        self.occ = np.zeros((n_sensors, n, N_JOINTS), bool)
        self.count = np.zeros(n_sensors, np.intp)

    def add(self, i: int, t: float, j: Array, st: NDArray[np.int8], occ: NDArray[np.bool_]) -> None:
        n = int(self.count[i])
        row = self.t[i]
        # the usual case is the newest; a late one goes in capture order
        late = n > 0 and t < row[n - 1]
        k = int(np.searchsorted(row[:n], t, side="right")) if late else n
        width = row.shape[0]
        if n == width:  # full: the oldest goes
            if k == 0:
                return  # older than everything kept
            for a in (self.t, self.joints, self.states, self.occ):
                a[i, : k - 1] = a[i, 1:k]  # (numpy copies overlapping ranges first)
            k -= 1
        else:
            for a in (self.t, self.joints, self.states, self.occ):
                a[i, k + 1 : n + 1] = a[i, k:n]
            self.count[i] = n + 1
        self.t[i, k], self.joints[i, k], self.states[i, k], self.occ[i, k] = t, j, st, occ


#: one frame's sequential part: the filter's position (25, 3) and variance (25,), alive,
#: measured, sensors used, TRACKED sensors (25,)
_Step = tuple[Array, Array, NDArray[np.bool_], NDArray[np.bool_], NDArray[np.intp], NDArray[Any]]


@dataclass(frozen=True, eq=False)
class _Guess:
    """A frame's combination prepared in a batch, for the swap decision it assumed."""

    flips: NDArray[np.bool_]
    x: Array
    cov_x: Array
    used: NDArray[np.intp]


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
        self._poses = poses.copy()
        self._buffers = _Buffers(len(poses), options.buffer)
        self._sensor_pos = poses[:, :3, 3].copy()
        b = options.best
        self._lateral = np.asarray(b.lateral_m)
        self._axial = np.asarray(b.axial_m)
        self._q = np.asarray(b.accel_psd)[:, None]
        self._kf = KalmanState.empty()
        self._t: float | None = None
        self._facing: Array | None = None
        #: whether a decided vote (an unambiguous view, agreeing ambiguous ones, the walking
        #: direction) has supported the facing so far since it was taken
        self._facing_confirmed = False
        #: how long the body has walked against the facing so far (s), and the last frame's time
        self._against_s = 0.0
        self._walk_t: float | None = None
        n_b = len(BONES)
        self._bone_n = np.zeros(n_b, dtype=np.int64)
        self._bone_len = np.zeros(n_b)
        self._bone_var = np.zeros(n_b)
        #: with ``record``, the last frame's filter step (the time step and the measurement's
        #: variances (25, 3)), for a smoother (:class:`~kinefuse.capture.fusion.model.FilterTape`)
        self.record = False
        self.last_filter_step: tuple[float, Array] | None = None
        #: the last frame's combined measurement (25, 3) and its covariance (25, 3, 3)
        self.last_measurement: tuple[Array, Array] | None = None
        #: the last frame's swap decision: the sensors mirrored back (S,), or None for none
        self.last_flips: NDArray[np.bool_] | None = None

    @property
    def n_sensors(self) -> int:
        return len(self._poses)

    def set_poses(self, sensor2world: ArrayLike) -> None:
        """Switch to new sensor poses ``(S', 4, 4)`` (a live calibration finished, a sensor was
        added), keeping the filter, the bone lengths and each kept sensor's observations.

        Sensor ``i`` stays index ``i``; ``S' >= S`` (new sensors get the new indices)."""
        poses = np.asarray(sensor2world, dtype=np.float64)
        if poses.ndim != 3 or poses.shape[1:] != (4, 4) or not np.isfinite(poses).all():
            raise FusionError(f"sensor2world must be finite (S, 4, 4), got {poses.shape}")
        n_old = self.n_sensors
        if len(poses) < n_old:
            raise FusionError(
                f"set_poses: {len(poses)} poses for {n_old} sensors; sensors are only ever added "
                "(keep a removed one's pose)"
            )
        if len(poses) > n_old:  # new sensors get empty buffer rows
            grown = _Buffers(len(poses), self.options.buffer)
            b = self._buffers
            grown.t[:n_old], grown.joints[:n_old] = b.t, b.joints
            grown.states[:n_old], grown.occ[:n_old] = b.states, b.occ
            grown.count[:n_old] = b.count
            self._buffers = grown
        self._poses = poses.copy()
        self._sensor_pos = poses[:, :3, 3].copy()

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
        if not 0 <= sensor < self.n_sensors:
            raise FusionError(f"unknown sensor index {sensor}; there are {self.n_sensors}")
        t = float(t_server_s)
        if not math.isfinite(t):
            raise FusionError(f"sensor {sensor}: capture time must be finite, got {t_server_s!r}")
        j = np.asarray(joints_sensor, dtype=np.float64).reshape(N_JOINTS, 3)
        st = np.asarray(states, dtype=np.int8).reshape(N_JOINTS)
        occ = (np.zeros(N_JOINTS, bool) if occluded is None
               else np.asarray(occluded, dtype=bool).reshape(N_JOINTS))  # fmt: skip
        self._buffers.add(sensor, t, j, st, occ)

    def fuse(self, t_server_s: float) -> LiveFrame:
        """The skeleton at ``t_server_s`` from everything pushed so far; advances the filter.

        Frame times should not go backwards (an earlier time is fused as a prediction-free
        update at the filter's current time)."""
        t = float(t_server_s)
        b = self._buffers
        joints, states, occ, age = self._at(np.array([t]), np.array([np.inf]), b.t, b.count,
                                            b.joints, b.states, b.occ)  # fmt: skip
        z, cov, evidence = self._prepare(joints, states, occ, age)
        ev = None if evidence is None else (evidence[0][0], evidence[1][0], evidence[2][0])
        return self._frame(t, z[0], cov[0], states[0], ev)

    # -- the parts of a frame ------------------------------------------------------------------

    def _at(
        self, t: Array, available: Array, times: Array, count: NDArray[np.intp], joints: Array,
        states: NDArray[np.int8], occ: NDArray[np.bool_] | None,
    ) -> tuple[Array, NDArray[np.int8], NDArray[np.bool_], Array]:  # fmt: skip
        b = self.options.best
        return sensor_at(t, available, times, count, joints, states, occ,
                         max_gap_s=b.max_interp_gap_s, max_hold_s=self.options.max_hold_s,
                         timestamp=b.timestamp)  # fmt: skip

    def _prepare(
        self, joints: Array, states: NDArray[np.int8], occ: NDArray[np.bool_], age: Array
    ) -> tuple[Array, Array, tuple[Array, NDArray[np.bool_], Array] | None]:
        """Frames' ``(T, S, ...)`` sensor joints -> world measurements, covariances and, when
        swaps are corrected, the swap evidence (facing, ambiguous, vote ``(T, 3)``)."""
        b = self.options.best
        z, cov = world_measurements(
            joints, states, occ, age, self._poses, lateral_m=self._lateral, axial_m=self._axial,
            inferred_inflation=b.inferred_inflation, occluded_inflation=b.occluded_inflation,
            covariance=b.covariance,
            view=(b.view_sigma_m, b.view_exponent, b.far_sigma_m, b.far_exponent),
        )  # fmt: skip
        if not (b.lr_swap and self.n_sensors > 1):
            return z, cov, None
        f, amb, w = swap_evidence(z, self._sensor_pos)
        return z, cov, (f, amb, swap_vote(f, w))

    def _combine(self, z: Array, cov: Array) -> tuple[Array, Array, NDArray[np.intp]]:
        b = self.options.best
        return robust_combine(
            z, cov, robust=b.robust, gate_chi2=b.gate_chi2, limb_correlation=b.limb_correlation
        )

    def _frame(
        self,
        t: float,
        z: Array,
        cov: Array,
        states: NDArray[np.int8],
        evidence: tuple[Array, NDArray[np.bool_], Array] | None,
    ) -> LiveFrame:
        """One frame: :meth:`_step` then :meth:`_finish`."""
        pos, var, alive, measured, used, tracked = self._step(t, z, cov, states, evidence)
        r = self._finish(pos[None], var[None], alive[None], measured[None], used[None],
                         tracked[None])  # fmt: skip
        return LiveFrame(t, r[0][0], r[1][0], r[2][0], r[3][0])

    def _step(
        self,
        t: float,
        z: Array,
        cov: Array,
        states: NDArray[np.int8],
        evidence: tuple[Array, NDArray[np.bool_], Array] | None,
        guess: _Guess | None = None,
    ) -> _Step:
        """The sequential part of a frame, from its measurements ``z (S, 25, 3)``, ``cov (S, 25,
        3, 3)``, ``states (S, 25)``: the swap decision (with the filter's facing so far), the
        combination (``guess``'s if it assumed the same swaps) and the filter.

        Returns the filter's position ``(25, 3)`` and variance ``(25,)``, which joints are alive
        and measured, the sensors used and the TRACKED sensors per joint ``(25,)``."""
        opt = self.options
        flips = None
        if evidence is not None:
            f, amb, vote = evidence
            dt = 0.0 if self._walk_t is None else max(t - self._walk_t, 0.0)
            self._walk_t = t
            # ``f`` is 0 where a sensor has no facing (it sees no trunk): it has no vote, so it
            # does not make the others' tie decided
            tie = False
            # a vote the sensors decide (not a tie, someone has a view): what confirms a facing
            decided = bool(f.any())
            if amb.any():
                seen = f.any(axis=-1)
                if (amb | ~seen).all():
                    # one ambiguous view alone cannot be checked by another: a tie too
                    n_seen = int(seen.sum())
                    v0, v1, v2 = vote.tolist()
                    norm = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
                    tie = n_seen == 1 or norm < opt.walk_tie * AMBIGUOUS_WEIGHT * n_seen
            if tie:
                # only ambiguous sensors that do not agree (e.g. two, one seeing the back): their
                # vote is a tie that the facing so far would freeze; a walking body faces where
                # it goes. Ambiguous sensors that agree (two in front of a person walking
                # backwards, in a real recording) are not overruled by the walking direction
                kf = self._kf
                vx, vy = float(kf.m[1, _PELVIS, 0]), float(kf.m[1, _PELVIS, 1])
                speed = math.hypot(vx, vy)
                if speed > opt.walk_speed_m_s and kf.started[_PELVIS].all():
                    fp = self._facing
                    against = fp is not None and vx * float(fp[0]) + vy * float(fp[1]) < 0.0
                    self._against_s = self._against_s + dt if against else 0.0
                    # (a facing no decided vote has confirmed is no evidence against it)
                    if (not against or self._against_s >= opt.walk_against_s
                            or not self._facing_confirmed):  # fmt: skip
                        vote = vote + opt.walk_weight * np.array([vx / speed, vy / speed, 0.0])
                        tie = False
            decided = decided and not tie
            w_prior = (opt.facing_prior_weight if self._facing_confirmed
                       else opt.unconfirmed_prior_weight)  # fmt: skip
            cap = opt.ambiguous_vote_cap
            if cap < math.inf and amb.any():
                a0, a1, a2 = (AMBIGUOUS_WEIGHT * f[amb].sum(axis=0)).tolist()
                na = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
                if na > cap:
                    vote = vote - (1.0 - cap / na) * np.array([a0, a1, a2])
            flips = decide_flips(f, amb, vote, self._facing, w_prior)
            self._facing_confirmed = self._facing_confirmed or decided
        if flips is not None and not flips.any():
            flips = None
        self.last_flips = flips
        if guess is not None and (
            (not guess.flips.any()) if flips is None else np.array_equal(guess.flips, flips)
        ):
            x, cov_x, used = guess.x, guess.cov_x, guess.used
            if flips is not None:
                states = states.copy()
                states[flips] = states[flips][:, _MIRROR]
                z = z.copy()
                z[flips] = z[flips][:, _MIRROR]
        else:
            if flips is not None:
                z, cov, states = z.copy(), cov.copy(), states.copy()
                for i in np.flatnonzero(flips):
                    z[i], cov[i], states[i] = z[i][_MIRROR], cov[i][_MIRROR], states[i][_MIRROR]
            xx, cc, uu = self._combine(z[None], cov[None])
            x, cov_x, used = xx[0], cc[0], uu[0]
        self.last_measurement = (x, cov_x)
        pos, var, alive = self._filter(t, x, cov_x)
        all_ = np.logical_and.reduce
        measured = all_(np.isfinite(x), axis=-1)
        tracked = np.add.reduce(all_(np.isfinite(z), axis=-1) & (states == _TRACKED), axis=0,
                                dtype=np.intp)  # fmt: skip
        # the body's facing so far, from the filter (hips and shoulders alive)
        h = pos[_FACING_JOINTS, :2].tolist()
        lr0 = h[0][0] - h[1][0] + h[2][0] - h[3][0]
        lr1 = h[0][1] - h[1][1] + h[2][1] - h[3][1]
        n = math.hypot(lr0, lr1)
        if alive[_FACING_JOINTS].all() and n > 1e-6:
            self._facing = np.array([lr1 / n, -lr0 / n, 0.0])
        elif not alive[_FACING_JOINTS].any():
            # the body is lost: its facing then says nothing of the body found again later
            self._facing, self._facing_confirmed = None, False
        return pos, var, alive, measured, used, tracked

    def _finish(
        self,
        pos: Array,
        var: Array,
        alive: NDArray[Any],
        measured: NDArray[Any],
        used: NDArray[Any],
        tracked: NDArray[Any],
    ) -> tuple[Array, Array, NDArray[np.int8], NDArray[np.intp]]:
        """Frames ``(T, 25, ...)`` of :meth:`_step` results -> positions, variances, status and
        sensors used: statuses, the running bone lengths (updated frame by frame, in order) and
        the projection onto them."""
        status = np.full(pos.shape[:2], _S_OK, dtype=np.int8)
        status[measured & (used <= 1)] = _S_SINGLE
        status[measured & (tracked == 0)] = _S_INFERRED
        good = alive & measured & (used >= 2) & (tracked >= 1)
        if self.options.best.bones:
            pos, dev = self._bones(pos, var, good)
            np.maximum(status, _S_BONE, out=status, where=measured & (dev > 1.0))
        status[~measured] = _S_PREDICTED
        status[~alive] = _S_NO_DATA
        pos = np.where(alive[..., None], pos, np.nan)
        var = np.where(alive, var, np.nan)
        return pos, var, status, np.asarray(used, dtype=np.intp)

    def _filter(self, t: float, x: Array, cov_x: Array) -> tuple[Array, Array, NDArray[np.bool_]]:
        """Predict the per-joint, per-axis constant-velocity filter to ``t`` and update it with
        the fused measurement ``x (25, 3)``; returns position, variance and which joints are
        alive (seen within ``max_predict_s``)."""
        d = 0.0 if self._t is None else max(t - self._t, 0.0)
        self._t = t if self._t is None else max(t, self._t)
        r = cov_x.diagonal(0, -2, -1)
        if self.record:
            self.last_filter_step = (d, r.copy())
        _, alive = kalman_step(self._kf, t, d, x, r, self._q, self.options.best.max_predict_s)
        p = self._kf.pxx
        var = (p[:, 0] + p[:, 1] + p[:, 2]) / 3
        return self._kf.x.copy(), var, np.logical_and.reduce(alive, axis=-1)

    def _bones(self, pos: Array, var: Array, good: NDArray[np.bool_]) -> tuple[Array, Array]:
        """Frames ``(T, 25, 3)``: update the running bone lengths from well-observed joints,
        frame by frame; project each frame onto the lengths known at it.

        Returns the projected positions and each joint's largest bone deviation before the
        projection, in units of the allowed one (NaN where no bone of the joint is known yet).
        """
        pa, ch = BONES[:, 0], BONES[:, 1]
        seg = pos[:, ch] - pos[:, pa]
        sq = seg * seg
        length = np.sqrt(sq[..., 0] + sq[..., 1] + sq[..., 2])  # (T, 24)
        finite = np.isfinite(length)
        ok = good[:, pa] & good[:, ch] & finite
        n_t, n_b = length.shape
        lengths = np.empty(length.shape)
        counts = np.empty(length.shape, dtype=np.int64)
        for k in range(n_t):
            # robust running mean: innovations clipped at 3 sigma once a bone has a few samples
            n = self._bone_n
            innov = length[k] - self._bone_len
            sigma = np.sqrt(self._bone_var / np.maximum(n, 1)) + 0.01
            clipped = np.minimum(np.maximum(innov, -3 * sigma), 3 * sigma)
            innov = np.where(n >= 5, clipped, innov)
            upd = ok[k] & np.isfinite(innov)
            n_new = n + upd
            step = np.zeros(n_b)
            np.divide(innov, n_new, out=step, where=upd)
            self._bone_len = self._bone_len + step
            self._bone_var = self._bone_var + np.where(upd, innov * (innov - step), 0.0)
            self._bone_n = n_new
            lengths[k], counts[k] = self._bone_len, n_new
        known = counts >= self.options.bone_min_samples
        # deviation relative to the tolerance: > 1 breaks the bone (short bones, the hands' and
        # feet's, get an absolute floor of 3 cm, about their trackers' noise); a last NaN column
        # for the padding of a joint's bones
        allowed = np.maximum(self.options.bone_tolerance * lengths, 0.03)
        dev_bone = np.full((n_t, n_b + 1), np.nan)
        np.divide(np.abs(length - lengths), allowed, out=dev_bone[:, :n_b], where=known)
        dev = np.fmax.reduce(dev_bone[:, JOINT_BONES], axis=-1)  # (T, 25)
        # one sweep over the bones, in groups that share no joint (so each group moves at
        # once), each end moving in proportion to its variance (the variances do not change
        # during the sweep: each bone's share is known before it); bones in the group order
        order = BONE_ORDER
        vv = np.where(np.isfinite(var), var, np.inf)
        va, vc = vv[:, _PARENTS], vv[:, _CHILDREN]
        inf_a, inf_c = np.isinf(va), np.isinf(vc)
        tot = va + vc
        wc_all = np.full(tot.shape, 0.5)
        np.divide(vc, tot, out=wc_all, where=np.isfinite(tot) & (tot > 0))
        wc_all = np.where(inf_c > inf_a, 1.0, np.where(inf_a > inf_c, 0.0, wc_all))  # one inf
        wa_all = 1.0 - wc_all
        movable = (known & finite & (length > 1e-9))[:, order]
        out = project_bones(pos, movable, lengths[:, order], wc_all, wa_all)
        return out, dev


def replay_streams(
    streams: Sequence[BodyFrames],
    sensor2world: ArrayLike,
    grid_s: Array,
    options: LiveOptions = LiveOptions(),
    *,
    record: bool = False,
) -> dict[str, Any]:
    """Run :class:`LiveFusion` over recorded streams as a live server would have.

    Before frame ``T`` is fused, every observation captured up to ``T + options.latency_s`` has
    arrived; nothing later is seen. The measurements of every frame (which depend only on the
    observations) are prepared in batches; the swap decision, filter and bone lengths then run
    frame by frame through the same :class:`LiveFusion` code as a live server's, so the result
    equals pushing and fusing frame by frame (a sensor's buffer aside: the replay looks up
    every arrived observation, a live buffer keeps the last ``options.buffer``, which covers
    the latency budget at any real frame rate).

    Parameters
    ----------
    streams : list of BodyFrames
        Capture times on the server clock (``t_server_s``), increasing per stream.
    sensor2world : (S, 4, 4) float
    grid_s : (T,) float
        Frame times, increasing.
    record : bool
        Also return the combined measurements and what a smoother needs (a
        :class:`~kinefuse.capture.fusion.model.FilterTape`: the filter's inputs and its state every
        ``_CHUNK`` frames, from which its moments are recomputed a block at a time; the moments
        of every frame, ten ``(T, 25, 3)`` arrays, are never held at once).

    Returns
    -------
    dict
        ``positions (T, 25, 3)``, ``variance_m2 (T, 25)``, ``status (T, 25) int8``,
        ``n_sensors (T, 25)``, ``mirrored (T, S)`` bool (the sensors whose skeleton the swap
        vote mirrored back); with ``record``: ``measurement (T, 25, 3)``, the trace of its
        covariance / 3 ``measurement_var (T, 25)`` and ``tape`` (a ``FilterTape``).
    """
    fusion = LiveFusion(sensor2world, options)
    fusion.record = record
    grid = np.asarray(grid_s, dtype=np.float64)
    n_t, n_s = grid.size, fusion.n_sensors
    if len(streams) != n_s:
        raise FusionError(f"{len(streams)} streams for {n_s} sensor poses; give one pose each")
    ordered = []  # each stream in capture order (the order a live buffer keeps)
    for s in streams:
        if not np.isfinite(s.t_server_s).all():
            raise FusionError(f"sensor {s.sensor_id!r}: capture times must be finite")
        inc = s.t_server_s.size < 2 or bool((np.diff(s.t_server_s) >= 0).all())
        ordered.append(s if inc else s.take(np.argsort(s.t_server_s, kind="stable")))
    out: dict[str, Any] = {
        "positions": np.full((n_t, N_JOINTS, 3), np.nan),
        "variance_m2": np.full((n_t, N_JOINTS), np.nan),
        "status": np.full((n_t, N_JOINTS), FusionStatus.NO_DATA, dtype=np.int8),
        "n_sensors": np.zeros((n_t, N_JOINTS), dtype=np.intp),
        "mirrored": np.zeros((n_t, n_s), dtype=bool),
    }
    checkpoints: list[KalmanState] = []
    if record:
        out["measurement"] = np.full((n_t, N_JOINTS, 3), np.nan)
        out["measurement_var"] = np.full((n_t, N_JOINTS), np.nan)
        step_d = np.zeros(n_t)
        step_r = np.full((n_t, N_JOINTS, 3), np.nan)
    for a in range(0, n_t, _CHUNK):
        if record:  # the filter's state before the chunk: where a smoother's block restarts
            kf = fusion._kf
            checkpoints.append(KalmanState(kf.m.copy(), kf.started.copy(), kf.last_seen.copy()))
        tg = grid[a : a + _CHUNK]
        avail = tg + options.latency_s
        m = tg.size
        joints = np.full((m, n_s, N_JOINTS, 3), np.nan)
        states = np.zeros((m, n_s, N_JOINTS), np.int8)
        occ = np.zeros((m, n_s, N_JOINTS), bool)
        age = np.zeros((m, n_s))
        for i, s in enumerate(ordered):
            if s.n_frames == 0:
                continue
            o = None if s.occluded is None else s.occluded[None]
            j, st, oc, ag = fusion._at(tg, avail, s.t_server_s[None], np.array([s.n_frames]),
                                       s.joints_m[None], s.states[None], o)  # fmt: skip
            joints[:, i], states[:, i], occ[:, i], age[:, i] = j[:, 0], st[:, 0], oc[:, 0], ag[:, 0]
        z, cov, evidence = fusion._prepare(joints, states, occ, age)
        # a guess of each frame's swaps (the vote without the fused facing so far): frames
        # whose actual decision differs are combined again on their own
        if evidence is None:
            flips = np.zeros((m, n_s), bool)
        else:
            f, amb, vote = evidence
            dots = (f * vote[:, None, :]).sum(-1)
            flips = amb & (dots < 0) & ((vote * vote).sum(-1) >= 1e-18)[:, None]
        zg, cg = z, cov
        if flips.any():
            zg, cg = z.copy(), cov.copy()
            tt, ss = np.nonzero(flips)
            zg[tt, ss] = z[tt, ss][:, _MIRROR]
            cg[tt, ss] = cov[tt, ss][:, _MIRROR]
        x, cov_x, used = fusion._combine(zg, cg)
        steps = []
        covs = []
        for k in range(m):
            ev = None if evidence is None else (evidence[0][k], evidence[1][k], evidence[2][k])
            guess = _Guess(flips[k], x[k], cov_x[k], used[k])
            steps.append(fusion._step(float(tg[k]), z[k], cov[k], states[k], ev, guess))
            if fusion.last_flips is not None:
                out["mirrored"][a + k] = fusion.last_flips
            if record:
                assert fusion.last_filter_step is not None and fusion.last_measurement is not None
                g = a + k
                step_d[g], step_r[g] = fusion.last_filter_step
                out["measurement"][g], cov_k = fusion.last_measurement
                covs.append(cov_k)
        sl = slice(a, a + m)
        if record:
            out["measurement_var"][sl] = np.trace(np.stack(covs), axis1=-2, axis2=-1) / 3
        stacked = [np.stack(v) for v in zip(*steps, strict=True)]
        res = fusion._finish(*stacked)
        out["positions"][sl], out["variance_m2"][sl], out["status"][sl] = res[:3]
        out["n_sensors"][sl] = res[3]
    if record:
        out["tape"] = FilterTape(
            t=grid, d=step_d, z=out["measurement"], r=step_r, q=fusion._q,
            max_predict_s=options.best.max_predict_s, every=_CHUNK,
            checkpoints=tuple(checkpoints),
        )  # fmt: skip
    return out


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
    """:func:`replay_streams` of streams given as arrays per sensor.

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
    occ = occluded if occluded is not None else [None] * len(t_server_s)
    streams = [
        BodyFrames.on_server_clock(t, j, st, occluded=o)
        for t, j, st, o in zip(t_server_s, joints_sensor, states, occ, strict=True)
    ]
    r = replay_streams(streams, sensor2world, grid_s, options)
    return (r["positions"], r["variance_m2"], r["status"].astype(np.int8),
            r["n_sensors"].astype(np.intp))  # fmt: skip

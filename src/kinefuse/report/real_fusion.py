"""Fuse real two-Kinect recordings (KinectMultiTrack logs) and report how well the sensors agree.

There is no ground truth in these recordings: every figure here is a *consistency* figure (how
far the two sensors are from each other, how far each is from the fused skeleton), not an error.

Pipeline (``docs/real_data.md`` shows the result and how to rerun it):

1. **Frames.** Each sensor's rows are reduced to its distinct frames (a row repeats a sensor's
   latest skeleton whenever the other sensor triggered the log line; rows are also logged out of
   capture order). A frame's receive time is its first appearance.
2. **Clocks** (:func:`fit_clock_lower_envelope`). Receive time = capture + latency + non-negative
   jitter, so the *lower envelope* of ``t_receive`` against ``t_sensor`` carries the clock
   relation ``t_receive ~ a + b t_sensor``. Capture times on the receiver's clock are then
   ``a + b t_sensor`` (up to one constant latency). What the clocks cannot show, a latency that
   differs between the two sensors' pipelines, is measured from the trunk motion
   (:func:`residual_lag_s`) and taken off.
3. **Registration.** KinectMultiTrack mapped every sensor into the reference sensor's frame by
   the body's initial yaw and centre. :func:`refine_registration` re-registers the other sensor
   rigidly onto the reference from the trunk joints at their aligned capture times (the body as
   the calibration object); the floor (:func:`fit_foot_plane`, the plane of the standing feet)
   gives the world's up. See :func:`sensor_poses` for how each sensor's pose is reconstructed.
4. **Fusion** with :func:`kinefuse.fusion.best.fuse_best` on a 30 Hz grid, with and without the
   left/right swap correction, and the per-joint consistency figures (:func:`consistency`).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.errors import InputError, SyncError
from kinefuse.fusion.best import BestOptions, SensorStream, correct_swaps, fuse_best
from kinefuse.geometry.transforms import fit_plane, kabsch, make_transform
from kinefuse.io.kinect_multitrack import (
    MultitrackRecording,
    MultitrackStream,
    read_kinect_multitrack,
)
from kinefuse.skeleton import JOINT_INDEX, JOINTS, MIRROR_INDEX, TrackingState

Array = NDArray[np.float64]

#: Joints used to register the sensors and to check the clocks: the trunk, which every Kinect
#: tracks best and which is not subject to left/right swaps of the limbs.
TRUNK_JOINTS: tuple[str, ...] = (
    "SpineBase",
    "SpineMid",
    "SpineShoulder",
    "Neck",
    "Head",
    "ShoulderLeft",
    "ShoulderRight",
    "HipLeft",
    "HipRight",
)
_TRUNK = np.array([JOINT_INDEX[n] for n in TRUNK_JOINTS])
_FEET = np.array([JOINT_INDEX["FootLeft"], JOINT_INDEX["FootRight"]])
LAYOUT_NAMES = {0: "parallel", 1: "45 deg"}
#: Nominal angle between the two optical axes of each KinectMultiTrack layout, degrees.
LAYOUT_NOMINAL_DEG = {0: 0.0, 1: 45.0}
SCENARIO_NAMES = {1: "stand", 2: "steps", 3: "walk"}


# --------------------------------------------------------------------------------------------
# clocks
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ClockFit:
    """A sensor clock mapped onto the receiver's clock: ``t_receive = offset + rate * (t - t0)``.

    Attributes
    ----------
    t0_sensor_s : float
        Origin of the sensor clock in the fit (its first frame), seconds.
    offset_s : float
        Receiver time of ``t0_sensor_s`` on the lower envelope (capture + minimum latency), s.
    rate : float
        Receiver seconds per sensor second.
    n_frames, n_envelope : int
        Frames fitted, and frames on the lower envelope used for the final fit.
    jitter_median_s, jitter_p95_s : float
        Receive time above the envelope (the jitter that the fit removes), median and p95, s.
    """

    t0_sensor_s: float
    offset_s: float
    rate: float
    n_frames: int
    n_envelope: int
    jitter_median_s: float
    jitter_p95_s: float

    @property
    def drift_ppm(self) -> float:
        """Drift of the sensor clock against the receiver, parts per million."""
        return (self.rate - 1.0) * 1e6

    def to_receiver(self, t_sensor_s: ArrayLike) -> Array:
        """Capture times ``(N,)`` on the receiver's clock for sensor times ``(N,)``, seconds."""
        t = np.asarray(t_sensor_s, dtype=np.float64)
        return self.offset_s + self.rate * (t - self.t0_sensor_s)


def fit_clock_lower_envelope(
    t_sensor_s: ArrayLike,
    t_receive_s: ArrayLike,
    *,
    quantile: float = 0.05,
    floor_quantile: float = 0.01,
    max_iter: int = 30,
) -> ClockFit:
    """Fit ``t_receive ~ a + b t_sensor`` on the lower envelope of the receive times.

    Receive time = capture + latency + delay with delay >= 0 (network jitter, and at a busy
    receiver a queue that can grow to hundreds of milliseconds), so the frames that arrived
    fastest carry the clock relation. The start is the line under all points that is highest at
    their mean time (the lower convex hull's edge there; the linear-programming estimate of
    Moon, Skelly & Towsley 1999), which an ordinary least-squares start would not be when the
    delay drifts. Then: keep the frames whose residual is in the lowest ``quantile``, refit by
    least squares on them, and repeat until the kept set no longer changes. The line is finally
    lowered to the ``floor_quantile`` of all residuals (a minimum that tolerates a few
    outliers), so the residuals are the delay above the fastest frames, ``>= 0`` for almost all.

    Parameters
    ----------
    t_sensor_s : (N,) float
        Capture times on the sensor's own clock, seconds (distinct frames, any order).
    t_receive_s : (N,) float
        Receive times of the same frames on the receiver's clock, seconds.
    quantile : float
        Fraction of frames kept on the envelope at each refit, in (0, 1].
    floor_quantile : float
        Residual quantile that the final line passes through, in [0, quantile].
    max_iter : int
        Maximum number of refits.

    Returns
    -------
    ClockFit

    Raises
    ------
    InputError
        Arrays of different shapes, not 1-D, non-finite, fewer than 3 frames, or quantiles out
        of range.
    SyncError
        The sensor times do not span a positive interval, or the envelope collapses to one
        instant (no clock relation can be fitted).
    """
    x = np.asarray(t_sensor_s, dtype=np.float64)
    y = np.asarray(t_receive_s, dtype=np.float64)
    if x.ndim != 1 or y.shape != x.shape:
        raise InputError(
            f"t_sensor_s and t_receive_s must be 1-D arrays of one length, got shapes {x.shape} "
            f"and {y.shape}; give one entry per frame"
        )
    if x.size < 3:
        raise InputError(f"a clock fit needs at least 3 frames, got {x.size}")
    if not (np.isfinite(x).all() and np.isfinite(y).all()):
        raise InputError("t_sensor_s and t_receive_s must be finite; drop frames without times")
    if not 0.0 < quantile <= 1.0:
        raise InputError(f"quantile must be in (0, 1], got {quantile!r}")
    if not 0.0 <= floor_quantile <= quantile:
        raise InputError(
            f"floor_quantile must be in [0, quantile={quantile}], got {floor_quantile!r}"
        )
    x0 = float(x.min())
    xs = x - x0
    span = float(xs.max())
    if span <= 0.0:
        raise SyncError(
            "the sensor times do not advance (all equal); a clock relation needs frames spread "
            "over time"
        )
    u = xs / span  # scaled for conditioning
    a_mat = np.stack([np.ones_like(u), u], axis=1)
    coef = _lower_support_line(u, y)
    keep_prev: NDArray[np.bool_] | None = None
    keep = np.ones(x.size, dtype=bool)
    for _ in range(max_iter):
        r = y - a_mat @ coef
        keep = r <= np.quantile(r, quantile)
        if keep.sum() < 2 or np.ptp(xs[keep]) <= 0.0:
            raise SyncError(
                "the lower envelope of the receive times collapses to one instant; the frames "
                "do not carry a clock relation (check that the times belong together)"
            )
        coef = np.asarray(np.linalg.lstsq(a_mat[keep], y[keep], rcond=None)[0], dtype=np.float64)
        if keep_prev is not None and np.array_equal(keep, keep_prev):
            break
        keep_prev = keep
    r = y - a_mat @ coef
    coef[0] += float(np.quantile(r, floor_quantile))
    jitter = y - a_mat @ coef
    return ClockFit(
        t0_sensor_s=x0,
        offset_s=float(coef[0]),
        rate=float(coef[1] / span),
        n_frames=int(x.size),
        n_envelope=int(keep.sum()),
        jitter_median_s=float(np.median(jitter)),
        jitter_p95_s=float(np.quantile(jitter, 0.95)),
    )


def _lower_support_line(x: Array, y: Array) -> Array:
    """``[a, b]`` of the line ``a + b x`` under every point, highest at the mean of ``x``.

    The edge of the lower convex hull of the points that spans ``mean(x)`` (monotone chain).
    """
    order = np.lexsort((y, x))
    xs, ys = x[order], y[order]
    hull: list[int] = []
    for i in range(xs.size):
        while len(hull) >= 2:
            i0, i1 = hull[-2], hull[-1]
            cross = (xs[i1] - xs[i0]) * (ys[i] - ys[i0]) - (ys[i1] - ys[i0]) * (xs[i] - xs[i0])
            if cross <= 0:
                hull.pop()
            else:
                break
        hull.append(i)
    hx, hy = xs[hull], ys[hull]
    # drop vertical steps (equal x): keep the lowest point of each x (already first by lexsort)
    k = int(np.clip(np.searchsorted(hx, x.mean(), side="right") - 1, 0, hx.size - 2))
    b = (hy[k + 1] - hy[k]) / (hx[k + 1] - hx[k])
    return np.array([hy[k] - b * hx[k], b])


# --------------------------------------------------------------------------------------------
# frames, interpolation, geometry helpers
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SensorFrames:
    """One sensor's distinct frames, sorted by capture time.

    Attributes
    ----------
    sensor_id : str
    t_sensor_s, t_receive_s : (N,) float
        Sensor clock, and first receive time (seconds since the file's first row).
    joints : (N, 25, 3) float
        As logged (reference sensor's frame, kinefuse axes), metres.
    scenario : (N,) int
    n_rows, n_duplicates, n_out_of_order : int
        Rows in the file, rows that repeated an already-logged frame, and frames logged after a
        frame captured later.
    """

    sensor_id: str
    t_sensor_s: Array
    t_receive_s: Array
    joints: Array
    scenario: NDArray[np.int64]
    n_rows: int
    n_duplicates: int
    n_out_of_order: int


def unique_frames(stream: MultitrackStream) -> SensorFrames:
    """Reduce a logged stream to its distinct frames (first receipt of each), in capture order."""
    ticks = np.round(stream.t_sensor_s * 1e7).astype(np.int64)
    order = np.lexsort((stream.t_receive_s, ticks))
    first = np.ones(order.size, dtype=bool)
    first[1:] = np.diff(ticks[order]) != 0
    keep = order[first]
    # out of order: a first appearance logged after the first appearance of a later frame
    row_first = np.sort(keep)
    later = np.maximum.accumulate(ticks[row_first])
    ooo = int((ticks[row_first][1:] < later[:-1]).sum())
    return SensorFrames(
        sensor_id=stream.sensor_id,
        t_sensor_s=stream.t_sensor_s[keep],
        t_receive_s=stream.t_receive_s[keep],
        joints=stream.joints_m[keep],
        scenario=stream.scenario[keep],
        n_rows=stream.n_frames,
        n_duplicates=int(stream.n_frames - keep.size),
        n_out_of_order=ooo,
    )


def interpolate(
    t_obs_s: ArrayLike, p: ArrayLike, t_query_s: ArrayLike, *, max_gap_s: float = 0.1
) -> Array:
    """Linear interpolation of a stream to query times, NaN across gaps and outside it.

    Parameters
    ----------
    t_obs_s : (N,) float
        Observation times, seconds (any order; sorted here).
    p : (N, ...) float
        Observations (e.g. ``(N, 25, 3)`` joints), NaN = missing.
    t_query_s : (Q,) float
    max_gap_s : float
        Neighbours further apart than this give NaN. At either end a query within half a 30 Hz
        frame of the first/last observation takes that observation.

    Returns
    -------
    (Q, ...) float
    """
    t = np.asarray(t_obs_s, dtype=np.float64)
    v = np.asarray(p, dtype=np.float64)
    q = np.asarray(t_query_s, dtype=np.float64)
    if t.ndim != 1 or v.ndim < 1 or v.shape[0] != t.size or q.ndim != 1:
        raise InputError(
            f"interpolate expects times (N,), values (N, ...) and query times (Q,), got "
            f"{t.shape}, {v.shape} and {q.shape}"
        )
    out_shape = (q.size, *v.shape[1:])
    if t.size == 0:
        return np.full(out_shape, np.nan)
    order = np.argsort(t, kind="stable")
    t, v = t[order], v[order]
    k = np.searchsorted(t, q, side="right")
    i0 = np.clip(k - 1, 0, t.size - 1)
    i1 = np.clip(k, 0, t.size - 1)
    dt = t[i1] - t[i0]
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.where(dt > 0, (q - t[i0]) / dt, 0.0)
    inside = (k > 0) & (k < t.size) & (dt <= max_gap_s)
    end_tol = 1.0 / 60.0
    at_start = (k == 0) & (t[0] - q <= end_tol)
    at_end = (k == t.size) & (q - t[-1] <= end_tol)
    w = np.where(at_start, 0.0, np.where(at_end, 1.0, w))
    ok = inside | at_start | at_end
    extra = (1,) * (v.ndim - 1)
    wv = w.reshape(-1, *extra)
    out = v[i0] * (1.0 - wv) + v[i1] * wv
    return np.where(ok.reshape(-1, *extra), out, np.nan)


def _facing_yaw_kinect(p_sensor: Array) -> Array:
    """KinectMultiTrack's body yaw ``(N,)`` from the shoulders, in Kinect camera axes, radians.

    ``atan2(SR.Z - SL.Z, SR.X - SL.X)`` with Kinect ``X = -x`` of kinefuse axes.
    """
    d = p_sensor[:, JOINT_INDEX["ShoulderRight"]] - p_sensor[:, JOINT_INDEX["ShoulderLeft"]]
    return np.arctan2(d[:, 2], -d[:, 0])


def kmt_rotation(delta_rad: float) -> Array:
    """KinectMultiTrack's sensor-to-reference rotation for a yaw difference, kinefuse axes.

    KinectMultiTrack maps a sensor's point ``p_i`` into the reference's frame as
    ``c_ref + M (p_i - c_i)`` with ``M`` a rotation about the vertical camera axis by the
    difference of the body's initial yaws ``delta = a_i - a_ref`` (``X' = X cos + Z sin``,
    ``Z' = Z cos - X sin`` in Kinect axes). In kinefuse axes (``x = -X``)::

        M = [[cos d, 0, -sin d], [0, 1, 0], [sin d, 0, cos d]]

    Returns
    -------
    (3, 3) float
    """
    c, s = math.cos(delta_rad), math.sin(delta_rad)
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


@dataclass(frozen=True)
class FloorFit:
    """The plane of the standing feet in a sensor's frame.

    Attributes
    ----------
    up : (3,) float
        Unit normal pointing from the feet toward the head, sensor frame.
    height_m : float
        Height of the sensor's optical centre above the plane of the foot joints (the Kinect's
        foot joint sits a few centimetres above the real floor), metres.
    rms_m : float
        RMS distance of the samples used to the plane, metres.
    n_samples : int
        Foot samples used (0: the fallback from the logged tilt and height was used).
    """

    up: Array
    height_m: float
    rms_m: float
    n_samples: int


def fit_foot_plane(
    t_s: ArrayLike,
    joints: ArrayLike,
    *,
    max_speed_m_s: float = 0.15,
    min_samples: int = 100,
    max_rms_m: float = 0.03,
    fallback_tilt_deg: float = 0.0,
    fallback_height_m: float = 1.0,
) -> FloorFit:
    """Fit the floor (the plane of the feet while they stand still) in one sensor's frame.

    Foot joints (``FootLeft``, ``FootRight``) slower than ``max_speed_m_s`` are stance samples;
    a plane is fitted by SVD and refitted three times without samples beyond three median
    absolute distances. With fewer than ``min_samples`` stance samples or an RMS above
    ``max_rms_m`` the floor comes from the logged tilt (degrees, positive = looking up) and
    height instead, and ``n_samples`` is 0.

    Parameters
    ----------
    t_s : (N,) float
        Capture times of the frames, seconds, strictly increasing.
    joints : (N, 25, 3) float
        The frames in the sensor's frame (x right, y down, z forward), metres.

    Returns
    -------
    FloorFit
    """
    t = np.asarray(t_s, dtype=np.float64)
    p = np.asarray(joints, dtype=np.float64)
    pts = np.empty((0, 3))
    if t.size >= 3:
        feet = p[:, _FEET]
        dt = (t[2:] - t[:-2])[:, None]
        speed = np.full(feet.shape[:2], np.inf)
        with np.errstate(invalid="ignore", divide="ignore"):
            speed[1:-1] = np.linalg.norm(feet[2:] - feet[:-2], axis=-1) / dt
        stance = np.isfinite(speed) & (speed < max_speed_m_s)
        pts = feet[stance]
    if len(pts) >= min_samples:
        normal = np.zeros(3)
        centre = pts.mean(axis=0)
        for _ in range(4):
            centre, normal = fit_plane(pts)
            dist = np.abs((pts - centre) @ normal)
            pts = pts[dist <= 3.0 * np.median(dist) + 1e-4]
        head = np.nanmean(p[:, JOINT_INDEX["Head"]], axis=0)
        if float((head - centre) @ normal) < 0:
            normal = -normal
        rms = float(np.sqrt(np.mean(((pts - centre) @ normal) ** 2)))
        if rms <= max_rms_m:
            return FloorFit(
                up=normal, height_m=float(-(centre @ normal)), rms_m=rms, n_samples=len(pts)
            )
    tilt = math.radians(fallback_tilt_deg)
    up = np.array([0.0, -math.cos(tilt), math.sin(tilt)])
    return FloorFit(up=up, height_m=float(fallback_height_m), rms_m=float("nan"), n_samples=0)


def world_from_floor(floor: FloorFit) -> Array:
    """``ref2world`` ``(4, 4)``: z up (the floor normal), y along the sensor's optical axis
    projected on the floor, x to the right; origin on the foot plane below the sensor."""
    up = floor.up / np.linalg.norm(floor.up)
    fwd = np.array([0.0, 0.0, 1.0]) - up[2] * up
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, up)
    return make_transform(np.stack([right, fwd, up]), np.array([0.0, 0.0, floor.height_m]))


@dataclass(frozen=True)
class Registration:
    """A rigid re-registration of one sensor's mapped stream onto the reference.

    Attributes
    ----------
    other2ref : (4, 4) float
        Correction applied to the other sensor's logged (already mapped) joints.
    angle_deg : float
        Rotation angle of the correction, degrees.
    rotvec_deg : (3,) float
        Its rotation vector in the reference's frame (x right, y down, z forward), degrees.
    trunk_median_before_m, trunk_median_after_m : float
        Median trunk-joint distance between the two sensors before and after, metres.
    n_pairs : int
        Joint pairs used in the final fit.
    """

    other2ref: Array
    angle_deg: float
    rotvec_deg: Array
    trunk_median_before_m: float
    trunk_median_after_m: float
    n_pairs: int


def _rotvec_deg(r: Array) -> Array:
    angle = math.acos(max(-1.0, min(1.0, (float(np.trace(r)) - 1.0) / 2.0)))
    if angle < 1e-12:
        return np.zeros(3)
    axis = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    n = float(np.linalg.norm(axis))
    if n < 1e-12:  # 180 degrees: axis from the symmetric part
        w, v = np.linalg.eigh((r + r.T) / 2.0)
        axis = v[:, int(np.argmax(w))]
        n = 1.0
    return np.asarray(math.degrees(angle) * axis / n)


def refine_registration(
    t_ref_s: ArrayLike,
    p_ref: ArrayLike,
    t_other_s: ArrayLike,
    p_other: ArrayLike,
    *,
    max_gap_s: float = 0.1,
    iterations: int = 3,
) -> Registration:
    """Rigidly re-register a sensor onto the reference from the trunk joints.

    The other stream is interpolated to the reference's capture times (both on one clock), and
    one rigid transform (Kabsch) is fitted over all paired trunk joints; pairs beyond three
    median distances are dropped and the fit repeated ``iterations`` times.

    Parameters
    ----------
    t_ref_s : (N,) float
    p_ref : (N, 25, 3) float
        The reference sensor's joints, its frame, metres.
    t_other_s : (M,) float
    p_other : (M, 25, 3) float
        The other sensor's joints as mapped into the reference's frame, metres.

    Returns
    -------
    Registration

    Raises
    ------
    InputError
        Fewer than 10 paired frames: the streams do not overlap in time.
    """
    pr = np.asarray(p_ref, dtype=np.float64)[:, _TRUNK]
    po = interpolate(t_other_s, np.asarray(p_other, dtype=np.float64), t_ref_s, max_gap_s=max_gap_s)
    po = po[:, _TRUNK]
    both = np.isfinite(pr).all((-1, -2)) & np.isfinite(po).all((-1, -2))
    if both.sum() < 10:
        raise InputError(
            f"only {int(both.sum())} frames of the two sensors overlap in time; registration "
            "needs at least 10 (are the clocks fitted on the same recording?)"
        )
    src = po[both].reshape(-1, 3)
    dst = pr[both].reshape(-1, 3)
    before = np.linalg.norm(src - dst, axis=1)
    w = np.ones(len(src))
    t = np.eye(4)
    for _ in range(iterations):
        t = kabsch(src, dst, w)
        d = np.linalg.norm(src @ t[:3, :3].T + t[:3, 3] - dst, axis=1)
        w = (d <= 3.0 * np.median(d)).astype(np.float64)
    d = np.linalg.norm(src @ t[:3, :3].T + t[:3, 3] - dst, axis=1)
    rv = _rotvec_deg(t[:3, :3])
    return Registration(
        other2ref=t,
        angle_deg=float(np.linalg.norm(rv)),
        rotvec_deg=rv,
        trunk_median_before_m=float(np.median(before)),
        trunk_median_after_m=float(np.median(d)),
        n_pairs=int(w.sum()),
    )


def sensor_poses(
    *,
    c_ref: Array,
    delta_rad: float,
    other_init_dist_m: float,
    ref2world: Array,
    correction: Array,
    other_offaxis_deg: float = 0.0,
    height_difference_m: float = 0.0,
) -> tuple[Array, Array]:
    """The other sensor's pose: ``other2ref`` (4, 4) and its mapping offset ``o_kmt`` (3,).

    KinectMultiTrack's mapping is ``p_ref = c_ref + M (p_i - c_i)`` (:func:`kmt_rotation`), so
    the other sensor's optical centre (``p_i = 0``) sits at ``o = c_ref - M c_i`` in the mapped
    frame, and ``other2ref = correction @ [M | o]``. ``c_i``, the body's initial centre in the
    other sensor's own frame, is only partly logged: its depth is ``Skeleton_Init_Dist``; its
    lateral coordinate is ``depth * tan(other_offaxis_deg)`` (an assumption: the sensor was aimed
    at the person, default 0); its vertical coordinate is solved so that the sensor's height
    above the floor equals the reference's plus ``height_difference_m`` (the logged heights).

    Parameters
    ----------
    c_ref : (3,) float
        The body's initial centre in the reference's frame, metres.
    delta_rad : float
        ``a_other - a_ref``, the difference of the logged initial yaws, radians.
    other_init_dist_m : float
    ref2world : (4, 4) float
    correction : (4, 4) float
        The rigid re-registration (identity: KinectMultiTrack's mapping as logged).

    Returns
    -------
    other2ref : (4, 4) float
    o_kmt : (3,) float
        The other sensor's centre in KinectMultiTrack's mapped frame (before ``correction``).
    """
    m = kmt_rotation(delta_rad)
    z_i = other_init_dist_m
    x_i = z_i * math.tan(math.radians(other_offaxis_deg))

    def centre_world(y_i: float) -> Array:
        o = c_ref - m @ np.array([x_i, y_i, z_i])
        o_ref = correction[:3, :3] @ o + correction[:3, 3]
        return np.asarray(ref2world[:3, :3] @ o_ref + ref2world[:3, 3])

    target = float(ref2world[2, 3]) + height_difference_m
    h0, h1 = centre_world(0.0)[2], centre_world(1.0)[2]
    # the sensor's vertical axis is never horizontal in practice; if it were, keep c_ref's height
    y_i = (target - h0) / (h1 - h0) if abs(h1 - h0) > 1e-6 else float(c_ref[1])
    o_kmt = c_ref - m @ np.array([x_i, y_i, z_i])
    return correction @ make_transform(m, o_kmt), o_kmt


# --------------------------------------------------------------------------------------------
# consistency figures
# --------------------------------------------------------------------------------------------


def _apply(a2b: Array, p_a: Array) -> Array:
    """Points ``(..., 3)`` through one ``(4, 4)`` transform (NaN stays NaN)."""
    return np.asarray(p_a @ a2b[:3, :3].T + a2b[:3, 3])


def _to_world(s: SensorStream) -> Array:
    return _apply(s.sensor2world, s.joints_sensor)


def _stats(d: Array) -> dict[str, Any]:
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
    streams: Sequence[SensorStream],
    t_grid_s: ArrayLike,
    *,
    names: Sequence[str] | None = None,
    options: BestOptions | None = None,
    max_gap_s: float = 0.1,
) -> dict[str, Any]:
    """Per-joint consistency of S sensors before and after fusion, on a frame grid.

    Parameters
    ----------
    streams : list of SensorStream
        Capture times on one clock, joints in each sensor's frame, poses ``sensor2world``.
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
    t_obs = [np.asarray(s.t_server_s, dtype=np.float64) for s in streams]
    p_world = [_to_world(s) for s in streams]
    sensor_pos = np.array([s.sensor2world[:3, 3] for s in streams])
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
    fused_on = fuse_best(list(streams), grid, opt_on)
    fused_off = fuse_best(list(streams), grid, opt_off)
    out: dict[str, Any] = {"disagreement": {}, "disagreement_lr": {}}
    for a in range(len(streams)):
        for b in range(a + 1, len(streams)):
            key = f"{labels[a]}|{labels[b]}"
            out["disagreement"][key] = _stats(np.linalg.norm(raw[a] - raw[b], axis=-1))
            out["disagreement_lr"][key] = _stats(np.linalg.norm(cor[a] - cor[b], axis=-1))
    out["to_fused"] = {
        n: _stats(np.linalg.norm(c - fused_on.positions, axis=-1))
        for n, c in zip(labels, cor, strict=True)
    }
    out["to_fused_no_lr"] = {
        n: _stats(np.linalg.norm(r - fused_off.positions, axis=-1))
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


def residual_lag_s(
    t_ref_s: ArrayLike,
    p_ref: ArrayLike,
    t_other_s: ArrayLike,
    p_other: ArrayLike,
    *,
    max_lag_s: float = 0.3,
    iterations: int = 30,
    tol_s: float = 1e-4,
) -> float:
    """The time lag of the other stream's stamps, from the trunk motion alone.

    If the other sensor's stamps are late by ``tau``, the other stream read at the reference's
    times plus ``lag`` differs from the reference by ``v (lag - tau)`` (``v``: the trunk
    joints' velocity, from the reference) plus a constant offset per joint plus noise. A least
    squares fit of the differences on the velocities (one intercept per joint, residuals beyond
    three median absolute residuals dropped) gives ``lag - tau``; ``lag`` is updated and the
    fit repeated until it moves by less than ``tol_s``. A positive result means the other
    sensor's stamps are late: subtract it from them. 0 means the times already agree.

    Parameters
    ----------
    t_ref_s : (N,) float
    p_ref : (N, 25, 3) float
    t_other_s : (M,) float
    p_other : (M, 25, 3) float
        Both streams in one frame, metres, times on one clock, seconds.
    max_lag_s : float
        The search stays within ``+-max_lag_s``.

    Returns
    -------
    float
        Seconds.

    Raises
    ------
    InputError
        The streams do not overlap in time, or the body does not move (no lag is measurable).
    """
    tr = np.asarray(t_ref_s, dtype=np.float64)
    pr = np.asarray(p_ref, dtype=np.float64)[:, _TRUNK]
    po = np.asarray(p_other, dtype=np.float64)[:, _TRUNK]
    order = np.argsort(tr, kind="stable")
    tr, pr = tr[order], pr[order]
    # velocity over +-2 frames (about 0.13 s), NaN across gaps
    v = np.full_like(pr, np.nan)
    if tr.size >= 5:
        dt = tr[4:] - tr[:-4]
        with np.errstate(invalid="ignore", divide="ignore"):
            vel = (pr[4:] - pr[:-4]) / dt[:, None, None]
        v[2:-2] = np.where((dt > 0)[:, None, None] & (dt <= 0.25)[:, None, None], vel, np.nan)
    lag = 0.0
    for _ in range(iterations):
        q = interpolate(t_other_s, po, tr + lag)
        d = q - pr
        ok: NDArray[np.bool_] = np.asarray(
            np.isfinite(d).all(-1) & np.isfinite(v).all(-1), dtype=bool
        )
        if ok.sum() < 10:
            raise InputError(
                f"the two streams overlap in time on only {int(ok.sum())} joint samples; a lag "
                "needs them to overlap on a moving body"
            )
        dd = np.where(ok[..., None], d, 0.0)
        vv = np.where(ok[..., None], v, 0.0)
        n = np.maximum(ok.sum(axis=0), 1)[:, None]
        dd = np.where(ok[..., None], dd - dd.sum(axis=0) / n, 0.0)
        vv = np.where(ok[..., None], vv - vv.sum(axis=0) / n, 0.0)
        w: Array = ok.astype(np.float64)
        slope = 0.0
        for _ in range(2):
            den = float(np.sum(w[..., None] * vv * vv))
            if den < 1e-6 * max(1.0, float(w.sum())):
                raise InputError("the body does not move; the time lag cannot be measured")
            slope = float(np.sum(w[..., None] * vv * dd)) / den
            res: Array = np.asarray(np.linalg.norm(dd - slope * vv, axis=-1))
            w = (ok & (res <= 3.0 * np.median(res[ok]))).astype(np.float64)
        lag = float(np.clip(lag - slope, -max_lag_s, max_lag_s))
        if abs(slope) < tol_s:
            break
    return lag


# --------------------------------------------------------------------------------------------
# a KinectMultiTrack file
# --------------------------------------------------------------------------------------------


def _skeleton_ids(path: Path) -> dict[str, set[int]]:
    """``Kinect_Id -> {Skeleton_Id}`` from the log (empty if the column is absent)."""
    out: dict[str, set[int]] = {}
    with path.open(newline="", encoding="utf-8-sig") as fh:
        reader = csv.reader(fh)
        header = [c.strip() for c in next(reader)]
        if "Skeleton_Id" not in header or "Kinect_Id" not in header:
            return out
        ik, isk = header.index("Kinect_Id"), header.index("Skeleton_Id")
        for row in reader:
            if len(row) > max(ik, isk):
                try:
                    out.setdefault(row[ik].strip(), set()).add(int(float(row[isk])))
                except ValueError:
                    continue
    return out


def reference_sensor(path: str | Path, rec: MultitrackRecording) -> tuple[str, str]:
    """The sensor whose frame KinectMultiTrack mapped everything into, and how it was found.

    KinectMultiTrack's logger maps every skeleton into the frame of the person's *local*
    skeleton (a sensor at ``127.0.0.1``) or else of the first one (``Skeleton_Id`` 0). Without a
    usable ``Skeleton_Id`` column, the reference is the sensor whose logged initial yaw matches
    the yaw of the logged (mapped) bodies at the start of the file, which is the reference's.

    Returns
    -------
    sensor_id : str
    how : str
        ``"local"``, ``"skeleton_id"`` or ``"yaw"``.
    """
    ids = [s.sensor_id for s in rec.streams]
    if "127.0.0.1" in ids:
        return "127.0.0.1", "local"
    sk = _skeleton_ids(Path(path))
    zero = [k for k in ids if sk.get(k) == {0}]
    if len(zero) == 1:
        return zero[0], "skeleton_id"
    first = rec.streams[0]
    yaw = float(np.median(_facing_yaw_kinect(first.joints_m[: min(30, first.n_frames)])))
    errs = [abs(math.remainder(yaw - s.init_angle_rad, 2 * math.pi)) for s in rec.streams]
    if not all(math.isfinite(e) for e in errs):
        raise InputError(
            f"{path}: cannot tell the reference sensor: no usable Skeleton_Id column and no "
            "Skeleton_Init_Angle; the log lacks the columns KinectMultiTrack writes"
        )
    return ids[int(np.argmin(errs))], "yaw"


def _grid(t_lists: Sequence[Array], hz: float) -> Array:
    lo = min(float(t.min()) for t in t_lists if t.size)
    hi = max(float(t.max()) for t in t_lists if t.size)
    n = math.floor((hi - lo) * hz + 1e-9) + 1
    return lo + np.arange(n) / hz


def _pose_summary(s2w: Array, ref2world: Array) -> dict[str, Any]:
    z = s2w[:3, 2]
    zr = ref2world[:3, 2]
    yaw = math.degrees(math.atan2(z[0], z[1]) - math.atan2(zr[0], zr[1]))
    return {
        "position_m": [float(v) for v in s2w[:3, 3]],
        "yaw_deg": float(math.degrees(math.remainder(math.radians(yaw), 2 * math.pi))),
        "pitch_deg": float(math.degrees(math.asin(max(-1.0, min(1.0, z[2]))))),
    }


def _pair_disagreement(
    t_a: Array, p_a: Array, t_b: Array, p_b: Array, grid: Array, max_gap_s: float
) -> dict[str, Any]:
    return _stats(
        np.linalg.norm(
            interpolate(t_a, p_a, grid, max_gap_s=max_gap_s)
            - interpolate(t_b, p_b, grid, max_gap_s=max_gap_s),
            axis=-1,
        )
    )


def fuse_multitrack(
    path: str | Path,
    *,
    registration: str = "refined",
    grid_hz: float = 30.0,
    other_offaxis_deg: float = 0.0,
    motion_latency: bool = True,
    options: BestOptions | None = None,
) -> dict[str, Any]:
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

    Returns
    -------
    dict
        JSON-ready: ``file``, ``layout``, ``reference`` (sensor and how it was found),
        ``sensors``, ``clocks`` (per sensor: ``drift_ppm``, ``offset_s``, ``rate``, frames,
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
    t_cap = {k: clocks[k].to_receiver(f.t_sensor_s) for k, f in frames.items()}
    fr, fo = frames[ref_id], frames[oth_stream.sensor_id]
    oth_id = fo.sensor_id

    # registration and the sensors' relative latency, estimated in turn
    t_clock_oth = t_cap[oth_id]
    latency = 0.0
    reg = refine_registration(t_cap[ref_id], fr.joints, t_clock_oth, fo.joints)
    lag_clock = residual_lag_s(
        t_cap[ref_id], fr.joints, t_clock_oth, _apply(reg.other2ref, fo.joints)
    )
    if motion_latency:
        dl = lag_clock
        for _ in range(2):
            latency += dl
            reg = refine_registration(t_cap[ref_id], fr.joints, t_clock_oth - latency, fo.joints)
            dl = residual_lag_s(
                t_cap[ref_id], fr.joints, t_clock_oth - latency, _apply(reg.other2ref, fo.joints)
            )
        t_cap[oth_id] = t_clock_oth - latency
    start = fr.t_receive_s <= fr.t_receive_s.min() + 1.0
    c_ref = np.nanmean(fr.joints[start], axis=(0, 1))
    floor = fit_foot_plane(
        t_cap[ref_id],
        fr.joints,
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
    joints_other_sensor = (fo.joints - o_kmt) @ m  # = M^T (p - o): the sensor's own frame
    s2w = {ref_id: ref2world, oth_id: ref2world @ oth2ref}
    joints_sensor = {ref_id: fr.joints, oth_id: joints_other_sensor}

    # floor of the other sensor's joints (mapped), before and after the correction
    fo_floor = fit_foot_plane(t_cap[oth_id], fo.joints)
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
            clocks[ref_id].to_receiver(ref_stream.t_sensor_s)
            - clocks[oth_id].to_receiver(oth_stream.t_sensor_s)
        )
        skew = [float(np.median(sk)) * 1e3, float(np.quantile(sk, 0.95)) * 1e3]

    opt = BestOptions() if options is None else options
    streams_all = {
        k: SensorStream(
            t_server_s=t_cap[k],
            joints_sensor=joints_sensor[k],
            states=np.where(np.isfinite(joints_sensor[k]).all(-1), TrackingState.TRACKED, 0).astype(
                np.int8
            ),
            sensor2world=s2w[k],
        )
        for k in (ref_id, oth_id)
    }
    pw = {k: _to_world(s) for k, s in streams_all.items()}
    pw_logged_other = _apply(ref2world @ oth2ref_logged, joints_other_sensor)
    pw_refined_other = _apply(ref2world @ oth2ref_refined, joints_other_sensor)

    scen_out: dict[str, Any] = {}
    for sc in rec.scenarios:
        sel = {k: frames[k].scenario == sc for k in frames}
        if not all(v.any() for v in sel.values()):
            continue
        grid = _grid([t_cap[k][sel[k]] for k in frames], grid_hz)
        sub = [
            replace(
                streams_all[k],
                t_server_s=streams_all[k].t_server_s[sel[k]],
                joints_sensor=streams_all[k].joints_sensor[sel[k]],
                states=streams_all[k].states[sel[k]],
            )
            for k in (ref_id, oth_id)
        ]
        cons = consistency(sub, grid, names=[ref_id, oth_id], options=opt)
        key = f"{ref_id}|{oth_id}"
        gap = opt.max_interp_gap_s
        dis = {
            "clock": _pair_disagreement(
                t_cap[ref_id][sel[ref_id]],
                pw[ref_id][sel[ref_id]],
                t_clock_oth[sel[oth_id]],
                pw_refined_other[sel[oth_id]],
                grid,
                gap,
            ),
            "receive": _pair_disagreement(
                fr.t_receive_s[sel[ref_id]],
                pw[ref_id][sel[ref_id]],
                fo.t_receive_s[sel[oth_id]],
                pw_refined_other[sel[oth_id]],
                _grid([fr.t_receive_s[sel[ref_id]], fo.t_receive_s[sel[oth_id]]], grid_hz),
                gap,
            ),
            "logged": _pair_disagreement(
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
    return {
        "file": str(rec.path),
        "layout": LAYOUT_NAMES.get(rec.kinect_config, f"config {rec.kinect_config}"),
        "kinect_config": rec.kinect_config,
        "reference": {"sensor": ref_id, "found_by": how},
        "sensors": [ref_id, oth_id],
        "fused_with": registration,
        "other_offaxis_deg": other_offaxis_deg,
        "clocks": {
            k: {
                "drift_ppm": clocks[k].drift_ppm,
                "offset_s": clocks[k].offset_s,
                "rate": clocks[k].rate,
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
            ref_id: _pose_summary(s2w[ref_id], ref2world),
            oth_id: _pose_summary(s2w[oth_id], ref2world),
        },
        "scenarios": scen_out,
    }


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


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m kinefuse.report.real_fusion PATH [PATH ...] [--json] [--registration ...]``."""
    ap = argparse.ArgumentParser(
        prog="kinefuse realdata",
        description="Fuse real two-Kinect KinectMultiTrack logs and report their consistency.",
    )
    ap.add_argument("paths", nargs="+", help="KinectMultiTrack CSV logs")
    ap.add_argument("--json", action="store_true", help="print JSON instead of text")
    ap.add_argument("--registration", choices=("refined", "logged"), default="refined")
    ap.add_argument("--other-offaxis-deg", type=float, default=0.0)
    ap.add_argument(
        "--no-motion-latency",
        action="store_true",
        help="align by the clock fit alone (no relative latency from the motion)",
    )
    args = ap.parse_args(argv)
    results = [
        fuse_multitrack(
            p,
            registration=args.registration,
            other_offaxis_deg=args.other_offaxis_deg,
            motion_latency=not args.no_motion_latency,
        )
        for p in args.paths
    ]
    if args.json:
        print(json.dumps(results if len(results) > 1 else results[0], indent=1))
    else:
        print("\n\n".join(format_report(r) for r in results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

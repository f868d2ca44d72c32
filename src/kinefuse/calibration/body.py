"""Registration of sensors from the body itself: the floor under the feet, the trunk as the target.

Where no calibration object was recorded (the real KinectMultiTrack logs, ``docs/real_data.md``),
the tracked body calibrates the sensors: the plane of the standing feet gives each sensor's up
and height (:func:`fit_foot_plane`, :func:`world_from_floor`), and the trunk joints that two
sensors see at the same instants give their relative pose (:func:`refine_registration`). Pure:
arrays in, frozen dataclasses out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.errors import InputError
from kinefuse.geometry.rotations import rotation_vector_deg
from kinefuse.geometry.transforms import fit_plane, kabsch, make_transform
from kinefuse.skeleton import JOINT_INDEX, TRUNK_JOINTS
from kinefuse.sync.assembly import interpolate

Array = NDArray[np.float64]

_TRUNK = np.array([JOINT_INDEX[n] for n in TRUNK_JOINTS])
_FEET = np.array([JOINT_INDEX["FootLeft"], JOINT_INDEX["FootRight"]])


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
class BodyRegistration:
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


def refine_registration(
    t_ref_s: ArrayLike,
    p_ref: ArrayLike,
    t_other_s: ArrayLike,
    p_other: ArrayLike,
    *,
    max_gap_s: float = 0.1,
    iterations: int = 3,
) -> BodyRegistration:
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
    BodyRegistration

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
    rv = rotation_vector_deg(t[:3, :3])
    return BodyRegistration(
        other2ref=t,
        angle_deg=float(np.linalg.norm(rv)),
        rotvec_deg=rv,
        trunk_median_before_m=float(np.median(before)),
        trunk_median_after_m=float(np.median(d)),
        n_pairs=int(w.sum()),
    )

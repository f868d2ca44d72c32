"""Registration of sensors from the body itself: the floor under the feet, the trunk as the target.

Where no calibration object was recorded (the real KinectMultiTrack logs, ``docs/real_data.md``),
the tracked body calibrates the sensors: the plane of the standing feet gives each sensor's up
and height (:func:`fit_foot_plane`, :func:`world_from_floor`), and the trunk joints that two
sensors see at the same instants give their relative pose (:func:`refine_registration`).
:func:`calibrate_from_body` does both for any number of sensors and grades the result from its
own evidence (the trunk residual, two halves of the frames, how far the person walked): the live
server's calibration without a wand (:mod:`kinefuse.live.server.person`). Pure: arrays in, frozen
dataclasses out.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.capture.sync.assembly import interpolate
from kinefuse.core.geometry.rotations import rotation_vector_deg
from kinefuse.core.geometry.transforms import fit_plane, kabsch, make_transform
from kinefuse.core.skeleton import JOINT_INDEX, TRUNK_JOINTS
from kinefuse.errors import InputError

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
    spread_m : float
        How far those samples spread over the plane: the standard deviation along its narrower
        axis, metres (NaN for the fallback). Feet that only stood in one place leave the tilt
        about the line between them undetermined.
    """

    up: Array
    height_m: float
    rms_m: float
    n_samples: int
    spread_m: float = float("nan")


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
            flat = pts - np.outer((pts - centre) @ normal, normal)
            ev = np.linalg.eigvalsh(np.cov(flat.T))
            return FloorFit(
                up=normal,
                height_m=float(-(centre @ normal)),
                rms_m=rms,
                n_samples=len(pts),
                spread_m=float(np.sqrt(max(ev[1], 0.0))),
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


# --------------------------------------------------------------------------------------------
# every sensor from the body, graded (the live server's calibration without a wand)
# --------------------------------------------------------------------------------------------

#: Median trunk-joint distance between a sensor and the reference after the fit above which the
#: calibration is doubtful / failed, metres. Two Kinects that see the same person disagree by
#: 1-2 cm side by side and 4-6 cm at 90 degrees even when registered on the whole take
#: (``docs/calibration.md``, "Calibration from the person"); a body that fits no rigid pose (a
#: sensor that sees the back and swaps left and right, another person) is 15 cm and more off.
BODY_RESIDUAL_DOUBTFUL_M = 0.065
BODY_RESIDUAL_FAILED_M = 0.150
#: How far the middle of the person's path moves between the poses fitted on two halves of the
#: frames (alternate ``BODY_HALVES_BLOCK_S`` blocks) above which the calibration is doubtful /
#: failed, metres.
BODY_HALVES_DOUBTFUL_M = 0.030
BODY_HALVES_FAILED_M = 0.100
BODY_HALVES_BLOCK_S = 2.0
#: The spread of the person's path across the floor (the standard deviation of the trunk's
#: position along the path's narrower horizontal axis, frames both sensors see): below the first
#: the trunk alone leaves the rotation between two sensors loose by several degrees and the
#: calibration is failed (not used); below the second it is doubtful. A person standing still
#: spreads a few millimetres, walking a 2 m square about 0.3 m.
BODY_SPREAD_FAILED_M = 0.10
BODY_SPREAD_GOOD_M = 0.25
#: The spread of the reference's standing feet over the floor below which the floor's tilt is
#: doubtful (:attr:`FloorFit.spread_m`): a person who only stood in one place gives two patches.
BODY_FLOOR_SPREAD_M = 0.15


@dataclass(frozen=True)
class BodySensorFit:
    """How one sensor was registered from the body (see :class:`BodyCalibration`).

    Attributes
    ----------
    residual_m : float
        Median trunk-joint distance to the reference after the fit, metres (0 for the reference).
    n_frames : int
        Frames paired with the reference (0 for the reference).
    spread_m : float
        Spread of the trunk across the floor over those frames, metres (NaN for the reference).
    halves_m : float
        How far the middle of the path moves between the fits on two halves, metres (NaN:
        unchecked).
    halves_deg : float
        The rotation between those two fits, degrees.
    """

    residual_m: float
    n_frames: int
    spread_m: float
    halves_m: float
    halves_deg: float


@dataclass(frozen=True)
class BodyCalibration:
    """Every sensor's pose from the tracked person (:func:`calibrate_from_body`).

    Attributes
    ----------
    reference : str
        The sensor the others are registered onto.
    sensor2world : dict of str to (4, 4) float
        The registered sensors' poses (the reference's too unless it was given as fixed).
    fits : dict of str to BodySensorFit
        Per registered sensor other than the reference.
    floor : FloorFit or None
        The reference's floor (None: the reference's pose was given).
    grade : str
        ``"good"``, ``"doubtful"`` or ``"failed"``.
    reasons : tuple of str
        One line per thing that makes it worse than good.
    unregistered : dict of str to str
        Sensors that could not be registered, and why.
    """

    reference: str
    sensor2world: dict[str, Array]
    fits: dict[str, BodySensorFit]
    floor: FloorFit | None
    grade: str
    reasons: tuple[str, ...]
    unregistered: dict[str, str]


def _level(x: float, doubtful: float, failed: float) -> int:
    """0 (good), 1 (doubtful: above ``doubtful``) or 2 (failed: above ``failed``)."""
    return 2 if x > failed else 1 if x > doubtful else 0


def _trunk_seen(p: Array) -> NDArray[np.bool_]:
    return np.asarray(np.isfinite(p[:, _TRUNK]).all((-1, -2)))


def _spread_m(p_ref: Array, up: Array) -> float:
    """Standard deviation of the trunk centre along the narrower horizontal axis of its path."""
    c = np.nanmean(p_ref[:, _TRUNK], axis=1)
    c = c[np.isfinite(c).all(1)]
    if len(c) < 3:
        return 0.0
    u = up / np.linalg.norm(up)
    flat = c - np.outer(c @ u, u)
    ev = np.linalg.eigvalsh(np.cov(flat.T))
    return float(np.sqrt(max(ev[1], 0.0)))  # ev[0] ~ 0: the axis along ``up``


def calibrate_from_body(
    tracks: Mapping[str, tuple[ArrayLike, ArrayLike]],
    *,
    fixed: Mapping[str, ArrayLike] | None = None,
    t0_s: float | None = None,
    max_gap_s: float = 0.1,
) -> BodyCalibration:
    """Register sensors from the person they all track, and grade the result.

    The reference is the first sensor (by id) that saw the trunk in at least half as many frames
    as the one that saw it most (among the ``fixed`` ones when some are). Without fixed poses the
    world comes from the reference's standing feet (:func:`fit_foot_plane`,
    :func:`world_from_floor`: z up, origin on the foot plane below the reference). Every other
    sensor is registered rigidly onto the reference from the trunk joints at the same instants
    (:func:`refine_registration`), and again on two halves of the frames (alternate
    ``BODY_HALVES_BLOCK_S`` blocks from ``t0_s``).

    The grade (thresholds ``BODY_*`` above): failed when a sensor's trunk fits no rigid pose
    (residual), its pose moves a lot between the halves, or the person has not moved across the
    floor (the spread); doubtful for the milder cases, when a sensor could not be registered, or
    when the reference saw no standing feet (the floor is then a guess: a level sensor 1 m up).

    Parameters
    ----------
    tracks : mapping sensor id -> (t_s (N,), joints (N, 25, 3))
        Each sensor's frames in its own frame, capture times on one clock (strictly increasing).
    fixed : mapping sensor id -> (4, 4), optional
        Sensors whose pose is known (and stays); the others are registered against them.
    t0_s : float, optional
        Start of the halves' blocks (default: the first frame).

    Returns
    -------
    BodyCalibration

    Raises
    ------
    InputError
        No sensor saw the trunk, or (with ``fixed``) no fixed sensor did.
    """
    data = {
        s: (np.asarray(t, dtype=np.float64), np.asarray(p, dtype=np.float64))
        for s, (t, p) in tracks.items()
    }
    seen = {s: int(_trunk_seen(p).sum()) for s, (_, p) in data.items() if len(p)}
    fx = {s: np.asarray(v, dtype=np.float64) for s, v in (fixed or {}).items()}
    pool = [s for s in seen if s in fx] if fx else list(seen)
    pool = [s for s in pool if seen[s] > 0]
    if not pool:
        raise InputError(
            "no " + ("calibrated " if fx else "")
            + "sensor saw the person's trunk; step into the sensors' view"
        )  # fmt: skip
    # the first by id of those that saw it in at least half as many frames as the most (so that
    # the reference, hence the world, stays put as frames come in)
    ref = min(s for s in pool if seen[s] >= 0.5 * max(seen[x] for x in pool))
    t_ref, p_ref = data[ref]
    floor: FloorFit | None = None
    if ref in fx:
        ref2world = fx[ref]
        up: Array = np.asarray(ref2world[2, :3], dtype=np.float64)  # world z in the sensor frame
    else:
        floor = fit_foot_plane(t_ref, p_ref)
        ref2world = world_from_floor(floor)
        up = floor.up
    poses = {} if ref in fx else {ref: ref2world}
    starts = [float(t[0]) for t, _ in data.values() if len(t)]
    t0 = min(starts) if t0_s is None else float(t0_s)
    fits: dict[str, BodySensorFit] = {}
    unregistered: dict[str, str] = {}
    worst = 0
    reasons: list[str] = []

    def flag(level: int, text: str) -> None:
        nonlocal worst
        worst = max(worst, level)
        reasons.append(f"{('good', 'doubtful', 'failed')[level]}: {text}")

    for sid in sorted(data):
        if sid == ref or sid in fx:
            continue
        t_o, p_o = data[sid]
        try:
            reg = refine_registration(t_ref, p_ref, t_o, p_o, max_gap_s=max_gap_s)
        except InputError as e:
            unregistered[sid] = str(e)
            flag(1, f"sensor {sid} was not registered: {e}")
            continue
        po = interpolate(t_o, p_o, t_ref, max_gap_s=max_gap_s)
        both = _trunk_seen(p_ref) & _trunk_seen(po)
        spread = _spread_m(p_ref[both], up)
        centre = np.append(np.nanmedian(p_ref[both][:, _TRUNK].reshape(-1, 3), axis=0), 1.0)
        halves = []
        for h in (0, 1):
            kr = np.floor((t_ref - t0) / BODY_HALVES_BLOCK_S).astype(np.int64) % 2 == h
            ko = np.floor((t_o - t0) / BODY_HALVES_BLOCK_S).astype(np.int64) % 2 == h
            try:
                halves.append(
                    refine_registration(
                        t_ref[kr], p_ref[kr], t_o[ko], p_o[ko], max_gap_s=max_gap_s
                    ).other2ref
                )
            except InputError:
                break
        if len(halves) == 2:
            moved = float(np.linalg.norm((halves[0] - halves[1]) @ centre))
            turn = float(
                np.linalg.norm(rotation_vector_deg(halves[0][:3, :3].T @ halves[1][:3, :3]))
            )
        else:
            moved = turn = float("nan")
        fits[sid] = BodySensorFit(reg.trunk_median_after_m, reg.n_pairs // len(_TRUNK), spread,
                                  moved, turn)  # fmt: skip
        poses[sid] = ref2world @ reg.other2ref
        res = reg.trunk_median_after_m
        lv = _level(res, BODY_RESIDUAL_DOUBTFUL_M, BODY_RESIDUAL_FAILED_M)
        if lv:
            limit = (BODY_RESIDUAL_DOUBTFUL_M, BODY_RESIDUAL_FAILED_M)[lv - 1]
            why = ": does it see the person's back, or another person?" if lv == 2 else ""
            flag(lv, f"sensor {sid}: its trunk is {1e3 * res:.0f} mm from {ref}'s after the "
                 f"fit (over {1e3 * limit:.0f} mm){why}")  # fmt: skip
        lv = _level(-spread, -BODY_SPREAD_GOOD_M, -BODY_SPREAD_FAILED_M)
        if lv:
            flag(lv, f"sensors {ref} and {sid} saw the person together over {1e2 * spread:.0f} "
                 f"cm of floor (need {1e2 * BODY_SPREAD_GOOD_M:.0f} cm): walk through the "
                 "volume")  # fmt: skip
        lv = _level(moved, BODY_HALVES_DOUBTFUL_M, BODY_HALVES_FAILED_M)
        if not np.isfinite(moved):
            flag(1, f"sensor {sid}: its pose could not be checked on two halves of the frames")
        elif lv:
            limit = (BODY_HALVES_DOUBTFUL_M, BODY_HALVES_FAILED_M)[lv - 1]
            flag(lv, f"sensor {sid}: the middle of the path moves {1e3 * moved:.0f} mm between "
                 f"fits on two halves of the frames (over {1e3 * limit:.0f} mm)")  # fmt: skip
    if not fits:
        flag(2, f"no sensor was registered onto {ref} (need two sensors that see the person at "
             "the same time)")  # fmt: skip
    if floor is not None and floor.n_samples == 0:
        flag(1, f"sensor {ref} saw no standing feet, so the floor is a guess (a level sensor 1 m "
             "up): stand still for a few seconds in its view")  # fmt: skip
    elif floor is not None and not floor.spread_m >= BODY_FLOOR_SPREAD_M:
        flag(1, f"the feet stood on {1e2 * floor.spread_m:.0f} cm of floor in sensor {ref}'s "
             f"view (need {1e2 * BODY_FLOOR_SPREAD_M:.0f} cm), so the floor's tilt is loose: "
             "walk through the volume")  # fmt: skip
    return BodyCalibration(
        reference=ref,
        sensor2world=poses,
        fits=fits,
        floor=floor,
        grade=("good", "doubtful", "failed")[worst],
        reasons=tuple(reasons),
        unregistered=unregistered,
    )

"""Normalization (paper B, METHODS.md B.1): default pose, body planes, a limb frame per frame.

1. **Default pose**: the frame of lowest cost, the cost summing three heuristics on the joints
   (each divided by its median over the frames so that none dominates by its unit): the mean
   squared distance to their best-fitting plane, the edge ratio (short / long) of the 2D bounding
   box of the joints projected into that plane, and the mean distance to their centre of gravity;
   plus a fourth of ours, stillness (see :func:`default_pose_costs`).
2. **Body planes** from that frame: frontal plane = best-fitting plane (its normal, signed
   forward, is the body ``x``); transverse normal = the global up made orthogonal to ``x`` (body
   ``z``); sagittal normal ``y = z × x`` (to the subject's left).
3. **Limb frames** at the default pose: the limb's main orientation ``u`` (proximal -> distal);
   of the body normals, the two most orthogonal to ``u`` are projected into the plane orthogonal
   to ``u`` (Gram-Schmidt) and the third axis completes them, so every limb frame keeps the body
   axes' labels (``x`` forward, ``y`` left, ``z`` up in the default pose). Placed at the midpoint.
4. **Propagation**: the constant transform between a limb's *original* frame and its normalized
   frame at the default pose is applied to every frame. The original frame is the source's own
   limb rotation where it has one (BVH, ASF/AMC, marker clusters). For position-only skeletons it
   is built from the limb's joints and a neighbour (:attr:`Limb.twist_ref`). The neighbour can
   be nearly parallel to the limb (a straight elbow): the twist then is weighted down smoothly
   toward the frame carried from the parent by the minimal rotation (weight 0 below 15°, 1 above
   35° between limb and reference), and the constant transform is the mean over the
   well-conditioned frames whose limb direction is within 25° of the default pose's (where the
   carried frame is exact up to noise), else taken at the nearest well-conditioned frame. Both
   choices are ours; the paper's marker bodies always give a full frame.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from kinefuse.biomech._vec import dot, tmm, tmv, twist_angle, wrap
from kinefuse.biomech.limbs import LIMB_INDEX, LIMB_PARENTS, LIMBS, Limb
from kinefuse.biomech.sequence import SkeletonSequence
from kinefuse.core.geometry.rotations import (
    chordal_mean,
    frames_from_vectors,
    minimal_rotation,
    rodrigues,
    unit,
)
from kinefuse.core.skeleton import JOINT_INDEX
from kinefuse.errors import InputError

Array = NDArray[np.float64]

#: Joints of the body used for the default-pose cost and the body planes (the hand tips, thumbs
#: and feet are left out: the least reliable joints of depth sensors).
BODY_JOINTS = (
    "SpineBase", "SpineMid", "SpineShoulder", "Neck", "Head", "ShoulderLeft", "ElbowLeft",
    "WristLeft", "ShoulderRight", "ElbowRight", "WristRight", "HipLeft", "KneeLeft", "AnkleLeft",
    "HipRight", "KneeRight", "AnkleRight",
)  # fmt: skip
#: Body joints without which there is no default pose or body frame; the others (head, neck,
#: elbows, wrists) are used when the source has them (marker sets often have no head).
REQUIRED_JOINTS = (
    "SpineBase", "SpineMid", "SpineShoulder", "ShoulderLeft", "ShoulderRight", "HipLeft",
    "KneeLeft", "AnkleLeft", "HipRight", "KneeRight", "AnkleRight",
)  # fmt: skip
#: A partial body (an upper- or lower-body-only capture) needs the root and one of these two
#: groups whole: the body frame's left-right line then comes from the shoulders or the hips
#: alone, and the limbs whose joints are absent get no frame (their status says which joint).
UPPER_BODY_JOINTS = ("SpineMid", "SpineShoulder", "ShoulderLeft", "ShoulderRight")
LOWER_BODY_JOINTS = ("HipLeft", "KneeLeft", "AnkleLeft", "HipRight", "KneeRight", "AnkleRight")
#: Below this angle between a limb and its twist reference the twist weight is 0, above the
#: second it is 1 (degrees; a straight elbow or knee leaves the twist unobservable).
TWIST_WEIGHT_DEG = (15.0, 35.0)
#: Frames whose limb direction is within this angle of the default pose's give the constant of
#: a position-only twist (degrees).
NEAR_DEFAULT_DEG = 25.0
#: A position-derived twist more uncertain than this per frame (see :func:`_twist_noise`) is
#: not observable: the limb's frame is carried from its parent and its twist is NaN (degrees;
#: 1 cm of joint noise gives the forearm's twist from hand and thumb, 3 cm apart, about 25°,
#: the shank's from the foot, 12 cm, about 7°).
TWIST_NOISE_MAX_DEG = 10.0
#: The frames within this span around the default-pose frame are averaged (seconds).
DEFAULT_WINDOW_S = 0.5


@dataclass(frozen=True, eq=False)
class Normalization:
    """Normalized limb frames of a sequence.

    Attributes
    ----------
    default_frame : int
        Index of the default-pose frame.
    body2world : (3, 3) float
        Body frame (columns x forward, y left, z up) in the world at the default pose.
    frames : (T, L, 3, 3) float
        Normalized limb-to-world rotation per frame and limb (:data:`~kinefuse.biomech.limbs.
        LIMBS` order); NaN where the limb's joints are missing.
    origins : (T, L, 3) float
        Limb midpoints, metres (where the normalized frames are placed).
    long_axis : (L, 3) float
        The limb's long axis (proximal -> distal) in its own normalized frame (a signed body
        axis: ``-z`` for a hanging thigh). The root (pelvis) carries the body frame itself, as
        in the paper, so its ``z`` is the body's up rather than SpineBase -> SpineMid.
    twist_weight : (T, L) float
        How observable the twist is in each frame, 0 to 1 (1 for sources with orientations).
    status : dict str -> str
        Per limb: ``"ok"``, or what is missing or not observable, in words.
    observable : dict str -> dict
        Per limb: ``{"swing_axes": n, "twist": "observable" | "when bent" | "not observable",
        "twist_frames": fraction of frames with weight 1}``.
    costs : (T,) float
        Default-pose cost per frame (NaN where joints are missing).
    constants : dict str -> LimbConstants
        What :func:`propagate` applies to new frames.
    """

    default_frame: int
    body2world: Array
    frames: Array
    origins: Array
    long_axis: Array
    twist_weight: Array
    status: dict[str, str] = field(default_factory=dict)
    observable: dict[str, dict[str, object]] = field(default_factory=dict)
    costs: Array = field(default_factory=lambda: np.zeros(0))
    constants: dict[str, LimbConstants] = field(default_factory=dict)

    def transforms(self) -> Array:
        """Limb-to-world transforms ``(T, L, 4, 4)`` (rotation :attr:`frames`, origin midpoint)."""
        t, n = self.frames.shape[:2]
        out = np.zeros((t, n, 4, 4))
        out[..., :3, :3] = self.frames
        out[..., :3, 3] = self.origins
        out[..., 3, 3] = 1.0
        return out

    def frame(self, limb: str) -> Array:
        """Normalized frames ``(T, 3, 3)`` of one limb."""
        return self.frames[:, LIMB_INDEX[limb]]


def default_pose_costs(positions: Array, rate_hz: float | None = None) -> Array:
    """The heuristics' cost per frame ``(T,)`` for body joints ``(T, J, 3)`` (metres).

    The paper's three, plus (when ``rate_hz`` is given) a fourth of ours: the mean joint speed
    averaged over half a second, because a default pose is *held*. Without it a momentary pose
    can beat the held one (a trunk turned by 30° fits a plane better than a slightly staggered
    stance). NaN for frames with a missing body joint. Each term is divided by its median over
    the valid frames before they are summed.
    """
    p = np.asarray(positions, dtype=np.float64)
    ok = np.isfinite(p).all(axis=(1, 2))
    cost = np.full(p.shape[0], np.nan)
    if not ok.any():
        return cost
    q = p[ok]
    c = q - q.mean(axis=1, keepdims=True)
    n = q.shape[1]
    lam, vec = np.linalg.eigh(np.matmul(np.swapaxes(c, 1, 2), c) / n)  # ascending
    plane = np.maximum(lam[:, 0], 0.0)  # mean squared distance to the best-fitting plane
    a = np.matmul(c, vec[:, :, 2:3])[..., 0]
    b = np.matmul(c, vec[:, :, 1:2])[..., 0]
    ea, eb = np.ptp(a, axis=1), np.ptp(b, axis=1)
    ratio = np.minimum(ea, eb) / np.maximum(np.maximum(ea, eb), 1e-9)
    spread = np.linalg.norm(c, axis=-1).mean(axis=1)
    terms = [plane, ratio, spread]
    if rate_hz is not None and p.shape[0] > 2:
        terms.append(_stillness(p, float(rate_hz))[ok])
    cost[ok] = sum(t / max(float(np.median(t)), 1e-12) for t in terms)
    return cost


def _stillness(p: Array, rate_hz: float, window_s: float = 0.5) -> Array:
    """Mean joint speed per frame (m/s), averaged over ``window_s``, NaN-aware."""
    sp = np.full(p.shape[0], np.nan)
    sp[1:] = np.linalg.norm(np.diff(p, axis=0), axis=-1).mean(axis=1) * rate_hz
    sp[0] = sp[1]
    ok = np.isfinite(sp)
    half = max(round(window_s * rate_hz / 2), 1)
    c = np.concatenate([[0.0], np.cumsum(np.where(ok, sp, 0.0))])
    n = np.concatenate([[0], np.cumsum(ok)])
    i = np.arange(p.shape[0])
    lo, hi = np.clip(i - half, 0, p.shape[0]), np.clip(i + half + 1, 0, p.shape[0])
    with np.errstate(invalid="ignore", divide="ignore"):
        out = (c[hi] - c[lo]) / (n[hi] - n[lo])
    return np.where(np.isfinite(out), out, np.nanmedian(sp) if ok.any() else 1.0)


def find_default_pose(seq: SkeletonSequence, /) -> int:
    """Index of the frame closest to the anatomical default pose (upright, arms hanging)."""
    return int(_default(seq)[0])


def _body_joints(seq: SkeletonSequence) -> tuple[str, ...]:
    """The :data:`BODY_JOINTS` the sequence has; a clear error if a required one is absent."""
    missing = [n for n in REQUIRED_JOINTS if not seq.has(n)]
    if missing and not partial_body(seq.joint_names):
        lack_up = [n for n in ("SpineBase", *UPPER_BODY_JOINTS) if not seq.has(n)]
        lack_low = [n for n in ("SpineBase", *LOWER_BODY_JOINTS) if not seq.has(n)]
        raise InputError(
            f"normalization needs the body joints {', '.join(missing)}, which "
            f"{seq.source or 'the sequence'} lacks; map them (a marker map, a name map) first. "
            f"An upper-body-only input needs {', '.join(('SpineBase', *UPPER_BODY_JOINTS))} "
            f"(missing: {', '.join(lack_up)}); a lower-body-only input needs "
            f"{', '.join(('SpineBase', *LOWER_BODY_JOINTS))} (missing: {', '.join(lack_low)})"
        )
    return tuple(n for n in BODY_JOINTS if seq.has(n) and seq.mask[:, seq.index(n)].any())


def partial_body(joints: Sequence[str]) -> str | None:
    """``"upper"`` or ``"lower"`` when ``joints`` lack some :data:`REQUIRED_JOINTS` but hold
    SpineBase and the :data:`UPPER_BODY_JOINTS` (or the :data:`LOWER_BODY_JOINTS`): a partial
    body normalization can work on; ``None`` for a full body or too little."""
    have = set(joints)
    if set(REQUIRED_JOINTS) <= have or "SpineBase" not in have:
        return None
    if set(UPPER_BODY_JOINTS) <= have:
        return "upper"
    if set(LOWER_BODY_JOINTS) <= have:
        return "lower"
    return None


def _default(seq: SkeletonSequence) -> tuple[int, Array]:
    names = _body_joints(seq)
    idx = [seq.index(n) for n in names]
    costs = default_pose_costs(seq.positions[:, idx], seq.rate_hz)
    if not np.isfinite(costs).any():
        raise InputError(
            "no frame has all body joints present, so no default pose can be found; "
            f"needed in one frame: {', '.join(names)}"
        )
    return int(np.nanargmin(costs)), costs


def body_frame(joints: Array, /, up: Array | None = None) -> Array:
    """Body frame ``(3, 3)`` (columns x forward, y left, z up) from the body joints ``(25, 3)``.

    ``joints`` is on the full Kinect topology; the finite :data:`BODY_JOINTS` are used.
    """
    up_v = np.array([0.0, 0.0, 1.0]) if up is None else unit(np.asarray(up, float))
    q = joints[[JOINT_INDEX[n] for n in BODY_JOINTS]]
    q = q[np.isfinite(q).all(axis=-1)]  # the body joints the source has
    _, _, vt = np.linalg.svd(q - q.mean(axis=0))
    x = vt[2]
    j = JOINT_INDEX
    hips = joints[j["HipLeft"]] - joints[j["HipRight"]]
    shoulders = joints[j["ShoulderLeft"]] - joints[j["ShoulderRight"]]
    if np.isfinite(hips).all() and np.isfinite(shoulders).all():
        left = hips + shoulders
    else:  # a partial body (upper or lower only): the line it has
        left = hips if np.isfinite(hips).all() else shoulders
    if dot(x, np.cross(left, up_v)) < 0:  # forward = left x up
        x = -x
    z = unit(up_v - dot(up_v, x) * x)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=-1)


def limb_frame_from_body(u: Array, body: Array, k: int | None = None) -> tuple[Array, int, float]:
    """The paper's limb frame ``(3, 3)`` for main orientation ``u`` and body frame ``body``.

    ``k`` is the body axis the limb axis replaces (default: the one closest to ``u``, the
    paper's choice). Returns the frame, ``k`` and the sign (the limb direction is
    ``sign * frame[:, k]``).
    """
    u = unit(u)
    if k is None:
        k = int(np.argmax(np.abs(body.T @ u)))
    a, b = (k + 1) % 3, (k + 2) % 3
    ea = unit(body[:, a] - dot(body[:, a], u) * u)
    eb = body[:, b] - dot(body[:, b], u) * u
    eb = unit(eb - dot(eb, ea) * ea)
    f = np.zeros((3, 3))
    f[:, a], f[:, b] = ea, eb
    f[:, k] = np.cross(ea, eb)
    return f, k, float(np.sign(dot(f[:, k], u)))


def _weight(sin_t: Array) -> Array:
    lo, hi = np.sin(np.radians(TWIST_WEIGHT_DEG))
    w = np.clip((sin_t - lo) / (hi - lo), 0.0, 1.0)
    return np.where(np.isfinite(w), w, 0.0)


def normalize(seq: SkeletonSequence, /, default_frame: int | None = None) -> Normalization:
    """Normalized limb frames for every frame of ``seq`` (METHODS.md B.1).

    Parameters
    ----------
    seq : SkeletonSequence
        The sequence; must contain the :data:`REQUIRED_JOINTS` (and uses the other
        :data:`BODY_JOINTS` it has).
    default_frame : int, optional
        Use this frame as the default pose instead of searching for it.

    Returns
    -------
    Normalization
    """
    d, costs = _default(seq)
    if default_frame is not None:
        if not 0 <= int(default_frame) < seq.n_frames:
            raise InputError(
                f"default_frame must be a frame index 0..{seq.n_frames - 1}, got {default_frame}"
            )
        d = int(default_frame)
    p = seq.kinect_positions()
    t = seq.n_frames
    # the default pose is held: average the frames of half a second around it (ours), so that
    # one noisy frame does not set the constants of the whole recording
    half = max(round(DEFAULT_WINDOW_S * seq.rate_hz / 2), 0)
    win = np.arange(max(d - half, 0), min(d + half + 1, t))
    win = win[np.isfinite(costs[win])] if np.isfinite(costs[win]).any() else np.array([d])
    # the mean over the window of each joint seen in it (NaN, without a warning, for a joint
    # missing in all of it: the marker sets without some Kinect joints)
    seen = np.isfinite(p[win]).sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        body = body_frame(np.where(seen > 0, np.nansum(p[win], axis=0) / seen, np.nan))
    if not np.isfinite(body).all():
        raise InputError(f"the default-pose frame {d} lacks body joints; choose another frame")
    root_note = ""
    sb, sm = JOINT_INDEX["SpineBase"], JOINT_INDEX["SpineMid"]
    if partial_body(seq.joint_names) == "lower" and not np.isfinite(p[:, sm]).any():
        # a lower-body-only input has no SpineMid: the pelvis's long axis is then the line from
        # the hip centres' midpoint through SpineBase (both rigid with the pelvis), put where
        # SpineMid would be for the root's frame only
        p = p.copy()
        hip_mid = 0.5 * (p[:, JOINT_INDEX["HipLeft"]] + p[:, JOINT_INDEX["HipRight"]])
        p[:, sm] = p[:, sb] + (p[:, sb] - hip_mid)
        root_note = (
            "SpineMid missing (lower body only): the long axis runs from the hip centres' "
            "midpoint through SpineBase"
        )
    n = len(LIMBS)
    frames = np.full((t, n, 3, 3), np.nan)
    origins = np.full((t, n, 3), np.nan)
    long_axis = np.zeros((n, 3))
    weight = np.zeros((t, n))
    status: dict[str, str] = {}
    observable: dict[str, dict[str, object]] = {}
    constants: dict[str, LimbConstants] = {}
    noisy: dict[str, str] = {}
    for i, lb in enumerate(LIMBS):
        u = p[:, lb.distal_index] - p[:, lb.proximal_index]
        origins[:, i] = 0.5 * (p[:, lb.distal_index] + p[:, lb.proximal_index])
        present: NDArray[np.bool_] = np.asarray(np.isfinite(u).all(axis=-1))
        if not present[d]:
            gone = [
                j for j in (lb.proximal, lb.distal) if not np.isfinite(p[d, JOINT_INDEX[j]]).all()
            ]
            status[lb.name] = f"{' and '.join(gone)} missing in the default pose"
            observable[lb.name] = {"swing_axes": lb.n_axes, "twist": "not observable"}
            continue
        n0, k, s = limb_frame_from_body(np.nanmean(u[win], axis=0), body, lb.body_axis)
        if LIMB_PARENTS[i] < 0:
            n0 = body  # the paper: the body coordinate system is the torso's (the root's)
        long_axis[i, k] = s
        src = seq.orientation(lb.name)
        carried = None
        if src is not None and np.isfinite(src[d]).all():
            # the paper's propagation: constant original-to-normalized transform
            c_src = _mean_rot(tmm(src[win], n0))
            k_i = LimbConstants("orientation", c_src, np.eye(3), np.zeros(3), long_axis[i])
        else:
            src = None
            k_i, carried = _position_constants(p, lb, i, d, win, n0, long_axis[i], frames)
        noise = float("nan")
        ref = None
        if k_i.kind == "twist":
            assert carried is not None
            ref = _reference_twist(lb, k_i, p, carried)
            noise, across = _twist_noise(lb, p, *ref)
            if noise > np.radians(TWIST_NOISE_MAX_DEG):  # not observable: carry the frame
                k_i = LimbConstants("carried", np.eye(3), k_i.l0, k_i.d0, k_i.axis)
                noisy[lb.name] = (
                    f"twist not observable: its reference {lb.twist_ref[0]}->{lb.twist_ref[1]} "
                    f"({100 * across:.0f} cm across the limb) is uncertain by "
                    f"{np.degrees(noise):.0f}° per frame (over {TWIST_NOISE_MAX_DEG:g}°)"
                )
        constants[lb.name] = k_i
        par = LIMB_PARENTS[i]
        frames[:, i], weight[:, i] = _limb_frames(
            lb, k_i, p, frames[:, par] if par >= 0 else None, src, carried, ref
        )
        if k_i.kind == "carried":
            tw_kind = "not observable"
        elif k_i.kind == "twist" and (weight[:, i] >= 1).mean() <= 0.95:
            tw_kind = "when bent"
        else:
            tw_kind = "observable"
        frac_missing = 1.0 - present.mean()
        twist_frames = float((weight[:, i] >= 1.0).mean())
        observable[lb.name] = {
            "swing_axes": lb.n_axes,
            "twist": tw_kind,
            "twist_frames": twist_frames,
        }
        if np.isfinite(noise):
            observable[lb.name]["twist_noise_deg"] = float(np.degrees(noise))
        if root_note and LIMB_PARENTS[i] < 0:
            observable[lb.name]["long_axis"] = root_note
        msg = []
        if frac_missing > 0:
            msg.append(f"joints missing in {int((~present).sum())} of {t} frames")
        if lb.name in noisy:
            msg.append(noisy[lb.name])
        elif tw_kind == "not observable":
            msg.append("twist not observable from positions")
        status[lb.name] = "ok" if not msg else "; ".join(msg)
    return Normalization(
        default_frame=d,
        body2world=body,
        frames=frames,
        origins=origins,
        long_axis=long_axis,
        twist_weight=weight,
        status=status,
        observable=observable,
        costs=costs,
        constants=constants,
    )


@dataclass(frozen=True, eq=False)
class LimbConstants:
    """The constant part of one limb's normalization (what propagates to every frame).

    ``kind``: ``"orientation"`` (the source's rotation times ``c``), ``"root"`` (the frame of
    the joints and the reference times ``c``), ``"carried"`` (the parent's frame, the minimal
    swing from the default direction ``d0`` (parent frame), then ``l0``), or ``"twist"``
    (carried, then turned about ``axis`` toward the reference's frame times ``c``).
    """

    kind: str
    c: Array
    l0: Array
    d0: Array
    axis: Array


def root_long_axis(p: Array) -> Array:
    """The pelvis's long axis ``(T, 3)`` (not unit) for its frame: from the hip centres'
    midpoint to SpineMid (the limb itself stays SpineBase -> SpineMid).

    Not SpineBase -> SpineMid, 17-18 cm apart: a depth sensor that sees the body from behind
    fits a body it believes turned around, and its SpineMid lands several cm in front, its
    SpineBase behind (fused, in a seed-1 session of ``studies/analysis_sweep.py``: +4.5 /
    -1.2 cm while that sensor took part, about nothing otherwise). The pelvis tilted by up to
    16 deg at each switch, and the trunk's and thighs' angles and axes with it (trunk axes 15-35
    deg off over that subject's sessions, their floor under 6 deg). The hips' midpoint is 10-12
    cm lower and, the mean of two joints, less biased there (the axis's direction error, phase
    median, 18 -> 7 deg). Where the hips are the worse joints (the bench's tilted rig seen at
    -75 deg: the left hip's height follows the legs by 1-10 cm) it costs: docs/analysis_measured.md,
    "The pelvis's long axis", has both."""
    hip_mid = 0.5 * (p[:, JOINT_INDEX["HipLeft"]] + p[:, JOINT_INDEX["HipRight"]])
    return p[:, JOINT_INDEX["SpineMid"]] - hip_mid


def _limb_frames(
    lb: Limb,
    k: LimbConstants,
    p: Array,
    fp: Array | None,
    src: Array | None,
    carried: Array | None = None,
    ref: tuple[Array, Array] | None = None,
) -> tuple[Array, Array]:
    """Normalized frames ``(T, 3, 3)`` and twist weight ``(T,)`` of one limb, any ``T``
    (``carried``: the carried frames when already computed with the same constants; ``ref``:
    :func:`_reference_twist` of them)."""
    u = p[:, lb.distal_index] - p[:, lb.proximal_index]
    if k.kind == "orientation":
        assert src is not None
        return src @ k.c, np.isfinite(src).all(axis=(1, 2)).astype(float)
    if k.kind == "root":
        r = p[:, JOINT_INDEX[lb.twist_ref[1]]] - p[:, JOINT_INDEX[lb.twist_ref[0]]]
        o = frames_from_vectors(root_long_axis(p), r)
        return o @ k.c, np.isfinite(o).all(axis=(1, 2)).astype(float)
    assert fp is not None
    if carried is None:
        d_loc = unit(tmv(fp, u))
        carried = fp @ minimal_rotation(np.broadcast_to(k.d0, d_loc.shape), d_loc) @ k.l0
    if k.kind == "carried":
        return carried, np.zeros(u.shape[0])
    psi, w = _reference_twist(lb, k, p, carried) if ref is None else ref
    ax = np.broadcast_to(k.axis, u.shape)
    return carried @ rodrigues(ax, w * np.where(np.isfinite(psi), psi, 0.0)), w


def _reference_twist(lb: Limb, k: LimbConstants, p: Array, carried: Array) -> tuple[Array, Array]:
    """The twist ``(T,)`` rad (NaN where undefined) from the carried frames to the reference's
    frames (times ``k.c``) about the limb's long axis, and the reference's weight ``(T,)``."""
    u = p[:, lb.distal_index] - p[:, lb.proximal_index]
    r = p[:, JOINT_INDEX[lb.twist_ref[1]]] - p[:, JOINT_INDEX[lb.twist_ref[0]]]
    w = _weight(np.linalg.norm(np.cross(unit(u), unit(r)), axis=-1))
    f = frames_from_vectors(u, r)
    if lb.one_way:
        # a bend the other way is the same hinge plane (Limb.one_way): its frame is turned by
        # 180° about the limb (before the twist is measured: a half turn's twist is undefined)
        expected = carried @ k.c.T  # the reference's frame for a bend the usual way
        back = dot(f[..., :, 1], expected[..., :, 1]) < 0.0
        f = np.where(back[..., None, None], f * np.array([1.0, -1.0, -1.0]), f)
    g = f @ k.c  # the reference's frame, equal to carried where c was taken
    return twist_angle(tmm(carried, g), np.broadcast_to(k.axis, u.shape)), w


def _twist_noise(lb: Limb, p: Array, psi: Array, w: Array) -> tuple[float, float]:
    """How uncertain a position-derived twist ``psi (T,)`` (weights ``w``, from
    :func:`_reference_twist`) is (rad, per frame), and the reference's median length across the
    limb (metres), from the data alone.

    The larger of two estimates, over the frames with full weight: the frame-to-frame noise
    of the twist (:func:`twist_jitter`; white noise), and the spread of the reference's length
    (a rigid pair of joints keeps it; 1.4826 MAD) over its length across the limb, as an angle
    (an error of the joints moves the reference across as much as along; this also sees slow
    errors that a smoothing filter leaves, unless the filter holds the length itself).
    """
    u = unit(p[:, lb.distal_index] - p[:, lb.proximal_index])
    r = p[:, JOINT_INDEX[lb.twist_ref[1]]] - p[:, JOINT_INDEX[lb.twist_ref[0]]]
    full = (w >= 1.0) & np.isfinite(r).all(axis=-1) & np.isfinite(u).all(axis=-1)
    if full.sum() < 10:
        return float("nan"), float("nan")
    length = np.linalg.norm(r[full], axis=-1)
    across = float(np.median(np.linalg.norm(np.cross(u[full], r[full]), axis=-1)))
    spread = 1.4826 * float(np.median(np.abs(length - np.median(length))))
    jitter = twist_jitter(psi, w)
    return float(np.nanmax([jitter, np.arctan2(spread, across)])), across


def twist_jitter(psi: Array, w: Array) -> float:
    """Frame-to-frame noise (SD, rad) of a position-derived twist ``psi (T,)`` over the runs of
    three frames with full weight ``w (T,)``; NaN when there are fewer than 10 such runs.

    White noise of SD ``s`` per frame gives second differences of SD ``sqrt(6) s``; the
    motion's own second difference (its acceleration times the frame interval squared) is a
    degree or less for a forearm turning at 1000 °/s² seen at 30 Hz, so a robust SD of the
    wrapped second differences (1.4826 MAD) over ``sqrt(6)`` measures the noise.
    """
    ok = np.isfinite(psi) & (w >= 1.0)
    trip = ok[:-2] & ok[1:-1] & ok[2:]
    if trip.sum() < 10:
        return float("nan")
    d2 = wrap(wrap(psi[2:] - psi[1:-1]) - wrap(psi[1:-1] - psi[:-2]))[trip]
    return float(1.4826 * np.median(np.abs(d2)) / np.sqrt(6.0))


def propagate(
    norm: Normalization, positions: Array, /, orientations: dict[str, Array] | None = None
) -> tuple[Array, Array]:
    """Normalized frames ``(T, L, 3, 3)`` and twist weights ``(T, L)`` of new frames.

    Applies the constants a :func:`normalize` found to other positions ``(T, 25, 3)`` (metres,
    the same subject and world), e.g. frames arriving live after a calibration phase.
    ``orientations`` maps limb names to ``(T, 3, 3)`` source rotations for limbs normalized
    from the source's rotations.
    """
    p = np.asarray(positions, dtype=np.float64)
    if p.ndim != 3 or p.shape[1:] != (len(JOINT_INDEX), 3):
        raise InputError(f"positions must be (T, 25, 3) Kinect joints, got {p.shape}")
    t = p.shape[0]
    frames = np.full((t, len(LIMBS), 3, 3), np.nan)
    weight = np.zeros((t, len(LIMBS)))
    for i, lb in enumerate(LIMBS):
        k = norm.constants.get(lb.name)
        if k is None:
            continue
        par = LIMB_PARENTS[i]
        src = None if orientations is None else orientations.get(lb.name)
        if k.kind == "orientation" and src is None:
            raise InputError(f"limb {lb.name} was normalized from source rotations; pass them")
        frames[:, i], weight[:, i] = _limb_frames(
            lb, k, p, frames[:, par] if par >= 0 else None, src
        )
    return frames, weight


def carried_frames(norm: Normalization, positions: Array, /, limb: str) -> Array:
    """One limb's frames ``(T, 3, 3)`` with its twist carried from its parent (the minimal
    swing from the default direction), not turned toward its twist reference.

    Where the reference was calibrated (a bent knee near the default direction) the two agree;
    where it is weak (a standing knee or elbow, nearly straight, whose bend plane is a few
    centimetres of joint-centre error) the carried frame is the better one. ``positions`` are
    the normalized sequence's ``(T, 25, 3)``. The limb's own frames for a limb whose twist is
    not taken from a reference.
    """
    i = LIMB_INDEX[limb]
    k = norm.constants.get(limb)
    if k is None or k.kind != "twist":
        return norm.frames[:, i]
    lb = LIMBS[i]
    carried = LimbConstants("carried", np.eye(3), k.l0, k.d0, k.axis)
    p = np.asarray(positions, dtype=np.float64)
    return _limb_frames(lb, carried, p, norm.frames[:, LIMB_PARENTS[i]], None)[0]


def _mean_rot(r: Array) -> Array:
    """Chordal mean of the finite rotations ``(N, 3, 3)``; NaN if there is none."""
    r = r[np.isfinite(r).all(axis=(1, 2))]
    return chordal_mean(r) if r.shape[0] else np.full((3, 3), np.nan)


def _position_constants(
    p: Array,
    lb: Limb,
    i: int,
    d: int,
    win: NDArray[np.intp],
    n0: Array,
    axis_l: Array,
    frames: Array,
) -> tuple[LimbConstants, Array | None]:
    """The constants of a position-only limb (parents' ``frames`` already filled), and its
    carried frames ``(T, 3, 3)`` when they were computed on the way."""
    eye = np.eye(3)
    par = LIMB_PARENTS[i]
    u = p[:, lb.distal_index] - p[:, lb.proximal_index]
    if par < 0:  # the root: its frame from its joints and the hip line, always conditioned
        r = p[:, JOINT_INDEX[lb.twist_ref[1]]] - p[:, JOINT_INDEX[lb.twist_ref[0]]]
        o = frames_from_vectors(root_long_axis(p), r)
        c_root = _mean_rot(tmm(o[win], n0))  # n0 is the body frame (see normalize)
        return LimbConstants("root", c_root, eye, np.zeros(3), axis_l), None
    fp = frames[:, par]
    d_loc = unit(tmv(fp, u))
    l0 = _mean_rot(tmm(fp[win], n0))
    with warnings.catch_warnings():  # a limb never seen in the window: NaN, its status says so
        warnings.simplefilter("ignore", RuntimeWarning)
        d0 = unit(np.nanmean(d_loc[win], axis=0))
    l0 = minimal_rotation(l0 @ axis_l, d0) @ l0  # the long axis onto the default direction
    carried_k = LimbConstants("carried", eye, l0, d0, axis_l)
    if not lb.twist_observable:
        return carried_k, None
    carried, _ = _limb_frames(lb, carried_k, p, fp, None)
    r = p[:, JOINT_INDEX[lb.twist_ref[1]]] - p[:, JOINT_INDEX[lb.twist_ref[0]]]
    w = _weight(np.linalg.norm(np.cross(unit(u), unit(r)), axis=-1))
    good = (w >= 1.0) & np.isfinite(carried).all(axis=(1, 2))
    if not good.any():
        return carried_k, carried
    # the constant from every well-conditioned frame near the default direction (where the
    # carried frame is exact up to noise), averaged; else from the nearest conditioned frame
    swing = np.arccos(np.clip(d_loc @ d0, -1.0, 1.0))
    near = good & (swing < np.radians(NEAR_DEFAULT_DEG))
    idx = np.flatnonzero(near if near.sum() >= 5 else good)
    if near.sum() < 5:
        idx = idx[[int(np.argmin(np.abs(idx - d)))]]
    o = frames_from_vectors(u[idx], r[idx])
    c = chordal_mean(tmm(o, carried[idx]))
    return LimbConstants("twist", c, l0, d0, axis_l), carried

"""Normalization (paper B, METHODS.md B.1): default pose, body planes, a limb frame per frame.

1. **Default pose**: the frame of lowest cost, the cost summing three heuristics on the joints
   (each divided by its median over the frames so that none dominates by its unit): the mean
   squared distance to their best-fitting plane, the edge ratio (short / long) of the 2D bounding
   box of the joints projected into that plane, and the mean distance to their centre of gravity.
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
   toward the frame carried from the parent by the minimal rotation (weight 0 below 8°, 1 above
   20° between limb and reference), and the constant transform is taken at the frame nearest to
   the default pose where the reference is well conditioned. Both choices are ours; the paper's
   marker bodies always give a full frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from kinefuse.analysis._vec import dot, frame_from, minimal_rotation, rodrigues, twist_angle, unit
from kinefuse.analysis.limbs import LIMB_INDEX, LIMB_PARENTS, LIMBS, Limb
from kinefuse.analysis.sequence import SkeletonSequence
from kinefuse.errors import InputError
from kinefuse.skeleton import JOINT_INDEX

Array = NDArray[np.float64]

#: Joints of the body used for the default-pose cost and the body planes (the hand tips, thumbs
#: and feet are left out: the least reliable joints of depth sensors).
BODY_JOINTS = (
    "SpineBase", "SpineMid", "SpineShoulder", "Neck", "Head", "ShoulderLeft", "ElbowLeft",
    "WristLeft", "ShoulderRight", "ElbowRight", "WristRight", "HipLeft", "KneeLeft", "AnkleLeft",
    "HipRight", "KneeRight", "AnkleRight",
)  # fmt: skip
#: Below this angle between a limb and its twist reference the twist weight is 0, above the
#: second it is 1 (degrees; a straight elbow or knee leaves the twist unobservable).
TWIST_WEIGHT_DEG = (8.0, 20.0)


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
        Normalized limb-to-world rotation per frame and limb (:data:`~kinefuse.analysis.limbs.
        LIMBS` order); NaN where the limb's joints are missing.
    origins : (T, L, 3) float
        Limb midpoints, metres (where the normalized frames are placed).
    long_axis : (L, 3) float
        The limb's long axis (proximal -> distal) in its own normalized frame (a signed body
        axis: ``-z`` for a hanging thigh).
    twist_weight : (T, L) float
        How observable the twist is in each frame, 0 to 1 (1 for sources with orientations).
    status : dict str -> str
        Per limb: ``"ok"``, or what is missing or not observable, in words.
    observable : dict str -> dict
        Per limb: ``{"swing_axes": n, "twist": "observable" | "when bent" | "not observable",
        "twist_frames": fraction of frames with weight 1}``.
    costs : (T,) float
        Default-pose cost per frame (NaN where joints are missing).
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


def default_pose_costs(positions: Array) -> Array:
    """The three heuristics' cost per frame ``(T,)`` for body joints ``(T, J, 3)`` (metres).

    NaN for frames with a missing body joint. Each heuristic is divided by its median over the
    valid frames before they are summed.
    """
    p = np.asarray(positions, dtype=np.float64)
    ok = np.isfinite(p).all(axis=(1, 2))
    cost = np.full(p.shape[0], np.nan)
    if not ok.any():
        return cost
    q = p[ok]
    c = q - q.mean(axis=1, keepdims=True)
    _, s, vt = np.linalg.svd(c, full_matrices=False)
    n = q.shape[1]
    plane = s[:, 2] ** 2 / n  # mean squared distance to the best-fitting plane
    a = np.einsum("tjk,tk->tj", c, vt[:, 0])
    b = np.einsum("tjk,tk->tj", c, vt[:, 1])
    ea, eb = np.ptp(a, axis=1), np.ptp(b, axis=1)
    ratio = np.minimum(ea, eb) / np.maximum(np.maximum(ea, eb), 1e-9)
    spread = np.linalg.norm(c, axis=-1).mean(axis=1)
    terms = [plane, ratio, spread]
    cost[ok] = sum(t / max(float(np.median(t)), 1e-12) for t in terms)
    return cost


def find_default_pose(seq: SkeletonSequence, /) -> int:
    """Index of the frame closest to the anatomical default pose (upright, arms hanging)."""
    return int(_default(seq)[0])


def _default(seq: SkeletonSequence) -> tuple[int, Array]:
    missing = [n for n in BODY_JOINTS if not seq.has(n)]
    if missing:
        raise InputError(
            f"normalization needs the body joints {', '.join(missing)}, which "
            f"{seq.source or 'the sequence'} lacks; map them (a marker map, a name map) first"
        )
    idx = [seq.index(n) for n in BODY_JOINTS]
    costs = default_pose_costs(seq.positions[:, idx])
    if not np.isfinite(costs).any():
        raise InputError(
            "no frame has all body joints present, so no default pose can be found; "
            f"needed in one frame: {', '.join(BODY_JOINTS)}"
        )
    return int(np.nanargmin(costs)), costs


def body_frame(joints: Array, /, up: Array | None = None) -> Array:
    """Body frame ``(3, 3)`` (columns x forward, y left, z up) from the body joints ``(25, 3)``.

    ``joints`` is on the full Kinect topology (NaN allowed outside :data:`BODY_JOINTS`).
    """
    up_v = np.array([0.0, 0.0, 1.0]) if up is None else unit(np.asarray(up, float))
    q = joints[[JOINT_INDEX[n] for n in BODY_JOINTS]]
    _, _, vt = np.linalg.svd(q - q.mean(axis=0))
    x = vt[2]
    j = JOINT_INDEX
    left = (joints[j["HipLeft"]] - joints[j["HipRight"]]) + (
        joints[j["ShoulderLeft"]] - joints[j["ShoulderRight"]]
    )
    if dot(x, np.cross(left, up_v)) < 0:  # forward = left x up
        x = -x
    z = unit(up_v - dot(up_v, x) * x)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=-1)


def limb_frame_from_body(u: Array, body: Array) -> tuple[Array, int, float]:
    """The paper's limb frame ``(3, 3)`` for main orientation ``u`` and body frame ``body``.

    Returns the frame, the index ``k`` of the body axis replaced by the limb axis and its sign
    (the limb direction is ``sign * frame[:, k]``).
    """
    u = unit(u)
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
        The sequence; must contain the :data:`BODY_JOINTS`.
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
    body = body_frame(p[d])
    if not np.isfinite(body).all():
        raise InputError(f"the default-pose frame {d} lacks body joints; choose another frame")
    n = len(LIMBS)
    frames = np.full((t, n, 3, 3), np.nan)
    origins = np.full((t, n, 3), np.nan)
    long_axis = np.zeros((n, 3))
    weight = np.zeros((t, n))
    status: dict[str, str] = {}
    observable: dict[str, dict[str, object]] = {}
    for i, lb in enumerate(LIMBS):
        u = p[:, lb.distal_index] - p[:, lb.proximal_index]
        origins[:, i] = 0.5 * (p[:, lb.distal_index] + p[:, lb.proximal_index])
        present: NDArray[np.bool_] = np.asarray(np.isfinite(u).all(axis=-1))
        if not present[d]:
            status[lb.name] = f"{lb.proximal} or {lb.distal} missing in the default pose"
            observable[lb.name] = {"swing_axes": lb.n_axes, "twist": "not observable"}
            continue
        n0, k, s = limb_frame_from_body(u[d], body)
        long_axis[i, k] = s
        src = seq.orientation(lb.name)
        if src is not None and np.isfinite(src[d]).all():
            # the paper's propagation: constant original-to-normalized transform
            c = src[d].T @ n0
            frames[:, i] = src @ c
            weight[:, i] = np.isfinite(src).all(axis=(1, 2)).astype(float)
            tw_kind = "observable"
        else:
            tw_kind = _position_frames(p, lb, i, d, n0, long_axis[i], frames, weight)
        frac_missing = 1.0 - present.mean()
        twist_frames = float((weight[:, i] >= 1.0).mean())
        observable[lb.name] = {
            "swing_axes": lb.n_axes,
            "twist": tw_kind,
            "twist_frames": twist_frames,
        }
        msg = []
        if frac_missing > 0:
            msg.append(f"joints missing in {int((~present).sum())} of {t} frames")
        if tw_kind == "not observable":
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
    )


def _position_frames(
    p: Array, lb: Limb, i: int, d: int, n0: Array, axis_l: Array, frames: Array, weight: Array
) -> str:
    """Fill ``frames[:, i]`` for a position-only limb; return the twist observability."""
    u = p[:, lb.distal_index] - p[:, lb.proximal_index]
    par = LIMB_PARENTS[i]
    if par < 0:  # the root: its frame from its joints and the hip line, always conditioned
        r = p[:, JOINT_INDEX[lb.twist_ref[1]]] - p[:, JOINT_INDEX[lb.twist_ref[0]]]
        o = frame_from(u, r)
        frames[:, i] = o @ (o[d].T @ n0)
        weight[:, i] = np.isfinite(o).all(axis=(1, 2)).astype(float)
        return "observable"
    fp = frames[:, par]
    # carried frame: parent frame x minimal swing from the default direction x local rest frame
    d_loc = unit(np.einsum("tji,tj->ti", fp, u))
    l0 = fp[d].T @ n0
    carried = fp @ minimal_rotation(np.broadcast_to(d_loc[d], d_loc.shape), d_loc) @ l0
    if not lb.twist_observable:
        frames[:, i] = carried
        return "not observable"
    r = p[:, JOINT_INDEX[lb.twist_ref[1]]] - p[:, JOINT_INDEX[lb.twist_ref[0]]]
    sin_t = np.linalg.norm(np.cross(unit(u), unit(r)), axis=-1)
    w = _weight(sin_t)
    o = frame_from(u, r)
    good = (w >= 1.0) & np.isfinite(carried).all(axis=(1, 2))
    if not good.any():
        frames[:, i] = carried
        return "not observable"
    frames_idx = np.flatnonzero(good)
    c_frame = int(frames_idx[np.argmin(np.abs(frames_idx - d))])
    c = o[c_frame].T @ carried[c_frame]
    g = o @ c  # twist-observing frame, equal to carried at c_frame
    psi = twist_angle(np.einsum("tji,tjk->tik", carried, g), np.broadcast_to(axis_l, u.shape))
    psi = np.where(np.isfinite(psi), psi, 0.0)
    frames[:, i] = carried @ rodrigues(np.broadcast_to(axis_l, u.shape), w * psi)
    weight[:, i] = w
    return "observable" if (w >= 1.0).mean() > 0.95 else "when bent"

"""Joint positions -> a BVH rig on the Kinect v2 skeleton: rest offsets and per-frame rotations.

The pure math behind ``kinefuse fuse --out F.bvh`` (the file is written by
:mod:`kinefuse.formats.bvh_export`). Conventions (``docs/formats.md``, "BVH export"):

* **Axes.** BVH axes are Y up: ``X = x, Y = z, Z = -y`` of the world (z up), as the TRC export.
  The rest pose (every rotation zero) faces **+Z** with the body's left on **+X**: a T-pose, arms
  along +-X, legs down -Y, feet forward +Z.
* **Hierarchy.** The 25 Kinect v2 joints, rooted at SpineBase (6 channels: position, then
  rotation); every other joint has 3 rotation channels; the five leaves (Head, HandTip*, Thumb*,
  Foot*) carry an End Site 5 cm on along their bone and a zero rotation. A joint's ``OFFSET`` is
  its bone from its parent: the session's bone length (median over the frames) along the rest
  direction. The rest directions of the limbs are the T-pose's; the children of the three
  branching joints (SpineBase: SpineMid and the hips; SpineShoulder: Neck and the shoulders;
  each wrist: hand and thumb) keep the session's mean shape, measured in a frame of the joint
  (see :data:`GROUPS`), so that one rotation fits all of them well.
* **Rotations.** A joint's rotation turns the bones that leave it. A branching joint's rotation is
  the least-squares fit of its children's rest offsets onto their directions in the frame
  (Kabsch). A joint with one child bone is turned so that the bone points at its child exactly;
  the remaining twist about the bone is taken from its neighbours (:data:`TWIST`):

  ======================  ===================================================================
  joint (bone)            twist from
  ======================  ===================================================================
  SpineMid                the mean of the hip line and the shoulder line (left axis)
  Neck (neck -> head)     the chest's left axis (the Kinect does not see the head's yaw)
  Shoulder, Elbow         the elbow's flexion axis (upper arm x forearm): the elbow is a
                          hinge; as the elbow straightens (bend under 25 deg, fully under 10)
                          the twist blends into the shortest turn from the parent's frame
  Hip, Knee               the knee's flexion axis, blended as the knee straightens into the
                          foot's axis (foot x shank), so a straight leg keeps its twist
  Ankle (ankle -> foot)   the shank's left axis
  Wrist, Hand             the shortest turn from the parent's frame (the Kinect's thumb and
                          hand tip are too noisy to twist the hand by: they flip it)
  ======================  ===================================================================

* **Gaps.** Where a joint's rotation cannot be solved (its joint, a child or a neighbour it
  needs is missing), the last solved local rotation is held (the first solved one before it is
  ever solved, zero if never); the root's position likewise. Held frames are counted per joint
  (:attr:`BvhPose.held`); the channels never hold NaN.
* **Channels.** Euler angles continuous over time (:func:`continuous_euler_deg`: no 360 degree
  wraps); per joint the order keeps gimbal lock away from common poses: ``Yrotation Zrotation
  Xrotation`` for the trunk, head and legs (lock only at 90 deg of sideways bend),
  ``Zrotation Xrotation Yrotation`` for the clavicles, upper arms and forearms (lock at 90 deg
  of twist, which the elbow's hinge keeps small), ``Xrotation Yrotation Zrotation`` for the
  wrists and hands, whose twist is the forearm's pronation (lock at 90 deg of wrist bend).

Forward kinematics of the result (:func:`forward_kinematics`) gives back the fused joints up to
the difference between each frame's bone lengths and the session's, and the change of shape of
the branching joints' children (``docs/formats.md`` states the figures).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.geometry.rotations import (
    continuous_euler_deg,
    frames_from_vectors,
    minimal_rotation,
    rotations_between_frames,
    slerp_rotations,
    unit,
)
from kinefuse.core.skeleton import JOINT_INDEX, JOINTS, N_JOINTS, PARENTS, standing_pose

Array = NDArray[np.float64]

#: world (z up) -> BVH (y up): X = x, Y = z, Z = -y.
ZUP_TO_BVH: Final = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
_X, _Y, _Z = np.eye(3)

#: Rest direction (BVH axes) of the bone ending at each joint whose parent has one child bone.
REST_DIRECTIONS: Final[dict[str, Array]] = {
    "SpineShoulder": _Y,
    "Head": _Y,
    "ElbowLeft": _X,
    "WristLeft": _X,
    "HandTipLeft": _X,
    "ElbowRight": -_X,
    "WristRight": -_X,
    "HandTipRight": -_X,
    "KneeLeft": -_Y,
    "AnkleLeft": -_Y,
    "FootLeft": _Z,
    "KneeRight": -_Y,
    "AnkleRight": -_Y,
    "FootRight": _Z,
}


@dataclass(frozen=True)
class Group:
    """A branching joint's children, and the frame their rest shape is measured in: ``e1``
    along the first child's bone (mapped to ``rest_primary``), ``e2`` toward ``ref[0] -
    ref[1]`` (mapped to ``rest_ref``)."""

    children: tuple[str, ...]
    ref: tuple[str, str]
    rest_primary: Array
    rest_ref: Array


#: The branching joints.
GROUPS: Final[dict[str, Group]] = {
    "SpineBase": Group(("SpineMid", "HipLeft", "HipRight"), ("HipLeft", "HipRight"), _Y, _X),
    "SpineShoulder": Group(
        ("Neck", "ShoulderLeft", "ShoulderRight"), ("ShoulderLeft", "ShoulderRight"), _Y, _X
    ),
    "WristLeft": Group(("HandLeft", "ThumbLeft"), ("ThumbLeft", "WristLeft"), _X, _Z),
    "WristRight": Group(("HandRight", "ThumbRight"), ("ThumbRight", "WristRight"), -_X, _Z),
}

LEAVES: Final = ("Head", "HandTipLeft", "ThumbLeft", "HandTipRight", "ThumbRight", "FootLeft",
                 "FootRight")  # fmt: skip
#: Channel order per joint (BVH rotation channels, listed order = intrinsic sequence).
ARM_JOINTS: Final = frozenset(
    f"{n}{side}"
    for side in ("Left", "Right")
    for n in ("Clavicle", "Shoulder", "Elbow", "Wrist", "Hand", "HandTip", "ThumbBase", "Thumb")
)


HAND_JOINTS: Final = frozenset(
    f"{n}{side}" for side in ("Left", "Right") for n in ("Wrist", "Hand", "HandTip", "ThumbBase",
                                                          "Thumb")
)  # fmt: skip
#: The three rotation sequences used (see :func:`channel_order`).
SEQUENCES: Final = ("ZXY", "XYZ", "YZX")


def channel_order(joint: str) -> str:
    """The joint's rotation sequence (intrinsic; its BVH channels in this order)."""
    if joint in HAND_JOINTS:
        return "XYZ"
    return "ZXY" if joint in ARM_JOINTS else "YZX"


#: Twist of a limb's bone: the bend (degrees between the two bones at the middle joint) under
#: which the flexion axis is not used, and over which it is used alone.
BEND_OFF_DEG: Final = 10.0
BEND_FULL_DEG: Final = 25.0
#: End Sites: this far on along the leaf's own bone.
END_SITE_M: Final = 0.05

_J = JOINT_INDEX

#: Helper joints: each sits on a branching joint (zero offset) and carries one of its extra bones,
#: so that every bone is aimed at its child exactly (name, the branching joint, the bone's child).
HELPERS: Final = (
    ("PelvisLeft", "SpineBase", "HipLeft"),
    ("PelvisRight", "SpineBase", "HipRight"),
    ("ClavicleLeft", "SpineShoulder", "ShoulderLeft"),
    ("ClavicleRight", "SpineShoulder", "ShoulderRight"),
    ("ThumbBaseLeft", "WristLeft", "ThumbLeft"),
    ("ThumbBaseRight", "WristRight", "ThumbRight"),
)
_HELPER_OF: Final = {child: (name, joint) for name, joint, child in HELPERS}


def _bvh_tree() -> tuple[tuple[str, ...], tuple[int, ...], tuple[int, ...]]:
    """BVH joint names, parents (BVH indices) and Kinect joint index (-1 for a helper), in
    depth-first file order from SpineBase."""
    names: list[str] = []
    parents: list[int] = []
    kinect: list[int] = []
    kids: dict[str, list[str]] = {}
    for j, par in enumerate(PARENTS):
        if par < 0:
            continue
        child = JOINTS[j]
        if child in _HELPER_OF:
            helper, joint = _HELPER_OF[child]
            kids.setdefault(joint, []).append(helper)
            kids.setdefault(helper, []).append(child)
        else:
            kids.setdefault(JOINTS[par], []).append(child)

    def visit(name: str, parent: int) -> None:
        names.append(name)
        parents.append(parent)
        kinect.append(_J.get(name, -1))
        me = len(names) - 1
        for c in kids.get(name, []):
            visit(c, me)

    visit("SpineBase", -1)
    return tuple(names), tuple(parents), tuple(kinect)


#: The BVH hierarchy: 25 Kinect joints + 6 helpers, parents before children (file order).
BVH_NAMES, BVH_PARENTS, BVH_KINECT = _bvh_tree()
N_BVH: Final = len(BVH_NAMES)
_B: Final = {n: i for i, n in enumerate(BVH_NAMES)}
#: BVH index of each Kinect joint, in :data:`JOINTS` order.
KINECT_TO_BVH: Final = np.array([_B[n] for n in JOINTS], dtype=np.intp)


@dataclass(frozen=True)
class BvhRig:
    """The hierarchy (:data:`BVH_NAMES`, :data:`BVH_PARENTS`): each joint's rest offset from
    its parent (BVH axes, metres; the root's and the helpers' are zero) and each leaf's End
    Site offset; ``bone_lengths (25,)`` per Kinect joint (its bone from its Kinect parent)."""

    offsets: Array  # (N_BVH, 3)
    end_sites: dict[int, Array]  # BVH index -> offset
    bone_lengths: Array  # (25,)


@dataclass(frozen=True)
class BvhPose:
    """A motion on a :class:`BvhRig`.

    ``root_m (T, 3)`` SpineBase in BVH axes; ``local (T, N_BVH, 3, 3)`` each joint's rotation
    relative to its parent's frame (the root's: to the BVH axes); ``channels_deg (T, N_BVH, 3)``
    the same as continuous Euler angles in :func:`channel_order`; ``held (T, N_BVH)`` frames where
    the joint's rotation (the root: also its position) was held, not solved.
    """

    rig: BvhRig
    root_m: Array
    local: Array
    channels_deg: Array
    held: NDArray[np.bool_]
    notes: tuple[str, ...] = field(default=())


def _bone_lengths(p: Array) -> Array:
    """Median length of each joint's bone from its parent over the frames (root: 0); a bone
    never seen takes the standing reference pose's length."""
    ref = standing_pose()
    out = np.zeros(N_JOINTS)
    for j, par in enumerate(PARENTS):
        if par < 0:
            continue
        length = np.linalg.norm(p[:, j] - p[:, par], axis=-1)
        length = length[np.isfinite(length)]
        out[j] = (
            float(np.median(length)) if length.size else float(np.linalg.norm(ref[j] - ref[par]))
        )
    return out


def _group_frames(p: Array, joint: str) -> Array:
    g = GROUPS[joint]
    a, b = g.ref
    primary = p[:, _J[g.children[0]]] - p[:, _J[joint]]
    return frames_from_vectors(primary, p[:, _J[a]] - p[:, _J[b]])


def _group_rest(p: Array, joint: str, lengths: Array) -> dict[int, Array]:
    """Rest offsets of a branching joint's children: their mean direction in the joint's frame
    over the frames where all are seen (the standing pose if none), at the session's lengths."""
    g = GROUPS[joint]
    children = [_J[c] for c in g.children]
    rest_frame = frames_from_vectors(g.rest_primary, g.rest_ref)
    for data in (p, (standing_pose() @ ZUP_TO_BVH.T)[None]):
        f = _group_frames(data, joint)
        vec = data[:, children] - data[:, None, _J[joint]]
        ok = np.isfinite(f).all(axis=(1, 2)) & np.isfinite(vec).all(axis=(1, 2))
        if ok.any():
            local = np.einsum("tji,tcj->tci", f[ok], unit(vec[ok]))  # F^T v
            mean = unit(local.mean(axis=0))
            return {c: rest_frame @ mean[k] * lengths[c] for k, c in enumerate(children)}
    raise AssertionError("the standing pose has every joint")  # pragma: no cover


def build_rig(positions_bvh: Array) -> BvhRig:
    """The rig of a motion given in BVH axes ``(T, 25, 3)`` (NaN = missing)."""
    lengths = _bone_lengths(positions_bvh)
    offsets = np.zeros((N_BVH, 3))
    for name, d in REST_DIRECTIONS.items():
        offsets[_B[name]] = d * lengths[_J[name]]
    for joint in GROUPS:
        for c, off in _group_rest(positions_bvh, joint, lengths).items():
            offsets[_B[JOINTS[c]]] = off
    ends = {_B[n]: unit(offsets[_B[n]]) * END_SITE_M for n in LEAVES}
    return BvhRig(offsets=offsets, end_sites=ends, bone_lengths=lengths)


def _bend_weight(d_a: Array, d_b: Array) -> Array:
    """0 for a straight joint (bend under BEND_OFF_DEG), 1 over BEND_FULL_DEG, linear between;
    0 where either bone is missing."""
    cos = np.clip(np.einsum("...i,...i->...", d_a, d_b), -1.0, 1.0)
    bend = np.degrees(np.arccos(cos))
    w = np.clip((bend - BEND_OFF_DEG) / (BEND_FULL_DEG - BEND_OFF_DEG), 0.0, 1.0)
    return np.nan_to_num(w, nan=0.0)


def _aim(d: Array, ref: Array, d0: Array, ref0: Array) -> Array:
    """Rotations taking the rest bone ``d0`` onto ``d`` exactly, with ``ref0`` turned as near
    ``ref`` as the bone allows."""
    return rotations_between_frames(frames_from_vectors(d0, ref0), frames_from_vectors(d, ref))


def _swing(g_parent: Array, d: Array, d0: Array) -> Array:
    """The shortest turn taking the parent-carried rest bone onto ``d``, after the parent's."""
    carried = np.einsum("tij,j->ti", g_parent, d0)
    return np.asarray(minimal_rotation(carried, d) @ g_parent, dtype=np.float64)


def _global_rotations(p: Array, rig: BvhRig) -> Array:
    """Global rotation of every BVH joint's frame per frame (NaN where it cannot be solved)."""
    t = p.shape[0]
    g = np.full((t, N_BVH, 3, 3), np.nan)

    def bone(a: str, b: str) -> Array:
        return unit(p[:, _J[b]] - p[:, _J[a]])

    def rest(child: str) -> Array:
        return unit(rig.offsets[_B[child]])

    def put(name: str, value: Array) -> None:
        g[:, _B[name]] = value

    def get(name: str) -> Array:
        return g[:, _B[name]]

    # the trunk: each bone aimed at its child, the twist from the hip and shoulder lines
    hips = bone("HipRight", "HipLeft")
    shoulders = bone("ShoulderRight", "ShoulderLeft")
    put("SpineBase", _aim(bone("SpineBase", "SpineMid"), hips, rest("SpineMid"), _X))
    put("SpineMid", _aim(bone("SpineMid", "SpineShoulder"), hips + shoulders,
                         rest("SpineShoulder"), _X))  # fmt: skip
    put("SpineShoulder", _aim(bone("SpineShoulder", "Neck"), shoulders, rest("Neck"), _X))
    put("Neck", _aim(bone("Neck", "Head"), get("SpineShoulder")[:, :, 0], rest("Head"), _X))
    for helper, joint, child in HELPERS:
        if joint != "WristLeft" and joint != "WristRight":
            put(helper, _swing(get(joint), bone(joint, child), rest(child)))
    for side in ("Left", "Right"):
        sh, el, wr, ha = (f"Shoulder{side}", f"Elbow{side}", f"Wrist{side}", f"Hand{side}")
        upper, fore = bone(sh, el), bone(el, wr)
        hinge = np.cross(upper, fore)
        hinge0 = np.cross(rest(el), _Z)  # T-pose: the forearm bends forward
        w = _bend_weight(upper, fore)
        parent = get(f"Clavicle{side}")
        for joint, d, d0 in ((sh, upper, rest(el)), (el, fore, rest(wr))):
            swing = _swing(parent, d, d0)
            aimed = _aim(d, hinge, d0, hinge0)
            use = (w > 0) & np.isfinite(aimed).all(axis=(1, 2))
            blended = swing.copy()
            if use.any():
                blended[use] = slerp_rotations(swing[use], aimed[use], w[use])
            put(joint, blended)
            parent = blended
        put(wr, _swing(get(el), bone(wr, ha), rest(ha)))
        put(f"ThumbBase{side}", _swing(get(wr), bone(wr, f"Thumb{side}"), rest(f"Thumb{side}")))
        put(ha, _swing(get(wr), bone(ha, f"HandTip{side}"), rest(f"HandTip{side}")))
        hip, kn, an, ft = (f"Hip{side}", f"Knee{side}", f"Ankle{side}", f"Foot{side}")
        thigh, shank, foot = bone(hip, kn), bone(kn, an), bone(an, ft)
        knee_axis = unit(np.cross(thigh, shank))
        foot_axis = unit(np.cross(foot, shank))
        wk = _bend_weight(thigh, shank)[:, None]
        ref = np.nan_to_num(knee_axis * wk, nan=0.0) + foot_axis * (1.0 - wk)
        put(hip, _aim(thigh, ref, rest(kn), _X))
        put(kn, _aim(shank, ref, rest(an), _X))
        put(an, _aim(foot, get(kn)[:, :, 0], rest(ft), _X))
    return g


def _hold(values: Array, valid: NDArray[np.bool_], default: Array) -> Array:
    """Forward-fill ``values (T, ...)`` over invalid frames; before the first valid frame the
    first valid value, ``default`` if none."""
    out = values.copy()
    idx = np.where(valid, np.arange(valid.size), -1)
    np.maximum.accumulate(idx, out=idx)
    if not valid.any():
        out[:] = default
        return out
    first = int(np.argmax(valid))
    idx[idx < 0] = first
    return out[idx]


def solve_pose(positions_m: Array, rig: BvhRig | None = None) -> BvhPose:
    """Solve the BVH channels of fused joints ``(T, 25, 3)`` (world frame, z up, metres; NaN =
    missing).

    Returns the rig (built from these frames unless given), the root position, every joint's
    local rotation and its continuous Euler channels, and the held frames (module docstring).
    """
    world = np.asarray(positions_m, dtype=np.float64)
    if world.ndim != 3 or world.shape[1:] != (N_JOINTS, 3) or world.shape[0] < 1:
        raise ValueError(f"positions must be (T, {N_JOINTS}, 3), got {world.shape}")
    p = world @ ZUP_TO_BVH.T
    rig = build_rig(p) if rig is None else rig
    t = p.shape[0]
    g = _global_rotations(p, rig)
    local = np.full_like(g, np.nan)
    for j, par in enumerate(BVH_PARENTS):
        local[:, j] = g[:, j] if par < 0 else np.einsum("tki,tkj->tij", g[:, par], g[:, j])
    local[:, [_B[n] for n in LEAVES]] = np.eye(3)
    held = np.zeros((t, N_BVH), dtype=bool)
    notes: list[str] = []
    root = _B["SpineBase"]
    for j in range(N_BVH):
        ok = np.asarray(np.isfinite(local[:, j]).all(axis=(1, 2)), dtype=bool)
        if j == root:
            ok &= np.isfinite(p[:, _J["SpineBase"]]).all(axis=-1)
        held[:, j] = ~ok
        if not ok.all():
            local[:, j] = _hold(local[:, j], ok, np.eye(3))
            notes.append(
                f"{BVH_NAMES[j]}: rotation held on {int((~ok).sum())} of {t} frames "
                "(a joint it needs is missing)"
            )
    root_m = _hold(p[:, _J["SpineBase"]], ~held[:, root], np.zeros(3))
    channels = np.zeros((t, N_BVH, 3))
    for seq in SEQUENCES:
        js = [j for j in range(N_BVH) if channel_order(BVH_NAMES[j]) == seq]
        channels[:, js] = continuous_euler_deg(local[:, js], seq)
    return BvhPose(rig, root_m, local, channels, held, tuple(notes))


def forward_kinematics(rig: BvhRig, root_m: Array, local: Array) -> Array:
    """Kinect joint positions ``(T, 25, 3)`` in BVH axes from a root position and the local
    rotations ``(T, N_BVH, 3, 3)`` of every BVH joint."""
    t = root_m.shape[0]
    pos = np.zeros((t, N_BVH, 3))
    g = np.zeros((t, N_BVH, 3, 3))
    for j, par in enumerate(BVH_PARENTS):  # parents come first
        if par < 0:
            pos[:, j] = root_m
            g[:, j] = local[:, j]
        else:
            pos[:, j] = pos[:, par] + np.einsum("tij,j->ti", g[:, par], rig.offsets[j])
            g[:, j] = g[:, par] @ local[:, j]
    return pos[:, KINECT_TO_BVH]


def bvh_to_world(p_bvh: Array) -> Array:
    """BVH axes (y up) back to the world frame (z up)."""
    return np.asarray(p_bvh, dtype=np.float64) @ ZUP_TO_BVH

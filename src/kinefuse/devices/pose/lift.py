"""Lifting 2D landmarks to 3D with the depth image registered to the landmarks' image.

A landmark is a pixel of the image the 2D model saw (the colour camera, or the IR image, which
is the depth camera itself). Its 3D point is on that pixel's ray, at the depth of the surface
the camera saw there. One depth pixel is not enough: a landmark a few pixels off lands on the
background, and a limb in front of a joint hides it. So each landmark gathers the depth readings
of a small window around it (depth pixels projected into the landmark's image through the
device's ``color_from_depth`` and both intrinsics, searched only along the landmark's epipolar
line), splits them into depth layers, and takes the *body's* layer: the nearest one for the
trunk; for a limb, among the layers its bone allows (a landmark is within its bone of its
parent, so its 2D distance to the parent bounds its depth), the one under the window's centre.

Hidden landmarks are flagged (inferred), never placed on what hides them: a landmark whose
window shows only something well in front of its parent, inside another limb's or the trunk's
silhouette, goes behind it at its parent's depth; a body turned to the side hides its far
shoulder and hip behind the trunk (:func:`_trunk_sides`).

The surface seen is the skin; the joint is inside. Each point is pushed along its ray by the
limb's radius (:data:`kinefuse.core.skeleton.CAPSULE_RADII_M`, the project's nominal radii of a
1.75 m adult: an assumption, a couple of centimetres off for a real body).
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise
from typing import Final

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.skeleton import CAPSULE_RADII_M, JOINT_INDEX, TrackingState, standing_pose
from kinefuse.devices.pose.landmarks import LM, N_LIFTED

__all__ = ["LiftParams", "LiftResult", "lift_landmarks"]

Array = NDArray[np.float64]

_TORSO: Final = (LM["left_shoulder"], LM["right_shoulder"], LM["left_hip"], LM["right_hip"])
_CHAIN: Final = {
    "elbow": "shoulder", "wrist": "elbow", "pinky": "wrist", "index": "wrist", "thumb": "wrist",
    "hand_centre": "wrist", "knee": "hip", "ankle": "knee", "heel": "ankle",
    "foot_index": "ankle",
}  # fmt: skip


def _parents() -> tuple[int, ...]:
    p = [-1] * N_LIFTED
    for s in ("left", "right"):
        for child, parent in _CHAIN.items():
            p[LM[f"{s}_{child}"]] = LM[f"{s}_{parent}"]
    return tuple(p)


#: parent landmark of each landmark; -1: the trunk's reference depth
PARENT: Final[tuple[int, ...]] = _parents()


def _level(i: int) -> int:
    n = 0
    while PARENT[i] >= 0:
        i, n = PARENT[i], n + 1
    return n


#: lifting order: the trunk first, then outward along the limbs (every parent before its child)
ORDER: Final[tuple[int, ...]] = tuple(
    sorted(range(N_LIFTED), key=lambda i: (_level(i), i not in _TORSO, i))
)

_RADIUS_OF: Final = {
    "shoulder": "ShoulderLeft", "elbow": "ElbowLeft", "wrist": "WristLeft",
    "hand_centre": "HandLeft", "index": "HandTipLeft", "pinky": "HandTipLeft",
    "thumb": "ThumbLeft", "hip": "HipLeft", "knee": "KneeLeft", "ankle": "AnkleLeft",
    "heel": "FootLeft", "foot_index": "FootLeft",
}  # fmt: skip


def _radii() -> tuple[float, ...]:
    r = [0.0] * N_LIFTED  # the face's landmarks are on the skin
    r[LM["head_centre"]] = CAPSULE_RADII_M["Head"]
    for s in ("left", "right"):
        for part, joint in _RADIUS_OF.items():
            r[LM[f"{s}_{part}"]] = CAPSULE_RADII_M[joint]
    return tuple(r)


#: depth of each landmark's joint centre under the skin the camera sees, metres
SURFACE_TO_CENTRE_M: Final[tuple[float, ...]] = _radii()

#: the limbs that can hide a landmark: (landmark a, landmark b, radius m)
_OCCLUDERS: Final = tuple(
    (LM[f"{s}_{a}"], LM[f"{s}_{b}"], CAPSULE_RADII_M[j])
    for s in ("left", "right")
    for a, b, j in (
        ("shoulder", "elbow", "ElbowLeft"),
        ("elbow", "wrist", "WristLeft"),
        ("hip", "knee", "KneeLeft"),
        ("knee", "ankle", "AnkleLeft"),
    )
)


_BONE_OF: Final = {
    "elbow": ("ShoulderLeft", "ElbowLeft"), "wrist": ("ElbowLeft", "WristLeft"),
    "hand_centre": ("WristLeft", "HandLeft"), "index": ("WristLeft", "HandTipLeft"),
    "pinky": ("WristLeft", "HandTipLeft"), "thumb": ("WristLeft", "ThumbLeft"),
    "knee": ("HipLeft", "KneeLeft"), "ankle": ("KneeLeft", "AnkleLeft"),
    "heel": ("AnkleLeft", "AnkleLeft"), "foot_index": ("AnkleLeft", "FootLeft"),
}  # fmt: skip


def _bones() -> tuple[float, ...]:
    pose = standing_pose()
    out = [0.0] * N_LIFTED
    for side in ("left", "right"):
        for part, (a, b) in _BONE_OF.items():
            length = float(np.linalg.norm(pose[JOINT_INDEX[a]] - pose[JOINT_INDEX[b]]))
            out[LM[f"{side}_{part}"]] = max(length, 0.07)  # the heel: 7 cm behind the ankle
    return tuple(out)


#: each limb landmark's distance to its parent on the 1.75 m reference body, metres
BONE_TO_PARENT_M: Final[tuple[float, ...]] = _bones()


def _width(left: str, right: str) -> float:
    pose = standing_pose()
    return float(np.linalg.norm(pose[JOINT_INDEX[left]] - pose[JOINT_INDEX[right]]))


#: shoulder and hip widths of the reference body, metres
_WIDTH_M: Final = {
    (LM["left_shoulder"], LM["right_shoulder"]): _width("ShoulderLeft", "ShoulderRight"),
    (LM["left_hip"], LM["right_hip"]): _width("HipLeft", "HipRight"),
}
#: the nearest any depth camera reads, metres (no search starts nearer)
_NEAREST_M: Final = 0.1
#: the trunk's radius as an occluder (the chest's, :data:`CAPSULE_RADII_M`), metres
_TRUNK_R: Final = CAPSULE_RADII_M["SpineShoulder"]


@dataclass(frozen=True)
class LiftParams:
    """How landmarks are lifted (lengths in metres).

    Attributes
    ----------
    window_m : float
        Radius of the window around a landmark, at the body's distance (converted to pixels
        with the trunk's depth): about a wrist's radius.
    layer_gap_m : float
        A jump in depth larger than this between sorted readings starts a new layer.
    min_layer_fraction : float
        A layer needs this share of the window's readings (flying pixels are not a layer).
    reach_m : float
        How far in front of the trunk a landmark may be (an arm stretched at the camera); the
        depth search of the limbs' windows spans this and 30 cm more around the trunk.
    bone_scale_max : float
        A limb landmark is at most its reference bone times this from its parent (1.2: a
        person 2.1 m tall); with the 2D distance to the parent this bounds its depth.
    depth_slack_m : float
        Added to that depth bound (landmark and depth noise).
    hidden_margin_m : float
        A landmark whose surface is this much in front of its parent and inside another limb's
        silhouette, at that limb's depth, is hidden behind it.
    min_visibility : float
        Below this visibility (the model's own) a landmark is inferred, not tracked.
    """

    window_m: float = 0.03
    layer_gap_m: float = 0.06
    min_layer_fraction: float = 0.15
    reach_m: float = 0.7
    bone_scale_max: float = 1.2
    depth_slack_m: float = 0.08
    hidden_margin_m: float = 0.10
    min_visibility: float = 0.5


@dataclass(frozen=True, eq=False)
class LiftResult:
    """The landmarks in 3D.

    Attributes
    ----------
    points_m : (36, 3) float
        Joint centres in the depth camera's frame (x right, y down, z forward), metres; NaN
        where not lifted.
    states : (36,) int8
        :class:`~kinefuse.core.skeleton.TrackingState`.
    hidden : (36,) bool
        Hidden behind another limb (placed behind it and inferred).
    """

    points_m: Array
    states: NDArray[np.int8]
    hidden: NDArray[np.bool_]


class _Registration:
    """Depth pixels seen from the landmarks' image: ``image = R @ depth + t``."""

    def __init__(self, depth_mm: NDArray[np.uint16], kd: Intrinsics, ki: Intrinsics,
                 image_from_depth: Array | None) -> None:  # fmt: skip
        self.z, self.kd, self.ki = depth_mm, kd, ki
        t = np.eye(4) if image_from_depth is None else np.asarray(image_from_depth, float)
        self.r, self.t = t[:3, :3], t[:3, 3]
        self.same = image_from_depth is None or (
            np.allclose(t, np.eye(4)) and ki == kd
        )  # the IR image: the depth camera itself
        self.r_inv = self.r.T
        self.t_inv = -self.r.T @ self.t

    def samples(
        self, u: float, v: float, radius_px: float, z_range: tuple[float, float]
    ) -> tuple[Array, Array]:
        """Depths (in the image camera's z, metres) around pixel ``(u, v)`` and their pixel
        distance to it, within ``radius_px``; searched for between depths ``z_range``."""
        kd, ki, h, w = self.kd, self.ki, *self.z.shape
        if self.same:
            u0, u1 = int(np.floor(u - radius_px)), int(np.ceil(u + radius_px))
            v0, v1 = int(np.floor(v - radius_px)), int(np.ceil(v + radius_px))
        else:  # the box around the landmark's epipolar segment in the depth image
            ray = np.array([(u - ki.cx) / ki.fx, (v - ki.cy) / ki.fy, 1.0])
            ends = np.array([ray * z_range[0], ray * z_range[1]])
            pd = ends @ self.r_inv.T + self.t_inv
            ud = kd.fx * pd[:, 0] / pd[:, 2] + kd.cx
            vd = kd.fy * pd[:, 1] / pd[:, 2] + kd.cy
            pad = radius_px * kd.fx / ki.fx + 2.0
            u0, u1 = int(np.floor(ud.min() - pad)), int(np.ceil(ud.max() + pad))
            v0, v1 = int(np.floor(vd.min() - pad)), int(np.ceil(vd.max() + pad))
        u0, v0, u1, v1 = max(u0, 0), max(v0, 0), min(u1, w - 1), min(v1, h - 1)
        if u1 < u0 or v1 < v0:
            return np.zeros(0), np.zeros(0)
        crop = self.z[v0 : v1 + 1, u0 : u1 + 1]
        vv, uu = np.nonzero(crop)
        z = crop[vv, uu] * 1e-3
        uu, vv = uu + u0, vv + v0
        if self.same:
            d = np.hypot(uu - u, vv - v)
        else:
            p = np.stack([(uu - kd.cx) / kd.fx * z, (vv - kd.cy) / kd.fy * z, z], -1)
            p = p @ self.r.T + self.t
            z = p[:, 2]
            with np.errstate(divide="ignore", invalid="ignore"):
                d = np.hypot(ki.fx * p[:, 0] / z + ki.cx - u, ki.fy * p[:, 1] / z + ki.cy - v)
        keep = d <= radius_px
        return z[keep], d[keep]


def _layers(z: Array, d: Array, params: LiftParams) -> list[tuple[float, int, int]]:
    """Depth layers of a window: ``(median depth, readings, readings in the inner half)``."""
    if z.size == 0:
        return []
    order = np.argsort(z)
    zs, ds = z[order], d[order]
    cuts = np.flatnonzero(np.diff(zs) > params.layer_gap_m) + 1
    inner = float(np.max(ds)) / 2.0 if ds.size else 0.0
    need = max(2, int(np.ceil(params.min_layer_fraction * zs.size)))
    is_inner = ds <= inner
    out = []
    bounds = [0, *cuts.tolist(), zs.size]
    for a, b in pairwise(bounds):
        if b - a >= need:  # sorted: the median is the middle
            mid = 0.5 * (zs[a + (b - a - 1) // 2] + zs[a + (b - a) // 2])
            out.append((float(mid), b - a, int(np.count_nonzero(is_inner[a:b]))))
    return out


def _choose(
    layers: list[tuple[float, int, int]], ref: float | None, dz_max: float
) -> tuple[float, str]:
    """The body's layer and why: ``ok``; ``hidden`` (only layers nearer than the landmark can
    be: something in front of it); ``none`` (no reading, or only the background behind).

    The trunk (``ref`` None): the nearest layer. A limb: among the layers within ``dz_max`` of
    its parent's depth ``ref``, the one under the window's centre.
    """
    if not layers:
        return float("nan"), "none"
    if ref is None or not np.isfinite(ref):
        return min(lay[0] for lay in layers), "ok"
    near = [lay for lay in layers if abs(lay[0] - ref) <= dz_max]
    if near:
        return max(near, key=lambda lay: (lay[2], lay[1], -abs(lay[0] - ref)))[0], "ok"
    if min(lay[0] for lay in layers) < ref - dz_max:
        return float("nan"), "hidden"
    return float("nan"), "none"


def _seg_dist(p: Array, a: Array, b: Array) -> tuple[float, float]:
    """2D distance of ``p`` to segment ``a``-``b`` and the closest point's parameter."""
    ab = b - a
    den = float(ab @ ab)
    s = 0.0 if den < 1e-12 else float(np.clip((p - a) @ ab / den, 0.0, 1.0))
    return float(np.linalg.norm(a + s * ab - p)), s


def lift_landmarks(
    uv_px: Array,
    visibility: Array,
    depth_mm: NDArray[np.uint16],
    depth_intrinsics: Intrinsics,
    image_intrinsics: Intrinsics,
    image_from_depth: Array | None = None,
    params: LiftParams = LiftParams(),
) -> LiftResult:
    """Lift the landmarks (with the virtual ones, ``(36, 2)``) to 3D joint centres.

    Parameters
    ----------
    uv_px : (36, 2) float
        Landmarks in the image's pixels (:func:`~kinefuse.devices.pose.landmarks.with_virtual`).
    visibility : (36,) float
    depth_mm : (H, W) uint16
        Depth in millimetres (0: no reading) in the depth camera.
    depth_intrinsics, image_intrinsics : Intrinsics
        The depth camera and the camera of the landmarks' image (the same for IR).
    image_from_depth : (4, 4) float or None
        Rigid transform from the depth camera's frame to the image camera's (the device's
        ``color_from_depth``); None: the image is the depth camera's own (IR).
    params : LiftParams

    Returns
    -------
    LiftResult
        Points in the depth camera's frame, metres.
    """
    uv = np.asarray(uv_px, dtype=np.float64).reshape(N_LIFTED, 2)
    vis = np.asarray(visibility, dtype=np.float64).reshape(N_LIFTED)
    reg = _Registration(depth_mm, depth_intrinsics, image_intrinsics, image_from_depth)
    ki = image_intrinsics
    inside = (
        np.isfinite(uv).all(axis=1)
        & (uv[:, 0] >= -0.5)
        & (uv[:, 0] <= ki.width - 0.5)
        & (uv[:, 1] >= -0.5)
        & (uv[:, 1] <= ki.height - 0.5)
    )

    # the trunk's depth first, with a window sized for 2 m, searched over the camera's range;
    # then every window at the body's size, searched within reach of the trunk
    def window(z_body: float) -> float:
        return float(np.clip(ki.fx * params.window_m / z_body, 2.0, 0.02 * ki.width))

    # the depths the camera read (not its specified range), from every 4th pixel: cheap
    coarse = depth_mm[::4, ::4]
    coarse = coarse[coarse > 0]
    if coarse.size == 0:
        nan3 = np.full((N_LIFTED, 3), np.nan)
        none = np.zeros(N_LIFTED, dtype=np.int8)
        return LiftResult(points_m=nan3, states=none, hidden=np.zeros(N_LIFTED, dtype=bool))
    full = (max(_NEAREST_M, 0.9e-3 * float(coarse.min())), 1.1e-3 * float(coarse.max()))
    samples: dict[int, tuple[Array, Array]] = {}
    torso_z = []
    for i in _TORSO:
        if inside[i]:
            samples[i] = reg.samples(uv[i, 0], uv[i, 1], window(2.0), full)
            zt, _ = _choose(_layers(*samples[i], params), None, 0.0)
            if np.isfinite(zt):
                torso_z.append(zt)
    trunk = float(np.median(torso_z)) if torso_z else float("nan")
    radius = window(trunk if np.isfinite(trunk) else 2.0)
    near = full
    if np.isfinite(trunk):  # a hand stretched forward is a reach in front of the trunk
        span = params.reach_m + 0.3
        near = (max(full[0], trunk - span), min(full[1], trunk + span))
    for i in range(N_LIFTED):
        if inside[i]:
            samples[i] = reg.samples(uv[i, 0], uv[i, 1], radius, near)
    layers = {i: _layers(*s, params) for i, s in samples.items()}

    z = np.full(N_LIFTED, np.nan)
    state = np.full(N_LIFTED, TrackingState.NOT_TRACKED, dtype=np.int8)
    hidden = np.zeros(N_LIFTED, dtype=bool)
    first_limb = next(k for k, i in enumerate(ORDER) if PARENT[i] >= 0)
    for sweep in range(2):  # the second sweep knows where every limb is
        for k, i in enumerate(ORDER):
            if k == first_limb:
                _trunk_sides(uv, vis, z, state, hidden, ki)
            if not inside[i]:
                continue
            ref = trunk if PARENT[i] < 0 else z[PARENT[i]]
            dz_max = params.reach_m
            if PARENT[i] >= 0 and np.isfinite(ref):
                gap = np.linalg.norm(uv[i] - uv[PARENT[i]]) * ref / ki.fx  # metres, 2D
                bone = params.bone_scale_max * BONE_TO_PARENT_M[i]
                dz_max = float(np.sqrt(max(bone * bone - gap * gap, 0.0))) + params.depth_slack_m
            zi, why = _choose(layers[i], ref if PARENT[i] >= 0 else None, dz_max)
            hidden[i] = why == "hidden"
            if sweep == 1 and why == "ok" and np.isfinite(ref):
                hz = _hidden_depth(i, zi, ref, uv, z, ki, params)
                if hz is not None:
                    zi, hidden[i] = hz, True
            if np.isfinite(zi):
                z[i] = zi
                ok = vis[i] >= params.min_visibility and not hidden[i]
                state[i] = TrackingState.TRACKED if ok else TrackingState.INFERRED
            elif np.isfinite(ref) and PARENT[i] >= 0:  # no depth of its own: at its parent's
                z[i] = ref
                state[i] = TrackingState.INFERRED
            else:
                z[i] = np.nan
                state[i] = TrackingState.NOT_TRACKED

    rays = np.stack([(uv[:, 0] - ki.cx) / ki.fx, (uv[:, 1] - ki.cy) / ki.fy, np.ones(N_LIFTED)], -1)
    z_centre = z + np.asarray(SURFACE_TO_CENTRE_M) / np.linalg.norm(rays, axis=1)
    p_img = rays * z_centre[:, None]
    p_depth = (p_img - reg.t) @ reg.r  # R^T (p - t)
    p_depth[state == TrackingState.NOT_TRACKED] = np.nan
    return LiftResult(points_m=p_depth, states=state, hidden=hidden)


def _hidden_depth(
    i: int, zi: float, ref: float, uv: Array, z: Array, ki: Intrinsics, params: LiftParams
) -> float | None:
    """Where landmark ``i`` is if another limb or the trunk hides it (its window shows that
    limb's or the trunk's near surface, well in front of its parent), else None."""
    if PARENT[i] < 0 or not zi < ref - params.hidden_margin_m:
        return None
    near = {i, PARENT[i]} | {k for k in range(N_LIFTED) if PARENT[k] == i}
    segments = [
        (uv[a], uv[b], z[a], z[b], r) for a, b, r in _OCCLUDERS if a not in near and b not in near
    ]
    sh = (LM["left_shoulder"], LM["right_shoulder"])
    hp = (LM["left_hip"], LM["right_hip"])
    # the trunk: hips' to shoulders' midpoint, at its nearer side's depth
    segments.append((uv[list(hp)].mean(axis=0), uv[list(sh)].mean(axis=0),
                     float(np.min(z[list(hp)])), float(np.min(z[list(sh)])), _TRUNK_R))  # fmt: skip
    for ua, ub, za, zb, r in segments:
        if not (np.isfinite(za) and np.isfinite(zb) and np.isfinite(ua).all()
                and np.isfinite(ub).all()):  # fmt: skip
            continue
        dist, s = _seg_dist(uv[i], ua, ub)
        z_axis = (1.0 - s) * za + s * zb + r  # the limb's axis behind its surface
        if dist > ki.fx * r / z_axis:
            continue  # outside its silhouette
        if abs(zi - (z_axis - r)) <= max(0.05, r):
            return max(ref, z_axis + r)
    return None


_FACE: Final = tuple(i for i in range(11) if i not in (LM["left_ear"], LM["right_ear"]))


def _trunk_sides(
    uv: Array,
    vis: Array,
    z: Array,
    state: NDArray[np.int8],
    hidden: NDArray[np.bool_],
    ki: Intrinsics,
) -> None:
    """A body seen from the side hides its far shoulder and hip behind the trunk: both
    windows then show the near side's surface. When a left/right pair is much closer in depth
    than its 2D gap and the body's width allow, the far one is put behind the near one by what
    the width requires, and flagged hidden. Which one is far: the side the face turns away
    from, or (no face turned enough) the side the model sees less of (visibility lower by 0.3
    or more); when the two disagree, neither is moved."""
    face = uv[list(_FACE)].mean(axis=0)  # the face's nine points: the facing is their mean's
    ears = 0.5 * (uv[LM["left_ear"]] + uv[LM["right_ear"]])
    hips = 0.5 * (uv[LM["left_hip"]] + uv[LM["right_hip"]])
    shoulders = 0.5 * (uv[LM["left_shoulder"]] + uv[LM["right_shoulder"]])
    up, fwd = shoulders - hips, face - ears
    facing = np.isfinite(up).all() and np.isfinite(fwd).all()
    for (a, b), width in _WIDTH_M.items():
        if not (np.isfinite(z[a]) and np.isfinite(z[b])):
            continue
        zm = 0.5 * (z[a] + z[b])
        gap = float(np.linalg.norm(uv[a] - uv[b])) * zm / ki.fx
        need = float(np.sqrt(max(width * width - gap * gap, 0.0)))
        if need < 0.6 * width or abs(z[a] - z[b]) > need - 0.1:
            continue  # turned less than about 40 degrees, or already apart in depth
        cues = []
        if facing and float(np.linalg.norm(fwd)) * zm / ki.fx >= 0.04:
            cues.append(float(up[0] * fwd[1] - up[1] * fwd[0]) > 0.0)  # image y points down
        if abs(vis[a] - vis[b]) >= 0.3:
            cues.append(bool(vis[a] < vis[b]))  # the left one (a) is seen less
        if not cues or len(set(cues)) > 1:
            continue  # nothing says which side is away, or the cues disagree
        far, near = (a, b) if cues[0] else (b, a)
        z[far] = z[near] + need
        state[far] = TrackingState.INFERRED
        hidden[far] = True

"""Lifting 2D landmarks to 3D with the depth image registered to the landmarks' image.

A landmark is a pixel of the image the 2D model saw (the colour camera, or the IR image, which
is the depth camera itself). Its 3D point is on that pixel's ray, at the depth of the surface
the camera saw there. One depth pixel is not enough: a landmark a few pixels off lands on the
background, and a limb in front of a joint hides it. So each landmark gathers the depth readings
of a small window around it (depth pixels projected into the landmark's image through the
device's ``color_from_depth`` and both intrinsics, searched only along the landmark's epipolar
line), splits them into depth layers, and takes the *body's* layer: the nearest one for the
trunk, for a limb one within reach of its parent joint (never the wall behind), preferring the
layer under the window's centre. A landmark whose window shows only another limb in front of
its parent (its pixel inside that limb's silhouette, its depth that limb's surface) is hidden:
it is flagged (inferred) and placed behind the limb at its parent's depth, not on the limb.

The surface seen is the skin; the joint is inside. Each point is pushed along its ray by the
limb's radius (:data:`kinefuse.skeleton.CAPSULE_RADII_M`, the project's nominal radii of a
1.75 m adult: an assumption, a couple of centimetres off for a real body).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import NDArray

from kinefuse.camera.intrinsics import Intrinsics
from kinefuse.devices.pose.landmarks import LM, N_LIFTED
from kinefuse.skeleton import CAPSULE_RADII_M, TrackingState

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
        The farthest a limb landmark's depth may be from its parent's (a forearm's length and
        then some); farther layers are the background.
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
        :class:`~kinefuse.skeleton.TrackingState`.
    hidden : (36,) bool
        Hidden behind another limb (placed behind it and inferred).
    """

    points_m: Array
    states: NDArray[np.int8]
    hidden: NDArray[np.bool_]


class _Registration:
    """Depth pixels seen from the landmarks' image: ``image = R @ depth + t``."""

    def __init__(self, depth_m: NDArray[np.float32], kd: Intrinsics, ki: Intrinsics,
                 image_from_depth: Array | None) -> None:  # fmt: skip
        self.z, self.kd, self.ki = depth_m, kd, ki
        t = np.eye(4) if image_from_depth is None else np.asarray(image_from_depth, float)
        self.r, self.t = t[:3, :3], t[:3, 3]
        self.same = image_from_depth is None or (
            np.allclose(t, np.eye(4)) and ki == kd
        )  # the IR image: the depth camera itself
        self.r_inv = self.r.T
        self.t_inv = -self.r.T @ self.t

    def samples(self, u: float, v: float, radius_px: float) -> tuple[Array, Array]:
        """Depths (in the image camera's z, metres) around pixel ``(u, v)`` and their pixel
        distance to it, within ``radius_px``."""
        kd, ki, h, w = self.kd, self.ki, *self.z.shape
        if self.same:
            u0, u1 = int(np.floor(u - radius_px)), int(np.ceil(u + radius_px))
            v0, v1 = int(np.floor(v - radius_px)), int(np.ceil(v + radius_px))
        else:  # the box around the landmark's epipolar segment in the depth image
            ray = np.array([(u - ki.cx) / ki.fx, (v - ki.cy) / ki.fy, 1.0])
            ends = np.array([ray * kd.min_range_m, ray * kd.max_range_m])
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
        vv, uu = np.nonzero(np.isfinite(crop))
        z = crop[vv, uu].astype(np.float64)
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
    out = []
    for part_z, part_d in zip(np.split(zs, cuts), np.split(ds, cuts), strict=True):
        if part_z.size >= need:
            out.append((float(np.median(part_z)), int(part_z.size), int((part_d <= inner).sum())))
    return out


def _choose(layers: list[tuple[float, int, int]], ref: float | None, params: LiftParams) -> float:
    """The body's layer: nearest for the trunk, within reach of the parent for a limb."""
    if not layers:
        return float("nan")
    if ref is None or not np.isfinite(ref):
        return min(lay[0] for lay in layers)
    near = [lay for lay in layers if abs(lay[0] - ref) <= params.reach_m]
    if not near:
        return float("nan")
    return max(near, key=lambda lay: (lay[2], lay[1], -abs(lay[0] - ref)))[0]


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
    depth_m = depth_mm.astype(np.float32) * np.float32(0.001)
    depth_m[depth_mm == 0] = np.nan
    reg = _Registration(depth_m, depth_intrinsics, image_intrinsics, image_from_depth)
    ki = image_intrinsics
    inside = (
        np.isfinite(uv).all(axis=1)
        & (uv[:, 0] >= -0.5)
        & (uv[:, 0] <= ki.width - 0.5)
        & (uv[:, 1] >= -0.5)
        & (uv[:, 1] <= ki.height - 0.5)
    )

    # the trunk's depth first, with a window sized for 2 m; then every window at the body's size
    def window(z_body: float) -> float:
        return max(2.0, ki.fx * params.window_m / z_body)

    samples: dict[int, tuple[Array, Array]] = {}
    torso_z = []
    for i in _TORSO:
        if inside[i]:
            samples[i] = reg.samples(uv[i, 0], uv[i, 1], window(2.0))
            zt = _choose(_layers(*samples[i], params), None, params)
            if np.isfinite(zt):
                torso_z.append(zt)
    trunk = float(np.median(torso_z)) if torso_z else float("nan")
    radius = window(trunk if np.isfinite(trunk) else 2.0)
    for i in range(N_LIFTED):
        if inside[i]:
            samples[i] = reg.samples(uv[i, 0], uv[i, 1], radius)
    layers = {i: _layers(*s, params) for i, s in samples.items()}

    z = np.full(N_LIFTED, np.nan)
    state = np.full(N_LIFTED, TrackingState.NOT_TRACKED, dtype=np.int8)
    hidden = np.zeros(N_LIFTED, dtype=bool)
    for sweep in range(2):  # the second sweep knows where every limb is
        for i in ORDER:
            if not inside[i]:
                continue
            ref = trunk if PARENT[i] < 0 else z[PARENT[i]]
            zi = _choose(layers[i], ref, params)
            hidden[i] = False
            if sweep == 1 and np.isfinite(zi) and np.isfinite(ref):
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
    """Where landmark ``i`` is if another limb hides it (its window shows that limb), else None."""
    if not zi < ref - params.hidden_margin_m:
        return None
    near = {i, PARENT[i]} | {k for k in range(N_LIFTED) if PARENT[k] == i}
    for a, b, r in _OCCLUDERS:
        if a in near or b in near or not (np.isfinite(z[a]) and np.isfinite(z[b])):
            continue
        dist, s = _seg_dist(uv[i], uv[a], uv[b])
        z_axis = (1.0 - s) * z[a] + s * z[b] + r  # the limb's axis behind its surface
        if dist > ki.fx * r / z_axis:
            continue  # outside that limb's silhouette
        if abs(zi - (z_axis - r)) <= max(0.05, r):
            return max(ref, z_axis + r)
    return None

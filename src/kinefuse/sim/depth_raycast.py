"""Casting a pinhole camera's rays into a :class:`~kinefuse.sim.depth_scene.Scene`, all at
once: the room analytically, capsules and spheres only on the pixels of their bounding
rectangles (culling), z-buffered; the noise-free geometry (:func:`render_geometry`). Re-exported
by :mod:`kinefuse.sim.depth`, which adds the noise.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.geometry.transforms import check_rigid
from kinefuse.errors import InputError
from kinefuse.sim.depth_noise import (
    DEFAULT_DEPTH_NOISE,
    DepthNoiseParams,
)
from kinefuse.sim.depth_scene import Scene, SurfaceLabel

Array = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class DepthGeometry:
    """Noise-free result of casting one camera's rays into a scene.

    Attributes
    ----------
    z_m : (H, W) float
        Depth (z in the sensor frame) of the first hit, metres; ``inf`` where nothing is hit.
    cos_incidence : (H, W) float
        Cosine of the angle between the ray and the surface normal (1 = head-on); 0 for no hit.
    label : (H, W) int8
        :class:`SurfaceLabel` of the first hit.
    corner_dist_m : (H, W) float
        For floor pixels the distance of the hit to the nearest wall, for wall pixels its height
        above the floor (the distance to the concave floor-wall corner); ``inf`` elsewhere.
    """

    z_m: Array
    cos_incidence: Array
    label: NDArray[np.int8]
    corner_dist_m: Array

    @property
    def incidence_rad(self) -> Array:
        """Incidence angle ``(H, W)`` in radians (pi/2 where nothing is hit)."""
        return np.asarray(np.arccos(np.clip(self.cos_incidence, 0.0, 1.0)), dtype=np.float64)


@dataclass(frozen=True, eq=False)
class _Rays:
    """Pixel rays scaled to z = 1, ``q = (x, y, 1)``: the ray parameter of a hit is its depth."""

    x: Array  # (W,) (u - cx) / fx
    y: Array  # (H,) (v - cy) / fy
    qnorm: Array  # (H, W) |q|: range = z * |q|


@lru_cache(maxsize=16)
def _base_rays(intr: Intrinsics) -> _Rays:
    xr = (np.arange(intr.width, dtype=np.float64) - intr.cx) / intr.fx
    yc = (np.arange(intr.height, dtype=np.float64) - intr.cy) / intr.fy
    qn = np.sqrt(xr[None, :] ** 2 + yc[:, None] ** 2 + 1.0)
    for a in (xr, yc, qn):
        a.setflags(write=False)
    return _Rays(xr, yc, qn)


def _check_inputs(
    scene: Any, sensor2world: Any, intrinsics: Any, params: Any
) -> tuple[Array, Array]:
    if not isinstance(scene, Scene):
        raise InputError(f"scene must be a Scene, got {type(scene).__name__}")
    if not isinstance(intrinsics, Intrinsics):
        raise InputError(f"intrinsics must be an Intrinsics, got {type(intrinsics).__name__}")
    if not isinstance(params, DepthNoiseParams):
        raise InputError(f"params must be a DepthNoiseParams, got {type(params).__name__}")
    try:
        t = np.asarray(sensor2world, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError("sensor2world must be a (4, 4) numeric array") from None
    if t.shape != (4, 4):
        raise InputError(f"sensor2world must be one (4, 4) transform, got shape {t.shape}")
    t = check_rigid(t, "sensor2world")
    rot = np.ascontiguousarray(t[:3, :3])
    o = np.ascontiguousarray(t[:3, 3])
    if scene.walls:
        lo, hi = scene.room_min_xy_m, scene.room_max_xy_m
        if not (lo[0] < o[0] < hi[0] and lo[1] < o[1] < hi[1] and 0.0 < o[2] < scene.wall_height_m):
            raise InputError(
                f"the sensor at {np.round(o, 3).tolist()} m is outside the room "
                f"x {lo[0]}..{hi[0]}, y {lo[1]}..{hi[1]}, z 0..{scene.wall_height_m} m; move it "
                "inside or build the Scene with walls=False"
            )
    elif scene.floor and not o[2] > 0.0:
        raise InputError(f"the sensor must be above the floor (z > 0), got z = {o[2]:.3f} m")
    return rot, o


@dataclass(frozen=True, eq=False)
class _Room:
    """The room seen through the exact pixel centres, cached per sensor pose and intrinsics."""

    z: Array  # (H, W) depth, inf where nothing is hit
    cos: Array  # (H, W) cosine of incidence, 0 where nothing is hit
    label: NDArray[np.int8]  # (H, W) SurfaceLabel
    corner: Array  # (H, W) distance to the floor-wall corner, inf for no multipath
    gu: Array  # (H, W) d(1/z)/du of the pixel's plane, 1/(m px): 1/z is affine in u, v
    gv: Array  # (H, W) d(1/z)/dv


def _room(scene: Scene, intr: Intrinsics, rot: Array, o: Array) -> _Room:
    key = (
        scene.room_min_xy_m,
        scene.room_max_xy_m,
        float(scene.wall_height_m),
        bool(scene.walls),
        bool(scene.floor),
    )
    return _room_cached(key, intr, rot.tobytes(), o.tobytes())


@lru_cache(maxsize=8)
def _room_cached(
    key: tuple[tuple[float, float], tuple[float, float], float, bool, bool],
    intr: Intrinsics,
    rot_bytes: bytes,
    o_bytes: bytes,
) -> _Room:
    lo, hi, height, walls, floor = key
    rot = np.frombuffer(rot_bytes, dtype=np.float64).reshape(3, 3)
    o = np.frombuffer(o_bytes, dtype=np.float64)
    rays = _base_rays(intr)
    h, w = intr.height, intr.width
    x = rays.x[None, :]
    y = rays.y[:, None]
    # world ray components (in-place arithmetic below: this runs once per pose, on full frames)
    d = [(rot[i, 0] * x + rot[i, 2]) + rot[i, 1] * y for i in range(3)]
    # faces: 0 floor (z = 0), 1 x = lo, 2 x = hi, 3 y = lo, 4 y = hi; 5 = nothing
    normals = np.array([[0, 0, 1], [1, 0, 0], [1, 0, 0], [0, 1, 0], [0, 1, 0]], dtype=float)
    offsets = np.array([0.0, lo[0], hi[0], lo[1], hi[1]])
    face = np.zeros((h, w), dtype=np.int8)
    with np.errstate(divide="ignore", invalid="ignore"):
        if floor:
            z = np.negative(d[2])
            np.maximum(z, 0.0, out=z)
            np.divide(o[2], z, out=z)  # inf where the ray does not go down
        else:
            z = np.full((h, w), np.inf)
        if walls:
            # the camera is inside the box: it leaves through x = hi when moving toward +x
            tx = np.where(d[0] >= 0.0, hi[0] - o[0], o[0] - lo[0])
            tx /= np.abs(d[0])
            ty = np.where(d[1] >= 0.0, hi[1] - o[1], o[1] - lo[1])
            ty /= np.abs(d[1])
            xwall = tx <= ty
            t_wall = np.minimum(tx, ty, out=tx)
            z_hit = np.multiply(t_wall, d[2], out=ty)
            z_hit += o[2]
            t_wall[z_hit > height] = np.inf  # above the wall
            wall_face = np.where(xwall, d[0] >= 0.0, d[1] >= 0.0).astype(np.int8)
            wall_face += 1
            wall_face[~xwall] += 2
            nearer = t_wall < z
            np.copyto(z, t_wall, where=nearer)
            np.copyto(face, wall_face, where=nearer)
    face[~np.isfinite(z)] = 5
    # 1/z = (n_s . q) / d_s on each face, n_s = R^T n_w and d_s = d_w - n_w . o in the sensor frame
    n_s = normals @ rot
    d_s = offsets - normals @ o
    label = np.array([SurfaceLabel.FLOOR] + [SurfaceLabel.WALL] * 4 + [SurfaceLabel.NONE])
    label = label.astype(np.int8)[face]
    cos = np.append(np.abs(d_s), 0.0)[face]  # |n_s . q| / |q| = |d_s| / (z |q|)
    with np.errstate(invalid="ignore"):
        cos /= np.multiply(z, rays.qnorm)
    corner = np.full((h, w), np.inf)
    if walls:
        with np.errstate(invalid="ignore"):
            px = np.multiply(z, d[0], out=d[0])
            px += o[0]
            dwall = px - lo[0]
            np.minimum(dwall, np.subtract(hi[0], px, out=px), out=dwall)
            py = np.multiply(z, d[1], out=d[1])
            py += o[1]
            dy = py - lo[1]
            np.minimum(dy, np.subtract(hi[1], py, out=py), out=dy)
            np.minimum(dwall, dy, out=dwall)  # floor point: distance to the nearest wall
            np.copyto(corner, dwall, where=face == 0)
            pz = np.multiply(z, d[2], out=d[2])
            pz += o[2]  # wall point: height above the floor
            np.copyto(corner, pz, where=(face > 0) & (face < 5))
    gu_face = np.append(n_s[:, 0] / (intr.fx * d_s), 0.0)
    gv_face = np.append(n_s[:, 1] / (intr.fy * d_s), 0.0)
    room = _Room(z=z, cos=cos, label=label, corner=corner, gu=gu_face[face], gv=gv_face[face])
    for arr in (room.z, room.cos, room.label, room.corner, room.gu, room.gv):
        arr.setflags(write=False)
    return room


def _axis_pixel_bounds(
    c_lat: Array, c_z: Array, r: Array, f: float, c0: float
) -> tuple[Array, Array]:
    """Exact range of the image coordinate (u or v, continuous) of rays that meet each sphere.

    Pixel column u lies in the plane ``x = z (u - c0) / f`` through the sensor's y axis; it meets
    the sphere iff the circle (the sphere projected on the x-z plane) meets that line: a 2-D
    test. Spheres must lie in front of the camera (``c_z > r``).
    """
    rho = np.hypot(c_lat, c_z)
    phi = np.arctan2(c_lat, c_z)
    half = np.arcsin(np.minimum(r / rho, 1.0))
    lim = 0.5 * np.pi - 1e-9
    lo_ang = np.maximum(phi - half, -lim)
    hi_ang = np.minimum(phi + half, lim)
    return c0 + f * np.tan(lo_ang), c0 + f * np.tan(hi_ang)


@dataclass(frozen=True, eq=False)
class _Pairs:
    """The (pixel, primitive) pairs to test: every pixel of each primitive's image rectangle."""

    a_s: Array  # (P, 3) capsule ends in the sensor frame
    b_s: Array  # (P, 3)
    r: Array  # (P,)
    label: NDArray[np.int8]  # (P,)
    counts: NDArray[np.intp]  # (P,) pairs per primitive, in pair order
    k: NDArray[np.intp]  # (N,) primitive of each pair
    row: NDArray[np.intp]  # (N,) pixel row
    col: NDArray[np.intp]  # (N,) pixel column
    pix: NDArray[np.intp]  # (N,) flat pixel index


def _pairs(scene: Scene, rot: Array, o: Array, intr: Intrinsics, margin_px: float) -> _Pairs | None:
    """Cull: each primitive is tested only on the pixels of its exact bounding rectangle."""
    h, w = intr.height, intr.width
    pa, pb, pr, plab = scene.primitives()
    if not len(pr):
        return None
    a_s = (pa - o) @ rot  # world -> sensor: R^T (p - o), row-vector form
    b_s = (pb - o) @ rot
    near = 1e-3
    zmin = np.minimum(a_s[:, 2], b_s[:, 2]) - pr
    zmax = np.maximum(a_s[:, 2], b_s[:, 2]) + pr
    keep = zmax > near  # not wholly behind the camera
    ul = np.full(len(pr), -np.inf)
    uh = np.full(len(pr), np.inf)
    vl = np.full(len(pr), -np.inf)
    vh = np.full(len(pr), np.inf)
    m = keep & (zmin > near)  # both end spheres wholly in front: an exact rectangle
    if m.any():
        ula, uha = _axis_pixel_bounds(a_s[m, 0], a_s[m, 2], pr[m], intr.fx, intr.cx)
        ulb, uhb = _axis_pixel_bounds(b_s[m, 0], b_s[m, 2], pr[m], intr.fx, intr.cx)
        vla, vha = _axis_pixel_bounds(a_s[m, 1], a_s[m, 2], pr[m], intr.fy, intr.cy)
        vlb, vhb = _axis_pixel_bounds(b_s[m, 1], b_s[m, 2], pr[m], intr.fy, intr.cy)
        # a capsule is the convex hull of its end spheres: the hull of the two intervals
        ul[m], uh[m] = np.minimum(ula, ulb), np.maximum(uha, uhb)
        vl[m], vh[m] = np.minimum(vla, vlb), np.maximum(vha, vhb)
    mg = margin_px + 1.0  # jittered rays reach margin_px further; 1 px for rounding
    keep &= (uh + mg >= 0) & (ul - mg <= w - 1) & (vh + mg >= 0) & (vl - mg <= h - 1)
    u0 = np.ceil(np.clip(ul - mg, 0, w - 1)).astype(np.intp)
    u1 = np.floor(np.clip(uh + mg, 0, w - 1)).astype(np.intp)
    v0 = np.ceil(np.clip(vl - mg, 0, h - 1)).astype(np.intp)
    v1 = np.floor(np.clip(vh + mg, 0, h - 1)).astype(np.intp)
    nw = np.where(keep, u1 - u0 + 1, 0)
    npx = nw * np.where(keep, v1 - v0 + 1, 0)
    total = int(npx.sum())
    if not total:
        return None
    k = np.repeat(np.arange(len(pr)), npx)
    local = np.arange(total) - np.repeat(np.cumsum(npx) - npx, npx)
    wk = nw[k]
    row = v0[k] + local // wk
    col = u0[k] + local % wk
    return _Pairs(a_s, b_s, pr, plab, npx, k, row, col, row * w + col)


#: a pixel whose noise-free depth is this far outside the range cannot be read (noise is smaller)
_RANGE_MARGIN_M = 0.5


def _cast(
    scene: Scene,
    rot: Array,
    o: Array,
    intr: Intrinsics,
    jitter: tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.intp]] | None = None,
    pairs: _Pairs | None = None,
) -> DepthGeometry:
    """Cast every pixel's ray.

    ``jitter = (du, dv, idx)``: flat per-pixel ray offsets in pixels, nonzero only at ``idx``;
    then ``pairs`` must have been culled with a margin covering the offsets.
    """
    h, w = intr.height, intr.width
    rays = _base_rays(intr)
    room = _room(scene, intr, rot, o)
    z = room.z.copy()
    if jitter is None:
        pairs = _pairs(scene, rot, o, intr, 0.0)
    else:
        # planes: 1/z is affine in (u, v), so the jittered ray's depth is exact on the same face
        du, dv, idx = jitter
        inv = 1.0 / room.z.reshape(-1)[idx]
        inv += room.gu.reshape(-1)[idx] * du[idx]
        inv += room.gv.reshape(-1)[idx] * dv[idx]
        with np.errstate(divide="ignore"):
            z.reshape(-1)[idx] = np.where(inv > 0.0, 1.0 / inv, np.inf)
    label = room.label.copy()
    cos_inc = room.cos.copy()
    corner = room.corner.copy()
    if pairs is None:
        return DepthGeometry(z_m=z, cos_incidence=cos_inc, label=label, corner_dist_m=corner)

    xf = rays.x[pairs.col]
    yf = rays.y[pairs.row]
    if jitter is not None:
        xf = xf + jitter[0][pairs.pix] * (1.0 / intr.fx)
        yf = yf + jitter[1][pairs.pix] * (1.0 / intr.fy)
    t = _ray_capsule_z(xf, yf, pairs.a_s, pairs.b_s, pairs.r, pairs.counts)
    zflat = z.reshape(-1)
    np.minimum.at(zflat, pairs.pix, t)
    win = np.isfinite(t) & (t == zflat[pairs.pix])
    prim = np.full(h * w, -1, dtype=np.intp)
    prim[pairs.pix[win]] = pairs.k[win]
    sel = np.flatnonzero(prim >= 0)
    if sel.size:
        kk = prim[sel]
        xs = rays.x[sel % w]
        ys = rays.y[sel // w]
        if jitter is not None:
            xs = xs + jitter[0][sel] * (1.0 / intr.fx)
            ys = ys + jitter[1][sel] * (1.0 / intr.fy)
        label.reshape(-1)[sel] = pairs.label[kk]
        corner.reshape(-1)[sel] = np.inf
        cos_inc.reshape(-1)[sel] = _capsule_cos(xs, ys, zflat[sel], pairs.a_s[kk], pairs.b_s[kk])
    return DepthGeometry(z_m=z, cos_incidence=cos_inc, label=label, corner_dist_m=corner)


def _ray_capsule_z(
    x: Array, y: Array, a_s: Array, b_s: Array, r: Array, counts: NDArray[np.intp]
) -> Array:
    """Depth of the nearest hit of rays ``(x, y, 1)`` from the origin with capsules, per pair.

    Capsule ``k`` (sensor frame) is repeated ``counts[k]`` times in the pair order. ``inf`` for
    a miss or a camera inside the primitive. Roots in the stable form ``c / (b + sqrt(b^2 - ac))``.
    """
    ba = b_s - a_s
    length = np.linalg.norm(ba, axis=1)
    e = np.where(length[:, None] > 1e-12, ba / np.maximum(length, 1e-300)[:, None], (0.0, 0.0, 1.0))
    aa = np.einsum("ij,ij->i", a_s, a_s)
    ae = np.einsum("ij,ij->i", a_s, e)
    r2 = r * r

    def rep(v: Array) -> Array:
        return np.repeat(v, counts)

    qq = x * x + y * y + 1.0
    qa = x * rep(a_s[:, 0]) + y * rep(a_s[:, 1]) + rep(a_s[:, 2])
    qe = x * rep(e[:, 0]) + y * rep(e[:, 1]) + rep(e[:, 2])
    ca = rep(aa - r2)  # > 0: camera outside the sphere at a
    cb = rep(np.einsum("ij,ij->i", b_s, b_s) - r2)
    cc = rep(aa - ae * ae - r2)  # > 0: camera outside the infinite cylinder
    ae_p = rep(ae)
    len_p = rep(length)
    qb = qa + len_p * qe
    with np.errstate(invalid="ignore", divide="ignore"):
        ha = qa * qa - qq * ca
        t = np.where((ha >= 0) & (qa > 0) & (ca > 0), ca / (qa + np.sqrt(ha)), np.inf)
        hb = qb * qb - qq * cb
        t = np.minimum(
            t, np.where((hb >= 0) & (qb > 0) & (cb > 0), cb / (qb + np.sqrt(hb)), np.inf)
        )
        ac = qq - qe * qe
        bc = qa - qe * ae_p
        hc = bc * bc - ac * cc
        tc = cc / (bc + np.sqrt(hc))
        s = tc * qe - ae_p  # axial coordinate of the hit
        ok = (hc >= 0) & (ac > 1e-12) & (bc > 0) & (cc > 0) & (s >= 0) & (s <= len_p)
        t = np.minimum(t, np.where(ok, tc, np.inf))
    return np.asarray(t, dtype=np.float64)


def _capsule_cos(x: Array, y: Array, z: Array, a_s: Array, b_s: Array) -> Array:
    """Cosine of incidence at hits ``z * (x, y, 1)`` on capsules ``a_s``-``b_s``, per pixel."""
    p = np.stack([x * z, y * z, z], axis=-1)
    ba = b_s - a_s
    baba = np.einsum("ij,ij->i", ba, ba)
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.where(baba > 1e-24, np.einsum("ij,ij->i", p - a_s, ba) / baba, 0.0)
    n = p - a_s - np.clip(s, 0.0, 1.0)[:, None] * ba  # from the axis to the hit
    qn = np.abs(x * n[:, 0] + y * n[:, 1] + n[:, 2])
    with np.errstate(invalid="ignore", divide="ignore"):
        c = qn / (np.sqrt(x * x + y * y + 1.0) * np.linalg.norm(n, axis=1))
    return np.asarray(np.clip(np.nan_to_num(c, nan=1.0), 0.0, 1.0), dtype=np.float64)


def render_geometry(scene: Scene, sensor2world: ArrayLike, intrinsics: Intrinsics) -> DepthGeometry:
    """Noise-free ray casting: depth, incidence and surface label of every pixel.

    Parameters
    ----------
    scene : Scene
    sensor2world : (4, 4) float
        The camera's pose (sensor frame x right, y down, z forward); it must be in the room.
    intrinsics : Intrinsics

    Returns
    -------
    DepthGeometry
        ``z_m`` is not range-limited here (``inf`` only where nothing is hit).
    """
    rot, o = _check_inputs(scene, sensor2world, intrinsics, DEFAULT_DEPTH_NOISE)
    return _cast(scene, rot, o, intrinsics)

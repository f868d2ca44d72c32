"""Depth images of the simulated lab, with Kinect v2 time-of-flight errors.

The scene is the lab room (floor ``z = 0`` and four walls of an axis-aligned box), the actor's
capsule body and, during calibration, the wand (a sphere on a thin stick). Rays are cast through
every pixel of a pinhole depth camera, all at once:

* the room analytically (a camera inside a box leaves it through exactly one face);
* capsules and spheres only on the pixels of their exact bounding rectangle in the image
  (culling), gathered into one flat batch of (pixel, primitive) pairs and z-buffered with
  ``np.minimum.at``; no pixel is tested against a primitive whose rectangle misses it.

:func:`render_depth` returns what the Kinect SDK gives: ``(H, W) uint16`` millimetres of the
z coordinate in the sensor frame (not the ray length), 0 for no reading. Its error model
(:class:`DepthNoiseParams`, every value with its unit, source and whether it is a measurement or
an assumption; see ``docs/error_model_depth.md``):

1. lateral noise: every pixel's ray is jittered by a sub-pixel Gaussian offset before casting;
2. flying pixels: pixels at depth discontinuities take a depth between foreground and background
   (or no reading, as the SDK's edge filter drops some);
3. axial noise along the ray, growing with distance and incidence angle (Fankhauser et al. 2015);
4. a systematic, distance-dependent range offset (a linear trend plus the periodic "wiggling"
   error of continuous-wave time-of-flight cameras);
5. multipath: concave floor-wall corners read too far;
6. no reading out of the 0.5-4.5 m range, at grazing incidence, or where nothing is hit.

:func:`render_depth_m` is the noise-free geometry in metres (NaN for no reading) for tests and
calibration checks, and :func:`render_geometry` adds the incidence angle and a per-pixel surface
label (floor, wall, body, wand sphere, wand stick): the ground truth a detector is checked with.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.errors import InputError
from kinefuse.sim.depth_noise import (
    DEFAULT_DEPTH_NOISE,
    DepthNoiseParams,
    axial_sigma_m,
    systematic_offset_m,
)
from kinefuse.sim.depth_raycast import (
    _RANGE_MARGIN_M,
    DepthGeometry,
    _base_rays,
    _cast,
    _check_inputs,
    _pairs,
    _room,
    render_geometry,
)
from kinefuse.sim.depth_scene import Scene, SurfaceLabel

Array = NDArray[np.float64]

__all__ = [
    "DEFAULT_DEPTH_NOISE",
    "DepthGeometry",
    "DepthNoiseParams",
    "Scene",
    "SurfaceLabel",
    "axial_sigma_m",
    "render_depth",
    "render_depth_m",
    "render_geometry",
    "systematic_offset_m",
]


def _deterministic_valid(
    geo: DepthGeometry, z: Array, intr: Intrinsics, params: DepthNoiseParams
) -> NDArray[np.bool_]:
    cos_max = math.cos(math.radians(params.grazing_max_deg))
    return (z >= intr.min_range_m) & (z <= intr.max_range_m) & (geo.cos_incidence >= cos_max)


def render_depth_m(
    scene: Scene,
    sensor2world: ArrayLike,
    intrinsics: Intrinsics,
    params: DepthNoiseParams = DEFAULT_DEPTH_NOISE,
) -> Array:
    """Noise-free depth image in metres, NaN where the camera gives no reading.

    No reading: nothing hit, depth outside ``intrinsics``' range, or incidence above
    ``params.grazing_max_deg`` (the only parameter used here).

    Parameters
    ----------
    scene : Scene
    sensor2world : (4, 4) float
    intrinsics : Intrinsics
    params : DepthNoiseParams

    Returns
    -------
    depth_m : (H, W) float
        z coordinate in the sensor frame, metres.
    """
    rot, o = _check_inputs(scene, sensor2world, intrinsics, params)
    geo = _cast(scene, rot, o, intrinsics)
    return np.where(_deterministic_valid(geo, geo.z_m, intrinsics, params), geo.z_m, np.nan)


def _flying_pixels(
    z: Array, params: DepthNoiseParams, rng: np.random.Generator
) -> tuple[Array, NDArray[np.bool_]]:
    """Mix depths across silhouettes. Returns the new depth and the pixels dropped at edges."""
    h, w = z.shape
    drop = np.zeros((h, w), dtype=bool)
    if params.flying_prob == 0.0 and params.edge_invalid_prob == 0.0:
        return z, drop
    with np.errstate(invalid="ignore"):
        eh = np.abs(z[:, 1:] - z[:, :-1]) > params.flying_jump_m  # False where inf - inf
        ev = np.abs(z[1:, :] - z[:-1, :]) > params.flying_jump_m
    fin = np.isfinite(z)
    eh &= fin[:, 1:] & fin[:, :-1]  # a hit next to nothing is no mixture
    ev &= fin[1:, :] & fin[:-1, :]
    edge = np.zeros((h, w), dtype=bool)
    edge[:, 1:] |= eh
    edge[:, :-1] |= eh
    edge[1:, :] |= ev
    edge[:-1, :] |= ev
    idx = np.flatnonzero(edge)
    if idx.size == 0:
        return z, drop
    zf = z.reshape(-1)
    zi = zf[idx]
    row, col = np.divmod(idx, w)
    # the 4-neighbour whose depth differs most: the other side of the silhouette
    best = np.zeros(idx.size)
    other = zi.copy()
    for ok, nb in (
        (col > 0, idx - 1),
        (col < w - 1, idx + 1),
        (row > 0, idx - w),
        (row < h - 1, idx + w),
    ):
        zn = zf[np.where(ok, nb, idx)]  # the pixel itself where there is no neighbour
        with np.errstate(invalid="ignore"):
            d = np.abs(zn - zi)
        better = np.isfinite(d) & (d > best)
        best = np.where(better, d, best)
        other = np.where(better, zn, other)
    u = rng.random(idx.size)
    frac = rng.random(idx.size) * params.flying_max_fraction
    fly = u < params.flying_prob
    dropped = ~fly & (u < params.flying_prob + params.edge_invalid_prob)
    out = z.copy()
    out.reshape(-1)[idx[fly]] = zi[fly] + frac[fly] * (other[fly] - zi[fly])
    drop.reshape(-1)[idx[dropped]] = True
    return out, drop


def render_depth(
    scene: Scene,
    sensor2world: ArrayLike,
    intrinsics: Intrinsics,
    rng: np.random.Generator,
    params: DepthNoiseParams = DEFAULT_DEPTH_NOISE,
    *,
    noise: bool = True,
) -> NDArray[np.uint16]:
    """A depth frame as the Kinect v2 SDK gives it: millimetres of sensor-frame z, 0 = no reading.

    Parameters
    ----------
    scene : Scene
        The room, the body and the wand, world metres.
    sensor2world : (4, 4) float
        The depth camera's pose; it must be inside the room.
    intrinsics : Intrinsics
        Image size, focal lengths, principal point and valid range (0.5-4.5 m for a Kinect v2).
    rng : numpy.random.Generator
        The only source of randomness: the same seed gives the same image.
    params : DepthNoiseParams
        The error model.
    noise : bool
        False: the noise-free depth rounded to mm (the deterministic no-reading rules still
        apply; ``rng`` is not used).

    Returns
    -------
    depth_mm : (H, W) uint16
    """
    if not isinstance(rng, np.random.Generator):
        raise InputError(
            "rng must be a numpy.random.Generator (np.random.default_rng(seed)), got "
            f"{type(rng).__name__}"
        )
    rot, o = _check_inputs(scene, sensor2world, intrinsics, params)
    if not noise:
        geo = _cast(scene, rot, o, intrinsics)
        return _to_mm(geo.z_m, _deterministic_valid(geo, geo.z_m, intrinsics, params))

    p = params
    h, w = intrinsics.height, intrinsics.width
    lo_z = intrinsics.min_range_m - _RANGE_MARGIN_M
    hi_z = intrinsics.max_range_m + _RANGE_MARGIN_M
    sig = p.lateral_sigma_px
    if sig > 0:
        # jitter only the rays that can give a reading: the room in range and the primitives
        pairs = _pairs(scene, rot, o, intrinsics, 3.0 * sig)
        room_z = _room(scene, intrinsics, rot, o).z.reshape(-1)
        cand = (room_z >= lo_z) & (room_z <= hi_z)
        if pairs is not None:
            cand[pairs.pix] = True
        jidx = np.flatnonzero(cand)
        jit = rng.standard_normal((2, jidx.size), dtype=np.float32)
        np.clip(jit, -3.0, 3.0, out=jit)
        jit *= np.float32(sig)
        du = np.zeros(h * w, dtype=np.float32)
        dv = np.zeros(h * w, dtype=np.float32)
        du[jidx] = jit[0]
        dv[jidx] = jit[1]
        geo = _cast(scene, rot, o, intrinsics, (du, dv, jidx), pairs)
    else:
        geo = _cast(scene, rot, o, intrinsics)

    z, dropped = _flying_pixels(geo.z_m, p, rng)
    idx = np.flatnonzero((z >= lo_z) & (z <= hi_z))  # the others cannot come into range
    zf = z.reshape(-1)[idx]
    # |q| of the unjittered ray: the sub-pixel jitter changes it by < 0.2 %, i.e. < 0.01 mm of
    # the noise terms converted below
    qn = _base_rays(intrinsics).qnorm.reshape(-1)[idx]
    theta = np.arccos(np.clip(geo.cos_incidence.reshape(-1)[idx], 0.0, 1.0))
    sigma = axial_sigma_m(zf, np.minimum(theta, math.radians(p.grazing_max_deg)), p)
    range_m = zf * qn
    err = systematic_offset_m(range_m, p)
    err += sigma * rng.standard_normal(idx.size, dtype=np.float32)
    if p.multipath_max_mm > 0:
        cd = geo.corner_dist_m.reshape(-1)[idx]
        err += 1e-3 * p.multipath_max_mm * np.clip(1.0 - cd / p.multipath_extent_m, 0.0, 1.0)
    zm_flat = np.full(h * w, np.inf)
    zm_flat[idx] = zf + err / qn  # the error is along the ray; z is its projection
    z_meas = zm_flat.reshape(h, w)

    # no reading: out of range, grazing (a dropout ramp, then a hard limit), the edge filter
    lo, hi = math.radians(p.grazing_soft_deg), math.radians(p.grazing_max_deg)
    valid = (
        (z_meas >= intrinsics.min_range_m)
        & (z_meas <= intrinsics.max_range_m)
        & (geo.cos_incidence >= math.cos(hi))
        & ~dropped
    )
    ri = np.flatnonzero(valid & (geo.cos_incidence < math.cos(lo)))
    if ri.size:
        th = np.arccos(np.clip(geo.cos_incidence.reshape(-1)[ri], 0.0, 1.0))
        p_drop = (th - lo) / max(hi - lo, 1e-12)
        valid.reshape(-1)[ri[rng.random(ri.size) < p_drop]] = False
    return _to_mm(z_meas, valid)


def _to_mm(z_m: Array, valid: NDArray[np.bool_]) -> NDArray[np.uint16]:
    """Round valid depths to whole millimetres (uint16), 0 elsewhere."""
    out = np.zeros(z_m.shape, dtype=np.uint16)
    out[valid] = (z_m[valid] * 1000.0 + 0.5).astype(np.uint16)
    return out

"""A robust detector of the spherical calibration wand in one depth frame.

The paper's detector (:mod:`kinefuse.capture.calibration.wand_paper`) takes the nearest object for
the wand. In a real room that is often the floor at the bottom of the image, the person holding the
wand, or a table. This detector instead looks for an object that has the wand's known geometry:

1. **Candidates** (on the frame subsampled by ``step``, for speed): pixels whose depth is continuous
   with their four neighbours (a jump larger than ``jump_m + jump_rel * z`` breaks continuity) are
   grouped into connected components (``scipy.ndimage.label``). Removing the pixels next to a depth
   jump also cuts the thin stick off the ball. A component is kept when its pixel count and its
   bounding box are compatible with a sphere of the known radius at the component's depth.
   A first look at the depth around each candidate drops those that are clearly not isolated
   from their surroundings (floor patches, body parts) before any fit.
2. **Fit** (full resolution, on a small window around each candidate): the pixels of the candidate
   are back-projected with the intrinsics and a sphere of the KNOWN radius is fitted to them by
   iteratively reweighted Gauss-Newton (Tukey weights), so flying pixels and the stick do not pull
   the centre.
3. **Checks**: the robust RMS residual of the fit, the *coverage* (fraction of the predicted
   silhouette whose depth agrees with the fitted sphere), the *circularity* (fraction of the
   nearby pixels at the sphere's depth that lie inside its silhouette) and the *isolation*
   (fraction of two rings of pixels around the silhouette that lie clearly behind the sphere or
   have no reading). A head passes the fit but not the isolation: it continues into the neck and
   shoulders at the same depth. A mug, a wall or the floor fail the size or the fit.

The score is ``coverage * isolation * circularity * exp(-(residual / tolerance)^2)``, in [0, 1].
Nothing that fails a check is reported: the frame gets ``found=False`` and the reason.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from kinefuse.capture.calibration.common import (
    WandDetection,
    WandTrack,
    check_depth_frame,
    check_frames,
)
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.camera.wand import Wand
from kinefuse.errors import InputError

Array = NDArray[np.float64]

_MAX_FIT_POINTS = 400
_GOOD_ENOUGH = 0.85  # a candidate this good ends the search
_RING_ANGLES = np.linspace(0.0, 2.0 * np.pi, 72, endpoint=False)
_COS = np.cos(_RING_ANGLES)
_SIN = np.sin(_RING_ANGLES)


@dataclass(frozen=True)
class RobustDetectorParams:
    """Tunables of :func:`detect_wand` (metres, pixels; defaults suit a Kinect v2).

    Attributes
    ----------
    step : int
        Subsampling of the candidate search (2: 256x212 for a Kinect v2 frame).
    jump_m, jump_rel : float
        Two neighbours are continuous when their depths differ by less than
        ``jump_m + jump_rel * z`` (z in metres).
    min_radius_px : float
        Smallest silhouette radius (full-resolution pixels) worth fitting.
    max_candidates : int
        At most this many components are fitted, the best-sized first.
    max_residual_m, residual_rel : float
        Accept a fit whose robust RMS residual is below ``max_residual_m + residual_rel * z^2``.
    min_coverage, min_circularity, min_isolation : float
        Minimum fractions (see the module docstring).
    isolation_gap_m : float
        A ring pixel isolates the sphere when it has no reading or lies this much behind the
        sphere's centre.
    ring_radii : tuple of float
        Radii of the isolation rings, in units of the silhouette radius.
    """

    step: int = 2
    jump_m: float = 0.03
    jump_rel: float = 0.02
    min_radius_px: float = 4.0
    max_candidates: int = 6
    max_residual_m: float = 0.004
    residual_rel: float = 0.0012
    min_coverage: float = 0.6
    min_circularity: float = 0.8
    min_isolation: float = 0.8
    isolation_gap_m: float = 0.10
    ring_radii: tuple[float, ...] = (1.3, 1.7)

    def __post_init__(self) -> None:
        if self.step < 1:
            raise InputError(f"step must be >= 1, got {self.step}")
        for name in ("min_coverage", "min_circularity", "min_isolation"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise InputError(f"{name} must be in [0, 1], got {v}")


DEFAULT_PARAMS = RobustDetectorParams()


def _continuous_mask(z: Array, p: RobustDetectorParams) -> NDArray[np.bool_]:
    """Valid pixels whose 4 neighbours (inside the image) are valid and depth-continuous."""
    valid = z > 0
    ok = valid.copy()
    # horizontal neighbours
    a, b = z[:, :-1], z[:, 1:]
    jump = np.abs(a - b) > (p.jump_m + p.jump_rel * np.minimum(a, b))
    jump |= ~(valid[:, :-1] & valid[:, 1:])
    ok[:, :-1] &= ~jump
    ok[:, 1:] &= ~jump
    a, b = z[:-1, :], z[1:, :]
    jump = np.abs(a - b) > (p.jump_m + p.jump_rel * np.minimum(a, b))
    jump |= ~(valid[:-1, :] & valid[1:, :])
    ok[:-1, :] &= ~jump
    ok[1:, :] &= ~jump
    return ok


def _silhouette_radius_px(f: float, r: float, zc: Array | float) -> Array:
    """Radius in pixels of the image of a sphere of radius ``r`` whose centre is at depth zc."""
    zc_ = np.maximum(np.asarray(zc, dtype=np.float64), r * 1.05)
    return np.asarray(f * r / np.sqrt(zc_ * zc_ - r * r))


def _fit_sphere_known_radius(
    pts: Array, r: float, c0: Array, sigma_floor: float, iters: int = 10
) -> tuple[Array, Array, Array]:
    """IRLS Gauss-Newton fit of a sphere of radius ``r``; returns (centre, residuals, weights).

    Tukey biweight with a scale from the median absolute residual (never below
    ``sigma_floor``), so flying pixels and the stick get zero weight.
    """
    c = c0.copy()
    w = np.ones(len(pts))
    scale = sigma_floor
    for it in range(iters):
        diff = c[None, :] - pts
        dist = np.maximum(np.sqrt(np.einsum("ij,ij->i", diff, diff)), 1e-9)
        res = dist - r
        if it < 3:  # the scale settles after the first steps; the median is the costly part
            scale = max(1.4826 * float(np.median(np.abs(res))), sigma_floor)
        u = res / (4.685 * scale)
        w = np.where(np.abs(u) < 1.0, (1.0 - u * u) ** 2, 0.0)
        if w.sum() < 6:
            break
        jac = diff / dist[:, None]
        jw = jac * w[:, None]
        step = np.linalg.solve(jw.T @ jac + 1e-9 * np.eye(3), jw.T @ res)
        c = c - step
        if float(step @ step) < 1e-12:  # 1 um
            break
    diff = c[None, :] - pts
    res = np.sqrt(np.einsum("ij,ij->i", diff, diff)) - r
    return c, res, w


def _sphere_front_depth(c: Array, r: float, rays: Array) -> Array:
    """z of the front surface of a sphere along unit-z-normalised rays ``(M, 3)`` (z = 1)."""
    # ray points: s * rays (rays have z = 1, so s is the depth)
    a = np.einsum("ij,ij->i", rays, rays)
    b = rays @ c
    disc = b * b - a * (c @ c - r * r)
    with np.errstate(invalid="ignore"):
        s = (b - np.sqrt(disc)) / a
    return np.where(disc >= 0, s, np.nan)


def _ring_isolation(
    d: NDArray[np.uint16],
    uv: Array,
    rho: float,
    zc: float,
    p: RobustDetectorParams,
) -> tuple[float, float]:
    """(isolated fraction, fraction of ring samples inside the image) around a silhouette."""
    h, w = d.shape
    radii = np.asarray(p.ring_radii)[:, None] * rho
    us = np.rint(uv[0] + radii * _COS[None, :]).astype(np.intp).ravel()
    vs = np.rint(uv[1] + radii * _SIN[None, :]).astype(np.intp).ravel()
    inside = (us >= 0) & (us < w) & (vs >= 0) & (vs < h)
    n_in = int(inside.sum())
    if n_in == 0:
        return 0.0, 0.0
    dz = d[vs[inside], us[inside]].astype(np.float64) * 1e-3
    iso = (dz <= 0) | (dz > zc + p.isolation_gap_m)
    return float(iso.mean()), n_in / len(us)


def _refine_candidate(
    d: NDArray[np.uint16],
    intr: Intrinsics,
    r: float,
    uv0: Array,
    z_front: float,
    p: RobustDetectorParams,
) -> tuple[WandDetection, int]:
    """Fit and check one candidate at full resolution around pixel ``uv0``.

    Returns the detection and how far the candidate got through the checks (for the reason
    reported when nothing is found: the candidate that came closest). Large silhouettes (a wand
    near the camera) are sampled with a stride so that about ``(2 * 15)^2`` pixels cover the
    disc; the cost per candidate stays constant.
    """
    h, w = d.shape
    f = 0.5 * (intr.fx + intr.fy)
    rho0 = float(_silhouette_radius_px(f, r, z_front + r))
    # cheap first look: most candidates (floor patches, body parts) are not isolated in depth
    iso0, _ = _ring_isolation(d, uv0, rho0, z_front + r, p)
    if iso0 < p.min_isolation - 0.25:
        return WandDetection.not_found(
            f"not isolated in depth ({iso0:.2f} of its surroundings behind it): not a wand"
        ), 2
    st = max(1, round(rho0 / 15.0))
    half = int(np.ceil(max(p.ring_radii) * rho0 + 3))
    u0 = max(int(uv0[0]) - half, 0)
    u1 = min(int(uv0[0]) + half + 1, w)
    v0 = max(int(uv0[1]) - half, 0)
    v1 = min(int(uv0[1]) + half + 1, h)
    win = d[v0:v1:st, u0:u1:st].astype(np.float64) * 1e-3
    vv, uu = np.mgrid[v0:v1:st, u0:u1:st]
    r2 = (uu - uv0[0]) ** 2 + (vv - uv0[1]) ** 2
    band = (win > z_front - 0.03) & (win < z_front + r + 0.03)
    sel = band & (r2 <= (1.15 * rho0) ** 2)
    n = int(sel.sum())
    if n < 12:
        return WandDetection.not_found("too few points at the candidate", n_points=n), 0
    zs = win[sel]
    us = uu[sel].astype(np.float64)
    vs_ = vv[sel].astype(np.float64)
    if n > _MAX_FIT_POINTS:  # regular thinning keeps the cost bounded (bias-free)
        k = slice(None, None, int(np.ceil(n / _MAX_FIT_POINTS)))
        zs, us, vs_ = zs[k], us[k], vs_[k]
    pts = np.stack([(us - intr.cx) / intr.fx * zs, (vs_ - intr.cy) / intr.fy * zs, zs], axis=1)
    mean = pts.mean(axis=0)
    c0 = mean + 0.5 * r * mean / np.linalg.norm(mean)
    sigma_floor = 0.0015 + 0.0005 * float(mean[2]) ** 2
    c, res, wts = _fit_sphere_known_radius(pts, r, c0, sigma_floor)
    inl = wts > 0
    if inl.sum() < 12 or not np.all(np.isfinite(c)):
        return WandDetection.not_found("sphere fit did not converge", n_points=n), 1
    resid = float(np.sqrt(np.mean(res[inl] ** 2)))
    zc = float(c[2])
    tol = p.max_residual_m + p.residual_rel * zc * zc
    if zc <= float(np.median(zs)):
        return WandDetection.not_found("fitted centre lies in front of the surface", n_points=n), 1
    uvc = np.array([intr.fx * c[0] / zc + intr.cx, intr.fy * c[1] / zc + intr.cy])
    rho = float(_silhouette_radius_px(f, r, zc))
    # coverage: inner disc pixels that agree with the fitted sphere's front surface
    dr2 = (uu - uvc[0]) ** 2 + (vv - uvc[1]) ** 2
    disc = dr2 <= (0.85 * rho) ** 2
    n_disc = int(disc.sum())
    if n_disc == 0:
        return WandDetection.not_found("silhouette outside the image", n_points=n), 1
    rays = np.stack(
        [(uu[disc] - intr.cx) / intr.fx, (vv[disc] - intr.cy) / intr.fy, np.ones(n_disc)], axis=1
    )
    z_pred = _sphere_front_depth(c, r, rays)
    agree_tol = 0.01 + 3.0 * sigma_floor
    coverage = float(np.mean(np.abs(win[disc] - z_pred) < agree_tol))
    # circularity: pixels at the sphere's depth near it should lie inside its silhouette
    near_depth = (win > zc - r - 0.03) & (win < zc + 0.5 * r)
    around = near_depth & (dr2 <= (max(p.ring_radii) * rho) ** 2)
    n_around = int(around.sum())
    inside = int((around & (dr2 <= (1.1 * rho + 1.0) ** 2)).sum())
    circularity = inside / n_around if n_around else 0.0
    isolation, frac_in = _ring_isolation(d, uvc, rho, zc, p)
    score = coverage * circularity * isolation * float(np.exp(-((resid / tol) ** 2)))
    det = WandDetection(
        found=True,
        centre_sensor_m=c,
        score=score,
        n_points=int(inl.sum()) * st * st,
        residual_m=resid,
        reason="ok",
        pixel_uv=uvc,
    )
    if resid > tol:
        return _reject(det, f"fit residual {resid * 1e3:.1f} mm above {tol * 1e3:.1f} mm"), 2
    if coverage < p.min_coverage:
        return _reject(det, f"coverage {coverage:.2f} below {p.min_coverage}"), 3
    if circularity < p.min_circularity:
        return _reject(det, f"circularity {circularity:.2f} below {p.min_circularity}"), 4
    if frac_in < 0.5:
        return _reject(det, "the wand is cut by the image border"), 5
    if isolation < p.min_isolation:
        return _reject(
            det,
            f"not isolated in depth ({isolation:.2f} of its surroundings behind it, need "
            f"{p.min_isolation}): a head or an object on a surface, not a wand",
        ), 6
    return det, 7


def _reject(det: WandDetection, reason: str) -> WandDetection:
    return WandDetection(
        found=False,
        centre_sensor_m=np.full(3, np.nan),
        score=0.0,
        n_points=det.n_points,
        residual_m=det.residual_m,
        reason=reason,
    )


def detect_wand(
    depth_mm: ArrayLike,
    intrinsics: Intrinsics,
    wand: Wand | None = None,
    *,
    params: RobustDetectorParams = DEFAULT_PARAMS,
    name: str = "depth frame",
) -> WandDetection:
    """Find the spherical wand in one depth frame, robustly (see the module docstring).

    Parameters
    ----------
    depth_mm : (H, W) uint16
        Depth (z in the sensor frame) in millimetres, 0 = no reading.
    intrinsics : Intrinsics
        Pinhole model of the depth camera; must match the frame size.
    wand : Wand, optional
        Wand geometry (default: ``Wand()``, a 0.10 m sphere).
    params : RobustDetectorParams
        Tunables.
    name : str
        Name of the frame for error messages.

    Returns
    -------
    WandDetection
        ``found=True`` with the sphere centre in the sensor frame (metres), score, number of
        points, robust RMS residual; or ``found=False`` with the reason.

    Raises
    ------
    InputError
        NaN depth, a frame whose size does not match the intrinsics.
    """
    d = check_depth_frame(depth_mm, intrinsics, name=name)
    wnd = Wand() if wand is None else wand
    r = wnd.radius_m
    s = params.step
    small: Array = d[::s, ::s].astype(np.float64) * 0.001
    mask = _continuous_mask(small, params)
    lab = np.empty(mask.shape, dtype=np.intp)
    n_lab = int(ndimage.label(mask, output=lab))
    if n_lab == 0:
        return WandDetection.not_found("no depth-continuous surface in the frame")
    flat = lab.ravel()
    count = np.bincount(flat, minlength=n_lab + 1)[1:].astype(np.float64)
    zsum = np.bincount(flat, weights=small.ravel(), minlength=n_lab + 1)[1:]
    zmean = zsum / np.maximum(count, 1)
    f = 0.5 * (intrinsics.fx + intrinsics.fy)
    rho = _silhouette_radius_px(f, r, zmean + 2.0 * r / 3.0)  # full-res px
    rho_s = rho / s
    expect = np.pi * np.maximum(rho_s - 1.0, 0.5) ** 2
    ratio = count / expect
    ok = (rho >= params.min_radius_px) & (ratio > 0.25) & (ratio < 1.6) & (count >= 4)
    cand = np.flatnonzero(ok)
    if cand.size == 0:
        return WandDetection.not_found("no object of the wand's size in the frame")
    # bounding boxes of the surviving components
    objs = ndimage.find_objects(lab)
    keep: list[tuple[int, tuple[slice, slice]]] = []
    for k in cand.tolist():
        sl = objs[k]
        if sl is None:
            continue
        hgt = sl[0].stop - sl[0].start
        wid = sl[1].stop - sl[1].start
        lim = 2.0 * rho_s[k]
        if hgt <= 1.35 * lim + 2 and wid <= 1.35 * lim + 2 and max(hgt, wid) >= 0.4 * lim:
            keep.append((k, sl))
    if not keep:
        return WandDetection.not_found("no object of the wand's shape in the frame")
    keep.sort(key=lambda ks: abs(np.log(ratio[ks[0]])))
    keep = keep[: params.max_candidates]
    best: WandDetection | None = None
    closest = ("", -1)  # reason of the rejected candidate that passed the most checks
    for k, sl in keep:  # k: component index (label k + 1)
        in_comp = lab[sl] == k + 1
        z_comp = small[sl][in_comp]
        z_front = float(np.percentile(z_comp, 2))
        rr, cc = np.nonzero(in_comp)
        uv0 = np.array([(cc.mean() + sl[1].start) * s, (rr.mean() + sl[0].start) * s])
        det, stage = _refine_candidate(d, intrinsics, r, uv0, z_front, params)
        if det.found:
            if best is None or det.score > best.score:
                best = det
            if det.score >= _GOOD_ENOUGH:
                break
        elif stage > closest[1]:
            closest = (det.reason, stage)
    if best is None:
        return WandDetection.not_found(closest[0] or "no candidate fitted the wand")
    return best


def detect_wand_sequence(
    frames_mm: ArrayLike,
    intrinsics: Intrinsics,
    wand: Wand | None = None,
    *,
    params: RobustDetectorParams = DEFAULT_PARAMS,
    name: str = "frames",
) -> WandTrack:
    """Run :func:`detect_wand` on every frame of a stack.

    Parameters
    ----------
    frames_mm : (N, H, W) uint16
        Depth frames in millimetres.
    intrinsics, wand, params
        As for :func:`detect_wand`.
    name : str
        Name of the stack for error messages (e.g. the sensor id); frame ``i`` is ``name[i]``.

    Returns
    -------
    WandTrack
        Arrays with the frame axis first: ``found (N,)``, ``centre_sensor_m (N, 3)`` (NaN where
        not found), ``score (N,)``, ``n_points (N,)``, ``residual_m (N,)``, ``reasons``.
    """
    frames = check_frames(frames_mm, intrinsics, name=name)
    dets = [
        detect_wand(frames[i], intrinsics, wand, params=params, name=f"{name}[{i}]")
        for i in range(frames.shape[0])
    ]
    return WandTrack.from_detections(dets)

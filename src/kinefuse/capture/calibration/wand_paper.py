"""Paper A's wand detector, as specified (METHODS.md A.3 steps 1-4), for comparison.

The paper takes the wand for the object nearest to the sensor:

1. **Standardization** of the depth in centimetres: no reading (d < 50) becomes 850, far values
   (d > 650) become 650.
2. **Iterated binarization**: every pixel starts labelled 1; at iteration k the threshold is
   ``r_k = mean(d | T = 1) * (1 - c_offset)``, kept no lower than
   ``min(d | T = 1) * (1 + c_offset)`` (without that floor the threshold can drop below the
   nearest pixel and empty the label map; with it the loop always ends on the nearest object);
   pixels nearer than ``r_k`` keep label 1.
   The loop stops when ``max(d | T = 1) <= min(d | T = 1) * (1 + c_offset)``.
3. **Centre**: the upper-left and bottom-right boundary pixels of the labelled region, their
   midpoint ``p_m``, back-projected with the camera intrinsics (not the paper's field-of-view
   formula) at the depth seen at ``p_m``, and pushed the wand's radius further along the ray.
4. **Repeated measurements**: the measurement is repeated ``repeats`` times with ``c_offset``
   spread by +-``spread`` around its value, and measurements farther than ``reject_m`` from
   their median are dropped (:func:`paper_filter`, which also filters over consecutive frames).

Where the keyword text of the paper is ambiguous (the exact threshold rule, the c_offset value)
this module chooses the reading above and says so; ``c_offset`` is a parameter. The paper's
method has no notion of shape: the floor at the bottom of the image, the hand or a table nearer
than the wand is taken for the wand (see :mod:`kinefuse.capture.calibration.wand_robust`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

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

#: Paper's standardization constants, centimetres.
NEAR_CM = 50.0
FAR_CM = 650.0
NO_READING_CM = 850.0


def standardize_depth_cm(depth_mm: NDArray[np.uint16]) -> NDArray[np.float32]:
    """Step 1: depth in cm with no reading -> 850 and far -> 650 (paper's eq. 1)."""
    d = depth_mm.astype(np.float32) * np.float32(0.1)
    out = np.where(d > FAR_CM, np.float32(FAR_CM), d)
    return np.where(d < NEAR_CM, np.float32(NO_READING_CM), out).astype(np.float32)


def binarize_nearest(
    d_cm: NDArray[np.float32], c_offset: float, max_iter: int = 100
) -> NDArray[np.bool_]:
    """Step 2: the iterated binarization; returns the label map ``T`` (True = wand)."""
    label = np.ones(d_cm.shape, dtype=bool)
    for _ in range(max_iter):
        vals = d_cm[label]
        lo, hi = float(vals.min()), float(vals.max())
        if hi <= lo * (1.0 + c_offset):
            break
        thr = max(float(vals.mean()) * (1.0 - c_offset), lo * (1.0 + c_offset))
        label &= d_cm <= thr
    return label


def _measure_once(
    d_mm: NDArray[np.uint16],
    d_cm: NDArray[np.float32],
    intr: Intrinsics,
    r: float,
    c_offset: float,
) -> tuple[Array, int] | None:
    label = binarize_nearest(d_cm, c_offset)
    # nothing but "no reading" or "far" left: no wand
    if not label.any() or float(d_cm[label].min()) >= FAR_CM:
        return None
    vs, us = np.nonzero(label)
    u_ul, v_ul, u_br, v_br = us.min(), vs.min(), us.max(), vs.max()
    um, vm = 0.5 * (u_ul + u_br), 0.5 * (v_ul + v_br)
    # depth at the midpoint: median of the labelled pixels in a 5x5 neighbourhood, else the
    # nearest labelled depth (the midpoint can fall in a hole of the label map)
    iu, iv = round(um), round(vm)
    sl = (slice(max(iv - 2, 0), iv + 3), slice(max(iu - 2, 0), iu + 3))
    near = d_mm[sl][label[sl]]
    z = float(np.median(near)) * 1e-3 if near.size else float(d_mm[label].min()) * 1e-3
    surface = intr.backproject(np.array([um, vm]), z)
    centre = surface + r * surface / np.linalg.norm(surface)
    return centre, int(label.sum())


def paper_filter(
    centres_m: ArrayLike, *, reject_m: float = 0.02
) -> tuple[Array, NDArray[np.bool_]]:
    """Step 4: combine repeated measurements, dropping those that deviate from the others.

    Parameters
    ----------
    centres_m : (K, 3) float
        Repeated measurements of one wand position (NaN rows are ignored).
    reject_m : float
        Measurements farther than this from the component-wise median are outliers.

    Returns
    -------
    centre : (3,) float
        Mean of the kept measurements (NaN if none).
    kept : (K,) bool
    """
    c = np.asarray(centres_m, dtype=np.float64)
    if c.ndim != 2 or c.shape[1] != 3:
        raise InputError(f"centres_m must have shape (K, 3), got {c.shape}")
    fin: NDArray[np.bool_] = np.asarray(np.isfinite(c).all(axis=1))
    if not fin.any():
        return np.full(3, np.nan), fin
    med = np.median(c[fin], axis=0)
    kept: NDArray[np.bool_] = fin & (
        np.linalg.norm(np.where(fin[:, None], c, 0.0) - med, axis=1) <= reject_m
    )
    if not kept.any():
        return np.full(3, np.nan), kept
    return c[kept].mean(axis=0), kept


def detect_wand_paper(
    depth_mm: ArrayLike,
    intrinsics: Intrinsics,
    wand: Wand | None = None,
    *,
    c_offset: float = 0.1,
    repeats: int = 5,
    spread: float = 0.3,
    reject_m: float = 0.02,
    name: str = "depth frame",
) -> WandDetection:
    """The paper's wand detector (nearest object, bounding-box midpoint, radius along the ray).

    Parameters
    ----------
    depth_mm : (H, W) uint16
        Depth in millimetres, 0 = no reading.
    intrinsics : Intrinsics
        Must match the frame size.
    wand : Wand, optional
        Its radius is added along the ray (default ``Wand()``).
    c_offset : float
        The paper's binarization coefficient (0 < c_offset < 1). 0.1 keeps a 10 cm sphere at
        1-4 m whole while cutting off the hand 0.4 m behind it.
    repeats : int
        Number of repeated measurements (c_offset spread over ``c_offset * (1 +- spread)``).
    spread : float
        Relative spread of c_offset over the repeats (0 repeats the same measurement).
    reject_m : float
        Outlier distance of :func:`paper_filter`.
    name : str
        Name of the frame for error messages.

    Returns
    -------
    WandDetection
        ``score`` is the fraction of repeats kept, ``n_points`` the mean labelled area,
        ``residual_m`` the RMS spread of the kept repeats.
    """
    if not 0.0 < c_offset < 1.0:
        raise InputError(f"c_offset must be between 0 and 1, got {c_offset}")
    if repeats < 1:
        raise InputError(f"repeats must be >= 1, got {repeats}")
    if not 0.0 <= spread < 1.0:
        raise InputError(f"spread must be in [0, 1), got {spread}")
    d = check_depth_frame(depth_mm, intrinsics, name=name)
    r = (Wand() if wand is None else wand).radius_m
    d_cm = standardize_depth_cm(d)
    offsets = (
        c_offset * (1.0 + spread * np.linspace(-1.0, 1.0, repeats)) if repeats > 1 else [c_offset]
    )
    centres = np.full((repeats, 3), np.nan)
    areas = np.zeros(repeats)
    for i, co in enumerate(offsets):
        m = _measure_once(d, d_cm, intrinsics, r, float(co))
        if m is not None:
            centres[i], areas[i] = m
    centre, kept = paper_filter(centres, reject_m=reject_m)
    if not kept.any():
        return WandDetection.not_found(
            "no near object" if not np.isfinite(centres).any() else "repeats disagree"
        )
    spread_m = float(np.sqrt(np.mean(np.sum((centres[kept] - centre) ** 2, axis=1))))
    uv = intrinsics.project(centre)
    return WandDetection(
        found=True,
        centre_sensor_m=centre,
        score=float(kept.mean()),
        n_points=int(areas[kept].mean()),
        residual_m=spread_m,
        reason="ok",
        pixel_uv=uv,
    )


def detect_wand_paper_sequence(
    frames_mm: ArrayLike,
    intrinsics: Intrinsics,
    wand: Wand | None = None,
    *,
    c_offset: float = 0.1,
    repeats: int = 5,
    spread: float = 0.3,
    reject_m: float = 0.02,
    name: str = "frames",
) -> WandTrack:
    """:func:`detect_wand_paper` on every frame of ``(N, H, W)`` (same parameters)."""
    frames = check_frames(frames_mm, intrinsics, name=name)
    dets = [
        detect_wand_paper(
            frames[i],
            intrinsics,
            wand,
            c_offset=c_offset,
            repeats=repeats,
            spread=spread,
            reject_m=reject_m,
            name=f"{name}[{i}]",
        )
        for i in range(frames.shape[0])
    ]
    return WandTrack.from_detections(dets)

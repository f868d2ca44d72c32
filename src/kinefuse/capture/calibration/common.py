"""Types and input checks shared by the wand detectors.

A detection is reported in the sensor frame (x right, y down, z forward, metres). A frame in which
the wand is not found still yields a :class:`WandDetection`, with ``found=False``, a NaN centre and
a ``reason`` that says why, so that a client can log it and move on.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.errors import InputError

Array = NDArray[np.float64]


def _nan3() -> Array:
    return np.full(3, np.nan)


@dataclass(frozen=True, eq=False)
class WandDetection:
    """The wand in one depth frame.

    Attributes
    ----------
    found : bool
        True when a wand was detected.
    centre_sensor_m : (3,) float
        Wand (sphere) centre in the sensor frame, metres; NaN when not found.
    score : float
        Quality in [0, 1] (1 = best); 0 when not found. The registration uses it as a weight.
    n_points : int
        Number of depth samples the estimate rests on (the robust detector: the inliers of its
        sphere fit, after thinning large silhouettes; the paper's: the labelled pixels).
    residual_m : float
        Robust RMS distance of those points to the fitted surface, metres (NaN when the method
        fits no surface, as the paper's does).
    reason : str
        ``"ok"`` or why nothing was found.
    pixel_uv : (2,) float
        Image position of the centre (pixels), NaN when not found.
    """

    found: bool
    centre_sensor_m: Array = field(default_factory=_nan3)
    score: float = 0.0
    n_points: int = 0
    residual_m: float = float("nan")
    reason: str = "ok"
    pixel_uv: Array = field(default_factory=lambda: np.full(2, np.nan))

    @classmethod
    def not_found(cls, reason: str, *, n_points: int = 0) -> WandDetection:
        """A negative detection carrying ``reason``."""
        return cls(found=False, reason=reason, n_points=n_points)


@dataclass(frozen=True, eq=False)
class WandTrack:
    """Detections of a sequence of frames, as arrays (frame axis first).

    Attributes
    ----------
    found : (N,) bool
    centre_sensor_m : (N, 3) float
        NaN where not found.
    score : (N,) float
    n_points : (N,) int
    residual_m : (N,) float
    reasons : tuple of str, length N
    """

    found: NDArray[np.bool_]
    centre_sensor_m: Array
    score: Array
    n_points: NDArray[np.int64]
    residual_m: Array
    reasons: tuple[str, ...]

    @classmethod
    def from_detections(cls, detections: list[WandDetection]) -> WandTrack:
        n = len(detections)
        return cls(
            found=np.array([d.found for d in detections], dtype=bool).reshape(n),
            centre_sensor_m=np.array([d.centre_sensor_m for d in detections]).reshape(n, 3),
            score=np.array([d.score for d in detections], dtype=np.float64).reshape(n),
            n_points=np.array([d.n_points for d in detections], dtype=np.int64).reshape(n),
            residual_m=np.array([d.residual_m for d in detections], dtype=np.float64).reshape(n),
            reasons=tuple(d.reason for d in detections),
        )


def check_depth_frame(
    depth_mm: ArrayLike, intrinsics: Intrinsics, *, name: str = "depth frame"
) -> NDArray[np.uint16]:
    """Validate one depth frame and return it as ``(H, W) uint16`` millimetres.

    Parameters
    ----------
    depth_mm : (H, W) array
        Depth (z in the sensor frame) in millimetres, 0 for no reading, as the Kinect SDK gives
        it. Float input is accepted if it holds whole, non-negative, finite values.
    intrinsics : Intrinsics
        The camera the frame comes from; its ``height`` x ``width`` must match the frame.
    name : str
        How to name the frame in error messages (e.g. ``"frame 12 of sensor k1"``).

    Raises
    ------
    InputError
        Wrong shape, NaN/inf, negative or out-of-range values.
    """
    if not isinstance(intrinsics, Intrinsics):
        raise InputError(
            f"{name}: intrinsics must be a kinefuse.core.camera.intrinsics.Intrinsics, "
            f"got {type(intrinsics).__name__}"
        )
    a = np.asarray(depth_mm)
    expected = (intrinsics.height, intrinsics.width)
    if a.shape != expected:
        raise InputError(
            f"{name} has shape {a.shape}, but the intrinsics describe a "
            f"{intrinsics.width}x{intrinsics.height} image (expected shape {expected}); "
            "pass the intrinsics of the camera that took this frame"
        )
    if a.dtype == np.uint16:
        return a
    if a.dtype.kind not in "uif":
        raise InputError(f"{name} must hold numbers (depth in mm), got dtype {a.dtype}")
    if a.dtype.kind == "f":
        bad = ~np.isfinite(a)
        if bad.any():
            v, u = np.argwhere(bad)[0]
            raise InputError(
                f"{name} contains {int(bad.sum())} NaN/inf depth values (first at pixel "
                f"u={u}, v={v}); depth frames are uint16 millimetres with 0 for no reading: "
                "replace NaN by 0"
            )
    if a.size and (a.min() < 0 or a.max() > np.iinfo(np.uint16).max):
        raise InputError(
            f"{name} has depth values outside 0..65535 mm (min {a.min()}, max {a.max()}); "
            "depth must be millimetres with 0 for no reading"
        )
    return np.rint(a).astype(np.uint16)


def check_frames(
    frames_mm: ArrayLike, intrinsics: Intrinsics, *, name: str = "frames"
) -> NDArray[np.uint16]:
    """Validate a stack of depth frames ``(N, H, W)``; errors name the offending frame index."""
    a = np.asarray(frames_mm)
    if a.ndim != 3:
        raise InputError(
            f"{name} must have shape (N, {intrinsics.height}, {intrinsics.width}), got {a.shape}"
        )
    if a.dtype == np.uint16 and a.shape[1:] == (intrinsics.height, intrinsics.width):
        return a
    out = np.empty(a.shape, dtype=np.uint16)
    for i in range(a.shape[0]):
        out[i] = check_depth_frame(a[i], intrinsics, name=f"{name}[{i}]")
    return out
